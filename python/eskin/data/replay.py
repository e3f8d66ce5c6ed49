"""Replay files: what the firmware simulator ``eskin-fw-sim`` streams.

The C++ side has no HDF5, so a campaign's recordings are laid out for it as one continuous
int16 stream, recordings separated by gaps of quiet noise, in a small documented binary file
(``docs/wire-protocol.md``, section "Replay file"). The file also holds where each recording
sits in the stream, its label and (when known) its contact interval, so a host can compare
what arrives over the link with the source::

    rf = write_replay_file(campaign, test_indices, "test.eskr", gap_s=0.5)
    # eskin-fw-sim test.eskr   ->  streams rf.samples at 3000 samples/s
"""

from __future__ import annotations

import math
import os
import struct
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from eskin._files import reserve_space, whole_file
from eskin.data.limits import MAX_SAMPLE_RATE_HZ, MIN_SAMPLE_RATE_HZ
from eskin.errors import ReplayFormatError

__all__ = [
    "REPLAY_MAGIC",
    "REPLAY_VERSION",
    "ReplayFile",
    "ReplayFormatError",
    "read_replay_file",
    "write_raw_records",
    "write_raw_stream",
    "write_recordings_npy",
    "write_replay_arrays",
    "write_replay_file",
]

REPLAY_MAGIC = b"ESKREPLY"
REPLAY_VERSION = 1
_HEADER = struct.Struct("<8sIIQHHIddII")  # 56 bytes
_SEGMENT = struct.Struct("<QQqqiIQ")  # 48 bytes
SEGMENT_DTYPE = np.dtype(
    [
        ("start", "<u8"),  # stream index of the recording's first sample
        ("length", "<u8"),  # samples
        ("contact_onset", "<i8"),  # within the recording; -1 when unknown
        ("contact_offset", "<i8"),
        ("label", "<i4"),  # class index into class_names; -1 when unknown
        ("recording", "<u4"),  # index of the recording in its source campaign
        ("reserved", "<u8"),
    ]
)


MAX_GAP_S = 3600.0
"""The longest quiet gap between recordings of a replay stream: an hour."""


@dataclass(frozen=True)
class ReplayFile:
    """A replay stream: ``samples`` int16 (n_samples, rows, cols) (memory-mapped when read)."""

    path: Path
    samples: np.ndarray
    segments: np.ndarray  # SEGMENT_DTYPE records, one per recording, in stream order
    sample_rate_hz: float
    volts_per_count: float
    class_names: tuple[str, ...]

    @property
    def n_samples(self) -> int:
        return int(self.samples.shape[0])

    @property
    def grid_shape(self) -> tuple[int, int]:
        return int(self.samples.shape[1]), int(self.samples.shape[2])

    def recording(self, k: int) -> np.ndarray:
        """Segment ``k`` as a campaign-layout int16 array (rows, cols, length)."""
        seg = self.segments[k]
        start, length = int(seg["start"]), int(seg["length"])
        return np.ascontiguousarray(np.moveaxis(self.samples[start : start + length], 0, -1))


def write_replay_arrays(
    path: str | os.PathLike[str],
    recordings: Sequence[np.ndarray],
    *,
    labels: Optional[Sequence[int]] = None,
    class_names: Sequence[str] = (),
    sample_rate_hz: float = 3000.0,
    volts_per_count: float = 1.0,
    contact_intervals: Optional[np.ndarray] = None,
    recording_indices: Optional[Sequence[int]] = None,
    gap_s: float = 0.5,
    noise_counts: Optional[float] = None,
    baseline: Optional[np.ndarray] = None,
    seed: int = 0,
    _raw: bool = False,
) -> ReplayFile:
    """Write recordings (each int16 (rows, cols, length)) as one replay stream.

    A gap of ``gap_s`` seconds of quiet noise precedes every recording (and follows the last),
    from a generator seeded with ``seed``, with standard deviation ``noise_counts`` or, by
    default, per taxel the quiet noise of the recordings it joins (the smaller of the standard
    deviations, linear trend removed, of a recording's first and last tenth), ramping
    geometrically from the one to the other: recordings of one campaign can differ severalfold in
    noise, and a stream detector that has learnt a quiet recording's floor would take a louder
    gap for a touch, while a geometric ramp changes by the same ratio every second, which the
    detector's running noise floor follows (up to about 4x in amplitude over a 2 s gap). The
    gap is centred on ``baseline`` (per taxel) when it is given; by default it ramps, per taxel,
    from the level at which the previous recording ends to the level at which the next one
    starts (medians of 10 ms), so that recording boundaries carry no step.
    """
    path = Path(path)
    recs = [np.asarray(r) for r in recordings]
    rows, cols = _check_recordings(recs)
    n = len(recs)
    labels_a, names, contacts, rec_idx = _segment_fields(
        n, labels, class_names, contact_intervals, recording_indices
    )
    if not MIN_SAMPLE_RATE_HZ <= sample_rate_hz <= MAX_SAMPLE_RATE_HZ:  # NaN too
        raise ValueError(f"sample_rate_hz must be {MIN_SAMPLE_RATE_HZ:g} to "
                         f"{MAX_SAMPLE_RATE_HZ:g} Hz, got {sample_rate_hz:g}")
    if not (math.isfinite(volts_per_count) and volts_per_count > 0):
        raise ValueError(f"volts_per_count must be finite and > 0, got {volts_per_count}")
    if not 0 <= gap_s <= MAX_GAP_S:  # NaN too
        raise ValueError(f"gap_s must be a number of seconds in [0, {MAX_GAP_S:g}], "
                         f"got {gap_s:g}")
    gaps = _QuietGaps(recs, (rows, cols), sample_rate_hz, noise_counts, baseline, seed)
    gap = int(round(gap_s * sample_rate_hz))

    segments = np.zeros(n, dtype=SEGMENT_DTYPE)
    start = gap
    for i, r in enumerate(recs):
        segments[i] = (start, r.shape[2], contacts[i, 0], contacts[i, 1], labels_a[i], rec_idx[i], 0)
        start += r.shape[2] + gap
    head = _replay_head(segments, names, start, rows, cols, sample_rate_hz, volts_per_count)

    path.parent.mkdir(parents=True, exist_ok=True)
    with whole_file(path) as tmp, open(tmp, "wb") as f:
        reserve_space(f, (0 if _raw else len(head)) + start * rows * cols * 2)
        if not _raw:
            f.write(head)
        for chunk in _stream_chunks(recs, gaps, gap):
            f.write(chunk)
    # the raw stream's (samples, rows, cols): write_raw_stream's answer
    return (start, rows, cols) if _raw else read_replay_file(path)  # type: ignore[return-value]


def _stream_chunks(recs: list[np.ndarray], gaps: _QuietGaps, gap: int) -> Iterator[bytes]:
    """The stream's bytes in order (int16 little-endian, one sample of every taxel after
    another): a quiet gap, then each recording followed by its gap."""
    yield gaps.quiet(gap, None, gaps.edge_level(recs[0], True), None, 0).tobytes()
    following: list[Optional[int]] = [*range(1, len(recs)), None]
    for i, (r, j) in enumerate(zip(recs, following)):
        clipped = np.clip(r, -32768, 32767).astype("<i2")
        yield np.ascontiguousarray(np.moveaxis(clipped, -1, 0)).tobytes()
        nxt = None if j is None else gaps.edge_level(recs[j], True)
        yield gaps.quiet(gap, gaps.edge_level(r, False), nxt, i, j).tobytes()


def _check_recordings(recs: list[np.ndarray]) -> tuple[int, int]:
    """At least one recording, all integer (rows, cols, length) on one grid; the grid."""
    if not recs:
        raise ValueError("write_replay_arrays needs at least one recording")
    grid = recs[0].shape[:2]
    for i, r in enumerate(recs):
        if r.ndim != 3 or r.shape[:2] != grid or r.shape[2] < 1:
            raise ValueError(
                f"recording {i} has shape {r.shape}; expected (rows, cols, length) with grid {grid}"
            )
        if r.dtype.kind not in "iu":
            raise ValueError(f"recording {i} must hold integer ADC codes, got dtype {r.dtype}")
    rows, cols = int(grid[0]), int(grid[1])
    if not (1 <= rows <= 255 and 1 <= cols <= 255):
        raise ValueError(f"grid shape {grid} is not within 1..255 x 1..255")
    return rows, cols


def _segment_fields(
    n: int,
    labels: Optional[Sequence[int]],
    class_names: Sequence[str],
    contact_intervals: Optional[np.ndarray],
    recording_indices: Optional[Sequence[int]],
) -> tuple[np.ndarray, list[str], np.ndarray, np.ndarray]:
    """The segment table's per-recording fields, checked: labels, class names, contact
    intervals (-1 when unknown) and the recordings' indices in their campaign."""
    labels_a = np.full(n, -1, dtype=np.int64) if labels is None else np.asarray(labels, np.int64)
    if labels_a.shape != (n,):
        raise ValueError(f"labels must have one entry per recording ({n}), got {labels_a.shape}")
    names = [str(c) for c in class_names]
    for c in names:
        if "\n" in c:
            raise ValueError(f"class name {c!r} contains a newline")
    if len(names) > 255:
        raise ValueError(f"at most 255 class names, got {len(names)}")
    if labels_a.min() < -1 or labels_a.max() >= len(names):  # the reader's rule
        raise ValueError(f"labels must be -1 or index class_names ({len(names)} names)")
    if contact_intervals is None:
        contacts = np.full((n, 2), -1, dtype=np.int64)
    else:
        contacts = np.asarray(contact_intervals, dtype=np.int64)
        if contacts.shape != (n, 2):
            raise ValueError(f"contact_intervals must be ({n}, 2), got {contacts.shape}")
    rec_idx = np.arange(n) if recording_indices is None else np.asarray(recording_indices)
    if rec_idx.shape != (n,):
        raise ValueError(f"recording_indices must have {n} entries, got {rec_idx.shape}")
    return labels_a, names, contacts, rec_idx


class _QuietGaps:
    """The quiet noise between recordings, drawn in stream order from one seeded generator."""

    def __init__(
        self,
        recs: list[np.ndarray],
        grid: tuple[int, int],
        sample_rate_hz: float,
        noise_counts: Optional[float],
        baseline: Optional[np.ndarray],
        seed: int,
    ) -> None:
        # a given baseline: every gap flat at it; otherwise each gap ramps between its
        # neighbours' edges (the stream has a recording before or after every gap)
        self.base = None if baseline is None else np.broadcast_to(np.asarray(baseline, float),
                                                                  grid)
        # one level for every gap when given; otherwise each taxel's own (self.levels)
        self.noise = 0.0 if noise_counts is None else float(noise_counts)
        if self.noise < 0:
            raise ValueError(f"noise_counts must be >= 0, got {self.noise}")
        self.shape = grid
        # per recording and taxel, its quiet noise (None: one level, noise_counts, for all)
        self.levels = None if noise_counts is not None else [_taxel_noise(r) for r in recs]
        self.edge = max(1, int(round(0.01 * sample_rate_hz)))
        self.rng = np.random.default_rng(seed)

    def edge_level(self, r: np.ndarray, first: bool) -> np.ndarray:
        """Per-taxel median of the first (or last) 10 ms of a recording."""
        k = min(r.shape[2], self.edge)
        part = r[:, :, :k] if first else r[:, :, -k:]
        return np.median(part.astype(np.float64), axis=2)

    def _noise(self, length: int, a: Optional[int], b: Optional[int]) -> Any:
        """The gap's noise std: ``noise_counts``, or per taxel a geometric ramp from the quiet
        noise of recording ``a`` to that of recording ``b`` (one of them may be None)."""
        if self.levels is None:
            return self.noise
        sa = np.maximum(self.levels[b if a is None else a], 0.1)
        sb = np.maximum(self.levels[a if b is None else b], 0.1)
        u = np.linspace(0.0, 1.0, length)[:, None, None]
        return sa[None] ** (1.0 - u) * sb[None] ** u

    def quiet(
        self, length: int, prev: Optional[np.ndarray], nxt: Optional[np.ndarray],
        prev_rec: Optional[int] = None, next_rec: Optional[int] = None,
    ) -> np.ndarray:
        # With a fixed baseline the gap is flat; otherwise it ramps from where the previous
        # recording ends to where the next one starts, so that no step (which a touch
        # detector would take for a touch) appears at a recording boundary.
        rows, cols = self.shape
        if self.base is not None:
            level = np.broadcast_to(self.base[None], (length, rows, cols))
        else:
            a = nxt if prev is None else prev
            b = prev if nxt is None else nxt
            t = np.linspace(0.0, 1.0, length)[:, None, None]
            level = a[None] * (1.0 - t) + b[None] * t
        noise = self._noise(length, prev_rec, next_rec)
        z = level + noise * self.rng.standard_normal((length, rows, cols))
        return np.clip(np.rint(z), -32768, 32767).astype("<i2")


def _taxel_noise(r: np.ndarray) -> np.ndarray:
    """Per taxel (rows, cols), a recording's quiet noise in counts: the smaller of the standard
    deviations of its first and last tenth (at most 300 samples each, linear trend removed),
    so that a touch near one end does not count as noise."""
    q = max(2, min(300, r.shape[-1] // 10))
    out = []
    for part in (r[..., :q], r[..., -q:]):
        x = np.asarray(part, np.float64)
        t = np.arange(x.shape[-1]) - (x.shape[-1] - 1) / 2
        slope = (x * t).sum(axis=-1, keepdims=True) / max(float((t * t).sum()), 1e-12)
        out.append(np.std(x - slope * t, axis=-1))
    return np.minimum(out[0], out[1])


def _replay_head(
    segments: np.ndarray,
    names: list[str],
    total: int,
    rows: int,
    cols: int,
    sample_rate_hz: float,
    volts_per_count: float,
) -> bytes:
    """The file's header, segment table and class names, padded to 8 bytes, with its CRC."""
    names_b = "\n".join(names).encode("utf-8")
    table = segments.tobytes() + names_b
    data_offset = (_HEADER.size + len(table) + 7) // 8 * 8
    header = _HEADER.pack(
        REPLAY_MAGIC, REPLAY_VERSION, data_offset, total, rows, cols, len(segments),
        float(sample_rate_hz), float(volts_per_count), len(names_b), 0,
    )
    head = header + table + b"\0" * (data_offset - _HEADER.size - len(table))
    crc = zlib.crc32(head)
    return head[:52] + struct.pack("<I", crc) + head[56:]


def write_replay_file(
    campaign: Any,
    indices: Optional[Sequence[int]],
    path: str | os.PathLike[str],
    *,
    gap_s: float = 0.5,
    noise_counts: Optional[float] = None,
    seed: int = 0,
) -> ReplayFile:
    """Write recordings ``indices`` (all when None) of a campaign as a replay file.

    ``campaign`` is an ``eskin.Campaign`` (or anything with ``recording(i)``, ``modality``,
    ``modalities``, ``sample_rate_hz`` and ``volts_per_count``); labels are its modality ids,
    contact intervals its simulator ground truth when present.
    """
    return write_replay_arrays(path, **_campaign_stream(campaign, indices), gap_s=gap_s,
                               noise_counts=noise_counts, seed=seed)


def write_raw_stream(
    campaign: Any,
    indices: Optional[Sequence[int]],
    path: str | os.PathLike[str],
    *,
    gap_s: float = 0.5,
    noise_counts: Optional[float] = None,
    seed: int = 0,
) -> tuple[int, int, int]:
    """Write the stream :func:`write_replay_file` would write with the same arguments, its
    samples alone: int16 little-endian, one sample of every taxel (row by row) after another,
    no header. This is what a controller loop reads sample by sample (the README's
    ``classify_stream.cpp`` on its standard input). Returns (samples, rows, cols)."""
    return write_replay_arrays(path, **_campaign_stream(campaign, indices), gap_s=gap_s,  # type: ignore[return-value]
                               noise_counts=noise_counts, seed=seed, _raw=True)


def _campaign_stream(campaign: Any, indices: Optional[Sequence[int]]) -> dict[str, Any]:
    """write_replay_arrays' arguments for recordings ``indices`` (all when None) of a
    campaign."""
    idx = np.arange(len(campaign)) if indices is None else np.asarray(indices, dtype=np.int64)
    recs = [np.asarray(campaign.recording(int(i))) for i in idx]
    labels = np.asarray(campaign.modality)[idx] if getattr(campaign, "modality", None) is not None else None
    contact = getattr(campaign, "contact_interval", None)
    contacts = np.asarray(contact)[idx] if contact is not None else None
    return dict(
        recordings=recs,
        labels=labels,
        class_names=list(getattr(campaign, "modalities", ()) or ()),
        sample_rate_hz=float(campaign.sample_rate_hz),
        volts_per_count=float(campaign.volts_per_count),
        contact_intervals=contacts,
        recording_indices=idx,
    )


# --------------------------------------------------------------------------- batch inputs
# eskin-classify reads recordings, not a stream: a .npy array or raw 'ESKR' records
# (docs/model-format.md, "Raw recordings").

RAW_RECORD_MAGIC = b"ESKR"
_RAW_RECORD = struct.Struct("<4sHHII")  # magic, rows, cols, T, reserved


def _chosen(campaign: Any, indices: Optional[Sequence[int]]) -> np.ndarray:
    idx = np.arange(len(campaign)) if indices is None else np.asarray(indices, dtype=np.int64)
    if not idx.size:
        raise ValueError("no recordings to write")
    return idx


def write_recordings_npy(
    campaign: Any, indices: Optional[Sequence[int]], path: str | os.PathLike[str]
) -> tuple[int, ...]:
    """Write recordings ``indices`` (all when None) as one int16 .npy array (n, rows, cols, T),
    each cut to its valid length, which must be the same for all (else use
    :func:`write_raw_records`). One recording is in memory at a time. Returns the shape."""
    idx = _chosen(campaign, indices)
    lengths = np.asarray(campaign.lengths)[idx]
    if lengths.min() != lengths.max():
        raise ValueError(
            f"{path}: the {idx.size} recordings have different lengths ({lengths.min()} to "
            f"{lengths.max()} samples) and a .npy array holds one length; write raw records "
            f"instead (eskin replay --format records)"
        )
    rows, cols = campaign.grid_shape
    shape = (idx.size, int(rows), int(cols), int(lengths.max()))
    header = {"descr": "<i2", "fortran_order": False, "shape": shape}
    # ordinary buffered writes, not a memory map: a full disk is an OSError, not a SIGBUS
    with whole_file(path) as tmp, open(tmp, "wb") as f:
        np.lib.format.write_array_header_1_0(f, header)
        reserve_space(f, f.tell() + 2 * math.prod(shape))
        for i in idx:  # each (rows, cols, its length): a campaign's
            f.write(np.ascontiguousarray(campaign.recording(int(i)), dtype="<i2").tobytes())
    return shape


def write_raw_records(
    campaign: Any, indices: Optional[Sequence[int]], path: str | os.PathLike[str]
) -> int:
    """Write recordings ``indices`` (all when None) as raw records, each its own length: a
    16-byte header ('ESKR', u16 rows, u16 cols, u32 T, u32 0) and its int16 samples in C order
    (rows, cols, T). Returns the number of records."""
    idx = _chosen(campaign, indices)
    with whole_file(path) as tmp, open(tmp, "wb") as f:
        for i in idx:
            r = np.ascontiguousarray(campaign.recording(int(i)), dtype="<i2")
            f.write(_RAW_RECORD.pack(RAW_RECORD_MAGIC, r.shape[0], r.shape[1], r.shape[2], 0))
            f.write(r.tobytes())
    return int(idx.size)


def read_replay_file(path: str | os.PathLike[str]) -> ReplayFile:
    """Open a replay file (samples memory-mapped); ReplayFormatError if it is not valid."""
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as f:
        raw = f.read(_HEADER.size)
        if len(raw) < _HEADER.size or raw[:8] != REPLAY_MAGIC:
            raise ReplayFormatError(f"{path}: not an eskin replay file (bad magic)")
        (_, version, data_offset, total, rows, cols, n_seg, rate, vpc, names_len, crc) = (
            _HEADER.unpack(raw)
        )
        if version != REPLAY_VERSION:
            raise ReplayFormatError(f"{path}: replay version {version}, expected {REPLAY_VERSION}")
        table_end = _HEADER.size + n_seg * _SEGMENT.size + names_len
        if data_offset < table_end or data_offset > size or data_offset % 8:
            raise ReplayFormatError(f"{path}: bad data offset {data_offset}")
        rest = f.read(data_offset - _HEADER.size)
    head = raw[:52] + b"\0\0\0\0" + rest
    if zlib.crc32(head) != crc:
        raise ReplayFormatError(f"{path}: header checksum mismatch")
    _check_header(path, rows, cols, rate, vpc)
    expected = data_offset + total * rows * cols * 2
    if size != expected:
        raise ReplayFormatError(f"{path}: size {size} bytes, expected {expected}")
    segments = np.frombuffer(rest[: n_seg * _SEGMENT.size], dtype=SEGMENT_DTYPE).copy()
    names_b = rest[n_seg * _SEGMENT.size : n_seg * _SEGMENT.size + names_len]
    try:
        names = tuple(names_b.decode("utf-8").split("\n")) if names_len else ()
    except UnicodeDecodeError as exc:
        raise ReplayFormatError(f"{path}: class names: not valid UTF-8 ({exc.reason} at byte "
                                f"{exc.start})") from None
    if len(names) > 255:
        raise ReplayFormatError(f"{path}: class names: {len(names)} names, at most 255")
    _check_segments(path, segments, total, len(names))
    samples = np.memmap(path, dtype="<i2", mode="r", offset=data_offset, shape=(total, rows, cols))
    return ReplayFile(path, samples, segments, float(rate), float(vpc), names)


def _check_header(path: Path, rows: int, cols: int, rate: float, vpc: float) -> None:
    """The header's grid and scales: what the writer accepts, nothing else."""
    if not (1 <= rows <= 255 and 1 <= cols <= 255):
        raise ReplayFormatError(f"{path}: grid: {rows}x{cols} is not within 1..255 x 1..255")
    if not MIN_SAMPLE_RATE_HZ <= rate <= MAX_SAMPLE_RATE_HZ:
        raise ReplayFormatError(f"{path}: sample_rate_hz: {rate!r} is not a rate of "
                                f"{MIN_SAMPLE_RATE_HZ:g} to {MAX_SAMPLE_RATE_HZ:g} Hz")
    if not (math.isfinite(vpc) and vpc > 0):
        raise ReplayFormatError(f"{path}: volts_per_count: {vpc!r} is not a finite number > 0")


def _check_segments(path: Path, seg: np.ndarray, total: int, n_names: int) -> None:
    """Every segment inside the stream, with a known label and a contact inside it."""
    start, length = seg["start"], seg["length"]
    on, off, label = seg["contact_onset"], seg["contact_offset"], seg["label"]
    unknown_contact = (on == -1) & (off == -1)
    problems = (
        (length == 0, lambda i: f"length {int(length[i])} is 0"),
        (length > total - np.minimum(start, total),  # a start past the end leaves room for 0
         lambda i: f"start {int(start[i])} + length {int(length[i])} runs past the end of the "
                   f"stream ({total} samples)"),
        ((label < -1) | (label >= n_names),
         lambda i: f"label {int(label[i])} is neither -1 nor a class index (< {n_names})"),
        (~unknown_contact & ((on < 0) | (off < on) | (off.astype(np.float64) > length)),
         lambda i: f"contact interval [{int(on[i])}, {int(off[i])}) is neither -1/-1 nor "
                   f"within [0, length {int(length[i])}] with onset <= offset"),
    )
    for bad, what in problems:
        idx = np.flatnonzero(bad)
        if idx.size:
            i = int(idx[0])
            raise ReplayFormatError(f"{path}: segment {i}: {what(i)} ({idx.size} bad segments)")
