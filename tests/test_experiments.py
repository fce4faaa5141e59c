"""Smoke test: every experiment runs with --quick and writes its table as Markdown and JSON."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.common import DATA

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(
    p.stem
    for p in (ROOT / "experiments").glob("*.py")
    if p.stem not in ("common", "__init__") and not p.stem.startswith("_")
)
# Experiments that exist only for real data (the others fall back to procedural input).
NEEDS_DATA = {"fox": "rigs/fox.glb"}
# The runs inherit the suite's code generation flags (conftest.py): the smoke test checks that
# each script runs end to end and writes its tables, not its timings or a result to the last
# bit (which `python -m experiments.NAME` gives with XLA's defaults).


@pytest.mark.parametrize("name", SCRIPTS)
def test_experiment_quick(name, tmp_path):
    if name in NEEDS_DATA and not (DATA / NEEDS_DATA[name]).exists():
        pytest.skip(f"{name} needs {DATA / NEEDS_DATA[name]}, which is absent")
    res = subprocess.run(
        [sys.executable, "-m", f"experiments.{name}", "--quick", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    md = list(tmp_path.glob("*.md"))
    js = list(tmp_path.glob("*.json"))
    assert md and js, f"{name} wrote no table into --out"
    for j in js:
        json.loads(j.read_text())
    assert "|" in res.stdout  # printed its table


def test_rle_bench_timed_reports_the_fastest_frame_and_the_last_cameras_output():
    # rle_bench's Embree peers compare their depth with the frame of the camera they
    # cast last, so timed() must return that camera's output; its steady time is the
    # fastest frame per camera, averaged over the cameras (the box drifts between rounds).
    import time

    import jax.numpy as jnp

    from experiments.rle_bench import timed

    calls: list[float] = []

    def frame(c):  # camera c takes c / 100 s; its first frame 0.2 s more (a slow round)
        time.sleep(c / 100 + (0.2 if c not in calls else 0.0))
        calls.append(c)
        return jnp.float32(c) * 2

    first, per_frame, out = timed(frame, [1.0, 2.0, 3.0], repeats=3)
    assert float(out) == 6.0
    # one first call, `repeats` frames per camera, then the output of the last camera
    assert calls == [1.0] + [c for c in (1.0, 2.0, 3.0) for _ in range(3)] + [3.0]
    assert first >= 0.21  # the first call, slow round included
    # mean of the fastest frames: 0.02 s; a mean of every frame would add 0.04 s
    assert 0.02 <= per_frame < 0.035
