"""The out-of-fold values the calibration is fitted on (eskin.learn.calibration): which folds,
which patterns each machine is retrained on, and the error the report states. A scikit-learn
logistic regression stands in for a tensor machine: the functions take any binary estimator
with ``decision_function`` (exact values, seconds instead of minutes)."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.linear_model import LogisticRegression
from sklearn.model_selection import StratifiedKFold

from eskin.learn.calibration import fit_calibration, out_of_fold_values


def _data(n: int = 40, seed: int = 3):
    rng = np.random.default_rng(seed)
    y = np.tile([0, 1], n // 2)
    X = rng.standard_normal((n, 3)) + 0.8 * y[:, None]
    return X, y


def test_two_groups_holding_every_class_give_two_grouped_folds():
    X, y = _data()
    groups = np.repeat([7, 9], len(y) // 2)  # each group holds both classes
    notes: list[str] = []
    F, n_folds = out_of_fold_values(LogisticRegression().fit(X, y), X, y, groups, n_folds=5,
                                    notes=notes)
    assert n_folds == 2 and notes == []
    for held in (7, 9):  # each group's values come from the machine trained on the other
        te = groups == held
        m = LogisticRegression().fit(X[~te], np.where(y[~te] == 1, 1, -1))
        np.testing.assert_array_equal(F[te, 0], m.decision_function(X[te]))


def test_a_machine_is_retrained_on_its_own_patterns_only():
    X, y = _data()
    subset = np.arange(30)  # the machine was trained on the first 30 patterns
    F, n_folds = out_of_fold_values(LogisticRegression().fit(X[subset], y[subset]), X, y,
                                    machine_indices=[subset], n_folds=4, seed=5)
    assert n_folds == 4
    want = np.empty(len(y))
    for tr, te in StratifiedKFold(4, shuffle=True, random_state=5).split(y, y):
        trk = np.intersect1d(tr, subset)
        assert np.unique(y[trk]).size == 2  # both sides in every fold's share of the subset
        m = LogisticRegression().fit(X[trk], np.where(y[trk] == 1, 1, -1))
        want[te] = m.decision_function(X[te])
    np.testing.assert_array_equal(F[:, 0], want)


def test_the_reported_error_counts_wrong_labels_both_ways():
    # symmetric values: the fitted sigmoid is centred on 0, so the label is f > 0; one pattern
    # of each class is on the wrong side (0.5 of class 0, -0.5 of class 1)
    F = np.array([[3.0], [2.0], [1.0], [-1.0], [-2.0], [-3.0], [0.5], [-0.5]])
    y = np.array([1, 1, 1, 0, 0, 0, 0, 1])
    cal = fit_calibration(F, y, 0.0, binary=True)
    assert abs(cal.offsets[0]) < 1e-3 * cal.slopes[0]
    assert cal.report["oof_error"] == 0.25
    assert cal.report["oof_error_decided"] == 0.25
    assert cal.report["oof_flagged"] == 0.0


def test_grouped_folds_that_leave_a_class_out_of_a_training_part_give_way_to_stratified_ones():
    X, y = _data(60)
    # class 1 only in group 0 (and class 0 everywhere): the fold holding out group 0 trains
    # on class 0 alone
    groups = np.where(y == 1, 0, np.arange(len(y)) % 3)
    notes: list[str] = []
    _, n_folds = out_of_fold_values(LogisticRegression().fit(X, y), X, y, groups, n_folds=5,
                                    notes=notes)
    assert notes == ["calibration: grouped folds left a class out of a training part; "
                     "stratified folds instead"]
    assert n_folds == 5


def test_by_default_the_values_come_from_five_folds():
    """Without groups and enough patterns of each class: five stratified folds (the calibration
    report's ``folds``)."""
    X, y = _data(60)
    F, n_folds = out_of_fold_values(LogisticRegression().fit(X, y), X, y)
    assert n_folds == 5 and F.shape == (60, 1)


def test_kernel_machines_of_one_alpha_share_the_distances_of_every_pattern():
    """The per-mode distances are computed once for all folds and machines only when every
    machine is a tensor kernel machine of the same alpha (each then slices them); machines of
    two alphas, or any other estimator, compute their own. The shared ones are those of the
    first machine's alpha over all patterns."""
    from eskin.learn.calibration import _shared
    from eskin.learn.estimators import TensorRLS, TensorSVC
    from eskin.learn.kernel import mode_distances, pattern_log_energy

    rng = np.random.default_rng(2)
    X = rng.standard_normal((12, 4, 4, 5))
    y = np.tile([0, 1], 6)
    half, one = (TensorSVC(alpha="half").fit(X, y), TensorRLS(alpha="half").fit(X, y)), \
        TensorSVC(alpha=1).fit(X, y)
    d, e = _shared(list(half), X)
    np.testing.assert_array_equal(d, mode_distances(X, alpha=half[0].alphas_))
    np.testing.assert_array_equal(e, pattern_log_energy(X))
    assert half[0].alphas_ != one.alphas_
    assert _shared([*half, one], X) is None
    assert _shared([half[0], LogisticRegression()], X) is None


def test_groups_of_one_value_give_stratified_folds():
    """One group cannot be split group-disjointly: the folds are then the stratified ones, as
    without groups (and nothing is noted: grouped folds were not tried)."""
    X, y = _data()
    notes: list[str] = []
    F, n_folds = out_of_fold_values(LogisticRegression().fit(X, y), X, y, np.full(len(y), 4),
                                    n_folds=3, seed=2, notes=notes)
    G, _ = out_of_fold_values(LogisticRegression().fit(X, y), X, y, None, n_folds=3, seed=2)
    assert n_folds == 3 and notes == []
    np.testing.assert_array_equal(F, G)


def test_a_class_of_two_patterns_gives_two_folds_and_one_of_one_none():
    from eskin.errors import TrainingError

    X, y = _data()
    y = y.copy()
    y[y == 1] = 0
    y[[5, 9]] = 1  # class 1: two patterns
    F, n_folds = out_of_fold_values(LogisticRegression().fit(X, y), X, y, n_folds=5)
    assert n_folds == 2 and np.isfinite(F).all()
    y[9] = 0  # one
    with pytest.raises(TrainingError) as refused:
        out_of_fold_values(LogisticRegression().fit(X, y), X, y, n_folds=5)
    assert str(refused.value) == "too few patterns per class for out-of-fold calibration"


def test_a_folds_share_of_the_subset_lacking_a_side_gives_way_to_the_whole_training_part():
    """The machine was trained on a subset holding one pattern of its class: in the folds whose
    training part leaves that pattern out, the machine is retrained on the whole training part;
    in the others on the fold's share of the subset."""
    X, y = _data()
    one = int(np.flatnonzero(y == 1)[0])
    subset = np.sort(np.r_[np.flatnonzero(y == 0)[:12], one])
    F, n_folds = out_of_fold_values(LogisticRegression().fit(X[subset], y[subset]), X, y,
                                    machine_indices=[subset], n_folds=4, seed=5)
    want, whole = np.empty(len(y)), 0
    for tr, te in StratifiedKFold(4, shuffle=True, random_state=5).split(y, y):
        trk = np.intersect1d(tr, subset)
        if one not in trk:
            trk, whole = tr, whole + 1
        m = LogisticRegression().fit(X[trk], y[trk])
        want[te] = m.decision_function(X[te])
    assert n_folds == 4 and whole == 1
    np.testing.assert_array_equal(F[:, 0], want)


def test_the_folds_are_seeded_with_0_by_default():
    X, y = _data()
    machine = LogisticRegression().fit(X, y)
    F, _ = out_of_fold_values(machine, X, y)
    for seed, same in ((0, True), (1, False)):
        assert np.array_equal(out_of_fold_values(machine, X, y, seed=seed)[0], F) is same
