"""The calibrated rule in a `.eskin` file (format version 4, section CALB): the compiled C++
classifier decides as the Python model, an old file keeps the paper's rule, a bad CALB section is
refused naming the field and the value."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from learn_data import small_simulated

from eskin.deploy.export import CompiledModel, ModelFormatError, export_model, model_to_bytes
from eskin.deploy.export import spec_from_model
from eskin.learn.models import load_model, save_model
from eskin.learn.training import train_model

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    from eskin.data.campaign import load_campaign

    return load_campaign(small_simulated(tmp_path_factory.getbasetemp()))


def _train(campaign, **kw):
    """A model of participants 0-3 (the campaign's 4 and 5 are new people to it)."""
    keep = np.flatnonzero(np.asarray(campaign.participant) < 4)
    names = [campaign.modalities[int(m)] for m in np.asarray(campaign.modality)[keep]]
    return train_model(np.asarray(campaign.signals)[keep], names,
                       lengths=np.asarray(campaign.lengths)[keep],
                       sample_rate_hz=float(campaign.sample_rate_hz), machine="svm", D=20,
                       subsample="algorithm2", negatives="all", quick=True, seed=0, **kw)


@pytest.fixture(scope="module")
def model(campaign):
    return _train(campaign, reject=0.3)


def _signals(campaign):
    return np.asarray(campaign.signals), np.asarray(campaign.lengths)


@pytest.mark.parametrize("dtype, tol", [("float64", 1e-9), ("float32", 1e-6)])
def test_compiled_classifier_decides_as_the_python_model(model, campaign, dtype, tol):
    X = model.preprocess(campaign)
    pred, F, dk, conf = model.decide(X)
    assert 0 < dk.sum() < len(dk)
    cm = CompiledModel.from_model(model, dtype=dtype)
    assert cm.format_version == 4 and cm.decision_rule == "calibrated"
    for d in (cm.classify(*_signals(campaign)), cm.classify_tensors(X)):
        np.testing.assert_array_equal(d.label_indices, pred)
        np.testing.assert_array_equal(d.dont_know, dk)
        np.testing.assert_allclose(d.decision_values, F, atol=tol, rtol=0)
        np.testing.assert_allclose(d.confidence, conf, atol=tol, rtol=0)


def test_files_keep_the_rule_and_predict_the_same(model, campaign, tmp_path):
    ref = model.predict_recordings(campaign)
    joblib_model = load_model(save_model(model, tmp_path / "m.joblib"))
    eskin_model = load_model(export_model(model, tmp_path / "m.eskin", dtype="float64"))
    compiled = CompiledModel(tmp_path / "m.eskin")
    np.testing.assert_allclose(eskin_model.calibration.slopes, model.calibration.slopes)
    assert eskin_model.calibration.threshold == model.calibration.threshold
    for preds in (joblib_model.predict_recordings(campaign),
                  eskin_model.predict_recordings(campaign),
                  compiled.predict_recordings(campaign)):
        assert [p["label"] for p in preds] == [p["label"] for p in ref]
        assert [p["dont_know"] for p in preds] == [p["dont_know"] for p in ref]
        np.testing.assert_allclose([p["confidence"] for p in preds],
                                   [p["confidence"] for p in ref], atol=1e-9)


def test_a_paper_rule_model_and_an_old_file_keep_the_papers_rule(campaign):
    from eskin.learn.estimators import one_vs_all_rule

    paper = _train(campaign, decision="paper")
    cm = CompiledModel.from_model(paper, dtype="float64")
    assert cm.format_version <= 3 and cm.decision_rule == "paper" and cm.calibration() is None
    d = cm.classify(*_signals(campaign))
    want, _, want_dk = one_vs_all_rule(d.decision_values)
    np.testing.assert_array_equal(d.label_indices, want)
    np.testing.assert_array_equal(d.dont_know, want_dk)
    assert np.isnan(d.confidence).all()
    old = CompiledModel(DATA / "model_small_float64.eskin")  # written before format version 4
    assert old.format_version == 1 and old.decision_rule == "paper"


def _calb_offset(blob: bytes) -> int:
    pos = 32
    while True:
        tag, n = struct.unpack_from("<4sI", blob, pos)
        if tag == b"CALB":
            return pos + 8
        pos += 8 + (n + 7) // 8 * 8


def _edited(blob: bytes, offset: int, fmt: str, value) -> bytes:
    b = bytearray(blob)
    struct.pack_into(fmt, b, offset, value)
    struct.pack_into("<I", b, len(b) - 4, zlib.crc32(bytes(b[:-4])) & 0xFFFFFFFF)
    return bytes(b)


@pytest.mark.parametrize("field, at, fmt, value, message", [
    ("threshold", 8, "<d", 1.5, "section CALB: threshold=1.5 must be within [0, 1]"),
    ("slope", 16 + 16, "<d", float("nan"), "section CALB: machine 1: slope=nan"),
    ("slope", 16, "<d", -2.0, "section CALB: machine 0: slope=-2 must be within [0, 1e+06]"),
    ("offset", 16 + 32 + 8, "<d", float("inf"), "section CALB: machine 2: offset=inf"),
    ("n_machines", 4, "<I", 2, "section CALB: n_machines=2 differs from MACH's n_machines=3"),
    ("rule", 0, "<I", 7, "section CALB: rule=7 is unknown"),
])
def test_a_bad_calb_section_names_the_field_and_value(model, field, at, fmt, value, message):
    blob = model_to_bytes(spec_from_model(model), "float64")
    bad = _edited(blob, _calb_offset(blob) + at, fmt, value)
    with pytest.raises(ModelFormatError) as err:
        CompiledModel(bad)
    assert message in str(err.value) and field in str(err.value)


def test_the_writer_refuses_a_calibration_the_loader_would_refuse(model):
    from dataclasses import replace

    spec = spec_from_model(model)
    for t in (1.2, -0.1):
        spec.calibration = replace(model.calibration, threshold=t)
        with pytest.raises(ModelFormatError) as info:
            model_to_bytes(spec, "float64")
        assert str(info.value) == f"calibration: threshold={t!r} must be within [0, 1]"
    for t in (0.0, 1.0):  # the ends are thresholds
        spec.calibration = replace(model.calibration, threshold=t)
        assert CompiledModel(model_to_bytes(spec, "float64")).calibration().threshold == t
    a, b = list(model.calibration.slopes), list(model.calibration.offsets)
    for slopes, offsets in ((a[:2], b), (a + [1.0], b), (a, b[:2]), (a, b + [0.0])):
        spec.calibration = replace(model.calibration, slopes=slopes, offsets=offsets)
        with pytest.raises(ModelFormatError) as info:
            model_to_bytes(spec, "float64")
        assert str(info.value) == (f"calibration: {len(slopes)} slopes and {len(offsets)} "
                                   f"offsets for 3 machines")
    # the ends of the ranges, the writer's as the loader's: slopes in [0, 1e6], offsets in
    # [-1e6, 1e6]; just outside, refused naming the machine
    k = len(model.calibration.slopes)
    for a, b in ((0.0, 1e6), (1e6, -1e6)):
        spec.calibration = replace(model.calibration, slopes=[a] * k, offsets=[b] * k)
        cm = CompiledModel(model_to_bytes(spec, "float64"))
        assert cm.decision_rule == "calibrated"
    for a, b in ((-5e-324, 0.0), (1e6 * (1 + 2**-52), 0.0), (1.0, -1e6 * (1 + 2**-52))):
        spec.calibration = replace(model.calibration, slopes=[a] * k, offsets=[b] * k)
        with pytest.raises(ModelFormatError, match=r"^calibration: machine 0: slope="):
            model_to_bytes(spec, "float64")
