"""Fitting deformation styles to depth and silhouette images (thesis 5.6 seen through a camera).

:func:`jaxgfx.skin.fit_style` fits a style to target *vertices*; a researcher observes depth scans
and outlines instead.  :func:`fit_style_images` fits the same log-parameters (textures and curves,
:func:`~jaxgfx._src.skin.fit.style_to_params`) to images of P posed characters seen by C cameras:

    style -> skin_fn(style, pose) -> rasterize -> analytic_antialias -> loss against the images

the P skinned meshes batched with ``vmap`` over poses, the images with one ``vmap`` over the
P x C (pose, camera) pairs.  Two images per (pose, camera):

* **silhouette**: the coverage image (1 where the character is drawn, 0 elsewhere) blended across
  silhouette edges by :func:`jaxgfx.silhouette.analytic_antialias` over a background of 0, so it
  moves continuously, with gradients of the covered area's size, as an outline moves across
  pixel centres;
* **depth**: camera-space z from :func:`jaxgfx.raster.rasterize` (differentiable where coverage does
  not change), ``+inf`` where nothing is drawn.  It is not antialiased: the depth term only counts
  pixels both images cover, and moving outlines are the silhouette term's job.

Loss per image (:func:`image_loss`), averaged over the P x C images::

    silhouette_weight * mean_pixels (S - S_target)^2
  + depth_weight * mean_{pixels both cover} ((z - z_target) * f_y / z_target)^2

The depth residual is measured in pixels at the target's depth (``f_y`` is the focal length in
pixels), so both terms are unit-free and the default weights (1 and 1) work for any scene scale.
Pixels whose residual exceeds ``depth_clip`` (4 pixels) are left out of the depth term: there
the two images see different surfaces (a tail in front of the body in one, the body in the
other), and their depth gradient would pull the surface the wrong way; the silhouette term moves
such outlines.

The silhouette needs the mesh's edge topology (:func:`jaxgfx.silhouette.silhouette_edges`) with
split vertices welded: glTF characters such as the Fox have vertices of their own per face, and
without welding every triangle edge would count as an outline.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxgfx._src.camera import Camera, focal_lengths, validate_camera
from jaxgfx._src.checks import check_float, check_int
from jaxgfx._src.raster import rasterize
from jaxgfx._src.silhouette import analytic_antialias, silhouette_edges
from jaxgfx._src.skin.fit import (
    FitResult,
    _run_optimizer,
    params_to_style,
    smoothness_penalty,
)
from jaxgfx._src.skin.styles import Style

__all__ = [
    "ImageTargets",
    "render_silhouette_depth",
    "render_style_images",
    "image_loss",
    "style_image_loss",
    "fit_style_images",
    "welded_silhouette_edges",
]

SkinFn = Callable[[Style, Any], jax.Array]
"""``skin_fn(style, pose) -> (V, 3)`` posed vertex positions (pure, jittable)."""


class ImageTargets(NamedTuple):
    """Observed images of P poses from C cameras (what :func:`fit_style_images` fits to)."""

    silhouette: jax.Array  # shape=(P, C, H, W), float32, antialiased coverage in about [0, 1]
    depth: jax.Array  # shape=(P, C, H, W), float32, camera z, +inf where nothing is seen


def render_silhouette_depth(
    cam: Camera, vertices: jax.Array, faces: jax.Array, edges: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Antialiased silhouette and depth of one mesh seen by one camera (pure; vmap it).

    Args:
        cam: one camera (unbatched).
        vertices: (V, 3) world positions.
        faces: (F, 3) int32 faces.
        edges: (F, 3) int32 :func:`jaxgfx.silhouette.silhouette_edges` of ``faces`` (with the
            vertices, where the mesh splits them at seams).

    Returns:
        ``(silhouette (H, W), depth (H, W))``: coverage blended across silhouette edges, and
        camera-space z (``+inf`` where empty).
    """
    ones = jnp.ones((vertices.shape[0], 1), jnp.float32)  # one cheap channel; colour is unused
    out = rasterize(cam, vertices, faces, ones)
    covered = (out.tri_id >= 0).astype(jnp.float32)[..., None]
    # Background 0: a gap narrower than a pixel between two parts shows as a gap.
    sil = analytic_antialias(cam, vertices, faces, out, covered, edges=edges, background=0.0)
    return sil[..., 0], out.depth


def _render_batch(skin_fn, style, poses, faces, edges, cameras):
    """(P, C, H, W) silhouettes and depths: the P skinned meshes, then one vmap over the P x C
    (mesh, camera) pairs.

    One batch axis, not a vmap over cameras inside a vmap over poses: the rasterizer's and the
    antialias pass's batching rules (one per platform) would nest, and each combination of them
    would be traced for the same compiled program.
    """
    verts = jax.vmap(lambda pose: skin_fn(style, pose))(poses)  # (P, V, 3)
    n_pose, n_cam = verts.shape[0], cameras.position.shape[0]
    pose_of = jnp.repeat(jnp.arange(n_pose), n_cam)  # pair k = (k // C, k % C)
    cam_of = jnp.tile(jnp.arange(n_cam), n_pose)
    pair_cams = jax.tree_util.tree_map(lambda a: a[cam_of], cameras)
    sil, depth = jax.vmap(render_silhouette_depth, (0, 0, None, None))(
        pair_cams, verts[pose_of], faces, edges
    )
    return (
        sil.reshape(n_pose, n_cam, *sil.shape[1:]),
        depth.reshape(n_pose, n_cam, *depth.shape[1:]),
    )


# Eager calls (the usual way to make a fit's targets) run the P x C images as one compiled
# program per skin_fn and shapes: op by op, vmap's batched skinning, z-buffer and antialias
# compiled hundreds of small programs (40 s of compilation for 2 x 2 images of 96x72 at XLA's
# defaults).  Under the caller's jit the call is inlined.
_compiled_render_batch = jax.jit(_render_batch, static_argnums=0)


def welded_silhouette_edges(skin_fn: SkinFn, style: Style, poses, faces) -> np.ndarray:
    """Edge topology of a skinned mesh with its split vertices welded (host, once per mesh).

    :func:`jaxgfx.silhouette.silhouette_edges` of ``faces`` with the vertices ``skin_fn`` puts
    on the first pose: vertices it places at exactly the same position (split at seams or per
    face, skinned alike) are one vertex.

    Args:
        skin_fn: ``skin_fn(style, pose) -> (V, 3)`` posed positions.
        style: a concrete style (e.g. the fit's starting style).
        poses: P stacked poses (concrete); the first is used.
        faces: (F, 3) int faces (concrete).

    Returns:
        (F, 3) int32 edge topology for :func:`render_silhouette_depth`.
    """
    pose0 = jax.tree_util.tree_map(lambda a: a[0], poses)
    return silhouette_edges(faces, np.asarray(jax.jit(skin_fn)(style, pose0)))


def _concrete(*trees) -> bool:
    """Whether no leaf of ``trees`` is traced."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(trees))


def render_style_images(
    skin_fn: SkinFn, style: Style, poses, faces, cameras: Camera, *, edges=None
) -> ImageTargets:
    """Images of ``style`` on every pose from every camera (e.g. the targets of a synthetic fit).

    Pure apart from the host-side checks; jit it with ``skin_fn`` closed over (and ``edges``
    given: see below).  Called eagerly, the images are one program compiled once per
    ``skin_fn`` (the same function object) and shapes.

    Args:
        skin_fn: ``skin_fn(style, pose) -> (V, 3)`` posed positions.
        style: the style to render.
        poses: a pytree of P stacked poses (leading axis P on every leaf).
        faces: (F, 3) int faces of the skinned mesh.
        cameras: C stacked cameras (:func:`jaxgfx.camera.stack_cameras`), one resolution.
        edges: (F, 3) edge topology of ``faces`` with split vertices welded,
            ``silhouette_edges(faces, skin_fn(style, pose))`` for any concrete pose.  When
            omitted: that, on the first pose, if ``style`` and ``poses`` are concrete; under
            ``jit``, ``silhouette_edges(faces)``, which draws split vertices' edges as outlines.

    Returns:
        :class:`ImageTargets` with (P, C, H, W) arrays.
    """
    if edges is None:
        edges = (
            welded_silhouette_edges(skin_fn, style, poses, faces)
            if _concrete(style, poses)
            else silhouette_edges(faces)
        )
    faces = jnp.asarray(faces, jnp.int32)
    try:
        hash(skin_fn)
    except TypeError:  # an unhashable callable cannot key a compiled program: trace it inline
        batch = _render_batch
    else:
        batch = _compiled_render_batch
    sil, depth = batch(skin_fn, style, poses, faces, jnp.asarray(edges), cameras)
    return ImageTargets(silhouette=sil, depth=depth)


def image_loss(
    silhouette: jax.Array,
    depth: jax.Array,
    target: ImageTargets | tuple[jax.Array, jax.Array],
    focal_y: jax.Array,
    *,
    silhouette_weight: float = 1.0,
    depth_weight: float = 1.0,
    depth_clip: float = 4.0,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Silhouette L2 plus depth L2 where both images cover, for one image (pure).

    Args:
        silhouette: (H, W) rendered antialiased coverage.
        depth: (H, W) rendered depth (``+inf`` where empty).
        target: ``(silhouette (H, W), depth (H, W))`` of the observation.
        focal_y: () focal length in pixels; depth residuals are scaled by
            ``focal_y / target_depth`` into pixels at that depth.
        silhouette_weight: weight of the silhouette term.
        depth_weight: weight of the depth term.
        depth_clip: pixels whose depth residual exceeds this many pixels are left out of the
            depth term (they see different surfaces, e.g. a tail in front of a body in one image
            and the body in the other); ``inf`` keeps every pixel both images cover.

    Returns:
        ``(total, silhouette_term, depth_term)``, each ().
    """
    t_sil, t_depth = target
    sil_term = jnp.mean((silhouette - t_sil) ** 2)
    both = jnp.isfinite(depth) & jnp.isfinite(t_depth)
    # Double where: the untaken branch sees finite values, so inf - inf never reaches a gradient.
    safe_t = jnp.where(both, t_depth, 1.0)
    resid = jnp.where(both, (jnp.where(both, depth, 1.0) - safe_t) * focal_y / safe_t, 0.0)
    same = both & (jnp.abs(jax.lax.stop_gradient(resid)) <= depth_clip)
    depth_term = jnp.sum(jnp.where(same, resid, 0.0) ** 2) / jnp.maximum(jnp.sum(same), 1)
    return silhouette_weight * sil_term + depth_weight * depth_term, sil_term, depth_term


def style_image_loss(
    params: dict,
    skin_fn: SkinFn,
    poses,
    faces: jax.Array,
    edges: jax.Array,
    cameras: Camera,
    targets: ImageTargets,
    hollow: jax.Array,
    *,
    silhouette_weight: float = 1.0,
    depth_weight: float = 1.0,
    depth_clip: float = 4.0,
    smoothness: float = 0.0,
) -> tuple[jax.Array, jax.Array]:
    """Mean :func:`image_loss` over the P x C images, plus ``smoothness`` times the penalty.

    Args:
        params: log-parameters (:func:`~jaxgfx.skin.style_to_params`).
        skin_fn: ``skin_fn(style, pose) -> (V, 3)``.
        poses: P stacked poses.
        faces: (F, 3) int32; edges: (F, 3) int32 :func:`jaxgfx.silhouette.silhouette_edges`.
        cameras: C stacked cameras.
        targets: :class:`ImageTargets` (P, C, H, W).
        hollow: () hollow offset of the style (not fitted).
        silhouette_weight, depth_weight: weights of the two terms.
        smoothness: weight of :func:`~jaxgfx.skin.smoothness_penalty`.

    Returns:
        Total loss and the data term (the image loss alone).
    """
    style = params_to_style(params, hollow)
    sil, depth = _render_batch(skin_fn, style, poses, faces, edges, cameras)
    _, fy = jax.vmap(focal_lengths)(cameras)  # (C,)
    per_cam = jax.vmap(
        lambda s, d, ts, td, f: image_loss(
            s,
            d,
            (ts, td),
            f,
            silhouette_weight=silhouette_weight,
            depth_weight=depth_weight,
            depth_clip=depth_clip,
        )[0],  # fmt: skip
        in_axes=(0, 0, 0, 0, 0),
    )
    per_image = jax.vmap(lambda s, d, ts, td: per_cam(s, d, ts, td, fy))(
        sil, depth, targets.silhouette, targets.depth
    )
    data = jnp.mean(per_image)
    return data + smoothness * smoothness_penalty(params), data


def _check_image_inputs(skin_fn, poses, faces, cameras, targets, init_style):
    """Host-side checks before anything is traced; returns (P, C)."""
    if not callable(skin_fn):
        raise TypeError(f"skin_fn must be callable as skin_fn(style, pose), got {skin_fn!r}")
    if not isinstance(init_style, Style):
        raise TypeError("init_style must be a Style (use jaxgfx.skin.make_style)")
    if np.any(np.asarray(init_style.textures) <= 0) or np.any(np.asarray(init_style.curves) <= 0):
        raise ValueError("init_style textures and curves must be > 0 (log parametrization)")
    if not isinstance(cameras, Camera):
        raise TypeError("cameras must be a Camera batch (use jaxgfx.camera.stack_cameras)")
    if np.ndim(cameras.position) != 2:
        raise ValueError(
            "cameras must be stacked with a leading axis C, got position shape "
            f"{np.shape(cameras.position)}"
        )
    n_cam = np.shape(cameras.position)[0]
    for k in range(n_cam):
        validate_camera(jax.tree_util.tree_map(lambda a, k=k: a[k], cameras))
    if not isinstance(targets, ImageTargets):
        raise TypeError("targets must be an ImageTargets(silhouette, depth)")
    leaves = jax.tree_util.tree_leaves(poses)
    if not leaves or any(np.ndim(x) < 1 for x in leaves):
        raise ValueError("poses must be a pytree of stacked poses (a leading axis P on every leaf)")
    n_pose = np.shape(leaves[0])[0]
    if any(np.shape(x)[0] != n_pose for x in leaves):
        raise ValueError("poses: every leaf must have the same leading axis P")
    shape = (n_pose, n_cam, cameras.height, cameras.width)
    for name, arr in (("silhouette", targets.silhouette), ("depth", targets.depth)):
        if tuple(np.shape(arr)) != shape:
            raise ValueError(
                f"targets.{name} must have shape (P, C, H, W) = {shape} for {n_pose} poses and "
                f"{n_cam} cameras of {cameras.width}x{cameras.height}, got {np.shape(arr)}"
            )
    sil = np.asarray(targets.silhouette)
    if not np.all(np.isfinite(sil)):
        raise ValueError("targets.silhouette must be finite")
    depth = np.asarray(targets.depth)
    if np.any(np.isnan(depth)) or np.any(depth <= 0) or np.any(depth == -np.inf):
        raise ValueError("targets.depth must be > 0 (or +inf where empty), without NaN")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[-1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be an (F, 3) integer array, got {f.shape} {f.dtype}")
    pose0 = jax.tree_util.tree_map(lambda a: a[0], poses)
    try:
        out = jax.eval_shape(skin_fn, init_style, pose0)
    except Exception as err:  # any failure to trace is a bad skin_fn or pose
        raise TypeError(f"skin_fn(style, pose) failed on init_style and poses[0]: {err}") from err
    if not hasattr(out, "shape") or len(out.shape) != 2 or out.shape[-1] != 3:
        raise ValueError(
            "skin_fn must return (V, 3) positions (take [0] of skin_exact / skin_gltf_chain), "
            f"got {jax.tree_util.tree_map(lambda a: a.shape, out)}"
        )
    if f.size and (f.min() < 0 or f.max() >= out.shape[0]):
        raise ValueError(f"faces must index the {out.shape[0]} vertices skin_fn returns")
    return n_pose, n_cam


def fit_style_images(
    skin_fn: SkinFn,
    poses,
    faces,
    cameras: Camera,
    targets: ImageTargets,
    init_style: Style,
    *,
    steps: int = 500,
    learning_rate: float = 0.03,
    silhouette_weight: float = 1.0,
    depth_weight: float = 1.0,
    depth_clip: float = 4.0,
    smoothness: float = 0.0,
    optimizer: optax.GradientTransformation | None = None,
    progress: bool = True,
    callback: Callable[[int, float, dict], None] | None = None,
    edges=None,
) -> FitResult:
    """Fit a style's textures and curves to depth and silhouette images (never to vertices).

    A driver like :func:`~jaxgfx.skin.fit_style`: it validates its inputs on the host,
    jit-compiles one optimization step (skinning, rasterization and antialiasing of all P x C
    images, batched with ``vmap``, and their gradient) and runs it ``steps`` times.

    Args:
        skin_fn: ``skin_fn(style, pose) -> (V, 3)`` posed positions, pure, e.g.
            ``lambda s, p: skin.skin_exact(rig, p, binding, s, styles="both")[0]`` or
            ``lambda s, p: skin.skin_gltf_chain(chain, p, s)[0]``.  The sampled fast path
            (thesis 5.8) with pass 1 done once: pass the pass-1 tables as the "poses",
            ``tables = jax.vmap(lambda p: skin.sample_spline_frames(rig, p, 32))(poses)`` and
            ``lambda s, t: skin.skin_sampled_tables(t[0], t[1], prep, s, samples=32,
            styles="both")[0]`` with ``prep = skin.prepare_sampled(binding, 32)``.
        poses: a pytree of P stacked poses (leading axis P on every leaf).
        faces: (F, 3) int faces of the skinned mesh (concrete).
        cameras: C stacked cameras (:func:`jaxgfx.camera.stack_cameras`).
        targets: :class:`ImageTargets`, (P, C, H, W) observed silhouettes and depths.
        init_style: starting style, e.g. the neutral :func:`jaxgfx.skin.identity_style` (its shapes
            are kept; its hollow offset is not fitted).
        steps: optimization steps.
        learning_rate: Adam's peak learning rate (cosine-decayed to 1 % over ``steps``); ignored
            when ``optimizer`` is given.
        silhouette_weight: weight of the silhouette L2 term (:func:`image_loss`).
        depth_weight: weight of the depth L2 term (residuals in pixels at the target's depth).
        depth_clip: leave pixels whose depth residual exceeds this many pixels out of the
            depth term (:func:`image_loss`); ``inf`` keeps them all.
        smoothness: weight of the smoothness penalty on the log-parameters.
        optimizer: any optax transformation (default Adam with cosine decay).
        progress: show a tqdm bar.
        callback: called as ``callback(step, loss, params)`` after each step, ``params``
            the log-parameters after it (:func:`params_to_style` makes the style).
        edges: (F, 3) edge topology of the mesh; default
            ``silhouette_edges(faces, skin_fn(init_style, poses[0]))`` (split vertices welded).

    Returns:
        :class:`~jaxgfx.skin.FitResult`; ``data_history`` is the image loss alone.

    Raises:
        TypeError: an argument of the wrong type, named, before anything is traced.
        ValueError: an argument of the wrong shape or value, named, before anything is
            traced.
    """
    _check_image_inputs(skin_fn, poses, faces, cameras, targets, init_style)
    steps = check_int("steps", steps, low=0)
    learning_rate = check_float("learning_rate", learning_rate, low=0.0)
    sw = check_float("silhouette_weight", silhouette_weight, low=0.0)
    dw = check_float("depth_weight", depth_weight, low=0.0)
    smoothness = check_float("smoothness", smoothness, low=0.0)
    if not (isinstance(depth_clip, (int, float)) and depth_clip > 0):
        raise ValueError(f"depth_clip must be > 0 (inf keeps every pixel), got {depth_clip!r}")
    if sw == 0 and dw == 0:
        raise ValueError("silhouette_weight and depth_weight must not both be 0")
    if optimizer is None:
        schedule = optax.cosine_decay_schedule(learning_rate, max(steps, 1), alpha=0.01)
        optimizer = optax.adam(schedule)
    if edges is None:
        edges = welded_silhouette_edges(skin_fn, init_style, poses, np.asarray(faces))
    faces = jnp.asarray(faces, jnp.int32)
    edges = jnp.asarray(edges, jnp.int32)
    if edges.shape != faces.shape:
        raise ValueError(f"edges must have the faces' shape {faces.shape}, got {edges.shape}")
    targets = ImageTargets(
        jnp.asarray(targets.silhouette, jnp.float32), jnp.asarray(targets.depth, jnp.float32)
    )
    hollow = jnp.asarray(init_style.hollow, jnp.float32)

    def loss_fn(p):
        return style_image_loss(
            p, skin_fn, poses, faces, edges, cameras, targets, hollow,
            silhouette_weight=sw, depth_weight=dw, depth_clip=float(depth_clip),
            smoothness=smoothness,
        )  # fmt: skip

    return _run_optimizer(
        loss_fn, init_style, optimizer, steps, desc="fit_style_images", progress=progress,
        callback=callback,
    )  # fmt: skip
