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
* :class:`Rejection` - a frame sound on the wire (COBS, CRC-32, layout) but with a field no
  controller sends (a sample index of 2^63, a rate of NaN, a grid unlike the stream's, a class
  index past the controller's class names): counted in ``absurd_frames`` and left out
  (:mod:`eskin.link.frame_checks`); a frame only a host sends (START, STOP, PING,
  INFO_REQUEST) is counted in ``unexpected_frames`` and left out; a frame the stream cannot go
  on after (an INFO of another protocol version, an INFO grid the host model cannot take)
  ends :meth:`LinkListener.events` with :class:`~eskin.errors.LinkStreamError` after the
  final :class:`Stats`;
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
one) are written, and the file is complete (renamed into place) when the listener closes. The
recordings do not depend on how the bytes arrive: a read of many seconds (a host that fell
behind) enters the history a second at a time, each second followed by the recordings it
completes; a touch still waiting for its context when the stream restarts (an index reset, a
long hole, another grid) is written with what arrived, as at the end of the stream.

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

import math
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from eskin.errors import LinkStreamError
from eskin.link.events import (
    Connection,
    DataBlock,
    Decision,
    InfoEvent,
    LinkEvent,
    LinkStats,
    Recorded,
    Rejection,
    Stats,
    StatusEvent,
)
from eskin.link.host_classifier import HostClassifier, load_host_classifier, max_touch_s
from eskin.link.protocol import (
    CommandFrame,
    FrameType,
    InfoFrame,
    StatusFrame,
    StreamState,
    encode_frame,
)
from eskin.link.recorder import StreamRecorder
from eskin.link.serial_port import PeerClosedError, SerialPort, SerialPortError
from eskin.link.receiver import StreamReceiver, unreceived_samples

__all__ = [
    "Connection",
    "DataBlock",
    "Decision",
    "HostClassifier",
    "InfoEvent",
    "LinkEvent",
    "LinkListener",
    "LinkStats",
    "LinkStreamError",
    "Recorded",
    "Rejection",
    "Stats",
    "StatusEvent",
    "load_host_classifier",
    "unreceived_samples",
]

RECORD_POLICIES = ("touch", "segment")

#: A read that returns fewer bytes than this is a trickle (a port that writes a byte at a time,
#: such as QEMU's UART on a pseudo-terminal): the port's reading thread then waits
#: TRICKLE_WAIT_S before the next read, so that it takes the stream in chunks instead of waking
#: for every few bytes (at 3 kSps of a 4 x 4 patch, 105 kB/s, a 4 ms wait gathers about 420
#: bytes, far inside the pty's 4 KiB line buffer). Waking for each cost the host a third of a
#: core, which the emulated board needed.
TRICKLE_BYTES = 2048
TRICKLE_WAIT_S = 0.004
#: Bytes the port's reading thread holds for the listener's loop, at most: the loop (decoding,
#: host decisions, recording, a live page's observer) may fall behind by this much (a minute of
#: a 4 x 4 patch at 10 times its 3 kSps) and catch up without a sample lost.
READ_QUEUE_BYTES = 64 << 20
#: The port's reading thread runs under the real-time policy SCHED_FIFO at this priority (the
#: lowest), where the system allows it (root, CAP_SYS_NICE, an RLIMIT_RTPRIO): on a loaded
#: machine an ordinary thread waits for the processor up to tens of milliseconds after its
#: bytes arrive (61 ms measured on 2 cores at a load of 14, with a browser drawing the live
#: page), longer than the driver's and the controller's buffers hold a fast stream (35 ms at
#: 10x); a real-time one runs at once. It does nothing but move bytes, bounded by what arrives.
READER_REALTIME_PRIORITY = 1


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


def _file_recorder(listener: "LinkListener", policy: str, *, context_s: float, overwrite: bool,
                   source: str, attrs: Optional[dict[str, Any]]) -> StreamRecorder:
    """The recorder of ``record=``: the listener's stream into that campaign file."""
    clf = listener.classifier
    return StreamRecorder(
        listener.record_path, policy=policy, replay=listener.replay,
        replay_offset=listener.replay_offset, context_s=float(context_s),
        overwrite=bool(overwrite), source=str(source), attrs=dict(attrs or {}),
        port=listener.path, host_names=list(clf.class_names) if clf else [],
        max_touch_s=max_touch_s(clf))


class LinkListener:
    """The controller's live stream over a serial port, as events. See the module docstring.

    It holds the port; what arrives goes to collaborators, each with its own state:
    :class:`~eskin.link.receiver.StreamReceiver` (bytes -> checked frames -> events, the counters),
    which feeds :class:`~eskin.link.stream.StreamAssembler` (the continuous stream, its
    history, the host's touches) and :class:`~eskin.link.recorder.StreamRecorder` (the
    campaign file).

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
    recorder : instead of ``record``, a :class:`~eskin.link.recorder.StreamRecorder` made by
        the caller (a skin's patches record into one campaign through theirs); its policy
        must be ``record_policy``'s.
    read_queue_bytes : the most bytes the port's reading thread holds for the loop (0: no
        reading thread, the loop reads the port itself, as a baseline for benchmarks).
    reader_priority : the reading thread's SCHED_FIFO priority where the system allows it
        (:data:`READER_REALTIME_PRIORITY`; 0: the ordinary policy, as a baseline).
    """

    # long: the constructor's parameters, each stored once
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
        recorder: Optional[StreamRecorder] = None,
        read_queue_bytes: int = READ_QUEUE_BYTES,
        reader_priority: int = READER_REALTIME_PRIORITY,
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
            None if model is None else load_host_classifier(model, backend))
        self.record_path = None if record is None else Path(record)
        self.record_policy = record_policy
        self.reconnect_enabled, self.reconnect_timeout = bool(reconnect), float(reconnect_timeout)
        self.send_start = bool(send_start)
        self.read_timeout = float(read_timeout)
        self.max_fill_s = float(max_fill_s)
        self.stats_interval = stats_interval
        self.history_s = float(history_s)
        self.recorder: Optional[StreamRecorder] = recorder
        if recorder is not None and self.record_path is not None:
            raise ValueError("give record= (a campaign file) or recorder=, not both")
        self.read_queue_bytes, self.reader_priority = int(read_queue_bytes), int(reader_priority)
        if self.record_path is not None:
            self.recorder = _file_recorder(self, record_policy, context_s=context_s,
                                           overwrite=overwrite, source=record_source,
                                           attrs=record_attrs)
        self.receiver = StreamReceiver(classifier=self.classifier, recorder=self.recorder,
                                   record_policy=record_policy, replay=replay,
                                   max_fill_s=self.max_fill_s, history_s=self.history_s)
        self._t0: Optional[float] = None
        self._disconnects = 0
        self._stop = False
        self._closed = False

    # -- opening and closing ---------------------------------------------------------------
    def open(self) -> LinkListener:
        """Open the port (unless given open) and send START + INFO_REQUEST."""
        if self._port is None:
            self._port = SerialPort(self.path)
        self._start_reader()
        if self._t0 is None:
            self._t0 = time.monotonic()
        if self.send_start:
            self._send_start()
        return self

    def _start_reader(self) -> None:
        """The port is read on a thread of the compiled core that does nothing else, into a large
        queue: what the driver holds is taken at once even while this loop is busy."""
        assert self._port is not None
        if self.read_queue_bytes > 0:
            self._port.start_reader(self.read_queue_bytes, TRICKLE_BYTES, TRICKLE_WAIT_S,
                                    self.reader_priority)

    @property
    def port(self) -> Optional[SerialPort]:
        """The port once open (its reading thread's ``reader_peak``, ``reader_realtime``)."""
        return self._port

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
            self._close_port()
        finally:
            if self.recorder is not None:
                self.recorder.close()

    def _close_port(self) -> None:
        if self._port is not None and self._port.is_open:
            try:
                self._port.close()
            except SerialPortError:
                pass

    def __enter__(self) -> LinkListener:
        return self.open()

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        # the recording is finished even after an error or Ctrl-C: what was received is kept
        self.close()

    def reconnect(self) -> Connection:
        """Close the port and open it again (the controller keeps its stream going)."""
        self._close_port()
        self._port = SerialPort(self.path)
        self._reopened()
        return Connection("reconnected", self.path, "reopened by the host")

    def _reopened(self) -> None:
        self._start_reader()
        self.receiver.reopened()
        if self.send_start:
            self._send_start()

    # -- what was received -----------------------------------------------------------------
    @property
    def stats(self) -> LinkStats:
        elapsed = 0.0 if self._t0 is None else time.monotonic() - self._t0
        return self.receiver.stats(elapsed, self._disconnects)

    @property
    def info(self) -> Optional[InfoFrame]:
        """The controller's last INFO accepted (None before one)."""
        return self.receiver.info

    @property
    def last_status(self) -> Optional[StatusFrame]:
        return self.receiver.last_status

    @property
    def decisions(self) -> list[Decision]:
        """Every decision so far, the controller's and the host's, in arrival order."""
        return self.receiver.decisions

    @property
    def rejections(self) -> list[Rejection]:
        """The last (at most 100) frames refused for their fields."""
        return self.receiver.rejections

    def activity(self, window_s: float = 0.2) -> Optional[np.ndarray]:
        """Recent energy per taxel, (rows, cols): RMS over the last ``window_s`` seconds of each
        taxel's deviation from its mean over the last second (ADC counts); None before data."""
        return self.receiver.activity(window_s)

    def feed(self, data: bytes) -> list[LinkEvent]:
        """The events of ``data``, bytes received from the controller (what :meth:`events`
        does with each read; also for bytes captured elsewhere). Never raises for what the
        bytes hold, except :class:`~eskin.errors.LinkStreamError` when the stream cannot go
        on."""
        if self._t0 is None:
            self._t0 = time.monotonic()
        return self.receiver.feed(data)

    def finish(self) -> list[LinkEvent]:
        """End the stream: count the samples sent after the last one received, end and decide
        a touch in progress, write the pending recordings (what :meth:`events` does at its end
        with ``flush``)."""
        return self.receiver.finish()

    # -- the event loop --------------------------------------------------------------------
    def events(self, *, duration: Optional[float] = None, until_eof: bool = False,
               eof_grace_s: float = 0.3, flush: bool = True) -> Iterator[LinkEvent]:
        """Yield events until ``duration`` seconds passed, or (``until_eof``) the controller
        reported the end of its replay (STATUS state FINISHED) and ``eof_grace_s`` more seconds
        passed, or the peer closed the port (and could not be reopened), or :meth:`stop`.

        At the end, with ``flush`` (the default), a touch in progress is ended and decided and
        pending touch recordings are written with what was received; pass ``flush=False`` to
        call :meth:`events` again later on the same stream. The last event is :class:`Stats`,
        also when a frame ends the stream with :class:`~eskin.errors.LinkStreamError` (raised
        after it)."""
        if self._port is None:
            self.open()
            yield Connection("connected", self.path)
        try:
            yield from self._loop(duration, until_eof, eof_grace_s)
            if flush:
                yield from self.finish()
        except LinkStreamError:
            yield Stats(self.stats)
            raise
        finally:
            self._stop = False
        yield Stats(self.stats)

    def _loop(self, duration: Optional[float], until_eof: bool,
              eof_grace_s: float) -> Iterator[LinkEvent]:
        t_start = t_stats = time.monotonic()
        finished_at: Optional[float] = None
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
                self._disconnects += 1
                yield Connection("disconnected", self.path, str(exc))
                conn = self._try_reconnect() if self.reconnect_enabled else None
                if conn is None:
                    break
                yield conn
                continue
            for ev in self.feed(chunk) if chunk else ():
                if (until_eof and finished_at is None and isinstance(ev, StatusEvent)
                        and ev.status.state == StreamState.FINISHED):
                    finished_at = time.monotonic()
                yield ev
            if self.read_queue_bytes <= 0 and 0 < len(chunk) < TRICKLE_BYTES:
                time.sleep(TRICKLE_WAIT_S)  # no reading thread to gather a trickle
            if self.stats_interval is not None and now - t_stats >= self.stats_interval:
                t_stats = now
                yield Stats(self.stats)

    def __iter__(self) -> Iterator[LinkEvent]:
        return self.events()

    def _try_reconnect(self) -> Optional[Connection]:
        deadline = time.monotonic() + self.reconnect_timeout
        self._close_port()
        while time.monotonic() < deadline and not self._stop:
            try:
                self._port = SerialPort(self.path)
            except SerialPortError:
                time.sleep(0.05)
                continue
            self._reopened()
            return Connection("reconnected", self.path, "port reopened after the peer closed")
        return None

    # -- bytes -> frames -> events ---------------------------------------------------------
