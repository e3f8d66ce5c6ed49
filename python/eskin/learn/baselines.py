"""Baseline classifiers that an evaluation runs in the same folds as the tensor machines.

Both see the same preprocessed patterns (rows, cols, D) as the tensor machine of the fold:

- ``vector``: an RBF support vector machine (scikit-learn ``SVC``) on the flattened patterns,
  standardised per feature, with C and gamma chosen by its own inner grouped cross-validation
  on the fold's training groups only (``GroupKFold``, at most 5 splits).
- ``minirocket``: MiniRocket features (Dempster et al., 2021) of the patterns read as
  multivariate time series (one channel per taxel, D time steps), then a ridge classifier
  with its regularisation chosen by leave-one-out (``RidgeClassifierCV``), the usual MiniRocket
  pipeline. It needs ``aeon`` (``pip install 'eskin[minirocket]'``) or ``sktime``; MiniRocket
  needs at least 9 time steps, so patterns with D < 9 are repeated along time
  (linear interpolation) up to 9 steps for it. Tested with aeon 1.0 and 1.6
  (``aeon.transformations.collection.convolution_based.MiniRocket``, multivariate since 1.0) and
  sktime 1.2 (``MiniRocketMultivariate``).

A baseline needs training patterns of at least two classes (``EvaluationError`` otherwise):
a ridge classifier fitted on one class would silently predict that class for everything.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from eskin.errors import BaselineUnavailable, EvaluationError

BASELINES: tuple[str, ...] = ("vector", "minirocket")
VECTOR_C: tuple[float, ...] = (0.1, 1.0, 10.0, 100.0)
#: gamma as multiples of 1/n_features (scikit-learn's "scale" for standardised features)
VECTOR_GAMMA_FACTORS: tuple[float, ...] = (0.1, 1.0, 10.0)
MINIROCKET_MIN_LENGTH = 9


def check_baselines(names: Sequence[str]) -> tuple[str, ...]:
    """Validate baseline names (and that their dependencies import); returns them in order."""
    out = []
    for name in names:
        if name not in BASELINES:
            raise ValueError(f"unknown baseline {name!r}: choose from {', '.join(BASELINES)}")
        if name == "minirocket":
            _minirocket_transform(0)
        if name not in out:
            out.append(name)
    return tuple(out)


def run_baseline(
    name: str,
    X_train: np.ndarray,
    y_train: np.ndarray,
    groups_train: np.ndarray,
    X_test: np.ndarray,
    *,
    seed: int = 0,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Fit baseline ``name`` on the training patterns; (predicted class ids, its settings)."""
    _check_two_classes(name, y_train)
    if name == "vector":
        return vector_svm(X_train, y_train, groups_train, X_test)
    if name == "minirocket":
        return minirocket(X_train, y_train, X_test, seed=seed)
    raise ValueError(f"unknown baseline {name!r}: choose from {', '.join(BASELINES)}")


def _check_two_classes(name: str, y_train: np.ndarray) -> None:
    classes = np.unique(np.asarray(y_train))
    if len(classes) < 2:
        found = f"only class {classes[0]}" if len(classes) else "no patterns"
        raise EvaluationError(
            f"baseline {name!r}: the training patterns hold {found}; at least 2 classes are needed"
        )


def _inner_splits(y: np.ndarray, groups: np.ndarray) -> Any:
    from sklearn.model_selection import GroupKFold, StratifiedKFold

    n_groups = len(np.unique(groups))
    if n_groups >= 2:
        return list(GroupKFold(n_splits=min(5, n_groups)).split(y, y, groups))
    smallest = int(np.min(np.bincount(y)[np.bincount(y) > 0]))
    return list(StratifiedKFold(n_splits=max(2, min(5, smallest))).split(y, y))


def vector_svm(
    X_train: np.ndarray, y_train: np.ndarray, groups_train: np.ndarray, X_test: np.ndarray
) -> tuple[np.ndarray, dict[str, Any]]:
    """RBF-SVM on flattened, standardised patterns; C and gamma by inner grouped CV.

    The search of scikit-learn's ``GridSearchCV(make_pipeline(StandardScaler(), SVC()), ...)``
    over :data:`VECTOR_C` x gammas, scored by balanced accuracy on :func:`_inner_splits`, with
    the kernel computed once per split instead of once per candidate: a candidate's RBF kernel
    depends on it only through gamma, so each split's squared distances between the
    standardised patterns (one matrix product) serve all twelve candidates, each an ``SVC`` on
    ``exp(-gamma * distances)`` (``kernel="precomputed"``, the same solver). Candidates are
    ranked as GridSearchCV ranks them (mean over the splits, the first best in grid order, C
    the outer loop; a fit that fails scores 0), and the best is refitted on all the training
    patterns. The kernel values differ from the pipeline's by rounding only, so the choice
    and the predictions are the pipeline's (tests/python/learn/test_baselines.py compares
    them)."""
    A = np.asarray(X_train, np.float64).reshape(len(X_train), -1)
    B = np.asarray(X_test, np.float64).reshape(len(X_test), -1)
    y = np.asarray(y_train, np.int64)
    grid = [(C, f / A.shape[1]) for C in VECTOR_C for f in VECTOR_GAMMA_FACTORS]
    splits = _inner_splits(y, np.asarray(groups_train))
    scores = np.zeros((len(grid), len(splits)))
    with warnings.catch_warnings():  # an inner split may hold one class only: scored anyway
        warnings.simplefilter("ignore", UserWarning)
        for s, (fit, held) in enumerate(splits):
            to_fit, to_held = _standardised_distances(A[fit], A[held])
            for c, (C, gamma) in enumerate(grid):
                scores[c, s] = _held_out_score(to_fit, y[fit], to_held, y[held], C, gamma)
    mean = np.average(scores, axis=1)
    best = int(np.argmax(mean))
    C, gamma = grid[best]
    to_fit, to_test = _standardised_distances(A, B)
    svc = _precomputed_svc(to_fit, y, C, gamma)
    settings = {
        "C": float(C),
        "gamma_x_n_features": float(gamma * A.shape[1]),
        "inner_cv_balanced_accuracy": float(mean[best]),
    }
    return svc.predict(np.exp(-gamma * to_test)).astype(np.int64), settings


def _standardised_distances(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Squared Euclidean distances (A to A, B to A) once both are standardised by A's mean
    and deviation (``StandardScaler`` fitted on A, as the pipeline fits it)."""
    from sklearn.metrics.pairwise import euclidean_distances
    from sklearn.preprocessing import StandardScaler

    scaler = StandardScaler().fit(A)
    Z = scaler.transform(A)
    return (euclidean_distances(Z, squared=True),
            euclidean_distances(scaler.transform(B), Z, squared=True))


def _precomputed_svc(to_fit: np.ndarray, y: np.ndarray, C: float, gamma: float) -> Any:
    from sklearn.svm import SVC

    return SVC(kernel="precomputed", C=C).fit(np.exp(-gamma * to_fit), y)


def _held_out_score(to_fit: np.ndarray, y_fit: np.ndarray, to_held: np.ndarray,
                    y_held: np.ndarray, C: float, gamma: float) -> float:
    """Balanced accuracy on the held-out part of one split (0 when the fit fails, e.g. on a
    split whose fitting part holds one class: GridSearchCV's ``error_score=0.0``)."""
    from sklearn.metrics import balanced_accuracy_score

    try:
        svc = _precomputed_svc(to_fit, y_fit, C, gamma)
    except ValueError:
        return 0.0
    return float(balanced_accuracy_score(y_held, svc.predict(np.exp(-gamma * to_held))))


def _minirocket_transform(seed: int) -> Any:
    """A MiniRocket transformer from aeon, else sktime; BaselineUnavailable if neither."""
    try:
        from aeon.transformations.collection.convolution_based import MiniRocket

        return MiniRocket(random_state=seed)
    except ImportError:
        pass
    try:
        from sktime.transformations.panel.rocket import MiniRocketMultivariate

        return MiniRocketMultivariate(random_state=seed)
    except ImportError:
        pass
    raise BaselineUnavailable(
        "the minirocket baseline needs aeon or sktime (with numba): pip install 'eskin[minirocket]'"
    )


def _series(X: np.ndarray) -> np.ndarray:
    """(n, rows, cols, D) patterns -> (n, rows*cols, max(D, 9)) float64 series."""
    X = np.asarray(X, np.float64)
    S = X.reshape(len(X), -1, X.shape[-1])
    D = S.shape[-1]
    if D >= MINIROCKET_MIN_LENGTH:
        return np.ascontiguousarray(S)
    if D == 1:
        return np.repeat(S, MINIROCKET_MIN_LENGTH, axis=-1)
    src = np.linspace(0.0, 1.0, D)
    dst = np.linspace(0.0, 1.0, MINIROCKET_MIN_LENGTH)
    flat = S.reshape(-1, D)
    out = np.stack([np.interp(dst, src, row) for row in flat])
    return out.reshape(S.shape[0], S.shape[1], MINIROCKET_MIN_LENGTH)


def minirocket(
    X_train: np.ndarray, y_train: np.ndarray, X_test: np.ndarray, *, seed: int = 0
) -> tuple[np.ndarray, dict[str, Any]]:
    """MiniRocket features + RidgeClassifierCV (alphas 1e-3..1e3, chosen by leave-one-out)."""
    from sklearn.linear_model import RidgeClassifierCV
    from sklearn.preprocessing import StandardScaler

    transform = _minirocket_transform(seed)
    A, B = _series(X_train), _series(X_test)
    Fa = np.asarray(transform.fit_transform(A), np.float64)
    Fb = np.asarray(transform.transform(B), np.float64)
    scaler = StandardScaler().fit(Fa)
    ridge = RidgeClassifierCV(alphas=np.logspace(-3, 3, 10)).fit(scaler.transform(Fa), y_train)
    settings = {
        "library": type(transform).__module__.split(".")[0],
        "n_features": int(Fa.shape[1]),
        "ridge_alpha": float(ridge.alpha_),
    }
    return ridge.predict(scaler.transform(Fb)).astype(np.int64), settings
