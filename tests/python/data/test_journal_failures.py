"""The recording journal (eskin.data.journal) when a call fails under it: an append that fails
half-way is cut off so that the next one follows the last complete record; if it cannot be cut
off, the journal refuses more appends and keeps what it has; an interrupt is the same as an
error; a header that cannot be written leaves no journal; a lock error other than "held" is
not taken for "held"."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from eskin.data import journal as jr

SETTINGS = {"grid_shape": [2, 2], "n_samples": 0, "compression_level": None,
            "contact_interval": False, "extra_fields": [], "attrs": []}
META = {"length": 3, "modality": 1, "participant": 2, "direction": 0, "run": 1}


def _chunks(path: Path) -> list[bytes]:
    with jr.LockedJournal(path) as j:
        contents = j.read()
        assert contents.dropped_bytes == 0, contents.dropped_reason
        return [r.chunk for r in contents.records()]


def _failing_write(monkeypatch, exc: BaseException, after: int) -> None:
    """os.write writes ``after`` bytes of its next call, then raises ``exc`` on the rest."""
    real = os.write
    state = {"left": after}

    def write(fd, data):
        if state["left"] <= 0:
            monkeypatch.setattr(os, "write", real)  # one failure, then the disk is back
            raise exc
        n = real(fd, bytes(data)[:state["left"]])
        state["left"] -= n
        return n

    monkeypatch.setattr(os, "write", write)


@pytest.mark.parametrize("exc", [OSError(errno.ENOSPC, "No space left on device"),
                                 KeyboardInterrupt()], ids=["ENOSPC", "interrupt"])
def test_a_torn_append_is_cut_off_and_the_next_follows_the_last_record(tmp_path, monkeypatch,
                                                                       exc):
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    w.append(META, {}, b"A" * 24)
    end = w.end
    _failing_write(monkeypatch, exc, after=10)
    with pytest.raises(type(exc)) as info:
        w.append(META, {}, b"B" * 24)
    if isinstance(exc, OSError):
        assert info.value.errno == errno.ENOSPC
        assert str(info.value) == (f"[Errno 28] {w.path}: cannot append recording 1 (No space "
                                   f"left on device); the 1 appended before are kept in the "
                                   f"journal")
    assert (w.n, w.end, w.path.stat().st_size) == (1, end, end)
    w.append(META, {}, b"C" * 24)
    w.release()
    assert _chunks(w.path) == [b"A" * 24, b"C" * 24]


def test_a_torn_append_that_cannot_be_cut_off_stops_the_journal_and_keeps_its_records(
        tmp_path, monkeypatch):
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    w.append(META, {}, b"A" * 24)

    def no_truncate(fd, size):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(os, "ftruncate", no_truncate)
    _failing_write(monkeypatch, OSError(errno.EIO, "Input/output error"), after=10)
    with pytest.raises(OSError, match="cannot append recording 1"):
        w.append(META, {}, b"B" * 24)
    assert w.broken.startswith("an append failed (OSError(5, 'Input/output error')) and the "
                               "torn record could not be cut off (Input/output error)")
    monkeypatch.undo()
    with pytest.raises(OSError) as info:
        w.append(META, {}, b"C" * 24)
    assert info.value.errno == errno.EIO
    assert str(info.value) == (f"[Errno 5] {w.path}: the journal cannot take more recordings "
                               f"({w.broken}); the 1 appended before are kept in it")
    w.release()
    with jr.LockedJournal(w.path) as j:
        contents = j.read()
        assert [r.chunk for r in contents.records()] == [b"A" * 24]
        assert contents.dropped_bytes == 10  # the torn start of recording 1, dropped on reading


@pytest.mark.parametrize("exc", [KeyboardInterrupt(), OSError(errno.EROFS, "Read-only")],
                         ids=["interrupt", "EROFS"])
def test_a_header_that_cannot_be_written_leaves_no_journal(tmp_path, monkeypatch, exc):
    _failing_write(monkeypatch, exc, after=3)
    with pytest.raises(type(exc)) as info:
        jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    if isinstance(exc, OSError):
        assert str(info.value) == (f"[Errno 30] {jr.journal_path(tmp_path / 'c.h5')}: cannot "
                                   f"write the recording journal (Read-only)")
    assert list(tmp_path.iterdir()) == []
    jr.JournalWriter(tmp_path / "c.h5", SETTINGS).discard()  # and the name is free again


def test_a_lock_error_other_than_held_is_raised_not_taken_for_held(tmp_path, monkeypatch):
    import fcntl

    path = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    path.release()

    def flock(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", flock)
    opened = set(os.listdir("/proc/self/fd"))
    with pytest.raises(OSError) as info:
        jr.LockedJournal(path.path)
    assert info.value.errno == errno.ENOLCK
    assert set(os.listdir("/proc/self/fd")) == opened  # and the journal is not left open


def test_discarding_a_journal_someone_removed_closes_it(tmp_path):
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    w.path.unlink()
    w.discard()
    assert w._fd == -1
    w.discard()  # twice: nothing left to do
    assert list(tmp_path.iterdir()) == []


def test_an_append_without_durability_writes_the_same_record(tmp_path):
    paths = []
    for durable in (True, False):
        w = jr.JournalWriter(tmp_path / f"{durable}.h5", SETTINGS, durable=durable)
        w.append(META, {}, np.arange(6, dtype="<i2").tobytes())
        w.release()
        paths.append(w.path)
    assert paths[0].read_bytes() == paths[1].read_bytes()


def test_a_journal_locked_by_another_writer_the_moment_it_is_made_is_left_to_it(
        tmp_path, monkeypatch):
    """Another process took the lock between our exclusive create and our lock (a writer of
    the same file started at the same instant): ours gives up and removes what it made."""
    import fcntl

    def held(fd, op):
        raise BlockingIOError(errno.EWOULDBLOCK, "Resource temporarily unavailable")

    monkeypatch.setattr(fcntl, "flock", held)
    target = tmp_path / "c.h5"
    with pytest.raises(FileExistsError) as info:
        jr.JournalWriter(target, SETTINGS)
    assert str(info.value) == (f"{target}: another writer is recording to this file right now "
                               f"(its journal .c.h5.partial is locked)")
    assert list(tmp_path.iterdir()) == []


def test_attributes_round_trip_through_the_header_as_scalars_or_arrays():
    for value in (np.float32(2.5), np.int64(-3), np.arange(6, dtype=np.uint16).reshape(2, 3)):
        back = jr.decode_attr(jr.encode_attr(value))
        assert type(back) is type(value) and np.array_equal(back, value)
        assert np.asarray(back).dtype == np.asarray(value).dtype


def test_an_object_value_is_never_pickled_into_the_journal(tmp_path):
    w = jr.JournalWriter(tmp_path / "c.h5", SETTINGS)
    size = w.path.stat().st_size
    with pytest.raises(ValueError, match="allow_pickle=False"):
        w.append(META, {"note": (np.array([{"a": 1}], dtype=object), np.dtype(object))}, b"x")
    assert (w.n, w.path.stat().st_size) == (0, size)
    w.discard()
