"""A campaign built in memory (eskin.data.campaign.Campaign): the signals it takes and refuses,
its extra fields, its subsets by index and by mask, and its lazy signal view read as an array
or one recording at a time."""

from __future__ import annotations

import numpy as np
import pytest

from eskin.data.campaign import (
    Campaign,
    CampaignFormatError,
    CampaignSignals,
    load_campaign,
    write_campaign,
)

N, T = 4, 12
LABELS = {"modality": [0, 1, 0, 1], "participant": [1, 2, 3, 4], "direction": [0, 1, 0, 1],
          "run": [1, 1, 2, 2]}
SETTINGS = {"modalities": ["a", "b"], "sample_rate_hz": 1000.0, "volts_per_count": 0.5,
            "source": "recorded"}


def _signals() -> np.ndarray:
    return (np.arange(N * 2 * 3 * T) % 251).astype(np.int16).reshape(N, 2, 3, T)


def _campaign(signals=None, **kw) -> Campaign:
    sig = _signals() if signals is None else signals
    return Campaign(sig, kw.pop("lengths", np.full(N, T)), **{**LABELS, **SETTINGS, **kw})


def _refused(**kw) -> tuple[str, str]:
    with pytest.raises(CampaignFormatError) as info:
        _campaign(**kw)
    return info.value.field, info.value.problem


def test_a_list_of_recordings_is_taken_as_their_array():
    c = _campaign(list(_signals()))
    assert isinstance(c.signals, np.ndarray)
    np.testing.assert_array_equal(c.signals, _signals())


def test_lazy_signals_given_to_a_campaign_stay_lazy(tmp_path):
    path = write_campaign(tmp_path / "c.h5", _signals(), **LABELS, **SETTINGS)
    with load_campaign(path) as loaded:
        c = _campaign(loaded.signals)
        assert isinstance(c.signals, CampaignSignals)
        np.testing.assert_array_equal(c.recording(2), _signals()[2])


@pytest.mark.parametrize("shape", [(N, 2, 3), (N, 1, 2, 3, T), (N, 6 * T)])
def test_signals_without_four_axes_are_refused(shape):
    sig = np.zeros(shape, np.int16)
    assert _refused(signals=sig) == (
        "/recordings/signals", f"wrong shape {shape}: expected 4 axes (n, rows, cols, T)")


@pytest.mark.parametrize("dtype", ["int8", "uint16", "int32", "float32", "float64"])
def test_signals_other_than_int16_are_refused(dtype):
    assert _refused(signals=_signals().astype(dtype)) == (
        "/recordings/signals", f"wrong dtype {dtype} (expected int16)")


def test_extra_fields_of_one_entry_per_recording_are_kept_whatever_their_other_axes():
    extras = {"force": np.arange(N, dtype=float), "xy": np.zeros((N, 2), np.int32)}
    c = _campaign(extras=extras)
    assert sorted(c.extras) == ["force", "xy"]
    np.testing.assert_array_equal(c.extras["force"], extras["force"])
    np.testing.assert_array_equal(c.subset([3, 1]).extras["force"], [3.0, 1.0])


@pytest.mark.parametrize("value", [np.float64(2.0), np.zeros(N - 1), np.zeros(N + 1),
                                   np.zeros((N + 1, 2))])
def test_an_extra_field_without_one_entry_per_recording_is_refused(value):
    assert _refused(extras={"force": value}) == (
        "/recordings/extra/force",
        f"wrong shape {np.shape(value)} (expected one entry per recording, n={N})")


def test_a_subset_by_mask_needs_one_entry_per_recording():
    c = _campaign()
    sub = c.subset(np.array([True, False, True, True]))
    assert sub.participant.tolist() == [1, 3, 4]
    np.testing.assert_array_equal(sub.signals, _signals()[[0, 2, 3]])
    for mask in (np.ones(N - 1, bool), np.ones(N + 1, bool), np.ones((N, 1), bool)):
        with pytest.raises(ValueError) as info:
            c.subset(mask)
        assert str(info.value) == f"boolean mask has shape {mask.shape}, expected ({N},)"


def test_a_subset_by_index_takes_either_end_and_nothing_past_them():
    c = _campaign()
    assert c.subset([-1, 0, -N, N - 1]).participant.tolist() == [4, 1, 1, 4]
    assert c.subset(2).participant.tolist() == [3]
    assert len(c.subset([])) == 0
    for bad in ([N], [-N - 1], [0, N + 3]):
        with pytest.raises(IndexError) as info:
            c.subset(bad)
        assert str(info.value) == f"subset indices out of range for {N} recordings"


def test_the_lazy_view_reads_as_an_array_of_any_type_and_one_recording_at_a_time(tmp_path):
    path = write_campaign(tmp_path / "c.h5", _signals(), **LABELS, **SETTINGS)
    with load_campaign(path) as c:
        as_float = np.asarray(c.signals, dtype=np.float32)
        assert as_float.dtype == np.float32
        np.testing.assert_array_equal(as_float, _signals().astype(np.float32))
        assert np.asarray(c.signals).dtype == np.int16
        recordings = list(c.signals)
        assert len(recordings) == N
        for got, want in zip(recordings, _signals()):
            np.testing.assert_array_equal(got, want)
        # a recording and a part of it, with the remaining axes indexed as numpy would
        np.testing.assert_array_equal(c.signals[1, 0], _signals()[1, 0])
        np.testing.assert_array_equal(c.signals[-1, :, 2, 3:5], _signals()[-1, :, 2, 3:5])
        np.testing.assert_array_equal(c.signals_float(3), _signals()[3] * 0.5)


def test_a_campaign_of_one_recording_is_subset_from_either_end():
    c = _campaign().subset([2])
    assert c.subset([-1]).participant.tolist() == c.subset([0]).participant.tolist() == [3]
    with pytest.raises(IndexError):
        c.subset([1])


def test_selecting_by_patch_without_patches_or_by_an_unknown_patch_says_which(tmp_path):
    with pytest.raises(ValueError) as info:
        _campaign().select(patch=0)
    assert str(info.value) == "<memory>: no patch field (a one-patch campaign)"
    ids = [f"p{i}" for i in range(9)]
    patches = "[" + ", ".join(f'"{p}"' for p in ids) + "]"
    c = _campaign(attrs={"patches": patches}, extras={"patch": np.array([0, 8, 8, 1], np.uint16)})
    assert c.select(patch="p8").participant.tolist() == [2, 3]
    assert c.select(patch=["p1", 0]).participant.tolist() == [1, 4]
    with pytest.raises(ValueError) as info:
        c.select(patch="p9")
    assert str(info.value) == ("<memory>: attribute 'patches': no patch 'p9' (patches: "
                               "p0, p1, p2, p3, p4, p5, p6, p7, ...)")
    eight = _campaign(attrs={"patches": "[" + ", ".join(f'"{p}"' for p in ids[:8]) + "]"},
                      extras={"patch": np.array([0, 7, 7, 1], np.uint16)})
    with pytest.raises(ValueError) as info:
        eight.select(patch="p8")
    assert str(info.value) == ("<memory>: attribute 'patches': no patch 'p8' (patches: "
                               "p0, p1, p2, p3, p4, p5, p6, p7)")
    few = _campaign(attrs={"patches": '["l", "r"]'},
                    extras={"patch": np.array([0, 1, 1, 0], np.uint16)})
    with pytest.raises(ValueError) as info:
        few.select(patch="x")
    assert str(info.value) == "<memory>: attribute 'patches': no patch 'x' (patches: l, r)"
    path = write_campaign(tmp_path / "c.h5", _signals(), **LABELS, **SETTINGS)
    with load_campaign(path) as loaded, pytest.raises(ValueError) as info:
        loaded.select(patch=0)
    assert str(info.value) == f"{path}: no patch field (a one-patch campaign)"


def test_the_summary_of_no_recordings_and_of_recordings_with_intervals():
    empty = _campaign(np.zeros((0, 2, 3, T), np.int16), lengths=[], modality=[],
                      participant=[], direction=[], run=[])
    info = empty.summary()
    assert (info["length_min"], info["length_median"], info["length_max"]) == (0, 0.0, 0)
    assert info["has_contact_interval"] is False
    c = _campaign(lengths=[3, 5, 9, 12], contact_interval=[[0, 3], [1, 5], [0, 0], [2, 12]])
    info = c.summary()
    assert (info["length_min"], info["length_median"], info["length_max"]) == (3, 7.0, 12)
    assert info["has_contact_interval"] is True


def test_a_missing_campaign_file_mentions_recovery_only_when_a_journal_is_there(tmp_path):
    from eskin.data.journal import journal_path

    path = tmp_path / "gone.h5"
    with pytest.raises(FileNotFoundError) as info:
        load_campaign(path)
    assert str(info.value) == f"{path}: no such campaign file"
    journal_path(path).write_bytes(b"")
    with pytest.raises(FileNotFoundError) as info:
        load_campaign(path)
    assert str(info.value) == (f"{path}: no such campaign file (a writer was interrupted while "
                               f"writing it: `eskin recover {path}` salvages its recordings)")
