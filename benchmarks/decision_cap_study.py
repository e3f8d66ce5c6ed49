"""What the host decision budget of `eskin train` costs in accuracy, over several group splits.

The built-in simulator's 70-participant campaign (``bench_peers.py``'s ``sim70``, cached in
``--cache``; ``--campaign`` takes its other campaigns: another grid, rate or size), split
several times into training and held-out participants (56 and 14 for ``sim70``; a permutation
of the participants seeded ``[seed, 22]``, as ``bench_peers.py`` does with its one seed 3). For
each split and each cap of ``--decision-us`` (``eskin.train_model(decision_us=...)``, the
default recipe search under that budget): the held-out accuracy, the support
vectors and D of the model, and its decision time on this host at the end of a touch (the
float32 ``.eskin`` in the compiled ``StreamClassifier``, the held-out recordings back to back,
median over the decisions of ``--passes`` passes, as ``bench_inference.py --model`` measures)
and warm (one window repeated).

Printed per split and cap, then per cap the mean accuracy with its standard deviation over
the splits and its difference from the first cap's split by split (paired; by default the first is
no host budget at all, as `eskin train` was before it had one), and the median
decision times. The data are SIMULATED.

    ESKIN_BIN_DIR=build/cpp PYTHONPATH=python python benchmarks/decision_cap_study.py \\
        [--seeds 3,4,5,6,7] [--caps 180,120,80,60]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_inference import touch_latencies  # noqa: E402
from bench_peers import CAMPAIGNS, _split, _truth, campaign  # noqa: E402


def one(train, test, cap: float | str | None, passes: int, tmp: Path, window: str) -> dict:
    from eskin.deploy.export import CompiledModel, export_model
    from eskin.learn.training import train_model

    model = train_model(train, window=window, n_jobs=1, decision_us=cap)
    X = model.preprocess(test)
    truth = _truth(test, model.classes)
    acc = float(np.mean(model.predict_indices(X)[0] == truth))
    cm = CompiledModel(export_model(model, tmp / f"cap{cap}.eskin"))
    stream = np.ascontiguousarray(np.concatenate(list(np.asarray(test.signals)), axis=-1))
    try:
        t = touch_latencies(cm, stream, passes)
    except IndexError:  # no touch detected in the stream (a pre-segmented campaign)
        t = {"touch": float("nan"), "warm": float("nan")}
    return {"accuracy": acc, "n_support": int(cm.n_support), "D": int(cm.D),
            "touch_us": t["touch"], "warm_us": t["warm"], "right": int(round(acc * len(truth))),
            "n": len(truth)}


def label(cap: float | str | None) -> str:
    if cap is None:
        return "no host budget"
    return "the default budget (auto)" if cap == "auto" else f"--decision-us {cap:g}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin_bench_peers"))
    ap.add_argument("--campaign", default="sim70", choices=sorted(CAMPAIGNS),
                    help="one of bench_peers.py's simulated campaigns")
    ap.add_argument("--seeds", default="3,4,5,6,7")
    ap.add_argument("--caps", default="none,180,120,80,60,auto", help="--decision-us values "
                    "('none': no host budget, the search before it had one; 'auto': eskin train's "
                    "default); the first is the reference")
    ap.add_argument("--passes", type=int, default=3)
    args = ap.parse_args(argv)
    import eskin

    seeds = [int(s) for s in args.seeds.split(",")]
    caps = [None if c == "none" else c if c == "auto" else float(c) for c in args.caps.split(",")]
    _, n_train, _, window = CAMPAIGNS[args.campaign]
    camp = eskin.load_campaign(campaign(args.cache, args.campaign), in_memory=True)
    res: dict[float | str | None, list[dict]] = {c: [] for c in caps}
    with tempfile.TemporaryDirectory() as tmpdir:
        for seed in seeds:
            train, test = _split(camp, n_train, seed)
            for cap in caps:
                r = one(train, test, cap, args.passes, Path(tmpdir), window)
                res[cap].append(r)
                print(f"split {seed}, {label(cap)}: {100 * r['accuracy']:.1f} % "
                      f"({r['right']}/{r['n']}), D {r['D']}, {r['n_support']} support vectors, "
                      f"end of touch {r['touch_us']:.0f} us, warm {r['warm_us']:.0f} us "
                      f"(load {os.getloadavg()[0]:.1f})", flush=True)
    ref = np.array([r["accuracy"] for r in res[caps[0]]])
    print(f"\nover {len(seeds)} splits (seeds {args.seeds}), SIMULATED campaign {args.campaign} "
          f"({n_train} training participants per split):")
    for cap in caps:
        acc = np.array([r["accuracy"] for r in res[cap]])
        d = 100 * (acc - ref)
        touch = [r["touch_us"] for r in res[cap]]
        warm = [r["warm_us"] for r in res[cap]]
        sd = 100 * acc.std(ddof=1) if len(acc) > 1 else 0.0
        per = ", ".join(f"{100 * a:.1f}" for a in acc)
        diff = ", ".join(f"{v:+.1f}" for v in d)
        times = ", ".join(f"{v:.0f}" for v in touch)
        print(f"{label(cap)}: accuracy {100 * acc.mean():.1f} % +- {sd:.1f} (per split "
              f"{per}); minus the first per split {diff}, mean {d.mean():+.1f} points; end of "
              f"touch median {np.median(touch):.0f} us (per split {times}), warm "
              f"{np.median(warm):.0f} us")

if __name__ == "__main__":
    main()
