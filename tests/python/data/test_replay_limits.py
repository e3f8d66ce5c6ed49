"""The replay file's limits at their edges, each through both copies of its rule: the writer
(``write_replay_arrays``) and the reader (``read_replay_file``)."""

from __future__ import annotations

import errno
import os
import resource
import signal
import struct
import zlib

import numpy as np
import pytest

from eskin.data.replay import ReplayFormatError, read_replay_file, write_replay_arrays


def _recs(n: int = 2, grid=(2, 3), length: int = 20) -> list[np.ndarray]:
    rng = np.random.default_rng(11)
    return [rng.integers(-5, 5, size=(*grid, length)).astype(np.int16) for _ in range(n)]


def _rewrite(path, edit) -> None:
    """The file with ``edit(raw)`` applied to its bytes and its header CRC made right again."""
    raw = bytearray(path.read_bytes())
    edit(raw)
    data_offset = struct.unpack_from("<I", raw, 12)[0]
    struct.pack_into("<I", raw, 52, 0)
    struct.pack_into("<I", raw, 52, zlib.crc32(bytes(raw[:data_offset])))
    path.write_bytes(bytes(raw))


def _refusal(tmp_path, offset: int, fmt: str, value) -> str:
    """The reader's message on the two-recording file with one header field set to value."""
    p = tmp_path / "f.eskr"
    write_replay_arrays(p, _recs(), labels=[0, 1], class_names=["a", "b"], gap_s=0.01)
    _rewrite(p, lambda raw: struct.pack_into(fmt, raw, offset, value))
    with pytest.raises(ReplayFormatError) as info:
        read_replay_file(p)
    return str(info.value).removeprefix(f"{p}: ")


def _under_file_size_limit(write, size: int, folder) -> tuple[OSError, int]:
    """write() under a file size limit of size - 1 bytes (the error, and the bytes this
    process wrote meanwhile; nothing may be left in folder), then under one of size."""
    old_handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # past the limit: EFBIG
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    try:
        resource.setrlimit(resource.RLIMIT_FSIZE, (size - 1, hard))
        before = _bytes_written()
        with pytest.raises(OSError) as info:
            write()
        written = _bytes_written() - before
        assert list(folder.iterdir()) == []
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, hard))
        write()
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, old_handler)
    return info.value, written


def test_255_class_names_are_written_and_read_back_exactly(tmp_path):
    names = [f"c{k}" for k in range(255)]
    p = tmp_path / "255.eskr"
    write_replay_arrays(p, _recs(), labels=[0, 254], class_names=names, gap_s=0.01)
    rf = read_replay_file(p)
    assert rf.class_names == tuple(names)
    assert rf.segments["label"].tolist() == [0, 254]


def test_256_class_names_are_refused_by_the_writer(tmp_path):
    with pytest.raises(ValueError, match=r"^at most 255 class names, got 256$"):
        write_replay_arrays(tmp_path / "256.eskr", _recs(), labels=[0, 1],
                            class_names=[f"c{k}" for k in range(256)], gap_s=0.01)
    assert list(tmp_path.iterdir()) == []


def test_256_class_names_are_refused_by_the_reader(tmp_path):
    # 255 names, the last one "zz": its second byte made a newline gives 256 names ("z", "")
    # in the same number of bytes
    names = [f"c{k}" for k in range(254)] + ["zz"]
    p = tmp_path / "256.eskr"
    write_replay_arrays(p, _recs(), labels=[0, 1], class_names=names, gap_s=0.01)

    def split_last(raw: bytearray) -> None:
        at = bytes(raw).index(b"\nzz") + 2
        raw[at] = ord("\n")

    _rewrite(p, split_last)
    with pytest.raises(ReplayFormatError) as info:
        read_replay_file(p)
    assert str(info.value) == f"{p}: class names: 256 names, at most 255"


def test_a_label_is_a_class_index_exactly_below_the_number_of_names(tmp_path):
    p = tmp_path / "ok.eskr"
    write_replay_arrays(p, _recs(), labels=[-1, 2], class_names=["a", "b", "c"], gap_s=0.01)
    assert read_replay_file(p).segments["label"].tolist() == [-1, 2]
    with pytest.raises(ValueError, match=r"labels must be -1 or index class_names \(3 names\)"):
        write_replay_arrays(tmp_path / "w.eskr", _recs(), labels=[0, 3],
                            class_names=["a", "b", "c"], gap_s=0.01)
    with pytest.raises(ValueError, match=r"labels must be -1 or index class_names"):
        write_replay_arrays(tmp_path / "w.eskr", _recs(), labels=[-2, 0],
                            class_names=["a", "b", "c"], gap_s=0.01)
    # without class names only -1: the reader refuses any other label (the writer wrote such
    # a file and its own reader refused it)
    with pytest.raises(ValueError) as refused:
        write_replay_arrays(tmp_path / "w.eskr", _recs(), labels=[-1, 0], gap_s=0.01)
    assert str(refused.value) == "labels must be -1 or index class_names (0 names)"
    assert not (tmp_path / "w.eskr").exists()
    assert write_replay_arrays(p, _recs(), labels=[-1, -1]).segments["label"].tolist() == [-1] * 2


@pytest.mark.parametrize("grid", [(1, 1), (255, 1), (1, 255)])
def test_the_grid_edges_are_written_and_read(tmp_path, grid):
    p = tmp_path / "g.eskr"
    write_replay_arrays(p, _recs(1, grid, 8), labels=[0], class_names=["a"], gap_s=0.01)
    rf = read_replay_file(p)
    assert rf.samples.shape[1:] == grid
    assert rf.n_samples == rf.samples.shape[0]


@pytest.mark.parametrize("field, offset", [("rows", 24), ("cols", 26)])
@pytest.mark.parametrize("value", [0, 256])
def test_a_grid_outside_1_to_255_is_refused_by_the_reader(tmp_path, field, offset, value):
    p = tmp_path / "g.eskr"
    write_replay_arrays(p, _recs(1, (2, 3), 8), labels=[0], class_names=["a"], gap_s=0.01)
    _rewrite(p, lambda raw: struct.pack_into("<H", raw, offset, value))
    grid = f"{value}x3" if field == "rows" else f"2x{value}"
    with pytest.raises(ReplayFormatError) as info:
        read_replay_file(p)
    assert str(info.value) == f"{p}: grid: {grid} is not within 1..255 x 1..255"


SEG1 = 56 + 48  # the second segment: start u64, length u64, onset i64, offset i64, label i32


def _with_contact(tmp_path, onset: int, offset: int):
    """A file of two recordings of 20 samples, the second's contact interval set as given."""
    p = tmp_path / "c.eskr"
    write_replay_arrays(p, _recs(), labels=[0, 1], class_names=["a", "b"], gap_s=0.01,
                        contact_intervals=[[1, 10], [2, 12]])

    def edit(raw: bytearray) -> None:
        struct.pack_into("<qq", raw, SEG1 + 16, onset, offset)

    _rewrite(p, edit)
    return p


@pytest.mark.parametrize("onset, offset", [(-1, -1), (0, 20), (5, 5), (0, 0), (20, 20)])
def test_a_contact_within_its_recording_or_unknown_is_read(tmp_path, onset, offset):
    rf = read_replay_file(_with_contact(tmp_path, onset, offset))
    seg = rf.segments[1]
    assert (int(seg["contact_onset"]), int(seg["contact_offset"])) == (onset, offset)


@pytest.mark.parametrize("onset, offset", [(-1, 5), (5, -1), (-2, 5), (-1, 0), (10, 5), (0, 21),
                                           (21, 21), (-5, -1), (-1, -5)])
def test_a_contact_half_unknown_reversed_or_past_its_recording_is_refused(tmp_path, onset, offset):
    p = _with_contact(tmp_path, onset, offset)
    with pytest.raises(ReplayFormatError) as info:
        read_replay_file(p)
    assert str(info.value) == (
        f"{p}: segment 1: contact interval [{onset}, {offset}) is neither -1/-1 nor within "
        f"[0, length 20] with onset <= offset (1 bad segments)")


@pytest.mark.parametrize("vpc", [0.0, -0.5, -2.0])
def test_a_volts_per_count_not_above_zero_is_refused_by_the_reader(tmp_path, vpc):
    assert _refusal(tmp_path, 40, "<d", vpc) == (f"volts_per_count: {vpc!r} is not a finite "
                                                 "number > 0")


@pytest.mark.parametrize("n_labels", [1, 3])
def test_labels_are_exactly_one_per_recording(tmp_path, n_labels):
    with pytest.raises(ValueError, match=rf"^labels must have one entry per recording \(2\), "
                                         rf"got \({n_labels},\)$"):
        write_replay_arrays(tmp_path / "l.eskr", _recs(), labels=list(range(n_labels)),
                            class_names=["a", "b", "c"], gap_s=0.01)


def test_quiet_gaps_of_zero_noise_are_the_baseline_and_negative_noise_is_refused(tmp_path):
    recs = _recs()
    rf = write_replay_arrays(tmp_path / "q.eskr", recs, labels=[0, 1], class_names=["a", "b"],
                             gap_s=0.01, noise_counts=0.0, baseline=np.full((2, 3), 7.0))
    first = int(rf.segments[0]["start"])
    assert first > 0
    # the first gap ramps from the baseline to the first recording's edge, with no noise: it
    # starts at the baseline exactly
    assert (np.asarray(rf.samples[0]) == 7).all()
    with pytest.raises(ValueError, match=r"^noise_counts must be >= 0, got -0\.1$"):
        write_replay_arrays(tmp_path / "n.eskr", recs, labels=[0, 1], class_names=["a", "b"],
                            gap_s=0.01, noise_counts=-0.1)


def test_a_file_longer_than_its_header_says_is_refused(tmp_path):
    p = tmp_path / "long.eskr"
    write_replay_arrays(p, _recs(), labels=[0, 1], class_names=["a", "b"], gap_s=0.01)
    size = p.stat().st_size
    with open(p, "ab") as f:
        f.write(b"\0\0")
    with pytest.raises(ReplayFormatError) as info:
        read_replay_file(p)
    assert str(info.value) == f"{p}: size {size + 2} bytes, expected {size}"


def test_a_data_offset_inside_the_class_names_is_refused(tmp_path):
    p = tmp_path / "off.eskr"
    names = [f"class-{k:03d}" for k in range(20)]  # 199 bytes of names
    write_replay_arrays(p, _recs(), labels=[0, 1], class_names=names, gap_s=0.01)
    raw = p.read_bytes()
    names_len = struct.unpack_from("<I", raw, 48)[0]
    table_end = 56 + 2 * 48 + names_len
    assert names_len == 199
    bad = (table_end - 16) // 8 * 8  # a multiple of 8, 16 to 23 bytes short of the names' end
    _rewrite(p, lambda b: struct.pack_into("<I", b, 12, bad))
    with pytest.raises(ReplayFormatError) as info:
        read_replay_file(p)
    assert str(info.value) == f"{p}: bad data offset {bad}"


def test_a_recording_of_one_sample_is_written_and_one_of_none_refused(tmp_path):
    one = [np.arange(6, dtype=np.int16).reshape(2, 3, 1)]
    rf = write_replay_arrays(tmp_path / "one.eskr", one, labels=[0], class_names=["a"],
                             gap_s=0.01)
    start = int(rf.segments[0]["start"])
    assert int(rf.segments[0]["length"]) == 1
    assert np.array_equal(np.asarray(rf.samples[start]), one[0][:, :, 0])
    with pytest.raises(ValueError, match=r"^recording 0 has shape \(2, 3, 0\); expected "):
        write_replay_arrays(tmp_path / "none.eskr", [np.zeros((2, 3, 0), np.int16)],
                            labels=[0], class_names=["a"], gap_s=0.01)


@pytest.mark.parametrize("loud_end", [False, True])
def test_a_recordings_quiet_noise_is_the_quieter_of_its_two_ends(loud_end):
    from eskin.data.replay import _taxel_noise

    # 400 samples: the first and last tenth (40 each) alternate +-1 and +-10; a touch between
    n = 400
    quiet = np.where(np.arange(n) % 2, 1.0, -1.0)
    x = quiet.copy()
    x[40:360] = 500.0 * np.sin(np.arange(320) / 7.0)
    loud = slice(n - 40, n) if loud_end else slice(0, 40)
    x[loud] *= 10.0
    r = np.broadcast_to(x, (2, 3, n)).astype(np.int16)
    noise = _taxel_noise(r)
    assert noise.shape == (2, 3)
    np.testing.assert_allclose(noise, 1.0, rtol=2e-3)


def test_the_default_sample_rate_and_scale_are_3000_hz_and_one_volt_per_count(tmp_path):
    """Without them the header's sample_rate_hz (f64 at offset 32) is 3000 Hz and its
    volts_per_count (f64 at offset 40) 1.0, exactly."""
    p = tmp_path / "d.eskr"
    rf = write_replay_arrays(p, _recs(), gap_s=0.01)
    assert p.read_bytes()[32:48] == struct.pack("<dd", 3000.0, 1.0)
    assert rf.sample_rate_hz == 3000.0 and rf.segments["start"].tolist() == [30, 80]
    assert rf.volts_per_count == 1.0


@pytest.mark.parametrize("grid", [(0, 3), (2, 0), (256, 1), (1, 256)])
def test_a_grid_outside_one_to_255_rows_or_columns_is_refused_by_the_writer(tmp_path, grid):
    """A grid of 0 or 256 rows or columns is refused, the message giving the grid."""
    with pytest.raises(ValueError) as info:
        write_replay_arrays(tmp_path / "g.eskr", [np.zeros((*grid, 8), np.int16)], gap_s=0.01)
    assert str(info.value) == f"grid shape {grid} is not within 1..255 x 1..255"
    assert list(tmp_path.iterdir()) == []


def test_a_class_name_with_a_newline_is_refused_by_the_writer(tmp_path):
    """A newline, the names' separator in the file, is refused inside a class name."""
    with pytest.raises(ValueError) as info:
        write_replay_arrays(tmp_path / "n.eskr", _recs(), labels=[0, 1],
                            class_names=["a", "b\nc"], gap_s=0.01)
    assert str(info.value) == "class name 'b\\nc' contains a newline"
    assert list(tmp_path.iterdir()) == []


def _bytes_written() -> int:
    """Bytes this process has written so far (Linux, /proc/self/io: wchar)."""
    with open("/proc/self/io") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("wchar:"))


@pytest.mark.skipif(not os.path.exists("/proc/self/io"), reason="needs Linux's /proc/self/io")
@pytest.mark.parametrize("raw", [False, True])
def test_a_stream_past_the_file_size_limit_is_refused_before_a_byte_is_written(tmp_path, raw):
    """A 3 MB stream under a file size limit one byte short of it: EFBIG naming the file,
    nothing written; under a limit of exactly its size it is written (the header, 104 bytes
    with one segment, only in a replay file)."""
    rec = [np.zeros((16, 16, 6000), np.int16)]  # 6000 samples x 512 bytes: 3.07 MB
    size = (0 if raw else 104) + 6000 * 512
    p = tmp_path / "big.eskr"
    error, written = _under_file_size_limit(
        lambda: write_replay_arrays(p, rec, gap_s=0.0, _raw=raw), size, tmp_path)
    assert (error.errno, error.filename) == (errno.EFBIG, str(p))
    assert written == 0
    assert p.stat().st_size == size


@pytest.mark.parametrize("level, code", [(-40000.0, -32768), (40000.0, 32767), (-32768.0, -32768),
                                         (32767.0, 32767)])
def test_quiet_gaps_beyond_the_adc_codes_are_clipped_to_int16(tmp_path, level, code):
    rf = write_replay_arrays(tmp_path / "c.eskr", _recs(), labels=[0, 1], class_names=["a", "b"],
                             gap_s=0.01, noise_counts=0.0, baseline=np.full((2, 3), level))
    first = int(rf.segments[0]["start"])
    assert (np.asarray(rf.samples[:first]) == code).all()


@pytest.mark.parametrize("vpc", [0.0, -1.0, float("inf"), float("nan")])
def test_a_volts_per_count_not_a_finite_number_above_zero_is_refused_by_the_writer(tmp_path, vpc):
    with pytest.raises(ValueError) as info:
        write_replay_arrays(tmp_path / "v.eskr", _recs(), labels=[0, 1], class_names=["a", "b"],
                            gap_s=0.01, volts_per_count=vpc)
    assert str(info.value) == f"volts_per_count must be finite and > 0, got {vpc}"


def test_a_gap_of_0_to_an_hour_is_written_and_one_outside_refused(tmp_path):
    for gap_s, n in ((0.0, 2 * 20), (3600.0, 3 * 360 + 2 * 20)):
        rf = write_replay_arrays(tmp_path / "g.eskr", _recs(), gap_s=gap_s, sample_rate_hz=0.1)
        assert rf.n_samples == n
    for gap_s in (np.nextafter(3600.0, np.inf), -0.5, float("nan"), float("inf")):
        with pytest.raises(ValueError) as refused:
            write_replay_arrays(tmp_path / "b.eskr", _recs(), gap_s=gap_s)
        assert str(refused.value) == f"gap_s must be a number of seconds in [0, 3600], got {gap_s:g}"


@pytest.mark.parametrize("rate", [0.1, 1e6])
def test_the_sample_rates_at_the_limits_are_written(tmp_path, rate):
    rf = write_replay_arrays(tmp_path / "r.eskr", _recs(), gap_s=0.0, sample_rate_hz=rate)
    assert rf.sample_rate_hz == rate
    for bad in (np.nextafter(0.1, 0.0), np.nextafter(1e6, np.inf)):
        with pytest.raises(ValueError, match="sample_rate_hz must be 0.1 to 1e[+]06 Hz"):
            write_replay_arrays(tmp_path / "b.eskr", _recs(), gap_s=0.0, sample_rate_hz=bad)


def test_unknown_labels_and_contacts_are_minus_one_and_recordings_numbered_in_order(tmp_path):
    rf = write_replay_arrays(tmp_path / "u.eskr", _recs(3), gap_s=0.0)
    seg = rf.segments
    assert seg["label"].tolist() == [-1] * 3 and rf.class_names == ()
    assert seg["contact_onset"].tolist() == seg["contact_offset"].tolist() == [-1] * 3
    assert seg["recording"].tolist() == [0, 1, 2]


@pytest.mark.parametrize("shape", [(2, 3), (3, 2), (2, 1), (2,), (1, 2, 2)])
def test_contact_intervals_are_one_pair_per_recording(tmp_path, shape):
    with pytest.raises(ValueError) as refused:
        write_replay_arrays(tmp_path / "c.eskr", _recs(2), contact_intervals=np.zeros(shape))
    assert str(refused.value) == f"contact_intervals must be (2, 2), got {shape}"


@pytest.mark.parametrize("n", [1, 3])
def test_recording_indices_are_one_per_recording(tmp_path, n):
    with pytest.raises(ValueError) as refused:
        write_replay_arrays(tmp_path / "i.eskr", _recs(2), recording_indices=list(range(n)))
    assert str(refused.value) == f"recording_indices must have 2 entries, got ({n},)"


def test_a_recording_of_one_sample_has_no_quiet_noise():
    from eskin.data.replay import _taxel_noise

    assert _taxel_noise(np.full((2, 1, 1), 7, np.int16)).tolist() == [[0.0], [0.0]]


@pytest.mark.parametrize("n, q", [(15, 2), (25, 2), (1000, 100), (1009, 100), (2990, 299),
                                  (4000, 300)])
def test_a_recordings_quiet_noise_is_the_spread_about_a_line_of_a_tenth_at_each_end(n, q):
    """Per taxel: the least-squares line through the first (and the last) tenth of the
    recording, at least 2 and at most 300 samples, removed, and the smaller standard deviation
    of what is left: computed here with numpy's polyfit."""
    from eskin.data.replay import _taxel_noise

    rng = np.random.default_rng(n)
    t = np.arange(n)
    r = np.rint(rng.normal(0, 1, (2, 2, n)) * [[[3.0], [9.0]], [[1.0], [20.0]]]
                + 40.0 - 0.2 * t).astype(np.int16)

    def spread(part):
        u = np.arange(part.size)
        return np.std(part - np.polyval(np.polyfit(u, part, 1), u))

    want = np.array([[min(spread(r[i, j, :q].astype(float)), spread(r[i, j, -q:].astype(float)))
                      for j in range(2)] for i in range(2)])
    np.testing.assert_allclose(_taxel_noise(r), want, rtol=1e-9, atol=1e-9)


@pytest.mark.skipif(not os.path.exists("/proc/self/io"), reason="needs Linux's /proc/self/io")
def test_an_npy_past_the_file_size_limit_is_refused_before_a_byte_is_written(tmp_path):
    """Recordings as one .npy array (128 bytes of header, 2 x 16 x 3000 samples) under a file
    size limit one byte short of it: EFBIG before a byte is written; at exactly its size it is
    written."""
    from eskin.data.campaign import load_campaign, write_campaign
    from eskin.data.replay import write_recordings_npy

    n, length = 2, 3000
    write_campaign(tmp_path / "c.h5", np.zeros((n, 4, 4, length), np.int16),
                   lengths=np.full(n, length), modality=np.arange(n) % 2,
                   participant=np.ones(n, int), direction=np.zeros(n, int), run=np.full(n, 2),
                   modalities=["a", "b"], sample_rate_hz=1000.0, volts_per_count=1e-3,
                   source="recorded")
    camp = load_campaign(tmp_path / "c.h5")
    size = 128 + 2 * n * 16 * length
    out = tmp_path / "out"
    out.mkdir()
    p = out / "r.npy"
    error, written = _under_file_size_limit(lambda: write_recordings_npy(camp, None, p), size,
                                            out)
    assert error.errno == errno.EFBIG
    assert written <= 128  # the header, before the space for the samples is reserved
    assert p.stat().st_size == size


@pytest.mark.parametrize("version", [0, 2, 2**32 - 1])
def test_a_version_other_than_1_is_refused(tmp_path, version):
    assert _refusal(tmp_path, 8, "<I", version) == f"replay version {version}, expected 1"


@pytest.mark.parametrize("offset, message", [
    (164, "bad data offset 164"),  # not a multiple of 8
    (1728, "bad data offset 1728"),  # past the end of the file (1720 bytes)
    (1720, "size 1720 bytes, expected 3280"),  # at its end: the samples are then missing
])
def test_a_data_offset_off_the_grid_of_8_or_past_the_file_is_refused(tmp_path, offset, message):
    assert _refusal(tmp_path, 12, "<I", offset) == message
    assert (tmp_path / "f.eskr").stat().st_size == 160 + 2 * 6 * (3 * 30 + 2 * 20) == 1720


@pytest.mark.parametrize("delta", [1, -1])
def test_a_checksum_above_or_below_the_headers_is_refused(tmp_path, delta):
    p = tmp_path / "c.eskr"
    write_replay_arrays(p, _recs(), labels=[0, 1], class_names=["a", "b"], gap_s=0.01)
    raw = bytearray(p.read_bytes())
    crc = struct.unpack_from("<I", raw, 52)[0]
    struct.pack_into("<I", raw, 52, (crc + delta) % 2**32)
    p.write_bytes(bytes(raw))
    with pytest.raises(ReplayFormatError) as info:
        read_replay_file(p)
    assert str(info.value) == f"{p}: header checksum mismatch"
