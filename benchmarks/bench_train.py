"""What `eskin train`'s default recipe costs against the paper's kernel, measured in one run.

Two ratios, each against a baseline run in the same process on the same data:

1. Training time: ``eskin.train_model`` with its defaults (the amplitude factor searched with
   widths off, 1 and 4; every pattern of the other classes for each one-vs-all machine) against
   the same recipe with the paper's kernel alone and the paper's balanced share of negatives
   (``amplitudes=(None,)``, ``negatives="balanced"``). Both alternate, the fastest of
   ``--repeats`` runs of each counts.
2. Decision time on this host: the default model exported to ``.eskin`` (the compiled C++
   classifier, ``CompiledModel.classify_tensors``) against the same model with every amplitude
   width set to 0 (the same machines and support vectors without the factor).

Data: a SIMULATED three-class campaign (``eskin.simulate``, run 2, ``--participants`` people,
cached in ``--cache``). Usage:

    python benchmarks/bench_train.py [--participants 30] [--repeats 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

import eskin
from eskin.deploy.export import CompiledModel, model_to_bytes, spec_from_model
from eskin.learn.training import train_model

PAPER = {"amplitudes": (None,), "negatives": "balanced"}


def campaign(cache: Path, participants: int) -> Path:
    path = cache / f"bench_train_{participants}p.h5"
    if not path.exists():
        cache.mkdir(parents=True, exist_ok=True)
        eskin.simulate(path, participants=participants, seed=3, runs=(2,), overwrite=True)
    return path


def fastest_training(path: Path, repeats: int) -> tuple[float, float, object]:
    """(seconds of the default recipe, seconds of the paper-like one, the default model)."""
    times = {"default": [], "paper": []}
    model = None
    for _ in range(repeats):
        for name, options in (("default", {}), ("paper", PAPER)):
            t0 = time.perf_counter()
            m = train_model(path, n_jobs=1, **options)
            times[name].append(time.perf_counter() - t0)
            model = m if name == "default" else model
    return min(times["default"]), min(times["paper"]), model


def decision_times(model, X: np.ndarray, repeats: int) -> tuple[float, float, int]:
    """(seconds per decision with the factor, without it, machines with the factor)."""
    spec = spec_from_model(model)
    plain = dataclasses.replace(spec, machines=[
        dataclasses.replace(m, amplitude_width=0.0) for m in spec.machines])
    engines = {"factor": CompiledModel(model_to_bytes(spec, "float32")),
               "plain": CompiledModel(model_to_bytes(plain, "float32"))}
    best = {k: np.inf for k in engines}
    for _ in range(repeats):
        for k, engine in engines.items():
            t0 = time.perf_counter()
            engine.classify_tensors(X)
            best[k] = min(best[k], (time.perf_counter() - t0) / len(X))
    n_factor = sum(1 for m in spec.machines if m.amplitude_width > 0)
    return best["factor"], best["plain"], n_factor


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--participants", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin_bench_train"))
    args = ap.parse_args(argv)
    path = campaign(args.cache, args.participants)
    default_s, paper_s, model = fastest_training(path, args.repeats)
    print(f"SIMULATED campaign {path.name}: training, fastest of {args.repeats}")
    print(f"  default recipe (amplitude off/1/4, all negatives): {default_s:7.2f} s")
    print(f"  paper's kernel, balanced negatives:                {paper_s:7.2f} s")
    print(f"  ratio default / paper-like: {default_s / paper_s:.2f}")
    X = model.preprocess(eskin.load_campaign(path))
    with_f, without_f, n_factor = decision_times(model, X, max(5, args.repeats))
    print(f"decision on this host (compiled classifier, float32 model, {len(X)} patterns, "
          f"factor on {n_factor} of {len(model.classes)} machines, fastest of "
          f"{max(5, args.repeats)})")
    print(f"  with the amplitude factor:    {1e6 * with_f:8.1f} us")
    print(f"  same model without it:        {1e6 * without_f:8.1f} us")
    print(f"  ratio with / without: {with_f / without_f:.3f}")


if __name__ == "__main__":
    main()
