"""eskin.learn.support_budget: at most N support vectors, each machine projected onto the kept
patterns (exact maths: orthogonality of the residual, nested kept sets, exact re-expression)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS, TensorSVC
from eskin.learn.support_budget import (
    _kernel,
    bound_support,
    distinct_support,
    kept_patterns,
    n_distinct_support,
    project_machine,
)


def _data(n=60, classes=3, seed=0):
    rng = np.random.default_rng(seed)
    y = np.arange(n) % classes
    X = rng.standard_normal((n, 4, 4, 6))
    X[:, 0, 0, :] += 1.5 * y[:, None]  # a class cue on one taxel
    X *= (1 + 0.5 * y)[:, None, None, None]  # and in amplitude
    return X, y


def _rkhs_residual(m, bounded) -> float:
    """||w - w_S||^2 in m's kernel (the amplitude factor included)."""
    a, ea = m.support_vectors_, m.sv_log_energy_
    b, eb = bounded.support_vectors_, bounded.sv_log_energy_
    beta, gamma = m.dual_coef_, bounded.dual_coef_
    return float(beta @ _kernel(m, a, ea, a, ea) @ beta - 2 * beta @ _kernel(m, a, ea, b, eb)
                 @ gamma + gamma @ _kernel(m, b, eb, b, eb) @ gamma)


@pytest.mark.parametrize("selection", ["greedy", "coefficients"])
@pytest.mark.parametrize("machine", [TensorRLS(lam=0.1, sigma=4.0, amplitude=1.0),
                                     TensorSVC(C=10.0, sigma=4.0)])
def test_the_residual_is_orthogonal_to_every_kept_pattern(machine, selection):
    X, y = _data(classes=2)
    m = machine.fit(X, y)
    k = n_distinct_support(m) // 3
    bounded = bound_support(m, k, selection)
    assert n_distinct_support(bounded) == k and n_distinct_support(m) > k  # m itself unchanged
    S, eS = bounded.support_vectors_, bounded.sv_log_energy_
    # <w - w_S, phi(s)> = 0 for every kept s: the projection's defining property
    resid = (_kernel(m, S, eS, m.support_vectors_, m.sv_log_energy_) @ m.dual_coef_
             - _kernel(m, S, eS, S, eS) @ bounded.dual_coef_)
    assert np.max(np.abs(resid)) < 1e-8 * max(1.0, np.max(np.abs(m.dual_coef_)))
    assert bounded.intercept_ == m.intercept_


@pytest.mark.parametrize("selection", ["greedy", "coefficients"])
def test_a_larger_budget_never_leaves_a_larger_residual(selection):
    X, y = _data(classes=2, seed=3)
    m = TensorRLS(lam=0.05, sigma=2.0).fit(X, y)
    residuals = [_rkhs_residual(m, bound_support(m, k, selection))
                 for k in (2, 5, 10, 20, 40, 59)]
    assert all(a >= b - 1e-9 for a, b in zip(residuals, residuals[1:]))  # kept sets are nested
    assert residuals[0] > residuals[-1] > -1e-9
    assert bound_support(m, 60, selection) is m  # nothing to bound: the machine itself
    for k in (2, 5, 10):
        assert set(kept_patterns(m, k, selection)) <= set(kept_patterns(m, 2 * k, selection))


def test_the_greedy_first_pattern_is_the_best_single_one():
    """With one pattern kept, matching pursuit's choice leaves the smallest residual of all."""
    X, y = _data(classes=2, seed=4)
    m = TensorSVC(C=10.0, sigma=3.0, amplitude=1.0).fit(X, y)
    (first,) = kept_patterns(m, 1)
    table, energies, _ = distinct_support(m)
    residual = []
    for i in range(len(table)):
        one = copy.deepcopy(m)
        project_machine(one, table[i:i + 1], energies[i:i + 1])
        residual.append(_rkhs_residual(m, one))
    assert first == int(np.argmin(residual))
    assert min(residual) < np.median(residual)  # the choice matters on this machine
    with pytest.raises(ValueError, match="selection must be one of"):
        kept_patterns(m, 1, "largest")


def test_re_expressing_a_machine_on_its_own_support_changes_nothing():
    X, y = _data(classes=2, seed=1)
    m = TensorSVC(C=1.0, sigma=3.0, amplitude=4.0).fit(X, y)
    before = m.decision_function(X)
    order = np.random.default_rng(0).permutation(len(m.support_vectors_))
    project_machine(m, m.support_vectors_[order], m.sv_log_energy_[order])
    np.testing.assert_allclose(m.decision_function(X), before, atol=1e-8)


def test_one_vs_all_machines_share_one_table_of_kept_patterns():
    X, y = _data(n=90)
    ova = OneVsAllTouchClassifier(estimator=TensorSVC(C=10.0, sigma=4.0)).fit(X, y)
    total = n_distinct_support(ova)
    bounded = bound_support(ova, 12)
    assert n_distinct_support(bounded) == 12 < total
    table, _, where = distinct_support(bounded)
    assert len(table) == 12 and all(sorted(w) == list(range(12)) for w in where)
    # the budget keeps what decides: more agreement with the full model than a budget of 3
    full = ova.predict(X)
    agree = [np.mean(bound_support(ova, k).predict(X) == full) for k in (3, 12, total - 1)]
    assert agree[0] <= agree[1] <= agree[2] and agree[2] > 0.9


@pytest.mark.parametrize("bad, error", [(0, ValueError), (-4, ValueError), (2.5, TypeError),
                                        (True, TypeError), ("8", TypeError)])
def test_a_bad_budget_is_named(bad, error):
    X, y = _data(classes=2)
    m = TensorRLS(lam=1.0, sigma=2.0).fit(X, y)
    with pytest.raises(error, match="max_support"):
        bound_support(m, bad)


def test_fitted_on_patterns_the_decisions_are_the_least_squares_fit():
    """With X_fit, each machine's decision values on X_fit are the least-squares fit of the
    full machine's on the kept patterns: the normal equations hold."""
    X, y = _data(n=90, seed=5)
    ova = OneVsAllTouchClassifier(estimator=TensorSVC(C=10.0, sigma=4.0, amplitude=1.0)).fit(X, y)
    bounded = bound_support(ova, 10, X_fit=X)
    assert n_distinct_support(bounded) == 10
    assert np.array_equal(bounded.estimators_[0].support_vectors_,
                          bound_support(ova, 10).estimators_[0].support_vectors_)  # same S
    from eskin.learn.kernel import pattern_log_energy

    eX = pattern_log_energy(X)
    for full, m in zip(ova.estimators_, bounded.estimators_):
        A = _kernel(m, X, eX, m.support_vectors_, m.sv_log_energy_)
        r = A @ m.dual_coef_ - (full.decision_function(X) - full.intercept_)
        assert np.max(np.abs(A.T @ r)) < 1e-7 * max(1.0, np.max(np.abs(A.T @ A)))
        assert m.intercept_ == full.intercept_
    # closer to the full model's decisions on X than the projection (what it minimises)
    gap_fit = np.linalg.norm(bounded.decision_function(X) - ova.decision_function(X))
    gap_proj = np.linalg.norm(bound_support(ova, 10).decision_function(X)
                              - ova.decision_function(X))
    assert gap_fit <= gap_proj


def test_each_greedy_pick_removes_the_most_of_the_remaining_residual():
    """Matching pursuit step by step, against the definition: after the first t kept patterns,
    the next is the one whose addition leaves the smallest ||w - P_S w||^2 (one machine, so no
    weighting), computed by projecting onto every candidate set."""
    X, y = _data(n=36, classes=2, seed=6)
    m = TensorRLS(lam=0.1, sigma=3.0, amplitude=1.0).fit(X, y)
    table, energies, _ = distinct_support(m)
    chosen: list[int] = []
    for k in range(1, 5):
        best, best_residual = None, np.inf
        for i in range(len(table)):
            if i in chosen:
                continue
            trial = copy.deepcopy(m)
            rows = chosen + [i]
            project_machine(trial, table[rows], energies[rows])
            r = _rkhs_residual(m, trial)
            if r < best_residual - 1e-12:
                best, best_residual = i, r
        chosen.append(best)
        assert sorted(chosen) == list(kept_patterns(m, k))


def test_the_bytes_of_a_support_vector_are_its_float32_bases_at_the_largest_alphas():
    from eskin.learn.support_budget import MODEL_FIXED_BYTES, support_bytes, support_for_size

    X, y = _data()
    clf = OneVsAllTouchClassifier(TensorSVC(C=10.0, sigma=1.0, alpha="half")).fit(X, y)
    # 4 x 4 x 6: N = 24, 24, 16; alpha Q/2 = 2, 2, 3
    per = 4 * (24 * 2 + 24 * 2 + 16 * 3) + 4 * 3 + 8 + 8 * 3
    assert support_bytes(clf) == per
    assert support_for_size(clf, MODEL_FIXED_BYTES + 10 * per + per - 1) == 10
    assert support_for_size(clf, 1) == 1
    mixed = OneVsAllTouchClassifier(TensorSVC(C=10.0, sigma=1.0, alpha=1)).fit(X, y)
    mixed.estimators_[1] = clf.estimators_[1]  # one machine at alpha Q/2: its bases are stored
    assert support_bytes(mixed) == per
