"""Wall time of the paper's whole protocol (`eskin experiment`) on a simulated campaign.

Simulates a 70-participant campaign (or reuses --campaign), then runs the full protocol: 3
binary problems x 5 runs x D in {20, 50, 100} x {tensor-SVM, tensor-RLS} x {MD, CV} over the
paper's 135-configuration grid, the three-class 1-vs-all experiment, the vector baseline and the
subsampling comparison. Prints the time of each part (summed task times) and the wall time
against the 5-minute goal; the report goes to --out.

Baseline in the same run: the time the protocol's tensor searches would take one after the
other in one process is the sum of the task times; the ratio wall / sum shows what the joblib
parallelism buys on this machine. (The selection benchmark, benchmarks/bench_selection.py,
measures one MD search against a straightforward implementation.)

    python benchmarks/bench_protocol.py [--participants 70] [--n-jobs -1] [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--participants", type=int, default=70)
    ap.add_argument("--campaign", type=Path, default=None, help="reuse this campaign file")
    ap.add_argument("--n-jobs", type=int, default=-1)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="the reduced --quick protocol")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    from eskin.experiments.paper_protocol import run_experiment
    from eskin.data.simulator import simulate

    tmp = Path(tempfile.mkdtemp(prefix="eskin-bench-"))
    campaign = args.campaign
    if campaign is None:
        campaign = tmp / f"sim{args.participants}.h5"
        t0 = time.perf_counter()
        simulate(campaign, participants=args.participants, seed=0, n_jobs=max(1, args.n_jobs))
        print(f"simulate {args.participants} participants: {time.perf_counter() - t0:.1f} s")
    out = args.out or tmp / "report"
    t0 = time.perf_counter()
    res = run_experiment(campaign, out, runs=args.runs, quick=args.quick, n_jobs=args.n_jobs)
    wall = time.perf_counter() - t0

    parts: dict[str, float] = defaultdict(float)
    cpu: dict[str, float] = defaultdict(float)
    counts: dict[str, int] = defaultdict(int)
    groups = [(f"binary {d['machine']} {d['selection']}", d) for d in res["binary"]]
    groups += [
        ("subsampling (extra searches)", d) for d in (res.get("subsampling") or {}).get("rows", [])
    ]
    groups += [("vector baseline", d) for d in res["baseline"]]
    groups += [(f"3-class {d['machine']}", d) for d in res["multiclass"].get("runs", [])]
    for k, d in groups:
        parts[k] += d["seconds"]
        cpu[k] += d.get("cpu_seconds", float("nan"))
        counts[k] += 1
    total_tasks = sum(parts.values())
    total_cpu = sum(cpu.values())
    cpus = os.cpu_count()
    print(f"campaign: {campaign} ({res['analysis_set']['n_patterns']} patterns analysed)")
    print(f"preprocessing (once per D): {res['preprocessing']['seconds']:.1f} s")
    for k in sorted(parts):
        print(f"  {k:<28} {counts[k]:4d} tasks  {parts[k]:8.1f} s wall  {cpu[k]:8.1f} s CPU")
    print(f"sum of task wall times: {total_tasks:.1f} s; of task CPU times: {total_cpu:.1f} s")
    est = res["preprocessing"]["seconds"] + total_cpu / max(
        1, min(cpus or 1, 2 if args.n_jobs < 0 else args.n_jobs)
    )
    print(f"CPU-time estimate of the wall time on an idle machine with these workers: {est:.1f} s")
    print(
        f"wall time of the protocol: {wall:.1f} s with n_jobs={args.n_jobs} on {cpus} CPUs "
        f"(ratio wall/sum {wall / max(total_tasks, 1e-9):.2f})"
    )
    goal = 300.0
    print(
        f"goal < {goal:.0f} s: {'met' if wall < goal else 'NOT met'} "
        f"({wall / goal:.2f} of the budget)"
    )
    print(f"report: {out / 'report.md'}")


if __name__ == "__main__":
    main()
