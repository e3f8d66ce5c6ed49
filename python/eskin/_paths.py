"""Where eskin finds its compiled command-line tools (eskin-classify, eskin-fw-sim)."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path


def find_executable(name: str) -> Path:
    """Return the path of one of eskin's executables.

    Looked up, in order: the folder named by ``ESKIN_BIN_DIR`` (and its ``firmware_sim``
    sub-folder, as a CMake build tree lays them out), the folder of the running Python
    (a virtual environment's ``bin``, where the wheel installs them), then ``PATH``.
    """
    candidates: list[Path] = []
    env = os.environ.get("ESKIN_BIN_DIR")
    if env:
        candidates += [Path(env) / name, Path(env) / "firmware_sim" / name]
    candidates.append(Path(sys.executable).parent / name)
    for c in candidates:
        if c.is_file() and os.access(c, os.X_OK):
            return c
    found = shutil.which(name)
    if found:
        return Path(found)
    raise FileNotFoundError(
        f"eskin executable {name!r} not found (looked in ESKIN_BIN_DIR={env!r}, "
        f"{Path(sys.executable).parent}, and PATH); build it with `make cpp` or `pip install .`"
    )
