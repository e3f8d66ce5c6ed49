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
from eskin.errors import TrainingError
from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS, TensorSVC
from eskin.learn.models import load_model, preprocess_campaign, train_model
from eskin.learn.recipes import (
    CandidateBudget,
    Recipe,
    RecipeSearch,
    one_vs_all_indices,
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


@pytest.mark.parametrize("machine,negatives", [("svm", "all"), ("svm", "balanced"),
                                               ("rls", "all"), ("rls", "balanced")])
def test_split_scores_are_those_of_the_one_vs_all_classifier(data, machine, negatives):
    """The search's error of a candidate on each split is the error of the shipped
    OneVsAllTouchClassifier trained on that split's training part (the same machines and
    negatives), predicting the split's held-out participants."""
    X, y, groups = data
    recipe = Recipe(machine, 20, "algorithm2", negatives)
    Xr = X[(20, "algorithm2")]
    search0 = RecipeSearch([recipe], [0.1], [1.0], ["Q/2"], [None], n_splits=2,
                           first_share=1.0, seed=4).fit(X, y, groups)
    est0 = (TensorSVC(C=10.0, sigma=1.0, alpha="half") if machine == "svm"
            else TensorRLS(lam=0.1, sigma=1.0, alpha="half"))
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


def test_successive_halving_keeps_a_third_per_round(data):
    X, y, groups = data
    recipes = [Recipe(m, 20, s, "all") for m in ("svm", "rls") for s in ("algorithm2", "even")]
    lams, sigmas = [0.01, 0.1, 1.0, 10.0], [0.5, 1.0, 2.0, 4.0]
    search = RecipeSearch(recipes, lams, sigmas, ["1", "Q/2"], [None, 1.0], n_splits=9,
                          first_share=0.5, seed=1).fit(X, y, groups)
    # 4 recipes x 32 of the 64 settings; each round keeps ceil(1/3) and triples the splits
    assert [r["candidates"] for r in search.rounds_] == [128, 43, 15]
    assert [r["splits"] for r in search.rounds_] == [1, 3, 9]
    assert search.n_evaluations_ == 128 * 1 + 43 * 2 + 15 * 6
    first = search._first_candidates()
    assert len({(c.lam, c.sigma, c.alpha, c.amplitude) for c in first}) == 32
    assert all(sum(c.recipe == r for c in first) == 32 for r in recipes)
    assert search.ranking_[0]["splits"] == 9
    # the choice is within one held-out pattern (over all splits) of the best final error
    best = min(e["error"] for e in search.ranking_)
    assert search.best_error_ <= best + search.tolerance_ + 1e-12
    # deterministic: the same seed gives the same choice and figures
    again = RecipeSearch(recipes, lams, sigmas, ["1", "Q/2"], [None, 1.0], n_splits=9,
                         first_share=0.5, seed=1).fit(X, y, groups)
    assert again.best_ == search.best_ and again.report()["recipes"] == search.report()["recipes"]


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
    from eskin.deploy.target import model_fits, parse_budget

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
