"""A straightforward numpy/scipy implementation of the touch detector and the subsampling.

Not part of the API: it is the baseline of ``benchmarks/bench_preprocess.py`` and an
independent cross-check of the C++ core in ``tests/python/test_preprocess.py``. It follows the
description in ``docs/preprocessing.md`` with whole-array numpy steps (DC blocker through
``scipy.signal.lfilter``, frame energies by reshaping) and a Python loop over the frames for the
state machine. Windows agree with the C++ core except where a frame energy sits within
rounding of a threshold.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from eskin.signal.preprocess import WindowConfig


def frame_energies(x: np.ndarray, p: dict, dc_alpha: float, combine: str) -> np.ndarray:
    """x (K, n) float64 -> (n // frame_len,) frame energies."""
    K, n = x.shape
    L = p["frame_len"]
    a = dc_alpha
    if a > 0:
        # fast start: the running mean while 1/(i+1) > a, then an exponential mean
        n1 = min(n, int(np.floor(1.0 / a)))  # samples i < n1 have 1/(i+1) >= a (nearly)
        while n1 > 0 and 1.0 / n1 < a:
            n1 -= 1
        m = np.empty_like(x)
        m[:, :n1] = np.cumsum(x[:, :n1], axis=1) / np.arange(1, n1 + 1)
        if n1 < n:
            zi = ((1.0 - a) * m[:, n1 - 1])[:, None] if n1 > 0 else np.zeros((K, 1))
            m[:, n1:], _ = lfilter([a], [1.0, -(1.0 - a)], x[:, n1:], axis=1, zi=zi)
        y = x - m
    else:
        y = x
    F = n // L
    e = (y[:, : F * L] ** 2).reshape(K, F, L).sum(axis=2) / L
    if combine == "max":
        return e.max(axis=0)
    total = e.sum(axis=0)
    return total - e.max(axis=0) if combine == "trimmed" and K > 1 else total


def window_stride(pushed: int, capacity: int) -> int:
    """The bounded window's decimation after ``pushed`` samples in a buffer of ``capacity``:
    the smallest power of two s with ceil(pushed / s) <= capacity."""
    s = 1
    while -(-pushed // s) > capacity:
        s *= 2
    return s


def detect(x: np.ndarray, sample_rate_hz: float, cfg: WindowConfig) -> list[dict]:
    """All touches of one recording x (K, n): dicts with start, stop, onset, offset, energy,
    truncated and stride (the bounded window's decimation)."""
    p = cfg.resolve(sample_rate_hz)
    L = p["frame_len"]
    n = x.shape[1]
    e_all = frame_energies(x.astype(np.float64), p, p["dc_alpha"], cfg.combine)
    noise: list[float] = []
    floor = cfg.min_noise_energy
    state = "idle"
    touches: list[dict] = []
    onset = start = last_above = quiet = 0
    energy = peak = 0.0
    last_stop = 0

    def push_noise(v: float) -> float:
        noise.append(v)
        if len(noise) > p["noise_frames"]:
            noise.pop(0)
        k = int(np.floor(cfg.noise_quantile * (len(noise) - 1)))
        return max(cfg.min_noise_energy, float(np.partition(np.asarray(noise), k)[k]))

    def finalise(now: int, forced: bool) -> None:
        nonlocal state, last_stop
        truncated = quiet == 0
        off_ = now if truncated else last_above
        stop = now if truncated else min(now, last_above + p["pad_after"])
        state = "refractory" if forced else "idle"
        last_stop = stop
        if off_ - onset >= p["min_duration"]:
            touches.append(dict(start=start, stop=stop, onset=onset, offset=off_, energy=energy,
                                truncated=truncated,
                                stride=window_stride(now - start, p["window_capacity"])))

    for f, e in enumerate(e_all):
        now = (f + 1) * L
        # the max_window cut happens at a sample, before this frame's decision
        if state == "active" and start + p["max_window"] <= now:
            finalise(start + p["max_window"], True)
        if f < p["warmup_frames"]:
            floor = push_noise(e)
            continue
        on, off = cfg.on_factor * floor, cfg.off_factor * floor
        if state == "idle":
            if e > on:
                state = "active"
                first = f
                while (f - first < p["lookback_frames"] and first - 1 >= p["warmup_frames"]
                       and (first - 1) * L >= last_stop and e_all[first - 1] > off):
                    first -= 1
                onset = first * L
                start = max(0, onset - p["pad_before"])
                last_above, quiet = now, 0
                energy = float(e_all[first : f + 1].sum()) * L
                peak = e
            else:
                floor = push_noise(e)
        elif state == "active":
            peak = max(peak, e)
            if e > max(off, cfg.release_fraction * peak):
                last_above, quiet = now, 0
                energy += e * L
            else:
                quiet += 1
                if quiet >= p["hold_frames"] and now >= last_above + p["pad_after"]:
                    finalise(now, False)
        else:
            if e <= off:
                state = "idle"
            floor = push_noise(e)
    if state == "active":
        if start + p["max_window"] <= n:
            finalise(start + p["max_window"], True)
        else:
            finalise(n, False)
    return touches


def select(touches: list[dict], length: int, cfg: WindowConfig, p: dict) -> tuple[int, int, int]:
    """The recording's window (start, stop, stride)."""
    if not touches:
        if cfg.fallback == "error":
            raise RuntimeError("no touch detected")
        return 0, length, 1
    if cfg.select == "first":
        return touches[0]["start"], touches[0]["stop"], touches[0]["stride"]
    best = max(touches, key=lambda w: w["energy"])
    if cfg.select == "energy":
        return best["start"], best["stop"], best["stride"]
    kept = [w for w in touches if w["energy"] >= cfg.span_fraction * best["energy"]]
    start = kept[0]["start"]
    stop = min(kept[-1]["stop"], start + p["max_window"])
    stride = max(w["stride"] for w in kept)
    if len(kept) > 1:  # a span of several touches: read as a bounded window of its length
        stride = max(stride, window_stride(stop - start, p["window_capacity"]))
    return start, stop, stride


def algorithm2(window: np.ndarray, D: int, stride: int = 1) -> np.ndarray:
    """window (rows, cols, S >= D) -> (rows, cols, D): samples (d-1)*floor(S/D), d = 1..D, each
    read from the bounded window's kept sample at or before it (every stride-th)."""
    interval = window.shape[-1] // D
    t = np.arange(D) * interval
    return window[..., (t // stride) * stride].astype(np.float64)


def preprocess(x: np.ndarray, D: int, sample_rate_hz: float = 3000.0,
               cfg: WindowConfig | None = None, length: int | None = None
               ) -> tuple[np.ndarray, tuple[int, int]]:
    """One recording (rows, cols, T) -> ((rows, cols, D), window); Algorithm 2, S >= D."""
    cfg = cfg or WindowConfig()
    rows, cols, T = x.shape
    length = T if length is None else length
    touches = detect(x.reshape(rows * cols, T)[:, :length], sample_rate_hz, cfg)
    start, stop, stride = select(touches, length, cfg, cfg.resolve(sample_rate_hz))
    return algorithm2(x[:, :, start:stop], D, stride), (start, stop)
