"""The campaign writer's arguments and per-recording labels (eskin.data.campaign.CampaignWriter):
each refused with a message naming the file, the recording and the value, at and past every
boundary, and what it takes written as given."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eskin.data.campaign import (
    CampaignFormatError,
    CampaignWriter,
    encode_recording,
    load_campaign,
)

T = 16
REC = np.ones((2, 2, T), np.int16)
LABELS = {"modality": 0, "participant": 1, "direction": 0, "run": 1}


def _writer(path: Path, **kw) -> CampaignWriter:
    args = {"grid_shape": (2, 2), "n_samples": T, "sample_rate_hz": 1000.0,
            "volts_per_count": 1.0, "modalities": ["a", "b"], "source": "recorded"}
    return CampaignWriter(path, **{**args, **kw})


@pytest.mark.parametrize("kw, message", [
    ({"on_error": "ignore"}, "on_error must be 'keep' or 'discard', got 'ignore'"),
    ({"grid_shape": (0, 4)}, "grid_shape must be positive, got (0, 4)"),
    ({"grid_shape": (4, 0)}, "grid_shape must be positive, got (4, 0)"),
    ({"n_samples": 0}, "n_samples must be >= 1, got 0"),
    ({"compression_level": 10}, "compression_level must be None or 0..9, got 10"),
    ({"compression_level": -1}, "compression_level must be None or 0..9, got -1"),
    ({"extra_fields": {"note": object}}, "extra field 'note': dtype object cannot be stored (use "
                                         "a numeric or fixed-size dtype)"),
])
def test_a_writer_argument_out_of_range_is_refused_and_leaves_nothing(tmp_path, kw, message):
    with pytest.raises(ValueError) as info:
        _writer(tmp_path / "c.h5", **kw)
    assert str(info.value) == message
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("level", [None, 0, 9])
def test_the_ends_of_the_arguments_are_taken(tmp_path, level):
    with _writer(tmp_path / "c.h5", grid_shape=(1, 1), n_samples=1,
                 compression_level=level) as w:
        w.append(np.ones((1, 1, 1), np.int16), **LABELS)
        assert len(w) == 1 and w.journal.exists()
    with load_campaign(tmp_path / "c.h5") as c:
        assert c.signals.shape == (1, 1, 1, 1)


def test_the_output_must_be_a_file_in_a_folder_that_exists(tmp_path):
    with pytest.raises(IsADirectoryError) as info:
        _writer(tmp_path, overwrite=True)
    assert str(info.value) == f"{tmp_path}: is a directory"
    with pytest.raises(FileNotFoundError) as info:
        _writer(tmp_path / "no" / "c.h5")
    assert str(info.value) == f"{tmp_path / 'no'}: output folder does not exist"


@pytest.mark.parametrize("labels, message", [
    ({"modality": "c"}, "unknown modality 'c' (campaign modalities: ['a', 'b'])"),
    ({"modality": 2}, "modality id 2 out of range"),
    ({"modality": -1}, "modality id -1 out of range"),
    ({"direction": 2}, "direction 2 (0 horizontal, 1 vertical, 255 unknown)"),
    ({"run": 256}, "run 256 outside [0, 255]"),
    ({"run": -1}, "run -1 outside [0, 255]"),
    ({"participant": 2**31}, f"participant {2**31} outside the int32 range"),
    ({"participant": -(2**31) - 1}, f"participant {-(2**31) - 1} outside the int32 range"),
])
def test_a_label_out_of_range_is_refused_naming_the_recording(tmp_path, labels, message):
    with _writer(tmp_path / "c.h5") as w:
        w.append(REC, **LABELS)
        with pytest.raises(ValueError) as info:
            w.append(REC, **{**LABELS, **labels})
        assert str(info.value) == f"{tmp_path / 'c.h5'}: recording 1: {message}"
        assert len(w) == 1


def test_the_ends_of_each_label_are_written_as_given(tmp_path):
    ends = [{"modality": "b", "direction": 255, "run": 0, "participant": -(2**31)},
            {"modality": 1, "direction": 1, "run": 255, "participant": 2**31 - 1}]
    with _writer(tmp_path / "c.h5") as w:
        for labels in ends:
            w.append(REC, **labels)
    with load_campaign(tmp_path / "c.h5") as c:
        assert c.modality.tolist() == [1, 1] and c.direction.tolist() == [255, 1]
        assert c.run.tolist() == [0, 255]
        assert c.participant.tolist() == [-(2**31), 2**31 - 1]


def test_contact_intervals_are_required_and_within_the_recording(tmp_path):
    path = tmp_path / "c.h5"
    with _writer(path, contact_interval=True) as w:
        with pytest.raises(ValueError) as info:
            w.append(REC, **LABELS)
        assert str(info.value) == f"{path}: recording 0: contact_interval required"
        for bad in ((-1, 3), (5, 4), (0, 11)):
            with pytest.raises(ValueError) as info:
                w.append(REC, **LABELS, length=10, contact_interval=bad)
            assert str(info.value) == (f"{path}: recording 0: contact interval [{bad[0]}, "
                                       f"{bad[1]}) not within [0, 10]")
        w.append(REC, **LABELS, length=10, contact_interval=(0, 10))
        w.append(REC, **LABELS, length=10, contact_interval=(4, 4))
    with load_campaign(path) as c:
        assert c.contact_interval.tolist() == [[0, 10], [4, 4]]


def test_an_encoded_recording_of_another_length_and_extra_fields_not_declared_are_refused(
        tmp_path):
    path = tmp_path / "c.h5"
    enc = encode_recording(REC, grid_shape=(2, 2), n_samples=T, length=10)
    with _writer(path, extra_fields={"force": "<f4"}) as w:
        with pytest.raises(ValueError) as info:
            w.append(enc, **LABELS, length=9, extra={"force": 1.0})
        assert str(info.value) == (f"{path}: recording 0: length 9 differs from the encoded "
                                   f"recording's 10")
        for extra in ({}, {"force": 1.0, "speed": 2.0}, {"speed": 2.0}):
            with pytest.raises(ValueError) as info:
                w.append(enc, **LABELS, extra=extra)
            assert str(info.value) == (f"{path}: recording 0: extra fields {sorted(extra)} do "
                                       f"not match the declared extra_fields ['force']")
        assert w.append(enc, **LABELS, length=10, extra={"force": 1.5}) == 0
    with load_campaign(path) as c:
        assert c.lengths.tolist() == [10] and c.extras["force"].tolist() == [1.5]


def test_a_closed_writer_refuses_appends_and_closes_once(tmp_path):
    w = _writer(tmp_path / "c.h5")
    w.append(REC, **LABELS)
    w.close()
    w.close()  # nothing more to do
    with pytest.raises(ValueError) as info:
        w.append(REC, **LABELS)
    assert str(info.value) == f"{tmp_path / 'c.h5'}: writer is closed"
    with load_campaign(tmp_path / "c.h5") as c:
        assert len(c) == 1


def test_an_existing_file_is_never_overwritten_unless_asked(tmp_path):
    path = tmp_path / "c.h5"
    path.write_bytes(b"recorded data")
    with pytest.raises(FileExistsError) as info:
        _writer(path)
    assert str(info.value) == (f"{path}: file exists; refusing to overwrite recorded data (pass "
                               f"overwrite=True, or --force on the command line)")
    assert path.read_bytes() == b"recorded data"
    with _writer(path, overwrite=True) as w:
        w.append(REC, **LABELS)
    with load_campaign(path) as c:
        assert len(c) == 1


@pytest.mark.parametrize("durable, syncs", [(None, 2), (True, 2), (False, 0)])
def test_each_append_reaches_the_disk_unless_durability_is_turned_off(tmp_path, monkeypatch,
                                                                      durable, syncs):
    import os

    kw = {} if durable is None else {"durable": durable}
    w = _writer(tmp_path / "c.h5", **kw)
    calls = []
    real = os.fdatasync
    monkeypatch.setattr(os, "fdatasync", lambda fd: (calls.append(fd), real(fd)))
    w.append(REC, **LABELS)
    w.append(REC, **LABELS)
    assert len(calls) == syncs
    monkeypatch.undo()
    w.close()


def test_a_grid_past_the_limits_is_refused_before_anything_is_written(tmp_path):
    from eskin.data import limits

    side = limits.MAX_GRID_SIDE + 1
    with pytest.raises(CampaignFormatError) as info:
        _writer(tmp_path / "c.h5", grid_shape=(side, 1))
    assert str(info.value).startswith(f"{tmp_path / 'c.h5'}: /recordings/signals: shape "
                                      f"(0, {side}, 1, {T}): ")
    assert list(tmp_path.iterdir()) == []


def _left(tmp_path: Path) -> list[str]:
    return sorted(p.name for p in tmp_path.iterdir())


def test_an_error_in_the_block_keeps_what_returned_and_says_so(tmp_path):
    path = tmp_path / "c.h5"
    with pytest.raises(RuntimeError) as info:
        with _writer(path) as w:
            w.append(REC, **LABELS)
            w.append(REC, **LABELS)
            raise RuntimeError("the sensor went away")
    assert info.value.__notes__ == [
        f"{path}: the 2 recordings whose append returned are kept in the journal {w.journal}; "
        f"`eskin recover {path}` builds the campaign from them"]
    assert _left(tmp_path) == [w.journal.name]


def test_a_failed_append_is_named_as_not_kept(tmp_path):
    path = tmp_path / "c.h5"
    with pytest.raises(ValueError) as info:
        with _writer(path) as w:
            w.append(REC, **LABELS)
            w.append(REC, **{**LABELS, "run": 300})
    assert info.value.__notes__[0].endswith(
        " builds the campaign from them (recording 1, whose append failed, is not among them)")
    assert "the 1 recordings whose append returned" in info.value.__notes__[0]


@pytest.mark.parametrize("on_error, appends", [("discard", 2), ("keep", 0)])
def test_an_error_with_nothing_to_keep_or_told_to_discard_leaves_nothing(tmp_path, on_error,
                                                                          appends):
    with pytest.raises(RuntimeError) as info:
        with _writer(tmp_path / "c.h5", on_error=on_error) as w:
            for _ in range(appends):
                w.append(REC, **LABELS)
            raise RuntimeError("stop")
    assert not getattr(info.value, "__notes__", [])
    assert _left(tmp_path) == []


def test_abort_and_keep_inside_the_block_end_the_writer(tmp_path):
    with _writer(tmp_path / "a.h5") as w:
        w.append(REC, **LABELS)
        w.abort()
    assert _left(tmp_path) == []
    with _writer(tmp_path / "k.h5") as w:
        w.append(REC, **LABELS)
        text = w.keep()
        with pytest.raises(ValueError, match="writer is closed"):
            w.append(REC, **LABELS)
    assert text.startswith(f"{tmp_path / 'k.h5'}: the 1 recordings whose append returned")
    assert "whose append failed" not in text
    assert _left(tmp_path) == [w.journal.name]  # kept for `eskin recover`, nothing built


def _whole(path: Path, n: int = 3, **kw):
    from eskin.data.campaign import write_campaign

    args = {"modality": [0] * n, "participant": list(range(n)), "direction": [0] * n,
            "run": [1] * n, "modalities": ["a"], "sample_rate_hz": 1000.0,
            "volts_per_count": 1.0, "source": "recorded"}
    return write_campaign(path, kw.pop("signals", np.ones((n, 2, 2, T), np.int16)),
                          **{**args, **kw})


@pytest.mark.parametrize("name", ["modality", "participant", "direction", "run", "lengths"])
@pytest.mark.parametrize("count", [2, 4])
def test_a_whole_campaign_needs_one_label_per_recording(tmp_path, name, count):
    value = ([T] if name == "lengths" else [0]) * count
    with pytest.raises(ValueError) as info:
        _whole(tmp_path / "c.h5", **{name: value})
    got = f"got shape ({count},)" if name != "lengths" else f"got ({count},)"
    assert str(info.value) == f"{name} must have one entry per recording (3), {got}"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kw, message", [
    ({"contact_interval": [[0, 1]] * 2}, "contact_interval must have shape (3, 2), got (2, 2)"),
    ({"contact_interval": [[0, 1, 2]] * 3}, "contact_interval must have shape (3, 2), got (3, 3)"),
    ({"extras": {"f": np.zeros(4)}}, "extras['f'] must have one entry per recording (3), got "
                                     "shape (4,)"),
    ({"extras": {"f": np.float32(1)}}, "extras['f'] must have one entry per recording (3), got "
                                       "shape ()"),
    ({"signals": np.ones((3, 4, T), np.int16)}, f"signals must be (n, rows, cols, T), got shape "
                                                f"(3, 4, {T})"),
    ({"signals": np.ones((3, 1, 2, 2, T), np.int16)},
     f"signals must be (n, rows, cols, T), got shape (3, 1, 2, 2, {T})"),
])
def test_a_whole_campaign_of_mismatched_parts_is_refused(tmp_path, kw, message):
    with pytest.raises(ValueError) as info:
        _whole(tmp_path / "c.h5", **kw)
    assert str(info.value) == message
    assert list(tmp_path.iterdir()) == []


def test_recordings_of_different_lengths_are_padded_to_the_longest(tmp_path):
    recs = [np.full((2, 2, 5), 1, np.int16), np.full((2, 2, 9), 2, np.int16)]
    path = _whole(tmp_path / "c.h5", n=2, signals=recs)
    with load_campaign(path) as c:
        assert c.signals.shape == (2, 2, 2, 9) and c.lengths.tolist() == [5, 9]
        assert c.recording(0).shape == (2, 2, 5) and (c.recording(1) == 2).all()


@pytest.mark.parametrize("t", [0, 1])
def test_recordings_of_no_or_one_sample_make_a_campaign_of_one_sample(tmp_path, t):
    path = _whole(tmp_path / "c.h5", signals=np.ones((3, 2, 2, t), np.int16))
    with load_campaign(path) as c:
        assert c.signals.shape == (3, 2, 2, 1) and c.lengths.tolist() == [t] * 3


def test_a_list_of_recordings_takes_its_grid_from_the_first(tmp_path):
    recs = [np.ones((2, 2, 5), np.int16), np.ones((3, 2, 5), np.int16)]
    with pytest.raises(ValueError) as info:
        _whole(tmp_path / "c.h5", n=2, signals=recs)
    assert str(info.value) == (f"{tmp_path / 'c.h5'}: recording 1: signals must have shape "
                               f"(2, 2, length), got (3, 2, 5)")


def test_saving_a_campaign_never_replaces_a_file_unless_asked(tmp_path):
    from eskin.data.campaign import save_campaign

    with load_campaign(_whole(tmp_path / "c.h5")) as c:
        target = tmp_path / "copy.h5"
        target.write_bytes(b"recorded data")
        with pytest.raises(FileExistsError):
            save_campaign(c.subset([0, 2]), target)
        assert target.read_bytes() == b"recorded data"
        save_campaign(c.subset([0, 2]), target, overwrite=True)
    with load_campaign(target) as copy:
        assert copy.participant.tolist() == [0, 2]
