"""frame_points: the nearest camera along a view direction that shows every point."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from jaxgfx.camera import camera_basis, frame_points


def _screen(cam, points):
    """Pixel coordinates and depths in float64 NumPy (an independent projection)."""
    p = np.asarray(points, np.float64) - np.asarray(cam.position, np.float64)
    r, u, f = (np.asarray(b, np.float64) for b in camera_basis(cam))
    z = p @ f
    (fx, fy), (cx, cy) = np.asarray(cam.focal, np.float64), np.asarray(cam.principal, np.float64)
    return cx + fx * (p @ r) / z, cy - fy * (p @ u) / z, z


@pytest.mark.parametrize("seed", range(4))
def test_every_point_inside_with_the_margin_and_the_fit_is_tight(seed):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(300, 3)) * rng.uniform(0.1, 4.0, 3) + rng.normal(size=3) * 10
    view = rng.normal(size=3)
    fov, m = float(rng.uniform(15, 110)), 0.05
    w, h = (int(v) for v in rng.integers(30, 400, 2))
    cam = frame_points(pts, view, fov, w, h, margin=m)
    x, y, z = _screen(cam, pts)
    assert z.min() > float(cam.near) and z.max() < float(cam.far)
    free = np.array([x.min() / w, 1 - x.max() / w, y.min() / h, 1 - y.max() / h])
    assert free.min() >= m - 1e-4  # every point inside, the margin kept on every side
    # tight: on the axis that decides the distance both sides touch the margin
    assert np.sort(free)[1] <= m + 1e-4
    # looking along -view
    f = np.asarray(camera_basis(cam)[2], np.float64)
    np.testing.assert_allclose(f, -view / np.linalg.norm(view), atol=1e-5)
    # a step nearer, some point leaves the margin
    pos = np.asarray(cam.position, np.float64) + 0.02 * np.ptp(pts, 0).max() * f
    x2, y2, _ = _screen(dataclasses.replace(cam, position=pos), pts)
    free2 = np.array([x2.min() / w, 1 - x2.max() / w, y2.min() / h, 1 - y2.max() / h])
    assert free2.min() < m


def test_cubes_are_framed_whole():
    centres = np.array([[0.5, 0.5, 0.5], [3.5, 1.5, 0.5]])
    cam = frame_points(centres, (0.3, 0.5, 1.0), 50, 64, 48, margin=0.1, half_size=0.5)
    corners = np.array(
        [c + np.array(s) * 0.5 for c in centres for s in itertools.product((-1, 1), repeat=3)]
    )
    x, y, _ = _screen(cam, corners)
    assert x.min() >= 0.1 * 64 - 1e-3 and x.max() <= 0.9 * 64 + 1e-3
    assert y.min() >= 0.1 * 48 - 1e-3 and y.max() <= 0.9 * 48 + 1e-3


def test_a_single_point_and_bad_arguments():
    cam = frame_points([[1.0, 2.0, 3.0]], (0, 0, 1), 45, 8, 8)  # no extent: a finite camera
    assert np.all(np.isfinite(np.asarray(cam.position))) and float(cam.near) > 0
    with pytest.raises(ValueError, match="degrees"):
        frame_points([[0, 0, 0], [1, 1, 1]], (0, 0, 1), 0.8)  # radians by mistake
    with pytest.raises(ValueError, match="empty"):
        frame_points(np.zeros((0, 3)), (0, 0, 1))
    with pytest.raises(ValueError, match="view"):
        frame_points([[0, 0, 0]], (0, 0, 0))
    with pytest.raises(ValueError, match="margin"):
        frame_points([[0, 0, 0]], (0, 0, 1), margin=0.5)
