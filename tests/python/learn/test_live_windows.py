"""The live touches of training recordings and the hold time train chooses from them, on a
simulated press-and-hold campaign (8x8 taxels, 1 kHz): a press and its release are two bursts
with a quiet hold between, which the stream detector at its default hold time reports as two
touches."""

from __future__ import annotations

import numpy as np
import pytest

from eskin.data.campaign import load_campaign
from eskin.data.simulator import acquisition_config, simulate
from eskin.learn.live_windows import HOLD_GRID_S, choose_hold, live_touch_counts
from eskin.signal.preprocess import WindowConfig


@pytest.fixture(scope="module")
def press(tmp_path_factory):
    path = tmp_path_factory.mktemp("press") / "press.h5"
    cfg = acquisition_config(grid=(8, 8), rate_hz=1000.0, duration_s=3.0,
                             modalities=("finger", "press"))
    simulate(path, participants=3, seed=3, config=cfg)
    with load_campaign(path) as c:
        yield c.subset(np.arange(len(c))).load()


def by_class(c, counts):
    return {name: counts[np.asarray(c.modality) == k] for k, name in enumerate(c.modalities)}


def test_a_press_is_two_live_touches_at_the_default_hold_and_one_at_0_6_s(press):
    idx = np.arange(len(press))
    at_default = by_class(press, live_touch_counts(press, idx, WindowConfig(), 1000.0))
    assert np.all(at_default["finger"] == 1)
    assert np.mean(at_default["press"] >= 2) > 0.5  # most presses split into press and release
    longer = by_class(press, live_touch_counts(press, idx, WindowConfig(), 1000.0, hold_s=0.6))
    assert np.all(longer["finger"] == 1) and np.all(longer["press"] == 1)


def test_choose_hold_takes_the_shortest_hold_that_gives_one_touch(press):
    idx = np.arange(len(press))
    choice = choose_hold(press, idx, WindowConfig(), 1000.0)
    assert choice.config.hold_s == 0.6
    assert choice.config.on_factor == WindowConfig().on_factor  # nothing else changes
    rec = choice.record
    assert rec["hold_s"] == 0.6 and rec["one"] == rec["recordings"] == len(press)
    assert list(rec["tried"]) == ["0.15", "0.3", "0.6"]  # stops at the first that does
    split = rec["tried"]["0.15"]["split"]
    assert split > 0
    (note,) = choice.notes
    assert note.startswith(f"hold_s = 0.6 s: at 0.15 s, {split} of {len(press)} training "
                           "recordings gave 2+ live touches")
    assert note.endswith(f"now {len(press)} of {len(press)} give one")


def test_a_given_hold_is_kept_and_the_split_is_noted(press):
    idx = np.arange(len(press))
    choice = choose_hold(press, idx, WindowConfig(hold_s=0.15), 1000.0, choose=False)
    assert choice.config.hold_s == 0.15 and choice.record["split"] > 0
    assert choice.notes[0].startswith("hold_s = 0.15 s (given): ")
    assert "a longer --hold merges them" in choice.notes[0]


def test_no_hold_below_the_live_gap_is_said_so(press):
    # a live stream with 0.5 s between gestures leaves only 0.15 s and 0.3 s to try
    idx = np.arange(len(press))
    choice = choose_hold(press, idx, WindowConfig(), 1000.0, gap_s=0.5)
    assert set(choice.record["tried"]) == {"0.15", "0.3"}
    assert choice.config.hold_s in (0.15, 0.3)
    assert "no hold time up to 0.3 s (below the 0.5 s between gestures" in choice.notes[0]


def test_a_campaign_that_gives_one_touch_keeps_its_hold_without_a_note(press):
    fingers = np.flatnonzero(np.asarray(press.modality) == 0)
    choice = choose_hold(press, fingers, WindowConfig(), 1000.0)
    assert choice.config.hold_s == 0.15 and choice.notes == []
    assert list(choice.record["tried"]) == ["0.15"]


def test_the_grid_starts_at_the_detector_default():
    assert HOLD_GRID_S[0] == WindowConfig().hold_s


def test_train_model_chooses_the_hold_and_keeps_a_given_one(press):
    from eskin.learn.training import train_model

    kw = dict(machine="svm", D=20, subsample="algorithm2", negatives="all", quick=True, seed=0)
    model = train_model(press, **kw)
    assert model.window_config.hold_s == 0.6
    assert model.training["live_touches"]["one"] == len(press)
    assert any(n.startswith("hold_s = 0.6 s: at 0.15 s") for n in model.training["notes"])
    fixed = train_model(press, window_config=WindowConfig(hold_s=0.15), choose_hold=False, **kw)
    assert fixed.window_config.hold_s == 0.15
    assert any("(given)" in n for n in fixed.training["notes"])
