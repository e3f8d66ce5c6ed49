"""The figures of the host budget's count (eskin.learn.host_budget), from end-of-touch times.

For D in {20, 50, 100} and alpha in {1, Q/2, Q}, a 3-class one-vs-all tensor-SVM (C = 10,
sigma 0.5, amplitude factor 4, every negative) is trained on the patterns of the first 25 and
then the first 56 participants of a simulated campaign (150 and 336 distinct support vectors
on the built-in one) and exported as float32. Each is timed as ``bench_inference.py --model``
times a model: the StreamClassifier fed the recordings of the campaign's last 5 participants
back to back, the push that ends a touch (its window subsampled, the input's bases, the
overlaps with the stored bases, the machines), the median over the touches of ``--passes``
passes. Between two touches the stream and the rest of the host take the caches, so the
stored bases of a large model come from memory at each decision: these are the times the
count must predict, not those of one window repeated (printed beside them, "warm").

The 18 times are fitted together by least squares to the count's three terms: a cost per entry
of the input's pattern (rows x cols x D: its bases), per support vector, and per entry of a
support vector's stored bases (:func:`basis_entries`). Printed beside the count itself
(:func:`host_decision_us`) and each model's residual. The input's share, which those models'
support vectors dwarf, is measured apart: at each D a model trained on the first
FEW_PEOPLE participants (a few dozen support vectors), its time less its support vectors'
share by the fit, fitted to a fixed cost plus a cost per entry of the pattern.

Run:  ESKIN_BIN_DIR=build/dev PYTHONPATH=python python benchmarks/host_budget_fit.py \\
          --campaign /tmp/eskin_bench_peers/bench_peers_sim70.h5
(the 70-participant campaign of benchmarks/bench_peers.py; simulated data)
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
from bench_inference import PARTICIPANTS_TEST, touch_latencies

import eskin
from eskin.deploy.export import CompiledModel, model_to_bytes, spec_from_model
from eskin.learn.estimators import OneVsAllTouchClassifier, TensorSVC
from eskin.learn.host_budget import basis_entries, host_decision_us
from eskin.learn.kernel import resolve_alphas
from eskin.learn.models import TouchModel

PEOPLE = (25, 56)
FEW_PEOPLE = 3


def decision_us(camp, X: np.ndarray, y: np.ndarray, D: int, alpha, stream: np.ndarray,
                passes: int) -> tuple[float, float, int]:
    """(median end-of-touch us, median warm us, distinct support vectors)."""
    est = OneVsAllTouchClassifier(TensorSVC(C=10.0, sigma=0.5, alpha=alpha, amplitude=4.0))
    est.fit(X, y)
    model = TouchModel(classes=list(camp.modalities), estimator=est, machine="svm",
                       selection="fixed", D=D, window="energy", subsample="algorithm2",
                       sample_rate_hz=camp.sample_rate_hz, grid_shape=X.shape[1:3])
    cm = CompiledModel(model_to_bytes(spec_from_model(model), "float32"))
    t = touch_latencies(cm, stream, passes)
    return t["touch"], t["warm"], int(cm.n_support)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path, required=True)
    ap.add_argument("--passes", type=int, default=3, help="passes over the test stream")
    args = ap.parse_args()
    camp = eskin.load_campaign(args.campaign, in_memory=True)
    part = np.asarray(camp.participant)
    people = np.unique(part)
    held = np.flatnonzero(np.isin(part, people[-PARTICIPANTS_TEST:]))
    stream = np.ascontiguousarray(np.concatenate(list(np.asarray(camp.signals)[held]), axis=-1))
    rows = []
    for D in (20, 50, 100):
        for alpha in (1, "half", "full"):
            for n in PEOPLE:
                idx = np.flatnonzero(np.isin(part, people[:n]))
                X = eskin.preprocess(np.asarray(camp.signals)[idx], D,
                                     lengths=np.asarray(camp.lengths)[idx],
                                     sample_rate_hz=camp.sample_rate_hz)
                touch, warm, n_sv = decision_us(camp, X, np.asarray(camp.modality)[idx].astype(
                    np.int64), D, alpha, stream, args.passes)
                grid = X.shape[1:3]
                al = resolve_alphas((*grid, D), alpha)
                rows.append((grid[0] * grid[1] * D, n_sv, basis_entries(grid, D, al), touch))
                print(f"D = {D:3d}, alphas {al}, {n_sv} SVs: {touch:6.1f} us at the end of a "
                      f"touch (warm {warm:6.1f}); the count: "
                      f"{host_decision_us(grid, D, al, n_sv):6.1f} us", flush=True)
    size, n_sv, entries, touch = (np.array(c, float) for c in zip(*rows))
    A = np.c_[size, n_sv, n_sv * entries]
    (c_in, c_sv, c_entry), *_ = np.linalg.lstsq(A, touch, rcond=None)
    res = A @ [c_in, c_sv, c_entry] - touch
    print(f"least squares: {1e3 * c_in:.1f} ns per entry of the input's pattern + "
          f"{1e3 * c_sv:.0f} ns per support vector + {1e3 * c_entry:.3f} ns per entry of its "
          f"bases; residuals (us) {np.round(res, 1).tolist()}. Load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.", flush=True)
    few = []
    idx = np.flatnonzero(np.isin(part, people[:FEW_PEOPLE]))
    for D in (20, 50, 100):
        X = eskin.preprocess(np.asarray(camp.signals)[idx], D,
                             lengths=np.asarray(camp.lengths)[idx],
                             sample_rate_hz=camp.sample_rate_hz)
        touch, _, n_sv = decision_us(camp, X, np.asarray(camp.modality)[idx].astype(np.int64),
                                     D, "full", stream, args.passes)
        grid = X.shape[1:3]
        entries = basis_entries(grid, D, resolve_alphas((*grid, D), "full"))
        few.append((grid[0] * grid[1] * D, touch - n_sv * (c_sv + c_entry * entries)))
        print(f"D = {D:3d}, alpha Q, {n_sv} SVs: {touch:6.1f} us at the end of a touch, "
              f"{few[-1][1]:6.1f} us without its support vectors' share", flush=True)
    size, rest = (np.array(c, float) for c in zip(*few))
    (fixed, per_entry), *_ = np.linalg.lstsq(np.c_[np.ones_like(size), size], rest, rcond=None)
    print(f"the input's share: {fixed:.1f} us + {1e3 * per_entry:.1f} ns per entry of the "
          f"pattern. Load average {os.getloadavg()[0]:.1f}.")


if __name__ == "__main__":
    main()
