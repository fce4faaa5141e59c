"""Tests for jaxgfx.skin.fit_style: a fitted style lowers the loss on a tiny problem."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxgfx import skin


@pytest.fixture(scope="module")
def problem():
    rig = skin.make_rig(
        np.array([[[0, 0, 0], [0, 0, 1], [0, 0, 2]]], np.float32),
        reference_normal=[[1.0, 0.0, 0.0]],
    )
    a = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    z = np.linspace(0.1, 1.9, 5)
    zz, aa = np.meshgrid(z, a, indexing="ij")
    v = np.stack([0.2 * np.cos(aa), 0.2 * np.sin(aa), zz], -1).reshape(-1, 3)
    v = np.concatenate([v, [[0.0, 0.0, 1.0]]])  # one vertex on the spline axis
    binding = skin.bind_mesh(rig, v, np.zeros((len(v), 1), np.int32), np.ones((len(v), 1)))

    def pose(b, t):
        rot = skin.axis_angle_to_matrix(jnp.array([b, 0.0, 0.0]))
        return skin.forward_kinematics(rig, jnp.eye(3)[None], rot[None], twist=jnp.array([t]))

    poses = jax.tree_util.tree_map(
        lambda *x: jnp.stack(x), *[pose(b, t) for b, t in [(0.0, 0.0), (0.8, 0.5), (1.6, -1.0)]]
    )
    truth = skin.make_style(np.full((3, 3, 4), 1.3), np.full((3, 4), 0.8))
    targets = jax.jit(
        jax.vmap(lambda p: skin.skin_exact(rig, p, binding, truth, styles="both")[0])
    )(poses)
    return rig, binding, poses, targets


def test_fit_reduces_loss(problem):
    rig, binding, poses, targets = problem
    init = skin.identity_style((3, 4), 4)
    res = skin.fit_style(
        rig,
        binding,
        poses,
        targets,
        init,
        steps=30,
        learning_rate=0.05,
        smoothness=1e-3,
        progress=False,
    )
    assert res.loss_history.shape == (31,)
    assert np.all(np.isfinite(res.loss_history))
    # the problem holds a straight pose and an on-axis vertex: gradients stayed finite throughout
    assert res.data_history[-1] < 0.1 * res.data_history[0]
    assert np.all(np.asarray(res.style.textures) > 0) and np.all(np.asarray(res.style.curves) > 0)


def test_smoothness_penalty_zero_for_constant_and_positive_otherwise():
    params = skin.style_to_params(skin.identity_style((3, 4), 4))
    assert float(skin.smoothness_penalty(params)) == 0.0
    bumpy = {**params, "curves": params["curves"].at[0, 1].set(0.5)}
    np.testing.assert_allclose(skin.smoothness_penalty(bumpy), 2 * 0.25 / 9, rtol=1e-6)


def test_fit_bad_input(problem):
    rig, binding, poses, targets = problem
    init = skin.identity_style((3, 4), 4)
    with pytest.raises(ValueError, match="targets"):
        skin.fit_style(rig, binding, poses, targets[:, :-1], init, steps=1, progress=False)
    with pytest.raises(ValueError, match="smoothness"):
        skin.fit_style(rig, binding, poses, targets, init, steps=1, smoothness=-1.0, progress=False)
    with pytest.raises(ValueError, match="styles"):
        skin.fit_style(rig, binding, poses, targets, init, steps=1, styles="none", progress=False)
    with pytest.raises(TypeError, match="init_style"):
        skin.fit_style(rig, binding, poses, targets, None, steps=1, progress=False)


# sampled vs exact skinning differ by O(1/S^2) (1.5 % of this loss at S = 32, 0.35 % at 64)
SAMPLED_REL_TOL = 1e-2


def test_fit_sampled_fast_path_matches_exact(problem):
    rig, binding, poses, targets = problem
    style = skin.make_style(np.full((3, 3, 4), 1.1), np.full((3, 4), 0.9))
    params = skin.style_to_params(style)

    def loss_and_grad(samples):
        # one plain gradient step of size 1: the log-parameters move by minus the gradient
        res = skin.fit_style(
            rig, binding, poses, targets, style, steps=1, smoothness=0.0,
            optimizer=optax.sgd(1.0), samples=samples, progress=False,
        )  # fmt: skip
        moved = skin.style_to_params(res.style)
        return res.loss_history[0], jax.tree_util.tree_map(jnp.subtract, params, moved)

    exact, g_exact = loss_and_grad(None)
    fast, g_fast = loss_and_grad(64)
    np.testing.assert_allclose(fast, exact, rtol=SAMPLED_REL_TOL)
    for a, b in zip(jax.tree_util.tree_leaves(g_fast), jax.tree_util.tree_leaves(g_exact)):
        assert float(jnp.abs(b).max()) > 0
        np.testing.assert_allclose(a, b, atol=SAMPLED_REL_TOL * float(jnp.abs(b).max()))
    with pytest.raises(ValueError, match="samples"):
        skin.fit_style(rig, binding, poses, targets, style, samples=1, progress=False)
