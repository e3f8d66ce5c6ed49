"""A skin's campaign (eskin.data.campaign): the ``patches`` attribute and the per-recording
``/recordings/extra/patch`` field, read back and refused when they do not go together; and the
edges of a campaign's indexing, extra fields, default compression and recovery message (the
encoder's: test_campaign_encoder.py)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from eskin.data.campaign import (
    CampaignFormatError,
    CampaignWriter,
    Recovery,
    encode_recording,
    load_campaign,
    write_campaign,
)

N, T = 5, 40


def _skin(path: Path, patches: str = '["left", "right"]', patch=(0, 1, 1, 0, 1)) -> Path:
    sig = np.arange(N * 4 * 4 * T, dtype=np.int16).reshape(N, 4, 4, T) % 97
    return write_campaign(path, sig, modality=[0, 1, 0, 1, 0], participant=[1, 2, 3, 4, 5],
                          direction=[0] * N, run=[1] * N, modalities=["a", "b"],
                          sample_rate_hz=1000.0, volts_per_count=1e-3, source="recorded",
                          attrs={"patches": patches},
                          extras={"patch": np.asarray(patch, np.uint16)})


def _edit(path: Path, fn) -> Path:
    with h5py.File(path, "a") as f:
        fn(f)
    return path


def _refused(path: Path) -> str:
    """The loader's one-line refusal of ``path``."""
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(path)
    return str(info.value)


def test_a_skin_campaign_reads_back_its_patches_and_selects_by_them(tmp_path):
    with load_campaign(_skin(tmp_path / "s.h5")) as c:
        assert c.patches == ["left", "right"]
        assert c.patch.tolist() == [0, 1, 1, 0, 1]
        assert c.select(patch="right").participant.tolist() == [2, 3, 5]
        assert c.select(patch=0).participant.tolist() == [1, 4]


@pytest.mark.parametrize("text", ["[]", '["a", "a"]', '["a", ""]', "[1, 2]", "not json",
                                  '{"a": 1}', '"left"'])
def test_a_patches_attribute_other_than_distinct_ids_is_refused(tmp_path, text):
    path = _edit(_skin(tmp_path / "s.h5"), lambda f: f.attrs.__setitem__("patches", text))
    assert _refused(path) == (f"{path}: attribute 'patches': must be a JSON list of distinct "
                              f"patch ids, got {text!r}")


def test_the_patch_field_and_the_patches_attribute_go_together(tmp_path):
    no_ids = _edit(_skin(tmp_path / "a.h5"), lambda f: f.attrs.__delitem__("patches"))
    with pytest.raises(CampaignFormatError, match=r"attribute 'patches': missing: "):
        load_campaign(no_ids)
    no_column = _edit(_skin(tmp_path / "b.h5"),
                      lambda f: f["recordings/extra"].__delitem__("patch"))
    with pytest.raises(CampaignFormatError,
                       match=r"/recordings/extra/patch: missing \(the attribute 'patches'"):
        load_campaign(no_column)
    past = _edit(_skin(tmp_path / "c.h5"),
                 lambda f: f["recordings/extra/patch"].__setitem__(2, 2))
    assert _refused(past) == (f"{past}: /recordings/extra/patch: recording 2 has patch 2, "
                              f"past the 2 ids of the attribute 'patches'")
    far = _edit(_skin(tmp_path / "d.h5"),
                lambda f: f["recordings/extra/patch"].__setitem__(3, 7))
    assert _refused(far) == (f"{far}: /recordings/extra/patch: recording 3 has patch 7, "
                             f"past the 2 ids of the attribute 'patches'")


def test_an_extra_field_of_one_entry_too_many_and_of_one_recording_is_refused(tmp_path):
    path = _edit(_skin(tmp_path / "s.h5"),
                 lambda f: f["recordings/extra"].create_dataset("force", data=np.zeros(N + 1)))
    assert _refused(path) == (f"{path}: /recordings/extra/force: wrong shape ({N + 1},) "
                              f"(expected one entry per recording, n={N}, at most "
                              f"{(1 << 30) // N} bytes each)")
    one = write_campaign(tmp_path / "one.h5", np.zeros((1, 4, 4, T), np.int16), modality=[0],
                         participant=[1], direction=[0], run=[1], modalities=["a"],
                         sample_rate_hz=1000.0, volts_per_count=1e-3, source="recorded")
    _edit(one, lambda f: f["recordings"].create_dataset("extra/force", data=np.zeros(2)))
    assert _refused(one) == (f"{one}: /recordings/extra/force: wrong shape (2,) (expected one "
                             f"entry per recording, n=1, at most {1 << 30} bytes each)")


def test_a_recording_index_is_taken_from_either_end_and_no_further(tmp_path):
    with load_campaign(_skin(tmp_path / "s.h5")) as c:
        s = c.signals
        np.testing.assert_array_equal(s[-N], s[0])
        np.testing.assert_array_equal(s[N - 1], s[-1])
        assert not np.array_equal(s[0], s[1])
        for i in (N, N + 1, 2 * N, -N - 1, -2 * N):
            with pytest.raises(IndexError) as info:
                s[i]
            assert str(info.value) == f"recording index {i} out of range for {N} recordings"



def test_an_empty_selection_of_recordings_reads_as_no_recordings(tmp_path):
    sig = np.arange(N * 4 * 4 * T, dtype=np.int16).reshape(N, 4, 4, T) % 97  # as _skin writes
    with load_campaign(_skin(tmp_path / "s.h5")) as c:
        for i in range(N):  # each recording read alone is the one written
            np.testing.assert_array_equal(c.signals[i], sig[i])
        np.testing.assert_array_equal(c.signals[1:4], sig[1:4])
        for key in (slice(2, 2), [], np.array([], int)):
            assert c.signals[key].shape == (0, 4, 4, T)
        none = c.select(participant=99)
        assert np.asarray(none.signals).shape == (0, 4, 4, T)
        # one recording twice, and recordings out of order, read as asked
        np.testing.assert_array_equal(c.signals[[3, 3]], np.stack([c.signals[3]] * 2))
        np.testing.assert_array_equal(c.signals[[4, 0, 2]],
                                      np.stack([c.signals[i] for i in (4, 0, 2)]))

def test_an_extra_field_without_one_entry_per_recording_is_refused(tmp_path):
    """A scalar extra dataset (no first axis at all) is refused like one of another length."""
    for name, data in (("scalar", np.uint16(3)), ("short", np.zeros(N - 1, np.uint16))):
        path = _edit(_skin(tmp_path / f"{name}.h5"),
                     lambda f, name=name, data=data: f["recordings/extra"].create_dataset(
                         name, data=data))
        with pytest.raises(CampaignFormatError) as info:
            load_campaign(path)
        assert info.value.field == f"/recordings/extra/{name}"
        assert info.value.problem.startswith(f"wrong shape {np.shape(data)} (expected one entry "
                                             f"per recording, n={N}")



def test_an_extra_field_over_one_gibibyte_is_refused_before_it_is_read(tmp_path):
    """Declared, never written (HDF5 allocates nothing): 8 bytes over the 1 GiB limit."""
    per = (1 << 30) // 8 // N + 1  # float64 values per recording: N * per * 8 > 1 GiB
    path = _edit(_skin(tmp_path / "big.h5"),
                 lambda f: f["recordings/extra"].create_dataset("big", shape=(N, per),
                                                                dtype="f8", chunks=(1, 4096)))
    assert path.stat().st_size < 1 << 20
    with pytest.raises(CampaignFormatError) as info:
        load_campaign(path)
    assert (info.value.field, info.value.problem) == (
        "/recordings/extra/big", f"wrong shape ({N}, {per}) (expected one entry per recording, "
        f"n={N}, at most {(1 << 30) // N} bytes each)")

def test_the_writer_compresses_each_recording_with_deflate_level_one_by_default(tmp_path):
    """docs/dataset-format.md: gzip (deflate level 1) and the shuffle filter."""
    path = tmp_path / "w.h5"
    with CampaignWriter(path, n_samples=T, sample_rate_hz=1000.0, volts_per_count=1e-3,
                        modalities=["a"], source="recorded") as w:
        w.append(np.ones((4, 4, T), np.int16), modality=0, participant=1, direction=0, run=1)
    with h5py.File(path, "r") as f:
        ds = f["recordings/signals"]
        assert (ds.compression, ds.compression_opts, ds.shuffle) == ("gzip", 1, True)
        _, stored = ds.id.read_direct_chunk((0, 0, 0, 0))
    # a chunk made outside the writer (the simulator's workers) is, by default, the same bytes
    enc = encode_recording(np.ones((4, 4, T), np.int16), grid_shape=(4, 4), n_samples=T)
    assert (enc.compression_level, enc.chunk) == (1, stored)


def test_a_recovery_names_ten_skipped_records_and_counts_the_rest():
    def message(k: int) -> str:
        return Recovery(Path("r.h5"), 3, 0, "", tuple(f"s{i}" for i in range(k))).message()

    ten = message(10)
    assert "s9)" in ten and "more" not in ten
    twelve = message(12)
    assert "; s9; 2 more)" in twelve and "s10" not in twelve
    assert "skipped" not in message(0)


@pytest.mark.parametrize("column", [np.zeros((N, 2), np.uint16), np.zeros(N, np.int16)])
def test_a_patch_field_other_than_one_unsigned_index_per_recording_is_refused(tmp_path, column):
    def swap(f):
        del f["recordings/extra/patch"]
        f["recordings/extra"].create_dataset("patch", data=column)

    path = _edit(_skin(tmp_path / "s.h5"), swap)
    assert _refused(path) == (f"{path}: /recordings/extra/patch: must be unsigned integers "
                              f"(n,), got {column.dtype} {column.shape}")


def test_a_recording_indexed_with_more_axes_is_that_part_of_it(tmp_path):
    with load_campaign(_skin(tmp_path / "s.h5")) as c:
        s = c.signals
        np.testing.assert_array_equal(s[2, 1], s[2][1])
        np.testing.assert_array_equal(s[2, 1, 3], s[2][1, 3])
        np.testing.assert_array_equal(s[-1, :, 0, 5:9], s[N - 1][:, 0, 5:9])


def test_the_summary_gives_each_recordings_duration_in_seconds(tmp_path):
    with load_campaign(_skin(tmp_path / "s.h5")) as c:
        info = c.summary()
    assert info["duration_s"] == T / 1000.0 and info["samples_per_recording"] == T


def test_a_list_of_one_recording_is_written_and_an_empty_list_refused(tmp_path):
    one = np.ones((4, 4, T), np.int16)
    kw = {"modality": [0], "participant": [1], "direction": [0], "run": [1],
          "modalities": ["a"], "sample_rate_hz": 1000.0, "volts_per_count": 1e-3,
          "source": "recorded"}
    with load_campaign(write_campaign(tmp_path / "one.h5", [one], **kw)) as c:
        assert len(c) == 1
        np.testing.assert_array_equal(c.signals[0], one)
    with pytest.raises(ValueError) as info:
        write_campaign(tmp_path / "none.h5", [], **kw)
    assert str(info.value) == "no recordings given (use a (0, rows, cols, T) array)"
    assert not (tmp_path / "none.h5").exists()


@pytest.mark.parametrize("value", [2**31, -(2**31) - 1])
def test_an_in_memory_label_outside_its_stored_range_is_refused(value):
    from eskin.data.campaign import Campaign

    sig = np.zeros((2, 4, 4, T), np.int16)
    labels = {"modality": [0, 0], "participant": np.array([1, value], np.int64),
              "direction": [0, 0], "run": [1, 1]}
    with pytest.raises(CampaignFormatError) as info:
        Campaign(sig, np.full(2, T), modalities=["a"], sample_rate_hz=1000.0,
                 volts_per_count=1.0, source="recorded", **labels)
    assert info.value.field == "/recordings/participant"
    assert info.value.problem == (f"values out of the int32 range [-2147483648, 2147483647]: "
                                  f"min {min(1, value)}, max {max(1, value)}")


def test_a_contact_interval_outside_its_recording_is_named_with_its_bounds(tmp_path):
    """The rule has a copy in the writer and one in the loader: both refuse, naming the
    recording and the interval."""
    sig = np.zeros((2, 4, 4, T), np.int16)
    kw = {"modality": [0, 0], "participant": [1, 2], "direction": [0, 0], "run": [1, 1],
          "modalities": ["a"], "sample_rate_hz": 1000.0, "volts_per_count": 1e-3,
          "source": "recorded"}
    with pytest.raises(ValueError) as info:
        write_campaign(tmp_path / "w.h5", sig, contact_interval=np.array([[0, 3], [7, 5]]), **kw)
    assert str(info.value) == (f"{tmp_path / 'w.h5'}: recording 1: contact interval [7, 5) not "
                               f"within [0, {T}]")
    path = write_campaign(tmp_path / "r.h5", sig, contact_interval=np.array([[0, 3], [2, 5]]),
                          **kw)
    _edit(path, lambda f: f["recordings/contact_interval"].__setitem__(1, [7, 5]))
    assert _refused(path) == (f"{path}: /recordings/contact_interval: recording 1 has interval "
                              f"[7, 5), not within [0, length={T}] with onset <= offset")


def test_one_recording_of_an_empty_grid_is_refused(tmp_path):
    path = write_campaign(tmp_path / "one.h5", np.zeros((1, 4, 4, T), np.int16), modality=[0],
                          participant=[1], direction=[0], run=[1], modalities=["a"],
                          sample_rate_hz=1000.0, volts_per_count=1e-3, source="recorded")

    def empty(f):
        del f["recordings/signals"]
        f["recordings"].create_dataset("signals", shape=(1, 0, 4, T), dtype=np.int16)

    _edit(path, empty)
    assert _refused(path) == f"{path}: /recordings/signals: empty taxel grid 0x4"


@pytest.mark.parametrize("grid", [(1, 4), (4, 1), (1, 1)])
def test_a_strip_and_a_single_taxel_are_grids(tmp_path, grid):
    sig = np.arange(2 * grid[0] * grid[1] * T, dtype=np.int16).reshape(2, *grid, T)
    path = write_campaign(tmp_path / "strip.h5", sig, modality=[0, 0], participant=[1, 2],
                          direction=[0, 0], run=[1, 1], modalities=["a"],
                          sample_rate_hz=1000.0, volts_per_count=1e-3, source="recorded")
    with load_campaign(path) as c:
        assert c.grid_shape == grid
        np.testing.assert_array_equal(c.recording(1), sig[1])
    _edit(path, lambda f: (f["recordings"].__delitem__("signals"), f["recordings"].create_dataset(
        "signals", shape=(2, grid[0], 0, T), dtype=np.int16)))
    assert _refused(path) == f"{path}: /recordings/signals: empty taxel grid {grid[0]}x0"


def test_no_recordings_of_an_empty_grid_is_an_empty_campaign(tmp_path):
    """Nothing to read: the grid of a campaign without recordings is not checked."""
    path = write_campaign(tmp_path / "none.h5", np.zeros((0, 4, 4, T), np.int16), modality=[],
                          participant=[], direction=[], run=[], modalities=["a"],
                          sample_rate_hz=1000.0, volts_per_count=1e-3, source="recorded")

    def empty(f):
        del f["recordings/signals"]
        f["recordings"].create_dataset("signals", shape=(0, 4, 0, T), dtype=np.int16)

    with load_campaign(_edit(path, empty)) as c:
        assert len(c) == 0 and c.grid_shape == (4, 0)


def test_a_recording_longer_than_the_campaign_is_refused_by_the_encoder():
    with pytest.raises(ValueError) as info:
        encode_recording(np.zeros((4, 4, T + 1), np.int16), grid_shape=(4, 4), n_samples=T)
    assert str(info.value) == f"recording: {T + 1} samples, more than the campaign's T={T}"


def test_an_attribute_read_as_an_array_of_no_axes_is_its_value():
    from eskin.data.campaign import _decode

    assert _decode(np.array(5)) == 5 and type(_decode(np.array(5))) is int
    assert _decode(np.array(b"ab")) == "ab"
    assert _decode(np.array([1.5, 2.0])) == [1.5, 2.0]


def test_the_summary_counts_the_recordings_of_each_modality(tmp_path):
    with load_campaign(_skin(tmp_path / "s.h5")) as c:
        assert c.summary()["per_modality"] == {"a": 3, "b": 2}


def test_an_in_memory_extra_field_of_fewer_entries_than_recordings_is_refused():
    from eskin.data.campaign import Campaign

    sig = np.zeros((3, 4, 4, T), np.int16)
    labels = {"modality": [0, 0, 0], "participant": [1, 2, 3], "direction": [0, 0, 0],
              "run": [1, 1, 1]}
    with pytest.raises(CampaignFormatError) as info:
        Campaign(sig, np.full(3, T), modalities=["a"], sample_rate_hz=1000.0,
                 volts_per_count=1.0, source="recorded", extras={"force": np.zeros(2)},
                 **labels)
    assert (info.value.field, info.value.problem) == (
        "/recordings/extra/force", "wrong shape (2,) (expected one entry per recording, n=3)")
