"""The whole skin on one core: N patches of 4x4 taxels at 3 kHz through one eskin::SkinEngine.

The model is the default recipe (``eskin.train_model(campaign)``, as ``eskin train CAMPAIGN``)
fitted on a small simulated campaign (``eskin.simulate``, --participants, seed 0), cached under
build/bench_skin/ (or the .eskin file given with --model). Each patch's stream is recordings of
a second simulated campaign (seed 1) back to back, with quiet stretches between them (recorded
noise: the start of each recording, before its touch) so that about --touching of the time is
touch; patch p starts its stream at its own offset. The stream is pushed as interleaved blocks of
--block samples of every patch (``SkinEngine.push_interleaved``); only the engine's calls are
timed (building the blocks is not). Real time X = seconds of stream / seconds of engine.

The patches share their window buffers as a chunked store (SkinEngine window_buffers and
window_chunk_samples, docs/skin-engine.md "Chunked window store"): the pool holds
--window-buffers x patches full windows' worth of kept samples (the rule: 3/4, the mean share
of its window a long touch keeps, since its kept samples grow from half to all of
window_samples and halve again), cut into chunks of --window-chunk samples. The run prints
the most chunks in use at once beside the pool's size, and the touches left without a tensor
(unbuffered: they must be 0). Afterwards every patch's decisions are checked against a
StreamClassifier fed the same patch stream (--check patches, default all): same samples,
windows, labels and decision values.

Baseline, in the same run: one StreamClassifier (the single-patch path, float samples) fed one
patch's stream by its C++ loop (``_core.StreamClassifier.feed``): ns per sample, and its heap
bytes (glibc mallinfo2 before and after constructing 20 of them; Linux only). The ratio lines
compare the engine's ns per patch-sample and bytes per patch with these.

Run:  ESKIN_BIN_DIR=build/dev PYTHONPATH=python python benchmarks/bench_skin.py
      [--patches 1000] [--seconds 12] [--block 300] [--participants 6] [--model m.eskin]
      [--window-buffers 0.75] [--window-chunk 64] [--check 1000]
The data are simulated (eskin.simulate).
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import time
from pathlib import Path

import numpy as np

import eskin
from eskin import _core
from eskin.deploy.export import CompiledModel, export_model
from eskin.deploy.skin_engine import SkinEngine

CACHE = Path(__file__).resolve().parents[1] / "build" / "bench_skin"


class _MallInfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


def heap_in_use() -> int:
    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = _MallInfo2
    gc.collect()
    m = libc.mallinfo2()
    return int(m.uordblks + m.hblkhd)


def default_model(participants: int) -> Path:
    path = CACHE / f"default_p{participants}.eskin"
    if path.exists():
        return path
    CACHE.mkdir(parents=True, exist_ok=True)
    camp = eskin.simulate(
        CACHE / f"train_p{participants}.h5", participants=participants, seed=0, overwrite=True
    )
    t0 = time.perf_counter()
    model = eskin.train_model(camp, n_jobs=1)
    print(
        f"trained the default recipe on {participants} simulated participants in "
        f"{time.perf_counter() - t0:.0f} s (cached: {path})"
    )
    return export_model(model, path)


def patch_streams(touching: float, k: int) -> np.ndarray:
    """k streams (k, T, 16) int16: a simulated campaign's recordings, each cut to its touch
    with quiet recorded noise between them so that about `touching` of the time is touch."""
    path = CACHE / "streams.h5"
    if not path.exists():
        eskin.simulate(path, participants=4, seed=1, runs=(2,), overwrite=True)
    camp = eskin.load_campaign(path, in_memory=True)
    sig, lengths = np.asarray(camp.signals), np.asarray(camp.lengths)
    contact = np.asarray(camp.contact_interval)
    rng = np.random.default_rng(0)
    streams = []
    for _ in range(k):
        parts = []
        for i in rng.permutation(len(sig)):
            rec = sig[i, :, :, : lengths[i]].reshape(16, -1).T  # (T, 16)
            a, b = (int(v) for v in contact[i])
            quiet = rec[: max(a, 1)]
            touch = rec[max(0, a - 150) : min(len(rec), b + 150)]
            gap = int(len(touch) * (1 - touching) / touching)
            reps = int(np.ceil(gap / len(quiet)))
            parts += [np.tile(quiet, (reps, 1))[:gap], touch]
        streams.append(np.concatenate(parts))
    T = min(len(s) for s in streams)
    return np.ascontiguousarray(np.stack([s[:T] for s in streams]), dtype=np.int16)


def baseline(cm: CompiledModel, stream: np.ndarray) -> tuple[float, int]:
    """One StreamClassifier: ns per sample over `stream`, heap bytes of one."""
    x = stream.astype(np.float64)
    sc = _core.StreamClassifier(cm._model)
    t0 = time.perf_counter()
    sc.feed(x, flush=True)
    ns = (time.perf_counter() - t0) * 1e9 / len(x)
    h0 = heap_in_use()
    many = [_core.StreamClassifier(cm._model) for _ in range(20)]
    per = (heap_in_use() - h0) // len(many)
    return ns, per


def patch_stream(streams: np.ndarray, patch: int, T: int) -> np.ndarray:
    """Patch `patch`'s stream (T, 16): one of the streams, from the patch's own offset."""
    k, L = streams.shape[0], streams.shape[1]
    return streams[patch % k, (patch * 7919 % L + np.arange(T)) % L]


def run_skin(cm: CompiledModel, streams: np.ndarray, patches: int, T: int, block: int,
             window_buffers: int = 0, window_chunk: int = 0):
    engine = SkinEngine(
        cm, n_patches=patches, window_buffers=window_buffers, window_chunk_samples=window_chunk
    )
    k, L = streams.shape[0], streams.shape[1]
    which = np.arange(patches) % k
    offset = (np.arange(patches) * 7919) % L
    spent, got = 0.0, []
    for t in range(0, T, block):
        n = min(block, T - t)
        rows = (offset[None, :] + t + np.arange(n)[:, None]) % L  # (n, patches)
        b = np.ascontiguousarray(streams[which[None, :], rows])  # (n, patches, 16)
        t0 = time.perf_counter()
        out = engine.push_interleaved(b)
        spent += time.perf_counter() - t0
        got += out
    t0 = time.perf_counter()
    out = engine.flush()
    spent += time.perf_counter() - t0
    return engine, spent, got + out


def check_decisions(cm: CompiledModel, streams: np.ndarray, T: int, got: list, patches: int) -> int:
    """Patches 0 .. patches-1: the engine's decisions against a StreamClassifier's on the same
    stream (sample, window, label, values). Returns the decisions compared; raises on any
    difference or on a touch the StreamClassifier decided and the engine did not."""
    mine: dict[int, list] = {}
    for d in got:
        mine.setdefault(d.patch, []).append((d.sample, d.window, d.label, list(d.values)))
    compared = 0
    for p in range(patches):
        sc = _core.StreamClassifier(cm._model)
        events = sc.feed(patch_stream(streams, p, T).astype(np.float64), flush=True)
        want = [
            (e["sample"], tuple(e["window"]), e["label"], list(e["values"]))
            for e in events
            if "label" in e
        ]
        if mine.get(p, []) != want:
            raise SystemExit(f"patch {p}: the engine's decisions differ from a StreamClassifier's")
        compared += len(want)
    return compared


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--patches", type=int, default=1000)
    ap.add_argument("--seconds", type=float, default=12.0, help="seconds of stream per patch")
    ap.add_argument("--block", type=int, default=300, help="samples per interleaved block")
    ap.add_argument("--touching", type=float, default=0.39)
    ap.add_argument("--participants", type=int, default=6, help="of the training campaign")
    ap.add_argument("--model", type=Path, default=None, help="a .eskin model (default: train one)")
    ap.add_argument("--window-buffers", type=float, default=0.75,
                    help="full windows' worth of shared window buffers, as a share of the patches "
                         "(0.75: 750 of 1000); 0: each patch its own (SkinEngine window_buffers)")
    ap.add_argument("--window-chunk", type=int, default=64,
                    help="samples per chunk of the shared window buffers; 0: whole buffers "
                         "(SkinEngine window_chunk_samples)")
    ap.add_argument("--check", type=int, default=None,
                    help="patches whose decisions are checked against a StreamClassifier "
                         "(default: all)")
    a = ap.parse_args()
    cm = CompiledModel(a.model or default_model(a.participants))
    print(
        f"model: {cm.n_support} support vectors, D={cm.D}, grid {cm.grid_shape}, "
        f"{cm.sample_rate_hz:g} Hz, classes {cm.class_names}, window_samples="
        f"{cm.window_config['window_samples']:g}"
    )
    streams = patch_streams(a.touching, 8)
    T = int(a.seconds * cm.sample_rate_hz)
    base_ns, base_bytes = baseline(cm, streams[0])
    shared = int(round(a.window_buffers * a.patches))
    chunk = a.window_chunk if shared else 0
    engine, spent, got = run_skin(cm, streams, a.patches, T, a.block, shared, chunk)
    decisions = len(got)
    touch = sum(d.window[1] - d.window[0] for d in got)
    realtime = a.seconds / spent
    ns = spent * 1e9 / (a.patches * T)
    B = engine.bytes_per_patch
    print(f"baseline: one StreamClassifier {base_ns:.1f} ns/sample, {base_bytes} bytes")
    print(
        f"skin: {a.patches} patches x {a.seconds:g} s in {spent:.2f} s, {ns:.1f} ns per "
        f"patch-sample, {decisions} decisions, {touch / (a.patches * T):.0%} of the time in a "
        f"touch window"
    )
    print(
        f"ratio: {base_ns / ns:.2f}x the baseline's speed per patch-sample, "
        f"{base_bytes / B:.2f}x less memory per patch"
    )
    size, peak = engine.window_pool_size, engine.window_buffers_peak
    if shared:
        what = f"chunks of {chunk} samples" if chunk else "whole window buffers"
        print(
            f"shared window buffers: {size} {what} ({shared} windows' worth for {a.patches} "
            f"patches), at most {peak} in use at once ({peak / max(size, 1):.0%})"
        )
    print(
        f"unclassified touches: {engine.unbuffered} unbuffered, {engine.dropped} dropped in all"
    )
    checked = a.patches if a.check is None else min(a.check, a.patches)
    compared = check_decisions(cm, streams, T, got, checked)
    print(
        f"check: {checked} patches, {compared} decisions identical to a StreamClassifier's "
        f"on the same stream"
    )
    print(f"SKIN-BENCH: patches={a.patches} realtime={realtime:.2f} bytes_per_patch={B}")


if __name__ == "__main__":
    main()
