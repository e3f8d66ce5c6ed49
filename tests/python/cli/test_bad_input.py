"""Absurd arguments and damaged attributes end in one line naming the file, field and value,
exit code 2 (the command line as a user runs it: the real `eskin` app)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from eskin.cli import app
from eskin.data.campaign import write_campaign


@pytest.fixture
def campaign(tmp_path):
    rng = np.random.default_rng(0)
    sig = rng.integers(-300, 300, (6, 4, 4, 400)).astype(np.int16)
    return write_campaign(tmp_path / "c.h5", sig, modality=[0, 1, 2] * 2,
                          participant=[1, 1, 1, 2, 2, 2], direction=[0] * 6, run=[1] * 6,
                          modalities=["brush", "finger", "washer"], sample_rate_hz=3000.0,
                          volts_per_count=1e-3, source="recorded")


def _one_line_error(args: list[str]) -> str:
    r = CliRunner().invoke(app, [str(a) for a in args])
    assert r.exit_code == 2, (r.exit_code, r.output, r.exception)
    assert r.output.count("\n") == 1 and r.output.startswith("error: "), r.output
    return r.output.strip()


@pytest.mark.parametrize("gap", ["1e12", "inf", "nan", "-1"])
def test_replay_gap_out_of_range(campaign, tmp_path, gap):
    line = _one_line_error(["replay", campaign, "-o", tmp_path / "r.eskr", "--gap", gap])
    assert line == f"error: --gap must be a number of seconds in [0, 3600], got {float(gap):g}"
    assert not (tmp_path / "r.eskr").exists()


def test_train_refuses_a_D_that_export_would_refuse(campaign, tmp_path):
    line = _one_line_error(["train", campaign, "-o", tmp_path / "m.joblib", "--all-classes",
                            "--D", "1"])
    assert "D must be in [2, 100000]" in line and "got 1" in line
    assert not (tmp_path / "m.joblib").exists()


def test_a_format_attribute_that_is_not_utf8(campaign):
    with h5py.File(campaign, "a") as f:
        f.attrs["format"] = np.bytes_(b"eskin-\xffcampaign")
    line = _one_line_error(["info", campaign])
    assert line == (f"error: {campaign}: attribute 'format': not UTF-8 text (byte 0xff at "
                    f"position 6)")


def test_an_empty_file_name():
    assert _one_line_error(["info", ""]) == "error: no file name given (the argument is empty)"
    assert _one_line_error(["plot", "", "-o", "x.png"]).startswith("error: no file name given")


@pytest.mark.parametrize("index", ["-1", "6"])
def test_plot_index_outside_the_campaign(campaign, tmp_path, index):
    line = _one_line_error(["plot", campaign, "--index", index, "-o", tmp_path / "p.png"])
    assert line == f"error: --index {index} is out of range: {campaign} holds recordings 0 to 5"
    assert not (tmp_path / "p.png").exists()
