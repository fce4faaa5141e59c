"""Smoke test: every experiment runs with --quick and writes its table as Markdown and JSON.

Most run in one shared process, started for the first of them (whose time in ``--durations``
includes it); the run's summary lists each one's own seconds there.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.common import DATA
from experiments.report import BENCHMARKS, QUICK_DEFAULT

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


# Experiments that need a process of their own: they set the number of host devices before
# JAX's backends start (jax_num_cpu_devices, or XLA_FLAGS for a run of themselves that they
# start), or pin their threads to cores; sweep_storage starts its Ctrl-C child with a
# preexec_fn, which Python calls unsafe in a process with threads (the shared one has JAX's).
# An experiment in neither list runs in its own process too.
OWN_PROCESS = {"bench_raster", "skinning_bench", "sweep_scaling", "sweep_storage"}
# The others run one after another in one shared process (run_experiments.py), which pays
# the imports, the eager operations' compiles and the library's traces once.  Experiments
# that use the same kernels follow each other (terrain, then the rasterizer and skinning,
# then the ray caster); rle_bench clears JAX's caches after each of its scenes, so nothing
# that compiles much comes after it.
SHARED_ORDER = (
    "clipbox_table",
    "far_away",
    "screen_error",
    "heightmap_reference",
    "flythrough",
    "fox",
    "silhouette_gradients",
    "fit_style_images",
    "fit_style",
    "fit_bench",
    "artifacts",
    "rle_quality",
    "cast_rays",
    "camera_models",
    "texture_fit",
    "vmap_identity",
    "rle_bench",
    "report",
)
# `report --quick` runs these benchmarks exactly as their smoke test would (`python -m
# experiments.NAME --quick --out DIR/NAME`, in a process of their own) and keeps what they
# print (DIR/NAME/stdout.txt): that run is their smoke test, not a second one.
VIA_REPORT = {b.name for b in BENCHMARKS if b.name in QUICK_DEFAULT and not b.args}
RUNNER = Path(__file__).with_name("run_experiments.py")
TIMEOUT = 300  # seconds per experiment


def _absent_data(name: str) -> Path | None:
    path = DATA / NEEDS_DATA[name] if name in NEEDS_DATA else None
    return path if path is not None and not path.exists() else None


@pytest.fixture(scope="module")
def shared_runs(request, tmp_path_factory) -> dict[str, dict]:
    """The shared process's runs of the experiments of SHARED_ORDER this session selected.

    Each is run_experiments.py's result (exit code, stdout, stderr, traceback) with ``out``:
    the experiment's --out folder.  Where the process ends during an experiment (a crash,
    or one over the time limit), that experiment gets the process's exit code and stderr
    and a new process runs the ones after it.
    """
    selected = {
        item.callspec.params["name"]
        for item in request.session.items
        if item.originalname == "test_experiment_quick"
    }
    if selected & VIA_REPORT:
        selected.add("report")
    pending = [n for n in SHARED_ORDER if n in selected and _absent_data(n) is None]
    base = tmp_path_factory.mktemp("experiments")
    runs: dict[str, dict] = {}
    while pending:
        res = subprocess.run(
            [sys.executable, str(RUNNER), str(base), *pending, "--timeout", str(TIMEOUT)],
            capture_output=True,
            text=True,
            timeout=TIMEOUT * len(pending) + 60,
            cwd=ROOT,
        )
        for name in pending:
            result = base / f"{name}.result.json"
            if not result.exists():
                break
            runs[name] = json.loads(result.read_text())
        else:
            break
        # The process ended during `name`: it gets the process's end, the rest a new process.
        ended = f"the shared process ended (exit {res.returncode}) during {name}:\n"
        runs[name] = dict(exit=res.returncode or 1, stdout="", stderr=ended + res.stderr, error="")
        pending = pending[pending.index(name) + 1 :]
    for name, run in runs.items():
        run["out"] = base / name
    return runs


@pytest.mark.parametrize("name", SCRIPTS)
def test_experiment_quick(name, tmp_path, request, record_property):
    if (absent := _absent_data(name)) is not None:
        pytest.skip(f"{name} needs {absent}, which is absent")
    if name in VIA_REPORT:
        report = request.getfixturevalue("shared_runs")["report"]
        code, out = report["exit"], report["out"] / name
        failure = report["stderr"][-1500:] + report["error"]  # names the benchmark that failed
        printed = out / "stdout.txt"
        stdout = printed.read_text() if printed.exists() else ""
    elif name in SHARED_ORDER and name not in OWN_PROCESS:
        run = request.getfixturevalue("shared_runs")[name]
        code, stdout, out = run["exit"], run["stdout"], run["out"]
        failure = run["stderr"][-1500:] + run["error"]  # the traceback last: kept below
        # --durations charges the shared process to the test that started it: the summary
        # at the end of the run (conftest.py) lists each experiment's own seconds.
        record_property("shared_process_seconds", run.get("seconds"))
    else:
        res = subprocess.run(
            [sys.executable, "-m", f"experiments.{name}", "--quick", "--out", str(tmp_path)],
            capture_output=True,
            text=True,
            timeout=TIMEOUT,
            cwd=ROOT,
        )
        code, stdout, failure, out = res.returncode, res.stdout, res.stderr, tmp_path
    assert code == 0, failure[-3000:]
    md = list(out.glob("*.md"))
    js = list(out.glob("*.json"))
    assert md and js, f"{name} wrote no table into --out"
    for j in js:
        json.loads(j.read_text())
    assert "|" in stdout  # printed its table


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
