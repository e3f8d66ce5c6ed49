"""Any real campaign trains: low and high rates, short segments, odd grids, many or few classes.

The campaigns are written as campaign files with the project's writer, shaped like the
recordings users bring: cut gesture segments of a capacitive grid (a DC offset on every taxel,
each class a blob of pressure at its own place with its own time course), from 3 to 450
samples long.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest


def shaped_campaign(
    path: Path,
    *,
    rows: int,
    cols: int,
    rate: float,
    min_len: int = 3,
    max_len: int = 450,
    counts: list[int] | None = None,
    participants: int = 4,
    seed: int = 0,
) -> Path:
    """``counts[k]`` recordings of class k per participant (default 3 of each of 3 classes);
    each participant's first recording of a class has ``min_len`` samples, the second
    ``max_len``, the others a random length in between."""
    from eskin.data.campaign import write_campaign

    counts = counts or [3, 3, 3]
    rng = np.random.default_rng(seed)
    rr, cc = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    recs, mod, part = [], [], []
    for p in range(participants):
        for k, n_rep in enumerate(counts):
            centre = ((k * 0.37) % 1 * (rows - 1), (k * 0.61) % 1 * (cols - 1))
            blob = np.exp(-((rr - centre[0]) ** 2 + (cc - centre[1]) ** 2) / (2 + 0.2 * k))
            for rep in range(n_rep):
                length = (min_len, max_len)[rep] if rep < 2 else int(rng.integers(min_len, max_len))
                t = np.linspace(0.0, 1.0, length)
                course = np.sin(np.pi * t) ** (1 + k % 3) * (
                    1 + 0.3 * np.sin(2 * np.pi * (k + 1) * t)
                )
                sig = 400 + 2000 * rng.uniform(0.7, 1.3) * blob[..., None] * course
                sig = sig + 20 * rng.standard_normal((rows, cols, length))
                recs.append(np.clip(sig, -32000, 32000).astype(np.int16))
                mod.append(k)
                part.append(p)
    n = len(recs)
    write_campaign(
        path,
        recs,
        modality=mod,
        participant=part,
        direction=[255] * n,
        run=[1] * n,
        modalities=[f"gesture{k}" for k in range(len(counts))],
        sample_rate_hz=rate,
        volts_per_count=1e-3,
        source="recorded",
    )
    return path


def _run(args: list[str]):
    from typer.testing import CliRunner

    from eskin.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.mark.parametrize(
    ("rows", "cols", "rate", "window"),
    [
        (19, 27, 10.0, "energy"),
        (19, 27, 10.0, "none"),
        (1, 4, 100.0, "energy"),
        (1, 4, 100.0, "none"),
    ],
)
def test_low_rate_campaigns_train_evaluate_and_predict(tmp_path, rows, cols, rate, window):
    camp = shaped_campaign(tmp_path / "c.h5", rows=rows, cols=cols, rate=rate, participants=3)
    model = tmp_path / "m.joblib"
    r = _run(
        ["train", camp, "-o", model, "--all-classes", "--quick", "--D", 20, "--window", window]
    )
    assert r.exit_code == 0, r.output
    if rate == 10.0 and window == "energy":  # the default 5 Hz DC cutoff cannot apply
        assert (
            "note: WindowConfig.dc_cutoff_hz = 5 Hz is not below half the sample rate" in r.output
        )
    r = _run(["predict", model, camp, "--json", tmp_path / "p.json"])
    assert r.exit_code == 0, r.output
    preds = json.loads((tmp_path / "p.json").read_text())
    assert len(preds) == 27 and all(p["label"].startswith("gesture") for p in preds)
    r = _run(["evaluate", camp, "--out", tmp_path / "ev", "--quick", "--D", 20, "--window", window])
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert len(res["folds"]) == 3 and res["n_recordings"] == 27


def check_trained_model(model_path: Path, camp: Path, *, rate: float, grid: tuple[int, int],
                        n_classes: int, D: int) -> None:
    """The model file holds what was trained (classes, grid, rate, D), classifies every
    recording of its campaign into one of its classes with finite decision values, and the
    compiled classifier reading it decides the same."""
    from eskin.data.campaign import load_campaign
    from eskin.deploy.export import compiled_engine
    from eskin.learn.models import load_model

    model = load_model(model_path)
    assert model.classes == [f"gesture{k}" for k in range(n_classes)]
    assert tuple(model.grid_shape) == grid
    assert model.sample_rate_hz == rate and model.D == D
    with load_campaign(camp) as c:
        py = model.predict_recordings(c)
        cpp = compiled_engine(model).predict_recordings(c)
        assert len(py) == len(c)
    assert {p["label"] for p in py} <= set(model.classes)
    values = np.array([p["decision_values"] for p in py])
    assert values.shape == (len(py), 1 if n_classes == 2 else n_classes)
    assert np.isfinite(values).all()
    assert [p["label"] for p in py] == [p["label"] for p in cpp]
    np.testing.assert_allclose(values, [p["decision_values"] for p in cpp], atol=1e-6)


def test_the_compiled_classifier_reads_a_low_rate_model(tmp_path):
    """The configuration adapted to 10 Hz is the one in the model file: the C++ classifier
    makes the same patterns and decisions as Python."""
    from eskin.data.campaign import load_campaign
    from eskin.deploy.export import compiled_engine
    from eskin.learn.models import load_model

    camp = shaped_campaign(tmp_path / "c.h5", rows=3, cols=5, rate=10.0, participants=2)
    model_path = tmp_path / "m.joblib"
    assert (
        _run(["train", camp, "-o", model_path, "--all-classes", "--quick", "--D", 12]).exit_code
        == 0
    )
    model = load_model(model_path)
    assert model.window_config.dc_cutoff_hz == pytest.approx(1.0)
    with load_campaign(camp) as c:
        py = model.predict_recordings(c)
        cpp = compiled_engine(model).predict_recordings(c)
    assert [p["label"] for p in py] == [p["label"] for p in cpp]
    np.testing.assert_allclose(
        [p["decision_values"] for p in py], [p["decision_values"] for p in cpp], atol=1e-6
    )


@pytest.mark.parametrize("rate", [1.0, 50_000.0])
def test_extreme_rates_train(tmp_path, rate):
    camp = shaped_campaign(
        tmp_path / "c.h5", rows=2, cols=2, rate=rate, participants=2, counts=[3, 3], max_len=120
    )
    r = _run(["train", camp, "-o", tmp_path / "m.joblib", "--all-classes", "--quick", "--D", 10])
    assert r.exit_code == 0, r.output
    check_trained_model(tmp_path / "m.joblib", camp, rate=rate, grid=(2, 2), n_classes=2, D=10)


@pytest.mark.parametrize(("rows", "cols"), [(1, 1), (64, 64)])
def test_extreme_grids_train(tmp_path, rows, cols):
    camp = shaped_campaign(
        tmp_path / "c.h5",
        rows=rows,
        cols=cols,
        rate=100.0,
        participants=2,
        counts=[2, 2],
        max_len=60,
    )
    r = _run(
        [
            "train",
            camp,
            "-o",
            tmp_path / "m.joblib",
            "--all-classes",
            "--quick",
            "--D",
            6,
            "--window",
            "none",
        ]
    )
    assert r.exit_code == 0, r.output
    check_trained_model(tmp_path / "m.joblib", camp, rate=100.0, grid=(rows, cols), n_classes=2, D=6)


def test_twenty_unbalanced_classes_and_a_rare_one_train_with_a_warning(tmp_path):
    counts = [1] + [2] * 18 + [6]  # per participant: a class of 3 recordings in all
    camp = shaped_campaign(
        tmp_path / "c.h5", rows=2, cols=3, rate=100.0, participants=3, counts=counts, max_len=80
    )
    r = _run(
        [
            "train",
            camp,
            "-o",
            tmp_path / "m.joblib",
            "--all-classes",
            "--quick",
            "--D",
            8,
            "--window",
            "none",
        ]
    )
    assert r.exit_code == 0, r.output
    assert "note: class gesture0 has only 3 recordings" in r.output
    check_trained_model(tmp_path / "m.joblib", camp, rate=100.0, grid=(2, 3), n_classes=20, D=8)


def test_segments_shorter_than_D_and_alpha_are_interpolated():
    """A 3-sample segment becomes D samples by linear interpolation (first and last kept);
    its time-mode unfolding then has rank <= 2 < alpha = Q_3, which the kernel's
    rank-deficient rule handles: the Gram matrix stays finite with a unit diagonal."""
    from eskin.learn.kernel import tensor_kernel

    import eskin

    seg = np.array([[[0, 10, 4], [5, 5, 5]]], dtype=np.int16)  # 1x2 grid, 3 samples
    X = eskin.preprocess(seg[None], 7, window="none")
    assert X.shape == (1, 1, 2, 7)
    np.testing.assert_allclose(X[0, 0, 0], [0, 10 / 3, 20 / 3, 10, 8, 6, 4])
    np.testing.assert_allclose(X[0, 0, 1], 5.0)
    other = eskin.preprocess(np.array([[[[3, 1, 4], [1, 5, 9]]]], np.int16), 7, window="none")
    K = tensor_kernel(np.concatenate([X, other]), sigma=1.0, alpha="full")
    assert np.all(np.isfinite(K)) and np.allclose(np.diag(K), 1.0)


def test_the_experiment_report_says_when_the_detector_was_adapted_to_the_rate(tmp_path):
    from eskin.experiments.paper_protocol import run_experiment

    camp = shaped_campaign(tmp_path / "c.h5", rows=3, cols=5, rate=10.0, participants=4)
    res = run_experiment(
        camp, tmp_path / "exp", quick=True, Ds=(20,), problems=["gesture0,gesture1"],
        progress=False, baseline=False, runs=1,
    )
    notes = res["analysis_set"]["notes"]
    assert any("WindowConfig.dc_cutoff_hz = 5 Hz is not below half the sample rate" in n
               for n in notes), notes
    assert "dc_cutoff_hz = 5 Hz" in (tmp_path / "exp" / "report.md").read_text()


def test_the_defaults_train_on_gestures_shorter_than_the_default_D(tmp_path):
    """eskin train with no options on 10 Hz gestures of 3 to 10 frames: D becomes at most the
    longest recording, and no more than the median touch window fills, each with a note;
    evaluate and predict run on the model."""
    from eskin.learn.grids import DEFAULT_D
    from eskin.learn.models import load_model

    camp = shaped_campaign(
        tmp_path / "c.h5", rows=19, cols=27, rate=10.0, participants=3, min_len=3, max_len=10
    )
    model = tmp_path / "m.joblib"
    r = _run(["train", camp, "-o", model, "--all-classes", "--quick", "--no-progress"])
    assert r.exit_code == 0, r.output
    assert (
        f"note: the training recordings are at most 10 samples long: D = 10 instead of "
        f"{DEFAULT_D}" in r.output
    )
    fill = re.search(r"note: the median training touch window is (\d+) samples long: D = "
                     r"(\d+) instead of 10", r.output)
    assert fill is not None, r.output
    assert 2 <= int(fill.group(1)) < 10 and load_model(model).D == int(fill.group(2))
    assert _run(["predict", model, camp]).exit_code == 0
    r = _run(["evaluate", camp, "--out", tmp_path / "ev", "--quick"])
    assert r.exit_code == 0, r.output
    r = _run(["train", camp, "-o", model, "--all-classes", "--quick", "--D", 11, "--force"])
    assert r.exit_code == 2 and "--D 11 is longer than every recording" in r.output


def test_the_default_D_is_100_when_the_recordings_allow_it(tmp_path):
    from eskin.learn.training import train_model

    camp = shaped_campaign(tmp_path / "c.h5", rows=2, cols=2, rate=100.0, participants=2,
                           counts=[3, 3], min_len=100, max_len=150)
    model = train_model(camp, quick=True)
    assert {r["D"] for r in model.training["recipe_search"]["recipes"]} <= {20, 50, 100}
    assert 100 in {r["D"] for r in model.training["recipe_search"]["recipes"]}
    assert not any("samples long" in n for n in model.training["notes"])
    assert train_model(camp, selection="md", quick=True).D == 100  # D not searched
