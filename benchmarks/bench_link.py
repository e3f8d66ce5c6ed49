"""The serial link end to end: eskin-fw-sim on a real pseudo-terminal, the Python host reading it
with eskin.serial_port.SerialPort + eskin.protocol.FrameDecoder.

Measures (printed, then a summary line per measurement):
1. real time, 3000 samples/s x 16 taxels for --duration s (default 60): samples lost (host
   decoder) and dropped (simulator), and the simulator's pacing error p50/p99/max;
2. unpaced (--speed 0) throughput as a multiple of real time (baseline: the 3000 samples/s of
   the real sensor), and, for context, the host decoder alone on the captured bytes;
3. with --model (on-board classification, one wake-up per sample): latency from the sample that
   ends a touch to its DECISION frame, as the simulator reports it (acquisition -> frame queued)
   and as the host sees it (acquisition -> frame decoded in Python, same CLOCK_MONOTONIC).

    python benchmarks/bench_link.py [--duration 60] [--latency-touches 30]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from eskin._paths import find_executable
from eskin.link.protocol import (
    CommandFrame,
    DataFrame,
    DecisionFrame,
    FrameDecoder,
    FrameType,
    encode_frame,
)
from eskin.data.replay import write_replay_arrays
from eskin.link.serial_port import PeerClosedError, SerialPort

RATE = 3000.0


def synthetic_recordings(n: int, seconds: float, seed: int) -> list[np.ndarray]:
    """n recordings of 4x4 taxels: quiet noise with one loud 'touch' in the middle third."""
    rng = np.random.default_rng(seed)
    T = int(seconds * RATE)
    out = []
    for _ in range(n):
        r = rng.normal(0, 30, size=(4, 4, T))
        a, b = T // 3, 2 * T // 3
        t = np.arange(b - a) / RATE
        r[:, :, a:b] += 2000 * np.sin(2 * np.pi * 40 * t) * rng.uniform(0.5, 1.5, size=(4, 4, 1))
        out.append(np.clip(r, -32768, 32767).astype(np.int16))
    return out


def run_link(replay: Path, *args: str) -> tuple[list, FrameDecoder, dict, list[int]]:
    """Runs the simulator, reads everything; returns frames, decoder, sim STATS, receive times."""
    exe = find_executable("eskin-fw-sim")
    proc = subprocess.Popen([str(exe), str(replay), "--wait-start", "--quiet", *args],
                            stdout=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().split()[1]
        proc.stdout.readline()  # ORIGIN_NS
        dec = FrameDecoder()
        frames: list = []
        recv_ns: list[int] = []
        with SerialPort(path) as port:
            port.write(encode_frame(CommandFrame(FrameType.START)))
            while True:
                try:
                    chunk = port.read(65536, timeout=2.0)
                except PeerClosedError:
                    break
                t = time.monotonic_ns()
                got = dec.feed(chunk)
                frames += got
                recv_ns += [t] * len(got)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    stats = json.loads([x for x in out.splitlines() if x.startswith("STATS ")][-1][6:])
    return frames, dec, stats, recv_ns


def model_file(path: Path, D: int, n_sv: int, seed: int = 0) -> Path:
    """A 3-class one-vs-all model of realistic size (random support tensors, real bases)."""
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    rng = np.random.default_rng(seed)
    pool = rng.standard_normal((2 * n_sv, 4, 4, D))
    machines = [
        MachineSpec(k, -1, 0.0, (2, 2, 8), (1.0, 1.0, 2.0),
                    pool[np.sort(rng.choice(2 * n_sv, n_sv, replace=False))],
                    rng.standard_normal(n_sv))
        for k in range(3)
    ]
    spec = ModelSpec(class_names=["brush", "finger", "washer"], rule="one_vs_all",
                     machines=machines, D=D, grid_shape=(4, 4))
    path.write_bytes(model_to_bytes(spec, "float32"))
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="real-time run length (s)")
    ap.add_argument("--latency-touches", type=int, default=30)
    ap.add_argument("--no-realtime", action="store_true",
                    help="do not ask the simulator for SCHED_FIFO (--realtime)")
    args = ap.parse_args()
    rt = [] if args.no_realtime else ["--realtime"]
    tmp = Path(tempfile.mkdtemp(prefix="eskin-bench-link-"))

    # 1. real time, zero loss
    n_rec = max(1, int(round(args.duration / 7.5)))
    recs = synthetic_recordings(n_rec, args.duration / n_rec, seed=1)
    rf = write_replay_arrays(tmp / "long.eskr", recs, gap_s=0.05, seed=1)
    t0 = time.monotonic()
    frames, dec, stats, _ = run_link(rf.path, "--speed", "1", *rt)
    wall = time.monotonic() - t0
    received = sum(f.n_samples for f in frames if isinstance(f, DataFrame))
    lost = rf.n_samples - received
    print(f"[real time] {rf.n_samples} samples x 16 taxels ({rf.n_samples / RATE:.1f} s of signal) "
          f"in {wall:.1f} s: received {received}, lost {lost} (decoder counted "
          f"{dec.stats.lost_samples}, simulator dropped {stats['dropped_samples']}), "
          f"rejected blocks {dec.stats.rejected}")
    print(f"[pacing]    wake-up lateness vs absolute deadlines over {stats['pacing_wakeups']} frames "
          f"(SCHED_FIFO: {stats['realtime']}): "
          f"p50 {stats['pacing_p50_ns'] / 1e3:.0f} us, p99 {stats['pacing_p99_ns'] / 1e3:.0f} us, "
          f"max {stats['pacing_max_ns'] / 1e3:.0f} us")

    # 2. unpaced throughput
    t0 = time.monotonic()
    frames, dec, stats, recv = run_link(rf.path, "--speed", "0")
    received = sum(f.n_samples for f in frames if isinstance(f, DataFrame))
    first = next(i for i, f in enumerate(frames) if isinstance(f, DataFrame))
    span_s = (recv[-1] - recv[first]) / 1e9
    rate = received / span_s
    wire = b"\x00" + b"".join(encode_frame(f) for f in frames)
    t1 = time.perf_counter()
    FrameDecoder().feed(wire)
    dec_rate = received / (time.perf_counter() - t1)
    print(f"[unpaced]   {received} samples in {span_s:.2f} s = {rate:,.0f} samples/s = "
          f"{rate / RATE:.1f}x real time (lost {rf.n_samples - received}); host decoder alone: "
          f"{dec_rate / RATE:.0f}x real time")

    # 3. latency of on-board decisions
    model = model_file(tmp / "m.eskin", D=100, n_sv=60)
    recs = synthetic_recordings(args.latency_touches, 0.6, seed=2)
    rf = write_replay_arrays(tmp / "touches.eskr", recs, gap_s=0.2, seed=2)
    exe_out = run_link(rf.path, "--speed", "1", "--model", str(model), *rt)
    frames, dec, stats, recv = exe_out
    origin = stats["origin_ns"]
    sim_lat, host_lat, end_lat = [], [], []
    for f, t in zip(frames, recv):
        if isinstance(f, DecisionFrame):
            sim_lat.append(f.latency_us / 1e3)
            acquired_ns = origin + (f.timestamp_us - f.latency_us) * 1000
            host_lat.append((t - acquired_ns) / 1e6)
            # the touch window's last sample was acquired (decided - offset + 1) periods earlier
            end_lat.append(host_lat[-1] + (f.decided_sample + 1 - f.offset_sample) / RATE * 1e3)

    def pct(v: list[float], q: float) -> float:
        return float(np.percentile(v, q)) if v else float("nan")

    print(f"[latency]   {len(sim_lat)} decisions (model D=100, 3 machines x 60 SVs, float32): "
          f"simulator acquisition -> DECISION queued p50 {pct(sim_lat, 50):.2f} ms, "
          f"p99 {pct(sim_lat, 99):.2f} ms; host-side acquisition -> frame decoded "
          f"p50 {pct(host_lat, 50):.2f} ms, p99 {pct(host_lat, 99):.2f} ms, "
          f"max {max(host_lat, default=float('nan')):.2f} ms (goal < 10 ms); pacing p99 "
          f"{stats['pacing_p99_ns'] / 1e3:.0f} us with one wake-up per sample "
          f"(SCHED_FIFO: {stats['realtime']})")
    print(f"[latency]   from the last sample of the touch window to the DECISION on the host "
          f"(adds the detector's hold time, by design): p50 {pct(end_lat, 50):.1f} ms, "
          f"p99 {pct(end_lat, 99):.1f} ms")
    print("summary: lost_samples=%d unpaced_x_realtime=%.1f decision_latency_p99_ms=%.2f"
          % (lost, rate / RATE, pct(host_lat, 99)))


if __name__ == "__main__":
    main()
