"""The installed C++ library: `cmake --install` of the build tree into a fresh prefix, then the
README's C++ example (its `classify_stream.cpp` and `CMakeLists.txt` blocks, verbatim) built
against it in a separate CMake project with find_package(eskin), and by hand with pkg-config;
both programs must report the touches the Python side finds on the same stream."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import eskin
from eskin.deploy.export import CompiledModel, MachineSpec, ModelSpec, model_to_bytes

REPO = next(p for p in Path(__file__).resolve().parents if (p / "README.md").is_file())


def build_tree() -> Path:
    """The CMake build tree the tests run against (ESKIN_BIN_DIR, else build/dev or build/cpp)."""
    env = os.environ.get("ESKIN_BIN_DIR")
    for d in filter(None, [env, REPO / "build/dev", REPO / "build/cpp"]):
        if (Path(d) / "cmake_install.cmake").is_file():
            return Path(d)
    pytest.fail(f"no CMake build tree with install rules (ESKIN_BIN_DIR={env!r}); run `make cpp`")


def tool(name: str) -> str:
    found = shutil.which(name) or shutil.which(name, path=str(Path(sys.executable).parent))
    if found is None:
        pytest.fail(f"{name} not found (it comes with `make venv`)")
    return found


def readme_block(language: str, after: str) -> str:
    """The first ```language block of README.md that follows the text ``after``."""
    text = (REPO / "README.md").read_text()
    start = text.index(after)
    m = re.compile(rf"^```{language}\n(.*?)^```", re.DOTALL | re.MULTILINE).search(text, start)
    assert m, f"README.md has no ```{language} block after {after!r}"
    return m.group(1)


@pytest.fixture(scope="module")
def prefix(tmp_path_factory) -> Path:
    prefix = tmp_path_factory.mktemp("prefix")
    subprocess.run(
        [tool("cmake"), "--install", str(build_tree()), "--prefix", str(prefix)],
        check=True,
        capture_output=True,
        text=True,
    )
    return prefix


@pytest.fixture(scope="module")
def model_and_stream(tmp_path_factory) -> tuple[Path, Path, list[str]]:
    """A 3-class model, a raw int16 stream with three touches (the last one cut by the end of the
    stream), and the lines classify_stream must print (from the Python side's stream classifier)."""
    d = tmp_path_factory.mktemp("model")
    rng = np.random.default_rng(3)
    pool = rng.standard_normal((9, 4, 4, 20))
    machines = [
        MachineSpec(
            k,
            -1,
            0.1 * (k - 1),
            (2, 2, 4),
            (1.0, 0.5, 2.0),
            pool[np.sort(rng.choice(9, 5, replace=False))],
            rng.standard_normal(5),
        )
        for k in range(3)
    ]
    spec = ModelSpec(
        class_names=["brush", "finger", "washer"],
        rule="one_vs_all",
        machines=machines,
        D=20,
        grid_shape=(4, 4),
    )
    model = d / "m.eskin"
    model.write_bytes(model_to_bytes(spec, "float64"))
    parts = []
    for n_quiet, n_loud in ((1500, 1200), (1500, 2000), (1500, 900)):
        parts += [rng.normal(0, 30, (n_quiet, 16)), rng.normal(0, 3000, (n_loud, 16))]
    stream = np.clip(np.concatenate(parts), -32768, 32767).astype("<i2")
    raw = d / "stream.bin"
    raw.write_bytes(stream.tobytes())
    events = CompiledModel(model).stream(stream)
    expected = [
        f"[{e['window'][0]}, {e['window'][1]}) {e['label']}{' ?' if e['dont_know'] else ''}"
        for e in events
        if e["status_name"] == "decision"
    ]
    assert len(expected) == 3
    return model, raw, expected


def run_classifier(exe: Path, model: Path, raw: Path) -> list[str]:
    with raw.open("rb") as f:
        out = subprocess.run(
            [str(exe), str(model)], stdin=f, capture_output=True, text=True, timeout=60, check=True
        )
    return out.stdout.splitlines()


def test_install_gives_headers_library_cmake_package_pkgconfig_and_tools(prefix):
    assert (prefix / "include/eskin/model.hpp").is_file()
    assert (prefix / "include/eskin/protocol.hpp").is_file()
    assert len(list(prefix.glob("lib*/libeskin_core.a"))) == 1
    config = list(prefix.glob("lib*/cmake/eskin/eskinConfig.cmake"))
    assert len(config) == 1
    assert "find_dependency(Eigen3" in config[0].read_text()
    assert (config[0].parent / "eskinConfigVersion.cmake").is_file()
    targets = "".join(p.read_text() for p in config[0].parent.glob("eskinTargets*.cmake"))
    assert "add_library(eskin::core STATIC IMPORTED)" in targets
    assert len(list(prefix.glob("lib*/pkgconfig/eskin.pc"))) == 1
    for exe in ("eskin-classify", "eskin-fw-sim"):
        out = subprocess.run(
            [str(prefix / "bin" / exe), "--version"], check=True, capture_output=True, text=True
        )
        assert out.stdout == f"{exe} {eskin.__version__}\n"
    bad = subprocess.run(
        [str(prefix / "bin/eskin-classify"), "--versio"],
        check=False,
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and "unknown option --versio" in bad.stderr
    # nothing of the build tree leaks into the installed package
    assert str(REPO) not in targets and str(build_tree()) not in targets


@pytest.fixture(scope="module")
def readme_example(prefix, tmp_path_factory) -> Path:
    """The README's classify_stream.cpp, built by its CMakeLists.txt with find_package(eskin)."""
    tmp_path = tmp_path_factory.mktemp("readme_example")
    project = tmp_path / "classify_stream"
    project.mkdir()
    (project / "classify_stream.cpp").write_text(readme_block("cpp", "classify_stream.cpp"))
    (project / "CMakeLists.txt").write_text(readme_block("cmake", "CMakeLists.txt"))
    cmake = tool("cmake")
    generator = (
        ["-G", "Ninja"]
        if shutil.which("ninja") or shutil.which("ninja", path=str(Path(sys.executable).parent))
        else []
    )
    build = tmp_path / "build"
    for cmd in (
        [
            cmake,
            "-S",
            str(project),
            "-B",
            str(build),
            *generator,
            f"-DCMAKE_PREFIX_PATH={prefix}",
            "-DCMAKE_BUILD_TYPE=Release",
        ],
        [cmake, "--build", str(build)],
    ):
        r = subprocess.run(cmd, check=False, capture_output=True, text=True)
        assert r.returncode == 0, r.stdout + r.stderr
    return build / "classify_stream"


def test_readme_example_builds_with_find_package(readme_example, model_and_stream):
    model, raw, expected = model_and_stream
    assert run_classifier(readme_example, model, raw) == expected


def eskin_cli(cwd: Path, *args: str) -> str:
    """Run ``eskin ARGS`` in ``cwd`` (the package under test); its standard output."""
    root = str(Path(eskin.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        filter(None, [root, os.environ.get("PYTHONPATH")])))
    r = subprocess.run([sys.executable, "-m", "eskin", *args], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, f"eskin {' '.join(args)}:\n{r.stdout}\n{r.stderr}"
    return r.stdout


def test_readme_example_runs_on_a_campaign_through_eskin_replay(readme_example, tmp_path):
    """Campaign -> model -> `eskin replay --format raw` -> the README's program on its stdin,
    with command-line tools only: one decision on every recording's touch, the decisions the
    Python side's stream classifier makes on the same bytes, and the bytes are the samples of
    the replay stream eskin-fw-sim would play."""
    d = tmp_path
    eskin_cli(d, "simulate", "-o", "c.h5", "--participants", "1", "--seed", "5", "-q")
    eskin_cli(d, "train", "c.h5", "--all-classes", "--quick", "-o", "m.joblib", "--no-progress")
    eskin_cli(d, "export", "m.joblib", "-o", "m.eskin")
    out = eskin_cli(d, "replay", "c.h5", "-o", "run2.raw", "--select", "run=2")
    assert "wrote run2.raw: 6 recordings (2 brush, 2 finger, 2 washer), " in out
    assert "a raw int16 stream" in out
    eskin_cli(d, "replay", "c.h5", "-o", "run2.eskr", "--select", "run=2")
    rf = eskin.read_replay_file(d / "run2.eskr")
    stream = np.fromfile(d / "run2.raw", dtype="<i2")
    assert np.array_equal(stream, np.asarray(rf.samples).ravel())
    lines = run_classifier(readme_example, d / "m.eskin", d / "run2.raw")
    events = CompiledModel(d / "m.eskin").stream(stream.reshape(rf.n_samples, -1))
    expected = [
        f"[{e['window'][0]}, {e['window'][1]}) {e['label']}{' ?' if e['dont_know'] else ''}"
        for e in events
        if e["status_name"] == "decision"
    ]
    assert lines == expected
    windows = [tuple(int(v) for v in line[1:].split(")")[0].split(", ")) for line in lines]
    for seg in rf.segments:  # every recording's touch is decided: a window overlaps it
        lo, hi = int(seg["start"]), int(seg["start"] + seg["length"])
        assert any(a < hi and b > lo for a, b in windows), (lo, hi, windows)


def test_readme_example_builds_with_pkg_config(prefix, model_and_stream, tmp_path):
    pkg_config, cxx = shutil.which("pkg-config"), shutil.which("g++")
    if pkg_config is None or cxx is None:
        pytest.skip("pkg-config or g++ is not installed")
    src = tmp_path / "classify_stream.cpp"
    src.write_text(readme_block("cpp", "classify_stream.cpp"))
    env = dict(
        os.environ,
        PKG_CONFIG_PATH=os.pathsep.join(
            str(p.parent) for p in prefix.glob("lib*/pkgconfig/eskin.pc")
        ),
    )
    flags = subprocess.run(
        [pkg_config, "--cflags", "--libs", "eskin"],
        env=env,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split()
    # the .pc file finds the prefix from its own place (the tree was installed with --prefix)
    assert any(
        f.startswith("-I") and Path(f[2:]).resolve() == (prefix / "include").resolve()
        for f in flags
    ), flags
    exe = tmp_path / "classify_stream"
    r = subprocess.run(
        [cxx, "-std=c++17", "-O1", str(src), *flags, "-o", str(exe)],
        check=False,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    model, raw, expected = model_and_stream
    assert run_classifier(exe, model, raw) == expected
