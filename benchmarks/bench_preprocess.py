"""Preprocessing throughput: 4x4x21000 int16 recordings -> 4x4x100 float64 tensors.

Compares, in the same process and on the same simulated recordings:
- eskin.preprocess (C++ core: energy detector + Algorithm 2), one thread and all threads;
- a straightforward numpy/scipy implementation of the same detector and subsampling
  (eskin._preprocess_numpy: whole-array DC blocker and frame energies, a Python loop over
  frames for the state machine), which must find the same windows;
- the streaming detector (eskin.TouchDetector) fed 10 ms blocks, as from a live link.

Usage: python benchmarks/bench_preprocess.py [--participants 4] [--repeat 3]
The recordings are SIMULATED (eskin.simulator).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from eskin.signal import _preprocess_numpy as ref
from eskin.signal.preprocess import TouchDetector, WindowConfig, preprocess
from eskin.data.simulator import iter_recordings


CPU = {}


def best_of(repeat: int, fn, key: str | None = None) -> float:
    """Best wall-clock time of `repeat` runs (and, under `key`, the best process CPU time, which
    is steadier on a shared machine; for one thread the two agree when the machine is idle)."""
    times, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    if key:
        CPU[key] = min(cpu)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--participants", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--D", type=int, default=100)
    args = ap.parse_args()

    recs = [rec for _, rec, _ in iter_recordings(args.participants, seed=0, runs=(2,))]
    X = np.stack(recs)
    n = len(X)
    D = args.D
    cfg = WindowConfig()
    print(f"{n} simulated recordings {X.shape[1:]} {X.dtype} -> ({X.shape[1]}, {X.shape[2]}, {D})"
          f", {os.cpu_count()} cores")

    out_cpp, win_cpp = preprocess(X, D, return_windows=True)
    t_cpp1 = best_of(args.repeat, lambda: preprocess(X, D, n_threads=1), "cpp1")
    t_cpp = best_of(args.repeat, lambda: preprocess(X, D))

    def numpy_all():
        return [ref.preprocess(x, D, 3000.0, cfg) for x in X]

    t_np = best_of(1, numpy_all, "numpy")
    res = numpy_all()
    win_np = np.array([w for _, w in res])
    out_np = np.stack([o for o, _ in res])
    agree = float((win_np == win_cpp).all(axis=1).mean())
    same_tensors = bool(np.array_equal(out_np, out_cpp))

    def stream_all():
        det = TouchDetector((X.shape[1], X.shape[2]), 3000.0, cfg)
        for x in X:
            det.reset()
            s = np.ascontiguousarray(np.moveaxis(x, -1, 0))
            for i in range(0, s.shape[0], 30):
                det.push(s[i : i + 30])
            det.flush()

    t_stream = best_of(1, stream_all)
    seconds_of_signal = n * X.shape[-1] / 3000.0

    print(f"numpy baseline          : {n / t_np:9.1f} recordings/s")
    print(f"C++ core, 1 thread      : {n / t_cpp1:9.1f} recordings/s   "
          f"x{t_np / t_cpp1:.1f} vs numpy")
    print(f"C++ core, all threads   : {n / t_cpp:9.1f} recordings/s   "
          f"x{t_np / t_cpp:.1f} vs numpy")
    print(f"streaming, 10 ms blocks : {seconds_of_signal / t_stream:9.1f} x real time "
          f"({n / t_stream:.1f} recordings/s, Python push per block)")
    print(f"CPU time, one thread    : numpy {1e3 * CPU['numpy'] / n:.2f} ms/recording, C++ "
          f"{1e3 * CPU['cpp1'] / n:.2f} ms/recording, x{CPU['numpy'] / CPU['cpp1']:.1f}")
    print(f"windows identical to the numpy baseline: {agree:.1%}; tensors identical: "
          f"{same_tensors}")


if __name__ == "__main__":
    main()
