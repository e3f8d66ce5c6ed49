"""The one progress display of every long command (experiment, simulate, train's search).

A rich progress bar on stdout that stays silent when it is disabled or when stdout is not a
terminal (a pipe, a log file, a test), so that only the command's own lines reach a file. The
object it yields is a :class:`rich.progress.Progress` either way: callers add tasks and
advance them without asking whether anything is shown.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def progress_bar(enabled: bool = True) -> Iterator[Any]:
    """A started :class:`rich.progress.Progress` (description, bar, done/total, elapsed,
    remaining), stopped on exit; shown only when ``enabled`` and stdout is a terminal."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    console = Console()
    progress = Progress(
        TextColumn("{task.description:<28}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        disable=not (enabled and console.is_terminal),
    )
    with progress:
        yield progress
