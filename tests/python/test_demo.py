"""eskin.demo end to end on a tiny campaign: simulate, train, export, stream over a real
pseudo-terminal through eskin-fw-sim, listen, and compare live with offline decisions."""

from __future__ import annotations

import json

import numpy as np
import pytest
from waiting import wait_until

from eskin.demo import assign_decisions, confusion_matrix
from eskin.link.listener import Decision


def _d(onset, offset, label):
    return Decision("controller", onset, offset, None, label, (0.5, -0.5, -1.0))


def test_assign_decisions_keeps_the_touch_on_the_contact():
    seg = np.zeros(3, dtype=[("start", "<u8"), ("length", "<u8"), ("contact_onset", "<i8"),
                             ("contact_offset", "<i8")])
    seg["start"], seg["length"] = [100, 1000, 2000], [500, 500, 500]
    seg["contact_onset"], seg["contact_offset"] = [50, -1, 0], [150, -1, 500]
    ds = [_d(0, 50, 2), _d(150, 250, 1), _d(300, 590, 0), _d(1490, 1700, 2), _d(2600, 2700, 1)]
    labels, values, _, extra = assign_decisions(ds, seg, 3)
    # segment 0: [150, 250) covers the contact [150, 250); the longer [300, 590) does not;
    # segment 1 (contact unknown): the largest overlap; segment 2: no decision
    assert labels.tolist() == [1, 2, -1]
    assert np.isnan(values[2]).all() and values[0].tolist() == [0.5, -0.5, -1.0]
    assert extra == [1, 0, 0, 2]  # one other touch in segment 0; two outside every segment
    cm = confusion_matrix(np.array([0, 1, 2]), labels, 3)
    assert cm.tolist() == [[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


def test_demo_end_to_end(tmp_path):
    pytest.importorskip("eskin.learn.models", reason="the learning stack is not installed")
    from eskin.demo import run_demo

    lines: list[str] = []
    r = run_demo(tmp_path / "demo", participants=2, test_participants=1, speed=20, quick=True,
                 max_recordings=3, n_jobs=1, log=lines.append)
    assert r.agree, r.disagreement
    assert len(r.true_labels) == 3 and r.class_names == ["brush", "finger", "washer"]
    for key in ("controller (live)", "host (live)", "offline (Python)"):
        assert r.confusion[key].sum() == 3
    assert r.stats.lost_samples == 0 and r.stats.rejected == 0
    assert r.stats.decisions_controller == r.stats.decisions_host >= 3
    report = json.loads(r.files["report"].read_text())
    assert report["agree"] and report["source"] == "simulated"
    jl = [json.loads(x) for x in r.files["decisions"].read_text().splitlines()]
    assert jl[-1]["type"] == "stats" and {d["source"] for d in jl[:-1]} == {"controller", "host"}
    from eskin.data.campaign import load_campaign
    from eskin.data.replay import read_replay_file

    live = load_campaign(r.files["live"])
    src = load_campaign(r.files["campaign"])
    rf = read_replay_file(r.files["replay"])
    assert len(live) == 3 and live.source == "simulated" and len(src) == 24
    for k, i in enumerate(rf.segments["recording"]):  # the stream, recorded, is the source
        assert np.array_equal(live.recording(k), src.recording(int(i)))
        assert live.modality[k] == src.modality[int(i)]


def test_demo_command_prints_the_held_out_error_beside_eskin_evaluates(tmp_path):
    """`eskin demo` (here a small run) prints the controller's live error on the held-out
    people with its interval and, for its default campaign and recipe, eskin evaluate's
    documented figure; other settings name the command that measures it."""
    pytest.importorskip("eskin.learn.models", reason="the learning stack is not installed")
    from typer.testing import CliRunner

    from eskin.cli import app
    from eskin.demo import EVALUATE_REFERENCE, _held_out_line

    out = tmp_path / "demo"
    r = CliRunner().invoke(app, ["demo", "--out", str(out), "--participants", "2",
                                 "--test-participants", "1", "--quick", "--recordings", "3"])
    assert r.exit_code == 0, r.output
    report = json.loads((out / "report.json").read_text())
    h = report["held_out"]
    assert (h["recordings"], h["participants"], h["evaluate"]) == (3, 1, None)
    assert h["live_error"] == report["error_rates"]["controller (live)"]
    lo, hi = h["live_error_ci95"]
    assert 0 <= lo <= h["live_error"] <= hi <= 1
    text = " ".join(r.output.split())
    assert (f"held-out error: live (controller) {h['live_error']:.1%} [{lo:.1%}, {hi:.1%}] on 3 "
            f"recordings of 1 unseen participants; `eskin evaluate CAMPAIGN --out DIR` "
            f"measures this recipe") in text
    assert "as fast as the host reads" in text
    # the defaults' line: eskin evaluate's figure for the same recipe and campaign
    line = _held_out_line({**h, "evaluate": EVALUATE_REFERENCE})
    assert "eskin evaluate, same recipe and campaign, 5 participant-disjoint folds: 18.3 % " \
           "[13.8 %, 23.3 %] on all 240 recordings" in line.replace("%", " %")


@pytest.mark.slow
def test_demo_web_shows_its_stream_on_the_live_page(tmp_path):
    """`eskin demo --web 127.0.0.1:0`: the demo's listener feeds a live page; once the stream
    is over the page holds every live decision of decisions.jsonl and the demo's summary."""
    pytest.importorskip("eskin.learn.models", reason="the learning stack is not installed")
    import re
    import subprocess
    import sys
    import urllib.request

    from web_data import child_env, stop

    out = tmp_path / "demo"
    proc = subprocess.Popen([sys.executable, "-m", "eskin", "demo", "--out", str(out),
                             "--participants", "2", "--test-participants", "1", "--quick",
                             "--recordings", "3", "--speed", "4", "--jobs", "1", "--web", "127.0.0.1:0",
                             "--web-grace", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=child_env())
    try:
        line = proc.stdout.readline()
        url = re.match(r"live page: (http://\S+)", line).group(1)
        def stopped_state():
            with urllib.request.urlopen(url + "state.json", timeout=10) as r:
                state = json.loads(r.read())
            assert proc.poll() is None, state["status"]  # the page's grace period outlives it
            return state if state["status"] == "stopped" else None

        state = wait_until(stopped_state, timeout=240, what="the page to say stopped",
                           interval=0.2)
        jl = [json.loads(x) for x in (out / "decisions.jsonl").read_text().splitlines()]
        live = [(d["source"], d["label"], d["onset_sample"]) for d in jl if d["type"] == "decision"]
        assert [(d["source"], d["label"], d["onset"]) for d in state["decisions"]] == live
        assert any("held-out error" in s for s in state["summary"])
        assert state["stats"]["lost_samples"] == 0
    finally:
        proc.terminate()
        stop(proc)
