"""Frames sound on the wire but with absurd fields (eskin.link.frame_checks): each is refused,
counted and named (frame type, field, value), the stream goes on, and `eskin listen` ends with
its statistics; the reproductions run the real CLI in a real process on a real pty."""

from __future__ import annotations

import json
import math
import os
import select
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from eskin.link.listener import DataBlock, InfoEvent, LinkListener, Rejection
from eskin.link.protocol import (
    DELIMITER,
    DataFrame,
    DecisionFrame,
    InfoFrame,
    StatusFrame,
    StreamState,
    encode_frame,
)
from waiting import wait_until

REPO = Path(__file__).resolve().parents[3]
NAMES = ("brush", "finger", "washer")


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO / "python") + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _host_wrote(master: int) -> bool:
    """Whether the host end of the pty has written something (its START) since the last call."""
    r, _, _ = select.select([master], [], [], 0.05)
    try:
        return bool(r and os.read(master, 4096))
    except OSError:  # EIO: the host has not opened the port yet
        return False


def _host_closed(master: int) -> bool:
    """Whether no process has the host end of the pty open any more (what the host writes
    meanwhile is read and dropped)."""
    r, _, _ = select.select([master], [], [], 0.05)
    try:
        if r:
            os.read(master, 4096)
        return False
    except OSError:  # EIO: the host end is closed
        return True


def _controller(wire: bytes) -> tuple[str, threading.Thread]:
    """A pty whose controller end sends ``wire`` once the host has written (its START)."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    os.close(slave)

    def run() -> None:
        wait_until(lambda: _host_wrote(master), what="the host's START", interval=0.02)
        view = memoryview(wire)
        while view:
            view = view[os.write(master, view):]
        # every host of these tests ends by itself (the replay's FINISHED, or an error): the
        # controller keeps its end open until the host has closed the port
        wait_until(lambda: _host_closed(master), what="the host to close the port",
                   interval=0.02)
        os.close(master)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return path, t


def _data(first: int, n: int = 10, grid=(4, 4), seq: int = 0) -> DataFrame:
    x = np.random.default_rng(first % 1000).integers(-50, 50, (n, *grid)).astype(np.int16)
    return DataFrame(first, 0, x, seq)


def _info(rate: float = 3000.0, grid=(4, 4), names=NAMES) -> InfoFrame:
    return InfoFrame(grid[0], grid[1], rate, volts_per_count=1e-4, has_model=True,
                     class_names=names)


#: the absurd frames of the reproductions, each with the line `eskin listen` prints for it
ABSURD = [
    (_info(math.inf), "refused INFO frame: sample_rate_hz = inf: not a finite number in "
                      "(0, 1e+06]"),
    (_info(math.nan), "refused INFO frame: sample_rate_hz = nan: "),
    (_info(0.0), "refused INFO frame: sample_rate_hz = 0.0: "),
    (_info(-3000.0), "refused INFO frame: sample_rate_hz = -3000.0: "),
    (_info(1e300), "refused INFO frame: sample_rate_hz = 1e+300: "),
    (_data(2**63), "refused DATA frame: first_sample = 9223372036854775808: outside [0, 2^53)"),
    (_data(2**64 - 5), f"refused DATA frame: first_sample = {2**64 - 5}: outside [0, 2^53)"),
    (_data(20, n=1, grid=(255, 7)), "refused DATA frame: grid = '255x7': the INFO accepted says 4x4"),
    (DecisionFrame(50, 40, 1, (0.5,)), "refused DECISION frame: offset_sample = 40: before "
                                       "onset_sample 50"),
    (DecisionFrame(10, 40, 9, (0.5,)), "refused DECISION frame: label = 9: not -1 (none) or a "
                                       "class index (the INFO accepted has 3 class names)"),
]


def test_absurd_frames_are_refused_named_and_the_stream_goes_on(tmp_path):
    good = [_info()] + [_data(k) for k in range(0, 200, 10)]
    decisions = [DecisionFrame(20, 180, 2, (-1.0, math.nan, math.inf), decided_sample=180),
                 DecisionFrame(20, 180, 0, (0.5, -0.5, -1.0), decided_sample=180)]
    frames = [ABSURD[0][0], good[0], *[f for f, _ in ABSURD[1:]], *good[1:], *decisions,
              StatusFrame(next_sample=200, samples_sent=200, state=StreamState.FINISHED,
                          connections=1)]
    wire = DELIMITER + b"".join(encode_frame(f) for f in frames)
    path, thread = _controller(wire)
    out = tmp_path / "d.jsonl"
    res = subprocess.run([sys.executable, "-m", "eskin", "listen", path, "--jsonl", str(out),
                          "--until-eof", "--duration", "60", "--view", "plain"],
                         capture_output=True, text=True, env=_env(), timeout=120)
    thread.join(5)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    refused = [x for x in res.stdout.splitlines() if x.startswith("refused ")]
    assert len(refused) == len(ABSURD), refused
    for line, (_, expected) in zip(refused, ABSURD):
        assert line.startswith(expected), (line, expected)
    lines = [json.loads(x) for x in out.read_text().splitlines()]  # strict JSON: no NaN
    assert [d["values"] for d in lines[:2]] == [[-1.0, None, None], [0.5, -0.5, -1.0]]
    assert [d["nonfinite_values"] for d in lines[:2]] == [True, False]
    stats = lines[-1]
    assert stats["type"] == "stats" and stats["absurd_frames"] == len(ABSURD)
    assert stats["samples"] == 200 + 2 * 10 + 1 and stats["lost_samples"] == 0
    assert stats["nonfinite_decisions"] == 1 and stats["decisions_controller"] == 2
    assert stats["frames"] == len(frames)
    assert "decision controller onset=20 (0.01 s) label=washer" in res.stdout  # 3000 Hz


def test_one_stray_grid_before_any_info_does_not_lock_the_stream():
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    frames = [_data(0, n=1, grid=(255, 7))] + [_data(k) for k in range(0, 100, 10)]
    events = listener.feed(DELIMITER + b"".join(encode_frame(f) for f in frames))
    blocks = [e for e in events if isinstance(e, DataBlock)]
    rejected = [e for e in events if isinstance(e, Rejection)]
    # the stray frame came first: two 4x4 frames are refused, the third takes the stream over
    assert [b.samples.shape[1:] for b in blocks] == [(255, 7)] + [(4, 4)] * 8
    assert [(r.frame, r.field, r.value) for r in rejected] == [("DATA", "grid", "4x4")] * 2
    assert listener.stats.absurd_frames == 2
    # an INFO first: the stray frame is refused and the stream is 4x4 from its first frame
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    events = listener.feed(DELIMITER + b"".join(encode_frame(f) for f in [_info(), *frames]))
    assert [type(e).__name__ for e in events[:2]] == ["InfoEvent", "Rejection"]
    assert sum(isinstance(e, DataBlock) for e in events) == 10
    assert listener.activity().shape == (4, 4)


def test_an_info_grid_the_model_cannot_take_ends_with_one_line_and_the_statistics(tmp_path):
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    rng = np.random.default_rng(3)
    X = rng.normal(size=(4, 4, 4, 5))
    machines = [MachineSpec(k, -1, 0.0, (2, 2, 2), (1.0, 1.0, 1.0), X, rng.normal(size=4))
                for k in range(2)]
    model = tmp_path / "m.eskin"
    model.write_bytes(model_to_bytes(ModelSpec(["a", "b"], "one_vs_all", machines, 5, (4, 4)),
                                     "float32"))
    wire = DELIMITER + b"".join(encode_frame(f) for f in [
        _data(0), _info(grid=(2, 2), names=("a", "b")), _data(10, grid=(2, 2))])
    path, thread = _controller(wire)
    out = tmp_path / "d.jsonl"
    res = subprocess.run([sys.executable, "-m", "eskin", "listen", path, "--model", str(model),
                          "--jsonl", str(out), "--duration", "60", "--view", "plain"],
                         capture_output=True, text=True, env=_env(), timeout=120)
    thread.join(5)
    assert res.returncode == 2
    assert res.stderr == ("error: INFO frame: grid = 2x2: the host model expects 4x4\n"), res.stderr
    assert "Traceback" not in res.stdout
    stats = json.loads(out.read_text().splitlines()[-1])
    assert stats["type"] == "stats" and stats["samples"] == 20 and stats["data_frames"] == 2
    assert [x for x in res.stdout.splitlines() if x.startswith("stats ")], res.stdout


def test_info_events_carry_only_accepted_infos():
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    wire = DELIMITER + b"".join(encode_frame(f) for f in (_info(0.0), _info(1500.0)))
    events = listener.feed(wire)
    assert [type(e) for e in events] == [Rejection, InfoEvent]
    assert listener.info.sample_rate_hz == 1500.0


def test_an_unpaced_controller_s_info_is_accepted():
    """eskin-fw-sim --speed 0 (unpaced, as fast as the host reads) announces speed 0 in its
    INFO: accepted; a negative or non-finite speed is refused."""
    import dataclasses

    from eskin.link.frame_checks import FrameChecks
    from eskin.link.protocol import InfoFrame

    base = InfoFrame(rows=4, cols=4, sample_rate_hz=3000.0, volts_per_count=1e-3, speed=0.0,
                     has_model=True, class_names=("brush", "finger", "washer"))
    assert FrameChecks().check(base) is None
    for bad in (-1.0, float("nan"), float("inf"), 2e6):
        r = FrameChecks().check(dataclasses.replace(base, speed=bad))
        assert r is not None and r.field == "speed"


def test_recording_at_a_rate_the_touch_detector_cannot_take_ends_with_one_line(tmp_path):
    """An INFO rate inside the checked range, and one a campaign may have, but far below what
    the touch detector works at (its DC cutoff is 5 Hz): `eskin listen --record` ends with one
    line naming the field and value and the final statistics, not a ValueError traceback from
    the detector. (1e-300 Hz, below what a campaign may have, is refused before the detector:
    test_recording_a_stream_slower_than_a_campaign_may_be.)"""
    wire = DELIMITER + b"".join(encode_frame(f) for f in [
        _info(1.0, grid=(2, 2), names=()), _data(0, grid=(2, 2))])
    path, thread = _controller(wire)
    out = tmp_path / "d.jsonl"
    res = subprocess.run([sys.executable, "-m", "eskin", "listen", path, "--record",
                          str(tmp_path / "live.h5"), "--jsonl", str(out), "--duration", "60",
                          "--view", "plain"],
                         capture_output=True, text=True, env=_env(), timeout=120)
    thread.join(5)
    assert res.returncode == 2, res.stderr
    assert res.stderr.startswith("error: INFO frame: sample_rate_hz = 1: cannot detect "
                                 "touches in this stream (WindowConfig.dc_cutoff_hz = 5")
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stdout
    stats = json.loads(out.read_text().splitlines()[-1])
    assert stats["type"] == "stats" and stats["frames"] == 2


def test_a_final_status_an_age_ahead_is_an_index_reset_not_a_loss():
    """A finished controller's STATUS whose next_sample lies more than an hour of samples past
    the last one received: like such a jump between two DATA frames, an index reset, not
    2^53 samples lost (found by test_listener_fuzz: the count went past 2^53). Counted once,
    however many times the stream is finished."""
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    frames = [_info(1000.0, grid=(2, 2), names=()), _data(0, grid=(2, 2)),
              _data(30, grid=(2, 2)),  # 20 samples lost, bridged
              StatusFrame(next_sample=2**53 - 1, samples_sent=20, state=StreamState.FINISHED,
                          connections=1)]
    listener.feed(DELIMITER + b"".join(encode_frame(f) for f in frames))
    for _ in range(2):  # finishing again counts nothing more
        listener.finish()
        assert listener.stats.lost_samples == 20 and listener.stats.sample_index_resets == 1
    # an hour's worth ahead is still a loss (the samples after the last frame received)
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    frames[-1] = StatusFrame(next_sample=40 + 3_600_000, samples_sent=40 + 3_600_000,
                             state=StreamState.FINISHED, connections=1)
    listener.feed(DELIMITER + b"".join(encode_frame(f) for f in frames))
    for _ in range(2):
        listener.finish()
        assert listener.stats.lost_samples == 20 + 3_600_000
        assert listener.stats.sample_index_resets == 0


def _listen(wire: bytes, out: Path) -> subprocess.CompletedProcess:
    path, thread = _controller(wire)
    res = subprocess.run([sys.executable, "-m", "eskin", "listen", path, "--jsonl", str(out),
                          "--until-eof", "--duration", "60", "--view", "plain"],
                         capture_output=True, text=True, env=_env(), timeout=120)
    thread.join(5)
    return res


def test_host_frames_from_the_controller_are_counted_and_skipped(tmp_path):
    """A sound PING (and START, STOP, INFO_REQUEST) reaching the host ended `eskin listen` with
    "0 is not a valid FrameType"; it is counted in unexpected_frames and the stream goes on."""
    from eskin.link.protocol import CommandFrame, FrameType, PingFrame

    host_frames = [PingFrame(7, 123), CommandFrame(FrameType.START),
                   CommandFrame(FrameType.STOP), CommandFrame(FrameType.INFO_REQUEST)]
    data = [_data(k) for k in range(0, 200, 10)]
    frames = [_info(), data[0], host_frames[0], *data[1:10], *host_frames[1:], *data[10:],
              StatusFrame(next_sample=200, samples_sent=200, state=StreamState.FINISHED,
                          connections=1)]
    out = tmp_path / "d.jsonl"
    res = _listen(DELIMITER + b"".join(encode_frame(f) for f in frames), out)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert "unexpected_frames=4" in res.stdout
    stats = json.loads(out.read_text().splitlines()[-1])
    assert stats["type"] == "stats" and stats["unexpected_frames"] == 4
    assert stats["absurd_frames"] == 0 and stats["frames"] == len(frames)
    assert stats["samples"] == 200 and stats["lost_samples"] == 0


def _version1_status(seq: int) -> bytes:
    """A STATUS frame as a version-1 controller lays it out: 64 bytes of payload (version 2
    added decisions_dropped and frames_dropped)."""
    import struct
    import zlib

    from eskin.link.protocol import cobs_encode

    payload = struct.pack("<QQQQIIIIIIIBBH", 1000, 200, 200, 0, 0, 0, 0, 1, 0, 0, 0, 2, 1, 1)
    assert len(payload) == 64
    raw = bytes([0x03, 0, seq & 0xFF, seq >> 8]) + payload
    return cobs_encode(raw + zlib.crc32(raw).to_bytes(4, "little")) + DELIMITER


@pytest.mark.parametrize("version,fields", [(1, {}), (99, {}), (3, {"sample_rate_hz": 0.0}),
                                            (1, {"rows": 0})])
def test_an_info_of_another_protocol_version_ends_the_stream_with_one_line(tmp_path, version,
                                                                          fields):
    """An older controller (version 1, whose STATUS is shorter) or a newer one: its STATUS is
    refused as malformed, never read by this version's layout, and its INFO ends the stream,
    whatever its other fields say (read by this version's rules, a rate of 0 or a grid of no
    rows would be refused as absurd)."""
    import dataclasses

    from eskin.link.protocol import PROTOCOL_VERSION

    assert PROTOCOL_VERSION == 2
    foreign = dataclasses.replace(_info(), protocol_version=version, **fields)
    frames = [_info(), *[_data(k) for k in range(0, 50, 10)]]
    wire = (DELIMITER + b"".join(encode_frame(f) for f in frames) + _version1_status(6)
            + encode_frame(foreign) + b"".join(encode_frame(_data(k)) for k in range(50, 100, 10)))
    out = tmp_path / "d.jsonl"
    res = _listen(wire, out)
    assert res.returncode == 2, (res.returncode, res.stdout, res.stderr)
    assert res.stderr == (f"error: INFO frame: protocol_version = {version}: this host speaks "
                          "version 2 of the eskin wire protocol and cannot read the controller's "
                          "frames (update eskin or the controller's firmware so that they "
                          "match)\n")
    stats = json.loads(out.read_text().splitlines()[-1])
    assert stats["type"] == "stats" and stats["samples"] >= 50  # the final statistics
    assert stats["malformed"] == 1 and stats["status_frames"] == 0
    assert stats["controller_state"] == "unknown"


def test_recording_a_stream_slower_than_a_campaign_may_be(tmp_path):
    """An INFO rate the link accepts (0.05 Hz) but a campaign refuses (0.1 Hz to 1 MHz): with
    --record, the stream ends with one line naming the rate, before any campaign is written."""
    from eskin.errors import LinkStreamError

    listener = LinkListener("/dev/null-not-opened", stats_interval=None,
                            record=tmp_path / "live.h5", context_s=0.01)
    with pytest.raises(LinkStreamError, match=r"^INFO frame: sample_rate_hz = 0.05: cannot "
                       r"record this stream \(a campaign's sample rate is 0.1 to 1e\+06 Hz\)"):
        listener.feed(DELIMITER + b"".join(encode_frame(f) for f in [
            _info(0.05, grid=(2, 2), names=()), _data(0, grid=(2, 2))]))
    listener.close()
    assert not (tmp_path / "live.h5").exists()


@pytest.mark.parametrize("count", ["samples", "decisions"])
def test_what_never_arrived_counts_only_from_a_status_that_follows_everything_sent(count):
    """unreceived_samples / unreceived_decisions: the STATUS's count minus what arrived, but
    only when the controller is not streaming and every frame it sent went to this host (1 to
    the host's sessions connections); else the count so far."""
    from eskin.link.receiver import unreceived_decisions, unreceived_samples

    fn = unreceived_samples if count == "samples" else unreceived_decisions
    field = "samples_sent" if count == "samples" else "decisions_sent"

    def status(state, connections):
        return StatusFrame(**{field: 50}, state=state, connections=connections)

    stopped, streaming = StreamState.STOPPED, StreamState.STREAMING
    assert fn(status(stopped, 1), 30, 0, known=4) == 20
    assert fn(status(stopped, 1), 48, 0, known=4) == 4  # the count only grows
    assert fn(status(stopped, 2), 30, 1, known=4) == 20  # two connections, one reconnect
    assert fn(status(stopped, 1), 30, 1, known=4) == 20
    assert fn(status(stopped, 2), 30, 0, known=4) == 4  # another host had a connection
    assert fn(status(stopped, 0), 30, 0, known=4) == 4  # an older controller: it does not say
    assert fn(status(streaming, 1), 30, 0, known=4) == 4  # more frames may follow
    assert fn(status(StreamState.FINISHED, 1), 30, 0, known=4) == 20  # its replay ended
    assert fn(status(stopped, 3), 30, 2, known=4) == 20  # three connections, two reconnects
    assert fn(status(stopped, 1), 30, 0) == 20 and fn(status(stopped, 1), 50, 0) == 0
    assert fn(status(stopped, 1), 60, 0) == 0  # more arrived than it says: nothing lost
    assert fn(status(streaming, 1), 30, 0) == 0


def test_activity_is_each_taxels_rms_deviation_from_its_mean_over_the_last_second():
    """A 1 kHz stream: each taxel a DC level of its own plus a known waveform. activity(w) is
    the RMS over the last max(1, w * rate) samples of each taxel's deviation from its mean
    over the last 1000 samples."""
    rate, n = 1000.0, 3000
    t = np.arange(n)
    dc = np.arange(16).reshape(4, 4) * 100 - 800
    wave = np.rint(40 * np.sin(2 * np.pi * t / 50) + 3 * (t % 7)).astype(np.int64)
    x = (dc[None] + wave[:, None, None] * (1 + np.arange(16).reshape(4, 4) % 3)).astype(np.int16)
    frames = [DataFrame(k, k * 1000, x[k:k + 10], (k // 10 + 1) % 65536) for k in range(0, n, 10)]
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    listener.feed(DELIMITER + encode_frame(_info(rate)) + b"".join(encode_frame(f) for f in frames))
    ref = x[-1000:].astype(np.float64).mean(axis=0)
    for window_s, last in ((0.2, 200), (0.05, 50), (0.0, 1), (0.0015, 1)):
        dev = x[-last:].astype(np.float64) - ref
        np.testing.assert_allclose(listener.activity(window_s), np.sqrt((dev * dev).mean(axis=0)),
                                   rtol=1e-12)
    np.testing.assert_array_equal(listener.activity(), listener.activity(0.2))  # the default
    listener.close()


def test_the_last_hundred_rejections_are_kept():
    listener = LinkListener("/dev/null-not-opened", stats_interval=None)
    bad = [_data(20 + k, n=1, grid=(255, 7)) for k in range(150)]
    listener.feed(DELIMITER + encode_frame(_info()) + b"".join(encode_frame(f) for f in bad))
    assert listener.stats.absurd_frames == 150
    assert [(r.frame, r.field, r.value) for r in listener.rejections] == [("DATA", "grid",
                                                                          "255x7")] * 100
    listener.close()
