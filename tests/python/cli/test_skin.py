"""The skin commands' user errors: one line, exit code 2, nothing overwritten."""

from __future__ import annotations

from typer.testing import CliRunner

from eskin.cli import app

SKIN = """
[defaults]
grid = [4, 4]
sample_rate_hz = 3000
link = "simulated"
[[patch]]
id = "p0"
[[patch]]
id = "p1"
origin_mm = [48.0, 0.0]
"""


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_simulate_skin_writes_the_folder_once(tmp_path):
    (tmp_path / "s.toml").write_text(SKIN)
    r = run("simulate", "--skin", tmp_path / "s.toml", "-o", tmp_path / "sim", "--gestures", 1,
            "--episode", 1)
    assert r.exit_code == 0, r.output
    assert "gesture 0: slide on p" in r.output
    assert sorted(p.name for p in (tmp_path / "sim").iterdir()) == ["p0.eskr", "p1.eskr",
                                                                   "skin.h5"]
    before = (tmp_path / "sim" / "p0.eskr").read_bytes()
    r = run("simulate", "--skin", tmp_path / "s.toml", "-o", tmp_path / "sim", "--gestures", 1,
            "--episode", 1, "--seed", 5)
    assert r.exit_code == 2 and "--force" in r.output and len(r.output.splitlines()) == 1
    assert (tmp_path / "sim" / "p0.eskr").read_bytes() == before


def test_bad_skin_files_are_one_line_errors(tmp_path):
    (tmp_path / "s.toml").write_text(SKIN.replace("[4, 4]", "[4, 0]"))
    for args in (("simulate", "--skin", tmp_path / "s.toml", "-o", tmp_path / "o"),
                 ("fw-sim", "--skin", tmp_path / "s.toml", tmp_path),
                 ("listen", "--skin", tmp_path / "s.toml", "--sim", tmp_path)):
        r = run(*args)
        assert r.exit_code == 2, r.output
        assert r.output.strip() == (f"error: {tmp_path / 's.toml'}: patch[0].grid: [4, 0]: "
                                    f"rows and columns must be in 1..255")


def test_fw_sim_skin_needs_the_replays(tmp_path):
    (tmp_path / "s.toml").write_text(SKIN)
    r = run("fw-sim", "--skin", tmp_path / "s.toml", tmp_path)
    assert r.exit_code == 2 and "p0.eskr: no replay for patch 'p0'" in r.output


def skin_campaign(tmp_path):
    """The small simulated campaign as a two-patch skin's: participants 1, 3, 5 on "left",
    2, 4, 6 on "right"."""
    import numpy as np

    from eskin.data.campaign import load_campaign, write_campaign
    from learn_data import small_simulated

    c = load_campaign(small_simulated(tmp_path.parent), in_memory=True)
    path = tmp_path / "skin.h5"
    write_campaign(path, np.asarray(c.signals), modality=c.modality, participant=c.participant,
                   direction=c.direction, run=c.run, lengths=c.lengths,
                   modalities=c.modalities, sample_rate_hz=c.sample_rate_hz,
                   volts_per_count=c.volts_per_count, source="simulated",
                   attrs={"patches": '["left", "right"]'},
                   extras={"patch": (c.participant % 2 == 0).astype(np.uint16)})
    return path, int(np.sum(c.participant % 2 == 0))


def test_train_on_some_patches_of_a_skin_campaign(tmp_path):
    from eskin.deploy import load_model

    path, n_right = skin_campaign(tmp_path)
    r = run("train", path, "-o", tmp_path / "right.joblib", "--patch", "right", "--quick",
            "--machine", "rls", "--D", 20, "--no-progress")
    assert r.exit_code == 0, r.output
    model = load_model(tmp_path / "right.joblib")
    assert len(model.training["recording_digests"]) == n_right
    r = run("train", path, "-o", tmp_path / "x.joblib", "--patch", "wrist", "--quick")
    assert r.exit_code == 2 and "no patch 'wrist' (patches: left, right)" in r.output


def test_train_patch_needs_a_skin_campaign(tmp_path):
    from learn_data import small_simulated

    plain = small_simulated(tmp_path.parent)
    r = run("train", plain, "-o", tmp_path / "x.joblib", "--patch", "a", "--quick")
    assert r.exit_code == 2 and "the campaign has no patch field" in r.output


def test_evaluate_on_some_patches_of_a_skin_campaign(tmp_path):
    import json

    path, _ = skin_campaign(tmp_path)
    r = run("evaluate", path, "-o", tmp_path / "ev", "--patch", "right", "--quick",
            "--machine", "rls", "--D", 20, "--folds", 3, "--no-live")
    assert r.exit_code == 0, r.output
    result = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    tested = sorted(g for f in result["folds"] for g in f["test_groups"])
    assert tested == [2, 4, 6]  # the participants of patch "right", each tested once
