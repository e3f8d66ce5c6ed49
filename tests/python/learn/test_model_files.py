"""Model files written before the package was split into layers (their pickles name
eskin.models, eskin.estimators, eskin.preprocess, ...) still load."""

from __future__ import annotations

import sys

import joblib
import numpy as np
import pytest

import eskin.learn.estimators
import eskin.learn.models
import eskin.signal.preprocess
from eskin.deploy import load_model
from eskin.learn.estimators import TensorRLS
from eskin.learn.models import TouchModel
from eskin.signal.preprocess import WindowConfig


def _model() -> TouchModel:
    rng = np.random.default_rng(0)
    X = rng.standard_normal((8, 2, 2, 5))
    y = np.array([0, 1] * 4)
    est = TensorRLS(lam=1.0, sigma=1.0).fit(X, y)
    return TouchModel(
        classes=["a", "b"],
        estimator=est,
        machine="rls",
        selection="md",
        D=5,
        window="energy",
        subsample="algorithm2",
        sample_rate_hz=3000.0,
        grid_shape=(2, 2),
        window_config=WindowConfig(),
    )


def test_a_model_file_with_the_old_module_paths_loads(tmp_path, monkeypatch):
    model = _model()
    old_paths = {
        "eskin.models": eskin.learn.models,
        "eskin.estimators": eskin.learn.estimators,
        "eskin.preprocess": eskin.signal.preprocess,
    }
    with monkeypatch.context() as m:
        # pickle the classes under the paths an earlier eskin used
        for name, module in old_paths.items():
            m.setitem(sys.modules, name, module)
        m.setattr(TouchModel, "__module__", "eskin.models")
        m.setattr(TensorRLS, "__module__", "eskin.estimators")
        m.setattr(WindowConfig, "__module__", "eskin.preprocess")
        path = tmp_path / "old.joblib"
        joblib.dump({"header": model.header(), "model": model}, path)
    assert b"eskin.models" in path.read_bytes()  # the file names the old paths
    assert "eskin.models" not in sys.modules

    back = load_model(path)
    assert isinstance(back, TouchModel) and isinstance(back.estimator, TensorRLS)
    X = np.random.default_rng(1).standard_normal((3, 2, 2, 5))
    np.testing.assert_array_equal(
        back.estimator.decision_function(X), model.estimator.decision_function(X)
    )
    assert "eskin.models" not in sys.modules  # the old paths were only there while loading


def test_a_file_that_names_an_unknown_eskin_module_is_a_model_format_error(tmp_path):
    path = tmp_path / "bad.joblib"
    path.write_bytes(
        b"\x80\x04\x95\x1a\x00\x00\x00\x00\x00\x00\x00\x8c\x0eeskin.nowhere\x94\x8c\x01X\x94\x93\x94."
    )
    with pytest.raises(ValueError, match="bad.joblib is not an eskin model file"):
        load_model(path)


def test_the_other_files_of_eskin_are_named_not_unpickled(tmp_path):
    """A campaign, a replay, a journal, an array or an exported model given where a model
    file goes: one line saying what it is (a campaign was "cannot be read: KeyError: 72")."""
    from eskin.data.campaign import CampaignWriter, write_campaign
    from eskin.data.replay import write_replay_arrays
    from eskin.deploy.export import export_model
    from eskin.errors import ModelFormatError

    rng = np.random.default_rng(0)
    sig = rng.integers(-99, 99, (2, 2, 2, 50)).astype(np.int16)
    files = {
        "c.h5": (write_campaign(tmp_path / "c.h5", sig, modality=[0, 1], participant=[1, 1],
                                direction=[0, 0], run=[1, 1], modalities=["a", "b"],
                                sample_rate_hz=1000.0, volts_per_count=1.0,
                                source="recorded"),
                 "an eskin campaign (a model is trained from one: `eskin train CAMPAIGN -o "
                 "MODEL.joblib`)"),
        "r.model": (write_replay_arrays(tmp_path / "r.model", list(sig)).path,
                    "a replay file (eskin replay), not a model"),
        "a.joblib": (tmp_path / "a.joblib", "a numpy .npy array, not a model"),
        "m.bin": (tmp_path / "m.bin", "an exported model (eskin export); name it .eskin to "
                                      "load it"),
        "other.h5": (tmp_path / "other.h5", "an HDF5 file, not a model"),
    }
    np.save(tmp_path / "a.npy", sig)
    (tmp_path / "a.npy").rename(tmp_path / "a.joblib")
    export_model(_model(), tmp_path / "m.eskin").rename(tmp_path / "m.bin")
    import h5py

    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = np.arange(3)
    with pytest.raises(RuntimeError), CampaignWriter(
            tmp_path / "j.h5", grid_shape=(2, 2), n_samples=50, sample_rate_hz=1000.0,
            volts_per_count=1.0, modalities=["a"], source="recorded") as w:
        w.append(sig[0], modality=0, participant=1, direction=0, run=1)
        raise RuntimeError("stop: the journal is kept")
    files["j"] = (tmp_path / ".j.h5.partial", "a campaign writer's journal (eskin recover "
                                              "turns it into a campaign)")
    for name, (path, kind) in files.items():
        with pytest.raises(ModelFormatError) as info:
            load_model(path)
        assert str(info.value) == f"{path} is not an eskin model file: it is {kind}", name
