"""The recipe search (eskin.learn.recipes): successive halving over recipes and settings,
scored by the multi-class error of participant-grouped splits; and `eskin train` choosing the
recipe on the user's campaign (every class by default, the choice printed and stored)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from learn_data import small_simulated
from typer.testing import CliRunner

from eskin.cli import app
from eskin.errors import ClassLeftOut, TrainingError
from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS, TensorSVC
from eskin.learn.kernel import resolve_alphas
from eskin.learn.models import load_model
from eskin.learn.training import train_model
from eskin.learn.training_set import preprocess_campaign
from eskin.learn.recipes import (
    CandidateBudget,
    Recipe,
    Candidate,
    RecipeSearch,
    budget_preference,
    corrected_paired_t,
    distance_memory,
    distance_scratch,
    one_vs_all_indices,
    recipe_preference,
    recipe_space,
)

runner = CliRunner()


@pytest.fixture(scope="module")
def sim_path(tmp_path_factory) -> Path:
    return small_simulated(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="module")
def data(sim_path):
    from eskin.data.campaign import load_campaign

    camp = load_campaign(sim_path, in_memory=True)
    idx = np.arange(len(camp))
    prep = preprocess_campaign(camp, idx, [(20, "algorithm2"), (20, "even"), (50, "algorithm2")])
    return prep.X, np.asarray(camp.modality).astype(np.int64), np.asarray(camp.participant)


def test_recipe_space_caps_D_by_the_longest_recording():
    recipes, notes = recipe_space(["svm"], [20, 50, 100], ["even"], ["all"], longest=40)
    assert [r.D for r in recipes] == [20, 40]
    assert len(notes) == 2 and "at most 40 samples" in notes[0]
    full, _ = recipe_space()
    assert len(full) == 24 and len(set(full)) == 24
    with pytest.raises(TrainingError, match="machine must be"):
        Recipe("knn", 20, "even", "all")


def test_recipe_space_caps_at_the_exact_length_and_never_below_2():
    """A D equal to the longest recording or to the windows' fill is kept, without a note; a
    cap below 2 gives D = 2 (a tensor needs two samples of time), the notes saying so."""
    recipes, notes = recipe_space(["svm"], [20, 50], ["even"], ["all"], longest=50, fill=20)
    assert [r.D for r in recipes] == [20] and notes == [
        "the median training touch window is 20 samples long: D = 20 instead of 50"]
    recipes, notes = recipe_space(["svm"], [20], ["even"], ["all"], longest=1)
    assert [r.D for r in recipes] == [2] and notes == [
        "the training recordings are at most 1 samples long: D = 2 instead of 20"]
    recipes, notes = recipe_space(["svm"], [20], ["even"], ["all"], fill=1)
    assert [r.D for r in recipes] == [2] and notes == [
        "the median training touch window is 1 samples long: D = 2 instead of 20"]
    recipes, notes = recipe_space(["svm"], [20, 50], ["even"], ["all"], longest=3, fill=1)
    assert [r.D for r in recipes] == [2] and notes == [
        "the training recordings are at most 3 samples long: D = 3 instead of 20",
        "the median training touch window is 1 samples long: D = 2 instead of 3",
        "the training recordings are at most 3 samples long: D = 3 instead of 50",
        "the median training touch window is 1 samples long: D = 2 instead of 3"]


def test_one_vs_all_indices_draw_balanced_negatives_only_where_there_are_more():
    """Each machine's indices: its class's patterns and, "balanced", as many distinct patterns
    of the other classes, drawn by numpy's generator of the seed in class order, by the machines
    whose other classes outnumber their own only (a tie draws nothing: every one is taken)."""
    y = np.array([0] * 5 + [1] * 10 + [2] * 3 + [3] * 2)  # 20: class 1 ties its others
    every = [np.arange(20)] * 4
    for got, want in zip(one_vs_all_indices(y, 4, "all", 7), every):
        np.testing.assert_array_equal(got, want)
    for seed in range(20):
        rng = np.random.default_rng(seed)
        for k, got in enumerate(one_vs_all_indices(y, 4, "balanced", seed)):
            pos, neg = np.flatnonzero(y == k), np.flatnonzero(y != k)
            if k != 1:
                neg = np.sort(rng.choice(neg, size=len(pos), replace=False))
            np.testing.assert_array_equal(got, np.union1d(pos, neg))
            assert len(np.unique(got)) == len(got) == 2 * len(pos)
    more = np.array([0] * 3 + [1] * 12)  # class 1 outnumbers the rest: all of them
    np.testing.assert_array_equal(one_vs_all_indices(more, 2, "balanced", 0)[1], np.arange(15))


def test_a_recipe_names_each_bad_field_and_takes_any_D_from_1():
    assert Recipe("rls", 1, "algorithm2", "balanced").D == 1
    for D in (0, -4):
        with pytest.raises(TrainingError) as bad:
            Recipe("svm", D, "even", "all")
        assert str(bad.value) == f"D must be >= 1, got {D}"
    with pytest.raises(TrainingError) as bad:
        Recipe("svm", 20, "odd", "all")
    assert str(bad.value) == "subsample must be one of ('algorithm2', 'even'), got 'odd'"
    with pytest.raises(TrainingError) as bad:
        Recipe("svm", 20, "even", "some")
    assert str(bad.value) == "negatives must be 'all' or 'balanced', got 'some'"


def test_recipe_space_caps_D_by_what_the_touch_windows_fill():
    recipes, notes = recipe_space(["svm"], [20, 50, 100], ["even"], ["all"], longest=40, fill=10)
    assert [r.D for r in recipes] == [10]
    assert any("median training touch window is 10 samples" in n for n in notes)
    recipes, _ = recipe_space(["svm"], [20, 50, 100], ["even"], ["all"], fill=60)
    assert [r.D for r in recipes] == [20, 50, 60]


def test_the_distances_within_a_memory_limit_are_those_without(data):
    X = data[0][(20, "algorithm2")]
    recipe = Recipe("svm", 20, "algorithm2", "all")
    free = RecipeSearch([recipe], [0.1], [1.0], ["Q"], [None], memory_limit=None)
    fixed, smallest = distance_memory(X.shape, resolve_alphas(X.shape[1:], "full"))
    tight = RecipeSearch([recipe], [0.1], [1.0], ["Q"], [None],
                         memory_limit=fixed + 2 * smallest)
    for a, b in zip(free._distances(X, "Q"), tight._distances(X, "Q")):
        np.testing.assert_array_equal(a, b)
    refused = RecipeSearch([recipe], [0.1], [1.0], ["Q"], [None],
                           memory_limit=fixed + smallest - 1)
    with pytest.raises(TrainingError, match=r"at D = 20, alpha Q need at least \d+ MiB, more "
                       r"than the memory limit .* raise --memory-limit"):
        refused._distances(X, "Q")


def test_a_candidate_over_the_budget_is_kept_bounded_to_at_least_half_its_support():
    """Under a budget with ``largest``, a candidate expected to need more support vectors than
    fit is kept, bounded to the most that fit, when those are at least half of what it needs
    (rounded up, and at least 1); else it does not fit."""
    from eskin.learn.recipes import _check_budget, _Row

    budget = CandidateBudget(fits=lambda c, n: n <= 10, largest=lambda c, n: min(n, 10))
    assert budget.keep_share == 0.5
    c = Candidate(Recipe("svm", 20, "even", "all"), 0.1, 1.0, "1", None)
    for expected, fits, bound in ((5, True, None), (10, True, None), (20, True, 10),
                                  (21, False, None)):
        row = _Row(c)
        _check_budget(budget, row, expected)
        assert (row.fits, row.bound) == (fits, bound), expected
    none_fit = CandidateBudget(fits=lambda c, n: n <= 0, largest=lambda c, n: 0)
    for expected in (1, 2):
        row = _Row(c)
        _check_budget(none_fit, row, expected)
        assert (row.fits, row.bound) == (False, None)
    strict = CandidateBudget(fits=lambda c, n: n <= 10, largest=lambda c, n: min(n, 10),
                             keep_share=0.9)
    for expected, fits in ((11, True), (12, False)):  # 10 of 11 is 0.91, 10 of 12 is 0.83
        row = _Row(c)
        _check_budget(strict, row, expected)
        assert row.fits == fits
    one = CandidateBudget(fits=lambda c, n: n <= 1, largest=lambda c, n: min(n, 1))
    row = _Row(c)
    _check_budget(one, row, 2)  # half of 2 is 1: kept with its one support vector
    assert (row.fits, row.bound) == (True, 1)
    never_none = CandidateBudget(fits=lambda c, n: n <= 0, largest=lambda c, n: 0, keep_share=0.0)
    row = _Row(c)
    _check_budget(never_none, row, 3)  # no share asks for none: a model keeps one at least
    assert (row.fits, row.bound) == (False, None)
    alone = CandidateBudget(fits=lambda c, n: n <= 10)  # no largest: fits as it is or not
    row = _Row(c)
    _check_budget(alone, row, 11)
    assert (row.fits, row.bound) == (False, None)


def test_the_second_round_keeps_the_third_of_lowest_error_on_the_first_split(data):
    """Successive halving's cut: the candidates scored on two splits are a third (rounded up)
    of those scored on the first, none of them worse on it than any candidate cut."""
    X, y, groups = data
    recipes = [Recipe("svm", 20, "algorithm2", "all"), Recipe("rls", 20, "even", "all")]
    grid = ([0.01, 0.1, 1.0, 10.0], [0.5, 2.0, 8.0], ["1", "Q/2"], [None])
    one = RecipeSearch(recipes, *grid, n_splits=1, first_share=1.0, significance=None,
                       seed=5).fit(X, y, groups)
    two = RecipeSearch(recipes, *grid, n_splits=2, first_share=1.0, significance=None,
                       seed=5).fit(X, y, groups)
    for a, b in zip(one.splits_[0], two.splits_[0]):
        np.testing.assert_array_equal(a, b)
    first = {e["candidate"]: e["split_errors"][0] for e in one.ranking_}
    kept = {e["candidate"] for e in two.ranking_}
    assert len(first) == 48 and len(kept) == 16 and kept < set(first)
    assert len({first[c] for c in first}) > 2  # the first split tells them apart
    assert max(first[c] for c in kept) <= min(first[c] for c in set(first) - kept)
    assert all(e["split_errors"][0] == first[e["candidate"]] for e in two.ranking_)


def test_the_search_is_seeded_with_0_by_default(data):
    X, y, groups = data
    args = ([Recipe("svm", 20, "algorithm2", "all")], [0.1, 1.0], [0.5, 2.0], ["Q/2"], [None])
    plain = RecipeSearch(*args, n_splits=2, first_share=1.0).fit(X, y, groups)
    zero = RecipeSearch(*args, n_splits=2, first_share=1.0, seed=0).fit(X, y, groups)
    one = RecipeSearch(*args, n_splits=2, first_share=1.0, seed=1).fit(X, y, groups)
    for (a, b), (c, d) in zip(plain.splits_, zero.splits_):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, d)
    assert plain.ranking_ == zero.ranking_
    assert any(not np.array_equal(a[1], c[1]) for a, c in zip(plain.splits_, one.splits_))


def test_the_search_refuses_settings_at_their_bounds_and_takes_a_first_share_of_1():
    r = [Recipe("svm", 20, "even", "all")]
    message = "n_splits must be >= 1, eta and growth >= 2 and first_share in (0, 1]"
    for bad in ({"first_share": 0.0}, {"first_share": -0.5}, {"first_share": 1.0000001},
                {"n_splits": 0}, {"eta": 1}, {"growth": 1}):
        with pytest.raises(TrainingError) as refused:
            RecipeSearch(r, [1.0], [1.0], ["1"], [None], **bad)
        assert str(refused.value) == message, bad
    for good in ({"first_share": 1.0}, {"first_share": 1e-6}, {"n_splits": 1}, {"eta": 2},
                 {"growth": 2}):
        RecipeSearch(r, [1.0], [1.0], ["1"], [None], **good)


def test_a_split_whose_training_part_lacks_a_class_is_refused(data):
    """Class 2 recorded by one participant only: a grouped split holding that participant out
    trains on two classes, which the search refuses (eskin train then splits by class)."""
    X, y, groups = data
    g = groups.copy()
    g[y == 2] = g[np.flatnonzero(y == 2)[0]]
    search = RecipeSearch([Recipe("svm", 20, "even", "all")], [0.1], [1.0], ["Q"], [None],
                          n_splits=6, test_size=0.5, first_share=1.0, seed=1)
    with pytest.raises(ClassLeftOut) as refused:
        search.fit(X, y, g)
    assert str(refused.value) == (
        "cross-validation split 1 left class 2 out of its training part; use more groups, "
        "a smaller test_size or another random_state")
    assert len(search.fit(X, y, None).splits_) == 6  # stratified by class instead: all fine


def test_a_round_of_two_or_three_keeps_one_and_of_four_keeps_two():
    """The best ceil(n / eta) of n ranked candidates (eta 3), at least one."""
    r = Recipe("svm", 20, "even", "all")
    ranked = [Candidate(r, la, 1.0, "1", None) for la in (1.0, 2.0, 3.0, 4.0)]
    s = RecipeSearch([r], [1.0], [1.0], ["1"], [None], eta=3, significance=None)
    assert [s._survivors(ranked[:n]) for n in (1, 2, 3, 4)] == [
        ranked[:1], ranked[:1], ranked[:1], ranked[:2]]
    # beside them, the best ceil(m / eta) of the preferred recipe's own m, at least one
    pref = Recipe("svm", 50, "algorithm2", "all")
    own = [Candidate(pref, la, 1.0, "1", None) for la in (1.0, 2.0, 3.0, 4.0)]
    s = RecipeSearch([r, pref], [1.0], [1.0], ["1"], [None], eta=3)
    for m, best, kept in ((1, 2, 1), (2, 2, 1), (3, 3, 1), (4, 3, 2)):  # best: of 4 + m
        assert s._survivors(ranked + own[:m]) == ranked[:best] + own[:kept], m


def test_the_search_times_itself(data):
    import time

    X, y, groups = data
    t0 = time.perf_counter()
    s = RecipeSearch([Recipe("svm", 20, "even", "all")], [0.1], [1.0], ["Q"], [None],
                     n_splits=2, first_share=1.0).fit(X, y, groups)
    assert 0 < s.seconds_ <= time.perf_counter() - t0


def test_the_paired_test_needs_two_splits(data):
    """With a significance level the choice is the paired test's from two splits on; on one
    split there is no test (no record): the lowest error's recipe."""
    X, y, groups = data
    recipes = [Recipe("svm", 20, "algorithm2", "all"), Recipe("rls", 20, "even", "all")]
    for n_splits, tested in ((1, False), (2, True)):
        s = RecipeSearch(recipes, [0.1], [1.0], ["Q/2"], [None], n_splits=n_splits,
                         first_share=1.0, seed=3).fit(X, y, groups)
        assert (s.preference_ is not None) is tested, n_splits


def test_a_recipe_given_twice_is_searched_once():
    a, b = Recipe("svm", 20, "even", "all"), Recipe("rls", 20, "even", "all")
    search = RecipeSearch([a, b, Recipe("svm", 20, "even", "all")], [0.1], [1.0], ["Q"], [None])
    assert search.recipes == [a, b] and search.recipes[0] is a
    assert len(search._first_candidates()) == 2


def test_the_search_needs_every_class_index_of_two_or_more_classes(data):
    X, y, groups = data
    search = RecipeSearch([Recipe("svm", 20, "even", "all")], [0.1], [1.0], ["Q"], [None])
    for bad, got in ((np.zeros_like(y), "[0]"), (np.where(y == 1, 2, y), "[0, 2]"),
                     (y[:0], "[]")):
        with pytest.raises(TrainingError) as refused:
            search.fit({(20, "even"): X[(20, "even")][: len(bad)]}, bad, groups[: len(bad)])
        assert str(refused.value) == ("y must hold the class indices 0..k-1 of k >= 2 classes, "
                                      f"each at least once: got {got}")


@pytest.mark.parametrize("machine,negatives,sigma", [
    ("svm", "all", 1.0), ("svm", "balanced", 1.0), ("rls", "all", 1.0), ("rls", "balanced", 1.0),
    # near the collapse: a held-out pattern's largest kernel sum (the reach) times C is above
    # the collapse tolerance, so the machines are fitted (and none collapses), though the
    # reach divided by C is below it
    ("svm", "all", 0.9)])
def test_split_scores_are_those_of_the_one_vs_all_classifier(data, machine, negatives, sigma):
    """The search's error of a candidate on each split is the error of the shipped
    OneVsAllTouchClassifier trained on that split's training part (the same machines and
    negatives), predicting the split's held-out participants."""
    X, y, groups = data
    recipe = Recipe(machine, 20, "algorithm2", negatives)
    Xr = X[(20, "algorithm2")]
    search0 = RecipeSearch([recipe], [0.1], [sigma], ["Q/2"], [None], n_splits=2,
                           first_share=1.0, seed=4).fit(X, y, groups)
    assert search0.collapsed_ == []
    est0 = (TensorSVC(C=10.0, sigma=sigma, alpha="half") if machine == "svm"
            else TensorRLS(lam=0.1, sigma=sigma, alpha="half"))
    err = []
    for s, (tr, te) in enumerate(search0.splits_):
        ix = [np.intersect1d(tr, m) for m in one_vs_all_indices(y, 3, negatives, 4)]
        sub = np.unique(np.concatenate(ix))
        pos = {int(i): j for j, i in enumerate(sub)}
        local = [np.array([pos[int(i)] for i in m]) for m in ix]
        ova0 = OneVsAllTouchClassifier(est0).fit(Xr[sub], y[sub], machine_indices=local)
        err.append(np.mean(ova0.predict(Xr[te]) != y[te]))
    entry = search0.ranking_[0]
    assert entry["splits"] == 2
    assert entry["error"] == pytest.approx(np.mean(err), abs=1e-12)


@pytest.mark.parametrize("negatives", ["all", "balanced"])
def test_every_C_of_the_grid_is_scored_as_a_machine_fitted_at_that_C(data, negatives):
    """sigma 2, C = 1/lambda from 0.1 (coefficients at their bound) to 100: each candidate's error is
    that of the one-vs-all classifier fitted at its own C, though the search reuses a machine
    none of whose coefficients reached its bound for the larger C's."""
    X, y, groups = data
    Xr = X[(20, "algorithm2")]
    lams = [10.0, 1.0, 0.1, 0.01]
    search = RecipeSearch([Recipe("svm", 20, "algorithm2", negatives)], lams, [2.0], ["Q/2"],
                          [None], n_splits=1, first_share=1.0, significance=None,
                          seed=4).fit(X, y, groups)
    [(tr, te)] = search.splits_
    ix = [np.intersect1d(tr, m) for m in one_vs_all_indices(y, 3, negatives, 4)]
    sub = np.unique(np.concatenate(ix))
    pos = {int(i): j for j, i in enumerate(sub)}
    local = [np.array([pos[int(i)] for i in m]) for m in ix]
    got = {e["candidate"].lam: e["error"] for e in search.ranking_}
    want, bounded = {}, []
    for lam in lams:
        ova = OneVsAllTouchClassifier(TensorSVC(C=1.0 / lam, sigma=2.0, alpha="half")).fit(
            Xr[sub], y[sub], machine_indices=local)
        want[lam] = np.mean(ova.predict(Xr[te]) != y[te])
        bounded.append(any(np.max(np.abs(e.dual_coef_)) >= 1.0 / lam * (1 - 1e-9)
                           for e in ova.estimators_))
    assert bounded[0] and not bounded[-1] and len(set(want.values())) > 1
    assert got == pytest.approx(want, abs=1e-12)


@pytest.mark.parametrize("machine,negatives", [("svm", "all"), ("rls", "all"),
                                               ("rls", "balanced")])
def test_two_class_split_scores_are_those_of_one_machine_on_the_sign(data, machine, negatives):
    """Two classes: the search's error on each split is that of one machine trained on every
    training pattern, +1 for class 1, predicting class 1 where its decision value is above 0."""
    X, y, groups = data
    keep = np.flatnonzero(y < 2)
    Xr, y2, g2 = X[(20, "algorithm2")][keep], y[keep], groups[keep]
    search = RecipeSearch([Recipe(machine, 20, "algorithm2", negatives)], [0.1], [1.0],
                          ["Q/2"], [None], n_splits=2, first_share=1.0, seed=4).fit(
        {(20, "algorithm2"): Xr}, y2, g2)
    err, at = [], {-1: [], 1: []}  # the errors at 0 and, to show they differ, at -1 and +1
    for tr, te in search.splits_:
        est = (TensorSVC(C=10.0, sigma=1.0, alpha="half") if machine == "svm"
               else TensorRLS(lam=0.1, sigma=1.0, alpha="half"))
        f = est.fit(Xr[tr], np.where(y2[tr] == 1, 1, -1)).decision_function(Xr[te])
        err.append(np.mean((f > 0).astype(int) != y2[te]))
        for t in at:
            at[t].append(np.mean((f > t).astype(int) != y2[te]))
    assert np.mean(at[-1]) != np.mean(err) != np.mean(at[1])
    assert search.ranking_[0]["error"] == pytest.approx(np.mean(err), abs=1e-12)


def test_successive_halving_keeps_a_third_per_round_on_twice_the_splits(data):
    X, y, groups = data
    recipes = [Recipe(m, 20, s, "all") for m in ("svm", "rls") for s in ("algorithm2", "even")]
    lams, sigmas = [0.01, 0.1, 1.0, 10.0], [0.5, 1.0, 2.0, 4.0]
    search = RecipeSearch(recipes, lams, sigmas, ["1", "Q/2"], [None, 1.0], n_splits=9,
                          first_share=0.5, significance=None, seed=1).fit(X, y, groups)
    # 4 recipes x 32 of the 64 settings; each round keeps ceil(1/3) and doubles the splits,
    # the last one all 9 (instead of 8)
    assert [r["candidates"] for r in search.rounds_] == [128, 43, 15, 5]
    assert [r["splits"] for r in search.rounds_] == [1, 2, 4, 9]
    assert search.n_evaluations_ == 128 * 1 + 43 * 1 + 15 * 2 + 5 * 5
    first = search._first_candidates()
    assert len({(c.lam, c.sigma, c.alpha, c.amplitude) for c in first}) == 32
    assert all(sum(c.recipe == r for c in first) == 32 for r in recipes)
    assert search.ranking_[0]["splits"] == 9
    # growth = eta: the splits tripled as the candidates are cut to a third
    tripled = RecipeSearch(recipes, lams, sigmas, ["1", "Q/2"], [None, 1.0], n_splits=9,
                           growth=3, first_share=0.5, significance=None, seed=1)
    assert tripled._schedule() == [1, 3, 9]
    # by default (docs/learning.md): one split, two, four, then all ten
    assert RecipeSearch(recipes, [1.0], [1.0], ["1"], [None])._schedule() == [1, 2, 4, 10]
    with pytest.raises(TrainingError, match="growth >= 2"):
        RecipeSearch(recipes, [1.0], [1.0], ["1"], [None], growth=1)
    # the choice is within one held-out pattern (over all splits) of the best final error
    best = min(e["error"] for e in search.ranking_)
    assert search.best_error_ <= best + search.tolerance_ + 1e-12
    # deterministic: the same seed gives the same choice and figures
    again = RecipeSearch(recipes, lams, sigmas, ["1", "Q/2"], [None, 1.0], n_splits=9,
                         first_share=0.5, significance=None, seed=1).fit(X, y, groups)
    assert again.best_ == search.best_ and again.report()["recipes"] == search.report()["recipes"]


def test_recipe_preference_puts_the_larger_D_and_the_former_default_first():
    recipes, _ = recipe_space()
    order = sorted(recipes, key=recipe_preference)
    assert order[0] == Recipe("svm", 100, "algorithm2", "all")
    assert order[1] == Recipe("svm", 100, "algorithm2", "balanced")
    assert order[2] == Recipe("svm", 100, "even", "all")
    assert order[4] == Recipe("rls", 100, "algorithm2", "all")
    assert [r.D for r in order] == [100] * 8 + [50] * 8 + [20] * 8


def test_corrected_paired_t_by_hand():
    """Nadeau and Bengio's corrected resampled t: the splits' variance times (1/J +
    n_test/n_train), J - 1 degrees of freedom; more conservative than the naive paired t."""
    from scipy.stats import t as student_t

    d = [0.1, 0.0, 0.2, 0.1]
    var = (0.0 + 0.01 + 0.01 + 0.0) / 3
    t_hand = 0.1 / np.sqrt((1 / 4 + 0.3 / 0.7) * var)
    t, p = corrected_paired_t(d, 0.3)
    assert t == pytest.approx(t_hand, rel=1e-12)
    assert p == pytest.approx(student_t.sf(t_hand, 3), rel=1e-12)
    naive = 0.1 / np.sqrt(var / 4)
    assert t < naive
    # the sign of the mean is the direction of the one-sided test
    t_neg, p_neg = corrected_paired_t([-x for x in d], 0.3)
    assert t_neg == pytest.approx(-t_hand) and p_neg == pytest.approx(1 - p, rel=1e-12)
    assert corrected_paired_t([0.05] * 5, 0.3) == (np.inf, 0.0)
    assert corrected_paired_t([-0.05] * 5, 0.3) == (-np.inf, 1.0)  # a constant loss
    assert corrected_paired_t([0.0] * 5, 0.3) == (0.0, 0.5)
    with pytest.raises(TrainingError, match="at least two splits"):
        corrected_paired_t([0.1], 0.3)


def test_the_preferred_recipe_survives_every_round():
    """Each round keeps the best third and, beside it, the best third of the most preferred
    recipe's own candidates."""
    pref, other = Recipe("svm", 50, "algorithm2", "all"), Recipe("rls", 20, "even", "all")
    ranked = ([Candidate(other, la, 1.0, "1", None) for la in (1, 2, 3, 4, 5, 6, 7, 8)]
              + [Candidate(pref, la, 1.0, "1", None) for la in (1, 2, 3, 4)])
    s = RecipeSearch([pref, other], [1.0], [1.0], ["1"], [None], eta=3)
    kept = s._survivors(ranked)
    assert kept == ranked[:4] + ranked[8:10]
    plain = RecipeSearch([pref, other], [1.0], [1.0], ["1"], [None], eta=3, significance=None)
    assert plain._survivors(ranked) == ranked[:4]


def test_under_a_budget_that_trades_D_the_familys_best_recipe_gets_the_whole_grid():
    """Under a budget that trades D the most preferred family (machine, subsampling,
    negatives) holds a recipe per D: the one with the lowest error on the sample gets the
    whole grid, not all of them; without a budget the most preferred recipe does."""
    from eskin.learn.recipes import _Row, _whole_grid

    d100, d20 = Recipe("svm", 100, "algorithm2", "all"), Recipe("svm", 20, "algorithm2", "all")
    other = Recipe("rls", 20, "even", "all")
    rows = {}
    for rec, err in ((d100, 0.3), (d20, 0.2), (other, 0.1)):
        c = Candidate(rec, 0.1, 1.0, "1", None)
        rows[c] = _Row(c, errors={0: err})
    grid = ([0.1, 1.0], [1.0], ["1"], [None])
    anything = CandidateBudget(lambda c, n: True, "anything")
    for search, whole in ((RecipeSearch([d100, d20, other], *grid, budget=anything), d20),
                          (RecipeSearch([d100, d20, other], *grid), d100)):
        assert _whole_grid(search.grid, search._preference_key(), list(rows), rows,
                           search._key) == [Candidate(whole, 1.0, 1.0, "1", None)]


def test_the_most_preferred_recipe_is_scored_on_the_whole_grid(data):
    """The first round samples the grid for every recipe but the most preferred one, which is
    scored on every setting (32 here; the sample of a 32-setting grid is 24)."""
    X, y, groups = data
    recipes = [Recipe("svm", 20, "algorithm2", "all"), Recipe("rls", 20, "even", "all")]
    grid = ([0.01, 0.1, 1.0, 10.0], [0.5, 1.0, 2.0, 4.0], ["1", "Q/2"], [None])
    s = RecipeSearch(recipes, *grid, n_splits=3, first_share=0.25, seed=2).fit(X, y, groups)
    assert s.rounds_[0]["candidates"] == 24 + 32
    plain = RecipeSearch(recipes, *grid, n_splits=3, first_share=0.25, significance=None,
                         seed=2).fit(X, y, groups)
    assert plain.rounds_[0]["candidates"] == 24 + 24
    assert s.n_evaluations_ > plain.n_evaluations_


@pytest.mark.parametrize("significance", [0.05, 0.5, 0.999])
def test_the_choice_is_the_most_preferred_recipe_not_significantly_worse(data, significance):
    """Recomputed from the final round's split errors: every more preferred recipe's best
    candidate is significantly worse than the lowest error; the chosen recipe's is not."""
    X, y, groups = data
    recipes = [Recipe("svm", 20, "algorithm2", "balanced"),
               Recipe("rls", 20, "algorithm2", "all"), Recipe("rls", 20, "even", "balanced")]
    s = RecipeSearch(recipes, [0.01, 1.0], [0.5, 2.0], ["1", "Q/2"], [None], n_splits=6,
                     first_share=1.0, significance=significance, seed=3).fit(X, y, groups)
    final = sorted(s.ranking_, key=lambda e: e["error"])
    lowest = final[0]
    share = np.mean([len(te) / (len(tr) + len(te)) for tr, te in s.splits_])

    def worse(recipe):
        own = min((e for e in final if e["candidate"].recipe == recipe),
                  key=lambda e: e["error"])
        diffs = np.subtract(own["split_errors"], lowest["split_errors"])
        if diffs.mean() <= s.tolerance_ + 1e-12:
            return False
        return corrected_paired_t(diffs, share)[1] < significance

    chosen = s.best_.recipe
    assert not worse(chosen)
    present = {e["candidate"].recipe for e in final}
    assert all(worse(r) for r in present if recipe_preference(r) < recipe_preference(chosen))
    assert s.report()["preference"]["recipe"] == chosen.label()
    # on these data the lowest error is tensor-RLS with every negative, 6.9 points under the
    # preferred recipe's best (tensor-SVM, balanced negatives) with p = 0.21: kept at the 5 %
    # level, not at 50 % or 99.9 %
    assert lowest["candidate"].recipe == recipes[1]
    assert chosen == (recipes[0] if significance == 0.05 else recipes[1])
    # no preference: the lowest error (up to one held-out pattern) wins
    plain = RecipeSearch(recipes, [0.01, 1.0], [0.5, 2.0], ["1", "Q/2"], [None], n_splits=6,
                         first_share=1.0, significance=None, seed=3).fit(X, y, groups)
    assert plain.best_error_ <= min(e["error"] for e in plain.ranking_) + plain.tolerance_ + 1e-12
    assert plain.report()["preference"] is None


def test_a_budget_removes_what_does_not_fit(data):
    X, y, groups = data
    recipes = [Recipe("svm", 20, "algorithm2", "all"), Recipe("svm", 50, "algorithm2", "all")]
    only20 = CandidateBudget(lambda c, n: c.recipe.D == 20 and n < 10_000, "D 20 only")
    s = RecipeSearch(recipes, [1.0], [1.0, 2.0], ["1"], [None], n_splits=3, first_share=1.0,
                     budget=only20).fit(X, y, groups)
    assert s.best_.recipe.D == 20
    assert all(e["candidate"].recipe.D == 20 for e in s.ranking_ + s.recipe_table_)
    assert s.report()["budget"] == "D 20 only"
    nothing = CandidateBudget(lambda c, n: False, "nothing")
    with pytest.raises(TrainingError, match="no candidate fits the budget"):
        RecipeSearch(recipes, [1.0], [1.0], ["1"], [None], n_splits=2,
                     budget=nothing).fit(X, y, groups)


def test_a_budget_keeps_a_candidate_bounded_to_what_fits(data, sim_path):
    """With ``largest``, a candidate expected to need more support vectors than fit is kept,
    bounded to the most that fit, when that keeps at least ``keep_share`` of them; the model
    train_model fits is bounded to it."""
    X, y, groups = data
    recipes = [Recipe("svm", 20, "algorithm2", "all")]
    grid = ([1.0], [1.0, 2.0], ["1"], [None])

    def fits(c, n):
        return n <= 5

    def largest(c, n):
        return min(int(n), 5)

    plain = RecipeSearch(recipes, *grid, n_splits=3, first_share=1.0).fit(X, y, groups)
    expected = plain.ranking_[0]["support_vectors"]
    assert expected > 10  # so that the bound below is a real cut
    s = RecipeSearch(recipes, *grid, n_splits=3, first_share=1.0,
                     budget=CandidateBudget(fits, "5 support vectors", largest=largest,
                                            keep_share=0.0)).fit(X, y, groups)
    assert s.best_bound_ == 5 and s.report()["chosen"]["support_bound"] == 5
    assert s.best_error_ == plain.best_error_  # the estimate is the unbounded candidate's
    strict = CandidateBudget(fits, "5 support vectors", largest=largest, keep_share=0.5)
    with pytest.raises(TrainingError, match="no candidate fits the budget"):
        RecipeSearch(recipes, *grid, n_splits=3, first_share=1.0, budget=strict).fit(X, y, groups)
    none = CandidateBudget(lambda c, n: False, "nothing", largest=lambda c, n: 0, keep_share=0.0)
    with pytest.raises(TrainingError, match="no candidate fits the budget"):
        RecipeSearch(recipes, *grid, n_splits=3, first_share=1.0, budget=none).fit(X, y, groups)
    m = train_model(sim_path, machine="svm", D=20, subsample="algorithm2", quick=True, seed=2,
                    budget=CandidateBudget(fits, "5", largest=largest,
                                                               keep_share=0.0))
    sb = m.training["support_budget"]
    assert sb["by"] == "budget" and sb["max_support"] == 5 and sb["support_vectors"] <= 5
    assert sb["support_vectors_before"] > 5


def test_under_a_budget_the_preference_leaves_D_out(data):
    """The order under a budget is the order without one, D left out: the recipes of one
    machine, subsampling and negatives are one family, and the family's lowest-error
    candidate stands for it (here the family is the only one, so it is the lowest error)."""
    X, y, groups = data
    for r in recipe_space()[0]:
        assert budget_preference(r) == recipe_preference(r)[1:]
    recipes = [Recipe("svm", 20, "algorithm2", "all"), Recipe("svm", 50, "algorithm2", "all")]
    grid = ([0.01, 1.0], [0.5, 2.0], ["1", "Q/2"], [None])
    anything = CandidateBudget(lambda c, n: True, "anything")
    s = RecipeSearch(recipes, *grid, n_splits=6, first_share=1.0, seed=3,
                     budget=anything).fit(X, y, groups)
    free = RecipeSearch(recipes, *grid, n_splits=6, first_share=1.0, seed=3).fit(X, y, groups)
    lowest = min(e["error"] for e in s.ranking_)
    assert s.best_error_ <= lowest + s.tolerance_ + 1e-12
    assert s.report()["preference"]["within_one_pattern"] is True
    # within one held-out pattern no test is made: t = 0 and p = 1 are the record's
    assert (s.report()["preference"]["t"], s.report()["preference"]["p"]) == (0.0, 1.0)
    # without the budget the larger D is kept unless significantly worse
    assert free.best_.recipe.D == 50


def test_the_family_stands_for_its_recipes_under_a_budget():
    """Split errors where the larger D of the preferred family is 10 points worse than its
    smaller D and everything is noisy (nothing significant): without a budget the choice is the
    larger D, under one (budget_preference) the family's best, the smaller D."""
    from eskin.learn.recipes import _preferred_recipe, _Row

    rng = np.random.default_rng(0)
    cands = {
        "svm50": (Candidate(Recipe("svm", 50, "algorithm2", "all"), 0.1, 1.0, "1", None), 0.30),
        "svm20": (Candidate(Recipe("svm", 20, "algorithm2", "all"), 0.1, 1.0, "Q", None), 0.20),
        "rls50": (Candidate(Recipe("rls", 50, "even", "all"), 0.1, 1.0, "Q", None), 0.19),
    }
    rows = {}
    for c, mean in cands.values():
        noise = rng.normal(0, 0.15, 10)
        rows[c] = _Row(c, errors={s: mean - noise.mean() + noise[s] for s in range(10)})
    final = sorted(rows, key=lambda c: rows[c].mean)
    splits = [(np.arange(7), np.arange(7, 10))] * 10
    plain, _ = _preferred_recipe(rows, final, splits, 1e-3, 0.05)
    under, rec = _preferred_recipe(rows, final, splits, 1e-3, 0.05, key=budget_preference)
    assert plain == cands["svm50"][0].recipe
    assert under == cands["svm20"][0].recipe and rec["lowest"] == "rls D=50 even negatives=all"
    anything = CandidateBudget(lambda c, n: True, "anything")
    assert RecipeSearch([c.recipe for c, _ in cands.values()], [1.0], [1.0], ["1"], [None],
                        budget=anything)._preference_key() is budget_preference
    assert RecipeSearch([c.recipe for c, _ in cands.values()], [1.0], [1.0], ["1"],
                        [None])._preference_key() is recipe_preference


def test_train_model_searches_unset_parts_and_stores_the_choice(sim_path):
    m = train_model(sim_path, D=20, quick=True, seed=2)
    rs = m.training["recipe_search"]
    assert m.training["searched"] == ["machine", "subsample", "negatives"]
    assert (rs["chosen"]["machine"], rs["chosen"]["D"], rs["chosen"]["subsample"],
            rs["chosen"]["negatives"]) == (m.machine, m.D, m.subsample, m.training["negatives"])
    assert all(r["D"] == 20 for r in rs["recipes"])
    assert {c["class"] for c in m.selected} == set(m.classes) == {"brush", "finger", "washer"}
    assert m.selected[0]["selection_terms"]["mean_test_error"] == pytest.approx(
        rs["chosen"]["cv_error"], abs=1e-6)
    fixed = train_model(sim_path, machine="svm", D=20, subsample="algorithm2", negatives="all",
                        quick=True)
    assert "recipe_search" not in fixed.training


def test_the_search_on_a_local_pool_matches_the_serial_run(sim_path):
    """Two joblib (loky) worker processes: the same candidates scored, the same recipe chosen,
    the same machines and decision values."""
    kw = {"D": 20, "quick": True, "seed": 3}
    serial = train_model(sim_path, n_jobs=1, **kw)
    pooled = train_model(sim_path, n_jobs=2, **kw)
    a, b = serial.training["recipe_search"], pooled.training["recipe_search"]
    a.pop("seconds"), b.pop("seconds")
    assert a == b and a["evaluations"] > 0
    assert serial.selected == pooled.selected
    from eskin.data.campaign import load_campaign

    X = serial.preprocess(load_campaign(sim_path, in_memory=True))
    np.testing.assert_array_equal(serial.decision_function(X), pooled.decision_function(X))


def test_the_default_memory_limit_is_half_a_gib_on_the_command_line_and_in_the_search():
    """--memory-limit's default (GiB, on eskin train and eskin evaluate) is the search's own
    default, 0.5 GiB as docs/learning.md states: a model trained with it records no memory
    option; any other value is recorded in bytes."""
    import inspect

    from eskin.cli.evaluate import evaluate
    from eskin.cli.learn import memory_options, train
    from eskin.learn.recipes import DEFAULT_MEMORY_LIMIT

    for command in (train, evaluate):
        assert inspect.signature(command).parameters["memory_limit"].default.default == 0.5
    assert DEFAULT_MEMORY_LIMIT == 2**29
    assert memory_options(0.5) == {}
    assert memory_options(0.25) == {"memory_limit": 2**28}
    assert "default 0.5 GiB" in (Path(__file__).parents[3] / "docs" / "learning.md").read_text()


def test_the_search_is_under_the_host_budget_by_default(sim_path):
    """By default the search runs under the host budget of HOST_DECISION_US (its description
    in the report, the same as eskin train's default); decision_us=None lifts it; a budget too
    small for any support vector fails with the budget named."""
    from eskin.cli.learn import DECISION_US_DEFAULT
    from eskin.learn.host_budget import HOST_DECISION_US

    assert DECISION_US_DEFAULT == HOST_DECISION_US == 80.0
    m = train_model(sim_path, D=20, quick=True, seed=2)
    assert m.training["recipe_search"]["budget"] == (
        "host: support vectors' share of a decision at most 80 us, or 2 times the input's bases "
        "where those take more (estimated)")
    wide = train_model(sim_path, D=20, quick=True, seed=2, decision_us=100)
    assert wide.training["recipe_search"]["budget"].startswith(
        "host: support vectors' share of a decision at most 100 us")
    free = train_model(sim_path, D=20, quick=True, seed=2, decision_us=None)
    assert free.training["recipe_search"]["budget"] is None
    with pytest.raises(TrainingError, match="no candidate fits the budget .host: support "
                                            "vectors' share of a decision at most 0.001 us"):
        train_model(sim_path, D=20, quick=True, seed=2, decision_us=0.001)


def test_cli_train_takes_every_class_and_prints_the_choice(sim_path, tmp_path):
    out = tmp_path / "m.joblib"
    r = runner.invoke(app, ["train", str(sim_path), "--quick", "--D", "20", "-o", str(out),
                            "--no-progress"])
    assert r.exit_code == 0, r.output
    m = load_model(out)
    assert m.classes == ["brush", "finger", "washer"]
    assert "recipe chosen on this campaign" in r.output and "runners-up" in r.output
    assert "inner-CV error" in r.output and "bytes as .eskin float32" in r.output
    both = runner.invoke(app, ["train", str(sim_path), "--classes", "brush,washer",
                               "--all-classes", "-o", str(tmp_path / "x.joblib")])
    assert both.exit_code == 2 and "not both" in both.output


def test_cli_train_under_a_budget(sim_path, tmp_path):
    from eskin.deploy.target import INSTRUCTION_MARGIN, model_fits, parse_budget

    out = tmp_path / "m.eskin"
    r = runner.invoke(app, ["train", str(sim_path), "--quick", "--target", "cortex-m4",
                            "--budget", "instr=0.9M", "-o", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "on cortex-m4" in r.output and "DOES NOT FIT" not in r.output
    fits, fig = model_fits(out.read_bytes(), parse_budget("instr=0.9M", "cortex-m4"))
    assert fits and fig["instructions"] <= 0.9e6 and fig["ram"] <= 131072
    bad = runner.invoke(app, ["train", str(sim_path), "--budget", "ram=lots", "-o",
                              str(tmp_path / "y.eskin")])
    assert bad.exit_code == 2 and "ram=lots" in bad.output and "Traceback" not in bad.output
    # D = 50 with about 36 support vectors needs more than 0.78 M instructions: with a budget of
    # 0.82 M estimated instructions (times the cost model's margin) it is bounded to fit
    tight = tmp_path / "tight.eskin"
    instr = f"instr={0.82 * (1 + INSTRUCTION_MARGIN):.4f}M"
    r = runner.invoke(app, ["train", str(sim_path), "--quick", "--D", "50", "--target",
                            "cortex-m4", "--budget", instr, "-o", str(tight), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "to fit the budget:" in r.output and "--max-support" not in r.output
    fits, fig = model_fits(tight.read_bytes(), parse_budget(instr, "cortex-m4"))
    assert fits and fig["estimate"] <= 0.82e6
    assert fig["estimate"] * (1 + INSTRUCTION_MARGIN) == pytest.approx(fig["instructions"])


def test_evaluate_searches_in_every_fold_and_under_the_budget_in_the_same_folds(sim_path,
                                                                               tmp_path):
    import json

    r = runner.invoke(app, ["evaluate", str(sim_path), "--out", str(tmp_path), "--folds", "2",
                            "--quick", "--D", "20", "--classes", "brush,washer",
                            "--target", "cortex-m4"])
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "evaluation.json").read_text())
    # nested: each fold ran its own search on its training participants only
    for fold in res["folds"]:
        assert set(fold["trained_with"]) >= {"machine", "subsample", "negatives"}
        assert not set(fold["train_groups"]) & set(fold["test_groups"])
    under = res["under_budget"]
    assert [f["fold"] for f in under["per_fold"]] == [f["fold"] for f in res["folds"]]
    assert under["recipe"]["budget"].startswith("cortex-m4")
    assert 0.0 <= under["accuracy"] <= 1.0
    assert "under the budget (cortex-m4" in r.output and "in the same folds" in r.output


def test_cli_train_says_when_the_preference_kept_a_recipe_with_a_higher_error(sim_path, tmp_path):
    """Without the host budget (the preference then keeps the larger D), with seed 1 the
    lowest inner-CV error on this campaign is another recipe's, less than one held-out pattern
    lower: train keeps the preferred recipe and says so; with seed 0 the lowest error is tied
    with the preferred recipe's and nothing is said."""
    out = tmp_path / "m.joblib"
    r = runner.invoke(app, ["train", str(sim_path), "--quick", "--seed", "1", "-o", str(out),
                            "--no-progress", "--decision-us", "0"])
    assert r.exit_code == 0, r.output
    pref = load_model(out).training["recipe_search"]["preference"]
    assert pref["recipe"] != pref["lowest"] and pref["gap"] > 0 and pref["within_one_pattern"]
    assert (f"kept the preferred recipe: {pref['lowest']} scored {100 * pref['gap']:.1f} points "
            "lower on the inner splits, less than one held-out pattern") in r.output
    r0 = runner.invoke(app, ["train", str(sim_path), "--quick", "--seed", "0", "-o",
                             str(tmp_path / "m0.joblib"), "--no-progress", "--decision-us", "0"])
    assert r0.exit_code == 0, r0.output
    assert load_model(tmp_path / "m0.joblib").training["recipe_search"]["preference"]["gap"] == 0
    assert "kept the preferred recipe" not in r0.output


@pytest.mark.parametrize("level", [0, 1, 1.5, -0.1])
def test_a_significance_outside_zero_one_is_refused(level):
    with pytest.raises(TrainingError, match=f"significance must be in \\(0, 1\\) or None, got {level}"):
        RecipeSearch([Recipe("svm", 20, "even", "all")], [1.0], [1.0], ["1"], [None],
                     significance=level)


def test_collapsed_means_some_machine_held_out_values_sit_at_its_intercept():
    from eskin.learn.recipes import COLLAPSE_TOLERANCE, collapsed

    rng = np.random.default_rng(0)
    b = np.array([-0.8, -1.0, 0.0])
    spread = b + rng.normal(0, 0.5, (20, 3))
    assert not collapsed(spread, b)
    flat = spread.copy()
    flat[:, 1] = b[1] + rng.uniform(-0.5, 0.5, 20) * COLLAPSE_TOLERANCE
    assert collapsed(flat, b)
    assert not collapsed(np.zeros((0, 3)), b)


def test_a_candidate_whose_kernel_collapsed_is_counted_against_and_said(data):
    """sigma = 0.001 makes every held-out kernel value ~0: each machine then answers its
    intercept for every held-out pattern, and the argmax would decide by noise. Such candidates
    score error 1.0 on those splits, the search says so, and a working sigma wins."""
    X, y, groups = data
    recipes = [Recipe("svm", 20, "algorithm2", "all"), Recipe("rls", 20, "algorithm2", "all")]
    search = RecipeSearch(recipes, [0.1], [0.001, 1.0], ["Q/2"], [None], n_splits=3,
                          first_share=1.0, significance=None, seed=2).fit(X, y, groups)
    flat = {c for c, _ in search.collapsed_}
    assert flat and all(c.sigma == 0.001 for c in flat)
    assert search.best_.sigma == 1.0 and search.best_error_ < 1.0
    note = search.report()["collapsed"]
    assert note.startswith(f"{len(flat)} candidate") and "counted as error 1.0" in note
    only_flat = RecipeSearch(recipes[:1], [0.1], [0.001], ["Q/2"], [None], n_splits=3,
                             first_share=1.0, significance=None, seed=2).fit(X, y, groups)
    assert only_flat.best_error_ == 1.0
    fine = RecipeSearch(recipes[:1], [0.1], [1.0], ["Q/2"], [None], n_splits=3,
                        first_share=1.0, significance=None, seed=2).fit(X, y, groups)
    assert fine.collapsed_ == [] and fine.report()["collapsed"] is None


@pytest.mark.parametrize("negatives", ["all", "balanced"])
def test_a_kernel_collapsed_whatever_the_fit_is_scored_as_its_fit(data, negatives):
    """sigma = 0.001: C times the largest sum of a held-out pattern's kernel values is below
    the collapse tolerance for every machine, so the search scores the candidate without
    fitting it: error 1.0 on every split, and the support vectors the fitted machines have
    (every training pattern of the machines, each of them collapsed)."""
    from eskin.learn.recipes import COLLAPSE_TOLERANCE

    X, y, groups = data
    Xr = X[(20, "algorithm2")]
    recipe = Recipe("svm", 20, "algorithm2", negatives)
    search = RecipeSearch([recipe], [0.1], [0.001], ["Q/2"], [None], n_splits=2,
                          first_share=1.0, significance=None, seed=4).fit(X, y, groups)
    [(_, splits)] = search.collapsed_
    assert splits == [0, 1] and search.best_error_ == 1.0
    counts = []
    for tr, te in search.splits_:
        ix = [np.intersect1d(tr, m) for m in one_vs_all_indices(y, 3, negatives, 4)]
        fitted = [TensorSVC(C=10.0, sigma=0.001, alpha="half") for _ in ix]
        for k, (f, m) in enumerate(zip(fitted, ix)):
            f.fit(Xr[m], np.where(y[m] == k, 1, -1))
        for f in fitted:
            assert np.max(np.abs(f.decision_function(Xr[te]) - f.intercept_)) < COLLAPSE_TOLERANCE
        used = np.unique(np.concatenate([m[f.support_] for m, f in zip(ix, fitted)]))
        assert len(used) == len(np.unique(np.concatenate(ix)))
        counts.append(len(used))
    share = np.mean([len(tr) for tr, _ in search.splits_]) / len(y)
    assert search.ranking_[0]["support_vectors"] == int(np.ceil(np.mean(counts) / share))


def test_a_candidates_label_names_every_setting_and_an_absent_amplitude_as_off():
    recipe = Recipe("svm", 20, "even", "all")
    assert Candidate(recipe, 0.1, 2.0, "Q/2", None).label() == (
        "svm D=20 even negatives=all, lambda=0.1, sigma=2, alpha=Q/2, amplitude=off")
    assert Candidate(recipe, 10.0, 0.5, "1", 1.5).label() == (
        "svm D=20 even negatives=all, lambda=10, sigma=0.5, alpha=1, amplitude=1.5")


def test_a_binary_splits_label_is_class_1_only_above_zero():
    """Two classes have one machine: a held-out value above 0 is class 1; 0 itself, and
    anything below, class 0 (the sign rule of the binary model)."""
    from eskin.learn.recipes import _predict

    F = np.array([[-2.0], [-0.5], [0.0], [0.5], [1.0], [3.0]])
    np.testing.assert_array_equal(_predict(F, 2), [0, 0, 0, 1, 1, 1])
    three = np.array([[0.2, -0.1, 0.9], [1.5, 0.3, -1.0]])
    np.testing.assert_array_equal(_predict(three, 3), [2, 0])


def test_a_p_value_exactly_at_the_level_is_not_significantly_worse():
    """The preferred recipe is kept when its paired test's p is at least the level: a p equal
    to the level to the bit keeps it, a level one ulp above that p does not."""
    from eskin.learn.recipes import _preferred_recipe, _Row

    pref = Candidate(Recipe("svm", 50, "algorithm2", "all"), 0.1, 1.0, "1", None)
    low = Candidate(Recipe("rls", 20, "even", "all"), 0.1, 1.0, "Q", None)
    rows = {low: _Row(low, errors={0: 0.1, 1: 0.2, 2: 0.1, 3: 0.2}),
            pref: _Row(pref, errors={0: 0.3, 1: 0.3, 2: 0.2, 3: 0.4})}
    splits = [(np.arange(7), np.arange(7, 10))] * 4
    share = float(np.mean([len(te) / (len(tr) + len(te)) for tr, te in splits]))
    diffs = [rows[pref].errors[s] - rows[low].errors[s] for s in range(4)]
    t, p = corrected_paired_t(diffs, share)
    assert 0 < p < 0.5
    kept, rec = _preferred_recipe(rows, [low, pref], splits, 1e-3, p)
    assert kept == pref.recipe and rec["p"] == round(p, 6) and rec["significance"] == p
    assert rec["t"] == round(t, 4) and len({round(t, 3), round(t, 4), round(t, 5)}) == 3
    assert rec["within_one_pattern"] is False and rec["gap"] == round(np.mean(diffs), 6)
    other, _ = _preferred_recipe(rows, [low, pref], splits, 1e-3, float(np.nextafter(p, 1)))
    assert other == low.recipe


def test_each_family_is_tested_with_its_own_best_candidate():
    """Three families by preference: the most preferred (D = 100) significantly worse than the
    lowest-error candidate (constantly 0.1 more), the next (D = 50) worse on the mean but not
    significantly (one bad split), the lowest (rls, D = 20) last: the D = 50 recipe is chosen,
    tested with its own candidate though the D = 100 one comes before it by error."""
    from eskin.learn.recipes import _preferred_recipe, _Row

    a = Candidate(Recipe("svm", 100, "algorithm2", "all"), 0.1, 1.0, "1", None)
    b = Candidate(Recipe("svm", 50, "algorithm2", "all"), 0.1, 1.0, "1", None)
    low = Candidate(Recipe("rls", 20, "even", "all"), 0.1, 1.0, "1", None)
    g = 0.123456789
    rows = {low: _Row(low, errors=dict.fromkeys(range(4), 0.1)),
            a: _Row(a, errors=dict.fromkeys(range(4), 0.2)),
            b: _Row(b, errors={0: 0.1, 1: 0.1, 2: 0.1, 3: 0.1 + 4 * g})}
    splits = [(np.arange(7), np.arange(7, 10))] * 4
    chosen, rec = _preferred_recipe(rows, [low, a, b], splits, 1e-3, 0.05)
    assert chosen == b.recipe
    t, p = corrected_paired_t([0.0, 0.0, 0.0, 4 * g], 0.3)
    assert rec == {"recipe": b.recipe.label(), "lowest": low.recipe.label(), "gap": 0.123457,
                   "within_one_pattern": False, "t": round(t, 4), "p": round(p, 6),
                   "significance": 0.05}
    # a constant excess within one held-out pattern (the tolerance) keeps the preferred recipe,
    # whatever the test would say (a zero variance: p = 0)
    for excess, kept in ((1e-3, True), (1e-3 + 5e-13, True), (1e-3 + 1e-9, False)):
        rows[a] = _Row(a, errors=dict.fromkeys(range(4), 0.1 + excess))
        chosen, rec = _preferred_recipe(rows, [low, a, b], splits, 1e-3, 0.05)
        assert (chosen == a.recipe) is kept and rec["within_one_pattern"] is kept, excess


def test_equal_errors_rank_the_simpler_candidate_first():
    """Ties on the mean error go to the larger lambda, then the larger sigma, then no
    amplitude factor, then the smaller D."""
    from eskin.learn.recipes import _Row

    r20, r50 = Recipe("svm", 20, "algorithm2", "all"), Recipe("svm", 50, "algorithm2", "all")
    order = [Candidate(r20, 1.0, 2.0, "1", None), Candidate(r50, 1.0, 2.0, "1", None),
             Candidate(r20, 1.0, 2.0, "1", 4.0), Candidate(r20, 1.0, 1.0, "1", None),
             Candidate(r20, 0.1, 4.0, "1", None)]
    search = RecipeSearch([r20, r50], [0.1, 1.0], [1.0, 2.0, 4.0], ["1"], [None, 4.0])
    rows = [_Row(c, errors={0: 0.25, 1: 0.5}) for c in order]
    assert [r.candidate for r in sorted(reversed(rows), key=search._key)] == order
    assert sorted(rows + [_Row(order[-1], errors={0: 0.2})], key=search._key)[0].mean == 0.2


def test_a_regularised_kernel_that_is_not_positive_definite_is_an_error_not_a_solution():
    """The tensor-RLS solve (LAPACK's posv): K + lambda I solved exactly when it is positive
    definite; when it is not (posv's info 1 here), SciPy's error, not posv's partial result."""
    from scipy import linalg

    from eskin.learn.recipes import _solve_pos

    K = np.array([[2.0, 1.0], [1.0, 2.0]])
    np.testing.assert_allclose(_solve_pos(K, 0.5, np.array([1.0, -1.0]), linalg),
                               [2 / 3, -2 / 3], rtol=1e-12)
    bad = np.array([[-5.0, 0.0], [0.0, 1.0]])
    assert linalg.lapack.dposv(bad + 0.1 * np.eye(2), np.ones(2), lower=False)[2] == 1
    with pytest.raises(np.linalg.LinAlgError) as refused:
        _solve_pos(bad, 0.1, np.ones(2), linalg)
    assert str(refused.value) == ("K + lambda I is not positive definite (lambda = 0.1: the "
                                  "leading minor of order 1 is not)")
    second = np.array([[1.0, 2.0], [2.0, 1.0]])  # its 2 x 2 minor: 1.1^2 - 4 < 0
    with pytest.raises(np.linalg.LinAlgError, match="minor of order 2 is not"):
        _solve_pos(second, 0.1, np.ones(2), linalg)


def test_the_binary_targets_are_plus_one_for_class_1_and_minus_one_else():
    from eskin.learn.recipes import _binary_targets

    y = np.array([0, 1, 1, 0, 1])
    np.testing.assert_array_equal(_binary_targets(y, 2), [[-1.0], [1.0], [1.0], [-1.0], [1.0]])
    three = np.array([2, 0, 1])
    np.testing.assert_array_equal(_binary_targets(three, 3),
                                  [[-1.0, -1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0]])


def test_each_recipes_row_is_its_candidate_of_the_most_splits_and_then_the_lowest_error(data):
    """The recipe table keeps, per recipe, the candidate scored on the most splits (the
    furthest round it reached), and among those the lowest mean error."""
    X, y, groups = data
    recipes = [Recipe("svm", 20, "algorithm2", "all"), Recipe("rls", 20, "even", "all")]
    s = RecipeSearch(recipes, [0.01, 0.1, 1.0, 10.0], [0.5, 2.0, 8.0], ["1", "Q/2"], [None],
                     n_splits=4, first_share=1.0, significance=None, seed=5).fit(X, y, groups)
    assert max(r["splits"] for r in s.rounds_) == 4 and s.rounds_[0]["splits"] == 1
    final = {}
    for e in s.ranking_:
        final.setdefault(e["candidate"].recipe, []).append(e)
    assert final  # the last round's candidates, 4 splits each
    table = {e["candidate"].recipe: e for e in s.recipe_table_}
    ties = 0
    for recipe, entries in final.items():
        assert table[recipe]["splits"] == 4
        lowest = min(e["error"] for e in entries)
        assert table[recipe]["error"] == lowest
        # equal errors: the simpler machine, as the ranking breaks ties (larger lambda, then
        # larger sigma, no amplitude factor, then alpha's label)
        tied = [e["candidate"] for e in entries if e["error"] == lowest]
        ties += len(tied) > 1
        assert table[recipe]["candidate"] == min(
            tied, key=lambda c: (-c.lam, -c.sigma, c.amplitude is not None, c.alpha))
    assert ties  # the case is there


@pytest.mark.parametrize("shape,alpha", [((19, 27, 18), "full"), ((16, 16, 10), "full"),
                                         ((4, 4, 20), "half")])
def test_the_smallest_distance_plan_is_the_least_memory_blocks_of_8_can_take(shape, alpha):
    """distance_memory's smallest scratch: the plan of a row and a column block of 8 patterns
    fits in it, and not in one byte less (on these shapes a projection mode packed as its
    bases is smaller than the first plan's)."""
    from eskin.learn.kernel import distance_plan

    alphas = resolve_alphas(shape, alpha)
    _, smallest = distance_memory((100, *shape), alphas)
    assert distance_plan(list(shape), alphas, 8, 8, max_bytes=smallest)["pack_bytes"] == smallest
    with pytest.raises(ValueError):
        distance_plan(list(shape), alphas, 8, 8, max_bytes=smallest - 1)
    assert smallest < distance_plan(list(shape), alphas, 8, 8)["pack_bytes"]


@pytest.mark.parametrize("shape,alpha", [((4, 4, 20), "full"), ((4, 4, 20), 1),
                                         ((3, 5, 12), "half")])
def test_the_smallest_distance_plan_when_no_mode_packs_smaller_is_the_first(shape, alpha):
    """On these shapes no projection mode's bases pack smaller than the mode itself: the
    smallest scratch is the plain plan of a row and a column block of 8 patterns, which fits in
    it and not in one byte less."""
    from eskin.learn.kernel import distance_plan

    alphas = resolve_alphas(shape, alpha)
    _, smallest = distance_memory((100, *shape), alphas)
    assert smallest == distance_plan(list(shape), alphas, 8, 8)["pack_bytes"]
    with pytest.raises(ValueError):
        distance_plan(list(shape), alphas, 8, 8, max_bytes=smallest - 1)


def test_the_scratch_left_to_the_kernel_and_the_refusal_at_one_byte_short():
    """200 patterns of a 19 x 27 grid at D = 18, alpha Q: bases of 3 x 9234 values a pattern
    (44,323,200 bytes) and four n x n distance matrices (1,280,000): the scratch left is the
    limit less those, down to the smallest plan's (limit exactly bases + distances + plan);
    a byte less is refused with the patterns, D, alpha and both figures in MiB."""
    shape, alphas = (200, 19, 27, 18), resolve_alphas((19, 27, 18), "full")
    fixed, smallest = distance_memory(shape, alphas)
    assert fixed == 44_323_200 + 1_280_000
    assert distance_scratch(shape, alphas, fixed + smallest, "x") == smallest
    assert distance_scratch(shape, alphas, 2**30, "x") == 2**30 - fixed
    assert 47 * 2**20 < fixed + smallest <= 48 * 2**20  # the need, rounded to 48 MiB
    with pytest.raises(TrainingError) as refused:
        distance_scratch(shape, alphas, fixed + smallest - 1, "D = 18, alpha Q")
    assert str(refused.value) == (
        "the distances of 200 patterns at D = 18, alpha Q need at least 48 MiB, more than the "
        "memory limit of 48 MiB: give a smaller D or alpha, or raise --memory-limit")
    with pytest.raises(TrainingError) as refused:
        distance_scratch(shape, alphas, 40 * 2**20, "D = 18, alpha Q")
    assert "need at least 48 MiB, more than the memory limit of 40 MiB: " in str(refused.value)


@pytest.mark.parametrize("shape,alpha", [((4, 4, 20), "full"), ((3, 5, 12), "half")])
def test_the_fixed_memory_counted_is_what_the_bases_and_distances_take(shape, alpha):
    """distance_memory's first part: the bytes of every pattern's bases (pattern_bases) and of
    the per-mode distances and their sum (mode_distances), as allocated."""
    from eskin.learn.kernel import mode_distances, pattern_bases

    X = np.random.default_rng(5).normal(size=(9, *shape))
    alphas = resolve_alphas(shape, alpha)
    fixed, _ = distance_memory(X.shape, alphas)
    bases = pattern_bases(X, alpha=alphas)
    d = mode_distances(X, alpha=alphas)
    held = sum(bases.mode_bases(z).nbytes for z in range(3)) + d.nbytes + d.sum(axis=0).nbytes
    assert fixed == held


def test_the_collapse_note_counts_candidates_and_splits_in_words():
    from eskin.learn.recipes import _collapse_note

    a = Candidate(Recipe("svm", 20, "even", "all"), 0.1, 0.001, "1", None)
    b = Candidate(Recipe("rls", 20, "even", "all"), 0.1, 0.001, "1", None)
    tail = ("(a machine's held-out decision values all within 0.001 of its intercept), counted "
            "as error 1.0 there")
    assert _collapse_note([]) is None
    assert _collapse_note([(a, [0])]) == f"1 candidate had a collapsed kernel on 1 split {tail}"
    assert _collapse_note([(a, [0, 2])]) == (
        f"1 candidate had a collapsed kernel on 2 splits {tail}")
    assert _collapse_note([(a, [0, 2]), (b, [1])]) == (
        f"2 candidates had a collapsed kernel on 3 splits {tail}")


def test_the_report_names_three_runners_up_by_default(data):
    """Five recipes: the report's runners-up are the best entries of three of the four other
    recipes by default, in the recipe table's order; ``runners_up`` asks for more or fewer."""
    X, y, groups = data
    recipes = [Recipe("svm", 20, "algorithm2", "all"), Recipe("rls", 20, "algorithm2", "all"),
               Recipe("svm", 20, "even", "all"), Recipe("rls", 20, "even", "balanced"),
               Recipe("svm", 50, "algorithm2", "balanced")]
    s = RecipeSearch(recipes, [1.0], [1.0], ["1"], [None], n_splits=2, first_share=1.0,
                     eta=10, seed=5).fit(X, y, groups)
    rep = s.report()
    others = [r for r in rep["recipes"] if (r["machine"], r["D"], r["subsample"],
                                            r["negatives"]) != (s.best_.recipe.machine,
                                                                s.best_.recipe.D,
                                                                s.best_.recipe.subsample,
                                                                s.best_.recipe.negatives)]
    assert len(rep["recipes"]) == 5 and len(others) == 4
    assert rep["runners_up"] == others[:3]
    assert s.report(runners_up=4)["runners_up"] == others
    assert s.report(runners_up=1)["runners_up"] == others[:1]


def test_the_search_takes_one_split_and_halving_and_growth_factors_from_two():
    recipe = [Recipe("svm", 20, "even", "all")]
    grid = ([1.0], [1.0], ["1"], [None])
    ok = RecipeSearch(recipe, *grid, n_splits=1, eta=2, growth=2)
    assert (ok.n_splits, ok.eta, ok.growth) == (1, 2, 2) and ok._schedule() == [1]
    for bad in ({"n_splits": 0}, {"eta": 1}, {"growth": 1}):
        with pytest.raises(TrainingError, match="n_splits must be >= 1, eta and growth >= 2"):
            RecipeSearch(recipe, *grid, **bad)


def test_a_spread_of_exactly_the_tolerance_is_not_a_collapse():
    from eskin.learn.recipes import COLLAPSE_TOLERANCE, collapsed

    b = np.zeros(2)
    wide = np.array([[1.0, COLLAPSE_TOLERANCE], [-1.0, -COLLAPSE_TOLERANCE], [0.5, 0.0]])
    assert not collapsed(wide, b)
    narrow = wide.copy()
    narrow[:2, 1] = [np.nextafter(COLLAPSE_TOLERANCE, 0), -np.nextafter(COLLAPSE_TOLERANCE, 0)]
    assert collapsed(narrow, b)


def test_the_kernel_reach_is_the_largest_held_out_row_sum_over_the_machines():
    """_kernel_reach: per machine's training set (each array object once) the largest sum of a
    held-out pattern's kernel row, inf for a machine with no held-out pattern; and how many
    training patterns the machines use together."""
    import math

    from eskin.learn.recipes import _kernel_reach

    a, b = np.array([0, 1, 2]), np.array([2, 3])
    # row sums 0.875, 0.75 and 0.625; column sums (a training pattern's) up to 1.75
    K_a = np.array([[0.125, 0.25, 0.5], [0.0, 0.0, 0.75], [0.0, 0.125, 0.5]])
    K_b = np.array([[0.25, 0.25]])
    assert _kernel_reach([(a, None, K_a), (b, None, K_b)]) == (0.875, 4)
    assert _kernel_reach([(a, None, K_a), (a, None, np.full((2, 3), 9.0))]) == (0.875, 3)
    assert _kernel_reach([(a, None, np.zeros((0, 3))), (b, None, K_b)]) == (math.inf, 4)


def _finished(rows: dict, final: list, significance=None, seconds: float = 0.0) -> RecipeSearch:
    """A search finished on the given rows: two splits of 10 training and 4 held-out patterns
    each (one held-out pattern over both: 1/8), n = 20 patterns in all."""
    recipes = sorted({c.recipe for c in rows}, key=recipe_preference)
    s = RecipeSearch(recipes, [0.1], [1.0], ["1"], [None], n_splits=2, significance=significance)
    s.splits_ = [(np.arange(10), np.arange(10, 14)), (np.arange(4, 14), np.arange(14, 18))]
    s.rounds_, s.n_evaluations_, s.seconds_, s.collapsed_ = [], 0, seconds, []
    s._finish(rows, final, 20)
    return s


def test_within_one_held_out_pattern_the_chosen_recipe_keeps_its_smallest_machine():
    """Among the chosen recipe's candidates, those less than one held-out pattern above its
    lowest error (over all the splits together: 1/8 here, exactly at it included) count as
    equally good, and of them the one expected to need the fewest support vectors wins; a
    candidate of another recipe, however small, does not."""
    from eskin.learn.recipes import _Row

    r = Recipe("svm", 20, "even", "all")
    other, lesser = Recipe("svm", 50, "even", "all"), Recipe("svm", 10, "even", "all")
    assert lesser < r < other  # (by D)

    def row(c, err, support):
        return _Row(c, errors={0: err, 1: err}, support={0: support, 1: support})

    low, at, above = (Candidate(r, lam, 1.0, "1", None) for lam in (0.1, 1.0, 10.0))
    small, smaller = Candidate(other, 0.1, 1.0, "1", None), Candidate(lesser, 0.1, 1.0, "1", None)
    rows = {low: row(low, 0.125, 10), at: row(at, 0.25, 5), above: row(above, 0.375, 1),
            small: row(small, 0.25, 1), smaller: row(smaller, 0.25, 1)}
    final = [low, at, small, smaller, above]  # by error
    s = _finished(rows, final)
    assert s.tolerance_ == 1 / 8
    assert s.best_ == at and s.best_error_ == 0.25
    # the expected support: the splits' mean over the share they trained on (10 of 20)
    assert [e["support_vectors"] for e in s.ranking_] == [10, 20, 2, 2, 2]
    assert [e["candidate"] for e in s.ranking_] == [at, low, small, smaller, above]
    # just above the tolerance: the lowest error's candidate
    rows[at] = row(at, 0.25 + 1e-9, 5)
    assert _finished(rows, final).best_ == low


def test_the_report_rounds_errors_and_the_tolerance_to_6_places_and_time_to_milliseconds():
    """The report's figures as a reader gets them: errors, their spread and the tie tolerance to
    6 decimal places, the seconds to 3; the runners-up are the other recipes' best, of any
    order."""
    from eskin.learn.recipes import _Row

    a, b, c = (Recipe("svm", 20, "even", "all"), Recipe("svm", 50, "even", "all"),
               Recipe("svm", 100, "even", "all"))
    cands = [Candidate(rec, 0.1, 1.0, "1", None) for rec in (b, a, c)]
    rows = {x: _Row(x, errors={0: e0, 1: e1}, support={0: 3, 1: 3})
            for x, (e0, e1) in zip(cands, ((1 / 3, 1 / 7), (0.5, 1 / 6), (0.5, 0.5)))}
    s = _finished(rows, cands, seconds=1.23456789)
    s.tolerance_ = 1 / 12
    rep = s.report()
    errs = [(1 / 3 + 1 / 7) / 2, (0.5 + 1 / 6) / 2, 0.5]
    stds = [(1 / 3 - 1 / 7) / 2, (0.5 - 1 / 6) / 2, 0.0]
    assert rep["chosen"]["cv_error"] == round(errs[0], 6) == 0.238095
    assert rep["chosen"]["cv_std"] == round(stds[0], 6) == 0.095238
    assert [e["cv_error"] for e in rep["recipes"]] == [round(e, 6) for e in errs]
    assert [e["cv_std"] for e in rep["recipes"]] == [round(e, 6) for e in stds]
    assert rep["tie_tolerance"] == 0.083333 and rep["seconds"] == 1.235
    # b (chosen) orders after a and before c: both of the others are runners-up
    assert a < b and c > b
    assert [e["D"] for e in rep["runners_up"]] == [20, 100]
