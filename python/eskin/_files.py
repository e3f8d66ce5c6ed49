"""The one overwrite rule of every command that writes a file.

Recorded data is never lost: a command replaces an existing file only when asked (``--force``),
and never writes onto one of its own inputs, even when asked (``eskin train camp.h5 -o camp.h5``
would destroy the campaign it is reading). Both refusals raise :class:`eskin.errors.
OverwriteError` (a FileExistsError) with a one-line message naming the file.
"""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, Union

from eskin.errors import OverwriteError

PathLike = Union[str, "os.PathLike[str]"]


def same_file(a: PathLike, b: PathLike) -> bool:
    """Whether two paths name the same file (through links and relative paths)."""
    a, b = Path(a), Path(b)
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet): compare where they would be
        pass
    try:
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):  # a symbolic link loop: compare the names
        return os.path.abspath(a) == os.path.abspath(b)


def refuse_overwrite(
    path: PathLike, force: bool = False, inputs: Iterable[PathLike | None] = ()
) -> Path:
    """Check that a command may write ``path``; returns it as a Path.

    Refuses (:class:`OverwriteError`) a path that is one of ``inputs`` (``None`` entries are
    skipped), whatever ``force`` says, and an existing path unless ``force``.
    """
    path = Path(path)
    for source in inputs:
        if source is not None and same_file(path, source):
            raise OverwriteError(
                f"{path}: this is also an input of the command; write the output elsewhere"
            )
    if path.is_dir():
        raise OverwriteError(f"{path}: is a folder, not a file")
    if path.exists() and not force:
        raise OverwriteError(
            f"{path}: file exists; refusing to overwrite it (use --force to replace it)"
        )
    _check_writable(path)
    return path


def _check_writable(path: Path) -> None:
    """OSError naming ``path`` when its folder (or the nearest one that exists) is on a
    read-only file system or not writable: said before a command's work, not after it (a
    full disk can only be found by writing)."""
    folder = path.absolute().parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        return  # cannot tell: the write will say
    if read_only:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OSError(errno.EACCES, os.strerror(errno.EACCES), str(path))


def refuse_overwrite_all(
    paths: Iterable[PathLike], force: bool = False, inputs: Iterable[PathLike | None] = ()
) -> list[Path]:
    """:func:`refuse_overwrite` for every file a command writes; also refuses two outputs that
    are the same file (``--record x --jsonl x``)."""
    inputs = list(inputs)
    out: list[Path] = []
    for p in paths:
        if any(same_file(p, q) for q in out):
            raise OverwriteError(f"{p}: given twice as an output of the command")
        out.append(refuse_overwrite(p, force, inputs))
    return out


def error_line(exc: BaseException, file: PathLike | None = None) -> str:
    """The one line a command prints for an error: an ``OSError`` as "FILE: reason" (without
    Python's "[Errno N]"; ``file`` names the file the command was writing when the error does
    not: a full disk under ``f.write``), anything else as its message."""
    if isinstance(exc, KeyError) and exc.args:
        return str(exc.args[0])
    if isinstance(exc, OSError) and exc.strerror:
        name = exc.filename if exc.filename is not None else file
        text = str(exc.strerror)
        if name is not None and str(name) not in text:
            text = f"{name}: {text}"
        return text.replace("\n", " ")
    return str(exc).replace("\n", " ")


@contextlib.contextmanager
def whole_file(path: PathLike) -> Iterator[Path]:
    """Write the file ``path`` whole or not at all: the block writes the hidden file it is
    given, next to ``path``; that file is then flushed to the disk and renamed over ``path``.
    On any error (a full or read-only disk) the hidden file is removed, ``path`` is as it was,
    and an OSError names ``path`` (not the hidden file, and not nothing, as a failing
    ``write`` would)."""
    path = Path(path)
    # the hidden file keeps the suffix, which writers read the format from (matplotlib)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    remove_stale(path.parent, f".{path.stem}.", f".tmp{path.suffix}")
    try:
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):  # (a read-only disk refuses even that)
            tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.strerror and exc.filename in (None, str(tmp), tmp):
            raise OSError(exc.errno, exc.strerror, str(path)) from exc
        raise


def write_whole(path: PathLike, data: bytes) -> None:
    """Write ``data`` as the file ``path``, whole or not at all (:func:`whole_file`)."""
    with whole_file(path) as tmp:
        tmp.write_bytes(data)


def reserve_space(f: Any, nbytes: int) -> None:
    """Reserve ``nbytes`` on the disk for the open file ``f`` before writing it: a disk that
    cannot hold the file says so (OSError ENOSPC, or EFBIG past the process's file size
    limit) before a byte is written. A file system that cannot reserve space (EOPNOTSUPP,
    EINVAL) is left to say it at the write."""
    if nbytes <= 0 or not hasattr(os, "posix_fallocate"):
        return
    try:
        os.posix_fallocate(f.fileno(), 0, nbytes)
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
            raise


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: alive, another user's
        return True
    return True


def remove_stale(folder: Path, head: str, tail: str) -> list[Path]:
    """Delete the hidden files ``head + PID + tail`` in ``folder`` that a process left when it
    was killed while writing (SIGKILL, or SIGTERM where nothing turns it into an exception:
    no cleanup runs) and that no living process is writing: their PID is not a process now.
    Called before writing the same target again; returns the files deleted."""
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        middle = name[len(head):len(name) - len(tail)] if len(name) > len(head) + len(tail) else ""
        if not (name.startswith(head) and name.endswith(tail) and middle.isdigit()):
            continue
        pid = int(middle)
        if pid == os.getpid() or _alive(pid):
            continue
        with contextlib.suppress(OSError):
            os.unlink(folder / name)
            removed.append(folder / name)
    return removed
