"""One window-to-tensor definition: training, ``predict --engine python``, ``--engine cpp`` and
the stream classifier compute the same tensor and the same decision values for a recording.

Every case runs the real compiled core on simulated campaigns of different grids and rates,
with a bounded window (``WindowConfig.window_samples``) much shorter than the touches, so the
stream keeps every 2nd, 4th, ... sample of a window: a batch path that read a window sample by
sample (skipping the stride) gives other tensors and fails here.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from eskin.data.campaign import load_campaign
from eskin.data.simulator import SimulatorConfig, simulate
from eskin.deploy.export import CompiledModel, export_model
from eskin.learn.models import load_model
from eskin.learn.training import train_model
from eskin.learn.training_set import preprocess_campaign
from eskin.signal.preprocess import TouchDetector, WindowConfig, detect_touches, preprocess

# (rows, cols, rate Hz, recording s, window_samples, D): windows of hundreds to thousands of
# samples kept in 16-64 samples; D below and above the kept count
CASES = {
    "1x4@100Hz": (1, 4, 100.0, 6.0, 16, 20),
    "4x4@3kHz": (4, 4, 3000.0, 4.0, 64, 50),
    "8x8@1kHz": (8, 8, 1000.0, 4.0, 32, 20),
    "19x27@100Hz": (19, 27, 100.0, 5.0, 16, 10),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def case(request, tmp_path_factory):
    rows, cols, rate, seconds, kept, D = CASES[request.param]
    path = tmp_path_factory.mktemp("one_tensor") / f"{request.param}.h5"
    top = 0.4 * rate  # the analog band below the simulation's Nyquist (oversample 2)
    cfg = SimulatorConfig(rows=rows, cols=cols, sample_rate_hz=rate, duration_s=seconds,
                          pitch_mm=44.0 / max(rows, cols, 2), electrode_mm=30.0 / max(rows, cols),
                          bpf_lowpass_hz=min(1500.0, top),
                          brush_band_hz=(min(15.0, top / 4), min(1200.0, top)))
    simulate(path, participants=2, seed=7, runs=(2,), config=cfg)
    camp = load_campaign(path)
    window_config = replace(WindowConfig(), window_samples=kept)
    model = train_model(
        camp, machine="svm", D=D, subsample="algorithm2", window_config=window_config,
        lambdas=[0.1], sigmas=[2.0], alphas=["1"], amplitudes=[None], negatives="all",
        quick=True, seed=0,
    )
    return request.param, camp, model


def _windows_decimated(camp, model) -> np.ndarray:
    idx = np.arange(len(camp))
    block = np.stack([np.asarray(camp.recording(int(i))) for i in idx])
    found = detect_touches(block, lengths=np.asarray(camp.lengths), sample_rate_hz=camp.sample_rate_hz,
                           config=model.window_config)
    return found.stride


def test_the_cases_exercise_the_bounded_window(case):
    _, camp, model = case
    stride = _windows_decimated(camp, model)
    assert (stride > 1).mean() > 0.5, f"strides {np.unique(stride)}: the case does not decimate"


def test_training_tensors_are_the_detector_s_tensors(case):
    """preprocess_campaign (training, predict --engine python) = preprocess(window="energy")
    = the tensor the stream detector computes when the touch ends."""
    _, camp, model = case
    idx = np.arange(len(camp))
    prep = preprocess_campaign(camp, idx, [(model.D, model.subsample)], config=model.window_config)
    X, windows = prep.X[(model.D, model.subsample)], prep.windows
    block = np.stack([np.asarray(camp.recording(int(i))) for i in idx])
    Y = preprocess(block, model.D, lengths=np.asarray(camp.lengths),
                   sample_rate_hz=camp.sample_rate_hz, config=model.window_config)
    np.testing.assert_array_equal(X, Y)
    compared = 0
    for i in idx:
        det = TouchDetector(model.grid_shape, camp.sample_rate_hz, model.window_config, D=model.D)
        rec = np.asarray(camp.recording(int(i)))[..., : int(camp.lengths[i])]
        touches = det.push(np.moveaxis(rec, -1, 0)) + det.flush()
        # the batch window is a touch of the stream, or the span of several (no stream twin)
        twin = [t for t in touches if (t.start, t.stop) == tuple(windows[i])]
        if twin:
            compared += 1
            np.testing.assert_array_equal(twin[0].tensor, X[i])
    assert compared >= 3


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_python_and_cpp_engines_give_the_same_decision_values(case, tmp_path, dtype):
    """``eskin predict m.eskin --engine python`` (Python tensors, the file's machines) and
    ``--engine cpp`` (the compiled classifier, tensors and all) on the same .eskin file."""
    name, camp, model = case
    path = export_model(model, tmp_path / f"{name}.eskin", dtype=dtype)
    loaded = load_model(path)
    py = loaded.predict_recordings(camp)
    cpp = CompiledModel(path).predict_recordings(camp)
    tol = 1e-9 if dtype == "float64" else 1e-6
    vp = np.array([p["decision_values"] for p in py])
    vc = np.array([p["decision_values"] for p in cpp])
    scale = max(1.0, float(np.abs(vp).max()))
    assert np.abs(vp - vc).max() <= tol * scale, f"worst {np.abs(vp - vc).max():.3g}"
    assert [p["label"] for p in py] == [p["label"] for p in cpp]


def test_the_stream_decides_as_the_batch_path(case):
    """Each recording pushed sample by sample through the compiled StreamClassifier: the touch
    whose window is the batch path's has the batch path's decision values."""
    _, camp, model = case
    compiled = CompiledModel.from_model(model, dtype="float64")
    batch = compiled.predict_recordings(camp)
    python = model.predict_recordings(camp)
    compared = 0
    for i, (b, p) in enumerate(zip(batch, python)):
        rec = np.asarray(camp.recording(i))[..., : int(camp.lengths[i])]
        np.testing.assert_allclose(p["decision_values"], b["decision_values"], rtol=0, atol=1e-9)
        twin = [e for e in compiled.stream(rec) if list(e.get("window", ())) == b["window"]]
        if twin:  # the batch window is one of the stream's touches (not a span of several)
            compared += 1
            np.testing.assert_allclose(twin[0]["values"], b["decision_values"], rtol=0, atol=1e-9)
    assert compared >= 3


def test_given_windows_keep_or_drop_the_stride_as_asked(case):
    """The detector's windows handed back with their strides give the detector's tensors; the
    same windows as plain [start, stop) pairs are read sample by sample (and differ)."""
    _, camp, model = case
    idx = np.arange(len(camp))
    block = np.stack([np.asarray(camp.recording(int(i))) for i in idx])
    lens = np.asarray(camp.lengths)
    kw = dict(lengths=lens, sample_rate_hz=camp.sample_rate_hz, config=model.window_config)
    found = detect_touches(block, **kw)
    energy = preprocess(block, model.D, **kw)
    np.testing.assert_array_equal(preprocess(block, model.D, window=found, **kw), energy)
    plain = preprocess(block, model.D, window=found.windows, **kw)
    decimated = found.stride > 1
    assert decimated.any()
    differs = np.any(plain != energy, axis=(1, 2, 3))
    assert differs[decimated].mean() > 0.5
    np.testing.assert_array_equal(plain[~decimated], energy[~decimated])


def test_a_given_stride_that_no_stream_has_is_refused():
    x = np.zeros((1, 2, 2, 100), np.int16)
    for stride, why in ((3, "power of two"), (0, "power of two"), (128, "stop - start = 90")):
        with pytest.raises(ValueError, match=rf"windows\[0\]: stride = {stride}: .*{why}"):
            preprocess(x, 10, window=np.array([[10, 100, stride]]))
