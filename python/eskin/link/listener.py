"""The host side of the serial link: the controller's live stream as typed events.

:class:`LinkListener` opens the port (``eskin.serial_port.SerialPort``), sends START and
INFO_REQUEST, decodes the frames (``eskin.protocol.FrameDecoder``) and yields events::

    with LinkListener("/dev/pts/3", model="model.eskin", record="live.h5") as link:
        for ev in link.events(until_eof=True):
            if isinstance(ev, Decision):
                print(ev.source, ev.onset_sample, ev.label)
        print(link.stats.lost_samples)

Events, in arrival order:

* :class:`DataBlock` - consecutive samples of every taxel (int16 ADC codes, ``(n, rows, cols)``),
  with their stream index and how many samples were lost just before them;
* :class:`Decision` - a decision on one touch, ``source="controller"`` (a DECISION frame) or
  ``source="host"`` (this host's own streaming classifier, when a model was given);
* :class:`StatusEvent` / :class:`InfoEvent` - the controller's STATUS and INFO frames;
* :class:`Recorded` - a recording was appended to the campaign file (``record=``);
* :class:`Connection` - :meth:`LinkListener.events` opened the port itself ("connected"), the
  peer went away ("disconnected"), or the port was reopened ("reconnected");
* :class:`Stats` - the link statistics, every ``stats_interval`` seconds and once at the end.

Host decisions. With ``model=`` (a ``.eskin`` file, a saved TouchModel, or a loaded
``TouchModel`` / ``CompiledModel``) the host runs a streaming touch detector and classifier on the
samples it receives. It prefers the compiled path (``eskin.export.CompiledModel``: the very C++
stream classifier the controller runs), and falls back to ``eskin.preprocess.TouchDetector`` plus
the TouchModel's Python machines when the compiled core has no model support. Sample indices are
the controller's stream indices, so host and controller decisions on the same touch carry the
same onset. A hole in the indices (lost samples) of at most ``max_fill_s`` seconds is bridged by
holding the last sample, so the detector's timing stays aligned; longer holes or an index reset
restart the classifier. A decision whose window overlaps lost samples reports how many in
``Decision.lost_samples``.

Recording (``record=PATH``), one of two policies, chosen with ``record_policy``:

* ``"segment"`` (the default when ``replay=`` names the replay file the controller streams):
  one recording per replay segment, exactly the samples the controller sent for that segment
  (stream indices ``replay_offset + start`` .. ``+ length``), labelled with the segment's true
  class, with its contact interval; so a recorded replay reads back equal to its source.
* ``"touch"`` (the default otherwise): one recording per touch the host detects, from
  ``context_s`` before the touch window to ``context_s`` after it. With a model the label is the
  host's decision (not ground truth; the file's ``labels`` attribute says so) and an ``unknown``
  class is added for don't-know decisions; without a model every recording is ``unknown``.

Either way the per-recording extra fields ``stream_start`` (stream index of sample 0) and
``lost_samples`` (samples inside the recording that never arrived and were held from the previous
one) are written, and the file is complete (renamed into place) when the listener closes.

Link statistics (:class:`LinkStats`) count everything the link lost or rejected: bytes, frames,
CRC errors, malformed and oversize blocks, sequence gaps and lost frames, lost samples, sample
index resets, DATA frames flagged OVERRUN, and the controller's own counters from its last STATUS
(dropped samples, overrun events, rx errors, injected faults). Lost samples are the holes in the
DATA indices, reconciled with the controller's count at every STATUS it sends while not streaming
(on STOP, at the end of its replay, on exit): then ``samples_sent`` minus the samples received
are lost too, also those after the last frame that arrived (docs/wire-protocol.md, "Host
rules").
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from eskin.link.protocol import (
    CommandFrame,
    DataFrame,
    DecisionFrame,
    DecoderStats,
    FrameDecoder,
    FrameType,
    InfoFrame,
    StatusFrame,
    StreamState,
    encode_frame,
)
from eskin.link.serial_port import PeerClosedError, SerialPort, SerialPortError

__all__ = [
    "Connection",
    "DataBlock",
    "Decision",
    "HostClassifier",
    "InfoEvent",
    "LinkEvent",
    "LinkListener",
    "LinkStats",
    "Recorded",
    "Stats",
    "StatusEvent",
    "load_host_classifier",
]

RECORD_POLICIES = ("touch", "segment")


# --------------------------------------------------------------------------- events


@dataclass(frozen=True, eq=False)
class DataBlock:
    """Consecutive samples as received: int16 ``(n, rows, cols)``, stream indices
    ``first_sample`` .. ``first_sample + n``; ``lost_before`` samples were lost just before."""

    first_sample: int
    samples: np.ndarray
    timestamp_us: int = 0
    overrun: bool = False
    lost_before: int = 0

    @property
    def end_sample(self) -> int:
        return self.first_sample + int(self.samples.shape[0])


@dataclass(frozen=True)
class Decision:
    """A decision on one touch, from the controller (a DECISION frame) or from this host.

    ``onset_sample``/``offset_sample``: the touch window ``[onset, offset)`` in stream indices;
    ``label``: a class name (None when the class is unknown, e.g. no INFO yet); ``label_index``
    indexes the class names (-1: none); ``values``: one decision value per binary machine;
    ``dont_know``: no machine or several machines claimed the touch. ``latency_us``: for the
    controller, its reported latency; for the host, the time from receiving the frame that ended
    the touch to the decision. ``lost_samples``: host only, samples of the window that were lost.
    """

    source: str
    onset_sample: int
    offset_sample: int
    label: Optional[str]
    label_index: int
    values: tuple[float, ...]
    dont_know: bool = False
    decided_sample: int = 0
    latency_us: float = 0.0
    lost_samples: int = 0

    def as_dict(self) -> dict[str, Any]:
        """The JSON object ``eskin listen --jsonl`` writes for this decision."""
        return {
            "type": "decision",
            "source": self.source,
            "onset_sample": int(self.onset_sample),
            "offset_sample": int(self.offset_sample),
            "decided_sample": int(self.decided_sample),
            "label": self.label,
            "label_index": int(self.label_index),
            "values": [float(v) for v in self.values],
            "dont_know": bool(self.dont_know),
            "latency_us": float(self.latency_us),
            "lost_samples": int(self.lost_samples),
        }


@dataclass(frozen=True)
class StatusEvent:
    status: StatusFrame


@dataclass(frozen=True)
class InfoEvent:
    info: InfoFrame


@dataclass(frozen=True)
class Recorded:
    """Recording ``index`` of the campaign file: stream samples ``[start, stop)``."""

    index: int
    start: int
    stop: int
    label: str
    lost_samples: int = 0


@dataclass(frozen=True)
class Connection:
    """``state``: "connected", "disconnected" (the peer closed the port) or "reconnected"."""

    state: str
    path: str
    reason: str = ""


@dataclass(frozen=True)
class LinkStats(DecoderStats):
    """Everything counted on the link (see the module docstring).

    The decoder counters inherited from :class:`DecoderStats` (``bytes`` ..
    ``sample_index_resets``, and ``rejected``) are this host's; the ``controller_*`` ones are
    the controller's cumulative counters from its last STATUS.
    """

    elapsed_s: float = 0.0
    overrun_frames: int = 0
    status_frames: int = 0
    decisions_controller: int = 0
    decisions_host: int = 0
    recordings: int = 0
    disconnects: int = 0
    reconnects: int = 0
    controller_samples_sent: int = 0
    controller_dropped_samples: int = 0
    controller_overrun_events: int = 0
    controller_rx_errors: int = 0
    controller_faults_injected: int = 0
    controller_decisions_sent: int = 0
    controller_pacing_p50_us: float = 0.0
    controller_pacing_p99_us: float = 0.0
    controller_state: str = "unknown"

    @property
    def rate_samples_per_s(self) -> float:
        return self.samples / self.elapsed_s if self.elapsed_s > 0 else 0.0

    def as_dict(self) -> dict[str, Any]:  # type: ignore[override]
        d: dict[str, Any] = dataclasses.asdict(self)
        d["rejected"] = self.rejected
        return d


@dataclass(frozen=True)
class Stats:
    stats: LinkStats


LinkEvent = Union[DataBlock, Decision, StatusEvent, InfoEvent, Recorded, Connection, Stats]


# --------------------------------------------------------------------------- host classifiers


@dataclass(frozen=True)
class _Touch:
    """A touch found by a host classifier, in its own sample count (from its last reset)."""

    start: int
    stop: int
    label_index: int = -1
    values: tuple[float, ...] = ()
    dont_know: bool = False


class HostClassifier:
    """A streaming touch detector (+ classifier) fed with int16 samples ``(n, n_taxels)``.

    ``push`` returns the touches completed by the samples, with their windows in samples since
    the last ``reset``; ``flush`` ends a touch in progress. ``class_names`` is empty for a bare
    detector (windows only, ``label_index`` -1).
    """

    kind = "detector"

    def __init__(self, grid: tuple[int, int], sample_rate_hz: float = 3000.0,
                 config: Any = None) -> None:
        from eskin.signal.preprocess import TouchDetector

        self.grid = (int(grid[0]), int(grid[1]))
        self.class_names: list[str] = []
        self.sample_rate_hz = float(sample_rate_hz)
        self._det = TouchDetector(self.grid, self.sample_rate_hz, config)

    def push(self, samples: np.ndarray) -> list[_Touch]:
        return [_Touch(w.start, w.stop) for w in self._det.push(samples)]

    def flush(self) -> list[_Touch]:
        return [_Touch(w.start, w.stop) for w in self._det.flush()]

    def reset(self) -> None:
        self._det.reset()


class _PythonModelClassifier(HostClassifier):
    """eskin.preprocess.TouchDetector + a TouchModel's Python machines."""

    kind = "python"

    def __init__(self, model: Any) -> None:
        from eskin.signal.preprocess import TouchDetector

        self.model = model
        self.grid = (int(model.grid_shape[0]), int(model.grid_shape[1]))
        self.class_names = [str(c) for c in model.classes]
        self.sample_rate_hz = float(model.sample_rate_hz)
        self._det = TouchDetector(self.grid, self.sample_rate_hz, model.window_config,
                                  D=int(model.D), subsample=str(model.subsample))

    def _classify(self, windows: list) -> list[_Touch]:
        out = []
        for w in windows:
            pred, F, dk = self.model.predict_indices(np.asarray(w.tensor)[None])
            values = tuple(float(v) for v in np.atleast_1d(np.asarray(F)[0]))
            out.append(_Touch(w.start, w.stop, int(pred[0]), values, bool(dk[0])))
        return out

    def push(self, samples: np.ndarray) -> list[_Touch]:
        return self._classify(self._det.push(samples))

    def flush(self) -> list[_Touch]:
        return self._classify(self._det.flush())


class _CompiledClassifier(HostClassifier):
    """The C++ stream classifier of eskin.export.CompiledModel (what the controller runs)."""

    kind = "compiled"

    def __init__(self, compiled: Any) -> None:
        from eskin import _core

        self.compiled = compiled
        self.grid = tuple(int(v) for v in compiled.grid_shape)  # type: ignore[assignment]
        self.class_names = [str(c) for c in compiled.class_names]
        self.sample_rate_hz = float(compiled.sample_rate_hz)
        self._sc = _core.StreamClassifier(compiled._model)

    def _events(self, events: list) -> list[_Touch]:
        out = []
        for e in events:
            if "label" not in e:
                continue  # an error status: the touch was dropped by the classifier
            start, stop = (int(v) for v in e["window"])
            out.append(_Touch(start, stop, int(e["label"]),
                              tuple(float(v) for v in e["values"]), bool(e["dont_know"])))
        return out

    def push(self, samples: np.ndarray) -> list[_Touch]:
        x = np.ascontiguousarray(samples.reshape(samples.shape[0], -1), dtype=np.float64)
        return self._events(self._sc.feed(x, False))

    def flush(self) -> list[_Touch]:
        k = self.grid[0] * self.grid[1]
        return self._events(self._sc.feed(np.zeros((0, k)), True))

    def reset(self) -> None:
        self._sc.reset()


def load_host_classifier(model: Any, backend: str = "auto") -> HostClassifier:
    """A host classifier from a model file path, a TouchModel or a CompiledModel.

    ``backend``: "compiled" (the C++ stream classifier; needs eskin.export), "python"
    (TouchDetector + the TouchModel's machines) or "auto" (compiled when available).
    """
    if backend not in ("auto", "compiled", "python"):
        raise ValueError(f"backend must be 'auto', 'compiled' or 'python', got {backend!r}")
    if isinstance(model, HostClassifier):
        return model
    try:
        from eskin.deploy.export import CompiledModel
    except ImportError:
        CompiledModel = None  # type: ignore[assignment,misc]
    if isinstance(model, (str, os.PathLike)):
        path = Path(model)
        if not path.is_file():
            raise FileNotFoundError(f"model file {path} does not exist")
        if path.suffix.lower() == ".eskin" and CompiledModel is not None and backend != "python":
            return _CompiledClassifier(CompiledModel(path))
        from eskin.deploy import load_model

        model = load_model(path)
    if CompiledModel is not None and isinstance(model, CompiledModel):
        if backend == "python":
            raise ValueError("a compiled .eskin model runs on the compiled backend only")
        return _CompiledClassifier(model)
    for attr in ("classes", "estimator", "D", "grid_shape"):
        if not hasattr(model, attr):
            raise ValueError(
                f"model must be a model file, a TouchModel or a CompiledModel, not "
                f"{type(model).__name__}"
            )
    if backend != "python" and CompiledModel is not None:
        compiled = getattr(getattr(model, "estimator", None), "compiled", None)
        if compiled is not None:  # a .eskin file loaded as a TouchModel
            return _CompiledClassifier(compiled)
        try:
            return _CompiledClassifier(CompiledModel.from_model(model))
        except (ValueError, TypeError, AttributeError):
            if backend == "compiled":
                raise
    elif backend == "compiled":
        raise RuntimeError("the compiled backend needs eskin.export (not available)")
    return _PythonModelClassifier(model)


# --------------------------------------------------------------------------- sample history


class _History:
    """The last ``capacity`` samples by stream index, with a mask of the ones that were lost."""

    def __init__(self, capacity: int, grid: tuple[int, int]) -> None:
        self.capacity = int(capacity)
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


# --------------------------------------------------------------------------- the listener


def unreceived_samples(status: StatusFrame, received: int, counts: dict[str, int],
                       known: int = 0) -> int:
    """Samples the controller sent that never arrived, from its STATUS counters: the larger of
    ``known`` (the count so far: it only grows) and what this STATUS shows.

    ``received``: samples of the DATA frames the host processed before this STATUS;
    ``counts["reconnects"]``: the host's reconnections. A STATUS sent while the
    controller is not streaming (stopped, or its replay finished) follows every DATA frame it
    sent before it, so each of its ``samples_sent`` has been received or is lost, including
    the ones after the last frame that arrived (which no hole in the sample indices reveals).
    This holds when every sample it sent went to this host: when its ``connections`` are at
    most the host's connections (0: an older controller that does not say)."""
    sessions = 1 + counts["reconnects"]
    if status.state == StreamState.STREAMING or not 1 <= status.connections <= sessions:
        return known
    return max(known, status.samples_sent - received)


def _checked_options(record_policy: Optional[str], replay: Any, read_timeout: float,
                     **non_negative: float) -> str:
    """LinkListener's options, checked; returns the recording policy (default: one recording
    per replay segment with a replay file, else one per detected touch)."""
    if record_policy is None:
        record_policy = "segment" if replay is not None else "touch"
    if record_policy not in RECORD_POLICIES:
        raise ValueError(
            f"record_policy must be one of {RECORD_POLICIES}, got {record_policy!r}")
    if record_policy == "segment" and replay is None:
        raise ValueError("record_policy='segment' needs the replay file (replay=...)")
    for name, v in non_negative.items():
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {v}")
    if not (read_timeout > 0):
        raise ValueError(f"read_timeout must be > 0, got {read_timeout}")
    return record_policy


class _FrameEvents:
    """Decoding: the received bytes -> frames -> the listener's events (a part of
    :class:`LinkListener`, which holds the state)."""

    # -- frames -> events ------------------------------------------------------------------
    def _process(self, chunk: bytes) -> list[LinkEvent]:
        out: list[LinkEvent] = []
        frames = self._decoder.feed(chunk)
        received = time.perf_counter()
        i = 0
        while i < len(frames):
            f = frames[i]
            if isinstance(f, DataFrame):
                j = i
                while j < len(frames) and isinstance(frames[j], DataFrame):
                    j += 1
                self._received += sum(int(fr.samples.shape[0]) for fr in frames[i:j])
                out += self._on_data(frames[i:j], received)
                i = j
                continue
            if isinstance(f, DecisionFrame):
                out.append(self._on_controller_decision(f))
            elif isinstance(f, StatusFrame):
                self.last_status = f
                self._counts["status_frames"] += 1
                self._unseen = unreceived_samples(f, self._received, self._counts, self._unseen)
                out.append(StatusEvent(f))
            elif isinstance(f, InfoFrame):
                self.info = f
                out.append(InfoEvent(f))
            i += 1  # PONG: nothing to do
        return out

    def _class_name(self, index: int) -> Optional[str]:
        """A controller label's name, from its INFO (None before INFO or out of range)."""
        names: Sequence[str] = self.info.class_names if self.info is not None else ()
        return str(names[index]) if 0 <= index < len(names) else None

    def _on_controller_decision(self, f: DecisionFrame) -> Decision:
        d = Decision("controller", f.onset_sample, f.offset_sample, self._class_name(f.label),
                     int(f.label), tuple(float(v) for v in f.values), bool(f.dont_know),
                     f.decided_sample, float(f.latency_us))
        self._counts["decisions_controller"] += 1
        self.decisions.append(d)
        return d


class _HostStream:
    """The stream on the host: DATA frames -> a continuous sample stream (holes bridged or
    restarted), its history, and the host classifier's decisions (a part of
    :class:`LinkListener`, which holds the state)."""

    def _setup_stream(self, grid: tuple[int, int]) -> None:
        self._grid = grid
        rate = self.info.sample_rate_hz if self.info is not None else 3000.0
        need = self.history_s
        if self.record_path is not None:
            if self.record_policy == "segment":
                segs = self.replay.segments
                longest = int(segs["length"].max()) if len(segs) else 0
                need = max(need, longest / rate + 1.0)
            else:
                need = max(need, self._max_touch_s() + 2 * self.context_s + 1.0)
        self._history = _History(int(math.ceil(need * rate)), grid)
        if self.classifier is not None and tuple(self.classifier.grid) != grid:
            raise ValueError(
                f"the controller streams a {grid[0]}x{grid[1]} grid; the host model expects "
                f"{self.classifier.grid[0]}x{self.classifier.grid[1]}"
            )
        if (self.record_path is not None and self.record_policy == "touch"
                and self.classifier is None):
            self._det = HostClassifier(grid, rate)

    def _max_touch_s(self) -> float:
        cfg = None
        c = self.classifier
        if c is not None:
            m = getattr(c, "model", None)
            cfg = getattr(m, "window_config", None) if m is not None else None
            if cfg is None and getattr(c, "compiled", None) is not None:
                cfg = c.compiled.window_config.get("max_window_s")  # type: ignore[union-attr]
                return float(cfg) if cfg is not None else 7.0
        return float(getattr(cfg, "max_window_s", 7.0) or 7.0)

    def _on_data(self, frames: list[DataFrame], received: float) -> list[LinkEvent]:
        """DATA frames -> DataBlocks; contiguous frames reach the classifier as one block."""
        out: list[LinkEvent] = []
        run: list[tuple[DataFrame, int]] = []

        def flush_run() -> None:
            if not run:
                return
            first = run[0][0].first_sample
            block = (run[0][0].samples if len(run) == 1
                     else np.concatenate([f.samples for f, _ in run]))
            self._feed(first, block, np.zeros(block.shape[0], bool), out, received)
            out.extend(DataBlock(f.first_sample, f.samples, f.timestamp_us, f.overrun, lost)
                       for f, lost in run)
            run.clear()

        for f in frames:
            if f.overrun:
                self._counts["overrun_frames"] += 1
            grid = (int(f.samples.shape[1]), int(f.samples.shape[2]))
            if self._grid is None:
                self._setup_stream(grid)
            elif grid != self._grid:
                continue  # a frame for another grid cannot be part of this stream: ignore it
            expected = run[-1][0].end_sample if run else self._next
            lost = 0
            if expected is not None and f.first_sample != expected:
                flush_run()
                if f.first_sample < expected:
                    self._index_resets += 1
                lost = self._bridge(f.first_sample, out)
                self._lost_samples += lost
            run.append((f, lost))
        flush_run()
        return out

    def _bridge(self, first: int, out: list[LinkEvent]) -> int:
        """A hole (or a reset) before stream index ``first``; returns the samples lost."""
        assert self._next is not None
        rate = self.info.sample_rate_hz if self.info is not None else 3000.0
        gap = first - self._next
        if 0 < gap <= self.max_fill_s * rate and self._last is not None:
            hold = np.broadcast_to(self._last, (gap, *self._last.shape))
            self._lost_ranges.append((self._next, first))
            self._feed(self._next, np.ascontiguousarray(hold), np.ones(gap, bool), out, None)
            return gap
        # too long a hole, or the indices went backwards: restart the host classifier here
        for c in (self.classifier, self._det):
            if c is not None:
                out.extend(self._touches(c, c.flush(), None))
                c.reset()
        if self.record_policy == "touch":
            out.extend(self._record_ready(final=True))
        self._base = first
        self._next = first
        if gap > 0:
            self._lost_ranges.append((first - gap, first))
        return max(gap, 0)

    def _feed(self, first: int, block: np.ndarray, lost: np.ndarray, out: list[LinkEvent],
              received: Optional[float]) -> None:
        if self._next is None:
            self._next = first
            self._base = first
        assert self._history is not None
        self._history.append(first, block, lost)
        self._next = first + block.shape[0]
        self._last = block[-1].copy()
        flat = block.reshape(block.shape[0], -1)
        if self.classifier is not None:
            out.extend(self._touches(self.classifier, self.classifier.push(flat), received))
        if self._det is not None:
            out.extend(self._touches(self._det, self._det.push(flat), received))
        out.extend(self._record_ready())

    def _touches(self, c: HostClassifier, touches: list[_Touch],
                 received: Optional[float]) -> list[LinkEvent]:
        out: list[LinkEvent] = []
        for t in touches:
            start, stop = self._base + t.start, self._base + t.stop
            if c is self.classifier:
                lost = sum(max(0, min(stop, b) - max(start, a)) for a, b in self._lost_ranges)
                latency = 0.0 if received is None else (time.perf_counter() - received) * 1e6
                names = c.class_names  # the host model's classes, not the controller's
                label = names[t.label_index] if 0 <= t.label_index < len(names) else None
                d = Decision("host", start, stop, label, t.label_index, t.values, t.dont_know,
                             self._next or stop, latency, lost)
                self._counts["decisions_host"] += 1
                self.decisions.append(d)
                out.append(d)
            if self.record_path is not None and self.record_policy == "touch":
                if c is self._det or (self._det is None and c is self.classifier):
                    label = "unknown"
                    if c is self.classifier and t.label_index >= 0 and not t.dont_know:
                        label = c.class_names[t.label_index]
                    self._pending_touch.append((start, stop, label))
        if self._lost_ranges and self._next is not None:
            horizon = self._next - (self._history.capacity if self._history else 0)
            self._lost_ranges = [r for r in self._lost_ranges if r[1] > horizon]
        return out

    def _end_of_stream(self) -> list[LinkEvent]:
        out: list[LinkEvent] = []
        s = self.last_status
        if (s is not None and s.state == StreamState.FINISHED and self._next is not None
                and s.next_sample > self._next and not self._tail_counted):
            # samples produced after the last one received, which no later frame revealed
            self._lost_samples += s.next_sample - self._next
            self._tail_counted = True
        for c in (self.classifier, self._det):
            if c is not None and self._history is not None:
                out.extend(self._touches(c, c.flush(), None))
        out.extend(self._record_ready(final=True))
        return out


class _StreamRecorder:
    """Recording the received stream to a campaign file, one recording per replay segment or
    per detected touch (a part of :class:`LinkListener`, which holds the state)."""

    # -- recording -------------------------------------------------------------------------
    def _open_writer(self) -> None:
        from eskin.data.campaign import CampaignWriter

        assert self.record_path is not None and self._grid is not None
        info = self.info
        rate = info.sample_rate_hz if info is not None else (
            self.replay.sample_rate_hz if self.replay is not None else 3000.0)
        vpc = info.volts_per_count if info is not None and info.volts_per_count > 0 else (
            self.replay.volts_per_count if self.replay is not None else 1.0)
        attrs: dict[str, Any] = {**self.record_attrs, "recorded_by": "eskin.link.LinkListener",
                                 "record_policy": self.record_policy, "port": self.path}
        with_contact = False
        if self.record_policy == "segment":
            names = list(self.replay.class_names) or []
            if not names or np.any(self.replay.segments["label"] < 0):
                names.append("unknown")
            n_samples = int(self.replay.segments["length"].max())
            attrs["labels"] = "true classes from the replay file"
            attrs["replay_file"] = str(self.replay.path)
            with_contact = bool(np.all(self.replay.segments["contact_onset"] >= 0))
        else:
            names = list(self.classifier.class_names) if self.classifier is not None else []
            names.append("unknown")
            n_samples = int(math.ceil((self._max_touch_s() + 2 * self.context_s) * rate)) + 1
            attrs["labels"] = ("the host's decisions (not ground truth); unknown = don't know"
                               if self.classifier is not None else "none (unknown)")
        self._with_contact = with_contact
        self._writer = CampaignWriter(
            self.record_path, grid_shape=self._grid, n_samples=n_samples, sample_rate_hz=rate,
            volts_per_count=vpc, modalities=names, source=self.record_source, attrs=attrs,
            contact_interval=with_contact, overwrite=self.overwrite,
            extra_fields={"stream_start": np.int64, "lost_samples": np.int32},
        )

    def _record_ready(self, final: bool = False) -> list[LinkEvent]:
        if self.record_path is None or self._history is None:
            return []
        out: list[LinkEvent] = []
        h = self._history
        rate = self.info.sample_rate_hz if self.info is not None else 3000.0
        if self.record_policy == "segment":
            segs = self.replay.segments
            while self._next_segment < len(segs):
                seg = segs[self._next_segment]
                start = self.replay_offset + int(seg["start"])
                stop = start + int(seg["length"])
                if h.end < stop:
                    break  # not there yet (a segment never completed is never written)
                self._next_segment += 1
                if h.begin > start:
                    continue  # not fully received: joined late, or a long hole inside it
                label = int(seg["label"])
                names = self._writer_names()
                modality = label if label >= 0 else len(names) - 1
                ci = None
                if self._with_contact:
                    ci = (int(seg["contact_onset"]), int(seg["contact_offset"]))
                out.append(self._append(start, stop, modality, ci))
        else:
            ctx = int(round(self.context_s * rate))
            keep = []
            for start, stop, label in self._pending_touch:
                a, b = start - ctx, stop + ctx
                if h.end < b and not final:
                    keep.append((start, stop, label))
                    continue
                names = self._writer_names()
                out.append(self._append(max(a, h.begin), min(b, h.end), names.index(label), None))
            self._pending_touch = keep
        return out

    def _writer_names(self) -> list[str]:
        if self._writer is None:
            self._open_writer()
        return list(self._writer.modalities)

    def _append(self, start: int, stop: int, modality: int,
                contact: Optional[tuple[int, int]]) -> Recorded:
        assert self._history is not None
        if self._writer is None:
            self._open_writer()
        samples, lost = self._history.get(start, stop)
        stop = start + samples.shape[0]
        rec = np.ascontiguousarray(np.moveaxis(samples, 0, -1))
        n_lost = int(lost.sum())
        idx = self._writer.append(
            rec, modality=modality, participant=-1, direction=255, run=0,
            contact_interval=contact, extra={"stream_start": start, "lost_samples": n_lost})
        self._counts["recordings"] += 1
        return Recorded(idx, start, stop, self._writer.modalities[modality], n_lost)


class LinkListener(_FrameEvents, _HostStream, _StreamRecorder):
    """The controller's live stream over a serial port, as events. See the module docstring.

    Parameters
    ----------
    port : the port path (e.g. the pseudo-terminal ``eskin-fw-sim`` publishes, or its ``--link``
        symlink) or an open :class:`~eskin.serial_port.SerialPort`.
    model : a model for host decisions (path, TouchModel or CompiledModel); None: no host model.
    backend : host classifier backend, "auto" | "compiled" | "python".
    record : a campaign file to record the received stream to (see ``record_policy``).
    replay : the replay file (path or :class:`eskin.replay.ReplayFile`) the controller streams:
        gives the segments for ``record_policy="segment"``; ``replay_offset`` is the stream index
        of the replay's first sample (0 for a fresh ``eskin-fw-sim``).
    reconnect : when the peer closes the port, keep trying to reopen the same path for
        ``reconnect_timeout`` seconds (a controller restarting, a USB cable replugged).
    send_start : send START and INFO_REQUEST on opening (and on every reconnect).
    max_fill_s : longest hole in the sample indices bridged by holding the last sample.
    stats_interval : seconds between :class:`Stats` events (None: only at the end).
    """

    def __init__(
        self,
        port: Union[str, os.PathLike, SerialPort],
        *,
        model: Any = None,
        backend: str = "auto",
        record: Union[str, os.PathLike, None] = None,
        record_policy: Optional[str] = None,
        replay: Any = None,
        replay_offset: int = 0,
        context_s: float = 0.5,
        overwrite: bool = False,
        record_source: str = "recorded",
        record_attrs: Optional[dict[str, Any]] = None,
        reconnect: bool = False,
        reconnect_timeout: float = 5.0,
        send_start: bool = True,
        read_timeout: float = 0.05,
        max_fill_s: float = 0.1,
        stats_interval: Optional[float] = 1.0,
        history_s: float = 2.0,
    ) -> None:
        record_policy = _checked_options(
            record_policy, replay, read_timeout, context_s=context_s, max_fill_s=max_fill_s,
            reconnect_timeout=reconnect_timeout, history_s=history_s)
        if isinstance(port, SerialPort):
            self._port: Optional[SerialPort] = port
            self.path = port.path
        else:
            self._port = None
            self.path = os.fspath(port)
        if replay is not None and not hasattr(replay, "segments"):
            from eskin.data.replay import read_replay_file

            replay = read_replay_file(replay)
        self.replay = replay
        self.replay_offset = int(replay_offset)
        self.classifier: Optional[HostClassifier] = (
            None if model is None else load_host_classifier(model, backend)
        )
        self.record_path = None if record is None else Path(record)
        self.record_policy = record_policy
        self.context_s = float(context_s)
        self.overwrite = bool(overwrite)
        self.record_source = str(record_source)
        self.record_attrs = dict(record_attrs or {})
        self.reconnect_enabled = bool(reconnect)
        self.reconnect_timeout = float(reconnect_timeout)
        self.send_start = bool(send_start)
        self.read_timeout = float(read_timeout)
        self.max_fill_s = float(max_fill_s)
        self.stats_interval = stats_interval
        self.history_s = float(history_s)

        self._init_state()

    def _init_state(self) -> None:
        """What the listener has received so far: nothing yet."""
        self.info: Optional[InfoFrame] = None
        self.last_status: Optional[StatusFrame] = None
        self.decisions: list[Decision] = []
        self._decoder = FrameDecoder()
        self._t0: Optional[float] = None
        self._counts = {"overrun_frames": 0, "status_frames": 0, "decisions_controller": 0,
                        "decisions_host": 0, "recordings": 0, "disconnects": 0, "reconnects": 0}
        self._stop = False
        self._closed = False
        # stream state
        self._grid: Optional[tuple[int, int]] = None
        self._next: Optional[int] = None  # next expected stream index
        self._last: Optional[np.ndarray] = None  # last sample (for holding over holes)
        self._base = 0  # stream index of the host classifier's sample 0
        self._lost_ranges: list[tuple[int, int]] = []
        self._lost_samples = self._received = self._unseen = 0  # see unreceived_samples
        self._tail_counted = False
        self._index_resets = 0
        self._history: Optional[_History] = None
        self._pending_touch: list[tuple[int, int, str]] = []  # (start, stop, label) to record
        self._next_segment = 0
        self._writer: Any = None
        self._with_contact = False
        self._det: Optional[HostClassifier] = None  # detector for touch recording w/o model

    # -- opening and closing ---------------------------------------------------------------
    def open(self) -> LinkListener:
        """Open the port (unless given open) and send START + INFO_REQUEST."""
        if self._port is None:
            self._port = SerialPort(self.path)
        if self._t0 is None:
            self._t0 = time.monotonic()
        if self.send_start:
            self._send_start()
        return self

    def _send_start(self) -> None:
        assert self._port is not None
        data = (b"\x00" + encode_frame(CommandFrame(FrameType.START))
                + encode_frame(CommandFrame(FrameType.INFO_REQUEST)))
        try:
            self._port.write(data, timeout=1.0)
        except PeerClosedError:
            pass  # noticed by the next read

    def send(self, command: FrameType) -> None:
        """Send a payload-less command (START, STOP, INFO_REQUEST)."""
        if self._port is None:
            raise RuntimeError("the link is not open")
        self._port.write(encode_frame(CommandFrame(command)), timeout=1.0)

    def stop(self) -> None:
        """Ask :meth:`events` to return after the current read (callable from another thread)."""
        self._stop = True

    def close(self) -> None:
        """Close the port and finish the recording file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._port is not None and self._port.is_open:
                try:
                    self._port.close()
                except SerialPortError:
                    pass
        finally:
            if self._writer is not None:
                self._writer.close()

    def __enter__(self) -> LinkListener:
        return self.open()

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        # the recording is finished even after an error or Ctrl-C: what was received is kept
        self.close()

    def reconnect(self) -> Connection:
        """Close the port and open it again (the controller keeps its stream going)."""
        if self._port is not None:
            try:
                self._port.close()
            except SerialPortError:
                pass
        self._port = SerialPort(self.path)
        self._decoder.reset(reset_stats=False)
        self._counts["reconnects"] += 1
        if self.send_start:
            self._send_start()
        return Connection("reconnected", self.path, "reopened by the host")

    # -- statistics ------------------------------------------------------------------------
    @property
    def stats(self) -> LinkStats:
        d = self._decoder.stats.as_dict()
        s = self.last_status
        ctrl: dict[str, Any] = {}
        if s is not None:
            ctrl = {
                "controller_samples_sent": s.samples_sent,
                "controller_dropped_samples": s.dropped_samples,
                "controller_overrun_events": s.overrun_events,
                "controller_rx_errors": s.rx_errors,
                "controller_faults_injected": s.faults_injected,
                "controller_decisions_sent": s.decisions_sent,
                "controller_pacing_p50_us": s.pacing_p50_ns / 1000.0,
                "controller_pacing_p99_us": s.pacing_p99_ns / 1000.0,
                "controller_state": StreamState(s.state).name.lower(),
            }
        elapsed = 0.0 if self._t0 is None else time.monotonic() - self._t0
        # sample losses are counted here rather than by the decoder, whose expectations are
        # reset when the port is reopened: a hole across a reconnect is a loss too
        d["lost_samples"] = max(self._lost_samples, self._unseen)
        d["sample_index_resets"] = self._index_resets
        return LinkStats(elapsed_s=elapsed, **d, **self._counts, **ctrl)

    # -- taxel activity --------------------------------------------------------------------
    def activity(self, window_s: float = 0.2) -> Optional[np.ndarray]:
        """Recent energy per taxel, (rows, cols): RMS over the last ``window_s`` seconds of each
        taxel's deviation from its mean over the last second (ADC counts); None before data."""
        h = self._history
        if h is None or h.end == h.begin:
            return None
        rate = self.info.sample_rate_hz if self.info is not None else 3000.0
        ref, _ = h.get(h.end - int(rate), h.end)
        recent, _ = h.get(h.end - max(1, int(window_s * rate)), h.end)
        base = ref.mean(axis=0)
        dev = recent.astype(np.float64) - base
        return np.sqrt(np.mean(dev * dev, axis=0))

    # -- the event loop --------------------------------------------------------------------
    def events(self, *, duration: Optional[float] = None, until_eof: bool = False,
               eof_grace_s: float = 0.3, flush: bool = True) -> Iterator[LinkEvent]:
        """Yield events until ``duration`` seconds passed, or (``until_eof``) the controller
        reported the end of its replay (STATUS state FINISHED) and ``eof_grace_s`` more seconds
        passed, or the peer closed the port (and could not be reopened), or :meth:`stop`.

        At the end, with ``flush`` (the default), a touch in progress is ended and decided and
        pending touch recordings are written with what was received; pass ``flush=False`` to
        call :meth:`events` again later on the same stream. The last event is :class:`Stats`."""
        if self._port is None:
            self.open()
            yield Connection("connected", self.path)
        t_start = time.monotonic()
        t_stats = t_start
        finished_at: Optional[float] = None
        try:
            while not self._stop:
                now = time.monotonic()
                if duration is not None and now - t_start >= duration:
                    break
                if finished_at is not None and now - finished_at >= eof_grace_s:
                    break
                try:
                    assert self._port is not None
                    chunk = self._port.read(65536, timeout=self.read_timeout)
                except PeerClosedError as exc:
                    self._counts["disconnects"] += 1
                    yield Connection("disconnected", self.path, str(exc))
                    conn = self._try_reconnect() if self.reconnect_enabled else None
                    if conn is None:
                        break
                    yield conn
                    continue
                if chunk:
                    for ev in self._process(chunk):
                        if (until_eof and finished_at is None and isinstance(ev, StatusEvent)
                                and ev.status.state == StreamState.FINISHED):
                            finished_at = time.monotonic()
                        yield ev
                if self.stats_interval is not None and now - t_stats >= self.stats_interval:
                    t_stats = now
                    yield Stats(self.stats)
            if flush:
                for ev in self._end_of_stream():
                    yield ev
            yield Stats(self.stats)
        finally:
            self._stop = False

    def __iter__(self) -> Iterator[LinkEvent]:
        return self.events()

    def _try_reconnect(self) -> Optional[Connection]:
        deadline = time.monotonic() + self.reconnect_timeout
        if self._port is not None:
            try:
                self._port.close()
            except SerialPortError:
                pass
        while time.monotonic() < deadline and not self._stop:
            try:
                self._port = SerialPort(self.path)
            except SerialPortError:
                time.sleep(0.05)
                continue
            self._decoder.reset(reset_stats=False)
            self._counts["reconnects"] += 1
            if self.send_start:
                self._send_start()
            return Connection("reconnected", self.path, "port reopened after the peer closed")
        return None














