"""Sphinx helpers for the API pages: every name of a module's ``__all__``, each documented once.

Two directives, both driven by ``__all__`` so that the pages follow the code:

``.. module-constants:: jaxgfx.raycast``
    ``automodule`` documents the functions and classes a face module re-exports from
    ``jaxgfx._src``, but not its re-exported constants (autodoc only knows data assigned in
    the module itself).  This emits an ``autodata`` entry for each such constant, with the
    docstring written where the constant is defined.

``.. public-names:: jaxgfx``
    One ``autosummary`` table per public module for the names of ``jaxgfx.__all__``, each
    linking to the module page that documents it (the top-level names are re-exports, so they
    are not documented a second time), plus the modules themselves.  Names no public module
    exports are documented on the page that uses this directive.

Also :func:`skip_fields`: a class's data fields are left to its docstring's ``Attributes:``
section and its signature; and :class:`PublicTargets`: a cross-reference to a class by its
defining (private) name is pointed at its public name.
"""

from __future__ import annotations

import importlib
import inspect
import sys
from typing import Any

from docutils import nodes
from sphinx import addnodes
from sphinx.application import Sphinx
from sphinx.pycode import ModuleAnalyzer
from sphinx.transforms.post_transforms import SphinxPostTransform
from sphinx.util.docutils import SphinxDirective

# The modules with an API page, in the order of the reference.
PUBLIC_MODULES = (
    "camera",
    "checks",
    "raster",
    "silhouette",
    "compose",
    "post",
    "io",
    "scene",
    "sweep",
    "showcase",
    "terrain",
    "raycast",
    "skin",
)


def _is_data(obj: Any) -> bool:
    return not (inspect.ismodule(obj) or inspect.isclass(obj) or callable(obj))


def _attr_doc(modname: str, name: str) -> list[str] | None:
    try:
        analyzer = ModuleAnalyzer.for_module(modname)
        return analyzer.find_attr_docs().get(("", name))
    except Exception:  # no source (a C module) or not parseable
        return None


def _defining_doc(obj: Any, name: str) -> list[str]:
    """The docstring written under ``name = ...`` in whichever jaxgfx module assigns it."""
    for modname, module in sorted(sys.modules.items()):
        if not modname.startswith("jaxgfx") or getattr(module, name, None) is not obj:
            continue
        doc = _attr_doc(modname, name)
        if doc:
            return list(doc)
    return []


def home_module(name: str) -> str | None:
    """The public module whose ``__all__`` holds ``name`` (its API page documents it)."""
    for mod in PUBLIC_MODULES:
        if name in importlib.import_module(f"jaxgfx.{mod}").__all__:
            return f"jaxgfx.{mod}"
    return None


class ModuleConstants(SphinxDirective):
    required_arguments = 1

    def run(self):
        modname = self.arguments[0]
        module = importlib.import_module(modname)
        lines: list[str] = []
        for name in module.__all__:
            obj = getattr(module, name)
            if not _is_data(obj) or _attr_doc(modname, name) is not None:
                continue  # automodule documents it
            lines += [f".. autodata:: {modname}.{name}", ""]
            lines += [f"   {line}" if line else "" for line in _defining_doc(obj, name)]
            lines.append("")
        return self.parse_text_to_nodes("\n".join(lines))


class PublicNames(SphinxDirective):
    required_arguments = 1

    def run(self):
        package = importlib.import_module(self.arguments[0])
        groups: dict[str, list[str]] = {}
        modules: list[str] = []
        here: list[str] = []
        for name in package.__all__:
            if inspect.ismodule(getattr(package, name)):
                modules.append(f"{package.__name__}.{name}")
            elif (home := home_module(name)) is not None:
                groups.setdefault(home, []).append(f"{home}.{name}")
            else:
                here.append(name)
        # Each table under its home module: the summaries' short cross-references (a
        # docstring's :class:`Camera`) resolve there, as on the home page itself.
        lines: list[str] = []
        for home, names in groups.items():
            lines += [f".. currentmodule:: {home}", ""]
            lines += [f"From :mod:`{home}`:", "", ".. autosummary::", "   :nosignatures:", ""]
            lines += [f"   {full.rsplit('.', 1)[1]}" for full in names] + [""]
        lines += [f".. currentmodule:: {package.__name__}", ""]
        if here:
            lines += ["Defined in the implementation package and documented here:", ""]
            for name in here:
                obj = getattr(package, name)
                kind = "class" if inspect.isclass(obj) else "function" if callable(obj) else "data"
                lines += [f".. auto{kind}:: {package.__name__}.{name}", ""]
        # Full module names: autosummary refuses names under the current module.
        lines += [".. currentmodule:: None", ""]
        lines += ["The public modules, one page each:", "", ".. autosummary::", ""]
        lines += [f"   {m}" for m in modules] + [""]
        return self.parse_text_to_nodes("\n".join(lines))


def skip_fields(app, what, name, obj, skip, options):
    """Leaves a class's data fields to its docstring's ``Attributes:`` section and signature.

    NamedTuple and dataclass fields carry no docstring of their own (a NamedTuple's says
    "Alias for field number N"); autodoc would list each one a second time beside napoleon's
    ``Attributes:`` entries, a duplicate object description.
    """
    if what == "class" and not (
        callable(obj) or isinstance(obj, (property, classmethod, staticmethod))
    ):
        return True
    return None


class PublicTargets(SphinxPostTransform):
    """Points a cross-reference to a class's defining name at the class's public name.

    A type hint names a class where it is defined (``jaxgfx._src.camera.Camera``).  Autodoc
    records that name as an alias (``:canonical:``) of the documented public one
    (``jaxgfx.camera.Camera``), so the link resolves, but the link's tooltip (and the text
    of an attribute's ``Type:`` field) would show the private name.  Runs before the
    references are resolved.
    """

    default_priority = 5  # sphinx's ReferencesResolver runs at 10

    def run(self, **kwargs: Any) -> None:
        objects = self.env.get_domain("py").objects  # type: ignore[attr-defined]
        for node in self.document.findall(addnodes.pending_xref):
            target = node.get("reftarget", "")
            if node.get("refdomain") != "py" or not target.startswith("jaxgfx._src."):
                continue
            entry = objects.get(target)
            if entry is not None and entry.aliased:
                node["reftarget"] = entry.node_id
                for text in list(node.findall(nodes.Text)):
                    if str(text) == target:
                        text.parent.replace(text, nodes.Text(entry.node_id))


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("module-constants", ModuleConstants)
    app.add_directive("public-names", PublicNames)
    app.add_post_transform(PublicTargets)
    app.connect("autodoc-skip-member", skip_fields)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
