"""Every shell and Python block of README.md and docs/*.md runs as written, and the documents cite
nothing outside the repository.

The blocks of one document run in order in one fresh directory (files made by one block are there
for the next), shell blocks with `bash -e -o pipefail`, each Python block in its own interpreter.
`eskin`, `python`, `eskin-fw-sim` and `eskin-classify` are on PATH, and ESKIN_REPO names the
repository. A block may be preceded by markers (HTML comments, invisible on the rendered page),
documented in README.md ("Tested documentation"):

    <!-- doctest: replace OLD => NEW -->   run with the text OLD replaced by NEW (e.g. smaller sizes)
    <!-- doctest: before
    CODE -->                               run CODE (same language) first, e.g. to make a
                                           fragment's inputs
    <!-- doctest: instead CMD -->          run the shell command CMD instead: a reduced form of a
                                           block that cannot run inside a test (`make test`)

A marker whose OLD text is not in its block is an error, so markers cannot go stale silently.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

import eskin
from eskin._paths import find_executable

REPO = next(p for p in Path(__file__).resolve().parents if (p / "README.md").is_file())
DOCUMENTS = ["README.md", *sorted(str(p.relative_to(REPO)) for p in (REPO / "docs").glob("*.md"))]
LANGUAGES = {"sh": "sh", "bash": "sh", "shell": "sh", "python": "python", "py": "python"}
#: blocks that are not run here: unlabelled ones (output, diagrams, synopses) and C++/CMake (the
#: README's are built against the installed library by test_cpp_install.py); a block in any other
#: language fails the test instead of being skipped
NOT_RUN = {"", "cpp", "cmake"}
BLOCK_TIMEOUT_S = 300

FENCE = re.compile(
    r"^(?P<indent>[ \t]*)```(?P<lang>[\w+-]*)[ \t]*\n(?P<body>.*?)^(?P=indent)```[ \t]*$",
    re.DOTALL | re.MULTILINE,
)
MARKER = re.compile(r"<!--\s*doctest:\s*(?P<kind>\w+)\s*(?P<arg>.*?)\s*-->", re.DOTALL)


@dataclass
class Block:
    document: str
    line: int
    language: str
    code: str
    before: list[str] = field(default_factory=list)
    instead: str | None = None

    @property
    def where(self) -> str:
        return f"{self.document}:{self.line}"


def _dedent(text: str, indent: str) -> str:
    return "".join(ln.removeprefix(indent) for ln in text.splitlines(keepends=True))


def _markers_before(text: str, start: int) -> list[re.Match]:
    """The doctest markers that directly precede position ``start`` (only whitespace between)."""
    found: list[re.Match] = []
    head = text[:start]
    while True:
        stripped = head.rstrip()
        if not stripped.endswith("-->"):
            return found[::-1]
        opening = stripped.rfind("<!--")
        m = MARKER.fullmatch(stripped[opening:])
        if m is None:
            return found[::-1]
        found.append(m)
        head = stripped[:opening]


def blocks_of(document: str) -> list[Block]:
    text = (REPO / document).read_text()
    blocks = []
    for m in FENCE.finditer(text):
        language = LANGUAGES.get(m.group("lang"))
        line = text.count("\n", 0, m.start()) + 1
        markers = _markers_before(text, m.start())
        assert language or m.group("lang") in NOT_RUN, (
            f"{document}:{line}: a ```{m.group('lang')} block: label it sh or python to run it, "
            "or add its language to NOT_RUN with the reason"
        )
        if language is None:
            assert not markers, f"{document}:{line}: doctest marker on a block that is not run"
            continue
        block = Block(document, line, language, _dedent(m.group("body"), m.group("indent")))
        for mk in markers:
            kind, arg = mk.group("kind"), mk.group("arg")
            if kind == "replace":
                old, sep, new = arg.partition(" => ")
                assert sep and old in block.code, f"{block.where}: stale marker 'replace {arg}'"
                block.code = block.code.replace(old, new)
            elif kind == "before":
                block.before.append(arg + "\n")
            elif kind == "instead":
                block.instead = arg
            else:
                raise AssertionError(f"{block.where}: unknown doctest marker {kind!r}")
        blocks.append(block)
    return blocks


def _environment(tmp: Path) -> dict[str, str]:
    """PATH with `eskin` and `python` (this interpreter, this package) and the C++ tools."""
    bin_dir = tmp / ".doctest-bin"
    bin_dir.mkdir()
    for name, target in (
        ("eskin", f'"{sys.executable}" -m eskin'),
        ("python", f'"{sys.executable}"'),
        ("python3", f'"{sys.executable}"'),
    ):
        script = bin_dir / name
        script.write_text(f'#!/bin/sh\nexec {target} "$@"\n')
        script.chmod(0o755)
    tool_dirs = {str(find_executable(t).parent) for t in ("eskin-fw-sim", "eskin-classify")}
    package_root = str(Path(eskin.__file__).resolve().parents[1])
    home = tmp / ".home"
    home.mkdir()
    env = dict(os.environ)
    env.update(
        PATH=os.pathsep.join(
            [
                str(bin_dir),
                *sorted(tool_dirs),
                str(Path(sys.executable).parent),
                env.get("PATH", ""),
            ]
        ),
        PYTHONPATH=os.pathsep.join(filter(None, [package_root, env.get("PYTHONPATH", "")])),
        ESKIN_REPO=str(REPO),
        HOME=str(home),
        MPLBACKEND="Agg",
        COLUMNS="100",
    )
    # the build tree of the tools (the README's install block installs from it)
    env["ESKIN_BIN_DIR"] = str(
        Path(env["ESKIN_BIN_DIR"]).resolve()
        if env.get("ESKIN_BIN_DIR")
        else find_executable("eskin-classify").parent
    )
    return env


def _run(block: Block, cwd: Path, env: dict[str, str]) -> None:
    if block.instead is not None:
        argv = ["bash", "-e", "-o", "pipefail", "-c", block.instead]
    elif block.language == "sh":
        argv = ["bash", "-e", "-o", "pipefail", "-c", "".join(block.before) + block.code]
    else:
        argv = [sys.executable, "-c", "".join(block.before) + block.code]
    proc = subprocess.Popen(
        argv,
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        out, _ = proc.communicate(timeout=BLOCK_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        raise AssertionError(f"{block.where}: still running after {BLOCK_TIMEOUT_S} s\n{out}")
    finally:
        try:  # what the block left running in the background (e.g. `eskin-fw-sim ... &`)
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    assert proc.returncode == 0, (
        f"{block.where}: the {block.language} block failed (exit {proc.returncode}):\n"
        f"{block.instead or block.code}\n--- output ---\n{out[-4000:]}"
    )


@pytest.mark.parametrize("document", DOCUMENTS)
def test_every_block_runs(document, tmp_path):
    blocks = blocks_of(document)
    env = _environment(tmp_path)
    for block in blocks:
        _run(block, tmp_path, env)
