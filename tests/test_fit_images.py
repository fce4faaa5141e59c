"""Tests for jaxgfx.skin.fit_style_images: styles fitted to depth + silhouette images.

One tiny rig (50 vertices), 2 poses x 2 cameras at 48x32; two compiles for the file: one image
at a time (targets, the loop side) and the fit (the batched loss and its gradient).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgfx import skin
from jaxgfx._src.skin import fit_images
from jaxgfx.camera import look_at, stack_cameras
from jaxgfx.silhouette import silhouette_edges

W, H = 48, 32
# the same images and losses through vmap and through a loop: float32 rounding of a mean
VMAP_TOL = 1e-4


@pytest.fixture(scope="module")
def problem():
    v, n, faces = skin.limb_mesh(8, 6, 0.25, 2.0)
    rig = skin.make_rig(
        np.array([[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.0]]], np.float32),
        stiffness=4.0,
        reference_normal=[[1.0, 0.0, 0.0]],
    )
    binding = skin.bind_mesh(rig, v, np.zeros((len(v), 1), np.int32), np.ones((len(v), 1)))
    poses = jax.vmap(lambda b, t: skin.demo_arm_pose(rig, b, t))(
        jnp.array([0.6, 1.6]), jnp.array([0.8, -0.5])
    )
    center = np.array([0.0, 1.0, -0.4])
    cams = stack_cameras(
        [
            look_at(center + 3.4 * np.array(d), center, 45.0, W, H)
            for d in ([0.8, 0.3, 0.5], [-0.8, 0.3, -0.5])
        ]
    )
    rows = np.linspace(0.0, 1.0, 3)[:, None]
    cols = np.linspace(0.0, 1.0, 4)[None, :]
    truth = skin.make_style(
        np.stack(
            [1.0 + 0.3 * rows * cols, 1.2 - 0.2 * cols + 0 * rows, 0.9 + 0.2 * rows + 0 * cols]
        ),
        np.stack([1.0 + 0.2 * cols[0], 1.15 - 0.1 * cols[0], 0.9 + 0 * cols[0]]),
    )

    def skin_fn(style, pose):
        return skin.skin_exact(rig, pose, binding, style, styles="both")[0]

    edges = silhouette_edges(faces)
    # One image at a time, one compile for every style (the fit batches them with vmap).
    one = jax.jit(
        lambda style, cam, pose: skin.render_silhouette_depth(
            cam, skin_fn(style, pose), jnp.asarray(faces), jnp.asarray(edges)
        )
    )

    def loop(style):
        images = [[one(style, _index(cams, k), _index(poses, p)) for k in range(2)] for p in (0, 1)]
        return skin.ImageTargets(
            jnp.asarray([[sil for sil, _ in row] for row in images]),
            jnp.asarray([[depth for _, depth in row] for row in images]),
        )

    return skin_fn, poses, faces, cams, truth, loop(truth), loop


def _index(tree, i):
    return jax.tree_util.tree_map(lambda a: a[i], tree)


INIT = skin.identity_style((3, 4), 4)


@pytest.fixture(scope="module")
def fitted(problem):
    """25 steps from the neutral style: the one compile of the batched loss and gradient."""
    skin_fn, poses, faces, cams, _, targets, _ = problem
    return skin.fit_style_images(
        skin_fn, poses, faces, cams, targets, INIT, steps=25, learning_rate=0.05, progress=False
    )


def test_targets_show_the_character(problem):
    targets = problem[5]
    assert targets.silhouette.shape == targets.depth.shape == (2, 2, H, W)
    covered = np.isfinite(np.asarray(targets.depth)).mean(axis=(2, 3))
    # every view sees the limb, none is filled by it
    assert np.all(covered > 0.03) and np.all(covered < 0.6), covered
    sil = np.asarray(targets.silhouette)
    # antialiasing leaves fractional coverage on the outline only
    assert np.any((sil > 0.05) & (sil < 0.95))


def test_fit_lowers_the_vertex_error_of_a_hidden_style(problem, fitted):
    skin_fn, poses, _, _, truth, _, _ = problem
    assert fitted.loss_history.shape == (26,)
    assert fitted.loss_history[-1] < 0.2 * fitted.loss_history[0]
    run = jax.jit(jax.vmap(skin_fn, in_axes=(None, 0)))
    want = np.asarray(run(truth, poses))
    before = np.linalg.norm(np.asarray(run(INIT, poses)) - want, axis=-1).mean()
    after = np.linalg.norm(np.asarray(run(fitted.style, poses)) - want, axis=-1).mean()
    # the fit saw images only; the vertices it never saw came closer
    assert after < 0.5 * before, (before, after)


def test_gradients_finite_and_nonzero(fitted):
    # Adam turns any NaN or inf in a gradient into NaN parameters, and leaves a parameter whose
    # gradient is always zero where it started: finite, moved textures and curves mean finite,
    # non-zero gradients through skinning, rasterization and antialiasing.
    assert np.all(np.isfinite(fitted.loss_history))
    for name in ("textures", "curves"):
        got = np.asarray(getattr(fitted.style, name))
        assert np.all(np.isfinite(got)), name
        assert np.abs(np.log(got)).max() > 1e-2, name


def test_vmap_path_equals_loop(problem, fitted):
    _, _, _, cams, _, targets, loop = problem
    images = loop(INIT)
    fy = np.asarray(cams.focal)[:, 1]
    losses = [
        skin.image_loss(
            images.silhouette[p, k],
            images.depth[p, k],
            (targets.silhouette[p, k], targets.depth[p, k]),
            fy[k],
        )[0]
        for p in range(2)
        for k in range(2)
    ]
    # the fit's first loss (vmap over poses and cameras) is the mean of the looped images' losses
    assert float(np.mean(losses)) > 1e-3
    np.testing.assert_allclose(fitted.loss_history[0], np.mean(losses), rtol=VMAP_TOL)


def test_image_loss_terms():
    sil = jnp.array([[0.0, 0.5], [1.0, 1.0]])
    depth = jnp.array([[jnp.inf, 2.0], [2.0, 4.0]])
    target = (jnp.array([[0.0, 1.0], [1.0, 1.0]]), jnp.array([[jnp.inf, jnp.inf], [2.0, 2.0]]))
    total, s, d = skin.image_loss(
        sil, depth, target, 10.0, silhouette_weight=2.0, depth_weight=3.0, depth_clip=np.inf
    )
    np.testing.assert_allclose(s, 0.25 / 4)
    # both cover two pixels: residuals 0 and (4 - 2) * 10 / 2 = 10 pixels
    np.testing.assert_allclose(d, 100.0 / 2)
    np.testing.assert_allclose(total, 2.0 * s + 3.0 * d)
    # the default depth_clip (4 pixels) leaves the 10-pixel residual out: it sees another surface
    assert float(skin.image_loss(sil, depth, target, 10.0)[2]) == 0.0
    # a target 1 % deeper is f_y / 101 pixels away wherever both cover
    deeper = skin.image_loss(sil, depth, (target[0], depth * 1.01), 10.0)[2]
    np.testing.assert_allclose(deeper, (10.0 / 101) ** 2, rtol=1e-5)
    g = jax.grad(lambda z: skin.image_loss(sil, z, target, 10.0)[0])(depth)
    assert np.all(np.isfinite(g)) and float(g[0, 0]) == 0.0


def test_bad_arguments_raise_before_tracing(problem):
    skin_fn, poses, faces, cams, _, targets, _ = problem
    init = skin.identity_style((3, 4), 4)

    def fit(**kw):
        args = dict(
            skin_fn=skin_fn, poses=poses, faces=faces, cameras=cams, targets=targets,
            init_style=init, steps=1, progress=False,
        )  # fmt: skip
        args.update(kw)
        return skin.fit_style_images(**args)

    with pytest.raises(ValueError, match="targets.depth"):
        fit(targets=skin.ImageTargets(targets.silhouette, targets.depth[:, :1]))
    with pytest.raises(ValueError, match="targets.silhouette"):
        fit(targets=skin.ImageTargets(targets.silhouette * np.nan, targets.depth))
    with pytest.raises(ValueError, match="targets.depth"):
        fit(targets=skin.ImageTargets(targets.silhouette, -targets.depth))
    with pytest.raises(TypeError, match="targets"):
        fit(targets=(targets.silhouette, targets.depth))
    with pytest.raises(TypeError, match="init_style"):
        fit(init_style=None)
    with pytest.raises(ValueError, match="init_style"):
        fit(init_style=skin.make_style(np.zeros((3, 3, 4)), np.ones((3, 4))))
    with pytest.raises(TypeError, match="cameras"):
        fit(cameras=None)
    with pytest.raises(ValueError, match="cameras"):
        fit(cameras=jax.tree_util.tree_map(lambda a: a[0], cams))
    with pytest.raises(ValueError, match="steps"):
        fit(steps=-1)
    with pytest.raises(ValueError, match="depth_weight"):
        fit(depth_weight=-1.0)
    with pytest.raises(ValueError, match="both be 0"):
        fit(depth_weight=0.0, silhouette_weight=0.0)
    with pytest.raises(ValueError, match="smoothness"):
        fit(smoothness=float("nan"))
    with pytest.raises(ValueError, match="faces"):
        fit(faces=np.asarray(faces) + 1000)
    with pytest.raises(ValueError, match="poses"):
        fit(poses=jax.tree_util.tree_map(lambda a: a[:1], poses))
    with pytest.raises(ValueError, match="skin_fn must return"):
        fit(skin_fn=lambda s, p: skin_fn(s, p)[:, :2])
    with pytest.raises(TypeError, match="skin_fn"):
        fit(skin_fn="skin")
    with pytest.raises(ValueError, match="edges"):
        fit(edges=np.zeros((3, 3), np.int32))


def test_split_vertices_are_welded_for_the_silhouette(problem):
    # The limb with three vertices of its own per face, as flat-shaded glTF meshes come: the
    # fit's edge topology welds them back, so only true outlines blend.
    skin_fn, poses, faces, *_ = problem
    faces = np.asarray(faces)
    split_faces = np.arange(faces.size).reshape(-1, 3)

    def split_fn(style, pose):
        return skin_fn(style, pose)[faces.reshape(-1)]

    welded = fit_images.welded_silhouette_edges(split_fn, INIT, poses, split_faces)
    np.testing.assert_array_equal(welded, silhouette_edges(faces))
    assert (silhouette_edges(split_faces) == -1).all()
