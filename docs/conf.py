"""Sphinx configuration for the jaxgfx documentation.

Build: ``sphinx-build -W --keep-going -b html docs docs/_build/html``.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "docs" / "_ext"))

import jaxgfx  # noqa: E402

project = "jaxgfx"
author = "jaxgfx authors"
release = version = jaxgfx.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "myst_parser",
    "jaxgfx_api",  # docs/_ext: constants re-exported by the faces, the top-level summary
    "jaxgfx_cli",  # docs/_ext: `jaxgfx CMD --help` from the parser
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "_ext"]
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3

autodoc_default_options = {"members": True, "undoc-members": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autosummary_generate = False
napoleon_google_docstring = True
napoleon_numpy_docstring = False
# A "Returns:" type such as ``(H, W) float32`` is a shape, not a class to link: it is shown
# with the description instead of as an ``:rtype:`` field of cross-references.
napoleon_use_rtype = False

# Every cross-reference must resolve (``-W`` turns a dangling one into an error).  The targets
# below belong to other projects, whose inventories this offline build does not load; autodoc
# writes them from the type hints (``jax.Array`` is rendered by its defining module).
nitpicky = True
nitpick_ignore = [
    ("py:class", name)
    for name in (
        "jax.Array",
        "jax.jaxlib._jax.Array",
        "jaxlib._jax.Device",
        "jax._src.mesh.Mesh",
        "numpy.ndarray",
        "optax._src.base.GradientTransformation",
        "collections.abc.Callable",
        "collections.abc.Mapping",
        "collections.abc.Sequence",
        "os.PathLike",
        "pathlib.Path",
        "Path",  # an exception's __init__ signature, annotated with pathlib.Path
    )
]

html_theme = "alabaster"
html_title = f"jaxgfx {release}"
