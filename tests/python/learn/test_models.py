"""Deployable models: train, save, load, predict (API and CLI), any campaign, clear errors."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import joblib
import numpy as np
import pytest
from learn_data import USER_CLASSES, small_simulated, user_campaign
from typer.testing import CliRunner

from eskin.cli import app
from eskin.errors import ModelFormatError, TrainingError
from eskin.learn.models import TouchModel, error_rate, load_model, save_model
from eskin.learn.training import train_model

runner = CliRunner()


@pytest.fixture(scope="module")
def sim_path(tmp_path_factory) -> Path:
    return small_simulated(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="module")
def user_path(tmp_path_factory) -> Path:
    return user_campaign(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="module")
def binary_model(sim_path) -> TouchModel:
    return train_model(
        sim_path,
        classes=["brush", "washer"],
        machine="svm",
        selection="md",
        D=20,
        quick=True,
        seed=1,
    )


def test_binary_model_round_trip(binary_model, sim_path, tmp_path):
    from eskin.data.campaign import load_campaign

    m = binary_model
    assert m.classes == ["brush", "washer"] and m.is_binary
    assert m.pattern_shape == (4, 4, 20)
    assert m.training["n_patterns"] == 24
    assert m.selected[0]["alpha"] in ("1", "Q/2")
    path = save_model(m, tmp_path / "m.joblib")
    back = load_model(path)
    assert back.classes == m.classes and back.D == m.D and back.window == m.window
    camp = load_campaign(sim_path)
    p1 = m.predict_recordings(camp)
    p2 = back.predict_recordings(camp)
    assert p1 == p2
    assert len(p1) == len(camp)
    for p in p1:
        assert p["label"] in m.classes
        assert len(p["decision_values"]) == 1
        assert (p["decision_values"][0] > 0) == (p["label"] == "washer")
        assert p["true_label"] in ("brush", "finger", "washer")
    err, n = error_rate(p1, m.classes)
    assert n == 24 and 0.0 <= err <= 1.0
    # patterns in, names out
    X = m.preprocess(camp, [0, 1, 2])
    assert X.shape == (3, 4, 4, 20)
    assert list(m.predict(X)) == [p["label"] for p in p1[:3]]


def test_cli_train_predict_json(sim_path, tmp_path):
    model = tmp_path / "three.joblib"
    res = runner.invoke(
        app,
        [
            "train",
            str(sim_path),
            "--all-classes",
            "--machine",
            "rls",
            "--selection",
            "cv",
            "--D",
            "20",
            "--subsample",
            "algorithm2",
            "--negatives",
            "all",
            "--quick",
            "-o",
            str(model),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "brush vs rest" in res.output
    out = tmp_path / "pred.json"
    res = runner.invoke(app, ["predict", str(model), str(sim_path), "--json", str(out)])
    assert res.exit_code == 0, res.output
    assert "error rate:" in res.output
    preds = json.loads(out.read_text())
    assert isinstance(preds, list) and len(preds) == 36
    assert [p["index"] for p in preds] == list(range(36))
    for p in preds:
        assert set(p) >= {"index", "label", "decision_values", "true_label", "dont_know"}
        assert len(p["decision_values"]) == 3
        assert p["label"] in ("brush", "finger", "washer")
    # the calibrated rule (the default): the label of the largest calibrated score, flagged
    # below the model's confidence threshold
    from eskin.learn.calibration import calibrated_decision

    cal = load_model(model).calibration
    F = np.array([p["decision_values"] for p in preds])
    idx, conf, dk = calibrated_decision(F, cal.slopes, cal.offsets, cal.threshold, False)
    assert [p["label"] for p in preds] == [["brush", "finger", "washer"][i] for i in idx]
    assert [p["dont_know"] for p in preds] == dk.tolist()
    np.testing.assert_allclose([p["confidence"] for p in preds], conf, rtol=1e-12)
    assert "don't know:" in res.output


def test_user_campaign_end_to_end(user_path, tmp_path):
    """3x5 taxels at 1000 Hz, 4 classes, cut recordings (some shorter than D), window off."""
    model = tmp_path / "user.joblib"
    res = runner.invoke(
        app,
        [
            "train",
            str(user_path),
            "--all-classes",
            "--machine",
            "svm",
            "--selection",
            "md",
            "--D",
            "50",
            "--window",
            "none",
            "--quick",
            "-o",
            str(model),
        ],
    )
    assert res.exit_code == 0, res.output
    m = load_model(model)
    assert m.classes == USER_CLASSES and m.grid_shape == (3, 5) and m.sample_rate_hz == 1000.0
    assert m.window == "none" and len(m.estimator.estimators_) == 4
    out = tmp_path / "p.json"
    res = runner.invoke(app, ["predict", str(model), str(user_path), "--json", str(out)])
    assert res.exit_code == 0, res.output
    preds = json.loads(out.read_text())
    assert len(preds) == 48 and all(len(p["decision_values"]) == 4 for p in preds)
    err, n = error_rate(preds, m.classes)
    assert n == 48
    assert err < 0.5  # the classes are well separated; chance is 0.75
    # a binary model from arrays, labels as names
    from eskin.data.campaign import load_campaign

    c = load_campaign(user_path)
    sig = np.stack(
        [np.pad(c.recording(i), ((0, 0), (0, 0), (0, 400 - c.lengths[i]))) for i in range(len(c))]
    )
    names = np.array([USER_CLASSES[k] for k in c.modality])
    keep = np.isin(names, ["tap", "pinch"])
    mb = train_model(
        sig[keep],
        names[keep],
        lengths=c.lengths[keep],
        sample_rate_hz=1000.0,
        machine="rls",
        selection="md",
        D=50,
        window="none",
        quick=True,
    )
    assert mb.classes == ["pinch", "tap"] and mb.is_binary
    assert set(mb.predict(mb.preprocess(sig[keep][:4]))) <= {"pinch", "tap"}


def test_unknown_class_is_a_clear_error(sim_path, tmp_path):
    with pytest.raises(TrainingError, match="unknown class.*glove"):
        train_model(sim_path, classes=["brush", "glove"], quick=True)
    res = runner.invoke(
        app,
        [
            "train",
            str(sim_path),
            "--classes",
            "brush,glove",
            "--quick",
            "-o",
            str(tmp_path / "x.joblib"),
        ],
    )
    assert res.exit_code == 2
    assert "glove" in res.output and "Traceback" not in res.output
    with pytest.raises(TrainingError, match="at least 2 classes"):
        train_model(sim_path, classes=["brush"], quick=True)


def test_bad_model_files(tmp_path, binary_model, sim_path):
    text = tmp_path / "notes.txt"
    text.write_text("not a model")
    with pytest.raises(ModelFormatError, match="not an eskin model"):
        load_model(text)
    other = tmp_path / "other.joblib"
    joblib.dump({"header": {"format": "something-else"}, "model": 3}, other)
    with pytest.raises(ModelFormatError, match="format 'something-else'"):
        load_model(other)
    newer = tmp_path / "newer.joblib"
    hdr = {**binary_model.header(), "format_version": 99}
    joblib.dump({"header": hdr, "model": binary_model}, newer)
    with pytest.raises(ModelFormatError, match="version 99"):
        load_model(newer)
    plain = tmp_path / "plain.pkl"
    plain.write_bytes(pickle.dumps([1, 2, 3]))
    with pytest.raises(ModelFormatError, match="no header"):
        load_model(plain)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_model(tmp_path / "missing.joblib")
    with pytest.raises(TypeError, match="TouchModel"):
        save_model({"not": "a model"}, tmp_path / "x.joblib")
    for bad in (text, tmp_path / "missing.joblib"):
        res = runner.invoke(app, ["predict", str(bad), str(sim_path)])
        assert res.exit_code == 2, res.output
        assert bad.name in res.output and "Traceback" not in res.output


def test_model_rejects_other_grid(binary_model, user_path):
    from eskin.data.campaign import load_campaign

    with pytest.raises(TrainingError, match="3x5 taxel grid.*4x4"):
        binary_model.predict_recordings(load_campaign(user_path))


def test_train_on_a_campaign_without_any_touch_fails_clearly(tmp_path):
    from eskin.data.campaign import write_campaign

    n = 12
    path = tmp_path / "zero.h5"
    write_campaign(path, np.zeros((n, 4, 4, 2000), np.int16), modality=np.arange(n) % 3,
                   participant=np.arange(n) // 3, direction=np.arange(n) % 2, run=np.full(n, 2),
                   modalities=["brush", "finger", "washer"], sample_rate_hz=3000.0,
                   volts_per_count=1e-3, source="recorded")
    r = CliRunner().invoke(app, ["train", str(path), "-o", str(tmp_path / "m.eskin"),
                                 "--all-classes", "--quick"])
    assert r.exit_code == 2
    assert r.output == (f"error: {path}: no touch anywhere: each of the 12 training recordings "
                        f"is flat (its preprocessed tensor is constant), so there is nothing to "
                        f"learn\n")
    assert not (tmp_path / "m.eskin").exists()
    # one recording with a touch is enough to train (the check is not over-eager)
    sig = np.zeros((n, 4, 4, 2000), np.int16)
    sig[:, :, :, 800:900] = (np.arange(n) * 50 + 300)[:, None, None, None]
    write_campaign(path, sig, modality=np.arange(n) % 3, participant=np.arange(n) // 3,
                   direction=np.arange(n) % 2, run=np.full(n, 2),
                   modalities=["brush", "finger", "washer"], sample_rate_hz=3000.0,
                   volts_per_count=1e-3, source="recorded", overwrite=True)
    r = CliRunner().invoke(app, ["train", str(path), "-o", str(tmp_path / "m.eskin"),
                                 "--all-classes", "--quick"])
    assert r.exit_code == 0, r.output


def _two_class_campaign(path, participant, modality):
    """4x4 taxels at 1000 Hz, cut recordings; brush and washer excite different taxels."""
    from eskin.data.campaign import write_campaign

    rng = np.random.default_rng(0)
    n = len(modality)
    t = np.arange(600) / 1000.0
    sig = np.empty((n, 4, 4, 600), np.int16)
    for i, m in enumerate(modality):
        gain = np.zeros((4, 4))
        gain[:, m * 2 : m * 2 + 2] = 1.0 + 0.3 * rng.random((4, 2))
        wave = np.sin(2 * np.pi * (10 + 20 * m) * t + rng.uniform(0, 6))
        sig[i] = np.clip(3000 * gain[..., None] * wave + 100 * rng.normal(size=(4, 4, 600)),
                         -32000, 32000)
    write_campaign(path, sig, modality=np.asarray(modality), participant=np.asarray(participant),
                   direction=np.arange(n) % 2, run=np.full(n, 2),
                   modalities=["brush", "washer"], sample_rate_hz=1000.0,
                   volts_per_count=1e-3, source="recorded")
    return path, sig


def test_default_selection_is_participant_grouped_cv_with_fallbacks(tmp_path):
    # 6 participants x 2 classes x 2 recordings: the default splits by participant
    part = np.repeat(np.arange(6), 4)
    mod = np.tile([0, 0, 1, 1], 6)
    path, sig = _two_class_campaign(tmp_path / "six.h5", part, mod)
    m = train_model(path, D=20, window="none", quick=True)
    assert m.selection == "cv" and m.training["cv_split_by"] == "participant"
    assert not any("cross-validation" in n for n in m.training["notes"])
    # the same recordings as arrays carry no participants: stratified splits, with a note
    m = train_model(sig, labels=np.array(["brush", "washer"])[mod], lengths=[600] * len(mod),
                    sample_rate_hz=1000.0, D=20, window="none", quick=True)
    assert m.training["cv_split_by"] == "recordings"
    assert any(n.startswith("no participant labels") for n in m.training["notes"])
    # every washer from one participant: a grouped split cannot keep both classes in training
    part = np.r_[np.zeros(6, int), np.arange(1, 7)]
    mod = np.r_[np.ones(6, int), np.zeros(6, int)]
    path, _ = _two_class_campaign(tmp_path / "lopsided.h5", part, mod)
    m = train_model(path, D=20, window="none", quick=True)
    assert m.training["cv_split_by"] == "recordings"
    assert any(n.startswith("grouped cross-validation left a class out") for n in
               m.training["notes"])
    # the command line's default is the same recipe
    r = CliRunner().invoke(app, ["train", str(tmp_path / "six.h5"), "--all-classes", "--quick",
                                 "--D", "20", "--window", "none", "-o", str(tmp_path / "m.joblib")])
    assert r.exit_code == 0, r.output
    assert "(svm, cv, D=20, window=none)" in r.output
