"""The amplitude-aware kernel: the tensor kernel times a Gaussian on the patterns' log energy."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.base import clone

import eskin
from eskin.errors import TrainingError
from eskin.learn.estimators import MIN_ENERGY_SPREAD, TensorRLS, TensorSVC
from eskin.learn.grids import param_grid, parse_amplitudes
from eskin.learn.selection import CrossValidationSearch, MaximalDiscrepancySearch

SHAPE = (3, 3, 8)


def _shapes_and_gains(n_per_class=20, seed=0, freqs=(1.5, 1.5)):
    """Two classes with the same touch shapes (random waves) but amplitudes a factor 4
    apart: a "tap" and a "punch". The tensor kernel alone cannot tell them apart (unless
    ``freqs`` gives the classes different waves)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, SHAPE[2])
    X, y = [], []
    for c, gain in enumerate((1.0, 4.0)):
        for _ in range(n_per_class):
            phase = rng.uniform(0, 2 * np.pi)
            wave = np.sin(2 * np.pi * freqs[c] * t + phase)[None, None, :]
            pattern = wave * (1.0 + np.arange(SHAPE[1]))[None, :, None] * np.ones(SHAPE)
            X.append(gain * rng.uniform(0.8, 1.25) * pattern + 0.05 * rng.normal(size=SHAPE))
            y.append(c)
    return np.asarray(X), np.asarray(y)


def test_log_energy_is_the_log_of_the_mean_square():
    X = np.stack([np.full(SHAPE, 2.0), np.zeros(SHAPE), np.arange(72.0).reshape(SHAPE)])
    e = eskin.pattern_log_energy(X)
    np.testing.assert_allclose(e[0], np.log(4.0 + 1e-12), rtol=1e-15)
    assert e[1] == pytest.approx(np.log(1e-12))
    np.testing.assert_allclose(e[2], np.log(np.mean(np.arange(72.0) ** 2) + 1e-12), rtol=1e-15)


@pytest.mark.parametrize("gain", [1e-3, 0.5, 7.0, 1e4])
def test_a_gain_shifts_every_log_energy_alike(gain):
    rng = np.random.default_rng(1)
    X = rng.normal(size=(6, *SHAPE))
    shift = eskin.pattern_log_energy(gain * X) - eskin.pattern_log_energy(X)
    np.testing.assert_allclose(shift, 2 * np.log(gain), atol=1e-9)


@pytest.mark.parametrize("machine", [TensorSVC(C=10.0), TensorRLS(lam=0.1)])
def test_decision_is_the_tensor_kernel_times_the_energy_factor(machine):
    X, y = _shapes_and_gains()
    m = clone(machine).set_params(sigma=1.0, alpha=1, amplitude=2.0).fit(X, y)
    e_train = eskin.pattern_log_energy(X)
    width = 2.0 * max(np.std(e_train), MIN_ENERGY_SPREAD)
    assert m.amplitude_width_ == pytest.approx(width, rel=1e-12)
    np.testing.assert_array_equal(m.sv_log_energy_, e_train[m.support_])
    Xt, _ = _shapes_and_gains(5, seed=9)
    K = eskin.tensor_kernel(Xt, m.support_vectors_, sigma=1.0, alpha=1)
    de = eskin.pattern_log_energy(Xt)[:, None] - m.sv_log_energy_[None, :]
    want = (K * np.exp(-de**2 / (2 * width**2))) @ m.dual_coef_ + m.intercept_
    np.testing.assert_allclose(m.decision_function(Xt), want, rtol=1e-10, atol=1e-12)


def test_without_amplitude_the_machine_is_the_papers():
    X, y = _shapes_and_gains()
    m = TensorSVC(C=10.0, sigma=1.0, alpha=1).fit(X, y)
    assert m.amplitude_width_ == 0.0
    K = eskin.tensor_kernel(X, m.support_vectors_, sigma=1.0, alpha=1)
    np.testing.assert_allclose(
        m.decision_function(X), K @ m.dual_coef_ + m.intercept_, rtol=1e-12, atol=1e-12
    )


def test_the_factor_tells_a_tap_from_a_punch_that_the_tensor_kernel_cannot():
    X, y = _shapes_and_gains(seed=0)
    Xt, yt = _shapes_and_gains(seed=1)
    plain = TensorSVC(C=10.0, sigma=1.0, alpha=1).fit(X, y)
    aware = TensorSVC(C=10.0, sigma=1.0, alpha=1, amplitude=1.0).fit(X, y)
    assert np.mean(aware.predict(Xt) == yt) == 1.0
    assert np.mean(plain.predict(Xt) == yt) <= 0.75


@pytest.mark.parametrize("gain", [1e-2, 30.0])
def test_decisions_do_not_depend_on_the_sensors_units(gain):
    X, y = _shapes_and_gains()
    Xt, _ = _shapes_and_gains(5, seed=3)
    a = TensorRLS(lam=0.1, sigma=1.0, alpha=1, amplitude=1.0).fit(X, y)
    b = TensorRLS(lam=0.1, sigma=1.0, alpha=1, amplitude=1.0).fit(gain * X, y)
    np.testing.assert_allclose(b.decision_function(gain * Xt), a.decision_function(Xt), atol=1e-8)


def test_equal_energies_get_the_smallest_spread_as_width():
    X, y = _shapes_and_gains()
    X = X / np.sqrt(np.mean(X.reshape(len(X), -1) ** 2, axis=1))[:, None, None, None]
    m = TensorSVC(C=1.0, amplitude=3.0).fit(X, y)
    assert m.amplitude_width_ == pytest.approx(3.0 * MIN_ENERGY_SPREAD)


@pytest.mark.parametrize("bad", [0, -1.0, 1e-3, 1e3, float("nan"), float("inf"), "1", True])
def test_a_bad_amplitude_is_refused(bad):
    X, y = _shapes_and_gains(4)
    with pytest.raises(ValueError, match=r"amplitude must be None or a number in \[0.01, 100\]"):
        TensorSVC(amplitude=bad).fit(X, y)


def test_searches_carry_the_amplitude_through_the_grid():
    X, y = _shapes_and_gains()
    groups = np.arange(len(y)) % 8
    grid = {"lam": [0.1], "sigma": [1.0], "alpha": [1], "amplitude": [None, 1.0]}
    cv = CrossValidationSearch(TensorSVC(), grid, n_splits=4, random_state=0)
    cv.fit(X, y, groups=groups)
    assert cv.cv_results_["amplitudes"] == [None, 1.0]
    err = cv.cv_results_["mean_test_error"]
    assert err[1] == 0.0 and err[0] > 0.2
    assert cv.best_params_["amplitude"] == 1.0
    assert cv.best_estimator_.amplitude_width_ > 0
    md = MaximalDiscrepancySearch(TensorRLS(), grid, random_state=0, n_labelings=3).fit(X, y)
    assert len(md.cv_results_["bound"]) == 2


def test_ties_go_to_the_kernel_without_the_factor():
    X, y = _shapes_and_gains(freqs=(0.5, 3.0))  # the shapes differ too: every setting is perfect
    grid = {"lam": [0.1], "sigma": [1.0], "alpha": [1], "amplitude": [4.0, None, 1.0]}
    cv = CrossValidationSearch(TensorRLS(), grid, n_splits=3, random_state=0)
    cv.fit(X, y, groups=np.arange(len(y)) % 5)
    assert np.all(cv.cv_results_["mean_test_error"] == 0.0)
    assert cv.best_params_["amplitude"] is None


def test_precomputed_distances_need_the_energies_with_an_amplitude_grid():
    X, y = _shapes_and_gains(6)
    dists = {(1, 1, 1): eskin.mode_distances(X, alpha=1)}
    grid = {"lam": [0.1], "sigma": [1.0], "alpha": [1], "amplitude": [1.0]}
    search = CrossValidationSearch(TensorRLS(), grid, n_splits=2, random_state=0, refit=False)
    with pytest.raises(ValueError, match="energies"):
        search.fit_distances(dists, y, SHAPE)
    e = eskin.pattern_log_energy(X)
    a = search.fit_distances(dists, y, SHAPE, energies=e).cv_results_["mean_test_error"]
    b = CrossValidationSearch(TensorRLS(), grid, n_splits=2, random_state=0).fit(X, y)
    np.testing.assert_array_equal(a, b.cv_results_["mean_test_error"])


def test_amplitudes_from_text():
    assert parse_amplitudes("off") == (None,)
    assert parse_amplitudes("off, 1,4") == (None, 1.0, 4.0)
    assert parse_amplitudes("none,0.5") == (None, 0.5)
    for bad in ("0", "-2", "x", "1,,2", "0.001", "1000"):
        with pytest.raises(TrainingError, match="amplitude must be 'off' or a number in"):
            parse_amplitudes(bad)


def test_the_grid_names_the_amplitude_only_when_there_is_one():
    assert "amplitude" not in param_grid()
    assert param_grid(amplitudes=(None, 2.0))["amplitude"] == [None, 2.0]
    assert len(list(eskin.learn.selection.ParameterGrid(param_grid(amplitudes=(None, 2))))) == 270
