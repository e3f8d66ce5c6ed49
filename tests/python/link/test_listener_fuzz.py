"""The listener driven with CRC-valid frames of arbitrary field values (hypothesis): no
exception escapes :meth:`LinkListener.feed` / :meth:`~LinkListener.finish`, and the counters
add up. ``make test`` runs a short, derandomized budget; ``make fuzz`` runs at least 10^5 inputs
(``ESKIN_FUZZ_EXAMPLES``; docs/fuzzing.md)."""

from __future__ import annotations

import math
import os

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
    DataFrame,
    DecisionFrame,
    InfoFrame,
    PongFrame,
    StatusFrame,
    StreamState,
    encode_frame,
)

EXAMPLES = int(os.environ.get("ESKIN_FUZZ_EXAMPLES", "150"))
FUZZ = EXAMPLES > 150  # the `make fuzz` run: random, not the fixed sequence of `make test`

U64 = st.integers(0, 2**64 - 1)
U32 = st.integers(0, 2**32 - 1)
#: near the limits the host checks, and anywhere
INDEX = st.one_of(st.integers(0, 5000), st.sampled_from([2**53 - 1, 2**53, 2**63, 2**64 - 5,
                                                         2**64 - 1]), U64)
REAL = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                 st.sampled_from([0.0, -0.0, -3000.0, 1e300, 3000.0, 1e6, 1e6 + 1, 5e-324]))


@st.composite
def data_frames(draw):
    rows, cols = draw(st.one_of(st.sampled_from([(2, 2), (2, 2), (1, 3)]),
                                st.tuples(st.integers(1, 255), st.integers(1, 255))))
    most = max(1, (MAX_FRAME_SIZE - 40) // (2 * rows * cols))
    n = draw(st.integers(1, min(most, 12)))
    seed = draw(st.integers(0, 2**16))
    samples = np.random.default_rng(seed).integers(-32768, 32767, (n, rows, cols), np.int16)
    first = draw(st.one_of(st.integers(0, 400), INDEX))
    return DataFrame(first, draw(U64), samples, draw(st.integers(0, 65535)),
                     draw(st.integers(0, 255)))


names = st.lists(st.text(max_size=6), max_size=5)
frames = st.one_of(
    data_frames(),
    data_frames(),
    st.builds(DecisionFrame, INDEX, INDEX, st.integers(-32768, 32767),
              st.lists(REAL, max_size=MAX_DECISION_VALUES).map(tuple), st.booleans(), INDEX,
              U64, U32, st.integers(0, 65535)),
    st.builds(StatusFrame, U64, INDEX, INDEX, INDEX, U32, U32, U32, U32, U32, U32, U32,
              st.sampled_from(list(StreamState)), st.booleans(), st.integers(0, 65535)),
    st.builds(InfoFrame, st.one_of(st.just(2), st.integers(0, 255)),
              st.one_of(st.just(2), st.integers(0, 255)), REAL, st.integers(0, 65535), REAL,
              REAL, st.booleans(), names.map(tuple)),
    st.builds(PongFrame, U32, U64),
)


@st.composite
def runs(draw):
    """Consecutive DATA frames of one grid (a stream, or a controller changing its grid)."""
    grid = draw(st.sampled_from([(2, 2), (1, 3), (3, 2)]))
    first = draw(st.one_of(st.integers(0, 400), INDEX))
    n, k = draw(st.integers(1, 12)), draw(st.integers(1, 5))
    x = np.zeros((n, *grid), np.int16)
    return [DataFrame((first + i * n) % 2**64, 0, x + i, i) for i in range(k)]


#: single frames of any kind, and runs of DATA frames
streams = st.lists(st.one_of(frames.map(lambda f: [f]), runs()), max_size=8).map(
    lambda parts: [f for part in parts for f in part])


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
@given(streams, st.lists(st.integers(1, 300), max_size=6))
def test_no_frame_field_breaks_the_listener_and_the_counts_add_up(fs, cuts):
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
                        + kinds[InfoEvent] + s.pong_frames + s.absurd_frames)
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


@settings(max_examples=max(EXAMPLES // 10, 15), deadline=None, derandomize=not FUZZ,
          database=None, suppress_health_check=list(HealthCheck))
@given(streams)
def test_recording_an_absurd_stream_ends_cleanly(tmp_path_factory, fs):
    """With --record (a touch detector and a campaign writer behind the stream): the only error
    that may end the stream is LinkStreamError (a rate and grid too large to record), and a
    campaign file written is one the loader accepts."""
    from eskin.data.campaign import load_campaign
    from eskin.errors import LinkStreamError

    sent, wire = _encoded(fs)
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
