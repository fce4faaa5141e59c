"""Sharded sweeps over 4 host devices and resuming after a hard kill (subprocesses)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import imageio.v3 as iio
import numpy as np
import trimesh

SHARDED = textwrap.dedent(
    """
    import json, sys
    import jax, numpy as np, trimesh
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
    )))
    """
)


def _env(devices=4, **extra):
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["JAX_PLATFORMS"] = "cpu"
    env.update(extra)
    return env


def test_sharded_sweep_equals_unsharded(tmp_path):
    res = subprocess.run(
        [sys.executable, "-c", SHARDED, str(tmp_path)],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    r = json.loads(res.stdout.strip().splitlines()[-1])
    assert r["n"] == 6
    assert r["s4"]["chunks"] == 2 and r["s1"]["chunks"] == 2
    # Same images: identical 8-bit pictures and depth; float colour to rounding
    # (each device compiles its own batch size, so XLA may reassociate).
    assert r["png_equal"] and r["coverage_equal"]
    assert r["depth_rel_diff"] <= 1e-6
    assert r["color_max_diff"] <= 1e-5
    assert r["direct_diff"] <= 1e-5


def test_sweep_killed_halfway_resumes(tmp_path):
    mesh_file = tmp_path / "box.ply"
    trimesh.creation.box((1.0, 0.6, 0.8)).export(mesh_file)
    out = tmp_path / "sw"
    cmd = [
        sys.executable, "-m", "jaxgfx.cli", "sweep", str(mesh_file),
        "--n", "8", "--chunk", "2", "--size", "20x16", "--out", str(out),
    ]  # fmt: skip
    killed = subprocess.run(
        cmd, env=_env(1, JAXGFX_SWEEP_KILL_AFTER="2"), capture_output=True, text=True, timeout=600
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
    frames = sorted(out.glob("frame_*.png"))
    assert len(frames) == 8
    # every frame is intact and holds exactly the rendered data of its chunk
    from jaxgfx.sweep import load_sweep

    data = load_sweep(out / "chunks")
    assert data["color"].shape == (8, 16, 20, 3)
    for k, f in enumerate(frames):
        np.testing.assert_array_equal(iio.imread(f), data["color"][k])
    # frames differ from each other (the cameras orbit): no stale copies
    assert len({data["color"][k].tobytes() for k in range(8)}) == 8
    sheet = iio.imread(out / "contact_sheet.png")
    assert sheet.shape == (32, 120, 3)
