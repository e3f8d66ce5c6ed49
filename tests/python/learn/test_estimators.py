"""Tensor-SVM, tensor-RLS, kernel k-means and the 1-vs-all rule (eskin.estimators)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.model_selection import GridSearchCV
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import FunctionTransformer
from sklearn.svm import SVC
from sklearn.utils.estimator_checks import parametrize_with_checks

import eskin
from eskin.learn.estimators import (
    KernelKMeans,
    OneVsAllTouchClassifier,
    TensorRLS,
    TensorSVC,
    kernel_kmeans,
    one_vs_all_rule,
    svm_train,
)
from eskin.learn.selection import MaximalDiscrepancySearch

SHAPE = (3, 3, 8)


def _patterns(n_per_class, n_classes=2, shape=SHAPE, noise=0.3, seed=0):
    """Tensor patterns whose subspaces depend on the class (a class-specific wave), plus noise."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, shape[2])
    X, y = [], []
    for c in range(n_classes):
        freq = 1.0 + 1.5 * c
        base = np.sin(
            2 * np.pi * (freq * t[None, None, :] + 0.3 * c * np.arange(shape[0])[:, None, None])
        ) * (1.0 + np.arange(shape[1]))[None, :, None]
        for _ in range(n_per_class):
            X.append(base + noise * rng.normal(size=shape))
            y.append(c)
    return np.asarray(X), np.asarray(y)


# ------------------------------------------------------------------------------------ machines
def test_tensor_svc_equals_sklearn_svc_on_the_tensor_gram():
    X, y = _patterns(15)
    K = eskin.tensor_kernel(X, sigma=0.7, alpha="half")
    ref = SVC(kernel="precomputed", C=3.0).fit(K, y)
    svm = TensorSVC(C=3.0, sigma=0.7, alpha="half").fit(X, y)
    np.testing.assert_allclose(svm.decision_function(X), ref.decision_function(K), atol=1e-9)
    np.testing.assert_array_equal(svm.support_, ref.support_)
    np.testing.assert_array_equal(svm.predict(X), ref.predict(K))


def test_fast_svm_path_equals_svc():
    rng = np.random.default_rng(3)
    Z = rng.normal(size=(40, 4))
    K = np.exp(-((Z[:, None] - Z[None]) ** 2).sum(-1) / 4.0)
    y = np.where(rng.random(40) < 0.4, -1.0, 1.0)
    for C in (0.1, 1.0, 100.0):
        beta, b, support = svm_train(K, y, C)
        ref = SVC(kernel="precomputed", C=C).fit(K, y)
        np.testing.assert_allclose(K @ beta + b, ref.decision_function(K), atol=1e-10)
        np.testing.assert_array_equal(support, ref.support_)


@pytest.mark.parametrize("label", [-1.0, 1.0])
def test_svm_on_a_single_class_labelling_is_the_constant_machine(label):
    # A random MD labelling of a tiny training set can hold one class only; libsvm has no
    # dual then. The machine must be f = label everywhere, with no support vector.
    rng = np.random.default_rng(4)
    Z = rng.normal(size=(6, 3))
    K = np.exp(-((Z[:, None] - Z[None]) ** 2).sum(-1))
    beta, b, support = svm_train(K, np.full(6, label), C=1.0)
    np.testing.assert_array_equal(beta, np.zeros(6))
    assert b == label
    assert support.size == 0
    np.testing.assert_array_equal(np.sign(K @ beta + b), np.full(6, label))


def test_tensor_rls_is_the_regularised_solve():
    X, y = _patterns(12)
    K = eskin.tensor_kernel(X, sigma=1.3, alpha=(2, 2, 4))
    y_pm = np.where(y == 1, 1.0, -1.0)
    rls = TensorRLS(lam=0.05, sigma=1.3, alpha=(2, 2, 4)).fit(X, y)
    beta = np.linalg.solve(K + 0.05 * np.eye(len(y)), y_pm)
    np.testing.assert_allclose(rls.dual_coef_, beta, atol=1e-10)
    assert rls.intercept_ == 0.0
    np.testing.assert_allclose(rls.decision_function(X), K @ beta, atol=1e-10)


@pytest.mark.parametrize("machine", [TensorSVC(C=10.0, sigma=1.0), TensorRLS(lam=0.01, sigma=1.0)])
def test_fitted_attributes_follow_the_contract(machine):
    X, y = _patterns(10)
    labels = np.array(["washer", "brush"])[y]  # classes_ sorted: brush, washer
    m = clone(machine).fit(X, labels)
    assert list(m.classes_) == ["brush", "washer"]
    n_sv = m.dual_coef_.shape[0]
    assert m.support_vectors_.shape == (n_sv, *SHAPE)
    assert m.support_vectors_.dtype == np.float64
    assert isinstance(m.intercept_, float)
    assert m.alphas_ == tuple(eskin.resolve_alphas(SHAPE, "half"))
    assert m.sigmas_ == (1.0, 1.0, 1.0)
    # decision = sum_i dual_coef_i K(sv_i, x) + intercept_, > 0 means classes_[1]
    Xt = X[::3]
    K = eskin.tensor_kernel(Xt, m.support_vectors_, sigma=m.sigmas_, alpha=m.alphas_)
    f = m.decision_function(Xt)
    np.testing.assert_allclose(f, K @ m.dual_coef_ + m.intercept_, atol=1e-10)
    np.testing.assert_array_equal(m.predict(Xt), np.where(f > 0, "washer", "brush"))
    assert m.score(X, labels) > 0.9


def test_two_d_input_with_tensor_shape_matches_tensor_input():
    X, y = _patterns(8)
    a = TensorSVC(sigma=0.8).fit(X, y)
    b = TensorSVC(sigma=0.8, tensor_shape=SHAPE).fit(X.reshape(len(X), -1), y)
    np.testing.assert_allclose(
        a.decision_function(X), b.decision_function(X.reshape(len(X), -1)), atol=1e-12
    )
    assert b.support_vectors_.shape[1:] == SHAPE


def test_bad_inputs_name_the_problem():
    X, y = _patterns(6)
    with pytest.raises(ValueError, match="binary machine"):
        TensorSVC().fit(X, np.arange(len(y)) % 3)
    with pytest.raises(ValueError, match="tensor_shape"):
        TensorRLS(tensor_shape=(2, 2)).fit(X.reshape(len(X), -1), y)
    m = TensorRLS().fit(X, y)
    with pytest.raises(ValueError, match="pattern shape"):
        m.decision_function(X[:, :, :, :4])
    with pytest.raises(ValueError, match="lam"):
        TensorRLS(lam=0.0).fit(X, y)
    with pytest.raises(ValueError, match="sigma"):
        TensorSVC(sigma=-1.0).fit(X, y)


def test_clone_pipeline_and_sklearn_grid_search():
    X, y = _patterns(10)
    pipe = Pipeline([("id", FunctionTransformer()), ("svm", TensorSVC())])
    gs = GridSearchCV(pipe, {"svm__sigma": [0.5, 2.0]}, cv=2).fit(X, y)
    assert gs.best_estimator_.named_steps["svm"].sigma in (0.5, 2.0)
    assert clone(TensorRLS(lam=0.3)).get_params()["lam"] == 0.3


# ------------------------------------------------------------------------------ kernel k-means
def _brute_force_inertia(K):
    n = K.shape[0]
    best = np.inf
    diag = np.diag(K)
    for bits in itertools.product([0, 1], repeat=n - 1):
        labels = np.array((0,) + bits)  # point 0 fixed in cluster 0: each partition once
        if labels.sum() == 0:
            continue
        total = 0.0
        for c in (0, 1):
            idx = np.flatnonzero(labels == c)
            Kc = K[np.ix_(idx, idx)]
            total += diag[idx].sum() - Kc.sum() / idx.size
        best = min(best, total)
    return best


@pytest.mark.parametrize("seed", range(4))
def test_kernel_kmeans_reaches_the_brute_force_optimum(seed):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(10, 3, 3, 5))
    X[:5] += 0.8 * rng.normal(size=(1, 3, 3, 5))  # a loose group, not a clean split
    K = eskin.tensor_kernel(X, sigma=0.6, alpha="half")
    labels, inertia, _ = kernel_kmeans(K, 2, n_init=10, random_state=seed)
    assert inertia == pytest.approx(_brute_force_inertia(K), rel=1e-10, abs=1e-12)
    assert set(labels) == {0, 1}


def test_kernel_kmeans_estimator_tensor_and_precomputed_agree():
    X, _ = _patterns(8, noise=0.5)
    km = KernelKMeans(sigma=0.9, alpha="half", random_state=1).fit(X)
    K = eskin.tensor_kernel(X, sigma=0.9, alpha="half")
    kp = KernelKMeans(kernel="precomputed", random_state=1).fit(K)
    np.testing.assert_array_equal(km.labels_, kp.labels_)
    assert km.inertia_ == pytest.approx(kp.inertia_)
    np.testing.assert_array_equal(km.predict(X), km.labels_)
    np.testing.assert_array_equal(kp.predict(K), kp.labels_)
    assert sorted(km.cluster_sizes_) == [8, 8]  # the two classes are the two clusters


def test_kernel_kmeans_survives_a_constant_kernel():
    labels, inertia, _ = kernel_kmeans(np.ones((6, 6)), 2, n_init=3, random_state=0)
    assert set(labels) == {0, 1} and inertia == pytest.approx(0.0, abs=1e-12)


# ---------------------------------------------------------------------------------- 1-vs-all
def test_rule_exactly_one_machine_claims():
    f = np.array([[-0.5, 0.2, -0.1]])
    index, n_claims, dont_know = one_vs_all_rule(f)
    assert index.tolist() == [1] and n_claims.tolist() == [1] and dont_know.tolist() == [False]


def test_rule_no_machine_claims_takes_the_largest_and_does_not_know():
    f = np.array([[-0.5, -0.9, -0.1]])
    index, n_claims, dont_know = one_vs_all_rule(f)
    assert index.tolist() == [2] and n_claims.tolist() == [0] and dont_know.tolist() == [True]


def test_rule_two_machines_claim_takes_the_largest_and_does_not_know():
    f = np.array([[0.3, -0.2, 0.7]])
    index, n_claims, dont_know = one_vs_all_rule(f)
    assert index.tolist() == [2] and n_claims.tolist() == [2] and dont_know.tolist() == [True]


def test_rule_all_claim_and_zero_is_not_a_claim():
    f = np.array([[0.3, 0.9, 0.7], [0.0, -1.0, -2.0]])
    index, n_claims, dont_know = one_vs_all_rule(f)
    assert index.tolist() == [1, 0] and n_claims.tolist() == [3, 0]
    assert dont_know.tolist() == [True, True]


def test_one_vs_all_classifier_end_to_end():
    X, y = _patterns(8, n_classes=3, noise=0.2)
    names = np.array(["brush", "finger", "washer"])[y]
    clf = OneVsAllTouchClassifier(TensorRLS(lam=0.1, sigma=1.0)).fit(X, names)
    assert list(clf.classes_) == ["brush", "finger", "washer"]
    assert len(clf.estimators_) == 3
    for k, m in enumerate(clf.estimators_):
        assert list(m.classes_) == [-1, 1]
        np.testing.assert_allclose(clf.decision_function(X)[:, k], m.decision_function(X))
    decision = clf.decide(X)
    assert decision.decision_values.shape == (len(X), 3)
    pred = clf.predict(X)
    np.testing.assert_array_equal(pred, decision.labels)
    np.testing.assert_array_equal(clf.dont_know_, decision.dont_know)
    assert np.mean(pred == names) > 0.9


def test_one_vs_all_with_own_training_sets_and_selection():
    X, y = _patterns(6, n_classes=3, noise=0.2)
    rng = np.random.default_rng(0)
    subsets = [
        np.concatenate([np.flatnonzero(y == c), rng.choice(np.flatnonzero(y != c), 6, False)])
        for c in range(3)
    ]
    search = MaximalDiscrepancySearch(
        TensorRLS(), {"lam": [0.01, 1.0], "sigma": [1.0]}, n_labelings=3, random_state=0
    )
    clf = OneVsAllTouchClassifier(search, n_jobs=1).fit(X, y, machine_indices=subsets)
    assert all(isinstance(s, MaximalDiscrepancySearch) for s in clf.searches_)
    assert all(isinstance(m, TensorRLS) for m in clf.estimators_)
    assert clf.predict(X).shape == (len(X),)


def test_one_vs_all_hands_groups_to_grouped_searches():
    from eskin.learn.selection import CrossValidationSearch

    X, y = _patterns(8, n_classes=3, noise=0.2)
    groups = np.arange(len(y)) % 6  # 6 participants
    search = CrossValidationSearch(
        TensorRLS(), {"lam": [0.01, 1.0], "sigma": [1.0]}, n_splits=3, random_state=0
    )
    clf = OneVsAllTouchClassifier(search).fit(X, y, groups=groups)
    for s in clf.searches_:  # every machine's splits keep the participants apart
        for tr, te in s.splits_:
            assert not set(groups[tr]) & set(groups[te])
    plain = OneVsAllTouchClassifier(search).fit(X, y)
    assert any(set(groups[tr]) & set(groups[te]) for tr, te in plain.searches_[0].splits_)
    # an estimator without groups in its fit trains as before
    OneVsAllTouchClassifier(TensorRLS()).fit(X, y, groups=groups)
    with pytest.raises(ValueError, match="groups has 3 entries"):
        OneVsAllTouchClassifier(search).fit(X, y, groups=groups[:3])


# ---------------------------------------------------------------------- scikit-learn's checks
# Checks that cannot pass, and why (also in docs/learning.md).
_OVA_XFAIL = {
    "check_classifiers_train": "decision_function is (n, n_classes) even for two classes "
    "(one machine per class, the paper's rule), sklearn wants (n,) for binary problems",
    "check_classifiers_classes": "same: the (n, 2) decision of a 2-class 1-vs-all",
}
_PRECOMPUTED_XFAIL = {
    "check_clustering": "feeds raw (n, 2) features to a kernel='precomputed' clusterer",
}


def _expected_failed(estimator):
    if isinstance(estimator, OneVsAllTouchClassifier):
        return _OVA_XFAIL
    if isinstance(estimator, KernelKMeans) and estimator.kernel == "precomputed":
        return _PRECOMPUTED_XFAIL
    return {}


@parametrize_with_checks(
    [
        TensorSVC(),
        TensorRLS(),
        KernelKMeans(random_state=0),
        KernelKMeans(kernel="precomputed", random_state=0),
        OneVsAllTouchClassifier(TensorRLS()),
    ],
    expected_failed_checks=_expected_failed,
    xfail_strict=True,
)
def test_sklearn_estimator_checks(estimator, check):
    check(estimator)


# ------------------------------------------------------------------ kernel k-means readings
def _two_groups(n_small, n_large, seed=0):
    """A tight small group and a tight large group, far apart in feature space."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(2, 3, 3, 5))
    X = np.concatenate(
        [centres[0] + 0.05 * rng.normal(size=(n_small, 3, 3, 5)),
         centres[1] + 0.05 * rng.normal(size=(n_large, 3, 3, 5))]
    )
    return eskin.tensor_kernel(X, sigma=0.5, alpha="half")


@pytest.mark.parametrize("n", [11, 12])
@pytest.mark.parametrize("seed", range(3))
def test_balanced_kernel_kmeans_returns_equal_halves(n, seed):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, 3, 3, 5))
    K = eskin.tensor_kernel(X, sigma=0.6, alpha="half")
    labels, inertia, _ = kernel_kmeans(K, 2, n_init=4, random_state=seed, method="balanced")
    assert sorted(np.bincount(labels, minlength=2).tolist()) == [n // 2, n - n // 2]
    assert inertia > 0


def test_balanced_kernel_kmeans_keeps_a_small_group_together():
    K = _two_groups(6, 14)
    labels, _, _ = kernel_kmeans(K, 2, n_init=5, random_state=0, method="balanced")
    assert np.bincount(labels).tolist() == [10, 10]
    assert len(set(labels[:6])) == 1  # the 6-point group is inside one half


@pytest.mark.parametrize("method", ["kmeans++", "lloyd", "lloyd-hartigan"])
def test_unconstrained_kernel_kmeans_finds_two_clean_groups(method):
    K = _two_groups(6, 14)
    labels, _, _ = kernel_kmeans(K, 2, n_init=5, random_state=1, method=method)
    assert len(set(labels[:6])) == 1 and len(set(labels[6:])) == 1
    assert labels[0] != labels[6]


@pytest.mark.parametrize("method", ["kmeans++", "lloyd", "lloyd-hartigan", "balanced"])
def test_kernel_kmeans_same_seed_same_labels(method):
    rng = np.random.default_rng(5)
    K = eskin.tensor_kernel(rng.normal(size=(30, 3, 3, 5)), sigma=0.8, alpha="half")
    a = kernel_kmeans(K, 2, n_init=3, random_state=7, method=method)
    b = kernel_kmeans(K, 2, n_init=3, random_state=7, method=method)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]
    km = KernelKMeans(kernel="precomputed", n_init=3, random_state=7, method=method).fit(K)
    np.testing.assert_array_equal(km.labels_, a[0])


def test_hartigan_moves_never_raise_the_inertia_of_lloyd():
    rng = np.random.default_rng(2)
    K = eskin.tensor_kernel(rng.normal(size=(40, 3, 3, 5)), sigma=0.7, alpha="half")
    for seed in range(5):  # the same random starts: Hartigan only moves when it lowers it
        lloyd = kernel_kmeans(K, 2, n_init=1, random_state=seed, method="lloyd")
        both = kernel_kmeans(K, 2, n_init=1, random_state=seed, method="lloyd-hartigan")
        assert both[1] <= lloyd[1] + 1e-12


def test_kernel_kmeans_rejects_unknown_methods():
    K = np.eye(4)
    with pytest.raises(ValueError, match="method must be one of"):
        kernel_kmeans(K, 2, method="spectral")
    with pytest.raises(ValueError, match="makes 2 clusters"):
        kernel_kmeans(K, 3, method="balanced")


@pytest.mark.parametrize("make", [TensorSVC, TensorRLS, lambda: OneVsAllTouchClassifier(TensorRLS())])
def test_patterns_of_another_order_are_named_as_such(make):
    X, y = _patterns(6, n_classes=3 if make not in (TensorSVC, TensorRLS) else 2)
    est = make().fit(X, y)
    name = type(est).__name__
    with pytest.raises(ValueError, match=rf"X has shape \({len(X)}, 72\), but {name} was fitted on "
                                         r"patterns of shape \(3, 3, 8\): its rows look flattened: "
                                         r"X.reshape\(-1, 3, 3, 8\) undoes it"):
        est.predict(X.reshape(len(X), -1))
    with pytest.raises(ValueError, match=r"one pattern needs the batch axis: X\[np.newaxis\]"):
        est.predict(X[0])
    assert est.predict(X[:1]).shape == (1,)


def test_one_vs_all_kernel_machines_share_the_distances_and_equal_machines_fitted_alone():
    """The 1-vs-all classifier computes the patterns' distances once and each kernel machine
    slices its own: the machines are those fitted alone on their patterns."""
    from eskin.learn.recipes import one_vs_all_indices

    rng = np.random.default_rng(5)
    X = rng.normal(size=(30, 3, 4, 6))
    y = np.repeat([0, 1, 2], 10)
    indices = one_vs_all_indices(y, 3, "balanced", 1)
    est = TensorSVC(C=10.0, sigma=2.0, alpha="half", amplitude=1.0)
    ova = OneVsAllTouchClassifier(est).fit(X, y, machine_indices=indices)
    for k, ix in enumerate(indices):
        alone = TensorSVC(C=10.0, sigma=2.0, alpha="half", amplitude=1.0).fit(
            X[ix], np.where(y[ix] == k, 1, -1))
        np.testing.assert_array_equal(ova.estimators_[k].support_, alone.support_)
        np.testing.assert_allclose(ova.estimators_[k].dual_coef_, alone.dual_coef_,
                                   rtol=1e-9, atol=1e-12)
        assert ova.estimators_[k].amplitude_width_ == alone.amplitude_width_
