"""Mutation testing's Python runner (tools/mutant_runner.py) against running the module's tests
in a new process on each mutant (what tools/mutation.py did before it, through cosmic-ray).

Workload: a seeded sample of one module's mutants (those tools/mutation.py would run: its
operator families, no known-equivalent ones), one mutant at a time on each side (one worker:
the runner's gain without its parallelism), in the same process, baseline first. Each side
gets its own copy of the tree. Prints seconds per mutant of each, their ratio, and whether
every verdict agrees (they must: the runner only changes how the tests are run).

Usage: python benchmarks/bench_mutation.py [--module python/eskin/data/journal.py]
       [--mutants 12] [--seed 5]   (ESKIN_BIN_DIR as for the tests)
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))

import mutation  # noqa: E402
from mutant_runner import run_mutants  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--module", default="python/eskin/data/journal.py")
    ap.add_argument("--mutants", type=int, default=12)
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args()
    tests = mutation.PYTHON_MODULES[args.module]
    base_tree, runner_tree = (mutation.OUT / "bench" / side for side in ("baseline", "runner"))
    for tree in (base_tree, runner_tree):
        mutation.copy_tree(tree)
    env = dict(os.environ, PYTHONPATH="python", PYTHONDONTWRITEBYTECODE="1")
    env.setdefault("ESKIN_BIN_DIR", str(REPO / "build" / "dev"))
    command = [*mutation.PYTHON, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
               "-p", "no:randomly", *tests]
    kept, _, _ = mutation.python_mutants(args.module, base_tree, env, command, None)
    chosen = mutation.choose(kept, args.mutants, args.seed, args.module)
    source = (base_tree / args.module).read_text()
    mutants = []
    for w in chosen:
        code = mutation.python_mutant_source(source, w.mutations[0])
        if code is not None:  # could not be applied: not a mutant
            mutants.append((w.mutations[0].start_pos[0], code))

    t0 = time.perf_counter()
    baseline = []
    path = base_tree / args.module
    for _, code in mutants:
        path.write_text(code)
        r = subprocess.run(command, cwd=base_tree, env=env, capture_output=True)
        baseline.append(r.returncode != 0)
    path.write_text(source)
    t_base = time.perf_counter() - t0

    t0 = time.perf_counter()
    fast = run_mutants([(line, lambda code=code: code) for line, code in mutants], args.module,
                       [runner_tree], mutation.PYTHON, env, tests, 600.0, [])
    t_fast = time.perf_counter() - t0

    n = len(mutants)
    print(f"module {args.module}: {n} mutants (seed {args.seed}), {sum(baseline)} killed")
    print(f"  a new pytest process per mutant, all its tests: {t_base / n:6.2f} s per mutant")
    print(f"  tools/mutant_runner.py, one worker:              {t_fast / n:6.2f} s per mutant "
          f"(its coverage run and start included)")
    print(f"  ratio: {t_base / t_fast:.1f}x; verdicts agree: {baseline == fast}")


if __name__ == "__main__":
    main()
