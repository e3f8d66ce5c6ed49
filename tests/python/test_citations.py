"""README.md, docs/, BENCHMARKS.md and the code cite only what is in the repository: no notes
file from outside it (the readings of the paper are docs/paper-readings.md), no internal issue
numbers, nothing of how the team works; "session" only for a recording session."""

from __future__ import annotations

import re
from pathlib import Path

REPO = next(p for p in Path(__file__).resolve().parents if (p / "README.md").is_file())


CITED_TREES = [
    "README.md",
    "BENCHMARKS.md",
    "docs",
    "python",
    "cpp",
    "firmware_sim",
    "benchmarks",
    "tests",
    "Makefile",
    "CMakeLists.txt",
    "cmake",
    "pyproject.toml",
]
TEXT_SUFFIXES = {".md", ".py", ".pyi", ".cpp", ".hpp", ".h", ".txt", ".in", ".toml", ""}
#: (pattern, what it is); matched case-sensitively unless the pattern says otherwise
FORBIDDEN = [
    (r"\bNOTES\b", "a notes file outside the repository (cite docs/paper-readings.md)"),
    (r"(?i)\bissues? #?\d+", "an internal issue number (name a commit, a version or a file)"),
    (r"(?i)\bsession[- ]\d", "an internal milestone (name a commit)"),
    (r"(?i)\b(?:seven|other|\d+) developers?\b|developers' (?:builds|jobs)", "the team at work"),
]
#: in the documents "session" means a recording session and nothing else (the code may speak
#: of a link's sessions, or of pytest's session scope)
FORBIDDEN_IN_DOCUMENTS = [
    (r"(?i)(?<!recording )(?<!recording-)\bsessions?\b", "'session' (only a recording session)"),
]


def _text_files():
    for entry in CITED_TREES:
        path = REPO / entry
        files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
        for f in files:
            if f.suffix in TEXT_SUFFIXES and "__pycache__" not in f.parts and f != Path(__file__):
                yield f


def test_documents_and_code_cite_only_the_repository():
    """No `NOTES n`, no internal issue numbers, nothing of the team's way of working: the text
    speaks of the product. (In the documents, 'session' only for a recording session.)"""
    bad = []
    for f in _text_files():
        text = f.read_text(errors="replace")
        rules = FORBIDDEN + (FORBIDDEN_IN_DOCUMENTS if f.suffix == ".md" else [])
        for pattern, what in rules:
            for m in re.finditer(pattern, text):
                line = text.count("\n", 0, m.start()) + 1
                bad.append(f"{f.relative_to(REPO)}:{line}: {m.group(0)!r}: {what}")
    assert not bad, "\n".join(bad)
