"""One Maximal Discrepancy search (n = 180 patterns 4x4x100, 135 configurations) vs. a
straightforward implementation of Algorithm 1, measured in the same run.

eskin.selection.MaximalDiscrepancySearch: per-mode distances once per alpha, reused for every
sigma; kernel k-means once per (sigma, alpha); RLS through one eigendecomposition per
(sigma, alpha) shared by every lambda, every lambda_hat step and every random labelling; the SVM
on libsvm with the precomputed kernel and a guessed-then-verified lambda_hat loop.

Straightforward: for every configuration, the kernel recomputed (eskin.tensor_kernel, the fast
C++ kernel), kernel k-means recomputed, every training a fresh solve (RLS: np.linalg.solve of
(K + lambda I) per labelling and per lambda_hat step; SVM: sklearn SVC(kernel="precomputed") per
fit), the lambda_hat loop run step by step as printed. It is run on every STRIDE-th configuration
and extrapolated to the 135 (said in the output); on that subset it must give the same v and chi
as the fast search (same seeds), which the script checks.

Data: a campaign file (--campaign, preprocessed with eskin.preprocess at D = 100, the first two
classes, 180 recordings) or, by default, 180 random structured patterns (two classes of noisy
travelling waves). Usage:

    python benchmarks/bench_selection.py [--campaign FILE] [--stride 5] [--n-jobs 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from sklearn.svm import SVC
from threadpoolctl import threadpool_limits

import eskin
from eskin.learn.estimators import TensorRLS, TensorSVC, kernel_kmeans
from eskin.learn.selection import (
    _KEY_KMEANS,
    PAPER_GRID,
    MaximalDiscrepancySearch,
    _blocks,
    _configurations,
    _random_labellings,
    _rng,
)

N_LABELINGS = 10
EPS = 2.0
MAX_STEPS = 30


def synthetic(n=180, shape=(4, 4, 100), seed=0, noise=3.0):
    rng = np.random.default_rng(seed)
    y = np.repeat([0, 1], n // 2)
    t = np.linspace(0, 1, shape[2])
    X = noise * rng.normal(size=(n, *shape))
    for i in range(n):
        amp, ph = 0.5 + rng.random(), rng.random()
        if y[i]:
            X[i] += amp * np.sin(
                2 * np.pi * (3 * t[None, None, :] + ph + 0.25 * np.arange(4)[:, None, None])
            )
        else:
            X[i] += amp * np.cos(2 * np.pi * (3 * t[None, None, :] + ph)) * np.arange(1, 5)[
                None, :, None
            ]
    return X, y


def from_campaign(path, n=180, seed=0):
    campaign = eskin.load_campaign(path)
    classes = np.asarray(campaign.modality)
    keep = np.flatnonzero(classes <= 1)
    rng = np.random.default_rng(seed)
    keep = np.sort(rng.choice(keep, size=min(n, keep.size), replace=False))
    signals = np.stack([campaign.recording(i) for i in keep])
    lengths = np.asarray(campaign.lengths)[keep]
    X = eskin.preprocess(signals, D=100, lengths=lengths, sample_rate_hz=campaign.sample_rate_hz)
    return X, classes[keep]


def naive_md(kind, X, y, configs, block_of, seed):
    """Algorithm 1 as printed, everything recomputed per configuration."""
    y_pm = np.where(y == np.unique(y)[1], 1.0, -1.0)
    n = y_pm.size
    out = []

    for cfg in configs:
        K = eskin.tensor_kernel(X, sigma=cfg.sigmas, alpha=cfg.alphas)
        labels, _, _ = kernel_kmeans(K, 2, 10, 100, _rng(seed, _KEY_KMEANS, block_of[cfg.index]))
        y_cl = np.where(labels == 0, 1.0, -1.0)

        def train(lam, target):
            if kind == "rls":
                beta = np.linalg.solve(K + lam * np.eye(n), target)
                return beta, 0.0
            svc = SVC(kernel="precomputed", C=1.0 / lam).fit(K, target)
            beta = np.zeros(n)
            beta[svc.support_] = svc.dual_coef_[0]
            return beta, float(svc.intercept_[0])

        def error(beta, b, target):
            return float(np.mean(np.where(K @ beta + b > 0, 1.0, -1.0) != target))

        beta_rkm, b = train(cfg.lam, y_pm)
        v = error(beta_rkm, b, y_pm)
        beta_p, _ = train(cfg.lam, y_cl)
        beta_m, _ = train(cfg.lam, -y_cl)
        ref = beta_p if np.linalg.norm(beta_p - beta_rkm) <= np.linalg.norm(beta_m - beta_rkm) \
            else beta_m
        gamma0 = ref @ K @ ref
        Ystar = _random_labellings(y_pm, N_LABELINGS, seed, cfg.index)
        errs = []
        for j in range(N_LABELINGS):
            lam_hat = cfg.lam
            for _ in range(MAX_STEPS + 1):
                beta, b = train(lam_hat, Ystar[:, j])
                if beta @ K @ beta <= gamma0:
                    break
                lam_hat *= EPS
            errs.append(error(beta, b, Ystar[:, j]))
        out.append((v, 1.0 - 2.0 * np.mean(errs)))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--campaign", help="campaign file (default: synthetic patterns)")
    ap.add_argument("--stride", type=int, default=5, help="baseline on every k-th configuration")
    ap.add_argument("--n-jobs", type=int, default=2)
    args = ap.parse_args()

    X, y = from_campaign(args.campaign) if args.campaign else synthetic()
    print(f"data: {'campaign ' + args.campaign if args.campaign else 'synthetic'}; "
          f"X {X.shape}, 135 configurations (lambda 5 x sigma 9 x alpha 3), "
          f"N = {N_LABELINGS} labellings, eps = {EPS}")
    rows = []
    for est in (TensorRLS(), TensorSVC()):
        name = type(est).__name__
        timings = {}
        # the n_jobs > 1 run is done twice, the second on joblib's warm worker pool
        for n_jobs in (1, args.n_jobs, args.n_jobs):
            search = MaximalDiscrepancySearch(
                est, PAPER_GRID, n_labelings=N_LABELINGS, eps=EPS, max_lambda_steps=MAX_STEPS,
                n_jobs=n_jobs, random_state=0, refit=False,
            )
            t0, c0 = time.perf_counter(), time.process_time()
            search.fit(X, y)
            timings[n_jobs] = time.perf_counter() - t0
            if n_jobs == 1:
                cpu = time.process_time() - c0
        kind, configs = _configurations(est, PAPER_GRID, X.shape[1:])
        block_of = {c.index: b for b, (_, cfgs) in enumerate(_blocks(configs)) for c in cfgs}
        subset = configs[:: args.stride]
        t0 = time.perf_counter()
        with threadpool_limits(limits=1):  # like eskin's blocks: no BLAS oversubscription
            naive = naive_md(kind, X, y, subset, block_of, search.random_state_)
        t_naive = (time.perf_counter() - t0) * len(configs) / len(subset)
        r = search.cv_results_
        same = all(
            r["train_error"][c.index] == v and abs(r["chi"][c.index] - chi) < 1e-12
            for c, (v, chi) in zip(subset, naive)
        )
        rows.append((name, timings[1], cpu, timings[args.n_jobs], t_naive, len(subset), same))

    print(f"\n| machine | eskin, 1 job: wall (CPU) s | eskin, {args.n_jobs} jobs, warm pool (s) "
          "| straightforward (s) | speed-up (1 job, wall) | same v, chi |")
    print("| --- | ---: | ---: | ---: | ---: | --- |")
    for name, t1, cpu, tj, tn, k, same in rows:
        print(f"| {name} | {t1:.2f} ({cpu:.2f}) | {tj:.2f} | {tn:.1f} (extrapolated from "
              f"{k}/135) | {tn / t1:.0f}x | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main()
