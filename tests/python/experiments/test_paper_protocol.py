"""The paper's protocol: splits, problems, exclusion, run_experiment outputs and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from learn_data import USER_CLASSES, small_simulated, user_campaign
from typer.testing import CliRunner

from eskin.experiments import paper_tables
from eskin.experiments.paper_protocol import (
    ExperimentError,
    binary_split,
    n_train_participants,
    one_vs_all_training_set,
    resolve_problems,
    run_experiment,
    split_participants,
)
from eskin.experiments.report import render_markdown, write_report


@pytest.fixture(scope="module")
def sim_path(tmp_path_factory) -> Path:
    return small_simulated(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="module")
def quick_out(sim_path, tmp_path_factory) -> Path:
    """`eskin experiment --quick` on the small simulated campaign, through the CLI."""
    from eskin.cli import app

    out = tmp_path_factory.mktemp("exp") / "quick"
    res = CliRunner().invoke(
        app,
        [
            "experiment",
            str(sim_path),
            "--out",
            str(out),
            "--quick",
            "--D",
            "20",
            "--n-jobs",
            "1",
            "--no-progress",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "simulated" in res.output
    return out


# ------------------------------------------------------------------------------------ splits
def paper_layout(n_participants: int = 65, n_classes: int = 3, gestures: int = 2):
    parts = np.repeat(np.arange(100, 100 + n_participants), n_classes * gestures)
    labels = np.tile(np.repeat(np.arange(n_classes), gestures), n_participants)
    return labels, parts


def test_paper_split_sizes():
    labels, parts = paper_layout()
    n_tr = n_train_participants(65)
    assert n_tr == 45
    tr_p, te_p = split_participants(parts, n_tr, seed=4)
    assert len(tr_p) == 45 and len(te_p) == 20
    for a, b in [(0, 2), (0, 1), (2, 1)]:  # A, B, C
        tr, va = binary_split(labels, parts, [a, b], tr_p)
        assert (len(tr), len(va)) == (180, 80)
        assert not set(parts[tr]) & set(parts[va])
    rng = np.random.default_rng(0)
    for k in range(3):
        idx, y = one_vs_all_training_set(labels, parts, k, [0, 1, 2], tr_p, rng)
        assert len(idx) == 180 and y.sum() == 90
        assert set(parts[idx]) <= set(tr_p)
        assert np.all((labels[idx] == k) == (y == 1))
    test = np.flatnonzero(~np.isin(parts, tr_p))
    assert len(test) == 120


@settings(max_examples=40, deadline=None)
@given(
    n_participants=st.integers(2, 40),
    n_classes=st.integers(2, 5),
    gestures=st.integers(1, 3),
    seed=st.integers(0, 2**31 - 1),
)
def test_splits_are_participant_disjoint(n_participants, n_classes, gestures, seed):
    labels, parts = paper_layout(n_participants, n_classes, gestures)
    n_tr = n_train_participants(n_participants)
    assert 1 <= n_tr < n_participants
    tr_p, te_p = split_participants(parts, n_tr, seed)
    assert len(tr_p) == n_tr and len(te_p) == n_participants - n_tr
    assert not set(tr_p) & set(te_p)
    assert set(tr_p) | set(te_p) == set(parts)
    again = split_participants(parts, n_tr, seed)
    assert np.array_equal(again[0], tr_p)
    tr, va = binary_split(labels, parts, [0, n_classes - 1], tr_p)
    assert len(tr) == n_tr * 2 * gestures
    assert len(va) == (n_participants - n_tr) * 2 * gestures
    assert not set(parts[tr]) & set(parts[va])
    assert set(labels[tr]) | set(labels[va]) == {0, n_classes - 1}
    rng = np.random.default_rng(seed)
    idx, y = one_vs_all_training_set(labels, parts, 0, list(range(n_classes)), tr_p, rng)
    assert y.sum() == n_tr * gestures == len(y) - y.sum()
    assert len(np.unique(idx)) == len(idx)
    assert set(parts[idx]) <= set(tr_p)


def test_split_rejects_impossible_sizes():
    with pytest.raises(ExperimentError, match="participants"):
        split_participants([1, 1, 2], 2, 0)
    with pytest.raises(ExperimentError, match="at least 2"):
        n_train_participants(1)


def test_problem_presets_and_pairs():
    names = ["brush", "finger", "washer"]
    assert resolve_problems(None, names) == paper_tables.PAPER_PROBLEMS
    assert resolve_problems(["A", "finger,brush"], names) == {
        "A": ("brush", "washer"),
        "finger vs brush": ("finger", "brush"),
    }
    user = resolve_problems(None, USER_CLASSES)
    assert len(user) == 6 and user["tap vs pinch"] == ("tap", "pinch")
    with pytest.raises(ExperimentError, match="unknown class"):
        resolve_problems(["brush,glove"], names)
    with pytest.raises(ExperimentError, match="distinct"):
        resolve_problems([("brush", "brush")], names)


def test_paper_tables_transcribed():
    for m in ("svm", "rls"):
        for p in "ABC":
            for D in (20, 50, 100):
                cells = paper_tables.BINARY[m][p][D]
                assert len(cells) == 5
                assert all(c[3] in ("1", "Q/2", "Q", "0") for c in cells)
    assert paper_tables.paper_cell("svm", "A", 50, 2) == (2.5, 1, 2.0, "0")
    assert paper_tables.paper_mean("rls", "C", 100) == pytest.approx(13.0)
    assert paper_tables.MULTICLASS["rls"]["average"] == 26.3


# ------------------------------------------------------------------------- the whole protocol
def test_quick_experiment_writes_everything(quick_out):
    for name in (
        "results.json",
        "report.md",
        "figure6.png",
        "figure7.png",
        "confusion_binary.png",
        "confusion_multiclass.png",
    ):
        assert (quick_out / name).is_file(), name
    res = json.loads((quick_out / "results.json").read_text())
    assert res["schema"] == "eskin.experiment/1"
    assert res["campaign"]["simulated"] is True
    assert set(res["versions"]) >= {"eskin", "numpy", "scikit-learn"}
    p = res["protocol"]
    assert p["quick"] and p["runs"] == 2 and p["Ds"] == [20]
    a = res["analysis_set"]
    assert a["n_participants"] == 6 and a["excluded_participants"] == []
    assert a["n_patterns"] == 36
    # one MD and one CV selection per (problem, run, D, machine)
    assert len(res["binary"]) == 3 * 2 * 1 * 2 * 2
    for d in res["binary"]:
        assert d["n_train"] == 16 and d["n_val"] == 8
        sel = d["selected"]
        assert sel["alpha"] in ("1", "Q/2") and sel["sigma"] in (0.5, 2.0)
        assert sel["lambda"] in (0.01, 1.0)
        if d["machine"] == "svm":
            assert sel["C"] == pytest.approx(1 / sel["lambda"])
        assert 0.0 <= d["error"] <= 1.0
        assert np.sum(d["confusion"]) == d["n_val"]
        if d["selection"] == "md":
            assert {"train_error", "chi", "tau", "bound"} <= set(d["selection_terms"])
    # the splits are the same for MD and CV and never share a participant
    for sp in res["splits"]:
        assert not set(sp["train_participants"]) & set(sp["test_participants"])
    assert len(res["baseline"]) == 3 * 2
    assert len(res["subsampling"]["rows"]) == 3 * 2
    mc = res["multiclass"]
    assert mc["ran"] and len(mc["runs"]) == 2 * 2
    for d in mc["runs"]:
        assert d["n_test"] == 12 and len(d["selected"]) == 3
        assert np.sum(d["confusion"]) == 12
    s = res["summary"]
    assert set(s["md_vs_cv_overall"]) == {"svm", "rls"}


def test_report_layout(quick_out):
    text = (quick_out / "report.md").read_text()
    assert "**The data are simulated**" in text
    for k in range(1, 7):
        assert f"### Table {k}:" in text
    assert "Table 7" in text and "D=20 paper" in text and "D=50 paper" not in text
    assert "MD vs CV, tensor-SVM" in text and "MD vs CV, tensor-RLS" in text
    assert "algorithm2" in text and "even" in text
    assert "D=20 ours" in text
    assert "Both machines show lambda" in text
    # which reading of Algorithm 1 ran, by name and in words (quick: N = 3 labellings)
    line = next(t for t in text.splitlines() if t.startswith("- Algorithm 1 as run: "))
    assert "reading 'default'" in line and "n_labelings=3" in line and "plain Lloyd" in line
    # the report can be rebuilt from results.json alone
    res = json.loads((quick_out / "results.json").read_text())
    assert render_markdown(res, []).startswith("# eskin experiment report")
    out = write_report(res, quick_out / "again", figures=False)
    assert out.read_text().count("### Table") == 6


def test_user_campaign_experiment(tmp_path_factory):
    """A 3x5 grid at 1000 Hz, 4 classes, no run 2, recordings shorter than D, window off."""
    path = user_campaign(tmp_path_factory.getbasetemp())
    out = tmp_path_factory.mktemp("user_exp")
    res = run_experiment(
        path,
        out,
        quick=True,
        Ds=(50,),
        window="none",
        problems=["tap,stroke", "press,pinch"],
        progress=False,
        baseline=False,
    )
    assert res["campaign"]["simulated"] is False
    assert res["campaign"]["grid_shape"] == [3, 5]
    assert res["analysis_set"]["run"] is None
    assert any("no run 2" in n for n in res["analysis_set"]["notes"])
    assert set(res["problems"]) == {"tap vs stroke", "press vs pinch"}
    assert res["multiclass"]["ran"] and res["multiclass"]["classes"] == USER_CLASSES
    for d in res["multiclass"]["runs"]:
        assert len(d["selected"]) == 4 and np.shape(d["confusion"]) == (4, 4)
    text = (out / "report.md").read_text()
    assert "simulated" not in text.split("## Binary")[0].lower()
    assert "### problem tap vs stroke" in text


def test_experiment_errors(sim_path, tmp_path):
    with pytest.raises(ExperimentError, match="unknown class"):
        run_experiment(sim_path, tmp_path, quick=True, problems=["brush,glove"], progress=False)
    with pytest.raises(ExperimentError, match="unknown option"):
        run_experiment(sim_path, tmp_path, quick=True, progress=False, colour="red")
    from eskin.cli import app

    res = CliRunner().invoke(
        app,
        [
            "experiment",
            str(tmp_path / "none.h5"),
            "--out",
            str(tmp_path / "o"),
            "--quick",
            "--no-progress",
        ],
    )
    assert res.exit_code == 2
    assert "none.h5" in res.output


def test_cli_problem_option_parsing():
    from eskin.cli.learn import _problems

    assert _problems(None) is None
    assert _problems("A,B") == ["A", "B"]
    assert _problems("brush:washer;finger:washer") == ["brush,washer", "finger,washer"]
    names = ["brush", "finger", "washer"]
    assert resolve_problems(_problems("brush:washer;C"), names) == {
        "brush vs washer": ("brush", "washer"),
        "C": ("washer", "finger"),
    }


def test_window_lengths_the_paper_can_be_compared_with():
    from eskin.errors import ExperimentError
    from eskin.experiments.paper_protocol import check_window_lengths

    check_window_lengths((16, 20, 21000), (4, 4), 21000)
    with pytest.raises(ExperimentError, match=r"D = 15 is below the 16 taxels of the 4x4 grid"):
        check_window_lengths((20, 15), (4, 4), 21000)
    with pytest.raises(ExperimentError, match=r"D = 21001 is longer than every recording"):
        check_window_lengths((21001,), (4, 4), 21000)
    check_window_lengths((6,), (2, 3), 100)


def test_a_small_analysis_set_says_it_cannot_be_compared():
    from eskin.experiments.report import too_small_note

    assert too_small_note(65) == "" and too_small_note(70) == ""
    assert too_small_note(3).startswith("3 participants in the analysis set (the paper: 65")
