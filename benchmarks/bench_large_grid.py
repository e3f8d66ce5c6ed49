"""What `eskin train` and `eskin evaluate` cost on a large, slow skin: a 19 x 27 grid at 10 Hz.

Data: a SIMULATED campaign (``eskin simulate --grid 19x27 --rate 10``, ``--participants``
people x 3 gestures x 2 directions x 2 runs: 28 people give 336 recordings), cached in
``--cache``. Every step runs as its own child process (the ``eskin`` command line); its CPU
seconds (user + system) and peak resident memory come from the kernel's accounting of that
child (``os.wait4``, ``ru_maxrss``), its wall time from this process's clock.

Steps:

1. ``eskin train`` with its defaults (D capped by the median touch window's samples, the 0.5
   GiB memory limit of the search's distances, the 4 MB model size): CPU, peak RSS, wall, the
   model's size, D, stored alphas and support vectors, and its decision time per recording on
   this host (the compiled classifier: detection, preprocessing, bases and kernel).
2. ``eskin train --D N`` with N the simulated touches' median true contact length in samples:
   the D the default takes when the detector's windows hold the touches (as on a recorded
   campaign whose windows' median is 10 samples).
3. ``--baseline``: ``eskin train --memory-limit 64 --max-model-size 0``, the search's distances
   in one block and no size limit (the behaviour before both; D is capped by the median touch
   window, 17-18 samples on this campaign since the detector keeps 5 warm-up frames at 10 Hz).
4. ``--evaluate``: ``eskin evaluate --D N --baselines vector,minirocket --no-live`` (leave one
   participant out): wall and CPU, the accuracy of the tensor recipe and of the baselines.

Ratios: baseline / default for CPU, peak RSS and model size. Usage:

    python benchmarks/bench_large_grid.py [--participants 28] [--baseline] [--evaluate]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ESKIN = [sys.executable, "-m", "eskin"]


def campaign(cache: Path, participants: int) -> Path:
    path = cache / f"large_grid_19x27_10hz_{participants}p.h5"
    if not path.exists():
        cache.mkdir(parents=True, exist_ok=True)
        subprocess.run([*ESKIN, "simulate", "-o", str(path), "--participants", str(participants),
                        "--grid", "19x27", "--rate", "10", "--seed", "5", "--quiet"], check=True)
    return path


def measured(args: list[str]) -> dict[str, float]:
    """Run ``eskin ARGS`` as a child: its wall seconds, CPU seconds and peak RSS (bytes)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([*ESKIN, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    out = proc.stdout.read().decode()  # type: ignore[union-attr]
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"eskin {' '.join(args)} failed:\n{out}")
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime,
            "rss_bytes": usage.ru_maxrss * 1024, "output": out}


def model_figures(model_path: Path, campaign_path: Path) -> dict[str, float]:
    """Size, D, stored alphas, support vectors and host decision time (the compiled classifier
    on whole recordings: detection, preprocessing, bases and kernel) of a written model."""
    from eskin.data.campaign import load_campaign
    from eskin.deploy.export import CompiledModel

    cm = CompiledModel(model_path)
    with load_campaign(campaign_path) as c:
        signals = np.stack([np.asarray(c.recording(i)) for i in range(32)])
        lengths = np.asarray(c.lengths)[:32]
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        cm.classify(signals, lengths)
        best = min(best, (time.perf_counter() - t0) / len(signals))
    return {"model_bytes": model_path.stat().st_size, "D": int(cm._model.D),
            "alpha": tuple(cm._model.alpha_store), "support_vectors": int(cm._model.n_support),
            "decision_ms": best * 1e3}


def train(path: Path, out: Path, extra: list[str]) -> dict[str, float]:
    res = measured(["train", str(path), "-o", str(out), "--force", "--no-progress", *extra])
    return {**res, **model_figures(out, path)}


def evaluate(path: Path, out: Path, extra: list[str]) -> dict[str, float]:
    res = measured(["evaluate", str(path), "-o", str(out), "--force", "--no-live",
                    "--baselines", "vector,minirocket", *extra])
    report = json.loads((out / "evaluation.json").read_text())
    res["accuracy"] = round(float(report["accuracy"]), 3)
    res["baselines"] = {k: round(float(v["accuracy"]), 3) for k, v in report["baselines"].items()}
    return res


def contact_D(path: Path) -> int:
    """The median true contact length of the simulated touches, in samples."""
    from eskin.data.campaign import load_campaign

    with load_campaign(path) as c:
        ci = np.asarray(c.contact_interval)
    return max(2, int(np.median(ci[:, 1] - ci[:, 0])))


def line(name: str, r: dict) -> str:
    keys = [("cpu_s", "CPU {:.1f} s"), ("wall_s", "wall {:.1f} s"),
            ("rss_bytes", "peak RSS {:.0f} MiB", 2**-20), ("model_bytes", "model {:.2f} MB", 1e-6),
            ("D", "D {}"), ("alpha", "alpha {}"), ("support_vectors", "{} support vectors"),
            ("decision_ms", "{:.2f} ms per decision"), ("accuracy", "accuracy {}"),
            ("baselines", "baselines {}")]
    parts = []
    for key, fmt, *scale in keys:
        if key in r:
            v = r[key] * scale[0] if scale else r[key]
            parts.append(fmt.format(v))
    return f"{name}: " + ", ".join(parts)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--participants", type=int, default=28)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin_bench_large_grid"))
    ap.add_argument("--baseline", action="store_true")
    ap.add_argument("--evaluate", action="store_true")
    args = ap.parse_args(argv)
    path = campaign(args.cache, args.participants)
    n = contact_D(path)
    print(f"campaign: {path} (SIMULATED, 19x27 taxels, 10 Hz); median contact {n} samples")
    default = train(path, args.cache / "default.eskin", [])
    print(line("train (default)", default))
    fill = train(path, args.cache / "contact.eskin", ["--D", str(n)])
    print(line(f"train --D {n}", fill))
    if args.baseline:
        base = train(path, args.cache / "baseline.eskin",
                     ["--memory-limit", "64", "--max-model-size", "0"])
        print(line("train --memory-limit 64 --max-model-size 0 (baseline)", base))
        for key, what in (("cpu_s", "CPU"), ("rss_bytes", "peak RSS"),
                          ("model_bytes", "model size")):
            print(f"  {what}: baseline / default = {base[key] / default[key]:.1f}x")
    if args.evaluate:
        ev = evaluate(path, args.cache / "evaluation", ["--D", str(n)])
        print(line(f"evaluate --D {n} --baselines vector,minirocket", ev))


if __name__ == "__main__":
    main()
