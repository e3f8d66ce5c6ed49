"""The eskin campaign file: recordings of a touch-sensing campaign in one HDF5 file.

The format is described in ``docs/dataset-format.md``. In short::

    /                       attrs: format="eskin-campaign", format_version=1, sample_rate_hz,
                                   volts_per_count, modalities (names; index = class id), source
    /recordings/signals     int16 (n, rows, cols, T), one recording per chunk, compressed
    /recordings/length      int32 (n,)   valid samples of each recording (the rest is padding)
    /recordings/modality    uint8 (n,)   class id, an index into the modalities attribute
    /recordings/participant int32 (n,)
    /recordings/direction   uint8 (n,)   0 horizontal, 1 vertical, 255 unknown
    /recordings/run         uint8 (n,)   1 = first (practice) run, 2 = second run, ...
    /recordings/contact_interval  int32 (n, 2)   optional: true [onset, offset) in samples
    /recordings/extra/patch uint16 (n,)  optional, with the root attribute ``patches`` (a JSON
                                         list of patch ids): the skin patch of each recording

:func:`load_campaign` validates every field and raises :class:`CampaignFormatError` (a
``ValueError``) naming the file, the field and the problem. :class:`CampaignWriter` appends one
recording at a time, so that a campaign never has to fit in memory; each append is durable (a
journal next to the target, flushed to the disk), the campaign file appears under its name only
when complete, and it never replaces an existing file unless ``overwrite=True``.
:func:`recover_campaign` salvages the recordings of a writer that died.
"""

from __future__ import annotations

import errno
import json
import math
import os
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eskin._files import remove_stale
from eskin.data import limits
from eskin.errors import CampaignFormatError

FORMAT = "eskin-campaign"
FORMAT_VERSION = 1
SOURCES = ("simulated", "recorded")

DIRECTION_HORIZONTAL = 0
DIRECTION_VERTICAL = 1
DIRECTION_UNKNOWN = 255
DIRECTION_NAMES = {DIRECTION_HORIZONTAL: "horizontal", DIRECTION_VERTICAL: "vertical",
                   DIRECTION_UNKNOWN: "unknown"}

RUN_PRACTICE = 1
RUN_SECOND = 2

_REQUIRED_ATTRS = ("format", "format_version", "sample_rate_hz", "volts_per_count", "modalities",
                   "source")
# name -> (dtype, trailing shape after n)
_LABEL_FIELDS: dict[str, tuple[np.dtype, tuple[int, ...]]] = {
    "length": (np.dtype(np.int32), ()),
    "modality": (np.dtype(np.uint8), ()),
    "participant": (np.dtype(np.int32), ()),
    "direction": (np.dtype(np.uint8), ()),
    "run": (np.dtype(np.uint8), ()),
}
_OPTIONAL_FIELDS: dict[str, tuple[np.dtype, tuple[int, ...]]] = {
    "contact_interval": (np.dtype(np.int32), (2,)),
}
_MAX_EXTRA_BYTES = 1 << 30  # all of one /recordings/extra field


# --------------------------------------------------------------------------- helpers


def _decode(value: Any) -> Any:
    """HDF5 attribute value -> plain Python (str, float, int, list)."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray):
        if value.ndim == 0:
            return _decode(value[()])
        return [_decode(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _check_labels(where: str | None, n: int, arrays: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """Validate the per-recording label arrays (integers of any type, each of one entry per
    recording, within its stored type's range); return them in their stored types. (The
    loader has checked the stored datasets' types and shapes before reading them.)"""
    out: dict[str, np.ndarray] = {}
    given = {k: v for k, v in _OPTIONAL_FIELDS.items() if arrays.get(k) is not None}
    for name, (dtype, tail) in {**_LABEL_FIELDS, **given}.items():
        field = f"/recordings/{name}"
        if arrays.get(name) is None:
            raise CampaignFormatError(where, field, "missing (a required field)")
        arr = np.asarray(arrays[name])
        if arr.shape != (n, *tail):
            raise CampaignFormatError(
                where, field, f"wrong shape {arr.shape} (expected {(n, *tail)}: one entry per "
                f"recording, {n} recordings in /recordings/signals)")
        if arr.dtype.kind not in "iu" and arr.size:
            raise CampaignFormatError(where, field, f"must be integers, got dtype {arr.dtype}")
        info = np.iinfo(dtype)
        if arr.size and (arr.min() < info.min or arr.max() > info.max):
            raise CampaignFormatError(
                where, field, f"values out of the {dtype.name} range "
                f"[{info.min}, {info.max}]: min {arr.min()}, max {arr.max()}")
        arr = arr.astype(dtype)
        out[name] = np.ascontiguousarray(arr)
    return out


def _check_contents(
    where: str | None, labels: Mapping[str, np.ndarray], n_modalities: int, n_samples: int,
    first: int = 0,
) -> None:
    """Cross-field checks on already typed label arrays (``first``: the index of their first
    recording, for the messages)."""

    def more(bad: np.ndarray) -> str:
        return f" ({bad.size} bad entries)" if bad.size > 1 else ""

    length = labels["length"]
    if length.size:
        bad = np.flatnonzero((length < 0) | (length > n_samples))
        if bad.size:
            i = int(bad[0])
            raise CampaignFormatError(
                where, "/recordings/length",
                f"recording {first + i} has length {int(length[i])}, outside "
                f"[0, T={n_samples}]{more(bad)}")
    modality = labels["modality"]
    if modality.size:
        bad = np.flatnonzero(modality >= n_modalities)
        if bad.size:
            i = int(bad[0])
            raise CampaignFormatError(
                where, "/recordings/modality",
                f"recording {first + i} has modality id {int(modality[i])}, out of range: the "
                f"modalities attribute names {n_modalities} classes{more(bad)}")
    direction = labels["direction"]
    if direction.size:
        bad = np.flatnonzero(~np.isin(direction, list(DIRECTION_NAMES)))
        if bad.size:
            i = int(bad[0])
            raise CampaignFormatError(
                where, "/recordings/direction",
                f"recording {first + i} has direction {int(direction[i])} (allowed: "
                f"0 horizontal, 1 vertical, 255 unknown)")
    ci = labels.get("contact_interval")
    if ci is not None and ci.size:
        bad = np.flatnonzero((ci[:, 0] < 0) | (ci[:, 1] < ci[:, 0]) | (ci[:, 1] > length))
        if bad.size:
            i = int(bad[0])
            raise CampaignFormatError(
                where, "/recordings/contact_interval",
                f"recording {first + i} has interval [{int(ci[i, 0])}, {int(ci[i, 1])}), not "
                f"within [0, length={int(length[i])}] with onset <= offset")


def _check_attrs(where: str | None, attrs: Mapping[str, Any]) -> dict[str, Any]:
    """Validate the root attributes; return them decoded."""
    dec = {}
    for k, v in attrs.items():
        try:
            dec[k] = _decode(v)
        except UnicodeDecodeError as exc:
            raise CampaignFormatError(
                where, f"attribute {k!r}", f"not UTF-8 text (byte {exc.object[exc.start]:#04x} "
                f"at position {exc.start})") from None
    if "format" not in dec:
        raise CampaignFormatError(
            where, "attribute 'format'",
            f"missing: not an eskin campaign (an HDF5 file without format={FORMAT!r})")
    if dec["format"] != FORMAT:
        raise CampaignFormatError(
            where, "attribute 'format'",
            f"is {dec['format']!r}, not {FORMAT!r}: not an eskin campaign")
    for name in _REQUIRED_ATTRS:
        if name not in dec:
            raise CampaignFormatError(where, f"attribute {name!r}", "missing (required)")
    version = dec["format_version"]
    if not isinstance(version, int) or isinstance(version, bool):
        raise CampaignFormatError(
            where, "attribute 'format_version'", f"must be an integer, got {version!r}")
    if version != FORMAT_VERSION:
        raise CampaignFormatError(
            where, "attribute 'format_version'",
            f"version {version} is not supported (this eskin reads version {FORMAT_VERSION})")
    for name in ("sample_rate_hz", "volts_per_count"):
        v = dec[name]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise CampaignFormatError(
                where, f"attribute {name!r}", f"must be a positive finite number, got {v!r}")
        dec[name] = float(v)
    if not limits.MIN_SAMPLE_RATE_HZ <= dec["sample_rate_hz"] <= limits.MAX_SAMPLE_RATE_HZ:
        raise CampaignFormatError(
            where, "attribute 'sample_rate_hz'",
            f"{dec['sample_rate_hz']:g} Hz is outside the sample rates eskin reads, "
            f"{limits.MIN_SAMPLE_RATE_HZ:g} Hz to {limits.MAX_SAMPLE_RATE_HZ:g} Hz "
            f"(docs/dataset-format.md)")
    mods = dec["modalities"]
    if isinstance(mods, str):
        mods = [mods]
    if (not isinstance(mods, list) or not mods
            or not all(isinstance(m, str) and m for m in mods)):
        raise CampaignFormatError(
            where, "attribute 'modalities'",
            f"must be a non-empty list of non-empty names, got {mods!r}")
    if len(set(mods)) != len(mods):
        raise CampaignFormatError(where, "attribute 'modalities'", f"has duplicate names {mods!r}")
    if len(mods) > 255:
        raise CampaignFormatError(where, "attribute 'modalities'", "more than 255 names")
    dec["modalities"] = mods
    if dec["source"] not in SOURCES:
        raise CampaignFormatError(
            where, "attribute 'source'", f"must be one of {SOURCES}, got {dec['source']!r}")
    return dec


# --------------------------------------------------------------------------- signals views


class CampaignSignals:
    """A lazy, array-like view of ``/recordings/signals`` (possibly a subset of it).

    Indexing reads only what it needs from the file: ``signals[i]`` is one recording as an
    int16 (rows, cols, T) array, ``signals[a:b]`` or ``signals[[i, j]]`` several, and
    ``np.asarray(signals)`` everything. ``shape``, ``dtype``, ``ndim`` and ``len`` behave as for a
    numpy array.
    """

    def __init__(self, dataset: Any, index: np.ndarray | None = None, path: str | None = None):
        self._ds = dataset
        self._index = index
        self._path = path

    @property
    def shape(self) -> tuple[int, ...]:
        n = self._ds.shape[0] if self._index is None else len(self._index)
        return (n, *self._ds.shape[1:])

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(self._ds.dtype)

    @property
    def ndim(self) -> int:
        return 4

    def __len__(self) -> int:
        return self.shape[0]

    def _read(self, rows: np.ndarray) -> np.ndarray:
        """Read file rows (any order, repeats allowed) as an ndarray."""
        out = np.empty((len(rows), *self._ds.shape[1:]), dtype=self.dtype)
        if len(rows) == 0:
            return out
        uniq, inverse = np.unique(rows, return_inverse=True)
        try:
            if np.all(np.diff(uniq) == 1):  # one recording, or a run of them: one read
                block = self._ds[int(uniq[0]):int(uniq[-1]) + 1]
            else:
                block = np.stack([self._ds[int(r)] for r in uniq])
        except (OSError, RuntimeError, KeyError) as exc:
            raise CampaignFormatError(
                self._path, "/recordings/signals", f"cannot read recording data ({exc})") from exc
        out[...] = block[inverse]
        return out

    def __getitem__(self, key: Any) -> np.ndarray:
        n = len(self)
        rest: tuple[Any, ...] = ()
        if isinstance(key, tuple):
            key, rest = key[0], key[1:]
        if isinstance(key, (int, np.integer)):
            i = int(key)
            if not -n <= i < n:
                raise IndexError(f"recording index {i} out of range for {n} recordings")
            i %= n
            rows = np.array([i if self._index is None else self._index[i]])
            data = self._read(rows)[0]
        else:
            sel = np.arange(n)[key]
            rows = sel if self._index is None else self._index[sel]
            data = self._read(np.asarray(rows, dtype=np.int64))
        return data[rest] if rest else data

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        data = self[:]
        return data if dtype is None else data.astype(dtype)

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        return f"CampaignSignals(shape={self.shape}, dtype={self.dtype.name}, lazy)"


# --------------------------------------------------------------------------- Campaign


class Campaign:
    """A campaign: signals plus per-recording labels and the acquisition settings.

    Built by :func:`load_campaign` (signals stay in the file, read on demand) or directly from
    arrays (validated the same way). Attributes: ``signals`` (int16, (n, rows, cols, T),
    lazy or ndarray), ``lengths``, ``modality``, ``participant``, ``direction``, ``run``,
    ``contact_interval`` (or None), ``modalities``, ``sample_rate_hz``, ``volts_per_count``,
    ``source``, ``attrs`` (every root attribute, decoded), ``extras`` (name -> per-recording
    array, from ``/recordings/extra``), ``path`` (or None).
    """

    def __init__(
        self,
        signals: Any,
        lengths: Any,
        modality: Any,
        participant: Any,
        direction: Any,
        run: Any,
        *,
        modalities: Sequence[str],
        sample_rate_hz: float,
        volts_per_count: float,
        source: str,
        contact_interval: Any = None,
        attrs: Mapping[str, Any] | None = None,
        extras: Mapping[str, Any] | None = None,
        path: str | os.PathLike[str] | None = None,
        _file: Any = None,
        _validated: bool = False,
    ):
        self.path = str(path) if path is not None else None
        self._file = _file
        if _validated:
            self.signals = signals
            self.lengths, self.modality, self.participant = lengths, modality, participant
            self.direction, self.run, self.contact_interval = direction, run, contact_interval
            self.modalities = list(modalities)
            self.sample_rate_hz, self.volts_per_count = float(sample_rate_hz), float(volts_per_count)
            self.source = source
            self.attrs = dict(attrs or {})
            self.extras = {k: np.asarray(v) for k, v in dict(extras or {}).items()}
            return
        where = self.path
        base = {"format": FORMAT, "format_version": FORMAT_VERSION,
                "sample_rate_hz": sample_rate_hz, "volts_per_count": volts_per_count,
                "modalities": list(modalities), "source": source}
        dec = _check_attrs(where, {**dict(attrs or {}), **base})
        if not isinstance(signals, CampaignSignals):
            signals = np.asarray(signals)
        if signals.ndim != 4:
            raise CampaignFormatError(
                where, "/recordings/signals",
                f"wrong shape {signals.shape}: expected 4 axes (n, rows, cols, T)")
        if signals.dtype != np.int16:
            raise CampaignFormatError(
                where, "/recordings/signals", f"wrong dtype {signals.dtype} (expected int16)")
        n, _, _, t = signals.shape
        labels = _check_labels(where, n, {
            "length": lengths, "modality": modality, "participant": participant,
            "direction": direction, "run": run, "contact_interval": contact_interval,
        })
        _check_contents(where, labels, len(dec["modalities"]), t)
        extras = {k: np.asarray(v) for k, v in dict(extras or {}).items()}
        for k, v in extras.items():
            if v.ndim < 1 or v.shape[0] != n:
                raise CampaignFormatError(
                    where, f"/recordings/extra/{k}",
                    f"wrong shape {v.shape} (expected one entry per recording, n={n})")
        _check_patches(where, dec, extras, n)
        self.__init__(  # type: ignore[misc]
            signals, labels["length"], labels["modality"], labels["participant"],
            labels["direction"], labels["run"], contact_interval=labels.get("contact_interval"),
            modalities=dec["modalities"], sample_rate_hz=dec["sample_rate_hz"],
            volts_per_count=dec["volts_per_count"], source=dec["source"], attrs=dec,
            extras=extras, path=path, _file=_file, _validated=True)

    # -- shape helpers
    def __len__(self) -> int:
        return int(self.signals.shape[0])

    @property
    def grid_shape(self) -> tuple[int, int]:
        """(rows, cols) of the taxel grid."""
        return (int(self.signals.shape[1]), int(self.signals.shape[2]))

    @property
    def n_samples(self) -> int:
        """T, the padded length of every recording (samples)."""
        return int(self.signals.shape[3])

    @property
    def modality_names(self) -> list[str]:
        """The modality name of each recording."""
        return [self.modalities[int(m)] for m in self.modality]

    # -- access
    def recording(self, i: int) -> np.ndarray:
        """Recording ``i`` as int16 (rows, cols, length): its valid samples only."""
        n = len(self)
        if not -n <= int(i) < n:
            raise IndexError(f"recording index {i} out of range for {n} recordings")
        i = int(i) % n
        return np.asarray(self.signals[i])[..., : int(self.lengths[i])]

    def signals_float(self, i: int) -> np.ndarray:
        """Recording ``i`` in volts, float64 (rows, cols, length)."""
        return self.recording(i).astype(np.float64) * self.volts_per_count

    def subset(self, indices: Any) -> Campaign:
        """A campaign of the chosen recordings (integer indices, or a boolean mask of length n).

        A file-backed campaign stays lazy: only the index is kept, no signal is read.
        """
        idx = np.asarray(indices)
        if idx.dtype == bool:
            if idx.shape != (len(self),):
                raise ValueError(
                    f"boolean mask has shape {idx.shape}, expected ({len(self)},)")
            idx = np.flatnonzero(idx)
        idx = idx.astype(np.int64).ravel()
        if idx.size and (idx.min() < -len(self) or idx.max() >= len(self)):
            raise IndexError(f"subset indices out of range for {len(self)} recordings")
        idx = np.where(idx < 0, idx + len(self), idx)
        if isinstance(self.signals, CampaignSignals):
            base = self.signals._index
            signals: Any = CampaignSignals(
                self.signals._ds, idx if base is None else base[idx], self.signals._path)
        else:
            signals = self.signals[idx]
        ci = None if self.contact_interval is None else self.contact_interval[idx]
        return Campaign(
            signals, self.lengths[idx], self.modality[idx], self.participant[idx],
            self.direction[idx], self.run[idx], contact_interval=ci, modalities=self.modalities,
            sample_rate_hz=self.sample_rate_hz, volts_per_count=self.volts_per_count,
            source=self.source, attrs=self.attrs,
            extras={k: v[idx] for k, v in self.extras.items()}, path=self.path,
            _file=self._file, _validated=True)

    @property
    def patches(self) -> list[str] | None:
        """The skin's patch ids (the ``patches`` attribute), or None for a one-patch campaign
        (a file without the field)."""
        text = self.attrs.get("patches")
        return None if text is None else list(json.loads(text))

    @property
    def patch(self) -> np.ndarray | None:
        """Each recording's patch, an index into :attr:`patches` (None without the field)."""
        return None if self.patches is None else self.extras["patch"]

    def select(self, *, modality: Any = None, participant: Any = None, direction: Any = None,
               run: Any = None, patch: Any = None) -> Campaign:
        """The recordings matching every given criterion (a value or a list of values;
        modality accepts names or ids, patch ids or indices)."""
        mask = np.ones(len(self), dtype=bool)

        def _vals(v: Any) -> list[Any]:
            return list(v) if isinstance(v, (list, tuple, set, np.ndarray)) else [v]

        if patch is not None:
            mask &= np.isin(self._patch_column(), [self._patch_index(p) for p in _vals(patch)])

        if modality is not None:
            ids = [self.modalities.index(m) if isinstance(m, str) else int(m)
                   for m in _vals(modality)]
            mask &= np.isin(self.modality, ids)
        if participant is not None:
            mask &= np.isin(self.participant, _vals(participant))
        if direction is not None:
            mask &= np.isin(self.direction, _vals(direction))
        if run is not None:
            mask &= np.isin(self.run, _vals(run))
        return self.subset(mask)

    def _patch_column(self) -> np.ndarray:
        if self.patch is None:
            raise ValueError(f"{self.path or '<memory>'}: no patch field (a one-patch campaign)")
        return self.patch

    def _patch_index(self, p: Any) -> int:
        ids = self.patches or []
        if isinstance(p, str):
            if p not in ids:
                raise ValueError(f"{self.path or '<memory>'}: attribute 'patches': no patch "
                                 f"{p!r} (patches: {', '.join(ids[:8])}"
                                 f"{', ...' if len(ids) > 8 else ''})")
            return ids.index(p)
        return int(p)

    def load(self) -> Campaign:
        """The same campaign with every signal read into memory (an ndarray)."""
        if not isinstance(self.signals, CampaignSignals):
            return self
        out = self.subset(np.arange(len(self)))
        out.signals = np.asarray(self.signals)
        return out

    def summary(self) -> dict[str, Any]:
        """Counts and settings, as plain Python values (what ``eskin info`` prints)."""
        def _counts(values: np.ndarray, names: Any = None) -> dict[Any, int]:
            u, c = np.unique(values, return_counts=True)
            return {(names(int(k)) if names else int(k)): int(v) for k, v in zip(u, c)}

        lengths = self.lengths
        return {
            "path": self.path,
            "recordings": len(self),
            "grid": self.grid_shape,
            "samples_per_recording": self.n_samples,
            "sample_rate_hz": self.sample_rate_hz,
            "duration_s": self.n_samples / self.sample_rate_hz,
            "volts_per_count": self.volts_per_count,
            "source": self.source,
            "modalities": list(self.modalities),
            "per_modality": {m: int(np.sum(self.modality == k))
                             for k, m in enumerate(self.modalities)},
            "participants": int(np.unique(self.participant).size),
            "per_participant": _counts(self.participant),
            "per_run": _counts(self.run),
            "per_direction": _counts(self.direction, lambda d: DIRECTION_NAMES.get(d, str(d))),
            "length_min": int(lengths.min()) if lengths.size else 0,
            "length_median": float(np.median(lengths)) if lengths.size else 0.0,
            "length_max": int(lengths.max()) if lengths.size else 0,
            "has_contact_interval": self.contact_interval is not None,
        }

    # -- file lifetime
    def close(self) -> None:
        """Close the underlying file (a lazy campaign can no longer read signals)."""
        if self._file is not None:
            try:
                self._file.close()
            except Exception:  # noqa: BLE001 - closing twice or after an error
                pass
            self._file = None

    def __enter__(self) -> Campaign:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        rows, cols = self.grid_shape
        return (f"Campaign({len(self)} recordings, grid {rows}x{cols}, T={self.n_samples}, "
                f"{self.sample_rate_hz:g} Hz, modalities={self.modalities}, "
                f"source={self.source!r})")


# --------------------------------------------------------------------------- reading


def load_campaign(path: str | os.PathLike[str], *, in_memory: bool = False,
                  check_data: bool = False, allow_external: bool = False) -> Campaign:
    """Open and validate a campaign file.

    Everything a campaign holds must be inside its file: a dataset with external storage
    (its data in another file, such as ``/dev/urandom``), a virtual dataset (mapped from other
    files) or an external link is refused, naming it, unless ``allow_external=True``
    (docs/dataset-format.md, "Storage outside the file").

    Signals stay in the file and are read on demand (``campaign.signals`` is a lazy
    :class:`CampaignSignals`); ``in_memory=True`` reads them all and closes the file.
    ``check_data=True`` also reads every recording once, to catch damaged data chunks.
    Raises :class:`CampaignFormatError` for any problem with the file's content,
    ``FileNotFoundError`` if it does not exist.
    """
    import h5py

    path = Path(path)
    where = str(path)
    try:
        os.stat(path)
    except FileNotFoundError:
        pass
    except OSError as exc:  # a symbolic link loop, a folder without permission, ...
        raise OSError(exc.errno, exc.strerror, where) from None
    if not path.exists():
        from eskin.data.journal import journal_path

        hint = ""
        if journal_path(path).exists():
            hint = (f" (a writer was interrupted while writing it: `eskin recover {where}` "
                    f"salvages its recordings)")
        raise FileNotFoundError(f"{where}: no such campaign file{hint}")
    if path.is_dir():
        raise CampaignFormatError(where, "", "is a directory, not a campaign file")
    try:
        is_hdf5 = h5py.is_hdf5(where)
    except OSError as exc:
        raise CampaignFormatError(where, "", f"cannot be read ({exc})") from exc
    if not is_hdf5:
        raise CampaignFormatError(
            where, "", "not an HDF5 file (no HDF5 signature), so not an eskin campaign (a campaign "
            "is an HDF5 file: docs/dataset-format.md)")
    try:
        f = h5py.File(where, "r")
    except OSError as exc:
        msg = str(exc)
        if "truncated" in msg:
            raise CampaignFormatError(
                where, "", f"truncated HDF5 file (incomplete copy or interrupted "
                f"write): {msg}") from exc
        raise CampaignFormatError(where, "", f"damaged HDF5 file: {msg}") from exc
    try:
        if not allow_external:
            _check_storage(f, where)
        campaign = _load_open(f, where)
        if check_data:
            for i in range(len(campaign)):
                campaign.signals[i]
        if in_memory:
            from eskin.data.limits import memory_problem

            n, rows, cols, t = campaign.signals.shape
            problem = memory_problem(n * rows * cols * t * 2, "reading every recording")
            if problem:
                raise CampaignFormatError(where, "/recordings/signals",
                                          f"in_memory=True: {problem}")
            loaded = campaign.load()
            f.close()
            loaded._file = None
            return loaded
        return campaign
    except CampaignFormatError:
        f.close()
        raise
    except (OSError, RuntimeError, KeyError, TypeError) as exc:
        f.close()
        raise CampaignFormatError(where, "", f"damaged HDF5 file: {exc}") from exc


def _check_storage(f: Any, where: str) -> None:
    """Refuse external links, external storage and virtual datasets anywhere in the file."""
    import h5py

    def walk(group: Any, prefix: str, depth: int) -> None:
        for name in group:
            path = f"{prefix}/{name}"
            link = group.get(name, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                raise CampaignFormatError(
                    where, path, f"an external link to {link.filename}:{link.path} (a campaign "
                    f"holds its data itself; load_campaign(..., allow_external=True) follows it)")
            if isinstance(link, h5py.SoftLink):
                continue  # a name for something inside this file, checked where it is
            obj = group.get(name)
            if isinstance(obj, h5py.Dataset):
                if obj.is_virtual:
                    raise CampaignFormatError(
                        where, path, "a virtual dataset (its data mapped from other files; "
                        "load_campaign(..., allow_external=True) reads it)")
                if obj.external:
                    files = ", ".join(str(e[0]) for e in obj.external[:3])
                    raise CampaignFormatError(
                        where, path, f"external storage: its data is in {files}, not in this "
                        f"file (load_campaign(..., allow_external=True) reads it)")
            elif isinstance(obj, h5py.Group) and depth < 8:
                walk(obj, path, depth + 1)

    walk(f, "", 0)


def _load_open(f: Any, where: str) -> Campaign:
    import h5py

    try:
        raw_attrs = dict(f.attrs.items())
    except (OSError, RuntimeError) as exc:
        raise CampaignFormatError(where, "root attributes", f"cannot be read ({exc})") from exc
    attrs = _check_attrs(where, raw_attrs)
    if "recordings" not in f:
        raise CampaignFormatError(where, "/recordings", "missing (a required group)")
    grp = f["recordings"]
    if not isinstance(grp, h5py.Group):
        raise CampaignFormatError(where, "/recordings", "must be a group, found a dataset")
    if "signals" not in grp:
        raise CampaignFormatError(where, "/recordings/signals", "missing (a required field)")
    sig = grp["signals"]
    if not isinstance(sig, h5py.Dataset):
        raise CampaignFormatError(where, "/recordings/signals", "must be a dataset")
    if sig.dtype != np.int16:
        raise CampaignFormatError(
            where, "/recordings/signals", f"wrong dtype {sig.dtype} (expected int16)")
    if sig.ndim != 4:
        raise CampaignFormatError(
            where, "/recordings/signals",
            f"wrong shape {sig.shape}: expected 4 axes (n, rows, cols, T)")
    n, rows, cols, t = sig.shape
    if n > 0 and (rows < 1 or cols < 1):
        raise CampaignFormatError(
            where, "/recordings/signals", f"empty taxel grid {rows}x{cols}")
    check_sizes(where, n, rows, cols, t)
    _check_stored(where, sig)
    arrays: dict[str, Any] = {}
    for name in (*_LABEL_FIELDS, *_OPTIONAL_FIELDS):
        if name in grp:
            ds = grp[name]
            if not isinstance(ds, h5py.Dataset):
                raise CampaignFormatError(where, f"/recordings/{name}", "must be a dataset")
            expected, tail = {**_LABEL_FIELDS, **_OPTIONAL_FIELDS}[name]
            if ds.dtype != expected:
                raise CampaignFormatError(
                    where, f"/recordings/{name}",
                    f"wrong dtype {ds.dtype} (expected {expected.name})")
            if ds.shape != (n, *tail):  # before reading it: the shape may be huge
                raise CampaignFormatError(
                    where, f"/recordings/{name}", f"wrong shape {ds.shape} (expected "
                    f"{(n, *tail)}: one entry per recording, {n} recordings in "
                    f"/recordings/signals)")
            arrays[name] = ds[()]
    labels = _check_labels(where, n, arrays)
    _check_contents(where, labels, len(attrs["modalities"]), t)
    extras: dict[str, np.ndarray] = {}
    if "extra" in grp and isinstance(grp["extra"], h5py.Group):
        for k, ds in grp["extra"].items():
            if not isinstance(ds, h5py.Dataset):
                continue
            if ds.ndim < 1 or ds.shape[0] != n or ds.size * ds.dtype.itemsize > _MAX_EXTRA_BYTES:
                raise CampaignFormatError(
                    where, f"/recordings/extra/{k}",
                    f"wrong shape {ds.shape} (expected one entry per recording, n={n}, at most "
                    f"{_MAX_EXTRA_BYTES // max(n, 1)} bytes each)")
            # read, a dataset of at least one axis is an array of its shape: n entries
            extras[k] = ds[()]
    _check_patches(where, attrs, extras, n)
    return Campaign(
        CampaignSignals(sig, None, where), labels["length"], labels["modality"],
        labels["participant"], labels["direction"], labels["run"],
        contact_interval=labels.get("contact_interval"), modalities=attrs["modalities"],
        sample_rate_hz=attrs["sample_rate_hz"], volts_per_count=attrs["volts_per_count"],
        source=attrs["source"], attrs=attrs, extras=extras, path=where, _file=f,
        _validated=True)


def _check_patches(where: str | None, attrs: Mapping[str, Any],
                   extras: Mapping[str, np.ndarray], n: int) -> None:
    """The skin fields: the ``patches`` attribute (a JSON list of distinct patch ids) and the
    per-recording ``/recordings/extra/patch`` (unsigned integers indexing it) go together."""
    text = attrs.get("patches")
    if text is None:
        if "patch" in extras:
            raise CampaignFormatError(where, "attribute 'patches'",
                                      "missing: /recordings/extra/patch needs the patch ids")
        return
    try:
        ids = json.loads(text) if isinstance(text, str) else None
    except json.JSONDecodeError:
        ids = None
    if (not isinstance(ids, list) or not ids or len(set(map(str, ids))) != len(ids)
            or not all(isinstance(i, str) and i for i in ids)):
        raise CampaignFormatError(where, "attribute 'patches'",
                                  f"must be a JSON list of distinct patch ids, got {text!r}")
    column = extras.get("patch")
    if column is None:
        raise CampaignFormatError(where, "/recordings/extra/patch",
                                  "missing (the attribute 'patches' names a skin's patches)")
    if column.shape != (n,) or column.dtype.kind != "u":
        raise CampaignFormatError(where, "/recordings/extra/patch",
                                  f"must be unsigned integers (n,), got {column.dtype} "
                                  f"{column.shape}")
    if column.size and int(column.max()) >= len(ids):
        k = int(np.argmax(column))
        raise CampaignFormatError(where, "/recordings/extra/patch",
                                  f"recording {k} has patch {int(column[k])}, past the "
                                  f"{len(ids)} ids of the attribute 'patches'")


def check_sizes(where: str | None, n: int, rows: int, cols: int, t: int) -> None:
    """Refuse declared sizes over the documented limits or the memory available (one
    recording must fit), before anything of that size is read or allocated."""
    from eskin.data import limits

    checks = ((n, limits.MAX_RECORDINGS, "recordings n"),
              (rows, limits.MAX_GRID_SIDE, "grid rows"), (cols, limits.MAX_GRID_SIDE, "grid cols"),
              (rows * cols, limits.MAX_TAXELS, f"taxels ({rows} x {cols})"),
              (t, limits.MAX_SAMPLES, "samples per recording T"),
              (rows * cols * t * 2, limits.MAX_RECORDING_BYTES, "bytes per recording"))
    for value, limit, what in checks:
        problem = limits.size_problem(value, limit, what)
        if problem:
            raise CampaignFormatError(
                where, "/recordings/signals", f"shape {(n, rows, cols, t)}: {problem}")
    problem = limits.memory_problem(rows * cols * t * 2, "one recording")
    if problem:
        raise CampaignFormatError(
            where, "/recordings/signals", f"shape {(n, rows, cols, t)}: {problem}")


def _check_stored(where: str, sig: Any) -> None:
    """Refuse a signals dataset that declares more samples than its stored chunks can hold
    (:func:`eskin.data.limits.stored_size_problem`), before reading any: an 11 KB file can
    declare 24 recordings of 64x64x100000 samples in chunks never written, which read as zeros
    for minutes. Data kept outside the file (allowed by ``allow_external``) is not measured."""
    from eskin.data.limits import filter_ratio, stored_size_problem

    if sig.is_virtual or sig.external:
        return
    try:
        plist = sig.id.get_create_plist()
        filters = [int(plist.get_filter(i)[0]) for i in range(plist.get_nfilters())]
        ratio = filter_ratio(filters)
        stored, backed = _stored_chunks(sig, ratio)
        file_bytes = os.path.getsize(sig.file.filename)
    except (OSError, RuntimeError, ValueError) as exc:
        raise CampaignFormatError(where, "/recordings/signals",
                                  f"cannot read its storage layout ({exc})") from exc
    stored = min(stored, file_bytes)
    problem = stored_size_problem(sig.size * 2, min(backed, stored * ratio), stored, filters)
    if problem:
        raise CampaignFormatError(where, "/recordings/signals", f"shape {sig.shape}: {problem}")


def _stored_chunks(sig: Any, ratio: int) -> tuple[int, int]:
    """(bytes stored, bytes of samples they can hold) of a dataset: per chunk, the smaller of
    its samples inside the dataset and ``ratio`` times its stored bytes."""
    if sig.chunks is None:  # contiguous: no filters, and the whole extent or nothing stored
        stored = int(sig.id.get_storage_size())
        return stored, stored
    shape, chunks, itemsize = sig.shape, sig.chunks, sig.dtype.itemsize
    totals = [0, 0]

    def visit(info: Any) -> None:
        inside = itemsize
        for c, s, o in zip(chunks, shape, info.chunk_offset):
            inside *= min(c, s - o)  # a chunk starts inside the dataset; the last may overhang
        totals[0] += int(info.size)
        totals[1] += min(inside, int(info.size) * ratio)

    if hasattr(sig.id, "chunk_iter"):  # HDF5 1.12.3 and later: one pass in C
        sig.id.chunk_iter(visit)
    else:
        for k in range(sig.id.get_num_chunks()):
            visit(sig.id.get_chunk_info(k))
    return totals[0], totals[1]


# --------------------------------------------------------------------------- writing


def _attr_value(value: Any) -> Any:
    """Python value -> something h5py stores as an attribute (dicts go to JSON)."""
    if isinstance(value, Mapping):
        return json.dumps(value, sort_keys=True)
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, str) for v in value):
        import h5py

        return np.array(value, dtype=h5py.string_dtype())
    return value


@dataclass(frozen=True)
class EncodedRecording:
    """One recording made ready for :class:`CampaignWriter` by :func:`encode_recording`:
    padded to ``n_samples`` and compressed exactly as the writer's HDF5 filters would
    (shuffle + deflate), so that the (slow) compression can run in worker processes."""

    chunk: bytes
    length: int
    grid_shape: tuple[int, int]
    n_samples: int
    compression_level: int | None


def encode_recording(signals: Any, *, grid_shape: tuple[int, int], n_samples: int,
                     length: int | None = None, compression_level: int | None = 1,
                     where: str = "recording") -> EncodedRecording:
    """Validate, pad and compress one (rows, cols, length) integer recording into the chunk
    that ``/recordings/signals`` stores (``compression_level`` None: uncompressed)."""
    x = np.asarray(signals)
    rows, cols = (int(v) for v in grid_shape)
    if x.ndim != 3 or x.shape[:2] != (rows, cols):
        raise ValueError(
            f"{where}: signals must have shape ({rows}, {cols}, length), got {x.shape}")
    if x.shape[2] > n_samples:
        raise ValueError(
            f"{where}: {x.shape[2]} samples, more than the campaign's T={n_samples}")
    if x.dtype != np.int16:
        if x.dtype.kind not in "iu":
            raise ValueError(f"{where}: signals must be int16 ADC counts, got dtype {x.dtype}")
        if x.size and (x.min() < -32768 or x.max() > 32767):
            raise ValueError(f"{where}: values outside the int16 range")
        x = x.astype(np.int16)
    n_valid = x.shape[2] if length is None else int(length)
    if not 0 <= n_valid <= x.shape[2]:
        raise ValueError(f"{where}: length {n_valid} outside [0, {x.shape[2]}]")
    buf = np.zeros((rows, cols, int(n_samples)), dtype="<i2")
    buf[:, :, :n_valid] = x[:, :, :n_valid]
    raw = buf.tobytes()
    if compression_level is None:
        chunk = raw
    else:
        # the HDF5 shuffle filter (byte planes), then deflate (zlib stream), as h5py would
        planes = np.frombuffer(raw, dtype=np.uint8).reshape(-1, 2).T.tobytes()
        chunk = zlib.compress(planes, int(compression_level))
    return EncodedRecording(chunk, n_valid, (rows, cols), int(n_samples), compression_level)


class CampaignWriter:
    """Write a campaign one recording at a time (never the whole campaign in memory).

    ::

        with CampaignWriter("c.h5", grid_shape=(4, 4), n_samples=21000, sample_rate_hz=3000,
                            volts_per_count=10 / 32768, modalities=["brush", "finger", "washer"],
                            source="recorded") as w:
            w.append(signals_i, modality=1, participant=7, direction=0, run=2)

    Crash-safe: each ``append`` writes its recording to a journal next to ``path``
    (``.NAME.partial``, see :mod:`eskin.data.journal`) and flushes it to the disk before it
    returns; if the process dies (kill -9, power loss), :func:`recover_campaign` (``eskin recover
    NAME``) salvages every recording whose ``append`` had returned. ``close`` builds the campaign
    file from the journal and moves it into place; it never replaces a file that exists (even one
    that appeared while recording) unless ``overwrite=True``. A second writer on the same
    ``path`` fails at open (the journal is created exclusively and locked).
    ``signals`` of one recording: integer (rows, cols, length) with length <= n_samples, padded
    with zeros. ``contact_interval=True`` adds the optional ground-truth field (then every append
    must give one). Extra root attributes go in ``attrs`` (dicts are stored as JSON text).
    ``durable=False`` skips the per-append ``fsync`` (appends still survive a crash of the
    process, not a power loss; for data that can be made again, such as simulated campaigns).
    ``append`` also takes an :class:`EncodedRecording` (from :func:`encode_recording` with this
    writer's ``grid_shape``, ``n_samples`` and ``compression_level``), which lets worker
    processes do the compression. Compression: gzip (deflate) at ``compression_level`` with the
    shuffle filter, or none (``compression_level=None``).

    Each way out of ``with CampaignWriter(...)`` (docs/dataset-format.md, "Each way out"):
    the block ends normally: the campaign file is built and the journal deleted; an exception
    (``KeyboardInterrupt`` from Ctrl-C included) ends it: no campaign file appears, the
    journal is kept with every recording whose append returned (``eskin recover`` builds the
    campaign) and the exception carries a note saying so and naming a failed append; the
    process dies (SIGTERM without a handler, kill -9, a crash, power loss): the journal is kept
    likewise. ``on_error="discard"`` deletes the journal on an exception instead, for data that
    still exists elsewhere (arrays in memory, imported files, a simulator seed). A block that
    appended nothing leaves nothing.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        grid_shape: tuple[int, int] = (4, 4),
        n_samples: int,
        sample_rate_hz: float,
        volts_per_count: float,
        modalities: Sequence[str],
        source: str,
        attrs: Mapping[str, Any] | None = None,
        contact_interval: bool = False,
        overwrite: bool = False,
        compression_level: int | None = 1,
        extra_fields: Mapping[str, Any] | None = None,
        durable: bool = True,
        on_error: str = "keep",
    ):
        from eskin.data.journal import JournalWriter

        if on_error not in ("keep", "discard"):
            raise ValueError(f"on_error must be 'keep' or 'discard', got {on_error!r}")
        self.on_error = on_error

        self.path = Path(path)
        rows, cols = (int(v) for v in grid_shape)
        if rows < 1 or cols < 1:
            raise ValueError(f"grid_shape must be positive, got {tuple(grid_shape)}")
        if int(n_samples) < 1:
            raise ValueError(f"n_samples must be >= 1, got {n_samples}")
        check_sizes(str(self.path), 0, rows, cols, int(n_samples))
        dec = _check_attrs(str(self.path), {
            **{k: v for k, v in dict(attrs or {}).items()},
            "format": FORMAT, "format_version": FORMAT_VERSION,
            "sample_rate_hz": sample_rate_hz, "volts_per_count": volts_per_count,
            "modalities": list(modalities), "source": source})
        _check_target(self.path, overwrite)
        if compression_level is not None and not 0 <= int(compression_level) <= 9:
            raise ValueError(f"compression_level must be None or 0..9, got {compression_level}")
        self.grid_shape = (rows, cols)
        self.n_samples = int(n_samples)
        self.compression_level = None if compression_level is None else int(compression_level)
        self.modalities = dec["modalities"]
        self.overwrite = bool(overwrite)
        self._with_ci = bool(contact_interval)
        self._extra_types = {str(k): np.dtype(v) for k, v in dict(extra_fields or {}).items()}
        for k, dt in self._extra_types.items():
            if dt.hasobject:
                raise ValueError(f"extra field {k!r}: dtype {dt} cannot be stored (use a "
                                 f"numeric or fixed-size dtype)")
        self._journal = JournalWriter(self.path, _journal_settings(
            dict(attrs or {}), dec, self.grid_shape, self.n_samples, self.compression_level,
            self._with_ci, self._extra_types), durable=durable)
        self._n = 0
        self._closed = False
        self._failed: int | None = None  # index of an append that raised

    def __len__(self) -> int:
        return self._n

    @property
    def journal(self) -> Path:
        """The journal file holding the recordings appended so far."""
        return self._journal.path

    def append(self, signals: Any, *, modality: int | str, participant: int, direction: int,
               run: int, length: int | None = None,
               contact_interval: tuple[int, int] | None = None,
               extra: Mapping[str, Any] | None = None) -> int:
        """Append one recording; return its index. When this returns, the recording is on the
        disk (it survives a crash of this process or of the machine)."""
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        try:
            return self._append(signals, modality, participant, direction, run, length,
                                contact_interval, extra)
        except BaseException:
            self._failed = self._n
            raise

    def _append(self, signals: Any, modality: int | str, participant: int, direction: int,
                run: int, length: int | None, contact_interval: tuple[int, int] | None,
                extra: Mapping[str, Any] | None) -> int:
        where = f"{self.path}: recording {self._n}"
        if isinstance(signals, EncodedRecording):
            enc = signals
            if (enc.grid_shape != self.grid_shape or enc.n_samples != self.n_samples
                    or enc.compression_level != self.compression_level):
                raise ValueError(
                    f"{where}: encoded for grid {enc.grid_shape}, T={enc.n_samples}, level "
                    f"{enc.compression_level}; this writer has {self.grid_shape}, "
                    f"T={self.n_samples}, level {self.compression_level}")
            if length is not None and int(length) != enc.length:
                raise ValueError(f"{where}: length {length} differs from the encoded "
                                 f"recording's {enc.length}")
        else:
            enc = encode_recording(signals, grid_shape=self.grid_shape, n_samples=self.n_samples,
                                   length=length, compression_level=self.compression_level,
                                   where=where)
        meta = self._check_labels(where, enc.length, modality, participant, direction, run,
                                  contact_interval)
        extra = dict(extra or {})
        if set(extra) != set(self._extra_types):
            raise ValueError(
                f"{where}: extra fields {sorted(extra)} do not match the declared "
                f"extra_fields {sorted(self._extra_types)}")
        typed = {k: (extra[k], dt) for k, dt in self._extra_types.items()}
        self._journal.append(meta, typed, enc.chunk)
        self._n += 1
        return self._n - 1

    def _check_labels(self, where: str, n_valid: int, modality: int | str, participant: int,
                      direction: int, run: int,
                      contact_interval: tuple[int, int] | None) -> dict[str, Any]:
        """Validate one recording's labels; return them as the journal stores them."""
        if isinstance(modality, str):
            if modality not in self.modalities:
                raise ValueError(
                    f"{where}: unknown modality {modality!r} "
                    f"(campaign modalities: {self.modalities})")
            modality = self.modalities.index(modality)
        if not 0 <= int(modality) < len(self.modalities):
            raise ValueError(f"{where}: modality id {modality} out of range")
        if int(direction) not in DIRECTION_NAMES:
            raise ValueError(f"{where}: direction {direction} (0 horizontal, 1 vertical, "
                             f"255 unknown)")
        if not 0 <= int(run) <= 255:
            raise ValueError(f"{where}: run {run} outside [0, 255]")
        info = np.iinfo(np.int32)
        if not info.min <= int(participant) <= info.max:
            raise ValueError(f"{where}: participant {participant} outside the int32 range")
        meta = {"length": int(n_valid), "modality": int(modality),
                "participant": int(participant), "direction": int(direction), "run": int(run)}
        if self._with_ci:
            if contact_interval is None:
                raise ValueError(f"{where}: contact_interval required")
            on, off = (int(v) for v in contact_interval)
            if not 0 <= on <= off <= n_valid:
                raise ValueError(f"{where}: contact interval [{on}, {off}) not within "
                                 f"[0, {n_valid}]")
            meta["contact_interval"] = [on, off]
        return meta

    def close(self) -> None:
        """Build the campaign file from the journal and move it into place.

        Raises ``FileExistsError`` if ``path`` appeared meanwhile (and ``overwrite`` is False);
        then, as after any failure here, the journal is kept and ``eskin recover`` can write
        the campaign elsewhere.
        """
        if self._closed:
            return
        self._closed = True
        _finish_journal(self._journal.path, self.path, self.overwrite, held=self._journal)

    def abort(self) -> None:
        """Discard everything written so far (the target file is left untouched)."""
        self._closed = True
        self._journal.discard()

    def keep(self) -> str:
        """Stop writing without building the campaign: the journal stays on the disk, holding
        every recording whose ``append`` returned, for ``eskin recover``; returns a sentence
        saying so (what ``with`` adds to an exception that ends the block)."""
        self._closed = True
        self._journal.release()
        text = (f"{self.path}: the {self._n} recordings whose append returned are kept in the "
                f"journal {self._journal.path}; `eskin recover {self.path}` builds the campaign "
                f"from them")
        if self._failed is not None:
            text += f" (recording {self._failed}, whose append failed, is not among them)"
        return text

    def __enter__(self) -> CampaignWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        elif self._closed:
            return
        elif self._n == 0 or self.on_error == "discard":
            self.abort()
        else:
            note = self.keep()
            if exc is not None and hasattr(exc, "add_note"):
                exc.add_note(note)


def _check_target(path: Path, overwrite: bool) -> None:
    """Refuse an output path that holds data (unless ``overwrite``) or cannot be written."""
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"{path}: file exists; refusing to overwrite recorded data "
            f"(pass overwrite=True, or --force on the command line)")
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a directory")
    if not path.parent.exists():
        raise FileNotFoundError(f"{path.parent}: output folder does not exist")


def _journal_settings(attrs: dict[str, Any], dec: Mapping[str, Any], grid: tuple[int, int],
                      n_samples: int, level: int | None, with_ci: bool,
                      extra_types: Mapping[str, np.dtype]) -> dict[str, Any]:
    """What the journal must remember to build the campaign file without the writer."""
    from eskin.data.journal import encode_attr

    values = {**attrs, "format": FORMAT, "format_version": np.int64(FORMAT_VERSION),
              "sample_rate_hz": float(dec["sample_rate_hz"]),
              "volts_per_count": float(dec["volts_per_count"]),
              "modalities": list(dec["modalities"]), "source": dec["source"]}
    return {"grid_shape": list(grid), "n_samples": n_samples, "compression_level": level,
            "contact_interval": with_ci,
            "extra_fields": [[k, dt.str] for k, dt in extra_types.items()],
            "attrs": [[k, encode_attr(_attr_value(v))] for k, v in values.items()]}


class _RecordCheck:
    """The campaign loader's checks on one journal record at a time (labels, contact interval,
    extra values, the chunk's size), so that recovery writes only what the loader accepts."""

    def __init__(self, settings: Mapping[str, Any], attrs: Mapping[str, Any], where: str):
        self.rows, self.cols = (int(v) for v in settings["grid_shape"])
        self.t = int(settings["n_samples"])
        self.level = settings["compression_level"]
        self.n_modalities = len(attrs["modalities"])
        self.with_ci = bool(settings["contact_interval"])
        self.extra_types = {k: np.dtype(v) for k, v in settings["extra_fields"]}
        self.extra_shapes: dict[str, tuple[int, ...]] = {}
        self.where = where

    def problem(self, index: int, rec: Any, verify_data: bool) -> str:
        """What is wrong with record ``index`` ("" when nothing), naming the field;
        ``verify_data``: also inflate its chunk to check its size."""
        arrays = {k: [rec.meta.get(k)] for k in _LABEL_FIELDS}
        if self.with_ci:
            arrays["contact_interval"] = [rec.meta.get("contact_interval")]
        try:
            arrays = {k: np.asarray(v) for k, v in arrays.items()}
            labels = _check_labels(self.where, 1, arrays)
            _check_contents(self.where, labels, self.n_modalities, self.t, first=index)
        except CampaignFormatError as exc:
            return f"{exc.field}: {exc.problem}"
        except (ValueError, TypeError, OverflowError) as exc:
            return f"labels: {exc}"
        for k, dt in self.extra_types.items():
            v = rec.extras.get(k)
            shape = self.extra_shapes.setdefault(k, getattr(v, "shape", ()))
            if not isinstance(v, np.ndarray) or v.dtype != dt or v.shape != shape:
                return (f"/recordings/extra/{k}: {getattr(v, 'dtype', type(v).__name__)} "
                        f"{getattr(v, 'shape', '')}, expected {dt} {shape}")
        size = self.rows * self.cols * self.t * 2
        if not verify_data:
            return ""
        try:
            raw = len(rec.chunk) if self.level is None else len(
                zlib.decompressobj().decompress(rec.chunk, size + 1))
        except zlib.error as exc:
            return f"/recordings/signals: the compressed chunk does not inflate ({exc})"
        if raw != size:
            return (f"/recordings/signals: the chunk holds {raw} bytes, not the {size} of a "
                    f"{self.rows}x{self.cols}x{self.t} int16 recording")
        return ""


def _build_from_journal(contents: Any, out: Path, verify_data: bool
                        ) -> tuple[int, list[str]]:
    """Write the campaign file ``out`` from a journal's settings and its records that pass the
    loader's checks; return the number of recordings written and, for each record skipped,
    "record K: field: problem"."""
    import h5py

    from eskin.data.journal import decode_attr

    s = contents.settings
    rows, cols = s["grid_shape"]
    t, level = int(s["n_samples"]), s["compression_level"]
    check_sizes(str(contents.path), 0, rows, cols, t)
    attrs = {k: decode_attr(v) for k, v in s["attrs"]}
    try:
        _check_attrs(str(contents.path), attrs)
    except CampaignFormatError as exc:
        raise CampaignFormatError(contents.path, f"header: {exc.field}", exc.problem) from None
    check = _RecordCheck(s, attrs, str(contents.path))
    labels: dict[str, list[Any]] = {k: [] for k in (*_LABEL_FIELDS, "contact_interval")}
    extras: dict[str, list[Any]] = {k: [] for k in check.extra_types}
    skipped: list[str] = []
    with h5py.File(out, "w") as f:
        for k, v in attrs.items():
            f.attrs[k] = v
        grp = f.create_group("recordings")
        sig = grp.create_dataset(
            "signals", shape=(0, rows, cols, t), maxshape=(None, rows, cols, t), dtype=np.int16,
            chunks=(1, rows, cols, t), compression=None if level is None else "gzip",
            compression_opts=level, shuffle=level is not None)
        n = 0
        skipped += contents.skipped
        for rec in contents.records():
            problem = check.problem(rec.index, rec, verify_data)
            if problem:
                skipped.append(f"record {rec.index}: {problem}")
                continue
            sig.resize(n + 1, axis=0)
            sig.id.write_direct_chunk((n, 0, 0, 0), rec.chunk, filter_mask=0)
            for k, values in labels.items():
                if k in rec.meta:
                    values.append(rec.meta[k])
            for k, values in extras.items():
                values.append(rec.extras[k])
            n += 1
        for name, (dtype, _) in _LABEL_FIELDS.items():
            grp.create_dataset(name, data=np.asarray(labels[name], dtype=dtype).reshape(n))
        if s["contact_interval"]:
            grp.create_dataset("contact_interval", data=np.asarray(
                labels["contact_interval"], dtype=np.int32).reshape(n, 2))
        if check.extra_types:
            eg = grp.create_group("extra")
            for k, dt in check.extra_types.items():
                shape = (n, *check.extra_shapes.get(k, ()))
                eg.create_dataset(k, data=np.asarray(extras[k], dtype=dt).reshape(shape))
    fd = os.open(out, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    return n, sorted(skipped, key=lambda text: int(text.split(":")[0].split()[1]))


def _place(tmp: Path, target: Path, overwrite: bool) -> None:
    """Move the finished file ``tmp`` to ``target``; without ``overwrite`` this is exclusive:
    a ``target`` that exists now (even one created a moment ago) is never replaced."""
    if overwrite:
        os.replace(tmp, target)
        return
    try:
        os.link(tmp, target)  # fails if target exists, atomically
    except FileExistsError:
        raise FileExistsError(
            f"{target}: file exists (it appeared while recording); refusing to overwrite "
            f"it") from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
            raise
        # a file system without hard links (FAT on a memory card): check, then rename
        if target.exists():
            raise FileExistsError(f"{target}: file exists; refusing to overwrite it") from None
        os.rename(tmp, target)
        return
    tmp.unlink()


@dataclass(frozen=True)
class Recovery:
    """What :func:`recover_campaign` salvaged."""

    output: Path
    recordings: int
    dropped_bytes: int
    dropped_reason: str
    skipped: tuple[str, ...] = ()
    kept_journal: Path | None = None

    def message(self) -> str:
        """One line for the user: what was recovered and what was not."""
        text = f"recovered {self.recordings} complete recordings into {self.output}"
        if self.skipped:
            more = len(self.skipped) - 10
            text += (f"; skipped {len(self.skipped)} invalid records ("
                     + "; ".join(self.skipped[:10]) + (f"; {more} more" if more > 0 else "")
                     + ")")
        if self.dropped_bytes:
            text += (f"; dropped the last {self.dropped_bytes} bytes of the journal "
                     f"({self.dropped_reason})")
        if self.kept_journal is not None:
            text += f"; the journal is kept as {self.kept_journal}"
        return text


def _finish_journal(journal: Path, output: Path, overwrite: bool,
                    held: Any = None) -> Recovery:
    """Build ``output`` from ``journal`` (locked by us: ``held`` is the writer holding it, or
    None to lock it here), check that it loads and reads back, place it, then delete the
    journal (or, if records were skipped as invalid, move it aside as ``.NAME.rejected``).
    An I/O error (a full or read-only disk) is one line naming the file; the journal stays
    until the campaign is in place."""
    try:
        return _build_and_place(journal, output, overwrite, held)
    except OSError as exc:
        if isinstance(exc, (FileExistsError, FileNotFoundError, IsADirectoryError)):
            raise
        reason = exc.strerror or str(exc).split("(")[0].strip() or type(exc).__name__
        keep = ("the journal is kept" if journal.exists()
                else "the campaign file is in place")
        message = f"{output}: cannot write the campaign file ({reason}); {keep}: {journal}"
        # without an errno, OSError(None, text) would print "[Errno None] text"
        raise (OSError(message) if exc.errno is None else OSError(exc.errno, message)) from exc
    finally:
        if held is not None:
            held.release()


def _build_and_place(journal: Path, output: Path, overwrite: bool, held: Any) -> Recovery:
    from eskin.data.journal import LockedJournal, fsync_dir

    tmp = output.with_name(f".{output.name}.{os.getpid()}.building")
    kept = None
    with LockedJournal(journal, lock=held is None) as reader:
        # what a builder killed during its close left (no cleanup runs on SIGKILL or SIGTERM)
        remove_stale(output.parent, f".{output.name}.", ".building")
        contents = reader.read()
        try:
            # the writer's own records were checked by append; recovery checks them all
            n, skipped = _build_from_journal(contents, tmp, verify_data=held is None)
            try:
                load_campaign(tmp, check_data=held is None).close()
            except CampaignFormatError as exc:
                raise CampaignFormatError(
                    output, "", f"the campaign built from {journal} does not check "
                    f"({exc.field}: {exc.problem}); the journal is kept") from None
            _place(tmp, output, overwrite)
        finally:
            tmp.unlink(missing_ok=True)
        fsync_dir(output.parent)
        if skipped:
            kept = journal.with_name(journal.name[: -len(".partial")] + ".rejected")
            os.replace(journal, kept)
        else:
            journal.unlink()
        fsync_dir(journal.parent)
    return Recovery(output, n, contents.dropped_bytes, contents.dropped_reason,
                    tuple(skipped), kept)


def recover_campaign(path: str | os.PathLike[str], output: str | os.PathLike[str] | None = None,
                     *, overwrite: bool = False) -> Recovery:
    """Salvage the recordings of a writer that died (kill -9, power loss, a crash).

    ``path`` is the campaign file the writer was writing (or its journal ``.NAME.partial``).
    Every recording whose ``append`` had returned is written to ``output`` (default: ``path``),
    a normal campaign file; the torn recording that was in flight, if any, is dropped. The
    journal is deleted once the campaign file is in place. Refuses while the writer is still
    alive, and never replaces an existing file unless ``overwrite=True``.
    """
    from eskin.data.journal import journal_and_target

    journal, target = journal_and_target(path)
    if not journal.exists():
        raise FileNotFoundError(f"{target}: nothing to recover (no journal {journal.name} "
                                f"next to it)")
    out = Path(output) if output is not None else target
    if out.exists() and os.path.samefile(out, journal):
        raise ValueError(f"{out}: is the journal being recovered; choose another output file")
    _check_target(out, overwrite)
    return _finish_journal(journal, out, overwrite)


def write_campaign(
    path: str | os.PathLike[str],
    signals: Any,
    *,
    modality: Any,
    participant: Any,
    direction: Any,
    run: Any,
    modalities: Sequence[str],
    sample_rate_hz: float,
    volts_per_count: float,
    source: str,
    lengths: Any = None,
    contact_interval: Any = None,
    attrs: Mapping[str, Any] | None = None,
    extras: Mapping[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a whole campaign at once; ``signals`` is int16 (n, rows, cols, T) or any
    sequence of (rows, cols, length_i) recordings. Returns the path.

    A :class:`Campaign` can be written back with :func:`save_campaign`.
    """
    if isinstance(signals, (np.ndarray, CampaignSignals)):
        n = signals.shape[0]
        if signals.ndim != 4:
            raise ValueError(f"signals must be (n, rows, cols, T), got shape {signals.shape}")
        grid = tuple(signals.shape[1:3])
        t = int(signals.shape[3])
        recs: Iterable[Any] = (signals[i] for i in range(n))
    else:
        recs_list = [np.asarray(r) for r in signals]
        n = len(recs_list)
        if n == 0:
            raise ValueError("no recordings given (use a (0, rows, cols, T) array)")
        grid = tuple(recs_list[0].shape[:2])
        t = max(r.shape[-1] for r in recs_list)
        recs = recs_list
    labels = {k: np.asarray(v).ravel() for k, v in (
        ("modality", modality), ("participant", participant), ("direction", direction),
        ("run", run))}
    for k, v in labels.items():
        if v.shape != (n,):
            raise ValueError(f"{k} must have one entry per recording ({n}), got shape {v.shape}")
    lens = None if lengths is None else np.asarray(lengths).ravel()
    if lens is not None and lens.shape != (n,):
        raise ValueError(f"lengths must have one entry per recording ({n}), got {lens.shape}")
    ci = None if contact_interval is None else np.asarray(contact_interval)
    if ci is not None and ci.shape != (n, 2):
        raise ValueError(f"contact_interval must have shape ({n}, 2), got {ci.shape}")
    ex = {k: np.asarray(v) for k, v in dict(extras or {}).items()}
    for k, v in ex.items():
        if v.ndim < 1 or v.shape[0] != n:
            raise ValueError(f"extras[{k!r}] must have one entry per recording ({n}), "
                             f"got shape {v.shape}")
    with CampaignWriter(path, grid_shape=grid, n_samples=max(t, 1), sample_rate_hz=sample_rate_hz,
                        volts_per_count=volts_per_count, modalities=modalities, source=source,
                        attrs=attrs, contact_interval=ci is not None, overwrite=overwrite,
                        extra_fields={k: v.dtype for k, v in ex.items()},
                        on_error="discard") as w:
        for i, rec in enumerate(recs):
            w.append(rec, modality=int(labels["modality"][i]),
                     participant=int(labels["participant"][i]),
                     direction=int(labels["direction"][i]), run=int(labels["run"][i]),
                     length=None if lens is None else int(lens[i]),
                     contact_interval=None if ci is None else tuple(ci[i]),
                     extra={k: v[i] for k, v in ex.items()})
    return Path(path)


def save_campaign(campaign: Campaign, path: str | os.PathLike[str], *,
                  overwrite: bool = False) -> Path:
    """Write a :class:`Campaign` (for example a subset of another one) to a new file."""
    extra = {k: v for k, v in campaign.attrs.items() if k not in _REQUIRED_ATTRS}
    return write_campaign(
        path, campaign.signals, modality=campaign.modality, participant=campaign.participant,
        direction=campaign.direction, run=campaign.run, modalities=campaign.modalities,
        sample_rate_hz=campaign.sample_rate_hz, volts_per_count=campaign.volts_per_count,
        source=campaign.source, lengths=campaign.lengths,
        contact_interval=campaign.contact_interval, attrs=extra, extras=campaign.extras,
        overwrite=overwrite)
