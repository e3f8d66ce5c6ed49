"""Every error type eskin raises, one home for each, by layer (the modules that raise them
re-export them: ``eskin.data.campaign.CampaignFormatError`` is this one).

All are ValueError or OSError subclasses, so that a caller that knows only the standard
exceptions still catches them; each message names the file, field and value at fault.
"""

from __future__ import annotations

import os

__all__ = [
    "BaselineUnavailable",
    "CampaignFormatError",
    "ClassLeftOut",
    "DemoError",
    "EvaluationError",
    "ExperimentError",
    "JournalError",
    "LinkStreamError",
    "ModelFormatError",
    "OverwriteError",
    "PeerClosedError",
    "QemuControllerError",
    "ReplayFormatError",
    "SchedulerError",
    "SerialPortError",
    "SkinFormatError",
    "TrainingError",
]

# ------------------------------------------------------------------------------- data


class CampaignFormatError(ValueError):
    """A campaign file (or in-memory campaign) breaks the format.

    Attributes ``path``, ``field`` and ``problem`` hold the three parts of the message
    (``field`` is empty when the problem is the whole file's).
    """

    def __init__(self, path: str | os.PathLike[str] | None, field: str, problem: str):
        self.path = str(path) if path is not None else "<memory>"
        self.field = field
        self.problem = problem
        super().__init__(f"{self.path}: {field}: {problem}" if field else f"{self.path}: {problem}")


class SkinFormatError(ValueError):
    """A skin description (the TOML file naming a skin's patches) breaks its format.

    Attributes ``path``, ``field`` and ``problem`` hold the three parts of the message, as
    :class:`CampaignFormatError` does (``field`` names the table and key, e.g.
    ``patch[3].grid``; empty when the problem is the whole file's).
    """

    def __init__(self, path: str | os.PathLike[str] | None, field: str, problem: str):
        self.path = str(path) if path is not None else "<memory>"
        self.field = field
        self.problem = problem
        super().__init__(f"{self.path}: {field}: {problem}" if field else f"{self.path}: {problem}")


class JournalError(ValueError):
    """A recording journal is not one, or its header is damaged (message names the file)."""


class ReplayFormatError(ValueError):
    """A replay file is not valid (names the file and the problem)."""


class OverwriteError(FileExistsError):
    """A command would replace a file without --force, or write onto one of its own inputs."""


# ------------------------------------------------------------------------------- learn, deploy


class TrainingError(ValueError):
    """Training data or options that cannot make a model (unknown class, one class, ...)."""


class ClassLeftOut(TrainingError):
    """A cross-validation split whose training part lacks a class (too few groups record it):
    ``eskin train`` then splits by class instead of by group."""


class ModelFormatError(ValueError):
    """A model file (the joblib container or the ``.eskin`` file) or a model description that
    is not valid: wrong type, version or content; the message names the file or field."""


class EvaluationError(ValueError):
    """Evaluation options or data that cannot give a group-disjoint evaluation."""


class BaselineUnavailable(ImportError):
    """A requested baseline whose optional dependency is not installed."""


class SchedulerError(ValueError):
    """A --scheduler value that names no usable Dask scheduler."""


# ------------------------------------------------------------------------------- link


class SerialPortError(OSError):
    """A serial port call failed; ``status`` is the core's status name (e.g. "open_failed")."""

    def __init__(self, status: str, message: str, errno_: int = 0):
        super().__init__(errno_ or None, message)
        self.status = status

    def __str__(self) -> str:
        return str(self.args[1]) if len(self.args) > 1 else super().__str__()


class LinkStreamError(ValueError):
    """The controller's stream cannot go on: a frame whose field contradicts what the host
    needs (an INFO grid the host model cannot take). The message names the frame type, the
    field and the value."""


class PeerClosedError(SerialPortError):
    """The other end of the link closed (the controller or simulator went away)."""


class QemuControllerError(OSError):
    """The emulated controller cannot start (no QEMU, no image, a model or replay too large)."""


# ------------------------------------------------------------------------------- experiments, demo


class ExperimentError(ValueError):
    """A campaign or an option that the protocol cannot run with."""


class DemoError(RuntimeError):
    """A step of the demo failed; the message says which and why."""
