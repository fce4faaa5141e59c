"""Sharded sweeps over 4 host devices, resuming after a hard kill (subprocesses), resume
refused for a changed function, and no recompilation between chunks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxgfx.sweep import (
    SweepMismatch,
    load_sweep,
    render_fingerprint,
    run_sweep,
    sharded_renderer,
)

SHARDED = textwrap.dedent(
    """
    import functools, json, sys
    import jax, jax.numpy as jnp, numpy as np, trimesh
    from jaxgfx.camera import orbit_cameras
    from jaxgfx.compose import background, composite, to_uint8
    from jaxgfx.scene import mesh_pass, render_mesh_pass
    from jaxgfx.sweep import load_sweep, run_sweep, sharded_renderer

    out = sys.argv[1]
    assert jax.device_count() == 4, jax.devices()
    m = trimesh.creation.torus(1.0, 0.4, major_sections=16, minor_sections=8)
    mp = mesh_pass(m.vertices.astype(np.float32), m.faces.astype(np.int32))
    cams = orbit_cameras([0, 0, 0], 4.0, 6, width=24, height=16)

    def one(cam):
        fr = composite([background(cam), render_mesh_pass(cam, mp)])
        return {"color": fr.color, "depth": fr.depth}

    s4 = run_sweep(one, cams, out + "/four", chunk_size=4, progress=False)
    s1 = run_sweep(one, cams, out + "/one", chunk_size=4, devices=jax.devices()[:1], progress=False)
    a, b = load_sweep(out + "/four"), load_sweep(out + "/one")
    direct = sharded_renderer(one)(jax.tree_util.tree_map(lambda x: x[:4], cams))
    # sharded_vmap: 6 characters' LBS on 4 devices (padded to 8), shared mesh replicated
    from jaxgfx import skin
    from jaxgfx.sweep import sharded_vmap
    rng = np.random.default_rng(0)
    t = rng.normal(size=(6, 5, 3, 4)).astype(np.float32)
    j = rng.integers(0, 5, (40, 4)).astype(np.int32)
    w = rng.random((40, 4)).astype(np.float32)
    w /= w.sum(1, keepdims=True)
    pv = rng.normal(size=(40, 3)).astype(np.float32)
    lbs = sharded_vmap(skin.linear_blend_skinning, in_axes=(0, None, None, None, None))
    sp, sn = lbs(t, *lbs.replicate((pv, pv, j, w)))
    lbs1 = sharded_vmap(skin.linear_blend_skinning, (0, None, None, None, None), chunk=1)
    cp, cn = lbs1(t, *lbs1.replicate((pv, pv, j, w)))  # each device loops over its items
    loop = [skin.linear_blend_skinning(t[k], pv, pv, j, w) for k in range(6)]
    lbs_diff = max(
        float(np.abs(np.asarray(o) - np.asarray(r)).max())
        for k in range(6) for o, r in zip((sp[k], sn[k], cp[k], cn[k]), loop[k] * 2)
    )
    # Computation follows data: a batch of 8 posed meshes that the user shards over the 4
    # devices renders each device's frames there; inputs on device 1 stay on device 1; an
    # unplaced batch stays on the default device; an export for CUDA needs one device.
    from jax.sharding import NamedSharding, PartitionSpec as P
    from jaxgfx.raster import rasterize
    v, f, cam0 = mp.vertices, mp.faces, jax.tree_util.tree_map(lambda x: x[0], cams)
    posed = np.asarray(v) * np.linspace(0.8, 1.2, 8, dtype=np.float32)[:, None, None]
    def ids_depth(vv):
        out = rasterize(cam0, vv, f, vv)
        return out.tri_id, jnp.where(out.tri_id >= 0, out.depth, 0.0)
    # The bit-identity claims (ids of a sharded batch, of a loop, of a face split) are about
    # the user's programs: those compile with XLA's default code generation.
    user_jit = functools.partial(jax.jit, compiler_options=json.loads(sys.argv[2]))
    batched = user_jit(jax.vmap(ids_depth))
    mesh4 = jax.make_mesh((4,), ("batch",))
    sharded = batched(jax.device_put(posed, NamedSharding(mesh4, P("batch"))))
    plain = batched(posed)
    # (where the frames run does not depend on the code generation: the suite's flags)
    on1 = jax.jit(jax.vmap(ids_depth))(jax.device_put(posed, jax.devices()[1]))
    single = user_jit(ids_depth)
    loop = [single(posed[j]) for j in range(8)]
    loop_ids, loop_depth = (np.stack([np.asarray(x[k]) for x in loop]) for k in (0, 1))
    s_ids, s_depth = (np.asarray(x) for x in sharded)
    p_ids, p_depth = (np.asarray(x) for x in plain)
    finite = np.where(p_depth > 0, p_depth, 1.0)
    exported = jax.export.export(batched, platforms=["cuda"])(
        jax.ShapeDtypeStruct(posed.shape, jnp.float32))
    # Skinning follows the data too: one mesh split by vertices, a pose batch by poses.
    from jaxgfx.sweep import shard_batch
    t8 = rng.normal(size=(8, 5, 3, 4)).astype(np.float32)
    mesh_parts = shard_batch((pv, pv, j, w))
    one_mesh = skin.linear_blend_skinning(t[0], *mesh_parts)
    poses = jax.jit(jax.vmap(skin.dual_quaternion_skinning, (0, None, None, None, None)))
    rigid = np.concatenate([np.tile(np.eye(3, dtype=np.float32), (8, 5, 1, 1)), t8[..., 3:]], -1)
    by_pose = poses(shard_batch(rigid), pv, pv, j, w)
    lbs_one = skin.linear_blend_skinning(t[0], pv, pv, j, w)
    pose_one = poses(rigid, pv, pv, j, w)
    skin_split = dict(
        mesh_devices=len(one_mesh[0].sharding.device_set),
        mesh_diff=float(np.abs(np.asarray(one_mesh[0]) - np.asarray(lbs_one[0])).max()),
        pose_devices=len(by_pose[0].sharding.device_set),
        pose_diff=float(np.abs(np.asarray(by_pose[0]) - np.asarray(pose_one[0])).max()),
    )
    placement = dict(
        sharded_devices=len(sharded[0].sharding.device_set),
        sharded_ids_differ=int(np.sum(s_ids != p_ids)),
        sharded_depth_rel=float(np.max(np.abs(s_depth - p_depth) / finite)),
        plain_devices=sorted(d.id for d in plain[0].devices()),
        on1_devices=sorted(d.id for d in on1[0].devices()),
        loop_ids_differ=int(np.sum(p_ids != loop_ids)),
        loop_depth_diff=float(np.abs(p_depth - loop_depth).max()),
        export_devices=exported.nr_devices,
        **skin_split,
    )
    # rasterize(devices=3): one 24x24 frame's faces dealt over 3 devices (padded faces:
    # 256 % 3 != 0) and its rows shaded 8 per device is bit-identical to one device.
    v, f = m.vertices.astype(np.float32), m.faces.astype(np.int32)
    ras = user_jit(rasterize, static_argnames=("devices",))
    cam3 = jax.tree_util.tree_map(
        lambda x: x[0], orbit_cameras([0, 0, 0], 4.0, 1, width=24, height=24))
    split_equal = all(
        np.array_equal(np.asarray(x), np.asarray(y))
        for x, y in zip(ras(cam3, v, f, v, devices=3), ras(cam3, v, f, v))
    )
    fa, fb = np.isfinite(a["depth"]), np.isfinite(b["depth"])
    da = np.where(fa, a["depth"], 1.0)
    db = np.where(fa, b["depth"], 1.0)
    print(json.dumps(dict(
        s4=s4, s1=s1,
        color_max_diff=float(np.abs(a["color"] - b["color"]).max()),
        png_equal=bool(np.array_equal(to_uint8(a["color"]), to_uint8(b["color"]))),
        coverage_equal=bool(np.array_equal(fa, fb)),
        depth_rel_diff=float(np.max(np.abs(da - db) / da)),
        direct_diff=float(np.abs(direct["color"] - a["color"][:4]).max()),
        n=int(a["color"].shape[0]),
        lbs_shape=list(sp.shape), lbs_diff=lbs_diff,
        lbs_devices=len(lbs.mesh.devices.flat),
        split_equal=split_equal, **placement,
    )))
    """
)


def _env(devices=4, *, codegen="test", **extra):
    """The subprocess's environment: ``devices`` host devices, and the suite's code generation
    flags (conftest.py: XLA:CPU's lowest optimization level) unless ``codegen="default"``:
    XLA's defaults, for files compared bit for bit with another process's."""
    env = dict(os.environ)
    flags = env.get("XLA_FLAGS", "") if codegen == "test" else ""
    env["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={devices}".strip()
    env["JAX_PLATFORMS"] = "cpu"
    env.update(extra)
    return env


def test_sharded_sweep_equals_unsharded(tmp_path, user_codegen):
    res = subprocess.run(
        [sys.executable, "-c", SHARDED, str(tmp_path), json.dumps(user_codegen)],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    r = json.loads(res.stdout.strip().splitlines()[-1])
    assert r["n"] == 6
    assert r["s4"]["chunks"] == 2 and r["s1"]["chunks"] == 2
    # Same images: identical 8-bit pictures and coverage; depth and float colour to
    # rounding (each device compiles its own batch size, so XLA may reassociate).
    assert r["png_equal"] and r["coverage_equal"]
    assert r["split_equal"]
    assert r["depth_rel_diff"] <= 4e-6  # a few float32 ulps
    assert r["color_max_diff"] <= 1e-5
    assert r["direct_diff"] <= 1e-5
    # sharded_vmap over 4 devices (batch 6, padded) equals a loop over the characters
    assert r["lbs_shape"] == [6, 40, 3] and r["lbs_devices"] == 4
    assert r["lbs_diff"] <= 1e-5
    # A sharded batch runs on the 4 devices and equals the one-device batch; the batch on one
    # device equals a loop over single frames (the same per-frame program).
    assert r["sharded_devices"] == 4
    assert r["sharded_ids_differ"] == 0 and r["sharded_depth_rel"] <= 1e-6
    assert r["plain_devices"] == [0] and r["on1_devices"] == [1]
    assert r["loop_ids_differ"] == 0 and r["loop_depth_diff"] <= 1e-5
    assert r["export_devices"] == 1
    assert r["mesh_devices"] == 4 and r["mesh_diff"] <= 1e-5
    assert r["pose_devices"] == 4 and r["pose_diff"] <= 1e-5


KILLED_CLI = textwrap.dedent(
    """
    import os, sys
    import jaxgfx._src.sweep as sweep
    from jaxgfx.cli import main

    kill_at, run, calls = int(sys.argv[1]), sweep._run, []

    def dying_run(*args):  # die like a killed process once `kill_at` chunks are done
        calls.append(1)
        if len(calls) > kill_at:
            os.kill(os.getpid(), 9)
        return run(*args)

    sweep._run = dying_run
    sys.exit(main(sys.argv[2:]))
    """
)


def test_sweep_killed_halfway_resumes(tmp_path):
    mesh_file = tmp_path / "box.ply"
    trimesh.creation.box((1.0, 0.6, 0.8)).export(mesh_file)
    out = tmp_path / "sw"
    cmd = [
        sys.executable, "-m", "jaxgfx.cli", "sweep", str(mesh_file),
        "--n", "8", "--chunk", "2", "--size", "20x16", "--out", str(out),
    ]  # fmt: skip
    # the same command, killed (SIGKILL, no clean-up) as the third chunk starts
    killed = subprocess.run(
        [sys.executable, "-c", KILLED_CLI, "2", *cmd[3:]],
        env=_env(1),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert killed.returncode == -9, killed.stderr[-2000:]
    chunks = sorted(p.name for p in (out / "chunks").glob("chunk_*.npz"))
    assert chunks == ["chunk_00000.npz", "chunk_00001.npz"]  # 2 of 4 chunks (of 2 frames) done
    # no half-written files left behind, even after SIGKILL
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]
    done = subprocess.run(cmd, env=_env(1), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["skipped"] == 2 and summary["computed"] == 2
    assert summary["devices"] == 1  # the user's XLA_FLAGS device count is kept
    frames = sorted(out.glob("frame_*.png"))
    assert len(frames) == 8
    # every frame is intact and holds exactly the rendered data of its chunk
    data = load_sweep(out / "chunks")
    assert data["color"].shape == (8, 16, 20, 3)
    for k, f in enumerate(frames):
        np.testing.assert_array_equal(iio.imread(f), data["color"][k])
    # frames differ from each other (the cameras orbit): no stale copies
    assert len({data["color"][k].tobytes() for k in range(8)}) == 8
    sheet = iio.imread(out / "contact_sheet.png")
    assert sheet.shape == (32, 120, 3)
    # Another view into the same folder is refused before anything is rendered or written.
    files = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    other = subprocess.run(
        [*cmd, "--fov", "50"], env=_env(1), capture_output=True, text=True, timeout=600
    )
    assert other.returncode == 2
    assert f"jaxgfx sweep: error: --out {out} holds a different sweep" in other.stderr
    assert "per-item parameters" in other.stderr and "delete" in other.stderr
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == files


def test_cli_sweep_gives_jax_the_host_devices(tmp_path):
    """Without a device count in XLA_FLAGS the CLI sets one before JAX starts (here 2)."""
    mesh_file = tmp_path / "box.ply"
    trimesh.creation.box((1.0, 0.6, 0.8)).export(mesh_file)
    env = _env(1)
    env["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "")  # the suite's code generation flags only
    cmd = [
        sys.executable, "-m", "jaxgfx.cli", "sweep", str(mesh_file),
        "--n", "3", "--chunk", "1", "--size", "12x8", "--devices", "2",
        "--out", str(tmp_path / "s"),
    ]  # fmt: skip
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    summary = json.loads(res.stdout.strip().splitlines()[-1])
    # --chunk 1 is rounded up to the 2 devices: 3 frames in 2 chunks (the last one padded)
    assert summary["devices"] == 2 and summary["chunks"] == 2 and summary["frames"] == 3
    assert len(list((tmp_path / "s").glob("frame_*.png"))) == 3


def _tint_sweep(tint):
    """A tiny render function closing over a constant (``tint``), and its parameters."""
    tint = jnp.asarray(tint, jnp.float32)

    def one(p):
        return {"color": p[:, None] * tint, "sum": jnp.sum(p)}

    return one, np.arange(15, dtype=np.float32).reshape(5, 3)


def test_resume_refuses_a_changed_function(tmp_path):
    one, params = _tint_sweep([1.0, 2.0])
    s = run_sweep(one, params, tmp_path, chunk_size=2, devices=jax.devices()[:1], progress=False)
    assert s["computed"] == 3
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    # The same function again (a fresh closure over equal constants) resumes.
    again, _ = _tint_sweep([1.0, 2.0])
    s = run_sweep(again, params, tmp_path, chunk_size=2, devices=jax.devices()[:1], progress=False)
    assert s["computed"] == 0 and s["skipped"] == 3
    # A different closed-over constant, the same shapes: refused, naming the function.
    other, _ = _tint_sweep([1.0, 3.0])
    with pytest.raises(SweepMismatch, match=r"render function \(.*function: on disk.*delete"):
        run_sweep(other, params, tmp_path, chunk_size=2, devices=jax.devices()[:1], progress=False)
    # Other output shapes: both the function and the outputs are named.
    wider, _ = _tint_sweep([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"render function.*output names, shapes"):
        run_sweep(wider, params, tmp_path, chunk_size=2, devices=jax.devices()[:1], progress=False)
    # Another version string only.
    with pytest.raises(ValueError, match=r"the version string \(version: on disk None, now 'v2'"):
        run_sweep(
            again, params, tmp_path, 2, devices=jax.devices()[:1], progress=False, version="v2"
        )
    # The refused runs left every file as it was.
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    np.testing.assert_array_equal(load_sweep(tmp_path)["color"], params[:, :, None] * [1.0, 2.0])


def test_render_fingerprint_same_in_another_process():
    code = textwrap.dedent(
        """
        import json, sys
        sys.path.insert(0, sys.argv[1])
        from test_sweep import _tint_sweep
        from jaxgfx.sweep import render_fingerprint
        one, params = _tint_sweep([1.0, 2.0])
        print(json.dumps(render_fingerprint(one, params[:2])))
        """
    )
    here = os.path.dirname(os.path.abspath(__file__))
    res = subprocess.run(
        [sys.executable, "-c", code, here], env=_env(1), capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, res.stderr[-3000:]
    one, params = _tint_sweep([1.0, 2.0])
    mine = render_fingerprint(one, params[:2])
    assert json.loads(res.stdout.strip().splitlines()[-1]) == mine
    assert mine["outputs"] == {"['color']": "float32[2, 3, 2]", "['sum']": "float32[2]"}


def test_sweep_and_sharded_renderer_compile_once(tmp_path, compile_counter):
    one, params = _tint_sweep([0.5, 4.0])
    counts = []
    with compile_counter() as c:
        run_sweep(
            one,
            params,
            tmp_path,
            chunk_size=2,
            devices=jax.devices()[:1],
            progress=False,
            on_chunk=lambda k, start, out: counts.append(c.count),
        )
    # Chunks 1 and 2 (the last one padded to the chunk size) compile nothing new.
    assert len(counts) == 3 and counts[0] >= 1 and counts[1] == counts[0] == counts[2], counts
    render = sharded_renderer(one, devices=jax.devices()[:1])
    first = render(params[:2])
    with compile_counter() as c:
        second = render(params[2:4])
    assert c.count == 0
    np.testing.assert_array_equal(second["color"], params[2:4, :, None] * [0.5, 4.0])
    assert not np.array_equal(first["color"], second["color"])


def test_sharded_vmap_checks_in_axes():
    from jaxgfx.sweep import sharded_vmap

    one = lambda a, b: a + b  # noqa: E731
    for bad in (0, (None, None), (1, None), [0, "x"]):
        with pytest.raises(ValueError, match="in_axes"):
            sharded_vmap(one, in_axes=bad)
    f = sharded_vmap(one, in_axes=(0, None), devices=jax.devices()[:1])
    np.testing.assert_array_equal(f(np.arange(3.0), 1.0), [1.0, 2.0, 3.0])
    with pytest.raises(TypeError, match="in_axes"):
        f(np.arange(3.0))

    # A loop whose carry starts from shared data and takes in per-item data (as the ray
    # caster's plane loop does) traces under the shard_map.
    def loop(x, s):
        body = lambda c: (c[0] + x, c[1] + 1)  # noqa: E731
        return jax.lax.while_loop(lambda c: c[1] < 3, body, (s, 0))[0]

    g = sharded_vmap(loop, in_axes=(0, None), devices=jax.devices()[:1])
    np.testing.assert_array_equal(g(np.arange(3.0), 1.0), 1.0 + 3 * np.arange(3.0))


# One process of a 2-process sweep on localhost (argv: process id or -1 for a one-process
# sweep, coordinator port, out dir).  Each process has one CPU device; the processes meet
# through jax.distributed (gloo collectives over TCP, JAX's CPU default).  Each process gets
# its own out dir, as on hosts without a shared disk: only process 0's holds files.
MULTIPROCESS = textwrap.dedent(
    """
    import json, sys
    import jax
    pid, port, out, kill_after = int(sys.argv[1]), sys.argv[2], sys.argv[3], int(sys.argv[4])
    if pid >= 0:
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        jax.distributed.initialize(
            f"localhost:{port}", num_processes=2, process_id=pid,
            initialization_timeout=120, heartbeat_timeout_seconds=5,
        )
    import jax.numpy as jnp
    from jaxgfx.camera import orbit_cameras, pixel_rays
    import jaxgfx._src.sweep as sweep
    from jaxgfx.sweep import run_sweep

    if kill_after > 0:  # die like a killed host after computing `kill_after` chunks: no clean-up
        import os
        run, calls = sweep._run, []

        def dying_run(*args):
            out = run(*args)
            calls.append(1)
            if len(calls) >= kill_after:
                os.kill(os.getpid(), 9)
            return out

        sweep._run = dying_run

    assert jax.device_count() == 2, jax.devices()
    cams = orbit_cameras([0, 0, 0], 4.0, 5, width=24, height=16)

    def one(cam):  # a unit sphere ray cast: cheap to compile, camera-dependent frames
        o, d = pixel_rays(cam, normalize=True)
        b = jnp.sum(o * d, -1)
        disc = b * b - jnp.sum(o * o, -1) + 1.0
        t = jnp.where(disc > 0, -b - jnp.sqrt(jnp.maximum(disc, 0.0)), jnp.inf)
        return {"t": t, "shade": (255 * jnp.exp(-t)).astype(jnp.uint8)}

    s = run_sweep(one, cams, out, chunk_size=2, progress=False)
    print(json.dumps(dict(s, process=jax.process_index(), processes=jax.process_count())))
    """
)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _two_processes(out, kill_after=None):
    """Starts processes 0 and 1 of the sweep, process 1 writing into ``out`` + ``_1`` (another
    host's disk); returns their (returncode, stdout, stderr)."""
    # The processes' chunks are compared bit for bit with a one-process sweep's: XLA's default
    # code generation, the user's, in both.
    port = str(_free_port())
    procs = []
    for pid in (0, 1):
        kill = str(kill_after) if kill_after and pid == 1 else "0"
        procs.append(
            subprocess.Popen(
                [sys.executable, "-c", MULTIPROCESS, str(pid), port, f"{out}{'_1' * pid}", kill],
                env=_env(1, codegen="default"),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
        )
    results = []
    for p in procs:
        try:
            so, se = p.communicate(timeout=120)  # the old sweep hung here
        except subprocess.TimeoutExpired:
            for q in procs:
                q.kill()
            raise
        results.append((p.returncode, so, se))
    return results


def _chunks(out):
    files = sorted(out.glob("chunk_*.npz"))
    return {f.name: {k: v for k, v in np.load(f).items()} for f in files}


def test_two_processes_equal_one_and_resume_after_a_kill(tmp_path):
    """Acceptance: 2 processes joined by jax.distributed render the same files as a
    one-process sweep over 2 host devices; after one process is killed mid-sweep (SIGKILL) the
    other is stopped by the coordination service, and rerunning both completes the sweep."""
    ref = subprocess.run(
        [sys.executable, "-c", MULTIPROCESS, "-1", "0", str(tmp_path / "one"), "0"],
        env=_env(2, codegen="default"),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ref.returncode == 0, ref.stderr[-3000:]
    assert json.loads(ref.stdout.strip().splitlines()[-1])["computed"] == 3
    out = tmp_path / "two"
    (r0, _, e0), (r1, _, e1) = _two_processes(out, kill_after=1)
    assert r1 == -9, e1[-3000:]  # process 1 died after its first chunk, with no clean-up
    assert r0 != 0, e0[-3000:]  # process 0 did not hang: the coordination service stopped it
    left = sorted(p.name for p in out.glob("chunk_*.npz"))
    assert 1 <= len(left) < 3, left
    assert not [p for p in out.iterdir() if ".tmp" in p.name]
    runs = _two_processes(out)
    for rc, _, se in runs:
        assert rc == 0, se[-3000:]
    summaries = [json.loads(so.strip().splitlines()[-1]) for _, so, _ in runs]
    for pid, s in enumerate(summaries):
        assert (s["process"], s["processes"], s["devices"]) == (pid, 2, 2)
        # every process skipped exactly the chunks on process 0's disk
        assert (s["skipped"], s["computed"]) == (len(left), 3 - len(left))
    assert (out / "manifest.json").read_bytes() == (tmp_path / "one" / "manifest.json").read_bytes()
    mine, theirs = _chunks(out), _chunks(tmp_path / "one")
    assert list(mine) == list(theirs) == [f"chunk_{k:05d}.npz" for k in range(3)]
    for name, arrays in theirs.items():
        assert list(mine[name]) == list(arrays) == ["shade", "t"]
        for key, a in arrays.items():
            np.testing.assert_array_equal(mine[name][key], a, err_msg=f"{name} {key}")
    assert not list(tmp_path.glob("two_1/*"))  # process 1 wrote nothing on its own disk
