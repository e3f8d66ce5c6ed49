"""What `eskin evaluate --scheduler local:N` costs against the serial run, in one run.

Both evaluate the same SIMULATED campaign (``eskin.simulate``, ``--participants`` people, seed
3) with the same options (``--folds``, seed 0; the default recipe and the live figure unless
``--extra`` says otherwise), each as its own ``python -m eskin evaluate`` process, serial and on
the pool alternating (the order flips every round: the machine is shared, so neither always
runs first). This script is the subreaper of every process a run starts
(``PR_SET_CHILD_SUBREAPER``): a run's CPU is the user + system time of all of them, the
evaluate process, its workers and helpers, each counted once when it is reaped (``os.wait4``),
whichever process reaps it. Peak RSS is the largest sum of the resident sets of the run's
live processes, sampled every 0.2 s.

The runs write bytecode as Python does (PYTHONDONTWRITEBYTECODE is left out of their
environment), and every module they import is compiled before the first (:data:`WARM`):
an installed package has its bytecode, and 5 s of compiling per process would be counted
against every worker.

On a machine shared with other jobs, the wall time of a run is its share of the cores, and
where the kernel groups the shares (autogroup: one group per ``setsid``) a run's processes all
share one group's, however many they are: as root, ``--nice -20`` runs every run in a group of
its own at that niceness, ahead of the other jobs, near the wall time of an idle machine.

Printed per run: the 1-minute load average at its start, CPU seconds, wall seconds, peak RSS;
then per round the ratios pool / serial of CPU and wall, and whether the pool's
evaluation.json equals the serial one (times left out). ``--baseline-src``: a third run per
round, the same scheduler with the eskin package of another ``python/`` folder (an earlier
commit's, with this checkout's compiled core).

    python benchmarks/bench_scheduler.py [--participants 20] [--folds 4] [--rounds 2]
        [--scheduler local:2] [--extra "--no-live"] [--baseline-src /tmp/eskin-base/python]
        [--nice -20]
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

import psutil

PR_SET_CHILD_SUBREAPER = 36

#: imported once per package tree before the timed runs, so that no run compiles bytecode
#: (the runs write it, as Python does: PYTHONDONTWRITEBYTECODE is left out of their environment)
WARM = (
    "eskin.cli, eskin.learn.training, eskin.learn.evaluation, eskin.learn.evaluation_report, "
    "eskin.link.live_scores, eskin.learn.baselines, joblib.externals.loky.process_executor, "
    "distributed"
)


def _env(src: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = str(src)
    return env


def warm(src: Path) -> None:
    code = f"import importlib; [importlib.import_module(m.strip()) for m in {WARM!r}.split(',')]"
    subprocess.run([sys.executable, "-c", code], env=_env(src), check=True)


def campaign(cache: Path, participants: int) -> Path:
    path = cache / f"bench_scheduler_{participants}p.h5"
    if not path.exists():
        import eskin

        cache.mkdir(parents=True, exist_ok=True)
        eskin.simulate(path, participants=participants, seed=3, overwrite=True)
    return path


def _tree_rss(root: psutil.Process) -> int:
    """Resident bytes of ``root`` and every live descendant (orphans adopted by this process
    included: they are its children)."""
    procs = [root, *psutil.Process().children(recursive=True)]
    total = 0
    for p in {q.pid: q for q in procs}.values():
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total


def _reap_all(cpu: float, deadline_s: float = 120.0) -> float:
    """``cpu`` plus the user + system time of every process this one still has to reap."""
    end = time.monotonic() + deadline_s
    while True:
        try:
            pid, _, ru = os.wait4(-1, os.WNOHANG)
        except ChildProcessError:
            return cpu
        if pid:
            cpu += ru.ru_utime + ru.ru_stime
        elif time.monotonic() > end:
            for p in psutil.Process().children():
                p.kill()
        else:
            time.sleep(0.05)


def _niceness(pid: int, nice: int) -> None:
    """Process ``pid``, just started by ``setsid``, at niceness ``nice`` and, where the kernel
    groups the CPU shares (``/proc/sys/kernel/sched_autogroup_enabled``), its autogroup too (the
    niceness of a process only orders it among the processes of its own group).
    Set just after the start: the processes it starts later inherit both."""
    os.setpriority(os.PRIO_PROCESS, pid, nice)
    try:
        Path(f"/proc/{pid}/autogroup").write_text(str(nice))
    except OSError:
        pass


def run(cmd: list[str], env: dict[str, str], nice: int = 0) -> dict[str, float]:
    """CPU, wall and peak RSS of ``cmd`` and every process it starts (at niceness ``nice``)."""
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
    )
    _niceness(proc.pid, nice)
    root = psutil.Process(proc.pid)
    peak, cpu, rc = 0, 0.0, None
    while rc is None:
        peak = max(peak, _tree_rss(root))
        pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            cpu, rc = ru.ru_utime + ru.ru_stime, os.waitstatus_to_exitcode(status)
            proc.returncode = rc
        else:
            time.sleep(0.2)
    wall = time.perf_counter() - t0
    cpu = _reap_all(cpu)
    if rc != 0:
        sys.exit(f"{shlex.join(cmd)} failed ({rc}): {proc.stderr.read().decode()[-2000:]}")
    proc.stderr.close()
    return {"load": load, "cpu": cpu, "wall": wall, "rss_mb": peak / 2**20}


def _untimed(x):
    if isinstance(x, dict):
        return {k: _untimed(v) for k, v in x.items() if not k.endswith("seconds")}
    return [_untimed(v) for v in x] if isinstance(x, list) else x


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--participants", type=int, default=20)
    ap.add_argument("--folds", type=int, default=4)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--scheduler", default="local:2")
    ap.add_argument("--extra", default="", help="more evaluate options, one string")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin_bench_scheduler"))
    ap.add_argument(
        "--baseline-src",
        type=Path,
        default=None,
        help="also run the scheduler with the eskin package of this python/ folder "
        "(the same compiled core), e.g. a checkout of an earlier commit",
    )
    ap.add_argument(
        "--nice",
        type=int,
        default=0,
        help="niceness of the runs (as root, -20 takes the cores from the other "
        "jobs of a shared machine: the wall time of a nearly idle one)",
    )
    args = ap.parse_args(argv)
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        sys.exit("prctl(PR_SET_CHILD_SUBREAPER) failed: the workers' CPU could not be counted")
    path = campaign(args.cache, args.participants)
    here = Path(__file__).resolve().parents[1] / "python"
    base = [
        sys.executable,
        "-m",
        "eskin",
        "evaluate",
        str(path),
        "--folds",
        str(args.folds),
        "--force",
        *shlex.split(args.extra),
    ]
    pool = ["--scheduler", args.scheduler]
    modes = {"serial": (here, []), args.scheduler: (here, pool)}
    if args.baseline_src is not None:
        modes["baseline"] = (args.baseline_src.resolve(), pool)
    for src in {src for src, _ in modes.values()}:
        warm(src)
    print(
        f"campaign {path.name}: {args.participants} participants, --folds {args.folds} "
        f"{args.extra}; {os.cpu_count()} cores; runs at niceness {args.nice}"
    )
    print(f"{'round':>5} {'run':>10} {'load':>5} {'CPU s':>8} {'wall s':>8} {'peak RSS MiB':>13}")
    for r in range(args.rounds):
        order = list(modes) if r % 2 == 0 else list(reversed(modes))
        res = {}
        for name in order:
            out = args.cache / f"out_{name.replace(':', '')}"
            src, opts = modes[name]
            res[name] = run([*base, "--out", str(out), *opts], _env(src), args.nice)
            m = res[name]
            print(
                f"{r + 1:>5} {name:>10} {m['load']:5.2f} {m['cpu']:8.2f} {m['wall']:8.2f} "
                f"{m['rss_mb']:13.0f}",
                flush=True,
            )
        results = {
            n: _untimed(
                json.loads(
                    (args.cache / f"out_{n.replace(':', '')}" / "evaluation.json").read_text()
                )
            )
            for n in modes
        }
        s = res["serial"]
        for name in list(modes)[1:]:
            p = res[name]
            print(
                f"round {r + 1}: {name} / serial CPU {p['cpu'] / s['cpu']:.2f}x, wall "
                f"{p['wall'] / s['wall']:.2f}x, peak RSS {p['rss_mb'] / s['rss_mb']:.2f}x; "
                f"results identical: {results[name] == results['serial']}",
                flush=True,
            )


if __name__ == "__main__":
    main()
