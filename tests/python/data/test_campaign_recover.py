"""Recovery in-process (eskin.data.campaign.recover_campaign): each journal record checked as
the loader checks a campaign, its extra fields held to the first record's type and shape, the
skipped ones named by index, and the campaign built from the rest."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eskin.data.campaign import CampaignWriter, encode_recording, load_campaign, recover_campaign

T = 20
META = {"length": T, "modality": 0, "participant": 5, "direction": 0, "run": 1}


def _journal(path: Path, records: list[dict]) -> None:
    """A writer's journal with one valid recording, then ``records`` (extra values given as
    (array, dtype) pairs, written as a buggy writer would), then one valid recording more."""
    w = CampaignWriter(path, grid_shape=(2, 2), n_samples=T, sample_rate_hz=1000.0,
                       volts_per_count=1.0, modalities=["a"], source="recorded",
                       extra_fields={"xy": "<f4"})
    w.append(np.ones((2, 2, T), np.int16), **{k: META[k] for k in META if k != "length"},
             extra={"xy": np.array([1.0, 2.0], np.float32)})
    chunk = encode_recording(np.zeros((2, 2, T), np.int16), grid_shape=(2, 2), n_samples=T).chunk
    for extras in records:
        w._journal.append(META, extras, chunk)
    w.append(np.full((2, 2, T), 3, np.int16), **{k: META[k] for k in META if k != "length"},
             extra={"xy": np.array([5.0, 6.0], np.float32)})
    w._journal.release()


def test_a_record_whose_extra_field_differs_from_the_first_is_skipped_by_name(tmp_path):
    path = tmp_path / "c.h5"
    _journal(path, [
        {"xy": (np.zeros(3, np.float32), np.dtype("<f4"))},  # another shape
        {"xy": (np.zeros(2), np.dtype("<f8"))},  # another type
        {"xy": (np.zeros((2, 1), np.float32), np.dtype("<f4"))},  # another number of axes
        {"xy": (np.zeros(1, np.float32), np.dtype("<f4"))},  # fewer values
        {"xy": (np.array([7.0, 8.0], np.float32), np.dtype("<f4"))},  # as the first: kept
    ])
    rec = recover_campaign(path)
    assert rec.recordings == 3
    assert rec.skipped == (
        "record 1: /recordings/extra/xy: float32 (3,), expected float32 (2,)",
        "record 2: /recordings/extra/xy: float64 (2,), expected float32 (2,)",
        "record 3: /recordings/extra/xy: float32 (2, 1), expected float32 (2,)",
        "record 4: /recordings/extra/xy: float32 (1,), expected float32 (2,)")
    with load_campaign(path) as c:
        assert c.extras["xy"].tolist() == [[1.0, 2.0], [7.0, 8.0], [5.0, 6.0]]
        assert (c.recording(2) == 3).all()


def test_recovery_never_replaces_a_campaign_unless_asked(tmp_path):
    path = tmp_path / "c.h5"
    _journal(path, [])
    other = tmp_path / "other.h5"
    other.write_bytes(b"recorded data")
    with pytest.raises(FileExistsError):
        recover_campaign(path, other)
    assert other.read_bytes() == b"recorded data"
    rec = recover_campaign(path, other, overwrite=True)
    assert rec.recordings == 2 and rec.output == other
    with load_campaign(other) as c:
        assert len(c) == 2


def test_a_chunk_of_another_size_is_skipped_with_the_bytes_it_holds(tmp_path):
    """A recording's chunk inflates to exactly rows x cols x T int16: more (read up to one
    byte past) or less is a damaged record."""
    path = tmp_path / "c.h5"
    w = CampaignWriter(path, grid_shape=(2, 2), n_samples=T, sample_rate_hz=1000.0,
                       volts_per_count=1.0, modalities=["a"], source="recorded")
    w.append(np.ones((2, 2, T), np.int16), modality=0, participant=1, direction=0, run=1)
    for t in (T + 10, T - 1):
        big = encode_recording(np.zeros((2, 2, t), np.int16), grid_shape=(2, 2), n_samples=t)
        w._journal.append(META, {}, big.chunk)
    w._journal.release()
    rec = recover_campaign(path)
    size = 2 * 2 * T * 2
    assert rec.recordings == 1
    assert rec.skipped == (
        f"record 1: /recordings/signals: the chunk holds {size + 1} bytes, not the {size} of a "
        f"2x2x{T} int16 recording",
        f"record 2: /recordings/signals: the chunk holds {size - 8} bytes, not the {size} of a "
        f"2x2x{T} int16 recording")


def test_the_recovery_message_says_what_was_kept_skipped_and_dropped():
    from eskin.data.campaign import Recovery

    out, kept = Path("c.h5"), Path(".c.h5.rejected")
    assert Recovery(out, 4, 0, "").message() == "recovered 4 complete recordings into c.h5"
    full = Recovery(out, 4, 37, "a torn record header", ("record 2: x", "record 5: y"), kept)
    assert full.message() == (
        "recovered 4 complete recordings into c.h5; skipped 2 invalid records (record 2: x; "
        "record 5: y); dropped the last 37 bytes of the journal (a torn record header); the "
        "journal is kept as .c.h5.rejected")


def test_a_recovery_result_cannot_be_changed():
    import dataclasses

    from eskin.data.campaign import Recovery

    with pytest.raises(dataclasses.FrozenInstanceError):
        Recovery(Path("c.h5"), 4, 0, "").recordings = 5


def test_a_campaign_placed_where_hard_links_are_not_supported_is_renamed_in(tmp_path,
                                                                           monkeypatch):
    """A memory card's FAT has no hard links: the exclusive link becomes check-then-rename."""
    import errno
    import os

    def no_links(src, dst):
        raise OSError(errno.EPERM, "Operation not permitted")

    path = tmp_path / "c.h5"
    _journal(path, [])
    monkeypatch.setattr(os, "link", no_links)
    rec = recover_campaign(path, tmp_path / "out.h5")
    assert rec.recordings == 2 and sorted(p.name for p in tmp_path.iterdir()) == ["out.h5"]
    with load_campaign(tmp_path / "out.h5") as c:
        assert len(c) == 2


@pytest.mark.parametrize("exc, prefix, reason", [
    (OSError(5, "Input/output error"), "[Errno 5] ", "Input/output error"),
    (OSError("the card went away (it was pulled)"), "", "the card went away"),
    (OSError(), "", "OSError")])
def test_an_error_placing_the_campaign_is_one_line_and_the_journal_stays(tmp_path, monkeypatch,
                                                                        exc, prefix, reason):
    """An unexpected error of the exclusive link, named by the system's message, else by its
    text up to the first parenthesis, else by its type."""
    import os

    from eskin.data.journal import journal_path

    def broken(src, dst):
        raise exc

    path = tmp_path / "c.h5"
    _journal(path, [])
    monkeypatch.setattr(os, "link", broken)
    with pytest.raises(OSError) as info:
        recover_campaign(path)
    assert str(info.value) == (f"{prefix}{path}: cannot write the campaign file ({reason}); the "
                               f"journal is kept: {journal_path(path)}")
    assert journal_path(path).exists() and not path.exists()
