"""The live figure of an evaluation: what the stream classifier decides on held-out recordings.

``eskin evaluate`` scores one window per recording (the batch path). A controller sees a
stream and decides on every touch its detector ends, so a gesture can give two decisions, or
none, and quiet can give one. For each outer fold, :class:`LiveScoring` plays the held-out
recordings as one continuous stream - the replay stream ``eskin replay --gap`` writes
(:func:`eskin.data.replay.write_replay_file`, recordings apart by
:data:`eskin.learn.live_windows.LIVE_GAP_S` of quiet) - through the compiled stream
classifier of the fold's model (the host classifier ``eskin listen`` runs,
:func:`eskin.link.host_classifier.load_host_classifier`), and scores the decisions recording
by recording with the code ``eskin listen --replay`` uses (:mod:`eskin.link.scoring`):
touches found on each recording, splits (more than one), misses (none), spurious touches in the
gaps, the decision kept per recording and its "don't know" flag.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["LiveScoring", "live_decisions", "score_stream"]

#: samples fed to the stream classifier at a time
_BLOCK = 65536


def live_decisions(classifier: Any, samples: np.ndarray) -> list[Any]:
    """The decisions (:class:`eskin.link.Decision`, source "host") of a host classifier fed
    ``samples`` (n, rows, cols) from its start, then flushed; windows in stream indices."""
    from eskin.link.events import Decision

    classifier.reset()
    touches = []
    for a in range(0, samples.shape[0], _BLOCK):
        block = np.asarray(samples[a : a + _BLOCK])
        touches += classifier.push(block.reshape(block.shape[0], -1))
    touches += classifier.flush()
    return [Decision("host", t.start, t.stop, classifier.label(t), t.label_index, t.values,
                     t.dont_know, t.stop)
            for t in touches]


def score_stream(decisions: Sequence[Any], replay: Any, classes: Sequence[str]) -> dict[str, Any]:
    """One stream's live figure: decisions against the replay's segments (one per recording).

    Returns counts (``recordings``, ``touches`` on recordings, ``split``, ``missed``,
    ``spurious`` in the gaps, ``correct``, ``dont_know``), the score ``eskin listen --replay``
    prints (``score``) and, per recording in replay order, ``touches`` and ``decided`` (index
    into ``classes`` of the decision kept, -1 for none or a class outside ``classes``)."""
    from eskin.link.scoring import assign_decisions, score_decisions, touches_per_segment

    segments = replay.segments
    index = {name: k for k, name in enumerate(replay.class_names)}
    mapped = [replace(d, label_index=index.get(d.label, -1)) for d in decisions]
    labels, _, dk, _ = assign_decisions(mapped, segments, 0)
    # every touch counts on the recording its window overlaps most (assign_decisions' rule)
    touches, spurious = touches_per_segment(decisions, replay)
    names = [replay.class_names[k] if k >= 0 else None for k in labels]
    decided = np.array([list(classes).index(n) if n in classes else -1 for n in names], np.int64)
    scores = score_decisions(list(decisions), replay)
    score = scores[0].as_dict() if scores else None
    return {
        "recordings": int(len(segments)),
        "touches": int(touches.sum()),
        "split": int(np.sum(touches > 1)),
        "missed": int(np.sum(touches == 0)),
        "spurious": spurious,
        "correct": int(score["correct"]) if score else 0,
        "dont_know": int(np.sum(dk & (labels >= 0))),
        "dont_know_right": int(score["dont_know_right"]) if score else 0,
        "score": score,
        "per_recording": {"touches": touches.tolist(), "decided": decided.tolist(),
                          "dont_know": dk.astype(bool).tolist()},
    }


def _pct(n: int, d: int) -> float | None:
    return n / d if d else None


class LiveScoring:
    """The live figure of ``eskin evaluate``: :meth:`fold` in each outer fold (picklable: it
    runs wherever the fold runs), :meth:`pool` over the folds."""

    def __init__(self, gap_s: float | None = None) -> None:
        self.gap_s = gap_s

    def fold(self, model: Any, test: Any, classes: Sequence[str], seed: int = 0
             ) -> dict[str, Any]:
        """The fold's held-out recordings ``test`` (a Campaign) as one replay stream through
        the compiled stream classifier of ``model``: :func:`score_stream`'s figure."""
        from eskin.data.replay import write_replay_file
        from eskin.learn.live_windows import LIVE_GAP_S
        from eskin.link.host_classifier import load_host_classifier

        gap = LIVE_GAP_S if self.gap_s is None else float(self.gap_s)
        classifier = load_host_classifier(model, "compiled")
        with tempfile.TemporaryDirectory(prefix="eskin-live-") as tmp:
            replay = write_replay_file(test, None, Path(tmp) / "fold.eskr", gap_s=gap, seed=seed)
            decisions = live_decisions(classifier, replay.samples)
            out = score_stream(decisions, replay, classes)
            del replay  # the memory map, before the folder goes
        out["gap_s"] = gap
        out["hold_s"] = float(model.window_config.hold_s)
        return out

    @staticmethod
    def pool(folds: Sequence[dict[str, Any]]) -> dict[str, Any]:
        """The folds' live figures together: counts summed, accuracy (kept decision right,
        over the recordings), touches per recording, the per-recording lists in fold order."""
        keys = ("recordings", "touches", "split", "missed", "spurious", "correct", "dont_know",
                "dont_know_right")
        out: dict[str, Any] = {k: int(sum(f[k] for f in folds)) for k in keys}
        n = out["recordings"]
        out["accuracy"] = _pct(out["correct"], n)
        decided = n - out["missed"] - out["dont_know"]
        out["error_decided"] = (None if not decided
                                else 1 - (out["correct"] - out["dont_know_right"]) / decided)
        out["error_flagged"] = (None if not out["dont_know"]
                                else 1 - out["dont_know_right"] / out["dont_know"])
        out["touches_per_recording"] = _pct(out["touches"], n)
        out["gap_s"] = folds[0]["gap_s"] if folds else None
        holds = sorted({f["hold_s"] for f in folds})
        out["hold_s"] = holds[0] if len(holds) == 1 else holds
        out["per_recording"] = {
            k: [v for f in folds for v in f["per_recording"][k]]
            for k in ("touches", "decided", "dont_know")}
        return out
