"""The calibrated decision rule: what a model says when it does not know.

The paper's rule (Section 5.3: the class whose machine alone claims the pattern, else the
largest f, flagged "don't know") flags touches by the sign of raw decision values, which have no
common scale across machines: a model whose machines all sit near their intercepts flags every
touch and decides by differences of hundredths. The calibrated rule instead gives every machine a
probability and flags the least confident touches, as many as the user asked for:

1. **Out-of-fold decision values.** The final recipe (each machine's own settings) is trained
   again on ``n_folds`` grouped folds (no participant on both sides; stratified folds when the
   groups cannot hold every class apart): every training pattern gets the decision values of
   machines that did not see it.
2. **One sigmoid per machine** (Platt scaling, scikit-learn's ``_sigmoid_calibration`` with
   Platt's target smoothing) fitted on those values against "the pattern is this machine's
   class": p_k = 1 / (1 + exp(-(a_k f_k + b_k))), with a_k >= 0 (a machine whose held-out values
   point the wrong way gets a_k = 0: a constant, its class's share). A binary model has one
   machine: p for its positive class, 1 - p for the other.
3. **Normalised scores** q_k = p_k / sum_j p_j; the label is the largest q (the first on ties),
   the **confidence** that q. Computed in the log domain (``log_sigmoid``), so it is finite for
   every finite f: the very formula of the C++ classifier (``cpp/src/model.cpp``).
4. **The threshold** t on the confidence is chosen on the out-of-fold confidences so that the
   requested fraction ``reject`` of the training touches falls below it; a touch is flagged
   "don't know" when its confidence < t (``reject`` 0: t = 0, nothing is flagged). The
   fraction holds for touches like the training ones seen by machines that did not train on them;
   the final model, trained on all of them, is usually more confident, so on new people the
   fraction flagged is near ``reject``, not equal to it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from eskin.errors import TrainingError

__all__ = [
    "Calibration",
    "DECISION_RULES",
    "DEFAULT_REJECT",
    "calibrated_decision",
    "choose_threshold",
    "fit_calibration",
    "fit_sigmoid",
    "log_sigmoid",
    "out_of_fold_values",
]

#: "calibrated" (the default for new models) or "paper" (Section 5.3)
DECISION_RULES = ("calibrated", "paper")
#: fraction of the training touches (out of fold) flagged "don't know" by default
DEFAULT_REJECT = 0.1
#: folds of the out-of-fold decision values
DEFAULT_FOLDS = 5
#: the model format's bound on a slope and an offset (docs/model-format.md, CALB)
MAX_CALIBRATION = 1e6


@dataclass(frozen=True)
class Calibration:
    """A fitted calibrated rule: per machine the slope a_k and offset b_k of its sigmoid, the
    confidence threshold, the fraction ``reject`` it was chosen for (NaN when unknown, e.g. read
    from a model file), whether the model is binary, and a JSON-friendly ``report``."""

    slopes: tuple[float, ...]
    offsets: tuple[float, ...]
    threshold: float
    reject: float
    binary: bool
    report: dict[str, Any] = field(default_factory=dict)

    def decide(self, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(class indices, confidences, don't-know flags) for decision values ``F``: (n,) or
        (n, 1) for a binary model, (n, n_machines) otherwise."""
        return calibrated_decision(F, self.slopes, self.offsets, self.threshold, self.binary)


def log_sigmoid(z: np.ndarray) -> np.ndarray:
    """log(1 / (1 + exp(-z))) = -(max(-z, 0) + log1p(exp(-|z|))), finite for finite z (as
    ``eskin::log_sigmoid``)."""
    z = np.asarray(z, dtype=np.float64)
    return -(np.maximum(-z, 0.0) + np.log1p(np.exp(-np.abs(z))))


def calibrated_decision(
    F: np.ndarray, slopes: Sequence[float], offsets: Sequence[float], threshold: float,
    binary: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The calibrated rule on decision values: (class indices, confidences, flags). The same
    operations in the same order as the C++ classifier."""
    F = np.asarray(F, dtype=np.float64)
    if F.ndim == 1:
        F = F[:, None]
    a = np.asarray(slopes, dtype=np.float64)
    b = np.asarray(offsets, dtype=np.float64)
    if F.shape[1] != a.size:
        raise ValueError(f"decision values for {F.shape[1]} machines, calibration of {a.size}")
    if b.size != a.size:
        raise ValueError(f"a calibration of {a.size} slopes and {b.size} offsets")
    if binary and a.size != 1:
        raise ValueError(f"a binary calibration has one machine, not {a.size}")
    if binary:
        z = a[0] * F[:, 0] + b[0]
        lp, ln = log_sigmoid(z), log_sigmoid(-z)
        index = (lp > ln).astype(np.int64)  # the machine's class (1) or the other (0)
        total = 1.0 + np.exp(-np.abs(lp - ln))
    else:
        L = log_sigmoid(a[None, :] * F + b[None, :])
        index = np.argmax(L, axis=1)
        best = L[np.arange(len(L)), index]
        total = np.zeros(len(L))
        for k in range(L.shape[1]):  # in machine order, as the C++ sum
            total = total + np.exp(L[:, k] - best)
    confidence = 1.0 / total
    return index, confidence, confidence < float(threshold)


def fit_sigmoid(values: np.ndarray, positive: np.ndarray) -> tuple[float, float]:
    """(a, b) of p = 1 / (1 + exp(-(a f + b))) fitted to out-of-fold values ``f`` and whether
    each pattern is of the machine's class (Platt scaling); a >= 0, both within the model
    format's bounds."""
    from sklearn.calibration import _sigmoid_calibration

    f = np.asarray(values, dtype=np.float64)
    y = np.asarray(positive, dtype=bool)
    if y.all() or not y.any():
        raise TrainingError("a machine's calibration needs patterns of its class and of others")
    A, B = _sigmoid_calibration(f, y.astype(np.int64))  # sklearn: p = 1 / (1 + exp(A f + B))
    a, b = float(-A), float(-B)
    if not np.isfinite([a, b]).all():
        raise TrainingError(f"the calibration sigmoid did not converge (a={a}, b={b})")
    if a <= 0:  # held-out values that do not rise with the class say nothing: its share
        share = float(y.mean())  # in (0, 1): both sides are present (above)
        a, b = 0.0, math.log(share / (1 - share))
    return min(a, MAX_CALIBRATION), float(np.clip(b, -MAX_CALIBRATION, MAX_CALIBRATION))


def choose_threshold(confidence: np.ndarray, reject: float) -> float:
    """The threshold t that flags (confidence < t) ``reject`` of ``confidence``: round(reject
    n) of them when the values are distinct (fewer on ties); 0 for reject 0."""
    c = np.sort(np.asarray(confidence, dtype=np.float64))
    if not 0 <= reject < 1:
        raise TrainingError(f"reject must be in [0, 1), got {reject}")
    m = int(round(float(reject) * len(c)))
    if m == 0:  # reject 0, or no confidence at all
        return 0.0
    return float(c[min(m, len(c) - 1)])


def _folds(y: np.ndarray, groups: np.ndarray | None, n_folds: int, seed: int,
           notes: list[str]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Grouped folds whose training parts hold every class, else stratified ones (noted)."""
    from sklearn.model_selection import GroupKFold, StratifiedKFold

    n_classes = np.unique(y).size
    if groups is not None and np.unique(groups).size >= 2:
        k = min(n_folds, np.unique(groups).size)
        folds = list(GroupKFold(k).split(y, y, groups))
        if all(np.unique(y[tr]).size == n_classes for tr, _ in folds):
            return folds
        notes.append("calibration: grouped folds left a class out of a training part; "
                     "stratified folds instead")
    k = min(n_folds, int(np.bincount(y).min()))
    if k < 2:
        raise TrainingError("too few patterns per class for out-of-fold calibration")
    return list(StratifiedKFold(k, shuffle=True, random_state=seed).split(y, y))


def _fold_values(machines: list[Any], X: np.ndarray, targets: np.ndarray,
                 subsets: list[np.ndarray], tr: np.ndarray, te: np.ndarray,
                 shared: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Decision values on ``te`` of every machine retrained on ``tr`` (and its subset).
    ``shared``: (the per-mode distances of all of ``X``, their log energies) when the machines
    are kernel machines of one alpha: each slices them instead of computing its own."""
    from sklearn.base import clone

    out = np.empty((len(te), len(machines)))
    for k, m in enumerate(machines):
        trk = np.intersect1d(tr, subsets[k], assume_unique=True)
        if np.unique(targets[trk, k]).size < 2:  # a small balanced subset: the fold's whole part
            trk = tr
        if shared is None:
            fitted = clone(m).fit(X[trk], targets[trk, k])
            values = fitted.decision_function(X[te])
        else:
            d, e = shared
            fitted = clone(m)._fit(X[trk], targets[trk, k], d[:, trk][:, :, trk], e[trk])
            sv = trk[fitted.support_]
            values = fitted._decision_from(d[:, te][:, :, sv], e[te])
        out[:, k] = np.asarray(values, dtype=np.float64).ravel()
    return out


def _shared(machines: list[Any], X: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(per-mode distances of all of ``X``, log energies) for kernel machines of one alpha
    (computed once for every fold and machine), else None."""
    from eskin.learn.estimators import _shared_distances, _TensorKernelMachine

    if not all(isinstance(m, _TensorKernelMachine) for m in machines):
        return None
    if len({tuple(m.alphas_) for m in machines}) != 1:
        return None
    return _shared_distances(machines[0], X)


def out_of_fold_values(
    estimator: Any, X: np.ndarray, y: np.ndarray, groups: np.ndarray | None = None, *,
    machine_indices: Sequence[np.ndarray] | None = None, n_folds: int = DEFAULT_FOLDS,
    seed: int = 0, n_jobs: int | None = 1, notes: list[str] | None = None,
) -> tuple[np.ndarray, int]:
    """((n, n_machines) decision values of machines that did not train on each pattern, folds).

    ``estimator``: a fitted binary machine (class indices ``y`` 0/1, f > 0 meaning 1) or a
    OneVsAllTouchClassifier (``estimators_``: machine k claims class k), each machine retrained
    with its own settings on the folds' training parts (machine k only on ``machine_indices[k]``
    when given, as it was trained; the fold's whole training part when its share of that subset
    lacks one side)."""
    from eskin.learn.parallel import run_calls

    y = np.asarray(y, dtype=np.int64)
    machines = list(getattr(estimator, "estimators_", [estimator]))
    binary = not hasattr(estimator, "estimators_")
    # 1 where machine k's class is (the binary machine's: class 1), 0 elsewhere: each
    # machine's classes_[1] is then 1, its f > 0 side
    targets = ((y == 1)[:, None] if binary else
               y[:, None] == np.arange(len(machines))[None, :]).astype(np.int64)
    subsets = ([np.arange(len(y))] * len(machines) if machine_indices is None
               else [np.asarray(ix, dtype=np.intp) for ix in machine_indices])
    folds = _folds(y, groups, n_folds, seed, [] if notes is None else notes)
    shared = _shared(machines, np.asarray(X, dtype=np.float64))
    calls = [((machines, X, targets, subsets, tr, te, shared), {}) for tr, te in folds]
    F = np.empty((len(y), len(machines)))
    for (_, te), values in zip(folds, run_calls(_fold_values, calls, n_jobs=n_jobs)):
        F[te] = values
    return F, len(folds)


def fit_calibration(F: np.ndarray, y: np.ndarray, reject: float, *, binary: bool,
                    n_folds: int | None = None) -> Calibration:
    """The calibrated rule fitted on out-of-fold decision values ``F`` (n, n_machines) and the
    class indices ``y``, with the threshold that flags ``reject`` of these patterns."""
    F = np.asarray(F, dtype=np.float64)
    y = np.asarray(y, dtype=np.int64)
    ab = [fit_sigmoid(F[:, k], (y == 1) if binary else (y == k)) for k in range(F.shape[1])]
    slopes = tuple(a for a, _ in ab)
    offsets = tuple(b for _, b in ab)
    index, conf, _ = calibrated_decision(F, slopes, offsets, 0.0, binary)
    threshold = choose_threshold(conf, reject)
    flagged = conf < threshold
    wrong = index != y
    report = {
        "rule": "calibrated",
        "reject": float(reject),
        "threshold": threshold,
        "folds": n_folds,
        "n_patterns": int(len(y)),
        "oof_flagged": float(flagged.mean()),
        "oof_error": float(wrong.mean()),
        "oof_error_decided": float(wrong[~flagged].mean()) if (~flagged).any() else None,
    }
    return Calibration(slopes, offsets, threshold, float(reject), binary, report)
