"""Build the test case of `make mcu`: a small model of the demo campaign and held-out samples.

Simulates a small demo campaign (SIMULATED data), trains the MCU preset of the demo model on all
participants but the last (tensor-RLS, Maximal Discrepancy selection on the quick grid, D and the
detector's longest window cut to fit a Cortex-M4F: see docs/mcu.md), with the amplitude-aware
kernel (``--amplitude SIGMA``, the estimators' ``amplitude``: default 1.0, so that the device's
parity check covers the factor; ``--amplitude off`` for the plain tensor kernel), exports it as a
float32 ``.eskin`` model (format version 2 with the factor, 1 without) and streams a few held-out recordings of the last participant through the
host's C++ stream classifier (float64 arithmetic) for the reference decisions. Writes into OUT:

* ``model.eskin``: the model;
* ``stream.i16``: the held-out samples, int16 little-endian, sample-major (n_samples x taxels),
  read by the device program through semihosting;
* ``mcu_model.h``: the model as a C header (eskin.deploy.write_c_header: the .eskin bytes as a
  const, 8-byte aligned array, which the linker places in flash);
* ``mcu_case.h``: the stream's path and size, and the host's decisions (window, label, values)
  with the tolerance;
* ``nofit/``: the same model with an unbounded 4 s window (``window_samples = 0``), whose
  stream classifier needs more RAM than the heap has: the device program built from it must be
  refused at construction (the heap bound, docs/mcu.md).

Any model on any recordings: ``--model M.eskin --campaign HELD.h5`` writes the same case from a
user's model and a few recordings of each class of a (held-out) campaign, instead of the demo's.

The model's flash and RAM on the target are reported (eskin.deploy.target) before anything is
written.

    python tools/mcu_case.py OUT [--D 20] [--max-window-s 0.4] [--per-class 2] [--amplitude 1.0]
    python tools/mcu_case.py OUT --model M.eskin --campaign HELD.h5 [--per-class 2]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

# Decision values of the float32 device path may differ from the host's float64 ones by this
# much (absolute; the values are O(1) RLS outputs; measured: below 1e-6); the labels and windows
# must be identical.
TOLERANCE = 1e-4


def build_case(
    out: Path,
    *,
    D: int,
    max_window_s: float,
    participants: int,
    per_class: int,
    seed: int,
    alpha: str | None = None,
    amplitude: float | None = None,
) -> dict:
    import eskin
    from eskin import WindowConfig
    from eskin.deploy import write_c_header
    from eskin.deploy.target import device_budget

    out.mkdir(parents=True, exist_ok=True)
    camp_path = eskin.simulate(
        out / "campaign.h5", participants=participants, seed=seed, overwrite=True
    )
    camp = eskin.load_campaign(camp_path)
    parts = np.unique(camp.participant)
    is_test = camp.participant == parts[-1]
    train_idx = np.flatnonzero(~is_test)
    test_idx = np.flatnonzero(is_test)
    # a few held-out recordings per class, spread over the participant's recordings
    chosen = []
    for c in np.unique(camp.modality[test_idx]):
        chosen.extend(test_idx[camp.modality[test_idx] == c][:per_class].tolist())
    chosen = sorted(chosen)
    # the quick grid (2 lambdas x 2 sigmas x alpha in {1, Q/2}), or one alpha forced
    from eskin.learn.grids import QUICK_LAMBDAS, QUICK_SIGMAS

    grid = (
        {"quick": True}
        if alpha is None
        else {
            "lambdas": QUICK_LAMBDAS,
            "sigmas": QUICK_SIGMAS,
            "alphas": (alpha,),
            "md_options": {"n_labelings": 3},
        }
    )
    if amplitude is not None:  # the amplitude factor's width, in spreads of log energy
        grid["amplitudes"] = (amplitude,)
    model = eskin.train_model(
        camp.subset(train_idx),
        machine="rls",
        selection="md",
        negatives="balanced",
        D=D,
        window_config=WindowConfig(max_window_s=max_window_s),
        seed=seed,
        n_jobs=1,
        **grid,
    )
    data = eskin.export_model(model, out / "model.eskin", dtype="float32").read_bytes()
    compiled = eskin.CompiledModel(data)
    budget = device_budget(compiled, "cortex-m4")
    print("\n".join(budget.report()))
    if not budget.fits:
        raise SystemExit("the MCU preset does not fit the target")
    # the same model with an unbounded 4 s window: its stream classifier does not fit the heap
    from dataclasses import replace

    nofit = out / "nofit"
    nofit.mkdir(exist_ok=True)
    big = replace(model, window_config=WindowConfig(max_window_s=4.0, window_samples=0))
    eskin.export_model(big, nofit / "model.eskin", dtype="float32")
    write_c_header(nofit / "model.eskin", nofit / "mcu_model.h", name="mcu_model")
    info = write_case(out, data, camp, chosen, seed=seed)
    (nofit / "mcu_case.h").write_text(
        "/* The heap-bound case of `make mcu` (tools/mcu_case.py). Generated: do not edit. */\n"
        "#define MCU_CASE_EXPECT_NO_FIT 1\n"
        + (out / "mcu_case.h").read_text().replace(
            '#include "mcu_model.h"', f'#include {json.dumps(str((nofit / "mcu_model.h").resolve()))}'
        )
    )
    return {**info, "D": D}


def from_files(out: Path, model_path: Path, campaign_path: Path, *, per_class: int, seed: int) -> dict:
    """The case of a user's model and a few recordings of each class of a campaign."""
    import eskin
    from eskin.deploy.target import device_budget

    out.mkdir(parents=True, exist_ok=True)
    data = Path(model_path).read_bytes()
    try:  # a damaged file is one line naming it, not a traceback
        compiled = eskin.CompiledModel(data)
    except ValueError as exc:
        raise SystemExit(f"{model_path}: {exc}") from None
    try:
        camp = eskin.load_campaign(campaign_path)
    except ValueError as exc:  # the campaign's errors name the file
        raise SystemExit(str(exc)) from None
    names = list(compiled.class_names)
    if tuple(camp.grid_shape) != tuple(compiled.grid_shape):
        raise SystemExit(
            f"{campaign_path}: grid {camp.grid_shape[0]}x{camp.grid_shape[1]}, the model "
            f"{model_path} expects {compiled.grid_shape[0]}x{compiled.grid_shape[1]}"
        )
    chosen = []
    labels = np.asarray(camp.modalities, dtype=object)[np.asarray(camp.modality)]
    for c in names:
        chosen.extend(np.flatnonzero(labels == c)[:per_class].tolist())
    if not chosen:
        raise SystemExit(
            f"{campaign_path}: no recording of the model's classes ({', '.join(names)})"
        )
    budget = device_budget(compiled, "cortex-m4")
    print("\n".join(budget.report()))
    (out / "model.eskin").write_bytes(data)
    return write_case(out, data, camp, sorted(chosen), seed=seed)


def write_case(out: Path, data: bytes, camp, chosen: list, *, seed: int) -> dict:
    """model.eskin's C header, the recordings `chosen` of `camp` as one stream with gaps, and the
    host stream classifier's decisions on it (mcu_case.h)."""
    import eskin
    from eskin.deploy import write_c_header

    compiled = eskin.CompiledModel(data)
    write_c_header(out / "model.eskin", out / "mcu_model.h", name="mcu_model")

    # the same recordings whole, for a host run of the same model (benchmarks/bench_mcu.py)
    np.save(out / "heldout.npy", np.asarray(camp.signals[chosen], dtype="<i2"))
    rf = eskin.write_replay_file(camp, chosen, out / "stream.eskr", gap_s=0.5, seed=seed)
    samples = np.ascontiguousarray(np.asarray(rf.samples, dtype="<i2").reshape(rf.n_samples, -1))
    samples.tofile(out / "stream.i16")
    events = compiled.stream(samples)
    names = list(compiled.class_names)
    decisions = [e for e in events if "label" in e]
    bad = [e for e in events if e.get("status_name") not in ("ok", "decision")]
    if bad:
        raise SystemExit(f"the host's stream classifier reported {bad[0]}")
    n_values = len(decisions[0]["values"]) if decisions else 1
    lines = [
        "/* The test case of `make mcu` (tools/mcu_case.py; SIMULATED demo campaign). Generated:",
        " * do not edit. */",
        "#pragma once",
        "#include <stdint.h>",
        "",
        f"#define MCU_CASE_TAXELS {samples.shape[1]}",
        f"#define MCU_CASE_N_SAMPLES {samples.shape[0]}",
        f"#define MCU_CASE_N_DECISIONS {len(decisions)}",
        f"#define MCU_CASE_MAX_DECISIONS {max(1, len(decisions)) + 8}",
        f"#define MCU_CASE_N_VALUES {n_values}",
        f"#define MCU_CASE_TOLERANCE {TOLERANCE!r}",
        f"#define MCU_CASE_STREAM {json.dumps(str((out / 'stream.i16').resolve()))}",
        "",
        '#include "mcu_model.h" /* the model: the .eskin bytes, const (flash), 8-byte aligned */',
        "",
        "struct McuCaseDecision { long start, stop; int label; double values[MCU_CASE_N_VALUES]; };",
        "/* the host's decisions (float64 arithmetic, same model, same samples) */",
        f"static const McuCaseDecision mcu_case_decisions[{max(1, len(decisions))}] = {{",
    ]
    for e in decisions:
        vals = ", ".join(repr(float(v)) for v in e["values"])
        lines.append(
            f"  {{{int(e['window'][0])}, {int(e['window'][1])}, "
            f"{names.index(e['label'])}, {{{vals}}}}},"
        )
    if not decisions:
        lines.append("  {0, 0, -1, {0}},")
    lines += ["};", ""]
    (out / "mcu_case.h").write_text("\n".join(lines))
    return {
        "model_bytes": len(data),
        "format_version": compiled.format_version,
        "amplitude_widths": "/".join(f"{w:.4g}" for w in compiled.amplitude_widths),
        "n_support": compiled.n_support,
        "D": compiled.D,
        "recordings": len(chosen),
        "samples": int(samples.shape[0]),
        "decisions": len(decisions),
        "classes": names,
    }


def _amplitude(text: str) -> float | None:
    if text.lower() in ("off", "none"):
        return None
    value = float(text)
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"--amplitude must be 'off' or > 0, got {text!r}")
    return value


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--D", type=int, default=20)
    ap.add_argument("--max-window-s", type=float, default=0.5)
    ap.add_argument("--participants", type=int, default=4)
    ap.add_argument("--per-class", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--alpha",
        choices=["1", "Q/2", "Q"],
        default=None,
        help="one alpha instead of the quick grid's choice",
    )
    ap.add_argument(
        "--amplitude",
        type=_amplitude,
        default=1.0,
        metavar="SIGMA",
        help="train with the amplitude factor of this width, in spreads of the training "
        "patterns' log energy (default 1.0); 'off': the plain tensor kernel",
    )
    ap.add_argument("--model", type=Path, default=None, help="a .eskin model instead of the demo's")
    ap.add_argument("--campaign", type=Path, default=None, help="its held-out recordings (.h5)")
    a = ap.parse_args(argv)
    if (a.model is None) != (a.campaign is None):
        ap.error("--model and --campaign go together")
    if a.model is not None:
        for p in (a.model, a.campaign):
            if not p.is_file():
                ap.error(f"{p}: no such file")
        info = from_files(a.out, a.model, a.campaign, per_class=a.per_class, seed=a.seed)
        print("mcu case: " + ", ".join(f"{k}={v}" for k, v in info.items()))
        return 0
    info = build_case(
        a.out,
        D=a.D,
        max_window_s=a.max_window_s,
        participants=a.participants,
        per_class=a.per_class,
        seed=a.seed,
        alpha=a.alpha,
        amplitude=a.amplitude,
    )
    print("mcu case: " + ", ".join(f"{k}={v}" for k, v in info.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
