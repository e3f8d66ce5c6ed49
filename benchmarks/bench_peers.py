"""eskin's training beside its peers, in one run on the same group-disjoint splits.

For each SIMULATED campaign (``eskin.simulate``, run 2) the participants are split once
(seeded) into training and held-out people, and each method is trained on the training
people's recordings and scored on the held-out people's:

* ``eskin``: ``eskin.train_model`` with its defaults (the recipe search; the model bounded by
  the host decision budget), and ``eskin, no host budget`` (``decision_us=None``);
* ``eskin (baseline)``: the same default of another source tree (``--baseline-src``, e.g. the
  ``python`` folder of an earlier commit, run with this build's compiled core): the ratio
  against it is measured in the same run;
* ``minirocket+ridge``: MiniRocket features (aeon) and ``RidgeClassifierCV``
  (``eskin.learn.baselines.minirocket``) on the patterns eskin's default preprocessing makes
  (energy window, or none for pre-segmented campaigns, D = 100, Algorithm 2); numba compiles
  its kernels on a tiny input before the clock starts;
* ``rbf-svc grid``: an RBF-SVM on the flattened standardised patterns, C and gamma by inner
  grouped CV (``eskin.learn.baselines.vector_svm``).

Each method runs in a fresh process (spawned), which reports its own process CPU time
(``time.process_time``: every thread of the process; preprocessing included, the imports of
the method's modules not) and its peak
resident set (``ru_maxrss``, interpreter and imports included), so that one method's memory
does not hide another's. For eskin's models also the distinct support vectors, D and the
decision time of the compiled classifier on this host (float32 ``.eskin``,
``CompiledModel.classify_tensors`` over the held-out patterns, the fastest of 5 passes, per
decision).

Usage (ESKIN_BIN_DIR / PYTHONPATH as for the other benchmarks):

    python benchmarks/bench_peers.py [--campaigns sim70,sim10,strip-1x4-100Hz,grid-8x8-1kHz]
        [--baseline-src /tmp/eskin-base/python] [--methods eskin,minirocket,rbf]

MiniRocket needs aeon (``pip install 'eskin[minirocket]'``). aeon pins an older numpy than
eskin's environment may hold, so the script can run from an environment of its own, with this
tree's sources and compiled core on PYTHONPATH (eskin's dependencies and aeon in it, their
bytecode compiled once, as pip does: without it every process compiles SciPy and
scikit-learn again)::

    uv venv /tmp/eskin-bench --python .venv/bin/python
    uv pip install --python /tmp/eskin-bench/bin/python 'aeon>=1.0' numpy scipy scikit-learn \
        h5py joblib matplotlib typer rich npTDMS aiohttp
    /tmp/eskin-bench/bin/python -m compileall -q /tmp/eskin-bench/lib
    PYTHONPATH=python ESKIN_BIN_DIR=build/dev /tmp/eskin-bench/bin/python \
        benchmarks/bench_peers.py --campaigns sim70,sim10 --methods eskin,minirocket \
        --baseline-src /tmp/eskin-base/python

A ``--baseline-src`` tree (``git archive COMMIT python | tar -x -C /tmp/eskin-base``) needs
this build's compiled core copied into its ``eskin`` folder.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import multiprocessing as mp
import resource
import sys
import time
from pathlib import Path

import numpy as np

#: name -> (participants, training participants, SimulatorConfig overrides, window)
CAMPAIGNS = {
    "sim70": (70, 56, {}, "energy"),
    "sim10": (10, 8, {}, "energy"),
    "strip-1x4-100Hz": (
        30, 24,
        {"rows": 1, "cols": 4, "sample_rate_hz": 100.0, "bpf_lowpass_hz": 45.0,
         "brush_band_hz": (15.0, 45.0), "duration_s": 3.0, "onset_min_s": 0.1,
         "onset_max_s": 0.6, "finger_speed_mm_s": 120.0, "brush_speed_mm_s": 200.0,
         "washer_speed_mm_s": 40.0},
        "none"),
    "grid-8x8-1kHz": (
        30, 24,
        {"rows": 8, "cols": 8, "pitch_mm": 5.0, "electrode_mm": 4.0, "sample_rate_hz": 1000.0,
         "bpf_lowpass_hz": 450.0, "brush_band_hz": (15.0, 450.0)},
        "energy"),
}
SEED = 3


def campaign(cache: Path, name: str) -> Path:
    import eskin

    people, _, overrides, _ = CAMPAIGNS[name]
    path = cache / f"bench_peers_{name}.h5"
    if not path.exists():
        cache.mkdir(parents=True, exist_ok=True)
        cfg = dataclasses.replace(eskin.SimulatorConfig(), **overrides)
        tmp = path.with_suffix(".part.h5")
        eskin.simulate(tmp, participants=people, seed=SEED, runs=(2,), config=cfg,
                       overwrite=True)
        tmp.rename(path)
    return path


def _split(camp, n_train: int, seed: int = SEED):
    """(training campaign, held-out campaign): the first ``n_train`` participants of a
    permutation seeded ``[seed, 22]`` train."""
    part = np.asarray(camp.participant)
    ids = np.random.default_rng([seed, 22]).permutation(np.unique(part))
    train = np.isin(part, ids[:n_train])
    return camp.subset(np.flatnonzero(train)), camp.subset(np.flatnonzero(~train))


def _truth(part, classes) -> np.ndarray:
    names = list(part.modalities)
    return np.array([list(classes).index(names[int(m)]) for m in np.asarray(part.modality)])


def _decision_us(model, X) -> tuple[float, int]:
    from eskin.deploy.export import CompiledModel, model_to_bytes, spec_from_model

    engine = CompiledModel(model_to_bytes(spec_from_model(model), "float32"))
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        engine.classify_tensors(X)
        best = min(best, (time.perf_counter() - t0) / len(X))
    return 1e6 * best, int(engine.n_support)


def _eskin(train, test, window, options):
    from eskin.learn.training import train_model

    model = train_model(train, window=window, n_jobs=1, **options)
    cpu = time.process_time()
    X = model.preprocess(test)
    pred = model.predict_indices(X)[0]
    acc = float(np.mean(pred == _truth(test, model.classes)))
    us, n_sv = _decision_us(model, X)
    recipe = f"{model.machine} D={model.D} {model.subsample} {model.training.get('negatives')}"
    return cpu, {"accuracy": acc, "decision_us": us, "n_support": n_sv, "recipe": recipe}


def _patterns(camp, window):
    from eskin.learn.training_set import preprocess_campaign, window_config_for_rate

    cfg, _ = window_config_for_rate(None, float(camp.sample_rate_hz))
    prep = preprocess_campaign(camp, np.arange(len(camp)), [(100, "algorithm2")], window=window,
                               config=cfg)
    return prep.X[(100, "algorithm2")], np.asarray(camp.modality).astype(np.int64)


def _peer(name, train, test, window):
    from eskin.learn.baselines import minirocket, vector_svm

    Xa, ya = _patterns(train, window)
    Xb, yb = _patterns(test, window)
    if name == "minirocket":
        pred, _ = minirocket(Xa, ya, Xb, seed=0)
    else:
        pred, _ = vector_svm(Xa, ya, np.asarray(train.participant), Xb)
    return time.process_time(), {"accuracy": float(np.mean(pred == yb))}


def _child(method, path, n_train, window, src):
    """One method in a fresh process: (CPU s, peak RSS MiB, figures)."""
    if src:
        sys.path.insert(0, src)
    import eskin

    camp = eskin.load_campaign(path, in_memory=True)
    train, test = _split(camp, n_train)
    if method == "minirocket":  # numba's compilation is not training: done before the clock
        from eskin.learn.baselines import minirocket

        rng = np.random.default_rng(0)
        minirocket(rng.normal(size=(6, 2, 2, 20)), np.array([0, 1] * 3),
                   rng.normal(size=(2, 2, 2, 20)))
    # importing is not training either: the method's modules (scikit-learn, SciPy and eskin's
    # own, compiled from source when there is no bytecode) are imported before the clock
    import eskin.learn.baselines
    import eskin.learn.training

    cpu0 = time.process_time()
    if method.startswith("eskin"):
        options = {"decision_us": None} if method == "eskin, no host budget" else {}
        cpu, out = _eskin(train, test, window, options)
    else:
        cpu, out = _peer(method, train, test, window)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return cpu - cpu0, rss, {**out, "source": eskin.__file__}


def run(method, path, n_train, window, src=None):
    ctx = mp.get_context("spawn")
    with cf.ProcessPoolExecutor(1, mp_context=ctx) as pool:
        return pool.submit(_child, method, str(path), n_train, window, src).result()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaigns", default=",".join(CAMPAIGNS))
    ap.add_argument("--methods", default="eskin,minirocket,rbf")
    ap.add_argument("--baseline-src", default=None,
                    help="a python/ folder of another eskin source tree, run as the baseline")
    ap.add_argument("--no-budget", action="store_true",
                    help="also train eskin without the host decision budget")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin_bench_peers"))
    args = ap.parse_args(argv)
    methods = []
    for m in args.methods.split(","):
        methods += {"eskin": ["eskin"], "minirocket": ["minirocket"], "rbf": ["rbf-svc grid"]}[m]
    if args.no_budget:
        methods.append("eskin, no host budget")
    if args.baseline_src:
        methods.append("eskin (baseline)")
    print("SIMULATED campaigns; CPU = process CPU seconds of training (preprocessing included), "
          "RSS = peak resident MiB of the method's own process")
    for name in args.campaigns.split(","):
        people, n_train, _, window = CAMPAIGNS[name]
        path = campaign(args.cache, name)
        print(f"\n{name}: {people} participants, {n_train} train / {people - n_train} held out")
        results = {}
        for m in methods:
            src = args.baseline_src if m == "eskin (baseline)" else None
            method = "eskin" if m == "eskin (baseline)" else m
            method = "minirocket" if m == "minirocket" else method
            method = "rbf" if m == "rbf-svc grid" else method
            cpu, rss, out = run(method, path, n_train, window, src)
            results[m] = cpu
            extra = ""
            if "decision_us" in out:
                extra = (f"  decision {out['decision_us']:7.1f} us, {out['n_support']:4d} "
                         f"support vectors, {out['recipe']}")
            print(f"  {m:24s} CPU {cpu:7.2f} s  RSS {rss:6.0f} MiB  held-out accuracy "
                  f"{100 * out['accuracy']:5.1f} %{extra}", flush=True)
        if "eskin" in results and "minirocket" in results:
            print(f"  ratio eskin / minirocket+ridge CPU: "
                  f"{results['eskin'] / results['minirocket']:.2f}")
        if "eskin" in results and "eskin (baseline)" in results:
            print(f"  ratio eskin / baseline CPU: "
                  f"{results['eskin'] / results['eskin (baseline)']:.2f}")


if __name__ == "__main__":
    main()
