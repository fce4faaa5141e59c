"""Where the suite's time goes: JAX's tracing, lowering and compiling per test.

With ``JAXGFX_JAX_TIME=DIR`` set, every test process (the xdist workers, the Python
processes they start, labelled with the starting test, and the shared experiments
process, whose runs are labelled ``EXP:name``) records JAX's monitoring events and writes
``DIR/<pid>.json`` when it exits; ``python tests/jax_time.py DIR`` sums them per
test module (experiments as one row) and lists the tests that compile most::

    JAXGFX_JAX_TIME=/tmp/jt pytest -q && python tests/jax_time.py /tmp/jt
"""

from __future__ import annotations

import atexit
import collections
import json
import os
import sys
import time
from pathlib import Path

EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}


def label() -> str:
    """The running test's id (``PYTEST_CURRENT_TEST``) or experiment (``JAXGFX_JAX_TIME_LABEL``)."""
    return (
        os.environ.get("JAXGFX_JAX_TIME_LABEL")
        or os.environ.get("PYTEST_CURRENT_TEST", "").split(" (")[0]
    )


_INSTALLED: list[bool] = []


def install() -> None:
    """Records the events of this process when ``JAXGFX_JAX_TIME`` names a folder.

    Also puts ``jax_time_site`` on ``PYTHONPATH``, so the Python processes this one starts
    record theirs (its ``sitecustomize`` calls this at their start).
    """
    out = os.environ.get("JAXGFX_JAX_TIME")
    if not out or _INSTALLED:
        return
    _INSTALLED.append(True)
    site = str(Path(__file__).with_name("jax_time_site"))
    paths = os.environ.get("PYTHONPATH", "").split(os.pathsep)
    if site not in paths:
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in [site, *paths] if p)
    import jax

    events: list = []

    def listener(event: str, duration: float, **kwargs) -> None:
        if event in EVENTS:
            events.append((EVENTS[event], duration, label(), str(kwargs.get("fun_name", ""))))

    jax.monitoring.register_event_duration_secs_listener(listener)

    def write() -> None:
        Path(out).mkdir(parents=True, exist_ok=True)
        tmp = Path(out) / f".{os.getpid()}.tmp"
        tmp.write_text(json.dumps(dict(argv=sys.argv, time=time.time(), events=events)))
        tmp.replace(Path(out) / f"{os.getpid()}.json")

    atexit.register(write)


def main(folder: str) -> None:
    per_module: dict = collections.defaultdict(collections.Counter)
    per_test: dict = collections.defaultdict(collections.Counter)
    per_function: dict = collections.defaultdict(collections.Counter)
    for f in Path(folder).glob("*.json"):
        for kind, seconds, name, *function in json.loads(f.read_text())["events"]:
            name = name or "(outside tests)"
            per_function[function[0] if function else "?"][kind] += seconds
            module = "experiments" if name.startswith("EXP:") else name.split("::")[0]
            per_test[name][kind] += seconds
            per_module[module][kind] += seconds
            if kind == "compile":  # how many programs, and the big ones' share
                big = "big" if seconds >= 1.0 else "small"
                per_module[module][f"n_{big}"] += 1
                per_module[module][big] += seconds
    kinds = list(EVENTS.values())
    cols = [*kinds, "sum", "n_big", "big", "n_small", "small"]
    print("| module | trace s | lower s | compile s | sum s | programs >= 1 s | their s |"
          " programs < 1 s | their s |")  # fmt: skip
    print("|---|" + "---:|" * len(cols))
    total: collections.Counter = collections.Counter()
    for c in per_module.values():
        total.update(c)
    rows = sorted(per_module.items(), key=lambda kv: -sum(kv[1][k] for k in kinds))
    for module, c in [*rows, ("all", total)]:
        c["sum"] = sum(c[k] for k in kinds)
        print(f"| {module} | " + " | ".join(f"{c[k]:.0f}" for k in cols) + " |")
    print("\nTests that trace, lower and compile most (s):")
    for name, c in sorted(per_test.items(), key=lambda kv: -sum(kv[1].values()))[:20]:
        print(f"{sum(c.values()):7.1f}  {name}")
    print("\nFunctions that trace, lower and compile most (s: trace, lower, compile):")
    for name, c in sorted(per_function.items(), key=lambda kv: -sum(kv[1].values()))[:25]:
        print(f"{sum(c.values()):7.1f}  " + " ".join(f"{c[k]:6.1f}" for k in kinds) + f"  {name}")


if __name__ == "__main__":
    main(sys.argv[1])
