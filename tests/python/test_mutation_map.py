"""tools/mutation.py (`make mutation`, docs/testing.md): every module it mutates has tests that
exist, the modules that guard data, results, the model format, the wire, the recipe search, the
cost model and the device's decision path are all in it, and its sample, interval and diff
arithmetic are right."""

from __future__ import annotations

import importlib.util
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _mutation():
    spec = importlib.util.spec_from_file_location("eskin_tools_mutation", REPO / "tools" / "mutation.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


mutation = _mutation()

#: the modules that must stay under mutation testing, by what they guard
GUARDED = {
    "data": ["python/eskin/data/journal.py", "python/eskin/data/campaign.py",
             "python/eskin/data/replay.py"],
    "results": ["python/eskin/learn/evaluation.py"],
    "model format": ["cpp/src/model_format.cpp", "python/eskin/deploy/export.py",
                     "python/eskin/learn/calibration.py"],
    "wire": ["python/eskin/link/protocol.py", "cpp/src/protocol.cpp",
             "python/eskin/link/receiver.py"],
    "recipe search": ["python/eskin/learn/recipes.py"],
    "cost model": ["python/eskin/deploy/target.py"],
    "decision path": ["cpp/src/model.cpp", "cpp/src/scalar_bases.hpp",
                      "cpp/src/model_overlap.cpp"],
}


@pytest.mark.parametrize("what", sorted(GUARDED))
def test_every_guarding_module_is_mutation_tested(what):
    missing = [m for m in GUARDED[what] if m not in mutation.modules()]
    assert not missing, f"{what}: not in tools/mutation.py: {missing}"


@pytest.mark.parametrize("module", sorted(mutation.PYTHON_MODULES))
def test_each_python_module_exists_and_its_test_files_exist(module):
    assert (REPO / module).is_file()
    args = mutation.PYTHON_MODULES[module]
    files = [a.split("::")[0] for a in args if a.startswith("tests/")]
    assert files, f"{module}: no test file"
    for f in files:
        assert (REPO / f).is_file(), f"{module}: {f} does not exist"
    # every argument is a test file (a node of one), or an option with its value
    rest = [a for a in args if not a.startswith("tests/")]
    assert all(o in ("-k", "-m") for o in rest[::2]) and len(rest) % 2 == 0, rest


@pytest.mark.parametrize("mod", mutation.CPP_MODULES, ids=lambda m: m.path)
def test_each_cpp_module_has_its_region_and_its_googletest_files(mod):
    assert (REPO / mod.path).is_file()
    assert mod.targets
    for t in mod.targets:
        assert (REPO / "tests" / "cpp" / f"{t}.cpp").is_file(), f"{mod.path}: {t}"
    # the markers are in the file and the region holds mutants
    assert len(mutation.cpp_mutants((REPO / mod.path).read_text(), mod)) > 10


@pytest.mark.parametrize("module", sorted(mutation.PYTHON_MODULES))
def test_each_python_module_runs_every_test_file_named_after_it(module):
    """python/eskin/<layer>/<name>.py: every tests/python/<layer>/test_<name>*.py is in its
    list (a new test file of a module that the list forgets kills no mutant)."""
    layer, name = Path(module).parent.name, Path(module).stem
    named = sorted(str(p.relative_to(REPO)) for p in
                   (REPO / "tests" / "python" / layer).glob(f"test_{name}*.py"))
    listed = {a.split("::")[0] for a in mutation.PYTHON_MODULES[module]}
    left_out = {f for f, m in mutation.NOT_LISTED.items() if m == module}
    assert not [f for f in named if f not in listed | left_out], (module, named)


def test_python_test_nodes_name_tests_that_exist():
    for module, args in mutation.PYTHON_MODULES.items():
        for a in args:
            if "::" in a:
                path, name = a.split("::", 1)
                assert f"def {name.split('[')[0]}(" in (REPO / path).read_text(), (module, a)


def test_the_wilson_interval():
    lo, hi = mutation.wilson(17, 20)
    assert (round(lo, 4), round(hi, 4)) == (0.6396, 0.9476)
    assert mutation.wilson(20, 20)[1] == 1.0
    assert mutation.wilson(0, 20)[0] == 0.0
    assert mutation.wilson(0, 0) == (0.0, 1.0)


def test_a_seed_draws_the_same_sample_and_another_seed_another():
    items = list(range(500))
    a = mutation.choose(items, 20, 7, "python/eskin/data/replay.py")
    assert a == mutation.choose(items, 20, 7, "python/eskin/data/replay.py")
    assert a == sorted(a) and len(set(a)) == 20
    assert a != mutation.choose(items, 20, 8, "python/eskin/data/replay.py")
    # two modules of the same size draw different positions with one seed
    assert a != mutation.choose(items, 20, 7, "cpp/src/model.cpp")
    assert mutation.choose(items, None, 7, "x") == items
    assert mutation.choose(items[:5], 20, 7, "x") == items[:5]


def test_the_sample_size_all_or_empty_is_every_mutant():
    assert mutation.sample_size("all") is None
    assert mutation.sample_size("") is None
    assert mutation.sample_size("20") == 20


def test_changed_lines_of_a_zero_context_diff():
    diff = """diff --git a/python/eskin/a.py b/python/eskin/a.py
index 1..2 100644
--- a/python/eskin/a.py
+++ b/python/eskin/a.py
@@ -3 +3 @@ def f():
-    return 1
+    return 2
@@ -10,0 +11,2 @@ def g():
+    x = 1
+    y = 2
@@ -20,3 +22,0 @@ def h():
-    a
-    b
-    c
diff --git a/cpp/src/gone.cpp b/cpp/src/gone.cpp
deleted file mode 100644
--- a/cpp/src/gone.cpp
+++ /dev/null
@@ -1,2 +0,0 @@
-int a;
-int b;
"""
    assert mutation.changed_lines(diff) == {"python/eskin/a.py": {3, 11, 12, 22, 23}}


def test_mutants_are_not_made_in_code_the_host_build_does_not_compile():
    mod = mutation.CppModule("x.cpp", "int f(", None, ("test_model",))
    text = "\n".join([
        "int f(int a) {",
        "#if defined(ESKIN_DEVICE)",
        "  if (a < 1) return 0;",
        "#else",
        "  if (a < 2) return 0;",
        "#endif",
        "  return a;",
        "}"])
    lines = {i for i, _, _ in mutation.cpp_mutants(text, mod)}
    assert lines == {4}


def test_make_mutation_passes_the_seed_the_sample_and_the_modules():
    def dry(*args: str) -> list[str]:
        out = subprocess.run(["make", "-n", *args], cwd=REPO, check=True, capture_output=True,
                             text=True).stdout
        line = next(ln for ln in out.splitlines() if "tools/mutation.py" in ln)
        return shlex.split(line.split("tools/mutation.py", 1)[1].replace("\\", ""))

    assert dry("mutation") == ["--sample", "20"]
    assert dry("mutation", "MUTATION_SAMPLE=", "MUTATION_SEED=12",
               "MUTATION_ONLY=cpp/src/model.cpp,python/eskin/data/replay.py") == [
        "--sample", "all", "--seed", "12", "--only", "cpp/src/model.cpp,python/eskin/data/replay.py"]
    assert dry("mutation-diff") == ["--diff", "--sample", "all"]
    assert dry("mutation-diff", "BASE=HEAD~2", "MUTATION_SAMPLE=5") == [
        "--diff", "HEAD~2", "--sample", "5"]


@pytest.mark.parametrize("module", sorted(mutation.EQUIVALENT))
def test_each_known_equivalent_mutant_names_exactly_one_mutant_of_its_module(module):
    """An entry of EQUIVALENT that an edit has made stale (its line changed or gone), or that
    matches two mutants (the same line twice in the module), fails here: it would leave out a
    mutant nobody has examined."""
    assert module in mutation.modules()
    text = (REPO / module).read_text()
    rows = [r.strip() for r in text.splitlines()]
    entries = mutation.EQUIVALENT[module]
    assert len({(e.operator, e.line, e.mutant) for e in entries}) == len(entries)
    for e in entries:
        assert e.why and e.line != e.mutant, e
        if module in mutation.PYTHON_MODULES:
            # cosmic-ray's mutants need the mutation extra; the line must be there, once
            assert rows.count(e.line) == 1, e
            continue
        mod = next(m for m in mutation.CPP_MODULES if m.path == module)
        found = [m for m in mutation.cpp_mutants(text, mod)
                 if m[1] == e.operator and rows[m[0]] == e.line and m[2].strip() == e.mutant]
        assert len(found) == 1, e


def test_a_known_equivalent_mutant_is_matched_by_its_operator_line_and_text():
    module = "cpp/src/model.cpp"
    e = mutation.EQUIVALENT[module][0]
    assert mutation.is_equivalent(module, e.operator, "  " + e.line, lambda: e.mutant + " ")
    assert not mutation.is_equivalent(module, e.operator, e.line, lambda: e.line)
    assert not mutation.is_equivalent(module, "delete check", e.line, lambda: e.mutant)
    assert not mutation.is_equivalent("cpp/src/protocol.cpp", e.operator, e.line,
                                      lambda: e.mutant)


def test_a_bare_star_or_slash_in_parameters_is_not_an_operator_to_mutate():
    source = ("def f(a, *, b=2 * 3):\n"
              "    return a * b\n"
              "def g(a, /, b: int, *args, c=lambda x, *, y: x / y):\n"
              "    y = (a /\n"
              "         b)\n"
              "h = lambda a, *, b: a * b\n")
    rows = source.splitlines()
    lists = mutation.parameter_lists(source)

    def marker(line: int, text: str, k: int = 0) -> bool:
        col = -1
        for _ in range(k + 1):
            col = rows[line - 1].index(text, col + 1)
        return mutation.is_parameter_marker(rows, (line, col), lists)

    assert marker(1, "*") and not marker(1, "*", 1)  # the marker, then 2 * 3 in a default
    assert not marker(2, "*")
    assert marker(3, "/") and marker(3, "*")  # *args: no operator either
    assert marker(3, "*", 1)  # the lambda's own marker, inside g's default
    assert not marker(3, "/", 1)  # x / y: the lambda's body
    assert not marker(4, "/")  # an operator at the end of a line
    assert marker(6, "*") and not marker(6, "*", 1)


def test_a_second_run_of_a_module_is_refused_while_the_first_holds_its_copies(tmp_path,
                                                                               monkeypatch):
    """Two invocations on one module would share its copies of the tree (the second copying it
    again under the first one's mutants): the second stops with a message; another module is
    free."""
    monkeypatch.setattr(mutation, "OUT", tmp_path)
    monkeypatch.setattr(mutation, "_HELD", [])
    mutation.hold_copies("python/eskin/data/replay.py")

    def other(module: str) -> subprocess.CompletedProcess:
        code = ("import importlib.util, pathlib, sys; "
                "spec = importlib.util.spec_from_file_location('m', sys.argv[1]); "
                "m = importlib.util.module_from_spec(spec); sys.modules['m'] = m; "
                "spec.loader.exec_module(m); m.OUT = pathlib.Path(sys.argv[2]); "
                "m.hold_copies(sys.argv[3]); print('held')")
        return subprocess.run([sys.executable, "-c", code, str(REPO / "tools" / "mutation.py"),
                               str(tmp_path), module], capture_output=True, text=True)

    second = other("python/eskin/data/replay.py")
    assert second.returncode == 1 and "held" not in second.stdout
    assert second.stderr.strip() == (
        f"mutation: another run of python/eskin/data/replay.py is using its copies under "
        f"{tmp_path / 'py'}; wait for it to end")
    free = other("python/eskin/data/journal.py")
    assert free.returncode == 0 and free.stdout == "held\n"
    for fh in mutation._HELD:
        fh.close()
