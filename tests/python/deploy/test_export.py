"""Deployment: the .eskin format, the C++ classifier against Python, the C header, eskin-classify.

Parity in the emlearn/m2cgen manner: the same simulated recordings go through the C++ classifier
(raw samples in, decisions out) and through Python (eskin.preprocess + the Python model), for
several models and D; labels must be identical and decision values within 1e-9 (float64 model)
or 1e-4 relative (float32 model).
"""

from __future__ import annotations

import json
import re
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

import eskin
from deploy_data import fit_machine
from eskin._paths import find_executable
from eskin.deploy.export import (
    CompiledModel,
    MachineSpec,
    ModelFormatError,
    ModelSpec,
    export_model,
    model_to_bytes,
    write_c_header,
)

REPO = Path(__file__).resolve().parents[3]


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="session")
def campaign(tmp_path_factory):
    """A small simulated campaign: 4 participants, run 2, 24 recordings (simulated data)."""
    path = tmp_path_factory.mktemp("campaign") / "sim.h5"
    eskin.simulate(path, participants=4, seed=11, runs=(2,))
    return eskin.load_campaign(path, in_memory=True)


def _signals(campaign):
    return np.asarray(campaign.signals), np.asarray(campaign.lengths)


def _patterns(campaign, D, subsample="algorithm2", window="energy"):
    sig, lengths = _signals(campaign)
    return eskin.preprocess(
        sig, D, lengths=lengths, sample_rate_hz=campaign.sample_rate_hz, window=window,
        subsample=subsample,
    )


def _random_spec(campaign, D, n_classes, *, seed=0, mixed_alphas=False, subsample="algorithm2"):
    """Machines whose support vectors are real patterns of the campaign, with random
    coefficients; sigma chosen so that kernel values are neither all 0 nor all 1."""
    rng = np.random.default_rng(seed)
    X = _patterns(campaign, D, subsample)
    full = eskin.resolve_alphas(X.shape[1:], "full")
    half = eskin.resolve_alphas(X.shape[1:], "half")
    machines = []
    n_machines = 1 if n_classes == 2 else n_classes
    for k in range(n_machines):
        idx = np.sort(rng.choice(len(X) // 2, size=8, replace=False))  # first half: SVs
        alphas = half if not (mixed_alphas and k == 1) else (1, full[1], max(1, full[2] - 3))
        sig = (1.5, 1.2, 2.0)
        pos, neg = ((1, 0) if n_classes == 2 else (k, -1))
        machines.append(MachineSpec(pos, neg, float(rng.normal(0, 0.1)), alphas, sig, X[idx],
                                    rng.normal(0, 1, size=8)))
    return ModelSpec(
        class_names=list(campaign.modalities[:n_classes]) if n_classes <= 3 else
        [f"c{k}" for k in range(n_classes)],
        rule="binary" if n_classes == 2 else "one_vs_all",
        machines=machines,
        D=D,
        grid_shape=X.shape[1:3],
        window="energy",
        subsample=subsample,
        sample_rate_hz=campaign.sample_rate_hz,
        window_config=eskin.WindowConfig(),
    )


def _python_decisions(spec, X):
    """Decision values of a ModelSpec computed in Python (eskin.tensor_kernel), and the
    scale sum_i |c_i| K_i + |b| used for relative tolerances."""
    F, S = [], []
    for m in spec.machines:
        K = eskin.tensor_kernel(X, m.support_vectors, sigma=m.sigmas, alpha=m.alphas)
        F.append(K @ m.dual_coef + m.intercept)
        S.append(K @ np.abs(m.dual_coef) + abs(m.intercept))
    return np.stack(F, axis=1), np.stack(S, axis=1)


def _python_labels(spec, F):
    if spec.rule == "binary":
        m = spec.machines[0]
        return np.where(F[:, 0] > 0, m.positive, m.negative), np.zeros(len(F), bool)
    claims = F > 0
    n = claims.sum(axis=1)
    return np.where(n == 1, np.argmax(claims, axis=1), np.argmax(F, axis=1)), n != 1


# ----------------------------------------------------------------------------- the format


def test_layout_header_and_checksum(campaign):
    spec = _random_spec(campaign, 20, 3)
    data = model_to_bytes(spec)
    assert data[:8] == b"\x89ESKIN\r\n"
    version, header_bytes, flags, size, n_sections = struct.unpack_from("<HHIII", data, 8)
    # the default WindowConfig has a bounded window (window_samples): format version 3
    assert (version, header_bytes, flags, size) == (3, 32, 0, len(data))
    assert n_sections == 5
    assert struct.unpack("<I", data[-4:])[0] == zlib.crc32(data[:-4])
    assert struct.unpack_from("<I", model_to_bytes(spec, "float64"), 12)[0] == 1  # flag float64


def _with_version(data: bytes, version: int) -> bytes:
    body = data[:8] + struct.pack("<H", version) + data[10:-4]
    return body + struct.pack("<I", zlib.crc32(body) & 0xFFFFFFFF)


def test_version_3_holds_the_bounded_window_and_older_files_load_unbounded(campaign):
    """window_samples > 0 is written as version 3 (20 window fields); window_samples = 0 as
    before (version 1, 19 fields), which the loader reads as an unbounded window; each version
    is refused with the other's field count, naming the field."""
    spec = _random_spec(campaign, 20, 3)
    spec.window_config = eskin.WindowConfig(window_samples=256)
    v3 = model_to_bytes(spec)
    cm = CompiledModel(v3)
    assert cm.format_version == 3 and cm.window_config["window_samples"] == 256
    spec.window_config = eskin.WindowConfig(window_samples=0)
    v1 = model_to_bytes(spec)
    assert struct.unpack_from("<H", v1, 8)[0] == 1 and len(v1) == len(v3) - 40  # one name + f64
    cm1 = CompiledModel(v1)
    assert cm1.format_version == 1 and cm1.window_config["window_samples"] == 0
    with pytest.raises(ModelFormatError, match=r"n_window_fields=20, expected 19 .*version 1"):
        CompiledModel(_with_version(v3, 1))
    with pytest.raises(ModelFormatError, match=r"n_window_fields=19, expected 20 .*version 3"):
        CompiledModel(_with_version(v1, 3))


def test_metadata_round_trips_through_the_cpp_loader(campaign):
    spec = _random_spec(campaign, 20, 3, mixed_alphas=True)
    cm = CompiledModel(model_to_bytes(spec, "float64"))
    assert cm.class_names == ["brush", "finger", "washer"]
    assert cm.rule == "one_vs_all" and cm.D == 20 and cm.grid_shape == (4, 4)
    assert cm.window == "energy" and cm.subsample == "algorithm2"
    assert cm.sample_rate_hz == campaign.sample_rate_hz
    assert cm.window_config == dict(
        zip(eskin.WindowConfig.field_names(), eskin.WindowConfig().to_array())
    )
    for m, got in zip(spec.machines, cm.machines):
        assert got["alphas"] == tuple(m.alphas)
        assert got["sigmas"] == pytest.approx(m.sigmas, abs=0)
        assert got["intercept"] == m.intercept
        assert sorted(got["coef"]) == sorted(m.dual_coef.tolist())
    assert cm.alpha_store == tuple(max(m.alphas[z] for m in spec.machines) for z in range(3))


def test_support_vectors_are_deduplicated_across_machines(campaign):
    spec = _random_spec(campaign, 20, 3, seed=4)
    unique = {x.tobytes() for m in spec.machines for x in m.support_vectors}
    total = sum(len(m.support_vectors) for m in spec.machines)
    assert len(unique) < total  # the fixture draws overlapping support vectors
    cm = CompiledModel(model_to_bytes(spec))
    assert cm.n_support == len(unique)
    # size: bases in float32 + a small header/metadata part
    N = [4 * 20, 4 * 20, 16]
    bases_bytes = sum(len(unique) * n * a * 4 for n, a in zip(N, cm.alpha_store))
    assert bases_bytes < cm.file_bytes < bases_bytes + 2048 + 8 * total


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda b: b"PK\x03\x04" + b[4:], "not an eskin model"),
        (lambda b: b[:8] + b"\x07" + b[9:], "version 7 is not supported"),
        (lambda b: b[:100] + bytes([b[100] ^ 1]) + b[101:], "checksum mismatch"),
        (lambda b: b[: len(b) // 2], "truncated"),
        (lambda b: b + b"\x00", "unexpected bytes"),
    ],
    ids=["foreign", "version", "checksum", "truncated", "trailing"],
)
def test_bad_files_give_clear_errors(campaign, tmp_path, mutate, message):
    good = model_to_bytes(_random_spec(campaign, 20, 2))
    path = tmp_path / "bad.eskin"
    path.write_bytes(mutate(good))
    with pytest.raises(ModelFormatError, match=message) as err:
        CompiledModel(path)
    assert str(path) in str(err.value)


def test_inconsistent_sizes_are_rejected_even_with_a_valid_checksum(campaign):
    good = bytearray(model_to_bytes(_random_spec(campaign, 20, 2)))
    prep = 32 + 8  # first section payload
    struct.pack_into("<I", good, prep + 8, 21)  # D: 20 -> 21, SV bases stay for D = 20
    good[-4:] = struct.pack("<I", zlib.crc32(bytes(good[:-4])))
    with pytest.raises(ModelFormatError, match="differ from the preprocessing"):
        CompiledModel(bytes(good))


def test_invalid_descriptions_are_rejected_before_writing(campaign):
    spec = _random_spec(campaign, 20, 2)
    spec.machines[0].alphas = (5, 2, 8)
    with pytest.raises(ModelFormatError, match=r"alpha\[0\]=5 out of range"):
        model_to_bytes(spec)
    spec = _random_spec(campaign, 20, 2)
    spec.class_names = ["brush", "a" * 40]
    with pytest.raises(ModelFormatError, match="at most 31"):
        model_to_bytes(spec)
    with pytest.raises(ModelFormatError, match="dtype"):
        model_to_bytes(_random_spec(campaign, 20, 2), "float16")


def test_missing_file():
    with pytest.raises(FileNotFoundError, match="does not exist"):
        CompiledModel("/nonexistent/model.eskin")


# ----------------------------------------------------------------------------- parity


@pytest.mark.parametrize("D", [20, 50, 100])
@pytest.mark.parametrize("n_classes", [2, 3])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_parity_with_python_kernel(campaign, D, n_classes, dtype):
    spec = _random_spec(campaign, D, n_classes, seed=D + n_classes, mixed_alphas=n_classes == 3)
    X = _patterns(campaign, D)
    F, scale = _python_decisions(spec, X)
    labels, dont_know = _python_labels(spec, F)
    cm = CompiledModel(model_to_bytes(spec, dtype))
    sig, lengths = _signals(campaign)
    got = cm.classify(sig, lengths)  # raw int16 recordings in
    np.testing.assert_array_equal(got.label_indices, labels)
    np.testing.assert_array_equal(got.dont_know, dont_know)
    if dtype == "float64":
        np.testing.assert_allclose(got.decision_values, F, rtol=0, atol=1e-9)
    else:
        assert np.all(np.abs(got.decision_values - F) <= 1e-4 * scale)
    windows = eskin.detect_windows(sig, lengths=lengths, sample_rate_hz=campaign.sample_rate_hz)
    np.testing.assert_array_equal(got.windows, np.asarray(windows).reshape(-1, 2))


def _fit(campaign, D, machine, n_classes, alpha):
    """A real machine trained on the first 3 participants (simulated data)."""
    return fit_machine(campaign, D, machine, n_classes, alpha=alpha)


@pytest.mark.parametrize("D", [20, 50])
@pytest.mark.parametrize("machine", ["svm", "rls"])
@pytest.mark.parametrize("n_classes", [2, 3])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_parity_with_trained_estimators(campaign, D, machine, n_classes, dtype):
    """Trained TensorSVC / TensorRLS / OneVsAllTouchClassifier: C++ on the raw recordings of
    the whole campaign (held-out participant included) against Python on eskin.preprocess."""
    from eskin.deploy.export import spec_from_estimator

    alpha = "half" if machine == "svm" else "full"
    est, X = _fit(campaign, D, machine, n_classes, alpha)
    names = list(campaign.modalities[:n_classes])
    spec = spec_from_estimator(est, names, D=D, grid_shape=(4, 4),
                               sample_rate_hz=campaign.sample_rate_hz)
    cm = CompiledModel(model_to_bytes(spec, dtype))
    got = cm.classify(*_signals(campaign))
    F = np.asarray(est.decision_function(X), float).reshape(len(X), -1)
    if n_classes == 2:
        labels, dont_know = (F[:, 0] > 0).astype(int), np.zeros(len(X), bool)
    else:
        labels, dont_know = est.predict(X), est.dont_know_
    np.testing.assert_array_equal(got.label_indices, labels)
    np.testing.assert_array_equal(got.dont_know, dont_know)
    if dtype == "float64":
        np.testing.assert_allclose(got.decision_values, F, rtol=0, atol=1e-9)
    else:
        _, scale = _python_decisions(spec, X)
        assert np.all(np.abs(got.decision_values - F) <= 1e-4 * scale)


def test_even_subsampling_and_no_window(campaign):
    spec = _random_spec(campaign, 50, 3, subsample="even")
    spec.window = "none"
    X = _patterns(campaign, 50, subsample="even", window="none")
    F, _ = _python_decisions(spec, X)
    got = CompiledModel(model_to_bytes(spec, "float64")).classify(*_signals(campaign))
    np.testing.assert_allclose(got.decision_values, F, rtol=0, atol=1e-9)


def _two_touches(n, seed):
    """Recordings with two or three separate touches of different energies (4x4, int16)."""
    rng = np.random.default_rng(seed)
    T = 15000
    x = rng.normal(0, 12, size=(n, 4, 4, T))
    t = np.arange(T)
    for i in range(n):
        for start, amp in zip(sorted(rng.choice(np.arange(1000, 13000, 2500), 3, replace=False)),
                              rng.uniform(30, 900, size=3)):
            L = int(rng.integers(600, 2000))
            burst = amp * np.sin(2 * np.pi * rng.uniform(30, 300) * t[:L] / 3000.0)
            x[i, :, :, start : start + L] += burst * rng.uniform(0.3, 1.0, size=(4, 4, 1))
    return np.clip(x, -32768, 32767).astype(np.int16)


@pytest.mark.parametrize("select", ["energy", "first", "span"])
def test_window_choice_with_several_touches_matches_detect_windows(campaign, select):
    cfg = eskin.WindowConfig(select=select)
    spec = _random_spec(campaign, 20, 3)
    spec.window_config = cfg
    sig = _two_touches(8, seed=5)
    cm = CompiledModel(model_to_bytes(spec, "float64"))
    got = cm.classify(sig)
    ref = np.asarray(eskin.detect_windows(sig, config=cfg)).reshape(-1, 2)
    np.testing.assert_array_equal(got.windows, ref)
    X = eskin.preprocess(sig, 20, config=cfg)
    F, _ = _python_decisions(spec, X)
    np.testing.assert_allclose(got.decision_values, F, rtol=0, atol=1e-9)


def test_stream_classifier_decides_like_the_batch_classifier(campaign):
    spec = _random_spec(campaign, 50, 3)
    spec.window_config = eskin.WindowConfig(select="energy")  # batch: one of the stream's touches
    cm = CompiledModel(model_to_bytes(spec, "float64"))
    sig, lengths = _signals(campaign)
    batch = cm.classify(sig[:6], lengths[:6])
    for i in range(6):
        events = cm.stream(sig[i, :, :, : lengths[i]])
        decisions = [e for e in events if e["status_name"] == "decision"]
        assert decisions, f"recording {i}: no touch detected by the stream classifier"
        # the batch window is the most energetic touch; the stream reports every touch
        match = [e for e in decisions if tuple(e["window"]) == tuple(batch.windows[i])]
        assert len(match) == 1
        assert match[0]["label"] == batch.labels[i]
        np.testing.assert_allclose(match[0]["values"], batch.decision_values[i], atol=1e-12)


def test_classify_rejects_bad_input(campaign):
    cm = CompiledModel(model_to_bytes(_random_spec(campaign, 20, 2)))
    with pytest.raises(ValueError, match="expected shape"):
        cm.classify(np.zeros((2, 3, 4, 100), np.int16))
    x = np.asarray(campaign.signals[:2], dtype=np.float64)
    x[1, 0, 0, 10] = np.nan
    with pytest.raises(ValueError, match="recording 1 cannot be classified: it holds NaN"):
        cm.classify(x)


# ----------------------------------------------------------------------------- C header


def test_c_header_compiles_and_classifies_identically(campaign, tmp_path):
    cxx = shutil.which("g++")
    lib = _core_library()
    if cxx is None or lib is None:
        pytest.skip("g++ or the built libeskin_core.a is not available")
    spec = _random_spec(campaign, 20, 3)
    model_file = export_model(spec, tmp_path / "m.eskin")
    header = write_c_header(model_file, tmp_path / "model.h", name="touch_model")
    text = header.read_text()
    assert "TOUCH_MODEL_ALIGN static const unsigned char touch_model_data[" in text
    assert "#define TOUCH_MODEL_D 20" in text
    src = tmp_path / "main.cpp"
    src.write_text(
        '#include <cstdio>\n#include <vector>\n#include "eskin/model.hpp"\n#include "model.h"\n'
        "int main(int argc, char** argv) {\n"
        "  const eskin::Model m = eskin::Model::view_bytes(touch_model_data, touch_model_size);\n"
        "  const unsigned char* b = reinterpret_cast<const unsigned char*>(m.bases_f32(0));\n"
        "  std::printf(\"%d\\n\", b > touch_model_data && b < touch_model_data + touch_model_size);\n"
        "  eskin::Classifier clf(m);\n"
        "  std::FILE* f = std::fopen(argv[1], \"rb\");\n"
        "  const int n = std::atoi(argv[2]), T = std::atoi(argv[3]);\n"
        "  std::vector<short> x(16 * (size_t)T);\n"
        "  for (int i = 0; i < n; ++i) {\n"
        "    if (std::fread(x.data(), 2, x.size(), f) != x.size()) return 3;\n"
        "    eskin::Decision d;\n"
        "    if (clf.classify(x.data(), 4, 4, T, T, &d) != eskin::ClassifyStatus::kOk) return 4;\n"
        "    std::printf(\"%d\", d.label);\n"
        "    for (int k = 0; k < d.n_machines; ++k) std::printf(\" %.17g\", d.values[k]);\n"
        "    std::printf(\"\\n\");\n"
        "  }\n  return argc > 0 ? 0 : 1;\n}\n"
    )
    exe = tmp_path / "firmware"
    subprocess.run(
        [cxx, "-std=c++17", "-O1", f"-I{REPO / 'cpp/include'}", f"-I{tmp_path}", str(src),
         str(lib), "-lpthread", "-o", str(exe)],
        check=True, capture_output=True,
    )
    sig = np.ascontiguousarray(np.asarray(campaign.signals[:5]), dtype="<i2")
    raw = tmp_path / "rec.bin"
    raw.write_bytes(sig.tobytes())
    out = subprocess.run([str(exe), str(raw), "5", str(sig.shape[-1])], check=True,
                         capture_output=True, text=True).stdout.split("\n")
    assert out[0] == "1"  # view_bytes reads the bases in place from the aligned array
    ref = CompiledModel(model_file).classify(sig)
    for i in range(5):
        fields = out[i + 1].split()
        assert int(fields[0]) == ref.label_indices[i]
        np.testing.assert_array_equal(np.array(fields[1:], float), ref.decision_values[i])


def _core_library():
    import os

    for d in filter(None, [os.environ.get("ESKIN_BIN_DIR"), REPO / "build/dev", REPO / "build/cpp"]):
        p = Path(d) / "libeskin_core.a"
        if p.is_file():
            return p
    return None


# ----------------------------------------------------------------------------- eskin-classify


def _eskin_classify():
    try:
        return str(find_executable("eskin-classify"))
    except FileNotFoundError:
        pytest.skip("eskin-classify is not built")


def _parse(stdout):
    lines = [ln for ln in stdout.splitlines() if ln and not ln.startswith("#")]
    header = lines[0].split("\t")
    rows = [dict(zip(header, ln.split("\t"))) for ln in lines[1:]]
    return header, rows


def test_eskin_classify_npy_and_raw_stdin(campaign, tmp_path):
    exe = _eskin_classify()
    spec = _random_spec(campaign, 50, 3)
    model_file = export_model(spec, tmp_path / "m.eskin", dtype="float64")
    sig = np.asarray(campaign.signals[:6])
    ref = CompiledModel(model_file).classify(sig)
    npy = tmp_path / "rec.npy"
    np.save(npy, sig)
    res = subprocess.run([exe, str(model_file), str(npy)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    header, rows = _parse(res.stdout)
    assert header[:5] == ["index", "label", "dont_know", "window_start", "window_stop"]
    assert [r["label"] for r in rows] == list(ref.labels)
    vals = np.array([[float(r[h]) for h in header[5:]] for r in rows])
    np.testing.assert_array_equal(vals, ref.decision_values)
    # one recording as float32 (rows, cols, T)
    np.save(npy, sig[2].astype(np.float32))
    res = subprocess.run([exe, str(model_file), str(npy)], capture_output=True, text=True)
    assert _parse(res.stdout)[1][0]["label"] == ref.labels[2]
    # raw records on standard input
    raw = b"".join(
        b"ESKR" + struct.pack("<HHII", 4, 4, r.shape[-1], 0) + r.astype("<i2").tobytes()
        for r in sig
    )
    res = subprocess.run([exe, str(model_file), "-"], input=raw, capture_output=True)
    assert res.returncode == 0, res.stderr
    assert [r["label"] for r in _parse(res.stdout.decode())[1]] == list(ref.labels)


@pytest.mark.parametrize(
    ("which", "message"),
    [
        ("model", "a .npy array (recordings), not a .eskin model"),
        ("input", "an eskin model (.eskin), not recordings"),
        ("grid", "model expects 4x4"),
    ],
)
def test_eskin_classify_errors(campaign, tmp_path, which, message):
    exe = _eskin_classify()
    model_file = export_model(_random_spec(campaign, 20, 2), tmp_path / "m.eskin")
    npy = tmp_path / "rec.npy"
    np.save(npy, np.zeros((3, 4, 50), np.int16) if which == "grid" else np.zeros((4, 4, 50), np.int16))
    args = {"model": [str(npy), str(npy)], "input": [str(model_file), str(model_file)],
            "grid": [str(model_file), str(npy)]}[which]
    res = subprocess.run([exe, *args], capture_output=True, text=True)
    assert res.returncode == 2
    assert message in res.stderr


# ----------------------------------------------------------------------------- CLI export


def test_cli_export_writes_model_and_header(campaign, tmp_path):
    from eskin.learn.models import TouchModel, save_model

    est, _ = _fit(campaign, 20, "svm", 2, "half")
    model = TouchModel(
        classes=list(campaign.modalities[:2]), estimator=est, machine="svm", selection="fixed",
        D=20, window="energy", subsample="algorithm2", sample_rate_hz=campaign.sample_rate_hz,
        grid_shape=(4, 4),
    )
    src = save_model(model, tmp_path / "model.joblib")
    out = tmp_path / "model.eskin"
    header = tmp_path / "model.h"
    res = _eskin("export", src, "-o", out, "--float64", "--c-header", header)
    assert "support vectors" in res.stdout
    cm = CompiledModel(out)
    assert cm.is_float64 and cm.class_names == list(campaign.modalities[:2])
    assert "eskin_model_data" in header.read_text()
    X = _patterns(campaign, 20)
    np.testing.assert_allclose(cm.classify(*_signals(campaign)).decision_values[:, 0],
                               est.decision_function(X), rtol=0, atol=1e-9)
    # a .eskin file loads back as a TouchModel (Python preprocessing, C++ machines)
    from eskin.deploy import load_model

    back = load_model(out)
    np.testing.assert_allclose(back.decision_function(X), est.decision_function(X), atol=1e-9)
    res = _eskin("export", out, "-o", tmp_path / "again.eskin", check=False)
    assert res.returncode == 2 and "already an exported" in res.stderr
    res = _eskin("export", header, "-o", tmp_path / "x.eskin", check=False)
    assert res.returncode == 2 and "error:" in res.stderr and "Traceback" not in res.stderr


def test_cli_export_prints_the_sizes_and_warns_above_the_documented_size(
        campaign, tmp_path, monkeypatch):
    """eskin export prints the size of the model file and of the C header, and warns (on
    stderr, still writing) when the model is larger than EXPORT_WARN_BYTES, the flash of a
    Cortex-M4F (1 MiB); the check is taken down to this test's small model."""
    from typer.testing import CliRunner

    import eskin.cli.deploy as cli_deploy
    from eskin.cli import app
    from eskin.deploy.target import TARGETS
    from eskin.learn.models import TouchModel, save_model

    assert cli_deploy.EXPORT_WARN_BYTES == TARGETS["cortex-m4"].flash_bytes == 1 << 20
    est, _ = _fit(campaign, 20, "svm", 2, "half")
    model = TouchModel(
        classes=list(campaign.modalities[:2]), estimator=est, machine="svm", selection="fixed",
        D=20, window="energy", subsample="algorithm2", sample_rate_hz=campaign.sample_rate_hz,
        grid_shape=(4, 4),
    )
    src = save_model(model, tmp_path / "model.joblib")
    out, header = tmp_path / "a.eskin", tmp_path / "a.h"
    r = CliRunner().invoke(app, ["export", str(src), "-o", str(out), "--c-header", str(header)])
    assert r.exit_code == 0, r.output
    n, h = out.stat().st_size, header.stat().st_size
    assert f"wrote {out}: {n} bytes, " in r.stdout and "warning" not in r.output
    assert f"wrote {header}: {cli_deploy._size(h)} of C source" in r.stdout
    assert cli_deploy._size(h) in (f"{h} bytes", f"{h / 1024:.1f} KiB ({h} bytes)")
    monkeypatch.setattr(cli_deploy, "EXPORT_WARN_BYTES", n - 1)
    r = CliRunner().invoke(app, ["export", str(src), "-o", str(tmp_path / "b.eskin")])
    assert r.exit_code == 0 and (tmp_path / "b.eskin").stat().st_size == n
    assert f"warning: {tmp_path / 'b.eskin'} is {n} bytes, more than the {n - 1} bytes of " \
           f"flash of a Cortex-M4F controller" in r.stderr


def test_c_header_names_the_function_that_wrote_it(campaign, tmp_path):
    """The header's comment names a function that exists."""
    import importlib

    model_file = tmp_path / "m.eskin"
    model_file.write_bytes(model_to_bytes(_random_spec(campaign, 20, 2)))
    text = write_c_header(model_file, tmp_path / "m.h").read_text()
    dotted = re.search(r"Generated by (eskin(?:\.\w+)+)", text).group(1)
    module, _, name = dotted.rpartition(".")
    assert callable(getattr(importlib.import_module(module), name))


def test_meta_section_is_json(campaign):
    data = model_to_bytes(_random_spec(campaign, 20, 2))
    pos = data.index(b"meta")
    n = struct.unpack_from("<I", data, pos + 4)[0]
    meta = json.loads(data[pos + 8 : pos + 8 + n])
    assert meta["format"] == "eskin-model" and meta["dtype"] == "float32"


# ----------------------------------------------------------------------------- end to end


def _eskin(*args, check=True):
    res = subprocess.run([sys.executable, "-m", "eskin", *map(str, args)], capture_output=True,
                         text=True)
    if check:
        assert res.returncode == 0, res.stderr
    return res


def test_train_export_classify_matches_python_labels(campaign, tmp_path):
    """`eskin train` -> `eskin export` (float32) -> `eskin-classify` on a held-out simulated
    campaign gives exactly the labels of the Python model (`eskin predict`), and so does
    `eskin predict --engine cpp`."""
    exe = _eskin_classify()
    train = tmp_path / "train.h5"
    eskin.simulate(train, participants=3, seed=21, runs=(2,))
    model = tmp_path / "model.joblib"
    _eskin("train", train, "-o", model, "--all-classes", "--quick", "--D", "20")
    _eskin("export", model, "-o", tmp_path / "model.eskin")
    held = tmp_path / "held.h5"
    shutil.copy(campaign.path, held)
    _eskin("predict", model, held, "--json", tmp_path / "py.json")
    python_labels = [p["label"] for p in json.loads((tmp_path / "py.json").read_text())]
    npy = tmp_path / "held.npy"
    np.save(npy, np.asarray(campaign.signals))
    res = subprocess.run([exe, str(tmp_path / "model.eskin"), str(npy)], capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stderr
    assert [r["label"] for r in _parse(res.stdout)[1]] == python_labels
    _eskin("predict", model, held, "--engine", "cpp", "--json", tmp_path / "cpp.json")
    cpp = json.loads((tmp_path / "cpp.json").read_text())
    assert [p["label"] for p in cpp] == python_labels


# ----------------------------------------------------------------------------- properties

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=25, deadline=None)
@given(
    rows=st.integers(1, 3), cols=st.integers(1, 3), D=st.integers(2, 9),
    n_classes=st.integers(2, 4), n_pool=st.integers(1, 6), seed=st.integers(0, 2**16),
    dtype=st.sampled_from(["float32", "float64"]),
)
def test_any_valid_description_round_trips(rows, cols, D, n_classes, n_pool, seed, dtype):
    """Any valid description (grid, D, classes, shared support vectors, per-machine alphas)
    is written, accepted by the C++ validator, and read back with the same machines; the
    support-vector table holds each distinct pattern once; C++ decisions equal Python's."""
    rng = np.random.default_rng(seed)
    shape = (rows, cols, D)
    full = eskin.resolve_alphas(shape, "full")
    pool = rng.normal(size=(n_pool, *shape))
    rule = "binary" if n_classes == 2 else "one_vs_all"
    machines = []
    for k in range(1 if rule == "binary" else n_classes):
        idx = rng.choice(n_pool, size=int(rng.integers(1, n_pool + 1)), replace=True)
        alphas = tuple(int(rng.integers(1, q + 1)) for q in full)
        machines.append(MachineSpec(1 if rule == "binary" else k, 0 if rule == "binary" else -1,
                                    float(rng.normal()), alphas,
                                    tuple(float(v) for v in rng.uniform(0.3, 3, 3)),
                                    pool[idx], rng.normal(size=len(idx))))
    spec = ModelSpec([f"class{k}" for k in range(n_classes)], rule, machines, D, (rows, cols),
                     window="none", sample_rate_hz=1000.0, window_config=eskin.WindowConfig())
    cm = CompiledModel(model_to_bytes(spec, dtype))
    used = {pool[i].tobytes() for m in machines for i in range(n_pool)
            if any(np.array_equal(pool[i], sv) for sv in m.support_vectors)}
    assert cm.n_support == len(used)
    for m, got in zip(machines, cm.machines):
        assert got["alphas"] == m.alphas and got["intercept"] == m.intercept
        # repeated patterns in one machine become one term with the summed coefficient
        assert np.isclose(sum(got["coef"]), m.dual_coef.sum(), rtol=1e-5, atol=1e-5)
    X = rng.normal(size=(3, *shape))
    F, scale = _python_decisions(spec, X)
    got = cm.classify_tensors(X).decision_values
    tol = 1e-9 if dtype == "float64" else 1e-4
    assert np.all(np.abs(got - F) <= tol * np.maximum(scale, 1e-300) + 1e-12)


@settings(max_examples=300, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    field=st.sampled_from(["sigma", "rate", "intercept", "coef", "alpha", "grid", "D", "name",
                           "amplitude"]),
    value=st.sampled_from([0.0, -1.0, 1e-9, 1e-7, 1e7, 1e300, float("inf"), float("nan"), 300]),
)
def test_a_damaged_description_is_refused_or_loads(seed, field, value):
    """One rule set: whatever the exporter writes, the C++ loader accepts; a description out
    of the loader's bounds (some of which the exporter's own checks do not know) is refused
    with a ModelFormatError, never written."""
    rng = np.random.default_rng(seed)
    rows, cols, D = 2, 2, 4
    pool = rng.normal(size=(3, rows, cols, D))
    machine = MachineSpec(1, 0, 0.1, (2, 2, 2), (1.0, 1.0, 1.0), pool, rng.normal(size=3))
    spec = ModelSpec(["a", "b"], "binary", [machine], D, (rows, cols), window="none",
                     sample_rate_hz=1000.0, window_config=eskin.WindowConfig())
    if field == "sigma":
        machine.sigmas = (1.0, value, 1.0)
    elif field == "rate":
        spec.sample_rate_hz = value
    elif field == "intercept":
        machine.intercept = value
    elif field == "coef":
        machine.dual_coef = np.array([1.0, value, 1.0])
    elif field == "alpha":
        machine.alphas = (2, int(min(value, 300)) if np.isfinite(value) else 0, 2)
    elif field == "grid":
        n = int(min(value, 300)) if np.isfinite(value) else 0
        spec.grid_shape = (n, 1)
    elif field == "D":
        spec.D = int(min(value, 300)) if np.isfinite(value) else 0
    elif field == "name":
        spec.class_names = ["a", "x" * int(min(value, 300) if np.isfinite(value) else 0)]
    elif field == "amplitude":
        machine.amplitude_width = value
    try:
        blob = model_to_bytes(spec, "float64")
    except ModelFormatError as exc:
        assert str(exc) and "\n" not in str(exc)
        return
    CompiledModel(blob)  # what was written loads
