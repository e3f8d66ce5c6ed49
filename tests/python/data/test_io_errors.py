"""I/O errors at every durable step of the writer, the journal and recovery, and through the
command line on real full and read-only file systems.

The rule: each failure is one line naming the file, and nothing durable is lost: every
recording whose append returned is, once the fault is gone, in the campaign file or in a
journal that `recover_campaign` turns into one.

Part 1 makes the operating-system calls themselves fail, in turn: the n-th call of
``os.open`` / ``write`` / ``fsync`` / ``fdatasync`` / ``link`` / ``replace`` / ``rename`` and
of HDF5's file creation raises ENOSPC, EIO or EROFS as the kernel would, before doing
anything (our code above them is not replaced). Part 2 runs ``eskin`` on a 256 KiB tmpfs and
on a read-only one (mounted for the test; skipped where mounting is not allowed).
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from tmpfs import mounted_tmpfs

from eskin.data.campaign import CampaignWriter, load_campaign, recover_campaign
from eskin.data.journal import journal_path

REPO = Path(__file__).resolve().parents[3]
CALLS = ("open", "write", "fsync", "fdatasync", "link", "replace", "rename")
ERRNOS = (errno.ENOSPC, errno.EIO, errno.EROFS)
N = 3


class Faults:
    """Counts the calls of one OS function (or HDF5 file creation) and fails the n-th."""

    def __init__(self, monkeypatch, call: str, nth: int = 0, err: int = errno.EIO):
        self.calls, self.nth, self.err, self.fired = 0, nth, err, False
        if call == "h5create":
            real = h5py.File

            def fake(name, mode="r", *args, **kw):
                if mode in ("w", "w-", "x") and self._fire():
                    raise OSError(self.err, f"Unable to create file (unable to open file: "
                                  f"name = '{name}', errno = {self.err}, error message = "
                                  f"'{os.strerror(self.err)}')")
                return real(name, mode, *args, **kw)

            monkeypatch.setattr(h5py, "File", fake)
            return
        real_os = getattr(os, call)

        def failing(*args, **kw):
            if self._fire():
                raise OSError(self.err, os.strerror(self.err))
            return real_os(*args, **kw)

        monkeypatch.setattr(os, call, failing)

    def _fire(self) -> bool:
        self.calls += 1
        if self.calls == self.nth:
            self.fired = True
            return True
        return False


def _write(path: Path) -> int:
    """Open a writer, append N recordings, close; returns the appends that returned."""
    returned = 0
    with CampaignWriter(path, grid_shape=(2, 2), n_samples=16, sample_rate_hz=1000.0,
                        volts_per_count=1e-3, modalities=["a", "b"], source="recorded") as w:
        for i in range(N):
            w.append(np.full((2, 2, 16), i, np.int16), modality=i % 2, participant=i,
                     direction=0, run=1)
            returned += 1
    return returned


def _held(path: Path) -> int:
    """Recordings held for ``path`` once the fault is gone (the campaign, else the journal)."""
    if not path.exists() and journal_path(path).exists():
        recover_campaign(path)
    if not path.exists():
        return 0
    with load_campaign(path, check_data=True) as c:
        assert list(c.participant) == list(range(len(c)))
        return len(c)


def _check_line(exc: BaseException, tmp: Path) -> None:
    text = str(exc)
    assert "\n" not in text and str(tmp) in text, text  # one line, naming the file


def _scenarios(call: str, counted: int):
    """(n-th call, errno) pairs: every call, the errno cycling; the first with each errno."""
    pairs = {(n, ERRNOS[n % 3]) for n in range(1, counted + 1)}
    pairs |= {(1, e) for e in ERRNOS}
    return sorted(pairs)


@pytest.mark.parametrize("call", [*CALLS, "h5create"])
def test_the_writer_loses_nothing_that_returned_when_a_call_fails(tmp_path, monkeypatch, call):
    with monkeypatch.context() as m:
        counter = Faults(m, call)
        assert _write(tmp_path / "count.h5") == N
    assert counter.calls > 0 or call in ("replace", "rename")  # link, not replace, places it
    for k, (nth, err) in enumerate(_scenarios(call, counter.calls)):
        path = tmp_path / f"c{k}.h5"
        returned, failure = 0, None
        with monkeypatch.context() as m:
            fault = Faults(m, call, nth, err)
            try:
                returned = _write(path)
            except OSError as exc:
                failure = exc
        assert fault.fired == (failure is not None) or call == "link", (call, nth, failure)
        if failure is not None:
            _check_line(failure, tmp_path)
            returned = len(load_campaign(path)) if path.exists() else _appended(failure)
        assert _held(path) >= returned, (call, nth, err, failure)


def _appended(failure: BaseException) -> int:
    """The appends that returned before ``failure``: its note (an exception in the block),
    else none (the writer failed while opening)."""
    import re

    for note in getattr(failure, "__notes__", []):
        m = re.search(r"the (\d+) recordings whose append returned", note)
        if m:
            return int(m.group(1))
    m = re.search(r"cannot append recording (\d+)", str(failure))
    return int(m.group(1)) if m else 0


@pytest.mark.parametrize("call", [*CALLS, "h5create"])
def test_recovery_keeps_the_journal_until_the_campaign_is_in_place(tmp_path, monkeypatch, call):
    def journal(path: Path) -> None:
        with pytest.raises(RuntimeError):
            with CampaignWriter(path, grid_shape=(2, 2), n_samples=16, sample_rate_hz=1e3,
                                volts_per_count=1e-3, modalities=["a"], source="recorded") as w:
                for i in range(N):
                    w.append(np.zeros((2, 2, 16), np.int16), modality=0, participant=i,
                             direction=0, run=1)
                raise RuntimeError("the program stops: the journal is kept")

    journal(tmp_path / "count.h5")
    with monkeypatch.context() as m:
        counter = Faults(m, call)
        recover_campaign(tmp_path / "count.h5")
    for k, (nth, err) in enumerate(_scenarios(call, counter.calls)):
        path = tmp_path / f"c{k}.h5"
        journal(path)
        with monkeypatch.context() as m:
            Faults(m, call, nth, err)
            try:
                recover_campaign(path)
            except OSError as exc:
                _check_line(exc, tmp_path)
        assert _held(path) == N, (call, nth, err)


# ----------------------------------------------------------------- real file systems, the CLI


def eskin(*args) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO / "python") + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "eskin", *map(str, args)], capture_output=True,
                          text=True, env=env, timeout=300)


def _one_line(r: subprocess.CompletedProcess, *names: Path) -> str:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr + r.stdout, r.stderr
    assert any(str(n) in r.stderr for n in names), r.stderr
    return r.stderr


def test_a_full_disk_through_the_command_line(tmp_path):
    from eskin.data.campaign import write_campaign

    src = write_campaign(tmp_path / "src.h5", np.random.default_rng(0).integers(
        -999, 999, (4, 4, 4, 3000)).astype(np.int16), modality=[0, 1, 0, 1],
        participant=[1, 1, 2, 2], direction=[0] * 4, run=[1] * 4, modalities=["a", "b"],
        sample_rate_hz=3000.0, volts_per_count=1e-3, source="recorded")
    # a journal of the 4 recordings, to recover onto the full disk
    with pytest.raises(RuntimeError), CampaignWriter(
            tmp_path / "j.h5", grid_shape=(4, 4), n_samples=3000, sample_rate_hz=3000.0,
            volts_per_count=1e-3, modalities=["a", "b"], source="recorded",
            compression_level=None) as w:
        with load_campaign(src) as c:
            for i in range(4):
                w.append(c.recording(i), modality=0, participant=i, direction=0, run=1)
        raise RuntimeError("stop")
    with mounted_tmpfs(tmp_path / "full", "size=256k") as full:
        line = _one_line(eskin("recover", tmp_path / "j.h5", "-o", full / "r.h5"), full / "r.h5")
        assert "cannot write the campaign file" in line and "the journal is kept" in line
        assert len(load_campaign(recover_campaign(tmp_path / "j.h5").output)) == 4
        _one_line(eskin("simulate", "-o", full / "s.h5", "--participants", "1", "-j", "1",
                        "-q"), full)
        assert sorted(p.name for p in full.iterdir()) == []  # simulated data: nothing kept
        _one_line(eskin("replay", src, "-o", full / "r.eskr", "--gap", "60"), full)


def test_a_read_only_disk_through_the_command_line(tmp_path):
    with mounted_tmpfs(tmp_path / "ro", "size=1m,ro") as ro:
        line = _one_line(eskin("simulate", "-o", ro / "s.h5", "--participants", "1", "-j", "1"),
                         ro)
        assert "Read-only file system" in line


def test_listen_record_onto_a_full_disk(tmp_path):
    """`eskin listen --record` against eskin-fw-sim: the disk fills while recording; one line
    naming the journal, the statistics still written, the recordings appended kept."""
    import json
    import signal

    from eskin._paths import find_executable
    from eskin.data.replay import write_replay_arrays

    rng = np.random.default_rng(5)
    recs = [rng.integers(-3000, 3000, (4, 4, 3000)).astype(np.int16) for _ in range(6)]
    replay = write_replay_arrays(tmp_path / "noise.eskr", recs, labels=[0, 1, 2] * 2,
                                 class_names=("a", "b", "c"), gap_s=0.05, seed=2)
    with mounted_tmpfs(tmp_path / "full", "size=200k") as full:
        sim = subprocess.Popen([find_executable("eskin-fw-sim"), str(replay.path), "--speed",
                                "10", "--wait-start", "--quiet", "--tx-buffer", str(1 << 22)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            pty = sim.stdout.readline().split()[1]
            out = tmp_path / "d.jsonl"
            r = eskin("listen", pty, "--record", full / "live.h5", "--replay", replay.path,
                      "--until-eof", "--duration", "120", "--jsonl", out, "--view", "plain")
        finally:
            sim.send_signal(signal.SIGINT)
            sim.communicate(timeout=30)
        line = _one_line(r, full / ".live.h5.partial")
        assert "cannot append recording" in line and f"eskin recover {full / 'live.h5'}" in line
        stats = json.loads(out.read_text().splitlines()[-1])
        assert stats["type"] == "stats" and stats["samples"] > 0
        kept = int(line.split("cannot append recording ")[1].split()[0])
        assert kept >= 1
        held = recover_campaign(full / "live.h5", tmp_path / "saved.h5")
        assert held.recordings == kept


def test_export_onto_a_full_disk(tmp_path):
    """`eskin export` of a trained model: one line naming the .eskin file, nothing left."""
    from eskin.data.simulator import simulate
    from eskin.learn.models import save_model
    from eskin.learn.training import train_model

    campaign = simulate(tmp_path / "c.h5", participants=2, seed=0, n_jobs=1)
    model = save_model(train_model(load_campaign(campaign), D=20, selection="md"),
                       tmp_path / "m.joblib")
    with mounted_tmpfs(tmp_path / "full", "size=8k") as full:
        (full / "filler").write_bytes(b"\0" * 4096)
        line = _one_line(eskin("export", model, "-o", full / "m.eskin"), full / "m.eskin")
        assert "No space left on device" in line
        assert sorted(p.name for p in full.iterdir()) == ["filler"]  # no partial model


def _fill(fs: Path) -> None:
    """Fill a file system to its last byte."""
    fd = os.open(fs / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        while os.write(fd, b"\0" * 1024):
            pass
    except OSError as exc:
        assert exc.errno == errno.ENOSPC
    finally:
        os.close(fd)


QUICK = ("--quick", "--D", "20", "--machine", "svm", "--subsample", "algorithm2",
         "--selection", "md")


def test_train_and_evaluate_onto_a_full_disk_and_a_read_only_one(tmp_path):
    """`eskin train -o` and `eskin evaluate --out`: one line naming the file; the model a
    --force run was replacing is intact and no partial file is left; evaluate prints its scores
    before writing, so the full disk costs the files, not the results."""
    from eskin.data.simulator import simulate

    campaign = simulate(tmp_path / "c.h5", participants=2, runs=(2,), seed=0, n_jobs=1)
    with mounted_tmpfs(tmp_path / "full", "size=64k") as full:
        old = b"the model of an earlier run" * 100
        (full / "m.joblib").write_bytes(old)
        (full / "ev").mkdir()
        _fill(full)
        line = _one_line(eskin("train", campaign, *QUICK, "-o", full / "m.joblib", "--force",
                               "--no-progress"), full / "m.joblib")
        assert line == f"error: {full / 'm.joblib'}: No space left on device\n"
        assert (full / "m.joblib").read_bytes() == old
        r = eskin("evaluate", campaign, *QUICK, "--folds", "2", "--out", full / "ev")
        line = _one_line(r, full / "ev" / "evaluation.json")
        assert line == f"error: {full / 'ev' / 'evaluation.json'}: No space left on device\n"
        assert "accuracy" in r.stdout
        assert sorted(p.name for p in full.rglob("*")) == ["ev", "filler", "m.joblib"]
    with mounted_tmpfs(tmp_path / "ro", "size=64k,ro") as ro:
        line = _one_line(eskin("train", campaign, *QUICK, "-o", ro / "m.joblib",
                               "--no-progress"), ro / "m.joblib")
        assert "Read-only file system" in line
        line = _one_line(eskin("evaluate", campaign, *QUICK, "--folds", "2", "--out", ro / "ev"),
                         ro / "ev")
        assert "Read-only file system" in line
