"""Model files that once crashed a consumer, through the real compiled core and the real tools.

Each file is the valid test fixture with one field changed and its CRC-32 recomputed, as an
adversary (or a corrupted copy) would: the C++ loader must refuse it, so that ``CompiledModel``
raises its ``ModelFormatError``, ``eskin-classify`` and ``eskin-fw-sim --model`` print one line
and exit with status 2, and nothing dies on a signal or runs out of memory.
"""

from __future__ import annotations

import io
import re
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from eskin._paths import find_executable
from eskin.deploy.export import CompiledModel, ModelFormatError

FIXTURE = Path(__file__).resolve().parents[2] / "data" / "model_small_float64.eskin"
# a 2x2-grid binary model of the fuzzing seed corpus
FIXTURE_TINY = (
    Path(__file__).resolve().parents[2] / "fuzz" / "corpus" / "model" / "tiny_float32.eskin"
)


def _section(b: bytes, tag: bytes) -> int:
    """Offset of the payload of section ``tag``."""
    pos = 32
    while pos + 8 <= len(b) - 4:
        size = struct.unpack_from("<I", b, pos + 4)[0]
        if b[pos : pos + 4] == tag:
            return pos + 8
        pos += 8 + (size + 7) // 8 * 8
    raise AssertionError(f"no section {tag!r}")


def _window_field(b: bytes, name: str) -> int:
    prep = _section(b, b"PREP")
    for k in range(19):
        at = prep + 40 + 40 * k
        if b[at : at + 32].rstrip(b"\0") == name.encode():
            return at + 32
    raise AssertionError(name)


def _alpha_2_31(b: bytearray) -> None:
    struct.pack_into("<I", b, _section(b, b"MACH") + 8 + 24, 2**31)


def _sigma_tiny(b: bytearray) -> None:
    struct.pack_into("<d", b, _section(b, b"MACH") + 8 + 24 + 8, 1e-300)


def _max_window_huge(b: bytearray) -> None:
    struct.pack_into("<d", b, _window_field(b, "max_window_s"), 1e6)


def _noise_window_huge(b: bytearray) -> None:
    struct.pack_into("<d", b, _window_field(b, "noise_window_s"), 1e6)


def _class_name_not_utf8(b: bytearray) -> None:
    at = _section(b, b"CLAS") + 8
    b[at : at + 3] = b"\xff\xfeX"


# edit -> what the one-line error says
CASES = {
    "alpha >= 2^31": (_alpha_2_31, r"machine 0: alpha\[0\]=2147483648 out of range"),
    "sigma 1e-300": (_sigma_tiny, r"machine 0: sigma\[0\]=1e-300 out of range \[1e-06, 1e\+06\]"),
    "max_window_s 1e6": (_max_window_huge, r"WindowConfig.max_window_s = 1e\+06: too large"),
    "noise_window_s 1e6": (_noise_window_huge, r"WindowConfig.noise_window_s = 1e\+06: too large"),
    "class name not UTF-8": (_class_name_not_utf8, r"field 'class name' is not valid UTF-8"),
}


@pytest.fixture(params=sorted(CASES))
def bad_model(request, tmp_path):
    edit, message = CASES[request.param]
    b = bytearray(FIXTURE.read_bytes())
    edit(b)
    b[-4:] = struct.pack("<I", zlib.crc32(bytes(b[:-4])))
    path = tmp_path / "bad.eskin"
    path.write_bytes(bytes(b))
    return path, message


def _tool(name: str) -> str:
    try:
        return str(find_executable(name))
    except FileNotFoundError:
        pytest.skip(f"{name} is not built")


def test_fixture_itself_loads():
    assert CompiledModel(FIXTURE).class_names[1] == "finger"


def test_compiled_model_refuses_it(bad_model):
    path, message = bad_model
    with pytest.raises(ModelFormatError, match=message):
        CompiledModel(path)
    with pytest.raises(ModelFormatError, match=message):
        CompiledModel(path.read_bytes())


def test_eskin_classify_refuses_it(bad_model, tmp_path):
    path, message = bad_model
    rec = tmp_path / "rec.npy"
    np.save(rec, np.zeros((4, 4, 300), np.int16))
    res = subprocess.run(
        [_tool("eskin-classify"), str(path), str(rec)],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1
    assert res.stderr.startswith(f"eskin-classify: {path}: section ")
    assert re.search(message, res.stderr)


def test_fw_sim_refuses_it(bad_model, tmp_path):
    path, message = bad_model
    stream = tmp_path / "stream.npy"
    np.save(stream, np.zeros((3000, 4, 4), np.int16))
    res = subprocess.run(
        [_tool("eskin-fw-sim"), str(stream), "--model", str(path), "--quiet"],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1
    assert res.stderr.startswith(f"eskin-fw-sim: --model: {path}: section ")
    assert re.search(message, res.stderr)


def test_eskin_classify_refuses_huge_declared_npy_at_once(tmp_path):
    """A 128-byte .npy declaring 2e9 recordings is refused from its header, not read."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<i2", "fortran_order": False, "shape": (2_000_000_000, 4, 4, 300)}
    )
    rec = tmp_path / "huge.npy"
    rec.write_bytes(header.getvalue() + bytes(64))
    for args, kwargs in (([str(rec)], {}), (["-"], {"input": rec.read_bytes()})):
        res = subprocess.run(
            [_tool("eskin-classify"), str(FIXTURE), *args],
            check=False,
            capture_output=True,
            timeout=60,
            **kwargs,
        )
        err = res.stderr.decode()
        assert res.returncode == 2, err
        assert err.count("\n") == 1
        assert "shape (2000000000, 4, 4, 300) of <i2 declares more than the limit" in err


# Runs a command and reports its peak resident size on stderr. The command is started from this
# small process, not from pytest: a child forked from a large process keeps that process's peak
# in its ru_maxrss across exec, which would measure pytest, not the tool.
_PEAK_RSS_LAUNCHER = """
import os, subprocess, sys
child = subprocess.Popen(sys.argv[1:])
_, status, usage = os.wait4(child.pid, 0)
sys.stderr.write(f"peak_rss_kb={usage.ru_maxrss}\\n")
sys.exit(os.waitstatus_to_exitcode(status))
"""


def test_eskin_classify_raw_record_allocates_only_what_arrives():
    """A raw record declaring 2^28 samples of 16 taxels (8 GiB) followed by 1000 bytes: the
    tool reads what arrives, says the record is truncated, and stays small."""
    header = b"ESKR" + struct.pack("<HHII", 4, 4, 1 << 28, 0)
    res = subprocess.run(
        [sys.executable, "-c", _PEAK_RSS_LAUNCHER, _tool("eskin-classify"), str(FIXTURE), "-"],
        input=header + bytes(1000),
        capture_output=True,
        timeout=60,
        check=False,
    )
    err, peak = res.stderr.decode().rsplit("peak_rss_kb=", 1)
    assert res.returncode == 2, err
    assert err == (
        "eskin-classify: <stdin>: record 0: truncated samples (1000 of 8589934592 bytes)\n"
    )
    assert int(peak) < 200_000  # kB: the declared 8 GiB were never allocated


# ---------------------------------------------------------------- the exporter's own checks


def _binary_spec(names=("a", "b"), rule="binary", seed=0, grid=(2, 3), D=4):
    import eskin
    from eskin.deploy.export import MachineSpec, ModelSpec

    rng = np.random.default_rng(seed)
    pool = rng.normal(size=(3, *grid, D))
    machine = MachineSpec(1, 0, 0.1, (2, 2, 2), (1.0, 1.0, 1.0), pool, rng.normal(size=3))
    return ModelSpec(list(names), rule, [machine], D, grid, window="none",
                     sample_rate_hz=1000.0, window_config=eskin.WindowConfig())


def test_class_names_with_control_characters_are_refused_by_the_exporter():
    from eskin.deploy.export import model_to_bytes

    for bad in ("a\x1f", "a\x7f", "\x01b"):
        with pytest.raises(ModelFormatError, match="contains control characters") as exc:
            model_to_bytes(_binary_spec(names=(bad, "b")), "float64")
        assert "would not load" not in str(exc.value)  # the exporter's check, not the loader's
    for ok in ("a b", "a~", "é", " "):
        cm = CompiledModel(model_to_bytes(_binary_spec(names=(ok, "b")), "float64"))
        assert cm.class_names[0] == ok


def test_a_rule_read_from_text_is_compared_by_its_value():
    """A rule that is not the interned literal (read from a file, joined) is the same rule."""
    from eskin.deploy.export import model_to_bytes

    rule = "".join(["bin", "ary"])
    cm = CompiledModel(model_to_bytes(_binary_spec(rule=rule), "float64"))
    assert cm.rule == "binary"


def test_the_format_versions_run_from_one_to_the_newest_the_loader_reads():
    from eskin import _core
    from eskin.deploy.export import FORMAT_VERSION, FORMAT_VERSIONS

    assert FORMAT_VERSION == _core.MODEL_FORMAT_VERSION
    assert FORMAT_VERSIONS == tuple(range(1, FORMAT_VERSION + 1))  # each one a file is written in


def test_the_c_header_names_the_rows_and_columns_of_a_grid(tmp_path):
    from eskin.deploy.export import write_c_header

    text = write_c_header(_binary_spec(grid=(2, 3)), tmp_path / "m.h", name="m").read_text()
    assert "#define M_ROWS 2\n" in text and "#define M_COLS 3\n" in text
    assert "#define M_N_CLASSES 2\n" in text
    # its comment gives the file's size and its CRC-32, the one the file ends with
    from eskin.deploy.export import model_to_bytes

    data = model_to_bytes(_binary_spec(grid=(2, 3)), "float32")
    crc = struct.unpack("<I", data[-4:])[0]
    assert f" {len(data)} bytes, CRC-32 0x{crc:08x}\n" in text


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_the_c_headers_comment_describes_the_model(tmp_path, dtype):
    from eskin.deploy.export import model_to_bytes, write_c_header

    data = model_to_bytes(_binary_spec(names=("tap", "press"), grid=(2, 3), D=5), dtype)
    text = write_c_header(data, tmp_path / "m.h", name="m").read_text()
    crc = struct.unpack("<I", data[-4:])[0]
    assert text.splitlines()[:4] == [
        "/* m: an eskin model (.eskin format version 3, docs/model-format.md)",  # bounded window
        " * classes: tap, press (binary)",
        " * grid 2x3, D = 5, window none, subsample algorithm2, 1000 Hz",
        f" * 3 support vectors, {dtype}, {len(data)} bytes, CRC-32 0x{crc:08x}"]


def test_one_pattern_classifies_as_the_first_of_a_batch_and_machines_keep_their_shape():
    from eskin.deploy.export import _CompiledMachines, model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    X = np.random.default_rng(3).normal(size=(4, 2, 3, 4))
    batch = cm.classify_tensors(X)
    one = cm.classify_tensors(X[0])
    assert one.decision_values.tolist() == batch.decision_values[:1].tolist()
    assert one.labels.tolist() == batch.labels[:1].tolist()
    machines = _CompiledMachines(cm)
    assert machines.decision_function(X).tolist() == batch.decision_values[:, 0].tolist()
    assert machines.predict(X).tolist() == batch.label_indices.tolist()


def test_a_recording_that_cannot_be_classified_is_named():
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    x = np.random.default_rng(1).normal(size=(3, 2, 3, 40))
    assert len(cm.classify(x).labels) == 3
    x[1, 0, 0, 5] = np.nan
    with pytest.raises(ValueError, match=r"^recording 1 cannot be classified: .*\(1 recording\(s\) failed\)"):
        cm.classify(x)


def test_per_recording_decisions_cover_every_recording_and_name_the_true_class(tmp_path):
    from eskin.data.campaign import load_campaign, write_campaign
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(names=("tap", "press")), "float64"))
    rng = np.random.default_rng(2)
    sig = (rng.normal(size=(5, 2, 3, 60)) * 100).astype(np.int16)
    path = write_campaign(tmp_path / "c.h5", sig, modality=[0, 1, 1, 0, 1],
                          participant=[0] * 5, direction=[0] * 5, run=[1] * 5,
                          modalities=["tap", "press"], sample_rate_hz=1000.0,
                          volts_per_count=1e-3, source="recorded")
    with load_campaign(path) as camp:
        items = cm.predict_recordings(camp, chunk=2)
        assert [it["index"] for it in items] == [0, 1, 2, 3, 4]
        assert [it["true_label"] for it in items] == ["tap", "press", "press", "tap", "press"]
        assert [it["index"] for it in cm.predict_recordings(camp, [3, 1])] == [3, 1]
        d = cm.classify(sig, camp.lengths)
        assert [it["window"] for it in items] == d.windows.tolist()
        assert [it["decision_values"] for it in items] == d.decision_values.tolist()
    raw = cm.predict_recordings(sig.astype(np.float64))
    assert [it["index"] for it in raw] == [0, 1, 2, 3, 4]
    assert all("true_label" not in it for it in raw)
    assert [it["label"] for it in raw] == [it["label"] for it in items]


def test_a_shared_support_vector_needs_one_log_energy_to_rounding():
    """Two machines sharing a support vector must give it the same log energy, to a relative
    1e-9: 1e-9 apart at e = 3 is rounding, 1e-6 apart is two different energies."""
    import eskin
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    rng = np.random.default_rng(5)
    pool = rng.normal(size=(2, 2, 3, 4))

    def spec(e1):
        machines = [MachineSpec(k, -1, 0.0, (2, 2, 2), (1.0, 1.0, 1.0), pool, rng.normal(size=2),
                                amplitude_width=0.5, sv_log_energy=np.array([3.0, e]))
                    for k, e in enumerate((3.0, e1))]
        return ModelSpec(["a", "b"], "one_vs_all", machines, 4, (2, 3), window="none",
                         sample_rate_hz=1000.0, window_config=eskin.WindowConfig())

    CompiledModel(model_to_bytes(spec(3.0 + 1e-9), "float64"))
    with pytest.raises(ModelFormatError, match=r"sv_log_energy\[1\]=3.000001, but the same support vector has 3.0 in machine 0"):
        model_to_bytes(spec(3.0 + 1e-6), "float64")


def test_a_binary_machine_of_other_classes_is_refused_by_the_exporter():
    from eskin.deploy.export import model_to_bytes

    for pos, neg in ((1, 1), (0, 2), (2, 1)):
        spec = _binary_spec()
        spec.machines[0].positive, spec.machines[0].negative = pos, neg
        with pytest.raises(ModelFormatError, match=rf"^binary machine classes \({pos}, {neg}\)"):
            model_to_bytes(spec, "float64")


def test_the_even_subsampling_is_written_as_such_and_a_recording_streams_as_its_samples():
    from eskin.deploy.export import model_to_bytes

    spec = _binary_spec()
    spec.subsample = "even"
    data = model_to_bytes(spec, "float64")
    prep = _section(data, b"PREP")
    assert struct.unpack_from("<I", data, prep + 16)[0] == 1  # subsample: 0 algorithm2, 1 even
    cm = CompiledModel(data)
    rec = (np.random.default_rng(4).normal(size=(2, 3, 300)) * 50).astype(np.float64)
    rec[:, :, 100:180] += 400 * np.sin(np.linspace(0, 20, 80))
    as_recording = cm.stream(rec)
    as_samples = cm.stream(rec.reshape(6, 300).T)
    assert as_recording == as_samples


def test_a_conflicting_log_energy_names_the_first_machine_that_gave_it():
    import eskin
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    rng = np.random.default_rng(6)
    pool = rng.normal(size=(2, 2, 3, 4))
    machines = [MachineSpec(k, -1, 0.0, (2, 2, 2), (1.0, 1.0, 1.0), pool, rng.normal(size=2),
                            amplitude_width=0.5, sv_log_energy=np.array([1.0, e]))
                for k, e in enumerate((3.0, 3.0, 4.0))]
    spec = ModelSpec(["a", "b", "c"], "one_vs_all", machines, 4, (2, 3), window="none",
                     sample_rate_hz=1000.0, window_config=eskin.WindowConfig())
    with pytest.raises(ModelFormatError,
                       match=r"^machine 2: sv_log_energy\[1\]=4.0, but the same support vector has "
                             r"3.0 in machine 0 "):
        model_to_bytes(spec, "float64")


def test_given_log_energies_are_written_and_missing_ones_computed_from_the_pattern():
    """AMPL holds each support vector's log energy as the first machine that uses it gave it,
    and, for one that no machine gave, the pattern's own e(x) = log(mean(x^2) + 1e-12)."""
    import eskin
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    rng = np.random.default_rng(7)
    pool = rng.normal(size=(3, 2, 3, 4))
    given = MachineSpec(0, -1, 0.0, (2, 2, 2), (1.0, 1.0, 1.0), pool[:2], rng.normal(size=2),
                        amplitude_width=0.5, sv_log_energy=np.array([1.5, -2.0]))
    computed = MachineSpec(1, -1, 0.0, (2, 2, 2), (1.0, 1.0, 1.0), pool[2:], rng.normal(size=1),
                           amplitude_width=0.5)
    spec = ModelSpec(["a", "b"], "one_vs_all", [given, computed], 4, (2, 3), window="none",
                     sample_rate_hz=1000.0, window_config=eskin.WindowConfig())
    b = model_to_bytes(spec, "float64")
    at = _section(b, b"AMPL")
    n_sv, n_machines = struct.unpack_from("<II", b, at)
    assert (n_sv, n_machines) == (3, 2)
    energies = struct.unpack_from("<3d", b, at + 8)
    assert energies[:2] == (1.5, -2.0)
    assert energies[2] == pytest.approx(np.log(np.mean(pool[2] ** 2) + 1e-12), rel=1e-12)
    assert struct.unpack_from("<2d", b, at + 8 + 24) == (0.5, 0.5)


def test_log_energies_of_another_length_than_the_support_vectors_are_refused():
    import eskin
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    rng = np.random.default_rng(8)
    pool = rng.normal(size=(2, 2, 3, 4))
    for e in (np.zeros(3), np.zeros(1), np.zeros((2, 1))):
        m = MachineSpec(1, 0, 0.0, (2, 2, 2), (1.0, 1.0, 1.0), pool, rng.normal(size=2),
                        amplitude_width=0.5, sv_log_energy=e)
        spec = ModelSpec(["a", "b"], "binary", [m], 4, (2, 3), window="none",
                         sample_rate_hz=1000.0, window_config=eskin.WindowConfig())
        with pytest.raises(ModelFormatError, match=re.escape(
                f"machine 0: sv_log_energy shape {e.shape}, expected (2,) (one per support vector)")):
            model_to_bytes(spec, "float64")


def test_decision_function_is_one_column_for_two_classes_and_one_per_class_otherwise():
    import eskin
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    x = np.random.default_rng(9).normal(size=(3, 2, 3, 40))
    binary = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    v = binary.decision_function(x)
    assert v.shape == (3,)
    assert v.tolist() == binary.classify(x).decision_values[:, 0].tolist()
    rng = np.random.default_rng(10)
    pool = rng.normal(size=(2, 2, 3, 4))
    machines = [MachineSpec(k, -1, 0.1, (2, 2, 2), (1.0, 1.0, 1.0), pool, rng.normal(size=2))
                for k in range(3)]
    multi = CompiledModel(model_to_bytes(ModelSpec(
        ["a", "b", "c"], "one_vs_all", machines, 4, (2, 3), window="none",
        sample_rate_hz=1000.0, window_config=eskin.WindowConfig()), "float64"))
    v = multi.decision_function(x)
    assert v.shape == (3, 3)
    assert v.tolist() == multi.classify(x).decision_values.tolist()


def test_predict_recordings_takes_its_data_by_name_and_its_chunk_only_by_name():
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    x = np.random.default_rng(11).normal(size=(3, 2, 3, 40))
    named = cm.predict_recordings(data=x, indices=[2, 0], chunk=1)
    assert [it["index"] for it in named] == [2, 0]
    with pytest.raises(TypeError):
        cm.predict_recordings(x, None, 1)


def test_the_cpp_engine_of_a_loaded_model_file_is_the_classifier_it_was_loaded_into(tmp_path):
    """``eskin predict --engine cpp`` on a .eskin file runs the file's own classifier (its
    float32 values), not a float64 recompilation."""
    from eskin.deploy.export import compiled_engine, model_to_bytes
    from eskin.learn.models import load_model

    path = tmp_path / "m.eskin"
    path.write_bytes(model_to_bytes(_binary_spec(), "float32"))
    model = load_model(path)
    assert compiled_engine(model) is model.estimator.compiled


def test_a_model_without_a_sample_rate_is_not_exported():
    """The touch window counts samples: a model object that does not say its rate is refused,
    not written at a rate it may not have been trained at."""
    from types import SimpleNamespace

    from eskin.deploy.export import spec_from_model

    model = SimpleNamespace(classes=["a", "b"], estimator=None, D=4, grid_shape=(2, 3),
                            window="none", subsample="algorithm2")
    with pytest.raises(ModelFormatError, match=r"^cannot export a SimpleNamespace: .*\(missing "
                                               r"'sample_rate_hz'\)"):
        spec_from_model(model)


def test_per_recording_decisions_do_not_depend_on_how_many_are_read_at_a_time(tmp_path):
    """Recordings of many lengths, read 1, 5, 70 or the default number at a time (each chunk
    padded to its longest): every decision value the same to the bit."""
    from eskin.data.campaign import load_campaign, write_campaign
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(names=("tap", "press")), "float64"))
    rng = np.random.default_rng(8)
    n = 70  # more than two default chunks
    sig = (rng.normal(size=(n, 2, 3, 90)) * 100).astype(np.int16)
    lengths = rng.integers(20, 91, size=n)
    path = write_campaign(tmp_path / "c.h5", sig, modality=rng.integers(0, 2, size=n),
                          participant=[0] * n, direction=[0] * n, run=[1] * n,
                          modalities=["tap", "press"], sample_rate_hz=1000.0,
                          volts_per_count=1e-3, source="recorded", lengths=lengths)
    with load_campaign(path) as camp:
        runs = [cm.predict_recordings(camp, **kw) for kw in ({}, {"chunk": 1}, {"chunk": 5},
                                                            {"chunk": n})]
    for items in runs:
        assert [it["index"] for it in items] == list(range(n))
        assert [it["decision_values"] for it in items] == [
            it["decision_values"] for it in runs[1]]
        assert [it["window"] for it in items] == [it["window"] for it in runs[1]]
    assert {it["window"][1] - it["window"][0] <= 90 for it in runs[0]} == {True}


def test_the_model_file_and_the_c_header_make_the_folders_of_a_new_path(tmp_path):
    from eskin.deploy.export import export_model, write_c_header

    path = export_model(_binary_spec(), tmp_path / "new" / "deeper" / "m.eskin", "float64")
    assert path == tmp_path / "new" / "deeper" / "m.eskin"
    assert CompiledModel(path.read_bytes()).class_names == ["a", "b"]
    header = write_c_header(path, tmp_path / "include" / "models" / "m.h", name="m")
    assert header == tmp_path / "include" / "models" / "m.h"
    assert f"static const size_t m_size = {path.stat().st_size};" in header.read_text()


@pytest.mark.parametrize("name,ident", [("touch_model", "touch_model"), ("a9", "a9"),
                                        ("9a", "m_9a"), ("touch-model v2", "touch_model_v2"),
                                        ("x{1}~", "x_1__"), ("", "m_")])
def test_the_c_header_turns_its_name_into_a_c_identifier(tmp_path, name, ident):
    """Characters a C identifier cannot hold become '_', and a name that would start with a
    digit (or is empty) gets 'm_' in front; the macros are the identifier in capitals."""
    from eskin.deploy.export import write_c_header

    text = write_c_header(_binary_spec(), tmp_path / "m.h", name=name).read_text()
    assert f"static const size_t {ident}_size = " in text
    assert f"#define {ident.upper()}_N_CLASSES 2\n" in text


def test_a_machine_without_support_vectors_is_not_exported():
    """A fitted machine left with no support vector (nothing to compare a touch with) is
    refused by name, not written as a machine that always answers its intercept."""
    from eskin.deploy.export import spec_from_estimator
    from eskin.learn.estimators import TensorSVC

    rng = np.random.default_rng(4)
    X = rng.normal(size=(8, 2, 3, 4))
    est = TensorSVC().fit(X, np.array([0, 1] * 4))
    assert est.support_vectors_.shape[0] > 0
    spec = spec_from_estimator(est, ["a", "b"], D=4, grid_shape=(2, 3))  # as fitted: exported
    assert (spec.grid_shape, spec.D, spec.class_names) == ((2, 3), 4, ["a", "b"])
    est.support_vectors_ = est.support_vectors_[:0]
    est.dual_coef_ = np.asarray(est.dual_coef_).reshape(-1)[:0]
    with pytest.raises(ModelFormatError) as info:
        spec_from_estimator(est, ["a", "b"], D=4, grid_shape=(2, 3))
    assert str(info.value) == ("binary machine: the machine has no support vectors; nothing to "
                               "export")


def test_a_specs_format_version_is_the_oldest_that_holds_it():
    """1 for the paper's model (a whole touch window), 2 with an amplitude factor, 3 with a
    bounded window (docs/model-format.md)."""
    from dataclasses import replace

    import eskin
    from eskin.deploy.export import format_version

    bounded = _binary_spec()
    plain = replace(bounded, window_config=eskin.WindowConfig(window_samples=0))
    assert format_version(plain) == 1
    m = plain.machines[0]
    wide = replace(plain, machines=[replace(m, amplitude_width=0.5,
                                            sv_log_energy=np.zeros(len(m.dual_coef)))])
    assert format_version(wide) == 2
    assert format_version(bounded) == 3


@pytest.mark.parametrize("energy", [np.nan, np.inf, 1e4 * (1 + 2**-52), -1e4, 1e4])
def test_a_log_energy_is_written_within_its_range_and_refused_outside(energy):
    """A support vector's log energy: finite and within [-1e4, 1e4], the ends included."""
    from dataclasses import replace

    from eskin.deploy.export import model_to_bytes

    plain = _binary_spec()
    m = plain.machines[0]
    e = np.zeros(len(m.dual_coef))
    e[1] = energy
    spec = replace(plain, machines=[replace(m, amplitude_width=0.5, sv_log_energy=e)])
    if abs(energy) <= 1e4:
        assert CompiledModel(model_to_bytes(spec, "float64")).sv_log_energy[1] == energy
        return
    with pytest.raises(ModelFormatError) as info:
        model_to_bytes(spec, "float64")
    assert str(info.value) == (f"machine 0: sv_log_energy[1]={energy!r} is not finite or "
                               f"outside [-10000, 10000]")


@pytest.mark.parametrize("ids", [[0, 0, 1], [-1, 0, 1], [0, 2, 1]])
def test_a_one_vs_all_estimator_of_other_class_ids_than_0_to_k_is_not_exported(ids):
    from eskin.deploy.export import spec_from_estimator
    from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS

    rng = np.random.default_rng(6)
    est = OneVsAllTouchClassifier(TensorRLS()).fit(rng.normal(size=(9, 2, 3, 4)),
                                                    np.arange(9) % 3)
    spec_from_estimator(est, ["a", "b", "c"], D=4, grid_shape=(2, 3))  # as fitted: exported
    est.classes_ = np.array(ids)
    with pytest.raises(ModelFormatError) as info:
        spec_from_estimator(est, ["a", "b", "c"], D=4, grid_shape=(2, 3))
    assert str(info.value) == f"one-vs-all classes_ {ids} must be 0..2"


def test_a_machine_of_one_support_vector_is_written_and_of_none_refused():
    from eskin.deploy.export import model_to_bytes

    spec = _binary_spec()
    m = spec.machines[0]
    m.support_vectors, m.dual_coef = m.support_vectors[:1], m.dual_coef[:1]
    cm = CompiledModel(model_to_bytes(spec, "float64"))
    assert cm.classify_tensors(m.support_vectors).labels.shape == (1,)
    m.support_vectors, m.dual_coef = m.support_vectors[:0], m.dual_coef[:0]
    with pytest.raises(ModelFormatError) as info:
        model_to_bytes(spec, "float64")
    assert str(info.value) == ("machine 0: support_vectors shape (0, 2, 3, 4), expected (n>=1, "
                               "2, 3, 4)")


def test_a_model_file_does_not_depend_on_the_order_of_its_metadata():
    from eskin.deploy.export import model_to_bytes

    one, two = _binary_spec(), _binary_spec()
    one.meta = {"trained_on": "c.h5", "alpha": [2, 2, 2], "seed": 3}
    two.meta = {"seed": 3, "alpha": [2, 2, 2], "trained_on": "c.h5"}
    assert model_to_bytes(one, "float64") == model_to_bytes(two, "float64")


def test_patterns_classified_directly_report_no_window_and_a_touch_found():
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    out = cm.classify_tensors(np.random.default_rng(5).normal(size=(3, 2, 3, 4)))
    assert out.windows.tolist() == [[0, 0]] * 3 and out.window_found.tolist() == [True] * 3


@pytest.mark.parametrize("ids", [[-1, 1], [0, 2], [1, 1]])
def test_a_binary_estimator_of_other_class_ids_than_0_and_1_is_not_exported(ids):
    from eskin.deploy.export import spec_from_estimator
    from eskin.learn.estimators import TensorSVC

    rng = np.random.default_rng(4)
    est = TensorSVC().fit(rng.normal(size=(8, 2, 3, 4)), np.array([0, 1] * 4))
    est.classes_ = np.array(ids)
    with pytest.raises(ModelFormatError) as info:
        spec_from_estimator(est, ["a", "b"], D=4, grid_shape=(2, 3))
    assert str(info.value) == (f"binary estimator classes_ {ids} must be [0, 1] for the classes "
                               f"['a', 'b']")


@pytest.mark.parametrize("shape", [(2, 1, 3, 10), (2, 2, 4, 10), (2, 3, 2, 10), (3, 3, 10),
                                   (1, 2, 3, 10, 1), (2, 3)])
def test_signals_not_of_the_models_grid_are_refused_with_the_shape_expected(shape):
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    with pytest.raises(ValueError) as info:
        cm.classify(np.zeros(shape, np.int16))
    assert str(info.value) == (f"signals: expected shape (n, 2, 3, T) or (2, 3, T), got "
                               f"{shape}")


def test_the_bounded_window_field_is_written_only_in_the_version_that_has_it():
    """Versions 1 and 2 have no window_samples field (their bytes are as they always were);
    version 3 writes it with its value."""
    import dataclasses

    from eskin.deploy.export import format_version, model_to_bytes

    unbounded = _binary_spec()
    unbounded.window_config = dataclasses.replace(unbounded.window_config, window_samples=0)
    assert format_version(unbounded) == 1

    def prep(b: bytes) -> bytes:
        return b[_section(b, b"PREP"):_section(b, b"CLAS")]

    assert b"window_samples" not in prep(model_to_bytes(unbounded, "float64"))
    unbounded.machines[0].amplitude_width = 0.5
    assert format_version(unbounded) == 2
    assert b"window_samples" not in prep(model_to_bytes(unbounded, "float64"))
    bounded = _binary_spec()
    bounded.window_config = dataclasses.replace(bounded.window_config, window_samples=400)
    assert format_version(bounded) == 3
    p = prep(model_to_bytes(bounded, "float64"))
    assert struct.unpack_from("<d", p, p.index(b"window_samples") + 32)[0] == 400.0


def test_an_estimator_never_fitted_is_not_exported():
    from eskin.deploy.export import spec_from_estimator
    from eskin.learn.estimators import TensorSVC

    with pytest.raises(ModelFormatError) as info:
        spec_from_estimator(TensorSVC(), ["a", "b"], D=4, grid_shape=(2, 3))
    assert str(info.value) == "binary estimator without classes_: not fitted, nothing to export"


@pytest.mark.parametrize("short, code", [("interpolate", 0), ("error", 1)])
def test_the_short_window_policy_is_written_with_its_documented_code(short, code):
    """docs/model-format.md, PREP: short_policy 0 interpolate, 1 error."""
    from eskin.deploy.export import model_to_bytes

    spec = _binary_spec()
    spec.short = short
    b = model_to_bytes(spec, "float64")
    assert struct.unpack_from("<6I", b, _section(b, b"PREP"))[5] == code


def test_support_vectors_of_another_grid_and_coefficients_of_another_count_are_refused():
    from eskin.deploy.export import model_to_bytes

    for shape in ((3, 2, 2, 4), (3, 2, 4, 4), (3, 2, 3, 3), (3, 2, 3, 5), (3, 2, 3), (3, 2, 3, 4, 1),
                  (2, 3, 4), ()):
        spec = _binary_spec()
        spec.machines[0].support_vectors = np.zeros(shape)
        with pytest.raises(ModelFormatError) as info:
            model_to_bytes(spec, "float64")
        assert str(info.value) == (f"machine 0: support_vectors shape {shape}, expected "
                                   f"(n>=1, 2, 3, 4)")
    for n in (2, 4):
        spec = _binary_spec()
        spec.machines[0].dual_coef = np.ones(n)
        with pytest.raises(ModelFormatError) as info:
            model_to_bytes(spec, "float64")
        assert str(info.value) == f"machine 0: {n} dual coefficients for 3 support vectors"
    spec = _binary_spec()
    spec.machines[0].dual_coef = np.ones((1, 3))  # scikit-learn's (1, n) row: its values
    assert CompiledModel(model_to_bytes(spec, "float64")).n_support == 3
    rng = np.random.default_rng(9)
    spec.machines[0].support_vectors = rng.normal(size=(300, 2, 3, 4))
    spec.machines[0].dual_coef = rng.normal(size=300)
    assert CompiledModel(model_to_bytes(spec, "float64")).n_support == 300
    spec.machines[0].dual_coef = rng.normal(size=299)
    with pytest.raises(ModelFormatError, match="^machine 0: 299 dual coefficients for 300 support"):
        model_to_bytes(spec, "float64")


@pytest.mark.parametrize("z", [0, 1, 2])
def test_each_modes_alpha_and_sigma_are_checked(z):
    from eskin.deploy.export import model_to_bytes

    q = (2, 3, 4)[z]  # min(mode size, the product of the others) on a 2x3 grid, D=4
    spec = _binary_spec()
    spec.machines[0].alphas = tuple(q + 1 if i == z else 1 for i in range(3))
    with pytest.raises(ModelFormatError) as info:
        model_to_bytes(spec, "float64")
    assert str(info.value) == f"machine 0: alpha[{z}]={q + 1} out of range [1, Q={q}]"
    spec = _binary_spec()
    spec.machines[0].sigmas = tuple(0.0 if i == z else 1.0 for i in range(3))
    with pytest.raises(ModelFormatError) as info:
        model_to_bytes(spec, "float64")
    assert str(info.value) == f"machine 0: sigma[{z}]=0.0 must be > 0"
    spec.machines[0].sigmas = tuple(-2.0 if i == z else 1.0 for i in range(3))
    with pytest.raises(ModelFormatError, match=rf"^machine 0: sigma\[{z}\]=-2.0 must be > 0$"):
        model_to_bytes(spec, "float64")


def test_a_modes_rank_is_bounded_by_the_product_of_the_other_modes():
    """On a 1x2 grid with D=4 the time mode's unfolding is 4 x 2: its rank is at most 2."""
    from eskin.deploy.export import model_to_bytes

    spec = _binary_spec(grid=(1, 2), D=4)
    spec.machines[0].alphas = (1, 1, 3)
    with pytest.raises(ModelFormatError, match=r"^machine 0: alpha\[2\]=3 out of range \[1, Q=2\]$"):
        model_to_bytes(spec, "float64")
    spec.machines[0].alphas = (1, 1, 2)
    assert CompiledModel(model_to_bytes(spec, "float64")).n_support == 3


def test_the_first_log_energy_out_of_range_is_named():
    from dataclasses import replace

    from eskin.deploy.export import model_to_bytes

    plain = _binary_spec()
    m = plain.machines[0]
    spec = replace(plain, machines=[replace(m, amplitude_width=0.5,
                                            sv_log_energy=np.array([0.0, 2e4, -3e4]))])
    with pytest.raises(ModelFormatError, match=r"^machine 0: sv_log_energy\[1\]=20000.0 is not"):
        model_to_bytes(spec, "float64")


def test_the_metadata_names_the_amplitude_factor_only_when_a_machine_has_it():
    import json

    from eskin.deploy.export import model_to_bytes

    def meta(spec) -> dict:
        b = model_to_bytes(spec, "float32")
        return json.JSONDecoder().raw_decode(b[b.index(b'{"'):].decode("latin-1"))[0]

    plain = _binary_spec()
    assert meta(plain) == {"dtype": "float32", "format": "eskin-model"}
    plain.machines[0].amplitude_width = 0.5
    assert meta(plain) == {"amplitude": True, "amplitude_widths": [0.5], "dtype": "float32",
                           "format": "eskin-model"}


def test_a_touch_still_on_at_the_end_is_decided_by_the_flush_stream_does_by_default():
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    rec = (np.random.default_rng(5).normal(size=(2, 3, 300)) * 50).astype(np.float64)
    rec[:, :, 220:] += 400 * np.sin(np.linspace(0, 20, 80))  # the touch lasts to the last sample
    unflushed = [e for e in cm.stream(rec, flush=False) if e["status_name"] == "decision"]
    flushed = [e for e in cm.stream(rec) if e["status_name"] == "decision"]
    assert unflushed == []
    assert len(flushed) == 1 and flushed[0]["sample"] == 300
    assert flushed[0]["label"] in ("a", "b")


@pytest.mark.parametrize("status, why", [
    (-1, "its shape does not fit the model"),
    (-2, "no touch was detected (the model's detector has fallback = error)"),
    (-3, "it holds NaN or Inf values"),
    (-4, "its window is shorter than D (the model's short policy is error)"),
    (-5, "the basis computation failed"),
    (-6, "status -6"),  # a null pointer: never passed from Python
    (-7, "status -7"),  # reserved by the core (it keeps the 4096 most energetic touches)
])
def test_each_status_of_the_core_is_named_in_the_error(status, why):
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    n = 3
    st = np.array([0, status, status], np.int32)
    with pytest.raises(ValueError) as err:
        cm._decisions(np.zeros(n, np.int32), np.zeros((n, 1)), np.zeros(n, bool), st,
                      np.zeros((n, 2), np.int64), np.ones(n, bool), np.zeros(n))
    assert str(err.value) == f"recording 1 cannot be classified: {why} (2 recording(s) failed)"


@pytest.mark.parametrize("rate, shown", [(0.0, "0"), (-5.0, "-5"), (np.nan, "nan"),
                                         (np.inf, "inf"), (2e7, "20000000")])
def test_a_sample_rate_outside_the_loaders_range_is_refused_naming_it(rate, shown):
    """The loader's one rule: a rate in (0, 1e7] Hz; the ends are written and load."""
    from eskin.deploy.export import model_to_bytes

    spec = _binary_spec()
    spec.sample_rate_hz = rate
    with pytest.raises(ModelFormatError, match=rf"section PREP: sample_rate_hz={shown} must be in \(0, 1e7\]"):
        model_to_bytes(spec, "float64")
    from dataclasses import replace

    spec.window_config = replace(spec.window_config, max_window_s=1.0)  # 1e7 samples at 1e7 Hz
    for ok in (1e7, 100.0):
        spec.sample_rate_hz = ok
        assert CompiledModel(model_to_bytes(spec, "float64")).sample_rate_hz == ok


def test_a_repeated_class_name_is_refused_naming_it():
    from eskin.deploy.export import model_to_bytes

    spec = _binary_spec(names=("tap", "tap"))
    with pytest.raises(ModelFormatError, match=r"section CLAS: class name 'tap' repeated"):
        model_to_bytes(spec, "float64")
    spec = _binary_spec(names=("tap", "Tap"))
    assert CompiledModel(model_to_bytes(spec, "float64")).class_names == ["tap", "Tap"]


def _machines_spec(rule, n_classes, pairs):
    """A spec of ``n_classes`` classes and one machine per (positive, negative) pair."""
    from dataclasses import replace

    spec = _binary_spec(names=[f"c{i}" for i in range(n_classes)], rule=rule)
    spec.machines = [replace(spec.machines[0], positive=p, negative=n) for p, n in pairs]
    return spec


@pytest.mark.parametrize("rule, n_classes, pairs, message", [
    ("binary", 3, [(1, 0)], "binary model: needs 2 classes and 1 machine, got 3 and 1"),
    ("binary", 2, [(1, 0), (0, 1)], "binary model: needs 2 classes and 1 machine, got 2 and 2"),
    ("binary", 2, [(1, 2)], r"binary machine classes \(1, 2\) must be \(1, 0\) or \(0, 1\)"),
    ("binary", 2, [(1, 1)], r"binary machine classes \(1, 1\) must be \(1, 0\) or \(0, 1\)"),
    ("one_vs_all", 3, [(0, -1), (1, -1)],
     r"one_vs_all model: needs one machine per class \(3\), got 2"),
    ("one_vs_all", 2, [(0, -1), (1, -1), (2, -1)],
     r"one_vs_all model: needs one machine per class \(2\), got 3"),
    ("one_vs_all", 1, [(0, -1)], r"one_vs_all model: needs one machine per class \(1\), got 1"),
    ("one_vs_all", 3, [(0, -1), (2, -1), (1, -1)],
     r"one_vs_all machine 1: positive/negative = \(2, -1\), expected \(1, -1\)"),
    ("one_vs_all", 3, [(0, -1), (1, -1), (2, 0)],
     r"one_vs_all machine 2: positive/negative = \(2, 0\), expected \(2, -1\)"),
    ("one_vs_all", 2, [(0, -2), (1, -1)],
     r"one_vs_all machine 0: positive/negative = \(0, -2\), expected \(0, -1\)"),
])
def test_machines_that_do_not_fit_the_rule_are_refused_by_the_exporter(rule, n_classes, pairs,
                                                                       message):
    """The exporter names the rule's machines and classes before the loader's check (which
    says the same of a file: cpp/src/model_format.cpp)."""
    from eskin.deploy.export import model_to_bytes

    with pytest.raises(ModelFormatError, match=f"^{message}$"):
        model_to_bytes(_machines_spec(rule, n_classes, pairs), "float64")


@pytest.mark.parametrize("rule, n_classes, pairs", [
    ("binary", 2, [(0, 1)]), ("one_vs_all", 2, [(0, -1), (1, -1)]),
    ("one_vs_all", 4, [(0, -1), (1, -1), (2, -1), (3, -1)])])
def test_machines_that_fit_the_rule_are_written(rule, n_classes, pairs):
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_machines_spec(rule, n_classes, pairs), "float64"))
    assert cm.rule == rule and len(cm.class_names) == n_classes


@pytest.mark.parametrize("field, value", [
    ("dual_coef", np.array([1.0, np.nan, 1.0])), ("dual_coef", np.array([np.inf, 1.0, 1.0])),
    ("intercept", np.nan), ("intercept", -np.inf)])
def test_a_coefficient_or_intercept_not_finite_is_refused(field, value):
    from eskin.deploy.export import model_to_bytes

    spec = _binary_spec()
    setattr(spec.machines[0], field, value)
    with pytest.raises(ModelFormatError, match=r"^machine 0: dual_coef or intercept not finite$"):
        model_to_bytes(spec, "float64")


@pytest.mark.parametrize("alphas, sigmas", [
    ((2, 2), (1.0, 1.0, 1.0)), ((2, 2, 2, 2), (1.0, 1.0, 1.0)),
    ((2, 2, 2), (1.0, 1.0)), ((2, 2, 2), (1.0, 1.0, 1.0, 1.0))])
def test_alphas_and_sigmas_need_one_value_per_mode(alphas, sigmas):
    from eskin.deploy.export import model_to_bytes

    spec = _binary_spec()
    spec.machines[0].alphas, spec.machines[0].sigmas = alphas, sigmas
    with pytest.raises(ModelFormatError,
                       match=r"^machine 0: alphas/sigmas need one value per mode \(3\)$"):
        model_to_bytes(spec, "float64")


@pytest.mark.parametrize("window_samples, version", [(None, 1), (0.0, 1), (64.0, 3), (-5.0, None)])
def test_a_window_mapping_without_the_bounded_field_is_an_unbounded_window(window_samples, version):
    """A plain mapping of the detector's settings may predate ``window_samples``: it means 0
    (every sample up to max_window_s); a negative value is written, and refused by the loader."""
    from eskin.deploy.export import _window_fields, format_version, model_to_bytes

    spec = _binary_spec()
    fields = _window_fields(spec.window_config)
    del fields["window_samples"]
    if window_samples is not None:
        fields["window_samples"] = window_samples
    spec.window_config = fields
    if version is None:
        with pytest.raises(ModelFormatError, match=r"WindowConfig.window_samples = -5: must be 0"):
            model_to_bytes(spec, "float64")
        return
    assert format_version(spec) == version
    cm = CompiledModel(model_to_bytes(spec, "float64"))
    assert cm.format_version == version and cm.window_config["window_samples"] == (window_samples or 0)


def _energy_spec(energies):
    """Three one-vs-all machines on the same two support vectors, each giving the log energies
    ``energies[k]`` (None: none given, computed from the pattern)."""
    import eskin
    from eskin.deploy.export import MachineSpec, ModelSpec

    rng = np.random.default_rng(8)
    pool = rng.normal(size=(2, 2, 3, 4))
    machines = [MachineSpec(k, -1, 0.0, (2, 2, 2), (1.0, 1.0, 1.0), pool, rng.normal(size=2),
                            amplitude_width=0.5,
                            sv_log_energy=None if e is None else np.array(e, dtype=np.float64))
                for k, e in enumerate(energies)]
    return ModelSpec(["a", "b", "c"], "one_vs_all", machines, 4, (2, 3), window="none",
                     sample_rate_hz=1000.0, window_config=eskin.WindowConfig())


def test_the_energies_given_by_a_later_machine_are_written_and_compared():
    """A first machine that gives no energies leaves them to the next that does; the energies
    two later machines give are compared with each other (1e-9 relative, the end allowed) and
    the first given is the one written."""
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_energy_spec([None, [5.0, -7.0], [5.0, -7.0]]), "float64"))
    assert cm.sv_log_energy.tolist() == [5.0, -7.0]  # not the patterns' own (about 0)
    for tie in (0.5e-9, 1e-9):  # within rounding of 0: machine 1's value is kept
        b = model_to_bytes(_energy_spec([None, [0.0, 1.0], [tie, 1.0]]), "float64")
        assert CompiledModel(b).sv_log_energy.tolist() == [0.0, 1.0]
    with pytest.raises(ModelFormatError, match=r"^machine 2: sv_log_energy\[0\]=1.5e-09, but the "
                                               r"same support vector has 0.0 in machine 1 "):
        model_to_bytes(_energy_spec([None, [0.0, 1.0], [1.5e-9, 1.0]]), "float64")


def test_a_computed_log_energy_out_of_range_names_the_first_support_vector():
    """Patterns whose mean square overflows have e(x) = inf: refused, naming the first."""
    import eskin
    from eskin.deploy.export import MachineSpec, ModelSpec, model_to_bytes

    rng = np.random.default_rng(10)
    pool = rng.normal(size=(3, 2, 3, 4))
    pool[1:] *= 1e160
    m = MachineSpec(1, 0, 0.0, (2, 2, 2), (1.0, 1.0, 1.0), pool, rng.normal(size=3),
                    amplitude_width=0.5)
    spec = ModelSpec(["a", "b"], "binary", [m], 4, (2, 3), window="none",
                     sample_rate_hz=1000.0, window_config=eskin.WindowConfig())
    with pytest.raises(ModelFormatError, match=r"^support vector 1: log energy inf is not finite "
                                               r"or outside \[-10000, 10000\]$"):
        model_to_bytes(spec, "float64")


def _fitted_svc(seed=4, **kw):
    from eskin.learn.estimators import TensorSVC

    rng = np.random.default_rng(seed)
    return TensorSVC(**kw).fit(rng.normal(size=(8, 2, 3, 4)) * np.arange(1, 9)[:, None, None, None],
                               np.array([0, 1] * 4))


def test_an_estimator_pickled_before_the_amplitude_factor_is_exported_without_it():
    """No ``amplitude_width_`` and no ``sv_log_energy_``: the paper's kernel, format version 1."""
    from eskin.deploy.export import format_version, spec_from_estimator

    est = _fitted_svc()
    del est.amplitude_width_, est.sv_log_energy_
    spec = spec_from_estimator(est, ["a", "b"], D=4, grid_shape=(2, 3), window="none",
                               window_config={})
    m = spec.machines[0]
    assert m.amplitude_width == 0.0 and m.sv_log_energy is None and format_version(spec) == 1


def test_an_amplitude_factor_needs_the_energies_it_was_fitted_with():
    from eskin.deploy.export import model_to_bytes, spec_from_estimator

    est = _fitted_svc(amplitude=1.0)
    assert est.amplitude_width_ > 0
    given = np.linspace(-1.0, 1.0, len(est.sv_log_energy_))  # not the patterns' own e(x)
    est.sv_log_energy_ = given[:, None]
    spec = spec_from_estimator(est, ["a", "b"], D=4, grid_shape=(2, 3))
    assert spec.machines[0].sv_log_energy.tolist() == given.tolist()
    del est.sv_log_energy_
    with pytest.raises(ModelFormatError) as info:
        spec_from_estimator(est, ["a", "b"], D=4, grid_shape=(2, 3))
    assert str(info.value) == (f"binary machine: amplitude_width_={est.amplitude_width_!r} but no "
                               f"fitted attribute 'sv_log_energy_'")
    est.amplitude_width_ = -0.5  # a damaged width: refused by the range, not as missing energies
    with pytest.raises(ModelFormatError, match=r"^machine 0: amplitude_width=-0.5 must be 0"):
        model_to_bytes(spec_from_estimator(est, ["a", "b"], D=4, grid_shape=(2, 3)), "float64")


def test_a_spec_made_without_a_rate_is_at_the_papers_3_khz():
    from eskin.deploy.export import spec_from_estimator

    spec = spec_from_estimator(_fitted_svc(), ["a", "b"], D=4, grid_shape=(2, 3))
    assert spec.sample_rate_hz == 3000.0


@pytest.mark.parametrize("names", [["a"], ["a", "b", "c"]])
def test_a_binary_estimator_needs_two_class_names(names):
    from eskin.deploy.export import spec_from_estimator

    with pytest.raises(ModelFormatError) as info:
        spec_from_estimator(_fitted_svc(), names, D=4, grid_shape=(2, 3))
    assert str(info.value) == f"binary estimator classes_ [0, 1] must be [0, 1] for the classes {names}"


@pytest.mark.parametrize("n_names", [2, 4])
def test_a_one_vs_all_estimator_needs_a_name_per_machine(n_names):
    from eskin.deploy.export import spec_from_estimator
    from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS

    rng = np.random.default_rng(6)
    est = OneVsAllTouchClassifier(TensorRLS()).fit(rng.normal(size=(9, 2, 3, 4)), np.arange(9) % 3)
    names = [f"c{i}" for i in range(n_names)]
    with pytest.raises(ModelFormatError) as info:
        spec_from_estimator(est, names, D=4, grid_shape=(2, 3))
    assert str(info.value) == f"one-vs-all estimator has 3 machines for {n_names} classes"


def test_three_hundred_one_vs_all_machines_make_a_spec_of_three_hundred():
    """Counts past the integers Python keeps one object of (256) compare by value."""
    from eskin.deploy.export import spec_from_estimator
    from eskin.learn.estimators import OneVsAllTouchClassifier, TensorRLS

    rng = np.random.default_rng(6)
    est = OneVsAllTouchClassifier(TensorRLS()).fit(rng.normal(size=(9, 2, 3, 4)), np.arange(9) % 3)
    est.estimators_ = est.estimators_[:1] * 300
    est.classes_ = np.arange(300)
    spec = spec_from_estimator(est, [f"c{i}" for i in range(300)], D=4, grid_shape=(2, 3))
    assert [(m.positive, m.negative) for m in spec.machines] == [(k, -1) for k in range(300)]


@pytest.mark.parametrize("rule", ["binary", "one_vs_all"])
def test_a_files_calibrated_rule_reads_back_as_written(rule):
    from eskin.deploy.export import model_to_bytes
    from eskin.learn.calibration import Calibration

    pairs = [(1, 0)] if rule == "binary" else [(0, -1), (1, -1)]
    spec = _machines_spec(rule, 2, pairs)
    k = len(pairs)
    spec.calibration = Calibration((2.0,) * k, (-0.5,) * k, 0.75, 0.1, rule == "binary")
    got = CompiledModel(model_to_bytes(spec, "float64")).calibration()
    assert (got.slopes, got.offsets, got.threshold, got.binary) == (
        (2.0,) * k, (-0.5,) * k, 0.75, rule == "binary")
    assert np.isnan(got.reject)  # a file holds the threshold, not the fraction it came from


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_a_compiled_models_decisions_are_frozen_and_its_repr_names_it(dtype):
    import dataclasses

    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(names=("tap", "press")), dtype))
    assert repr(cm) == f"CompiledModel(classes=['tap', 'press'], rule='binary', D=4, n_support=3, {dtype})"
    x = np.random.default_rng(3).normal(size=(3, 2, 3, 40))
    d = cm.classify(x)
    with pytest.raises(dataclasses.FrozenInstanceError):
        d.labels = d.labels[:1]
    one = cm.classify(x[1])  # one recording (rows, cols, T) is a batch of one
    assert one.decision_values.tolist() == d.decision_values[1:2].tolist()
    assert one.windows.tolist() == d.windows[1:2].tolist()


def test_signals_of_any_numeric_type_or_layout_classify_as_their_float64_values():
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    x = np.round(np.random.default_rng(1).normal(size=(2, 2, 3, 80)) * 100)
    want = cm.classify(x).decision_values
    for other in (x.astype(np.int16), x.astype(np.int32), x.astype(np.int64), x.astype(np.float32),
                  np.asfortranarray(x), x.tolist()):
        assert cm.classify(other).decision_values.tolist() == want.tolist()
    every_other = x[:, :, :, ::2]  # a strided view
    assert cm.classify(every_other).decision_values.tolist() == \
        cm.classify(every_other.copy()).decision_values.tolist()
    with pytest.raises(ValueError, match="could not convert string to float"):
        cm.classify(np.full((1, 2, 3, 40), "a", dtype=object))


@pytest.mark.parametrize("shape", [(1, 2, 3, 40), (3, 40), (240,), (40, 5)])
def test_stream_takes_samples_or_one_recording_and_refuses_other_shapes(shape):
    from eskin.deploy.export import model_to_bytes

    cm = CompiledModel(model_to_bytes(_binary_spec(), "float64"))
    with pytest.raises(ValueError, match=r"^samples: expected shape \(n, 6\)$"):
        cm.stream(np.zeros(shape))


def test_a_spec_is_at_the_papers_3_khz_unless_told():
    from eskin.deploy.export import MachineSpec, ModelSpec

    m = _binary_spec().machines[0]
    assert ModelSpec(["a", "b"], "binary", [m], 4, (2, 3)).sample_rate_hz == 3000.0
    assert isinstance(m, MachineSpec)


@pytest.mark.parametrize("name, ok", [("x" * 31, True), ("é" * 15 + "x", True), ("x" * 32, False),
                                      ("é" * 16, False), ("", False), ("a\x00b", False)])
def test_a_class_name_is_one_to_31_utf8_bytes_without_nul(name, ok):
    from eskin.deploy.export import model_to_bytes

    spec = _binary_spec(names=("a", name))
    if ok:
        assert CompiledModel(model_to_bytes(spec, "float64")).class_names == ["a", name]
        return
    with pytest.raises(ModelFormatError) as info:
        model_to_bytes(spec, "float64")
    assert str(info.value) == (f"class name {name!r}: must be a non-empty name of at most 31 "
                               f"UTF-8 bytes")


@pytest.mark.parametrize("attr", ["support_vectors_", "dual_coef_", "intercept_", "alphas_",
                                  "sigmas_"])
def test_an_estimator_missing_a_fitted_attribute_is_named(attr):
    from eskin.deploy.export import spec_from_estimator

    est = _fitted_svc()
    delattr(est, attr)
    with pytest.raises(ModelFormatError) as info:
        spec_from_estimator(est, ["a", "b"], D=4, grid_shape=(2, 3))
    assert str(info.value) == f"binary machine: the estimator has no fitted attribute {attr!r}"


def test_a_calibrated_model_streams_its_confidences_and_the_papers_none():
    from eskin.deploy.export import _CompiledMachines, model_to_bytes
    from eskin.learn.calibration import Calibration

    rec = (np.random.default_rng(4).normal(size=(2, 3, 300)) * 50).astype(np.float64)
    rec[:, :, 100:180] += 400 * np.sin(np.linspace(0, 20, 80))
    spec = _binary_spec()
    paper = [e for e in CompiledModel(model_to_bytes(spec, "float64")).stream(rec)
             if e["status_name"] == "decision"]
    spec.calibration = Calibration((2.0,), (-0.5,), 0.6, 0.1, True)
    cm = CompiledModel(model_to_bytes(spec, "float64"))
    calibrated = [e for e in cm.stream(rec) if e["status_name"] == "decision"]
    assert len(paper) == len(calibrated) >= 1
    assert all(e["confidence"] is None for e in paper)
    assert all(0.5 <= e["confidence"] <= 1.0 for e in calibrated)
    assert _CompiledMachines(cm).dont_know_.shape == (0,)  # nothing decided yet
