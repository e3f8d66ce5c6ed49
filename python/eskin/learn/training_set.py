"""Training sets: recordings, their labels and groups, preprocessed once per (D, subsample).

:func:`preprocess_campaign` turns the recordings of a campaign (or of in-memory arrays,
:class:`ArrayRecordings`) into tensors in chunks, once per (D, subsample method), with each
recording's touch window read at the bounded window's stride the stream uses; the rest reads
class and group labels, adapts the detector to the sample rate, and says which groups the
cross-validation splits follow.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eskin.data.limits import MAX_D, MIN_D
from eskin.errors import ClassLeftOut, TrainingError


@dataclass
class Prepared:
    """Preprocessed patterns of some recordings, per (D, subsample method)."""

    X: dict[tuple[int, str], np.ndarray]
    windows: np.ndarray  # (n, 2) [start, stop) samples, per recording
    bad_taxels: np.ndarray  # (n,) dead or noisy taxels per recording (with stats=True)
    snr_db: np.ndarray  # (n,) power inside the window over power outside, dB (nan if undefined)
    seconds: float
    notes: list[str] = field(default_factory=list)  # detector settings adapted to the rate


class ArrayRecordings:
    """Campaign-like access (recording(i), lengths, sample_rate_hz) to an in-memory array."""

    def __init__(
        self,
        signals: np.ndarray,
        lengths: Sequence[int] | None = None,
        sample_rate_hz: float = 3000.0,
    ) -> None:
        sig = np.asarray(signals)
        if sig.ndim != 4:
            raise TrainingError(
                f"signals must have shape (n, rows, cols, T), got shape {sig.shape}"
            )
        self.signals = sig
        T = sig.shape[-1]
        self.lengths = (
            np.full(len(sig), T, np.int64) if lengths is None else np.asarray(lengths, np.int64)
        )
        if (
            self.lengths.shape != (len(sig),)
            or np.any(self.lengths < 1)
            or np.any(self.lengths > T)
        ):
            raise TrainingError(f"lengths must be {len(sig)} values in 1..{T}")
        self.sample_rate_hz = float(sample_rate_hz)

    def __len__(self) -> int:
        return len(self.signals)

    def recording(self, i: int) -> np.ndarray:
        return self.signals[i][..., : self.lengths[i]]


def _recording_stats(rec: np.ndarray, start: int, stop: int) -> tuple[int, float]:
    """(bad taxels, window SNR in dB) of one recording (rows, cols, length).

    A taxel is bad when it is dead (standard deviation below 1 % of the recording's median
    taxel standard deviation) or noisy (its standard deviation outside the touch window above
    4 times the median over taxels). The SNR is the mean power inside the window over the mean
    power outside it (nan when either side is empty).
    """
    x = rec.reshape(-1, rec.shape[-1]).astype(np.float64)
    x = x - x.mean(axis=1, keepdims=True)
    std = x.std(axis=1)
    med = float(np.median(std))
    dead = std <= 0.01 * med if med > 0 else np.ones(len(std), bool)
    quiet = np.concatenate([x[:, :start], x[:, stop:]], axis=1)
    noisy = np.zeros(len(std), bool)
    if quiet.shape[1] > 1:
        qstd = quiet.std(axis=1)
        qmed = float(np.median(qstd))
        if qmed > 0:
            noisy = qstd > 4.0 * qmed
    bad = int(np.sum(dead | noisy))
    p = np.mean(x**2, axis=0)
    inside = p[start:stop]
    outside = np.concatenate([p[:start], p[stop:]])
    if inside.size == 0 or outside.size == 0 or float(np.mean(outside)) <= 0:
        return bad, float("nan")
    return bad, 10 * math.log10(max(float(np.mean(inside)), 1e-300) / float(np.mean(outside)))


def preprocess_campaign(
    campaign: Any,
    indices: Sequence[int] | np.ndarray,
    variants: Sequence[tuple[int, str]],
    *,
    window: str = "energy",
    config: Any = None,
    sample_rate_hz: float | None = None,
    short: str = "interpolate",
    chunk: int = 32,
    stats: bool = False,
    on_chunk: Callable[[int], None] | None = None,
) -> Prepared:
    """Preprocess the recordings ``indices`` of ``campaign`` for every (D, subsample method).

    ``campaign`` is a :class:`~eskin.campaign.Campaign` or an :class:`ArrayRecordings`. Touch
    windows are detected once per recording with :func:`eskin.detect_touches` (or the whole
    recording is the window with ``window="none"``) and handed to :func:`eskin.preprocess` for
    every variant with their bounded-window strides, so detection is not repeated and every
    tensor is the one ``window="energy"`` (and a stream classifier) computes. Recordings are read in chunks: a lazily loaded
    campaign never sits in memory whole. ``short`` says what to do with a window shorter than D
    ("interpolate" or "error", see :func:`eskin.preprocess`). ``stats`` also computes the per-recording bad-taxel
    counts and window SNR used to rank outlier participants.
    """
    from eskin.signal.preprocess import detect_touches, preprocess

    if window not in ("energy", "none"):
        raise TrainingError(f"window must be 'energy' or 'none', got {window!r}")
    t0 = time.perf_counter()
    rate = float(sample_rate_hz if sample_rate_hz is not None else campaign.sample_rate_hz)
    config, notes = window_config_for_rate(config, rate)
    indices = np.asarray(indices, dtype=np.int64)
    lengths = np.asarray(campaign.lengths)
    n = len(indices)
    variants = _checked_variants(variants)
    if n == 0:
        raise TrainingError("no recording to preprocess")
    rows, cols = (int(v) for v in np.shape(campaign.recording(int(indices[0])))[:2])
    out = {(D, s): np.empty((n, rows, cols, D)) for D, s in variants}
    windows = np.zeros((n, 2), np.int64)
    bad = np.zeros(n, np.int64)
    snr = np.full(n, np.nan)
    for c0 in range(0, n, chunk):
        sel = indices[c0 : c0 + chunk]
        block, lens = _read_block(campaign, sel, lengths[sel], rows, cols)
        if window == "energy":
            found = detect_touches(block, lengths=lens, sample_rate_hz=rate, config=config)
            win = np.stack([found.start, found.stop, found.stride], axis=1).astype(np.int64)
        else:
            win = np.stack([np.zeros_like(lens), lens, np.ones_like(lens)], axis=1)
        for D, s in variants:
            out[(D, s)][c0 : c0 + len(sel)] = preprocess(
                block,
                D,
                lengths=lens,
                sample_rate_hz=rate,
                window=win,
                subsample=s,
                config=config,
                short=short,
            )
        windows[c0 : c0 + len(sel)] = win[:, :2]
        if stats:
            for j in range(len(sel)):
                bad[c0 + j], snr[c0 + j] = _recording_stats(
                    block[j, :, :, : lens[j]], int(win[j, 0]), int(win[j, 1])
                )
        if on_chunk is not None:
            on_chunk(len(sel))
    return Prepared(out, windows, bad, snr, time.perf_counter() - t0, notes)


#: the share of the training touch windows that must hold at least D samples for D to be
#: searched or used by default (0.5: the median window fills D without interpolation)
FILL_QUANTILE = 0.5


def touch_window_lengths(
    campaign: Any,
    indices: Sequence[int] | np.ndarray,
    *,
    window: str = "energy",
    config: Any = None,
    sample_rate_hz: float | None = None,
    chunk: int = 32,
) -> np.ndarray:
    """Samples in each recording's touch window (the window :func:`preprocess_campaign` reads):
    the detector's ``stop - start`` with ``window="energy"``, the recording's length with
    ``window="none"``."""
    from eskin.signal.preprocess import detect_touches

    indices = np.asarray(indices, dtype=np.int64)
    lengths = np.asarray(campaign.lengths)
    if window == "none" or len(indices) == 0:
        return lengths[indices].astype(np.int64)
    rate = float(sample_rate_hz if sample_rate_hz is not None else campaign.sample_rate_hz)
    config, _ = window_config_for_rate(config, rate)
    rows, cols = (int(v) for v in np.shape(campaign.recording(int(indices[0])))[:2])
    out = np.zeros(len(indices), np.int64)
    for c0 in range(0, len(indices), chunk):
        sel = indices[c0 : c0 + chunk]
        block, lens = _read_block(campaign, sel, lengths[sel], rows, cols)
        found = detect_touches(block, lengths=lens, sample_rate_hz=rate, config=config)
        out[c0 : c0 + len(sel)] = np.asarray(found.stop) - np.asarray(found.start)
    return out


def fillable_D(window_lengths: Sequence[int] | np.ndarray) -> int | None:
    """The largest D that the share :data:`FILL_QUANTILE` of the touch windows fill with
    samples of their own (a longer D only interpolates them: 10 samples resampled to 100 add
    90 made-up ones and grow every mode of the time axis tenfold), at least :data:`MIN_D`;
    None without windows."""
    w = np.asarray(window_lengths, dtype=np.int64)
    if w.size == 0:
        return None
    return max(MIN_D, int(np.quantile(w, 1.0 - FILL_QUANTILE, method="lower")))


def _checked_variants(variants: Sequence[tuple[int, str]]) -> list[tuple[int, str]]:
    """The distinct (D, subsample method) pairs, sorted and checked."""
    variants = sorted({(int(D), str(s)) for D, s in variants})
    for D, s in variants:
        if not MIN_D <= D <= MAX_D:
            raise TrainingError(f"D must be in [{MIN_D}, {MAX_D}] (what a .eskin model holds), "
                                f"got {D}")
        if s not in ("algorithm2", "even"):
            raise TrainingError(f"subsample must be 'algorithm2' or 'even', got {s!r}")
    return variants


def _read_block(
    campaign: Any, sel: np.ndarray, lengths: np.ndarray, rows: int, cols: int
) -> tuple[np.ndarray, np.ndarray]:
    """The recordings ``sel`` as one zero-padded block (n, rows, cols, longest) and their
    valid lengths."""
    recs = [np.asarray(campaign.recording(int(i))) for i in sel]
    lens = np.minimum(np.array([r.shape[-1] for r in recs], np.int64), lengths)
    if np.any(lens < 1):
        raise TrainingError(f"recording {int(sel[np.argmin(lens)])} is empty (length 0)")
    block = np.zeros((len(recs), rows, cols, int(lens.max())), dtype=recs[0].dtype)
    for j, r in enumerate(recs):
        block[j, :, :, : lens[j]] = r[..., : lens[j]]
    return block, lens


#: classes with fewer recordings than this get a warning note
MIN_CLASS_RECORDINGS = 5
#: labels of every campaign that can group recordings (integer extra fields can too)
GROUP_FIELDS: tuple[str, ...] = ("participant", "run", "direction")


def true_label_names(data: Any, indices: Sequence[int] | np.ndarray) -> list[str | None]:
    """The class each of the recordings ``indices`` of ``data`` was recorded as: a campaign's
    modality names indexed by its modality ids (its loader refuses an id the names do not
    cover); None for every recording of data without names (in-memory arrays)."""
    names = [str(m) for m in (getattr(data, "modalities", None) or [])]
    if not names:
        return [None] * len(indices)
    modality = np.asarray(data.modality)
    return [names[int(modality[i])] for i in indices]


def group_labels(campaign: Any, name: str) -> np.ndarray:
    """The per-recording integer label ``name`` of a campaign: participant, run, direction, or
    an integer extra field (``/recordings/extra/<name>``)."""
    if name in GROUP_FIELDS:
        values = np.asarray(getattr(campaign, name))
    elif name in getattr(campaign, "extras", {}):
        values = np.asarray(campaign.extras[name])
    else:
        extras = sorted(getattr(campaign, "extras", {}))
        raise TrainingError(
            f"--groups {name!r}: no such label; the campaign has {', '.join(GROUP_FIELDS)}"
            + (f" and the extra fields {', '.join(extras)}" if extras else "")
        )
    if values.ndim != 1 or values.dtype.kind not in "iub":
        raise TrainingError(
            f"--groups {name!r}: must be one integer per recording, got dtype {values.dtype} "
            f"shape {values.shape}"
        )
    return values.astype(np.int64)


def window_config_for_rate(config: Any, rate: float) -> tuple[Any, list[str]]:
    """The detector configuration (default: eskin's) made valid at ``rate``, with notes on what
    was adapted (see :meth:`eskin.WindowConfig.for_rate`)."""
    from eskin.signal.preprocess import WindowConfig

    if config is None:
        config = WindowConfig()
    elif isinstance(config, Mapping):
        config = WindowConfig.from_dict(dict(config))
    return config.for_rate(rate)


def small_class_notes(classes: Sequence[str], y: np.ndarray) -> list[str]:
    """A warning for every class with fewer than :data:`MIN_CLASS_RECORDINGS` recordings."""
    notes = []
    for k, name in enumerate(classes):
        n = int(np.sum(y == k))
        if n < MIN_CLASS_RECORDINGS:
            notes.append(
                f"class {name} has only {n} recording{'s' if n != 1 else ''} (fewer than "
                f"{MIN_CLASS_RECORDINGS}): its machine rests on very few examples, and the "
                "selection's estimates and this class's accuracy are unreliable"
            )
    return notes


def load_training_data(
    data: Any, labels: Any, class_names: Sequence[str] | None, lengths: Any, sample_rate_hz: float
) -> tuple[Any, np.ndarray, list[str], np.ndarray | None, dict[str, Any]]:
    """(recordings, label ids, class names, participant ids or None, source info)."""
    if isinstance(data, (str, Path)):
        from eskin.data.campaign import load_campaign

        path = Path(data)
        data = load_campaign(path)
        info = {"campaign": str(path)}
    else:
        info = {}
    if hasattr(data, "modalities") and hasattr(data, "recording"):
        info.update(
            {"source": str(getattr(data, "source", "unknown")), "n_recordings": int(len(data))}
        )
        part = getattr(data, "participant", None)
        return (
            data,
            np.asarray(data.modality).astype(np.int64),
            [str(m) for m in data.modalities],
            None if part is None else np.asarray(part),
            info,
        )
    rec = ArrayRecordings(data, lengths, sample_rate_hz)
    if labels is None:
        raise TrainingError("training from arrays needs labels (one per recording)")
    lab = np.asarray(labels)
    if lab.shape != (len(rec),):
        raise TrainingError(f"labels must have shape ({len(rec)},), got {lab.shape}")
    if lab.dtype.kind in "iu":
        if class_names is None:
            names = [str(v) for v in sorted(set(lab.tolist()))]
            ids = np.searchsorted(np.array(sorted(set(lab.tolist()))), lab)
        else:
            names = [str(c) for c in class_names]
            if lab.min() < 0 or lab.max() >= len(names):
                raise TrainingError(f"integer labels must index class_names (0..{len(names) - 1})")
            ids = lab.astype(np.int64)
    else:
        names = [str(c) for c in (class_names or sorted(set(map(str, lab.tolist()))))]
        unknown = sorted(set(map(str, lab.tolist())) - set(names))
        if unknown:
            raise TrainingError(f"labels {unknown} are not in class_names {names}")
        ids = np.array([names.index(str(v)) for v in lab], np.int64)
    info.update({"source": "arrays", "n_recordings": int(len(rec))})
    return rec, ids, names, None, info


def cv_groups(
    selection: str, groups: np.ndarray | None, group_by: str
) -> tuple[np.ndarray | None, list[str]]:
    """The groups CV splits by (None: stratified splits of the recordings) and why not."""
    if selection != "cv":
        return groups, []
    if groups is None or len(np.unique(groups)) < 2:
        return None, [
            f"no {group_by} labels with at least 2 values: cross-validation splits the "
            "recordings (stratified by class), not people, so it may favour settings that "
            "suit the people it has seen more than new ones"
        ]
    return groups, []


def fit_grouped(
    fit: Callable[[np.ndarray | None], Any],
    groups: np.ndarray | None,
    group_by: str,
    notes: list[str],
) -> Any:
    """``(fit(groups), groups used)``; when a grouped split leaves one class out of a training
    part (too few groups for a class), ``fit(None)`` (stratified splits) with a note."""
    try:
        return fit(groups), groups is not None
    except ClassLeftOut:
        if groups is None:
            raise
    notes.append(
        f"grouped cross-validation left a class out of a training part (too few {group_by} "
        "groups per class): the splits are stratified by class instead, not by group"
    )
    return fit(None), False


def require_touches(X: np.ndarray, data: Any) -> None:
    """Refuse training data in which no recording holds any signal (no touch anywhere)."""
    flat = X.reshape(len(X), -1)
    if len(flat) and np.all(flat.max(axis=1) == flat.min(axis=1)):
        where = f"{data}: " if isinstance(data, (str, os.PathLike)) else ""
        raise TrainingError(
            f"{where}no touch anywhere: each of the {len(flat)} training recordings is flat "
            f"(its preprocessed tensor is constant), so there is nothing to learn"
        )
