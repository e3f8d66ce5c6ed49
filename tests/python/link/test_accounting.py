"""Link accounting with the real eskin-fw-sim over a real pty: every sample the controller sent
is received or counted lost, and `eskin listen` writes its final statistics even when a signal
ends it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from eskin.data.replay import write_replay_arrays

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def fw_sim():
    from eskin._paths import find_executable

    return find_executable("eskin-fw-sim")


@pytest.fixture(scope="module")
def replay(tmp_path_factory):
    """A 2 s replay of noise (6000 samples of 4x4 taxels)."""
    rng = np.random.default_rng(11)
    recs = [rng.integers(-300, 300, size=(4, 4, 2000)).astype(np.int16) for _ in range(3)]
    path = tmp_path_factory.mktemp("replay") / "noise.eskr"
    return write_replay_arrays(path, recs, gap_s=0.0, seed=2)


def start_fw_sim(exe, *args) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [str(exe), *map(str, args), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    first = proc.stdout.readline().split()
    assert first and first[0] == "PTY", (first, proc.stderr.read())
    return proc, first[1]


def fw_sim_stats(proc) -> dict:
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    return json.loads([x for x in out.splitlines() if x.startswith("STATS ")][-1][6:])


def eskin_cmd(*args) -> list[str]:
    return [sys.executable, "-m", "eskin", *map(str, args)]


def child_env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO / "python") + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_listen_writes_its_final_statistics_when_a_signal_ends_it(fw_sim, replay, tmp_path, signum):
    proc, pty_path = start_fw_sim(fw_sim, replay.path, "--speed", 1, "--loop")
    out = tmp_path / "events.jsonl"
    listen = subprocess.Popen(
        eskin_cmd("listen", pty_path, "--jsonl", out, "--view", "plain"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=child_env(),
    )
    try:
        line = listen.stdout.readline()
        assert line.startswith(f"listening on {pty_path}"), (line, listen.stderr.read())
        time.sleep(0.7)  # some samples arrive
        listen.send_signal(signum)
        stdout, stderr = listen.communicate(timeout=30)
    finally:
        if listen.poll() is None:
            listen.kill()
        proc.send_signal(signal.SIGINT)
        fw_sim_stats(proc)
    assert listen.returncode == 0, stderr
    assert "interrupted" in stdout and "Traceback" not in stderr
    lines = out.read_text().splitlines()
    final = json.loads(lines[-1])
    assert final["type"] == "stats"
    assert final["samples"] > 0 and final["frames"] > 0
    assert final["samples"] % 10 == 0  # whole DATA frames of 10 samples
