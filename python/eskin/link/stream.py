"""The received stream on the host: DATA frames -> one continuous sample stream (short holes
bridged by holding the last sample, long holes and index resets restart it), the recent
samples by stream index (:class:`SampleHistory`), and the touches the host classifier and
detector find in it (:class:`StreamAssembler`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Optional

import numpy as np

from eskin.link.host_classifier import HostClassifier, Touch
from eskin.link.protocol import DataFrame

__all__ = ["SampleHistory", "StreamAssembler"]

MAX_BRIDGED_JUMP_S = 3600.0
"""A forward jump of the sample index longer than this (in seconds of samples) is an index
reset (a controller restarted), not a loss: no link loses an hour of samples unnoticed."""


class SampleHistory:
    """The last ``capacity`` samples by stream index, with a mask of the ones that were lost."""

    def __init__(self, capacity: int, grid: tuple[int, int]) -> None:
        self.capacity = max(1, int(capacity))
        self.grid = grid
        self.buf = np.zeros((self.capacity, grid[0], grid[1]), np.int16)
        self.lost = np.zeros(self.capacity, bool)
        self.end = 0  # one past the newest stream index held
        self.begin = 0  # oldest stream index held

    def append(self, first: int, block: np.ndarray, lost: np.ndarray) -> None:
        n = block.shape[0]
        if first != self.end:  # a reset: start over at this index
            self.begin = self.end = first
        if n >= self.capacity:
            first += n - self.capacity
            block, lost = block[-self.capacity:], lost[-self.capacity:]
            n = self.capacity
            self.begin = self.end = first
        pos = (first + np.arange(n)) % self.capacity
        self.buf[pos] = block
        self.lost[pos] = lost
        self.end = first + n
        self.begin = max(self.begin, self.end - self.capacity)

    def get(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """Samples [start, stop) clipped to what is held: (samples (n, rows, cols), lost (n,))."""
        start, stop = max(start, self.begin), min(stop, self.end)
        if stop <= start:
            return self.buf[:0].copy(), self.lost[:0].copy()
        pos = np.arange(start, stop) % self.capacity
        return self.buf[pos], self.lost[pos]


class StreamAssembler:
    """DATA frames of one grid -> the continuous stream, its history and the host's touches.

    ``on_touch(classifier, start, stop, touch, received)`` is called for every touch a
    classifier completes (stream indices ``[start, stop)``); ``on_restart()`` when the stream
    restarts (a long hole or an index reset), after the classifiers were flushed; ``on_fed()``
    after each block of samples entered the history (a second of samples at most).
    """

    def __init__(self, grid: tuple[int, int], *, rate: float, history_capacity: int,
                 max_fill_s: float, classifiers: list[HostClassifier],
                 on_touch: Callable[..., None], on_restart: Callable[[], None],
                 on_fed: Callable[[], None]) -> None:
        self.grid = grid
        self.rate = float(rate)
        self.max_fill_s = float(max_fill_s)
        self.history = SampleHistory(history_capacity, grid)
        self.classifiers = classifiers
        self._on_touch = on_touch
        self._on_restart = on_restart
        self._on_fed = on_fed
        self.next: Optional[int] = None  # next expected stream index
        self._last: Optional[np.ndarray] = None  # last sample (held over holes)
        self._base = 0  # stream index of the classifiers' sample 0
        self.lost_ranges: list[tuple[int, int]] = []
        self.lost_samples = 0
        self.index_resets = 0

    def feed_frames(self, frames: list[DataFrame], received: float,
                    emit: Callable[[DataFrame, int], None]) -> None:
        """Feed consecutive DATA frames (all of this grid); contiguous ones reach the
        classifiers as one block, after which ``emit(frame, lost)`` is called for each of them
        (``lost``: the samples lost just before it)."""
        run: list[tuple[DataFrame, int]] = []

        def flush_run() -> None:
            if run:
                block = (run[0][0].samples if len(run) == 1
                         else np.concatenate([f.samples for f, _ in run]))
                self._feed(run[0][0].first_sample, block, np.zeros(block.shape[0], bool),
                           received)
                for f, lost in run:
                    emit(f, lost)
                run.clear()

        for f in frames:
            expected = run[-1][0].end_sample if run else self.next
            lost = 0
            if expected is not None and f.first_sample != expected:
                flush_run()
                lost = self._bridge(int(f.first_sample))
            run.append((f, lost))
        flush_run()

    def _bridge(self, first: int) -> int:
        """A hole (or a reset) before stream index ``first``; returns the samples lost."""
        assert self.next is not None
        gap = first - self.next
        if 0 < gap <= self.max_fill_s * self.rate and self._last is not None:
            hold = np.broadcast_to(self._last, (gap, *self._last.shape))
            self.lost_ranges.append((self.next, first))
            self._feed(self.next, np.ascontiguousarray(hold), np.ones(gap, bool), None)
            self.lost_samples += gap
            return gap
        # too long a hole, or the indices went backwards: restart the classifiers here
        self.restart()
        if gap < 0 or gap > MAX_BRIDGED_JUMP_S * self.rate:
            self.index_resets += 1
            gap = 0
        elif gap > 0:
            self.lost_ranges.append((first - gap, first))
            self.lost_samples += gap
        self._base = self.next = first
        return gap

    def restart(self) -> None:
        """End the touches in progress and start the classifiers over."""
        for c in self.classifiers:
            self._touches(c, c.flush(), None)
            c.reset()
        self._on_restart()

    def _feed(self, first: int, block: np.ndarray, lost: np.ndarray,
              received: Optional[float]) -> None:
        # at most a second of samples at a time, each followed by on_fed(): the history holds a
        # second more than a recording needs, so a read of many seconds (a host that fell
        # behind, a large grid at a low rate) cannot overwrite a touch's samples before the
        # recorder has written them
        step = max(1, int(self.rate))
        for a in range(0, block.shape[0], step):
            self._feed_piece(first + a, block[a:a + step], lost[a:a + step], received)

    def _feed_piece(self, first: int, block: np.ndarray, lost: np.ndarray,
                    received: Optional[float]) -> None:
        if self.next is None:
            self.next = self._base = first
        self.history.append(first, block, lost)
        self.next = first + block.shape[0]
        self._last = block[-1].copy()
        flat = block.reshape(block.shape[0], -1)
        for c in self.classifiers:
            self._touches(c, c.push(flat), received)
        self._on_fed()

    def _touches(self, c: HostClassifier, touches: list[Touch], received: Optional[float]) -> None:
        for t in touches:
            self._on_touch(c, self._base + t.start, self._base + t.stop, t, received)
        if self.lost_ranges and self.next is not None:
            horizon = self.next - self.history.capacity
            self.lost_ranges = [r for r in self.lost_ranges if r[1] > horizon]

    def lost_in(self, start: int, stop: int) -> int:
        """Samples of ``[start, stop)`` that were lost (held from the previous one)."""
        return sum(max(0, min(stop, b) - max(start, a)) for a, b in self.lost_ranges)

    def flush(self) -> None:
        """End the touches in progress (the end of the stream)."""
        for c in self.classifiers:
            self._touches(c, c.flush(), None)

    @staticmethod
    def latency_us(received: Optional[float]) -> float:
        return 0.0 if received is None else (time.perf_counter() - received) * 1e6


