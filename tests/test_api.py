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
    assert len(names) <= 102 and len(set(names)) == len(names)
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
# Layers of the private package, lowest first: a module imports only its own layer or lower.
ENGINE = ("checks", "precision", "hostmem", "io", "report", "camera", "placement")
ENGINE += ("zbuffer", "frames")
ENGINE += ("zsplit", "raster", "silhouette", "compose", "post")
TOP = ("scene", "showcase", "sweep")
PUBLIC = tuple(p.stem for p in PKG.glob("*.py") if p.stem != "__init__") + ("cli",)


def _jaxgfx_imports(path: Path, root: Path = PKG.parent) -> set[str]:
    """Every ``jaxgfx...`` module or name a file imports, relative imports resolved."""
    rel = path.relative_to(root).with_suffix("").parts
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = rel[: len(rel) - node.level]
                base = ".".join(pkg + ((base,) if base else ()))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {i for i in out if i == "jaxgfx" or i.startswith("jaxgfx.")}


def _layer(rel: str) -> tuple[str, str]:
    """(kind, name) of a module path relative to the package: its layer and chapter."""
    parts = rel.removesuffix(".py").split("/")
    if parts[0] != "_src":
        return "public", parts[0]
    for face, src in CHAPTERS.items():
        if parts[1] == src:
            return "chapter", face
    if parts[1] in TOP:
        return "top", parts[1]
    return "engine", parts[1]


def _import_violations(rel: str, imports: set[str]) -> list[str]:
    kind, name = _layer(rel)
    bad = []
    for imp in imports:
        parts = imp.split(".")
        if kind != "public" and (imp == "jaxgfx" or parts[1] != "_src"):
            bad.append(f"{rel} (private) imports the public {imp}")
            continue
        if len(parts) < 3 or parts[1] != "_src":
            if kind == "public" and name in CHAPTERS and len(parts) > 1 and parts[1] in CHAPTERS:
                if parts[1] != name:
                    bad.append(f"{rel} (chapter face) imports the {parts[1]} chapter: {imp}")
            continue
        target_kind, target = _layer("/".join(parts[1:3]))
        if kind in ("chapter", "public") and name in CHAPTERS and target_kind == "chapter":
            if target != name:
                bad.append(f"{rel} ({name} chapter) imports the {target} chapter: {imp}")
        if kind == "chapter" and target_kind == "top":
            bad.append(f"{rel} ({name} chapter) imports up into {imp}")
        if kind == "engine" and target_kind in ("chapter", "top"):
            bad.append(f"{rel} (engine) imports up into {imp}")
    return bad


def test_imports_point_down_and_chapters_never_import_each_other():
    bad = []
    for path in _modules():
        rel = path.relative_to(PKG).as_posix()
        bad += _import_violations(rel, _jaxgfx_imports(path))
    assert not bad, "\n".join(sorted(bad))


@pytest.mark.parametrize(
    "rel, line",
    [
        ("_src/voxel/render.py", "from jaxgfx.raster import rasterize"),
        ("_src/voxel/render.py", "import jaxgfx.camera"),
        ("_src/voxel/render.py", "from jaxgfx import camera"),
        ("_src/voxel/render.py", "from jaxgfx._src.skin.rig import SplineRig"),
        ("_src/voxel/render.py", "from ..skin import rig"),
        ("_src/skin/fit.py", "from jaxgfx._src.terrain import clipbox"),
        ("_src/raster.py", "from jaxgfx._src.voxel.render import render_rle"),
        ("_src/camera.py", "from jaxgfx._src.scene import render_frame"),
        ("_src/terrain/display.py", "from jaxgfx._src.showcase import build_demo"),
        ("terrain.py", "from jaxgfx.skin import make_rig"),
        ("terrain.py", "from jaxgfx._src.voxel.voxset import Voxels"),
    ],
)
def test_the_import_check_sees_an_injected_upward_or_sideways_import(rel, line, tmp_path):
    path = PKG / rel
    copy = tmp_path / "jaxgfx" / rel
    copy.parent.mkdir(parents=True)
    copy.write_text(path.read_text() + "\n" + line + "\n")
    imports = _jaxgfx_imports(copy, tmp_path)
    assert _import_violations(rel, imports), f"{line!r} in {rel} was not caught"
    assert not _import_violations(rel, _jaxgfx_imports(path))


@pytest.mark.parametrize("face", sorted(p.stem for p in PKG.glob("*.py") if p.stem != "__init__"))
def test_public_modules_are_thin_faces(face):
    # A public module holds a docstring, re-exports and __all__; the code is in _src.
    tree = ast.parse((PKG / f"{face}.py").read_text())
    defs = [
        n.name
        for n in tree.body
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef)
    ]
    assert not defs, f"jaxgfx.{face} defines {defs}: move them under jaxgfx/_src"
    mod = __import__(f"jaxgfx.{face}", fromlist=["__all__"])
    for name in mod.__all__:
        home = getattr(getattr(mod, name), "__module__", None) or "jaxgfx._src"
        assert home.startswith("jaxgfx._src"), f"jaxgfx.{face}.{name} is defined in {home}"
