"""tools/mcu_case.py, the case builder of `make mcu MODEL=... CAMPAIGN=...`: a damaged model or
campaign file is one line naming the file and a non-zero exit, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

REPO = Path(__file__).resolve().parents[2]


def _model(path: Path) -> Path:
    """A valid three-class model of random support vectors (4x4, D = 20)."""
    rng = np.random.default_rng(0)
    pool = rng.standard_normal((8, 4, 4, 20))
    machines = [MachineSpec(k, -1, 0.0, (1, 1, 1), (1.0, 1.0, 1.0), pool[:6],
                            rng.standard_normal(6)) for k in range(3)]
    spec = ModelSpec(class_names=["brush", "finger", "washer"], rule="one_vs_all",
                     machines=machines, D=20, grid_shape=(4, 4))
    path.write_bytes(model_to_bytes(spec, "float32"))
    return path


@pytest.mark.parametrize("damaged", ["model", "campaign"])
def test_a_damaged_file_is_one_line_naming_it(tmp_path, damaged):
    good = _model(tmp_path / "m.eskin")
    bad = tmp_path / ("bad.eskin" if damaged == "model" else "bad.h5")
    bad.write_bytes(b"not what it claims to be\n" * 4)
    # the model is read first: with a damaged one, the campaign (any file) is never opened
    model, campaign = (bad, good) if damaged == "model" else (good, bad)
    r = subprocess.run([sys.executable, str(REPO / "tools" / "mcu_case.py"),
                        str(tmp_path / "case"), "--model", str(model),
                        "--campaign", str(campaign)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode != 0
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(str(bad)), r.stderr
    assert ("not an eskin model file" if damaged == "model" else "not an HDF5 file") in lines[0]


def test_mcu_link_streams_a_users_campaign_cut_to_the_models_touch_windows(tmp_path):
    """`make mcu-link MODEL=m.eskin CAMPAIGN=held.h5`'s replay step: --per-class recordings of
    each of the model's classes from the user's campaign, each cut to the touch window the
    model's own detector finds, with the margin on either side."""
    from eskin.data.campaign import load_campaign
    from eskin.data.replay import read_replay_file
    from eskin.data.simulator import simulate
    from eskin.signal.preprocess import detect_touches

    model = _model(tmp_path / "m.eskin")
    held = simulate(tmp_path / "held.h5", participants=1, seed=4, runs=(2,))
    case, replay = tmp_path / "case", tmp_path / "stream.eskr"
    r = subprocess.run([sys.executable, str(REPO / "tools" / "mcu_case.py"), str(case), "--model",
                        str(model), "--campaign", str(held)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([sys.executable, str(REPO / "tools" / "mcu_link.py"), "replay", str(case),
                        str(replay), "--campaign", str(held), "--per-class", "1", "--margin-s",
                        "0.25"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert f"3 recordings of 3 classes of {held}" in r.stdout
    rf, camp = read_replay_file(replay), load_campaign(held)
    assert list(rf.segments["recording"]) == [0, 2, 4]  # the first of each class, in order
    assert list(rf.segments["label"]) == [int(camp.modality[i]) for i in (0, 2, 4)]
    for k, i in enumerate((0, 2, 4)):
        sig = np.asarray(camp.recording(i))
        w = detect_touches(sig[None], sample_rate_hz=camp.sample_rate_hz)
        a = max(0, int(w.start[0]) - 750)
        b = min(sig.shape[-1], int(w.stop[0]) + 750)
        np.testing.assert_array_equal(rf.recording(k), sig[..., a:b])
