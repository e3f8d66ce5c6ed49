"""Baselines of an evaluation: the vector RBF-SVM and the optional MiniRocket."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from eskin.errors import EvaluationError
from eskin.learn.baselines import (
    VECTOR_C,
    VECTOR_GAMMA_FACTORS,
    BaselineUnavailable,
    _inner_splits,
    _series,
    check_baselines,
    run_baseline,
)


def _two_classes(n: int, seed: int = 0):
    """Patterns (n, 2, 3, 12): class 1 has a sine on taxel (0, 0); 6 groups."""
    rng = np.random.default_rng(seed)
    y = np.arange(n) % 2
    X = rng.standard_normal((n, 2, 3, 12))
    X[y == 1, 0, 0] += 3 * np.sin(np.linspace(0, 2 * np.pi, 12))
    return X, y, (np.arange(n) // 2) % 6


def test_vector_svm_learns_a_separable_problem_with_grouped_inner_cv():
    X, y, g = _two_classes(60)
    pred, settings = run_baseline("vector", X[:40], y[:40], g[:40], X[40:])
    assert np.array_equal(pred, y[40:])
    assert set(settings) == {"C", "gamma_x_n_features", "inner_cv_balanced_accuracy"}
    assert settings["inner_cv_balanced_accuracy"] > 0.9


def _pipeline_search(X_train, y_train, groups_train, X_test):
    """The vector baseline as scikit-learn's GridSearchCV of StandardScaler + SVC(rbf) gives
    it: the oracle of the precomputed-kernel search."""
    import warnings

    from sklearn.model_selection import GridSearchCV
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    A = X_train.reshape(len(X_train), -1)
    grid = {"svc__C": list(VECTOR_C),
            "svc__gamma": [f / A.shape[1] for f in VECTOR_GAMMA_FACTORS]}
    search = GridSearchCV(make_pipeline(StandardScaler(), SVC(kernel="rbf")), grid,
                          cv=_inner_splits(y_train, groups_train), scoring="balanced_accuracy",
                          error_score=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        search.fit(A, y_train)
    settings = {"C": search.best_params_["svc__C"],
                "gamma_x_n_features": search.best_params_["svc__gamma"] * A.shape[1],
                "inner_cv_balanced_accuracy": search.best_score_}
    return search.predict(X_test.reshape(len(X_test), -1)), settings


@pytest.mark.parametrize("seed", range(6))
def test_vector_svm_chooses_and_predicts_as_the_scaler_and_svc_pipeline(seed):
    """Three classes of noisy patterns, some taxels constant (a deviation of 0), groups of
    unequal size: the same candidate, inner score and predictions as the pipeline's search."""
    rng = np.random.default_rng(seed)
    n = 72
    y = rng.integers(0, 3, n)
    X = rng.standard_normal((n, 3, 4, 7)) * rng.uniform(0.2, 3.0, (1, 3, 4, 1))
    X[:, 0, 0] = 1.5
    X += (0.4 + 0.3 * seed / 6) * y[:, None, None, None] * np.linspace(-1, 1, 7)
    g = rng.integers(0, 7, n)
    train = g != 6
    pred, settings = run_baseline("vector", X[train], y[train], g[train], X[~train])
    want_pred, want = _pipeline_search(X[train], y[train], g[train], X[~train])
    assert np.array_equal(pred, want_pred)
    assert settings == want


def test_unknown_baseline_is_named():
    with pytest.raises(ValueError, match="unknown baseline 'knn': choose from vector, minirocket"):
        check_baselines(["vector", "knn"])
    assert check_baselines(["vector", "vector"]) == ("vector",)


def test_short_patterns_are_stretched_to_minirocket_length():
    X = np.arange(2 * 3 * 4, dtype=float).reshape(1, 2, 3, 4)
    S = _series(X)
    assert S.shape == (1, 6, 9)
    np.testing.assert_allclose(
        S[0, 0], np.interp(np.linspace(0, 1, 9), np.linspace(0, 1, 4), X[0, 0, 0])
    )
    assert _series(np.ones((2, 1, 1, 1))).shape == (2, 1, 9)
    long = np.ones((1, 1, 2, 30))
    assert _series(long).shape == (1, 2, 30)


def _hide(monkeypatch: pytest.MonkeyPatch, *packages: str) -> None:
    """Make importing ``packages`` (and their submodules) fail as if they were not installed."""
    loaded = [m for m in sys.modules if m.split(".")[0] in packages]
    for name in (*packages, *loaded):
        monkeypatch.setitem(sys.modules, name, None)


def test_minirocket_without_aeon_or_sktime_says_how_to_install(monkeypatch):
    _hide(monkeypatch, "aeon", "sktime")
    with pytest.raises(BaselineUnavailable, match=r"pip install 'eskin\[minirocket\]'"):
        check_baselines(["minirocket"])


@pytest.mark.parametrize("library", ["aeon", "sktime"])
def test_minirocket_learns_a_separable_problem(library, monkeypatch):
    pytest.importorskip(library)
    if library == "sktime":
        _hide(monkeypatch, "aeon")  # aeon is preferred when both are installed
    X, y, g = _two_classes(40)
    pred, settings = run_baseline("minirocket", X[:20], y[:20], g[:20], X[20:])
    assert np.array_equal(pred, y[20:])
    assert settings["library"] == library
    assert settings["n_features"] > 0


@pytest.mark.parametrize("name", ["vector", "minirocket"])
def test_a_baseline_refuses_training_patterns_of_one_class(name):
    X, y, g = _two_classes(40)
    one_class = y == 0
    with pytest.raises(EvaluationError, match=rf"baseline '{name}': .* only class 0"):
        run_baseline(name, X[one_class], y[one_class], g[one_class], X[~one_class])
