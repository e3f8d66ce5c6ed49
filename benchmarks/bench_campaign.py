"""Campaign benchmarks: simulator generation time, campaign write and read throughput.

Prints absolute times and ratios against baselines measured in the same process (the machine is
shared, so ratios are the stable numbers):

* baseline W: writing the same number of int16 recordings of white noise through
  CampaignWriter (the cost of the file format alone: compression, the crash-safe journal with
  one fsync per recording, HDF5); W without fsync (``durable=False``, as the simulator writes)
  gives the price of the fsync;
* simulate, 1 and N worker processes: the whole physics chain plus writing;
* read: load_campaign + reading every recording back (lazy, one chunk per recording).

Usage: python benchmarks/bench_campaign.py [--participants 70] [--jobs 2] [--writer-only]
The full campaign (70 participants, 840 recordings) is the issue's target: under a minute on
2 cores. Data are SIMULATED.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from eskin.data.campaign import CampaignWriter, load_campaign
from eskin.data.simulator import MODALITIES, SimulatorConfig, simulate


def _cpu() -> float:
    """CPU seconds used so far by this process and its finished children (pool workers)."""
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _write_noise(path: Path, n: int, cfg: SimulatorConfig, durable: bool = True,
                 close_time: list | None = None) -> float:
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    w = CampaignWriter(path, grid_shape=(cfg.rows, cfg.cols), n_samples=cfg.n_samples,
                       sample_rate_hz=cfg.sample_rate_hz, volts_per_count=cfg.volts_per_count,
                       modalities=list(MODALITIES), source="simulated", durable=durable)
    for i in range(n):
        rec = rng.normal(0.0, 30.0, (cfg.rows, cfg.cols, cfg.n_samples)).astype(np.int16)
        w.append(rec, modality=i % 3, participant=i // 12, direction=i % 2, run=1)
    t1 = time.perf_counter()
    w.close()  # builds the campaign file from the journal
    if close_time is not None:
        close_time.append(time.perf_counter() - t1)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--participants", type=int, default=70)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--writer-only", action="store_true", help="only the two W rows")
    args = ap.parse_args()
    cfg = SimulatorConfig()
    n = args.participants * 12
    print(f"campaign: {args.participants} participants -> {n} SIMULATED recordings "
          f"({cfg.rows}x{cfg.cols} taxels, {cfg.n_samples} samples), {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        closing: list = []
        t_w = _write_noise(tmp / "noise.h5", n, cfg, close_time=closing)
        print(f"baseline W  write {n} noise recordings      {t_w:7.1f} s  "
              f"{n / t_w:7.1f} rec/s   (close, the file from the journal: {closing[0]:.1f} s "
              f"= {closing[0] / t_w:.2f} x W)")
        t_nd = _write_noise(tmp / "noise_nd.h5", n, cfg, durable=False)
        print(f"W, durable=False (no fsync)             {t_nd:7.1f} s  {n / t_nd:7.1f} rec/s  "
              f"= {t_nd / t_w:5.2f} x W   (fsync: {1000 * (t_w - t_nd) / n:.1f} ms/recording)")
        if args.writer_only:
            return
        t0, c0 = time.perf_counter(), _cpu()
        simulate(tmp / "sim1.h5", participants=args.participants, seed=0, n_jobs=1)
        t_1, c_1 = time.perf_counter() - t0, _cpu() - c0
        print(f"simulate    1 process                   {t_1:7.1f} s  {n / t_1:7.1f} rec/s  "
              f"= {t_1 / t_w:5.2f} x W   CPU {c_1:6.1f} s = {1000 * c_1 / n:.0f} ms/recording")
        if args.jobs > 1:
            t0, c0 = time.perf_counter(), _cpu()
            simulate(tmp / "simN.h5", participants=args.participants, seed=0, n_jobs=args.jobs)
            t_n, c_n = time.perf_counter() - t0, _cpu() - c0
            print(f"simulate    {args.jobs} processes                 {t_n:7.1f} s  "
                  f"{n / t_n:7.1f} rec/s  = {t_n / t_w:5.2f} x W, speed-up {t_1 / t_n:4.2f}"
                  f"   CPU {c_n:6.1f} s")
        print(f"load average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores "
              f"(wall times stretch when other work shares the cores; CPU times do not)")
        t0 = time.perf_counter()
        with load_campaign(tmp / "sim1.h5") as c:
            total = 0
            for i in range(len(c)):
                total += int(c.recording(i)[0, 0, 0])
        t_r = time.perf_counter() - t0
        size = (tmp / "sim1.h5").stat().st_size / 2**20
        print(f"read        load + every recording      {t_r:7.1f} s  {n / t_r:7.1f} rec/s  "
              f"= {t_r / t_w:5.2f} x W   (file {size:.0f} MiB, "
              f"{size * 2**20 / (n * cfg.rows * cfg.cols * cfg.n_samples * 2):.2f} of raw int16)")


if __name__ == "__main__":
    main()
