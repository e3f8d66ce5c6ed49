"""The listener driven with CRC-valid frames of arbitrary field values (hypothesis): no
exception escapes :meth:`LinkListener.feed` / :meth:`~LinkListener.finish`, and the counters
add up. ``make test`` runs a short, derandomized budget; ``make fuzz`` runs at least 10^5 inputs
(``ESKIN_FUZZ_EXAMPLES``; docs/fuzzing.md).

Each input is one byte string that :func:`frames_from` reads as a stream of frames (up to
``MAX_FRAMES``) and the pieces the wire is fed in, like a libFuzzer data provider: a single
draw per input keeps hypothesis's generation cheap (the nested per-field strategies this test
used first spent four fifths of each input generating it), and zero bytes read as the simplest
values, so hypothesis shrinks a finding towards small, plain frames."""

from __future__ import annotations

import math
import os
import struct

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eskin.link.listener import (
    DataBlock,
    Decision,
    InfoEvent,
    LinkListener,
    Recorded,
    Rejection,
    Stats,
    StatusEvent,
)
from eskin.link.protocol import (
    DELIMITER,
    MAX_DECISION_VALUES,
    MAX_FRAME_SIZE,
    CommandFrame,
    DataFrame,
    DecisionFrame,
    FrameType,
    InfoFrame,
    PingFrame,
    PongFrame,
    StatusFrame,
    StreamState,
    encode_frame,
)

EXAMPLES = int(os.environ.get("ESKIN_FUZZ_EXAMPLES", "150"))
FUZZ = EXAMPLES > 150  # the `make fuzz` run: random, not the fixed sequence of `make test`
#: inputs of the recording test (a touch detector and an HDF5 writer behind the stream: slower)
RECORD_EXAMPLES = int(os.environ.get("ESKIN_FUZZ_RECORD_EXAMPLES", max(EXAMPLES // 10, 15)))
MAX_FRAMES = 48
INPUT_SIZE = 1024

#: sample indices near the limits the host checks (2^53: exact in a float64)
EDGE_INDEX = (0, 1, 2**53 - 1, 2**53, 2**63 - 1, 2**63, 2**64 - 5, 2**64 - 1, 2**32, 2**31)
EDGE_REAL = (0.0, -0.0, 3000.0, -3000.0, 1e300, -1e300, 1e6, 1e6 + 1, 5e-324, math.nan,
             math.inf, -math.inf, 1.0, 2.5e-3, 1e-300, 200.0)
SMALL_GRIDS = ((2, 2), (2, 2), (1, 3), (3, 2), (4, 4), (1, 1), (8, 8), (2, 2))
#: class-name characters: plain, control, non-ASCII, outside the BMP, a lone surrogate
NAME_CHARS = "ab_ \n\t\x00\x7f\u00e9\u4e2d\U0001f600\ud800,\"\\"
_POOL = np.random.default_rng(0).integers(-32768, 32767, 1 << 17, dtype=np.int16)


class _Bytes:
    """Reads values off the input; past its end every read is zero."""

    def __init__(self, blob: bytes) -> None:
        self.blob, self.pos = blob, 0

    def left(self) -> int:
        return len(self.blob) - self.pos

    def take(self, n: int) -> bytes:
        b = self.blob[self.pos:self.pos + n]
        self.pos += n
        return b.ljust(n, b"\0")

    def u8(self) -> int:
        return self.take(1)[0]

    def uint(self, nbytes: int) -> int:
        return int.from_bytes(self.take(nbytes), "little")

    def index(self) -> int:
        """A u64 sample index: small, an edge, or any."""
        t = self.u8() % 4
        if t < 2:
            return self.uint(2) % 5001
        if t == 2:
            return EDGE_INDEX[self.u8() % len(EDGE_INDEX)]
        return self.uint(8)

    def real(self) -> float:
        """A float64: an edge, any bit pattern, or a plain value."""
        t = self.u8() % 3
        if t == 0:
            return EDGE_REAL[self.u8() % len(EDGE_REAL)]
        if t == 1:
            return struct.unpack("<d", self.take(8))[0]
        return self.uint(2) / 8.0

    def names(self) -> tuple[str, ...]:
        out = []
        for _ in range(self.u8() % 6):
            out.append("".join(NAME_CHARS[self.u8() % len(NAME_CHARS)]
                               for _ in range(self.u8() % 7)))
        return tuple(out)


def _data_frame(src: _Bytes) -> DataFrame:
    t = src.u8()
    rows, cols = (SMALL_GRIDS[t % len(SMALL_GRIDS)] if t < 224
                  else (1 + src.u8() % 255, 1 + src.u8() % 255))
    most = max(1, (MAX_FRAME_SIZE - 40) // (2 * rows * cols))
    n = 1 + src.u8() % min(most, 12)
    size = n * rows * cols
    at = src.uint(2) % (len(_POOL) - size) if size < len(_POOL) else 0
    samples = np.resize(_POOL[at:at + size], size).reshape(n, rows, cols)
    return DataFrame(src.index(), src.uint(8), samples, src.uint(2), src.u8())


def _run(src: _Bytes) -> list[DataFrame]:
    """Consecutive DATA frames of one grid (a stream, or a controller changing its grid)."""
    grid = SMALL_GRIDS[src.u8() % len(SMALL_GRIDS)]
    first = src.index()
    n, k = 1 + src.u8() % 12, 1 + src.u8() % 5
    x = np.zeros((n, *grid), np.int16)
    return [DataFrame((first + i * n) % 2**64, 0, x + i, i) for i in range(k)]


def _decision(src: _Bytes) -> DecisionFrame:
    onset, offset = src.index(), src.index()
    label = src.uint(2) - 32768 if src.u8() & 1 else src.u8() % 8 - 1
    values = tuple(src.real() for _ in range(src.u8() % (MAX_DECISION_VALUES + 1)))
    return DecisionFrame(onset, offset, label, values, bool(src.u8() & 1), src.index(),
                         src.uint(8), src.uint(4), src.uint(2))


def _status(src: _Bytes) -> StatusFrame:
    return StatusFrame(src.uint(8), src.index(), src.index(), src.index(),
                       *(src.uint(4) for _ in range(7)),
                       StreamState(src.u8() % 3), bool(src.u8() & 1), src.uint(2))


def _info(src: _Bytes) -> InfoFrame:
    def side() -> int:
        t = src.u8()
        return 2 if t < 128 else src.u8()

    return InfoFrame(side(), side(), src.real(), src.uint(2), src.real(), src.real(),
                     bool(src.u8() & 1), src.names())


_MAKERS = (lambda s: [_data_frame(s)], lambda s: [_data_frame(s)], _run, _run,
           lambda s: [_decision(s)], lambda s: [_status(s)], lambda s: [_info(s)],
           lambda s: [PongFrame(s.uint(4), s.uint(8))],
           lambda s: [PingFrame(s.uint(4), s.uint(8))],
           lambda s: [CommandFrame((FrameType.START, FrameType.STOP,
                                    FrameType.INFO_REQUEST)[s.u8() % 3])])


def frames_from(blob: bytes) -> tuple[list, list[int]]:
    """The frames an input stands for, and the sizes of the pieces the wire is fed in."""
    src = _Bytes(blob)
    cuts = [1 + src.u8() for _ in range(src.u8() % 7)]
    frames: list = []
    count = 1 + src.u8() % MAX_FRAMES
    while src.left() > 0 and len(frames) < count:
        frames += _MAKERS[src.u8() % len(_MAKERS)](src)
    return frames, cuts


#: inputs of one size: hypothesis draws a variable-length byte string one byte and one
#: "go on?" decision at a time, which cost more than the listener's work on it
streams = st.binary(min_size=INPUT_SIZE, max_size=INPUT_SIZE)


def _encoded(fs: list) -> tuple[list, bytes]:
    kept, wire = [], [DELIMITER]
    for f in fs:
        try:
            wire.append(encode_frame(f))
        except ValueError:  # not encodable (a class name with a newline, ...): not sent
            continue
        kept.append(f)
    return kept, b"".join(wire)


@settings(max_examples=EXAMPLES, deadline=None, derandomize=not FUZZ, database=None,
          suppress_health_check=list(HealthCheck))
@given(streams)
def test_no_frame_field_breaks_the_listener_and_the_counts_add_up(blob):
    fs, cuts = frames_from(blob)
    sent, wire = _encoded(fs)
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    events = []
    pos = 0
    for cut in [*cuts, len(wire)]:
        events += listener.feed(wire[pos:pos + cut])
        pos += cut
    events += listener.feed(wire[pos:])
    events += listener.finish()
    s = listener.stats
    kinds = {k: sum(isinstance(e, k) for e in events)
             for k in (DataBlock, Decision, StatusEvent, InfoEvent, Rejection, Recorded, Stats)}
    pongs = sum(isinstance(f, PongFrame) for f in sent)
    # every frame sent arrived (nothing was damaged on the way) and is either used or refused
    assert s.frames == len(sent) and s.crc_errors == s.malformed == s.oversize == 0
    assert s.frames == (kinds[DataBlock] + kinds[Decision] + kinds[StatusEvent]
                        + kinds[InfoEvent] + s.pong_frames + s.absurd_frames
                        + s.unexpected_frames)
    assert s.unexpected_frames == sum(isinstance(f, (PingFrame, CommandFrame)) for f in sent)
    assert s.pong_frames == pongs and s.absurd_frames == kinds[Rejection]
    assert s.decisions_controller == kinds[Decision] and s.decisions_host == 0
    assert s.status_frames == kinds[StatusEvent]
    assert s.samples == sum(f.n_samples for f in sent if isinstance(f, DataFrame))
    assert sum(e.samples.shape[0] for e in events if isinstance(e, DataBlock)) <= s.samples
    assert 0 <= s.lost_samples < 2**53 and s.sample_index_resets >= 0
    assert s.nonfinite_decisions == sum(
        not all(math.isfinite(v) for v in e.values) for e in events if isinstance(e, Decision))
    for e in events:
        if isinstance(e, Rejection):
            assert e.frame in ("DATA", "DECISION", "STATUS", "INFO") and e.field and e.problem
            assert e.message().startswith(f"{e.frame} frame: {e.field} = ")
        elif isinstance(e, InfoEvent):
            assert 0 < e.info.sample_rate_hz <= 1e6 and e.info.rows * e.info.cols <= 4096
        elif isinstance(e, DataBlock):
            assert 0 <= e.first_sample and e.end_sample < 2**53 and e.lost_before >= 0
        elif isinstance(e, Decision):
            assert e.onset_sample <= e.offset_sample < 2**53
            assert all(v is None or math.isfinite(v) for v in e.as_dict()["values"])
    info = listener.info
    grids = {e.samples.shape[1:] for e in events if isinstance(e, DataBlock)}
    if info is not None and events and isinstance(events[-1], DataBlock):
        assert events[-1].samples.shape[1:] == (info.rows, info.cols)
    assert len(grids) <= len(sent)


@settings(max_examples=RECORD_EXAMPLES, deadline=None, derandomize=not FUZZ,
          database=None, suppress_health_check=list(HealthCheck))
@given(streams)
def test_recording_an_absurd_stream_ends_cleanly(tmp_path_factory, blob):
    """With --record (a touch detector and a campaign writer behind the stream): the only error
    that may end the stream is LinkStreamError (a rate and grid too large to record), and a
    campaign file written is one the loader accepts."""
    from eskin.data.campaign import load_campaign
    from eskin.errors import LinkStreamError

    sent, wire = _encoded(frames_from(blob)[0])
    out = tmp_path_factory.mktemp("rec") / "live.h5"
    listener = LinkListener("/dev/null-not-opened", stats_interval=None, record=out,
                            context_s=0.01)
    try:
        listener.feed(wire)
        listener.finish()
    except LinkStreamError as exc:
        assert str(exc).startswith(("INFO frame: sample_rate_hz = ", "DATA frame: grid = "))
    listener.close()
    if out.exists():
        with load_campaign(out, check_data=True) as c:
            assert len(c) == listener.stats.recordings
