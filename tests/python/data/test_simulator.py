"""The campaign simulator: format, determinism, physics sanity, separability of the modalities."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest

from eskin.data.campaign import load_campaign
from eskin.data.simulator import MODALITIES, SimulatorConfig, simulate


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    p = tmp_path_factory.mktemp("sim") / "small.h5"
    simulate(p, participants=2, seed=5)
    return p


def test_simulated_file_is_a_valid_campaign(small):
    with load_campaign(small, check_data=True) as c:
        assert len(c) == 2 * 3 * 2 * 2
        assert c.signals.shape == (24, 4, 4, 21000) and c.signals.dtype == np.int16
        assert c.sample_rate_hz == 3000.0 and c.source == "simulated"
        assert c.modalities == list(MODALITIES) == ["brush", "finger", "washer"]
        assert sorted(set(c.participant.tolist())) == [1, 2]
        assert sorted(set(c.run.tolist())) == [1, 2]
        assert np.all(c.lengths == 21000)
        # the paper's order: participant, run, modality, horizontal then vertical
        assert c.direction[:4].tolist() == [0, 1, 0, 1]
        assert c.modality[:6].tolist() == [0, 0, 1, 1, 2, 2]
        on, off = c.contact_interval.T
        assert np.all(on > 0) and np.all(off > on) and np.all(off < 21000)
        cfg = SimulatorConfig.from_json(c.attrs["simulator_config"])
        assert cfg == SimulatorConfig()
        assert "SIMULATED" in c.attrs["description"]
        assert set(c.extras) >= {"speed_mm_s", "force_n", "variant"}


def test_same_seed_same_content(small, tmp_path):
    again = tmp_path / "again.h5"
    simulate(again, participants=2, seed=5, n_jobs=2)
    with h5py.File(small) as a, h5py.File(again) as b:
        for name in a["recordings"]:
            if isinstance(a["recordings"][name], h5py.Dataset):
                np.testing.assert_array_equal(a["recordings"][name][()], b["recordings"][name][()])
        assert dict(a.attrs) .keys() == dict(b.attrs).keys()
        assert a.attrs["simulator_config"] == b.attrs["simulator_config"]
    other = tmp_path / "other.h5"
    simulate(other, participants=1, seed=6)
    with h5py.File(small) as a, h5py.File(other) as b:
        assert not np.array_equal(a["recordings/signals"][0], b["recordings/signals"][0])


def test_signal_is_in_the_contact_interval(small):
    """Energy inside the true contact interval dominates the energy before the touch."""
    with load_campaign(small) as c:
        ratios = []
        for i in range(len(c)):
            x = c.signals_float(i).reshape(16, -1)
            x = x - np.median(x, axis=1, keepdims=True)
            on, off = c.contact_interval[i]
            inside = np.mean(x[:, on:off] ** 2)
            before = np.mean(x[:, : max(on - 300, 10)] ** 2)
            ratios.append(inside / before)
        assert np.median(ratios) > 20


def test_config_validation():
    with pytest.raises(ValueError, match="difficulty"):
        SimulatorConfig(difficulty=-1)
    with pytest.raises(ValueError, match="bpf_lowpass_hz"):
        SimulatorConfig(bpf_lowpass_hz=5000.0)
    with pytest.raises(ValueError, match="participants"):
        simulate("/nonexistent/x.h5", participants=0)


def test_refuses_to_overwrite(small):
    with pytest.raises(FileExistsError):
        simulate(small, participants=1)


def test_difficulty_zero_is_clean(tmp_path):
    p = tmp_path / "clean.h5"
    simulate(p, participants=1, seed=1, difficulty=0.0)
    with load_campaign(p) as c:
        assert c.attrs["difficulty"] == 0.0
        assert np.all(c.extras["variant"] == 0)  # no atypical gestures
        assert np.all(c.extras["dead_taxel"] == -1)


def test_odd_grid_and_rate(tmp_path):
    cfg = dataclasses.replace(SimulatorConfig(), rows=3, cols=5, sample_rate_hz=2000.0,
                              duration_s=5.0, bpf_lowpass_hz=900.0, pitch_mm=10.0)
    p = tmp_path / "odd.h5"
    simulate(p, participants=1, config=cfg, runs=(2,))
    with load_campaign(p) as c:
        assert c.signals.shape == (6, 3, 5, 10000) and c.sample_rate_hz == 2000.0


# ---------------------------------------------------------------- command line


def _cli(*args):
    from typer.testing import CliRunner

    from eskin.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


def test_cli_simulate_info_plot(tmp_path, small):
    out = tmp_path / "cli.h5"
    r = _cli("simulate", "-o", out, "--participants", 1, "--seed", 3, "-q")
    assert r.exit_code == 0, r.output
    assert "SIMULATED" in r.output and out.exists()
    r = _cli("simulate", "-o", out, "--participants", 1)
    assert r.exit_code == 2 and "refusing to overwrite" in r.output
    assert _cli("simulate", "-o", out, "--participants", 1, "--force", "-q").exit_code == 0

    r = _cli("info", small, "--check")
    assert r.exit_code == 0, r.output
    for text in ("SIMULATED", "24", "4 x 4", "3000 Hz", "brush (0)", "finger (1)", "washer (2)",
                 "2 participants x 12", "ground truth"):
        assert text in r.output, text

    png = tmp_path / "rec.png"
    r = _cli("plot", small, "--index", 3, "-o", png)
    assert r.exit_code == 0, r.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = _cli("plot", small, "--index", 99, "-o", tmp_path / "x.png")
    assert r.exit_code == 2 and "out of range" in r.output


def test_cli_errors_are_clear(tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_text("not a campaign")
    r = _cli("info", bad)
    assert r.exit_code == 2
    assert "bad.h5: not an HDF5 file" in r.output
    assert "Traceback" not in r.output
    r = _cli("info", tmp_path / "missing.h5")
    assert r.exit_code == 2 and "no such campaign file" in r.output


# ---------------------------------------------------------------- calibration check


def test_modalities_separable_but_not_trivially(tmp_path):
    """A small fixed-seed experiment (not the paper's protocol): run 2 of 20 simulated
    participants, D = 50, tensor-kernel SVMs one-vs-rest, 4-fold participant-disjoint
    cross-validation (every recording is tested once, by machines that never saw its participant).
    The three modalities must be recognised well above chance (1/3) but not perfectly: the
    simulator is calibrated to be about as hard as the paper's data."""
    from sklearn.svm import SVC

    import eskin

    p = tmp_path / "sep.h5"
    simulate(p, participants=20, seed=11, runs=(2,))
    with load_campaign(p) as c:
        X = eskin.preprocess(c.signals, 50, lengths=c.lengths, sample_rate_hz=c.sample_rate_hz)
        y = c.modality.astype(int)
        part = c.participant
    K = eskin.tensor_kernel(X, sigma=4.0, alpha="half")
    pred = np.zeros(len(y), dtype=int)
    for fold in range(4):
        test = part % 4 == fold
        scores = np.zeros((int(test.sum()), 3))
        for k in range(3):
            svm = SVC(C=10.0, kernel="precomputed").fit(K[np.ix_(~test, ~test)], y[~test] == k)
            scores[:, k] = svm.decision_function(K[np.ix_(test, ~test)])
        pred[test] = np.argmax(scores, axis=1)
    accuracy = float(np.mean(pred == y))
    assert 0.5 <= accuracy <= 0.95, accuracy
    # every modality is recognised above chance, none perfectly
    for k in range(3):
        recall = float(np.mean(pred[y == k] == k))
        assert 1 / 3 < recall < 1.0, (k, recall)


# ------------------------------------------------------------------ press-and-hold, other grids


def press_campaign(path, participants=1, **changes):
    from eskin.data.simulator import acquisition_config

    cfg = acquisition_config(grid=(8, 8), rate_hz=1000.0, duration_s=3.0,
                             modalities=("finger", "press"))
    simulate(path, participants=participants, seed=11, config=dataclasses.replace(cfg, **changes))
    return path


def frame_energy(rec: np.ndarray, frame: int) -> np.ndarray:
    """Energy per frame of the recording less its 0.1 s moving mean, summed over the taxels."""
    from scipy.ndimage import uniform_filter1d

    x = rec.reshape(-1, rec.shape[-1]).astype(float)
    x = x - uniform_filter1d(x, 10 * frame + 1, axis=1)
    n = x.shape[1] // frame * frame
    return (x[:, :n] ** 2).reshape(x.shape[0], -1, frame).mean(axis=2).sum(axis=0)


def test_press_and_hold_is_two_bursts_with_a_quiet_hold(tmp_path):
    with load_campaign(press_campaign(tmp_path / "p.h5")) as c:
        assert c.modalities == ["finger", "press"] and len(c) == 8
        assert c.signals.shape[1:] == (8, 8, 3000) and c.sample_rate_hz == 1000.0
        cfg = SimulatorConfig.from_json(c.attrs["simulator_config"])
        assert cfg.modalities == ("finger", "press") and cfg.press_hold_s == 0.5
        for i in np.flatnonzero(c.modality == 1):
            e = frame_energy(c.recording(int(i)), 10)  # 10 ms frames
            on, off = (int(v) // 10 for v in c.contact_interval[i])
            quiet = np.median(e[: max(on - 5, 5)])
            # the press (its first 0.15 s) and the release (the end) are loud
            assert e[on : on + 15].max() > 50 * quiet and e[off - 15 : off + 5].max() > 50 * quiet
            # the middle of the 0.5 s hold is quiet: the sensor sees changes, not force
            mid = (on + off) // 2
            assert np.median(e[mid - 10 : mid + 10]) < 3 * quiet


def test_the_press_has_no_tremor_of_a_sliding_finger_when_told(tmp_path):
    # press_tremor scales the participant's tremor: a resting finger's is a tenth of it
    loud = press_campaign(tmp_path / "loud.h5", press_tremor=10.0)
    quiet = press_campaign(tmp_path / "quiet.h5")
    held = []
    for path in (loud, quiet):
        with load_campaign(path) as c:
            i = int(np.flatnonzero(c.modality == 1)[0])
            e = frame_energy(c.recording(i), 10)
            on, off = (int(v) // 10 for v in c.contact_interval[i])
            held.append(np.median(e[(on + off) // 2 - 10 : (on + off) // 2 + 10]))
    assert held[0] > 10 * held[1]


def test_acquisition_config_keeps_the_sensed_area_and_checks_values():
    from eskin.data.simulator import acquisition_config

    cfg = acquisition_config(grid=(8, 8), rate_hz=1000.0)
    assert (cfg.rows, cfg.cols, cfg.pitch_mm, cfg.electrode_mm) == (8, 8, 6.0, 4.0)
    assert cfg.bpf_lowpass_hz == 800.0  # below the simulation's 1 kHz Nyquist
    assert acquisition_config() == SimulatorConfig()
    for kw, text in (({"grid": (0, 4)}, "grid 0x4"), ({"rate_hz": 5.0}, "rate 5 Hz"),
                     ({"duration_s": 0.5}, "duration 0.5 s"),
                     ({"modalities": ("finger", "glove")}, "modalities")):
        with pytest.raises(ValueError, match=text):
            acquisition_config(**kw)
    with pytest.raises(ValueError, match="press_hold_s must be positive"):
        SimulatorConfig(press_hold_s=0.0)


def test_cli_simulate_a_press_campaign_and_its_errors(tmp_path):
    from typer.testing import CliRunner

    from eskin.cli import app

    out = tmp_path / "p.h5"
    r = CliRunner().invoke(app, ["simulate", "-o", str(out), "--participants", "1", "--grid",
                                 "8x8", "--rate", "1000", "--duration", "3", "--modalities",
                                 "finger,press", "-q"])
    assert r.exit_code == 0, r.output
    assert "8 SIMULATED recordings" in r.output
    with load_campaign(out) as c:
        assert c.modalities == ["finger", "press"] and c.signals.shape[1:] == (8, 8, 3000)
    for args, text in ((["--grid", "8"], "--grid 8: expected ROWSxCOLS"),
                       (["--rate", "1"], "--rate 1.0: rate 1 Hz: must be in [10, 100000] Hz"),
                       (["--modalities", "press,glove"], "--modalities press,glove: ")):
        r = CliRunner().invoke(app, ["simulate", "-o", str(tmp_path / "x.h5"), *args, "-q"])
        assert r.exit_code == 2 and text in r.output and "Traceback" not in r.output
        assert not (tmp_path / "x.h5").exists()
