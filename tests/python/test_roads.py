"""From a campaign file to the controller with command-line tools only (no Python glue):

- the firmware road: eskin replay -> eskin-fw-sim (model on board) -> eskin listen --replay, which
  ends with the live accuracy and confusion matrix against the replay's true classes;
- the batch road: eskin replay (.npy or raw records) -> eskin-classify.
"""

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

PACKAGE_ROOT = str(Path(eskin.__file__).resolve().parents[1])


def eskin_cli(cwd: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join(filter(None, [PACKAGE_ROOT, os.environ.get("PYTHONPATH")])),
        COLUMNS="120",
    )
    r = subprocess.run(
        [sys.executable, "-m", "eskin", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    if check:
        assert r.returncode == 0, f"eskin {' '.join(args)}:\n{r.stdout}\n{r.stderr}"
    return r


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A folder with a 1-participant simulated campaign and a 3-class model exported from it."""
    d = tmp_path_factory.mktemp("road")
    eskin_cli(d, "simulate", "-o", "c.h5", "--participants", "1", "--seed", "5", "-q")
    eskin_cli(d, "train", "c.h5", "--classes", "brush,washer,finger", "--quick", "-o", "m.joblib")
    eskin_cli(d, "export", "m.joblib", "-o", "m.eskin")
    return d


def test_replay_refuses_to_replace_a_file_without_force(trained):
    from typer.testing import CliRunner

    from eskin.cli import app

    out, camp = str(trained / "once.eskr"), str(trained / "c.h5")
    assert (
        CliRunner().invoke(app, ["replay", camp, "-o", out, "--select", "index=0"]).exit_code == 0
    )
    first = Path(out).read_bytes()
    r = CliRunner().invoke(app, ["replay", camp, "-o", out, "--select", "index=1"])
    assert r.exit_code == 2 and "once.eskr: file exists" in r.output and "--force" in r.output
    assert Path(out).read_bytes() == first
    r = CliRunner().invoke(app, ["replay", camp, "-o", out, "--select", "index=1", "--force"])
    assert r.exit_code == 0 and Path(out).read_bytes() != first


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["--select", "modality=glove"],
            "unknown ['glove']; this campaign has brush, finger, washer",
        ),
        (["--select", "participant=9"], "no recording of 12 matches --select participant=9"),
        (["--select", "size=3"], "expected KEY=VALUES with KEY one of modality, participant"),
        (["--select", "run=two"], "'two' is not an integer or a range a-b"),
        (["--format", "npy", "--gap", "-1"], "--gap must be a number of seconds in [0, 3600]"),
    ],
)
def test_replay_bad_arguments_are_one_line_errors(trained, args, message):
    from typer.testing import CliRunner

    from eskin.cli import app

    r = CliRunner().invoke(
        app, ["replay", str(trained / "c.h5"), "-o", str(trained / "x.npy"), *args]
    )
    assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output
    r = CliRunner().invoke(app, ["replay", str(trained / "c.h5"), "-o", str(trained / "x.bin")])
    assert r.exit_code == 2 and "x.bin: say what to write with --format" in r.output


def test_firmware_road_ends_with_the_live_accuracy(trained):
    d = trained
    r = eskin_cli(d, "replay", "c.h5", "-o", "test.eskr", "--select", "run=2")
    assert "wrote test.eskr: 6 recordings (2 brush, 2 finger, 2 washer)" in r.stdout
    sim = subprocess.Popen(
        [
            str(find_executable("eskin-fw-sim")),
            "test.eskr",
            "--model",
            "m.eskin",
            "--wait-start",
            "--link",
            "skin.tty",
            "--speed",
            "0",
            "--quiet",
        ],
        cwd=d,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert sim.stdout.readline().startswith("PTY ")
        r = eskin_cli(
            d,
            "listen",
            "skin.tty",
            "--model",
            "m.eskin",
            "--until-eof",
            "--replay",
            "test.eskr",
            "--jsonl",
            "d.jsonl",
            "--view",
            "plain",
        )
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
    out = r.stdout.splitlines()
    decided = [ln for ln in out if ln.startswith("decision ")]
    assert decided and all(" true=" in ln for ln in decided)
    objects = [json.loads(ln) for ln in (d / "d.jsonl").read_text().splitlines()]
    scores = {o["source"]: o for o in objects if o["type"] == "accuracy"}
    assert objects[-1]["type"] == "stats" and set(scores) == {"controller", "host"}
    for source, sc in scores.items():
        cm = np.array(sc["confusion"])
        assert sc["recordings"] == 6 and cm.shape == (3, 4) and cm.sum() == 6
        assert cm.trace() == sc["correct"] and sc["accuracy"] == sc["correct"] / 6
        assert cm.sum(axis=1).tolist() == [2, 2, 2]  # two recordings of each true class
        assert f"{source}: {sc['correct']}/6 recordings right" in r.stdout
    # the controller and the host run the same .eskin model on the same samples
    assert scores["controller"]["confusion"] == scores["host"]["confusion"]
    assert "true \\ decided" in r.stdout


def test_batch_road_to_eskin_classify(trained):
    d = trained
    eskin_cli(d, "replay", "c.h5", "-o", "run2.npy", "--select", "run=2")
    eskin_cli(d, "replay", "c.h5", "-o", "run2.rec", "--select", "run=2", "--format", "records")
    classify = str(find_executable("eskin-classify"))
    lines = {}
    for name in ("run2.npy", "run2.rec"):
        r = subprocess.run(
            [classify, "m.eskin", name],
            cwd=d,
            capture_output=True,
            text=True,
            check=True,
            timeout=60,
        )
        lines[name] = [ln.split("\t") for ln in r.stdout.splitlines() if ln[:1].isdigit()]
    assert lines["run2.npy"] == lines["run2.rec"] and len(lines["run2.npy"]) == 6
    with eskin.load_campaign(d / "c.h5") as c:
        run2 = np.flatnonzero(c.run == 2)
        expected = eskin.CompiledModel(d / "m.eskin").classify(np.asarray(c.signals[run2]))
    assert [row[1] for row in lines["run2.npy"]] == list(expected.labels)


def test_a_campaign_given_straight_to_the_tools_names_the_way_in(trained):
    for tool, args, command in (
        ("eskin-fw-sim", ["c.h5"], "`eskin replay CAMPAIGN -o FILE.eskr`"),
        ("eskin-classify", ["m.eskin", "c.h5"], "`eskin replay CAMPAIGN -o recordings.npy`"),
    ):
        r = subprocess.run(
            [str(find_executable(tool)), *args],
            cwd=trained,
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
        )
        assert r.returncode == 2
        assert (
            f"{tool}: c.h5: an HDF5 file (an eskin campaign?)" in r.stderr and command in r.stderr
        )


def test_eskin_classify_names_a_file_given_in_the_wrong_place(trained):
    """A replay file ('ESKREPLY' starts with the raw-record magic 'ESKR'), a campaign, a
    Python model or a .eskin model where the other belongs: one line naming what the file is
    and what reads it, exit 2, nothing on standard output."""
    eskin_cli(trained, "replay", "c.h5", "-o", "wrong.eskr", "--select", "run=2")
    cases = (
        (["m.eskin", "wrong.eskr"],
         "wrong.eskr: an eskin replay file (.eskr, the stream eskin-fw-sim plays), not "
         "recordings: eskin-fw-sim streams it"),
        (["m.eskin", "m.eskin"],
         "m.eskin: an eskin model (.eskin), not recordings: eskin-classify reads it as MODEL"),
        (["m.eskin", "m.joblib"], "m.joblib: a Python model file (joblib; eskin train writes"),
        (["wrong.eskr", "m.eskin"],
         "MODEL wrong.eskr: an eskin replay file (.eskr, the stream eskin-fw-sim plays), not a "
         ".eskin model; eskin-fw-sim streams it"),
        (["c.h5", "wrong.eskr"],
         "MODEL c.h5: an HDF5 file (an eskin campaign?), not a .eskin model; `eskin replay "
         "CAMPAIGN -o recordings.npy`"),
        (["m.joblib", "wrong.eskr"],
         "MODEL m.joblib: a Python model file (joblib; eskin train writes them), not a .eskin "
         "model; `eskin export MODEL.joblib -o MODEL.eskin` writes the .eskin model"),
    )
    for args, message in cases:
        r = subprocess.run([str(find_executable("eskin-classify")), *args], cwd=trained,
                           capture_output=True, text=True, timeout=30, check=False)
        assert (r.returncode, r.stdout) == (2, ""), (args, r.stdout, r.stderr)
        assert r.stderr.startswith("eskin-classify: ") and message in r.stderr, r.stderr
        assert len(r.stderr.splitlines()) == 1


def test_listen_replay_names_the_recordings_the_link_lost_samples_of(trained):
    """Bytes dropped on the link (fault injection, fixed seed) cost samples; eskin listen
    --replay names the recordings they belong to, scores without them too, and its --jsonl
    accuracy objects list them. The lost samples it names add up to the link's count."""
    d = trained
    eskin_cli(d, "replay", "c.h5", "-o", "lossy.eskr", "--select", "run=2")
    sim = subprocess.Popen(
        [str(find_executable("eskin-fw-sim")), "lossy.eskr", "--model", "m.eskin",
         "--wait-start", "--link", "lossy.tty", "--speed", "0", "--quiet",
         "--drop-rate", "0.0005", "--seed", "3"],
        cwd=d, stdout=subprocess.PIPE, text=True)
    try:
        assert sim.stdout.readline().startswith("PTY ")
        r = eskin_cli(d, "listen", "lossy.tty", "--model", "m.eskin", "--until-eof",
                      "--replay", "lossy.eskr", "--jsonl", "lossy.jsonl", "--view", "plain")
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
    objects = [json.loads(ln) for ln in (d / "lossy.jsonl").read_text().splitlines()]
    stats = objects[-1]
    scores = {o["source"]: o for o in objects if o["type"] == "accuracy"}
    assert stats["lost_samples"] > 0 and set(scores) == {"controller", "host"}
    for source, sc in scores.items():
        lossy = sc["recordings_with_losses"]
        assert lossy and all(x["lost_samples"] > 0 for x in lossy)
        assert sum(x["lost_samples"] for x in lossy) <= stats["lost_samples"]
        assert sc["recordings_without_losses"] == 6 - len(lossy)
        assert sc["correct_without_losses"] == sc["correct"] - sum(x["right"] for x in lossy)
        line = (f"  {len(lossy)} recording(s) lost samples on the link, so their decisions are "
                f"not a fair score of the model: segment {lossy[0]['segment']} "
                f"({lossy[0]['lost_samples']} samples lost;")
        assert line in r.stdout
        assert (f"  without them: {sc['correct_without_losses']}/"
                f"{sc['recordings_without_losses']} right") in r.stdout
