"""What the host receives from the controller: bytes -> checked frames -> events.

:class:`StreamReceiver` decodes the bytes (``eskin.protocol.FrameDecoder``), checks every field of
every frame (:class:`~eskin.link.frame_checks.FrameChecks`), feeds the accepted DATA frames to
the stream (:class:`~eskin.link.stream.StreamAssembler`: history, host decisions) and the
recorder (:class:`~eskin.link.recorder.StreamRecorder`), and keeps the counters of
:class:`~eskin.link.events.LinkStats`. It knows nothing of the port: :class:`LinkListener`
reads the port and hands it the bytes.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any, Optional

import numpy as np

from eskin.errors import LinkStreamError
from eskin.link.events import (
    DataBlock,
    Decision,
    InfoEvent,
    LinkEvent,
    LinkStats,
    StatusEvent,
)
from eskin.link.frame_checks import FrameChecks, GridVote, Rejection
from eskin.link.host_classifier import HostClassifier, Touch
from eskin.link.protocol import (
    PROTOCOL_VERSION,
    DataFrame,
    DecisionFrame,
    FrameDecoder,
    InfoFrame,
    PongFrame,
    StatusFrame,
    StreamState,
)
from eskin.link.recorder import StreamRecorder
from eskin.link.stream import MAX_BRIDGED_JUMP_S, StreamAssembler

__all__ = ["StreamReceiver", "unreceived_decisions", "unreceived_samples"]

MAX_HISTORY_BYTES = 256 << 20
"""The recent samples kept for the taxel activity view, at most (the ``history_s`` seconds
asked for, fewer at very high rates and grids); recording keeps what its recordings need."""
_COUNTS = ("absurd_frames", "unexpected_frames", "nonfinite_decisions", "pong_frames",
           "overrun_frames", "status_frames", "decisions_controller", "decisions_host")


def unreceived_samples(status: StatusFrame, received: int, reconnects: int,
                       known: int = 0) -> int:
    """Samples the controller sent that never arrived, from its STATUS counters: the larger of
    ``known`` (the count so far: it only grows) and what this STATUS shows.

    ``received``: samples of the DATA frames the host processed before this STATUS;
    ``reconnects``: the host's reconnections. A STATUS sent while the
    controller is not streaming (stopped, or its replay finished) follows every DATA frame it
    sent before it, so each of its ``samples_sent`` has been received or is lost, including
    the ones after the last frame that arrived (which no hole in the sample indices reveals).
    This holds when every sample it sent went to this host: when its ``connections`` are at
    most the host's connections (0: an older controller that does not say)."""
    if not _follows_everything_sent(status, reconnects):
        return known
    return max(known, status.samples_sent - received)


def unreceived_decisions(status: StatusFrame, received: int, reconnects: int,
                         known: int = 0) -> int:
    """DECISION frames the controller sent that never arrived (lost on the link, or refused
    as absurd), from its STATUS's ``decisions_sent``, under the rule of
    :func:`unreceived_samples`: a STATUS sent while the controller is not streaming follows
    every frame it sent before it, when every frame went to this host. ``received``: the
    controller's decisions the host took before this STATUS. The decisions the controller
    could not send at all are its own count, ``decisions_dropped``."""
    if not _follows_everything_sent(status, reconnects):
        return known
    return max(known, status.decisions_sent - received)


def _follows_everything_sent(status: StatusFrame, reconnects: int) -> bool:
    """Whether ``status`` follows every frame the controller sent and all of them went to this
    host: it is not streaming, and it counts 1 to 1 + ``reconnects`` connections."""
    return status.state != StreamState.STREAMING and 1 <= status.connections <= 1 + reconnects


class StreamReceiver:
    """Bytes -> events for one stream (see the module docstring); ``record_policy`` is the
    recorder's, ``replay`` the replay file the controller streams (or None)."""

    def __init__(self, *, classifier: Optional[HostClassifier],
                 recorder: Optional[StreamRecorder], record_policy: str, replay: Any,
                 max_fill_s: float, history_s: float) -> None:
        self.classifier = classifier
        self.recorder = recorder
        self.record_policy = record_policy
        self.replay = replay
        self.max_fill_s = float(max_fill_s)
        self.history_s = float(history_s)
        self.info: Optional[InfoFrame] = None
        self.last_status: Optional[StatusFrame] = None
        self.decisions: list[Decision] = []
        self.rejections: list[Rejection] = []  # the last ones (at most 100)
        self.reconnects = 0
        self._decoder = FrameDecoder()
        self._checks = FrameChecks()
        self._grid_vote = GridVote(classifier.grid if classifier is not None else None)
        self._stream: Optional[StreamAssembler] = None
        self._out: list[LinkEvent] = []  # events of the frames being processed
        self._counts = dict.fromkeys(_COUNTS, 0)
        self._received = self._unseen = self._tail = 0  # see unreceived_samples
        self._lost_decisions = 0  # see unreceived_decisions
        self._tail_reset = False

    def reopened(self) -> None:
        """The port was reopened: partial input is dropped, the counters go on."""
        self._decoder.reset(reset_stats=False)
        self.reconnects += 1

    def stats(self, elapsed_s: float, disconnects: int) -> LinkStats:
        """The statistics so far (``elapsed_s`` and ``disconnects`` are the port's)."""
        d: dict[str, Any] = self._decoder.stats.as_dict()
        s = self.last_status
        if s is not None:
            d.update(controller_samples_sent=s.samples_sent,
                     controller_dropped_samples=s.dropped_samples,
                     controller_overrun_events=s.overrun_events,
                     controller_rx_errors=s.rx_errors,
                     controller_faults_injected=s.faults_injected,
                     controller_decisions_sent=s.decisions_sent,
                     controller_decisions_dropped=s.decisions_dropped,
                     controller_frames_dropped=s.frames_dropped,
                     controller_pacing_p50_us=s.pacing_p50_ns / 1000.0,
                     controller_pacing_p99_us=s.pacing_p99_ns / 1000.0,
                     controller_state=StreamState(s.state).name.lower())
        # sample losses are counted here rather than by the decoder, whose expectations are
        # reset when the port is reopened: a hole across a reconnect is a loss too
        st = self._stream
        d["lost_samples"] = max((st.lost_samples if st else 0) + self._tail, self._unseen)
        d["sample_index_resets"] = st.index_resets if st else 0
        d["lost_decisions"] = self._lost_decisions
        d["recordings"] = self.recorder.recordings if self.recorder else 0
        d.update(elapsed_s=elapsed_s, disconnects=disconnects, reconnects=self.reconnects)
        return LinkStats(**d, **self._counts)

    def activity(self, window_s: float) -> Optional[np.ndarray]:
        """Recent energy per taxel, (rows, cols): RMS over the last ``window_s`` seconds of each
        taxel's deviation from its mean over the last second (ADC counts); None before data."""
        if self._stream is None:  # a stream holds the samples of one DATA frame at least
            return None
        h = self._stream.history
        rate = self.rate()
        ref, _ = h.get(h.end - int(rate), h.end)
        recent, _ = h.get(h.end - max(1, int(window_s * rate)), h.end)
        dev = recent.astype(np.float64) - ref.mean(axis=0)
        return np.sqrt(np.mean(dev * dev, axis=0))

    def rate(self) -> float:
        if self.info is not None:
            return float(self.info.sample_rate_hz)
        return float(self.replay.sample_rate_hz) if self.replay is not None else 3000.0

    def volts_per_count(self) -> float:
        if self.info is not None and self.info.volts_per_count > 0:
            return float(self.info.volts_per_count)
        return float(self.replay.volts_per_count) if self.replay is not None else 1.0

    def feed(self, data: bytes) -> list[LinkEvent]:
        """The events of ``data``, bytes received from the controller. Never raises for what
        the bytes hold, except :class:`~eskin.errors.LinkStreamError` when the stream cannot
        go on."""
        frames = self._decoder.feed(data)
        received = time.perf_counter()
        self._out = out = []
        data_run: list[DataFrame] = []
        for f in frames:
            # an INFO of another protocol version ends the stream (in _on_info) whatever its
            # fields say: they are laid out by another version's rules
            foreign = isinstance(f, InfoFrame) and f.protocol_version != PROTOCOL_VERSION
            problem = None if foreign else self._checks.check(f)
            if problem is None and isinstance(f, DataFrame):
                problem = self._grid_vote.check(f, self._checks.info)
            if problem is not None:
                self._reject(problem)
                continue
            if isinstance(f, DataFrame):
                if data_run and data_run[0].samples.shape[1:] != f.samples.shape[1:]:
                    self._on_data(data_run, received)  # one grid per run
                    data_run = []
                data_run.append(f)
                continue
            if data_run:
                self._on_data(data_run, received)
                data_run = []
            self._on_frame(f)
        if data_run:
            self._on_data(data_run, received)
        self._out = []
        return out

    def _reject(self, problem: Rejection) -> None:
        self._counts["absurd_frames"] += 1
        self.rejections = [*self.rejections[-99:], problem]
        self._out.append(problem)

    def _on_frame(self, f: Any) -> None:
        if isinstance(f, DecisionFrame):
            names: Sequence[str] = self.info.class_names if self.info is not None else ()
            label = str(names[f.label]) if 0 <= f.label < len(names) else None
            d = Decision("controller", f.onset_sample, f.offset_sample, label, int(f.label),
                         tuple(float(v) for v in f.values), bool(f.dont_know),
                         f.decided_sample, float(f.latency_us))
            self._counts["decisions_controller"] += 1
            self._decision(d)
        elif isinstance(f, StatusFrame):
            self.last_status = f
            self._counts["status_frames"] += 1
            self._unseen = unreceived_samples(f, self._received, self.reconnects,
                                              self._unseen)
            self._lost_decisions = unreceived_decisions(
                f, self._counts["decisions_controller"], self.reconnects, self._lost_decisions)
            self._out.append(StatusEvent(f))
        elif isinstance(f, InfoFrame):
            self._on_info(f)
        elif isinstance(f, PongFrame):
            self._counts["pong_frames"] += 1
        else:  # a host's frame (START, STOP, PING, INFO_REQUEST): controllers never send one
            self._counts["unexpected_frames"] += 1

    def _decision(self, d: Decision) -> None:
        if not all(math.isfinite(v) for v in d.values):
            self._counts["nonfinite_decisions"] += 1
        self.decisions.append(d)
        self._out.append(d)

    def _on_info(self, f: InfoFrame) -> None:
        if f.protocol_version != PROTOCOL_VERSION:
            raise LinkStreamError(
                f"INFO frame: protocol_version = {int(f.protocol_version)}: this host speaks "
                f"version {PROTOCOL_VERSION} of the eskin wire protocol and cannot read the "
                f"controller's frames (update eskin or the controller's firmware so that "
                f"they match)")
        grid = (int(f.rows), int(f.cols))
        if self.classifier is not None and tuple(self.classifier.grid) != grid:
            raise LinkStreamError(
                f"INFO frame: grid = {grid[0]}x{grid[1]}: the host model expects "
                f"{self.classifier.grid[0]}x{self.classifier.grid[1]}")
        recorded = self.recorder.grid if self.recorder is not None else None
        if recorded is not None and recorded != grid:
            raise LinkStreamError(
                f"INFO frame: grid = {grid[0]}x{grid[1]}: {self.recorder.path} is being recorded "
                f"with {recorded[0]}x{recorded[1]}")
        self.info = f
        if self._stream is not None and self._stream.grid != grid:
            self._stream.restart()  # a provisional grid (DATA before any INFO) was wrong
            self._stream = None
        elif self._stream is not None:
            self._stream.rate = self.rate()
        self._out.append(InfoEvent(f))

    def _on_data(self, frames: list[DataFrame], received: float) -> None:
        """Accepted DATA frames (all of one grid) -> DataBlocks, host decisions, recordings."""
        grid = (int(frames[0].samples.shape[1]), int(frames[0].samples.shape[2]))
        if self._stream is None or self._stream.grid != grid:
            if self._stream is not None:
                self._stream.restart()
            self._stream = self._new_stream(grid)
        self._received += sum(f.n_samples for f in frames)
        self._counts["overrun_frames"] += sum(1 for f in frames if f.overrun)
        self._stream.feed_frames(frames, received, self._emit_block)

    def _emit_block(self, f: DataFrame, lost: int) -> None:
        self._out.append(DataBlock(f.first_sample, f.samples, f.timestamp_us, f.overrun, lost))

    def _new_stream(self, grid: tuple[int, int]) -> StreamAssembler:
        rate = self.rate()
        per_sample = grid[0] * grid[1] * 2
        capacity = min(int(math.ceil(self.history_s * rate)), MAX_HISTORY_BYTES // per_sample)
        if self.recorder is not None:
            problem = self.recorder.size_problem(grid, rate)
            if problem:
                what = (f"INFO frame: sample_rate_hz = {rate:g}" if self.info is not None
                        else f"DATA frame: grid = {grid[0]}x{grid[1]}")
                raise LinkStreamError(f"{what}: cannot record this stream ({problem})")
            capacity = max(capacity, int(math.ceil(self.recorder.history_s(rate) * rate)))
        classifiers = [] if self.classifier is None else [self.classifier]
        if self.recorder is not None and self.record_policy == "touch" and not classifiers:
            try:
                classifiers.append(HostClassifier(grid, rate))  # windows to record, no labels
            except ValueError as exc:  # a rate the touch detector cannot work at
                raise LinkStreamError(f"INFO frame: sample_rate_hz = {rate:g}: cannot detect "
                                      f"touches in this stream ({exc})") from None
        return StreamAssembler(grid, rate=rate, history_capacity=capacity,
                               max_fill_s=self.max_fill_s, classifiers=classifiers,
                               on_touch=self._on_touch, on_restart=self._on_restart,
                               on_fed=self._record)

    def _on_touch(self, c: HostClassifier, start: int, stop: int, t: Touch,
                  received: Optional[float]) -> None:
        assert self._stream is not None
        if c is self.classifier:
            # the host model's classes, not the controller's
            d = Decision("host", start, stop, c.label(t), t.label_index, t.values, t.dont_know,
                         self._stream.next or stop, self._stream.latency_us(received),
                         self._stream.lost_in(start, stop))
            self._counts["decisions_host"] += 1
            self._decision(d)
        if self.recorder is not None and self.record_policy == "touch":
            name = c.label(t) if c is self.classifier and not t.dont_know else None
            self.recorder.touch(start, stop, "unknown" if name is None else name)

    def _on_restart(self) -> None:
        if self.record_policy == "touch":
            self._record(final=True)

    def _record(self, final: bool = False) -> None:
        if self.recorder is not None and self._stream is not None:
            self._out.extend(self.recorder.ready(self._stream.history, self.rate(),
                                                 self.volts_per_count(), final))

    def finish(self) -> list[LinkEvent]:
        """End the stream: count the samples sent after the last one received, end and decide
        a touch in progress, write the pending recordings."""
        self._out = out = []
        s, st = self.last_status, self._stream
        if (s is not None and s.state == StreamState.FINISHED and st is not None
                and st.next is not None and s.next_sample > st.next and not self._tail):
            tail = s.next_sample - st.next
            if tail <= MAX_BRIDGED_JUMP_S * st.rate:
                # samples produced after the last one received, which no later frame revealed
                self._tail = tail
            elif not self._tail_reset:  # more than an hour ahead: an index reset, as a jump
                self._tail_reset = True  # between two DATA frames would be, not a loss
                st.index_resets += 1
        if st is not None:
            st.flush()
            self._record(final=True)
        self._out = []
        return out
