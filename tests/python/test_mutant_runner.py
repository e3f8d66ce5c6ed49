"""tools/mutant_runner.py (`make mutation`'s runner of Python mutants): on a small package of its
own, with real forked workers and a real coverage run, each mutant's verdict is the one running
all the tests on it would give, the covering tests alone decide a kill, a hang is a kill, and the
worker's copy of the module is left as it was."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _runner():
    spec = importlib.util.spec_from_file_location("eskin_tools_mutant_runner",
                                                  REPO / "tools" / "mutant_runner.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


runner = _runner()

MODULE = "python/toy/ops.py"
SOURCE = '''\
LIMIT = 10


def clamp(x):
    if x > LIMIT:
        return LIMIT
    return x


def unused(x):
    return x + 1


def loop(n):
    while n != 0:
        n -= 1
    return n
'''
TESTS = '''\
from toy.ops import clamp, loop


def test_clamp():
    assert clamp(11) == 10 and clamp(3) == 3


def test_loop():
    assert loop(3) == 0
'''


def _tree(root: Path) -> Path:
    (root / "python" / "toy").mkdir(parents=True)
    (root / "python" / "toy" / "__init__.py").write_text("")
    (root / MODULE).write_text(SOURCE)
    (root / "tests").mkdir()
    (root / "tests" / "test_ops.py").write_text(TESTS)
    return root


def _mutant(old: str, new: str):
    assert SOURCE.count(old) == 1
    line = SOURCE[:SOURCE.index(old)].count("\n") + 1
    return line, lambda: SOURCE.replace(old, new)


def test_each_verdict_is_what_the_tests_say(tmp_path, monkeypatch):
    monkeypatch.setattr(runner, "PRELOAD", ("pytest",))  # the toy's tests need nothing else
    works = [_tree(tmp_path / f"w{i}") for i in range(2)]  # two workers side by side
    env = {"PYTHONPATH": "python", "PYTHONDONTWRITEBYTECODE": "1",
           "PATH": "/usr/bin:/bin"}
    mutants = [
        _mutant("if x > LIMIT:", "if x >= LIMIT:"),      # clamp(10) untested: survives
        _mutant("if x > LIMIT:", "if x < LIMIT:"),       # clamp(3) becomes 10: killed
        _mutant("LIMIT = 10", "LIMIT = 11"),             # import time: all tests, killed
        _mutant("return x + 1", "return x - 1"),         # no test runs it: survives
        _mutant("while n != 0:", "while n != -1:"),      # never ends: killed by the timeout
        (5, lambda: None),                               # cannot be applied
    ]
    verdicts = runner.run_mutants(mutants, MODULE, works, [sys.executable], env,
                                  ["tests/test_ops.py"], timeout=3.0, prefix=[])
    assert verdicts == [False, True, True, False, True, None]
    for w in works:
        assert (w / MODULE).read_text() == SOURCE


def test_the_coverage_map_names_the_tests_of_each_line(tmp_path):
    work = _tree(tmp_path / "w")
    env = {"PYTHONPATH": "python", "PYTHONDONTWRITEBYTECODE": "1", "PATH": "/usr/bin:/bin"}
    order, lines = runner.coverage_map([sys.executable], work, MODULE, ["tests/test_ops.py"],
                                       env, tmp_path / "map.json")
    assert order == ["tests/test_ops.py::test_clamp", "tests/test_ops.py::test_loop"]
    assert lines[1] == {""}  # LIMIT = 10: at import
    assert lines[5] == {"tests/test_ops.py::test_clamp"}
    assert lines[15] == {"tests/test_ops.py::test_loop"}
    assert 11 not in lines  # unused's body
