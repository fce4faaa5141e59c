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


def test_rle_bench_hands_the_peers_the_last_cameras_frame():
    # rle_bench's Embree peers compare their depth with the frame of the camera they
    # cast last, so timed() must return that camera's output (session 17's review
    # returned the first camera's, and the agreement column fell to 0.3-19 %).
    import jax.numpy as jnp

    from experiments.rle_bench import timed

    first, per_frame, out = timed(lambda c: jnp.float32(c) * 2, [1.0, 2.0, 3.0], repeats=2)
    assert float(out) == 6.0 and first >= 0.0 and per_frame >= 0.0
