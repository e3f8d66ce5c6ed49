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
