"""Runs a Python module's mutants quickly, with the same verdicts as running its tests on each
(tools/mutation.py, docs/testing.md).

Three things make a mutant cheap without changing what counts as killed:

* **The covering tests first.** One unmutated run under coverage.py records which tests execute
  each line of the module (a context per test). A mutant first runs only the tests that execute
  its line (all of them when the line runs at import time), in the order pytest collects them;
  if one fails (or the run times out) the mutant is killed: those tests are part of the module's
  test command, which would fail too.
* **No start-up per mutant.** Each worker is one process that has imported the tests' heavy
  dependencies (numpy, scipy, h5py, scikit-learn, pytest; never eskin) and forks a child per
  mutant; the child imports the mutated package afresh from its worker's copy of the tree.
* **The verdict "survived" from all the tests.** A mutant the covering tests do not kill (or
  on a line no test executes in-process: code run by a subprocess has no coverage) runs all
  the module's tests; only that run can call it a survivor. The unmutated tests must pass in
  every worker first, so a failure is the mutant's.

Workers (``jobs``) each own a copy of the tree, so mutants of one module run side by side.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

#: imported once by each worker before it forks: what the tests import on every run (no pytest
#: plugin such as hypothesis: pytest would warn that it cannot rewrite its asserts)
PRELOAD = ("numpy", "scipy.signal", "scipy.linalg", "h5py", "pytest",
           "sklearn.base", "typer", "rich")

#: the worker: reads one JSON request a line ({"tests": [...], "timeout": s}), forks a child
#: that runs pytest on them in the worker's tree, answers {"rc": code} (-1: timed out)
SERVER = r"""
import importlib, json, os, signal, sys, time
for name in sys.argv[1].split(","):
    try:
        importlib.import_module(name)
    except Exception:
        pass
assert not any(m == "eskin" or m.startswith("eskin.") for m in sys.modules), "eskin preloaded"
for line in sys.stdin:
    req = json.loads(line)
    pid = os.fork()
    if pid == 0:
        os.setpgid(0, 0)
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        import pytest
        try:
            rc = pytest.main(["-x", "-q", "-p", "no:cacheprovider", "-p", "no:randomly",
                              *req["tests"]])
        except BaseException:
            rc = 99
        os._exit(int(rc))
    deadline = time.monotonic() + req["timeout"]
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            rc = os.waitstatus_to_exitcode(status)
            break
        if time.monotonic() > deadline:
            try:
                os.killpg(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)
            rc = -1
            break
        time.sleep(0.02)
    try:
        os.killpg(pid, signal.SIGKILL)  # whatever the child left running
    except (ProcessLookupError, PermissionError):
        pass
    print(json.dumps({"rc": rc}), flush=True)
"""

#: the coverage run: the tests once, each under its own coverage context; writes
#: {"order": [node ids], "lines": {line: [node ids, "" for import time]}} to argv[2]
COVERAGE = r"""
import json, sys
import coverage, pytest
module, out, tests = sys.argv[1], sys.argv[2], sys.argv[3:]
cov = coverage.Coverage(data_file=None, include=[module])
order = []
class Contexts:
    def pytest_collection_modifyitems(self, items):
        order.extend(i.nodeid for i in items)
    def pytest_runtest_setup(self, item):
        cov.switch_context(item.nodeid)
cov.start()
rc = pytest.main(["-q", "-p", "no:cacheprovider", "-p", "no:randomly", *tests],
                 plugins=[Contexts()])
cov.stop()
data = cov.get_data()
lines = {}
for f in data.measured_files():
    for line, ctx in data.contexts_by_lineno(f).items():
        lines.setdefault(line, set()).update(ctx)
json.dump({"rc": int(rc), "order": order,
           "lines": {str(k): sorted(v) for k, v in lines.items()}}, open(out, "w"))
"""


def coverage_map(python: list[str], work: Path, module: str, tests: list[str], env: dict,
                 out: Path) -> tuple[list[str], dict[int, set[str]]]:
    """The tests in collection order, and for each line of ``module`` the tests that execute it
    ("" among them: the line runs when the module is imported)."""
    r = subprocess.run([*python, "-c", COVERAGE, str(work / module), str(out), *tests],
                       cwd=work, env=env, capture_output=True, text=True, check=False)
    if r.returncode != 0 or not out.exists():
        sys.exit(f"mutation: the coverage run of {module}'s tests failed:\n{r.stdout[-3000:]}"
                 f"{r.stderr[-2000:]}")
    data = json.loads(out.read_text())
    return data["order"], {int(k): set(v) for k, v in data["lines"].items()}


class Worker:
    """One copy of the tree and one forking process that runs tests in it."""

    def __init__(self, python: list[str], work: Path, env: dict, prefix: list[str]) -> None:
        self.work = work
        self.env = env
        self.proc = subprocess.Popen([*prefix, *python, "-c", SERVER, ",".join(PRELOAD)],
                                     cwd=work, env=env, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True)

    def quick(self, tests: list[str], timeout: float) -> int:
        """pytest's exit code on ``tests`` in a forked child (-1: it timed out)."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"tests": tests, "timeout": timeout}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            sys.exit(f"mutation: the test worker in {self.work} stopped")
        return int(json.loads(line)["rc"])

    def close(self) -> None:
        if self.proc.stdin:
            self.proc.stdin.close()
        self.proc.wait()
        if self.proc.stdout:
            self.proc.stdout.close()


def run_mutants(mutants: list[tuple[int, Callable[[], str | None]]], module: str,
                works: list[Path], python: list[str], env: dict, tests: list[str],
                timeout: float, prefix: list[str], progress: str = "",
                verdict: Callable[[int, bool | None], None] | None = None) -> list[bool | None]:
    """Whether each mutant (its line, and a function making the mutated source; None: the
    mutation cannot be applied) is killed, with ``len(works)`` workers; None for a mutant that
    could not be applied. ``verdict(i, killed)`` is called as each mutant's comes in.

    ``tests``: the module's pytest arguments (files, -k)."""
    order, lines = coverage_map(python, works[0], module, tests, env,
                                works[0] / ".mutation-coverage.json")
    rank = {t: i for i, t in enumerate(order)}
    workers = [Worker(python, w, env, prefix) for w in works]
    free = list(workers)
    lock = threading.Lock()
    done = [0]
    t0 = time.monotonic()
    if any(w.quick(tests, timeout) != 0 for w in workers):  # the unmutated tests must pass
        sys.exit(f"mutation: the tests of {module} fail in a forked worker, unmutated")

    def one(i: int) -> bool | None:
        killed = run_one(*mutants[i])
        if verdict is not None:
            with lock:
                verdict(i, killed)
        return killed

    def run_one(line: int, make: Callable[[], str | None]) -> bool | None:
        source = make()  # here, not before: the other workers' tests run meanwhile
        if source is None:
            return None
        with lock:
            worker = free.pop()
        path = worker.work / module
        original = path.read_text()
        try:
            path.write_text(source)
            covering = lines.get(line, set())
            selected = tests if "" in covering else sorted(covering - {""}, key=rank.__getitem__)
            killed = bool(selected) and worker.quick(selected, timeout) != 0
            if not killed and selected != tests:
                killed = worker.quick(tests, timeout) != 0
        finally:
            path.write_text(original)
            with lock:
                free.append(worker)
                done[0] += 1
                if progress and (done[0] % 50 == 0 or done[0] == len(mutants)):
                    print(f"  {progress}: {done[0]}/{len(mutants)} mutants in "
                          f"{time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)
        return killed

    try:
        with ThreadPoolExecutor(len(workers)) as pool:
            return list(pool.map(one, range(len(mutants))))
    finally:
        for w in workers:
            w.close()
