"""The recording journal: the crash-safe side of :class:`eskin.CampaignWriter`.

While a campaign is being written, every appended recording goes first to an append-only
journal file next to the target (``.NAME.partial``), flushed to the disk (``fsync``) before
``append`` returns. The journal is not a campaign file: it is a header (the campaign's settings)
followed by self-checking records (labels + the compressed chunk + a CRC-32). When the writer
closes, the campaign file is built from the journal; when the writing process dies (kill -9,
power loss, a crash), :class:`LockedJournal` reads back every record whose append had returned
and stops at the first torn or damaged one (the recording in flight).

The journal is created exclusively (``O_EXCL``) and locked (``flock``) for as long as its writer
lives, so a second writer on the same target fails at open and a recovery never reads a journal
that is still being written.

Layout (little-endian)::

    header  b"ESKJRNL1" | u32 n | n bytes of JSON (settings) | u32 CRC-32 of the JSON
    record  b"REC1" | u32 index | u32 m | u64 b | m bytes of JSON (labels, extra sizes)
            | b bytes (the extra values as .npy blobs, then the chunk) | u32 CRC-32 of
            everything after the magic
"""

from __future__ import annotations

import base64
import errno
import io
import json
import os
import struct
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eskin.errors import JournalError

HEADER_MAGIC = b"ESKJRNL1"
RECORD_MAGIC = b"REC1"
_RECORD_HEAD = struct.Struct("<4sIIQ")  # magic, index, meta length, body length
_CRC = struct.Struct("<I")
_MAX_META = 1 << 20  # labels of one recording: a few hundred bytes in practice
_MAX_HEADER = 64 << 20  # settings and root attributes


def journal_path(target: str | os.PathLike[str]) -> Path:
    """The journal of the campaign file ``target``: ``.NAME.partial`` in the same folder."""
    target = Path(target)
    return target.with_name(f".{target.name}.partial")


def target_of(journal: str | os.PathLike[str]) -> Path:
    """The campaign file a journal belongs to (inverse of :func:`journal_path`)."""
    journal = Path(journal)
    name = journal.name
    if not (name.startswith(".") and name.endswith(".partial")) or len(name) <= 9:
        raise ValueError(f"{journal}: not a recording journal name (.NAME.partial)")
    return journal.with_name(name[1 : -len(".partial")])


def journal_and_target(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """(journal, campaign file) from either of the two."""
    p = Path(path)
    if p.name.startswith(".") and p.name.endswith(".partial"):
        return p, target_of(p)
    return journal_path(p), p


def fsync_dir(folder: Path) -> None:
    """Make a creation, rename or removal in ``folder`` durable."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _lock(fd: int) -> bool:
    """Try to take the exclusive lock of an open journal; False if another process holds it."""
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return False
        raise
    return True


def busy_message(target: Path, journal: Path, live: bool) -> str:
    """Why a new writer (or a recovery) cannot use ``journal``."""
    if live:
        return (
            f"{target}: another writer is recording to this file right now "
            f"(its journal {journal.name} is locked)"
        )
    return (
        f"{target}: an interrupted recording was left in {journal.name}; salvage it with "
        f"`eskin recover {target}` (or delete {journal} to discard it)"
    )


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


# --------------------------------------------------------------------------- values


def _npy_bytes(value: Any, dtype: np.dtype) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.asarray(value, dtype=dtype), allow_pickle=False)
    return buf.getvalue()


def _npy_value(blob: bytes) -> np.ndarray:
    return np.load(io.BytesIO(blob), allow_pickle=False)


def encode_attr(value: Any) -> Any:
    """An HDF5-ready attribute value -> JSON (exact dtypes kept for numbers and arrays)."""
    if isinstance(value, (bool, int, float, str)):
        return value
    arr = np.asarray(value)
    if arr.dtype.kind in "OSU":
        return {
            "strings": [
                v.decode() if isinstance(v, bytes) else str(v) for v in arr.reshape(-1).tolist()
            ],
            "shape": list(arr.shape),
        }
    return {"npy": base64.b64encode(_npy_bytes(arr, arr.dtype)).decode("ascii")}


def decode_attr(value: Any) -> Any:
    """Inverse of :func:`encode_attr` (strings come back as an h5py string array)."""
    if not isinstance(value, dict):
        return value
    if "npy" in value:
        arr = _npy_value(base64.b64decode(value["npy"]))
        return arr[()]  # a 0-d array as its scalar, any other as itself
    import h5py

    return np.array(value["strings"], dtype=h5py.string_dtype()).reshape(value["shape"])


# --------------------------------------------------------------------------- writing


class JournalWriter:
    """Create, lock and append to a journal. Every append has reached the operating system when
    it returns (it survives the death of the process) and, if ``durable``, the disk (it survives
    a power loss)."""

    def __init__(self, target: Path, settings: Mapping[str, Any], *, durable: bool = True):
        self.target = Path(target)
        self.durable = durable
        self.path = journal_path(self.target)
        try:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            raise FileExistsError(
                busy_message(self.target, self.path, _is_locked(self.path))
            ) from None
        except OSError as exc:
            raise OSError(exc.errno, f"{self.path}: cannot create the recording journal "
                          f"({exc.strerror})") from None
        try:
            if not _lock(self._fd):
                raise FileExistsError(busy_message(self.target, self.path, True))
            text = json.dumps(dict(settings), sort_keys=True).encode("utf-8")
            _write_all(
                self._fd, HEADER_MAGIC + _CRC.pack(len(text)) + text + _CRC.pack(zlib.crc32(text))
            )
            os.fsync(self._fd)
            fsync_dir(self.path.parent)
        except FileExistsError:  # locked by another process the moment it was made
            self.discard()
            raise
        except OSError as exc:
            self.discard()
            raise OSError(exc.errno, f"{self.path}: cannot write the recording journal "
                          f"({exc.strerror or exc})") from None
        except BaseException:
            self.discard()
            raise
        self.n = 0
        self.end = os.lseek(self._fd, 0, os.SEEK_CUR)  # one past the last complete record
        self.broken = ""

    def append(
        self, meta: Mapping[str, Any], extras: Mapping[str, tuple[Any, np.dtype]], chunk: bytes
    ) -> None:
        """Write one record (labels ``meta``, extra values, the chunk) and fsync it."""
        blobs = [(k, _npy_bytes(v, dt)) for k, (v, dt) in extras.items()]
        text = json.dumps(
            {**meta, "extra": [[k, len(b)] for k, b in blobs], "chunk": len(chunk)}
        ).encode("utf-8")
        body = b"".join(b for _, b in blobs) + chunk
        head = _RECORD_HEAD.pack(RECORD_MAGIC, self.n, len(text), len(body))
        crc = zlib.crc32(body, zlib.crc32(text, zlib.crc32(head[4:])))
        if self.broken:
            raise OSError(errno.EIO, f"{self.path}: the journal cannot take more recordings "
                          f"({self.broken}); the {self.n} appended before are kept in it")
        try:
            _write_all(self._fd, head + text + body + _CRC.pack(crc))
            if self.durable:
                os.fdatasync(self._fd)
        except OSError as exc:
            self._cut_back(exc)
            raise OSError(exc.errno, f"{self.path}: cannot append recording {self.n} "
                          f"({exc.strerror or exc}); the {self.n} appended before are kept in "
                          f"the journal") from exc
        except BaseException as exc:
            self._cut_back(exc)
            raise
        self.end += len(head) + len(text) + len(body) + _CRC.size
        self.n += 1

    def _cut_back(self, exc: BaseException) -> None:
        """After a failed append: cut the journal back to its last complete record, so that
        later appends follow it; if that fails too, refuse further appends (the reader stops
        at the torn record anyway: nothing appended before is lost)."""
        try:
            os.ftruncate(self._fd, self.end)
            os.lseek(self._fd, self.end, os.SEEK_SET)
        except OSError as cut:
            self.broken = f"an append failed ({exc!r}) and the torn record could not be cut " \
                f"off ({cut.strerror})"

    def release(self) -> None:
        """Close and unlock the journal, leaving it on disk (for a later recovery)."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def discard(self) -> None:
        """Close and delete the journal."""
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass
        self.release()


def _is_locked(path: Path) -> bool:
    """True if a live process holds the lock of the journal at ``path``."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return False
    try:
        return not _lock(fd)
    finally:
        os.close(fd)


# --------------------------------------------------------------------------- reading


@dataclass
class JournalRecord:
    """One complete recording read back from a journal (``index``: its append's index)."""

    meta: dict[str, Any]
    extras: dict[str, np.ndarray]
    chunk: bytes
    index: int = 0


@dataclass
class JournalContents:
    """What :meth:`LockedJournal.read` found, all known as soon as it returns: the settings,
    where each complete record starts, the records skipped as unreadable (CRC-valid, but
    labels a campaign cannot hold: "record K: problem"), and how many bytes at the end were
    torn or damaged (and why). :meth:`records` reads the records one at a time."""

    path: Path
    settings: dict[str, Any]
    offsets: list[int] = field(default_factory=list, repr=False)
    skipped: list[str] = field(default_factory=list)
    dropped_bytes: int = 0
    dropped_reason: str = ""
    _fh: Any = field(default=None, repr=False)

    def records(self) -> Iterator[JournalRecord]:
        """The complete records, in append order (one in memory at a time)."""
        for index, pos in enumerate(self.offsets):
            self._fh.seek(pos)
            record, reason = _read_record(self._fh, None, 1 << 62)
            if record is None:  # changed under its lock: a damaged disk
                raise JournalError(f"{self.path}: record at byte {pos} no longer reads ({reason})")
            yield record


class LockedJournal:
    """A journal opened for reading under its lock (``with`` releases it). ``lock=False``:
    the caller holds the lock already (the writer reading back its own journal)."""

    def __init__(self, path: Path, *, lock: bool = True):
        self.path = Path(path)
        try:
            self._fh = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        except FileNotFoundError:
            raise FileNotFoundError(f"{self.path}: no such recording journal") from None
        try:
            if lock and not _lock(self._fh.fileno()):
                raise FileExistsError(busy_message(target_of(self.path), self.path, True))
            self.size = os.fstat(self._fh.fileno()).st_size
        except BaseException:  # held, or the lock itself failed: the file is not left open
            self._fh.close()
            raise

    def read(self) -> JournalContents:
        """Parse the header and walk every record once (checking its CRC-32 and labels), so
        that what is complete, skipped and dropped is known before anything is built."""
        settings, pos = _read_header(self._fh, self.path)
        contents = JournalContents(self.path, settings, _fh=self._fh)
        fh, index = self._fh, 0
        fh.seek(pos)
        while pos < self.size:
            record, reason = _read_record(fh, index, self.size - pos)
            if record is None and not reason.startswith("skip:"):
                contents.dropped_bytes, contents.dropped_reason = self.size - pos, reason
                break
            problem = reason[5:] if record is None else _meta_problem(
                record.meta, record.extras, settings)
            if problem:
                contents.skipped.append(f"record {index}: {problem}")
            else:
                contents.offsets.append(pos)
            pos = fh.tell()
            index += 1
        return contents

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> LockedJournal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _read_header(fh: Any, path: Path) -> tuple[dict[str, Any], int]:
    head = fh.read(len(HEADER_MAGIC) + 4)
    if len(head) < len(HEADER_MAGIC) + 4 or head[: len(HEADER_MAGIC)] != HEADER_MAGIC:
        raise JournalError(
            f"{path}: not a recording journal (no {HEADER_MAGIC!r} header), "
            f"or its header was never completely written"
        )
    (n,) = _CRC.unpack(head[len(HEADER_MAGIC) :])
    if n > _MAX_HEADER:
        raise JournalError(f"{path}: header: declared size {n} bytes is implausible")
    text = fh.read(n)
    crc = fh.read(4)
    if len(text) < n or len(crc) < 4 or _CRC.unpack(crc)[0] != zlib.crc32(text):
        raise JournalError(
            f"{path}: header: torn or damaged (the writer died while creating "
            f"the journal: no recording was written)"
        )
    try:
        settings = json.loads(text.decode("utf-8"))
    except ValueError as exc:
        raise JournalError(f"{path}: header: not valid JSON ({exc})") from None
    problem = _settings_problem(settings)
    if problem:
        raise JournalError(f"{path}: header: {problem}")
    return settings, fh.tell()


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _settings_problem(s: Any) -> str | None:
    """What is wrong with a header's settings (None: nothing)."""
    if not isinstance(s, dict):
        return "settings are not a JSON object"
    checks = {
        "grid_shape": lambda v: isinstance(v, list) and len(v) == 2 and all(map(_is_int, v)),
        "n_samples": _is_int,
        "compression_level": lambda v: v is None or _is_int(v),
        "contact_interval": lambda v: isinstance(v, bool),
        "extra_fields": lambda v: (
            isinstance(v, list)
            and all(
                isinstance(e, list) and len(e) == 2 and all(isinstance(x, str) for x in e)
                for e in v
            )
        ),
        "attrs": lambda v: (
            isinstance(v, list)
            and all(isinstance(e, list) and len(e) == 2 and isinstance(e[0], str) for e in v)
        ),
    }
    for key, ok in checks.items():
        if key not in s or not ok(s[key]):
            return f"{key!r} missing or malformed ({s.get(key)!r})"
    return None


_LABELS = ("length", "modality", "participant", "direction", "run")


def _meta_problem(meta: Any, extras: Mapping[str, Any], settings: Mapping[str, Any]) -> str:
    """What is wrong with one record's labels and extras ("" when nothing); the values are
    checked against the campaign format when the campaign is built."""
    if not isinstance(meta, dict) or not all(_is_int(meta.get(k)) for k in _LABELS):
        return f"labels: {meta!r} incomplete (each of {', '.join(_LABELS)} an integer)"
    ci = meta.get("contact_interval")
    if settings["contact_interval"] and not (
        isinstance(ci, list) and len(ci) == 2 and all(map(_is_int, ci))
    ):
        return f"/recordings/contact_interval: {ci!r} missing or not two integers"
    if list(extras) != [k for k, _ in settings["extra_fields"]]:
        return f"/recordings/extra: fields {list(extras)} differ from the header's"
    return ""


def _read_record(fh: Any, index: int | None, remaining: int) -> tuple[JournalRecord | None, str]:
    """Read the next record (``index``: the one expected, None: any); (None, reason) if it is
    torn or damaged, (None, "skip:" + reason) if it is complete but its labels unreadable."""
    head = fh.read(_RECORD_HEAD.size)
    if len(head) < _RECORD_HEAD.size:
        return None, "a torn record header"
    magic, idx, m, b = _RECORD_HEAD.unpack(head)
    if magic != RECORD_MAGIC or (index is not None and idx != index):
        return None, f"no record {index} where expected (damaged data)"
    if m > _MAX_META or _RECORD_HEAD.size + m + b + 4 > remaining:
        return None, f"recording {idx} incomplete (the append in flight)"
    text, body, crc = fh.read(m), fh.read(b), fh.read(4)
    if _CRC.unpack(crc)[0] != zlib.crc32(body, zlib.crc32(text, zlib.crc32(head[4:]))):
        return None, f"recording {idx} fails its CRC-32 (torn or damaged)"
    try:
        meta = json.loads(text.decode("utf-8"))
        extras, pos = {}, 0
        for name, size in meta.pop("extra"):
            extras[str(name)] = _npy_value(body[pos : pos + int(size)])
            pos += int(size)
        chunk = body[pos:]
        if len(chunk) != meta.pop("chunk"):
            return None, "skip:/recordings/signals: chunk size differs from its label"
    except (ValueError, KeyError, TypeError, AttributeError, OverflowError) as exc:
        return None, f"skip:labels: unreadable ({exc})"
    return JournalRecord(meta, extras, chunk, idx), ""
