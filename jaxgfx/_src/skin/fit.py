"""Gradient fitting of deformation styles to target poses (thesis 5.6 made differentiable).

The thesis's artist paints three scale textures and draws three scale curves by hand
(Fig. 5.9, 5.11).  Because spline skinning with styles (Eq. 5.13) is differentiable in the
textures and curves, they can instead be fitted to example poses: given a rig, a bound mesh, P
poses and the target vertex positions in each pose, :func:`fit_style` minimizes the mean squared
vertex error plus a smoothness penalty with optax (Adam by default).

``samples=S`` fits through the sampled fast path (thesis 5.8, :func:`skin_sampled`) instead of
exact spline skinning: the poses do not change during a fit, so pass 1 (the sampled frames) and
the unstyled skin are computed once, and a step evaluates (and differentiates) only the style
offsets of the dominant spline (:func:`~jaxgfx._src.skin.kernels.style_offsets`).  The
gradient w.r.t. the textures and curves is a scatter-add into those small tables.

Textures and curves are parametrized by their logarithm, so they stay positive (Eq. 5.9 and 5.12
require ``T, C >= 0``) and the identity style is the zero parameter.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm.auto import tqdm

from jaxgfx._src.checks import check_int
from jaxgfx._src.skin.binding import SkinBinding
from jaxgfx._src.skin.kernels import style_offsets
from jaxgfx._src.skin.rig import SplinePose, SplineRig
from jaxgfx._src.skin.sampled import prepare_sampled, sample_spline_frames, skin_sampled_tables
from jaxgfx._src.skin.skinning import skin_exact
from jaxgfx._src.skin.styles import Style, _style_flags

__all__ = [
    "FitResult",
    "style_to_params",
    "params_to_style",
    "smoothness_penalty",
    "style_loss",
    "fit_style",
]


class FitResult(NamedTuple):
    """Result of :func:`fit_style`."""

    style: Style  # the fitted style
    loss_history: np.ndarray  # shape=(steps + 1,), float64, total loss before each step and after
    data_history: np.ndarray  # shape=(steps + 1,), float64, the data term alone
    seconds: float  # wall time of the optimization loop, compilation included


def style_to_params(style: Style) -> dict:
    """Log-parameters of a style (textures and curves must be > 0)."""
    return {"textures": jnp.log(style.textures), "curves": jnp.log(style.curves)}


def params_to_style(params: dict, hollow) -> Style:
    """Inverse of :func:`style_to_params`."""
    return Style(
        textures=jnp.exp(params["textures"]),
        curves=jnp.exp(params["curves"]),
        hollow=jnp.asarray(hollow, jnp.float32),
    )


def smoothness_penalty(params: dict) -> jax.Array:
    """Mean squared first differences of the log-textures (along x and α) and log-curves."""
    t, c = params["textures"], params["curves"]
    return (
        jnp.mean(jnp.diff(t, axis=1) ** 2)
        + jnp.mean(jnp.diff(t, axis=2) ** 2)
        + jnp.mean(jnp.diff(c, axis=1) ** 2)
    )


def style_loss(
    params: dict,
    rig: SplineRig,
    binding: SkinBinding,
    poses: SplinePose,
    targets: jax.Array,
    hollow: jax.Array,
    *,
    smoothness: float = 0.0,
    styles: str = "both",
    dominant_only: bool = False,
) -> tuple[jax.Array, jax.Array]:
    """Mean squared vertex error over poses, plus ``smoothness`` times the penalty.

    Args:
        params: log-parameters (:func:`style_to_params`).
        rig: the rig.
        binding: the bound mesh.
        poses: P stacked poses (leading axis P on every field).
        targets: (P, V, 3) target positions.
        hollow: () hollow offset of the style (not fitted).
        smoothness: weight of :func:`smoothness_penalty`.
        styles: which envelopes to use.
        dominant_only: style only the dominant spline.

    Returns:
        Total loss and the data term.
    """
    style = params_to_style(params, hollow)
    pred = jax.vmap(
        lambda p: skin_exact(rig, p, binding, style, styles=styles, dominant_only=dominant_only)[0]
    )(poses)
    return _loss_terms(params, pred, targets, smoothness)


def _loss_terms(params, pred, targets, smoothness) -> tuple[jax.Array, jax.Array]:
    data = jnp.mean(jnp.sum((pred - targets) ** 2, axis=-1))
    return data + smoothness * smoothness_penalty(params), data


def _check_sampled(binding: SkinBinding, samples: int, dominant_only: bool) -> int:
    samples = check_int("samples", samples, low=2)
    if not dominant_only and binding.weight.shape[1] > 1:
        raise ValueError(
            "samples: the sampled path styles the dominant spline only (thesis 5.8.2); "
            "pass dominant_only=True"
        )
    return samples


def _sampled_predictor(
    rig: SplineRig, binding: SkinBinding, poses: SplinePose, samples: int, styles: str
) -> Callable[[Style], jax.Array]:
    """``style -> (P, V, 3)`` posed positions by the sampled path, pose work done once.

    Pass 1 and the unstyled skin do not depend on the style: they are computed here, once, and
    the returned function adds the style offsets (the only part a fitting step differentiates).
    Equal to ``vmap(skin_sampled(...)[0])`` over the poses.
    """
    radial, rect = _style_flags(styles)
    prep = prepare_sampled(binding, samples)

    @jax.jit
    def pose_terms(poses):
        def one(pose):
            skinning, style_table = sample_spline_frames(rig, pose, samples)
            pos = skin_sampled_tables(skinning, style_table, prep, samples=samples)[0]
            return pos, style_table

        return jax.vmap(one)(poses)

    base, style_tables = pose_terms(poses)

    def predict(style: Style) -> jax.Array:
        def one(style_table):
            return style_offsets(
                style_table, style, samples, prep.dominant_coord, prep.dominant_weight,
                prep.dominant_local, prep.dominant_local_normal, radial=radial, rect=rect,
            )[0]  # fmt: skip

        return base + jax.vmap(one)(style_tables)

    return predict


def _check_fit_inputs(rig, binding, poses, targets, init_style):
    if not isinstance(binding, SkinBinding):
        raise TypeError("binding must be a SkinBinding (use jaxgfx.skin.bind_mesh)")
    if not isinstance(init_style, Style):
        raise TypeError("init_style must be a Style (use jaxgfx.skin.make_style)")
    pts = np.asarray(poses.points)
    if pts.ndim != 4 or pts.shape[1:] != (rig.num_splines, 3, 3):
        raise ValueError(
            f"poses.points must have shape (P, {rig.num_splines}, 3, 3), got {pts.shape}"
        )
    t = np.asarray(targets)
    nv = binding.rest.shape[0]
    if t.shape != (pts.shape[0], nv, 3):
        raise ValueError(f"targets must have shape ({pts.shape[0]}, {nv}, 3), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("targets must be finite")
    if np.any(np.asarray(init_style.textures) <= 0) or np.any(np.asarray(init_style.curves) <= 0):
        raise ValueError("init_style textures and curves must be > 0 (log parametrization)")


def fit_style(
    rig: SplineRig,
    binding: SkinBinding,
    poses: SplinePose,
    targets,
    init_style: Style,
    *,
    steps: int = 500,
    learning_rate: float = 0.05,
    smoothness: float = 1e-3,
    optimizer: optax.GradientTransformation | None = None,
    styles: str = "both",
    dominant_only: bool = False,
    samples: int | None = None,
    progress: bool = True,
    callback: Callable[[int, float, dict], None] | None = None,
) -> FitResult:
    """Fit a style's textures and curves to target poses by gradient descent.

    This is a driver (like a training loop): it validates its inputs, jit-compiles one
    optimization step and runs it ``steps`` times with a tqdm progress bar.

    Args:
        rig: the rig.
        binding: the bound mesh (:func:`jaxgfx.skin.bind_mesh`).
        poses: P stacked poses.
        targets: (P, V, 3) target positions.
        init_style: starting style (its shapes are kept; its hollow offset is not fitted).
        steps: optimization steps.
        learning_rate: Adam's peak learning rate (cosine-decayed to 1 % over ``steps``); ignored
            when ``optimizer`` is given.
        smoothness: weight of the smoothness penalty.
        optimizer: any optax transformation (default Adam with cosine decay).
        styles: 'radial', 'rect' or 'both'.
        dominant_only: style only the dominant spline.
        samples: None fits through exact spline skinning; S >= 2 through the sampled fast path
            (S samples per spline, pass 1 and the unstyled skin computed once; style on the
            dominant spline, so ``dominant_only=True`` is required for several influences).
            Faster per step, at the sampled path's accuracy (``experiments/fit_style.py``
            reports both).
        progress: show a tqdm bar.
        callback: called as ``callback(step, loss, params)`` after each step, ``params``
            the log-parameters after it (:func:`params_to_style` makes the style).

    Returns:
        :class:`FitResult` with the fitted style and the loss history.
    """
    _check_fit_inputs(rig, binding, poses, targets, init_style)
    steps = check_int("steps", steps, low=0)
    if not smoothness >= 0:
        raise ValueError(f"smoothness must be >= 0, got {smoothness}")
    if styles == "none":
        raise ValueError("styles must be 'radial', 'rect' or 'both' to fit a style")
    _style_flags(styles)
    if samples is not None:
        samples = _check_sampled(binding, samples, dominant_only)
    if optimizer is None:
        schedule = optax.cosine_decay_schedule(learning_rate, max(steps, 1), alpha=0.01)
        optimizer = optax.adam(schedule)
    targets = jnp.asarray(targets, jnp.float32)
    hollow = jnp.asarray(init_style.hollow, jnp.float32)

    if samples is None:

        def loss_fn(p):
            return style_loss(
                p, rig, binding, poses, targets, hollow,
                smoothness=smoothness, styles=styles, dominant_only=dominant_only,
            )  # fmt: skip
    else:
        predict = _sampled_predictor(rig, binding, poses, samples, styles)

        def loss_fn(p):
            return _loss_terms(p, predict(params_to_style(p, hollow)), targets, smoothness)

    return _run_optimizer(
        loss_fn, init_style, optimizer, steps, desc="fit_style", progress=progress,
        callback=callback,
    )  # fmt: skip


def _run_optimizer(
    loss_fn: Callable[[dict], tuple[jax.Array, jax.Array]],
    init_style: Style,
    optimizer: optax.GradientTransformation,
    steps: int,
    *,
    desc: str,
    progress: bool,
    callback: Callable[[int, float, dict], None] | None,
) -> FitResult:
    """The optimization loop of the fitting drivers: one jitted step run ``steps`` times.

    Args:
        loss_fn: ``params -> (total loss, data term)`` of the log-parameters, pure.
        init_style: the starting style (its hollow offset is kept).
        optimizer: the optax transformation.
        steps: steps to run.
        desc: tqdm label.
        progress: show a tqdm bar.
        callback: called as ``callback(step, loss, params)`` after each step, ``params``
            the log-parameters after it (:func:`params_to_style` makes the style).

    Returns:
        :class:`FitResult`: the losses before each step and after the last, and the wall seconds
        of the loop (compilation included).
    """
    params = style_to_params(init_style)

    @jax.jit
    def step(p, s):
        (loss, data), grads = jax.value_and_grad(loss_fn, has_aux=True)(p)
        updates, s = optimizer.update(grads, s, p)
        return optax.apply_updates(p, updates), s, loss, data

    opt_state = optimizer.init(params)
    losses, datas = [], []
    t0 = time.perf_counter()
    bar = tqdm(range(steps), disable=not progress, desc=desc, leave=False)
    for i in bar:
        params, opt_state, loss, data = step(params, opt_state)
        losses.append(float(loss))
        datas.append(float(data))
        if progress and (i % 10 == 0 or i == steps - 1):
            bar.set_postfix(loss=f"{losses[-1]:.3e}")
        if callback is not None:
            callback(i, losses[-1], params)
    # the loss after the last step without a second compile: one more step's value (its update
    # is dropped); with no steps, the loss alone
    final, final_data = jax.jit(loss_fn)(params) if steps == 0 else step(params, opt_state)[2:]
    seconds = time.perf_counter() - t0
    return FitResult(
        style=params_to_style(params, init_style.hollow),
        loss_history=np.asarray(losses + [float(final)]),
        data_history=np.asarray(datas + [float(final_data)]),
        seconds=seconds,
    )
