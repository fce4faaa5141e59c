"""Runs experiments' ``--quick`` smoke runs one after another in this one process.

``python tests/run_experiments.py RESULTS NAME...`` calls each
``experiments.NAME.main(["--quick", "--out", "RESULTS/NAME"])`` in the order given and writes
``RESULTS/NAME.result.json`` as soon as it returns: its exit code (0 for a ``main`` that
returns ``None``, the code of a ``SystemExit``, 1 for any other exception), its printed
output (stdout and stderr apart), the traceback of its exception and its wall time.  One
process for all of them shares what each run would otherwise pay again: the imports, the
compiles of JAX's eager operations and the traces and compiles of the library's jitted
functions (``test_experiments.py`` starts it).

An experiment that changes JAX's configuration, the environment or the working directory
has them put back before the next one starts, so that each runs as it would alone; the
names of what it changed are in its result (``"changed"``).  JAX's backends start before
the first experiment: one that must set the device count first fails here (those run in
their own process).  A run that takes longer than ``--timeout`` seconds ends the process
with every thread's traceback on stderr; the caller starts another for the experiments
after it.
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import importlib
import io
import json
import os
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _exit_code(code: object) -> int:
    """``SystemExit.code`` (or ``main``'s return value) as a process's exit status.

    Args:
        code: ``None`` (success), an exit status, or a message (which exits with 1).

    Returns:
        The exit status the interpreter would give.
    """
    if code is None:
        return 0
    return code if isinstance(code, int) else 1


def run_one(name: str, out: Path) -> dict:
    """Runs ``experiments.NAME.main`` with ``--quick --out OUT`` in this process.

    Args:
        name: the experiment's module under ``experiments``.
        out: its ``--out`` folder.

    Returns:
        Its result: ``name``, ``exit``, ``stdout``, ``stderr``, ``error`` (the traceback of an
        exception other than ``SystemExit``, or ""), ``seconds`` and ``changed`` (the JAX
        options, ``$VARIABLES`` and ``cwd`` it changed, now put back).
    """
    import jax

    config, environ, cwd = dict(jax.config.values), dict(os.environ), os.getcwd()
    stdout, stderr = io.StringIO(), io.StringIO()
    error = ""
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        try:
            module = importlib.import_module(f"experiments.{name}")
            code = _exit_code(module.main(["--quick", "--out", str(out)]))
        except SystemExit as exc:
            code = _exit_code(exc.code)
            if not isinstance(exc.code, int | None):
                print(exc.code, file=sys.stderr)  # as the interpreter prints it on exit
        except BaseException:
            code, error = 1, traceback.format_exc()
    seconds = time.perf_counter() - t0
    changed = [k for k, v in config.items() if jax.config.values.get(k) != v]
    for key in changed:
        jax.config.update(key, config[key])
    changed += [f"${k}" for k in {*os.environ, *environ} if os.environ.get(k) != environ.get(k)]
    os.environ.clear()
    os.environ.update(environ)
    if os.getcwd() != cwd:
        changed.append("cwd")
        os.chdir(cwd)
    return dict(
        name=name,
        exit=code,
        stdout=stdout.getvalue(),
        stderr=stderr.getvalue(),
        error=error,
        seconds=round(seconds, 1),
        changed=changed,
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", help="folder for each experiment's --out and result")
    ap.add_argument("names", nargs="+", help="experiments, run in this order")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per experiment")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))  # the experiments package, as `python -m` from the root has it
    import jax

    jax.devices()  # start the backends: an experiment cannot change the device count
    results = Path(args.results)
    for name in args.names:
        os.environ["JAXGFX_JAX_TIME_LABEL"] = f"EXP:{name}"  # jax_time.py, when recording
        (results / name).mkdir(parents=True, exist_ok=True)
        faulthandler.dump_traceback_later(args.timeout, exit=True, file=sys.__stderr__)
        result = run_one(name, results / name)
        faulthandler.cancel_dump_traceback_later()
        (results / f"{name}.result.json").write_text(json.dumps(result))
        print(f"{name}: exit {result['exit']} after {result['seconds']} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
