"""Smoke test: every experiment runs with --quick and writes its table as Markdown and JSON."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

EXP = Path(__file__).resolve().parents[1] / "experiments"
SCRIPTS = sorted(
    p for p in EXP.glob("*.py") if p.name != "common.py" and not p.name.startswith("_")
)


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_experiment_quick(script, tmp_path):
    res = subprocess.run(
        [sys.executable, str(script), "--quick", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    md = list(tmp_path.glob("*.md"))
    js = list(tmp_path.glob("*.json"))
    assert md and js, f"{script.name} wrote no table into --out"
    for j in js:
        json.loads(j.read_text())
    assert "|" in res.stdout  # printed its table
