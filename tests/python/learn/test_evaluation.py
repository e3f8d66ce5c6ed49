"""Nested group-disjoint evaluation: folds, scores, intervals, the report and the command."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from eskin.learn.evaluation import (
    EvaluationError,
    confusion_matrix,
    group_bootstrap_ci,
    make_folds,
    scores_from_confusion,
)


@st.composite
def group_layouts(draw):
    """Random recordings: group label (arbitrary integers), class, and a fold count."""
    n = draw(st.integers(4, 60))
    labels = draw(st.lists(st.integers(-5, 1000), min_size=2, max_size=12, unique=True))
    groups = np.array(draw(st.lists(st.sampled_from(labels), min_size=n, max_size=n)))
    groups[:2] = labels[:2]  # at least two groups
    y = np.array(draw(st.lists(st.integers(0, 3), min_size=n, max_size=n)))
    n_groups = len(np.unique(groups))
    k = draw(st.one_of(st.none(), st.integers(2, n_groups)))
    return groups, y, k, draw(st.integers(0, 2**31 - 1))


@settings(max_examples=150, deadline=None)
@given(group_layouts())
def test_folds_never_share_a_group_and_test_every_recording_once(layout):
    groups, y, k, seed = layout
    folds = make_folds(groups, y, k, seed)
    tested = np.concatenate([te for _, te in folds])
    assert np.array_equal(np.sort(tested), np.arange(len(y)))  # each recording tested once
    for tr, te in folds:
        assert len(te) > 0
        assert not set(groups[tr]) & set(groups[te])
        assert np.array_equal(np.union1d(tr, te), np.arange(len(y)))
    n_groups = len(np.unique(groups))
    assert len(folds) == (n_groups if k is None else k)
    if k is None:  # leave-one-group-out: one group per test set
        assert all(len(np.unique(groups[te])) == 1 for _, te in folds)


def test_folds_need_two_groups_and_a_possible_fold_count():
    with pytest.raises(EvaluationError, match="at least 2 groups"):
        make_folds(np.zeros(5, int), np.arange(5) % 2)
    with pytest.raises(EvaluationError, match=r"--folds 4: must be in \[2, 3\]"):
        make_folds(np.array([0, 1, 2, 0]), np.array([0, 1, 0, 1]), 4)


def test_scores_of_a_known_confusion():
    y_true = np.array([0, 0, 0, 0, 1, 1, 2, 2, 2, 2])
    y_pred = np.array([0, 0, 0, 1, 1, 0, 2, 2, 2, 2])
    cm = confusion_matrix(y_true, y_pred, 4)
    assert cm.tolist() == [[3, 1, 0, 0], [1, 1, 0, 0], [0, 0, 4, 0], [0, 0, 0, 0]]
    acc, bal, recall = scores_from_confusion(cm)
    assert acc == pytest.approx(0.8)
    assert recall[:3].tolist() == pytest.approx([0.75, 0.5, 1.0])
    assert np.isnan(recall[3])  # no test recording of class 3: left out of the balance
    assert bal == pytest.approx(0.75)
    from sklearn.metrics import balanced_accuracy_score

    assert bal == pytest.approx(balanced_accuracy_score(y_true, y_pred))



def test_pooling_reads_the_fold_records_without_changing_them():
    """Pooled scores of folds given out of order: the predictions are concatenated in fold
    order, with their groups; the baseline is scored on its own predictions; the fold records
    passed in keep their predictions, the result's folds are copies without them."""
    import copy

    from eskin.learn.evaluation import _pooled

    folds = [(np.array([2, 3]), np.array([0, 1])), (np.array([0, 1]), np.array([2, 3]))]
    records = [
        {"fold": 1, "accuracy": 0.5, "y_true": np.array([1, 1]), "y_pred": np.array([1, 0]),
         "baselines": {"majority": {"accuracy": 0.0, "y_pred": np.array([0, 0])}}},
        {"fold": 0, "accuracy": 1.0, "y_true": np.array([0, 0]), "y_pred": np.array([0, 0]),
         "baselines": {"majority": {"accuracy": 1.0, "y_pred": np.array([0, 0])}}},
    ]
    before = copy.deepcopy(records)
    labels = np.array([7, 7, 8, 8])
    result = _pooled(records, folds, labels, ["a", "b"], ["majority"], seed=0)
    for r, b in zip(records, before):  # unchanged, predictions included
        assert r.keys() == b.keys() and r["baselines"]["majority"].keys() == b["baselines"]["majority"].keys()
        np.testing.assert_array_equal(r["y_pred"], b["y_pred"])
        np.testing.assert_array_equal(r["y_true"], b["y_true"])
    assert result["predictions"] == {
        "index": [0, 1, 2, 3], "group": [7, 7, 8, 8], "true": [0, 0, 1, 1], "predicted": [0, 0, 1, 0]}
    assert result["accuracy"] == pytest.approx(0.75)
    assert result["per_class_recall"] == {"a": 1.0, "b": 0.5}
    assert result["confusion"] == [[2, 0], [1, 1]]
    assert result["baselines"]["majority"]["accuracy"] == pytest.approx(0.5)
    assert result["baselines"]["majority"]["confusion"] == [[2, 0], [2, 0]]
    assert [f["fold"] for f in result["folds"]] == [0, 1]
    assert [f["accuracy"] for f in result["folds"]] == [1.0, 0.5]
    for f in result["folds"]:
        assert "y_true" not in f and "y_pred" not in f
        assert f["baselines"]["majority"].keys() == {"accuracy"}


def test_recall_of_an_asymmetric_confusion_is_per_true_class_and_named():
    """Rows are the true classes: recall divides by the row sums (the column sums, precision,
    differ here), and the named recalls follow the class order."""
    from eskin.learn.evaluation import summarise

    y_true = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2])
    y_pred = np.array([0, 1, 2, 1, 1, 0, 0, 0, 2])
    cm = confusion_matrix(y_true, y_pred, 3)
    assert cm.tolist() == [[1, 1, 1], [0, 2, 0], [3, 0, 1]]
    acc, bal, recall = scores_from_confusion(cm)
    assert recall.tolist() == pytest.approx([1 / 3, 1.0, 0.25])  # precision: 0.25, 2/3, 0.5
    assert acc == pytest.approx(4 / 9) and bal == pytest.approx((1 / 3 + 1 + 0.25) / 3)
    s = summarise(y_true, y_pred, np.arange(9), ["a", "b", "c"], seed=0)
    assert s["per_class_recall"] == pytest.approx({"a": 1 / 3, "b": 1.0, "c": 0.25})
    assert s["confusion"] == cm.tolist()
    assert (s["accuracy"], s["balanced_accuracy"]) == pytest.approx((acc, bal))
    # the intervals: the bootstrap's with seed 0 by default, another with seed 1
    assert summarise(y_true, y_pred, np.arange(9), ["a", "b", "c"]) == s
    ci = group_bootstrap_ci(y_true, y_pred, np.arange(9), 3, seed=0)
    assert (s["ci95"], s["ci95_balanced_accuracy"]) == (ci["accuracy"], ci["balanced_accuracy"])
    other = summarise(y_true, y_pred, np.arange(9), ["a", "b", "c"], seed=1)
    assert (other["ci95"], other["ci95_balanced_accuracy"]) != (s["ci95"],
                                                                s["ci95_balanced_accuracy"])


def test_one_group_resampled_is_the_data_itself():
    """With a single group every bootstrap resample is the whole data, so the interval is the
    point estimate exactly: a resample pooled with rows and columns swapped (macro precision
    0.47 here, not the balanced accuracy 0.53) would widen it."""
    y_true = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2])
    y_pred = np.array([0, 1, 2, 1, 1, 0, 0, 0, 2])
    ci = group_bootstrap_ci(y_true, y_pred, np.zeros(9), 3, n_boot=50, seed=3)
    acc, bal, _ = scores_from_confusion(confusion_matrix(y_true, y_pred, 3))
    assert ci["accuracy"] == pytest.approx([acc, acc])
    assert ci["balanced_accuracy"] == pytest.approx([bal, bal])


@pytest.mark.parametrize("sizes, rare, level", [
    ([4, 6, 3, 5, 7], False, 0.8), ([1] * 9, True, 0.8),
    ([1, 2, 3, 4, 5, 6] * 5, False, 0.9)])  # 30 groups: resamples of distinct scores
def test_the_bootstrap_is_the_documented_resampling_redone_one_resample_at_a_time(sizes, rare,
                                                                                 level):
    """The intervals against the resampling its docstring describes, redone with a loop over
    the resamples (each pools the recordings of the groups drawn, with repeats), numpy's
    percentiles and the widening to the point estimate. Also with groups of one recording and
    a class of one recording (a recall of one test recording, or none, in many resamples)."""
    rng = np.random.default_rng(8)
    groups = np.repeat(10 * (1 + rng.permutation(len(sizes))), sizes)
    y_true = rng.integers(0, 2 if rare else 3, len(groups))
    if rare:
        y_true[4] = 2
    y_pred = np.where(rng.random(len(groups)) < 0.6, y_true, rng.integers(0, 3, len(groups)))
    n_boot, seed = 40, 11
    uniq = np.unique(groups)
    draws = np.random.default_rng(np.random.SeedSequence([seed, 7])).integers(
        0, len(uniq), size=(n_boot, len(uniq)))
    accs, bals = [], []
    for row in draws:
        idx = np.concatenate([np.flatnonzero(groups == uniq[g]) for g in row])
        t, p = y_true[idx], y_pred[idx]
        accs.append(np.mean(t == p))
        bals.append(np.mean([np.mean(p[t == c] == c) for c in range(3) if np.any(t == c)]))
    ci = group_bootstrap_ci(y_true, y_pred, groups, 3, n_boot=n_boot, level=level, seed=seed)
    acc, bal, _ = scores_from_confusion(confusion_matrix(y_true, y_pred, 3))
    for name, values, point in (("accuracy", accs, acc), ("balanced_accuracy", bals, bal)):
        low, high = np.percentile(values, [50 - 50 * level, 50 + 50 * level])
        assert ci[name] == pytest.approx([min(low, point), max(high, point)], abs=1e-12)


def test_a_fold_task_cannot_be_changed_once_made():
    import dataclasses

    from eskin.learn.evaluation import FoldTask

    task = FoldTask(1, "c.h5", np.arange(3), np.arange(3, 5), ("a", "b"), {}, "participant",
                    (), 0, 1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        task.seed = 1  # type: ignore[misc]
    from eskin.learn.evaluation import _Parts

    parts = _Parts(("a", "b"), 1000.0, 1e-3, "simulated", {}, None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        parts.sample_rate_hz = 1.0  # type: ignore[misc]


def test_the_bootstrap_seed_changes_the_resamples():
    rng = np.random.default_rng(4)
    groups = np.repeat(np.arange(12), 5)
    y = rng.integers(0, 3, 60)
    pred = np.where(rng.random(60) < 0.6, y, rng.integers(0, 3, 60))
    intervals = {tuple(group_bootstrap_ci(y, pred, groups, 3, n_boot=200, seed=s)["accuracy"])
                 for s in range(5)}
    assert len(intervals) > 1
    # without a seed, seed 0: the same intervals on every run
    default = group_bootstrap_ci(y, pred, groups, 3, n_boot=200)
    assert default == group_bootstrap_ci(y, pred, groups, 3, n_boot=200, seed=0)
    assert default != group_bootstrap_ci(y, pred, groups, 3, n_boot=200, seed=1)


def test_groups_are_dealt_largest_first_to_the_emptiest_fold():
    """One group of 5 recordings and five of 1, in 2 folds: largest first gives 5 and 5
    (smallest first would end 3 and 7, whatever the seed)."""
    from eskin.learn.evaluation import _dealt_folds

    groups = np.array([0, 0, 0, 0, 0, 1, 2, 3, 4, 5])
    for seed in range(4):
        folds = _dealt_folds(groups, 2, seed)
        assert sorted(len(f) for f in folds) == [5, 5]
        assert any(set(f.tolist()) == {0, 1, 2, 3, 4} for f in folds)
        assert sorted(np.concatenate(folds).tolist()) == list(range(10))

@settings(max_examples=100, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 40), st.integers(2, 5), st.floats(0.0, 1.0))
def test_interval_contains_the_point_estimate(seed, n_groups, n_classes, skill):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(n_groups, 6 * n_groups + 1))
    groups = np.concatenate([np.arange(n_groups), rng.integers(0, n_groups, n - n_groups)])
    y_true = rng.integers(0, n_classes, n)
    right = rng.random(n) < skill
    y_pred = np.where(right, y_true, rng.integers(0, n_classes, n))
    ci = group_bootstrap_ci(y_true, y_pred, groups, n_classes, n_boot=300, seed=seed)
    acc, bal, _ = scores_from_confusion(confusion_matrix(y_true, y_pred, n_classes))
    for (low, high), point in ((ci["accuracy"], acc), (ci["balanced_accuracy"], bal)):
        assert 0.0 <= low <= point <= high <= 1.0


def test_interval_is_seeded_and_narrows_with_more_groups():
    rng = np.random.default_rng(1)

    def interval(n_groups: int) -> list[float]:
        groups = np.repeat(np.arange(n_groups), 10)
        y = rng.integers(0, 2, len(groups))
        pred = np.where(rng.random(len(groups)) < 0.7, y, 1 - y)
        a = group_bootstrap_ci(y, pred, groups, 2, seed=5)["accuracy"]
        assert a == group_bootstrap_ci(y, pred, groups, 2, seed=5)["accuracy"]
        return a

    small, large = interval(5), interval(80)
    assert large[1] - large[0] < small[1] - small[0]


# --------------------------------------------------------------------------- the command

REQUIRED = {"accuracy", "balanced_accuracy", "ci95", "confusion", "classes", "folds"}
FOLD_KEYS = {"train_groups", "test_groups", "accuracy", "n_test", "selected"}


def _run(args: list[str]):
    from typer.testing import CliRunner

    from eskin.cli import app

    return CliRunner().invoke(app, args)


def check_evaluation_json(path: Path, campaign: Path) -> dict:
    """The schema of evaluation.json, checked against the campaign it evaluated."""
    from eskin.data.campaign import load_campaign

    res = json.loads(path.read_text())
    assert REQUIRED <= set(res)
    k = len(res["classes"])
    cm = np.array(res["confusion"])
    assert cm.shape == (k, k)
    assert cm.sum() == res["n_recordings"] == sum(f["n_test"] for f in res["folds"])
    assert res["accuracy"] == pytest.approx(np.trace(cm) / cm.sum())
    low, high = res["ci95"]
    assert 0 <= low <= res["accuracy"] <= high <= 1
    with load_campaign(campaign) as camp:
        part = np.asarray(camp.participant)
    idx = np.array(res["predictions"]["index"])
    assert len(np.unique(idx)) == len(idx) == res["n_recordings"]
    # each fold's accuracy is its share of right predictions (pooled: the overall accuracy)
    right = np.array(res["predictions"]["true"]) == np.array(res["predictions"]["predicted"])
    offsets = np.cumsum([0] + [f["n_test"] for f in res["folds"]])
    for f, a, b in zip(res["folds"], offsets[:-1], offsets[1:]):
        assert f["accuracy"] == pytest.approx(right[a:b].mean())
    for f in res["folds"]:
        assert FOLD_KEYS <= set(f)
        assert not set(f["train_groups"]) & set(f["test_groups"])
        assert isinstance(f["selected"], list) and f["selected"]
    # the groups recorded per fold are the participants of the recordings it tested
    offsets = np.cumsum([0] + [f["n_test"] for f in res["folds"]])
    for f, a, b in zip(res["folds"], offsets[:-1], offsets[1:]):
        assert sorted(set(part[idx[a:b]].tolist())) == f["test_groups"]
    return res


@pytest.fixture(scope="module")
def sim_campaign(tmp_path_factory) -> Path:
    from learn_data import small_simulated

    return small_simulated(tmp_path_factory.mktemp("evaluation"))


def test_evaluate_command_on_a_simulated_campaign(sim_campaign, tmp_path):
    out = tmp_path / "ev"
    r = _run(
        [
            "evaluate",
            str(sim_campaign),
            "--out",
            str(out),
            "--folds",
            "3",
            "--quick",
            "--classes",
            "brush,washer",
            "--selection",
            "cv",
            "--D",
            "20",
            "--machine",
            "svm",
            "--subsample",
            "algorithm2",
            "--negatives",
            "all",
            "--baselines",
            "vector",
        ]
    )
    assert r.exit_code == 0, r.output
    res = check_evaluation_json(out / "evaluation.json", sim_campaign)
    assert res["classes"] == ["brush", "washer"]
    assert len(res["folds"]) == 3
    assert "vector" in res["baselines"] and "vector" in res["folds"][0]["baselines"]
    assert (out / "evaluation.md").read_text().startswith("# Evaluation")
    assert (out / "evaluation.png").read_bytes()[:4] == b"\x89PNG"
    assert "balanced accuracy" in r.output and "95 % CI" in r.output
    assert "confusion" in r.output
    # what the folds really ran: the given options and train's defaults together
    ran = res["trained_with"]
    assert {k: ran[k] for k in ("machine", "selection", "D", "window", "subsample")} == {
        "machine": "svm", "selection": "cv", "D": 20, "window": "energy",
        "subsample": "algorithm2",
    }
    from eskin.learn.grids import DEFAULT_AMPLITUDES

    assert ran["amplitudes"] == list(DEFAULT_AMPLITUDES) and ran["negatives"] == "all"
    assert all(f["trained_with"]["D"] == 20 for f in res["folds"])
    words = "trained with: tensor-SVM, cv selection, D = 20, window energy"
    assert words in r.output
    assert words.replace("trained with", "Trained with") in (out / "evaluation.md").read_text()
    # the options it was given, as the command line spells them (not a JSON dict)
    assert ("options given: `--D 20`, `--machine svm`, `--negatives all`, `--quick`, "
            "`--selection cv`, `--subsample algorithm2`;" in (out / "evaluation.md").read_text())


def test_evaluate_bounds_each_folds_support_vectors(sim_campaign, tmp_path):
    common = ["--folds", "2", "--quick", "--D", "8", "--classes", "brush,washer", "--machine",
              "rls", "--subsample", "even", "--negatives", "all"]
    r = _run(["evaluate", str(sim_campaign), "--out", str(tmp_path), *common,
              "--max-support", "3"])
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "evaluation.json").read_text())
    assert res["recipe"]["max_support"] == 3
    for f in res["folds"]:  # tensor-RLS keeps every training pattern: bounded to 3
        assert f["support_budget"] == {"max_support": 3, "support_vectors": 3,
                                       "support_vectors_before": f["n_train"]}


def test_evaluate_rejects_an_unknown_group_label(sim_campaign, tmp_path):
    r = _run(["evaluate", str(sim_campaign), "--out", str(tmp_path), "--groups", "sitting"])
    assert r.exit_code == 2
    assert "--groups 'sitting': no such label" in r.output


def _without_times(res: dict) -> dict:
    res = dict(res)
    res.pop("seconds")
    res["folds"] = [{k: v for k, v in f.items() if k != "seconds"} for f in res["folds"]]
    return res


@pytest.fixture(scope="module")
def dask_scheduler():
    """A running scheduler with two workers (threads of this process: quick to start)."""
    from dask.distributed import LocalCluster

    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0"
    ) as cluster:
        yield cluster.scheduler_address


def test_evaluate_and_train_on_a_dask_cluster_match_the_serial_run(
    sim_campaign, tmp_path, dask_scheduler
):
    """Folds and searches sent to a real Dask cluster give the serial results exactly."""
    common = ["--folds", "2", "--quick", "--D", "8", "--classes", "brush,washer"]
    for name, extra in (("a", []), ("b", ["--scheduler", dask_scheduler])):
        r = _run(["evaluate", str(sim_campaign), "--out", str(tmp_path / name), *common, *extra])
        assert r.exit_code == 0, r.output
    a = json.loads((tmp_path / "a" / "evaluation.json").read_text())
    b = json.loads((tmp_path / "b" / "evaluation.json").read_text())
    assert _without_times(a) == _without_times(b)

    classes = ["--classes", "brush,finger,washer", "--quick", "--D", "8"]
    for name, extra in (("serial.joblib", []), ("dask.joblib", ["--scheduler", dask_scheduler])):
        r = _run(["train", str(sim_campaign), "-o", str(tmp_path / name), *classes, *extra])
        assert r.exit_code == 0, r.output
    from eskin.data.campaign import load_campaign
    from eskin.deploy import load_model

    m1, m2 = load_model(tmp_path / "serial.joblib"), load_model(tmp_path / "dask.joblib")
    assert m1.selected == m2.selected
    with load_campaign(sim_campaign) as camp:
        assert m1.predict_recordings(camp) == m2.predict_recordings(camp)


def test_evaluate_with_two_jobs_matches_the_serial_run(sim_campaign, tmp_path):
    """--n-jobs 2: the folds on a pool of two worker processes (as --scheduler local:2), with
    the vector baseline; the same evaluation as one fold after the other."""
    common = ["--folds", "3", "--quick", "--D", "8", "--classes", "brush,washer",
              "--baselines", "vector", "--no-live"]
    for name, extra in (("serial", ["--n-jobs", "1"]), ("pool", ["--n-jobs", "2"])):
        r = _run(["evaluate", str(sim_campaign), "--out", str(tmp_path / name), *common, *extra])
        assert r.exit_code == 0, r.output
    a = json.loads((tmp_path / "serial" / "evaluation.json").read_text())
    b = json.loads((tmp_path / "pool" / "evaluation.json").read_text())
    assert _without_times(a) == _without_times(b)
    assert len(b["folds"]) == 3 and "vector" in b["baselines"]


def _untimed(x):
    """A results.json without its timings (keys ending in seconds, created_utc)."""
    if isinstance(x, dict):
        return {
            k: _untimed(v)
            for k, v in x.items()
            if not k.endswith("seconds") and k not in ("seconds_total", "created_utc")
        }
    return [_untimed(v) for v in x] if isinstance(x, list) else x


def test_experiment_on_a_dask_cluster_matches_the_serial_run(
    sim_campaign, tmp_path, dask_scheduler
):
    for name, extra in (("a", ["--n-jobs", "1"]), ("b", ["--scheduler", dask_scheduler])):
        r = _run(
            [
                "experiment",
                str(sim_campaign),
                "--out",
                str(tmp_path / name),
                "--quick",
                "--no-progress",
                *extra,
            ]
        )
        assert r.exit_code == 0, r.output
    a = json.loads((tmp_path / "a" / "results.json").read_text())
    b = json.loads((tmp_path / "b" / "results.json").read_text())
    assert a["binary"] and _untimed(a) == _untimed(b)


def test_scheduler_address_errors_are_one_line(sim_campaign, tmp_path):
    r = _run(["evaluate", str(sim_campaign), "--out", str(tmp_path), "--scheduler", "local:x"])
    assert r.exit_code == 2
    assert "--scheduler 'local:x': expected local:N" in r.output


def test_a_middle_class_recorded_by_one_group_only_is_named(tmp_path):
    """The class of one group only is named whichever its place among the classes."""
    from eskin.data.campaign import write_campaign

    rng = np.random.default_rng(0)
    recs = [(rng.standard_normal((2, 2, 50)) * 100).astype(np.int16) for _ in range(12)]
    path = write_campaign(tmp_path / "c.h5", recs, modality=[0, 2] * 5 + [1, 1],
                          participant=[0, 0, 1, 1, 2, 2, 0, 0, 1, 1, 2, 2], direction=[255] * 12,
                          run=[1] * 12, modalities=["a", "b", "c"], sample_rate_hz=100.0,
                          volts_per_count=1e-3, source="recorded")
    r = _run(["evaluate", str(path), "--out", str(tmp_path / "ev"), "--quick"])
    assert r.exit_code == 2
    assert re.search(r"fold \d: no training recording of class\(es\) \['b'\] once", r.output)


def test_plain_values_are_python_numbers_lists_and_none_for_nan():
    from eskin.learn.evaluation import _plain

    got = _plain({"a": np.int64(3), 2: [np.float32(0.5), np.nan], "f": (True, np.bool_(False))})
    assert got == {"a": 3, "2": [0.5, None], "f": [True, np.bool_(False)]}
    assert type(got["a"]) is int and type(got["2"][0]) is float and got["f"][0] is True


def test_a_class_recorded_by_one_group_only_is_a_clear_error(tmp_path):
    from eskin.data.campaign import write_campaign

    rng = np.random.default_rng(0)
    recs = [(rng.standard_normal((2, 2, 50)) * 100).astype(np.int16) for _ in range(12)]
    path = write_campaign(
        tmp_path / "c.h5",
        recs,
        modality=[0, 1] * 5 + [2, 2],
        participant=[0, 0, 1, 1, 2, 2, 0, 0, 1, 1, 2, 2],
        direction=[255] * 12,
        run=[1] * 12,
        modalities=["a", "b", "c"],
        sample_rate_hz=100.0,
        volts_per_count=1e-3,
        source="recorded",
    )
    r = _run(["evaluate", str(path), "--out", str(tmp_path / "ev"), "--quick"])
    assert r.exit_code == 2
    assert "fold 3: no training recording of class(es) ['c']" in r.output
    r = _run(
        [
            "evaluate",
            str(path),
            "--out",
            str(tmp_path / "ev"),
            "--quick",
            "--D",
            "5",
            "--window",
            "none",
            "--classes",
            "a,b",
        ]
    )
    assert r.exit_code == 0, r.output


def test_classes_and_runs_both_filter_the_recordings(tmp_path):
    """--classes and --runs select the recordings that pass both."""
    from learn_data import user_campaign

    from eskin.data.campaign import load_campaign
    from eskin.learn.evaluation import plan_folds

    with load_campaign(user_campaign(tmp_path)) as camp:  # every recording is of run 1
        folds, names, _ = plan_folds(camp, classes=["tap", "stroke"], runs=[1], n_folds=2)
        tested = np.sort(np.concatenate([te for _, te in folds]))
        mod = np.asarray(camp.modality)
        assert names == ["tap", "stroke"]
        np.testing.assert_array_equal(tested, np.flatnonzero(np.isin(mod, [0, 1])))
        with pytest.raises(EvaluationError):
            plan_folds(camp, classes=["tap", "stroke"], runs=[2], n_folds=2)


def test_a_small_evaluation_pools_its_folds_and_scores_each_baseline_on_its_own_predictions(
    tmp_path,
):
    """evaluate_recipe end to end on a small campaign (seconds): the pooled result is the folds'
    predictions put together, a baseline's scores are those of its own predictions, and the
    record says how it was run."""
    from learn_data import user_campaign

    from eskin.data.campaign import load_campaign
    from eskin.learn.evaluation import evaluate_recipe

    path = user_campaign(tmp_path)
    classes = ["tap", "stroke", "press"]
    seen: list[int] = []
    t0 = time.perf_counter()
    res = evaluate_recipe(
        str(path), recipe={"quick": True, "D": 5, "window": "none", "seed": 99},
        n_folds=2, classes=classes, baselines=("vector",), seed=4,
        on_fold=lambda record, n: seen.append(n),
    )
    elapsed = time.perf_counter() - t0
    assert seen == [2, 2]
    with load_campaign(path) as camp:
        part = np.asarray(camp.participant)
        names = [str(m) for m in camp.modalities]
        mod = np.asarray(camp.modality)
    pred = res["predictions"]
    idx, true = np.array(pred["index"]), np.array(pred["true"])
    predicted = np.array(pred["predicted"])
    # every recording of the chosen classes tested once, its true class by name
    assert sorted(idx.tolist()) == np.flatnonzero(np.isin(mod, [names.index(c) for c in classes])).tolist()
    assert [classes[t] for t in true] == [names[mod[i]] for i in idx]
    assert pred["group"] == part[idx].tolist()
    cm = confusion_matrix(true, predicted, 3)
    assert res["confusion"] == cm.tolist()
    acc, bal, recall = scores_from_confusion(cm)
    assert res["accuracy"] == acc and res["balanced_accuracy"] == bal
    assert res["per_class_recall"] == dict(zip(classes, recall.tolist()))
    assert res["classes"] == classes and res["n_recordings"] == len(idx)
    # the calibrated rule's confidences: one finite number per recording, 1/3 to 1
    conf = pred["confidence"]
    assert len(conf) == len(idx) and all(1 / 3 <= c <= 1 for c in conf)
    assert res["n_groups"] == 4 and res["groups"] == "participant"
    assert res["scheme"] == "2 grouped folds" and res["seed"] == 4
    assert res["campaign"] == str(path)
    # the fold records in fold order, each its share of the pooled predictions, no predictions
    # left in them
    assert [f["fold"] for f in res["folds"]] == [0, 1]
    offsets = np.cumsum([0] + [f["n_test"] for f in res["folds"]])
    vector_right = 0.0
    for f, a, b in zip(res["folds"], offsets[:-1], offsets[1:]):
        assert f["accuracy"] == pytest.approx(np.mean(true[a:b] == predicted[a:b]))
        assert f["test_groups"] == sorted(set(part[idx[a:b]].tolist()))
        assert not set(f["train_groups"]) & set(f["test_groups"])
        assert f["n_train"] + f["n_test"] == len(idx)
        assert 0 < f["seconds"] <= elapsed  # the fold's own duration
        assert "y_true" not in f and "y_pred" not in f and "y_pred" not in f["baselines"]["vector"]
        assert f["trained_with"]["D"] == 5 and f["trained_with"]["window"] == "none"
        vector_right += f["baselines"]["vector"]["accuracy"] * f["n_test"]
    # the baseline's pooled accuracy is that of its own fold predictions, not the recipe's
    base = res["baselines"]["vector"]
    assert base["accuracy"] == pytest.approx(vector_right / len(idx))
    assert np.trace(np.array(base["confusion"])) == round(vector_right)
    assert np.array(base["confusion"]).sum(axis=1).tolist() == cm.sum(axis=1).tolist()
    assert res["trained_with"]["D"] == 5 and res["trained_with"]["window"] == "none"
    assert res["recipe"] == {"quick": True, "D": 5, "window": "none"}  # seed is the evaluation's
    assert 0 < res["seconds"] <= elapsed  # the evaluation's own duration, within the call's


def test_the_interval_ends_are_the_bootstrap_percentiles_of_its_level():
    """Ten one-recording groups, every other one right: a resample's accuracy is k/10 with k
    binomial(10, 1/2), whose 2.5th and 97.5th percentiles are 0.2 and 0.8 (P(k <= 1) = 1.1 %,
    P(k <= 2) = 5.5 %); level 0 gives the median, 0.5, at both ends."""
    y_true = np.zeros(10, np.int64)
    y_pred = np.tile([0, 1], 5)
    groups = np.arange(10)
    ci = group_bootstrap_ci(y_true, y_pred, groups, 2, seed=0)
    assert ci["accuracy"] == [0.2, 0.8]
    assert group_bootstrap_ci(y_true, y_pred, groups, 2, level=0.0, seed=0)["accuracy"] == [0.5, 0.5]


def test_folds_default_to_seed_0():
    groups = np.repeat(np.arange(6), 3)
    y = np.tile([0, 1, 2], 6)
    for k in (None, 3):
        a, b = make_folds(groups, y, k), make_folds(groups, y, k, 0)
        assert [te.tolist() for _, te in a] == [te.tolist() for _, te in b]


def test_a_class_with_one_test_recording_has_a_recall_in_the_scores_and_the_interval():
    y_true = np.array([0, 0, 0, 1, 2, 2])
    y_pred = np.array([0, 0, 1, 1, 2, 0])
    acc, bal, recall = scores_from_confusion(confusion_matrix(y_true, y_pred, 3))
    assert recall.tolist() == pytest.approx([2 / 3, 1.0, 0.5])
    assert bal == pytest.approx((2 / 3 + 1.0 + 0.5) / 3)
    ci = group_bootstrap_ci(y_true, y_pred, np.zeros(6), 3, n_boot=20, seed=1)
    assert ci["balanced_accuracy"] == pytest.approx([bal, bal])


def test_grouped_folds_depend_on_the_seed():
    groups = np.repeat(np.arange(12), 2)
    y = np.tile([0, 1], 12)
    plans = {tuple(tuple(te.tolist()) for _, te in make_folds(groups, y, 3, seed))
             for seed in range(6)}
    assert len(plans) > 1


def test_the_recorded_recipe_and_the_inner_estimate():
    import eskin
    from eskin.learn.evaluation import _inner_estimate, _recorded

    cfg = eskin.WindowConfig(window_samples=0)
    rec = _recorded({"window_config": cfg, "D": 5, "budget": None})
    assert rec["window_config"] == cfg.to_dict() and rec["D"] == 5
    terms = [{"selection_terms": {"mean_test_error": 0.2}}, {"selection_terms": {}},
             {"selection_terms": {"mean_test_error": 0.4}}]
    assert _inner_estimate(terms) == pytest.approx(0.3)
    assert _inner_estimate([{}]) is None and _inner_estimate([]) is None


def test_the_documented_number_of_resamples_is_the_one_drawn():
    """docs/evaluation.md names the bootstrap's resample count; the code draws that many by
    default and records it in every result."""
    import inspect
    import re

    from eskin.learn.evaluation import CI_METHOD, N_BOOTSTRAP

    doc = (Path(__file__).resolve().parents[3] / "docs" / "evaluation.md").read_text()
    (stated,) = {int(n) for n in re.findall(r"bootstrap over groups\*\*: (\d+) resamples", doc)}
    assert stated == N_BOOTSTRAP
    assert inspect.signature(group_bootstrap_ci).parameters["n_boot"].default == N_BOOTSTRAP
    assert f"({stated} resamples" in CI_METHOD.format(n=N_BOOTSTRAP)


def test_the_hold_each_fold_chose_is_one_line_per_hold():
    from eskin.learn.evaluation_report import hold_choice_lines

    def fold(hold, split, one, chosen=True, n=40):
        tried = {"0.15": {"recordings": n, "one": n - split, "split": split, "none": 0}}
        if hold != 0.15:
            tried[f"{hold:g}"] = {"recordings": n, "one": one, "split": n - one, "none": 0}
        return {"live_touches": {"hold_s": hold, "chosen": chosen, "share": 0.95,
                                 "recordings": n, "one": one, "split": n - one, "none": 0,
                                 "tried": tried}}

    result = {"folds": [fold(0.6, 10, 40), fold(0.6, 12, 39), fold(0.15, 0, 40), {}]}
    assert hold_choice_lines(result) == [
        "hold_s = 0.6 s (chosen) in 2 of 3 folds: at 0.15 s, 10 to 12 of 40 training "
        "recordings per fold gave 2+ live touches; at 0.6 s, 39 to 40 give one"]
    given = {"folds": [fold(0.15, 8, 32, chosen=False)] * 2}
    assert hold_choice_lines(given) == [
        "hold_s = 0.15 s (given) in 2 of 2 folds: 8 of 40 training recordings per fold gave 2+ "
        "live touches (a longer --hold merges them)"]
    result = {"folds": [fold(1.5, 20, 30)]}
    assert hold_choice_lines(result)[0].endswith(
        "at 1.5 s, 30 give one (in 1 of them no hold up to 1.5 s gave one touch on 95 % of the "
        "recordings)")


def test_pooled_dont_know_flags_give_the_accuracy_on_each_side():
    from eskin.learn.evaluation import _pooled
    from eskin.learn.evaluation_report import _dont_know_lines

    folds = [(np.array([2, 3]), np.array([0, 1])), (np.array([0, 1]), np.array([2, 3]))]
    records = [
        {"fold": 0, "accuracy": 1.0, "y_true": np.array([0, 0]), "y_pred": np.array([0, 0]),
         "dont_know": [False, True], "baselines": {}},
        {"fold": 1, "accuracy": 0.5, "y_true": np.array([1, 1]), "y_pred": np.array([1, 0]),
         "dont_know": [False, True], "baselines": {}},
    ]
    result = _pooled(records, folds, np.array([7, 7, 8, 8]), ["a", "b"], [], seed=0)
    assert result["predictions"]["dont_know"] == [False, True, False, True]
    assert result["dont_know"] == {"flagged": 0.5, "n_flagged": 2, "accuracy_decided": 1.0,
                                   "accuracy_flagged": 0.5}
    assert all("dont_know" not in f for f in result["folds"])
    assert _dont_know_lines(result["dont_know"]) == [
        "don't know        50.0 % flagged (2); accuracy 100.0 % on the decided, 50.0 % on the "
        "flagged"]


@pytest.mark.parametrize("extra, flagged", [(["--reject", "0"], 0.0), (["--decision", "paper"], None)])
def test_evaluate_passes_the_decision_rule_to_the_folds(sim_campaign, tmp_path, extra, flagged):
    """--reject and --decision reach each fold's model: --reject 0 flags no held-out touch;
    --decision paper is recorded and each held-out recording has its flag."""
    out = tmp_path / "ev"
    r = _run(["evaluate", str(sim_campaign), "--out", str(out), "--folds", "2", "--quick",
              "--D", "20", "--machine", "rls", "--subsample", "even", "--negatives", "all",
              *extra])
    assert r.exit_code == 0, r.output
    res = json.loads((out / "evaluation.json").read_text())
    assert "don't know" in r.output
    if flagged is not None:
        assert res["dont_know"]["flagged"] == flagged and res["dont_know"]["n_flagged"] == 0
    else:
        assert res["recipe"]["decision"] == "paper"
        assert len(res["predictions"]["dont_know"]) == res["n_recordings"]


def test_risk_coverage_decides_the_most_confident_first():
    from eskin.learn.evaluation import risk_coverage

    y_true = np.array([0, 0, 0, 0, 1, 1, 1, 1, 1, 1])
    y_pred = np.array([0, 0, 0, 0, 1, 1, 1, 1, 0, 0])  # the last two wrong
    informative = np.linspace(1.0, 0.1, 10)  # the wrong ones least confident
    rc = risk_coverage(y_true, y_pred, informative, points=10)
    assert rc["coverage"] == [k / 10 for k in range(1, 11)]
    assert rc["error"] == [0.0] * 8 + [1 / 9, 0.2]
    reversed_ = risk_coverage(y_true, y_pred, informative[::-1], points=10)
    assert reversed_["error"][:2] == [1.0, 1.0] and reversed_["error"][-1] == 0.2
    # ties keep the recordings' order; the full coverage is the overall error
    flat = risk_coverage(y_true, y_pred, np.ones(10), points=5)
    assert flat["error"] == [0.0, 0.0, 0.0, 0.0, 0.2]
    # 20 points unless told: coverages of 1/20 to 1 (at least one recording each)
    rc = risk_coverage(y_true, y_pred, informative)
    assert rc["coverage"] == [max(1, round(10 * k / 20)) / 10 for k in range(1, 21)]


def test_pooled_confidences_give_a_risk_coverage_curve_and_its_report():
    from eskin.learn.evaluation import _pooled
    from eskin.learn.evaluation_report import _risk_coverage_markdown, risk_coverage_lines

    folds = [(np.array([2, 3]), np.array([0, 1])), (np.array([0, 1]), np.array([2, 3]))]
    records = [
        {"fold": 0, "accuracy": 1.0, "y_true": np.array([0, 0]), "y_pred": np.array([0, 0]),
         "dont_know": [False, True], "confidence": [0.9, 0.4], "baselines": {}},
        {"fold": 1, "accuracy": 0.5, "y_true": np.array([1, 1]), "y_pred": np.array([1, 0]),
         "dont_know": [False, True], "confidence": [0.8, 0.3], "baselines": {}},
    ]
    result = _pooled(records, folds, np.array([7, 7, 8, 8]), ["a", "b"], [], seed=0)
    assert result["predictions"]["confidence"] == [0.9, 0.4, 0.8, 0.3]
    rc = result["risk_coverage"]
    assert rc["coverage"][-1] == 1.0 and rc["error"][-1] == 0.25
    assert rc["error"][9] == 0.0  # half the recordings: the two most confident, both right
    assert all("confidence" not in f for f in result["folds"])
    assert risk_coverage_lines(rc) == [
        "risk-coverage     error 25.0 % at 100 %, 0.0 % at 75 %, 0.0 % at 50 % coverage (the "
        "most confident decided, the rest flagged)"]
    md = "\n".join(_risk_coverage_markdown(result))
    assert "## \"Don't know\" and the risk-coverage curve" in md
    assert "| error on the decided | 0.0 % | 0.0 % | 0.0 % | 25.0 % |" in md
    # a fold without confidences (the paper's rule) leaves the curve out
    records[1]["confidence"] = [None, None]
    assert "risk_coverage" not in _pooled(records, folds, np.array([7, 7, 8, 8]), ["a", "b"],
                                          [], seed=0)


def test_the_interval_level_sets_the_percentiles():
    """The ten one-recording groups above (a resample's accuracy k/10, k binomial(10, 1/2)):
    the 50 % interval is the quartiles, 0.4 and 0.6 (P(k <= 3) = 17 %, P(k <= 4) = 38 %),
    narrower than the 95 % one; accuracy and balanced accuracy (one class) agree."""
    y_true = np.zeros(10, np.int64)
    y_pred = np.tile([0, 1], 5)
    ci = group_bootstrap_ci(y_true, y_pred, np.arange(10), 2, level=0.5, seed=0)
    assert ci == {"accuracy": [0.4, 0.6], "balanced_accuracy": [0.4, 0.6]}


def test_accuracy_and_balanced_accuracy_intervals_are_not_swapped():
    """Nine groups of class 0, all right, and one of class 1, wrong: accuracy 0.9, balanced
    accuracy 0.5 (the mean of recalls 1 and 0). A resample holding the class-1 group m times
    (m binomial(10, 1/10)) has accuracy 1 - m/10 (m <= 3 in 98.7 % of them, m = 0 in 35 %)
    and balanced accuracy 0.5, or 1 when m = 0."""
    y_true = np.array([0] * 9 + [1])
    y_pred = np.zeros(10, np.int64)
    acc, bal, _ = scores_from_confusion(confusion_matrix(y_true, y_pred, 2))
    assert (acc, bal) == (0.9, 0.5)
    ci = group_bootstrap_ci(y_true, y_pred, np.arange(10), 2, seed=0)
    assert ci == {"accuracy": [0.7, 1.0], "balanced_accuracy": [0.5, 1.0]}


def test_grouped_folds_are_the_stratified_split_when_it_is_valid():
    """Eight groups of three, two of them all class 0: StratifiedGroupKFold gives three
    non-empty folds, and those are the plan (not the fallback's dealing, which differs)."""
    from sklearn.model_selection import StratifiedGroupKFold

    from eskin.learn.evaluation import _dealt_folds

    groups = np.repeat(np.arange(8), 3)
    y = np.tile([0, 1, 2], 8)
    y[:6] = 0
    for seed in (0, 1):
        plan = [te.tolist() for _, te in make_folds(groups, y, 3, seed)]
        split = StratifiedGroupKFold(3, shuffle=True, random_state=seed).split(y, y, groups)
        assert plan == [sorted(te.tolist()) for _, te in split]
        assert plan != [te.tolist() for te in _dealt_folds(groups, 3, seed)]


def test_risk_coverage_counts_any_disagreement_as_an_error():
    """Errors in both directions (a true 0 called 1, a true 1 called 0) count alike."""
    from eskin.learn.evaluation import risk_coverage

    rc = risk_coverage(np.array([0, 1, 0, 1]), np.array([0, 1, 1, 0]), np.array([4, 3, 2, 1.0]),
                       points=4)
    assert rc["error"] == [0.0, 0.0, 1 / 3, 0.5]


def test_settings_equal_in_every_fold_are_given_once():
    from eskin.learn.evaluation import _folds_trained_with

    records = [{"trained_with": {"amplitudes": [0.5, 1.0], "D": 20, "hold_s": None}},
               {"trained_with": {"amplitudes": [0.5, 1.0], "D": 30, "hold_s": None}}]
    assert _folds_trained_with(records) == {"amplitudes": [0.5, 1.0], "D": [20, 30],
                                            "hold_s": None}
    assert _folds_trained_with([]) == {}
    assert _folds_trained_with(records[:1]) == records[0]["trained_with"]


def test_a_fold_record_without_predictions_keeps_its_other_live_scores():
    from eskin.learn.evaluation import _without_predictions

    record = {"fold": 0, "accuracy": 0.5, "y_true": [0], "y_pred": [1], "dont_know": [False],
              "confidence": [0.3],
              "live": {"accuracy": 0.25, "touches": 4, "per_recording": [1, 0]},
              "baselines": {"nearest": {"accuracy": 0.75, "y_pred": [0], "z_score": 1.0}}}
    assert _without_predictions(record) == {
        "fold": 0, "accuracy": 0.5, "live": {"accuracy": 0.25, "touches": 4},
        "baselines": {"nearest": {"accuracy": 0.75, "z_score": 1.0}}}  # (z sorts after y)


def test_a_stratified_split_with_an_empty_fold_gives_way_to_dealt_groups():
    """Four groups in four folds, where scikit-learn's StratifiedGroupKFold (seed 1) leaves a
    fold empty: the groups are dealt instead, one per fold."""
    from sklearn.model_selection import StratifiedGroupKFold

    from eskin.learn.evaluation import _dealt_folds

    groups = np.array([0, 0, 1, 2, 2, 2, 3, 3, 3])
    y = np.array([0, 0, 1, 1, 1, 1, 1, 0, 1])
    import warnings

    with warnings.catch_warnings():  # "the least populated class has only 3 members"
        warnings.simplefilter("ignore", UserWarning)
        split = list(StratifiedGroupKFold(4, shuffle=True, random_state=1).split(y, y, groups))
    assert sorted(len(te) for _, te in split) == [0, 3, 3, 3]
    plan = [te.tolist() for _, te in make_folds(groups, y, 4, seed=1)]
    assert plan == [te.tolist() for te in _dealt_folds(groups, 4, 1)]
    assert sorted(len(te) for te in plan) == [1, 2, 3, 3]


def test_the_fold_count_runs_from_2_to_the_number_of_groups():
    groups, y = np.array([0, 1, 2, 0, 1, 2]), np.array([0, 1, 0, 1, 0, 1])
    for n in (2, 3):
        assert len(make_folds(groups, y, n)) == n
    for n in (1, 4):
        with pytest.raises(EvaluationError) as refused:
            make_folds(groups, y, n)
        assert str(refused.value) == f"--folds {n}: must be in [2, 3] (the number of groups)"


def test_a_campaigns_parts_rebuild_its_recordings_for_a_worker(sim_campaign):
    """What a fold sends to a cluster worker (settings and arrays of the recordings it uses)
    opens there as the same recordings, labels, groups and settings."""
    from eskin.data.campaign import load_campaign
    from eskin.learn.evaluation import _opened, _parts

    used = np.array([5, 0, 7])
    with load_campaign(sim_campaign) as camp:
        want = camp.subset(used).load()
        meta, arrays = _parts(camp, used)
    with _opened(meta, arrays) as got:
        assert len(got) == 3 and got.path == want.path
        for k in ("signals", "lengths", "modality", "participant", "direction", "run"):
            np.testing.assert_array_equal(np.asarray(getattr(got, k)), np.asarray(getattr(want, k)))
        np.testing.assert_array_equal(got.contact_interval, want.contact_interval)
        assert (got.modalities, got.sample_rate_hz, got.volts_per_count, got.source) == (
            want.modalities, want.sample_rate_hz, want.volts_per_count, want.source)
        assert got.attrs == want.attrs and got.extras.keys() == want.extras.keys()


def test_a_campaigns_parts_are_refused_when_they_would_not_fit_in_memory(sim_campaign,
                                                                          monkeypatch):
    """Before a fold's recordings are read to be sent to a cluster, their bytes (int16
    samples: recordings x rows x cols x padded length x 2) are checked against the memory
    available: exactly that many fit, one byte less is refused, naming the campaign's file
    (or "campaign" for one in memory)."""
    import dataclasses

    from eskin.data import limits
    from eskin.data.campaign import load_campaign
    from eskin.learn.evaluation import _from_parts, _parts

    used = np.array([5, 0, 7])

    def check(camp, name):
        _, rows, cols, t = camp.signals.shape
        need = len(used) * rows * cols * t * 2
        monkeypatch.setattr(limits, "available_memory", lambda: need)
        assert len(_parts(camp, used)[1]["signals"]) == 3
        monkeypatch.setattr(limits, "available_memory", lambda: need - 1)
        with pytest.raises(EvaluationError) as refused:
            _parts(camp, used)
        assert str(refused.value).startswith(f"{name}: sending the recordings to the cluster "
                                             "would take ")

    with load_campaign(sim_campaign) as camp:
        check(camp, str(sim_campaign))
        monkeypatch.undo()
        meta, arrays = _parts(camp, np.arange(len(camp)))
    check(_from_parts(dataclasses.replace(meta, path=None), arrays), "campaign")


def test_class_ids_follow_the_given_classes_and_mark_others_minus_one(sim_campaign):
    from eskin.data.campaign import load_campaign
    from eskin.learn.evaluation import _class_ids

    with load_campaign(sim_campaign) as camp:
        names = [str(m) for m in camp.modalities]
        modality = np.asarray(camp.modality)
        classes = tuple(reversed(names[1:]))  # the first class left out
        idx = np.arange(len(camp))
        want = [len(names) - 1 - int(m) if m > 0 else -1 for m in modality]
        assert _class_ids(camp, idx, classes).tolist() == want
        assert -1 in want and 0 in want


def test_an_evaluation_needs_two_distinct_classes_and_its_folds_are_seeded_with_0(sim_campaign):
    from eskin.data.campaign import load_campaign
    from eskin.learn.evaluation import plan_folds

    with load_campaign(sim_campaign) as camp:
        names = [str(m) for m in camp.modalities]
        for chosen in ([names[0]], [names[0], names[0]]):
            with pytest.raises(EvaluationError) as refused:
                plan_folds(camp, classes=chosen)
            assert str(refused.value) == f"at least 2 classes are needed, got {chosen}"
        folds, got, _ = plan_folds(camp, classes=names[:2], n_folds=2)
        assert got == names[:2] and len(folds) == 2

        def plan(**seed):
            return [te.tolist() for _, te in plan_folds(camp, n_folds=2, **seed)[0]]

        assert plan() == plan(seed=0) != plan(seed=1)


def test_an_evaluation_of_a_loaded_campaign_is_that_of_its_path_with_seed_0(tmp_path):
    """evaluate_recipe takes a loaded campaign as well as its path, and its seed is 0 unless
    given: the same folds, predictions and scores."""
    from learn_data import user_campaign

    from eskin.data.campaign import load_campaign
    from eskin.learn.evaluation import evaluate_recipe

    path = user_campaign(tmp_path)
    recipe = {"quick": True, "D": 5, "window": "none", "seed": 99}
    by_path = evaluate_recipe(str(path), recipe=recipe, n_folds=2, seed=0)
    with load_campaign(path) as camp:
        loaded = evaluate_recipe(camp, recipe=recipe, n_folds=2)
    assert loaded["predictions"] == by_path["predictions"] and loaded["seed"] == 0
    assert (loaded["accuracy"], loaded["ci95"]) == (by_path["accuracy"], by_path["ci95"])


def test_local_folds_never_read_all_their_recordings_into_memory_first(
        tmp_path, monkeypatch):
    """Only recordings sent to a Dask cluster are read into memory first (and checked against
    the memory available); without a cluster the folds read them from the file as they go, so
    an evaluation runs with less memory available than its recordings take."""
    from learn_data import user_campaign

    from eskin.data import limits
    from eskin.data.campaign import load_campaign
    from eskin.learn.evaluation import evaluate_recipe

    path = user_campaign(tmp_path)
    with load_campaign(path) as camp:
        need = int(np.prod(camp.signals.shape)) * 2
    monkeypatch.setattr(limits, "available_memory", lambda: need - 1)
    res = evaluate_recipe(str(path), recipe={"quick": True, "D": 5, "window": "none"},
                          n_folds=2)
    assert len(res["predictions"]) > 0


def test_dont_know_scores_count_errors_both_ways_and_nothing_of_no_recordings():
    from eskin.learn.evaluation import dont_know_scores

    y_true, y_pred = np.array([0, 1, 2, 1, 0]), np.array([0, 2, 1, 1, 0])  # wrong up and down
    s = dont_know_scores(y_true, y_pred, np.array([False, False, True, False, True]))
    assert s == {"flagged": 0.4, "n_flagged": 2, "accuracy_decided": 2 / 3,
                 "accuracy_flagged": 0.5}
    empty = np.array([], np.int64)
    assert dont_know_scores(empty, empty, np.array([], bool)) == {
        "flagged": 0.0, "n_flagged": 0, "accuracy_decided": None, "accuracy_flagged": None}
