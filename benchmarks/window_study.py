"""What the bounded touch window costs in accuracy on unseen participants.

A stream keeps at most ``WindowConfig.window_samples`` samples per taxel of a touch window and
halves the time resolution each time the buffer fills (docs/preprocessing.md, "Bounded
window"); ``window_samples = 0`` keeps every sample (the paper's reading). This study trains the
same classifier on patterns made with each setting and tests it on participants it never saw.

* Campaigns: several simulated campaigns unlike each other (seeds, difficulty 1 = calibrated
  to the paper's error ranges and 2 = harder), ``--participants`` each (SIMULATED data).
* Classifier: a one-vs-all tensor-SVM at fixed hyperparameters (sigma = 0.5, C = 10,
  alpha = Q/2, the paper's Table 7 choice; every negative), D = 100, so that the only change
  between the columns is the window's resolution (no model selection to absorb it).
* Split: participant-grouped 5-fold cross-validation (GroupKFold): each test fold's
  participants are unseen in training. Accuracy per campaign: pooled over its folds; spread: the
  standard deviation over its folds.
* Also reported: the share of windows the bound decimates (stride > 1) and their median stride.

Run:  ESKIN_BIN_DIR=build/dev PYTHONPATH=python python benchmarks/window_study.py
      [--participants 10] [--campaigns 4] [--settings 0,2048,1024,512,256,128] [--out DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from sklearn.model_selection import GroupKFold

import eskin
from eskin.signal.preprocess import detect_touches
from eskin.learn.estimators import OneVsAllTouchClassifier, TensorSVC

D = 100
SIGMA, C, ALPHA = 0.5, 10.0, "half"


def campaigns(n: int, participants: int, work: Path) -> list[tuple[str, object]]:
    out = []
    for k in range(n):
        difficulty = 1.0 if k % 2 == 0 else 2.0
        seed = 101 + k
        path = eskin.simulate(work / f"c{k}.h5", participants=participants, seed=seed,
                              difficulty=difficulty, overwrite=True)
        out.append((f"seed {seed}, difficulty {difficulty:g}",
                    eskin.load_campaign(path, in_memory=True)))
    return out


def accuracy(camp, window_samples: int) -> tuple[float, float, float, float]:
    """(pooled accuracy, std over folds, share of decimated windows, median stride of those)."""
    cfg = eskin.WindowConfig(window_samples=window_samples)
    sig = np.asarray(camp.signals)
    lengths = np.asarray(camp.lengths)
    X = eskin.preprocess(sig, D, lengths=lengths, sample_rate_hz=camp.sample_rate_hz, config=cfg)
    stride = detect_touches(sig, lengths=lengths, sample_rate_hz=camp.sample_rate_hz,
                                  config=cfg).stride
    y = np.asarray(camp.modality).astype(np.int64)
    groups = np.asarray(camp.participant)
    correct, folds = 0, []
    for tr, te in GroupKFold(n_splits=5).split(X, y, groups):
        est = OneVsAllTouchClassifier(TensorSVC(C=C, sigma=SIGMA, alpha=ALPHA)).fit(X[tr], y[tr])
        hit = est.predict(X[te]) == y[te]
        correct += int(hit.sum())
        folds.append(float(hit.mean()))
    dec = stride > 1
    return (correct / len(y), float(np.std(folds)), float(dec.mean()),
            float(np.median(stride[dec])) if dec.any() else 1.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--participants", type=int, default=10)
    ap.add_argument("--campaigns", type=int, default=4)
    ap.add_argument("--settings", default="0,2048,1024,512,256,128")
    ap.add_argument("--out", type=Path, default=None, help="keep the campaigns here")
    a = ap.parse_args()
    settings = [int(s) for s in a.settings.split(",")]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = a.out or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        camps = campaigns(a.campaigns, a.participants, work)
        header = "| campaign | " + " | ".join(
            f"window_samples={s}" if s else "unbounded (0)" for s in settings) + " |"
        print(header)
        print("|" + "---|" * (len(settings) + 1))
        deltas = {s: [] for s in settings}
        for name, camp in camps:
            cells, base = [], None
            for s in settings:
                acc, sd, dec, med = accuracy(camp, s)
                base = acc if base is None else base
                deltas[s].append(acc - base)
                extra = "" if s == 0 else f", {100 * dec:.0f} % decimated (stride {med:g})"
                cells.append(f"{100 * acc:.1f} % +- {100 * sd:.1f}{extra}")
            print(f"| {name} ({len(camp.participant)} recordings) | " + " | ".join(cells) + " |")
        print()
        for s in settings[1:]:
            d = np.asarray(deltas[s]) * 100
            print(f"window_samples={s}: accuracy minus the unbounded window's, per campaign "
                  f"{', '.join(f'{v:+.1f}' for v in d)} points (mean {d.mean():+.2f}, "
                  f"worst {d.min():+.1f})")
    print(f"({time.perf_counter() - t0:.0f} s; D={D}, tensor-SVM sigma={SIGMA} C={C} "
          f"alpha={ALPHA}, GroupKFold(5) by participant, SIMULATED campaigns)")


if __name__ == "__main__":
    main()
