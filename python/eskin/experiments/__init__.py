"""The experiments layer: the paper's protocol (binary and multiclass tasks, participant
splits, baselines), the report that compares the results with the paper, and the paper's
tables. Builds on eskin.learn."""

from . import paper_tables
from .paper_protocol import ExperimentError, ProtocolConfig, quick_config, run_experiment
from .report import render_markdown, summarise, write_report

__all__ = [
    "ExperimentError",
    "ProtocolConfig",
    "paper_tables",
    "quick_config",
    "render_markdown",
    "run_experiment",
    "summarise",
    "write_report",
]
