"""Size limits of what eskin reads, checked before any large read or allocation.

A file declares its sizes (recordings, grid, samples) before its data; a damaged or hostile file
can declare sizes that no real campaign has and that would exhaust the memory. Readers compare
each declared size with these limits (documented in ``docs/dataset-format.md``) and with the
memory available, and name the field that is too large.
"""

from __future__ import annotations

import os
from pathlib import Path

MAX_RECORDINGS = 100_000
"""Recordings in one campaign (the paper's campaign has 840)."""
MAX_GRID_SIDE = 256
"""Taxel rows, and taxel columns, of a grid."""
MAX_TAXELS = 4096
"""Taxels of a grid (rows x cols; a 64 x 64 skin)."""
MAX_SAMPLES = 1 << 24
"""Samples of one recording, T (16,777,216: 93 minutes at 3 kHz)."""
MIN_D = 2
"""Samples of a subsampled window, D, at least (the model format's lower bound)."""
MAX_D = 100_000
"""Samples of a subsampled window, D (the core's ``kMaxD``)."""
MAX_RECORDING_BYTES = 1 << 30
"""Bytes of one recording as int16 (rows x cols x T x 2): a recording is read whole."""
MIN_SAMPLE_RATE_HZ = 0.1
"""Sample rate of a campaign, at least (one sample every 10 s)."""
MAX_SAMPLE_RATE_HZ = 1e6
"""Sample rate of a campaign, and of a stream on the link, at most (1 MHz)."""


def available_memory() -> int | None:
    """Bytes of memory this process can still use (MemAvailable, capped by the cgroup limit);
    None where unknown."""
    avail = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (OSError, ValueError, AttributeError):
            avail = None
    room = _cgroup_room()
    if room is not None:
        avail = room if avail is None else min(avail, room)
    return avail


def _cgroup_room() -> int | None:
    """Memory left under this process's cgroup (v2) limit, if it has one."""
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit == "max":
            return None
        used = int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
        return max(0, int(limit) - used)
    except (OSError, ValueError):
        return None


def gib(nbytes: float) -> str:
    """A byte count for a message ("3.2 GiB")."""
    return f"{nbytes / (1 << 30):.3g} GiB"


def memory_problem(nbytes: int, what: str) -> str | None:
    """Why ``nbytes`` for ``what`` cannot be allocated now, or None if they fit."""
    avail = available_memory()
    if avail is not None and nbytes > avail:
        return f"{what} would take {gib(nbytes)}, more than the {gib(avail)} of memory available"
    return None


def size_problem(value: int, limit: int, what: str) -> str | None:
    """Why a declared size is refused, or None if it is within ``limit``."""
    if value > limit:
        return f"{what} {value:,} is over the limit of {limit:,} (docs/dataset-format.md)"
    return None


#: How many times smaller than its samples the stored bytes of a dataset can be, at most, after
#: each HDF5 filter (by filter id). Deflate (gzip) shrinks at most 1032 times (the format's
#: longest match, 258 bytes, costs at least 2 bits); LZF at most 88 times (264 bytes in 3);
#: shuffle and the Fletcher-32 checksum do not shrink. Any other filter (szip, scale-offset,
#: n-bit, a plugin) is given FILTER_RATIO_UNKNOWN.
FILTER_RATIOS = {1: 1032, 2: 1, 3: 1, 32000: 88}
FILTER_RATIO_UNKNOWN = 1 << 16
FILTER_NAMES = {1: "gzip", 2: "shuffle", 3: "fletcher32", 4: "szip", 5: "nbit",
                6: "scaleoffset", 32000: "lzf"}
UNSTORED_BYTES = 1 << 26
"""Bytes of samples a file may declare beyond what its stored bytes can hold (64 MiB: chunks
never written read as zeros, and reading that many takes a fraction of a second)."""


def filter_ratio(filters: list[int]) -> int:
    """How many times its stored bytes a chunk passed through HDF5 ``filters`` (ids, in
    order) can hold, at most."""
    ratio = 1
    for fid in filters:
        ratio *= FILTER_RATIOS.get(fid, FILTER_RATIO_UNKNOWN)
    return ratio


def stored_size_problem(declared: int, backed: int, stored: int,
                        filters: list[int]) -> str | None:
    """Why ``declared`` bytes of samples are refused when the file's ``stored`` bytes of them
    (with these HDF5 ``filters``) can hold only ``backed`` of them (each chunk at most
    :func:`filter_ratio` times its stored bytes; a chunk never written holds nothing and reads
    as zeros), or None when all but :data:`UNSTORED_BYTES` are backed. Such a file would be
    read as gigabytes of zeros, for minutes."""
    if declared <= backed + UNSTORED_BYTES:
        return None
    names = "+".join(FILTER_NAMES.get(fid, f"filter {fid}") for fid in filters) or "none"
    return (f"declares {declared:,} bytes of samples but the file stores {stored:,} bytes of "
            f"them, which hold at most {backed:,} (filters: {names}; a chunk never written "
            f"holds none); the file is damaged or was not written whole")
