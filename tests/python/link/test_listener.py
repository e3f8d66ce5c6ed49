"""eskin.link.LinkListener and `eskin listen` on real pseudo-terminals.

Unit-level tests open a pty pair with os.openpty and play the controller by writing encoded
frames into the master end; end-to-end tests start eskin-fw-sim on a small replay file.
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import numpy as np
import pytest
from web_data import synthetic_touch

from eskin.data.campaign import load_campaign
from eskin.data.replay import write_replay_arrays
from eskin.link.listener import (
    Connection,
    DataBlock,
    Decision,
    InfoEvent,
    LinkListener,
    Recorded,
    Stats,
    StatusEvent,
)
from eskin.link.protocol import (
    DELIMITER,
    DataFrame,
    DecisionFrame,
    Flags,
    FrameDecoder,
    FrameType,
    InfoFrame,
    StatusFrame,
    StreamState,
    encode_frame,
)
from waiting import wait_until

SPF = 10  # samples per DATA frame


# --------------------------------------------------------------------------- helpers


@pytest.fixture
def pty(tmp_path):
    """(master fd, stable symlink path to the slave) - the symlink can be re-pointed."""
    master, slave = os.openpty()
    link = tmp_path / "skin.tty"
    link.symlink_to(os.ttyname(slave))
    os.close(slave)
    state = {"master": master, "done": threading.Event(), "threads": []}
    yield state, str(link)
    state["done"].set()  # no helper thread may outlive its test (fd numbers get reused)
    for t in state["threads"]:
        t.join(5)
    try:
        os.close(state["master"])
    except OSError:
        pass


def write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        try:
            n = os.write(fd, view[:4096])
        except OSError:
            return  # the host went away
        view = view[n:]


class Controller:
    """Plays the controller: encodes frames with its own sequence counter."""

    def __init__(self, grid=(4, 4), rate=3000.0, names=()):
        self.seq = 0
        self.grid = grid
        self.rate = rate
        self.names = tuple(names)

    def _next(self) -> int:
        s = self.seq
        self.seq = (self.seq + 1) % 65536
        return s

    def info(self) -> bytes:
        return encode_frame(InfoFrame(self.grid[0], self.grid[1], self.rate, volts_per_count=1e-4,
                                      has_model=bool(self.names), class_names=self.names,
                                      seq=self._next(), flags=int(Flags.SYNC)))

    def data(self, first: int, samples: np.ndarray, flags: int = 0) -> bytes:
        return encode_frame(DataFrame(first, first * 333, samples, self._next(), flags))

    def data_frames(self, stream: np.ndarray, first: int = 0) -> list[bytes]:
        return [self.data(first + k, stream[k:k + SPF]) for k in range(0, len(stream), SPF)]

    def status(self, state=StreamState.STREAMING, dropped=0) -> bytes:
        return encode_frame(StatusFrame(uptime_us=1, next_sample=0, dropped_samples=dropped,
                                        state=state, host_connected=True, seq=self._next()))

    def decision(self, onset, offset, label, values) -> bytes:
        return encode_frame(DecisionFrame(onset, offset, label, tuple(values), False, offset,
                                          0, 120, self._next()))


def wait_for_start(state, master: int | None = None, timeout: float = 20.0) -> list:
    """Read the master end until the host's START arrives (it has opened the port in raw
    mode by then); returns the commands seen."""
    import select

    master = state["master"] if master is None else master
    dec = FrameDecoder()
    seen: list = []

    def started() -> bool:
        if state["done"].is_set():
            return True
        r, _, _ = select.select([master], [], [], 0.05)
        if r:
            try:
                seen.extend(dec.feed(os.read(master, 4096)))
            except OSError:  # EIO: no slave end open yet
                return False
        return any(getattr(f, "command", None) == FrameType.START for f in seen)

    wait_until(started, timeout=timeout, what="the host's START", interval=0.02, required=False)
    return seen


def feed_when_open(state, data: bytes, seen: list | None = None) -> threading.Thread:
    """Write ``data`` into the master once the host has opened the port and sent START."""

    def run():
        cmds = wait_for_start(state)
        if seen is not None:
            seen.extend(cmds)
        if not state["done"].is_set():
            write_all(state["master"], data)

    return start_thread(state, run)


def start_thread(state, target) -> threading.Thread:
    t = threading.Thread(target=target, daemon=True)
    state["threads"].append(t)
    t.start()
    return t


def rng_stream(n: int, seed: int = 0, grid=(4, 4)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(-2000, 2000, size=(n, *grid)).astype(np.int16)


def received_samples(events) -> dict[int, np.ndarray]:
    out = {}
    for ev in events:
        if isinstance(ev, DataBlock):
            for k in range(ev.samples.shape[0]):
                out[ev.first_sample + k] = ev.samples[k]
    return out


def touch_stream(seed: int = 1, n_quiet: int = 4500, n_touch: int = 900) -> np.ndarray:
    """Quiet noise, one strong burst on a few taxels, quiet noise: int16 (n, 4, 4)."""
    rng = np.random.default_rng(seed)
    n = 2 * n_quiet + n_touch
    x = rng.normal(0, 5, size=(n, 4, 4))
    t = np.arange(n_touch) / 3000.0
    x[n_quiet:n_quiet + n_touch, 1:3, 1:3] += (800 * np.sin(2 * np.pi * 40 * t))[:, None, None]
    return np.rint(x).astype(np.int16)


# --------------------------------------------------------------------------- unit level (pty pair)


def test_stream_events_commands_and_stats(pty):
    state, path = pty
    c = Controller(names=("brush", "finger", "washer"))
    stream = rng_stream(600)
    payload = (DELIMITER + c.info() + b"".join(c.data_frames(stream))
               + c.decision(100, 400, 1, (-0.5, 0.7, -0.2)) + c.status(StreamState.FINISHED, 7))
    cmds: list = []
    with LinkListener(path, stats_interval=None) as link:
        assert link.activity() is None  # nothing received yet
        feeder = feed_when_open(state, payload, cmds)
        events = list(link.events(until_eof=True, eof_grace_s=0.05))
        act = link.activity()
        feeder.join(10)
    assert act.shape == (4, 4) and np.all(act > 100)  # the random stream is "active" everywhere
    # the host asked for the stream and the controller's description
    assert [f.command for f in cmds][:1] == [FrameType.START]
    assert FrameType.INFO_REQUEST in [f.command for f in cmds] or len(cmds) == 1
    assert any(isinstance(e, InfoEvent) for e in events)
    got = received_samples(events)
    assert sorted(got) == list(range(600))
    assert np.array_equal(np.stack([got[i] for i in range(600)]), stream)
    dec = [e for e in events if isinstance(e, Decision)]
    assert len(dec) == 1 and dec[0].source == "controller" and dec[0].label == "finger"
    assert dec[0].values == (-0.5, 0.7, -0.2) and dec[0].onset_sample == 100
    assert isinstance(events[-1], Stats)
    s = events[-1].stats
    assert s.data_frames == 60 and s.samples == 600 and s.lost_samples == 0
    assert s.rejected == 0 and s.sequence_gaps == 0 and s.controller_dropped_samples == 7
    assert s.controller_state == "finished" and s.decisions_controller == 1
    assert any(isinstance(e, StatusEvent) for e in events)


def _damage(kind: str, frame: bytes, rng: np.random.Generator) -> bytes:
    b = bytearray(frame)
    body = len(b) - 1  # the last byte is the delimiter
    if kind == "flip":
        i = int(rng.integers(0, len(b)))
        b[i] ^= 1 << int(rng.integers(0, 8))
    elif kind == "drop":
        del b[int(rng.integers(0, len(b)))]
    elif kind == "truncate":
        b = b[: int(rng.integers(1, body))]  # cut short, delimiter lost too
    elif kind == "burst":
        i = int(rng.integers(0, body - 24))
        b[i:i + 24] = rng.integers(0, 256, 24, dtype=np.uint8).tobytes()
    elif kind == "garbage_before":
        b = bytearray(rng.integers(0, 256, 40, dtype=np.uint8).tobytes()) + b
    elif kind == "garbage_zeros":
        junk = bytearray(rng.integers(0, 256, 40, dtype=np.uint8).tobytes())
        junk[::7] = b"\x00" * len(junk[::7])
        b = junk + b
    return bytes(b)


FAULTS = ("flip", "drop", "truncate", "burst", "garbage_before", "garbage_zeros")


@pytest.mark.parametrize("seed", [0, 1])
def test_faults_never_accept_corruption_cost_at_most_two_frames_and_are_counted(pty, seed):
    state, path = pty
    rng = np.random.default_rng(seed)
    c = Controller()
    n_frames = 240
    stream = rng_stream(n_frames * SPF, seed)
    frames = c.data_frames(stream)
    fault_at = {}
    for k in range(5, n_frames - 5, 6):  # one fault every 6 frames, each kind many times
        fault_at[k] = FAULTS[(k // 6) % len(FAULTS)]
    wire = bytearray(DELIMITER)
    for k, f in enumerate(frames):
        wire += _damage(fault_at[k], f, rng) if k in fault_at else f
    wire += c.status(StreamState.FINISHED)
    with LinkListener(path, stats_interval=None) as link:
        feed_when_open(state, bytes(wire))
        events = list(link.events(until_eof=True, eof_grace_s=0.05))
    got = received_samples(events)
    # no corrupted frame was accepted: every received sample is the sent one
    for i, x in got.items():
        assert np.array_equal(x, stream[i]), f"sample {i} corrupted"
    lost_frames = sorted({i // SPF for i in range(len(stream))} - {i // SPF for i in got})
    # each fault costs at most two frames, and only the frames around it
    for lf in lost_frames:
        assert lf in fault_at or lf - 1 in fault_at, f"frame {lf} lost without a fault near it"
    for k in fault_at:
        assert sum(1 for lf in lost_frames if lf in (k, k + 1)) <= 2
    s = events[-1].stats
    # every loss is counted: lost samples, sequence gaps, and the rejected blocks
    assert s.lost_samples == len(stream) - len(got) == SPF * len(lost_frames)
    assert s.lost_frames == len(lost_frames)
    assert sum(e.lost_before for e in events if isinstance(e, DataBlock)) == s.lost_samples
    assert s.rejected >= len([k for k, v in fault_at.items() if v != "garbage_before"]) // 2
    assert s.samples == len(got)


def test_joining_mid_stream_skips_the_partial_frame(pty):
    state, path = pty
    c = Controller()
    stream = rng_stream(300, 3)
    frames = c.data_frames(stream)
    wire = b"".join(frames)[len(frames[0]) + 17:] + c.status(StreamState.FINISHED)
    with LinkListener(path, stats_interval=None) as link:
        feed_when_open(state, wire)
        events = list(link.events(until_eof=True, eof_grace_s=0.05))
    got = received_samples(events)
    assert sorted(got) == list(range(20, 300))  # frame 0 gone, frame 1 cut, the rest whole
    s = events[-1].stats
    assert s.skipped_bytes == len(frames[1]) - 17 - 1 and s.rejected == 0 and s.lost_samples == 0


def test_peer_close_and_reconnect_on_the_same_path(pty, tmp_path):
    state, path = pty
    c = Controller()
    stream = rng_stream(400, 4)
    frames = c.data_frames(stream)
    events: list = []
    with LinkListener(path, reconnect=True, reconnect_timeout=5.0, stats_interval=None) as link:
        def controller():
            wait_for_start(state)
            first = DELIMITER + b"".join(frames[:15])
            write_all(state["master"], first)
            wait_until(lambda: link.stats.bytes >= len(first), what="the host to take them")
            os.close(state["master"])  # the controller goes away ...
            master, slave = os.openpty()  # ... and comes back on a new pty behind the same link
            os.unlink(path)
            os.symlink(os.ttyname(slave), path)
            os.close(slave)
            state["master"] = master
            wait_for_start(state, master)  # the host reopens and sends START
            write_all(master, DELIMITER + b"".join(frames[25:]) + c.status(StreamState.FINISHED))

        t = start_thread(state, controller)
        events = list(link.events(until_eof=True, eof_grace_s=0.05))
        t.join(5)
    kinds = [e.state for e in events if isinstance(e, Connection)]
    assert kinds == ["disconnected", "reconnected"]
    got = received_samples(events)
    assert sorted(got) == list(range(150)) + list(range(250, 400))
    s = events[-1].stats
    assert s.disconnects == 1 and s.reconnects == 1
    assert s.lost_samples == 100 and s.rejected == 0


def test_peer_close_without_reconnect_ends_the_events(pty):
    state, path = pty
    c = Controller()
    frames = c.data_frames(rng_stream(50, 5))
    with LinkListener(path, stats_interval=None) as link:
        def controller():
            wait_for_start(state)
            wire = DELIMITER + b"".join(frames)
            write_all(state["master"], wire)
            wait_until(lambda: link.stats.bytes >= len(wire), what="the host to take them")
            os.close(state["master"])

        start_thread(state, controller)
        events = list(link.events(duration=10.0))
    assert [e.state for e in events if isinstance(e, Connection)] == ["disconnected"]
    assert events[-1].stats.samples == 50 and events[-1].stats.disconnects == 1


def test_host_disconnect_and_reconnect(pty):
    state, path = pty
    c = Controller()
    stream = rng_stream(300, 6)
    frames = c.data_frames(stream)
    with LinkListener(path, stats_interval=None) as link:
        write_thread = feed_when_open(state, DELIMITER + b"".join(frames[:10]))
        ev1 = list(link.events(duration=0.4, flush=False))
        write_thread.join()
        conn = link.reconnect()  # the host closes and reopens; the controller kept streaming
        assert conn.state == "reconnected"
        feed_when_open(state, DELIMITER + b"".join(frames[20:]) + c.status(StreamState.FINISHED))
        ev2 = list(link.events(until_eof=True, eof_grace_s=0.05))
    got = received_samples(ev1 + ev2)
    assert sorted(got) == list(range(100)) + list(range(200, 300))
    assert ev2[-1].stats.lost_samples == 100 and ev2[-1].stats.reconnects == 1


def test_small_holes_are_bridged_for_the_detector_and_reported(pty):
    """Holes up to max_fill_s keep the detector's indices aligned; decisions report the loss."""
    state, path = pty
    c = Controller()
    stream = touch_stream()
    frames = c.data_frames(stream)
    dropped = set(range(470, 475))  # 50 samples inside the touch
    wire = DELIMITER + b"".join(f for k, f in enumerate(frames) if k not in dropped)
    wire += c.status(StreamState.FINISHED)
    out = Path(os.path.dirname(path)) / "touches.h5"
    with LinkListener(path, record=out, stats_interval=None) as link:
        feed_when_open(state, wire)
        events = list(link.events(until_eof=True, eof_grace_s=0.05))
    rec = [e for e in events if isinstance(e, Recorded)]
    assert len(rec) == 1 and rec[0].label == "unknown" and rec[0].lost_samples == 50
    camp = load_campaign(out)
    assert len(camp) == 1 and camp.modalities == ["unknown"]
    r = camp.recording(0)
    start = int(camp.extras["stream_start"][0])
    assert start == rec[0].start and start < 4500 and 5400 < rec[0].stop
    src = np.moveaxis(stream[rec[0].start:rec[0].stop], 0, -1)
    keep = np.ones(r.shape[-1], bool)
    keep[4700 - start:4750 - start] = False
    assert np.array_equal(r[..., keep], src[..., keep])  # everything received is kept exactly
    assert events[-1].stats.lost_samples == 50


def test_record_segments_reads_back_equal_to_the_source(pty, tmp_path):
    state, path = pty
    rng = np.random.default_rng(7)
    recs = [rng.integers(-500, 500, size=(4, 4, n)).astype(np.int16) for n in (700, 450, 900)]
    rf = write_replay_arrays(tmp_path / "r.eskr", recs, labels=[2, 0, 1],
                             class_names=["brush", "finger", "washer"], gap_s=0.1,
                             contact_intervals=np.array([[10, 600], [0, 450], [100, 200]]))
    c = Controller(names=())
    stream = np.asarray(rf.samples)
    wire = DELIMITER + c.info() + b"".join(c.data_frames(stream)) + c.status(StreamState.FINISHED)
    out = tmp_path / "live.h5"
    with LinkListener(path, record=out, replay=rf, stats_interval=None,
                      record_source="simulated") as link:
        assert link.record_policy == "segment"
        feed_when_open(state, wire)
        events = list(link.events(until_eof=True, eof_grace_s=0.05))
    assert [e.index for e in events if isinstance(e, Recorded)] == [0, 1, 2]
    camp = load_campaign(out)
    assert camp.modalities == ["brush", "finger", "washer"] and camp.source == "simulated"
    assert list(camp.modality) == [2, 0, 1]
    assert np.array_equal(camp.contact_interval, [[10, 600], [0, 450], [100, 200]])
    assert camp.attrs["record_policy"] == "segment"
    assert camp.volts_per_count == 1e-4 != rf.volts_per_count  # the INFO frame's, not the file's
    for k, r in enumerate(recs):
        assert np.array_equal(camp.recording(k), r)


def test_jsonl_schema_from_the_cli(pty, tmp_path):
    from typer.testing import CliRunner

    from eskin.cli import app

    state, path = pty
    c = Controller(names=("brush", "finger", "washer"))
    wire = (DELIMITER + c.info() + b"".join(c.data_frames(rng_stream(200, 8)))
            + c.decision(20, 180, 2, (-1.0, -0.25, 0.5)) + c.status(StreamState.FINISHED))
    out = tmp_path / "d.jsonl"
    feed_when_open(state, wire)
    res = CliRunner().invoke(app, ["listen", path, "--jsonl", str(out), "--until-eof",
                                   "--duration", "20"])
    assert res.exit_code == 0, res.output
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) == 2
    d, s = lines
    assert d == {"type": "decision", "source": "controller", "onset_sample": 20,
                 "offset_sample": 180, "decided_sample": 180, "label": "washer",
                 "label_index": 2, "values": [-1.0, -0.25, 0.5], "nonfinite_values": False,
                 "dont_know": False, "latency_us": 120.0, "lost_samples": 0}
    assert s["type"] == "stats" and s["samples"] == 200 and s["lost_samples"] == 0
    assert {"frames", "bytes", "crc_errors", "malformed", "sequence_gaps", "lost_samples",
            "controller_dropped_samples", "controller_overrun_events"} <= set(s)
    assert "decision controller" in res.output  # plain lines when not on a terminal


def test_listen_reports_a_missing_port_clearly(tmp_path):
    from typer.testing import CliRunner

    from eskin.cli import app

    res = CliRunner().invoke(app, ["listen", str(tmp_path / "nope"), "--duration", "1"])
    assert res.exit_code == 2 and "nope" in res.output and "Traceback" not in res.output


# --------------------------------------------------------------------------- with eskin-fw-sim


@pytest.fixture(scope="module")
def fw_sim_path():
    from eskin._paths import find_executable

    return find_executable("eskin-fw-sim")


def _small_spec(intercept: float = -0.2):
    """A 3-class model whose support patterns are preprocessed synthetic touches (with the
    intercept -0.2 the paper's rule says "don't know" on the test touches, with 0 it decides)."""
    from eskin.deploy.export import MachineSpec, ModelSpec
    from eskin.signal.preprocess import preprocess

    D = 20
    train = [synthetic_touch(k, 100 + i) for i in range(3) for k in range(3)]
    y = np.array([k for _ in range(3) for k in range(3)])
    X = preprocess(np.stack(train), D)
    X /= np.linalg.norm(X.reshape(len(X), -1), axis=1)[:, None, None, None]
    machines = [MachineSpec(k, -1, intercept, (2, 2, 3), (1.0, 1.0, 1.0), X,
                            np.where(y == k, 1.0, -0.5)) for k in range(3)]
    return ModelSpec(["brush", "finger", "washer"], "one_vs_all", machines, D, (4, 4))


@pytest.fixture(scope="module")
def small_model(tmp_path_factory):
    """A real compiled 3-class model (_small_spec) and a replay file of 9 other synthetic
    touches."""
    from eskin.deploy.export import CompiledModel, model_to_bytes

    d = tmp_path_factory.mktemp("model")
    spec = _small_spec()
    path = d / "small.eskin"
    path.write_bytes(model_to_bytes(spec, "float32"))
    test = [synthetic_touch(k, i) for i in range(3) for k in range(3)]
    rf = write_replay_arrays(d / "test.eskr", test, labels=[k for _ in range(3) for k in range(3)],
                             class_names=spec.class_names, gap_s=0.4, seed=5)
    return CompiledModel(path), path, rf, test


def run_fw_sim(exe, *args):
    import subprocess

    # a 1 MB transmit queue: a host slowed down by a busy test machine must not lose samples
    proc = subprocess.Popen([str(exe), *map(str, args), "--tx-buffer", str(1 << 20), "--quiet"],
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline().split()
    assert first and first[0] == "PTY", (first, proc.stderr.read())
    return proc, first[1]


def finish(proc) -> dict:
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    return json.loads([x for x in out.splitlines() if x.startswith("STATS ")][-1][6:])


def test_live_decisions_equal_offline_decisions(fw_sim_path, small_model, tmp_path):
    from eskin.demo import assign_decisions

    cm, path, rf, test = small_model
    proc, pty_path = run_fw_sim(fw_sim_path, rf.path, "--model", path, "--speed", 20,
                                "--wait-start")
    try:
        with LinkListener(pty_path, model=cm, replay=rf, record=tmp_path / "live.h5",
                          stats_interval=None) as link:
            assert link.classifier.kind == "compiled"
            events = list(link.events(until_eof=True, duration=60))
    finally:
        stats = finish(proc)
    s = events[-1].stats
    assert s.lost_samples == 0 and s.rejected == 0 and s.controller_dropped_samples == 0
    assert s.samples == rf.n_samples == stats["samples_sent"]
    dec = [e for e in events if isinstance(e, Decision)]
    ctrl = [d for d in dec if d.source == "controller"]
    host = [d for d in dec if d.source == "host"]
    assert len(ctrl) == len(host) == stats["decisions_sent"] >= len(test)
    # the host runs the controller's classifier on the samples it received: same decisions
    for c, h in zip(ctrl, host):
        assert (c.onset_sample, c.offset_sample, c.label, c.dont_know) == (
            h.onset_sample, h.offset_sample, h.label, h.dont_know)
        np.testing.assert_allclose(c.values, h.values, rtol=0, atol=1e-9)
    # and the same as offline: the stream classifier over the replay file, and per recording
    offline = [e for e in cm.stream(np.asarray(rf.samples).reshape(rf.n_samples, -1))
               if "label" in e]
    assert [(c.onset_sample, c.offset_sample, c.label) for c in ctrl] == [
        (e["window"][0], e["window"][1], e["label"]) for e in offline]
    batch = cm.classify(np.stack(test))
    for src in (ctrl, host):
        lab, val, _, _ = assign_decisions(src, rf.segments, 3)
        assert list(lab) == list(batch.label_indices)
        np.testing.assert_allclose(val, batch.decision_values, atol=1e-5)
    # the recording of the stream reads back equal to the source
    camp = load_campaign(tmp_path / "live.h5")
    assert len(camp) == len(test)
    for k, r in enumerate(test):
        assert np.array_equal(camp.recording(k), r)


def test_faults_from_the_fw_sim_are_rejected_and_counted(fw_sim_path, small_model):
    _, _, rf, _ = small_model
    proc, pty_path = run_fw_sim(fw_sim_path, rf.path, "--speed", 0, "--wait-start",
                                "--flip-rate", "1e-4", "--drop-rate", "1e-4", "--burst", "0.01",
                                "--truncate-rate", "0.01", "--seed", 3)
    try:
        with LinkListener(pty_path, stats_interval=None) as link:
            events = list(link.events(until_eof=True, duration=60))
    finally:
        stats = finish(proc)
    got = received_samples(events)
    src = np.asarray(rf.samples)
    for i, x in got.items():  # no corrupted frame was ever accepted
        assert np.array_equal(x, src[i]), f"sample {i} corrupted"
    s = events[-1].stats
    assert stats["faults_injected"] > 10
    # every loss is counted: holes inside the stream, and what never came at its ends
    assert s.samples + s.lost_samples == rf.n_samples == stats["samples_sent"]
    assert s.rejected > 0
    # each fault costs at most two frames
    assert s.lost_samples <= 2 * SPF * stats["faults_injected"]


def test_host_reconnect_to_the_fw_sim_counts_what_it_missed(fw_sim_path, small_model):
    _, _, rf, _ = small_model
    proc, pty_path = run_fw_sim(fw_sim_path, rf.path, "--speed", 4, "--wait-start")
    try:
        with LinkListener(pty_path, stats_interval=None) as link:
            first = list(link.events(duration=0.5, flush=False))
            link.reconnect()  # the controller keeps streaming (and drops) while nobody listens
            rest = list(link.events(until_eof=True, duration=60))
    finally:
        stats = finish(proc)
    got = received_samples(first + rest)
    src = np.asarray(rf.samples)
    assert all(np.array_equal(x, src[i]) for i, x in got.items())
    s = rest[-1].stats
    assert s.reconnects == 1 and s.rejected == 0 and min(got) == 0
    # every sample the controller produced was received or counted as lost: the ones it
    # dropped while nobody listened, and the ones still in the port's buffer when it closed
    assert s.samples + s.lost_samples == stats["samples_produced"] == rf.n_samples
    assert s.lost_samples >= stats["dropped_samples"] == s.controller_dropped_samples


def test_python_host_backend_decides_like_the_controller(fw_sim_path, small_model):
    """The host's Python path (TouchDetector + a TouchModel's machines) on the live stream."""
    pytest.importorskip("eskin.learn.models", reason="the learning stack is not installed")
    from eskin.deploy import load_model

    _, path, rf, _ = small_model
    model = load_model(path)  # a .eskin file as a TouchModel: Python preprocessing
    proc, pty_path = run_fw_sim(fw_sim_path, rf.path, "--model", path, "--speed", 20,
                                "--wait-start")
    try:
        with LinkListener(pty_path, model=model, backend="python", stats_interval=None) as link:
            assert link.classifier.kind == "python"
            events = list(link.events(until_eof=True, duration=60))
    finally:
        finish(proc)
    dec = [e for e in events if isinstance(e, Decision)]
    ctrl = [d for d in dec if d.source == "controller"]
    host = [d for d in dec if d.source == "host"]
    assert len(ctrl) == len(host) > 0
    for c, h in zip(ctrl, host):
        assert (c.onset_sample, c.offset_sample, c.label) == (h.onset_sample, h.offset_sample,
                                                              h.label)
        np.testing.assert_allclose(c.values, h.values, atol=1e-6)


def test_listen_live_view_renders(pty, tmp_path):
    from typer.testing import CliRunner

    from eskin.cli import app

    state, path = pty
    c = Controller(names=("brush", "finger", "washer"))
    wire = (DELIMITER + c.info() + b"".join(c.data_frames(touch_stream()))
            + c.decision(4450, 5450, 0, (0.9, -0.5, -0.7)) + c.status(StreamState.FINISHED))
    out = tmp_path / "d.jsonl"
    feed_when_open(state, wire)
    res = CliRunner().invoke(app, ["listen", path, "--view", "live", "--until-eof",
                                   "--duration", "20", "--jsonl", str(out)])
    assert res.exit_code == 0, res.output
    for text in ("taxel activity", "link statistics", "decisions (latest last)", "brush",
                 "lost samples"):
        assert text in res.output
    assert json.loads(out.read_text().splitlines()[0])["label"] == "brush"


def test_a_recorded_touch_takes_the_host_decisions_label_unless_it_does_not_know(small_model,
                                                                                 tmp_path):
    """record_policy "touch" with a host model: each touch is recorded under the label the
    host decided, or "unknown" where the decision is "don't know"."""
    from eskin.deploy.export import CompiledModel, model_to_bytes

    unsure, _, rf, _ = small_model
    sure = CompiledModel(model_to_bytes(_small_spec(0.0), "float32"))
    for cm, decided in ((sure, True), (unsure, False)):
        _record_touches(cm, rf, tmp_path / f"touches_{decided}.h5", decided)


def _record_touches(cm, rf, out, decided):
    x = np.asarray(rf.samples).reshape(rf.n_samples, 4, 4).astype(np.int16)
    wire = [encode_frame(InfoFrame(4, 4, float(rf.sample_rate_hz), volts_per_count=1e-4,
                                   has_model=False, class_names=(), seq=0))]
    wire += [encode_frame(DataFrame(k, k * 333, x[k:k + 10], (k // 10 + 1) % 65536))
             for k in range(0, len(x), 10)]
    listener = LinkListener("/dev/null-not-opened", model=cm, record=out, record_policy="touch",
                            stats_interval=None)
    events = listener.feed(DELIMITER + b"".join(wire)) + listener.finish()
    listener.close()
    host = [e for e in events if isinstance(e, Decision) and e.source == "host"]
    assert len(host) == 9 and {d.label_index for d in host} == {0, 1, 2}
    assert all(d.dont_know is not decided for d in host)
    want = [d.label if decided else "unknown" for d in host]
    with load_campaign(out) as camp:
        names = list(camp.modalities)
        assert [names[int(m)] for m in np.asarray(camp.modality)] == want


def test_a_restart_writes_the_pending_touch_as_the_end_of_the_stream_would(small_model, tmp_path):
    """record_policy "touch": a touch waits for ``context_s`` of samples after it before it is
    written. When the controller restarts (its indices go back to 0) before those arrive, the
    touch is written at once with what was received, exactly as when the stream ends there;
    the restarted stream's samples never end up in it."""
    _, _, rf, _ = small_model
    x = np.asarray(rf.samples).reshape(rf.n_samples, 4, 4).astype(np.int16)
    info = encode_frame(InfoFrame(4, 4, float(rf.sample_rate_hz), volts_per_count=1e-4,
                                  has_model=False, class_names=(), seq=0))

    def data(first, block, seq):
        return encode_frame(DataFrame(first, first * 333, block, seq % 65536))

    def run(wire, name):
        out = tmp_path / name
        listener = LinkListener("/dev/null-not-opened", record=out, record_policy="touch",
                                context_s=0.5, stats_interval=None)
        events = listener.feed(DELIMITER + b"".join(wire)) + listener.finish()
        listener.close()
        with load_campaign(out) as camp:
            recs = [np.asarray(camp.recording(i)) for i in range(len(camp))]
        return [e for e in events if isinstance(e, Recorded)], recs

    ctx = int(round(0.5 * rf.sample_rate_hz))
    events, full = run([info] + [data(k, x[k:k + 10], k // 10 + 1) for k in range(0, len(x), 10)],
                       "full.h5")
    assert len(full) == 9
    touch_stop = events[2].stop - ctx  # the third touch's window ends here
    cut = (touch_stop // 10 + 2) * 10  # 10-20 samples later, on a frame boundary
    before = [data(k, x[k:k + 10], k // 10 + 1) for k in range(0, cut, 10)]
    quiet = np.zeros((10, 4, 4), np.int16)
    after = [data(k, quiet, 10_000 + k // 10) for k in range(0, 3000, 10)]  # indices from 0
    ev_restarted, restarted = run([info] + before + after, "restarted.h5")
    ev_ended, ended = run([info] + before, "ended.h5")
    assert len(ended) == 3 and len(restarted) == 3
    assert [(e.start, e.stop) for e in ev_restarted] == [(e.start, e.stop) for e in ev_ended]
    assert ev_ended[2].start == events[2].start and ev_ended[2].stop == cut
    for a, b in zip(restarted, ended):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("policy", ["touch", "segment"])
def test_recordings_do_not_depend_on_how_the_bytes_were_read(small_model, tmp_path, policy):
    """The same stream read all at once (a host that fell behind by 9 s: more than the
    history the recordings need) or one frame per read gives the same recordings, each of
    them whole: a touch with its context on both sides, a segment with all its samples."""
    _, _, rf, _ = small_model
    x = np.asarray(rf.samples).reshape(rf.n_samples, 4, 4).astype(np.int16)
    wire = [encode_frame(InfoFrame(4, 4, float(rf.sample_rate_hz), volts_per_count=1e-4,
                                   has_model=False, class_names=(), seq=0))]
    wire += [encode_frame(DataFrame(k, k * 333, x[k:k + 10], (k // 10 + 1) % 65536))
             for k in range(0, len(x), 10)]

    def run(reads, name):
        out = tmp_path / name
        listener = LinkListener("/dev/null-not-opened", record=out, record_policy=policy,
                                replay=rf if policy == "segment" else None, context_s=0.5,
                                stats_interval=None)
        events = []
        for r in reads:
            events += listener.feed(r)
        events += listener.finish()
        listener.close()
        with load_campaign(out) as camp:
            recs = [np.asarray(camp.recording(i)) for i in range(len(camp))]
        return [(e.start, e.stop) for e in events if isinstance(e, Recorded)], recs

    at_once = run([DELIMITER + b"".join(wire)], "at_once.h5")
    per_frame = run([DELIMITER + w for w in wire], "per_frame.h5")
    assert len(x) > 3 * rf.sample_rate_hz * 3  # the single read holds 9 s of samples
    assert at_once[0] == per_frame[0] and len(at_once[0]) == 9
    for a, b in zip(at_once[1], per_frame[1]):
        np.testing.assert_array_equal(a, b)
    for (start, stop), rec in zip(at_once[0], at_once[1]):
        np.testing.assert_array_equal(rec, np.moveaxis(x[start:stop], 0, -1))
    if policy == "touch":
        ctx = int(round(0.5 * rf.sample_rate_hz))
        assert all(stop - start > 2 * ctx for start, stop in at_once[0])
    else:
        segs = rf.segments
        assert at_once[0] == [(int(s["start"]), int(s["start"]) + int(s["length"])) for s in segs]
