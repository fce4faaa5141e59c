"""``.. cli-help:: [COMMAND]``: the ``jaxgfx [COMMAND] --help`` text, from the parser itself.

The command-line page shows each subcommand's options as argparse prints them, so the page
cannot drift from the code.  Without an argument it shows the top-level help.
"""

from __future__ import annotations

import argparse
import os
from typing import Any

from docutils import nodes
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

WIDTH = 92  # columns argparse wraps the help at (it reads $COLUMNS)


def help_text(command: str | None) -> str:
    """``jaxgfx [command] --help`` as it prints at :data:`WIDTH` columns."""
    from jaxgfx.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(WIDTH)
    try:
        parser = build_parser()
        if command is not None:
            subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
            if command not in subs.choices:
                raise ValueError(f"jaxgfx has no subcommand {command!r}")
            parser = subs.choices[command]
        return parser.format_help().rstrip()
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


class CliHelp(SphinxDirective):
    optional_arguments = 1

    def run(self):
        command = self.arguments[0] if self.arguments else None
        try:
            text = help_text(command)
        except ValueError as exc:
            raise self.error(str(exc)) from None
        block = nodes.literal_block(text, text)
        block["language"] = "text"
        return [block]


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("cli-help", CliHelp)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
