"""Which negatives should each one-vs-all machine see? A three-class study on unseen people.

The paper trains machine k of a one-vs-all model on the patterns of class k and as many patterns
drawn at random from the other classes ("balanced", ``eskin train``'s default until this study);
the alternative gives it every pattern of the other classes ("all"). This script measures both,
and any other recipe given, with ``eskin evaluate``'s nested group-disjoint evaluation
(:func:`eskin.learn.evaluation.evaluate_recipe`: five folds of participants, model selection
inside each fold's training participants only) on several simulated three-class campaigns of
20 participants: the simulator at difficulty 0-3, a 1x4 strip, 200 Hz sampling and equal mean
force for every modality. Campaigns are cached under ``--cache``; results are appended to
``results.jsonl`` there and a rerun only computes what is missing.

    python benchmarks/multiclass_study.py [--campaigns d1,d2] [--recipes balanced,all]

Prints the accuracy per campaign and recipe, the mean over campaigns and the paired
difference to the first recipe with wins/ties/losses. The data are SIMULATED.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

import eskin
from eskin.learn.evaluation import evaluate_recipe

#: name -> (simulate() keyword arguments, SimulatorConfig overrides)
CAMPAIGNS = {
    "d0": ({"difficulty": 0.0}, {}),
    "d1": ({"difficulty": 1.0}, {}),
    "d2": ({"difficulty": 2.0}, {}),
    "d3": ({"difficulty": 3.0}, {}),
    "d1-1x4": ({"difficulty": 1.0}, {"rows": 1, "cols": 4}),
    "d1-200Hz": (
        {"difficulty": 1.0},
        {"sample_rate_hz": 200.0, "bpf_lowpass_hz": 90.0, "brush_band_hz": (15.0, 90.0)},
    ),
    "d1-sameforce": (
        {"difficulty": 1.0},
        {"brush_force_n": 1.0, "finger_force_n": 1.0, "washer_force_n": 1.0,
         "style_force_sigma": 0.8},
    ),
}
#: recipe name -> keyword arguments of eskin.train_model (on top of its defaults)
RECIPES = {
    "balanced": {"negatives": "balanced"},
    "all": {"negatives": "all"},
}


def campaign_file(cache: Path, name: str, participants: int, seed: int) -> Path:
    """Simulate run 2 of ``participants`` people once; later runs reuse the file."""
    sim_args, overrides = CAMPAIGNS[name]
    path = cache / f"{name}-{participants}p-seed{seed}.h5"
    if not path.exists():
        cache.mkdir(parents=True, exist_ok=True)
        cfg = dataclasses.replace(eskin.SimulatorConfig(), **overrides)
        tmp = path.with_suffix(".part.h5")
        eskin.simulate(tmp, participants=participants, seed=seed, runs=(2,), config=cfg,
                       overwrite=True, **sim_args)
        tmp.rename(path)
    return path


def done_keys(results: Path) -> set[tuple[str, str]]:
    if not results.exists():
        return set()
    rows = [json.loads(line) for line in results.read_text().splitlines() if line]
    return {(r["campaign"], r["recipe"]) for r in rows}


def run(cache: Path, campaigns: list[str], recipes: list[str], participants: int,
        folds: int, seeds: list[int]) -> tuple[Path, list[str]]:
    """Evaluate every (campaign, simulator seed, recipe) not in ``results.jsonl`` yet; append
    its row. Returns the file and the names of the campaigns ("d1/s7": campaign d1, seed 7)."""
    results = cache / "results.jsonl"
    done = done_keys(results)
    names = []
    for seed in seeds:
        for camp in campaigns:
            names.append(f"{camp}/s{seed}")
            _evaluate(cache, camp, seed, recipes, participants, folds, results, done)
    return results, names


def _evaluate(cache, camp, seed, recipes, participants, folds, results, done):
    name = f"{camp}/s{seed}"
    path = campaign_file(cache, camp, participants, seed)
    for recipe in recipes:
        if (name, recipe) in done:
            continue
        t0 = time.perf_counter()
        r = evaluate_recipe(path, recipe=RECIPES[recipe], n_folds=folds, seed=0)
        row = {
            "campaign": name,
            "recipe": recipe,
            "accuracy": r["accuracy"],
            "balanced_accuracy": r["balanced_accuracy"],
            "ci95": r["ci95"],
            "seconds": time.perf_counter() - t0,
        }
        with results.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(f"{name} {recipe}: {100 * r['accuracy']:.1f} % "
              f"({row['seconds']:.0f} s)", flush=True)


def table(results: Path, campaigns: list[str], recipes: list[str]) -> str:
    """Markdown: accuracy % per campaign and recipe, the mean, and the paired difference to
    the first recipe (wins/ties/losses over campaigns)."""
    rows = [json.loads(line) for line in results.read_text().splitlines() if line]
    acc = {(r["campaign"], r["recipe"]): 100 * r["accuracy"] for r in rows}
    camps = [c for c in campaigns if all((c, rc) in acc for rc in recipes)]
    lines = ["| recipe | " + " | ".join(camps) + " | mean | vs " + recipes[0] + " (w/t/l) |",
             "| --- |" + " ---: |" * (len(camps) + 2)]
    for rc in recipes:
        vals = np.array([acc[(c, rc)] for c in camps])
        ref = np.array([acc[(c, recipes[0])] for c in camps])
        d = vals - ref
        wtl = f"{int((d > 0).sum())}/{int((d == 0).sum())}/{int((d < 0).sum())}"
        lines.append(f"| {rc} | " + " | ".join(f"{v:.1f}" for v in vals)
                     + f" | {vals.mean():.1f} | {d.mean():+.1f} ({wtl}) |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaigns", default=",".join(CAMPAIGNS))
    ap.add_argument("--recipes", default=",".join(RECIPES))
    ap.add_argument("--participants", type=int, default=20)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--seeds", default="7,8,9", help="simulator seeds (one campaign each)")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin_multiclass_study"))
    args = ap.parse_args(argv)
    campaigns, recipes = args.campaigns.split(","), args.recipes.split(",")
    seeds = [int(v) for v in args.seeds.split(",")]
    results, names = run(args.cache, campaigns, recipes, args.participants, args.folds, seeds)
    print("\naccuracy % on unseen participants (nested, group-disjoint; SIMULATED campaigns)\n")
    print(table(results, names, recipes))


if __name__ == "__main__":
    main()
