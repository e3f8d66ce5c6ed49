"""Training sets (eskin.learn.training_set): the touch windows' lengths and the D they fill."""

from __future__ import annotations

import numpy as np
import pytest
from learn_data import small_simulated

from eskin.learn.training_set import (
    ArrayRecordings,
    fillable_D,
    preprocess_campaign,
    touch_window_lengths,
    true_label_names,
)


def test_fillable_D_is_the_median_window_at_least_two_samples():
    assert fillable_D([7, 12, 10, 9, 30]) == 10
    assert fillable_D([8, 10, 12, 14]) == 10  # the lower of the two middle ones
    assert fillable_D([1, 1, 3]) == 2
    assert fillable_D([]) is None


def test_window_lengths_are_the_windows_the_patterns_are_cut_from(tmp_path):
    from eskin.data.campaign import load_campaign

    camp = load_campaign(small_simulated(tmp_path), in_memory=True)
    idx = np.arange(0, len(camp), 3)
    prep = preprocess_campaign(camp, idx, [(20, "even")], chunk=5)
    lengths = touch_window_lengths(camp, idx, chunk=7)
    np.testing.assert_array_equal(lengths, prep.windows[:, 1] - prep.windows[:, 0])
    assert np.all(lengths < np.asarray(camp.lengths)[idx])


def test_without_a_detector_the_window_is_the_recording():
    rec = ArrayRecordings(np.ones((3, 2, 2, 40)), lengths=[40, 12, 25], sample_rate_hz=10.0)
    np.testing.assert_array_equal(touch_window_lengths(rec, [2, 1], window="none"), [25, 12])
    assert fillable_D(touch_window_lengths(rec, [0, 1, 2], window="none")) == 25


@pytest.mark.parametrize("window", ["energy", "none"])
def test_no_recording_no_window(window):
    rec = ArrayRecordings(np.ones((1, 2, 2, 4)), sample_rate_hz=10.0)
    assert touch_window_lengths(rec, [], window=window).size == 0


def test_at_10_hz_the_windows_and_the_D_they_fill_follow_the_touches():
    """1 s touches (10 samples) in 7 s recordings at 10 Hz: the windows hold the touches (with
    the settings window_config_for_rate gives, WindowConfig.for_rate), so D is capped near the
    touches' length, not at the recording's 70 samples."""
    rng = np.random.default_rng(4)
    x = rng.normal(0, 1.0, (6, 5, 6, 70)) + rng.integers(-50, 50, (6, 5, 6, 1))
    for i, at in enumerate([12, 20, 28, 36, 44, 52]):
        x[i, 1:4, 2:5, at : at + 10] += 20 * np.sin(np.pi * np.arange(1, 11) / 11)
    rec = ArrayRecordings(x, sample_rate_hz=10.0)
    lengths = touch_window_lengths(rec, np.arange(6))
    assert np.all((lengths >= 10) & (lengths <= 17)), lengths
    assert 10 <= fillable_D(lengths) <= 17
    prep = preprocess_campaign(rec, np.arange(6), [(10, "even")])
    np.testing.assert_array_equal(prep.windows[:, 1] - prep.windows[:, 0], lengths)
    assert any("warmup_s = 0.1 s at 10 Hz" in n for n in prep.notes)


def test_the_true_label_of_a_recording_is_its_modality_name_and_none_without_names(tmp_path):
    from eskin.data.campaign import load_campaign

    camp = load_campaign(small_simulated(tmp_path), in_memory=True)
    names = list(camp.modalities)
    idx = [len(camp) - 1, 0, 4]
    assert true_label_names(camp, idx) == [names[int(camp.modality[i])] for i in idx]
    assert len(set(true_label_names(camp, range(len(camp))))) == len(names)
    assert true_label_names(ArrayRecordings(np.ones((3, 2, 2, 40))), [2, 0]) == [None, None]
    assert true_label_names(np.ones((3, 2, 2, 40)), [1]) == [None]
