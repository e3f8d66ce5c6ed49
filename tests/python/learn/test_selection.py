"""Maximal Discrepancy (Algorithm 1) and cross-validation selection (eskin.selection)."""

from __future__ import annotations

import math

import joblib
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import eskin
from eskin.learn.estimators import TensorRLS, TensorSVC, kernel_from_distances
from eskin.learn.selection import (
    CrossValidationSearch,
    MaximalDiscrepancySearch,
    _Config,
    _first_true,
    _md_block_svm,
    _MDSettings,
    md_tau,
    rls_eig_solve,
)

SHAPE = (3, 3, 8)


def _noise(n, seed=0, shape=SHAPE):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, *shape)), rng.permutation(np.arange(n) % 2)


def _separable(n_per_class, seed=0, noise=0.3):
    """Two classes whose patterns span different subspaces (a different wave per class)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, SHAPE[2])
    X, y = [], []
    for c, freq in enumerate((1.0, 2.5)):
        base = np.sin(2 * np.pi * (freq * t[None, None, :] + 0.3 * c * np.arange(3)[:, None, None]))
        base = base * (1.0 + np.arange(3))[None, :, None]
        for _ in range(n_per_class):
            X.append(base + noise * rng.normal(size=SHAPE))
            y.append(c)
    return np.asarray(X), np.asarray(y)


# --------------------------------------------------------------------------------- RLS maths
def test_rls_by_eigendecomposition_equals_a_direct_solve():
    X, y = _noise(40, seed=1)
    K = eskin.tensor_kernel(X, sigma=0.8, alpha="half")
    w, Q = np.linalg.eigh(K)
    rng = np.random.default_rng(2)
    Y = np.where(rng.random((40, 5)) < 0.5, -1.0, 1.0)
    for lam in (1e-3, 1e-1, 10.0):
        direct = np.linalg.solve(K + lam * np.eye(40), Y)
        np.testing.assert_allclose(rls_eig_solve(w, Q, Y, lam), direct, rtol=0, atol=1e-10)
        np.testing.assert_allclose(
            rls_eig_solve(w, Q, Y[:, 0], lam), direct[:, 0], rtol=0, atol=1e-10
        )


def test_tau_is_the_finite_sample_term():
    assert md_tau(180, 0.05) == pytest.approx(3 * math.sqrt(math.log(40.0) / 360.0))


# ------------------------------------------------------------------------------ Algorithm 1
def _md(estimator, grid, X, y, **kw):
    kw.setdefault("n_labelings", 8)
    kw.setdefault("random_state", 0)
    return MaximalDiscrepancySearch(estimator, grid, **kw).fit(X, y)


def test_chi_near_zero_for_a_machine_that_cannot_fit_random_labels():
    # two groups of 21 identical patterns: every machine is constant on a group, so a random
    # labelling (an odd count per group, never a tie) is fitted no better than by majority
    rng = np.random.default_rng(0)
    X = np.repeat(rng.normal(size=(2, *SHAPE)), 21, axis=0)
    y = np.repeat([0, 1], 21)
    for est in (TensorRLS(), TensorSVC()):
        for lam, sigma in ((1e-3, 0.5), (10.0, 4.0)):
            s = _md(est, {"lam": [lam], "sigma": [sigma]}, X, y, n_labelings=20)
            chi = s.cv_results_["chi"][0]
            assert chi < 0.3, (type(est).__name__, lam, sigma, chi)
            assert s.cv_results_["train_error"][0] == 0.0


def test_chi_near_one_for_a_machine_that_can_fit_random_labels():
    X, y = _noise(40)
    for est in (TensorRLS(), TensorSVC()):
        s = _md(est, {"lam": [1e-3], "sigma": [2.0**-4], "alpha": ["full"]}, X, y)
        # K is the identity: the machine memorises any labelling
        assert s.cv_results_["chi"][0] > 0.9, type(est).__name__
        assert s.cv_results_["train_error"][0] == 0.0


@pytest.mark.parametrize("seed", [3, 4])
def test_selection_prefers_simpler_settings_on_pure_noise_labels(seed):
    X, y = _noise(40, seed=seed)
    grid = {"lam": [1e-3, 1.0], "sigma": [2.0**-4, 2.0**4], "alpha": [1, "half"]}
    for est in (TensorRLS(), TensorSVC()):
        s = _md(est, grid, X, y)
        r = s.cv_results_
        best = s.best_index_
        # the smoothest kernel and the strongest regularisation
        assert r["sigmas"][best][0] == 16.0, (type(est).__name__, s.best_params_)
        assert r["lam"][best] == 1.0, (type(est).__name__, s.best_params_)
        # the memorising corner (tiny lambda, tiny sigma) has chi = 1 and the worst bound
        corner = (r["lam"] == 1e-3) & np.array([sg[0] == 2.0**-4 for sg in r["sigmas"]])
        assert np.all(r["chi"][corner] == 1.0)
        assert r["bound"][corner].min() == r["bound"].max()


def test_md_results_table_and_refit():
    X, y = _separable(12)
    grid = {"lam": [1e-2, 1.0], "sigma": [0.5, 2.0], "alpha": [1, "half"]}
    s = _md(TensorSVC(), grid, X, y, delta=0.1)
    r = s.cv_results_
    n_cfg = 8
    for key in ("lam", "C", "train_error", "chi", "tau", "bound", "gamma_0", "cap_hits",
                "mean_lambda_steps", "rank_bound", "criterion", "mean_random_error"):
        assert len(r[key]) == n_cfg, key
    assert r["random_errors"].shape == (n_cfg, 8)
    np.testing.assert_allclose(r["tau"], md_tau(24, 0.1))
    np.testing.assert_allclose(r["chi"], 1 - 2 * r["random_errors"].mean(axis=1))
    np.testing.assert_allclose(r["bound"], r["train_error"] + r["chi"] + r["tau"])
    assert s.best_index_ == int(np.argmin(r["bound"])) or r["bound"][s.best_index_] == r[
        "bound"
    ].min()
    # grid in lambda, machine in C = 1/lambda (reading R9)
    np.testing.assert_allclose(r["C"], 1 / r["lam"])
    assert all(set(p) == {"C", "sigma", "alpha"} for p in r["params"])
    assert s.best_params_["C"] == pytest.approx(1 / r["lam"][s.best_index_])
    assert s.best_estimator_.get_params()["C"] == s.best_params_["C"]
    np.testing.assert_array_equal(s.predict(X), s.best_estimator_.predict(X))
    assert s.score(X, y) >= 0.9
    assert s.cap_hits_ == int(r["cap_hits"].sum())


def test_rls_search_accepts_a_grid_in_c():
    X, y = _separable(8)
    s = _md(TensorRLS(), {"C": [0.1, 10.0], "sigma": [1.0]}, X, y)
    np.testing.assert_allclose(s.cv_results_["lam"], [10.0, 0.1])
    assert set(s.best_params_) == {"lam", "sigma"}


def test_cap_is_reported_when_hit():
    X, y = _separable(8)
    # one step of lambda_hat at most and a tiny eps: the cap is hit for some labelling
    s = _md(TensorRLS(), {"lam": [1e-3], "sigma": [1.0]}, X, y, eps=1.01, max_lambda_steps=1)
    assert s.cv_results_["cap_hits"][0] > 0
    assert s.cv_results_["max_lambda_steps_used"][0] == 1


def test_svm_step_search_equals_the_linear_loop():
    X, y = _noise(30, seed=5)
    y_pm = np.where(y == 1, 1.0, -1.0)
    d = eskin.mode_distances(X, alpha="half")
    K = kernel_from_distances(d, (0.7,) * 3)
    y_cl = np.where(np.arange(30) < 12, 1.0, -1.0)
    cfgs = [_Config(i, lam, {}, (), ()) for i, lam in enumerate((1e-3, 1e-1))]
    st_ = _MDSettings(n_labelings=6, eps=2.0, max_lambda_steps=30, n_init=1, max_iter=10)
    a = _md_block_svm(K, y_pm, y_cl, cfgs, st_, 7, strategy="linear")
    b = _md_block_svm(K, y_pm, y_cl, cfgs, st_, 7, strategy="search")
    for ra, rb in zip(a, b):
        np.testing.assert_array_equal(ra["steps"], rb["steps"])
        np.testing.assert_array_equal(ra["errors"], rb["errors"])
    assert max(r["steps"].max() for r in a) > 0  # the loop was exercised


@settings(max_examples=200, deadline=None)
@given(
    kmax=st.integers(0, 40),
    threshold=st.integers(0, 45),
    guess=st.integers(-3, 45),
)
def test_first_true_finds_the_threshold_from_any_guess(kmax, threshold, guess):
    calls = []

    def pred(k):
        assert 0 <= k <= kmax
        calls.append(k)
        return k >= threshold

    expected = threshold if threshold <= kmax else None
    assert _first_true(pred, guess, kmax) == expected


def test_same_results_for_any_n_jobs_and_seeded_by_random_state():
    X, y = _noise(30, seed=4)
    grid = {"lam": [1e-2, 1.0], "sigma": [0.5, 2.0], "alpha": [1, "half"]}
    a = _md(TensorRLS(), grid, X, y, n_jobs=1, random_state=11)
    with joblib.parallel_backend("threading"):  # process pools: see the Dask test
        b = _md(TensorRLS(), grid, X, y, n_jobs=2, random_state=11)
    _assert_same_results(a, b)
    c = _md(TensorRLS(), grid, X, y, n_jobs=1, random_state=12)
    assert not np.array_equal(a.cv_results_["random_errors"], c.cv_results_["random_errors"])


def _assert_same_results(a, b):
    ra, rb = a.cv_results_, b.cv_results_
    assert ra.keys() == rb.keys()
    for key in ra:
        if isinstance(ra[key], np.ndarray) and ra[key].dtype != object:
            np.testing.assert_array_equal(ra[key], rb[key], err_msg=key)
        else:
            assert list(ra[key]) == list(rb[key]), key
    assert a.best_index_ == b.best_index_ and a.best_params_ == b.best_params_


# the cluster's own start-up/tear-down chatter on a loaded machine is not what is tested here
@pytest.mark.filterwarnings("ignore::UserWarning:distributed")
@pytest.mark.filterwarnings("ignore::ResourceWarning")
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_dask_cluster_gives_the_serial_results():
    distributed = pytest.importorskip("distributed")
    import dask

    X, y = _noise(30, seed=6)
    grid = {"lam": [1e-2, 1.0], "sigma": [0.5, 2.0], "alpha": [1, "half"]}
    serial = _md(TensorSVC(), grid, X, y, n_jobs=1, random_state=3)
    with dask.config.set({"distributed.comm.timeouts.connect": "60s"}), distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster, timeout="60s"):
        with joblib.parallel_backend("dask"):
            on_dask = _md(TensorSVC(), grid, X, y, random_state=3)
            cv_dask = CrossValidationSearch(
                TensorRLS(), grid, n_splits=3, random_state=3
            ).fit(X, y)
    _assert_same_results(serial, on_dask)
    cv_serial = CrossValidationSearch(TensorRLS(), grid, n_splits=3, random_state=3).fit(X, y)
    _assert_same_results(cv_serial, cv_dask)


# ------------------------------------------------------------------------- cross-validation
def test_cross_validation_search_with_groups():
    X, y = _separable(12)
    groups = np.repeat(np.arange(12), 2)  # 12 participants, two patterns each
    grid = {"lam": [1e-2, 1.0], "sigma": [0.5, 2.0]}
    s = CrossValidationSearch(TensorSVC(), grid, n_splits=4, random_state=0).fit(
        X, y, groups=groups
    )
    for tr, te in s.splits_:
        assert not set(groups[tr]) & set(groups[te])
    r = s.cv_results_
    errs = np.column_stack([r[f"split{i}_test_error"] for i in range(4)])
    np.testing.assert_allclose(r["mean_test_error"], errs.mean(axis=1))
    assert r["criterion"][s.best_index_] == r["mean_test_error"].min()
    assert s.best_params_["C"] == pytest.approx(1 / r["lam"][s.best_index_])
    assert s.score(X, y) >= 0.9


def test_cross_validation_rls_matches_fitting_each_split():
    X, y = _separable(10)
    grid = {"lam": [1e-2, 1.0], "sigma": [1.0]}
    s = CrossValidationSearch(TensorRLS(), grid, n_splits=3, random_state=1).fit(X, y)
    for i, params in enumerate(s.cv_results_["params"]):
        for k, (tr, te) in enumerate(s.splits_):
            m = TensorRLS(**params).fit(X[tr], y[tr])
            err = np.mean(m.predict(X[te]) != y[te])
            assert s.cv_results_[f"split{k}_test_error"][i] == pytest.approx(err)


def test_search_rejects_bad_settings():
    X, y = _separable(4)
    with pytest.raises(ValueError, match="eps"):
        _md(TensorRLS(), {"lam": [1.0]}, X, y, eps=1.0)
    with pytest.raises(ValueError, match="cannot be searched"):
        _md(TensorRLS(), {"gamma": [1.0]}, X, y)
    with pytest.raises(TypeError, match="TensorSVC and TensorRLS"):
        from sklearn.svm import SVC

        _md(SVC(), {"C": [1.0]}, X.reshape(len(X), -1), y)


# ---------------------------------------------------------------- readings of Algorithm 1
from eskin.learn.selection import MD_READINGS, md_reading

_GRID = {"lam": [1e-2, 1.0], "sigma": [0.5, 2.0], "alpha": [1, "half"]}


@pytest.mark.parametrize("name", sorted(MD_READINGS))
@pytest.mark.parametrize("est", [TensorRLS(), TensorSVC()], ids=["rls", "svm"])
def test_every_named_reading_is_reproducible_and_says_what_it_ran(name, est):
    X, y = _separable(10, noise=0.6)
    a = _md(est, _GRID, X, y, random_state=4, **md_reading(name))
    b = _md(est, _GRID, X, y, random_state=4, **md_reading(name))
    _assert_same_results(a, b)
    assert a.describe_reading().startswith(f"reading {name!r}: ")


def test_unknown_reading_and_options_are_rejected():
    X, y = _separable(4)
    with pytest.raises(ValueError, match="unknown Maximal Discrepancy reading"):
        md_reading("paper-ish")
    for key, bad in (("clustering", "spectral"), ("gamma0", "smaller"), ("reference", "x"),
                     ("chi", "median"), ("n_init", 0)):
        with pytest.raises(ValueError, match=key):
            _md(TensorRLS(), {"lam": [1.0]}, X, y, **{key: bad})
    custom = MaximalDiscrepancySearch(TensorRLS(), clustering="lloyd", chi="max")
    assert custom.describe_reading().startswith("a custom reading (clustering=lloyd")


def test_same_lambda_reference_trains_every_labelling_with_lambda():
    X, y = _separable(10, noise=0.8)
    grid = {"lam": [1e-1, 1.0], "sigma": [1.0], "alpha": ["half"]}
    s = _md(TensorRLS(), grid, X, y, reference="same-lambda", n_labelings=4)
    r = s.cv_results_
    assert np.all(r["mean_lambda_steps"] == 0) and np.all(np.isinf(r["gamma_0"]))
    # the same labellings through a plain RLS solve with the configuration's own lambda
    from eskin.learn.selection import _random_labellings

    y_pm = np.where(y == s.classes_[1], 1.0, -1.0)
    K = eskin.tensor_kernel(X, sigma=1.0, alpha="half")
    for i, lam in enumerate(r["lam"]):
        Ystar = _random_labellings(y_pm, 4, s.random_state_, i)
        F = K @ np.linalg.solve(K + lam * np.eye(len(y)), Ystar)
        errs = np.mean(np.where(F > 0, 1.0, -1.0) != Ystar, axis=0)
        np.testing.assert_allclose(r["random_errors"][i], errs)


def test_true_norm_reference_bounds_labellings_by_the_true_label_machine():
    X, y = _separable(10, noise=0.8)
    grid = {"lam": [1e-2, 1.0], "sigma": [1.0], "alpha": ["half"]}
    s = _md(TensorRLS(), grid, X, y, reference="true-norm")
    y_pm = np.where(y == s.classes_[1], 1.0, -1.0)
    K = eskin.tensor_kernel(X, sigma=1.0, alpha="half")
    for i, lam in enumerate(s.cv_results_["lam"]):
        beta = np.linalg.solve(K + lam * np.eye(len(y)), y_pm)
        assert s.cv_results_["gamma_0"][i] == pytest.approx(beta @ K @ beta, rel=1e-9)


@pytest.mark.parametrize("est", [TensorRLS(), TensorSVC()], ids=["rls", "svm"])
def test_larger_gamma0_is_never_below_the_nearer(est):
    X, y = _separable(10, noise=0.8)
    near = _md(est, _GRID, X, y, gamma0="nearer").cv_results_
    large = _md(est, _GRID, X, y, gamma0="larger").cv_results_
    assert np.all(large["gamma_0"] >= near["gamma_0"] * (1 - 1e-9))
    # a looser norm bound needs no more lambda steps
    assert np.all(large["mean_lambda_steps"] <= near["mean_lambda_steps"])


def test_chi_max_is_the_largest_discrepancy_over_the_labellings():
    X, y = _noise(30, seed=2)
    mean = _md(TensorRLS(), _GRID, X, y, chi="mean").cv_results_
    top = _md(TensorRLS(), _GRID, X, y, chi="max").cv_results_
    np.testing.assert_array_equal(mean["random_errors"], top["random_errors"])
    np.testing.assert_allclose(top["chi"], 1 - 2 * top["random_errors"].min(axis=1))
    assert np.all(top["chi"] >= mean["chi"])


@pytest.mark.parametrize("est", [TensorRLS(), TensorSVC()], ids=["rls", "svm"])
def test_fit_distances_gives_the_results_of_fit(est):
    X, y = _separable(8, noise=0.6)
    groups = np.repeat(np.arange(8), 2)
    dists = {}
    for a in (1, "half"):
        alphas = tuple(int(v) for v in eskin.resolve_alphas(SHAPE, a))
        dists[alphas] = eskin.mode_distances(X, alpha=alphas)
    md = _md(est, _GRID, X, y, clustering="lloyd")
    md_d = MaximalDiscrepancySearch(
        est, _GRID, n_labelings=8, random_state=0, clustering="lloyd"
    ).fit_distances(dists, y, SHAPE)
    _assert_same_results(md, md_d)
    assert not hasattr(md_d, "best_estimator_")
    cv = CrossValidationSearch(est, _GRID, n_splits=3, random_state=0).fit(X, y, groups=groups)
    cv_d = CrossValidationSearch(est, _GRID, n_splits=3, random_state=0).fit_distances(
        dists, y, SHAPE, groups=groups
    )
    _assert_same_results(cv, cv_d)


def test_cluster_minority_share_reports_the_reference_partition():
    X, y = _separable(10, noise=0.8)  # n = 20
    bal = _md(TensorRLS(), _GRID, X, y, clustering="balanced").cv_results_
    np.testing.assert_array_equal(bal["cluster_minority_share"], 0.5)
    pp = _md(TensorRLS(), _GRID, X, y).cv_results_["cluster_minority_share"]
    assert np.all((pp > 0) & (pp <= 0.5))
    free = _md(TensorRLS(), _GRID, X, y, reference="true-norm").cv_results_
    assert np.all(np.isnan(free["cluster_minority_share"]))


@pytest.mark.parametrize(("est", "same_as"), [(TensorSVC(), "stratified"),
                                              (TensorRLS(), "uniform")], ids=["svm", "rls"])
def test_default_flip_is_stratified_for_the_svm_and_uniform_for_rls(est, same_as):
    X, y = _noise(30, seed=8)
    auto = _md(est, _GRID, X, y)  # the defaults: the reading named "default"
    assert auto.describe_reading().startswith("reading 'default': ")
    _assert_same_results(auto, _md(est, _GRID, X, y, flip=same_as))
    # eskin's first reading stays available by name
    first = MaximalDiscrepancySearch(est, **md_reading("kmeans++"))
    assert (first.clustering, first.flip) == ("kmeans++", "uniform")
