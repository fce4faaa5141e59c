"""The demo scene: every object stands on the terrain, every pass shows in the frame."""

from __future__ import annotations

import json

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgfx.cli import main
from jaxgfx.showcase import build_demo, data_source, find_data

GROUND_TOL = 1.0
"""World units (level-0 terrain voxels): no bottom voxel or vertex of an object may float
higher than this above the terrain surface under it, and its highest-standing one (the contact)
must be within this of the surface (not sunk)."""

MIN_SHARE = {"terrain pass": 0.25, "static objects pass": 0.01, "character pass": 0.004}
"""Share of the demo frame each pass must show after compositing."""


def _surface(tfn, x, z, y_range):
    """Independent column scan: y of the first air voxel above the highest solid one."""
    lo, hi = y_range
    ys = np.arange(lo, hi)
    xz = np.stack([np.floor(x), np.floor(z)], -1).astype(np.int32)
    pts = np.stack(
        [
            np.repeat(xz[:, 0], len(ys)),
            np.tile(ys, len(xz)),
            np.repeat(xz[:, 1], len(ys)),
        ],
        -1,
    ).astype(np.int32)
    solid = np.asarray(jax.vmap(tfn)(jnp.asarray(pts))).reshape(len(xz), len(ys))
    assert not solid[:, -1].any(), "the scan range must reach the air above the ground"
    top = np.where(solid, ys[None] + 1, lo).max(1)
    return top


def _check_placements(demo):
    assert demo.placements, "the demo places objects"
    for p in demo.placements:
        g = _surface(demo.terrain_fn, p.bottom[:, 0], p.bottom[:, 2], demo.y_range)
        gap = p.bottom[:, 1] - g
        # Nothing floats, and the object touches the ground: its lowest contact is on it.
        assert gap.max() <= GROUND_TOL and gap.min() <= GROUND_TOL, (p.name, gap.max())
        assert gap.max() >= -GROUND_TOL, (p.name, "sunk into the ground", gap.max())


def test_demo_objects_stand_on_the_dem(data_dir):
    demo = build_demo(32, 24, key=jax.random.key(0), data=data_dir)
    assert "St Helens" in demo.description and "fox" in demo.description
    assert len(demo.credits) == len(set(demo.credits)) == 3
    assert {c.split(":")[0] for c in demo.credits} == {"St Helens DEM", "kv6 sprites", "Fox"}
    assert {"tree", "barrel", "caco", "character"} <= {p.name for p in demo.placements}
    _check_placements(demo)


def test_find_data_rejects_a_file(tmp_path):
    f = tmp_path / "x"
    f.write_text("")
    with pytest.raises(ValueError, match="data"):
        find_data(f)


def test_find_data_takes_the_flag_then_the_variable_then_shared_data_beside_the_cwd(
    tmp_path, monkeypatch
):
    # tmp/checkout is the working directory; tmp/shared/data is the folder beside it.
    checkout, shared = tmp_path / "checkout", tmp_path / "shared" / "data"
    flag, env = tmp_path / "flag", tmp_path / "env"
    for d in (checkout, shared, flag, env):
        d.mkdir(parents=True)
    monkeypatch.chdir(checkout)
    monkeypatch.setenv("JAXGFX_DATA", str(env))
    assert data_source(flag) == (flag, f"data: {flag} (from --data)")
    assert data_source() == (env, f"data: {env} (from $JAXGFX_DATA)")
    monkeypatch.setenv("JAXGFX_DATA", "")  # set but empty: as if unset
    found, source = data_source()
    assert found == shared.resolve() and "../shared/data from the current directory" in source
    assert find_data() == shared.resolve()
    monkeypatch.setenv("JAXGFX_DATA", str(tmp_path / "missing"))
    with pytest.raises(ValueError, match=r"\$JAXGFX_DATA"):
        find_data()  # a variable that names nothing is an error, not a silent fallback
    monkeypatch.delenv("JAXGFX_DATA")
    monkeypatch.chdir(shared)  # ../shared/data from here does not exist
    found, source = data_source()
    assert found is None and find_data() is None and "procedural" in source


def test_demo_cli_writes_images_gif_and_pass_shares(tmp_path, capsys, monkeypatch):
    # The demo command's procedural scene (64x48, seed 0, an empty data folder); the scene
    # it built is checked too: its objects stand on the procedural ground.
    import jaxgfx.showcase

    built = []
    monkeypatch.setattr(
        jaxgfx.showcase,
        "build_demo",
        lambda *a, **k: built.append(build_demo(*a, **k)) or built[-1],
    )
    out, empty = tmp_path / "demo", tmp_path / "no-data"
    empty.mkdir()
    argv = ["demo", "--size", "64x48", "--out", str(out), "--frames", "2", "--data", str(empty)]
    assert main(argv) == 0
    (demo,) = built
    assert "procedural" in demo.description
    assert demo.credits == ()  # nothing of the shared data was drawn: nothing to credit
    assert {"tree", "character"} <= {p.name for p in demo.placements}
    _check_placements(demo)
    color = iio.imread(out / "color.png")
    depth = iio.imread(out / "depth.png")
    assert color.shape == (48, 64, 3) and depth.shape == (48, 64)
    assert color.std() > 5  # a picture, not a flat fill
    assert depth.max() > depth.min()
    gif = iio.imread(out / "demo.gif")
    assert gif.shape[0] == 2 and gif.shape[1:3] == (48, 64)
    timing = json.loads((out / "timing.json").read_text())
    assert {r["stage"] for r in timing["stages"]} >= {"frame total"}
    for prefix, least in MIN_SHARE.items():
        share = [v for k, v in timing["coverage"].items() if k.startswith(prefix)]
        assert len(share) == 1 and share[0] >= least, (prefix, timing["coverage"])
    assert "| stage |" in (out / "timing.md").read_text()
    printed = capsys.readouterr().out
    for credit in timing["credits"]:
        assert printed.count(credit) == 1  # each credit once
    # Which data folder the scene came from, in the output and the timing table.
    source = f"data: {empty} (from --data)"
    assert timing["data"] == source and source in printed
    assert source in (out / "timing.md").read_text()
