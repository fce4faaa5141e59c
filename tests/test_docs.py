"""The docs site builds without a warning and its API reference documents every public name.

One Sphinx build (``-W``: any warning fails it) is shared by the checks, also across xdist
workers; it takes about ten seconds of CPU.  The API checks read the build's
``objects.inv``, the index every cross-reference resolves through, so a name missing there
has no page to link to.
"""

from __future__ import annotations

import fcntl
import importlib
import inspect
import json
import os
import pkgutil
import posixpath
import re
import subprocess
import sys
from pathlib import Path

import pytest

import jaxgfx

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

pytest.importorskip("sphinx")
pytest.importorskip("myst_parser")
from sphinx.util.inventory import InventoryFile  # noqa: E402

# Modules of the package that are not library API: the command line has its own page.
NOT_API = {"cli"}


def public_modules() -> list[str]:
    """Every non-private submodule of ``jaxgfx`` (each must have an API page)."""
    return sorted(
        m.name
        for m in pkgutil.iter_modules(jaxgfx.__path__)
        if not m.name.startswith("_") and m.name not in NOT_API
    )


def _build(out: Path) -> None:
    """Builds the site into ``out``; its exit code and warnings go to ``out/build.json``."""
    res = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", DOCS, out],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    (out / "build.json").write_text(json.dumps({"rc": res.returncode, "stderr": res.stderr}))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    if os.environ.get("PYTEST_XDIST_WORKER"):
        # One build for the whole run: the xdist workers share this run's base folder, and
        # the first to take the lock builds while the others wait for it.
        out = tmp_path_factory.getbasetemp().parent / "docs_html"
        with open(f"{out}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (out / "build.json").exists():
                out.mkdir(exist_ok=True)
                _build(out)
    else:
        out = tmp_path_factory.mktemp("docs_html")
        _build(out)
    build = json.loads((out / "build.json").read_text())
    assert build["rc"] == 0, f"sphinx-build -W failed:\n{build['stderr'][-6000:]}"
    return out


@pytest.fixture(scope="module")
def inventory(site) -> dict[str, set[str]]:
    """Documented object names by role, e.g. ``{"py:function": {"jaxgfx.raster.rasterize"}}``."""
    with open(site / "objects.inv", "rb") as fh:
        inv = InventoryFile.load(fh, "", posixpath.join)
    data = getattr(inv, "data", inv)  # Sphinx >= 8.2 wraps the dict
    return {role: set(entries) for role, entries in data.items()}


def _documented(inventory) -> set[str]:
    return {name for role, names in inventory.items() if role.startswith("py:") for name in names}


@pytest.mark.parametrize("module", public_modules())
def test_every_public_name_has_an_api_entry(inventory, module):
    mod = importlib.import_module(f"jaxgfx.{module}")
    assert hasattr(mod, "__all__"), f"jaxgfx.{module} has no __all__"
    assert f"jaxgfx.{module}" in inventory.get("py:module", set())
    documented = _documented(inventory)
    missing = [n for n in mod.__all__ if f"jaxgfx.{module}.{n}" not in documented]
    assert not missing, f"jaxgfx.{module}: not in the API reference: {missing}"


def test_every_top_level_name_links_to_its_documentation(inventory):
    documented = _documented(inventory)
    modules = {m: importlib.import_module(f"jaxgfx.{m}") for m in public_modules()}
    missing = []
    for name in jaxgfx.__all__:
        obj = getattr(jaxgfx, name)
        if inspect.ismodule(obj):
            ok = obj.__name__ in inventory.get("py:module", set())
        else:
            # Documented once: on the page of the public module that exports it, else on the
            # top-level page itself.
            homes = [f"jaxgfx.{m}.{name}" for m, mod in modules.items() if name in mod.__all__]
            ok = any(h in documented for h in homes) or f"jaxgfx.{name}" in documented
        if not ok:
            missing.append(name)
    assert not missing, f"jaxgfx.__all__ names without API documentation: {missing}"


def test_api_pages_never_point_into_the_private_package(site):
    # The reference documents public names only: a docstring that links or names a module of
    # jaxgfx._src (or its files), or a type shown by its defining private name, sends the
    # reader to something they cannot rely on.  The build is nitpicky, so every link resolves;
    # this checks what the links and the text say.
    private = re.compile(r"jaxgfx[./]_src\b[\w./]*")
    hits = {
        page.name: sorted(set(private.findall(page.read_text())))
        for page in sorted((site / "api").glob("*.html"))
    }
    hits = {page: found for page, found in hits.items() if found}
    assert not hits, f"API pages point into jaxgfx._src: {hits}"


def test_pages_and_cli_help_are_built(site):
    for page in ("index", "getting_started", "cli", "engine", "terrain", "raycast", "skin"):
        assert (site / f"{page}.html").exists(), page
    for page in ("benchmarks", "api/index", "api/jaxgfx", "design/index"):
        assert (site / f"{page}.html").exists(), page
    from jaxgfx.cli import build_parser

    sub = next(a for a in build_parser()._actions if hasattr(a, "choices") and a.choices)
    cli = (site / "cli.html").read_text()
    missing = [c for c in sub.choices if f"usage: jaxgfx {c}" not in cli]
    assert not missing, f"cli page lacks the --help of {missing}"


def test_readme_and_docs_hold_no_work_log():
    # The README and the docs describe the library as it is: no numbered work-log runs, no
    # issue numbers (history belongs in git).  The word is spelled with a character class so
    # that this file passes the same search.
    sources = [ROOT / "README.md"] + [
        p
        for p in DOCS.rglob("*")
        if p.suffix in (".md", ".rst", ".py") and "_build" not in p.relative_to(DOCS).parts
    ]
    bad = re.compile(r"s[e]ssion|issue ?[0-9]+", re.IGNORECASE)
    hits = [
        f"{p.relative_to(ROOT)}:{i}: {line.strip()}"
        for p in sources
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if bad.search(line)
    ]
    assert not hits, "\n".join(hits)
