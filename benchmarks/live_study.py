"""What the live path decides beside what the batch path scores, with and without the hold time
``eskin train`` chooses, on campaigns whose gestures a stream can split.

For each campaign the script runs ``eskin evaluate`` twice through the command line, once with
the hold time fixed at the detector's default 0.15 s (``--hold 0.15``) and once as ``eskin
train`` does by default (the hold chosen per fold so that one training recording gives one live
touch), and prints from each ``evaluation.json``: accuracy per recording (the batch path) and
live (each fold's held-out recordings as one replay stream through the fold's compiled stream
classifier), touches per recording, splits, misses and touches in the quiet gaps, the share of
recordings flagged "don't know" and the error on the decided and the flagged ones.

Campaigns: the built-in simulator's (12 participants, seed 21) and a press-and-hold one (8x8
taxels at 1 kHz, finger strokes and presses held 0.5 s, 5 participants, seed 3).

    python benchmarks/live_study.py --cache /tmp/eskin-live
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

CAMPAIGNS = {
    "built-in": ["--participants", "12", "--seed", "21"],
    "press-and-hold 8x8 1 kHz": ["--participants", "5", "--seed", "3", "--grid", "8x8",
                                 "--rate", "1000", "--duration", "3",
                                 "--modalities", "finger,press"],
}


def eskin(*args: str) -> None:
    env = dict(os.environ, COLUMNS="120")
    subprocess.run([sys.executable, "-m", "eskin", *args], check=True, env=env,
                   stdout=subprocess.DEVNULL)


def pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def row(name: str, hold: str, r: dict) -> str:
    live, dk = r["live"], r.get("dont_know") or {}
    n = live["recordings"]
    err_dec = None if dk.get("accuracy_decided") is None else 1 - dk["accuracy_decided"]
    err_fl = None if dk.get("accuracy_flagged") is None else 1 - dk["accuracy_flagged"]
    return (f"| {name} | {hold} | {n} | {pct(r['accuracy'])} | {pct(live['accuracy'])} | "
            f"{live['touches_per_recording']:.2f} | {live['split']} | {live['missed']} | "
            f"{live['spurious']} | {pct(dk.get('flagged'))} | {pct(err_dec)} | {pct(err_fl)} | "
            f"{pct(live.get('error_decided'))} | {pct(live.get('error_flagged'))} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/eskin-live"))
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    print("| campaign | hold | recordings | accuracy per recording | accuracy live | touches per "
          "recording | split | missed | in the gaps | don't know | error decided | error "
          "flagged | live error decided | live error flagged |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, sim in CAMPAIGNS.items():
        key = name.split()[0]
        camp = a.cache / f"{key}.h5"
        if not camp.exists():
            eskin("simulate", "-o", str(camp), *sim, "-q")
        for hold, extra in (("0.15 s (given)", ["--hold", "0.15"]), ("chosen", [])):
            out = a.cache / f"{key}-{'given' if extra else 'chosen'}"
            t0 = time.perf_counter()
            eskin("evaluate", str(camp), "-o", str(out), "--force", *extra)
            r = json.loads((out / "evaluation.json").read_text())
            if not extra:
                hold = f"chosen: {r['live']['hold_s']} s"
            print(row(name, hold, r), flush=True)
            print(f"  ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
