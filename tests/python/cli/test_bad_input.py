"""Absurd arguments and damaged attributes end in one line naming the file, field and value,
exit code 2 (the command line as a user runs it: the real `eskin` app)."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from tmpfs import mounted_tmpfs
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


# ------------------------------------------------------------------ a full disk, a real process

REPO = Path(__file__).resolve().parents[3]
REPLAY_FORMATS = ("replay", "npy", "records", "raw")


def eskin(*args, preexec_fn=None) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO / "python") + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "eskin", *map(str, args)], capture_output=True,
                          text=True, env=env, timeout=120, preexec_fn=preexec_fn)


def _one_line_exit_2(r: subprocess.CompletedProcess, name: Path) -> str:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)  # not 135 (SIGBUS)
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr + r.stdout, r.stderr
    assert r.stderr.startswith(f"error: {name}: "), r.stderr
    return r.stderr.strip()


@pytest.mark.parametrize("fmt", REPLAY_FORMATS)
def test_replay_onto_a_full_disk(campaign, tmp_path, fmt):
    """A 32 KiB tmpfs: the .npy (77 KB) was written through a memory map, which a full tmpfs
    kills with SIGBUS, leaving a sparse file of the full size under the target name; the other
    formats were left truncated under it. Now: one line, exit 2, nothing under any name."""
    with mounted_tmpfs(tmp_path / "full", "size=32k") as full:
        out = full / f"b.{fmt}"
        line = _one_line_exit_2(eskin("replay", campaign, "-o", out, "--format", fmt), out)
        assert line == f"error: {out}: No space left on device"
        assert sorted(full.iterdir()) == []


def _file_size_limit(limit: int):
    def set_limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # past the limit, write gives EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return set_limit


@pytest.mark.parametrize("fmt", REPLAY_FORMATS)
def test_replay_past_the_file_size_limit(campaign, tmp_path, fmt):
    """The same without a tmpfs (no root needed): a process limited to files of 32 KiB."""
    out = tmp_path / "out" / f"b.{fmt}"
    out.parent.mkdir()
    r = eskin("replay", campaign, "-o", out, "--format", fmt,
              preexec_fn=_file_size_limit(32 << 10))
    assert _one_line_exit_2(r, out) == f"error: {out}: File too large"
    assert sorted(out.parent.iterdir()) == []


@pytest.mark.parametrize("fmt", ["npy", "raw"])
def test_replay_force_keeps_the_old_file_when_the_new_one_cannot_be_written(
        campaign, tmp_path, fmt):
    out = tmp_path / "out" / f"b.{fmt}"
    out.parent.mkdir()
    out.write_bytes(b"an earlier replay")
    r = eskin("replay", campaign, "-o", out, "--format", fmt, "--force",
              preexec_fn=_file_size_limit(32 << 10))
    _one_line_exit_2(r, out)
    assert out.read_bytes() == b"an earlier replay"
    assert sorted(p.name for p in out.parent.iterdir()) == [out.name]


# ------------------------------------------------------- declared sizes the file cannot hold


def _unwritten_campaign(path: Path) -> Path:
    """11 KB declaring 24 recordings of 64x64x100000 samples (19.7 GB) in gzip chunks never
    written: within every size limit; `info --check`, `plot` and `replay` read zeros for 60-90 s."""
    write_campaign(path, np.zeros((24, 4, 4, 10), np.int16), modality=[0, 1, 2] * 8,
                   participant=[1] * 24, direction=[0] * 24, run=[1] * 24,
                   modalities=["brush", "finger", "washer"], sample_rate_hz=3000.0,
                   volts_per_count=1e-3, source="recorded")
    with h5py.File(path, "a") as f:
        del f["recordings/signals"]
        f["recordings"].create_dataset("signals", shape=(24, 64, 64, 100_000), dtype=np.int16,
                                       chunks=(1, 64, 64, 2000), compression="gzip",
                                       shuffle=True)
        f["recordings/length"][...] = 100_000
    return path


@pytest.mark.parametrize("command", [["info", "--check"], ["plot", "-o", "p.png"],
                                     ["replay", "-o", "r.eskr"]])
def test_a_campaign_declaring_more_than_it_stores(tmp_path, command):
    import time

    p = _unwritten_campaign(tmp_path / "huge.h5")
    assert p.stat().st_size < 20_000
    args = [a if not a.endswith((".png", ".eskr")) else str(tmp_path / a) for a in command]
    start = time.perf_counter()
    line = _one_line_error([args[0], p, *args[1:]])
    assert time.perf_counter() - start < 5.0
    assert line.startswith(f"error: {p}: /recordings/signals: shape (24, 64, 64, 100000): "
                           f"declares 19,660,800,000 bytes of samples but the file stores 0 "
                           f"bytes of them")
    assert sorted(q.name for q in tmp_path.iterdir()) == ["huge.h5"]


# --------------------------------------------------------------- symbolic link loops, rates


@pytest.mark.parametrize("command", [["plot", "-o", "x.png"], ["replay", "-o", "x.eskr"],
                                     ["info", "--check"]])
def test_a_symbolic_link_loop(tmp_path, command):
    loop = tmp_path / "loop.h5"
    loop.symlink_to("loop.h5")
    args = [a if not a.endswith((".png", ".eskr")) else str(tmp_path / a) for a in command]
    line = _one_line_error([args[0], loop, *args[1:]])
    assert line == f"error: {loop}: Too many levels of symbolic links"
    assert sorted(q.name for q in tmp_path.iterdir()) == ["loop.h5"]


@pytest.mark.parametrize("rate", [1e300, 1e-300])
@pytest.mark.parametrize("command", [["replay", "-o", "r.eskr"], ["replay", "-o", "r.raw"],
                                     ["info"]])
def test_a_sample_rate_outside_the_range_eskin_reads(campaign, tmp_path, rate, command):
    with h5py.File(campaign, "a") as f:
        f.attrs["sample_rate_hz"] = rate
    args = [a if not a.endswith((".raw", ".eskr")) else str(tmp_path / a) for a in command]
    line = _one_line_error([args[0], campaign, *args[1:]])
    assert line == (f"error: {campaign}: attribute 'sample_rate_hz': {rate:g} Hz is outside "
                    f"the sample rates eskin reads, 0.1 Hz to 1e+06 Hz (docs/dataset-format.md)")
    assert sorted(q.name for q in tmp_path.iterdir()) == ["c.h5"]


# ---------------------------------------------------------------------- smaller refusals


@pytest.mark.parametrize("budget,line", [
    ("flash=1M,flash=2M", "error: --budget flash=1M,flash=2M: flash is given twice"),
    ("", "error: --budget '' is empty: give flash=..,ram=..,instr=.. (or leave --budget out "
         "for the target's own budget)"),
])
def test_train_budget_repeated_or_empty(campaign, tmp_path, budget, line):
    assert _one_line_error(["train", campaign, "-o", tmp_path / "m.joblib", "--budget",
                            budget]) == line
    assert not (tmp_path / "m.joblib").exists()


@pytest.mark.parametrize("command", [["export", "-o", "m.eskin"], ["predict"]])
def test_a_campaign_given_as_a_model(campaign, tmp_path, command):
    """`eskin export CAMPAIGN` said "KeyError: 72" (joblib reading an HDF5 file)."""
    args = [a if not a.endswith(".eskin") else str(tmp_path / a) for a in command]
    rest = [campaign] if args[0] == "predict" else []
    line = _one_line_error([args[0], campaign, *rest, *args[1:]])
    assert line == (f"error: {campaign} is not an eskin model file: it is an eskin campaign (a "
                    f"model is trained from one: `eskin train CAMPAIGN -o MODEL.joblib`)")
    assert not (tmp_path / "m.eskin").exists()


def test_a_hidden_file_of_a_killed_writer_is_removed_by_the_next_write(campaign, tmp_path):
    """`eskin replay -o r.eskr` killed before its rename leaves `.r.<pid>.tmp.eskr` (SIGKILL,
    SIGTERM: no cleanup runs); the next write of r.eskr removes it when its process is gone."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f".r.{dead.pid}.tmp.eskr"
    stale.write_bytes(b"half a replay")
    r = CliRunner().invoke(app, ["replay", str(campaign), "-o", str(tmp_path / "r.eskr")])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.h5", "r.eskr"]
