"""The calibrated decision rule: monotone sigmoids, the threshold's reject fraction, the log-domain
formula, and what it does on trained models (fixed seeds, the small simulated campaign)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from learn_data import small_simulated

from eskin.errors import TrainingError
from eskin.learn.calibration import (
    calibrated_decision,
    choose_threshold,
    fit_calibration,
    fit_sigmoid,
    log_sigmoid,
    out_of_fold_values,
)
from eskin.learn.training import train_model


@pytest.fixture(scope="module")
def sim_path(tmp_path_factory) -> Path:
    return small_simulated(tmp_path_factory.getbasetemp())


def _recordings(path: Path, participants: list[int]):
    """Raw signals, class names, lengths and rate of some participants of a campaign."""
    from eskin.data.campaign import load_campaign

    c = load_campaign(path)
    keep = np.flatnonzero(np.isin(np.asarray(c.participant), participants))
    names = [c.modalities[int(m)] for m in np.asarray(c.modality)[keep]]
    return (np.asarray(c.signals)[keep], names, np.asarray(c.lengths)[keep],
            float(c.sample_rate_hz), np.asarray(c.participant)[keep])


# ----------------------------------------------------------------------------- the pieces


def test_sigmoid_increases_with_the_decision_value():
    rng = np.random.default_rng(0)
    y = rng.random(400) < 0.3
    f = np.where(y, 0.6, -0.4) + 0.5 * rng.standard_normal(400)
    a, b = fit_sigmoid(f, y)
    assert a > 0
    grid = np.linspace(-3, 3, 101)
    p = 1.0 / (1.0 + np.exp(-(a * grid + b)))
    assert np.all(np.diff(p) > 0)
    # the fitted probability follows the data: higher where the class is more frequent
    assert p[grid.searchsorted(0.6)] > y.mean() > p[grid.searchsorted(-0.4)]


def test_values_pointing_the_wrong_way_give_a_flat_sigmoid_at_the_class_share():
    rng = np.random.default_rng(1)
    y = rng.random(300) < 0.25
    f = np.where(y, -1.0, 1.0) + 0.3 * rng.standard_normal(300)
    a, b = fit_sigmoid(f, y)
    assert a == 0.0
    assert 1.0 / (1.0 + np.exp(-b)) == pytest.approx(y.mean())


def test_a_weak_slope_is_kept_and_a_weak_wrong_one_gives_the_class_share():
    """Slopes between -1 and 1: a weakly increasing one (0.23) is the fitted sigmoid's; a weakly
    decreasing one (-0.16) is flat at the class's share, as a strongly decreasing one is."""
    from sklearn.calibration import _sigmoid_calibration

    rng = np.random.default_rng(1)
    y = rng.random(300) < 0.25
    for sign in (1.0, -1.0):
        f = sign * np.where(y, 0.5, -0.5) + 2.0 * rng.standard_normal(300)
        A, B = _sigmoid_calibration(f, y.astype(np.int64))  # p = 1 / (1 + exp(A f + B))
        a, b = fit_sigmoid(f, y)
        if sign > 0:
            assert 0 < -A < 1 and (a, b) == (-A, -B)
        else:
            assert -1 < -A < 0 and a == 0.0
            assert b == pytest.approx(math.log(y.mean() / (1 - y.mean())), rel=1e-12)


def test_held_out_values_all_equal_give_a_flat_sigmoid_at_the_class_share():
    """Platt's fit of values that carry nothing has a slope of exactly 0 (and its smoothed
    share as offset); the rule's flat sigmoid is at the class's own share, as for values that
    point the wrong way."""
    y = np.r_[np.ones(10), np.zeros(30)].astype(bool)
    assert fit_sigmoid(np.zeros(40), y) == (0.0, math.log(0.25 / 0.75))


def test_a_machine_without_both_sides_cannot_be_calibrated():
    with pytest.raises(TrainingError, match="its class and of others"):
        fit_sigmoid(np.zeros(5), np.ones(5, bool))


@pytest.mark.parametrize("reject", [0.05, 0.1, 0.25, 0.5])
def test_threshold_flags_the_requested_fraction(reject):
    conf = np.random.default_rng(2).uniform(1 / 3, 1, 237)
    t = choose_threshold(conf, reject)
    assert np.sum(conf < t) == round(reject * len(conf))


def test_reject_zero_flags_nothing_and_reject_one_is_refused():
    conf = np.random.default_rng(3).uniform(0.5, 1, 50)
    assert choose_threshold(conf, 0.0) == 0.0
    for bad in (1.0, 1.5, -0.1, float("nan")):
        with pytest.raises(TrainingError) as refused:
            choose_threshold(conf, bad)
        assert str(refused.value) == f"reject must be in [0, 1), got {bad}"


def test_log_domain_rule_equals_the_plain_formula():
    rng = np.random.default_rng(4)
    F = rng.normal(0, 1.5, (200, 4))
    a, b = rng.uniform(0.2, 4, 4), rng.normal(0, 1, 4)
    idx, conf, dk = calibrated_decision(F, a, b, 0.5, binary=False)
    p = 1.0 / (1.0 + np.exp(-(a * F + b)))
    q = p / p.sum(axis=1, keepdims=True)
    np.testing.assert_array_equal(idx, np.argmax(q, axis=1))
    np.testing.assert_allclose(conf, q.max(axis=1), rtol=1e-12)
    np.testing.assert_array_equal(dk, conf < 0.5)
    # binary: the machine's class when a f + b > 0, confidence max(p, 1 - p)
    z = a[0] * F[:, 0] + b[0]
    idx, conf, _ = calibrated_decision(F[:, 0], a[:1], b[:1], 0.0, binary=True)
    np.testing.assert_array_equal(idx, (z > 0).astype(int))
    pb = 1.0 / (1.0 + np.exp(-z))
    np.testing.assert_allclose(conf, np.maximum(pb, 1 - pb), rtol=1e-12)


def test_extreme_values_give_finite_confidences():
    F = np.array([[1e300, -1e300, 0.0], [-1e300, -1e300, -1e300]])
    _, conf, _ = calibrated_decision(F, [1e6] * 3, [0.0] * 3, 0.5, binary=False)
    assert np.all(np.isfinite(conf)) and np.all(conf >= 1 / 3 - 1e-15)
    assert np.all(np.isfinite(log_sigmoid(np.array([-1e306, 1e306]))))


# ----------------------------------------------------------------------------- on trained models


@pytest.fixture(scope="module")
def trained(sim_path):
    signals, names, lengths, rate, part = _recordings(sim_path, [0, 1, 2, 3])
    model = train_model(signals, names, lengths=lengths, sample_rate_hz=rate, machine="svm",
                        D=20, subsample="algorithm2", negatives="all", quick=True, seed=0,
                        reject=0.2)
    return model, (signals, names, lengths, rate, part)


def test_the_threshold_rejects_the_fraction_of_out_of_fold_touches(trained):
    model, (signals, names, lengths, rate, _) = trained
    X = model.preprocess(signals)
    y = np.array([model.classes.index(n) for n in names])
    F, folds = out_of_fold_values(model.estimator, X, y, seed=0)
    assert folds >= 2
    # held-out values: not the ones of machines that trained on the patterns
    assert np.abs(F - model.decision_function(X)).max() > 1e-3
    cal = fit_calibration(F, y, 0.2, binary=False, n_folds=folds)
    assert cal.slopes == model.calibration.slopes and cal.threshold == model.calibration.threshold
    _, conf, dk = cal.decide(F)
    assert abs(dk.sum() - round(0.2 * len(y))) <= 1
    assert model.training["decision"]["oof_flagged"] == pytest.approx(dk.mean())


def test_decided_touches_are_more_often_right_than_all(trained, sim_path):
    model, _ = trained
    signals, names, lengths, _, _ = _recordings(sim_path, [4, 5])  # people it never saw
    preds = model.predict_recordings(signals)
    wrong = np.array([p["label"] != n for p, n in zip(preds, names)])
    flagged = np.array([p["dont_know"] for p in preds])
    assert 0 < flagged.sum() < len(preds)
    assert wrong.mean() > 0  # otherwise nothing to compare
    assert wrong[~flagged].mean() < wrong.mean()
    assert all(p["confidence"] is not None and 1 / 3 <= p["confidence"] <= 1 for p in preds)


def test_reject_zero_never_flags_and_paper_keeps_the_papers_rule(sim_path):
    from eskin.learn.estimators import one_vs_all_rule

    signals, names, lengths, rate, _ = _recordings(sim_path, [0, 1, 2, 3, 4, 5])
    common = dict(lengths=lengths, sample_rate_hz=rate, machine="rls", D=20,
                  subsample="even", negatives="all", quick=True, seed=0)
    never = train_model(signals, names, reject=0.0, **common)
    assert never.calibration.threshold == 0.0
    assert not any(p["dont_know"] for p in never.predict_recordings(signals))
    paper = train_model(signals, names, decision="paper", **common)
    assert paper.calibration is None and paper.training["decision"] == {"rule": "paper"}
    X = paper.preprocess(signals)
    pred, F, dk, conf = paper.decide(X)
    want, _, want_dk = one_vs_all_rule(F)
    np.testing.assert_array_equal(pred, want)
    np.testing.assert_array_equal(dk, want_dk)
    assert np.isnan(conf).all()


def test_a_binary_model_is_calibrated_on_its_one_machine(sim_path):
    signals, names, lengths, rate, _ = _recordings(sim_path, [0, 1, 2, 3, 4, 5])
    model = train_model(signals, names, classes=["brush", "washer"], lengths=lengths,
                        sample_rate_hz=rate, machine="svm", D=20, subsample="algorithm2",
                        negatives="all", quick=True, seed=0, reject=0.25)
    cal = model.calibration
    assert cal.binary and len(cal.slopes) == 1 and cal.slopes[0] > 0
    X = model.preprocess(signals[np.isin(names, ["brush", "washer"])])
    pred, F, dk, conf = model.decide(X)
    z = cal.slopes[0] * F + cal.offsets[0]
    np.testing.assert_array_equal(pred, (z > 0).astype(int))
    assert np.all(conf >= 0.5) and np.array_equal(dk, conf < cal.threshold)


@pytest.mark.parametrize("decision, reject, message", [
    ("vote", 0.1, "decision must be one of"),
    ("calibrated", 1.0, "reject must be in"),
    ("calibrated", -0.1, "reject must be in"),
    ("calibrated", "a lot", "reject must be a number"),
])
def test_bad_rule_options_are_refused_before_training(sim_path, decision, reject, message):
    with pytest.raises(TrainingError, match=message):
        train_model(sim_path, decision=decision, reject=reject, quick=True)
