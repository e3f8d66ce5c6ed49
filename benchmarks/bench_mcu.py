"""Instructions per decision of the inference core on a Cortex-M4F (QEMU), beside x86-64.

For each model of the table below (the MCU preset of the demo model, tools/mcu_case.py: a
3-class tensor-RLS, Maximal Discrepancy selection on the quick grid, trained on all simulated
participants but one; the detector's longest window cut so that its buffers fit 128 KB), the
device program of `make mcu` is rebuilt with that model compiled in and run on QEMU's
mps2-an386 board (Cortex-M4, -icount shift=0: instructions counted with SysTick, see
docs/mcu.md). Printed per model: support vectors, alpha_store, model bytes, the program's flash
and RAM, the median instructions of the push that ends a touch (subsample the window, the input's
bases in float32, the distances to the support vectors, the machines), the same decision on this
x86-64 host (float64, the host build: valgrind callgrind inside Classifier::classify_tensor,
eskin-classify on the same held-out recordings), their ratio, and the time at 168 MHz for 1 and
1.5 cycles per instruction. Every device run must end with parity=ok.

Run (after `make dev` and `make mcu-deps`):
    ESKIN_BIN_DIR=build/dev PYTHONPATH=python python benchmarks/bench_mcu.py
The data are simulated (eskin.simulate).
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
# (D, participants simulated, detector's max_window_s, alpha: None = the quick grid's choice):
# the detector's buffers and the input's tensor must fit 128 KB of RAM beside the rest
CONFIGS = [
    (20, 4, 0.5, None),
    (50, 4, 0.5, None),
    (100, 4, 0.4, None),
    (20, 8, 0.5, None),
    (50, 8, 0.4, None),
    (20, 4, 0.5, "Q/2"),
    (50, 4, 0.4, "Q"),
    (100, 4, 0.37, "Q/2"),
]


# --part svm: tensor-SVM models with and without the amplitude factor (what the searched default
# and `eskin train --target cortex-m4` produce), for the cost model of eskin.deploy.target:
# (D, participants simulated, alpha, amplitude width or None, negatives)
SVM_CONFIGS = [
    (20, 4, "1", 1.0, "all"),
    (20, 8, "1", 1.0, "all"),
    (20, 8, "1", None, "all"),
    (50, 4, "1", 1.0, "all"),
    (50, 6, "1", 1.0, "balanced"),
    (20, 6, "Q/2", 1.0, "all"),
    (100, 4, "1", 1.0, "all"),
    (100, 8, "1", 1.0, "all"),
    (50, 4, "Q", 1.0, "all"),
    (50, 8, "Q", 1.0, "all"),
    (20, 8, "Q", 1.0, "all"),
    (50, 6, "Q/2", 1.0, "all"),
    (100, 4, "Q/2", 1.0, "all"),
    (50, 6, "Q", None, "all"),
]


def svm_case(out: Path, D: int, participants: int, alpha: str, amplitude, negatives: str) -> dict:
    """A tensor-SVM model (grouped CV on the quick grid, one alpha and amplitude width) of a
    simulated campaign and a few recordings of its last participant, held out: a `make mcu`
    case (tools/mcu_case.from_files). Returns the model's cost-model inputs."""
    import eskin
    from eskin.learn.grids import QUICK_LAMBDAS, QUICK_SIGMAS

    out.mkdir(parents=True, exist_ok=True)
    camp = eskin.load_campaign(eskin.simulate(out / "campaign.h5", participants=participants,
                                              seed=5, overwrite=True))
    held = camp.participant == np.unique(camp.participant)[-1]
    model = eskin.train_model(
        camp.subset(np.flatnonzero(~held)), machine="svm", selection="cv", D=D,
        subsample="algorithm2", negatives=negatives, lambdas=QUICK_LAMBDAS, sigmas=QUICK_SIGMAS,
        alphas=(alpha,), amplitudes=(amplitude,), seed=0, n_jobs=1,
    )
    eskin.export_model(model, out / "trained.eskin", dtype="float32")
    from eskin.data.campaign import write_campaign

    write_campaign(
        out / "held.h5", [camp.recording(int(i)) for i in np.flatnonzero(held)],
        modality=camp.modality[held], participant=camp.participant[held],
        direction=camp.direction[held], run=camp.run[held],
        modalities=camp.modalities, sample_rate_hz=camp.sample_rate_hz,
        volts_per_count=camp.volts_per_count, source="simulated", overwrite=True,
    )
    _mcu_case().from_files(out, out / "trained.eskin", out / "held.h5", per_class=2, seed=0)
    from eskin.deploy import CompiledModel

    cm = CompiledModel(out / "model.eskin")
    return {"D": D, "n_support": cm.n_support, "alpha_store": tuple(cm.alpha_store),
            "terms": sum(len(m["coef"]) for m in cm.machines),
            "amplitude": bool(cm.sv_log_energy.size), "file_bytes": cm.file_bytes}


def main_svm(out: Path) -> None:
    from eskin.deploy.target import decision_instructions

    rows = []
    for D, participants, alpha, amplitude, negatives in SVM_CONFIGS:
        case = out / f"svm-D{D}-P{participants}-a{alpha.replace('/', '')}-{amplitude}-{negatives}"
        info = svm_case(case, D, participants, alpha, amplitude, negatives)
        dev = device_run(out / "build", case / "mcu_case.h")
        est = decision_instructions((4, 4), D, info["alpha_store"], info["n_support"],
                                    amplitude=info["amplitude"], terms=info["terms"])
        rows.append((info, dev, est))
        print(f"{info}: {dev}, cost model {est:.0f}", flush=True)
    print()
    print("| D | support vectors | kernel terms | alpha_store | amplitude | flash | RAM | "
          "instructions per decision (QEMU) | cost model | error | parity |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for info, dev, est in rows:
        print(f"| {info['D']} | {info['n_support']} | {info['terms']} | {info['alpha_store']} | "
              f"{'yes' if info['amplitude'] else 'no'} | {dev['flash']} | {dev['ram']} | "
              f"{dev['instr']} | {est:.0f} | {100 * (est - dev['instr']) / dev['instr']:+.1f} % | "
              f"{dev['parity']} ({dev['decisions']} decisions) |")
    print("\nas INSTRUCTION_CALIBRATION rows (D, n_support, alpha_store, amplitude, "
          "instructions):")
    for info, dev, _ in rows:
        print(f"    ({info['D']}, {info['n_support']}, {info['alpha_store']}, "
              f"{info['amplitude']}, {dev['instr'] / 1e6:.3f}e6),")


def _mcu_case():
    spec = importlib.util.spec_from_file_location("mcu_case", REPO / "tools" / "mcu_case.py")
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(mod)
    return mod


def device_run(build: Path, header: Path) -> dict:
    """Rebuild the device program with `header` and run it on QEMU; the numbers it printed."""
    subprocess.run(
        [
            "cmake",
            "-S",
            str(REPO),
            "-B",
            str(build),
            "-G",
            "Ninja",
            f"-DCMAKE_TOOLCHAIN_FILE={REPO / 'cmake/arm-none-eabi.cmake'}",
            "-DESKIN_DEVICE=ON",
            "-DCMAKE_BUILD_TYPE=Release",
            f"-DESKIN_MCU_MODEL_HEADER={header}",
        ],
        check=True,
        capture_output=True,
    )
    res = subprocess.run(
        ["cmake", "--build", str(build)], capture_output=True, text=True, check=False
    )
    if res.returncode != 0:
        raise SystemExit(f"the device build failed:\n{res.stdout[-3000:]}{res.stderr[-2000:]}")
    # the decision's stack need, written into the image (the program refuses to run without)
    subprocess.run([sys.executable, str(REPO / "tools/mcu_stack.py"),
                    str(build / "mcu/eskin-mcu.elf"), "--write"], check=True, capture_output=True)
    res = subprocess.run(
        [str(REPO / "mcu/run.sh"), str(build / "mcu/eskin-mcu.elf")],
        capture_output=True,
        text=True,
        check=False,
    )
    last = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else ""
    m = re.match(
        r"MCU: board=(\S+) decisions=(\d+) parity=(\w+) instr_per_decision=(\d+) "
        r"flash=(\d+) ram=(\d+) stack=(\d+)/(\d+)$",
        last,
    )
    if m is None:
        raise SystemExit(f"the device run did not end with the MCU line:\n{res.stdout[-2000:]}")
    det = re.search(r"(\d+) instructions per sample on average", res.stdout)
    big = re.search(r"instructions per decision: median \d+, largest (\d+)", res.stdout)
    return {
        "decisions": int(m.group(2)),
        "parity": m.group(3),
        "instr": int(m.group(4)),
        "flash": int(m.group(5)),
        "ram": int(m.group(6)),
        "stack": int(m.group(7)),
        "stack_size": int(m.group(8)),
        "per_sample": int(det.group(1)) if det else 0,
        "instr_max": int(big.group(1)) if big else int(m.group(4)),
    }


def x86_instructions(model: Path, recordings: Path) -> float | None:
    """Instructions per Classifier::classify_tensor call on this host (callgrind)."""
    from eskin._paths import find_executable

    valgrind = shutil.which("valgrind")
    if valgrind is None:
        return None
    exe = str(find_executable("eskin-classify"))
    res = subprocess.run(
        [
            valgrind,
            "--tool=callgrind",
            "--callgrind-out-file=/dev/null",
            "--toggle-collect=eskin::Classifier::classify_tensor(*",
            exe,
            str(model),
            str(recordings),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    m = re.search(r"Collected\s*:\s*(\d+)", res.stderr)
    n = sum(1 for ln in res.stdout.splitlines() if ln and ln[0].isdigit())
    if m is None or n == 0 or int(m.group(1)) == 0:
        return None
    return int(m.group(1)) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "build" / "bench-mcu")
    ap.add_argument("--part", choices=["rls", "svm"], default="rls",
                    help="rls: the demo's MCU presets (CONFIGS); svm: tensor-SVM models with and "
                    "without the amplitude factor (SVM_CONFIGS), against the cost model")
    args = ap.parse_args()
    if args.part == "svm":
        main_svm(args.out)
        return
    from eskin.deploy import CompiledModel

    case_mod = _mcu_case()
    rows = []
    for D, participants, max_window_s, alpha in CONFIGS:
        case = args.out / f"D{D}-P{participants}-a{(alpha or 'grid').replace('/', '')}"
        case_mod.build_case(
            case,
            D=D,
            max_window_s=max_window_s,
            participants=participants,
            per_class=2,
            seed=0,
            alpha=alpha,
        )
        cm = CompiledModel(case / "model.eskin")
        dev = device_run(args.out / "build", case / "mcu_case.h")
        x86 = x86_instructions(case / "model.eskin", case / "heldout.npy")
        rows.append((D, cm.n_support, cm.alpha_store, cm.file_bytes, dev, x86, max_window_s))
        print(f"D={D} n_sv={cm.n_support}: {dev}, x86 {x86}", flush=True)
    print()
    print(
        "| D | support vectors | alpha_store | model bytes | flash | RAM | instructions per "
        "decision (M4F) | x86-64 (float64) | M4F / x86 | at 168 MHz (CPI 1 - 1.5) | detector "
        "per sample | parity |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for D, n_sv, alpha, size, dev, x86, _ in rows:
        ratio = f"{dev['instr'] / x86:.1f}" if x86 else "-"
        x86s = f"{x86 / 1e6:.3f} M" if x86 else "-"
        ms = dev["instr"] / 168e6 * 1e3
        print(
            f"| {D} | {n_sv} | {tuple(alpha)} | {size} | {dev['flash']} | {dev['ram']} | "
            f"{dev['instr'] / 1e6:.3f} M | {x86s} | {ratio} | {ms:.1f} - {1.5 * ms:.1f} ms | "
            f"{dev['per_sample']} | {dev['parity']} ({dev['decisions']} decisions) |"
        )


if __name__ == "__main__":
    main()
