"""The calibrated rule's edges in Python (eskin.learn.calibration), the copy the C++
classifier's (tests/cpp/test_model.cpp, ModelCalibration) must equal: a confidence equal to the
threshold is decided, the first machine wins an exact tie."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eskin.learn.calibration import calibrated_decision, choose_threshold, fit_calibration


def test_a_confidence_equal_to_the_threshold_is_decided():
    F = np.array([[0.3, -0.2, 0.1]])
    slopes, offsets = (2.0, 0.5, 1.5), (-1.0, 0.25, 0.0)
    _, conf, flag = calibrated_decision(F, slopes, offsets, 0.0, binary=False)
    c = float(conf[0])
    assert 0 < c < 1 and not flag[0]
    _, conf_at, flag_at = calibrated_decision(F, slopes, offsets, c, binary=False)
    assert conf_at[0] == c and not flag_at[0]
    _, _, flag_above = calibrated_decision(F, slopes, offsets, math.nextafter(c, 1.0),
                                           binary=False)
    assert flag_above[0]


def test_an_exact_tie_goes_to_the_first_machine_with_half_the_confidence():
    F = np.array([[0.5, 0.5], [-1.0, -1.0]])
    index, conf, _ = calibrated_decision(F, (1.0, 1.0), (0.0, 0.0), 0.0, binary=False)
    assert index.tolist() == [0, 0]
    assert conf.tolist() == [0.5, 0.5]


def test_a_binary_decision_at_zero_is_the_other_class_with_confidence_one_half():
    index, conf, _ = calibrated_decision(np.array([[0.0], [1e-9], [-1e-9]]), (1.0,), (0.0,),
                                         0.0, binary=True)
    assert index.tolist() == [0, 1, 0]
    assert conf[0] == 0.5


def test_the_threshold_of_tied_confidences_flags_none_of_the_tie():
    # five equal confidences: no threshold can flag two of them without flagging all five
    t = choose_threshold(np.full(5, 0.7), 0.4)
    assert t == 0.7
    assert int((np.full(5, 0.7) < t).sum()) == 0


def test_a_reject_that_rounds_to_every_pattern_takes_the_largest_confidence():
    # reject 0.9 of 3: round(2.7) = 3, past the last index: the largest confidence
    assert choose_threshold(np.array([0.3, 0.1, 0.2]), 0.9) == 0.3
    assert choose_threshold(np.array([0.3, 0.1, 0.2]), 0.5) == 0.3  # round(1.5) = 2
    assert choose_threshold(np.array([0.3, 0.1, 0.2]), 0.4) == 0.2  # round(1.2) = 1


def test_a_calibration_whose_sizes_disagree_is_refused():
    F = np.array([[0.5, -0.5]])
    with pytest.raises(ValueError, match="2 slopes and 1 offsets"):
        calibrated_decision(F, (1.0, 1.0), (0.0,), 0.5, binary=False)
    with pytest.raises(ValueError, match="decision values for 2 machines, calibration of 1"):
        calibrated_decision(F, (1.0,), (0.0,), 0.5, binary=False)
    with pytest.raises(ValueError, match="decision values for 2 machines, calibration of 3"):
        calibrated_decision(F, (1.0,) * 3, (0.0,) * 3, 0.5, binary=False)
    with pytest.raises(ValueError, match="2 slopes and 3 offsets"):
        calibrated_decision(F, (1.0, 1.0), (0.0,) * 3, 0.5, binary=False)
    with pytest.raises(ValueError, match="binary calibration has one machine, not 2"):
        calibrated_decision(F, (1.0, 1.0), (0.0, 0.0), 0.5, binary=True)
    with pytest.raises(ValueError, match="binary calibration has one machine, not 0"):
        calibrated_decision(np.zeros((3, 0)), (), (), 0.5, binary=True)


def test_no_confidences_give_the_threshold_zero():
    assert choose_threshold(np.array([]), 0.5) == 0.0
    assert choose_threshold(np.array([0.7]), 0.4) == 0.0  # round(0.4) = 0 flagged
    assert choose_threshold(np.array([0.7]), 0.6) == 0.7  # round(0.6) = 1: the only one


def test_a_calibration_of_many_machines_is_applied():
    """Sizes are compared by value (300 machines: past the integers CPython shares)."""
    n = 300
    F = np.zeros((2, n))
    F[0, 7] = F[1, 250] = 1.0
    index, conf, _ = calibrated_decision(F, np.ones(n), np.zeros(n), 0.0, binary=False)
    assert index.tolist() == [7, 250]
    assert np.all(conf > 1 / n)


def test_the_rule_of_a_calibration_is_named_not_positional():
    F = np.array([[1.0], [-1.0], [0.5], [-0.5]])
    y = np.array([1, 0, 1, 0])
    with pytest.raises(TypeError):
        fit_calibration(F, y, 0.0, True)
    assert fit_calibration(F, y, 0.0, binary=True).binary


@pytest.mark.parametrize("shift, offset", [(0.0, None), (1.0, -1e6), (-1.0, 1e6)])
def test_a_steeper_sigmoid_is_held_at_the_model_formats_bound(shift, offset):
    """Held-out values a millionth apart whose class follows a slope of 2e6: the slope is held
    at the model format's bound of 1e6 (docs/model-format.md, CALB), and so is an offset beyond
    it either way (values shifted by 1 or -1: the fitted offset is about -+2e6)."""
    from eskin.learn.calibration import fit_sigmoid

    rng = np.random.default_rng(0)
    f = rng.normal(0.0, 1e-6, 400)
    y = rng.random(400) < 1.0 / (1.0 + np.exp(-2e6 * f))
    a, b = fit_sigmoid(f + shift, y)
    assert a == 1e6
    if offset is None:
        assert abs(b) < 1.0
    else:
        assert b == offset


def test_a_fitted_calibration_cannot_be_changed():
    import dataclasses

    from eskin.learn.calibration import Calibration

    cal = Calibration((1.0,), (0.0,), 0.5, 0.1, True)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cal.threshold = 0.0  # type: ignore[misc]
