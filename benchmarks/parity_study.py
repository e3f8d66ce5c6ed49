"""One truth: do training, ``eskin predict --engine python``, ``--engine cpp``, the host stream
and the controller simulator give the same decision values on recordings none of them saw?

For each campaign (the built-in simulator's, every campaign of benchmarks/selection_study.py
with fewer participants, an 8x8 1 kHz skin and a 19x27 100 Hz grid) the script simulates a
training and a held-out campaign (other seeds), trains a model as ``eskin train`` does (the
whole recipe search; ``--quick`` for the 19x27 grid), exports it as float32 and float64
``.eskin`` files and compares on every held-out recording:

- python vs cpp: ``load_model(m.eskin).predict_recordings`` (Python tensors, the file's
  machines) against ``CompiledModel(m.eskin).predict_recordings`` (the compiled classifier);
  recordings whose values differ by more than 1e-6 (float32) / 1e-9 (float64), and the worst;
- stream: the held-out recordings played as one replay stream (``eskin replay``'s) through the
  compiled StreamClassifier: each touch whose window is a recording's batch window (not a span
  of several touches) has its values compared with the batch decision;
- "don't know": the share of held-out recordings the model flags, its error on all of them,
  on those it decides and on those it flags;
- fw-sim (the built-in campaign, ``--fw-sim``): the same replay file through the real
  ``eskin-fw-sim`` (model on board) and ``eskin listen``; the controller's decisions are
  compared with the host stream's, touch by touch (values travel as float32 on the wire).

    python benchmarks/parity_study.py --cache /tmp/eskin-parity [--participants 12] [--fw-sim]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import eskin
from eskin._paths import find_executable
from eskin.data.campaign import load_campaign
from eskin.data.replay import read_replay_file, write_replay_file
from eskin.deploy.export import CompiledModel, export_model
from eskin.learn.models import load_model
from eskin.learn.training import train_model

sys.path.insert(0, str(Path(__file__).resolve().parent))
from selection_study import CAMPAIGNS, OTHER_CAMPAIGNS  # noqa: E402

EXTRA = {
    "8x8-1kHz": {"rows": 8, "cols": 8, "sample_rate_hz": 1000.0, "bpf_lowpass_hz": 450.0,
                 "brush_band_hz": (15.0, 450.0), "pitch_mm": 5.5, "electrode_mm": 4.0},
    "19x27-100Hz": {"rows": 19, "cols": 27, "sample_rate_hz": 100.0, "bpf_lowpass_hz": 40.0,
                    "brush_band_hz": (10.0, 40.0), "pitch_mm": 1.6, "electrode_mm": 1.2,
                    "duration_s": 4.0},
}
TOL = {"float32": 1e-6, "float64": 1e-9}


def campaigns() -> dict[str, tuple[dict, dict, str]]:
    """name -> (simulate() arguments, SimulatorConfig overrides, window)."""
    out = {"built-in": ({}, {}, "energy")}
    for name, (_, sim, over, window) in {**CAMPAIGNS, **OTHER_CAMPAIGNS}.items():
        out[name] = ({"difficulty": sim["difficulty"]}, over, window)
    for name, over in EXTRA.items():
        out[name] = ({}, over, "energy")
    return out


def simulated(cache: Path, name: str, sim: dict, over: dict, participants: int, seed: int) -> Path:
    path = cache / f"{name}-{participants}p-s{seed}.h5"
    if not path.exists():
        cfg = dataclasses.replace(eskin.SimulatorConfig(), **over)
        eskin.simulate(path.with_suffix(".part"), participants=participants, seed=seed,
                       runs=(2,), config=cfg, overwrite=True, **sim)
        path.with_suffix(".part").rename(path)
    return path


def values(predictions) -> np.ndarray:
    return np.array([p["decision_values"] for p in predictions], dtype=np.float64)


def reject_cells(predictions) -> str:
    """Flagged share, error on the decided and on the flagged recordings (python engine)."""
    wrong = np.array([p["label"] != p["true_label"] for p in predictions])
    flag = np.array([p["dont_know"] for p in predictions])
    dec = 100 * wrong[~flag].mean() if (~flag).any() else float("nan")
    fl = 100 * wrong[flag].mean() if flag.any() else float("nan")
    return (f"{100 * flag.mean():.0f} % | {100 * wrong.mean():.1f} % | {dec:.1f} % | {fl:.1f} %")


def stream_check(compiled: CompiledModel, replay_path: Path, batch) -> tuple[int, int, float]:
    """(touches compared, touches over 1e-9, worst difference) of the replay stream."""
    rp = read_replay_file(replay_path)
    x = np.asarray(rp.samples, dtype=np.float64).reshape(rp.n_samples, -1)
    events = [e for e in compiled.stream(x) if "label" in e]
    by_window = {tuple(e["window"]): e for e in events}
    n = bad = 0
    worst = 0.0
    for k, seg in enumerate(rp.segments):
        w = batch[k]["window"]
        start = int(seg["start"])
        e = by_window.get((start + w[0], start + w[1]))
        if e is None:
            continue
        d = float(np.abs(np.asarray(e["values"]) - batch[k]["decision_values"]).max())
        n += 1
        bad += d > 1e-9
        worst = max(worst, d)
    return n, bad, worst


def fw_sim_check(d: Path, model: Path, replay: Path, compiled: CompiledModel) -> str:
    """The replay through eskin-fw-sim and eskin listen; the controller's decisions against the
    host stream's (same samples, same model), touch by touch."""
    sim = subprocess.Popen([str(find_executable("eskin-fw-sim")), str(replay), "--model",
                            str(model), "--wait-start", "--link", str(d / "skin.tty"),
                            "--speed", "0", "--quiet"], stdout=subprocess.PIPE, text=True)
    try:
        assert sim.stdout.readline().startswith("PTY ")
        jsonl = d / "listen.jsonl"
        jsonl.unlink(missing_ok=True)
        subprocess.run([sys.executable, "-m", "eskin", "listen", str(d / "skin.tty"), "--model",
                        str(model), "--until-eof", "--replay", str(replay), "--jsonl", str(jsonl),
                        "--view", "plain"], check=True, capture_output=True, timeout=900)
    finally:
        sim.terminate()
        sim.communicate(timeout=10)
    objs = [json.loads(line) for line in jsonl.read_text().splitlines()]
    ctl = [o for o in objs if o.get("type") == "decision" and o.get("source") == "controller"]
    rp = read_replay_file(replay)
    host = [e for e in compiled.stream(np.asarray(rp.samples, np.float64).reshape(rp.n_samples, -1))
            if "label" in e]
    if len(ctl) != len(host):
        return f"controller {len(ctl)} decisions, host stream {len(host)}"
    diff = max((float(np.abs(np.asarray(c["values"]) - h["values"]).max()) for c, h in zip(ctl, host)),
               default=0.0)
    same = sum(c["label"] == h["label"] for c, h in zip(ctl, host))
    return f"{len(ctl)} decisions, labels {same}/{len(ctl)} equal, worst value difference {diff:.2g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin-parity"))
    ap.add_argument("--participants", type=int, default=12, help="training participants")
    ap.add_argument("--held", type=int, default=None,
                    help="held-out participants (default: half the training participants)")
    ap.add_argument("--only", default=None, help="comma-separated campaign names")
    ap.add_argument("--fw-sim", action="store_true", help="also the firmware road (built-in)")
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    chosen = campaigns()
    if a.only:
        chosen = {k: v for k, v in chosen.items() if k in a.only.split(",")}
    held_n = a.held or max(1, a.participants // 2)
    print(f"eskin {eskin.__version__}; held-out recordings of {held_n} participants")
    print("| campaign | model | recordings | python vs cpp f32: over 1e-6 (worst) | "
          "f64: over 1e-9 (worst) | stream touches compared: over 1e-9 (worst) | "
          "don't know | error | error decided | error flagged |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, (sim, over, window) in chosen.items():
        t0 = time.perf_counter()
        train = simulated(a.cache, name, sim, over, a.participants, 21)
        test = simulated(a.cache, name, sim, over, held_n, 22)
        model = train_model(load_campaign(train), window=window, quick=name.startswith("19x27"))
        held = load_campaign(test)
        cells = []
        compiled64 = None
        for dtype in ("float32", "float64"):
            path = export_model(model, a.cache / f"{name}-{dtype}.eskin", dtype=dtype)
            py = load_model(path).predict_recordings(held)
            cpp = CompiledModel(path).predict_recordings(held)
            diff = np.abs(values(py) - values(cpp)).max(axis=1)
            cells.append(f"{int((diff > TOL[dtype]).sum())} ({diff.max():.2g})")
            if dtype == "float64":
                compiled64, batch, rejects = CompiledModel(path), cpp, reject_cells(py)
        replay = write_replay_file(held, None, a.cache / f"{name}-held.eskr", seed=1).path
        n, bad, worst = stream_check(compiled64, replay, batch)
        label = (f"{model.machine} D={model.D} {model.subsample} "
                 f"window_samples={model.window_config.window_samples:g}")
        print(f"| {name} | {label} | {len(held)} | {cells[0]} | {cells[1]} | "
              f"{n}: {bad} ({worst:.2g}) | {rejects} |", flush=True)
        if a.fw_sim and name == "built-in":
            f32 = a.cache / f"{name}-float32.eskin"
            print(f"  fw-sim ({name}, float32 on board): "
                  f"{fw_sim_check(a.cache, f32, replay, CompiledModel(f32))}", flush=True)
        print(f"  ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)


if __name__ == "__main__":
    os.environ.setdefault("COLUMNS", "120")
    main()
