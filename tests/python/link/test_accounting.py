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
from child_process import interruptible
from waiting import wait_until

from eskin.data.replay import write_replay_arrays
from eskin.link.listener import LinkListener
from eskin.link.protocol import DELIMITER, DataFrame, StatusFrame, StreamState, encode_frame

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
        preexec_fn=interruptible,
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
        preexec_fn=interruptible,
    )
    try:
        line = listen.stdout.readline()
        assert line.startswith(f"listening on {pty_path}"), (line, listen.stderr.read())
        # wait for a periodic statistics line that counts samples (an event, not a delay)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = listen.stdout.readline()
            assert line, listen.stderr.read()
            if line.startswith("stats ") and " samples=0 " not in line:
                break
        else:
            raise AssertionError("eskin listen printed no statistics with samples")
        listen.send_signal(signum)
        stdout, stderr = listen.communicate(timeout=30)
    finally:
        if listen.poll() is None:
            listen.kill()
        proc.send_signal(signal.SIGINT)
        fw_sim_stats(proc)
    assert listen.returncode == 128 + signum, stderr  # as a shell reports an interrupt
    assert "interrupted" in stdout and "Traceback" not in stderr
    lines = out.read_text().splitlines()
    final = json.loads(lines[-1])
    assert final["type"] == "stats"
    assert final["samples"] > 0 and final["frames"] > 0
    assert final["samples"] % 10 == 0  # whole DATA frames of 10 samples


def _controller_on_a_pty(frames: bytes, host_bytes):
    """A pty whose controller end, once the host has written its START, sends ``frames`` and
    closes once ``host_bytes()`` (the bytes the host has taken) has reached them all; returns
    (path of the host end, the controller thread)."""
    import select
    import threading

    master, slave = os.openpty()
    path = os.ttyname(slave)
    os.close(slave)

    def host_wrote() -> bool:  # the host opened the port and sent START
        r, _, _ = select.select([master], [], [], 0.05)
        try:
            return bool(r and os.read(master, 4096))
        except OSError:  # EIO: not open yet
            return False

    def run():
        wait_until(host_wrote, timeout=20, what="the host's START", interval=0.02)
        view = memoryview(frames)
        while view:
            view = view[os.write(master, view) :]
        wait_until(lambda: host_bytes() >= len(frames), what="the host to take every byte")
        os.close(master)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return path, t


def _frames(status_state, connections, samples_sent=50) -> bytes:
    rng = np.random.default_rng(0)
    data = [
        DataFrame(first, 0, rng.integers(-9, 9, (10, 2, 2)).astype(np.int16), seq=k)
        for k, first in enumerate((0, 20))
    ]  # samples 10..19 lost: a hole of 10
    status = StatusFrame(
        next_sample=50,
        samples_sent=samples_sent,
        state=status_state,
        host_connected=True,
        connections=connections,
        seq=2,
    )
    return DELIMITER + b"".join(encode_frame(f) for f in (*data, status))


@pytest.mark.parametrize(
    "state, connections, lost",
    [
        (StreamState.FINISHED, 1, 30),  # 50 sent, 20 received: the tail 30..49 counts too
        (StreamState.STOPPED, 1, 30),
        (StreamState.STREAMING, 1, 10),  # frames may still be on their way: holes only
        (StreamState.STOPPED, 2, 10),  # another host got some of the 50: holes only
        (StreamState.STOPPED, 0, 10),  # an older controller that does not say
        # finished: the samples after the last one received (next_sample 50) are lost anyway
        (StreamState.FINISHED, 0, 30),
    ],
)
def test_lost_samples_reconcile_with_the_controller_count(state, connections, lost):
    host: dict = {}
    path, thread = _controller_on_a_pty(_frames(state, connections),
                                        lambda: host["link"].stats.bytes if host else 0)
    with LinkListener(path, stats_interval=None) as link:
        host["link"] = link
        events = list(link.events(duration=10.0))
    thread.join(5)
    s = events[-1].stats
    assert (s.samples, s.lost_samples, s.controller_samples_sent) == (20, lost, 50)


@pytest.mark.parametrize("flip_rate, seed", [(0.05, 4), (0.002, 5)])
def test_lost_equals_sent_minus_received_under_bit_flips(fw_sim, replay, flip_rate, seed):
    proc, pty_path = start_fw_sim(
        fw_sim,
        replay.path,
        "--speed",
        0,
        "--wait-start",
        "--flip-rate",
        flip_rate,
        "--seed",
        seed,
        "--status-ms",
        10,
        "--hold",
        2,
        "--tx-buffer",
        1 << 20,
    )
    try:
        with LinkListener(pty_path, stats_interval=None) as link:
            events = list(link.events(until_eof=True, duration=30))
    finally:
        stats = fw_sim_stats(proc)
    s = events[-1].stats
    assert stats["samples_sent"] == replay.n_samples and stats["dropped_samples"] == 0
    assert s.controller_state == "finished" and s.controller_samples_sent == replay.n_samples
    assert s.lost_samples == stats["samples_sent"] - s.samples
    if flip_rate < 0.01:
        assert 0 < s.samples < replay.n_samples  # some frames arrived, some did not


def test_listen_record_killed_with_sigkill_loses_no_recording_it_reported(fw_sim, tmp_path):
    """`eskin listen --record` killed with SIGKILL: `eskin recover` salvages every recording
    the listener had reported as recorded, equal to its source segment."""
    from eskin.data.campaign import load_campaign

    rng = np.random.default_rng(8)
    recs = [rng.integers(-400, 400, size=(4, 4, 600)).astype(np.int16) for _ in range(30)]
    rf = write_replay_arrays(
        tmp_path / "segments.eskr",
        recs,
        labels=[k % 3 for k in range(30)],
        class_names=["a", "b", "c"],
        gap_s=0.05,
        seed=1,
    )
    # a 1 MB transmit queue: a host slowed down by a busy machine must not lose samples
    proc, pty_path = start_fw_sim(
        fw_sim, rf.path, "--speed", 1, "--wait-start", "--tx-buffer", 1 << 20
    )
    out = tmp_path / "live.h5"
    listen = subprocess.Popen(
        eskin_cmd("listen", pty_path, "--record", out, "--replay", rf.path, "--view", "plain"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=child_env(),
    )
    reported = []
    try:
        for line in listen.stdout:
            if line.startswith("recorded #"):
                reported.append(int(line.split()[1][1:]))
                if len(reported) == 4:
                    break
        listen.kill()
    finally:
        if listen.poll() is None:
            listen.kill()
        _, err = listen.communicate(timeout=10)
        proc.send_signal(signal.SIGINT)
        fw_sim_stats(proc)
    assert reported == [0, 1, 2, 3], err
    assert listen.returncode == -signal.SIGKILL
    assert not out.exists()
    res = subprocess.run(
        eskin_cmd("recover", out), capture_output=True, text=True, env=child_env(), timeout=60
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("recovered ")
    camp = load_campaign(out)
    assert len(camp) >= 4  # the kill came after the 4th report; a 5th may have been appended
    assert not np.any(camp.extras["lost_samples"])  # every recording arrived whole
    for k in range(len(camp)):
        assert np.array_equal(camp.recording(k), recs[k])
        assert camp.modalities[camp.modality[k]] == "abc"[k % 3]


def test_listen_record_onto_an_existing_file_is_one_line(fw_sim, tmp_path):
    rng = np.random.default_rng(3)
    recs = [rng.integers(-400, 400, size=(4, 4, 300)).astype(np.int16) for _ in range(3)]
    rf = write_replay_arrays(tmp_path / "s.eskr", recs, gap_s=0.05, seed=1)
    out = tmp_path / "taken.h5"
    out.write_bytes(b"someone's data")
    proc, pty_path = start_fw_sim(fw_sim, rf.path, "--speed", 0, "--wait-start")
    try:
        res = subprocess.run(
            eskin_cmd(
                "listen",
                pty_path,
                "--record",
                out,
                "--replay",
                rf.path,
                "--until-eof",
                "--view",
                "plain",
                "--duration",
                30,
            ),
            capture_output=True,
            text=True,
            env=child_env(),
            timeout=60,
        )
    finally:
        proc.send_signal(signal.SIGINT)
        fw_sim_stats(proc)
    assert res.returncode == 2, res.stderr
    errors = [x for x in res.stderr.splitlines() if x]
    assert errors == [
        f"error: {out}: file exists; refusing to overwrite it (use --force to replace it)"
    ], res.stderr
    assert out.read_bytes() == b"someone's data"


def test_decisions_sent_but_not_received_are_counted():
    """A controller's STATUS (finished) says it sent 3 decisions and 2 dropped; 1 arrived: the
    host counts 2 lost on the link, beside the controller's 2 dropped."""
    from eskin.link.protocol import DecisionFrame

    dec = DecisionFrame(onset_sample=2, offset_sample=8, label=-1, decided_sample=9, seq=1)
    data = DataFrame(0, 0, np.zeros((10, 2, 2), np.int16), seq=0)
    status = StatusFrame(next_sample=10, samples_sent=10, decisions_sent=3, decisions_dropped=2,
                         state=StreamState.FINISHED, host_connected=True, connections=1, seq=4)
    host: dict = {}
    path, thread = _controller_on_a_pty(
        DELIMITER + b"".join(encode_frame(f) for f in (data, dec, status)),
        lambda: host["link"].stats.bytes if host else 0)
    with LinkListener(path, stats_interval=None) as link:
        host["link"] = link
        events = list(link.events(duration=10.0))
    thread.join(5)
    s = events[-1].stats
    assert (s.decisions_controller, s.lost_decisions, s.controller_decisions_dropped) == (1, 2, 2)
    assert s.controller_decisions_sent == 3 and s.lost_frames == 2  # seq 2, 3 missing
