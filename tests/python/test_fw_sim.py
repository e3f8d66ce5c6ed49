"""eskin-fw-sim end to end: the real executable, a real pseudo-terminal, the bound SerialPort
and FrameDecoder on the host side."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from eskin._paths import find_executable
from eskin.data.replay import read_replay_file, write_replay_arrays
from eskin.link.protocol import (
    SAMPLES_PER_FRAME,
    CommandFrame,
    DataFrame,
    DecisionFrame,
    Flags,
    FrameDecoder,
    FrameType,
    InfoFrame,
    PingFrame,
    PongFrame,
    StatusFrame,
    StreamState,
    encode_frame,
)
from eskin.link.serial_port import PeerClosedError, SerialPort
from waiting import wait_until

START = encode_frame(CommandFrame(FrameType.START))
# Paced tests that expect no drops give the simulator a queue that outlasts a host stalled by a
# busy machine (drops are tested on their own, with a small queue).
BIG_QUEUE = ("--tx-buffer", str(4 << 20))
STOP = encode_frame(CommandFrame(FrameType.STOP))


@pytest.fixture(scope="module")
def fw_sim() -> Path:
    try:
        return find_executable("eskin-fw-sim")
    except FileNotFoundError as e:  # the C++ tools are part of every build
        pytest.fail(str(e))


@pytest.fixture(scope="module")
def replay(tmp_path_factory) -> Path:
    """Three recordings (0.5-1.2 s) of random 4x4 ADC codes with 0.1 s quiet gaps."""
    rng = np.random.default_rng(42)
    recs = []
    for n in (1500, 3600, 2400):
        r = rng.normal(0, 300, size=(4, 4, n))
        r[:, :, n // 3 : 2 * n // 3] *= 20
        recs.append(np.clip(r, -32768, 32767).astype(np.int16))
    path = tmp_path_factory.mktemp("replay") / "small.eskr"
    write_replay_arrays(
        path, recs, labels=[0, 1, 2], class_names=["brush", "finger", "washer"], gap_s=0.1,
        volts_per_count=2.5e-4, seed=3,
    )
    return path


class Sim:
    """A running eskin-fw-sim; always terminated at the end of the test."""

    def __init__(self, exe: Path, *args: str):
        self.proc = subprocess.Popen(
            [str(exe), *args] + ([] if os.environ.get("FWSIM_VERBOSE") else ["--quiet"]), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        first = self.proc.stdout.readline().split()
        assert first[0] == "PTY", first
        self.path = first[1]
        assert self.proc.stdout.readline().startswith("ORIGIN_NS ")

    def stats(self, timeout: float = 20.0) -> dict:
        out, err = self.proc.communicate(timeout=timeout)
        assert self.proc.returncode == 0, err
        line = [x for x in out.splitlines() if x.startswith("STATS ")][-1]
        return json.loads(line[len("STATS ") :])

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.communicate()


@pytest.fixture
def sim(fw_sim):
    started: list[Sim] = []

    def start(*args: str) -> Sim:
        s = Sim(fw_sim, *[str(a) for a in args])
        started.append(s)
        return s

    yield start
    for s in started:
        s.close()


def read_until_closed(port: SerialPort, dec: FrameDecoder, limit_s: float = 30.0) -> list:
    frames: list = []
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        try:
            frames += dec.feed(port.read(65536, timeout=0.5))
        except PeerClosedError:
            return frames
    raise AssertionError("the simulator did not finish in time")


def check_samples(frames: list, source: np.ndarray) -> int:
    """Every DATA frame holds exactly the source samples at its indices; returns the count."""
    n = 0
    for f in frames:
        if isinstance(f, DataFrame):
            np.testing.assert_array_equal(f.samples, source[f.first_sample : f.end_sample])
            n += f.n_samples
    return n


def test_every_sample_arrives_intact(sim, replay):
    rf = read_replay_file(replay)
    s = sim(replay, "--speed", "0", "--wait-start")
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        port.write(START)
        frames = read_until_closed(port, dec)
    stats = s.stats()
    data = [f for f in frames if isinstance(f, DataFrame)]
    got = np.concatenate([f.samples for f in data])
    np.testing.assert_array_equal(got, rf.samples)
    # the simulator's default frame size is the one eskin.link.protocol states
    assert [f.first_sample for f in data] == list(range(0, rf.n_samples, SAMPLES_PER_FRAME))
    info = next(f for f in frames if isinstance(f, InfoFrame))
    assert info.samples_per_frame == SAMPLES_PER_FRAME
    assert (info.rows, info.cols, info.sample_rate_hz) == (4, 4, 3000.0)
    assert info.class_names == ("brush", "finger", "washer")
    assert info.volts_per_count == pytest.approx(2.5e-4)
    status = [f for f in frames if isinstance(f, StatusFrame)]
    assert status[-1].state == StreamState.FINISHED
    assert status[-1].samples_sent == rf.n_samples
    st = dec.stats
    assert st.rejected == st.lost_samples == st.sequence_gaps == 0
    assert stats["samples_sent"] == rf.n_samples and stats["dropped_samples"] == 0


def test_paced_replay_reports_pacing(sim, replay):
    rf = read_replay_file(replay)
    s = sim(replay, "--speed", "8", "--wait-start", *BIG_QUEUE)
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        port.write(START)
        frames = read_until_closed(port, dec)
    stats = s.stats()
    assert check_samples(frames, rf.samples) == rf.n_samples
    assert stats["pacing_wakeups"] == rf.n_samples // 10
    assert stats["pacing_p50_ns"] <= stats["pacing_p99_ns"] <= stats["pacing_max_ns"]
    data = [f for f in frames if isinstance(f, DataFrame)]
    # timestamps follow the sample clock (x8): last minus first ~ duration / 8
    span_us = data[-1].timestamp_us - data[0].timestamp_us
    expected_us = (data[-1].end_sample - data[0].end_sample) / 3000 / 8 * 1e6
    assert span_us == pytest.approx(expected_us, rel=0.05, abs=2000)


@pytest.mark.parametrize(
    "faults",
    [
        ["--flip-rate", "2e-4"],
        ["--drop-rate", "2e-4"],
        ["--burst", "0.01", "--burst-len", "40"],
        ["--truncate-rate", "0.01"],
        ["--flip-rate", "1e-4", "--drop-rate", "1e-4", "--burst", "0.005", "--truncate-rate", "0.005"],
    ],
    ids=["flip", "drop", "burst", "truncate", "all"],
)
def test_faults_never_corrupt_and_every_loss_is_counted(sim, replay, faults):
    rf = read_replay_file(replay)
    s = sim(replay, "--speed", "0", "--wait-start", "--seed", "7", *faults)
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        port.write(START)
        frames = read_until_closed(port, dec)
    stats = s.stats()
    assert stats["faults_injected"] > 0
    received = check_samples(frames, rf.samples)  # no corrupted frame was accepted
    data = [f for f in frames if isinstance(f, DataFrame)]
    st = dec.stats
    span = data[-1].end_sample - data[0].first_sample
    assert received + st.lost_samples == span  # every lost sample is counted
    assert received < rf.n_samples
    # each fault costs at most two frames
    assert st.lost_frames <= 2 * stats["faults_injected"]
    if "--burst" not in faults:
        assert st.rejected > 0


def blocked_in_poll(pid: int) -> bool:
    """Whether the process is asleep in poll(2) (/proc/<pid>/syscall: its number first)."""
    nr = Path(f"/proc/{pid}/syscall").read_text().split()[0]
    return nr in ("7", "271")  # poll, ppoll (x86-64)


def test_slow_host_makes_the_sim_drop_not_block(sim, replay):
    """The host reads nothing until the paced replay is over: 240 kB of samples cannot fit in
    the pty and the 4 kB queue, so the simulator drops and counts instead of waiting."""
    rf = read_replay_file(replay)
    s = sim(replay, "--speed", "1000", "--wait-start", "--tx-buffer", "4096", "--hold", "60")
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        port.write(START)
        # paced, the simulator sleeps in poll only while it waits for START or after the end of
        # the replay; bytes waiting on the port show it has started, so this is the end
        polls = [0]

        def idle() -> bool:  # five looks in a row
            started = port.in_waiting > 0
            polls[0] = polls[0] + 1 if started and blocked_in_poll(s.proc.pid) else 0
            return polls[0] >= 5

        wait_until(idle, what="the simulator to go idle")
        frames: list = []
        while not any(isinstance(f, StatusFrame) and f.state == StreamState.FINISHED
                      for f in frames):
            frames += dec.feed(port.read(65536, timeout=0.5))
        s.proc.send_signal(signal.SIGINT)
        frames += read_until_closed(port, dec)
    stats = s.stats()
    assert stats["dropped_samples"] > 0 and stats["overrun_events"] >= 1
    received = check_samples(frames, rf.samples)
    assert received + stats["dropped_samples"] == rf.n_samples
    data = [f for f in frames if isinstance(f, DataFrame)]
    # every drop before the last received frame shows up as a hole in the sample indices
    assert dec.stats.lost_samples == stats["dropped_samples"] - (rf.n_samples - data[-1].end_sample)
    # the drops are flagged to the host: on the next DATA frame, or on a STATUS when none follows
    assert any(f.overrun for f in frames if isinstance(f, (DataFrame, StatusFrame)))


def test_host_disconnect_and_reconnect(sim, replay):
    rf = read_replay_file(replay)
    s = sim(replay, "--speed", "4", "--wait-start", *BIG_QUEUE)
    dec = FrameDecoder()
    frames: list = []
    port = SerialPort(s.path)
    port.write(START)
    end = time.monotonic() + 0.3
    while time.monotonic() < end:
        frames += dec.feed(port.read(65536, timeout=0.05))
    port.close()
    # the host is away while the controller goes on sampling: for 20 of its pacing wake-ups
    woke = context_switches(s.proc.pid)[0]
    wait_until(lambda: context_switches(s.proc.pid)[0] >= woke + 20,
               what="the simulator to sample on without its host")
    with SerialPort(s.path) as port:
        frames += read_until_closed(port, dec)
    stats = s.stats()
    assert stats["connections"] == 2
    received = check_samples(frames, rf.samples)
    data = [f for f in frames if isinstance(f, DataFrame)]
    assert data[0].first_sample == 0 and data[-1].end_sample == rf.n_samples
    assert stats["dropped_samples"] > 0
    assert received + dec.stats.lost_samples == rf.n_samples
    assert dec.stats.lost_samples >= stats["dropped_samples"]


def test_joining_mid_stream(sim, replay):
    rf = read_replay_file(replay)
    s = sim(replay, "--speed", "4", *BIG_QUEUE)  # streams at once, nobody listening yet
    # the host joins after 20 of the controller's pacing wake-ups
    woke = context_switches(s.proc.pid)[0]
    wait_until(lambda: context_switches(s.proc.pid)[0] >= woke + 20,
               what="the simulator to stream without a host")
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        frames = read_until_closed(port, dec)
    stats = s.stats()
    data = [f for f in frames if isinstance(f, DataFrame)]
    assert data[0].first_sample > 0  # what streamed while no host was there is gone
    received = check_samples(frames, rf.samples)
    assert received == rf.n_samples - data[0].first_sample
    assert dec.stats.lost_samples == 0 and dec.stats.rejected == 0
    assert stats["dropped_samples"] == data[0].first_sample


def test_commands_ping_stop_start_and_link(sim, replay, tmp_path):
    rf = read_replay_file(replay)
    link = tmp_path / "ttyESKIN"
    s = sim(replay, "--speed", "2", "--wait-start", "--link", link, "--status-ms", "50", *BIG_QUEUE)
    assert os.readlink(link) == s.path
    with SerialPort(link) as port:
        dec = FrameDecoder()
        port.write(encode_frame(PingFrame(token=1234, timestamp_us=5)))
        frames: list = []
        end = time.monotonic() + 5
        while not any(isinstance(f, PongFrame) for f in frames) and time.monotonic() < end:
            frames += dec.feed(port.read(4096, timeout=0.1))
        pong = next(f for f in frames if isinstance(f, PongFrame))
        assert pong.token == 1234
        assert not any(isinstance(f, DataFrame) for f in frames)  # waiting for START
        port.write(encode_frame(CommandFrame(FrameType.START, seq=1)))
        while sum(isinstance(f, DataFrame) for f in frames) < 20:
            frames += dec.feed(port.read(4096, timeout=0.5))
        port.write(encode_frame(CommandFrame(FrameType.STOP, seq=2)))
        n_sent = len(frames)
        # after STOP, a STOPPED status arrives and DATA ceases
        while not any(isinstance(f, StatusFrame) and f.state == StreamState.STOPPED
                      for f in frames[n_sent:]):
            frames += dec.feed(port.read(4096, timeout=0.5))
        at = next(i for i in range(n_sent, len(frames))
                  if isinstance(frames[i], StatusFrame) and frames[i].state == StreamState.STOPPED)
        stopped = frames[at]
        # commands are served in order: whatever the simulator sends between STOP and the
        # answer to a PING sent after it is what was already queued, never a new sample
        port.write(encode_frame(PingFrame(token=99, timestamp_us=6)))
        after_stop: list = []
        while not any(isinstance(f, PongFrame) and f.token == 99 for f in after_stop):
            after_stop += dec.feed(port.read(4096, timeout=0.5))
        frames += after_stop
        assert all(f.end_sample <= stopped.next_sample
                   for f in frames[at:] if isinstance(f, DataFrame))
        port.write(encode_frame(CommandFrame(FrameType.START, seq=3)))
        n_before = sum(f.n_samples for f in frames if isinstance(f, DataFrame))
        while sum(f.n_samples for f in frames if isinstance(f, DataFrame)) < n_before + 100:
            frames += dec.feed(port.read(4096, timeout=0.5))
    s.close()
    assert not link.exists()  # the symlink goes away with the simulator
    check_samples(frames, rf.samples)
    assert dec.stats.lost_samples == 0  # STOP pauses the replay; indices continue
    assert dec.stats.rejected == 0


def test_loop_repeats_the_replay_with_increasing_indices(sim, replay):
    rf = read_replay_file(replay)
    s = sim(replay, "--speed", "0", "--wait-start", "--loop")
    frames: list = []
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        port.write(START)
        while sum(f.n_samples for f in frames if isinstance(f, DataFrame)) < 2 * rf.n_samples + 100:
            frames += dec.feed(port.read(65536, timeout=1.0))
    s.close()
    data = [f for f in frames if isinstance(f, DataFrame)]
    looped = [f for f in data if f.flags & Flags.LOOP]
    assert looped and looped[0].first_sample >= rf.n_samples
    for f in data:  # sample i of the stream is sample i mod n of the replay
        idx = np.arange(f.first_sample, f.end_sample) % rf.n_samples
        np.testing.assert_array_equal(f.samples, np.asarray(rf.samples)[idx])
    assert dec.stats.lost_samples == 0 and dec.stats.sample_index_resets == 0


def test_hold_keeps_the_port_open_after_the_replay(sim, replay):
    s = sim(replay, "--speed", "0", "--wait-start", "--hold", "0.5", "--status-ms", "50")
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        port.write(START)
        frames = read_until_closed(port, dec)
    s.stats()
    finished = [f for f in frames if isinstance(f, StatusFrame) and f.state == StreamState.FINISHED]
    assert len(finished) >= 3  # periodic STATUS while holding


def test_bad_input_is_a_clear_error(fw_sim, tmp_path):
    bad = tmp_path / "bad.eskr"
    bad.write_bytes(b"not a replay file at all")
    out = subprocess.run([str(fw_sim), str(bad)], capture_output=True, text=True, timeout=10)
    assert out.returncode == 2
    assert "bad.eskr" in out.stderr and "replay" in out.stderr
    out = subprocess.run([str(fw_sim), str(bad), "--speed", "x"], capture_output=True, text=True)
    assert out.returncode == 2 and "--speed" in out.stderr


def test_npy_input(sim, tmp_path):
    rng = np.random.default_rng(1)
    arr = rng.integers(-1000, 1000, size=(905, 16)).astype("<i2")
    np.save(tmp_path / "stream.npy", arr)
    s = sim(tmp_path / "stream.npy", "--grid", "4x4", "--speed", "0", "--wait-start")
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        port.write(START)
        frames = read_until_closed(port, dec)
    s.stats()
    got = np.concatenate([f.samples for f in frames if isinstance(f, DataFrame)])
    np.testing.assert_array_equal(got.reshape(-1, 16), arr)


def small_model(path: Path, D: int = 8, n_support: int = 5) -> Path:
    """A 3-class one-vs-all model (random support tensors, real bases) in a .eskin file."""
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    rng = np.random.default_rng(0)
    pool = rng.standard_normal((2 * n_support - 1, 4, 4, D))
    machines = [
        MachineSpec(k, -1, 0.1 * (k - 1), (2, 2, 4), (1.0, 0.5, 2.0),
                    pool[np.sort(rng.choice(len(pool), n_support, replace=False))],
                    rng.standard_normal(n_support))
        for k in range(3)
    ]
    spec = ModelSpec(class_names=["brush", "finger", "washer"], rule="one_vs_all",
                     machines=machines, D=D, grid_shape=(4, 4))
    path.write_bytes(model_to_bytes(spec, "float64"))
    return path


def test_on_board_decisions_equal_offline_decisions(sim, replay, tmp_path):
    from eskin.deploy.export import CompiledModel

    rf = read_replay_file(replay)
    model = small_model(tmp_path / "m.eskin")
    offline = [e for e in CompiledModel(model).stream(np.asarray(rf.samples).reshape(rf.n_samples, -1))
               if e["status_name"] == "decision"]
    assert len(offline) == 3  # one per loud recording
    s = sim(replay, "--speed", "0", "--wait-start", "--model", model)
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        port.write(START)
        frames = read_until_closed(port, dec)
    stats = s.stats()
    info = next(f for f in frames if isinstance(f, InfoFrame))
    assert info.has_model and info.class_names == ("brush", "finger", "washer")
    live = [f for f in frames if isinstance(f, DecisionFrame)]
    assert len(live) == len(offline) == stats["decisions_sent"]
    for d, e in zip(live, offline):
        assert info.class_names[d.label] == e["label"]
        assert d.dont_know == e["dont_know"]
        assert (d.onset_sample, d.offset_sample) == tuple(e["window"])
        assert d.decided_sample == e["sample"] - 1
        np.testing.assert_allclose(d.values, e["values"], rtol=0, atol=1e-12)
    assert check_samples(frames, rf.samples) == rf.n_samples


def context_switches(pid: int) -> tuple[int, int]:
    """(voluntary, involuntary) context switches of a running process (/proc/<pid>/status)."""
    fields = dict(line.split(":", 1) for line in
                  Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    return int(fields["voluntary_ctxt_switches"]), int(fields["nonvoluntary_ctxt_switches"])


def test_no_host_means_no_busy_waiting(sim, replay):
    """With nobody on the pty (a hung-up master wakes poll at once), the simulator sleeps: waiting
    for START, replaying paced, or unpaced (which waits for a host). A sleeper gives up the CPU
    itself on every wake-up (a voluntary context switch); a busy loop never does, and is only
    ever preempted. Counted by the kernel, so the machine's load does not change the verdict."""
    waiting = sim(replay, "--wait-start")
    paced = sim(replay, "--loop")
    unpaced = sim(replay, "--speed", "0", "--loop")
    procs = {"--wait-start": waiting.proc, "paced --loop": paced.proc, "--speed 0 --loop": unpaced.proc}
    before = {k: context_switches(p.pid) for k, p in procs.items()}
    now: dict = {}
    slept: dict = {}

    def woke_200_times() -> bool:
        now.update({k: context_switches(p.pid) for k, p in procs.items()})
        slept.update({k: now[k][0] - before[k][0] for k in procs})
        return min(slept.values()) >= 200

    wait_until(woke_200_times, interval=0.05, required=False)
    assert all(p.poll() is None for p in procs.values())
    preempted = {k: now[k][1] - before[k][1] for k in procs}
    assert min(slept.values()) >= 200, (slept, preempted)
    for k in procs:  # most of its switches are its own sleeps
        assert preempted[k] < slept[k], (k, slept[k], preempted[k])
    # the unpaced replay waited for a host instead of running through (and dropping) the samples
    with SerialPort(unpaced.path) as port:
        dec = FrameDecoder()
        frames: list = []
        end = time.monotonic() + 10
        while not any(isinstance(f, DataFrame) for f in frames) and time.monotonic() < end:
            frames += dec.feed(port.read(65536, timeout=0.2))
    first = next(f for f in frames if isinstance(f, DataFrame))
    assert first.first_sample == 0


def test_forced_end_of_replay_decision_counts_its_classification_time(sim, tmp_path):
    """A replay that ends inside a touch gets its decision when the replay ends; its latency_us
    runs from the last sample's acquisition, so it includes that classification."""
    rng = np.random.default_rng(5)
    quiet = rng.normal(0, 30, size=(900, 16))
    loud = rng.normal(0, 3000, size=(600, 16))
    arr = np.clip(np.concatenate([quiet, loud]), -32768, 32767).astype("<i2")
    np.save(tmp_path / "ends_in_a_touch.npy", arr)
    model = small_model(tmp_path / "m.eskin", D=100, n_support=40)
    s = sim(tmp_path / "ends_in_a_touch.npy", "--grid", "4x4", "--speed", "0", "--wait-start",
            "--model", model)
    with SerialPort(s.path) as port:
        dec = FrameDecoder()
        port.write(START)
        frames = read_until_closed(port, dec)
    s.stats()
    decisions = [f for f in frames if isinstance(f, DecisionFrame)]
    assert len(decisions) == 1
    d = decisions[0]
    assert d.decided_sample == len(arr) - 1 and d.offset_sample == len(arr)
    # the latency runs from the acquisition of the last sample (the timestamp of the DATA frame
    # that carries it): the decision's timestamp less its latency is that instant (each of the
    # three is truncated to whole microseconds on its own, so they agree to 1 us)
    last = max((f for f in frames if isinstance(f, DataFrame)), key=lambda f: f.end_sample)
    assert last.end_sample == len(arr)
    assert d.timestamp_us - d.latency_us - last.timestamp_us in (0, 1)
    assert d.timestamp_us >= last.timestamp_us


def test_class_names_that_info_cannot_carry_are_refused_not_shortened(fw_sim, tmp_path):
    """A replay whose class names overrun one INFO frame: one line naming the file, exit 2 (the
    simulator announced the names that fitted and dropped the rest without a word)."""
    names = [f"gesture-{k:03d}-" + "x" * 80 for k in range(30)]  # 30 x 92 bytes: over 2048
    rng = np.random.default_rng(1)
    recs = [rng.integers(-50, 50, (2, 2, 500)).astype(np.int16) for _ in range(2)]
    path = tmp_path / "long_names.eskr"
    write_replay_arrays(path, recs, labels=[0, 29], class_names=names, gap_s=0.1, seed=0)
    out = subprocess.run([str(fw_sim), str(path), "--quiet"], capture_output=True, text=True,
                         timeout=20)
    assert out.returncode == 2, out.stderr
    assert out.stderr == (f"eskin-fw-sim: {path}: its 30 class names do not fit one INFO frame "
                          "(2048 bytes, at most 255 names, none holding a newline)\n")
    assert out.stdout == ""  # refused before the pty opens


def test_a_host_that_stops_reading_loses_no_decision_or_sample_without_a_count(fw_sim, tmp_path):
    """The transmitter starved: a small queue (2 KiB) and a host (eskin.LinkListener) that
    stops reading after the first decision until the simulator says it dropped one. Every
    decision the controller made is received or counted in STATUS's decisions_dropped, every
    sample received or counted lost, exactly: the host's counts and the controller's add up."""
    import queue
    import threading

    from eskin.deploy.export import CompiledModel
    from eskin.link.events import Decision, Stats
    from eskin.link.listener import LinkListener

    rng = np.random.default_rng(5)
    recs = []
    for _ in range(14):
        r = rng.normal(0, 300, size=(4, 4, 900))
        r[:, :, 300:600] *= 20
        recs.append(np.clip(r, -32768, 32767).astype(np.int16))
    path = write_replay_arrays(tmp_path / "touches.eskr", recs, labels=[k % 3 for k in range(14)],
                               class_names=["brush", "finger", "washer"], gap_s=0.1, seed=6)
    rf = read_replay_file(path.path)
    model = small_model(tmp_path / "m.eskin")
    offline = [e for e in CompiledModel(model).stream(
        np.asarray(rf.samples).reshape(rf.n_samples, -1)) if e["status_name"] == "decision"]
    assert len(offline) == 14

    proc = subprocess.Popen(
        [str(fw_sim), str(path.path), "--model", str(model), "--wait-start", "--speed", "2",
         "--tx-buffer", "2048", "--status-ms", "20"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stderr], daemon=True).start()
    try:
        pty_path = proc.stdout.readline().split()[1]
        decisions, final = [], None
        # read_queue_bytes=0: no reading thread, so a loop that stops reading stops the
        # reading of the port, as a stalled host does
        with LinkListener(pty_path, stats_interval=None, read_queue_bytes=0) as link:
            events = link.events(duration=120)
            for ev in events:
                if isinstance(ev, Decision) and ev.source == "controller":
                    decisions.append(ev)
                    break
            # the host stops reading until the simulator drops a decision (an event, with a
            # deadline), then reads to the end
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                try:
                    line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    break
                if "dropped (the output is full)" in line:
                    break
            else:
                raise AssertionError("the simulator dropped no decision")
            for ev in events:
                if isinstance(ev, Decision) and ev.source == "controller":
                    decisions.append(ev)
                elif isinstance(ev, Stats):
                    final = ev.stats
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
    stats = json.loads([x for x in out.splitlines() if x.startswith("STATS ")][-1][6:])
    s = final
    assert s is not None and s.controller_state == "finished"
    # decisions: made (the model's 14) = received + counted dropped, none still waiting
    assert stats["decisions_made"] == 14
    assert s.controller_decisions_dropped == stats["decisions_dropped"] > 0
    assert len(decisions) == s.decisions_controller == s.controller_decisions_sent
    assert len(decisions) + s.controller_decisions_dropped == 14
    assert len(decisions) >= 2
    # the ones received are the model's, in order
    got = [(d.onset_sample, d.offset_sample, d.label) for d in decisions]
    want = [(*e["window"], e["label"]) for e in offline]
    assert all(g in want for g in got) and got == sorted(got)
    # samples: produced = received + lost, and every loss was the controller's own drop
    assert stats["samples_produced"] == rf.n_samples
    assert s.samples + s.lost_samples == rf.n_samples
    assert s.lost_samples == s.controller_dropped_samples == stats["dropped_samples"] > 0
    assert s.crc_errors == s.malformed == s.lost_frames == s.lost_decisions == 0
    assert s.controller_frames_dropped == stats["frames_dropped"]


# one corruption per rule of the replay format: (edits (offset, struct format, value), the
# field eskin-fw-sim names, the start of the Python reader's message)
_SEG1 = 56 + 48
REPLAY_CORRUPTIONS = {
    "magic": ([(0, "<B", ord("X"))], "not an eskin replay file (magic", "not an eskin replay file"),
    "version 2": ([(8, "<I", 2)], "version", "replay version 2"),
    "data_offset odd": ([(12, "<I", None)], "data_offset", "bad data offset"),
    "grid 0": ([(26, "<H", 0)], "grid", "grid: 2x0"),
    "grid 4096": ([(24, "<H", 4096)], "grid", "grid: 4096x3"),
    "rate 0.05": ([(32, "<d", 0.05)], "sample_rate_hz", "sample_rate_hz: 0.05 is not a rate"),
    "rate 2e6": ([(32, "<d", 2e6)], "sample_rate_hz", "sample_rate_hz: 2000000.0 is not"),
    "rate 5e6": ([(32, "<d", 5e6)], "sample_rate_hz", "sample_rate_hz: 5000000.0 is not"),
    "rate nan": ([(32, "<d", float("nan"))], "sample_rate_hz", "sample_rate_hz: nan"),
    "volts 0": ([(40, "<d", 0.0)], "volts_per_count", "volts_per_count: 0.0"),
    "n_samples + 1": ([(16, "<Q", None)], "size", "size "),
    "names not UTF-8": ([(56 + 2 * 48, "<B", 0xFF)], "class_names", "class names: not valid"),
    "empty segment": ([(_SEG1 + 8, "<Q", 0)], "segment 1", "segment 1: length 0"),
    "segment past the end": ([(_SEG1, "<Q", 2**63)], "segment 1", "segment 1: start 92233"),
    "label 7": ([(_SEG1 + 32, "<i", 7)], "segment 1", "segment 1: label 7"),
    "contact past length": ([(_SEG1 + 24, "<q", 61)], "segment 1", "segment 1: contact"),
}


def _corrupted_replay(tmp_path, name, edits, crc=True):
    """A valid replay file (the Python writer's) with fields replaced and, with ``crc``, the
    header CRC recomputed so that only the edited field is wrong."""
    import struct
    import zlib

    rng = np.random.default_rng(0)
    recs = [rng.integers(-5, 5, size=(2, 3, n)).astype(np.int16) for n in (40, 60)]
    p = tmp_path / name
    write_replay_arrays(p, recs, labels=[0, 1], class_names=["a", "b"], gap_s=0.01,
                        contact_intervals=[[1, 30], [0, 60]])
    raw = bytearray(p.read_bytes())
    for offset, fmt, value in edits:
        if value is None:  # one more than the field holds
            value = struct.unpack_from(fmt, raw, offset)[0] + (4 if offset == 12 else 1)
        struct.pack_into(fmt, raw, offset, value)
    if crc:
        data_offset = struct.unpack_from("<I", raw, 12)[0]
        struct.pack_into("<I", raw, 52, 0)
        struct.pack_into("<I", raw, 52, zlib.crc32(bytes(raw[:min(data_offset, len(raw))])))
    p.write_bytes(bytes(raw))
    return p


@pytest.mark.parametrize("case", sorted(REPLAY_CORRUPTIONS) + ["crc", "one byte short"])
def test_python_and_the_compiled_reader_refuse_the_same_replays(fw_sim, tmp_path, case):
    """The replay format has one rule set: eskin.read_replay_file and the core's reader (here in
    eskin-fw-sim, which refuses with one line naming the file, the field and the value, exit
    status 2) refuse the same corrupted files, for the same field."""
    from eskin.data.replay import ReplayFormatError

    if case == "crc":
        p = _corrupted_replay(tmp_path, "bad.eskr", [(60, "<B", 0x55)], crc=False)
        field, python = "crc", "header checksum mismatch"
    elif case == "one byte short":
        p = _corrupted_replay(tmp_path, "bad.eskr", [])
        p.write_bytes(p.read_bytes()[:-1])
        field, python = "size", "size "
    else:
        edits, field, python = REPLAY_CORRUPTIONS[case]
        p = _corrupted_replay(tmp_path, "bad.eskr", edits)
    with pytest.raises(ReplayFormatError) as info:
        read_replay_file(p)
    assert str(info.value).startswith(f"{p}: {python}"), str(info.value)
    r = subprocess.run([str(fw_sim), str(p)], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2, r.stderr
    assert r.stdout == ""
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(f"eskin-fw-sim: {p}: {field}"), r.stderr
    if field in ("version", "data_offset", "grid", "sample_rate_hz", "volts_per_count", "size"):
        assert f"{field} = " in r.stderr, r.stderr  # the value is named


def test_python_and_the_compiled_reader_accept_the_same_edge_rates(fw_sim, tmp_path):
    """0.1 Hz and 1 MHz, the ends of the range, are accepted by both readers: eskin-fw-sim
    opens its port (its first line) instead of refusing the file."""
    for rate in (0.1, 1e6):
        p = _corrupted_replay(tmp_path, f"r{rate}.eskr", [(32, "<d", rate)])
        assert read_replay_file(p).sample_rate_hz == rate
        proc = subprocess.Popen([str(fw_sim), str(p), "--wait-start", "--quiet"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            first = proc.stdout.readline()
        finally:
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=30)
        assert first.startswith("PTY "), err
        assert proc.returncode == 0, err
