"""Voxel functions take what a user naturally passes, or say clearly what they need."""

from __future__ import annotations

import numpy as np
import pytest

from jaxgfx import raycast as V


def _ball(n: int = 8) -> np.ndarray:
    g = np.indices((n, n, n)) - (n - 1) / 2
    return (g**2).sum(0) <= (n / 2 - 0.5) ** 2


def test_an_occupancy_array_is_taken_as_its_surface_voxels():
    occ = _ball()
    from_array = V.encode_rle(occ)
    from_voxels = V.encode_rle(V.dense_to_voxels(occ))  # colours optional: the clay colour
    assert from_array.shape == occ.shape
    got = V.decode_rle(from_array)
    np.testing.assert_array_equal(got.coords, V.decode_rle(from_voxels).coords)
    # the surface only: every voxel of the ball has an empty 6-neighbour
    dense = V.voxels_to_dense(got)[0]
    assert dense.sum() == V.surface_mask(occ).sum() < occ.sum()
    assert np.all(got.colors == V.CLAY)


def test_save_scene_takes_an_rle_volume_and_an_array(tmp_path):
    occ = _ball()
    vox = V.dense_to_voxels(occ, np.array([10, 20, 30], np.uint8))
    V.save_scene(tmp_path / "rle.npz", V.encode_rle(vox, levels=2))  # saved as its level 0
    back = V.load_scene(tmp_path / "rle.npz")
    np.testing.assert_array_equal(back.coords, vox.coords)
    np.testing.assert_array_equal(back.colors, vox.colors)
    V.save_scene(tmp_path / "occ.npz", occ)
    np.testing.assert_array_equal(V.load_scene(tmp_path / "occ.npz").coords, vox.coords)


def test_other_inputs_are_refused_naming_what_makes_voxels(tmp_path):
    with pytest.raises(TypeError, match="make_voxels"):
        V.encode_rle(np.zeros((5, 3), np.int32))  # coordinates without colours or shape
    with pytest.raises(TypeError, match="Voxels"):
        V.encode_rle([[0, 0, 0]])
    with pytest.raises(ValueError, match="colors must broadcast"):
        V.dense_to_voxels(_ball(), np.zeros((2, 3), np.uint8))
    with pytest.raises(ValueError, match="3-D"):
        V.dense_to_voxels(np.ones((4, 4), bool))
    (tmp_path / "mesh.ply").write_text("ply\nformat ascii 1.0\nend_header\n")
    with pytest.raises(ValueError, match="not a scene .npz"):
        V.load_scene(tmp_path / "mesh.ply")
    with pytest.raises(ValueError, match="is a directory"):
        V.load_scene(tmp_path)
