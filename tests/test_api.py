"""The package's shape: a curated public API, chapter faces, imports that point down only."""

from __future__ import annotations

import ast
import inspect
import types
from pathlib import Path

import pytest

import jaxgfx

PKG = Path(jaxgfx.__file__).resolve().parent
MAX_LINES = 600


def test_top_level_api_is_curated_and_documented():
    names = jaxgfx.__all__
    assert len(names) <= 100 and len(set(names)) == len(names)
    for name in names:
        assert not name.startswith("_"), name
        obj = getattr(jaxgfx, name)
        assert inspect.getdoc(obj), f"jaxgfx.{name} has no docstring"
    # The sweep module is a module (its entry point is run_sweep), not shadowed by a function.
    assert isinstance(jaxgfx.sweep, types.ModuleType) and callable(jaxgfx.run_sweep)


@pytest.mark.parametrize("chapter", ["terrain", "raycast", "skin"])
def test_chapter_faces_hold_their_public_functions(chapter):
    face = getattr(__import__("jaxgfx", fromlist=[chapter]), chapter)
    assert face.__doc__ and len(face.__all__) >= 30
    for name in face.__all__:
        assert not name.startswith("_")
        obj = getattr(face, name)
        assert inspect.getdoc(obj) or not callable(obj), f"jaxgfx.{chapter}.{name}: no docstring"
    # Every top-level name from this chapter is reachable from its face.
    src = f"jaxgfx._src.{ {'raycast': 'voxel'}.get(chapter, chapter) }"
    for name in jaxgfx.__all__:
        obj = getattr(jaxgfx, name)
        if getattr(obj, "__module__", "").startswith(src):
            assert getattr(face, name) is obj


def _modules():
    return sorted(p for p in PKG.rglob("*.py"))


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_every_module_is_short():
    long = {
        str(p.relative_to(PKG)): n
        for p in _modules()
        if (n := len(p.read_text().splitlines())) > MAX_LINES
    }
    assert not long, f"modules over {MAX_LINES} lines: {long}"


CHAPTERS = {"terrain": "terrain", "raycast": "voxel", "skin": "skin"}


def test_chapters_never_import_each_other_and_engine_never_imports_up():
    for path in _modules():
        rel = path.relative_to(PKG).as_posix()
        imports = _imports(path)
        own = next(
            (
                face
                for face, src in CHAPTERS.items()
                if rel in (f"{face}.py",) or rel.startswith(f"_src/{src}/")
            ),
            None,
        )
        for face, src in CHAPTERS.items():
            if own is not None and face != own:
                bad = {
                    i
                    for i in imports
                    if i in (f"jaxgfx.{face}",) or i.startswith(f"jaxgfx._src.{src}")
                }
                assert not bad, f"{rel} ({own} chapter) imports the {face} chapter: {bad}"
        engine = ("camera.py", "io.py", "raster.py", "compose.py", "post.py", "silhouette.py")
        engine += ("_src/zbuffer.py",)
        if rel in engine or rel.startswith("_src/check"):
            up = {
                i
                for i in imports
                if i.split(".")[1:2] and i.split(".")[1] in ("scene", "sweep", "cli", *CHAPTERS)
            }
            assert not {i for i in up if i.startswith("jaxgfx.")}, f"{rel} imports upward: {up}"
