"""The device budget against the device: `eskin train --target cortex-m4` on simulated campaigns
of several grids and rates, each model measured as `make mcu MODEL= CAMPAIGN=` measures it.

For each campaign (SIMULATED data: ``eskin simulate --grid RxC --rate R``, 10 participants to
train on, seed 21, and 2 held out, seed 77), first the cost model's calibration (``CALIBRATION``:
a tensor-RLS at D = 20, a binary tensor-SVM at D = 50 and a 3-class one bounded to 40 support
vectors, trained without a budget), then, once every campaign's calibration counts are written,
the default search of ``eskin train --target cortex-m4`` (``TARGET``); each model is trained by
the CLI, its budget estimate read (:func:`eskin.deploy.target.model_fits`: flash, RAM,
instructions per decision), and the device program of `make mcu` is built with it and run on
QEMU on 2 held-out recordings of each class (tools/mcu_case.py,
benchmarks/bench_mcu.device_run). Printed per model: estimated and measured
instructions (the median decision and the largest), flash and RAM, whether each measurement is
within the budget, and whether the largest decision is within the estimate times (1 + the cost
model's margin) (:func:`eskin.deploy.target.instruction_margin`).

``--write`` merges the counts into the data file the cost model is fitted to
(``python/eskin/deploy/cortex_m4_counts.json``: grid, rate, D, support vectors, alpha_store,
amplitude factor, bounded window, machines, kernel terms, median and largest instructions); the
figures printed beside them are then of the cost model fitted with them, and its left-out error
(each count predicted by the model fitted without it; and each grid's counts by the model fitted
without that grid) is printed at the end.

Run (after `make dev` and `make mcu-deps`; about 25 minutes on two cores):
    ESKIN_BIN_DIR=build/dev PYTHONPATH=python python benchmarks/bench_device_budget.py --write
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: (grid, samples per second)
CAMPAIGNS = [("8x8", 1000.0), ("1x4", 3000.0), ("3x5", 3000.0), ("4x4", 3000.0)]
#: the cost model's calibration: (name, `eskin train` options), trained without a budget (a
#: model may exceed the instruction budget: it is a count), the detector's window buffer cut to
#: 128 samples per taxel so that every grid's buffers fit the RAM
#: (D = 50 on 4x4 and smaller grids, 25 on larger ones, whose input tensor needs the RAM)
CALIBRATION = [
    ("rls-D20", ["--machine", "rls", "--quick", "--D", "20", "--window-samples", "128"]),
    ("svm-Dmid-binary", ["--machine", "svm", "--quick", "--D", "{Dmid}", "--classes",
                         "brush,washer", "--window-samples", "128"]),
    ("svm-Dmid-sv40", ["--machine", "svm", "--quick", "--D", "{Dmid}", "--max-support", "40",
                       "--window-samples", "128"]),
]
#: the budget: the default search of `eskin train --target cortex-m4`; where no model fits it,
#: the same search with twice the instructions (`--budget instr=3M`), so that the estimate of
#: that grid is measured all the same
TARGET = [("target", ["--target", "cortex-m4"])]
TARGET_FALLBACK = ("target-instr3M", ["--target", "cortex-m4", "--budget", "instr=3M"])
REFUSED: list[tuple] = []
COUNTS = REPO / "python" / "eskin" / "deploy" / "cortex_m4_counts.json"


def _module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def eskin_cli(*args: str) -> str:
    res = subprocess.run([sys.executable, "-m", "eskin", *args], capture_output=True, text=True,
                         check=False, cwd=REPO)
    if res.returncode != 0:
        raise SystemExit(f"eskin {' '.join(args)} failed:\n{res.stdout[-2000:]}{res.stderr[-2000:]}")
    return res.stdout


def campaigns(out: Path, grid: str, rate: float) -> tuple[Path, Path]:
    d = out / f"{grid}-{rate:g}Hz"
    d.mkdir(parents=True, exist_ok=True)
    train, held = d / "train.h5", d / "held.h5"
    for path, participants, seed in ((train, 10, 21), (held, 2, 77)):
        if not path.is_file():
            eskin_cli("simulate", "-o", str(path), "--participants", str(participants), "--seed",
                      str(seed), "--grid", grid, "--rate", f"{rate:g}", "--force")
    return train, held


def measure(case: Path, model: Path, held: Path, build: Path) -> dict:
    mcu_case = _module("mcu_case", REPO / "tools" / "mcu_case.py")
    bench_mcu = _module("bench_mcu", REPO / "benchmarks" / "bench_mcu.py")
    from eskin.deploy import device_budget

    budget = device_budget(model.read_bytes(), "cortex-m4")
    if not budget.fits:
        raise SystemExit("; ".join(budget.report()[1:3]))
    mcu_case.from_files(case, model, held, per_class=2, seed=0)
    return {**bench_mcu.device_run(build, case / "mcu_case.h"), "model": str(case / "model.eskin")}


def count_of(model: Path, grid: str, rate: float, recipe: str, dev: dict) -> dict:
    from eskin.deploy import CompiledModel
    from eskin.deploy.target import _bounded

    cm = CompiledModel(model.read_bytes())
    return {
        "grid": list(cm.grid_shape), "rate": rate, "D": cm.D, "n_support": cm.n_support,
        "alpha_store": list(cm.alpha_store), "amplitude": bool(cm.sv_log_energy.size),
        "bounded_window": _bounded(cm.window_config), "machines": len(cm.machines),
        "terms": sum(len(m["coef"]) for m in cm.machines),
        "instr_median": dev["instr"], "instr_max": dev["instr_max"],
        "decisions": dev["decisions"],
        "source": f"benchmarks/bench_device_budget.py: {grid} at {rate:g} Hz, recipe {recipe}",
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "build" / "bench-budget")
    ap.add_argument("--write", action="store_true",
                    help=f"merge the counts into {COUNTS.relative_to(REPO)}")
    ap.add_argument("--campaigns", default=None,
                    help="e.g. 8x8@1000,1x4@3000 (default: " + ",".join(
                        f"{g}@{r:g}" for g, r in CAMPAIGNS) + ")")
    args = ap.parse_args()
    todo = CAMPAIGNS if args.campaigns is None else [
        (c.split("@")[0], float(c.split("@")[1])) for c in args.campaigns.split(",")]
    from eskin.deploy.target import parse_budget

    budget = parse_budget(None, "cortex-m4")
    rows = []
    for phase in (CALIBRATION, TARGET):
        for grid, rate in todo:
            train, held = campaigns(args.out, grid, rate)
            for name, options in phase:
                row = run_one(args, grid, rate, train, held, name, options)
                if row is None and phase is TARGET and REFUSED and REFUSED[-1][:3] == (
                        grid, rate, name):
                    row = run_one(args, grid, rate, train, held, *TARGET_FALLBACK)
                if row is None:
                    continue
                rows.append(row)
                if args.write:
                    write_counts([r[3] for r in rows])
    report(rows, budget)


def run_one(args, grid: str, rate: float, train: Path, held: Path, name: str,
            options: list[str]) -> tuple | None:
    """Train, measure on QEMU (both kept in the case's folder and reused when there), count;
    None when the model does not fit the device."""
    rows, cols = (int(v) for v in grid.split("x"))
    options = [o.format(Dmid=50 if rows * cols <= 16 else 25) for o in options]
    name = name.replace("Dmid", f"D{50 if rows * cols <= 16 else 25}")
    case = args.out / f"{grid}-{rate:g}Hz" / name
    case.mkdir(parents=True, exist_ok=True)
    model = case / "trained.eskin"
    done = case / "result.json"
    t0 = time.time()
    refused = case / "refused.json"
    if refused.is_file():
        REFUSED.append((grid, rate, name, json.loads(refused.read_text())["why"]))
        return None
    if done.is_file():
        res = json.loads(done.read_text())
        line, dev = res["line"], res["dev"]
        t1 = t0
    else:
        try:
            log = eskin_cli("train", str(train), "-o", str(model), "--force", "--n-jobs", "1",
                            "--no-progress", *options)
        except SystemExit as exc:
            why = next((ln for ln in str(exc).splitlines() if ln.startswith("error:")), str(exc))
            print(f"{grid} {rate:g} Hz {name}: eskin train refused: {why}", flush=True)
            REFUSED.append((grid, rate, name, why))
            refused.write_text(json.dumps({"why": why}))
            return None
        line = next((ln for ln in log.splitlines() if "(cost model" in ln), "")
        t1 = time.time()
        try:
            dev = measure(case, model, held, args.out / "build")
        except SystemExit as exc:
            print(f"{grid} {rate:g} Hz {name}: not measured: {str(exc)[-300:]}", flush=True)
            return None
        done.write_text(json.dumps({"line": line, "dev": dev}))
    count = count_of(case / "model.eskin", grid, rate, name, dev)
    print(f"{grid} {rate:g} Hz {name}: train {t1 - t0:.0f} s, device {time.time() - t1:.0f} s: "
          f"{line.strip()} | {dev}", flush=True)
    return (grid, rate, name, count, dev, line.strip())


def write_counts(new: list[dict]) -> None:
    data = json.loads(COUNTS.read_text())
    keep = [c for c in data["counts"] if c["source"] not in {n["source"] for n in new}]
    data["counts"] = keep + new
    COUNTS.write_text(json.dumps(data, indent=1) + "\n")


def report(rows, budget) -> None:
    import eskin.deploy.target as target

    target = importlib.reload(target)  # the cost model fitted with the counts just written
    from eskin.deploy.target import (
        decision_instructions,
        instruction_margin,
        model_fits,
        parse_budget,
    )

    margin = instruction_margin()
    print("(the CLI's own lines, at training time, with the cost model of that moment:)")
    for grid, rate, name, _, _, line in rows:
        if line:
            print(f"  {grid} {rate:g} Hz {name}: {line}")
    print(f"\ncost model: {len(target.instruction_counts())} counts; margin "
          f"{100 * margin:.1f} % (the largest left-out under-estimate of a decision)")
    print("| grid | rate | recipe | D | support vectors | alpha_store | instructions: estimate "
          "| x (1 + margin) | measured median | largest | within budget | within the stated "
          "error | flash: estimate | measured (without the test's decisions) | RAM: estimate | "
          "measured | fits |")
    print("|" + "---|" * 17)
    for grid, rate, name, c, dev, _ in rows:
        est = decision_instructions(tuple(c["grid"]), c["D"], tuple(c["alpha_store"]),
                                    c["n_support"], c["amplitude"], c["bounded_window"],
                                    c["terms"])
        b = parse_budget("instr=3M", "cortex-m4") if name.endswith("instr3M") else budget
        # the device's flash without the test's table of reference decisions (16 + 8 bytes
        # per machine's value, per decision: tools/mcu_case.py), which no firmware holds
        flash = dev["flash"] - max(1, dev["decisions"]) * (16 + 8 * c["machines"])
        fits, fig = model_fits(Path(dev["model"]).read_bytes(), b)
        inside = dev["instr_max"] <= b.instructions and flash <= b.flash_bytes \
            and dev["ram"] <= b.ram_bytes
        stated = dev["instr_max"] <= est * (1 + margin)
        print(f"| {grid} | {rate:g} | {name} | {c['D']} | {c['n_support']} | "
              f"{tuple(c['alpha_store'])} | {est / 1e6:.3f} M | {est * (1 + margin) / 1e6:.3f} M "
              f"| {dev['instr'] / 1e6:.3f} M | {dev['instr_max'] / 1e6:.3f} M | "
              f"{'yes' if inside else 'NO'} | {'yes' if stated else 'NO'} | {fig['flash']:.0f} | "
              f"{flash} | {fig['ram']:.0f} | {dev['ram']} | {'yes' if fits else 'no'} |")
    for grid, rate, name, why in REFUSED:
        print(f"{grid} at {rate:g} Hz, {name}: eskin train refused: {why}")
    err = target.instruction_model_error()
    print("\nthe cost model's error (relative: |estimate / median - 1|):")
    for k, v in err.items():
        print(f"  {k}: {v}")


if __name__ == "__main__":
    main()
