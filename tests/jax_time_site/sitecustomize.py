"""Records JAX's time in the subprocesses of a test run with ``JAXGFX_JAX_TIME`` set.

Python imports ``sitecustomize`` at start-up; :func:`jax_time.install` puts this folder on
the ``PYTHONPATH`` that the test processes pass on, so the CLI runs, examples and
experiments they start are measured too (under the starting test's id).
"""

import os
import sys

if os.environ.get("JAXGFX_JAX_TIME"):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    import jax_time

    jax_time.install()
