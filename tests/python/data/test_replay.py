"""eskin.replay: the firmware simulator's input file."""

from __future__ import annotations

import numpy as np
import pytest

from eskin.data.replay import (
    ReplayFormatError,
    read_replay_file,
    write_replay_arrays,
    write_replay_file,
)


def test_arrays_round_trip_with_gaps(tmp_path):
    rng = np.random.default_rng(0)
    recs = [rng.integers(-500, 500, size=(4, 4, n)).astype(np.int16) for n in (100, 250)]
    rf = write_replay_arrays(
        tmp_path / "a.eskr", recs, labels=[1, 0], class_names=["a", "b"], gap_s=0.01,
        sample_rate_hz=3000.0, volts_per_count=1e-3, contact_intervals=[[10, 50], [0, 200]],
        noise_counts=2.0, baseline=np.zeros((4, 4)), seed=1,
    )
    assert rf.n_samples == 30 + 100 + 30 + 250 + 30
    assert rf.grid_shape == (4, 4)
    assert rf.class_names == ("a", "b")
    assert list(rf.segments["start"]) == [30, 160]
    assert list(rf.segments["label"]) == [1, 0]
    assert list(rf.segments["contact_onset"]) == [10, 0]
    for k, r in enumerate(recs):
        np.testing.assert_array_equal(rf.recording(k), r)
    gap = np.asarray(rf.samples[:30], dtype=float)
    assert abs(gap.mean()) < 1.5 and 0.5 < gap.std() < 4.0  # quiet noise around the baseline
    again = write_replay_arrays(tmp_path / "b.eskr", recs, gap_s=0.01, noise_counts=2.0, seed=1,
                                baseline=np.zeros((4, 4)))
    np.testing.assert_array_equal(again.samples, rf.samples)  # seeded


def test_from_a_simulated_campaign(tmp_path):
    from eskin.data.campaign import load_campaign
    from eskin.data.simulator import simulate

    path = simulate(tmp_path / "c.h5", participants=1, seed=3, runs=(2,))
    camp = load_campaign(path)
    rf = write_replay_file(camp, [0, 3], tmp_path / "c.eskr", gap_s=0.05)
    assert rf.class_names == tuple(camp.modalities)
    assert rf.sample_rate_hz == camp.sample_rate_hz
    assert rf.volts_per_count == pytest.approx(camp.volts_per_count)
    assert list(rf.segments["recording"]) == [0, 3]
    assert list(rf.segments["label"]) == [int(camp.modality[0]), int(camp.modality[3])]
    np.testing.assert_array_equal(rf.segments["contact_onset"],
                                  np.asarray(camp.contact_interval)[[0, 3], 0])
    np.testing.assert_array_equal(rf.recording(1), camp.recording(3))


def test_bad_files_are_named(tmp_path):
    p = tmp_path / "x.eskr"
    p.write_bytes(b"hello")
    with pytest.raises(ReplayFormatError, match="x.eskr.*magic"):
        read_replay_file(p)
    rng = np.random.default_rng(0)
    recs = [rng.integers(-5, 5, size=(2, 3, 40)).astype(np.int16)]
    write_replay_arrays(p, recs, gap_s=0.0)
    raw = bytearray(p.read_bytes())
    raw[60] ^= 1  # inside the segment table
    p.write_bytes(bytes(raw))
    with pytest.raises(ReplayFormatError, match="checksum"):
        read_replay_file(p)
    write_replay_arrays(p, recs, gap_s=0.0)
    p.write_bytes(p.read_bytes()[:-2])
    with pytest.raises(ReplayFormatError, match="size"):
        read_replay_file(p)


def test_argument_errors(tmp_path):
    ok = np.zeros((4, 4, 10), np.int16)
    with pytest.raises(ValueError, match="at least one"):
        write_replay_arrays(tmp_path / "e.eskr", [])
    for bad in ((3, 4, 10), (5, 4, 10), (4, 3, 10), (4, 5, 10), (4, 4), (4, 4, 10, 1)):
        with pytest.raises(ValueError) as refused:
            write_replay_arrays(tmp_path / "e.eskr", [ok, np.zeros(bad, np.int16)])
        assert str(refused.value) == (f"recording 1 has shape {bad}; expected (rows, cols, "
                                      "length) with grid (4, 4)")
    with pytest.raises(ValueError, match="integer"):
        write_replay_arrays(tmp_path / "e.eskr", [ok.astype(float)])
    with pytest.raises(ValueError, match="labels"):
        write_replay_arrays(tmp_path / "e.eskr", [ok], labels=[3], class_names=["a"])


def test_default_gaps_ramp_between_recording_levels_so_boundaries_are_not_touches(tmp_path):
    # Two quiet recordings sitting at different DC levels (an amplifier offset that differs
    # from one recording to the next): the gaps must join them without a step, which the
    # touch detector would report as a touch.
    from eskin.signal.preprocess import TouchDetector

    rng = np.random.default_rng(5)
    fs = 3000.0
    recs = [
        (level + 8.0 * rng.standard_normal((4, 4, 3000))).astype(np.int16)
        for level in (-15.0, 15.0)
    ]
    rf = write_replay_arrays(tmp_path / "r.eskr", recs, gap_s=0.5, sample_rate_hz=fs,
                             noise_counts=8.0, seed=2)
    s = np.asarray(rf.samples, dtype=float)
    g = int(rf.segments["start"][1]) - 1500  # the gap between the two recordings
    assert abs(np.median(s[g : g + 5]) - (-15.0)) < 8  # starts where recording 0 ends
    assert abs(np.median(s[g + 1495 : g + 1500]) - 15.0) < 8  # ends where recording 1 starts
    assert abs(np.median(s[1495:1500]) - (-15.0)) < 8  # the leading gap sits at the first level
    det = TouchDetector((4, 4), fs)
    assert det.push(rf.samples) + det.flush() == []
    # with a fixed baseline the gaps stay flat
    flat = write_replay_arrays(tmp_path / "f.eskr", recs, gap_s=0.5, sample_rate_hz=fs,
                               noise_counts=8.0, baseline=np.zeros((4, 4)), seed=2)
    assert abs(np.median(np.asarray(flat.samples[g : g + 1500], dtype=float))) < 2



def _patched(tmp_path, name, edits):
    """A valid replay file with header/segment bytes replaced and the header CRC recomputed,
    so that only the edited field is wrong."""
    import struct
    import zlib

    rng = np.random.default_rng(0)
    recs = [rng.integers(-5, 5, size=(2, 3, n)).astype(np.int16) for n in (40, 60)]
    p = tmp_path / name
    write_replay_arrays(p, recs, labels=[0, 1], class_names=["a", "b"], gap_s=0.01,
                        contact_intervals=[[1, 30], [0, 60]])
    raw = bytearray(p.read_bytes())
    for offset, fmt, value in edits:
        struct.pack_into(fmt, raw, offset, value)
    data_offset = struct.unpack_from("<I", raw, 12)[0]
    struct.pack_into("<I", raw, 52, 0)
    struct.pack_into("<I", raw, 52, zlib.crc32(bytes(raw[:data_offset])))
    p.write_bytes(bytes(raw))
    return p


SEG1 = 56 + 48  # the second segment: start u64, length u64, onset i64, offset i64, label i32
BAD_REPLAYS = {
    "rate inf": ([(32, "<d", float("inf"))], "sample_rate_hz: inf is not a rate of 0.1 to "
                 "1e+06 Hz"),
    "rate 0": ([(32, "<d", 0.0)], "sample_rate_hz: 0.0 is not a rate of 0.1 to 1e+06 Hz"),
    "rate 1e300": ([(32, "<d", 1e300)], "sample_rate_hz: 1e+300 is not a rate of 0.1 to "
                   "1e+06 Hz"),
    "rate 1e-300": ([(32, "<d", 1e-300)], "sample_rate_hz: 1e-300 is not a rate of 0.1 to "
                    "1e+06 Hz"),
    "volts NaN": ([(40, "<d", float("nan"))], "volts_per_count: nan is not a finite number > 0"),
    "volts inf": ([(40, "<d", float("inf"))], "volts_per_count: inf is not a finite number > 0"),
    "start at the end": ([(SEG1, "<Q", 190)], "segment 1: start 190 + length 60 runs past the "
                         "end of the stream (190 samples)"),
    "start past the end": ([(SEG1, "<Q", 191)], "segment 1: start 191 + length 60 runs past "
                           "the end of the stream (190 samples)"),
    "ends after the end": ([(SEG1, "<Q", 131)], "segment 1: start 131 + length 60 runs past the "
                           "end of the stream (190 samples)"),
    "grid 4096": ([(24, "<H", 4096)], "grid: 4096x3 is not within 1..255 x 1..255"),
    "segment past the end": ([(SEG1, "<Q", 2**63)], "segment 1: start 9223372036854775808 + "
                             "length 60 runs past the end of the stream"),
    "huge length": ([(SEG1 + 8, "<Q", 2**64 - 1)], "segment 1: start 100 + length "
                    "18446744073709551615 runs past the end"),
    "empty segment": ([(SEG1 + 8, "<Q", 0)], "segment 1: length 0 is 0"),
    "label 7": ([(SEG1 + 32, "<i", 7)], "segment 1: label 7 is neither -1 nor a class index (< 2)"),
    "label 2": ([(SEG1 + 32, "<i", 2)], "segment 1: label 2 is neither -1 nor a class index (< 2) "
                "(1 bad segments)"),
    "label -2": ([(SEG1 + 32, "<i", -2)], "segment 1: label -2 is neither -1 nor a class index"),
    "two labels": ([(56 + 32, "<i", 5), (SEG1 + 32, "<i", 2)], "segment 0: label 5 is neither "
                   "-1 nor a class index (< 2) (2 bad segments)"),
    "contact past length": ([(SEG1 + 24, "<q", 61)], "segment 1: contact interval [0, 61) is "
                            "neither -1/-1 nor within [0, length 60]"),
    "names not UTF-8": ([(56 + 2 * 48, "<B", 0xFF)], "class names: not valid UTF-8"),
}


@pytest.mark.parametrize("case", sorted(BAD_REPLAYS))
def test_bad_header_fields_and_segments_are_named(tmp_path, case):
    edits, message = BAD_REPLAYS[case]
    p = _patched(tmp_path, "bad.eskr", edits)
    with pytest.raises(ReplayFormatError) as info:
        read_replay_file(p)
    assert str(info.value).startswith(f"{p}: {message}"), str(info.value)


def test_listen_with_a_bad_replay_is_a_one_line_error(tmp_path):
    from typer.testing import CliRunner

    from eskin.cli import app

    p = _patched(tmp_path, "bad.eskr", BAD_REPLAYS["segment past the end"][0])
    r = CliRunner().invoke(app, ["listen", str(tmp_path / "no-port"), "--replay", str(p)])
    assert r.exit_code == 2
    assert r.output.startswith(f"error: {p}: segment 1: start 9223372036854775808")
    assert r.output.count("\n") == 1 and "Traceback" not in r.output


def test_writer_refuses_non_finite_scales(tmp_path):
    ok = [np.zeros((2, 2, 10), np.int16)]
    for rate in (float("inf"), float("nan"), 1e300, 1e-300):
        with pytest.raises(ValueError, match=r"sample_rate_hz must be 0.1 to 1e\+06 Hz, got "):
            write_replay_arrays(tmp_path / "e.eskr", ok, sample_rate_hz=rate)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="volts_per_count must be finite"):
        write_replay_arrays(tmp_path / "e.eskr", ok, volts_per_count=float("nan"))


# --------------------------------------------------------------------------- eskin-classify inputs


def _campaign_of_arrays(path, lengths):
    from eskin.data.campaign import load_campaign, write_campaign

    rng = np.random.default_rng(4)
    sig = rng.integers(-900, 900, size=(len(lengths), 4, 4, max(lengths))).astype(np.int16)
    for i, n in enumerate(lengths):
        sig[i, ..., n:] = 0
    n = len(lengths)
    write_campaign(
        path, sig, lengths=np.asarray(lengths), modality=np.arange(n) % 2,
        participant=np.arange(n) // 2 + 1, direction=np.zeros(n, int), run=np.full(n, 2),
        modalities=["tap", "slide"], sample_rate_hz=1000.0, volts_per_count=1e-3, source="recorded",
    )
    return load_campaign(path), sig


def test_recordings_as_one_npy_array(tmp_path):
    from eskin.data.replay import write_recordings_npy

    camp, sig = _campaign_of_arrays(tmp_path / "same.h5", [300, 300, 300])
    assert write_recordings_npy(camp, [2, 0], tmp_path / "r.npy") == (2, 4, 4, 300)
    got = np.load(tmp_path / "r.npy")
    assert got.dtype == np.dtype("<i2")
    np.testing.assert_array_equal(got, sig[[2, 0]])
    camp, _ = _campaign_of_arrays(tmp_path / "mixed.h5", [300, 120, 250])
    with pytest.raises(ValueError, match=r"r2.npy: the 3 recordings have different lengths "
                                         r"\(120 to 300 samples\).*--format records"):
        write_recordings_npy(camp, None, tmp_path / "r2.npy")


def test_raw_records_keep_each_length(tmp_path):
    from eskin.data.replay import write_raw_records

    camp, sig = _campaign_of_arrays(tmp_path / "mixed.h5", [300, 120, 250])
    assert write_raw_records(camp, None, tmp_path / "r.rec") == 3
    raw = (tmp_path / "r.rec").read_bytes()
    pos = 0
    for i, n in enumerate((300, 120, 250)):
        assert raw[pos : pos + 4] == b"ESKR"
        assert np.frombuffer(raw, "<u2", 2, pos + 4).tolist() == [4, 4]
        assert np.frombuffer(raw, "<u4", 2, pos + 8).tolist() == [n, 0]
        body = np.frombuffer(raw, "<i2", 16 * n, pos + 16).reshape(4, 4, n)
        np.testing.assert_array_equal(body, sig[i, ..., :n])
        pos += 16 + 32 * n
    assert pos == len(raw)


def test_raw_stream_is_the_replay_files_samples_without_its_header(tmp_path):
    """The raw stream is the bytes of the replay file from data_offset on, nothing else."""
    from eskin.data.replay import write_raw_stream

    camp, sig = _campaign_of_arrays(tmp_path / "same.h5", [300, 300, 300])
    n = write_raw_stream(camp, [2, 0], tmp_path / "s.raw", gap_s=0.01, seed=3)
    write_replay_file(camp, [2, 0], tmp_path / "s.eskr", gap_s=0.01, seed=3)
    raw, eskr = (tmp_path / "s.raw").read_bytes(), (tmp_path / "s.eskr").read_bytes()
    data_offset = int(np.frombuffer(eskr, "<u4", 1, 12)[0])
    assert raw == eskr[data_offset:]
    assert n == (10 + 300 + 10 + 300 + 10, 4, 4) and len(raw) == 2 * 630 * 16
    samples = np.frombuffer(raw, "<i2").reshape(630, 4, 4)
    np.testing.assert_array_equal(samples[10:310], np.moveaxis(sig[2], -1, 0))


def test_default_gap_noise_ramps_between_the_recordings_noise(tmp_path):
    # recordings of one campaign can differ severalfold in noise (another day, another hum): a gap
    # at one level for all would be loud next to a quiet recording, and a stream detector that
    # has learnt the quiet recording's floor would take it for a touch
    from eskin.signal.preprocess import TouchDetector

    rng = np.random.default_rng(4)
    fs = 1000.0
    recs = [np.rint(rng.normal(0, s, (4, 4, 3000))).astype(np.int16) for s in (2.0, 8.0, 2.0)]
    rf = write_replay_arrays(tmp_path / "n.eskr", recs, gap_s=2.0, sample_rate_hz=fs, seed=1)
    x = np.asarray(rf.samples, dtype=float)

    def noise(a, b, s=x):  # per taxel over time (the gap's level ramps too)
        return float(s[a:b].std(axis=0).mean())

    gap = int(rf.segments["start"][1]) - 2000  # the gap from the quiet to the loud recording
    assert 1.5 < noise(gap, gap + 20) < 4.0  # starts at the quiet recording's noise
    assert 6.5 < noise(gap + 1980, gap + 2000) < 10.0  # ends at the loud one's
    # geometrically: the same ratio every second, which a detector's noise floor follows
    assert 3.2 < noise(gap + 990, gap + 1010) < 4.8
    back = int(rf.segments["start"][2]) - 2000  # and back down
    assert noise(back, back + 20) > 6.5 and noise(back + 1980, back + 2000) < 3.0
    det = TouchDetector((4, 4), fs)
    assert det.push(x.reshape(len(x), -1)) + det.flush() == []  # no touch anywhere
    # a noise level given is the level of every gap
    flat = write_replay_arrays(tmp_path / "f.eskr", recs, gap_s=2.0, sample_rate_hz=fs, seed=1,
                               noise_counts=5.0)
    y = np.asarray(flat.samples, dtype=float)
    assert 4.0 < noise(gap, gap + 100, y) < 6.0 and 4.0 < noise(gap + 1900, gap + 2000, y) < 6.0


def test_a_grid_of_unequal_sides_reads_back_rows_by_columns(tmp_path):
    rng = np.random.default_rng(2)
    recs = [rng.integers(-500, 500, size=(2, 5, n)).astype(np.int16) for n in (60, 40)]
    rf = write_replay_arrays(tmp_path / "g.eskr", recs, gap_s=0.0, baseline=np.zeros((2, 5)))
    assert rf.grid_shape == (2, 5) and rf.samples.shape[1:] == (2, 5)
    for k, r in enumerate(recs):
        np.testing.assert_array_equal(rf.recording(k), r)


@pytest.mark.parametrize("names, data_offset", [(["a", "bc"], 160), (["abc", "defg"], 160),
                                                (["abc", "defgh"], 168)])
def test_the_header_and_segments_sit_at_the_offsets_the_format_documents(tmp_path, names,
                                                                         data_offset):
    """docs/wire-protocol.md, "Replay file": each field at its offset, in its type, little-endian;
    the reserved field 0; the names then zeros up to data_offset, the next multiple of 8 at or
    after them (56 + 2 x 48 bytes of segments + 4, 8 or 9 of names); the CRC over
    [0, data_offset) with its own field taken as 0."""
    import struct
    import zlib

    rng = np.random.default_rng(5)
    recs = [rng.integers(-9, 9, size=(2, 3, n)).astype(np.int16) for n in (7, 5)]
    write_replay_arrays(tmp_path / "f.eskr", recs, labels=[1, -1], class_names=names,
                        sample_rate_hz=2000.0, volts_per_count=0.25, gap_s=0.002,
                        contact_intervals=[[1, 6], [-1, -1]], recording_indices=[9, 4],
                        noise_counts=0.0, baseline=np.zeros((2, 3)))
    raw = (tmp_path / "f.eskr").read_bytes()
    assert raw[:8] == b"ESKREPLY"
    (version, offset, n_samples, rows, cols, n_seg, rate, vpc, names_len,
     crc) = struct.unpack_from("<IIQHHIddII", raw, 8)
    text = "\n".join(names).encode()
    assert (version, n_samples, rows, cols, n_seg) == (1, 4 + 7 + 4 + 5 + 4, 2, 3, 2)
    assert (rate, vpc, names_len, offset) == (2000.0, 0.25, len(text), data_offset)
    segs = [struct.unpack_from("<QQqqiIQ", raw, 56 + 48 * k) for k in range(2)]
    assert segs == [(4, 7, 1, 6, 1, 9, 0), (15, 5, -1, -1, -1, 4, 0)]
    end = 152 + len(text)
    assert raw[152:end] == text and raw[end:data_offset] == b"\0" * (data_offset - end)
    assert crc == zlib.crc32(raw[:52] + b"\0" * 4 + raw[56:data_offset])
    assert len(raw) == data_offset + 2 * n_samples * 6


def test_a_replay_is_read_only_once_read(tmp_path):
    import dataclasses

    rf = write_replay_arrays(tmp_path / "r.eskr", [np.zeros((1, 1, 3), np.int16)], gap_s=0.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        rf.sample_rate_hz = 1.0  # type: ignore[misc]


def test_the_default_gap_is_half_a_second_and_made_in_missing_folders(tmp_path):
    from eskin.data.replay import write_raw_stream

    rf = write_replay_arrays(tmp_path / "new" / "dir" / "r.eskr",
                             [np.zeros((1, 1, 3), np.int16)] * 2, sample_rate_hz=100.0)
    assert list(rf.segments["start"]) == [50, 103] and rf.n_samples == 156
    camp, _ = _campaign_of_arrays(tmp_path / "c.h5", [30, 30])
    assert write_raw_stream(camp, None, tmp_path / "s.raw") == (3 * 500 + 60, 4, 4)  # 1 kHz
    assert (tmp_path / "s.raw").stat().st_size == 2 * 16 * (3 * 500 + 60)
    # seeded with 0 by default: the same stream as seed 0, another than seed 1's
    rf = write_replay_file(camp, None, tmp_path / "d.eskr")
    assert list(rf.segments["start"]) == [500, 1030]
    raw = (tmp_path / "s.raw").read_bytes()
    assert np.asarray(rf.samples).tobytes() == raw
    for seed, same in ((0, True), (1, False)):
        other = write_replay_file(camp, None, tmp_path / f"{seed}.eskr", seed=seed)
        assert np.array_equal(other.samples, rf.samples) is same
        write_raw_stream(camp, None, tmp_path / f"{seed}.raw", seed=seed)
        assert ((tmp_path / f"{seed}.raw").read_bytes() == raw) is same


def test_each_gap_meets_the_recordings_it_joins(tmp_path):
    """Without noise, the gap before the first recording is flat at the median of its first
    10 ms, the gap after the last flat at the median of its last 10 ms, and a gap between two
    ramps linearly from the one's last 10 ms to the other's first (30 samples at 3 kSps)."""
    head = np.full((1, 2, 60), 100, np.int16)
    head[:, :, 30:] = 400  # the first recording ends at 400
    head[0, 1, :30] = 200  # taxel 1 starts at 200
    tail = np.full((1, 2, 60), -300, np.int16)
    tail[:, :, 30:] = -50  # the last ends at -50
    middle = np.full((1, 2, 60), 1000, np.int16)
    rf = write_replay_arrays(tmp_path / "e.eskr", [head, middle, tail], gap_s=0.01,
                             noise_counts=0.0)
    x = np.asarray(rf.samples, dtype=np.int64)[:, 0, :]  # (time, taxel)
    assert (x[:30] == [100, 200]).all()
    assert (x[-30:] == [-50, -50]).all()
    for at, a, b in ((90, 400, 1000), (180, 1000, -300)):
        ramp = np.rint(a + (b - a) * np.linspace(0, 1, 30))
        assert (x[at:at + 30] == ramp[:, None]).all()


def test_the_first_gap_has_the_first_recordings_noise_and_the_last_the_lasts(tmp_path):
    rng = np.random.default_rng(8)
    recs = [np.rint(rng.normal(0, s, (2, 2, 3000))).astype(np.int16) for s in (3.0, 60.0)]
    rf = write_replay_arrays(tmp_path / "n.eskr", recs, gap_s=1.0, sample_rate_hz=1000.0,
                             seed=2)
    x = np.asarray(rf.samples, dtype=float)
    first, last = x[:1000].std(axis=0).mean(), x[-1000:].std(axis=0).mean()
    assert 2.5 < first < 3.5 and 50.0 < last < 70.0


def test_recordings_beyond_the_adc_codes_are_clipped_to_int16(tmp_path):
    codes = [-40000, -32769, -32768, -32767, 0, 32766, 32767, 32768, 40000]
    rec = np.asarray(codes, np.int32).reshape(1, 1, -1)
    rf = write_replay_arrays(tmp_path / "c.eskr", [rec], gap_s=0.0)
    assert rf.recording(0).ravel().tolist() == [-32768, -32768, -32768, -32767, 0, 32766, 32767,
                                                32767, 32767]


def test_more_recordings_than_small_integers_are_joined_each_to_the_next(tmp_path):
    """300 one-sample recordings (beyond the integers Python keeps as one object): each gap
    ramps from the one before to the one after it."""
    recs = [np.full((1, 1, 1), 4 * k, np.int16) for k in range(300)]
    rf = write_replay_arrays(tmp_path / "m.eskr", recs, gap_s=0.001, noise_counts=0.0)
    x = np.asarray(rf.samples).ravel()  # gaps of 3 samples at 3 kSps
    assert x.tolist() == [0, 0, 0] + sum(([4 * k, 4 * k, 4 * k + 2, 4 * k + 4] for k in
                                          range(299)), []) + [1196] * 4


def test_below_100_hz_a_gap_meets_the_single_sample_at_each_edge(tmp_path):
    """The edge level is the median of 10 ms, at least one sample: at 40 Hz (0.4 samples) the
    recording's first and last samples themselves."""
    rec = np.asarray([[[7, 50, 60, 70, -9]]], np.int16)
    rf = write_replay_arrays(tmp_path / "l.eskr", [rec], gap_s=0.1, sample_rate_hz=40.0,
                             noise_counts=0.0)
    assert np.asarray(rf.samples).ravel().tolist() == [7] * 4 + [7, 50, 60, 70, -9] + [-9] * 4


def test_a_recording_shorter_than_10_ms_gives_its_whole_median(tmp_path):
    rec = np.zeros((1, 2, 5), np.int16)
    rec[0, :, :] = [[1], [2]] * np.asarray([10, 10, 40, 90, 90])  # 5 samples: 1.7 ms
    rf = write_replay_arrays(tmp_path / "s.eskr", [rec], gap_s=0.01, noise_counts=0.0)
    x = np.asarray(rf.samples)[:, 0, :]
    assert (x[:30] == [40, 80]).all() and (x[-30:] == [40, 80]).all()


def test_a_gap_beside_a_recording_without_noise_starts_at_a_tenth_of_a_count(tmp_path):
    """A recording without noise (constant) has quiet noise 0: the gap's noise ramps from 0.1
    count instead (a geometric ramp needs two levels above 0), so its first samples, rounded,
    are the level's, and its middle has the geometric mean of 0.1 and the next's noise."""
    rng = np.random.default_rng(6)
    quiet = np.zeros((4, 4, 2000), np.int16)
    loud = np.rint(rng.normal(0, 40.0, (4, 4, 2000))).astype(np.int16)
    rf = write_replay_arrays(tmp_path / "z.eskr", [quiet, loud, quiet], gap_s=1.0,
                             sample_rate_hz=1000.0, seed=3)
    t = np.linspace(0.0, 1.0, 1000)[:, None, None]
    gap = np.asarray(rf.samples[3000:4000], dtype=float)  # quiet -> loud
    level = np.median(loud[:, :, :10], axis=2)  # the ramp's end
    resid = gap - level[None] * t  # the level ramps from 0 to the loud one's start
    assert (np.abs(resid[:10]) < 1.0).all()  # noise of 0.1 and the rounding's 0.5
    mid = resid[450:550].std()  # sqrt(0.1 * 40) = 2
    assert 1.5 < mid < 2.6, mid
    back = np.asarray(rf.samples[6000:7000], dtype=float)  # loud -> quiet
    resid = back - np.median(loud[:, :, -10:], axis=2)[None] * (1.0 - t)
    assert (np.abs(resid[-10:]) < 1.0).all() and 1.5 < resid[450:550].std() < 2.6


def test_the_quiet_gaps_are_seeded_with_0_by_default(tmp_path):
    recs = [np.zeros((2, 2, 50), np.int16)] * 2
    rf = write_replay_arrays(tmp_path / "d.eskr", recs, noise_counts=3.0, sample_rate_hz=100.0)
    for seed, same in ((0, True), (1, False)):
        other = write_replay_arrays(tmp_path / f"{seed}.eskr", recs, noise_counts=3.0,
                                    sample_rate_hz=100.0, seed=seed)
        assert np.array_equal(other.samples, rf.samples) is same


def test_a_raw_stream_of_a_grid_of_unequal_sides_says_rows_then_columns(tmp_path):
    from eskin.data.replay import write_raw_stream

    camp, _ = _unequal_grid_campaign(tmp_path / "g.h5", [40, 30])
    assert write_raw_stream(camp, [1], tmp_path / "g.raw", gap_s=0.002) == (2 + 30 + 2, 2, 5)
    assert (tmp_path / "g.raw").stat().st_size == 2 * 10 * 34


def test_batch_files_take_one_recording_and_refuse_none(tmp_path):
    from eskin.data.replay import write_raw_records, write_recordings_npy

    camp, sig = _campaign_of_arrays(tmp_path / "c.h5", [50, 50])
    assert write_recordings_npy(camp, [1], tmp_path / "one.npy") == (1, 4, 4, 50)
    assert write_raw_records(camp, [1], tmp_path / "one.rec") == 1
    for write, name in ((write_recordings_npy, "none.npy"), (write_raw_records, "none.rec")):
        with pytest.raises(ValueError) as refused:
            write(camp, [], tmp_path / name)
        assert str(refused.value) == "no recordings to write"
        assert not (tmp_path / name).exists()


def _unequal_grid_campaign(path, lengths):
    from eskin.data.campaign import load_campaign, write_campaign

    n = len(lengths)
    sig = (np.arange(n * 2 * 5 * max(lengths), dtype=np.int64) % 300).astype(np.int16)
    sig = sig.reshape(n, 2, 5, max(lengths))
    write_campaign(path, sig, lengths=np.asarray(lengths), modality=np.arange(n) % 2,
                   participant=np.ones(n, int), direction=np.zeros(n, int), run=np.full(n, 2),
                   modalities=["tap", "slide"], sample_rate_hz=1000.0, volts_per_count=1e-3,
                   source="recorded")
    return load_campaign(path), sig


def test_an_npy_of_a_grid_of_unequal_sides_is_recordings_by_rows_by_columns(tmp_path):
    from eskin.data.replay import write_recordings_npy

    camp, sig = _unequal_grid_campaign(tmp_path / "g.h5", [30, 40, 30])
    assert write_recordings_npy(camp, [2, 0], tmp_path / "g.npy") == (2, 2, 5, 30)
    np.testing.assert_array_equal(np.load(tmp_path / "g.npy"), sig[[2, 0], ..., :30])
    header = 128  # numpy's format 1.0 header, padded to 64 bytes (here 128)
    assert (tmp_path / "g.npy").stat().st_size == header + 2 * 2 * 10 * 30


def test_raw_records_of_a_grid_of_unequal_sides_say_rows_then_columns(tmp_path):
    from eskin.data.replay import write_raw_records

    camp, sig = _unequal_grid_campaign(tmp_path / "g.h5", [30, 40])
    assert write_raw_records(camp, [1], tmp_path / "g.rec") == 1
    raw = (tmp_path / "g.rec").read_bytes()
    assert raw[:16] == b"ESKR" + np.asarray([2, 5], "<u2").tobytes() + np.asarray(
        [40, 0], "<u4").tobytes()
    np.testing.assert_array_equal(np.frombuffer(raw, "<i2", offset=16).reshape(2, 5, 40), sig[1])


@pytest.mark.parametrize("size", [8, 30, 55])
def test_a_file_shorter_than_the_header_is_not_a_replay_file(tmp_path, size):
    """The magic followed by less than the 56-byte header."""
    p = tmp_path / "short.eskr"
    p.write_bytes((b"ESKREPLY" + bytes(range(48)))[:size])
    with pytest.raises(ReplayFormatError) as refused:
        read_replay_file(p)
    assert str(refused.value) == f"{p}: not an eskin replay file (bad magic)"


@pytest.mark.parametrize("magic", [b"ESKREPLX", b"ESKREPLZ", b"eskreply", b"\0" * 8])
def test_a_file_of_another_magic_is_not_a_replay_file(tmp_path, magic):
    write_replay_arrays(tmp_path / "r.eskr", [np.zeros((1, 1, 4), np.int16)], gap_s=0.0)
    p = tmp_path / "r.eskr"
    p.write_bytes(magic + p.read_bytes()[8:])
    with pytest.raises(ReplayFormatError) as refused:
        read_replay_file(p)
    assert str(refused.value) == f"{p}: not an eskin replay file (bad magic)"
