"""The `eskin` command line as a user meets it: --version, the help of on/off options, the
predict table, `info --check`, and the one-line error for a file that is not a campaign."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

import eskin
from eskin.cli import app

PACKAGE_ROOT = str(Path(eskin.__file__).resolve().parents[1])


def run_eskin(*args: str) -> subprocess.CompletedProcess:
    """The installed entry point's code path (eskin.cli.main), in a child process."""
    env = dict(
        os.environ,
        COLUMNS="100",
        PYTHONPATH=os.pathsep.join(filter(None, [PACKAGE_ROOT, os.environ.get("PYTHONPATH")])),
    )
    return subprocess.run(
        [sys.executable, "-m", "eskin", *args],
        capture_output=True,
        text=True,
        env=env,
        check=False,
        timeout=120,
    )


def test_dash_dash_version():
    r = run_eskin("--version")
    assert r.returncode == 0 and r.stdout == f"eskin {eskin.__version__}\n"


@pytest.mark.parametrize("command", ["simulate", "info", "listen", "experiment", "replay"])
def test_help_shows_flags_without_a_value(command):
    r = run_eskin(command, "--help")
    assert r.returncode == 0
    assert "<bool>" not in r.stdout and "--help" in r.stdout


def test_the_command_list_gives_each_command_one_whole_sentence():
    """`eskin --help` lists every command with the first sentence of its help: no sentence
    cut at a line break of the docstring (a row without a command name is a cut)."""
    env = dict(os.environ, COLUMNS="400",
               PYTHONPATH=os.pathsep.join(filter(None, [PACKAGE_ROOT,
                                                        os.environ.get("PYTHONPATH")])))
    r = subprocess.run([sys.executable, "-m", "eskin", "--help"], capture_output=True,
                       text=True, env=env, check=True, timeout=120)
    box = r.stdout.split("Commands")[1].splitlines()[1:]
    rows = [ln.strip("│ ").split(None, 1) for ln in box if ln.startswith("│")]
    names = {c.name for c in app.registered_commands} | {"version"}
    assert {row[0] for row in rows} <= names and len(rows) >= 15
    for name, summary in rows:
        assert summary.rstrip().endswith((".", "?")), (name, summary)


def test_help_texts_name_python_functions_that_exist():
    """eskin-fw-sim --help names the Python function that writes its input; it exists."""
    import importlib
    import re

    from eskin._paths import find_executable

    r = subprocess.run([str(find_executable("eskin-fw-sim")), "--help"], capture_output=True,
                       text=True, check=False, timeout=30)
    dotted = re.findall(r"\beskin(?:\.\w+)+", r.stdout)
    assert "eskin.data.replay.write_replay_file" in dotted
    for name in dotted:
        module, _, attr = name.rpartition(".")
        assert callable(getattr(importlib.import_module(module), attr)), name


def test_a_flag_takes_no_value():
    r = run_eskin("info", "x.h5", "--check", "true")
    assert r.returncode == 2 and "unexpected extra argument" in r.stderr + r.stdout


def test_predict_table_columns_line_up():
    from eskin.cli.learn import _prediction_table

    model = SimpleNamespace(is_binary=False, classes=["brush", "finger", "washer"])
    preds = [
        {
            "index": 0,
            "label": "brush",
            "true_label": "washer",
            "decision_values": [1.0, -0.25, -3.5],
        },
        {
            "index": 12,
            "label": "washer",
            "true_label": "finger",
            "decision_values": [-1, 0.5, 12.25],
            "dont_know": True,
        },
    ]
    lines = _prediction_table(model, preds)
    assert lines[0].split() == ["index", "label", "true", "f(brush)", "f(finger)", "f(washer)"]
    # text columns start where their header does, number columns end where theirs does
    for name in ("label", "true"):
        start = lines[0].index(name)
        assert all(ln[start - 1] == " " and ln[start] != " " for ln in lines[1:]), (name, lines)
    ends = [lines[0].index(h) + len(h) for h in ("f(brush)", "f(finger)", "f(washer)")]
    for ln in lines[1:]:
        assert all(ln[e - 1] != " " and (e == len(ln) or ln[e] == " ") for e in ends), lines
    assert lines[2].endswith("+12.2500  (don't know)")


@pytest.fixture(scope="module")
def one_person(tmp_path_factory) -> Path:
    """A simulated campaign of one participant, run 2: 6 recordings of 21000 samples."""
    from eskin.data.simulator import simulate

    return simulate(tmp_path_factory.mktemp("one") / "c.h5", participants=1, runs=(2,))


def test_info_check_says_what_it_checked(one_person):
    r = CliRunner().invoke(app, ["info", str(one_person), "--check"])
    assert r.exit_code == 0
    assert r.output.splitlines()[-3] == ("check: read the data of all 6 recordings; every chunk "
                                         "matched its checksum (gzip's Adler-32)")
    assert r.output.splitlines()[-1].startswith("check: the labels, the extra fields and the "
                                                "attributes carry no checksum")
    assert "intact" not in r.output
    r = CliRunner().invoke(app, ["info", str(one_person)])
    assert "check:" not in r.output


def test_train_refuses_a_D_no_recording_fills(one_person, tmp_path):
    r = CliRunner().invoke(
        app,
        [
            "train",
            str(one_person),
            "--classes",
            "brush,washer",
            "--D",
            "100000",
            "-o",
            str(tmp_path / "m.joblib"),
        ],
    )
    assert r.exit_code == 2
    assert (
        f"error: --D 100000 is longer than every recording of {one_person} (at most 21000 samples)"
    ) in r.output
    assert not (tmp_path / "m.joblib").exists()


def test_training_set_notes(one_person):
    from eskin.cli.learn import _training_set_notes

    assert _training_set_notes(one_person, 100, "cv") == []  # CV notes one group itself
    one = "every recording comes from one participant"
    assert any(one in n for n in _training_set_notes(one_person, 100, "md"))
    assert any(
        "--D 5000 is far above the paper's 20-100" in n
        for n in _training_set_notes(one_person, 5000, "cv")
    )


def test_experiment_refuses_D_below_the_taxels(one_person, tmp_path):
    r = CliRunner().invoke(
        app,
        [
            "experiment",
            str(one_person),
            "--out",
            str(tmp_path / "x"),
            "--D",
            "7",
            "--quick",
            "--no-progress",
        ],
    )
    assert r.exit_code == 2
    assert "D = 7 is below the 16 taxels of the 4x4 grid" in r.output
    assert not (tmp_path / "x").exists()


def test_a_file_that_is_not_a_campaign_is_named_once(tmp_path):
    (tmp_path / "notes.txt").write_text("hello\n")
    r = CliRunner().invoke(app, ["info", str(tmp_path / "notes.txt")])
    assert r.exit_code == 2
    assert r.output.strip() == (
        f"error: {tmp_path / 'notes.txt'}: not an HDF5 file (no HDF5 signature), so not an eskin "
        "campaign (a campaign is an HDF5 file: docs/dataset-format.md)"
    )


def test_reports_written_to_a_pipe_are_not_cut_at_80_columns(monkeypatch):
    from eskin.cli.link import report_console

    monkeypatch.delenv("COLUMNS", raising=False)
    console = report_console()  # pytest's stdout is not a terminal
    assert console.width >= 200
    with console.capture() as cap:
        console.print("x" * 150)
    assert cap.get().rstrip("\n") == "x" * 150


def test_train_searches_the_amplitude_widths_it_is_given(one_person, tmp_path):
    out = tmp_path / "m.joblib"
    args = ["train", str(one_person), "--classes", "brush,washer", "--quick", "--D", "20"]
    r = CliRunner().invoke(app, [*args, "--amplitude", "off,1", "-o", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    model = eskin.load_model(out)
    assert model.training["grid"]["amplitudes"] == [None, 1.0]
    chosen = model.selected[0]["amplitude"]
    assert chosen in (None, 1.0)
    assert (", amplitude=1 (" in r.output) == (chosen == 1.0)


@pytest.mark.parametrize("bad", ["0", "loud", "1,-2"])
def test_train_refuses_a_bad_amplitude(one_person, tmp_path, bad):
    out = tmp_path / "m.joblib"
    args = ["train", str(one_person), "--classes", "brush,washer", "--quick", "-o", str(out)]
    r = CliRunner().invoke(app, [*args, "--amplitude", bad])
    assert r.exit_code == 2
    assert f"error: --amplitude {bad}: amplitude must be 'off' or a number in [0.01, 100]" in r.output
    assert not out.exists()


def test_train_groups_its_cv_splits_by_the_label_it_is_given(one_person, tmp_path):
    out = tmp_path / "m.joblib"
    args = ["train", str(one_person), "--classes", "brush,washer", "--quick", "-o", str(out)]
    r = CliRunner().invoke(app, [*args, "--groups", "direction", "--no-progress"])
    assert r.exit_code == 0, r.output
    assert eskin.load_model(out).training["cv_split_by"] in ("direction", "recordings")
    r = CliRunner().invoke(app, [*args, "--groups", "nosuch", "--force"])
    assert r.exit_code == 2
    assert "error: --groups 'nosuch': no such label; the campaign has participant" in r.output


@pytest.mark.parametrize("negatives", ["all", "balanced"])
def test_train_gives_each_machine_the_negatives_asked_for(one_person, tmp_path, negatives):
    out = tmp_path / "m.joblib"
    args = ["train", str(one_person), "--all-classes", "--quick", "-o", str(out), "--no-progress"]
    r = CliRunner().invoke(app, [*args, "--negatives", negatives])
    assert r.exit_code == 0, r.output
    model = eskin.load_model(out)
    assert model.training["negatives"] == negatives
    # 6 recordings, 2 per class: a machine sees its 2 and the other 4, or 2 of them
    assert [s["n_train"] for s in model.selected] == [6 if negatives == "all" else 4] * 3


def test_predict_says_when_the_recordings_trained_the_model(one_person, tmp_path):
    """On its own training campaign (or a copy holding some of those recordings) predict's
    error rate is followed by a note that these recordings trained the model; on other
    recordings there is no note."""
    from eskin.data.campaign import load_campaign
    from eskin.data.simulator import simulate

    model = tmp_path / "m.joblib"
    r = CliRunner().invoke(app, ["train", str(one_person), "--all-classes", "--quick", "-o",
                                 str(model), "--no-progress"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(app, ["predict", str(model), str(one_person)])
    assert r.exit_code == 0
    assert ("note: 6 of these 6 recordings trained this model: their error rate says how well "
            "the model fits them, not how it does on new recordings") in r.output
    other = simulate(tmp_path / "other.h5", participants=1, runs=(2,), seed=7)
    with load_campaign(other) as c:
        assert len(c) == 6
    r = CliRunner().invoke(app, ["predict", str(model), str(other)])
    assert r.exit_code == 0 and "error rate:" in r.output and "trained this model" not in r.output


@pytest.fixture(scope="module")
def grid8(tmp_path_factory) -> Path:
    """An 8x8 campaign: each taxel of a simulated 4x4 campaign (3 participants, run 2) spread
    over a 2x2 block of taxels, with a little independent noise."""
    import numpy as np

    from eskin.data.campaign import CampaignWriter, load_campaign
    from eskin.data.simulator import simulate

    d = tmp_path_factory.mktemp("grid8")
    src = simulate(d / "c4.h5", participants=3, runs=(2,))
    rng = np.random.default_rng(0)
    with load_campaign(src) as c, CampaignWriter(
            d / "c8.h5", grid_shape=(8, 8), n_samples=int(max(c.lengths)),
            sample_rate_hz=c.sample_rate_hz, volts_per_count=c.volts_per_count,
            modalities=list(c.modalities), source="simulated") as w:
        for i in range(len(c)):
            r = np.repeat(np.repeat(c.recording(i).astype(np.int32), 2, 0), 2, 1)
            r = np.clip(r + rng.integers(-2, 3, r.shape), -32768, 32767).astype(np.int16)
            w.append(r, modality=int(c.modality[i]), participant=int(c.participant[i]),
                     direction=int(c.direction[i]), run=int(c.run[i]))
    return d / "c8.h5"


def test_experiment_quick_on_an_8x8_grid_chooses_a_valid_D(grid8, tmp_path):
    """--quick's default D values (20, 50) are below the 64 taxels of an 8x8 grid: the
    protocol runs at the paper's D = 100 and its report says so; a D given is still checked."""
    import json

    out = tmp_path / "x"
    r = CliRunner().invoke(app, ["experiment", str(grid8), "--out", str(out), "--quick",
                                 "--no-progress"])
    assert r.exit_code == 0, r.output
    res = json.loads((out / "results.json").read_text())
    assert res["protocol"]["Ds"] == [100] and res["protocol"]["multiclass_D"] == 100
    report = (out / "report.md").read_text()
    assert ("D in {100} instead of the default {20, 50}: D must be at least the 64 taxels of "
            "the 8x8 grid") in report and "D in {100}, 8 configurations" in report
    r = CliRunner().invoke(app, ["experiment", str(grid8), "--out", str(tmp_path / "y"),
                                 "--quick", "--D", "50", "--no-progress"])
    assert r.exit_code == 2 and "D = 50 is below the 64 taxels of the 8x8 grid" in r.output


def test_plot_labels_at_most_16_taxels_of_an_8x8_grid(grid8, tmp_path):
    from eskin.signal.plotting import MAX_TAXEL_LABELS, labelled_taxels

    r = CliRunner().invoke(app, ["plot", str(grid8), "-i", "3", "-o", str(tmp_path / "p.png")])
    assert r.exit_code == 0 and (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    assert labelled_taxels(4, 4) == list(range(16))
    assert labelled_taxels(8, 8) == [r * 8 + c for r in range(8) for c in (0, 4)]
    for rows, cols in ((1, 64), (64, 64), (3, 7), (20, 1)):
        shown = labelled_taxels(rows, cols)
        assert 0 < len(shown) <= MAX_TAXEL_LABELS and shown == sorted(set(shown))
        assert shown[0] == 0 and shown[-1] < rows * cols


def test_train_takes_the_window_settings(one_person, tmp_path):
    """--max-window and --window-samples reach the model's detector (and its .eskin file)."""
    out = tmp_path / "m.eskin"
    args = ["train", str(one_person), "--classes", "brush,washer", "--quick", "--D", "20"]
    r = CliRunner().invoke(app, [*args, "--max-window", "2.5", "--window-samples", "256",
                                 "-o", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    cm = eskin.CompiledModel(out)
    assert cm.window_config["max_window_s"] == 2.5 and cm.window_config["window_samples"] == 256
    assert cm.format_version == 4 and cm.decision_rule == "calibrated"  # version 3's fields
    paper = tmp_path / "paper.eskin"
    r = CliRunner().invoke(app, [*args, "--max-window", "2.5", "--window-samples", "256",
                                 "--decision", "paper", "-o", str(paper), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert eskin.CompiledModel(paper).format_version == 3


@pytest.mark.parametrize(
    "option, value, message",
    [("--window-samples", "3", "WindowConfig.window_samples = 3: must be 0 (every sample) or an "
      "even integer"), ("--max-window", "0.01", "WindowConfig.max_window_s = 0.01: must leave room")],
)
def test_train_refuses_bad_window_settings(one_person, tmp_path, option, value, message):
    out = tmp_path / "m.eskin"
    args = ["train", str(one_person), "--classes", "brush,washer", "--quick", "-o", str(out)]
    r = CliRunner().invoke(app, [*args, option, value])
    assert r.exit_code == 2
    assert f"error: {option}: {message}" in r.output
    assert not out.exists()


def test_train_bounds_the_support_vectors_and_the_compiled_model_agrees(one_person, tmp_path):
    import numpy as np

    from eskin.data.campaign import load_campaign
    from eskin.deploy.export import CompiledModel, model_to_bytes, spec_from_model

    out = tmp_path / "m.joblib"
    r = CliRunner().invoke(app, ["train", str(one_person), "--all-classes", "--quick", "--machine",
                                 "svm", "-o", str(out), "--no-progress", "--max-support", "4"])
    assert r.exit_code == 0, r.output
    model = eskin.load_model(out)
    b = model.training["support_budget"]
    assert b == {"max_support": 4, "support_vectors_before": 6, "support_vectors": 4}
    assert "support vectors bounded by --max-support 4: 6 -> 4" in r.output
    cm = CompiledModel(model_to_bytes(spec_from_model(model), "float64"))
    assert cm.n_support == 4
    with load_campaign(one_person) as c:
        X = model.preprocess(c)
    np.testing.assert_allclose(cm.classify_tensors(X).decision_values,
                               model.decision_function(X).reshape(len(X), -1), atol=1e-9)
    r = CliRunner().invoke(app, ["train", str(one_person), "--all-classes", "--quick", "-o",
                                 str(tmp_path / "n.joblib"), "--max-support", "0"])
    assert r.exit_code == 2 and "--max-support" in r.output


def test_train_takes_the_detector_thresholds_and_a_given_hold(one_person, tmp_path):
    """--hold, --on-factor and --off-factor reach the model's detector; a given hold is kept."""
    out = tmp_path / "m.eskin"
    args = ["train", str(one_person), "--classes", "brush,washer", "--quick", "--D", "20"]
    r = CliRunner().invoke(app, [*args, "--hold", "0.25", "--on-factor", "5", "--off-factor",
                                 "2.5", "-o", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    cfg = eskin.CompiledModel(out).window_config
    assert (cfg["hold_s"], cfg["on_factor"], cfg["off_factor"]) == (0.25, 5.0, 2.5)


@pytest.mark.parametrize("command", ["train", "evaluate"])
@pytest.mark.parametrize(
    "option, value, message",
    [("--hold", "-1", "WindowConfig.hold_s = -1: must be >= 0"),
     ("--on-factor", "1", "WindowConfig.on_factor = 1: must be >= off_factor = 2 (hysteresis)"),
     ("--off-factor", "5", "WindowConfig.on_factor = 4: must be >= off_factor = 5 (hysteresis)"),
     ("--hold", "nan", "WindowConfig.hold_s = nan: must be finite")],
)
def test_bad_detector_settings_are_one_line_errors(one_person, tmp_path, command, option, value,
                                                    message):
    out = tmp_path / ("m.eskin" if command == "train" else "ev")
    r = CliRunner().invoke(app, [command, str(one_person), "--quick", "-o", str(out), option,
                                 value])
    assert r.exit_code == 2 and r.output == f"error: {option}: {message}\n", r.output
    assert not out.exists()


def test_train_chooses_the_hold_of_a_press_and_hold_campaign_and_says_why(tmp_path):
    from eskin.data.simulator import acquisition_config, simulate

    cfg = acquisition_config(grid=(8, 8), rate_hz=1000.0, duration_s=3.0,
                             modalities=("finger", "press"))
    simulate(tmp_path / "p.h5", participants=2, seed=3, config=cfg)
    out = tmp_path / "m.eskin"
    r = CliRunner().invoke(app, ["train", str(tmp_path / "p.h5"), "--quick", "--D", "20",
                                 "-o", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    note = next(ln for ln in r.output.splitlines() if ln.startswith("note: hold_s = "))
    assert note.startswith("note: hold_s = 0.6 s: at 0.15 s, ") and "2+ live touches" in note
    assert note.endswith("now 16 of 16 give one")
    assert eskin.CompiledModel(out).window_config["hold_s"] == 0.6


def test_evaluate_reports_the_live_figure_beside_the_per_recording_one(tmp_path):
    import json

    from eskin.data.simulator import acquisition_config, simulate

    cfg = acquisition_config(grid=(8, 8), rate_hz=1000.0, duration_s=3.0,
                             modalities=("finger", "press"))
    simulate(tmp_path / "p.h5", participants=3, seed=3, config=cfg)
    args = ["evaluate", str(tmp_path / "p.h5"), "--quick", "--machine", "svm", "--D", "20",
            "--subsample", "algorithm2", "--negatives", "all"]
    r = CliRunner().invoke(app, [*args, "-o", str(tmp_path / "ev")])
    assert r.exit_code == 0, r.output
    result = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    live = result["live"]
    assert live["recordings"] == result["n_recordings"] == 24 and live["hold_s"] == 0.6
    assert live["touches"] == 24 and live["split"] == live["missed"] == live["spurious"] == 0
    assert len(live["per_recording"]["touches"]) == 24
    assert all("live" in f and "per_recording" not in f["live"] for f in result["folds"])
    lines = r.output.splitlines()
    (note,) = [ln for ln in lines if ln.startswith("note: hold_s")]  # one line for all folds
    assert note.startswith("note: hold_s = 0.6 s (chosen) in 3 of 3 folds: at 0.15 s, ")
    assert note.endswith("at 0.6 s, 16 give one")
    at = next(i for i, ln in enumerate(lines) if ln.startswith("live: each fold's held-out"))
    assert lines[at + 1].startswith(f"  accuracy live {100 * live['accuracy']:.1f} %, per "
                                    f"recording {100 * result['accuracy']:.1f} %")
    assert lines[at + 2].startswith("  touches per recording 1.00 (24 on 24 recordings): 0 split")
    report = (tmp_path / "ev" / "evaluation.md").read_text()
    assert "## Live: the stream a controller sees" in report
    # at the default hold, given, the presses split live; --no-live leaves the figure out
    r = CliRunner().invoke(app, [*args, "--hold", "0.15", "-o", str(tmp_path / "ev15")])
    assert r.exit_code == 0, r.output
    live15 = json.loads((tmp_path / "ev15" / "evaluation.json").read_text())["live"]
    assert live15["hold_s"] == 0.15 and live15["split"] > 0 and live15["touches"] > 24
    assert any(ln.startswith("note: hold_s = 0.15 s (given) in 3 of 3 folds: ")
               and ln.endswith("gave 2+ live touches (a longer --hold merges them)")
               for ln in r.output.splitlines())
    r = CliRunner().invoke(app, [*args, "--no-live", "-o", str(tmp_path / "none")])
    assert r.exit_code == 0 and "live:" not in r.output
    assert "live" not in json.loads((tmp_path / "none" / "evaluation.json").read_text())


@pytest.mark.parametrize("reject", ["0", "0.5"])
def test_train_reject_sets_the_share_of_touches_flagged(one_person, tmp_path, reject):
    """--reject 0 never flags a touch; --reject 0.5 flags about half of the out-of-fold ones
    (printed by train) and predict reports the flagged share."""
    import json

    out, preds = tmp_path / "m.joblib", tmp_path / "p.json"
    r = CliRunner().invoke(app, ["train", str(one_person), "--all-classes", "--quick", "--reject",
                                 reject, "-o", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert f"(--reject {float(reject):g})" in r.output
    model = eskin.load_model(out)
    assert model.calibration.reject == float(reject)
    assert model.training["decision"]["oof_flagged"] == pytest.approx(float(reject), abs=1 / 6)
    r = CliRunner().invoke(app, ["predict", str(out), str(one_person), "--json", str(preds)])
    assert r.exit_code == 0, r.output
    flagged = [p["dont_know"] for p in json.loads(preds.read_text())]
    if reject == "0":
        assert not any(flagged) and "don't know: none flagged" in r.output
    else:
        assert model.calibration.threshold > 0
        assert "don't know:" in r.output


def test_train_refuses_a_reject_share_of_one(one_person, tmp_path):
    r = CliRunner().invoke(app, ["train", str(one_person), "--all-classes", "--quick", "--reject",
                                 "1", "-o", str(tmp_path / "m.joblib"), "--no-progress"])
    assert r.exit_code == 2 and "--reject" in r.output


def test_train_keeps_the_model_within_its_size(one_person, tmp_path):
    from eskin.deploy.export import CompiledModel

    out = tmp_path / "m.eskin"
    r = CliRunner().invoke(app, ["train", str(one_person), "--all-classes", "--quick", "--machine",
                                 "svm", "-o", str(out), "--no-progress",
                                 "--max-model-size", "0.07"])
    assert r.exit_code == 0, r.output
    assert "to fit --max-model-size 0.07 MB: 6 -> " in r.output
    assert out.stat().st_size <= 70_000
    assert CompiledModel(out).n_support < 6
