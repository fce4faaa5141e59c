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


# ---------------------------------------------------------------- the default front


def _slab(extents, one_sided_normal=None):
    """A closed box, or (``one_sided_normal``) only its faces whose normals point that way
    plus the four rims: an open scan that shows one side."""
    import trimesh

    box = trimesh.creation.box(extents=extents)
    if one_sided_normal is None:
        return np.asarray(box.vertices), np.asarray(box.faces)
    keep = np.asarray(box.face_normals) @ np.asarray(one_sided_normal, float) > -0.5
    return np.asarray(box.vertices), np.asarray(box.faces)[keep]


def test_the_front_is_the_broad_side_and_the_scanned_side_of_an_open_scan():
    from jaxgfx.cli.framing import mesh_front, pick_front, side_areas
    from jaxgfx.io import up_rotation

    def front(v, f, up="y", **kw):
        world = np.asarray(v) @ up_rotation(up).T
        return tuple(mesh_front(world, f, front=None, up=up, **kw))

    # a closed slab, y-up: broad faces along +-z, then +-x; opposite sides tie, +z/+x first
    assert front(*_slab((4.0, 3.0, 0.2))) == (0.0, 0.0, 1.0)
    assert front(*_slab((0.2, 3.0, 4.0))) == (1.0, 0.0, 0.0)
    # the same slabs saved z-up (broad faces along the file's +-y, then +-x), --up z
    assert front(*_slab((4.0, 0.2, 3.0)), up="z") == (0.0, 0.0, 1.0)
    assert front(*_slab((0.2, 4.0, 3.0)), up="z") == (1.0, 0.0, 0.0)
    # an open scan: its scanned side faces -x (y-up), or the file's +y (z-up: -z in the world)
    assert front(*_slab((0.2, 3.0, 4.0), (-1, 0, 0))) == (-1.0, 0.0, 0.0)
    assert front(*_slab((4.0, 0.2, 3.0), (0, 1, 0)), up="z") == (0.0, 0.0, -1.0)
    # glTF states its front (+z) whatever the areas; --front overrides every rule
    assert front(*_slab((0.2, 3.0, 4.0)), path="a.glb") == (0.0, 0.0, 1.0)
    v, f = _slab((0.2, 3.0, 4.0))
    assert tuple(mesh_front(v, f, front="-z", up="y")) == (0.0, 0.0, -1.0)
    # within FRONT_TIE the fixed order decides; a clear lead wins
    assert tuple(pick_front([1.0, 0.0, 1.015, 0.0])) == (0.0, 0.0, 1.0)
    assert tuple(pick_front([1.0, 0.0, 1.05, 0.0])) == (0.0, 0.0, -1.0)
    assert tuple(pick_front([0.0, 0.0, 0.0, 0.0])) == (0.0, 0.0, 1.0)
    np.testing.assert_allclose(side_areas(*_slab((4.0, 3.0, 0.2))), [12, 0.6, 12, 0.6])
    with pytest.raises(ValueError, match="faces"):
        side_areas(v, [[0, 1, 99]])
    with pytest.raises(ValueError, match="areas"):
        pick_front([1.0, -1.0, 0.0, 0.0])


def test_voxel_side_areas_count_open_faces():
    from jaxgfx.cli.framing import pick_front, voxel_side_areas

    slab = np.array(list(np.ndindex(1, 3, 4)))  # one voxel thick along x
    np.testing.assert_allclose(voxel_side_areas(slab), [3, 12, 3, 12])
    assert tuple(pick_front(voxel_side_areas(slab))) == (1.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="coords"):
        voxel_side_areas(np.zeros((3, 2)))


def test_turn_view_keeps_the_elevation_and_turns_the_side():
    from jaxgfx.cli.framing import turn_view

    np.testing.assert_allclose(turn_view((0.8, 0.4, 0.6), (0, 0, 1)), [0.8, 0.4, 0.6])
    np.testing.assert_allclose(turn_view((0.8, 0.4, 0.6), (1, 0, 0)), [0.6, 0.4, -0.8])
    with pytest.raises(ValueError, match="front"):
        turn_view((0, 0, 1), (0, 1, 0))


# ---------------------------------------------------------------- a height map's default view


def test_heightmaps_are_seen_whole_from_the_same_side():
    from jaxgfx import terrain as T
    from jaxgfx.camera import camera_from_degrees
    from jaxgfx.cli import build_parser
    from jaxgfx.cli.terrain import _view, levels_for_map

    args = build_parser().parse_args(["terrain", "--size", "64x48"])
    z, x = np.mgrid[0:30, 0:50]
    maps = [
        T.heightmap_terrain(np.hypot(x - 10, z - 20) * -1.0),  # a cone, off centre
        T.heightmap_terrain(np.sin(z.T / 3.0) * 20.0, wrap=False),  # ridges, 50 x 30
    ]
    yaws = set()
    for t in maps:
        args.function = "heightmap:x"  # any height map: the view reads only the terrain
        viewer, (yaw, pitch), _, eye = _view(args, t)
        yaws.add((yaw, pitch))
        pos = np.asarray(viewer, float) + eye
        cam = camera_from_degrees(pos, yaw, pitch, 0.0, args.fov, 64, 48)
        m = t.mapping
        h = np.asarray(t.heights)
        x0, z0 = m.origin
        x1, z1 = x0 + m.shape[1] * m.cells[0], z0 + m.shape[0] * m.cells[1]
        corners = [
            (x0, h[0, 0], z0),
            (x1, h[0, -1], z0),
            (x0, h[-1, 0], z1),
            (x1, h[-1, -1], z1),
        ]
        sx, sy, depth = _screen(cam, np.asarray(corners, float) + [0, m.base, 0])
        assert depth.min() > 0
        assert sx.min() >= 0 and sx.max() <= 64 and sy.min() >= 0 and sy.max() <= 48
        assert pos[2] > z1 and pos[1] > h.max()  # south of the map (row 0 is north), above it
        # the boxes hold the whole map
        n = levels_for_map(t, viewer, pos, args.resolution)
        reach = args.resolution * (1 << (n - 1)) // 2
        assert reach >= max(abs(x0 - viewer[0]), abs(x1 - viewer[0]), abs(z1 - viewer[2]))
    assert yaws == {(180.0, -35.0)}
