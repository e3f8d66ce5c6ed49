"""What the live page shows, kept apart from the listener's loop.

:meth:`LiveState.observe` runs in the listener's thread, once per event, and only appends to
bounded deques (it never waits, never computes: a DATA block is a reference appended, the
oldest one falls out when the page's side is behind). Everything else runs in the server's
thread: :meth:`LiveState.tick` drains the deques at display rate and turns the samples into one
small frame (per-taxel energy and a peak-keeping decimated trace, at most ``points_per_tick``
points of every taxel whatever the stream's rate), :meth:`LiveState.hello` gives a page that
connects (or reloads) the whole current state, and :meth:`LiveState.decisions_html` the
decisions as plain HTML for the server-rendered page.
"""

from __future__ import annotations

import html
import math
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any, Optional

import numpy as np

from eskin.link.events import Connection, DataBlock, Decision, InfoEvent, Stats

__all__ = ["LiveState"]

#: DATA blocks waiting for the server's thread, at most (a frame of 10 samples each: at 3 kSps
#: and 10 ticks a second a tick drains about 30; the oldest are dropped when it falls behind)
MAX_PENDING_BLOCKS = 4096
#: decisions a page that connects receives (all of them are scored)
RECENT_DECISIONS = 500
#: trace points kept for a page that connects (about 6 s of display at 10 Hz x 16 points)
TRACE_POINTS = 1000
#: seconds of stream time over which the per-taxel baseline (the mean ADC code) adapts
BASELINE_S = 1.0
#: seconds of stream time the heat map's energy is measured over (the terminal view's 0.2 s,
#: rounded up to whole display frames)
ENERGY_S = 0.2


def _finite(v: float, digits: int = 4) -> Optional[float]:
    return round(float(v), digits) if math.isfinite(v) else None


class LiveState:
    """The live page's state (see the module docstring).

    ``port``: shown in the header; ``replay``: the replay file the controller streams (each
    decision then carries its recording's true class and the page scores them);
    ``replay_offset``: the stream index of its first sample; ``points_per_tick``: trace points
    per taxel per display frame.
    """

    def __init__(self, port: str = "", replay: Any = None, replay_offset: int = 0,
                 points_per_tick: int = 16, max_pending_blocks: int = MAX_PENDING_BLOCKS) -> None:
        self.port = str(port)
        self.replay = replay
        self.replay_offset = int(replay_offset)
        self.points_per_tick = int(points_per_tick)
        # written by the listener's thread only (appends), drained by the server's thread
        self._blocks: deque[DataBlock] = deque(maxlen=max_pending_blocks)
        self._events: deque[Any] = deque()
        self.blocks_observed = 0  # listener's thread
        self.blocks_shown = 0  # server's thread
        # the server's thread only
        self.status = "live"
        self.summary: list[str] = []
        self.info: Optional[dict[str, Any]] = None
        self.stats: Optional[dict[str, Any]] = None
        self.connection: Optional[dict[str, str]] = None
        self.decisions: deque[dict[str, Any]] = deque(maxlen=RECENT_DECISIONS)
        self.n_decisions = 0
        self.accuracy: dict[str, dict[str, int]] = {}
        self.energy: Optional[list[float]] = None
        self.trace: deque[tuple[int, list[float]]] = deque(maxlen=TRACE_POINTS)
        self.end_sample = 0
        self._grid: Optional[tuple[int, int]] = None
        self._baseline: Optional[np.ndarray] = None
        self._energy_parts: deque[tuple[int, np.ndarray]] = deque()  # (samples, sum of squares)

    # -- the listener's thread -------------------------------------------------------------
    def observe(self, ev: Any) -> None:
        """Take one listener event (never blocks: appends a reference)."""
        if isinstance(ev, DataBlock):
            self._blocks.append(ev)
            self.blocks_observed += 1
        elif isinstance(ev, (Decision, InfoEvent, Stats, Connection)):
            self._events.append(ev)

    def observe_stats(self, stats: Any) -> None:
        """Take the link statistics (a :class:`~eskin.link.events.LinkStats`)."""
        self._events.append(Stats(stats))

    def observed(self, events: Any, stats: Optional[Callable[[], Any]] = None,
                 every_s: float = 0.5) -> Iterator[Any]:
        """Pass the listener's events on, observing each one; ``stats()`` (the listener's
        statistics) is observed every ``every_s`` seconds too."""
        t_stats = time.monotonic()
        for ev in events:
            self.observe(ev)
            if stats is not None:
                now = time.monotonic()
                if now - t_stats >= every_s:
                    t_stats = now
                    self.observe_stats(stats())
            yield ev

    @property
    def blocks_dropped(self) -> int:
        """DATA blocks the page never saw (the server's side was behind)."""
        return self.blocks_observed - self.blocks_shown - len(self._blocks)

    # -- the server's thread ---------------------------------------------------------------
    def rate(self) -> float:
        if self.info is not None:
            return float(self.info["rate"])
        return float(self.replay.sample_rate_hz) if self.replay is not None else 3000.0

    def tick(self) -> list[dict[str, Any]]:
        """Drain what the listener observed since the last tick: the messages for the pages
        (events first, then at most one display frame)."""
        out: list[dict[str, Any]] = []
        while self._events:
            msg = self._event(self._events.popleft())
            if msg is not None:
                out.append(msg)
        blocks = []
        while self._blocks:
            blocks.append(self._blocks.popleft())
        self.blocks_shown += len(blocks)
        frame = self._frame(blocks)
        if frame is not None:
            out.append(frame)
        return out

    def _event(self, ev: Any) -> Optional[dict[str, Any]]:
        if isinstance(ev, Decision):
            d = self._decision(ev)
            return {"type": "decision", "decision": d, "accuracy": self.accuracy}
        if isinstance(ev, InfoEvent):
            i = ev.info
            self.info = {"rows": int(i.rows), "cols": int(i.cols),
                         "rate": float(i.sample_rate_hz), "speed": float(i.speed),
                         "classes": list(i.class_names)}
            return {"type": "info", "info": self.info}
        if isinstance(ev, Stats):
            self.stats = {k: (_finite(v) if isinstance(v, float) else v)
                          for k, v in ev.stats.as_dict().items()}
            self.stats["display_blocks_dropped"] = self.blocks_dropped
            return {"type": "stats", "stats": self.stats}
        if isinstance(ev, Connection):
            self.connection = {"state": ev.state, "path": ev.path, "reason": ev.reason}
            return {"type": "connection", "connection": self.connection}
        return None

    def _truth(self, d: Decision) -> Optional[str]:
        from eskin.link.scoring import segment_of

        if self.replay is None:
            return None
        k = segment_of(self.replay, d.onset_sample, d.offset_sample, self.replay_offset)
        names = list(self.replay.class_names)
        label = int(self.replay.segments["label"][k]) if k >= 0 else -1
        return names[label] if 0 <= label < len(names) else "-"

    def _decision(self, ev: Decision) -> dict[str, Any]:
        rate = self.rate()
        self.n_decisions += 1
        label = ev.label if ev.label is not None else f"#{ev.label_index}"
        true = self._truth(ev)
        right = None if true in (None, "-") else ev.label == true
        d = {"n": self.n_decisions, "source": ev.source, "onset": int(ev.onset_sample),
             "offset": int(ev.offset_sample), "onset_s": round(ev.onset_sample / rate, 3),
             "duration_ms": round(1000 * (ev.offset_sample - ev.onset_sample) / rate, 1),
             "label": label, "dont_know": bool(ev.dont_know),
             "values": [_finite(v) for v in ev.values],
             "latency_ms": round(float(ev.latency_us) / 1000, 3),
             "lost": int(ev.lost_samples), "true": true, "right": right}
        if right is not None:
            acc = self.accuracy.setdefault(ev.source, {"scored": 0, "right": 0, "dont_know": 0})
            acc["scored"] += 1
            acc["right"] += int(right)
            acc["dont_know"] += int(ev.dont_know)
        self.decisions.append(d)
        return d

    def _frame(self, blocks: list[DataBlock]) -> Optional[dict[str, Any]]:
        """One display frame from the samples of ``blocks``: the RMS deviation of every taxel
        from its slowly adapting baseline, and the decimated trace."""
        if not blocks:
            return None
        grid = blocks[-1].samples.shape[1:]
        blocks = [b for b in blocks if b.samples.shape[1:] == grid]
        x = np.concatenate([b.samples.reshape(b.samples.shape[0], -1) for b in blocks])
        idx = np.concatenate([np.arange(b.first_sample, b.end_sample) for b in blocks])
        x = x.astype(np.float64)
        if self._grid != tuple(grid) or self._baseline is None:
            self._grid = (int(grid[0]), int(grid[1]))
            self._baseline = x.mean(axis=0)
            self.trace.clear()
            self._energy_parts.clear()
        a = 1.0 - math.exp(-len(x) / (self.rate() * BASELINE_S))
        self._baseline += a * (x.mean(axis=0) - self._baseline)
        dev = x - self._baseline
        self.energy = self._energy(dev)
        points = self._decimate(idx, dev)
        self.trace.extend(points)
        self.end_sample = int(blocks[-1].end_sample)
        return {"type": "frame", "grid": list(self._grid), "end_sample": self.end_sample,
                "energy": self.energy, "trace": [[s, v] for s, v in points]}

    def _energy(self, dev: np.ndarray) -> list[float]:
        """RMS of every taxel's deviation over the last ENERGY_S seconds of samples received
        (these and the frames before them)."""
        self._energy_parts.append((len(dev), np.sum(dev * dev, axis=0)))
        want = ENERGY_S * self.rate()
        while (len(self._energy_parts) > 1
               and sum(n for n, _ in self._energy_parts) - self._energy_parts[0][0] >= want):
            self._energy_parts.popleft()
        n = sum(k for k, _ in self._energy_parts)
        total = sum(sq for _, sq in self._energy_parts)
        return [round(float(v), 1) for v in np.sqrt(total / n)]

    def _decimate(self, idx: np.ndarray, dev: np.ndarray) -> list[tuple[int, list[float]]]:
        """At most ``points_per_tick`` points: per bin of samples, every taxel's deviation of
        largest magnitude (so a short burst is not averaged away), at the bin's middle."""
        n = len(idx)
        bins = np.array_split(np.arange(n), min(n, self.points_per_tick))
        out = []
        for b in bins:
            seg = dev[b]
            k = np.argmax(np.abs(seg), axis=0)
            peak = seg[k, np.arange(seg.shape[1])]
            out.append((int(idx[b[len(b) // 2]]), [round(float(v), 1) for v in peak]))
        return out

    def stopped(self, summary: Optional[list[str]] = None) -> dict[str, Any]:
        """The listener has stopped: the message saying so (with the final summary lines)."""
        self.status = "stopped"
        self.summary = list(summary or [])
        return {"type": "stopped", "summary": self.summary, "stats": self.stats,
                "accuracy": self.accuracy}

    def hello(self) -> dict[str, Any]:
        """Everything a page that connects needs to show the running stream."""
        return {"type": "hello", "status": self.status, "port": self.port, "info": self.info,
                "stats": self.stats, "connection": self.connection,
                "decisions": list(self.decisions), "n_decisions": self.n_decisions,
                "accuracy": self.accuracy, "grid": list(self._grid) if self._grid else None,
                "energy": self.energy, "end_sample": self.end_sample,
                "trace": [[s, v] for s, v in self.trace], "summary": self.summary,
                "has_truth": self.replay is not None}

    def decisions_html(self) -> str:
        """The decisions so far as table rows (newest first), for the server-rendered page."""
        return "\n".join(decision_row(d) for d in reversed(self.decisions))


def decision_row(d: dict[str, Any]) -> str:
    """One decision as an HTML table row (the page's script builds the same rows)."""
    e = html.escape
    label = e(str(d["label"])) + (' <span class="dk">(don\'t know)</span>'
                                  if d["dont_know"] else "")
    true = "" if d["true"] is None else e(str(d["true"]))
    mark = {True: "right", False: "wrong", None: ""}[d["right"]]
    values = ", ".join("-" if v is None else f"{v:+.3f}" for v in d["values"])
    return (f'<tr class="{mark}" data-n="{d["n"]}"><td>{d["n"]}</td><td>{e(d["source"])}</td>'
            f'<td>{d["onset_s"]:.2f} s</td><td>{d["duration_ms"]:.0f} ms</td>'
            f'<td class="label">{label}</td><td>{true}</td><td>{d["latency_ms"]:.2f} ms</td>'
            f'<td class="values">{e(values)}</td><td>{d["lost"] or ""}</td></tr>')
