"""Writes tests/data/replay_small.eskr with the Python writer (eskin.data.replay): the valid
replay file tests/cpp/test_replay_format.cpp reads. Run from the repository root:
PYTHONPATH=python python tests/data/make_replay_fixture.py"""

from pathlib import Path

import numpy as np

from eskin.data.replay import write_replay_arrays

rng = np.random.default_rng(0)
recs = [rng.integers(-5, 5, size=(2, 3, n)).astype(np.int16) for n in (40, 60)]
out = Path(__file__).resolve().parent / "replay_small.eskr"
write_replay_arrays(out, recs, labels=[0, 1], class_names=["brush", "finger"], gap_s=0.01,
                    contact_intervals=[[1, 30], [0, 60]], sample_rate_hz=3000.0,
                    volts_per_count=2.5e-4, seed=1)
