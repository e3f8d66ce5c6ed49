"""Per-pattern subspace bases (the first half of the tensor kernel) and the Gram matrix's split.

Workload: n = 180 random 4 x 4 x D patterns, alpha = (2, 2, 8), one thread.

* batch: ``_core.compute_pattern_bases`` on all 180 patterns (eight patterns per eigen-solver
  lane group), per pattern; baseline: numpy's batched ``np.linalg.svd`` of the three unfoldings
  of all patterns (LAPACK, one BLAS thread), per pattern.
* single: ``_core.BasisWorkspace.compute`` (the controller's heap-free path, one pattern at a
  time, Python call included); baseline: ``np.linalg.svd`` of one pattern's three unfoldings.
* for each instruction set the run-time dispatch may use (``ESKIN_KERNEL_ISA`` caps the tile
  kernels and the eigen-solver; the other helpers stay as the loader chose them).
* split of eskin's Gram matrix K(X, X): bases vs pairwise part (from precomputed bases).

Fastest of --repeats runs, eskin and numpy taking turns. Usage:
python benchmarks/bench_bases.py [--n 180] [--D 100] [--repeats 20]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from threadpoolctl import threadpool_limits

from eskin import _core

ALPHA = [2, 2, 8]


def unfoldings(X: np.ndarray) -> list[np.ndarray]:
    n = X.shape[0]
    return [np.moveaxis(X, z + 1, 1).reshape(n, X.shape[z + 1], -1) for z in range(X.ndim - 1)]


def best(fn, repeats: int) -> float:
    t = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        t = min(t, time.perf_counter() - t0)
    return t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--n", type=int, default=180)
    ap.add_argument("--D", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    rng = np.random.default_rng(args.D)
    X = rng.normal(size=(args.n, 4, 4, args.D))
    U = unfoldings(X)
    ws = _core.BasisWorkspace([4, 4, args.D], ALPHA)
    n_single = min(args.n, 60)

    def numpy_batch() -> None:
        for u in U:
            np.linalg.svd(u, full_matrices=False)

    def numpy_single() -> None:
        for i in range(n_single):
            for u in U:
                np.linalg.svd(u[i], full_matrices=False)

    def eskin_single() -> None:
        for i in range(n_single):
            ws.compute(X[i])

    print(
        f"bases of {args.n} random 4x4x{args.D} patterns, alpha={tuple(ALPHA)}, one thread, "
        f"load average {os.getloadavg()[0]:.1f}; fastest of {args.repeats} runs"
    )
    print(
        "| ISA | eskin batch (us/pattern) | numpy batched SVD | ratio | eskin single "
        "(us/pattern) | numpy SVD of one pattern | ratio |"
    )
    print("|---|---|---|---|---|---|---|")
    saved = os.environ.get("ESKIN_KERNEL_ISA")
    with threadpool_limits(limits=1):
        for isa in ("default", "avx2", "generic"):
            if isa == "default":
                os.environ.pop("ESKIN_KERNEL_ISA", None)
            else:
                os.environ["ESKIN_KERNEL_ISA"] = isa
            name = _core.tensor_kernel_isa()
            tb = tn = ts = tns = float("inf")
            for _ in range(args.repeats):  # taking turns
                tb = min(tb, best(lambda: _core.compute_pattern_bases(X, ALPHA, 1), 1))
                tn = min(tn, best(numpy_batch, 1))
                ts = min(ts, best(eskin_single, 1))
                tns = min(tns, best(numpy_single, 1))
            print(
                f"| {isa} ({name}) | {tb / args.n * 1e6:.1f} | {tn / args.n * 1e6:.1f} | "
                f"{tn / tb:.1f}x | {ts / n_single * 1e6:.1f} | {tns / n_single * 1e6:.1f} | "
                f"{tns / ts:.1f}x |"
            )
        if saved is None:
            os.environ.pop("ESKIN_KERNEL_ISA", None)
        else:
            os.environ["ESKIN_KERNEL_ISA"] = saved
        pb = _core.compute_pattern_bases(X, ALPHA, 1)
        t_bases = best(lambda: _core.compute_pattern_bases(X, ALPHA, 1), args.repeats)
        t_pairs = best(lambda: _core.tensor_kernel(pb, None, [1.0], 1), args.repeats)
    print()
    print(
        f"Gram matrix K(X, X), one thread ({_core.tensor_kernel_isa()}): bases "
        f"{t_bases * 1e3:.2f} ms + pairwise part {t_pairs * 1e3:.2f} ms = "
        f"{(t_bases + t_pairs) * 1e3:.2f} ms"
    )


if __name__ == "__main__":
    main()
