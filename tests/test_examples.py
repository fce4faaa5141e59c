"""Every example of the README and the docs pages runs as written.

Each ```` ```python ```` block of ``README.md`` and ``docs/*.md`` runs as a script of its own, in
a fresh process whose working folder is a temporary one (what it writes stays out of the
checkout), beside a ``shared/data`` that is the real data folder, as the README's layout
has it.  The process inherits this suite's compile flags and compilation cache (the
variables ``tests/conftest.py`` sets).  Blocks with the same text (the README repeats the
getting-started examples) run once.

In ```` ```bash ```` blocks every ``jaxgfx ...`` command must parse with the CLI's own parser,
and in a block that runs, every file it reads must exist: in the data folder (the page
skips when that is absent), in the checkout, or written by an earlier command of the same
page (the voxelize example writes what the render-voxels example reads).  ``python -m``
must name a module of the checkout.  The cheap commands (:data:`CHEAP`) are run.  A
``jaxgfx`` command quoted inline in the text (the command tables) must parse too.

A block that must not run (``pip install``, the test suite itself) is marked in the
Markdown by an HTML comment on the line before it, unseen by the reader:
``<!-- not run: the reason -->``.  Its ``jaxgfx`` commands must still parse.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from jaxgfx.cli import build_parser
from jaxgfx.cli.args import join_negative_values

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))
DATA = Path(os.environ.get("JAXGFX_DATA", ROOT / ".." / "shared" / "data"))
SHARED = "../shared/data"

NOT_RUN = re.compile(r"<!--\s*not run:\s*(.+?)\s*-->")
FENCE = re.compile(r"^```(\w+)\s*$")
OUTPUT_OPTIONS = {"--out", "--depth", "--mesh", "--still"}
PATH_LIKE = re.compile(r"/|\.[A-Za-z]\w{1,4}$")

CHEAP = (("voxelize", "tree"),)
"""``jaxgfx`` commands (their first words) the test runs: a few seconds each.  The others
compile a renderer (20-60 s on two cores) that the python examples compile already."""


@dataclasses.dataclass(frozen=True)
class Block:
    page: Path
    line: int  # the opening fence's, 1-based
    lang: str
    code: str
    not_run: str | None  # the reason of a <!-- not run: ... --> mark, or None

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def page_blocks(page: Path) -> list[Block]:
    """The fenced blocks of a Markdown page with a language name, in order."""
    lines = page.read_text().splitlines()
    out, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        before = next((s for s in reversed(lines[:i]) if s.strip()), "")
        mark = NOT_RUN.search(before)
        code = "\n".join(lines[i + 1 : end]) + "\n"
        out.append(Block(page, i + 1, m.group(1), code, mark.group(1) if mark else None))
        i = end + 1
    return out


BLOCKS = [b for page in PAGES for b in page_blocks(page)]


def _python_examples() -> list:
    """One pytest param per distinct python block, named by every place it appears."""
    by_code: dict[str, list[Block]] = {}
    for b in BLOCKS:
        if b.lang == "python":
            by_code.setdefault(b.code, []).append(b)
    return [pytest.param(bs, id="+".join(b.where for b in bs)) for bs in by_code.values()]


def _env() -> dict[str, str]:
    """This process's variables (the suite's XLA flags and cache), the checkout importable."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return env


def _workdir(tmp_path: Path) -> Path:
    """``tmp/work``, with ``tmp/shared/data`` the data folder (when there is one)."""
    work = tmp_path / "work"
    work.mkdir()
    if DATA.is_dir():
        (tmp_path / "shared").mkdir()
        (tmp_path / "shared" / "data").symlink_to(DATA.resolve(), target_is_directory=True)
    return work


def _printed_claims(code: str) -> list[str]:
    """What ``print(...)  # (8, 240, 320, 3) ...`` lines say they print (shapes)."""
    return re.findall(r"^print\(.*\)\s+#\s*(\(.*\))\s*$", code, re.MULTILINE)


@pytest.mark.parametrize("blocks", _python_examples())
def test_python_example_runs_as_written(blocks, tmp_path):
    block = blocks[0]
    if block.not_run:
        pytest.skip(f"{block.where}: not run: {block.not_run}")
    if SHARED in block.code and not DATA.is_dir():
        pytest.skip(f"real data folder {DATA} is absent")
    work = _workdir(tmp_path)
    (work / "example.py").write_text(block.code)
    res = subprocess.run(
        [sys.executable, "example.py"],
        cwd=work,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert res.returncode == 0, f"{block.where} failed:\n{res.stderr[-4000:]}"
    for claim in _printed_claims(block.code):
        assert claim in res.stdout, f"{block.where} printed {res.stdout!r}, not {claim!r}"
    # The image fit's text says its vertex error falls more than fivefold (getting started).
    for before, after in re.findall(r"vertex error (\S+) -> (\S+)", res.stdout):
        assert float(before) >= 5 * float(after), f"{block.where}: {before} -> {after}"


def _commands(code: str) -> list[list[str]]:
    """The shell commands of a block: continuation lines joined, comments dropped, ``&&``
    split."""
    out = []
    for line in code.replace("\\\n", " ").splitlines():
        words = shlex.split(line, comments=True)
        while words:
            cut = words.index("&&") if "&&" in words else len(words)
            out.append(words[:cut])
            words = words[cut + 1 :]
    return [c for c in out if c]


def _files(argv: list[str]) -> tuple[list[str], list[str]]:
    """(files read, files or folders written) named by a command's arguments."""
    read, written = [], []
    for i, word in enumerate(argv):
        if i > 0 and argv[i - 1] in OUTPUT_OPTIONS:
            written.append(word.rstrip("/"))
        elif not word.startswith("-") and PATH_LIKE.search(word):
            read.append(word.removeprefix("heightmap:"))
    return read, written


def _check_file(path: str, written: list[str], where: str) -> str | None:
    """An error message if ``path`` (relative to the checkout) is missing; None if present.

    A data path passes unchecked when the data folder is absent (the caller skips then).
    """
    if any(path == w or path.startswith(w + "/") for w in written):
        return None
    if path.startswith(SHARED + "/"):
        found = not DATA.is_dir() or (DATA / path.removeprefix(SHARED + "/")).exists()
        return None if found else f"{where}: {path} is not in the data folder {DATA}"
    return None if (ROOT / path).exists() else f"{where}: {path} (not written before it)"


def _parse(argv: list[str], where: str) -> str | None:
    """An error message if the CLI's parser refuses ``jaxgfx argv``; None if it accepts it."""
    try:
        build_parser().parse_args(join_negative_values(argv))
    except SystemExit as exc:
        return f"{where}: jaxgfx {shlex.join(argv)} does not parse (exit {exc.code})"
    return None


@pytest.mark.parametrize(
    "page",
    [p for p in PAGES if any(b.page == p and b.lang == "bash" for b in BLOCKS)],
    ids=lambda p: str(p.relative_to(ROOT)),
)
def test_bash_commands_parse_and_read_files_that_exist(page, tmp_path, capsys):
    errors, written, needs_data = [], [], False
    work = None
    for block in (b for b in BLOCKS if b.page == page and b.lang == "bash"):
        for cmd in _commands(block.code):
            if cmd[0] == "jaxgfx":
                errors.append(_parse(cmd[1:], block.where))
            if block.not_run:
                continue  # pip, venv, the suite: never run; their jaxgfx commands parse
            if cmd[0] == "jaxgfx" or cmd[:2] in (["python", "-m"], ["python3", "-m"]):
                read, out = _files(cmd)
                if cmd[0] == "jaxgfx":  # an experiment's own arguments are its to check
                    errors += [_check_file(p, written, block.where) for p in read]
                    needs_data |= any(p.startswith(SHARED + "/") for p in read)
                written += out
            else:
                errors.append(f"{block.where}: `{cmd[0]}` runs unmarked: mark it not run")
                continue
            if cmd[0] != "jaxgfx":
                module = cmd[2]
                if (
                    importlib.util.find_spec(module.split(".")[0]) is None
                    or not (ROOT / (module.replace(".", "/") + ".py")).is_file()
                ):
                    errors.append(f"{block.where}: python -m {module}: no such module")
            elif any(tuple(cmd[1 : 1 + len(c)]) == c for c in CHEAP):
                work = work or _workdir(tmp_path)
                res = subprocess.run(
                    [sys.executable, "-m", "jaxgfx.cli", *cmd[1:]],
                    cwd=work,
                    env=_env(),
                    capture_output=True,
                    text=True,
                    timeout=300,
                )
                if res.returncode != 0:
                    errors.append(f"{block.where}: {shlex.join(cmd)}:\n{res.stderr[-2000:]}")
                for p in out:
                    if not (work / p).exists():
                        errors.append(f"{block.where}: {shlex.join(cmd)} did not write {p}")
    capsys.readouterr()  # the parser's usage messages
    errors = [e for e in errors if e]
    assert not errors, "\n".join(errors)
    if needs_data and not DATA.is_dir():
        pytest.skip(f"real data folder {DATA} is absent: its paths were not checked")


def test_the_checks_see_a_bad_command_a_missing_file_and_an_unmarked_install():
    # The bash checks above pass only if they can fail: the parser refuses an unknown
    # option, a file no earlier command writes is missing, and pip needs a mark.
    assert _parse(["render", "x.ply", "--no-such-option"], "here")
    assert _parse(["terrain", "--function", "csg", "--out", "t.png"], "here") is None
    assert _check_file("no/such/file.ply", [], "here")
    assert _check_file("out/hr/inputs/map.tif", ["out/hr"], "here") is None
    assert _commands("pip install . && jaxgfx demo --out d/  # c\n") == [
        ["pip", "install", "."],
        ["jaxgfx", "demo", "--out", "d/"],
    ]
    block = page_blocks(ROOT / "README.md")[0]
    assert block.lang == "bash" and block.not_run, "README's install block carries its mark"


def test_inline_commands_parse_and_name_data_that_exists():
    # Commands quoted in the text (the README's and the CLI page's command tables): a
    # subcommand with arguments parses, and the data files it names are in the data folder.
    errors = []
    for page in PAGES:
        for span in re.findall(r"`(jaxgfx [^`]+)`", page.read_text()):
            argv = shlex.split(span)[1:]
            if any("CMD" in w for w in argv) or len(argv) < 2:  # a placeholder, or a bare name
                continue
            where = f"{page.relative_to(ROOT)}: `{span}`"
            errors.append(_parse(argv, where))
            read, _ = _files(argv)
            errors += [_check_file(p, [], where) for p in read if p.startswith(SHARED + "/")]
    errors = [e for e in errors if e]
    assert not errors, "\n".join(errors)
