"""The per-plane ray caster from end to end (thesis 4.5): :func:`render_rle`.

One frame: the vanishing point and the four screen segments (:mod:`.planes`), the
ray buffer (every element scattered into the planes that cross its cell,
:mod:`.scatter`; for a map beyond the scatter's limits, each plane walked in
blocks of cells, :mod:`.wide`), the warp to the screen (:mod:`.warp`) and, for
pixels the warp is unsure of, a short exact re-walk.  Its
static settings (sizes and switches that fix the program) are one
:class:`~jaxgfx._src.voxel.settings.RenderSettings`.

All functions take the shared :class:`jaxgfx.camera.Camera`; depth is the camera-space
z (distance along the view axis), ``+inf`` where nothing was hit.  Scene coordinates
are voxel units, y up.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, as_float32, focal_lengths, pixel_rays, validate_camera
from jaxgfx._src.checks import check_float, checking, require_values
from jaxgfx._src.frames import per_frame
from jaxgfx._src.precision import in_32bit
from jaxgfx._src.voxel.codec import HALF_LIMIT, IZ_BITS, unpack_element
from jaxgfx._src.voxel.encode import RLEVolume
from jaxgfx._src.voxel.planes import screen_segments, vanishing_point
from jaxgfx._src.voxel.scatter import scatter_frame, scatter_limits
from jaxgfx._src.voxel.settings import RenderOutput, RenderSettings
from jaxgfx._src.voxel.warp import refine_hits, warp_lists
from jaxgfx._src.voxel.wide import traverse_wide

__all__ = [
    "RenderOutput",
    "RenderSettings",
    "default_num_planes",
    "render_rle",
    "lod_distance_for",
    "check_camera_outside",
]


def default_num_planes(
    width: int,
    height: int,
    oversample: float = 1.0,
    *,
    scene_shape=None,
    planes_per_voxel: float = 0.0,
) -> int:
    """Static plane budget: ``2 (W + H)`` (sum of Eq. 4.4 with vp on screen) times oversample.

    With ``scene_shape`` ``(X, Y, Z)`` and ``planes_per_voxel = k``, plus ``k (X + Z)``:
    a far scene needs about ``k`` planes per voxel across its width (see
    :func:`~jaxgfx.raycast.screen_segments`).
    """
    extra = (
        0
        if scene_shape is None
        else int(math.ceil(planes_per_voxel * (scene_shape[0] + scene_shape[2])))
    )
    return int(math.ceil(2 * (width + height) * oversample)) + extra + 64


def lod_distance_for(cam: Camera, pixels: float = 1.0) -> jax.Array:
    """The ``lod_distance`` at which every mip cell spans about ``pixels`` pixels.

    :func:`render_rle` switches to mip level ``l`` (cells of ``2 ** l`` voxels) at
    ``lod_distance * 2 ** (l - 1)``, so a cell at the start of its band spans
    ``2 f / lod_distance`` pixels at every level (``f`` the focal length in
    pixels): this returns ``2 max(fx, fy) / pixels``.  That holds on the view
    axis; toward the screen's corners a cell at the same horizontal distance can
    be up to ``1 / cos`` of the corner ray's angle larger on screen.  The thesis
    leaves its band length ``pd`` a free constant (4.5.4.1); a short one (96
    voxels for a 512x384, 55 degree view, where level-1 cells span 8 pixels)
    makes far instances cheap but fat, and with the thesis's cube mips a
    one-voxel floor steps up where the bands meet (``encode_rle(...,
    mips="column")`` keeps the heights exact).  For a supersampled camera pass
    the original view, or ``pixels`` = the factor, to count output pixels.

    Args:
        cam: the camera (batched cameras give a batch of distances).
        pixels: the cell size on screen to allow, > 0.

    Returns:
        () float32 (or the camera's batch shape): horizontal distance in voxels.

    Raises:
        TypeError, ValueError: ``pixels`` not a number or not > 0.
    """
    pixels = check_float("pixels", pixels)
    if pixels <= 0:
        raise ValueError(f"pixels must be > 0, got {pixels}")
    fx, fy = focal_lengths(cam)
    return 2.0 * jnp.maximum(fx, fy) / pixels


@in_32bit
def render_rle(
    rle,
    cam: Camera,
    *,
    settings: RenderSettings | None = None,
    lod_distance=jnp.inf,
) -> RenderOutput:
    """Renders an :class:`~jaxgfx.raycast.RLEVolume` with the per-plane ray caster (4.5).

    ``jax.jit(render_rle)`` needs no static arguments (the :class:`RenderSettings`
    are static pytree metadata); called eagerly, the frame runs as the same
    compiled program (compiled once per scene layout, camera size and settings).
    ``jax.vmap`` over a batched camera (same
    resolution, :func:`~jaxgfx.camera.stack_cameras`) is one program (a
    ``custom_vmap`` rule, :class:`RenderSettings` ``batching``): lowered for the
    CPU it renders the views one after another (bit-identical to a loop of eager
    or jitted calls at XLA's default flags, no slower
    per frame; shard the batch over devices to use more cores,
    :func:`jaxgfx.sweep.sharded_renderer`); lowered for an accelerator it renders
    them as one wider frame, a batch taking about its slowest frame's dependent
    loop steps.  The default ``traversal`` scatters the map's elements (an
    instance map's: each tile's, at the tile's mip level) into the planes
    (every platform); a map beyond its limits
    (:func:`~jaxgfx.raycast.scatter_limits`) takes the wide traversal
    (a block of cells per plane per loop step), on the CPU with
    plane slots (``RenderSettings.slots``).

    The depth is differentiable w.r.t. the camera: the traversal's choices are
    discrete (no gradient flows through them) and each hit pixel's depth carries
    the derivative of its ray's entry into the level-0 voxel it hit.

    The defaults are the settings the acceptance test (agreement with the
    per-pixel 3-D DDA of :func:`reference_render`: depth within one voxel on
    >= 99 % and the same colour on >= 98 % of pixels) is measured with.  The
    thesis method alone is ``RenderSettings(oversample=1, neighbors=0, refine_steps=0,
    planes_per_voxel=0)``: it
    samples each pixel from its nearest plane, and where columns project to
    less than a plane spacing (far or grazing surfaces) it shows a
    neighbouring voxel.  The defaults add (a) two planes per border pixel,
    placed so that pixel-centre planes are kept (:class:`Segments`), and more
    for a far scene, spaced by a third of a voxel at its far end
    (``planes_per_voxel``: without them the agreement falls with the distance), (b) an
    exact test of the pixel's own ray against the elements of the adjacent
    planes' texels (only screen tiles that a drawn element
    covers are warped), and (c) for the wide traversal's lists, a short exact
    re-walk of the pixel's own ray only for pixels whose
    ray entered none of those elements, at most ``refine_budget`` of them (the
    scatter's warp needs none: ``RenderSettings.refine_steps``).  Elements are
    still processed once per plane, never per pixel.

    Args:
        rle: the scene; NumPy buffers (from :func:`~jaxgfx.raycast.encode_rle`) work,
            also closed over under ``jit``; :func:`~jaxgfx.raycast.as_jax` keeps them on
            the device between calls.
        cam: camera; must not sit inside a solid voxel (see
            :func:`check_camera_outside`).
        settings: static :class:`RenderSettings` (None: the defaults).
        lod_distance: horizontal distance where mip level 1 starts, level ``l``
            at ``lod_distance * 2 ** (l - 1)``; ``inf`` uses level 0 only
            (traced: changing it does not recompile); :func:`lod_distance_for`
            gives the one where mip cells stay about a pixel wide.

    Returns:
        :class:`RenderOutput` with colour (H, W, 3), depth (H, W) and counters
        (``refined``: pixels that asked for a re-walk; ``traversal_steps`` and
        ``loop_iterations``: the dependent loop steps of the traversal and of the
        whole frame, traversal + warp + re-walk; ``passes``: 1 for the wide
        traversal).  With ``traversal="scatter"``, ``elements_total`` counts (element, plane) pairs,
        ``elements_processed`` their rows, ``elements_rendered`` the texels drawn,
        ``passes`` the runs of planes drawn in turn (``RenderSettings.texels``)
        and ``buffer_overflow`` is 0.
    """
    s = RenderSettings() if settings is None else settings
    if not isinstance(s, RenderSettings):
        raise TypeError(f"settings must be a RenderSettings, got {type(s).__name__}")
    if not isinstance(rle, RLEVolume):
        raise TypeError(f"rle must be an RLEVolume (from encode_rle), got {type(rle).__name__}")
    validate_camera(cam, where="render_rle")
    _check_lod_distance(lod_distance)
    if max(cam.width, cam.height) >= HALF_LIMIT:
        raise ValueError(f"camera size {cam.width}x{cam.height} too large: rows must be < 32768")
    if rle.shape[1] >= HALF_LIMIT or rle.shape[2] >= 1 << IZ_BITS:
        raise ValueError(f"rle shape {rle.shape} too large: height must be < 32768, z < 2^26")
    # NumPy buffers straight from encode_rle (closed over under jit, as users write it)
    # become constants here; device buffers pass through unchanged.
    rle = jax.tree_util.tree_map(jnp.asarray, rle)
    cam = as_float32(cam)
    return _compiled_frame(s, rle, cam, jnp.asarray(lod_distance, jnp.float32))


@functools.partial(jax.jit, static_argnums=0)
def _compiled_frame(s: RenderSettings, rle, cam: Camera, lod) -> RenderOutput:
    """:func:`render_rle` of checked arguments, as one compiled program.

    An eager call runs the frame compiled once per scene layout, camera size and
    settings; op by op, its loops would compile again at every call (seconds each)
    and round apart from the jitted frame.  Under the caller's ``jit`` (or ``vmap``,
    ``grad``) the call is inlined into the caller's program.
    """
    # The traversal picks voxels (discrete); the depth's derivative w.r.t. the
    # camera is that of the hit voxel's box entry along the pixel's ray.
    fixed = jax.tree_util.tree_map(jax.lax.stop_gradient, cam)
    out = _frame_kernel(s)(rle, fixed, jax.lax.stop_gradient(lod))
    return out._replace(depth=_differentiable_depth(cam, out.depth))


def _check_lod_distance(lod_distance) -> None:
    """``lod_distance`` must be > 0 (``inf``: level 0 only): the mip levels and the planes'
    spacing are derived from it, and NaN or a distance <= 0 gives them no meaning.

    Concrete values are checked now, traced ones inside :func:`~jaxgfx.checks.checked`.
    """
    if np.ndim(lod_distance) != 0:
        raise ValueError(f"lod_distance must be a scalar, got shape {np.shape(lod_distance)}")
    if not isinstance(lod_distance, jax.core.Tracer):
        if not float(lod_distance) > 0:
            raise ValueError(f"lod_distance must be > 0 (inf: level 0 only), got {lod_distance}")
        return
    if checking():
        d = jnp.asarray(lod_distance)
        require_values("lod_distance", d > 0, d, "{} must be > 0", "render_rle")


def _differentiable_depth(cam: Camera, depth):
    """``depth``, with the derivative w.r.t. ``cam`` of the hit voxel's entry along each ray.

    The hit point just past ``depth`` names the voxel; the slab test of the pixel's
    ray against that unit box gives its entry ``t``, whose value is replaced by
    ``depth`` (the same number up to rounding) and whose gradient is kept.  Misses
    keep ``+inf`` and a zero gradient.
    """
    hit = jnp.isfinite(depth)
    t = jnp.where(hit, depth, 0.0)
    origins, dirs = pixel_rays(cam, normalize=False)
    o_fixed, d_fixed = jax.lax.stop_gradient((origins, dirs))
    p = o_fixed + d_fixed * (t + 1e-3)[..., None]
    lo = jnp.floor(p)
    t_enter = jnp.full(depth.shape, -jnp.inf)
    for k in range(3):
        dk = dirs[..., k]
        safe = jnp.where(jnp.abs(dk) < 1e-12, 1e-12, dk)
        t0 = (lo[..., k] - origins[..., k]) / safe
        t1 = (lo[..., k] + 1.0 - origins[..., k]) / safe
        near = jnp.where(jnp.abs(dk) < 1e-12, -jnp.inf, jnp.minimum(t0, t1))
        t_enter = jnp.maximum(t_enter, near)
    t_enter = jnp.where(hit & jnp.isfinite(t_enter), t_enter, 0.0)
    return jnp.where(hit, depth + (t_enter - jax.lax.stop_gradient(t_enter)), depth)


# Plane slots of the wide traversal on the CPU: 4-8x faster there than every plane
# in every step on rle_bench's scenes (experiments.rle_bench, slots_ms beside wide_ms).
_CPU_SLOTS = 512


def _render_auto(s: RenderSettings, rle, cam: Camera, lod, frames: int = 1) -> RenderOutput:
    """One frame; ``traversal="auto"`` picks by the scene and the platform.

    A map the scatter can draw takes it everywhere: a few wide steps a frame,
    and on XLA:CPU faster than the thesis's one-cell walk on every scene of
    ``experiments.rle_bench``, instance maps included.  A map beyond its limits
    takes the wide traversal: on the CPU with 512 plane slots (a done plane's
    slot takes the next plane, so a step's width follows the live planes;
    ``rle_bench``'s ``slots_ms``), elsewhere every plane in every step (an
    accelerator pays per dependent step, a kernel launch each).  Only the
    chosen branch is compiled.
    ``frames``: the frames of the vectorized batch this frame is one of.
    """
    if s.traversal != "auto":
        return _render_frame(s, rle, cam, lod, frames)
    if scatter_limits(rle, _num_planes(s, rle, cam)) is None:
        return _render_frame(dataclasses.replace(s, traversal="scatter"), rle, cam, lod, frames)
    wide = dataclasses.replace(s, traversal="wide")
    slots = wide if s.slots is not None else dataclasses.replace(wide, slots=_CPU_SLOTS)
    return jax.lax.platform_dependent(
        rle,
        cam,
        lod,
        cpu=functools.partial(_render_frame, slots, frames=frames),
        default=functools.partial(_render_frame, wide, frames=frames),
    )


def _num_planes(s: RenderSettings, rle, cam: Camera) -> int:
    """The frame's static plane budget: ``s.num_planes`` or :func:`default_num_planes`."""
    if s.num_planes is not None:
        return s.num_planes
    return default_num_planes(
        cam.width,
        cam.height,
        s.oversample,
        scene_shape=rle.shape,
        planes_per_voxel=s.planes_per_voxel,
    )


@functools.cache
def _frame_kernel(s: RenderSettings):
    """:func:`_render_frame` with the shared batching rule (one kernel per settings).

    On XLA:CPU a batch runs frame by frame: the frame's loops stop early (the scatter's
    windows and passes, the wide walk's plane slots and re-walk batches), which a
    vectorized batch would run to the longest frame; one frame at a time is bit-identical
    to a loop over the cameras.  Elsewhere the batch is one program
    (:func:`jaxgfx._src.frames.per_frame`).
    """
    return per_frame(
        functools.partial(_render_auto, s),
        s.batching,
        batch_fn=lambda n: functools.partial(_render_auto, s, frames=n),
    )


def _render_frame(s: RenderSettings, rle, cam: Camera, lod, frames: int = 1) -> RenderOutput:
    """One frame of :func:`render_rle` (its arguments already checked and on the device).

    ``frames``: the frames of the vectorized batch this frame is one of (the scatter's
    accelerator window).
    """
    num_planes = _num_planes(s, rle, cam)
    rows = max(cam.width, cam.height)
    vp_h = vanishing_point(cam)
    seg = screen_segments(
        cam,
        vp_h,
        num_planes=num_planes,
        oversample=s.oversample,
        scene_shape=rle.shape,
        planes_per_voxel=s.planes_per_voxel,
        lod_distance=lod,
        levels=rle.levels,
    )
    planes = jnp.arange(num_planes, dtype=jnp.int32)
    if s.traversal == "scatter":
        image, stats, steps, passes = scatter_frame(
            rle, cam, seg, planes, rows=rows, lod_distance=lod, settings=s, frames=frames
        )
        # No re-walk by default; asked for, it runs in batches, idle ones skipped.
        warped = (*image, jnp.int32(0))
        return _finish_frame(rle, cam, seg, s, stats[None, :], steps, warped, passes, batched=False)
    # The accelerator's form (every plane in every step) warps every busy tile in
    # one step and re-walks every uncertain pixel in one batch: its dependent steps
    # stay a few tens per frame.  Plane slots are the CPU's form: batched warp.
    batched = s.slots is None
    lists = traverse_wide(
        rle,
        cam,
        seg,
        planes,
        rows=rows,
        lod_distance=lod,
        buffer_size=s.buffer_size,
        block_cells=s.block_cells,
        block_elements=s.block_elements,
        slots=s.slots,
    )
    warped = warp_lists(
        rle,
        cam,
        seg,
        *lists[:5],
        neighbors=s.neighbors,
        batch_tiles=(1 << 30) if batched else None,
        scan_width=8 if batched else 1,
        with_steps=True,
    )
    return _finish_frame(
        rle, cam, seg, s, lists[5], lists[6], warped, jnp.int32(1), batched=batched
    )


def _finish_frame(
    rle, cam, seg, s: RenderSettings, stats, trav_steps, warped, passes, *, batched: bool
) -> RenderOutput:
    """The re-walk of a warped frame; the frame's statistics (``stats``: (planes, 4) counts)."""
    color, depth, entered, warp_steps = warped
    W, H = cam.width, cam.height
    refined = jnp.int32(0)
    refine_steps_taken = jnp.int32(0)
    refine_steps = s.refine_steps
    if refine_steps is None:
        refine_steps = 0 if s.traversal == "scatter" else 16
    budget = (W * H) // 32 if s.refine_budget is None else s.refine_budget
    if refine_steps > 0:
        batch = budget if batched else 1024
        color, depth, refined = refine_hits(
            rle,
            cam,
            color,
            depth,
            steps=refine_steps,
            mask=~entered,
            budget=budget,
            batch=batch,
        )
        refine_steps_taken = refine_steps * ((jnp.minimum(refined, budget) + batch - 1) // batch)
    total = jnp.sum(stats, axis=0)
    return RenderOutput(
        color,
        depth,
        dict(
            elements_total=total[0],
            elements_processed=total[1],
            elements_rendered=total[2],
            buffer_overflow=total[3],
            planes=jnp.sum(seg.count),
            refined=refined,
            refine_overflow=jnp.maximum(refined - budget, 0) if refine_steps > 0 else refined,
            traversal_steps=trav_steps,
            loop_iterations=trav_steps + warp_steps + refine_steps_taken,
            passes=passes,
        ),
    )


# ---------------------------------------------------------------------------
# The camera must be in empty space
# ---------------------------------------------------------------------------


def check_camera_outside(rle, cam: Camera) -> None:
    """Raises ``ValueError`` if a concrete camera sits inside a drawn voxel's column run.

    The renderers assume the eye is in empty space; a camera inside solid voxels
    has no well-defined first hit.
    """
    pos = np.asarray(cam.position, np.float64)
    for p in pos.reshape(-1, 3):
        _check_point(rle, p)


def _check_point(rle, p):
    X, Y, Z = rle.shape
    i = np.floor(p).astype(np.int64)
    if np.any(i < 0) or i[0] >= X or i[1] >= Y or i[2] >= Z:
        return
    count = np.asarray(rle.count, np.int64)
    ox, _, oz = rle.level_shapes[0]
    if np.asarray(rle.tiles)[i[0] // ox, i[2] // oz] < 0:
        return
    col = rle.level_offsets[0] + (i[0] % ox) * oz + i[2] % oz
    if count[col] == 0:
        return
    first = int(np.asarray(rle.first)[col])
    ptr = int(np.asarray(rle.ptr)[col])
    els = [first] + [int(v) for v in np.asarray(rle.elements)[ptr : ptr + count[col] - 1]]
    y = Y
    for el in els:
        skip, draw = unpack_element(el)
        y -= skip
        if y - draw <= i[1] < y:
            raise ValueError(f"camera position {p.tolist()} is inside a solid voxel")
        y -= draw
