"""Every field of every frame the listener receives, checked before use.

The decoder (``eskin.protocol.FrameDecoder``) accepts a frame when its bytes are sound: COBS,
CRC-32, a known type and a payload of the right size. A sound frame can still carry values no
controller sends: a sample index of 2^63, a rate of 0, NaN or 1e300, a 255x7 grid in a 4x4
stream, a class index past the controller's class names, an onset after the offset.
:class:`FrameChecks` judges each frame against the limits below and against what the stream
has established (the grid and class names of the INFO it accepted); the listener counts a
refused frame, reports it as a :class:`Rejection` naming the frame type, the field and the
value, and goes on without it (docs/wire-protocol.md, "Host rules").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

from eskin.data.limits import MAX_GRID_SIDE, MAX_SAMPLE_RATE_HZ, MAX_TAXELS
from eskin.link.protocol import DataFrame, DecisionFrame, InfoFrame, StatusFrame

__all__ = ["MAX_SAMPLE_RATE_HZ", "MAX_STREAM_INDEX", "FrameChecks", "GridVote", "Rejection"]

MAX_STREAM_INDEX = 1 << 53
"""Sample indices and sample counts: below 2^53 (exact as a float; 95,000 years at 3 kHz)."""
MAX_SPEED = 1e6
"""INFO's replay speed factor: at most 10^6; 0 is an unpaced controller (eskin-fw-sim --speed 0:
as fast as the host reads)."""


@dataclass(frozen=True)
class Rejection:
    """A frame refused by :class:`FrameChecks`: ``frame`` (DATA, INFO, ...), the ``field`` at
    fault, its ``value`` and the ``problem``."""

    frame: str
    field: str
    value: Any
    problem: str

    def message(self) -> str:
        return f"{self.frame} frame: {self.field} = {self.value!r}: {self.problem}"


def _index_problem(value: int) -> Optional[str]:
    if not 0 <= value < MAX_STREAM_INDEX:
        return "outside [0, 2^53)"
    return None


class FrameChecks:
    """Checks frames against fixed limits and against the stream's accepted INFO."""

    def __init__(self) -> None:
        self.info: Optional[InfoFrame] = None  # the last INFO accepted

    def check(self, f: Any) -> Optional[Rejection]:
        """None if frame ``f`` may be used, else why not. An accepted INFO becomes the
        reference for the frames after it."""
        if isinstance(f, DataFrame):
            return self._data(f)
        if isinstance(f, DecisionFrame):
            return self._decision(f)
        if isinstance(f, StatusFrame):
            return self._status(f)
        if isinstance(f, InfoFrame):
            problem = self._info(f)
            if problem is None:
                self.info = f
            return problem
        return None

    def _data(self, f: DataFrame) -> Optional[Rejection]:
        for name in ("first_sample", "end_sample"):
            problem = _index_problem(int(getattr(f, name)))
            if problem:
                return Rejection("DATA", name, int(getattr(f, name)), problem)
        rows, cols = int(f.samples.shape[1]), int(f.samples.shape[2])
        if self.info is not None and (rows, cols) != (self.info.rows, self.info.cols):
            return Rejection("DATA", "grid", f"{rows}x{cols}",
                             f"the INFO accepted says {self.info.rows}x{self.info.cols}")
        if rows * cols > MAX_TAXELS:
            return Rejection("DATA", "grid", f"{rows}x{cols}", f"over {MAX_TAXELS} taxels")
        return None

    def _decision(self, f: DecisionFrame) -> Optional[Rejection]:
        for name in ("onset_sample", "offset_sample", "decided_sample"):
            problem = _index_problem(int(getattr(f, name)))
            if problem:
                return Rejection("DECISION", name, int(getattr(f, name)), problem)
        if f.offset_sample < f.onset_sample:
            return Rejection("DECISION", "offset_sample", int(f.offset_sample),
                             f"before onset_sample {int(f.onset_sample)}")
        names = self.info.class_names if self.info is not None else None
        if f.label < -1 or (names is not None and f.label >= len(names)):
            known = f"{len(names)} class names" if names is not None else "none"
            return Rejection("DECISION", "label", int(f.label),
                             f"not -1 (none) or a class index (the INFO accepted has {known})")
        return None

    def _status(self, f: StatusFrame) -> Optional[Rejection]:
        for name in ("next_sample", "samples_sent", "dropped_samples"):
            problem = _index_problem(int(getattr(f, name)))
            if problem:
                return Rejection("STATUS", name, int(getattr(f, name)), problem)
        return None

    def _info(self, f: InfoFrame) -> Optional[Rejection]:
        if not (1 <= f.rows <= MAX_GRID_SIDE and 1 <= f.cols <= MAX_GRID_SIDE
                and f.rows * f.cols <= MAX_TAXELS):
            return Rejection("INFO", "grid", f"{f.rows}x{f.cols}",
                             f"not a grid of 1..{MAX_TAXELS} taxels")
        checks = (
            ("sample_rate_hz", f.sample_rate_hz, 0.0, MAX_SAMPLE_RATE_HZ, False),
            ("volts_per_count", f.volts_per_count, 0.0, math.inf, True),
            ("speed", f.speed, 0.0, MAX_SPEED, True),  # 0: unpaced
        )
        for name, v, lo, hi, zero_ok in checks:
            if not (math.isfinite(v) and (lo < v or (zero_ok and v == lo)) and v <= hi):
                bound = f"[0, {hi:g}]" if zero_ok else f"(0, {hi:g}]"
                return Rejection("INFO", name, float(v), f"not a finite number in {bound}")
        if f.samples_per_frame < 1:
            return Rejection("INFO", "samples_per_frame", int(f.samples_per_frame), "not >= 1")
        names = list(f.class_names)
        if any(not n or not n.isprintable() for n in names) or len(set(names)) != len(names):
            return Rejection("INFO", "class_names", names,
                             "empty, unprintable or repeated names")
        return None


class GridVote:
    """The grid of DATA frames before any INFO. With a host model, its grid; without, the
    grid of the first frame, replaced by another once ``switch_after`` frames in a row carry
    that other one (so one stray frame cannot lock a stream on its grid). After an INFO, the
    INFO's grid (checked by :class:`FrameChecks`)."""

    switch_after = 3

    def __init__(self, model_grid: Optional[tuple[int, int]]) -> None:
        self.grid = None if model_grid is None else (int(model_grid[0]), int(model_grid[1]))
        self.fixed = model_grid is not None
        self._other: Optional[tuple[int, int]] = None
        self._count = 0

    def check(self, f: DataFrame, info: Optional[InfoFrame]) -> Optional[Rejection]:
        grid = (int(f.samples.shape[1]), int(f.samples.shape[2]))
        if info is not None or self.grid is None or grid == self.grid:
            self.grid = grid if info is None and self.grid is None else self.grid
            self._count = 0
            return None
        self._count = self._count + 1 if grid == self._other else 1
        self._other = grid
        if not self.fixed and self._count >= self.switch_after:
            self.grid, self._count = grid, 0
            return None
        expected = "the host model's" if self.fixed else "the stream's"
        return Rejection("DATA", "grid", f"{grid[0]}x{grid[1]}",
                         f"{expected} grid is {self.grid[0]}x{self.grid[1]} (no INFO yet)")
