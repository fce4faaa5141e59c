"""The static settings of the voxel renderer, :class:`RenderSettings`, and its result type.

Sizes and switches that fix :func:`~jaxgfx.raycast.render_rle`'s program, one
frozen dataclass (a pytree without leaves), so ``jax.jit(render_rle)`` compiles once
per distinct settings.  :class:`RenderOutput` is what the renderer and the reference
renderer (:mod:`.reference`, which imports no module of the renderer) return.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax

from jaxgfx._src.checks import check_float, check_int, static_field
from jaxgfx._src.frames import BATCHING

__all__ = ["RenderOutput", "RenderSettings"]

_TRAVERSALS = ("auto", "wide", "scatter")
_BATCHINGS = BATCHING


def _optional_int(name: str, value, low: int) -> int | None:
    return None if value is None else check_int(name, value, low=low)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RenderSettings:
    """The static settings of :func:`~jaxgfx.raycast.render_rle`: sizes and switches of the program.

    A pytree without leaves: every field is static, so ``jax.jit(render_rle)`` needs
    no ``static_argnames`` and compiles once per distinct settings (the fields are
    part of the cache key, like shapes).  Frozen, so one instance can be shared.
    See :func:`~jaxgfx.raycast.render_rle` for what the defaults measure.

    Attributes:
        num_planes: ray-buffer plane budget (None:
            :func:`~jaxgfx.raycast.default_num_planes`).
        oversample: planes per pixel on each segment's far border (1 = thesis
            Eq. 4.4, default 2).
        buffer_size: wide traversal: drawn elements kept per plane (None:
            ``max(64, max(W, H) // 2)``); see ``stats["buffer_overflow"]``.
        refine_steps: if > 0, pixels whose ray entered no candidate element
            re-walk their own ray that many voxels from just before the
            neighbourhood's depth (not in the thesis).  None (default): 16 for
            the wide traversal's lists, 0 for the scatter, whose
            warp tests every pixel against the writers of three planes a
            fraction of a voxel apart: there the re-walk moved the acceptance
            views' agreement by at most 0.2 points and cost 7-20 % of a frame
            (``experiments.rle_quality --refine-steps 16``, ``rle_bench``'s
            ``rewalk_ms``).
        neighbors: adjacent planes on each side whose texels the warp tests against
            the pixel's ray (default 1; 0 = thesis).
        refine_budget: largest number of re-walked pixels (None: ``W H / 32``); see
            ``stats["refine_overflow"]``.
        planes_per_voxel: if > 0 (default 3), the planes cover only the screen
            rectangle of the scene box and are spaced at most ``1 / planes_per_voxel``
            voxels apart at its farthest depth (while the box is wholly in front of
            the eye), so columns narrower than a pixel are still found and the
            agreement does not fall with distance; 0 = the thesis's spacing
            (:func:`~jaxgfx.raycast.screen_segments`).  It also raises the default
            ``num_planes`` by ``planes_per_voxel (X + Z)``.
        traversal: ``"scatter"``: every element projected into the planes that
            cross its cell, each texel keeping its first writer by a scatter-min
            of the walk order (a few wide
            steps a frame); ``"wide"``: each plane walked in blocks of cells, a
            block per plane per loop step (tens
            of steps, each as wide as the planes).  ``"auto"`` (default):
            ``"scatter"`` for a map within its limits
            (:func:`~jaxgfx.raycast.scatter_limits`), on every
            platform; otherwise ``"wide"``, with 512 ``slots`` where the program
            is lowered for the CPU (``jax.lax.platform_dependent``).
        block_cells: wide traversal: major-axis columns per block (default 16).
        block_elements: wide traversal: element slots per plane per step (None:
            ``max(2 max_elements, block_cells, 8)``; at least two columns).
        slots: wide traversal: planes stepped at once, a done plane's slot taking
            the next plane (None: all planes every step, fewest steps; ``"auto"``
            on the CPU: 512).
        window: scatter traversal: (element, plane) pairs per loop step (None: a
            power of two of at least 2^14 sized from the frame: half its pixels on the
            CPU; on an accelerator, where a step costs a launch and a host sync, a few
            times its pixels, shared by a vectorized batch).
        texels: scatter traversal: size of the ray buffer, the planes' rows back
            to back (None: four per pixel, at most every plane's whole column and
            2^24); a frame with more is drawn in passes (``stats["passes"]``).
        chunk: scatter traversal of an instance map: element instances (a tile's
            element at the tile's mip level) gathered at once (None: the power of
            two at or above the frame's pixels, at least 2^14: about one instance a
            pixel at the one-pixel LOD); a frame with more takes them in turn.
        batching: the ``vmap`` rule: ``"frames"`` (one frame after another,
            ``lax.map``), ``"vectorized"`` (the frames as one vmapped program) or
            ``"auto"`` (default: frames on the CPU, vector elsewhere).

    Raises:
        TypeError: a count that is not an int, an ``oversample`` that is not a number.
        ValueError: a count below its least useful value, ``oversample <= 0``.
    """

    num_planes: int | None = static_field(None)
    oversample: float = static_field(2.0)
    buffer_size: int | None = static_field(None)
    refine_steps: int | None = static_field(None)
    neighbors: int = static_field(1)
    refine_budget: int | None = static_field(None)
    planes_per_voxel: float = static_field(3.0)
    traversal: str = static_field("auto")
    block_cells: int = static_field(16)
    block_elements: int | None = static_field(None)
    slots: int | None = static_field(None)
    window: int | None = static_field(None)
    texels: int | None = static_field(None)
    chunk: int | None = static_field(None)
    batching: str = static_field("auto")

    def __post_init__(self):
        # Normalised to Python ints / floats: equal settings hash alike (one compile).
        fields = dict(
            num_planes=_optional_int("num_planes", self.num_planes, 1),
            oversample=check_float("oversample", self.oversample),
            buffer_size=_optional_int("buffer_size", self.buffer_size, 1),
            refine_steps=_optional_int("refine_steps", self.refine_steps, 0),
            neighbors=check_int("neighbors", self.neighbors, low=0),
            refine_budget=_optional_int("refine_budget", self.refine_budget, 1),
            planes_per_voxel=check_float("planes_per_voxel", self.planes_per_voxel),
            block_cells=check_int("block_cells", self.block_cells, low=1),
            block_elements=_optional_int("block_elements", self.block_elements, 1),
            slots=_optional_int("slots", self.slots, 1),
            window=_optional_int("window", self.window, 1),
            texels=_optional_int("texels", self.texels, 1),
            chunk=_optional_int("chunk", self.chunk, 1),
        )
        if self.traversal not in _TRAVERSALS:
            raise ValueError(f"traversal must be one of {_TRAVERSALS}, got {self.traversal!r}")
        if self.batching not in _BATCHINGS:
            raise ValueError(f"batching must be one of {_BATCHINGS}, got {self.batching!r}")
        if fields["planes_per_voxel"] < 0:
            raise ValueError(f"planes_per_voxel must be >= 0, got {fields['planes_per_voxel']}")
        if fields["oversample"] <= 0:
            raise ValueError(f"oversample must be > 0, got {fields['oversample']}")
        for name, value in fields.items():
            object.__setattr__(self, name, value)


class RenderOutput(NamedTuple):
    """Result of a voxel render.

    Attributes:
        color: (H, W, 3) float32 in [0, 1]; 0 where nothing was hit.
        depth: (H, W) float32 camera-space z, +inf where nothing was hit.
        stats: dict of () int32 counters (``elements_total``: elements in the
            traversed columns, ``elements_processed``: those visited before the
            plane was done, ``elements_rendered``: those that passed culling),
            empty for the reference renderer.
    """

    color: jax.Array
    depth: jax.Array
    stats: dict
