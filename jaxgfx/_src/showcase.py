"""The demo scene: every thesis system in one frame, everything standing on the ground (ch. 2).

Clip-Box terrain from a real elevation model (the St Helens DEM when the project's shared data
is present, a procedural fractal heightmap otherwise; ch. 3), an instanced forest of procedural
voxel trees and Voxlap ``.kv6`` sprites drawn by the per-plane RLE ray caster (ch. 4), and the
glTF fox walking on the slope, skinned by its bones with its tail replaced by one spline that
carries a deformation style (ch. 5, 5.9.3; without the data: the spline-skinned demo arm).  All
passes share one camera and meet in the depth buffer, with sky and fog (2.3-2.4).

World units are level-0 terrain voxels, y up.  Every object is placed from the terrain
function itself: :func:`column_top` scans the voxel columns under the object's footprint and
the object's lowest voxel layer is set on the lowest of them (a mesh is lifted until no vertex
is below the ground), so nothing floats.
:class:`Placement` records what was placed where; the tests check it against the terrain.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxgfx._src.camera import Camera, look_at
from jaxgfx._src.checks import static_field
from jaxgfx._src.compose import background, composite, fog
from jaxgfx._src.placement import GroundPatch, Placement, column_top, ground_patch
from jaxgfx._src.scene import MeshPass, VoxelPass, render_mesh_pass, render_voxel_pass
from jaxgfx._src.skin.chain import gltf_pose, gltf_spline_chain, skin_gltf_chain
from jaxgfx._src.skin.gltf import GltfSkin, load_gltf_skin
from jaxgfx._src.skin.limb import demo_arm, demo_arm_pose
from jaxgfx._src.skin.rig import SplinePose, SplineRig
from jaxgfx._src.skin.sampled import SampledBinding, prepare_sampled, skin_sampled
from jaxgfx._src.skin.styles import Style, make_style, muscle_style
from jaxgfx._src.terrain.display import level_arrays
from jaxgfx._src.terrain.heightmap import HeightmapData, heightmap_terrain, read_heightmap
from jaxgfx._src.terrain.pipeline import ClipBoxPipeline
from jaxgfx._src.terrain.shading import SKY_HORIZON, SKY_ZENITH, terrain_colors
from jaxgfx._src.voxel.encode import as_jax, encode_rle, share_columns
from jaxgfx._src.voxel.formats import load_kv6
from jaxgfx._src.voxel.tree import procedural_tree
from jaxgfx._src.voxel.voxset import Voxels, downsample_voxels, make_voxels

__all__ = [
    "data_source",
    "find_data",
    "Placement",
    "column_top",
    "GroundPatch",
    "ground_patch",
    "fractal_heights",
    "demo_heightmap",
    "stand_voxels",
    "forest_and_props",
    "CharacterPass",
    "demo_character_pass",
    "character_pose",
    "FoxCharacter",
    "fox_character",
    "bushy_tail_style",
    "Demo",
    "build_demo",
]

FOX_CREDIT = (
    "Fox: model by PixelMannen (CC0), rigging and animation by @tomkranis (CC-BY 4.0), glTF "
    "conversion by @AsoboStudio and @scurest"
)
DEM_CREDIT = "St Helens DEM: USGS, via VTK sample data"
KV6_CREDIT = "kv6 sprites: Ken Silverman's Voxlap sample data"


def data_source(data: str | os.PathLike | None = None) -> tuple[Path | None, str]:
    """The demo's real-data folder (None: the procedural scene) and a line naming its source.

    The rule is :func:`find_data`'s; ``jaxgfx demo`` prints the line and writes it to its
    ``timing.md``.

    Raises:
        ValueError: ``data`` (or ``$JAXGFX_DATA``) is set but is not a directory.
    """
    for name, value in (("data", data), ("$JAXGFX_DATA", os.environ.get("JAXGFX_DATA") or None)):
        if value is not None:
            p = Path(value).expanduser()
            if not p.is_dir():
                raise ValueError(f"{name}: {str(p)!r} is not a directory")
            return p, f"data: {p} (from {'--data' if name == 'data' else name})"
    # Beside the checkout, for commands run from its root (the README's layout).
    if (shared := Path("..", "shared", "data").resolve()).is_dir():
        return shared, f"data: {shared} (../shared/data from the current directory)"
    return None, "data: none (no --data, $JAXGFX_DATA or ../shared/data): the procedural scene"


def find_data(data: str | os.PathLike | None = None) -> Path | None:
    """The demo's real-data folder, or None for the procedural scene.

    In order: ``data`` if given (``jaxgfx demo --data DIR``); else ``$JAXGFX_DATA`` if
    set; else ``../shared/data`` relative to the current directory if it exists; else
    None.  A folder without one of the demo's files leaves that part procedural: without
    ``terrain/SainteHelens.dem`` the terrain, without ``voxlap/barrel.kv6`` and
    ``caco.kv6`` no sprites, without ``rigs/fox.glb`` the demo arm for the fox.

    Raises:
        ValueError: ``data`` (or ``$JAXGFX_DATA``) is set but is not a directory.
    """
    return data_source(data)[0]


# --------------------------------------------------------------------------------------
# Terrain
# --------------------------------------------------------------------------------------


def fractal_heights(key: jax.Array, n: int = 256, *, relief: float = 900.0) -> np.ndarray:
    """A procedural elevation model: fractal (1/f^2 spectrum) noise and a volcano-like cone.

    Stands in for a real DEM when no data is present; values are "metres" on a 30 m grid.
    """
    k1, k2 = jax.random.split(key)
    f = np.fft.fftfreq(n)
    kk = np.hypot(*np.meshgrid(f, f))
    kk[0, 0] = 1.0
    spec = (
        np.asarray(jax.random.normal(k1, (n, n))) + 1j * np.asarray(jax.random.normal(k2, (n, n)))
    ) / kk**2
    spec[0, 0] = 0.0
    noise = np.real(np.fft.ifft2(spec))
    noise = (noise - noise.min()) / np.ptp(noise)
    yy, xx = np.mgrid[0:n, 0:n] / n - 0.5
    r = np.hypot(xx, yy)
    cone = np.clip(1.0 - r / 0.35, 0.0, None) ** 1.5 - 0.35 * np.exp(-((r / 0.06) ** 2))
    return relief * (0.45 * noise + 0.75 * cone)


def demo_heightmap(data: Path | None, *, key: jax.Array):
    """(the DEM as :class:`~jaxgfx.terrain.HeightmapData`, or (H, W) metres on a 30 m grid;
    a description of the source)."""
    if data is not None and (data / "terrain" / "SainteHelens.dem").is_file():
        dem = read_heightmap(data / "terrain" / "SainteHelens.dem")
        rows, cols = dem.heights.shape
        return dem, f"St Helens USGS DEM ({rows} x {cols} samples, 30 m)"
    return fractal_heights(key), "procedural fractal heightmap (256 x 256, 30 m)"


# --------------------------------------------------------------------------------------
# Static objects: trees and kv6 sprites on the ground (ch. 4)
# --------------------------------------------------------------------------------------


def _bottom_layer(vox: Voxels) -> np.ndarray:
    c = np.asarray(vox.coords)
    return c[c[:, 1] == c[:, 1].min()]


def stand_voxels(vox: Voxels, ground: GroundPatch, at_xz, unit: float, origin) -> np.ndarray:
    """Integer offset (in object voxels) that puts ``vox`` on the ground at world ``at_xz``.

    The object's footprint centre goes to ``at_xz``; its lowest voxel layer is set on the
    lowest terrain column under that layer, so no part of the bottom floats (on a slope the
    uphill side of the layer is buried, as a trunk or a barrel dug in would be).

    Args:
        vox: the object.
        ground: the terrain's column tops around the object.
        at_xz: (2,) world x, z.
        unit: world units per object voxel.
        origin: (3,) world position of the combined scene's voxel (0, 0, 0).

    Returns:
        (3,) int offset of the object's voxels in the combined scene.
    """
    bottom = _bottom_layer(vox)
    X, _, Z = vox.shape
    ox = int(round((at_xz[0] - origin[0]) / unit - X / 2))
    oz = int(round((at_xz[1] - origin[2]) / unit - Z / 2))
    wx = origin[0] + (bottom[:, 0] + ox + 0.5) * unit
    wz = origin[2] + (bottom[:, 2] + oz + 0.5) * unit
    g = ground.at(wx, wz).min()
    oy = int(np.floor((g - origin[1]) / unit)) - int(bottom[0, 1])
    return np.array([ox, oy, oz])


def _shrink(vox: Voxels, times: int) -> Voxels:
    for _ in range(times):
        vox = downsample_voxels(vox)
    return vox


def forest_and_props(
    ground: GroundPatch,
    centre_xz,
    *,
    key: jax.Array,
    data: Path | None,
    trees: int = 16,
    unit: float = 1 / 10,
):
    """Trees (procedural, 4.3.3) and kv6 sprites on the ground around ``centre_xz``.

    The camera is taken to look along +z from 28 units before ``centre_xz``: trees fill a
    fan in front of it, clear of the kv6 sprites and the character's lane.

    Returns:
        ``(VoxelPass, [Placement], description)``; one RLE scene with two mip levels.
    """
    kinds = [procedural_tree(64, key=k, depth=4) for k in jax.random.split(key, 3)]
    rng = np.random.default_rng(int(jax.random.randint(key, (), 0, 2**30)))
    cx, cz = centre_xz
    props = (("barrel", 2, 3.0, 4.0), ("caco", 1, -6.0, 8.0))  # kv6 name, mips down, dx, dz
    spots: list = []
    taken = [(dx, dz) for _, _, dx, dz in props] + [(float(k), -14.0) for k in range(-6, 7, 3)]
    while len(spots) < trees:
        # A fan in front of the camera (it looks along +z from 28 units before the centre).
        dz = rng.uniform(-10.0, 22.0)
        dx = rng.uniform(-0.62, 0.62) * (28.0 + dz)
        if min(np.hypot(dx - a, dz - b) for a, b in taken) < 4.5:
            continue
        taken.append((dx, dz))
        spots.append(("tree", kinds[len(spots) % 3], (cx + dx, cz + dz)))
    names = []
    if data is not None and (data / "voxlap").is_dir():
        for name, shrink, dx, dz in props:
            path = data / "voxlap" / f"{name}.kv6"
            if path.is_file():
                spots.append((name, _shrink(load_kv6(str(path)), shrink), (cx + dx, cz + dz)))
                names.append(name)
    lo = np.array([cx - 32.0, float(ground.tops.min()) - 8.0, cz - 32.0])
    origin = np.floor(lo)
    coords, colors, places = [], [], []
    for name, vox, xz in spots:
        off = stand_voxels(vox, ground, xz, unit, origin)
        c = np.asarray(vox.coords) + off
        coords.append(c)
        colors.append(np.asarray(vox.colors))
        b = _bottom_layer(vox) + off
        bottom = origin + (b + [0.5, 0.0, 0.5]) * unit
        places.append(Placement(name, "voxel", bottom, unit))
    allc = np.concatenate(coords)
    shift = allc.min(0)
    shift[0] -= shift[0] % 2
    shift[2] -= shift[2] % 2
    allc = allc - shift
    origin = origin + shift * unit
    shape = tuple(int(s) + 2 for s in allc.max(0) + 1)
    shape = (shape[0] + shape[0] % 2, shape[1], shape[2] + shape[2] % 2)
    vox = make_voxels(allc, np.concatenate(colors), shape)
    plain = encode_rle(vox, levels=2)
    # Copies of a kind differ only in their columns' inline first elements (their heights):
    # the rest of every column and its colours are stored once (pointer-map instancing).
    shared = share_columns(plain)
    rle = as_jax(shared)
    vp = VoxelPass(rle, jnp.asarray(origin, jnp.float32), jnp.float32(unit))
    kb = [(2 * r.elements.size + r.colors.size) / 1024 for r in (plain, shared)]
    desc = (
        f"{sum(p.name == 'tree' for p in places)} voxel trees (3 procedural kinds) instanced "
        f"through the pointer map (column runs and colours: {kb[1]:.0f} KiB stored, "
        f"{kb[0]:.0f} KiB without sharing)"
    )
    if names:
        desc += f" and kv6 sprites ({', '.join(names)})"
    return vp, places, desc


# --------------------------------------------------------------------------------------
# The frame
# --------------------------------------------------------------------------------------


class Demo(NamedTuple):
    """The demo frame as timed passes sharing one camera (thesis 2.3, Fig. 2.2).

    Attributes:
        camera: the shared camera (world units = level-0 terrain voxels).
        passes: ``[(name, fn, args, first-call seconds or None)]``; results that are
            :class:`~jaxgfx.compose.Frame` are composited.
        composite: jitted list of frames -> fogged frame.
        description: one paragraph naming what is in the frame and its sources.
        placements: every object standing on the terrain (:class:`Placement`).
        terrain_fn: the terrain function the objects were placed on.
        y_range: heights :func:`column_top` scans for that terrain.
        animate: ``(camera, phase in [0, 1)) -> character Frame`` (the GIF's walk; the
            character pass itself, built from jitted steps).
        credits: data credits to print with the images.
    """

    camera: Camera
    passes: list
    composite: Callable
    description: str
    placements: list
    terrain_fn: object
    y_range: tuple
    animate: Callable
    credits: tuple


def _terrain_pass(levels, lo: float, hi: float) -> MeshPass:
    v, n, f, _ = level_arrays(levels, (0, 0, 0))
    if f.shape[0] == 0:
        f = np.zeros((1, 3), np.int32)  # one degenerate triangle draws nothing
    return MeshPass(
        jnp.asarray(v, jnp.float32),
        jnp.asarray(f, jnp.int32),
        terrain_colors(v, n, height_range=(lo, hi)),
        jnp.asarray(n, jnp.float32),
    )


def build_demo(
    width: int,
    height: int,
    *,
    key: jax.Array,
    data: str | os.PathLike | None = None,
    size: int = 64,
    levels: int = 6,
    cell: int = 4,
) -> Demo:
    """Builds the demo scene and its jitted passes.

    Args:
        width, height: frame size in pixels.
        key: randomness for the procedural parts (trees, the fallback heightmap).
        data: the shared data folder (default: :func:`find_data`); without it every
            input is procedural.
        size: Clip-Box edge N (voxels).
        levels: nested Clip-Boxes.
        cell: level-0 voxels per heightmap sample (heights are interpolated between).
    """
    import time

    root = find_data(data)
    k_map, k_trees, k_ssn = jax.random.split(key, 3)
    hm, map_desc = demo_heightmap(root, key=k_map)
    # True proportions: the DEM says its spacing; the procedural map is on a 30 m grid.
    vs = None if isinstance(hm, HeightmapData) else cell / 30.0
    tfn = heightmap_terrain(hm, cell=cell, vertical_scale=vs)
    m = tfn.mapping
    h = np.asarray(hm.heights if isinstance(hm, HeightmapData) else hm)
    relief = float(np.max(np.asarray(tfn.heights)))  # voxels above base
    y_range = (int(np.floor(m.base)) - 2, int(np.ceil(m.base + relief)) + 4)

    # The camera stands north of the summit, looking at it over the slope.
    r0, c0 = np.unravel_index(np.argmax(h), h.shape)
    summit = m.sample_position(r0, c0, h[r0, c0])
    eye = summit + np.array([0.0, 0.0, -1.0]) * 0.24 * m.shape[0] * m.cell  # row 0 is north
    fwd = (summit - eye) / np.linalg.norm(summit - eye)
    target = eye + 30.0 * fwd
    stage = eye + 28.0 * fwd  # where the objects stand, in front of the camera
    scan = jax.jit(column_top, static_argnums=2)
    tops = np.asarray(
        scan(
            tfn,
            jnp.asarray(np.floor([p[[0, 2]] for p in (summit, eye, target)]), jnp.int32),
            y_range,
        )
    )
    summit[1], eye[1], target[1] = tops[0], tops[1] + 5.0, tops[2] + 3.0
    far = 8.0 * size * (1 << levels)
    cam = look_at(eye, target, 55.0, width, height, 0.2, far)
    ground = ground_patch(tfn, stage[[0, 2]], 40, y_range)

    pipe = ClipBoxPipeline(tfn, size=size, levels=levels, smoothing=4)
    viewer = tuple(int(round(c)) for c in eye)

    def generate_terrain(viewer):
        # Host-driven Clip-Box build (sampling, faces, smoothing, normals, welding).
        state = pipe.init(viewer)
        jax.block_until_ready(state)
        return _terrain_pass(pipe.views(state), m.base, m.base + relief)

    t0 = time.perf_counter()
    terrain_pass = generate_terrain(viewer)
    first_build = time.perf_counter() - t0  # includes tracing and compiling every step

    objects, places, obj_desc = forest_and_props(ground, stage[[0, 2]], key=k_trees, data=root)
    character, ch_place, ch_desc = _character(root, ground, stage, fwd)
    places = places + [ch_place]
    render = jax.jit(render_mesh_pass)
    passes = [
        (
            "background pass (sky)",
            jax.jit(lambda c: background(c, SKY_HORIZON, SKY_ZENITH)),
            (cam,),
            None,
        ),
        (
            f"terrain generation ({levels} Clip-Boxes of {size}^3)",
            generate_terrain,
            (viewer,),
            first_build,
        ),
        ("terrain pass (rasterizer)", render, (cam, terrain_pass), None),
        (
            "static objects pass (RLE voxels, per-plane ray caster, SSN lighting)",
            jax.jit(lambda c, vp, k: render_voxel_pass(c, vp, key=k)),
            (cam, objects, k_ssn),
            None,
        ),
        (
            "character pass (skinning + spline tail with style + rasterizer)",
            character,
            (cam, 0.0),
            None,
        ),
    ]
    desc = (
        f"terrain: {map_desc}, {levels} Clip-Boxes of {size}^3, "
        f"{int(terrain_pass.faces.shape[0])} triangles; static objects: {obj_desc}; "
        f"character: {ch_desc}"
    )
    # Fog fades into the sky behind each pixel (the background pass, frame 0).
    comp = jax.jit(lambda fs: fog(composite(fs), fs[0].color, density=4.0 / (size * (1 << levels))))
    credits = tuple(
        c
        for c, used in (
            (DEM_CREDIT, isinstance(hm, HeightmapData)),
            (KV6_CREDIT, "kv6" in obj_desc),
            (FOX_CREDIT, ch_desc.startswith("the glTF fox")),
        )
        if used
    )
    return Demo(cam, passes, comp, desc, places, tfn, y_range, character, credits)


# --------------------------------------------------------------------------------------
# The character: the glTF fox walking (ch. 5), or the demo arm without data
# --------------------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CharacterPass:
    """A spline-skinned character with a deformation style, placed in the world (thesis ch. 5).

    Attributes:
        rig: the spline rig.
        binding: sampled-path binding (:func:`jaxgfx.skin.prepare_sampled`).
        style: the deformation style applied on each vertex's dominant spline.
        faces: (F, 3) int32 triangles of the bind mesh.
        color: (3,) albedo.
        scale: () uniform world scale.
        offset: (3,) world position of the rig origin.
        samples: static, spline samples of pass 1.
        styles: static, which envelopes: 'none', 'radial', 'rect' or 'both'.
    """

    rig: SplineRig
    binding: SampledBinding
    style: Style
    faces: jax.Array
    color: jax.Array
    scale: jax.Array
    offset: jax.Array
    samples: int = static_field(32)
    styles: str = static_field("both")


def demo_character_pass(offset=(5.0, 0.0, 4.0), scale: float = 1.4) -> CharacterPass:
    """The demo character: :func:`jaxgfx.skin.demo_arm` with the muscle style."""
    arm = demo_arm()
    return CharacterPass(
        rig=arm.rig,
        binding=prepare_sampled(arm.binding, 32),
        style=muscle_style(),
        faces=jnp.asarray(arm.faces),
        color=jnp.array([0.85, 0.62, 0.5], jnp.float32),
        scale=jnp.float32(scale),
        offset=jnp.asarray(offset, jnp.float32),
    )


def character_pose(ch: CharacterPass, phase: jax.Array) -> SplinePose:
    """Animation of the demo arm: bend up to ~115 degrees and twist with ``phase`` in [0, 1)."""
    ang = 2.0 * jnp.pi * phase
    return demo_arm_pose(ch.rig, 1.0 - jnp.cos(ang), 0.6 * jnp.sin(ang))


FOX_WALK = (7.62, 8.72)
"""Seconds of the fox clip that hold one walk cycle (the clip is survey, walk, run)."""


def bushy_tail_style(strength: float = 0.45, size: tuple[int, int] = (8, 16)) -> Style:
    """A deformation style for a tail (thesis 5.6): the radial texture swells mid-tail."""
    rows, cols = size
    x = np.linspace(0.0, 1.0, cols)[None, :]
    swell = np.broadcast_to(1.0 + strength * np.sin(np.pi * x) ** 1.5, (rows, cols))
    ones = np.ones((rows, cols))
    return make_style(np.stack([ones, ones, swell]), np.ones((3, cols)))


def _yaw_matrix(direction) -> np.ndarray:
    """Rotation about +y taking +z to ``direction`` (x, z)."""
    a = np.arctan2(direction[0], direction[1])
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], np.float32)


def _lift_onto_ground(points: np.ndarray, ground: GroundPatch) -> float:
    """Vertical shift that sets the lowest point (relative to the ground under it) on the ground."""
    g = ground.at(points[:, 0], points[:, 2])
    return float(np.max(g - points[:, 1]))


def _bottom_vertices(points: np.ndarray, unit: float) -> np.ndarray:
    return points[points[:, 1] <= points[:, 1].min() + 0.5 * unit]


class FoxCharacter(NamedTuple):
    """The fox as the demo draws it: skin, colours and its placement in the world."""

    skin: GltfSkin
    colors: np.ndarray  # (V, 3) albedo
    rotation: np.ndarray  # (3, 3) model -> world
    scale: float
    at_xz: np.ndarray  # (2,) world x, z of the model origin


def fox_character(path, at_xz, heading, scale: float = 0.9) -> FoxCharacter:
    """Loads the fox and gives it colours: orange fur, dark legs, a white tail tip."""
    g = load_gltf_skin(path)
    v = g.vertices
    col = np.tile(np.array([[0.82, 0.42, 0.16]], np.float32), (len(v), 1))
    col[v[:, 1] < 0.45] = (0.25, 0.16, 0.12)
    col[v[:, 2] < v[:, 2].min() + 0.35] = (0.93, 0.92, 0.88)
    return FoxCharacter(g, col, _yaw_matrix(heading), float(scale), np.asarray(at_xz, np.float64))


def _character(root: Path | None, ground: GroundPatch, stage: np.ndarray, fwd: np.ndarray):
    """``(frame(cam, phase) -> Frame, Placement, description)``: the character pass, which
    also animates the GIF's walk."""
    side = np.array([fwd[2], -fwd[0]])  # walks across the view
    at = stage[[0, 2]] - 14.0 * fwd[[0, 2]]
    path = None if root is None else root / "rigs" / "fox.glb"
    if path is not None and path.is_file():
        fox = fox_character(path, at, side)
        g = fox.skin
        chain = gltf_spline_chain(g)  # the three tail joints -> one spline (5.9.3)
        style = bushy_tail_style()
        sk = jax.jit(skin_gltf_chain)
        faces, colors = g.faces, fox.colors
        rot, scale = fox.rotation, fox.scale
        t0, t1 = FOX_WALK
        speed = 1.1  # world units per second of the clip, about the stride of the walk

        def model(phase):
            t = t0 + (t1 - t0) * phase
            p, n = sk(chain, gltf_pose(g, chain, t), style)
            return np.asarray(p), np.asarray(n), speed * (t1 - t0) * phase

        desc = (
            f"the glTF fox ({len(g.vertices)} vertices, {len(g.joint_names)} joints) walking: "
            "linear blend skinning, with its three tail joints replaced by one spline that "
            "carries a bushy-tail style (5.9.3)"
        )
    else:
        arm = demo_character_pass(offset=(0.0, 0.0, 0.0), scale=1.0)
        sk = jax.jit(
            lambda ch, ph: skin_sampled(
                ch.rig, character_pose(ch, ph), ch.binding, ch.style, samples=ch.samples
            )
        )
        faces = np.asarray(arm.faces)
        colors = np.broadcast_to(np.asarray(arm.color), (int(arm.binding.rest.shape[0]), 3))
        rot, scale = _yaw_matrix(side), 1.6

        def model(phase):
            p, n = sk(arm, jnp.float32(phase))
            return np.asarray(p), np.asarray(n), 0.0

        desc = (
            f"the demo arm ({int(arm.binding.rest.shape[0])} vertices) bending, spline "
            "skinning with the muscle style (no fox.glb found)"
        )

    render = jax.jit(render_mesh_pass)
    fc, cc = jnp.asarray(faces, jnp.int32), jnp.asarray(colors, jnp.float32)

    def world(phase):
        p, n, walked = model(phase)
        p = (p @ rot.T) * scale
        p[:, 0] += at[0] + walked * side[0]
        p[:, 2] += at[1] + walked * side[1]
        p[:, 1] += _lift_onto_ground(p, ground)
        return p.astype(np.float32), (n @ rot.T).astype(np.float32)

    def frame(cam, phase):
        p, n = world(float(phase))
        return render(cam, MeshPass(jnp.asarray(p), fc, cc, jnp.asarray(n)))

    p0, _ = world(0.0)
    place = Placement("character", "mesh", _bottom_vertices(p0, 0.05), 1.0)
    return frame, place, desc
