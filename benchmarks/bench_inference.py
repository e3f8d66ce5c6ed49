"""Footprint and speed of the deployed classifier.

For D in {20, 50, 100}: a 3-class one-vs-all tensor-SVM trained on the paper's 180-pattern sets
(45 simulated participants, run 2; each machine: 90 patterns of its modality + 90 drawn from the
other two), hyperparameters fixed at the paper's Table 7 choice (sigma = 2^-1, C = 10,
alpha = Q/2: model selection is not what is measured here). Reported per D:

* model bytes (float32 .eskin file) against the bytes of its bases in float32, support vectors
  kept (unique, after deduplication across the three machines);
* per-decision latency, median over many windows, raw samples -> label: (a) at the end of a
  touch, the StreamClassifier push that completes it (subsample the window's raw samples to D,
  bases, machines; one long-lived classifier fed the test recordings back to back), (b) a whole 7-s recording (4 x 4 x 21000 int16) through Classifier.classify
  (energy detector over every sample, then the decision); C++ timed in C++ around each call,
  against baselines measured in the same run: a numpy implementation of the same decision from
  the same stored bases (bases by numpy SVD, one batched matmul per mode), and the Python model
  (eskin.subsample / eskin.preprocess + TouchModel.decision_function);
* instructions per decision with valgrind --tool=callgrind (deterministic), counted inside
  Classifier::classify_tensor (a) and Classifier::classify (b) only.

Run:  ESKIN_BIN_DIR=build/dev python benchmarks/bench_inference.py [--campaign sim.h5]
The data are simulated (eskin.simulate).

With ``--model M.eskin`` (e.g. what ``eskin train`` wrote, exported by ``eskin export``) it
measures that model instead, on the recordings of ``--campaign`` (those of its last
participants, PARTICIPANTS_TEST of them): the same end-of-touch and warm latencies, its
support vectors, D and alphas.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import eskin
from eskin import _core
from eskin.learn.estimators import OneVsAllTouchClassifier, TensorSVC
from eskin.deploy.export import CompiledModel, export_model
from eskin.learn.models import TouchModel

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
    """The same decision in numpy, from the same stored bases (those the C++ model holds)."""

    def __init__(self, cm: CompiledModel, model: TouchModel) -> None:
        from eskin.deploy.export import pattern_bases, spec_from_model

        self.D = cm.D
        self.machines = cm.machines
        spec = spec_from_model(model)
        table: dict[bytes, int] = {}
        unique = []
        for m in spec.machines:
            for x in m.support_vectors:
                if x.tobytes() not in table:
                    table[x.tobytes()] = len(unique)
                    unique.append(x)
        self.alphas = cm.alpha_store
        ranks, bases = pattern_bases(np.stack(unique), self.alphas)
        self.ranks = np.asarray(ranks, np.float64)
        self.bases = [np.asarray(b, np.float32) for b in bases]  # (n_sv, alpha, N)

    def bases_of(self, X: np.ndarray):
        out, ranks = [], []
        for z in range(3):
            A = np.moveaxis(X, z, 0).reshape(X.shape[z], -1)
            _, s, vt = np.linalg.svd(A, full_matrices=False)
            tau = max(1e-12, 16 * max(A.shape) * 2.0**-52)
            r = int(np.sum(s**2 > tau * s[0] ** 2)) if s[0] > 0 else 0
            V = vt[: self.alphas[z]].astype(np.float32)
            V[r:] = 0
            out.append(V)
            ranks.append(min(r, self.alphas[z]))
        return out, ranks

    def decide_tensor(self, X: np.ndarray) -> int:
        V, r = self.bases_of(X)
        d = np.zeros(len(self.ranks))
        for z in range(3):
            G = self.bases[z] @ V[z].T  # (n_sv, alpha, alpha): one batched matmul per mode
            ov = np.einsum("ikl,ikl->i", G, G, dtype=np.float64)
            d += np.maximum(0.0, self.ranks[:, z] + r[z] - 2 * ov) / (2 * SIGMA**2)
        K = np.exp(-d)
        f = np.array([m["intercept"] + K[m["sv_index"]] @ np.asarray(m["coef"])
                      for m in self.machines])
        claims = f > 0
        return int(np.argmax(claims) if claims.sum() == 1 else np.argmax(f))

    def decide_window(self, w: np.ndarray) -> int:
        """Raw touch window (rows, cols, S) -> label, as at the end of a touch."""
        return self.decide_tensor(eskin.subsample(w, self.D))


def median_us(fn, windows, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        for w in windows:
            t0 = time.perf_counter_ns()
            fn(w)
            times.append(time.perf_counter_ns() - t0)
    return float(np.median(times)) / 1e3


def callgrind_instructions(exe: str, model_path: Path, windows: np.ndarray, tmp: Path,
                           function: str) -> float | None:
    """Instructions per call of `function` (callgrind --toggle-collect), eskin-classify on
    10 recordings."""
    valgrind = shutil.which("valgrind")
    if valgrind is None:
        return None
    npy = tmp / "cg.npy"
    np.save(npy, windows[:10])
    res = subprocess.run(
        [valgrind, "--tool=callgrind", "--callgrind-out-file=/dev/null",
         f"--toggle-collect={function}", exe, str(model_path), str(npy)],
        capture_output=True, text=True)
    m = re.search(r"Collected\s*:\s*(\d+)", res.stderr)
    if res.returncode != 0 or m is None:
        print(res.stderr[-2000:])
        return None
    if int(m.group(1)) == 0:  # no symbol matched: a stripped binary (e.g. the pip-installed one)
        print(f"callgrind: no instructions under {function!r} in {exe} (stripped?); "
              "set ESKIN_BIN_DIR to a CMake build (make bench does)")
        return None
    return int(m.group(1)) / min(10, len(windows))


def touch_latencies(cm: CompiledModel, stream: np.ndarray, repeats: int) -> dict:
    """Median end-of-touch us ("touch"), median warm us ("warm"), the touch windows and their
    labels (of the first pass) and the decisions timed ("n") of a compiled model fed ``stream``
    (rows, cols, T) back to back ``repeats`` times."""
    touch_ns, windows, labels = [], [], []
    for rep in range(repeats):
        for e in cm.stream(stream, timed=True):
            if e["status_name"] == "decision":
                touch_ns.append(e["push_ns"])
                if rep == 0:
                    s0, s1 = e["window"]
                    windows.append(np.ascontiguousarray(stream[:, :, s0:s1]))
                    labels.append(cm.class_names.index(e["label"]))
    warm_us = float(np.median(cm._clf.time_classify_tensors(
        eskin.subsample(windows[0][None], cm.D), 200))) / 1e3
    return {"touch": float(np.median(touch_ns)) / 1e3, "warm": warm_us, "windows": windows,
            "labels": labels, "n": len(touch_ns)}


def measure_model(path: Path, campaign, repeats: int) -> None:
    """The end-of-touch and warm latencies of the model file ``path`` on the recordings of
    the campaign's last PARTICIPANTS_TEST participants."""
    cm = CompiledModel(path)
    part = np.asarray(campaign.participant)
    people = np.unique(part)
    idx = np.flatnonzero(np.isin(part, people[-PARTICIPANTS_TEST:]))
    stream = np.ascontiguousarray(np.concatenate(list(np.asarray(campaign.signals)[idx]),
                                                 axis=-1))
    t = touch_latencies(cm, stream, repeats)
    touch, warm, n = t["touch"], t["warm"], t["n"]
    print(f"{path}: D = {cm.D}, alphas {cm.alpha_store}, {cm.n_support} support vectors, "
          f"{cm.file_bytes} bytes")
    print(f"end of touch -> label (C++ stream, median of {n} decisions): {touch:.1f} us; warm "
          f"(one window 200 times): {warm:.1f} us. Load average: {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores.")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path, default=None, help="reuse/keep the simulated campaign")
    ap.add_argument("--Ds", default="20,50,100")
    ap.add_argument("--repeats", type=int, default=5, help="passes over the test windows (C++)")
    ap.add_argument("--model", type=Path, default=None,
                    help="measure this .eskin model on the campaign's recordings instead")
    args = ap.parse_args()
    from eskin._paths import find_executable

    exe = str(find_executable("eskin-classify"))
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        campaign = load_or_simulate(args.campaign, tmp)
        if args.model is not None:
            measure_model(args.model, campaign, args.repeats)
            return
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
        stream = np.ascontiguousarray(np.concatenate(list(windows), axis=-1))
        rows = []
        for D in [int(v) for v in args.Ds.split(",")]:
            model = train(campaign, D, train_idx)
            path = export_model(model, tmp / f"model_D{D}.eskin")
            cm = CompiledModel(path)
            N = [4 * D, 4 * D, 16]
            bases32 = cm.n_support * sum(n * a for n, a in zip(N, cm.alpha_store)) * 4
            terms = sum(len(m["sv_index"]) for m in cm.machines)
            base = NumpyBaseline(cm, model)
            # end of touch: the stream classifier's push that decides (window -> label)
            # one long-lived stream classifier, as on the controller: the test recordings
            # back to back
            t = touch_latencies(cm, stream, args.repeats)
            touch_us, warm_us, touch_windows, n_touch = t["touch"], t["warm"], t["windows"], t["n"]
            agree = [base.decide_window(w) == lab for w, lab in zip(touch_windows, t["labels"])]
            numpy_touch_us = median_us(base.decide_window, touch_windows, 2)
            py_touch_us = median_us(
                lambda w: model.decision_function(eskin.subsample(w[None], D)), touch_windows, 1)
            # a whole 7-s recording -> label (the detector runs over all 21000 samples)
            rec_us = float(np.median(cm._clf.time_classify(windows, 3))) / 1e3
            py_rec_us = median_us(lambda w: model.decision_function(eskin.preprocess(
                w[None], D, sample_rate_hz=campaign.sample_rate_hz)), windows[:10], 1)
            instr_touch = callgrind_instructions(exe, path, windows, tmp,
                                                 "eskin::Classifier::classify_tensor*")
            instr_rec = callgrind_instructions(exe, path, windows, tmp,
                                               "eskin::Classifier::classify(*")
            rows.append(dict(D=D, bytes=cm.file_bytes, bases32=bases32, nsv=cm.n_support,
                             terms=terms, alpha=cm.alpha_store, touch=touch_us,
                             np_touch=numpy_touch_us, warm=warm_us, py_touch=py_touch_us, rec=rec_us,
                             py_rec=py_rec_us, i_touch=instr_touch, i_rec=instr_rec,
                             agree=float(np.mean(agree)), n=n_touch))
        print()
        print("Footprint (float32 .eskin file):")
        print("| D | model bytes | bases in float32 | file / bases | SVs kept (machine terms) "
              "| alpha_store |")
        print("|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['D']} | {r['bytes']} | {r['bases32']} | {r['bytes'] / r['bases32']:.3f} | "
                  f"{r['nsv']} ({r['terms']}) | {r['alpha']} |")
        print()
        print("Latency per decision, median (C++ timed in C++; baselines in the same run):")
        print("| D | end of touch -> label, C++ us | (warm) | numpy us | ratio | Python model us "
              "| ratio | instructions | 7-s recording -> label, C++ us | Python model us | ratio "
              "| instructions |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            def ins(v):
                return "n/a" if v is None else f"{v / 1e6:.2f} M"
            print(f"| {r['D']} | {r['touch']:.1f} | {r['warm']:.1f} | {r['np_touch']:.0f} | "
                  f"{r['np_touch'] / r['touch']:.0f}x | {r['py_touch']:.0f} | "
                  f"{r['py_touch'] / r['touch']:.0f}x | {ins(r['i_touch'])} | {r['rec']:.0f} | "
                  f"{r['py_rec']:.0f} | {r['py_rec'] / r['rec']:.1f}x | {ins(r['i_rec'])} |")
        print()
        print("end of touch: the StreamClassifier push that completes a touch (subsampling of the "
              f"window, bases, machines), one classifier fed the test recordings back to back, "
              f"{rows[0]['n']} decisions per D; numpy: the same decision "
              "from the same stored bases (eskin.subsample + numpy SVD + batched matmul); "
              "Python model: eskin.subsample + TouchModel.decision_function. 7-s recording: "
              "Classifier.classify on the raw int16 recording (energy detector over all samples, "
              "then the decision) vs eskin.preprocess + TouchModel.decision_function. "
              "Instructions: callgrind on eskin-classify, per call of classify_tensor / classify.")
        print("(warm): the same decision repeated 200 times on one window (caches warm). "
              f"Load average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.")
        print("numpy baseline labels equal to C++: "
              + ", ".join(f"D={r['D']}: {100 * r['agree']:.0f} %" for r in rows))


if __name__ == "__main__":
    main()
