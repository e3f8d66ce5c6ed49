"""CLI commands: simulate, info, plot, import-csv, import-tdms (issue 3)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add this module's commands to the eskin app."""
