"""The live figure of an evaluation fold: held-out recordings played as one stream through the
compiled stream classifier, scored per recording; and a real eskin-fw-sim + eskin listen run on
the same recordings, which must decide the same touches."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import eskin
from eskin._paths import find_executable
from eskin.data.campaign import load_campaign
from eskin.data.replay import read_replay_file, write_replay_arrays
from eskin.data.simulator import acquisition_config, simulate
from eskin.link.events import Decision
from eskin.link.live_scores import LiveScoring, live_decisions, score_stream
from eskin.link.scoring import score_decisions

PACKAGE_ROOT = str(Path(eskin.__file__).resolve().parents[1])


def decision(onset: int, offset: int, label: str | None, dont_know: bool = False) -> Decision:
    return Decision("host", onset, offset, label, -1, (0.0,), dont_know)


def test_score_stream_counts_splits_misses_and_spurious_touches(tmp_path):
    rng = np.random.default_rng(0)
    recs = [rng.integers(-5, 5, (2, 2, 1000)).astype(np.int16) for _ in range(4)]
    rf = write_replay_arrays(tmp_path / "s.eskr", recs, labels=[0, 1, 0, 1],
                             class_names=["a", "b"], gap_s=1.0, sample_rate_hz=1000.0)
    s = [int(v) for v in rf.segments["start"]]  # 1000, 3000, 5000, 7000
    decisions = [
        decision(s[0] + 100, s[0] + 300, "b"),  # recording 0 split in two touches
        decision(s[0] + 500, s[0] + 900, "a"),  # (this one overlaps it most: kept)
        decision(s[1] - 600, s[1] - 200, "a"),  # in the gap before recording 1: spurious
        decision(s[2] + 200, s[2] + 800, "a", dont_know=True),  # recording 2, right, unsure
        # recording 3: a class the figure does not have (no decision, so not "don't know")
        decision(s[3] + 100, s[3] + 900, "c", dont_know=True),
    ]
    out = score_stream(decisions, rf, ["a", "b"])
    assert out["per_recording"] == {"touches": [2, 0, 1, 1], "decided": [0, -1, 0, -1],
                                    "dont_know": [False, False, True, True]}
    assert {k: out[k] for k in ("recordings", "touches", "split", "missed", "spurious",
                                "correct", "dont_know")} == {
        "recordings": 4, "touches": 4, "split": 1, "missed": 1, "spurious": 1, "correct": 2,
        "dont_know": 1}
    # the score eskin listen --replay prints, from the same code
    score = score_decisions(decisions, rf)[0]
    assert out["score"] == score.as_dict()
    assert (score.touches, score.split, score.missed, score.spurious) == (4, 1, 1, 1)
    # decided: recording 0 (right); flagged: recording 2 (right); recording 3's class is not
    # the replay's, so it has no decision, like recording 1
    assert score.dont_know_right == 1 and score.error_decided == 0 and score.error_flagged == 0
    assert score.live_line() == (
        'host: 4 touches on 4 recordings (1 split, 1 missed), 1 in the gaps; 1 of 2 decisions '
        '"don\'t know"; error 50.0 % overall, 0.0 % on the decided, 0.0 % on the flagged')


def test_pool_adds_the_folds_up():
    fold = {"recordings": 4, "touches": 5, "split": 1, "missed": 0, "spurious": 1, "correct": 3,
            "dont_know": 1, "dont_know_right": 0, "gap_s": 2.0, "hold_s": 0.6,
            "per_recording": {"touches": [1, 2, 1, 1], "decided": [0, 1, 1, 0],
                              "dont_know": [False, False, False, True]}}
    other = {**fold, "hold_s": 0.3, "correct": 4, "dont_know_right": 1}
    pooled = LiveScoring.pool([fold, other])
    assert pooled["recordings"] == 8 and pooled["correct"] == 7 and pooled["accuracy"] == 7 / 8
    # 6 decided recordings, all right; 2 flagged, 1 of them right
    assert pooled["error_decided"] == 0 and pooled["error_flagged"] == 0.5
    assert pooled["touches_per_recording"] == 10 / 8 and pooled["hold_s"] == [0.3, 0.6]
    assert pooled["per_recording"]["touches"] == [1, 2, 1, 1] * 2


# --------------------------------------------------------------------------- press-and-hold

TEST_PARTICIPANT = 3


@pytest.fixture(scope="module")
def press(tmp_path_factory) -> Path:
    """8x8 taxels at 1 kHz, finger strokes and press-and-holds, 3 participants."""
    path = tmp_path_factory.mktemp("press") / "c.h5"
    cfg = acquisition_config(grid=(8, 8), rate_hz=1000.0, duration_s=3.0,
                             modalities=("finger", "press"))
    return simulate(path, participants=3, seed=3, config=cfg)


def fold_model(campaign, **kw):
    """A model of the participants other than TEST_PARTICIPANT, and their campaign."""
    from eskin.learn.training import train_model

    test = np.flatnonzero(np.asarray(campaign.participant) == TEST_PARTICIPANT)
    train = np.setdiff1d(np.arange(len(campaign)), test)
    model = train_model(campaign.subset(train), machine="svm", D=20, subsample="algorithm2",
                        negatives="all", quick=True, seed=0, **kw)
    return model, campaign.subset(test)


def test_one_live_touch_per_recording_once_train_chose_the_hold(press):
    from eskin.signal.preprocess import WindowConfig

    with load_campaign(press) as c:
        chosen, test = fold_model(c)
        default, _ = fold_model(c, window_config=WindowConfig(), choose_hold=False)
        live_chosen = LiveScoring().fold(chosen, test, ["finger", "press"])
        live_default = LiveScoring().fold(default, test, ["finger", "press"])
    assert chosen.window_config.hold_s == 0.6 and live_chosen["hold_s"] == 0.6
    n = len(test)
    assert live_chosen["per_recording"]["touches"] == [1] * n
    assert live_chosen["split"] == live_chosen["missed"] == live_chosen["spurious"] == 0
    # at the detector's default hold, presses are a press and a release: two decisions
    assert default.window_config.hold_s == 0.15
    assert live_default["split"] > 0 and live_default["touches"] > n
    is_press = np.asarray(test.modality) == 1
    split = np.asarray(live_default["per_recording"]["touches"]) > 1
    assert np.all(is_press[split])  # only presses split


def eskin_cli(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, COLUMNS="120",
               PYTHONPATH=os.pathsep.join(filter(None, [PACKAGE_ROOT,
                                                        os.environ.get("PYTHONPATH")])))
    r = subprocess.run([sys.executable, "-m", "eskin", *args], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, f"eskin {' '.join(args)}:\n{r.stdout}\n{r.stderr}"
    return r


def test_the_live_figure_is_what_eskin_fw_sim_and_listen_decide(press, tmp_path):
    """The fold's live figure against a real run: eskin replay of the held-out participant
    (--gap 2, as the figure plays it), eskin-fw-sim with the exported model on a pty, eskin
    listen --replay: the controller decides the same touches, the score is the same."""
    from eskin.deploy.export import export_model
    from eskin.link.host_classifier import load_host_classifier

    with load_campaign(press) as c:
        model, test = fold_model(c)
        figure = LiveScoring().fold(model, test, list(c.modalities), seed=0)
        export_model(model, tmp_path / "m.eskin")
        eskin_cli(tmp_path, "replay", str(press), "-o", "test.eskr", "--select",
                  f"participant={TEST_PARTICIPANT}", "--gap", "2")
        rf = read_replay_file(tmp_path / "test.eskr")
        assert len(rf.segments) == len(test)
        ours = live_decisions(load_host_classifier(model, "compiled"), rf.samples)
    sim = subprocess.Popen([str(find_executable("eskin-fw-sim")), "test.eskr", "--model",
                            "m.eskin", "--wait-start", "--link", "skin.tty", "--speed", "0",
                            "--quiet"], cwd=tmp_path, stdout=subprocess.PIPE, text=True)
    try:
        assert sim.stdout.readline().startswith("PTY ")
        eskin_cli(tmp_path, "listen", "skin.tty", "--model", "m.eskin", "--until-eof",
                  "--replay", "test.eskr", "--jsonl", "d.jsonl", "--view", "plain")
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
    objects = [json.loads(ln) for ln in (tmp_path / "d.jsonl").read_text().splitlines()]
    board = [o for o in objects if o["type"] == "decision" and o["source"] == "controller"]
    # touch by touch: the same windows, labels and "don't know" on the controller
    assert [(d["onset_sample"], d["offset_sample"], d["label"], d["dont_know"]) for d in board] \
        == [(d.onset_sample, d.offset_sample, d.label, d.dont_know) for d in ours]
    assert len(board) == figure["touches"] + figure["spurious"] == len(test)
    # and the score listen prints is the figure's
    score = next(o for o in objects if o["type"] == "accuracy" and o["source"] == "controller")
    for key in ("recordings", "correct", "dont_know", "no_decision", "confusion"):
        assert score[key] == figure["score"][key], key
