"""Footprint and speed of the deployed classifier (issue 5).

For D in {20, 50, 100}: a 3-class one-vs-all tensor-SVM trained on the paper's 180-pattern sets
(45 simulated participants, run 2; each machine: 90 patterns of its modality + 90 drawn from the
other two), hyperparameters fixed at the paper's Table 7 choice (sigma = 2^-1, C = 10,
alpha = Q/2: model selection is not what is measured here). Reported per D:

* model bytes (float32 .eskin file) against the bytes of its bases in float32, support vectors
  kept (unique, after deduplication across the three machines);
* per-decision latency, raw window (4 x 4 x 21000 int16) -> label, median over many windows:
  the C++ classifier (timed in C++ around each call), against two baselines measured in the same
  run: a numpy implementation of the same decision from the same stored bases (preprocessing
  through eskin.preprocess, bases by numpy SVD, distances by one batched matmul per mode), and
  the Python model itself (TouchModel: eskin.preprocess + estimator.decision_function);
* instructions per decision with valgrind --tool=callgrind (deterministic): eskin-classify on
  11 windows minus eskin-classify on 1 window, divided by 10 (model loading cancels out).

Run:  ESKIN_BIN_DIR=build/dev python benchmarks/bench_inference.py [--campaign sim.h5]
The data are simulated (eskin.simulate).
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import eskin
from eskin import _core
from eskin.estimators import OneVsAllTouchClassifier, TensorSVC
from eskin.export import CompiledModel, export_model
from eskin.models import TouchModel

PARTICIPANTS_TRAIN = 45
PARTICIPANTS_TEST = 5
SIGMA, C, ALPHA = 0.5, 10.0, "half"


def load_or_simulate(path: Path | None, tmp: Path):
    if path is not None and path.is_file():
        return eskin.load_campaign(path, in_memory=True)
    out = path or tmp / "bench_campaign.h5"
    t0 = time.perf_counter()
    eskin.simulate(out, participants=PARTICIPANTS_TRAIN + PARTICIPANTS_TEST, seed=2014, runs=(2,),
                   n_jobs=2)
    print(f"simulated {out} in {time.perf_counter() - t0:.0f} s")
    return eskin.load_campaign(out, in_memory=True)


def machine_sets(y: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
    """The paper's per-machine sets: all patterns of class k + as many from the others."""
    sets = []
    for k in range(3):
        pos = np.flatnonzero(y == k)
        neg = rng.choice(np.flatnonzero(y != k), size=len(pos), replace=False)
        sets.append(np.sort(np.concatenate([pos, neg])))
    return sets


def train(campaign, D: int, train_idx: np.ndarray) -> TouchModel:
    sig = np.asarray(campaign.signals)[train_idx]
    X = eskin.preprocess(sig, D, lengths=np.asarray(campaign.lengths)[train_idx],
                         sample_rate_hz=campaign.sample_rate_hz)
    y = np.asarray(campaign.modality)[train_idx].astype(np.int64)
    sets = machine_sets(y, np.random.default_rng(D))
    est = OneVsAllTouchClassifier(TensorSVC(C=C, sigma=SIGMA, alpha=ALPHA)).fit(
        X, y, machine_indices=sets)
    return TouchModel(
        classes=list(campaign.modalities), estimator=est, machine="svm", selection="fixed",
        D=D, window="energy", subsample="algorithm2", sample_rate_hz=campaign.sample_rate_hz,
        grid_shape=(int(X.shape[1]), int(X.shape[2])),
    )


class NumpyBaseline:
    """The same decision in numpy, from the same stored bases (read back from the C++ model)."""

    def __init__(self, cm: CompiledModel, model: TouchModel) -> None:
        self.D = cm.D
        self.rate = cm.sample_rate_hz
        self.machines = cm.machines
        from eskin.export import pattern_bases, spec_from_model

        spec = spec_from_model(model)
        table: dict[bytes, int] = {}
        unique = []
        for m in spec.machines:
            for x in m.support_vectors:
                if x.tobytes() not in table:
                    table[x.tobytes()] = len(unique)
                    unique.append(x)
        self.alphas = cm.alpha_store
        self.ranks, self.bases = pattern_bases(np.stack(unique), self.alphas)
        self.bases = [np.asarray(b, np.float32) for b in self.bases]

    def bases_of(self, X: np.ndarray):
        out, ranks = [], []
        for z in range(3):
            A = np.moveaxis(X, z, 0).reshape(X.shape[z], -1)
            _, s, vt = np.linalg.svd(A, full_matrices=False)
            r = int(np.sum(s**2 > max(1e-12, 16 * max(A.shape) * 2.0**-52) * s[0] ** 2)) if s[0] > 0 else 0
            V = vt[: self.alphas[z]].astype(np.float32)
            V[r:] = 0
            out.append(V)
            ranks.append(min(r, self.alphas[z]))
        return out, ranks

    def decide(self, rec: np.ndarray) -> int:
        X = eskin.preprocess(rec[None], self.D, sample_rate_hz=self.rate)[0]
        V, r = self.bases_of(X)
        d = np.zeros(len(self.ranks))
        for z in range(3):
            G = self.bases[z] @ V[z].T  # (n_sv, alpha, alpha)
            ov = np.einsum("ikl,ikl->i", G, G, dtype=np.float64)
            d += np.maximum(0.0, self.ranks[:, z] + r[z] - 2 * ov) / (2 * SIGMA**2)
        K = np.exp(-d)
        f = np.array([m["intercept"] + K[m["sv_index"]] @ np.asarray(m["coef"]) for m in self.machines])
        claims = f > 0
        return int(np.argmax(claims) if claims.sum() == 1 else np.argmax(f))


def median_us(fn, windows, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        for w in windows:
            t0 = time.perf_counter_ns()
            fn(w)
            times.append(time.perf_counter_ns() - t0)
    return float(np.median(times)) / 1e3


def callgrind_instructions(exe: str, model_path: Path, windows: np.ndarray, tmp: Path) -> float | None:
    valgrind = shutil.which("valgrind")
    if valgrind is None:
        return None
    counts = []
    for n in (1, 11):
        npy = tmp / f"cg_{n}.npy"
        np.save(npy, windows[:n])
        res = subprocess.run(
            [valgrind, "--tool=callgrind", "--callgrind-out-file=/dev/null", exe, str(model_path),
             str(npy)], capture_output=True, text=True)
        m = re.search(r"Collected\s*:\s*(\d+)", res.stderr)
        if res.returncode != 0 or m is None:
            print(res.stderr[-2000:])
            return None
        counts.append(int(m.group(1)))
    return (counts[1] - counts[0]) / 10


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path, default=None, help="reuse/keep the simulated campaign")
    ap.add_argument("--Ds", default="20,50,100")
    ap.add_argument("--repeats", type=int, default=20, help="passes over the test windows (C++)")
    args = ap.parse_args()
    from eskin._paths import find_executable

    exe = str(find_executable("eskin-classify"))
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        campaign = load_or_simulate(args.campaign, tmp)
        part = np.asarray(campaign.participant)
        people = np.unique(part)
        train_idx = np.flatnonzero(np.isin(part, people[:PARTICIPANTS_TRAIN]))
        test_idx = np.flatnonzero(~np.isin(part, people[:PARTICIPANTS_TRAIN]))
        sig = np.asarray(campaign.signals)
        windows = np.ascontiguousarray(sig[test_idx])
        print(f"{len(train_idx)} training recordings ({len(people[:PARTICIPANTS_TRAIN])} "
              f"participants), {len(windows)} test windows of {windows.shape[1:]} int16; "
              f"simulated data")
        print(f"overlap micro-kernel: {_core.model_overlap_kernel()}")
        rows = []
        for D in [int(v) for v in args.Ds.split(",")]:
            model = train(campaign, D, train_idx)
            path = export_model(model, tmp / f"model_D{D}.eskin")
            cm = CompiledModel(path)
            N = [4 * D, 4 * D, 16]
            bases32 = cm.n_support * sum(n * a for n, a in zip(N, cm.alpha_store)) * 4
            ns = cm._clf.time_classify(windows, args.repeats)
            cpp_us = float(np.median(ns)) / 1e3
            base = NumpyBaseline(cm, model)
            agree = np.mean([base.decide(w) == lab for w, lab in
                             zip(windows, cm.classify(windows).label_indices)])
            numpy_us = median_us(base.decide, windows, 2)
            py_us = median_us(lambda w: model.decision_function(
                eskin.preprocess(w[None], D, sample_rate_hz=campaign.sample_rate_hz)), windows[:10], 1)
            instr = callgrind_instructions(exe, path, windows, tmp)
            terms = sum(len(m["sv_index"]) for m in cm.machines)
            rows.append((D, cm.file_bytes, bases32, cm.n_support, terms, cm.alpha_store, cpp_us,
                         numpy_us, py_us, instr, agree))
        print()
        print("| D | model bytes | bases f32 bytes | file/bases | SVs kept (terms) | alpha_store | "
              "C++ us/decision | numpy us | ratio | Python model us | ratio | instructions/decision |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for (D, fb, b32, nsv, terms, ast, cpp, npy, py, instr, agree) in rows:
            print(f"| {D} | {fb} | {b32} | {fb / b32:.3f} | {nsv} ({terms}) | {ast} | {cpp:.1f} | "
                  f"{npy:.0f} | {npy / cpp:.1f}x | {py:.0f} | {py / cpp:.0f}x | "
                  f"{'n/a' if instr is None else f'{instr / 1e6:.2f} M'} |")
        print()
        print("numpy baseline agrees with C++ on "
              + ", ".join(f"D={r[0]}: {100 * r[-1]:.0f} %" for r in rows) + " of the windows")
        print("latency: median over windows; C++ timed in C++ around each classify() call; "
              "instructions: callgrind (same micro-kernel as timed)")


if __name__ == "__main__":
    main()
