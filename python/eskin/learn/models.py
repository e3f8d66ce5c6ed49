"""Deployable touch models: train on a campaign (or arrays), save, load, predict.

A :class:`TouchModel` bundles everything needed to classify a raw recording: the
preprocessing settings (D, window mode and detector configuration, subsampling method, sample
rate, grid shape), the class names, the fitted estimator (one binary tensor machine, or a
:class:`~eskin.estimators.OneVsAllTouchClassifier` for three or more classes) and the model
selection report.

Files: :func:`save_model` / :func:`load_model` are the one function pair through which models
are written and read. The default container is a joblib (pickle) file holding a header dict
(``format``, ``format_version``, eskin version, classes, D, ...) and the model; loading checks the
header and says clearly what is wrong with a file that is not an eskin model. Like any pickle,
only load model files you trust. Other formats (the C++ ``.eskin`` file of :mod:`eskin.export`)
plug in by file suffix through :func:`register_model_format`.

This module also holds the pieces shared with :mod:`eskin.experiments`: the paper's grid in
per-mode alpha terms, building MD/CV searches, and preprocessing a campaign once per (D,
subsample method) in chunks.
"""

from __future__ import annotations

import contextlib
import importlib
import math
import os
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from eskin.data.limits import MAX_D, MIN_D
from eskin.errors import ModelFormatError, TrainingError
from eskin.learn.calibration import DEFAULT_REJECT
from eskin.learn.recipes import ALPHA_SPEC, one_vs_all_indices

MODEL_FORMAT = "eskin.touch-model"
MODEL_FORMAT_VERSION = 1

#: The paper's grid (Section 5.2). For the SVM, C = 1/lambda.
PAPER_LAMBDAS: tuple[float, ...] = (1e-3, 1e-2, 1e-1, 1e0, 1e1)
PAPER_SIGMAS: tuple[float, ...] = tuple(2.0**k for k in range(-4, 5))
PAPER_ALPHAS: tuple[str, ...] = ("1", "Q/2", "Q")

#: The amplitude-aware kernel's widths searched by default (None: the paper's kernel; a number:
#: the width in spreads of the training patterns' log energy, see eskin.TensorSVC). With the
#: factor in the grid the default recipe's held-out error on unseen participants of simulated
#: campaigns fell from 14.4 % to 11.3 % (99 units, docs/selection-study.md); "off" stays in the
#: grid for sensors whose amplitude says nothing about the touch.
DEFAULT_AMPLITUDES: tuple[float | None, ...] = (None, 1.0, 4.0)

QUICK_LAMBDAS: tuple[float, ...] = (1e-2, 1e0)
QUICK_SIGMAS: tuple[float, ...] = (2.0**-1, 2.0**1)
QUICK_ALPHAS: tuple[str, ...] = ("1", "Q/2")

#: D when the recordings allow it (the paper's largest; the study found it as good as 50 and
#: better than 20); with D=None, train_model takes the longest training recording when that is
#: shorter (no point stretching every touch by interpolation).
DEFAULT_D = 100

MACHINES: tuple[str, ...] = ("svm", "rls")
SELECTIONS: tuple[str, ...] = ("md", "cv")


# --------------------------------------------------------------------------------------------
# grid and searches (shared with eskin.experiments)




def alpha_value(label: str, shape: Sequence[int]) -> tuple[int, ...]:
    """Per-mode alpha of the grid labels "1", "Q/2", "Q" on patterns of ``shape``
    (``docs/paper-readings.md``, R8).

    Q_z = min(d_z, product of the other dimensions) is the rank bound of the mode-z unfolding
    (4, 4 and 16 for a 4x4xD pattern with D >= 16); Q_z/2 is rounded down and at least 1.
    """
    from eskin.learn.kernel import resolve_alphas

    if label not in ALPHA_SPEC:
        raise TrainingError(f"alpha label must be one of '1', 'Q/2', 'Q', got {label!r}")
    return tuple(int(a) for a in resolve_alphas(tuple(shape), ALPHA_SPEC[label]))


def alpha_label(alpha: Any) -> str | None:
    """The grid label ("1", "Q/2", "Q") of an estimator alpha value, or None."""
    for lab, spec in ALPHA_SPEC.items():
        if isinstance(alpha, str) == isinstance(spec, str) and alpha == spec:
            return lab
    return None


def param_grid(
    lambdas: Sequence[float] = PAPER_LAMBDAS,
    sigmas: Sequence[float] = PAPER_SIGMAS,
    alphas: Sequence[str] = PAPER_ALPHAS,
    amplitudes: Sequence[float | None] = (None,),
) -> dict[str, list[Any]]:
    """The search grid in lambda for both machines (the searches train the SVM with C =
    1/lambda, reading R9), sigma, alpha in the estimators' terms (1, "half", "full") and, unless
    it is only None (the paper's kernel), the amplitude factor's width."""
    for a in alphas:
        if a not in ALPHA_SPEC:
            raise TrainingError(f"alpha label must be one of '1', 'Q/2', 'Q', got {a!r}")
    if not lambdas or not sigmas or not alphas or not amplitudes:
        raise TrainingError(
            "the grid needs at least one lambda, one sigma, one alpha and one amplitude"
        )
    grid: dict[str, list[Any]] = {
        "lam": [float(v) for v in lambdas],
        "sigma": [float(v) for v in sigmas],
        "alpha": [ALPHA_SPEC[a] for a in alphas],
    }
    if list(amplitudes) != [None]:
        grid["amplitude"] = [_checked_amplitude(a) for a in amplitudes]
    return grid


def _checked_amplitude(value: Any) -> float | None:
    """``value`` (None, a number or its text) as the estimators' ``amplitude``; a TrainingError
    naming the accepted range otherwise."""
    from eskin.learn.estimators import AMPLITUDE_RANGE, check_amplitude

    if value is None:
        return None
    try:
        return check_amplitude(float(value))
    except (TypeError, ValueError):
        low, high = AMPLITUDE_RANGE
        raise TrainingError(
            f"amplitude must be 'off' or a number in [{low:g}, {high:g}], got {value!r}"
        ) from None


def parse_amplitudes(text: str) -> tuple[float | None, ...]:
    """Amplitude-factor widths from text such as "off", "1" or "off,1,4" ("off"/"none": the
    paper's kernel without the factor)."""
    values: list[float | None] = []
    for item in (t.strip() for t in str(text).split(",")):
        values.append(None if item.lower() in ("off", "none") else _checked_amplitude(item))
    return tuple(values)


def make_search(
    machine: str,
    selection: str,
    grid: Mapping[str, list[Any]],
    *,
    seed: int = 0,
    md_options: Mapping[str, Any] | None = None,
    cv_options: Mapping[str, Any] | None = None,
    n_jobs: int = 1,
) -> Any:
    """A Maximal Discrepancy or cross-validation search over ``grid`` for one tensor machine.

    CV searches are fitted with ``groups`` (participants) when known (:func:`fit_search`), so
    that no participant is on both sides of a split.
    """
    from eskin.learn.estimators import TensorRLS, TensorSVC
    from eskin.learn.selection import CrossValidationSearch, MaximalDiscrepancySearch

    if machine not in MACHINES:
        raise TrainingError(f"machine must be 'svm' or 'rls', got {machine!r}")
    est = TensorSVC() if machine == "svm" else TensorRLS()
    if selection == "md":
        return MaximalDiscrepancySearch(
            est, dict(grid), random_state=seed, n_jobs=n_jobs, **dict(md_options or {})
        )
    if selection == "cv":
        return CrossValidationSearch(
            est, dict(grid), random_state=seed, n_jobs=n_jobs, **dict(cv_options or {})
        )
    raise TrainingError(f"selection must be 'md' or 'cv', got {selection!r}")


def fit_search(search: Any, X: np.ndarray, y: np.ndarray, groups: np.ndarray | None) -> Any:
    """Fit a search; CV searches get the participant groups (when there are at least 2)."""
    from eskin.learn.selection import CrossValidationSearch

    if (
        isinstance(search, CrossValidationSearch)
        and groups is not None
        and len(np.unique(groups)) >= 2
    ):
        return search.fit(X, y, groups=groups)
    return search.fit(X, y)


def describe_params(
    machine: str, params: Mapping[str, Any], estimator: Any = None
) -> dict[str, Any]:
    """A selected setting in the paper's terms: lambda (and C for the SVM), sigma, alpha label,
    and the per-mode alphas the fitted estimator used."""
    alpha = params.get("alpha")
    lam = 1.0 / float(params["C"]) if "C" in params else float(params["lam"])
    out: dict[str, Any] = {
        "lambda": lam,
        "sigma": float(np.mean(np.atleast_1d(params["sigma"]))),
        "alpha": alpha_label(alpha),
        "alpha_value": alpha if isinstance(alpha, str) else np.atleast_1d(alpha).tolist(),
        "alphas": [int(a) for a in getattr(estimator, "alphas_", ())] or None,
        "amplitude": params.get("amplitude"),
    }
    if machine == "svm":
        out["C"] = 1.0 / lam
    return out


_TERMS = (
    "train_error",
    "chi",
    "tau",
    "bound",
    "mean_random_error",
    "cap_hits",
    "n_support",
    "gamma_0",
    "mean_test_error",
    "std_test_error",
    "mean_train_error",
)


def selected_row(search: Any) -> dict[str, float]:
    """The selection table's row of the chosen configuration (MD terms v = train_error, chi,
    tau, bound; or the CV error)."""
    res = getattr(search, "cv_results_", None)
    idx = getattr(search, "best_index_", None)
    if res is None or idx is None:
        return {}
    return {k: float(np.asarray(res[k], dtype=float)[idx]) for k in _TERMS if k in res}


def _plain(v: Any) -> Any:
    if isinstance(v, (tuple, list, np.ndarray)):
        return [_plain(x) for x in v]
    if isinstance(v, (np.integer, int)) and not isinstance(v, bool):
        return int(v)
    if isinstance(v, (np.floating, float)):
        return float(v)
    return v if isinstance(v, (str, bool)) or v is None else str(v)


def selection_table(search: Any) -> dict[str, list[Any]]:
    """The whole selection table (one entry per configuration) as JSON-friendly lists."""
    res = getattr(search, "cv_results_", None)
    if res is None:
        return {}
    out: dict[str, list[Any]] = {}
    for key, val in res.items():
        if key.startswith("param_"):
            out[key] = [_plain(v) for v in list(val)]
        elif key in _TERMS:
            out[key] = np.asarray(val, dtype=float).round(6).tolist()
    return out


# --------------------------------------------------------------------------------------------
# preprocessing of whole campaigns, once per (D, subsample method)


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


# --------------------------------------------------------------------------------------------
# the model


@dataclass
class TouchModel:
    """A trained, deployable touch-modality classifier.

    ``estimator`` is one fitted binary machine (``classes_`` = [0, 1], decision > 0 means
    ``classes[1]``) for two classes, or a fitted OneVsAllTouchClassifier (``classes_`` =
    0..k-1, one machine per class) for three or more. Labels map to names through ``classes``.
    """

    classes: list[str]
    estimator: Any
    machine: str
    selection: str
    D: int
    window: str
    subsample: str
    sample_rate_hz: float
    grid_shape: tuple[int, int]
    window_config: Any = None
    short: str = "interpolate"
    selected: list[dict[str, Any]] = field(default_factory=list)
    selection_report: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    #: the calibrated decision rule (:class:`eskin.learn.calibration.Calibration`); None: the
    #: paper's rule (a model trained with --decision paper, or before the calibrated rule)
    calibration: Any = None

    @property
    def n_classes(self) -> int:
        return len(self.classes)

    @property
    def is_binary(self) -> bool:
        return len(self.classes) == 2

    @property
    def pattern_shape(self) -> tuple[int, int, int]:
        return (int(self.grid_shape[0]), int(self.grid_shape[1]), int(self.D))

    def header(self) -> dict[str, Any]:
        """The summary written in front of the model in a model file."""
        import eskin

        return {
            "format": MODEL_FORMAT,
            "format_version": MODEL_FORMAT_VERSION,
            "eskin_version": eskin.__version__,
            "classes": list(self.classes),
            "machine": self.machine,
            "selection": self.selection,
            "D": int(self.D),
            "window": self.window,
            "subsample": self.subsample,
            "short": getattr(self, "short", "interpolate"),
            "sample_rate_hz": float(self.sample_rate_hz),
            "grid_shape": [int(v) for v in self.grid_shape],
            "window_config": (
                self.window_config.to_dict()
                if hasattr(self.window_config, "to_dict")
                else self.window_config
            ),
        }

    # -- preprocessing and decisions ------------------------------------------------------
    def preprocess(self, data: Any, indices: Sequence[int] | None = None) -> np.ndarray:
        """Patterns (n, rows, cols, D) from a campaign, an :class:`ArrayRecordings` or raw
        signals (n, rows, cols, T), preprocessed as in training."""
        rec = (
            data if hasattr(data, "recording") else ArrayRecordings(data, None, self.sample_rate_hz)
        )
        idx = np.arange(len(rec)) if indices is None else np.asarray(indices, np.int64)
        shape = tuple(np.shape(rec.recording(int(idx[0])))[:2]) if len(idx) else self.grid_shape
        if tuple(int(v) for v in shape) != tuple(int(v) for v in self.grid_shape):
            raise TrainingError(
                f"the recordings have a {shape[0]}x{shape[1]} taxel grid; the model was trained "
                f"on {self.grid_shape[0]}x{self.grid_shape[1]}"
            )
        prep = preprocess_campaign(
            rec,
            idx,
            [(self.D, self.subsample)],
            window=self.window,
            config=self.window_config,
            short=getattr(self, "short", "interpolate"),
        )
        return prep.X[(self.D, self.subsample)]

    def _check_patterns(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 4 or X.shape[1:] != self.pattern_shape:
            raise TrainingError(
                f"patterns must have shape (n, {', '.join(map(str, self.pattern_shape))}), "
                f"got {X.shape}"
            )
        return X

    def decision_function(self, X: np.ndarray) -> np.ndarray:
        """(n,) decision values for a binary model (> 0: classes[1]), (n, k) otherwise."""
        return np.asarray(self.estimator.decision_function(self._check_patterns(X)), float)

    def decide(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(class indices, decision values, don't-know flags, confidences) for preprocessed
        patterns: by the calibrated rule when the model has one (confidence: the label's
        normalised calibrated score), else by the paper's (confidence NaN)."""
        X = self._check_patterns(X)
        F = np.asarray(self.estimator.decision_function(X), float)
        cal = getattr(self, "calibration", None)
        if cal is not None:
            pred, conf, dk = cal.decide(F)
            return pred.astype(np.int64), F, dk, conf
        nan = np.full(len(F), np.nan)
        if self.is_binary:
            return (F > 0).astype(np.int64), F, np.zeros(len(F), bool), nan
        pred = np.asarray(self.estimator.predict(X)).astype(np.int64)
        dk = np.asarray(getattr(self.estimator, "dont_know_", np.zeros(len(pred), bool)), bool)
        return pred, F, dk, nan

    def predict_indices(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(class indices, decision values, don't-know flags) for preprocessed patterns."""
        return self.decide(X)[:3]

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Class names of preprocessed patterns."""
        return np.asarray(self.classes, dtype=object)[self.predict_indices(X)[0]]

    def predict_recordings(
        self, data: Any, indices: Sequence[int] | None = None
    ) -> list[dict[str, Any]]:
        """Per-recording predictions of a campaign (or raw signals), ready for JSON.

        Each item: ``index`` (recording position in ``data``), ``label``, ``decision_values``
        (a list: one value for a binary model, > 0 meaning classes[1]; one per class
        otherwise), ``dont_know`` (the calibrated rule: confidence below the model's threshold;
        the paper's: no machine or several claimed the pattern), ``confidence`` (the calibrated
        rule's confidence in the label, None under the paper's rule), and ``true_label`` when
        ``data`` is a campaign whose modality names are known.
        """
        rec = (
            data if hasattr(data, "recording") else ArrayRecordings(data, None, self.sample_rate_hz)
        )
        idx = np.arange(len(rec)) if indices is None else np.asarray(indices, np.int64)
        X = self.preprocess(rec, idx)
        pred, F, dk, conf = self.decide(X)
        names = list(getattr(rec, "modalities", []) or [])
        mod = np.asarray(getattr(rec, "modality", np.full(len(rec), -1)))
        out = []
        for j, i in enumerate(idx):
            item: dict[str, Any] = {
                "index": int(i),
                "label": self.classes[int(pred[j])],
                "decision_values": [float(v) for v in np.atleast_1d(F[j])],
                "dont_know": bool(dk[j]),
                "confidence": float(conf[j]) if np.isfinite(conf[j]) else None,
            }
            m = int(mod[i]) if i < len(mod) else -1
            if names and 0 <= m < len(names):
                item["true_label"] = str(names[m])
            out.append(item)
        return out


def error_rate(
    predictions: Sequence[Mapping[str, Any]], classes: Sequence[str]
) -> tuple[float, int]:
    """(error rate, count) over the predictions whose true label is one of ``classes``."""
    known = [p for p in predictions if p.get("true_label") in set(classes)]
    if not known:
        return float("nan"), 0
    return float(np.mean([p["label"] != p["true_label"] for p in known])), len(known)


# --------------------------------------------------------------------------------------------
# training


#: classes with fewer recordings than this get a warning note
MIN_CLASS_RECORDINGS = 5
#: labels of every campaign that can group recordings (integer extra fields can too)
GROUP_FIELDS: tuple[str, ...] = ("participant", "run", "direction")


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


def _load_data(
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
    except ValueError as exc:
        if groups is None or "left one class only" not in str(exc):
            raise
    notes.append(
        f"grouped cross-validation left a class out of a training part (too few {group_by} "
        "groups per class): the splits are stratified by class instead, not by group"
    )
    return fit(None), False


def _require_touches(X: np.ndarray, data: Any) -> None:
    """Refuse training data in which no recording holds any signal (no touch anywhere)."""
    flat = X.reshape(len(X), -1)
    if len(flat) and np.all(flat.max(axis=1) == flat.min(axis=1)):
        where = f"{data}: " if isinstance(data, (str, os.PathLike)) else ""
        raise TrainingError(
            f"{where}no touch anywhere: each of the {len(flat)} training recordings is flat "
            f"(its preprocessed tensor is constant), so there is nothing to learn"
        )


@dataclass(frozen=True)
class _Recipe:
    """How :func:`train_model` trains (its arguments of the same names, checked on creation)."""

    machine: str
    selection: str
    D: int
    window: str
    subsample: str
    negatives: str
    seed: int
    n_jobs: int
    group_by: str
    lambdas: Sequence[float] = PAPER_LAMBDAS
    sigmas: Sequence[float] = PAPER_SIGMAS
    alphas: Sequence[str] = PAPER_ALPHAS
    amplitudes: Sequence[float | None] = DEFAULT_AMPLITUDES
    md_options: Mapping[str, Any] | None = None
    cv_options: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.machine not in MACHINES:
            raise TrainingError(f"machine must be 'svm' or 'rls', got {self.machine!r}")
        if self.selection not in SELECTIONS:
            raise TrainingError(f"selection must be 'md' or 'cv', got {self.selection!r}")
        if self.negatives not in ("balanced", "all"):
            raise TrainingError(f"negatives must be 'balanced' or 'all', got {self.negatives!r}")
        if self.D is not None and not MIN_D <= int(self.D) <= MAX_D:
            raise TrainingError(f"D must be in [{MIN_D}, {MAX_D}] (what a .eskin model holds), "
                                f"got {self.D}")

    def with_grid(
        self,
        quick: bool,
        lambdas: Sequence[float],
        sigmas: Sequence[float],
        alphas: Sequence[str],
        amplitudes: Sequence[float | None],
        md_options: Mapping[str, Any] | None,
        cv_options: Mapping[str, Any] | None,
    ) -> _Recipe:
        """This recipe searching the given grid, or with ``quick`` the 2x2x2 grid (times the
        given amplitudes) and lighter selection options (3 labelings, 3 splits; given options
        win)."""
        if quick:
            lambdas, sigmas, alphas = QUICK_LAMBDAS, QUICK_SIGMAS, QUICK_ALPHAS
            md_options = {"n_labelings": 3, **dict(md_options or {})}
            cv_options = {"n_splits": 3, **dict(cv_options or {})}
        return replace(
            self,
            lambdas=lambdas,
            sigmas=sigmas,
            alphas=alphas,
            amplitudes=tuple(amplitudes),
            md_options=md_options,
            cv_options=cv_options,
        )


def _training_data(
    data: Any,
    labels: Any,
    classes: Sequence[str] | None,
    class_names: Sequence[str] | None,
    lengths: Any,
    sample_rate_hz: float,
    runs: Sequence[int] | None,
    group_by: str,
) -> tuple[Any, dict[str, Any], list[str], np.ndarray, np.ndarray, np.ndarray | None]:
    """(recordings, source info, classes learnt, indices of the recordings trained on, their
    labels 0..len(classes)-1, their ``group_by`` groups or None). The classes default to every
    class present and must be known, distinct, at least 2 and each recorded among the training
    recordings (only those of ``runs``, when given)."""
    rec, ids, names, parts, info = _load_data(data, labels, class_names, lengths, sample_rate_hz)
    if group_by != "participant" and hasattr(rec, "modalities"):
        parts = group_labels(rec, group_by)
    present = [names[k] for k in sorted(set(ids.tolist())) if 0 <= k < len(names)]
    if classes is None:
        classes = present
    classes = [str(c) for c in classes]
    unknown = [c for c in classes if c not in names]
    if unknown:
        raise TrainingError(f"unknown class(es) {unknown}; the data has classes {names}")
    if len(set(classes)) != len(classes):
        raise TrainingError(f"classes must be distinct, got {classes}")
    if len(classes) < 2:
        raise TrainingError(f"at least 2 classes are needed, got {classes}")
    cls_ids = [names.index(c) for c in classes]
    mask = np.isin(ids, cls_ids)
    if runs is not None and hasattr(rec, "run"):
        mask &= np.isin(np.asarray(rec.run), list(runs))
    idx = np.flatnonzero(mask)
    missing = [c for c, k in zip(classes, cls_ids) if not np.any(ids[idx] == k)]
    if missing:
        raise TrainingError(f"no recording of class(es) {missing} in the training data")
    y_all = np.array([cls_ids.index(k) for k in ids[idx]], np.int64)
    groups = parts[idx] if parts is not None else None
    return rec, info, classes, idx, y_all, groups


def _default_D(recipe: _Recipe, rec: Any, idx: np.ndarray, notes: list[str]) -> _Recipe:
    """The recipe with D resolved: as given, else :data:`DEFAULT_D`, or the longest training
    recording (at least 2 samples) when that is shorter, with a note."""
    if recipe.D is not None:
        return recipe
    lengths = np.asarray(rec.lengths)[idx]
    longest = int(lengths.max()) if len(lengths) else DEFAULT_D
    if longest >= DEFAULT_D:
        return replace(recipe, D=DEFAULT_D)
    D = max(2, longest)
    notes.append(
        f"the training recordings are at most {longest} samples long: D = {D} instead of "
        f"{DEFAULT_D} (a longer D would only stretch every touch by interpolation)"
    )
    return replace(recipe, D=D)


def _training_patterns(
    data: Any, rec: Any, idx: np.ndarray, recipe: _Recipe, window_config: Any, rate: float
) -> tuple[np.ndarray, float]:
    """(the preprocessed patterns of the training recordings, seconds taken); refuses patterns
    without any touch."""
    key = (int(recipe.D), recipe.subsample)
    prep = preprocess_campaign(
        rec, idx, [key], window=recipe.window, config=window_config, sample_rate_hz=rate
    )
    X = prep.X[key]
    _require_touches(X, data)
    return X, prep.seconds


def _selected_settings(machine: str, fitted_search: Any, ys: np.ndarray) -> dict[str, Any]:
    """What one fitted search chose, its selection terms and the size of its training set."""
    return {
        **describe_params(machine, fitted_search.best_params_, fitted_search.best_estimator_),
        "selection_terms": selected_row(fitted_search),
        "n_train": int(len(ys)),
        "n_positive": int(np.sum(ys == 1)),
    }


def _select_and_fit(
    recipe: _Recipe,
    X: np.ndarray,
    y_all: np.ndarray,
    classes: list[str],
    groups: np.ndarray | None,
    notes: list[str],
) -> tuple[Any, bool, list[dict[str, Any]], float]:
    """(fitted estimator, whether its splits were grouped, the settings each machine chose,
    seconds taken): one binary machine for 2 classes, else one 1-vs-all machine per class.
    Notes on the splits are added to ``notes``."""
    search = make_search(
        recipe.machine,
        recipe.selection,
        param_grid(recipe.lambdas, recipe.sigmas, recipe.alphas, recipe.amplitudes),
        seed=recipe.seed,
        md_options=recipe.md_options,
        cv_options=recipe.cv_options,
        n_jobs=recipe.n_jobs,
    )
    t0 = time.perf_counter()
    groups, group_notes = cv_groups(recipe.selection, groups, recipe.group_by)
    notes += group_notes
    if len(classes) == 2:
        _, grouped = fit_grouped(
            lambda g: fit_search(search, X, y_all, g), groups, recipe.group_by, notes
        )
        selected = [_selected_settings(recipe.machine, search, y_all)]
        return search.best_estimator_, grouped, selected, time.perf_counter() - t0
    from eskin.learn.estimators import OneVsAllTouchClassifier

    machine_indices = one_vs_all_indices(y_all, len(classes), recipe.negatives, recipe.seed)
    estimator, grouped = fit_grouped(
        lambda g: OneVsAllTouchClassifier(estimator=search).fit(
            X, y_all, machine_indices=machine_indices, groups=g
        ),
        groups,
        recipe.group_by,
        notes,
    )
    selected = [
        {
            "class": classes[k],
            **_selected_settings(recipe.machine, srch, (y_all[mi] == k).astype(int)),
        }
        for k, (srch, mi) in enumerate(zip(estimator.searches_, machine_indices))
    ]
    return estimator, grouped, selected, time.perf_counter() - t0


def _training_record(
    recipe: _Recipe,
    info: dict[str, Any],
    classes: list[str],
    y_all: np.ndarray,
    grouped: bool,
    notes: list[str],
    seconds: float,
) -> dict[str, Any]:
    """The model's ``training`` record: data source, pattern counts, grid, selection options,
    how the CV splits went, notes, time taken, creation time and eskin version."""
    import eskin

    split_by = (recipe.group_by if grouped else "recordings") if recipe.selection == "cv" else None
    return {
        **info,
        "n_patterns": int(len(y_all)),
        "patterns_per_class": {c: int(np.sum(y_all == k)) for k, c in enumerate(classes)},
        "grid": {
            "lambdas": list(map(float, recipe.lambdas)),
            "sigmas": list(map(float, recipe.sigmas)),
            "alphas": list(recipe.alphas),
            "amplitudes": list(recipe.amplitudes),
        },
        "md_options": dict(recipe.md_options or {}),
        "cv_options": dict(recipe.cv_options or {}),
        "cv_split_by": split_by,
        "negatives": recipe.negatives,
        "seed": recipe.seed,
        "notes": notes,
        "seconds": seconds,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "eskin_version": eskin.__version__,
    }


def _touch_model(
    recipe: _Recipe,
    classes: list[str],
    estimator: Any,
    selected: list[dict[str, Any]],
    training: dict[str, Any],
    rate: float,
    shape: tuple[int, ...],
    window_config: Any,
) -> TouchModel:
    """The trained :class:`TouchModel`."""
    return TouchModel(
        classes=classes,
        estimator=estimator,
        machine=recipe.machine,
        selection=recipe.selection,
        D=int(recipe.D),
        window=recipe.window,
        subsample=recipe.subsample,
        sample_rate_hz=rate,
        grid_shape=(int(shape[0]), int(shape[1])),
        window_config=window_config,
        selected=selected,
        selection_report={"lambda_shown": "lambda for both machines; the SVM uses C = 1/lambda"},
        training=training,
    )


# long: the public entry point documents every parameter; the body dispatches
def train_model(
    data: Any,
    labels: Any = None,
    *,
    classes: Sequence[str] | None = None,
    machine: str | None = None,
    selection: str = "cv",
    D: int | None = None,
    window: str = "energy",
    subsample: str | None = None,
    window_config: Any = None,
    lambdas: Sequence[float] = PAPER_LAMBDAS,
    sigmas: Sequence[float] = PAPER_SIGMAS,
    alphas: Sequence[str] = PAPER_ALPHAS,
    amplitudes: Sequence[float | None] = DEFAULT_AMPLITUDES,
    quick: bool = False,
    md_options: Mapping[str, Any] | None = None,
    cv_options: Mapping[str, Any] | None = None,
    negatives: str | None = None,
    runs: Sequence[int] | None = None,
    class_names: Sequence[str] | None = None,
    lengths: Sequence[int] | None = None,
    sample_rate_hz: float = 3000.0,
    seed: int = 0,
    n_jobs: int = 1,
    group_by: str = "participant",
    budget: Any = None,
    recipe_options: Mapping[str, Any] | None = None,
    max_support: int | None = None,
    choose_hold: bool = True,
    decision: str = "calibrated",
    reject: float = DEFAULT_REJECT,
) -> TouchModel:
    """Select the recipe and its hyperparameters, fit on all the data: a :class:`TouchModel`.

    Parameters
    ----------
    data : a campaign path, a loaded Campaign, or raw signals (n, rows, cols, T) with ``labels``
        (class names, or integers indexing ``class_names``), ``lengths`` and ``sample_rate_hz``.
    classes : the classes to learn (default: every class). Two give one binary machine (> 0:
        ``classes[1]``); more give one 1-vs-all machine each (the paper's rule, Section 5.3).
    machine : "svm" (tensor-SVM, C = 1/lambda) or "rls" (tensor-RLS).
    selection : "cv" (default: 10 random splits holding out 30 % of the ``group_by`` groups;
        stratified splits of the recordings, with a note, when grouped ones are impossible;
        ``cv_options``: :class:`~eskin.CrossValidationSearch`) or "md" (Maximal Discrepancy,
        Algorithm 1; ``md_options``: :class:`~eskin.MaximalDiscrepancySearch`).
    D, window, subsample, window_config : preprocessing (see :func:`eskin.preprocess`); D
        None (default) is 100, or the longest training recording when that is shorter.
    lambdas, sigmas, alphas : the grid (default the paper's, 135 configurations); ``quick``
        replaces it by a 2x2x2 grid (for tests and demos).
    amplitudes : the amplitude-aware kernel's widths searched (None: the paper's kernel; a
        number: the factor's width in spreads of the training patterns' log energy, see
        :class:`~eskin.TensorSVC`), each multiplying the grid.
    negatives : what each 1-vs-all machine sees of the other classes: "all" their patterns
        (benchmarks/multiclass_study.py) or "balanced" (the paper: as many, seeded random).
    runs : only recordings of these runs (default: all).
    group_by : the label whose groups the CV splits keep apart: "participant" (default), "run",
        "direction" or an integer extra field.
    budget : a :class:`~eskin.learn.recipes.CandidateBudget`
        (:func:`eskin.deploy.target.candidate_budget`): only what fits it is chosen.
    recipe_options : options of the :class:`~eskin.learn.recipes.RecipeSearch` (``eta``, ...).
    max_support : at most this many distinct support vectors in the model (all machines
        together; :func:`eskin.learn.support_budget.bound_support`). None: all of them.
    choose_hold : with the energy window, choose ``window_config.hold_s`` so that one training
        recording gives one live touch (:func:`eskin.learn.live_windows.choose_hold`); False
        keeps the given hold and only notes when live touches split.
    decision : "calibrated" (default: :mod:`eskin.learn.calibration`, a sigmoid per machine
        fitted on out-of-fold decision values, the label of the largest calibrated score,
        "don't know" below a confidence threshold) or "paper" (Section 5.3).
    reject : the calibrated rule's fraction of (out-of-fold) training touches flagged "don't
        know", in [0, 1); 0 never flags.

    Recipe search: with ``selection="cv"``, each of ``machine``, ``D``, ``subsample`` and
    ``negatives`` left None is searched by :class:`~eskin.learn.recipes.RecipeSearch`.
    With all four given, or ``selection="md"`` (the unset ones then svm, D 100 or the longest
    recording, algorithm2, all), each machine selects its own setting of the grid.
    """
    recipe_given = dict(machine=machine, D=D, subsample=subsample, negatives=negatives)
    common = dict(classes=classes, window=window, window_config=window_config, lambdas=lambdas,
                  sigmas=sigmas, alphas=alphas, amplitudes=amplitudes, quick=quick,
                  cv_options=cv_options, runs=runs, class_names=class_names, lengths=lengths,
                  sample_rate_hz=sample_rate_hz, seed=seed, n_jobs=n_jobs, group_by=group_by,
                  max_support=_checked_max_support(max_support), choose_hold=choose_hold,
                  rule=_checked_rule(decision, reject))
    if selection == "cv" and None in recipe_given.values():
        return _train_searched(data, labels, **recipe_given, **common, budget=budget,
                               recipe_options=recipe_options)
    if budget is not None:
        raise TrainingError("a budget needs the recipe searched (selection cv, and at least one "
                            "of machine, D, subsample, negatives left to the search)")
    return _train_fixed(data, labels, selection=selection, md_options=md_options,
                        **recipe_given, **common)


def _checked_rule(decision: Any, reject: Any) -> tuple[str, float]:
    """(decision rule, reject fraction), checked before any training."""
    from eskin.learn.calibration import DECISION_RULES

    if decision not in DECISION_RULES:
        raise TrainingError(f"decision must be one of {DECISION_RULES}, got {decision!r}")
    try:
        r = float(reject)
    except (TypeError, ValueError):
        raise TrainingError(f"reject must be a number in [0, 1), got {reject!r}") from None
    if not 0 <= r < 1:
        raise TrainingError(f"reject must be in [0, 1), got {reject!r}")
    return str(decision), r


def _with_calibration(model: TouchModel, estimator: Any, X: np.ndarray, y_all: np.ndarray,
                      groups: np.ndarray | None, negatives: str, seed: int, n_jobs: int,
                      rule: tuple[str, float]) -> TouchModel:
    """``model`` with the calibrated rule fitted on out-of-fold values of ``estimator`` (the
    fitted machines, before any support budget), or as it is for the paper's rule."""
    from eskin.learn import calibration as cal

    decision, reject = rule
    if decision == "paper":
        model.training["decision"] = {"rule": "paper"}
        return model
    t0 = time.perf_counter()
    binary = len(model.classes) == 2
    indices = None if binary else one_vs_all_indices(y_all, len(model.classes), negatives, seed)
    notes = model.training.setdefault("notes", [])
    try:
        F, n_folds = cal.out_of_fold_values(estimator, X, y_all, groups, machine_indices=indices,
                                            seed=seed, n_jobs=n_jobs, notes=notes)
        model.calibration = cal.fit_calibration(F, y_all, reject, binary=binary, n_folds=n_folds)
    except TrainingError as exc:
        notes.append(f"the calibrated rule cannot be fitted ({exc}): the model keeps the "
                     "paper's rule")
        model.training["decision"] = {"rule": "paper", "calibration_failed": str(exc)}
        return model
    model.training["decision"] = {**model.calibration.report,
                                  "seconds": time.perf_counter() - t0}
    return model


def _checked_max_support(max_support: Any) -> int | None:
    """None, or ``max_support`` checked (before any training: a TrainingError naming it)."""
    from eskin.learn.support_budget import check_max_support

    if max_support is None:
        return None
    try:
        return check_max_support(max_support)
    except (TypeError, ValueError) as exc:
        raise TrainingError(str(exc)) from None


def _with_support_budget(model: TouchModel, max_support: int | None,
                         X: np.ndarray) -> TouchModel:
    """``model`` with at most ``max_support`` distinct support vectors (None: as it is), the
    machines' coefficients fitted to their decision values on the training patterns ``X``,
    and a record of it."""
    from eskin.learn.support_budget import bound_support, n_distinct_support

    if max_support is None:
        return model
    before = n_distinct_support(model.estimator)
    model.estimator = bound_support(model.estimator, max_support, X_fit=X)
    model.training["support_budget"] = {
        "max_support": max_support,
        "support_vectors_before": before,
        "support_vectors": n_distinct_support(model.estimator),
    }
    return model


def _train_fixed(
    data: Any, labels: Any, *, classes: Sequence[str] | None, machine: str | None,
    selection: str, D: int | None, window: str, subsample: str | None, window_config: Any,
    lambdas: Sequence[float], sigmas: Sequence[float], alphas: Sequence[str],
    amplitudes: Sequence[float | None], quick: bool, md_options: Mapping[str, Any] | None,
    cv_options: Mapping[str, Any] | None, negatives: str | None, runs: Sequence[int] | None,
    class_names: Sequence[str] | None, lengths: Any, sample_rate_hz: float, seed: int,
    n_jobs: int, group_by: str, max_support: int | None, choose_hold: bool,
    rule: tuple[str, float],
) -> TouchModel:
    """train_model with the recipe given (or Maximal Discrepancy): each machine selects its
    own setting of the grid."""
    machine = machine or "svm"
    subsample = subsample or "algorithm2"
    negatives = negatives or "all"
    recipe = _Recipe(machine, selection, D, window, subsample, negatives, seed, n_jobs, group_by)
    recipe = recipe.with_grid(quick, lambdas, sigmas, alphas, amplitudes, md_options, cv_options)
    rec, info, classes, idx, y_all, groups = _training_data(
        data, labels, classes, class_names, lengths, sample_rate_hz, runs, group_by
    )
    rate = float(getattr(rec, "sample_rate_hz", sample_rate_hz))
    # the detector settings valid at this rate, written into the model explicitly (also with
    # window="none": the compiled classifier builds its detector from them)
    window_config, notes = window_config_for_rate(window_config, rate)
    notes = (notes if window == "energy" else []) + small_class_notes(classes, y_all)
    window_config, live = _live_hold(rec, idx, window_config, rate, window, choose_hold, notes)
    recipe = _default_D(recipe, rec, idx, notes)
    X, prep_seconds = _training_patterns(data, rec, idx, recipe, window_config, rate)
    estimator, grouped, selected, fit_seconds = _select_and_fit(
        recipe, X, y_all, classes, groups, notes
    )
    training = _training_record(
        recipe, info, classes, y_all, grouped, notes, fit_seconds + prep_seconds
    )
    training["live_touches"] = live
    model = _touch_model(recipe, classes, estimator, selected, training, rate, X.shape[1:],
                         window_config)
    model = _with_calibration(model, estimator, X, y_all, groups, recipe.negatives, recipe.seed,
                              n_jobs, rule)
    return _with_support_budget(model, max_support, X)


def _train_searched(
    data: Any, labels: Any, *, classes: Sequence[str] | None, machine: str | None,
    D: int | None, window: str, subsample: str | None, window_config: Any,
    lambdas: Sequence[float], sigmas: Sequence[float], alphas: Sequence[str],
    amplitudes: Sequence[float | None], quick: bool, cv_options: Mapping[str, Any] | None,
    negatives: str | None, runs: Sequence[int] | None, class_names: Sequence[str] | None,
    lengths: Any, sample_rate_hz: float, seed: int, n_jobs: int, group_by: str, budget: Any,
    recipe_options: Mapping[str, Any] | None, max_support: int | None, choose_hold: bool,
    rule: tuple[str, float],
) -> TouchModel:
    """train_model with the recipe searched (see its docstring)."""
    from eskin.learn.recipes import (
        MACHINES as R_MACHINES, NEGATIVES, SEARCH_DS, SUBSAMPLES, RecipeSearch, recipe_space,
    )

    base = _Recipe(machine or "svm", "cv", D, window, subsample or "algorithm2",
                   negatives or "all", seed, n_jobs, group_by)
    base = base.with_grid(quick, lambdas, sigmas, alphas, amplitudes, None, cv_options)
    rec, info, classes, idx, y_all, groups = _training_data(
        data, labels, classes, class_names, lengths, sample_rate_hz, runs, group_by
    )
    rate = float(getattr(rec, "sample_rate_hz", sample_rate_hz))
    window_config, notes = window_config_for_rate(window_config, rate)
    notes = (notes if window == "energy" else []) + small_class_notes(classes, y_all)
    window_config, live = _live_hold(rec, idx, window_config, rate, window, choose_hold, notes)
    lens = np.asarray(rec.lengths)[idx]
    recipes, cap_notes = recipe_space(
        [machine] if machine else R_MACHINES, [D] if D else SEARCH_DS,
        [subsample] if subsample else SUBSAMPLES, [negatives] if negatives else NEGATIVES,
        longest=int(lens.max()) if len(lens) else None,
    )
    notes += sorted(set(cap_notes))
    t0 = time.perf_counter()
    prep = preprocess_campaign(rec, idx, sorted({r.variant for r in recipes}), window=window,
                               config=window_config, sample_rate_hz=rate)
    for X in prep.X.values():
        _require_touches(X, data)
    cv = dict(base.cv_options or {})
    options = {"n_splits": int(cv.get("n_splits", 10)), "test_size": float(cv.get("test_size", 0.3)),
               **dict(recipe_options or {})}
    groups, group_notes = cv_groups("cv", groups, group_by)
    notes += group_notes

    def run(g: np.ndarray | None) -> RecipeSearch:
        return RecipeSearch(recipes, base.lambdas, base.sigmas, base.alphas, base.amplitudes,
                            budget=budget, seed=seed, n_jobs=n_jobs, **options).fit(
            prep.X, y_all, g)

    search, grouped = fit_grouped(run, groups, group_by, notes)
    if search.collapse_note():
        notes.append(f"recipe search: {search.collapse_note()}")
    best = search.best_
    chosen = replace(base, machine=best.recipe.machine, D=best.recipe.D,
                     subsample=best.recipe.subsample, negatives=best.recipe.negatives)
    X = prep.X[best.recipe.variant]
    estimator, selected = _fit_candidate(best, X, y_all, classes, seed)
    for s in selected:
        s["selection_terms"] = {"mean_test_error": float(search.best_error_),
                                "std_test_error": float(search.ranking_[0]["std"])}
    training = _training_record(chosen, info, classes, y_all, grouped, notes,
                                time.perf_counter() - t0)
    training["live_touches"] = live
    training["recipe_search"] = search.report()
    training["searched"] = [k for k, v in (("machine", machine), ("D", D),
                                           ("subsample", subsample), ("negatives", negatives))
                            if v is None]
    by_budget = search.best_bound_ is not None and (max_support is None
                                                     or search.best_bound_ < max_support)
    model = _with_calibration(
        _touch_model(chosen, classes, estimator, selected, training, rate, X.shape[1:],
                     window_config), estimator, X, y_all, groups if grouped else None,
        chosen.negatives, seed, n_jobs, rule)
    model = _with_support_budget(model, search.best_bound_ if by_budget else max_support, X)
    if by_budget:  # bounded by the search, to the most support vectors that fit the budget
        model.training["support_budget"]["by"] = "budget"
    return model


def _live_hold(rec: Any, idx: np.ndarray, window_config: Any, rate: float, window: str,
               choose: bool, notes: list[str]) -> tuple[Any, dict[str, Any] | None]:
    """(window_config with the hold time chosen for one live touch per training recording,
    the record of the choice); notes added to ``notes``. Nothing to choose with window none."""
    if window != "energy":
        return window_config, None
    from eskin.learn.live_windows import choose_hold

    choice = choose_hold(rec, idx, window_config, rate, choose=choose)
    notes += choice.notes
    return choice.config, choice.record


def _fit_candidate(
    best: Any, X: np.ndarray, y_all: np.ndarray, classes: list[str], seed: int
) -> tuple[Any, list[dict[str, Any]]]:
    """(the fitted estimator of a recipe-search candidate, the settings of its machines)."""
    from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS, TensorSVC

    alpha = ALPHA_SPEC[best.alpha]
    if best.recipe.machine == "svm":
        est = TensorSVC(C=1.0 / best.lam, sigma=best.sigma, alpha=alpha, amplitude=best.amplitude)
        params = {"C": 1.0 / best.lam, "sigma": best.sigma, "alpha": alpha,
                  "amplitude": best.amplitude}
    else:
        est = TensorRLS(lam=best.lam, sigma=best.sigma, alpha=alpha, amplitude=best.amplitude)
        params = {"lam": best.lam, "sigma": best.sigma, "alpha": alpha,
                  "amplitude": best.amplitude}
    if len(classes) == 2:
        est.fit(X, y_all)
        return est, [{**describe_params(best.recipe.machine, params, est),
                      "n_train": int(len(y_all)), "n_positive": int(np.sum(y_all == 1))}]
    indices = one_vs_all_indices(y_all, len(classes), best.recipe.negatives, seed)
    ova = OneVsAllTouchClassifier(estimator=est).fit(X, y_all, machine_indices=indices)
    selected = []
    for k, (m, mi) in enumerate(zip(ova.estimators_, indices)):
        selected.append({"class": classes[k],
                         **describe_params(best.recipe.machine, params, m),
                         "n_train": int(len(mi)), "n_positive": int(np.sum(y_all[mi] == k))})
    return ova, selected


# --------------------------------------------------------------------------------------------
# files

Saver = Callable[[TouchModel, Path], None]
Loader = Callable[[Path], TouchModel]
_FORMATS: dict[str, tuple[Saver, Loader]] = {}


def register_model_format(suffix: str, saver: Saver, loader: Loader) -> None:
    """Route :func:`save_model`/:func:`load_model` for files ending in ``suffix`` (e.g.
    ".eskin") to ``saver``/``loader``. Every other suffix uses the joblib container."""
    _FORMATS[suffix.lower()] = (saver, loader)


def _format_for(path: Path) -> tuple[Saver, Loader] | None:
    # eskin.deploy registers ".eskin" when it is imported (this layer does not import it)
    return _FORMATS.get(path.suffix.lower())


def save_model(model: TouchModel, path: str | Path) -> Path:
    """Write ``model`` to ``path`` (a joblib container: header dict + model; other formats by
    suffix, see :func:`register_model_format`). Returns the path."""
    import joblib

    if not isinstance(model, TouchModel):
        raise TypeError(f"save_model expects a TouchModel, got {type(model).__name__}")
    path = Path(path)
    fmt = _format_for(path)
    if fmt is not None:
        fmt[0](model, path)
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    from eskin._files import whole_file

    with whole_file(path) as tmp:  # a full disk leaves no partial model, and the old one
        joblib.dump({"header": model.header(), "model": model}, tmp, compress=3)
    return path


def load_model(path: str | Path) -> TouchModel:
    """Read a model written by :func:`save_model`, checking its header.

    Raises FileNotFoundError for a missing file and :class:`ModelFormatError` (a ValueError)
    for a file that is not an eskin model, has another format version, or is damaged.
    Loading unpickles: only load model files you trust.
    """
    import joblib

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {path} does not exist")
    fmt = _format_for(path)
    if fmt is not None:
        return fmt[1](path)
    kind = _other_kind(path)
    if kind is not None:
        raise ModelFormatError(f"{path} is not an eskin model file: it is {kind}")
    try:
        with _renamed_modules():
            obj = joblib.load(path)
    except Exception as exc:
        raise ModelFormatError(
            f"{path} is not an eskin model file (cannot be read: {type(exc).__name__}: {exc})"
        ) from None
    if not isinstance(obj, dict) or not isinstance(obj.get("header"), dict):
        raise ModelFormatError(f"{path} is not an eskin model file (no header)")
    header = obj["header"]
    if header.get("format") != MODEL_FORMAT:
        raise ModelFormatError(
            f"{path} is not an eskin model file (format {header.get('format')!r}, expected "
            f"{MODEL_FORMAT!r})"
        )
    version = header.get("format_version")
    if version != MODEL_FORMAT_VERSION:
        raise ModelFormatError(
            f"{path}: model format version {version!r} is not supported (this eskin reads "
            f"version {MODEL_FORMAT_VERSION}); retrain the model or use the matching eskin"
        )
    model = obj.get("model")
    if not isinstance(model, TouchModel):
        raise ModelFormatError(f"{path}: the file holds no TouchModel")
    if list(model.classes) != list(header.get("classes", [])) or int(model.D) != header.get("D"):
        raise ModelFormatError(f"{path}: the header does not match the model it holds")
    return model


#: the first bytes of the other files eskin reads and writes, and what to call them
_SIGNATURES = (
    (b"\x89HDF\r\n\x1a\n", "an HDF5 file, not a model"),
    (b"\x89ESKIN\r\n", "an exported model (eskin export); name it .eskin to load it"),
    (b"ESKREPLY", "a replay file (eskin replay), not a model"),
    (b"ESKJRNL1", "a campaign writer's journal (eskin recover turns it into a campaign)"),
    (b"\x93NUMPY", "a numpy .npy array, not a model"),
)


def _other_kind(path: Path) -> str | None:
    """What a file that is not a joblib model is, from its first bytes (None: maybe a model)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return None
    for magic, kind in _SIGNATURES:
        if head.startswith(magic):
            return _campaign_or(path, kind) if magic.startswith(b"\x89HDF") else kind
    return None


def _campaign_or(path: Path, kind: str) -> str:
    """'an eskin campaign (...)' when the HDF5 file ``path`` says it is one, else ``kind``."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format")
    except (OSError, RuntimeError, ValueError):
        return kind
    if isinstance(fmt, bytes):
        fmt = fmt.decode("utf-8", "replace")
    if fmt == "eskin-campaign":
        return ("an eskin campaign (a model is trained from one: `eskin train CAMPAIGN -o "
                "MODEL.joblib`)")
    return kind


#: modules whose classes model files written before the package's layers pickled by these paths
_RENAMED_MODULES = {
    "eskin.models": "eskin.learn.models",
    "eskin.estimators": "eskin.learn.estimators",
    "eskin.selection": "eskin.learn.selection",
    "eskin.kernel": "eskin.learn.kernel",
    "eskin.preprocess": "eskin.signal.preprocess",
}


@contextlib.contextmanager
def _renamed_modules() -> Iterator[None]:
    """While unpickling, the old module paths name the modules that now hold the classes."""
    added = [old for old in _RENAMED_MODULES if old not in sys.modules]
    for old in added:
        sys.modules[old] = importlib.import_module(_RENAMED_MODULES[old])
    try:
        yield
    finally:
        for old in added:
            sys.modules.pop(old, None)
