"""Campaign files shared by test_experiments.py and test_models.py (written once per test run).

- ``small_simulated``: eskin's simulator, 6 participants, run 2 only, the paper's 4x4 grid at
  3000 Hz and its three modalities.
- ``user_campaign``: a hand-made "user" campaign unlike the paper's: a 3x5 grid at 1000 Hz, four
  classes, recordings already cut to the touch (for ``window="none"``), some shorter than D=50.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_CACHE: dict[str, Path] = {}

USER_CLASSES = ["tap", "stroke", "press", "pinch"]


def small_simulated(base: Path) -> Path:
    if "sim" not in _CACHE:
        from eskin.data.simulator import simulate

        path = base / "small_sim.h5"
        simulate(path, participants=6, seed=3, runs=(2,))
        _CACHE["sim"] = path
    return _CACHE["sim"]


def user_campaign(base: Path) -> Path:
    """4 participants x 4 classes x 3 repetitions, 3x5 taxels, 1000 Hz, cut recordings."""
    if "user" not in _CACHE:
        from eskin.data.campaign import write_campaign

        rng = np.random.default_rng(11)
        rows, cols, rate, T = 3, 5, 1000.0, 400
        recs, mod, part, dirn, run = [], [], [], [], []
        for p in range(4):
            for k in range(len(USER_CLASSES)):
                for rep in range(3):
                    length = int(rng.integers(30, 45)) if rep == 0 else int(rng.integers(150, T))
                    t = np.arange(length) / rate
                    freq = 8.0 + 25.0 * k
                    # each class excites its own band of columns with its own frequency
                    gain = np.exp(-0.5 * ((np.arange(cols) - (k + 0.5)) / 1.2) ** 2)
                    gain = np.tile(gain, (rows, 1)) * (1 + 0.2 * rng.standard_normal((rows, cols)))
                    sig = 3000 * gain[..., None] * np.sin(2 * np.pi * freq * t + rng.uniform(0, 6))
                    sig = sig + 150 * rng.standard_normal((rows, cols, length))
                    recs.append(np.clip(sig, -32000, 32000).astype(np.int16))
                    mod.append(k)
                    part.append(p)
                    dirn.append(rep % 2)
                    run.append(1)
        path = base / "user_3x5_1khz.h5"
        write_campaign(
            path,
            recs,
            modality=mod,
            participant=part,
            direction=dirn,
            run=run,
            modalities=USER_CLASSES,
            sample_rate_hz=rate,
            volts_per_count=1e-4,
            source="recorded",
        )
        _CACHE["user"] = path
    return _CACHE["user"]
