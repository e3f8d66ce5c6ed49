"""The eskin wire protocol between the skin controller and its host.

Frames are COBS-encoded, end with one ``0x00`` delimiter, and carry a CRC-32 (the zlib one)
of all their bytes; see ``docs/wire-protocol.md``. Encoding and decoding run in the compiled
core (the same code as the firmware simulator); this module gives them typed frames::

    dec = FrameDecoder()
    for frame in dec.feed(port.read(4096)):
        if isinstance(frame, DataFrame):
            frame.samples            # int16 (n_samples, rows, cols) raw ADC codes
    dec.stats.lost_samples

``encode_frame(frame)`` turns any frame back into bytes (used by hosts for commands and by
tests).
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import Any, Union

import numpy as np

from eskin import _core

_p = _core.protocol

PROTOCOL_VERSION: int = int(_p.PROTOCOL_VERSION)
MAX_FRAME_SIZE: int = int(_p.MAX_FRAME_SIZE)
MAX_DECISION_VALUES: int = int(_p.MAX_DECISION_VALUES)
DELIMITER = b"\x00"
SAMPLES_PER_FRAME = 10  # what eskin-fw-sim sends by default (3.33 ms at 3000 Hz)

__all__ = [
    "DELIMITER",
    "MAX_DECISION_VALUES",
    "MAX_FRAME_SIZE",
    "PROTOCOL_VERSION",
    "SAMPLES_PER_FRAME",
    "CommandFrame",
    "DataFrame",
    "DecisionFrame",
    "DecoderStats",
    "Flags",
    "Frame",
    "FrameDecoder",
    "FrameType",
    "InfoFrame",
    "PingFrame",
    "PongFrame",
    "StatusFrame",
    "StreamState",
    "cobs_decode",
    "cobs_encode",
    "crc32",
    "encode_frame",
]


class FrameType(enum.IntEnum):
    """Frame type byte. DATA..PONG go controller -> host; START..INFO_REQUEST host -> controller."""

    DATA = 0x01
    DECISION = 0x02
    STATUS = 0x03
    INFO = 0x04
    START = 0x10
    STOP = 0x11
    PING = 0x12
    PONG = 0x13
    INFO_REQUEST = 0x14


class Flags(enum.IntFlag):
    """Bits of the header's flags byte."""

    NONE = 0
    OVERRUN = 0x01  # the sender dropped samples since its previous DATA frame
    SYNC = 0x02  # first frame of a stream: no sequence gap is counted on it
    LOOP = 0x04  # DATA: the replay wrapped around (--loop)


class StreamState(enum.IntEnum):
    STOPPED = 0
    STREAMING = 1
    FINISHED = 2


@dataclass(frozen=True, eq=False)
class DataFrame:
    """A few consecutive samples of every taxel, as raw ADC codes.

    ``samples`` is int16 shaped ``(n_samples, rows, cols)``; sample ``k`` of the frame has the
    stream index ``first_sample + k``. ``timestamp_us`` is the sender's clock when the last
    sample was acquired.
    """

    first_sample: int
    timestamp_us: int
    samples: np.ndarray
    seq: int = 0
    flags: int = 0

    @property
    def n_samples(self) -> int:
        return int(self.samples.shape[0])

    @property
    def end_sample(self) -> int:
        """One past the stream index of the last sample."""
        return self.first_sample + self.n_samples

    @property
    def overrun(self) -> bool:
        return bool(self.flags & Flags.OVERRUN)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, DataFrame):
            return NotImplemented
        return (
            (self.first_sample, self.timestamp_us, self.seq, self.flags)
            == (other.first_sample, other.timestamp_us, other.seq, other.flags)
            and bool(np.array_equal(self.samples, other.samples))  # shapes included
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class DecisionFrame:
    """The controller's decision on one touch: ``label`` indexes the INFO class names (-1: none).

    ``values`` holds one decision value per binary machine. The touch window is
    ``[onset_sample, offset_sample)``; the decision was made after sample ``decided_sample``,
    ``latency_us`` after that sample was acquired.
    """

    onset_sample: int
    offset_sample: int
    label: int
    values: tuple[float, ...] = ()
    dont_know: bool = False
    decided_sample: int = 0
    timestamp_us: int = 0
    latency_us: int = 0
    seq: int = 0
    flags: int = 0


@dataclass(frozen=True)
class StatusFrame:
    """The controller's link and pacing counters (sent periodically)."""

    uptime_us: int = 0
    next_sample: int = 0
    samples_sent: int = 0
    dropped_samples: int = 0
    overrun_events: int = 0
    rx_errors: int = 0
    faults_injected: int = 0
    decisions_sent: int = 0
    pacing_p50_ns: int = 0
    pacing_p99_ns: int = 0
    pacing_max_ns: int = 0
    state: StreamState = StreamState.STOPPED
    host_connected: bool = False
    connections: int = 0
    decisions_dropped: int = 0
    frames_dropped: int = 0
    seq: int = 0
    flags: int = 0

    @property
    def overrun(self) -> bool:
        return bool(self.flags & Flags.OVERRUN)


@dataclass(frozen=True)
class InfoFrame:
    """What the controller streams: grid shape, rate, scale and (with a model) class names."""

    rows: int
    cols: int
    sample_rate_hz: float
    samples_per_frame: int = SAMPLES_PER_FRAME
    volts_per_count: float = 0.0
    speed: float = 1.0
    has_model: bool = False
    class_names: tuple[str, ...] = ()
    protocol_version: int = PROTOCOL_VERSION
    seq: int = 0
    flags: int = 0


@dataclass(frozen=True)
class CommandFrame:
    """A host command without payload: START, STOP or INFO_REQUEST."""

    command: FrameType
    seq: int = 0
    flags: int = 0

    def __post_init__(self) -> None:
        cmd = FrameType(self.command)
        if cmd not in (FrameType.START, FrameType.STOP, FrameType.INFO_REQUEST):
            raise ValueError(f"CommandFrame command must be START, STOP or INFO_REQUEST, got {cmd!r}")
        object.__setattr__(self, "command", cmd)


@dataclass(frozen=True)
class PingFrame:
    """Host -> controller; answered by a PongFrame with the same token."""

    token: int
    timestamp_us: int = 0
    seq: int = 0
    flags: int = 0


@dataclass(frozen=True)
class PongFrame:
    """Controller -> host answer to a PING (same token, controller clock)."""

    token: int
    timestamp_us: int = 0
    seq: int = 0
    flags: int = 0


Frame = Union[DataFrame, DecisionFrame, StatusFrame, InfoFrame, CommandFrame, PingFrame, PongFrame]

_TYPE_OF: dict[type, FrameType] = {
    DataFrame: FrameType.DATA,
    DecisionFrame: FrameType.DECISION,
    StatusFrame: FrameType.STATUS,
    InfoFrame: FrameType.INFO,
    PingFrame: FrameType.PING,
    PongFrame: FrameType.PONG,
}


_CLASS_OF: dict[FrameType, type] = {t: cls for cls, t in _TYPE_OF.items()}


def _from_dict(d: dict[str, Any]) -> Frame:
    """A frame of the core decoder's dict (its type, then its fields); the types without a
    class of their own are commands."""
    t = FrameType(d.pop("type"))
    if "state" in d:  # STATUS
        d["state"] = StreamState(d["state"])
    cls = _CLASS_OF.get(t)
    return CommandFrame(command=t, **d) if cls is None else cls(**d)


def encode_frame(frame: Frame) -> bytes:
    """Encode one frame: its COBS bytes followed by the ``0x00`` delimiter.

    A sender starting a stream first writes ``DELIMITER`` on its own, so that a receiver that
    joined in the middle of something resynchronises before the first frame.
    """
    if isinstance(frame, CommandFrame):
        d: dict[str, Any] = {"type": int(frame.command), "seq": frame.seq, "flags": frame.flags}
        return _p.encode(d)
    t = _TYPE_OF.get(type(frame))
    if t is None:
        raise TypeError(f"encode_frame takes an eskin.protocol frame, got {type(frame).__name__}")
    d = {f.name: getattr(frame, f.name) for f in dataclasses.fields(frame)}
    d["type"] = int(t)
    if isinstance(frame, DataFrame):
        samples = np.asarray(frame.samples)
        if samples.ndim != 3:
            raise ValueError(
                f"DataFrame.samples must be (n_samples, rows, cols), got shape {samples.shape}"
            )
        if samples.dtype.kind not in "iu":
            raise ValueError(f"DataFrame.samples must hold integer ADC codes, got {samples.dtype}")
        if samples.size and (samples.min() < -32768 or samples.max() > 32767):
            raise ValueError("DataFrame.samples must fit int16")
        d["samples"] = samples
    elif isinstance(frame, StatusFrame):
        d["state"] = int(d["state"])
    elif isinstance(frame, InfoFrame):
        d["class_names"] = [str(n) for n in d["class_names"]]
        for i, name in enumerate(d["class_names"]):
            try:
                name.encode("utf-8")
            except UnicodeEncodeError as exc:
                raise ValueError(f"InfoFrame.class_names[{i}] = {name!r} is not valid text "
                                 f"(not encodable as UTF-8: {exc.reason})") from None
    return _p.encode(d)


@dataclass(frozen=True)
class DecoderStats:
    """What a FrameDecoder saw. Every fault on the link shows up in one of the counters.

    ``crc_errors``: blocks whose CRC-32 did not match; ``malformed``: invalid COBS, too short,
    unknown type or wrong payload size; ``oversize``: blocks longer than the limit;
    ``sequence_gaps``/``lost_frames``: holes in the 16-bit sequence numbers;
    ``lost_samples``: holes in the DATA sample indices; ``skipped_bytes``: bytes before the
    first delimiter (joining mid-stream).
    """

    bytes: int = 0
    skipped_bytes: int = 0
    frames: int = 0
    data_frames: int = 0
    samples: int = 0
    crc_errors: int = 0
    malformed: int = 0
    oversize: int = 0
    sequence_gaps: int = 0
    lost_frames: int = 0
    lost_samples: int = 0
    sample_index_resets: int = 0

    @property
    def rejected(self) -> int:
        """Blocks rejected for any reason."""
        return self.crc_errors + self.malformed + self.oversize

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


class FrameDecoder:
    """Streaming decoder: feed it bytes as they arrive, in any split, get the accepted frames.

    It never raises on any input, keeps at most ``max_frame_size`` bytes, resynchronises at the
    next delimiter after damage, and accepts a frame only if its COBS block, CRC-32 and layout
    are all valid. Bytes before the first delimiter are skipped (a sender starts every stream
    with one); pass ``wait_for_delimiter=False`` to decode from the very first byte.
    """

    def __init__(self, max_frame_size: int = MAX_FRAME_SIZE, *, wait_for_delimiter: bool = True):
        if not 8 <= int(max_frame_size) <= MAX_FRAME_SIZE:
            raise ValueError(
                f"max_frame_size must be in [8, {MAX_FRAME_SIZE}], got {max_frame_size}"
            )
        self._dec = _p.FrameDecoder(int(max_frame_size), bool(wait_for_delimiter))

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Decode these bytes; return the frames they complete (possibly none)."""
        return [_from_dict(d) for d in self._dec.feed(data)]

    @property
    def stats(self) -> DecoderStats:
        return DecoderStats(**self._dec.stats())

    def reset(self, *, reset_stats: bool = False) -> None:
        """Forget partial input and sequence/sample expectations (e.g. after a reconnect)."""
        self._dec.reset(reset_stats)

    @property
    def max_frame_size(self) -> int:
        return int(self._dec.max_frame_size)


def crc32(data: bytes, crc: int = 0) -> int:
    """CRC-32 as the protocol uses it (equal to ``zlib.crc32``)."""
    return int(_p.crc32(bytes(data), crc))


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (no delimiter appended)."""
    return bytes(_p.cobs_encode(bytes(data)))


def cobs_decode(block: bytes) -> bytes:
    """Decode one COBS block (without its delimiter); ValueError if it is not valid COBS."""
    return bytes(_p.cobs_decode(bytes(block)))

