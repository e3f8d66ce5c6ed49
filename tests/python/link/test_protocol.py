"""eskin.protocol: frames, COBS, CRC-32 and the streaming decoder (compiled core)."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from eskin.link.protocol import (
    DELIMITER,
    MAX_FRAME_SIZE,
    CommandFrame,
    DecoderStats,
    DataFrame,
    DecisionFrame,
    Flags,
    FrameDecoder,
    FrameType,
    InfoFrame,
    PingFrame,
    PongFrame,
    StatusFrame,
    StreamState,
    cobs_decode,
    cobs_encode,
    crc32,
    encode_frame,
)


def reference_cobs(data: bytes) -> bytes:
    """Plain-Python COBS to check the core against: split at zeros, 254-byte blocks."""
    out = bytearray()
    parts = data.split(b"\x00")
    for j, part in enumerate(parts):
        full, rem = divmod(len(part), 254)
        for k in range(full):
            out += b"\xff" + part[k * 254 : (k + 1) * 254]
        # the remainder block (it carries the implied zero), except after a last run of
        # exactly k*254 bytes
        if rem or j < len(parts) - 1 or not part:
            r = part[full * 254 :]
            out += bytes([len(r) + 1]) + r
    return bytes(out)


def make_frames(seed: int = 0, n: int = 40) -> list:
    rng = np.random.default_rng(seed)
    frames: list = []
    sample = 0
    for i in range(n):
        k = i % 6
        if k in (0, 1, 2):
            s = rng.integers(-32768, 32768, size=(10, 4, 4)).astype(np.int16)
            s[:, 0, :] = 0
            frames.append(DataFrame(first_sample=sample, timestamp_us=sample * 333, samples=s, seq=i))
            sample += 10
        elif k == 3:
            frames.append(
                DecisionFrame(
                    onset_sample=max(0, sample - 50), offset_sample=sample, label=i % 3,
                    values=(0.5, -1.25, 3.0), dont_know=bool(i % 2), decided_sample=sample + 1,
                    timestamp_us=i, latency_us=123, seq=i,
                )
            )
        elif k == 4:
            frames.append(
                StatusFrame(uptime_us=i, next_sample=sample, dropped_samples=2,
                            state=StreamState.STREAMING, host_connected=True,
                            connections=1 + i % 3, seq=i)
            )
        else:
            frames.append(
                InfoFrame(rows=4, cols=4, sample_rate_hz=3000.0, volts_per_count=1e-3,
                          class_names=("brush", "finger", "washer"), has_model=True, seq=i)
            )
    return frames


STREAM_FRAMES = make_frames()
STREAM = DELIMITER + b"".join(encode_frame(f) for f in STREAM_FRAMES)


def test_crc_known_vector_and_zlib():
    assert crc32(b"123456789") == 0xCBF43926 == zlib.crc32(b"123456789")
    assert crc32(b"") == 0


@given(st.binary(max_size=2000), st.integers(0, 2**32 - 1))
def test_crc_equals_zlib(data, start):
    assert crc32(data) == zlib.crc32(data)
    assert crc32(data, start) == zlib.crc32(data, start)


@given(st.binary(max_size=1200))
def test_cobs_round_trip_and_matches_reference(data):
    enc = cobs_encode(data)
    assert b"\x00" not in enc
    assert len(enc) <= len(data) + len(data) // 254 + 1
    assert cobs_decode(enc) == data
    assert enc == reference_cobs(data)


@pytest.mark.parametrize("n", [254, 255, 508, 509])
def test_cobs_long_runs(n):
    data = bytes((i % 255) + 1 for i in range(n))
    assert cobs_decode(cobs_encode(data)) == data
    assert cobs_encode(data)[0] == 0xFF


def test_cobs_decode_rejects_invalid():
    with pytest.raises(ValueError):
        cobs_decode(b"\x05\x11")
    with pytest.raises(ValueError):
        cobs_decode(b"\x02\x00")


def test_every_frame_type_round_trips():
    frames = STREAM_FRAMES[:6] + [
        CommandFrame(FrameType.START, seq=6),
        CommandFrame(FrameType.STOP, seq=7),
        CommandFrame(FrameType.INFO_REQUEST, seq=8),
        PingFrame(token=0xDEADBEEF, timestamp_us=12, seq=9),
        PongFrame(token=1, timestamp_us=2**63, seq=10),
    ]
    dec = FrameDecoder()
    got = dec.feed(DELIMITER + b"".join(encode_frame(f) for f in frames))
    assert got == frames
    assert dec.stats.frames == len(frames)
    assert dec.stats.sequence_gaps == 0
    assert isinstance(got[4], StatusFrame) and got[4].state is StreamState.STREAMING


def test_frame_bytes_follow_the_documented_layout():
    s = np.array([[[1, -2]]], dtype=np.int16)
    enc = encode_frame(DataFrame(first_sample=7, timestamp_us=9, samples=s, seq=0x0102, flags=2))
    assert enc[-1] == 0 and b"\x00" not in enc[:-1]
    raw = cobs_decode(enc[:-1])
    assert raw[:4] == bytes([0x01, 0x02, 0x02, 0x01])
    first, ts, rows, cols, n = struct.unpack_from("<QQBBH", raw, 4)
    assert (first, ts, rows, cols, n) == (7, 9, 1, 2, 1)
    assert struct.unpack_from("<hh", raw, 24) == (1, -2)
    assert struct.unpack("<I", raw[-4:])[0] == zlib.crc32(raw[:-4])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, len(STREAM)), max_size=40))
def test_any_split_gives_identical_frames(cuts):
    cuts = sorted(set(cuts))
    pieces = [STREAM[a:b] for a, b in zip([0, *cuts], [*cuts, len(STREAM)])]
    dec = FrameDecoder()
    got = []
    for piece in pieces:
        got += dec.feed(piece)
    assert got == STREAM_FRAMES
    assert dec.stats.bytes == len(STREAM)


@settings(max_examples=80, deadline=None)
@given(st.binary(max_size=6000))
def test_garbage_never_crashes_and_is_never_accepted(data):
    dec = FrameDecoder(wait_for_delimiter=False)
    assert dec.feed(data) == []  # a random block passing CRC-32 has probability 2**-32
    stats = dec.stats
    assert stats.bytes == len(data)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_corruption_is_never_accepted_and_costs_at_most_two_frames(data):
    frames = STREAM_FRAMES
    encoded = [encode_frame(f) for f in frames]
    # a DATA frame follows the damage, so that the lost frames and samples can be counted
    victim = data.draw(st.integers(1, len(frames) - 4), label="victim")
    kind = data.draw(st.sampled_from(["flip", "drop", "garbage", "truncate"]), label="kind")
    e = bytearray(encoded[victim])
    if kind == "flip":
        pos = data.draw(st.integers(0, len(e) - 1))
        e[pos] ^= 1 << data.draw(st.integers(0, 7))
    elif kind == "drop":
        del e[data.draw(st.integers(0, len(e) - 1))]
    elif kind == "garbage":
        pos = data.draw(st.integers(0, len(e) - 1))
        e[pos:pos] = data.draw(st.binary(min_size=1, max_size=64))
    else:
        e = e[: data.draw(st.integers(1, len(e) - 2))] + b"\x00"
    stream = DELIMITER + b"".join(encoded[:victim]) + bytes(e) + b"".join(encoded[victim + 1 :])
    dec = FrameDecoder()
    got = dec.feed(stream)
    by_seq = {f.seq: f for f in frames}
    for g in got:
        assert g == by_seq[g.seq], "a corrupted frame was accepted"
    lost = len(frames) - len(got)
    assert lost <= 2
    stats = dec.stats
    assert stats.lost_frames == lost
    if lost:
        assert stats.rejected >= 1
    sent_samples = sum(f.n_samples for f in frames if isinstance(f, DataFrame))
    assert stats.samples + stats.lost_samples == sent_samples


def test_joining_mid_stream_skips_to_the_next_delimiter():
    tail = STREAM[57:]  # inside the first DATA frame
    dec = FrameDecoder()
    got = dec.feed(tail)
    assert got == STREAM_FRAMES[1:]
    assert dec.stats.skipped_bytes > 0
    assert dec.stats.rejected == 0


def test_oversize_blocks_are_dropped_with_bounded_memory():
    dec = FrameDecoder(max_frame_size=128)
    got = dec.feed(STREAM)
    # DATA frames (348 bytes) are oversize for this decoder; the others pass
    assert [type(g) for g in got] == [type(f) for f in STREAM_FRAMES if not isinstance(f, DataFrame)]
    assert dec.stats.oversize == sum(isinstance(f, DataFrame) for f in STREAM_FRAMES)
    with pytest.raises(ValueError, match="max_frame_size"):
        FrameDecoder(max_frame_size=1 << 20)


def test_encode_frame_rejects_bad_frames():
    for shape in ((10, 16), (10, 4, 4, 1)):
        with pytest.raises(ValueError) as refused:
            encode_frame(DataFrame(0, 0, np.zeros(shape, np.int16)))
        assert str(refused.value) == ("DataFrame.samples must be (n_samples, rows, cols), got "
                                      f"shape {shape}")
    with pytest.raises(ValueError, match="int16"):
        encode_frame(DataFrame(0, 0, np.full((1, 1, 1), 40000, np.int32)))
    with pytest.raises(ValueError, match="at most"):
        encode_frame(DecisionFrame(0, 1, 0, values=tuple(range(17))))
    with pytest.raises(ValueError, match="4096"):
        encode_frame(DataFrame(0, 0, np.zeros((200, 4, 4), np.int16)))
    with pytest.raises(ValueError, match="seq"):
        encode_frame(PingFrame(token=1, seq=70000))
    with pytest.raises(TypeError):
        encode_frame("START")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        CommandFrame(FrameType.DATA)


def test_class_names_are_text_both_ways():
    """A name that is not encodable as UTF-8 (a lone surrogate) is refused by field, not by a
    pybind11 cast error; name bytes on the wire that are not UTF-8 arrive as replacement
    characters, never as an exception out of the decoder."""
    with pytest.raises(ValueError, match=r"class_names\[1\] = '\\ud800' is not valid text"):
        encode_frame(InfoFrame(2, 2, 100.0, class_names=("tap", "\ud800")))
    raw = bytearray(cobs_decode(encode_frame(InfoFrame(2, 2, 100.0, class_names=("QQQQ",)))[:-1]))
    at = raw.index(b"QQQQ")
    raw[at:at + 4] = b"\xffq\xc3\x28"
    raw[-4:] = struct.pack("<I", zlib.crc32(bytes(raw[:-4])))
    (got,) = FrameDecoder().feed(DELIMITER + cobs_encode(bytes(raw)) + DELIMITER)
    assert got.class_names == ("\ufffdq\ufffd(",)


def test_reset_forgets_partial_frame():
    dec = FrameDecoder()
    dec.feed(STREAM[:100])
    dec.reset()
    assert dec.feed(STREAM[100:]) == STREAM_FRAMES[1:]


def test_python_numbering_is_the_cores():
    """One source for the protocol's numbers: the C++ header (cpp/include/eskin/protocol.hpp),
    read through the compiled core; eskin.link.protocol's enums must equal it name for name."""
    from eskin import _core
    from eskin.link.protocol import DELIMITER, Flags, FrameType, StreamState

    core = _core.protocol
    assert {t.name: int(t) for t in FrameType} == dict(core.FRAME_TYPES)
    assert {f.name: int(f) for f in Flags if f.name != "NONE"} == dict(core.FLAGS)
    assert {s.name: int(s) for s in StreamState} == dict(core.STREAM_STATES)
    assert DELIMITER == core.DELIMITER


def _data(**kw) -> DataFrame:
    fields = dict(first_sample=10, timestamp_us=5, rows=1, cols=2, seq=3, flags=0,
                  samples=np.array([[[1, 2]], [[3, 4]]], np.int16))
    fields.update(kw)
    samples = fields.pop("samples")
    fields.pop("rows"), fields.pop("cols")
    return DataFrame(samples=samples, **fields)


def test_data_frames_are_equal_only_when_every_field_and_sample_is():
    """The round-trip tests rely on ==: each field and each sample value must count."""
    a = _data()
    assert a == _data() and not (a != _data())
    for other in (_data(first_sample=11), _data(timestamp_us=6), _data(seq=4),
                  _data(flags=int(Flags.OVERRUN)), _data(first_sample=9), _data(seq=2)):
        assert a != other and other != a  # both ways: a larger or smaller field
        assert not (a == other) and not (other == a)
    assert a != _data(samples=np.array([[[1, 2]], [[3, 5]]], np.int16))  # one value
    assert a != _data(samples=np.array([[[1], [2]], [[3], [4]]], np.int16))  # same values, 2x1
    assert a.__eq__("not a frame") is NotImplemented


def test_a_data_frame_has_no_flags_unless_given_and_decision_values_go_as_floats():
    frame = DataFrame(0, 0, np.zeros((1, 1, 2), np.int16))
    assert (frame.seq, frame.flags, frame.overrun) == (0, 0, False)
    (back,) = FrameDecoder(wait_for_delimiter=False).feed(encode_frame(frame))
    assert back.flags == 0 and not back.overrun
    sent = DecisionFrame(10, 40, 1, (np.float32(0.5), 2, np.float64(-1.25)))
    (got,) = FrameDecoder(wait_for_delimiter=False).feed(encode_frame(sent))
    assert got.values == (0.5, 2.0, -1.25) and all(type(v) is float for v in got.values)


def test_a_data_frames_end_is_one_past_its_last_sample():
    frame = _data(first_sample=1000, samples=np.zeros((7, 4, 4), np.int16))
    assert (frame.n_samples, frame.end_sample) == (7, 1007)
    assert _data(first_sample=5, samples=np.zeros((0, 4, 4), np.int16)).end_sample == 5


def test_the_int16_range_is_accepted_to_its_ends_and_refused_past_them():
    ends = np.array([[[-32768, 32767]]], np.int32)
    frame = _data(samples=ends)
    (back,) = FrameDecoder(wait_for_delimiter=False).feed(encode_frame(frame))
    np.testing.assert_array_equal(back.samples, ends)
    for bad in (-32769, 32768):
        with pytest.raises(ValueError, match="int16"):
            encode_frame(_data(samples=np.array([[[0, bad]]], np.int32)))
    with pytest.raises(ValueError, match="integer ADC codes"):
        encode_frame(_data(samples=np.zeros((1, 1, 2), np.float32)))
    with pytest.raises(ValueError, match=r"\(n_samples, rows, cols\)"):
        encode_frame(_data(samples=np.zeros((1, 2), np.int16)))


def test_rejected_counts_crc_errors_malformed_and_oversize_blocks():
    dec = FrameDecoder(64)
    good = encode_frame(_data())
    damaged = bytearray(good)
    damaged[3] ^= 0x40
    oversize = encode_frame(_data(samples=np.zeros((20, 1, 2), np.int16)))
    dec.feed(DELIMITER + bytes(damaged) + oversize + b"\x01\x01\x01\x00" + good)
    st = dec.stats
    assert (st.crc_errors, st.oversize, st.malformed) == (1, 1, 1)
    assert st.rejected == 3
    assert st.frames == 1


def test_reset_keeps_or_clears_the_statistics_as_asked():
    dec = FrameDecoder(wait_for_delimiter=False)
    dec.feed(encode_frame(_data()) + b"\x05junk\x00")
    before = dec.stats
    assert before.frames == 1 and before.rejected == 1
    dec.reset()
    assert dec.stats == before
    dec.reset(reset_stats=True)
    assert dec.stats == DecoderStats()
    # a reset also forgets the expected sequence and sample index: no gap is counted after it
    dec.feed(encode_frame(_data(seq=1, first_sample=0)))
    dec.reset()
    dec.feed(encode_frame(_data(seq=9, first_sample=100)))
    assert dec.stats.sequence_gaps == 0 and dec.stats.lost_samples == 0


@pytest.mark.parametrize("size", [7, MAX_FRAME_SIZE + 1])
def test_the_decoder_limit_is_checked(size):
    with pytest.raises(ValueError, match=rf"\[8, {MAX_FRAME_SIZE}\], got {size}"):
        FrameDecoder(size)
    assert FrameDecoder(8).max_frame_size == 8
    assert FrameDecoder(MAX_FRAME_SIZE).max_frame_size == MAX_FRAME_SIZE


def test_frames_are_immutable_and_sequence_numbers_start_at_zero():
    import dataclasses

    frames = [_data(), DecisionFrame(onset_sample=1, offset_sample=2, decided_sample=2, label=0,
                                     values=(0.5,)),
              StatusFrame(), InfoFrame(rows=4, cols=4, sample_rate_hz=3000.0), PingFrame(token=1),
              PongFrame(token=1),
              CommandFrame(FrameType.START)]
    for f in frames:
        name = dataclasses.fields(f)[0].name
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(f, name, getattr(f, name))
    assert [f.seq for f in frames[1:]] == [0] * 6
    assert frames[2].pacing_p99_ns == 0 and frames[3].speed == 1.0  # documented defaults
    dec = FrameDecoder(wait_for_delimiter=False)
    (ping,) = dec.feed(encode_frame(PingFrame(token=7)))
    assert ping == PingFrame(token=7) and ping.seq == 0


def test_the_default_frame_length_is_the_simulators():
    """SAMPLES_PER_FRAME (InfoFrame's default) is what eskin-fw-sim sends unless told otherwise,
    as its usage says."""
    import re
    import subprocess

    from eskin._paths import find_executable
    from eskin.link.protocol import SAMPLES_PER_FRAME, InfoFrame

    usage = subprocess.run([str(find_executable("eskin-fw-sim")), "--help"], capture_output=True,
                           text=True, check=True).stdout
    m = re.search(r"--samples-per-frame N\s+samples per DATA frame \(default (\d+)\)", usage)
    assert m, usage
    assert int(m.group(1)) == SAMPLES_PER_FRAME
    assert InfoFrame(rows=1, cols=1, sample_rate_hz=1.0).samples_per_frame == SAMPLES_PER_FRAME


def test_what_a_frame_does_not_say_is_zero_false_or_empty():
    """Documented defaults: a counter, time or flag byte left out is 0, a scale 0.0 (unknown),
    a speed 1.0 (real time); Flags.NONE has no bit, so it combines with nothing."""
    import dataclasses

    from eskin.link.protocol import PROTOCOL_VERSION

    d = DecisionFrame(onset_sample=1, offset_sample=2, label=0, values=(0.5,))
    assert (d.dont_know, d.decided_sample, d.timestamp_us, d.latency_us, d.seq, d.flags) == (
        False, 0, 0, 0, 0, 0)
    s = StatusFrame()
    for f in dataclasses.fields(s):
        if f.name != "state":
            assert getattr(s, f.name) in (0, False), f.name
    i = InfoFrame(rows=4, cols=4, sample_rate_hz=3000.0)
    assert (i.volts_per_count, i.speed, i.has_model, i.class_names, i.seq, i.flags) == (
        0.0, 1.0, False, (), 0, 0)
    assert i.protocol_version == PROTOCOL_VERSION
    for f in (PingFrame(token=1), PongFrame(token=1)):
        assert (f.timestamp_us, f.seq, f.flags) == (0, 0, 0)
    assert int(Flags.NONE) == 0 and Flags.SYNC | Flags.NONE == Flags.SYNC
    assert Flags(0) is Flags.NONE and not Flags.NONE


def test_reset_takes_reset_stats_by_name_only():
    dec = FrameDecoder(wait_for_delimiter=False)
    with pytest.raises(TypeError):
        dec.reset(True)  # which reset? refused: only reset(reset_stats=True) clears statistics


def test_after_reset_the_tail_of_a_frame_is_skipped_not_counted_as_corrupted():
    """A reopened port resumes anywhere: the decoder waits for the next delimiter again."""
    import numpy as np

    from eskin.link.protocol import DataFrame, FrameDecoder, encode_frame

    wire = b"\x00" + b"".join(encode_frame(DataFrame(
        first_sample=8 * i, timestamp_us=i, samples=np.full((8, 4, 4), i, np.int16), seq=i))
        for i in range(3))
    dec = FrameDecoder()
    assert [f.seq for f in dec.feed(wire[: len(wire) // 2])] == [0]  # and half of frame 1
    dec.reset()
    frames = dec.feed(wire[len(wire) // 2:] + wire)
    assert [f.seq for f in frames] == [2, 0, 1, 2]  # the tail of frame 1 is skipped
    st = dec.stats
    assert st.crc_errors == st.malformed == 0 and st.skipped_bytes > 0


def test_data_frames_are_equal_by_value_and_cannot_be_changed():
    """DATA frames of equal fields and samples (of one shape) are equal, whatever the arrays'
    identity; a frame is read-only and not hashable (it holds an array)."""
    import dataclasses

    s = np.arange(32, dtype=np.int16).reshape(2, 4, 4)
    a = DataFrame(3, 9, s)
    assert a == DataFrame(3, 9, s.copy())
    for other in (DataFrame(3, 9, s.reshape(4, 2, 4)), DataFrame(4, 9, s), DataFrame(3, 8, s),
                  DataFrame(3, 9, s, seq=1), DataFrame(3, 9, s, flags=1), DataFrame(3, 9, s + 1)):
        assert a != other
    with pytest.raises(TypeError, match="unhashable"):
        hash(a)
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.seq = 1  # type: ignore[misc]


@pytest.mark.parametrize("flags, overrun", [(0, False), (Flags.OVERRUN, True),
                                            (Flags.SYNC | Flags.LOOP, False),
                                            (Flags.SYNC | Flags.OVERRUN, True)])
def test_overrun_is_the_flags_overrun_bit_alone(flags, overrun):
    s = np.zeros((1, 2, 2), np.int16)
    assert StatusFrame(flags=int(flags)).overrun is overrun
    assert DataFrame(0, 0, s, flags=int(flags)).overrun is overrun


def test_a_command_carries_no_flags_and_sequence_0_unless_given():
    """A command made with its type alone has sequence 0 and flags 0, and reads back so."""
    for command in (FrameType.START, FrameType.STOP, FrameType.INFO_REQUEST):
        frame = CommandFrame(command)
        assert (frame.seq, frame.flags) == (0, 0)
        (back,) = FrameDecoder().feed(DELIMITER + encode_frame(frame))
        assert back == frame
