"""A glTF bone chain replaced by a spline (thesis 5.9.3) on the real Fox: skin_gltf_chain."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgfx import skin

_F32 = 2e-5  # float32 rounding, relative to the fox's size (bbox diagonal ~4.4)
_BIND = 5e-3  # the re-export's rest TRS vs inverse bind matrices: ~0.15 % of the size

chain_jit = jax.jit(skin.skin_gltf_chain)


@pytest.fixture(scope="module")
def fox(data_dir):
    gskin = skin.load_gltf_skin(data_dir / "rigs" / "fox.glb")
    chain = skin.gltf_spline_chain(gskin, skin.TAIL_JOINTS, stiffness=3.0)
    size = float(np.linalg.norm(gskin.vertices.max(0) - gskin.vertices.min(0)))
    return gskin, chain, size


def _experiment_formula(gskin, t):
    """The tail as one spline from the skinning primitives, not the library's chain code."""
    names = list(gskin.joint_names)
    tail = [names.index(n) for n in skin.TAIL_JOINTS]
    rest_globals = skin.joint_globals(gskin, gskin.rest_trs)
    rig = skin.make_rig(rest_globals[tail, :3, 3].astype(np.float32)[None], stiffness=3.0)
    tail_w = np.where(np.isin(gskin.joints, tail), gskin.weights, 0.0).sum(1)
    on_tail = tail_w > 0
    binding = skin.bind_mesh(
        rig,
        gskin.vertices[on_tail],
        np.zeros((on_tail.sum(), 1), np.int32),
        np.ones((on_tail.sum(), 1)),
        normals=gskin.normals[on_tail],
    )
    other_w = np.where(np.isin(gskin.joints, tail), 0.0, gskin.weights)
    globs = skin.joint_globals(gskin, skin.sample_animation(gskin, t))
    mats = (globs @ gskin.inverse_bind)[:, :3, :]
    pts = jnp.asarray(globs[tail, :3, 3], jnp.float32)
    rot0 = jnp.asarray(globs[tail[0], :3, :3] @ rest_globals[tail[0], :3, :3].T, jnp.float32)
    pose = skin.SplinePose(points=pts[None], stiffness=rig.bind.stiffness, twist=jnp.zeros(1))
    ref = rot0 @ rig.reference_normal[0]
    d = pts[1] - pts[0]
    d = d / jnp.linalg.norm(d)
    n0 = ref - jnp.dot(ref, d) * d
    n0 = (n0 / jnp.linalg.norm(n0))[None]
    one = lambda s, w, x, lv, ln: skin.skin_vertex_exact(pose, n0, s, w, x, lv, ln)  # noqa: E731
    sp, _ = jax.jit(jax.vmap(one))(
        binding.spline, binding.weight, binding.x, binding.local, binding.local_normal
    )
    # the other bones in float64 NumPy: Σ_{j ∉ tail} w_j M_j v
    m = np.einsum("vi,virc->vrc", other_w, mats[gskin.joints])
    out = np.einsum("vrc,vc->vr", m[..., :3], gskin.vertices) + m[..., 3]
    out[on_tail] += tail_w[on_tail, None] * np.asarray(sp, np.float64)
    return out, on_tail


def test_chain_equals_the_experiment_formula(fox):
    gskin, chain, size = fox
    ref, on_tail = _experiment_formula(gskin, 0.7)
    pos, nrm = chain_jit(chain, skin.gltf_pose(gskin, chain, 0.7))
    assert pos.shape == nrm.shape == (1728, 3) and pos.dtype == jnp.float32
    assert int(on_tail.sum()) == chain.chain_vertex.shape[0] == 250
    np.testing.assert_allclose(np.asarray(pos), ref, atol=_F32 * size)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(nrm), axis=1), 1.0, atol=1e-5)
    # off the tail the result is the 23-joint LBS of the file
    mats = skin.joint_matrices(gskin, skin.sample_animation(gskin, 0.7)).astype(np.float64)
    m = np.einsum("vi,virc->vrc", gskin.weights, mats[gskin.joints])
    lbs = np.einsum("vrc,vc->vr", m[..., :3], gskin.vertices) + m[..., 3]
    np.testing.assert_allclose(np.asarray(pos)[~on_tail], lbs[~on_tail], atol=_F32 * size)
    # and the tail follows the 23-joint tail closely (the spline stands in for the bones)
    assert float(np.abs(np.asarray(pos) - lbs).max()) < 0.05 * size


def test_chain_bind_pose_and_styles(fox):
    gskin, chain, size = fox
    bind = skin.gltf_pose(gskin, chain)  # time None: the bind pose
    pos, _ = chain_jit(chain, bind)
    assert float(jnp.abs(pos - gskin.vertices).max()) < _BIND * size
    pose = skin.gltf_pose(gskin, chain, 0.7)
    plain = chain_jit(chain, pose)[0]
    ident = chain_jit(chain, pose, skin.identity_style((16, 16), 16))[0]
    np.testing.assert_allclose(ident, plain, atol=_F32 * size)  # Eq. 5.10: no change
    muscle, mnrm = chain_jit(chain, pose, skin.muscle_style(strength=3.0))
    assert bool(jnp.all(jnp.isfinite(muscle))) and bool(jnp.all(jnp.isfinite(mnrm)))
    moved = np.asarray(jnp.linalg.norm(muscle - plain, axis=1))
    off = np.ones(len(moved), bool)
    off[np.asarray(chain.chain_vertex)] = False
    assert moved[off].max() == 0.0 and moved[~off].max() > 1e-5 * size
    # the time wraps into the clip like sample_animation
    later = skin.gltf_pose(gskin, chain, 0.7 + gskin.duration)
    np.testing.assert_allclose(later.matrices, pose.matrices, atol=1e-5)


def test_chain_bad_arguments(fox):
    gskin, chain, _ = fox
    with pytest.raises(ValueError, match="chain: joints"):
        skin.gltf_spline_chain(gskin, ("b_Tail01", "b_Tail02", "b_Nope"))
    with pytest.raises(ValueError, match="chain must be three"):
        skin.gltf_spline_chain(gskin, ("b_Tail01", "b_Tail02"))
    with pytest.raises(ValueError, match="stiffness"):
        skin.gltf_spline_chain(gskin, stiffness=1.0)
    with pytest.raises(ValueError, match="time"):
        skin.gltf_pose(gskin, chain, float("nan"))
    with pytest.raises(ValueError, match=r"pose.matrices"):
        skin.skin_gltf_chain(
            chain, skin.GltfChainPose(jnp.zeros((23, 4, 4)), jnp.zeros((3, 3)), jnp.eye(3))
        )
