"""SHA-256 digests of the frames and arrays the benchmarks and the demo produce.

A refactor that claims "behaviour unchanged" must leave every digest equal: run this
before and after and compare the JSON files (``--compare``).  It renders, at small
sizes, every pass the benchmarks time: the demo frame (terrain Clip-Boxes, polygons,
RLE voxel forest with screen-space normals and AO, skinned character), the rasterizer on
the bunny, the per-plane ray caster on a procedural tree and the voxelized bunny (default
and 2x1 AA settings) against the reference DDA, heightmap Clip-Box meshes from the St
Helens DEM, spline/LBS/DQS skinning, a short style fit and the glTF fox's joint matrices.
Real-data items are skipped (and named) when ``../shared/data`` is absent.

    python tools/frame_digest.py --out digests.json [--compare before.json]
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def _mod(*names):
    """The first importable module of ``names`` (the layout moves modules between versions)."""
    for n in names:
        try:
            return importlib.import_module(n)
        except ImportError:
            continue
    raise ImportError(names)


def digest(x) -> str:
    leaves = jax.tree_util.tree_leaves(x)
    h = hashlib.sha256()
    for leaf in leaves:
        a = np.asarray(leaf)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:24]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--compare", default=None)
    ap.add_argument("--data", default=str(DATA), help="the shared data folder")
    args = ap.parse_args(argv)
    data = Path(args.data)

    from jaxgfx import camera as C
    from jaxgfx import raster as R
    from jaxgfx import skin as SK
    from jaxgfx import terrain as T

    RC = _mod("jaxgfx.raycast")
    V = _mod("jaxgfx.voxels", "jaxgfx.raycast")
    FIT = _mod("jaxgfx.fit", "jaxgfx.skin")
    GL = _mod("jaxgfx.gltf", "jaxgfx.skin")
    out: dict[str, str] = {}

    # 1. The demo frame, every pass and the composite (what `jaxgfx demo` draws).
    build_demo = _mod("jaxgfx.showcase", "jaxgfx.scene").build_demo
    demo = build_demo(96, 72, key=jax.random.key(0), data=data if data.is_dir() else None)
    frames = []
    for name, fn, fn_args, _ in demo.passes:
        res = jax.block_until_ready(fn(*fn_args))
        out[f"demo/{name}"] = digest(res)
        if hasattr(res, "color") and hasattr(res, "depth"):
            frames.append(res)
    out["demo/composite"] = digest(demo.composite(frames))

    # 2. Rasterizer (bench_raster): bunny from three cameras, every output field.
    if (data / "meshes" / "bun_zipper_res2.ply").exists():
        import trimesh

        m = trimesh.load(data / "meshes" / "bun_zipper_res2.ply", force="mesh")
        v = np.asarray(m.vertices, np.float32)
        f = np.asarray(m.faces, np.int32)
        nrm = np.asarray(m.vertex_normals, np.float32)
        ctr = v.mean(0)
        raster = jax.jit(R.rasterize)
        for i, eye in enumerate([(0.0, 0.05, 0.25), (0.2, 0.15, -0.1), (0.0, 0.3, 0.01)]):
            cam = C.look_at(ctr + np.array(eye), ctr, 45.0, 128, 96, 0.01, 10.0)
            out[f"raster/bunny/{i}"] = digest(raster(cam, v, f, nrm))
    else:
        out["raster/bunny"] = "skipped: no data"

    # 3. Per-plane ray caster (rle_bench): procedural tree and voxelized bunny, default
    #    settings and the thesis's 2x1 AA frame, plus the reference DDA.
    static = getattr(RC, "RENDER_RLE_STATIC", None)  # layouts without RenderSettings
    render = jax.jit(RC.render_rle, static_argnames=static) if static else jax.jit(RC.render_rle)
    tree = V.procedural_tree(48, key=jax.random.key(1))
    scenes = {"tree": tree}
    if (data / "meshes" / "bun_zipper_res2.ply").exists():
        scenes["bunny"] = V.voxelize_mesh(v, f, 96)
    for sname, vox in scenes.items():
        rle = V.as_jax(V.encode_rle(vox, levels=3))
        out[f"rle/{sname}/encode"] = digest(rle)
        X, Y, Z = vox.shape
        c = np.array([X / 2, Y / 2, Z / 2], np.float32)
        for i, (eye, size) in enumerate(
            [((X * 1.6, Y * 0.9, -Z * 0.8), (96, 72)), ((X * 0.5, Y * 3.0, Z * 0.45), (80, 60))]
        ):
            cam = C.look_at(c + np.array(eye), c, 50.0, *size, 0.5, 4 * X)
            out[f"rle/{sname}/cam{i}"] = digest(render(rle, cam))
            cam2 = C.supersampled(cam, (2, 1))
            out[f"rle/{sname}/cam{i}/aa2x1"] = digest(render(rle, cam2))
        occ, col = V.voxels_to_dense(vox)
        out[f"rle/{sname}/reference"] = digest(
            RC.reference_render(jnp.asarray(occ), jnp.asarray(col), cam)
        )

    # 4. Clip-Box terrain from the St Helens DEM and the default CSG function.
    if (data / "terrain" / "SainteHelens.dem").exists():
        hm = T.load_heightmap(data / "terrain" / "SainteHelens.dem")
        out["terrain/dem/load"] = digest(hm)
        terr = T.heightmap_terrain(hm)
        pipe = T.ClipBoxPipeline(terr, size=32, levels=3, smoothing=2)
        st = pipe.init((10, 40, 10))
        out["terrain/dem/init"] = digest(st)
        st, _ = pipe.update(st, (30, 40, 20))  # (state, stats); stats hold wall-clock ms
        out["terrain/dem/update"] = digest(st)
    csg = T.random_csg_terrain(key=jax.random.key(2), count=400, period=256)
    pipe = T.ClipBoxPipeline(csg, size=32, levels=2)
    out["terrain/csg/init"] = digest(pipe.init((0, 0, 0)))

    # 5. Skinning: the demo arm (exact spline + styles), sampled, LBS, DQS, a short fit.
    out["skin/demo_character"] = digest(SK.demo_character(0.3))
    rig = SK.make_rig(
        np.array([[[0, 0, 0], [0, 0, 1], [0, 0, 2]]], np.float32),
        reference_normal=[[1.0, 0.0, 0.0]],
    )
    a = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    z = np.linspace(0.1, 1.9, 5)
    zz, aa = np.meshgrid(z, a, indexing="ij")
    verts = np.stack([0.2 * np.cos(aa), 0.2 * np.sin(aa), zz], -1).reshape(-1, 3)
    binding = SK.bind_mesh(
        rig, verts, np.zeros((len(verts), 1), np.int32), np.ones((len(verts), 1))
    )
    rot = SK.axis_angle_to_matrix(jnp.array([0.8, 0.0, 0.0]))
    pose = SK.forward_kinematics(rig, jnp.eye(3)[None], rot[None], twist=jnp.array([0.5]))
    style = SK.muscle_style()
    out["skin/exact"] = digest(SK.skin_exact(rig, pose, binding, style, styles="both"))
    sb = SK.prepare_sampled(binding, 16)
    out["skin/sampled"] = digest(SK.skin_sampled(rig, pose, sb, style, styles="both"))
    tr = SK.bone_transforms(rig, pose)
    joints, weights = SK.bone_weights_from_binding(binding)
    nrm0 = binding.rest_normal
    out["skin/lbs"] = digest(SK.linear_blend_skinning(tr, verts, nrm0, joints, weights))
    out["skin/dqs"] = digest(SK.dual_quaternion_skinning(tr, verts, nrm0, joints, weights))
    poses = jax.tree_util.tree_map(lambda *x: jnp.stack(x), pose, pose)
    truth = SK.make_style(np.full((3, 3, 4), 1.3), np.full((3, 4), 0.8))
    targets = jax.vmap(lambda p: SK.skin_exact(rig, p, binding, truth, styles="both")[0])(poses)
    res = FIT.fit_style(
        rig, binding, poses, targets, SK.identity_style((3, 4), 4), steps=5, progress=False
    )
    out["skin/fit"] = digest((res.style, res.loss_history))

    # 6. glTF fox rig.
    if (data / "rigs" / "fox.glb").exists():
        fox = GL.load_gltf_skin(data / "rigs" / "fox.glb")
        out["gltf/fox/joints"] = digest(GL.joint_matrices(fox, GL.sample_animation(fox, 0.7)))

    Path(args.out).write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    print(f"{len(out)} digests -> {args.out}")
    if args.compare:
        before = json.loads(Path(args.compare).read_text())
        bad = [k for k in sorted(set(before) | set(out)) if before.get(k) != out.get(k)]
        for k in bad:
            print(f"DIFFERS: {k}: {before.get(k)} -> {out.get(k)}")
        print("all digests equal" if not bad else f"{len(bad)} digests differ")
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
