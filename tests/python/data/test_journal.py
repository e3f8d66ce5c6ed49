"""The recording journal (eskin.data.journal) on its own: what reaches the disk and when, and
what its reader accepts, skips or drops."""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from eskin.data import journal as jr
from eskin.errors import JournalError

SETTINGS = {
    "grid_shape": [2, 2],
    "n_samples": 0,
    "compression_level": None,
    "contact_interval": True,
    "extra_fields": [["force", "<f4"]],
    "attrs": [],
}
META = {"length": 3, "modality": 1, "participant": 2, "direction": 0, "run": 1,
        "contact_interval": [0, 3]}


def write(tmp_path: Path, n: int = 2, settings=None, **kw) -> Path:
    w = jr.JournalWriter(tmp_path / "c.h5", settings or SETTINGS, **kw)
    for k in range(n):
        w.append(META, {"force": (np.float32(k), np.dtype("<f4"))}, bytes([k]) * 24)
    w.release()
    return w.path


def read(path: Path):
    with jr.LockedJournal(path) as j:
        contents = j.read()
        return contents, [r for r in contents.records()]


def test_records_read_back_in_order_with_their_labels_and_extras(tmp_path):
    contents, records = read(write(tmp_path, 3))
    assert contents.settings == SETTINGS
    assert [r.index for r in records] == [0, 1, 2]
    assert [r.chunk for r in records] == [bytes([k]) * 24 for k in range(3)]
    assert [float(r.extras["force"]) for r in records] == [0.0, 1.0, 2.0]
    assert all(r.meta == META for r in records)
    assert contents.dropped_bytes == 0 and contents.skipped == []


@pytest.mark.parametrize("durable", [True, False])
def test_the_header_and_its_directory_entry_reach_the_disk_and_appends_when_durable(
        tmp_path, monkeypatch, durable):
    """The real fsync calls, counted: the header and the folder once at creation, then one
    data sync per append only when durable."""
    calls: list[str] = []
    real_fsync, real_fdatasync = os.fsync, os.fdatasync

    def fsync(fd):
        calls.append("dir" if os.path.isdir(f"/proc/self/fd/{fd}") else "file")
        real_fsync(fd)

    def fdatasync(fd):
        calls.append("append")
        real_fdatasync(fd)

    monkeypatch.setattr(jr.os, "fsync", fsync)
    monkeypatch.setattr(jr.os, "fdatasync", fdatasync)
    write(tmp_path, 3, durable=durable)
    assert calls[:2] == ["file", "dir"]
    assert calls[2:] == (["append"] * 3 if durable else [])


def test_a_record_replayed_at_the_next_place_is_not_taken_for_it(tmp_path):
    """A record copied after itself has a valid CRC but the wrong index: the reader stops
    there instead of reading it twice."""
    path = write(tmp_path, 1)
    data = path.read_bytes()
    header_end = len(jr.HEADER_MAGIC) + 4 + struct.unpack("<I", data[8:12])[0] + 4
    path.write_bytes(data + data[header_end:])
    contents, records = read(path)
    assert len(records) == 1
    assert contents.dropped_bytes == len(data) - header_end
    assert "no record 1 where expected" in contents.dropped_reason


def test_a_torn_last_record_is_dropped_and_measured(tmp_path):
    path = write(tmp_path, 2)
    data = path.read_bytes()
    path.write_bytes(data[:-5])
    contents, records = read(path)
    assert len(records) == 1 and contents.dropped_bytes > 0
    assert "incomplete" in contents.dropped_reason


@pytest.mark.parametrize(
    ("key", "value"),
    [("grid_shape", [2]), ("grid_shape", [2, "2"]), ("n_samples", 1.5),
     ("compression_level", "9"), ("contact_interval", 1), ("extra_fields", [["force"]]),
     ("extra_fields", [["force", 4]]), ("extra_fields", [["force", "<f4", "x"]]),
     ("grid_shape", [2, 2, 2]), ("attrs", [[1, 2]]), ("attrs", "x")],
)
def test_a_malformed_header_setting_is_named(tmp_path, key, value):
    path = write(tmp_path, 0, settings={**SETTINGS, key: value})
    with pytest.raises(JournalError, match=f"header: '{key}' missing or malformed"):
        read(path)
    missing = {k: v for k, v in SETTINGS.items() if k != key}
    path.unlink()
    path = write(tmp_path, 0, settings=missing)
    with pytest.raises(JournalError, match=f"header: '{key}' missing or malformed"):
        read(path)


def test_the_header_crc_and_size_are_checked(tmp_path):
    path = write(tmp_path, 0)
    data = bytearray(path.read_bytes())
    data[14] ^= 1
    path.write_bytes(bytes(data))
    with pytest.raises(JournalError, match="header: torn or damaged"):
        read(path)
    path.write_bytes(jr.HEADER_MAGIC + struct.pack("<I", (64 << 20) + 1))
    with pytest.raises(JournalError, match="implausible"):
        read(path)
    path.write_bytes(jr.HEADER_MAGIC + struct.pack("<I", 64 << 20))  # the limit: not refused
    with pytest.raises(JournalError, match="header: torn or damaged"):  # for its size
        read(path)
    text = json.dumps(SETTINGS, sort_keys=True).encode()
    for wrong in ((zlib.crc32(text) + 1) % 2**32, (zlib.crc32(text) - 1) % 2**32):  # off by one
        path.write_bytes(jr.HEADER_MAGIC + struct.pack("<I", len(text)) + text
                         + struct.pack("<I", wrong))
        with pytest.raises(JournalError, match="header: torn or damaged"):
            read(path)
    for cut in (1, 2, 3):  # the CRC after it cut short
        path.write_bytes(jr.HEADER_MAGIC + struct.pack("<I", len(text)) + text
                         + struct.pack("<I", zlib.crc32(text))[:-cut])
        with pytest.raises(JournalError, match="header: torn or damaged"):
            read(path)
    text = b"[1, 2]"
    path.write_bytes(jr.HEADER_MAGIC + struct.pack("<I", len(text)) + text
                     + struct.pack("<I", zlib.crc32(text)))
    with pytest.raises(JournalError, match="settings are not a JSON object"):
        read(path)


@pytest.mark.parametrize(
    ("meta", "extras", "problem"),
    [
        ({**META, "contact_interval": None}, {"force": 0}, "contact_interval"),
        ({**META, "contact_interval": [0]}, {"force": 0}, "contact_interval"),
        ({**META, "run": "1"}, {"force": 0}, "labels:"),
        (META, {}, "/recordings/extra"),
        (META, {"other": 0}, "/recordings/extra"),
    ],
)
def test_records_a_campaign_cannot_hold_are_skipped_and_named(tmp_path, meta, extras, problem):
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    w.append(META, {"force": (np.float32(0), np.dtype("<f4"))}, b"a" * 24)
    w.append(meta, {k: (np.float32(v), np.dtype("<f4")) for k, v in extras.items()}, b"b" * 24)
    w.append(META, {"force": (np.float32(2), np.dtype("<f4"))}, b"c" * 24)
    w.release()
    contents, records = read(w.path)
    assert [r.index for r in records] == [0, 2]
    assert len(contents.skipped) == 1
    assert contents.skipped[0].startswith("record 1: ") and problem in contents.skipped[0]
    assert contents.dropped_bytes == 0


def test_without_contact_intervals_a_record_needs_none(tmp_path):
    settings = {**SETTINGS, "contact_interval": False}
    w = jr.JournalWriter(tmp_path / "c.h5", settings)
    w.append({k: v for k, v in META.items() if k != "contact_interval"},
             {"force": (np.float32(0), np.dtype("<f4"))}, b"a" * 24)
    w.release()
    contents, records = read(w.path)
    assert len(records) == 1 and contents.skipped == []


def test_a_second_writer_or_reader_is_refused_while_the_journal_is_held(tmp_path):
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    with pytest.raises(FileExistsError):
        jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    with pytest.raises(FileExistsError):
        jr.LockedJournal(w.path)
    w.discard()
    assert not w.path.exists()


def raw_record(index: int, meta: dict, body: bytes) -> bytes:
    """A record as the writer lays it out, from its parts (for records it would not write)."""
    text = json.dumps(meta).encode()
    head = struct.pack("<4sIIQ", jr.RECORD_MAGIC, index, len(text), len(body))
    return head + text + body + struct.pack("<I", zlib.crc32(body, zlib.crc32(text, zlib.crc32(head[4:]))))


def test_a_missing_record_stops_the_reading_at_its_place(tmp_path):
    """Record 2 where record 1 should be (a lost block of the disk): not taken for record 1."""
    one = {**META, "extra": [], "chunk": 4}
    path = write(tmp_path, 0, settings={**SETTINGS, "extra_fields": []})
    path.write_bytes(path.read_bytes() + raw_record(0, one, b"abcd") + raw_record(2, one, b"efgh"))
    contents, records = read(path)
    assert [r.index for r in records] == [0]
    assert "no record 1 where expected" in contents.dropped_reason


def test_complete_records_with_unreadable_labels_are_skipped_with_their_reason(tmp_path):
    path = write(tmp_path, 0, settings={**SETTINGS, "extra_fields": []})
    ok = {**META, "extra": [], "chunk": 4}
    path.write_bytes(path.read_bytes() + raw_record(0, ok, b"abcd")
                     + raw_record(1, {**ok, "chunk": 5}, b"abcd")
                     + raw_record(2, {k: v for k, v in ok.items() if k != "extra"}, b"abcd")
                     + raw_record(3, {**ok, "chunk": 3}, b"abcd")
                     + raw_record(4, ok, b"efgh"))
    contents, records = read(path)
    assert [r.chunk for r in records] == [b"abcd", b"efgh"]
    assert contents.skipped[0] == "record 1: /recordings/signals: chunk size differs from its label"
    assert contents.skipped[1].startswith("record 2: labels: unreadable (")
    assert contents.skipped[2] == "record 3: /recordings/signals: chunk size differs from its label"
    assert contents.dropped_bytes == 0


def test_a_contact_interval_is_exactly_two_integers(tmp_path):
    w = jr.JournalWriter(tmp_path / "c.h5", {**SETTINGS, "extra_fields": []})
    w.append({**META, "contact_interval": [0, 3, 5]}, {}, b"a" * 24)
    w.append({**META, "contact_interval": [0, 3.0]}, {}, b"a" * 24)
    w.release()
    contents, records = read(w.path)
    assert records == [] and len(contents.skipped) == 2


@pytest.mark.parametrize("value", [True, 3, 2.5, "s", np.float32(1.5), np.arange(6).reshape(2, 3),
                                   np.array(7, np.int16), np.array(["ab", "c"])])
def test_attributes_round_trip_with_their_dtype(value):
    back = jr.decode_attr(json.loads(json.dumps(jr.encode_attr(value))))
    if isinstance(value, (bool, int, float, str)):
        assert back == value and type(back) is type(value)
    elif np.asarray(value).dtype.kind == "U":
        assert [v.decode() if isinstance(v, bytes) else v for v in back.tolist()] == value.tolist()
    else:
        assert np.asarray(back).dtype == np.asarray(value).dtype
        np.testing.assert_array_equal(back, value)
        assert np.ndim(back) == np.ndim(value)


def test_labels_over_a_mebibyte_are_not_read(tmp_path):
    """A record declaring more than 1 MiB of labels is taken for damage (the reader never
    allocates what a damaged length says), even with a valid CRC."""
    path = write(tmp_path, 0, settings={**SETTINGS, "extra_fields": []})
    big = {**META, "extra": [], "chunk": 4, "note": "x" * (1 << 20)}
    path.write_bytes(path.read_bytes() + raw_record(0, big, b"abcd"))
    contents, records = read(path)
    assert records == [] and contents.dropped_bytes > 1 << 20
    assert "recording 0 incomplete" in contents.dropped_reason


@pytest.mark.parametrize("name", ["c.h5", "campaign.v2.h5", "x"])
def test_a_journal_names_its_target(tmp_path, name):
    target = tmp_path / name
    journal = jr.journal_path(target)
    assert journal.parent == tmp_path and journal.name == f".{name}.partial"
    assert jr.target_of(journal) == target
    assert jr.journal_and_target(journal) == (journal, target)
    assert jr.journal_and_target(target) == (journal, target)


@pytest.mark.parametrize("name", ["c.h5.partial", ".c.h5", ".partial", "..partial"])
def test_other_names_are_not_journals(tmp_path, name):
    with pytest.raises(ValueError, match="not a recording journal name"):
        jr.target_of(tmp_path / name)
    assert jr.target_of(tmp_path / ".a.partial") == tmp_path / "a"


@pytest.mark.parametrize("name", ["c.h5.partial", ".c.h5"])
def test_a_target_whose_name_has_one_of_the_journal_marks_is_a_target(tmp_path, name):
    """Only a name both starting with a dot and ending in .partial is a journal: a campaign
    file named like one half of that is the target of its own journal."""
    target = tmp_path / name
    assert jr.journal_and_target(target) == (tmp_path / f".{name}.partial", target)


def test_releasing_a_journal_twice_closes_it_once_and_leaves_it_on_disk(tmp_path):
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    w.append(META, {"force": (np.float32(0), np.dtype("<f4"))}, bytes(24))
    w.release()
    saved = os.dup(0)
    try:
        w.release()
        os.fstat(0)  # the second release closed nothing, standard input included
    finally:
        os.dup2(saved, 0)
        os.close(saved)
    contents, records = read(w.path)
    assert len(records) == 1 and contents.dropped_bytes == 0


def test_a_journal_opened_on_descriptor_zero_is_closed_by_its_release(tmp_path):
    """A recorder started with standard input closed (a service) gets descriptor 0 for its
    journal: releasing it closes it all the same."""
    saved = os.dup(0)
    try:
        os.close(0)
        w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
        assert os.path.samefile("/proc/self/fd/0", w.path)
        w.release()
        with pytest.raises(OSError):
            os.fstat(0)
    finally:
        os.dup2(saved, 0)
        os.close(saved)


def test_the_header_is_the_same_bytes_whatever_the_order_of_the_settings(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = write(tmp_path / "a", 0)
    b = write(tmp_path / "b", 0, settings=dict(reversed(list(SETTINGS.items()))))
    assert list(SETTINGS) != list(dict(reversed(list(SETTINGS.items()))))
    assert a.read_bytes() == b.read_bytes()


def test_the_writer_knows_where_its_journal_ends_after_every_append(tmp_path):
    """The writer's end is the file's size after each append (a failed append cuts the journal
    back to it): records of different sizes, labels and extras."""
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    try:
        assert w.end == w.path.stat().st_size
        for k, n in enumerate((24, 0, 1000)):
            meta = {**META, "participant": k, "length": n // 8, "contact_interval": [0, n // 8]}
            w.append(meta, {"force": (np.float32(k), np.dtype("<f4"))}, bytes([k]) * n)
            assert w.end == w.path.stat().st_size and w.n == k + 1
    finally:
        w.release()


def test_a_record_with_a_damaged_magic_is_not_read(tmp_path):
    """The CRC covers a record from its index on: its magic is checked on its own."""
    path = write(tmp_path, 2)
    clean = path.read_bytes()
    second = clean.rindex(jr.RECORD_MAGIC)
    for magic in (b"ABC1", b"ZZZ1"):  # sorting before and after REC1
        data = bytearray(clean)
        data[second : second + 4] = magic
        path.write_bytes(bytes(data))
        contents, records = read(path)
        assert len(records) == 1 and "no record 1 where expected" in contents.dropped_reason


def test_three_hundred_records_are_read_back_in_order(tmp_path):
    """Indices past the integers Python keeps as single objects."""
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS, durable=False)
    for k in range(300):
        w.append({**META, "participant": k}, {"force": (np.float32(k), np.dtype("<f4"))},
                 bytes(8))
    w.release()
    contents, records = read(w.path)
    assert [r.meta["participant"] for r in records] == list(range(300))
    assert [r.index for r in records] == list(range(300)) and contents.dropped_bytes == 0


def test_a_file_without_the_journal_magic_is_named_as_such(tmp_path):
    path = write(tmp_path, 1)
    data = bytearray(path.read_bytes())
    for magic in (b"ESKJRNL0", b"\x00" * 8, b"\xff" * 8):  # sorting before and after ours
        data[0:8] = magic
        path.write_bytes(bytes(data))
        with pytest.raises(JournalError, match="not a recording journal"):
            read(path)


def test_the_journal_file_mode_and_scalar_attributes(tmp_path):
    umask = os.umask(0)
    os.umask(umask)
    path = write(tmp_path, 0)
    assert path.stat().st_mode & 0o777 == 0o644 & ~umask
    for value in (np.float32(1.5), np.array(7, np.int16)):
        back = jr.decode_attr(json.loads(json.dumps(jr.encode_attr(value))))
        assert not isinstance(back, np.ndarray) and back.dtype == value.dtype and back == value


@pytest.mark.parametrize("attrs", [[["a"]], [["a", "x", "y"]]])
def test_a_header_attribute_is_exactly_a_name_and_a_value(tmp_path, attrs):
    path = write(tmp_path, 0, settings={**SETTINGS, "attrs": attrs})
    with pytest.raises(JournalError, match="header: 'attrs' missing or malformed"):
        read(path)


def test_an_attribute_holding_a_pickle_is_never_unpickled():
    """A journal is data: an object array (a pickle inside .npy) in it is refused, not run."""
    import base64
    import io

    buf = io.BytesIO()
    np.save(buf, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match="allow_pickle"):
        jr.decode_attr({"npy": base64.b64encode(buf.getvalue()).decode()})


def test_the_contents_repr_leaves_out_the_record_offsets_and_the_open_file(tmp_path):
    contents, records = read(write(tmp_path, 3))
    assert len(contents.offsets) == 3 and len(records) == 3
    assert "offsets" not in repr(contents) and "_fh" not in repr(contents)
    assert repr(contents).startswith("JournalContents(path=")


def test_labels_of_exactly_a_mebibyte_are_read(tmp_path):
    """The limit is 1 MiB of labels: a record at it is read like any other."""
    path = write(tmp_path, 0, settings={**SETTINGS, "extra_fields": []})
    meta = {**META, "extra": [], "chunk": 4, "note": ""}
    meta["note"] = "x" * ((1 << 20) - len(json.dumps(meta).encode()))
    assert len(json.dumps(meta).encode()) == 1 << 20
    path.write_bytes(path.read_bytes() + raw_record(0, meta, b"abcd"))
    contents, records = read(path)
    assert [r.chunk for r in records] == [b"abcd"]
    assert contents.dropped_bytes == 0 and contents.skipped == []


@pytest.mark.parametrize("keep", [0, 1, 2, 3])
def test_a_header_cut_inside_its_size_field_is_named_as_never_completely_written(tmp_path, keep):
    path = write(tmp_path, 1)
    path.write_bytes(path.read_bytes()[: len(jr.HEADER_MAGIC) + keep])
    with pytest.raises(JournalError) as info:
        read(path)
    assert str(info.value) == (f"{path}: not a recording journal (no {jr.HEADER_MAGIC!r} "
                               f"header), or its header was never completely written")


def test_a_grid_shape_is_exactly_two_integers(tmp_path):
    for shape in ([2, 2, 2], [2, 2, 1, 1]):
        path = write(tmp_path, 0, settings={**SETTINGS, "grid_shape": shape})
        with pytest.raises(JournalError, match="header: 'grid_shape' missing or malformed"):
            read(path)
        path.unlink()


def test_any_damaged_byte_of_a_record_body_drops_it(tmp_path):
    """Whichever way the CRC-32 of the damaged record compares with the stored one."""
    path = write(tmp_path, 1)
    good = path.read_bytes()
    body_end = len(good) - 4  # the record's CRC follows its 24-byte body
    for k in range(body_end - 24, body_end):
        path.write_bytes(good[:k] + bytes([good[k] ^ 0x5A]) + good[k + 1:])
        contents, records = read(path)
        assert records == [] and "fails its CRC-32" in contents.dropped_reason, k


def test_a_clean_journal_drops_nothing_and_writes_durably_by_default(tmp_path):
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    assert w.durable
    for k in range(3):
        w.append(META, {"force": (np.float32(k), np.dtype("<f4"))}, bytes([k]) * 24)
    w.release()
    contents, records = read(w.path)
    assert len(records) == 3
    assert (contents.dropped_bytes, contents.dropped_reason, contents.skipped) == (0, "", [])


def test_a_journal_that_is_gone_or_unlocked_is_not_held_by_a_live_writer(tmp_path):
    """The busy message asks whether a live writer holds the journal: one removed in the
    meantime (the other writer finished) holds none, nor does one nobody has locked."""
    gone = tmp_path / "gone.h5.journal"
    assert jr._is_locked(gone) is False
    left = tmp_path / "left.h5.journal"
    left.write_bytes(b"x")
    assert jr._is_locked(left) is False
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    try:
        assert jr._is_locked(w.path) is True
    finally:
        w.release()
