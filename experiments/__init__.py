"""Benchmarks and experiments that reproduce the thesis's tables and compare with peers.

Run each from the repository root with the project installed, e.g.
``python -m experiments.bench_raster --quick --out out/bench_raster``.  Every script takes
``--quick`` (under a minute on a 2-core CPU) and ``--out DIR`` (its table as Markdown and
JSON, its figures as PNG).  Shared helpers (timing, machine line, tables, the skinning
experiments' limb rigs) are in :mod:`experiments.common`.
"""
