"""The link's counters and the controller's STATUS as eskin.link.receiver reports them (through
LinkListener.feed and .stats, no port): each counter equal to what was sent, field by field, and
the rate a stream without an INFO frame is taken at."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eskin.data.campaign import load_campaign
from eskin.link.events import DataBlock
from eskin.link.listener import LinkListener, Recorded
from eskin.link.protocol import (
    DELIMITER,
    DataFrame,
    Flags,
    InfoFrame,
    StatusFrame,
    StreamState,
    encode_frame,
)

SPF = 10
TESTS = Path(__file__).resolve().parents[2]


def _info(seq: int = 0, rate: float = 3000.0, volts_per_count: float = 1e-4,
          class_names: tuple[str, ...] = (), grid: tuple[int, int] = (4, 4)) -> bytes:
    return encode_frame(InfoFrame(*grid, rate, volts_per_count=volts_per_count,
                                  has_model=bool(class_names), class_names=class_names, seq=seq))


def _recorder(path: Path, policy: str, replay=None, max_touch_s: float = 7.0):
    """A campaign-file recorder of the stream, as the listener makes one (0.5 s of context)."""
    from eskin.link.recorder import StreamRecorder

    return StreamRecorder(path, policy=policy, replay=replay, replay_offset=0, context_s=0.5,
                          overwrite=False, source="recorded", attrs={}, port="test",
                          host_names=[], max_touch_s=max_touch_s)


def _data(x: np.ndarray, first_seq: int = 1, overrun: frozenset[int] = frozenset()) -> bytes:
    """DATA frames of SPF samples each; the k-th frame flagged OVERRUN when k is in overrun."""
    return b"".join(
        encode_frame(DataFrame(first, first * 333, x[first:first + SPF], (first_seq + k) % 65536,
                               int(Flags.OVERRUN) if k in overrun else 0))
        for k, first in enumerate(range(0, len(x), SPF)))


def _touch_stream(n_quiet: int = 4500, n_touch: int = 900) -> np.ndarray:
    """Quiet noise, a strong 40 Hz burst on four taxels, quiet noise at 3 kHz: (n, 4, 4)."""
    rng = np.random.default_rng(5)
    x = rng.normal(0, 5, size=(2 * n_quiet + n_touch, 4, 4))
    t = np.arange(n_touch) / 3000.0
    x[n_quiet:n_quiet + n_touch, 1:3, 1:3] += (800 * np.sin(2 * np.pi * 40 * t))[:, None, None]
    return np.rint(x).astype(np.int16)


def test_the_stats_carry_the_last_status_field_by_field():
    """Every controller_* counter is the last STATUS frame's, the pacing percentiles turned
    from nanoseconds to microseconds (distinct values, so no field can stand in for another)."""
    first = StatusFrame(uptime_us=10, samples_sent=1, pacing_p50_ns=1, pacing_p99_ns=2,
                        state=StreamState.STOPPED, seq=1)
    last = StatusFrame(uptime_us=99, next_sample=700, samples_sent=690, dropped_samples=3,
                       overrun_events=4, rx_errors=5, faults_injected=6, decisions_sent=7,
                       pacing_p50_ns=1500, pacing_p99_ns=2750, pacing_max_ns=9000,
                       state=StreamState.STREAMING, host_connected=True, connections=1,
                       decisions_dropped=8, frames_dropped=9, seq=2)
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    listener.feed(DELIMITER + encode_frame(first) + encode_frame(last))
    s = listener.stats
    listener.close()
    assert (s.controller_samples_sent, s.controller_dropped_samples, s.controller_overrun_events,
            s.controller_rx_errors, s.controller_faults_injected, s.controller_decisions_sent,
            s.controller_decisions_dropped, s.controller_frames_dropped) == (690, 3, 4, 5, 6, 7,
                                                                             8, 9)
    assert (s.controller_pacing_p50_us, s.controller_pacing_p99_us) == (1.5, 2.75)
    assert s.controller_state == "streaming" and s.status_frames == 2


def test_overrun_frames_count_exactly_the_data_frames_flagged_overrun():
    x = np.zeros((200, 4, 4), dtype=np.int16)  # 20 frames; 3 flagged, two of them adjacent
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    listener.feed(DELIMITER + _info() + _data(x, overrun=frozenset({0, 7, 8})))
    s = listener.stats
    listener.close()
    assert (s.data_frames, s.overrun_frames, s.samples) == (20, 3, 200)


def test_a_stream_without_info_is_taken_at_three_kilohertz(tmp_path):
    """DATA frames and no INFO (a controller whose INFO was lost, no replay file given): the
    stream is taken at 3000 Hz, eskin-fw-sim's default rate, and the touch recorded at it."""
    x = _touch_stream()
    out = tmp_path / "touches.h5"
    listener = LinkListener("/dev/null-not-opened", record=out, stats_interval=None)
    events = listener.feed(DELIMITER + _data(x)) + listener.finish()
    listener.close()
    assert listener.info is None
    assert len([e for e in events if isinstance(e, Recorded)]) == 1
    with load_campaign(out) as c:
        assert c.sample_rate_hz == 3000.0


def test_decisions_host_counts_each_decision_of_the_host_model(tmp_path):
    """With a host model, each touch the host decides is one ``decisions_host``; the
    controller sent none."""
    from eskin.deploy.export import CompiledModel

    model = CompiledModel((TESTS / "data" / "model_projection_float64.eskin").read_bytes())
    x = np.concatenate([_touch_stream(), _touch_stream()])  # two touches apart
    listener = LinkListener("/dev/null-not-opened", model=model, stats_interval=None)
    events = listener.feed(DELIMITER + _info() + _data(x)) + listener.finish()
    s = listener.stats
    listener.close()
    host = [e for e in events if getattr(e, "source", None) == "host"]
    assert len(host) == 2
    assert (s.decisions_host, s.decisions_controller) == (2, 0)


def test_nothing_received_is_nothing_lost():
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    s = listener.stats
    assert (s.lost_samples, s.lost_decisions, s.sample_index_resets, s.recordings) == (0, 0, 0, 0)
    assert listener.activity() is None
    listener.close()


def test_an_info_frame_of_a_larger_grid_than_the_data_before_it_restarts_the_stream():
    """DATA before any INFO gives a provisional grid; an INFO frame of another grid, larger or
    smaller, replaces it: the stream restarts at the INFO's grid."""
    rng = np.random.default_rng(2)
    for before, after in (((2, 2), (4, 4)), ((4, 4), (2, 2))):
        listener = LinkListener("/dev/null-not-opened", stats_interval=None)
        x0 = rng.integers(-50, 50, size=(40, *before)).astype(np.int16)
        listener.feed(DELIMITER + _data(x0))
        assert listener.activity().shape == before
        listener.feed(_info(seq=5, grid=after))
        assert listener.activity() is None  # restarted at the INFO frame, before any new DATA
        x1 = rng.integers(-50, 50, size=(3000, *after)).astype(np.int16)
        listener.feed(_data(x1, first_seq=6))
        assert listener.activity().shape == after
        listener.close()


def test_the_activity_history_is_at_most_256_mib_of_samples():
    """history_s seconds of samples, but never more than 256 MiB of int16 taxels."""
    # 6,000 samples; 8,388,608 = 256 MiB / (16 taxels x 2 bytes) of the 3e9 asked for
    for history_s, want in ((2.0, 6000), (1e6, 8_388_608)):
        listener = LinkListener("/dev/null-not-opened", stats_interval=None, history_s=history_s)
        listener.feed(DELIMITER + _info() + _data(np.zeros((10, 4, 4), np.int16)))
        assert listener.receiver._stream.history.capacity == want
        listener.close()
    # a grid of 2 x 8 (DATA before any INFO, at 3000 samples/s): 256 MiB / 32 bytes as well,
    # and of 2 x 3: 256 MiB / 12 bytes
    for grid, want in (((2, 8), 8_388_608), ((2, 3), 22_369_621)):
        listener = LinkListener("/dev/null-not-opened", stats_interval=None, history_s=1e6)
        listener.feed(DELIMITER + _data(np.zeros((10, *grid), np.int16)))
        assert listener.receiver._stream.history.capacity == want
        listener.close()


def test_a_recording_takes_the_info_frames_volts_per_count_and_1_when_it_says_0(tmp_path):
    """The volts per count of a recorded stream: the INFO frame's when it gives one (> 0), else
    the replay file's (none here), else 1 (the samples kept as counts)."""
    from eskin.data.campaign import load_campaign

    x = _touch_stream()
    for vpc, want in ((2.5e-4, 2.5e-4), (0.0, 1.0)):
        out = tmp_path / f"vpc{vpc}.h5"
        info = _info(volts_per_count=vpc)
        listener = LinkListener("/dev/null-not-opened", record=out, record_policy="touch",
                                stats_interval=None)
        events = listener.feed(DELIMITER + info + _data(x)) + listener.finish()
        listener.close()
        assert sum(isinstance(e, Recorded) for e in events) == 1
        with load_campaign(out) as camp:
            assert camp.volts_per_count == want


def test_grids_of_as_many_columns_voted_in_within_one_read_restart_the_stream():
    """No INFO: 4x4 frames, then 2x4 ones (the same columns), then 4x4 again, all in the same
    read. The third frame of the other grid in a row wins the vote; from there the stream has
    that grid, its samples in blocks of it."""
    rng = np.random.default_rng(3)
    a = rng.integers(-50, 50, size=(50, 4, 4)).astype(np.int16)
    b = rng.integers(-50, 50, size=(60, 2, 4)).astype(np.int16)
    c = rng.integers(-50, 50, size=(40, 4, 4)).astype(np.int16)
    wire, seq = b"", 1
    for x in (a, b, c):
        for k in range(0, len(x), SPF):
            wire += encode_frame(DataFrame(k, k * 333, x[k:k + SPF], seq))
            seq += 1
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    events = listener.feed(DELIMITER + wire)
    s = listener.stats
    listener.close()
    blocks = [e for e in events if isinstance(e, DataBlock)]
    assert [blk.samples.shape[1:] for blk in blocks] == [(4, 4)] * 5 + [(2, 4)] * 4 + [(4, 4)] * 2
    np.testing.assert_array_equal(np.concatenate([blk.samples for blk in blocks[5:9]]), b[20:])
    np.testing.assert_array_equal(np.concatenate([blk.samples for blk in blocks[9:]]), c[20:])
    assert s.samples == 150 and s.absurd_frames == 4  # the first two of each new grid refused
    assert listener.receiver._stream.grid == (4, 4)


def test_a_controller_label_is_named_by_the_info_frame_and_without_one_kept_as_an_index():
    """A DECISION's label names an INFO class (one past them is refused as absurd); before any
    INFO frame it has no name, only its index."""
    from eskin.link.events import Decision
    from eskin.link.protocol import DecisionFrame

    info = _info(seq=3, class_names=("brush", "finger"))

    def decision(label: int, seq: int) -> bytes:
        return encode_frame(DecisionFrame(10, 90, label, (0.5, -0.5), seq=seq))

    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    events = listener.feed(DELIMITER + decision(0, 0) + decision(1, 1) + decision(-1, 2) + info
                           + decision(1, 4) + decision(2, 5) + decision(-1, 6))
    listener.close()
    got = [(d.label, d.label_index) for d in events if isinstance(d, Decision)]
    assert got == [(None, 0), (None, 1), (None, -1), ("finger", 1), (None, -1)]
    assert listener.stats.absurd_frames == 1  # label 2 of two classes


def test_a_bare_detector_as_host_classifier_decides_no_class_and_records_unknown(tmp_path):
    """A StreamReceiver given a detector without classes (label -1, never "don't know") as its
    host classifier: each touch is a host decision of no class, and is recorded as "unknown",
    never under a class the detector does not have."""
    from eskin.link.events import Decision
    from eskin.link.host_classifier import HostClassifier, max_touch_s
    from eskin.link.receiver import StreamReceiver

    clf = HostClassifier((4, 4), 3000.0)
    out = tmp_path / "touches.h5"
    rec = _recorder(out, "touch", max_touch_s=max_touch_s(clf))
    rx = StreamReceiver(classifier=clf, recorder=rec, record_policy="touch", replay=None,
                        max_fill_s=0.1, history_s=2.0)
    x = np.concatenate([_touch_stream(), _touch_stream()])  # two touches apart
    events = rx.feed(DELIMITER + _info() + _data(x)) + rx.finish()
    rec.close()
    host = [e for e in events if isinstance(e, Decision)]
    assert [(d.source, d.label, d.label_index, d.dont_know) for d in host] == \
        [("host", None, -1, False)] * 2
    assert len([e for e in events if isinstance(e, Recorded)]) == 2
    with load_campaign(out) as camp:
        names = list(camp.modalities)
        assert [names[int(m)] for m in np.asarray(camp.modality)] == ["unknown"] * 2


def test_pong_frames_and_nonfinite_decisions_are_counted_one_by_one():
    """Three PONG frames are 3 ``pong_frames``; of three controller decisions (one with a NaN,
    one with an infinite value, one finite) two are ``nonfinite_decisions``."""
    from eskin.link.protocol import DecisionFrame, PongFrame

    nan, inf = float("nan"), float("inf")
    frames = [PongFrame(token=k, timestamp_us=10 * k, seq=k) for k in range(3)]
    frames += [DecisionFrame(0, 10, 0, values, decided_sample=10, seq=3 + k)
               for k, values in enumerate(((0.5, nan, -1.0), (0.5, -0.5, -1.0),
                                           (-inf, 0.2, 0.1)))]
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    listener.feed(DELIMITER + _info(class_names=("a", "b", "c"))
                  + b"".join(encode_frame(f) for f in frames))
    s = listener.stats
    listener.close()
    assert (s.pong_frames, s.nonfinite_decisions, s.decisions_controller) == (3, 2, 3)


def test_a_data_frames_grid_that_cannot_be_recorded_is_named_in_the_error(tmp_path, monkeypatch):
    """No INFO frame yet: a stream whose recordings would not fit in the memory available
    ends at its first DATA frame with the error naming that frame's grid, before any campaign
    is written."""
    from eskin.data import limits
    from eskin.errors import LinkStreamError

    monkeypatch.setattr(limits, "available_memory", lambda: 1000)  # not one recording
    listener = LinkListener("/dev/null-not-opened", record=tmp_path / "live.h5",
                            stats_interval=None)
    with pytest.raises(LinkStreamError) as refused:
        listener.feed(DELIMITER + _data(np.zeros((20, 2, 3), dtype=np.int16)))
    listener.close()
    assert str(refused.value).startswith("DATA frame: grid = 2x3: cannot record this stream (")
    assert "one recording would take" in str(refused.value)
    assert not (tmp_path / "live.h5").exists()


def test_a_host_decision_is_made_at_the_end_of_the_frame_that_ends_its_touch():
    """A host decision's ``decided_sample`` is the stream's next sample when the touch was
    decided: past the touch's window, at the end of the DATA frame that ended it when frames
    arrive one by one, at the end of a second's piece of a read of many seconds (the host
    feeds its classifier at most a second at a time)."""
    from eskin.deploy.export import CompiledModel

    model = CompiledModel((TESTS / "data" / "model_projection_float64.eskin").read_bytes())
    x = np.concatenate([_touch_stream(), _touch_stream()])  # two touches apart
    frames = [encode_frame(DataFrame(k, k * 333, x[k:k + SPF], (1 + k // SPF) % 65536))
              for k in range(0, len(x), SPF)]
    for reads, piece in (([_data(x)], 3000), (frames, SPF)):
        listener = LinkListener("/dev/null-not-opened", model=model, stats_interval=None)
        events = listener.feed(DELIMITER + _info())
        for r in reads:
            events += listener.feed(r)
        events += listener.finish()
        listener.close()
        host = [e for e in events if getattr(e, "source", None) == "host"]
        assert len(host) == 2
        for d in host:
            assert d.decided_sample % piece == 0
            assert d.offset_sample < d.decided_sample < d.offset_sample + 3000 + piece

def _segment_replay(tmp_path: Path, recs: list[np.ndarray], rate: float, gap_s: float):
    """A replay file of ``recs`` ((rows, cols, n) each) labelled 1, 0, 1, ... at ``rate``,
    and its stream as (n, rows, cols)."""
    from eskin.data.replay import write_replay_arrays

    rf = write_replay_arrays(tmp_path / "r.eskr", recs, labels=[(k + 1) % 2 for k in
                                                                range(len(recs))],
                             class_names=["brush", "finger"], sample_rate_hz=rate, gap_s=gap_s)
    return rf, np.asarray(rf.samples).reshape(rf.n_samples, *recs[0].shape[:2]).astype(np.int16)


def test_segments_are_recorded_at_a_rate_the_touch_detector_cannot_take(tmp_path):
    """The "segment" policy records the replay file's segments and runs no touch detector:
    a stream at 1 Hz (a rate a campaign may have, far below the detector's 5 Hz DC cutoff)
    is recorded segment by segment, equal to the source."""
    rng = np.random.default_rng(3)
    recs = [rng.integers(-500, 500, size=(2, 2, n)).astype(np.int16) for n in (30, 20, 40)]
    rf, x = _segment_replay(tmp_path, recs, 1.0, 10.0)
    out = tmp_path / "live.h5"
    listener = LinkListener("/dev/null-not-opened", record=out, replay=rf, stats_interval=None)
    events = listener.feed(DELIMITER + _info(rate=1.0, grid=(2, 2)) + _data(x)) + listener.finish()
    listener.close()
    assert [e.index for e in events if isinstance(e, Recorded)] == [0, 1, 2]
    with load_campaign(out) as camp:
        assert camp.sample_rate_hz == 1.0 and list(camp.modality) == [1, 0, 1]
        for k, r in enumerate(recs):
            assert np.array_equal(camp.recording(k), r)


def test_a_host_models_touches_are_not_recorded_by_segments(tmp_path):
    """With a host model and the "segment" policy, the host decides each touch and the file
    gets the replay file's segments only; a recorder of segments refuses a touch outright."""
    from eskin.deploy.export import CompiledModel
    from eskin.link.events import Decision

    recs = [np.moveaxis(_touch_stream(n_quiet=1500), 0, -1)] * 2  # a touch in each
    rf, x = _segment_replay(tmp_path, recs, 3000.0, 0.5)
    model = CompiledModel((TESTS / "data" / "model_projection_float64.eskin").read_bytes())
    out = tmp_path / "live.h5"
    listener = LinkListener("/dev/null-not-opened", model=model, record=out, replay=rf,
                            stats_interval=None)
    events = listener.feed(DELIMITER + _info() + _data(x)) + listener.finish()
    listener.close()
    assert len([e for e in events if isinstance(e, Decision)]) == 2
    assert [e.index for e in events if isinstance(e, Recorded)] == [0, 1]
    with load_campaign(out) as camp:
        assert list(camp.modality) == [1, 0]
        for k, r in enumerate(recs):
            assert np.array_equal(camp.recording(k), r)
    rec = _recorder(tmp_path / "other.h5", "segment", replay=rf)
    with pytest.raises(ValueError, match="the 'segment' policy records no touches"):
        rec.touch(0, 10, "unknown")
    rec.close()
