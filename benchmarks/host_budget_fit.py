"""The figures of the host budget's count (eskin.learn.host_budget), from decision times.

For D in {20, 50, 100} and alpha in {1, Q/2, Q}, a 3-class one-vs-all tensor-SVM (C = 10,
sigma 0.5, amplitude factor 4, every negative) is trained on the patterns of the first 25 and
then the first 56 participants of a simulated campaign (150 and 336 distinct support vectors
on the built-in one), exported as float32 and timed warm (``time_classify_tensors``, 40
patterns, 15 passes; the 10th percentile, the least disturbed by other processes). The time per
support vector is the slope between the two models; it is fitted by least squares to a cost per
support vector plus a cost per entry of its stored bases (:func:`basis_entries`). Printed
beside the count itself (:func:`host_decision_us`).

Run:  ESKIN_BIN_DIR=build/dev PYTHONPATH=python python benchmarks/host_budget_fit.py \\
          --campaign /tmp/eskin_bench_peers/bench_peers_sim70.h5
(the 70-participant campaign of benchmarks/bench_peers.py; simulated data)
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

import eskin
from eskin.deploy.export import CompiledModel, model_to_bytes, spec_from_model
from eskin.learn.estimators import OneVsAllTouchClassifier, TensorSVC
from eskin.learn.host_budget import basis_entries, host_decision_us
from eskin.learn.kernel import resolve_alphas
from eskin.learn.models import TouchModel

PEOPLE = (25, 56)


def warm_us(camp, X: np.ndarray, y: np.ndarray, D: int, alpha) -> tuple[float, int]:
    """(10th percentile of the warm decision times in us, distinct support vectors)."""
    est = OneVsAllTouchClassifier(TensorSVC(C=10.0, sigma=0.5, alpha=alpha, amplitude=4.0))
    est.fit(X, y)
    model = TouchModel(classes=list(camp.modalities), estimator=est, machine="svm",
                       selection="fixed", D=D, window="energy", subsample="algorithm2",
                       sample_rate_hz=camp.sample_rate_hz, grid_shape=X.shape[1:3])
    cm = CompiledModel(model_to_bytes(spec_from_model(model), "float32"))
    t = np.concatenate([np.ravel(cm._clf.time_classify_tensors(X[:40], 5)) for _ in range(3)])
    return float(np.percentile(t, 10)) / 1e3, int(cm.n_support)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path, required=True)
    args = ap.parse_args()
    camp = eskin.load_campaign(args.campaign, in_memory=True)
    part = np.asarray(camp.participant)
    people = np.unique(part)
    rows = []
    for D in (20, 50, 100):
        for alpha in (1, "half", "full"):
            times = []
            for n in PEOPLE:
                idx = np.flatnonzero(np.isin(part, people[:n]))
                X = eskin.preprocess(np.asarray(camp.signals)[idx], D,
                                     lengths=np.asarray(camp.lengths)[idx],
                                     sample_rate_hz=camp.sample_rate_hz)
                times.append(warm_us(camp, X, np.asarray(camp.modality)[idx].astype(np.int64),
                                     D, alpha))
            (t0, n0), (t1, n1) = times
            grid = X.shape[1:3]
            al = resolve_alphas((*grid, D), alpha)
            rows.append((D, al, (t1 - t0) / (n1 - n0), basis_entries(grid, D, al)))
            print(f"D = {D:3d}, alphas {al}: {n0} SVs {t0:6.1f} us, {n1} SVs {t1:6.1f} us; "
                  f"{1e3 * rows[-1][2]:6.0f} ns per SV; the count: "
                  f"{host_decision_us(grid, D, al, n1):6.1f} us", flush=True)
    A = np.array([[1.0, r[3]] for r in rows])
    slope = np.array([r[2] for r in rows])
    (per_sv, per_entry), *_ = np.linalg.lstsq(A, slope, rcond=None)
    print(f"least squares: {1e3 * per_sv:.0f} ns per support vector + {1e3 * per_entry:.3f} ns "
          f"per entry of its bases; largest residual "
          f"{1e3 * np.max(np.abs(A @ [per_sv, per_entry] - slope)):.0f} ns per SV. "
          f"Load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.")


if __name__ == "__main__":
    main()
