"""The amplitude factor in the deployable model (.eskin format version 2, section AMPL).

A machine with amplitude width w > 0 multiplies each tensor-kernel term by
exp(-(e(x) - e(sv))^2 / (2 w^2)), e(x) = log(mean(x^2) + 1e-12). The C++ classifier must compute
what Python computes, a model without the factor must be written exactly as before (version 1),
and every bad width or energy must be refused with a message naming it.
"""

from __future__ import annotations

import importlib.util
import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

import eskin
from deploy_data import fit_machine, model_sections
from eskin.deploy import device_budget
from eskin.deploy.export import (
    CompiledModel,
    MachineSpec,
    ModelFormatError,
    ModelSpec,
    export_model,
    model_to_bytes,
    spec_from_estimator,
    write_c_header,
)

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A small simulated campaign: 4 participants, run 2 (simulated data)."""
    path = tmp_path_factory.mktemp("campaign") / "sim.h5"
    eskin.simulate(path, participants=4, seed=5, runs=(2,))
    return eskin.load_campaign(path, in_memory=True)


# an unbounded touch window (WindowConfig.window_samples = 0): files of format versions 1 and 2
_CFG = eskin.WindowConfig(window_samples=0)


def _patterns(campaign, D):
    return eskin.preprocess(
        np.asarray(campaign.signals), D, lengths=np.asarray(campaign.lengths),
        sample_rate_hz=campaign.sample_rate_hz, config=_CFG,
    )


def _log_energy(X):
    """The documented formula, written out: log(mean over all entries of x^2 + 1e-12)."""
    X = np.asarray(X, dtype=np.float64)
    return np.log((X.reshape(len(X), -1) ** 2).mean(axis=1) + 1e-12)


def _spec(campaign, D, widths, *, seed=0):
    """A one-vs-all model (binary if one width) whose support vectors are real patterns of the
    campaign, with random coefficients and the given amplitude widths."""
    rng = np.random.default_rng(seed)
    X = _patterns(campaign, D)
    half = eskin.resolve_alphas(X.shape[1:], "half")
    n = len(widths)
    machines = []
    for k, w in enumerate(widths):
        idx = np.sort(rng.choice(len(X) // 2, size=8, replace=False))
        pos, neg = (1, 0) if n == 1 else (k, -1)
        machines.append(MachineSpec(pos, neg, float(rng.normal(0, 0.1)), half, (1.5, 1.2, 2.0),
                                    X[idx], rng.normal(0, 1, size=8), amplitude_width=w))
    return ModelSpec(
        class_names=list(campaign.modalities[: max(2, n)]),
        rule="binary" if n == 1 else "one_vs_all",
        machines=machines, D=D, grid_shape=X.shape[1:3],
        sample_rate_hz=campaign.sample_rate_hz, window_config=_CFG,
    ), X


def _python_decisions(spec, X):
    """Decision values by the formula (eskin.tensor_kernel times the amplitude factor), and the
    scale sum_i |c_i| K_i + |b| for relative tolerances."""
    F, S = [], []
    ex = _log_energy(X)
    for m in spec.machines:
        K = eskin.tensor_kernel(X, m.support_vectors, sigma=m.sigmas, alpha=m.alphas)
        if m.amplitude_width > 0:
            gap = ex[:, None] - _log_energy(m.support_vectors)[None, :]
            K = K * np.exp(-gap**2 / (2 * m.amplitude_width**2))
        F.append(K @ m.dual_coef + m.intercept)
        S.append(K @ np.abs(m.dual_coef) + abs(m.intercept))
    return np.stack(F, axis=1), np.stack(S, axis=1)


# ----------------------------------------------------------------------------- the format


def test_a_model_without_the_factor_is_version_1_byte_for_byte():
    """The committed version-1 fixtures are written again, identically, by this exporter; a
    width of 0 with energies given changes nothing either."""
    spec_file = DATA / "make_model_fixture.py"
    mod_spec = importlib.util.spec_from_file_location("make_model_fixture", spec_file)
    fx = importlib.util.module_from_spec(mod_spec)
    mod_spec.loader.exec_module(fx)
    committed_bases = _committed_bases(DATA / "model_small_float64.eskin")
    for dtype in ("float32", "float64"):
        spec = fx.fixture_spec()
        data = model_to_bytes(spec, dtype, bases_fn=committed_bases)
        assert data == (DATA / f"model_small_{dtype}.eskin").read_bytes()
        for m in spec.machines:
            m.sv_log_energy = _log_energy(m.support_vectors)
        assert model_to_bytes(spec, dtype, bases_fn=committed_bases) == data
        assert CompiledModel(data).format_version == 1


def _committed_bases(path):
    """A ``bases_fn`` giving the support-vector bases stored in a committed float64 fixture.

    The fixture's bases came from LAPACK's QR, whose last bits differ between numpy builds; the
    test is about the writer, so it takes the bases as the file holds them (the float32 fixture
    holds the same values rounded)."""
    svbs = dict(model_sections(path.read_bytes()))[b"SVBS"]
    _, n_sv, rows, cols, D, *alphas = struct.unpack_from("<8I", svbs, 0)
    pos = 32
    ranks = np.frombuffer(svbs, "<u4", n_sv * 3, pos).reshape(n_sv, 3)
    pos += (n_sv * 12 + 7) // 8 * 8
    total = rows * cols * D
    bases = []
    for z, n_z in enumerate((rows, cols, D)):
        shape = (n_sv, alphas[z], total // n_z)
        bases.append(np.frombuffer(svbs, "<f8", int(np.prod(shape)), pos).reshape(shape))
        pos += bases[-1].nbytes

    def bases_fn(tensors, alpha_store):
        assert len(tensors) == n_sv and tuple(alpha_store) == tuple(alphas)
        return ranks, bases

    return bases_fn


def test_version_2_layout_meta_and_loaded_fields(campaign):
    spec, _ = _spec(campaign, 20, [0.7, 0.0, 1.5])
    data = model_to_bytes(spec, "float64")
    version, _, _, size, n_sections = struct.unpack_from("<HHIII", data, 8)
    assert (version, size, n_sections) == (2, len(data), 6)
    assert struct.unpack("<I", data[-4:])[0] == zlib.crc32(data[:-4])
    sections = model_sections(data)
    assert [t for t, _ in sections] == [b"PREP", b"CLAS", b"SVBS", b"MACH", b"AMPL", b"meta"]
    ampl, meta = sections[4][1], json.loads(sections[5][1])
    n_sv, n_m = struct.unpack_from("<II", ampl)
    assert len(ampl) == 8 + 8 * (n_sv + n_m) and n_m == 3
    assert meta["amplitude"] is True and meta["amplitude_widths"] == [0.7, 0.0, 1.5]
    cm = CompiledModel(data)
    assert cm.format_version == 2 and cm.n_support == n_sv
    assert cm.amplitude_widths == (0.7, 0.0, 1.5)
    assert [m["amplitude_width"] for m in cm.machines] == [0.7, 0.0, 1.5]
    # the table holds each unique support vector once, with its energy
    unique = {}
    for m in spec.machines:
        for x in m.support_vectors:
            unique.setdefault(x.tobytes(), x)
    want = _log_energy(np.stack(list(unique.values())))
    np.testing.assert_allclose(cm.sv_log_energy, want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.frombuffer(ampl, "<f8", n_sv, 8), cm.sv_log_energy)
    # without any factor: version 1, and its meta does not mention amplitude
    v1 = model_to_bytes(_spec(campaign, 20, [0.0, 0.0, 0.0])[0])
    assert struct.unpack_from("<H", v1, 8)[0] == 1
    assert "amplitude" not in json.loads(dict(model_sections(v1))[b"meta"])


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda s: setattr(s.machines[1], "amplitude_width", -1.0),
         "machine 1: amplitude_width=-1.0 must be 0 (no amplitude factor) or within [1e-06, 1e+06]"),
        (lambda s: setattr(s.machines[1], "amplitude_width", 1e-7), "machine 1: amplitude_width=1e-07"),
        (lambda s: setattr(s.machines[0], "amplitude_width", float("nan")), "machine 0: amplitude_width=nan"),
        (lambda s: setattr(s.machines[0], "amplitude_width", 2e6), "machine 0: amplitude_width=2000000.0"),
        (lambda s: setattr(s.machines[0], "amplitude_width", 1e6 * (1 + 2**-52)),
         "machine 0: amplitude_width=1000000.0000000002 must be 0"),
        (lambda s: setattr(s.machines[0], "amplitude_width", -0.5), "machine 0: amplitude_width=-0.5"),
        (lambda s: setattr(s.machines[2], "sv_log_energy", np.zeros(3)),
         "machine 2: sv_log_energy shape (3,), expected (8,)"),
        (lambda s: setattr(s.machines[2], "sv_log_energy", np.full(8, np.inf)),
         "machine 2: sv_log_energy[0]=inf is not finite or outside [-10000, 10000]"),
        (lambda s: setattr(s.machines[0], "sv_log_energy", np.r_[np.zeros(7), 2e4]),
         "machine 0: sv_log_energy[7]=20000.0"),
    ],
)
def test_bad_widths_and_energies_are_refused_before_writing(campaign, edit, message):
    spec, _ = _spec(campaign, 20, [0.7, 0.0, 1.5])
    edit(spec)
    with pytest.raises(ModelFormatError) as info:
        model_to_bytes(spec)
    assert str(info.value).startswith(message)  # the exporter's own message, not the loader's


@pytest.mark.parametrize("width", [1e-6, 1e6, 0.0])
def test_widths_at_the_ends_of_the_range_and_none_are_written(campaign, width):
    spec, _ = _spec(campaign, 20, [0.7, width, 1.5])
    b = model_to_bytes(spec, "float64")
    assert CompiledModel(b).format_version == 2
    assert json.loads(dict(model_sections(b))[b"meta"])["amplitude_widths"] == [0.7, width, 1.5]


def test_the_same_support_vector_has_one_energy(campaign):
    spec, _ = _spec(campaign, 20, [0.7, 1.0, 1.5])
    shared = spec.machines[0].support_vectors[0]
    spec.machines[1].support_vectors[0] = shared
    e0 = _log_energy(spec.machines[0].support_vectors)
    e1 = _log_energy(spec.machines[1].support_vectors)
    spec.machines[0].sv_log_energy = e0
    spec.machines[1].sv_log_energy = e1
    model_to_bytes(spec)  # consistent: one table entry, one energy
    e1[0] += 0.5
    with pytest.raises(ModelFormatError, match=r"machine 1: sv_log_energy\[0\]=.*but the same "
                       r"support vector has .* in machine 0 \(one pattern, one energy\)"):
        model_to_bytes(spec)


def test_the_cpp_loader_refuses_a_bad_width_written_anyway(campaign):
    """A file edited past the exporter: the C++ loader names the field (kValue)."""
    spec, _ = _spec(campaign, 20, [0.7])
    data = bytearray(model_to_bytes(spec, "float64"))
    pos = 32
    while struct.unpack_from("<4s", data, pos)[0] != b"AMPL":
        pos += 8 + (struct.unpack_from("<I", data, pos + 4)[0] + 7) // 8 * 8
    n_sv = struct.unpack_from("<I", data, pos + 8)[0]
    struct.pack_into("<d", data, pos + 16 + 8 * n_sv, 2.0**-21)  # 4.8e-7, exact
    data[-4:] = struct.pack("<I", zlib.crc32(bytes(data[:-4])))
    with pytest.raises(ModelFormatError, match=r"section AMPL: machine 0: amplitude_width=4.76837158203125e-07 "
                       r"must be 0 \(no amplitude factor\) or within \[1e-06, 1e\+06\]"):
        CompiledModel(bytes(data))


# ----------------------------------------------------------------------------- decisions


@pytest.mark.parametrize("widths", [[0.5], [0.7, 0.0, 1.5]])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_cpp_decisions_equal_the_formula(campaign, widths, dtype):
    """Raw recordings through the C++ classifier against eskin.preprocess + the formula."""
    spec, X = _spec(campaign, 20, widths, seed=len(widths))
    F, scale = _python_decisions(spec, X)
    F0, _ = _python_decisions(
        ModelSpec(**{**spec.__dict__, "machines": [
            MachineSpec(**{**m.__dict__, "amplitude_width": 0.0}) for m in spec.machines]}), X)
    assert np.abs(F - F0)[:, np.asarray(widths) > 0].max() > 1e-3  # the factor matters here
    cm = CompiledModel(model_to_bytes(spec, dtype))
    got = cm.classify(np.asarray(campaign.signals), np.asarray(campaign.lengths))
    if dtype == "float64":
        np.testing.assert_allclose(got.decision_values, F, rtol=0, atol=1e-9)
    else:
        assert np.all(np.abs(got.decision_values - F) <= 1e-4 * scale)
    # the preprocessed patterns directly: the same values
    np.testing.assert_allclose(cm.classify_tensors(X).decision_values, got.decision_values,
                               rtol=0, atol=1e-12)


def test_overflowing_patterns_give_the_intercept_not_nan(campaign):
    spec, X = _spec(campaign, 20, [0.5])
    cm = CompiledModel(model_to_bytes(spec, "float64"))
    d = cm.classify_tensors(X[:3] * 1e160)  # mean(x^2) overflows: e(x) = inf, factor 0
    assert not np.isnan(d.decision_values).any()
    np.testing.assert_array_equal(d.decision_values[:, 0], spec.machines[0].intercept)


def test_stream_classifier_decides_like_the_batch_classifier(campaign):
    spec, _ = _spec(campaign, 20, [0.7, 0.0, 1.5])
    cm = CompiledModel(model_to_bytes(spec, "float32"))
    rec = np.asarray(campaign.signals[0])[..., : int(campaign.lengths[0])]
    events = [e for e in cm.stream(rec) if "label" in e]
    assert events
    batch = cm.classify(rec)
    np.testing.assert_allclose(events[0]["values"], batch.decision_values[0], rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- files and targets


def test_c_header_and_device_budget_of_a_version_2_model(campaign, tmp_path):
    spec, _ = _spec(campaign, 20, [0.7, 0.0, 1.5])
    path = export_model(spec, tmp_path / "m.eskin")
    data = path.read_bytes()
    text = write_c_header(path, tmp_path / "m.h", name="amp_model").read_text()
    assert "(.eskin format version 2, docs/model-format.md)" in text
    body = text.split("amp_model_data[", 1)[1].split("{", 1)[1].split("};", 1)[0]
    assert bytes(int(v, 16) for v in body.replace("\n", " ").split(",") if v.strip()) == data
    # the budget counts the AMPL bytes in flash and the energies and gaps in RAM
    v1 = model_to_bytes(ModelSpec(**{**spec.__dict__, "machines": [
        MachineSpec(**{**m.__dict__, "amplitude_width": 0.0}) for m in spec.machines]}))
    b2, b1 = device_budget(data), device_budget(v1)
    n_sv = CompiledModel(data).n_support
    assert b2.flash["model"] - b1.flash["model"] == len(data) - len(v1) >= 8 + 8 * (n_sv + 3)
    assert b2.ram["model tables"] - b1.ram["model tables"] == n_sv * 12


def _fit(campaign, D, machine, n_classes, amplitude):
    """A real machine with the amplitude factor, trained on the first 3 participants."""
    return fit_machine(campaign, D, machine, n_classes, alpha="half", amplitude=amplitude)


@pytest.mark.parametrize("machine", ["svm", "rls"])
@pytest.mark.parametrize("n_classes", [2, 3])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_exported_estimators_decide_like_python(campaign, machine, n_classes, dtype):
    """TensorSVC / TensorRLS(amplitude=1.0), alone or one-vs-all: the C++ decision values on the
    raw recordings of the whole campaign against the estimator's decision_function."""
    est, X = _fit(campaign, 20, machine, n_classes, amplitude=1.0)
    names = list(campaign.modalities[:n_classes])
    spec = spec_from_estimator(est, names, D=20, grid_shape=(4, 4),
                               sample_rate_hz=campaign.sample_rate_hz)
    assert all(m.amplitude_width > 0 for m in spec.machines)
    data = model_to_bytes(spec, dtype)
    cm = CompiledModel(data)
    assert cm.format_version == 3  # the default bounded window; AMPL as in version 2
    got = cm.classify(np.asarray(campaign.signals), np.asarray(campaign.lengths))
    F = np.asarray(est.decision_function(X), float).reshape(len(X), -1)
    _, scale = _python_decisions(spec, X)
    if dtype == "float64":
        np.testing.assert_allclose(got.decision_values, F, rtol=0, atol=1e-6)
        assert np.abs(got.decision_values - F).max() < 1e-9  # measured: ~1e-15
        labels = est.predict(X)
        if n_classes == 2:
            labels = (F[:, 0] > 0).astype(int)
        np.testing.assert_array_equal(got.label_indices, labels)
    else:
        assert np.all(np.abs(got.decision_values - F) <= 1e-4 * scale)
    # the estimator's energies are the table's, and the formula's e()
    machines = est.estimators_ if n_classes > 2 else [est]
    for m in machines:
        np.testing.assert_allclose(m.sv_log_energy_, _log_energy(m.support_vectors_), atol=1e-12)
    np.testing.assert_allclose(eskin.pattern_log_energy(X), _log_energy(X), rtol=0, atol=1e-12)


def test_an_estimator_without_the_factor_exports_version_1(campaign):
    est, _ = _fit(campaign, 20, "rls", 2, amplitude=None)
    assert est.amplitude_width_ == 0.0
    spec = spec_from_estimator(est, ["a", "b"], D=20, grid_shape=(4, 4), window_config=_CFG)
    assert struct.unpack_from("<H", model_to_bytes(spec), 8)[0] == 1
    # with the default bounded window: version 3, without the AMPL section
    spec = spec_from_estimator(est, ["a", "b"], D=20, grid_shape=(4, 4))
    data = model_to_bytes(spec)
    assert struct.unpack_from("<H", data, 8)[0] == 3 and b"AMPL" not in data
    cm = CompiledModel(data)
    assert cm.format_version == 3 and not cm.sv_log_energy.size
    assert cm.window_config["window_samples"] == eskin.WindowConfig().window_samples


def test_an_estimator_with_a_width_but_no_energies_is_refused(campaign):
    est, _ = _fit(campaign, 20, "rls", 2, amplitude=1.0)
    del est.sv_log_energy_  # as a machine fitted by other code, without the energies
    with pytest.raises(ModelFormatError, match=r"binary machine: amplitude_width_=.* but no "
                       "fitted attribute 'sv_log_energy_'"):
        spec_from_estimator(est, ["a", "b"], D=20, grid_shape=(4, 4))


def test_eskin_classify_runs_a_version_2_model_and_says_so(campaign, tmp_path):
    """The command-line classifier on a model with the factor on two of three machines: its
    decisions are the compiled model's, and its header line counts the machines with it."""
    import subprocess

    from eskin._paths import find_executable

    try:
        exe = str(find_executable("eskin-classify"))
    except FileNotFoundError:
        pytest.skip("eskin-classify is not built")
    spec, _ = _spec(campaign, 20, [1.5, 0.0, 0.7])
    model_file = export_model(spec, tmp_path / "m.eskin", dtype="float64")
    sig = np.asarray(campaign.signals[:5])
    np.save(tmp_path / "rec.npy", sig)
    res = subprocess.run([exe, str(model_file), str(tmp_path / "rec.npy")],
                         capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[0].startswith("# model") and "amplitude factor on 2 of 3 machines" in lines[0]
    header = lines[1].split("\t")
    values = np.array([[float(v) for v in ln.split("\t")[5:]] for ln in lines[2:]])
    assert header[5:] == [f"f_{c}" for c in spec.class_names]
    np.testing.assert_array_equal(values, CompiledModel(model_file).classify(sig).decision_values)
