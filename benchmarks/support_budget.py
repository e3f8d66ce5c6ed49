"""Held-out error against the number of support vectors: what ``--max-support`` costs.

For each campaign (the simulated campaigns of ``selection_study.py --part search``, unlike one
another: eskin's default simulator, difficulty 2, pre-segmented short gestures at 200 Hz, a 1x4
strip at 100 Hz, an 8x8 grid at 500 Hz, ...) and each participant split (70 % of the
participants train, the others are unseen; the same seeded splits as the study), the searched
default (``eskin.train_model`` with no recipe option) is trained once on the training
participants. Its machines are then bounded to ``--budgets`` distinct support vectors in two
ways, and each is scored on the unseen participants:

- greedy: ``eskin.learn.support_budget.bound_support`` (what ``eskin train --max-support``
  does): the patterns chosen one at a time by kernel matching pursuit, every machine projected
  onto them;
- coef: the patterns with the largest share of the machines' coefficients, every machine
  projected onto them (``selection="coefficients"``);
- drop: the patterns of "coef" with their own coefficients, the others removed (the naive
  pruning the projection improves on).

Printed and written (``--out``, JSON lines): campaign, split, budget, distinct support vectors
of the model, held-out error of each way. The data are SIMULATED.

With ``--part target``: per unit, the held-out error of the searched default, of the
``eskin train --target cortex-m4`` model, and of ``--target cortex-m4 --max-support N`` for each
N of ``--target-supports`` (the search then estimates candidates at N support vectors, so larger
recipes can fit).

    python benchmarks/support_budget.py [--campaigns s-d1,short-200Hz] [--splits 2]
    python benchmarks/support_budget.py --part target --campaigns s-d1,s-d2 --splits 2
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import eskin  # noqa: E402
from eskin.learn.training import train_model  # noqa: E402
from eskin.learn.support_budget import (  # noqa: E402
    _machines,
    bound_support,
    distinct_support,
    kept_patterns,
    n_distinct_support,
)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from selection_study import (  # noqa: E402
    SEARCH_CAMPAIGNS,
    SEARCH_TRAIN_SHARE,
    _heldout_error,
    campaign_path,
)

DEFAULT_CAMPAIGNS = "s-d1,s-d2,short-200Hz,strip-1x4-100Hz,grid-8x8-500Hz"
WAYS = ("greedy", "fit", "coef", "drop")


def dropped(estimator, max_support: int):
    """The naive bound: keep the same patterns as bound_support, with their own coefficients."""
    table, _, where = distinct_support(estimator)
    keep = set(kept_patterns(estimator, max_support, "coefficients").tolist())
    out = copy.deepcopy(estimator)
    for m, idx in zip(_machines(out), where):
        mask = np.array([i in keep for i in idx], dtype=bool)
        m.support_vectors_ = np.ascontiguousarray(m.support_vectors_[mask])
        m.sv_log_energy_ = np.ascontiguousarray(m.sv_log_energy_[mask])
        m.dual_coef_ = np.ascontiguousarray(m.dual_coef_[mask])
        m.support_ = m.support_[mask]
    return out


def with_estimator(model, estimator):
    other = copy.copy(model)
    other.estimator = estimator
    return other


def split_campaign(cache: Path, name: str, split: int):
    """(spec, campaign, training participants' part, unseen participants' part): the study's
    seeded participant split of ``selection_study.py --part search``."""
    spec = SEARCH_CAMPAIGNS[name]
    camp = eskin.load_campaign(campaign_path(cache, name, spec), in_memory=True)
    part = np.asarray(camp.participant)
    ids = np.unique(part)
    rng = np.random.default_rng([split, 22])
    train_ids = rng.permutation(ids)[: round(len(ids) * SEARCH_TRAIN_SHARE)]
    return (spec, camp, camp.subset(np.flatnonzero(np.isin(part, train_ids))),
            camp.subset(np.flatnonzero(~np.isin(part, train_ids))))


def unit(cache: Path, name: str, split: int, budgets: list[int], seed: int) -> list[dict]:
    spec, camp, train, test = split_campaign(cache, name, split)
    t0 = time.process_time()
    model = train_model(train, window=spec[3], seed=seed)
    cpu = time.process_time() - t0
    full = n_distinct_support(model.estimator)
    X_train = model.preprocess(train)
    recipe = f"{model.machine} D={model.D} {model.subsample} {model.training.get('negatives')}"
    rows = [{"campaign": name, "split": split, "budget": None, "support_vectors": full,
             **dict.fromkeys(WAYS, _heldout_error(model, test)),
             "recipe": recipe, "train_cpu_s": round(cpu, 1)}]
    for k in budgets:
        if k >= full:
            continue
        ways = {"greedy": bound_support(model.estimator, k),
                "fit": bound_support(model.estimator, k, X_fit=X_train),
                "coef": bound_support(model.estimator, k, "coefficients"),
                "drop": dropped(model.estimator, k)}
        rows.append({"campaign": name, "split": split, "budget": k,
                     "support_vectors": n_distinct_support(ways["greedy"]),
                     **{w: _heldout_error(with_estimator(model, e), test)
                        for w, e in ways.items()},
                     "recipe": recipe})
    return rows


def target_unit(cache: Path, name: str, split: int, supports: list[int], seed: int) -> list[dict]:
    """The searched default, the `--target cortex-m4` model, and the `--target cortex-m4
    --max-support N` models, each on the unseen participants of one split (what eskin train runs
    for them: the detector window fitted to the budget, the search restricted to candidates
    whose estimated compiled model fits)."""
    from eskin.deploy.export import model_to_bytes, spec_from_model
    from eskin.deploy.target import model_fits, parse_budget, training_budget

    spec, camp, train, test = split_campaign(cache, name, split)
    budget = parse_budget(None, "cortex-m4")
    grid_shape = tuple(int(v) for v in np.shape(camp.recording(0))[:2])
    rate = float(camp.sample_rate_hz)
    n_classes = len(camp.modalities)
    rows = []
    for label, k in [("searched", None), ("target", None),
                     *((f"target max-support {n}", n) for n in supports)]:
        opts = {"window": spec[3], "seed": seed, "max_support": k}
        if label != "searched":
            wc, search_budget, _ = training_budget(budget, grid_shape, rate, None, n_classes, k)
            opts |= {"window_config": wc, "budget": search_budget}
        t0 = time.process_time()
        try:
            model = train_model(train, **opts)
        except ValueError as exc:  # no candidate fits
            rows.append({"campaign": name, "split": split, "method": label, "error": None,
                         "note": str(exc)})
            continue
        fits, fig = model_fits(model_to_bytes(spec_from_model(model), "float32"), budget)
        rows.append({"campaign": name, "split": split, "method": label,
                     "error": _heldout_error(model, test),
                     "recipe": f"{model.machine} D={model.D} {model.subsample} "
                               f"{model.training.get('negatives')}",
                     "support_vectors": n_distinct_support(model.estimator),
                     "fits": bool(fits), **{k2: float(v) for k2, v in fig.items()},
                     "train_cpu_s": round(time.process_time() - t0, 1)})
    return rows


def target_table(rows: list[dict]) -> str:
    methods = list(dict.fromkeys(r["method"] for r in rows))
    lines = ["| campaign | splits | " + " | ".join(methods) + " |",
             "|" + "---|" * (len(methods) + 2)]
    for name in dict.fromkeys(r["campaign"] for r in rows):
        cells = [name, str(len({r["split"] for r in rows if r["campaign"] == name}))]
        for m in methods:
            at = [r for r in rows if r["campaign"] == name and r["method"] == m]
            if any(r["error"] is None for r in at):
                cells.append("no model fits")
                continue
            cells.append(f"{100 * np.mean([r['error'] for r in at]):.1f} "
                         f"({np.mean([r['support_vectors'] for r in at]):.0f} SVs)")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def table(rows: list[dict]) -> str:
    budgets = sorted({r["budget"] for r in rows if r["budget"] is not None}, reverse=True)
    head = ["campaign", "splits", "all: SVs", "all: error"] + [f"{k}: " + " / ".join(WAYS)
                                                               for k in budgets]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name in dict.fromkeys(r["campaign"] for r in rows):
        mine = [r for r in rows if r["campaign"] == name]
        base = [r for r in mine if r["budget"] is None]
        cells = [name, str(len(base)), f"{np.mean([r['support_vectors'] for r in base]):.0f}",
                 f"{100 * np.mean([r['greedy'] for r in base]):.1f}"]
        for k in budgets:
            at = [r for r in mine if r["budget"] == k]
            if len(at) != len(base):  # a split whose model had fewer support vectors
                cells.append("-")
                continue
            cells.append(" / ".join(f"{100 * np.mean([r[w] for r in at]):.1f}" for w in WAYS))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaigns", default=DEFAULT_CAMPAIGNS,
                    help=f"comma-separated, of {', '.join(SEARCH_CAMPAIGNS)}")
    ap.add_argument("--splits", type=int, default=2)
    ap.add_argument("--budgets", default="64,32,16,8")
    ap.add_argument("--part", choices=("curve", "target"), default="curve",
                    help="curve: error against the support vectors of the searched default; "
                    "target: the --target cortex-m4 model with and without --max-support "
                    "(--target-supports)")
    ap.add_argument("--target-supports", default="64,32")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin_selection_study"))
    ap.add_argument("--out", type=Path, default=None, help="JSON lines (default: in --cache)")
    args = ap.parse_args(argv)
    names = [c.strip() for c in args.campaigns.split(",") if c.strip()]
    unknown = [c for c in names if c not in SEARCH_CAMPAIGNS]
    if unknown:
        ap.error(f"--campaigns: unknown {unknown}; known: {', '.join(SEARCH_CAMPAIGNS)}")
    budgets = [int(b) for b in args.budgets.split(",")]
    out = args.out or args.cache / f"results_support_budget_{args.part}.jsonl"
    out.parent.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    if args.part == "target":
        supports = [int(b) for b in args.target_supports.split(",")]
        run, line, summary = (lambda n, k: target_unit(args.cache, n, k, supports, args.seed),
                              _target_line, target_table)
    else:
        run, line, summary = (lambda n, k: unit(args.cache, n, k, budgets, args.seed),
                              _curve_line, table)
    for name in names:
        for split in range(args.splits):
            got = run(name, split)
            with out.open("a") as f:
                for r in got:
                    f.write(json.dumps(r) + "\n")
            rows += got
            print(f"{name} split {split}: {line(got)}", flush=True)
    print(summary(rows))
    return 0


def _target_line(got: list[dict]) -> str:
    return ", ".join(f"{r['method']} " + ("-" if r["error"] is None else
                                         f"{100 * r['error']:.1f} % {r['recipe']} "
                                         f"{r['support_vectors']} SVs") for r in got)


def _curve_line(got: list[dict]) -> str:
    return f"({got[0]['recipe']}) " + ", ".join(
        f"{r['support_vectors']} SVs " + "/".join(f"{100 * r[w]:.1f}" for w in WAYS) + " %"
        for r in got)


if __name__ == "__main__":
    raise SystemExit(main())
