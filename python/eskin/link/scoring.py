"""How well live decisions match the truth a replay file carries: each replay segment is one
recording with its true class, so the decisions that arrive over the link (the controller's and
the host's) can be scored against it, recording by recording, as ``eskin listen --replay`` and
``eskin demo`` do."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

__all__ = ["ReplayScore", "assign_decisions", "confusion_matrix", "lost_per_segment",
           "score_decisions", "segment_of", "touches_per_segment"]


def confusion_matrix(true: np.ndarray, pred: np.ndarray, n_classes: int) -> np.ndarray:
    """(k, k + 1) counts: row = true class, column = decided class, last column = no decision."""
    cm = np.zeros((n_classes, n_classes + 1), np.int64)
    for t, p in zip(np.asarray(true), np.asarray(pred)):
        cm[int(t), int(p) if p >= 0 else n_classes] += 1
    return cm


def assign_decisions(
    decisions: list, segments: np.ndarray, n_values: int, offset: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """Decisions (eskin.link.Decision of one source) -> one per replay segment.

    A decision belongs to the segment its window ``[onset, offset)`` overlaps most. A segment
    keeps the decision on its touch: the one overlapping its true contact interval most (when the
    segment has one: the simulator's ground truth), else the one overlapping the segment most;
    a stream detector also reports the small transients where a recording meets the quiet gap,
    which this rule leaves aside. Returns (labels, values, dont_know, extra) with -1 / nan where
    a segment got no decision; ``extra`` counts, per segment and last for the gaps, the decisions
    that were not kept.
    """
    n = len(segments)
    labels = np.full(n, -1, np.int64)
    values = np.full((n, n_values), np.nan)
    dk = np.zeros(n, bool)
    best = [(-1, -1)] * n
    extra = [0] * (n + 1)
    starts = offset + segments["start"].astype(np.int64)
    stops = starts + segments["length"].astype(np.int64)
    names = segments.dtype.names or ()
    if "contact_onset" in names and "contact_offset" in names:
        known = segments["contact_onset"] >= 0
        c_on = np.where(known, starts + segments["contact_onset"].astype(np.int64), starts)
        c_off = np.where(known, starts + segments["contact_offset"].astype(np.int64), stops)
    else:
        c_on, c_off = starts, stops
    for d in decisions:
        ov = np.minimum(stops, d.offset_sample) - np.maximum(starts, d.onset_sample)
        k = int(np.argmax(ov))
        if ov[k] <= 0:
            extra[n] += 1
            continue
        score = (int(min(c_off[k], d.offset_sample) - max(c_on[k], d.onset_sample)), int(ov[k]))
        if score > best[k]:
            if labels[k] >= 0:
                extra[k] += 1
            best[k] = score
            labels[k] = d.label_index
            values[k] = np.nan
            v = np.asarray(d.values, float)[:n_values]
            values[k, : len(v)] = v
            dk[k] = d.dont_know
        else:
            extra[k] += 1
    return labels, values, dk, extra


@dataclass(frozen=True)
class ReplayScore:
    """One source's decisions (controller or host) against a replay's true labels, one decision
    per recording (segment) as :func:`assign_decisions` keeps it."""

    source: str
    class_names: tuple[str, ...]
    recordings: int  # segments with a known true class
    correct: int
    dont_know: int  # kept decisions flagged "don't know" (no machine, or several, claimed)
    no_decision: int  # segments that got no decision at all
    confusion: np.ndarray  # (k, k + 1): row = true class, column = decided, last = none
    #: the recordings some of whose samples never reached the host (a lost frame, a sample the
    #: controller dropped): (segment index, samples lost, decided label index or -1, right);
    #: their decisions rest on incomplete data, so the score also leaves them out
    lossy: tuple[tuple[int, int, int, bool], ...] = ()
    #: the live path's view of the segments: every decision of the source counts on the
    #: segment its window overlaps most (``touches`` in all), ``split`` segments got more than
    #: one, ``missed`` none, ``spurious`` decisions overlap no segment (in the quiet gaps)
    touches: int = 0
    split: int = 0
    missed: int = 0
    spurious: int = 0
    #: kept decisions flagged "don't know" that were right nonetheless
    dont_know_right: int = 0

    @property
    def accuracy(self) -> float:
        return self.correct / self.recordings if self.recordings else float("nan")

    @property
    def decided(self) -> int:
        """Segments whose kept decision is not flagged "don't know"."""
        return self.recordings - self.no_decision - self.dont_know

    @property
    def error_decided(self) -> float:
        """The error on the decided segments (NaN when there is none)."""
        right = self.correct - self.dont_know_right
        return 1 - right / self.decided if self.decided else float("nan")

    @property
    def error_flagged(self) -> float:
        """The error on the segments whose kept decision is flagged "don't know"."""
        return 1 - self.dont_know_right / self.dont_know if self.dont_know else float("nan")

    @property
    def recordings_without_losses(self) -> int:
        return self.recordings - len(self.lossy)

    @property
    def correct_without_losses(self) -> int:
        return self.correct - sum(1 for *_, right in self.lossy if right)

    @property
    def accuracy_without_losses(self) -> float:
        n = self.recordings_without_losses
        return self.correct_without_losses / n if n else float("nan")

    def as_dict(self) -> dict[str, Any]:
        """The JSON object ``eskin listen --jsonl`` writes for this score."""
        return {
            "type": "accuracy",
            "source": self.source,
            "recordings": self.recordings,
            "correct": self.correct,
            "accuracy": self.accuracy,
            "dont_know": self.dont_know,
            "no_decision": self.no_decision,
            "classes": list(self.class_names),
            "confusion_columns": [*self.class_names, "none"],
            "confusion": self.confusion.tolist(),
            "recordings_with_losses": [
                {"segment": k, "lost_samples": n,
                 "decided": self.class_names[lab] if lab >= 0 else None, "right": right}
                for k, n, lab, right in self.lossy],
            "recordings_without_losses": self.recordings_without_losses,
            "correct_without_losses": self.correct_without_losses,
            "accuracy_without_losses": self.accuracy_without_losses,
            "touches": self.touches,
            "split": self.split,
            "missed": self.missed,
            "spurious": self.spurious,
            "dont_know_right": self.dont_know_right,
            "error_decided": self.error_decided,
            "error_flagged": self.error_flagged,
        }

    def live_line(self) -> str:
        """The live path in one line, as ``eskin listen --replay``, ``eskin demo`` and ``eskin
        evaluate`` print it: touches per recording, splits, misses, spurious touches, and how
        the decided and the "don't know" recordings fare."""
        pct = lambda v: "-" if v != v else f"{100 * v:.1f} %"  # noqa: E731 (NaN: none)
        return (f"{self.source}: {self.touches} touches on {self.recordings} recordings "
                f"({self.split} split, {self.missed} missed), {self.spurious} in the gaps; "
                f"{self.dont_know} of {self.recordings - self.no_decision} decisions \"don't "
                f"know\"; error {pct(1 - self.accuracy)} overall, {pct(self.error_decided)} on "
                f"the decided, {pct(self.error_flagged)} on the flagged")


def lost_per_segment(segments: np.ndarray, lost_ranges: Sequence[tuple[int, int]],
                     offset: int = 0) -> np.ndarray:
    """Samples of each segment inside the lost stream ranges ``[start, stop)``."""
    starts = offset + segments["start"].astype(np.int64)
    stops = starts + segments["length"].astype(np.int64)
    lost = np.zeros(len(segments), np.int64)
    for a, b in lost_ranges:
        lost += np.maximum(0, np.minimum(stops, int(b)) - np.maximum(starts, int(a)))
    return lost


def score_decisions(decisions: Sequence[Any], replay: Any, offset: int = 0,
                    lost_ranges: Sequence[tuple[int, int]] = ()) -> list[ReplayScore]:
    """Score the decisions (``eskin.link.Decision``) of each source against the true labels of
    ``replay`` (an ``eskin.data.ReplayFile``) whose first sample had stream index ``offset``.
    Labels are compared by class name (a model may order its classes unlike the replay); a
    recording without a decision counts as wrong, and segments of unknown class are left out.
    ``lost_ranges``: the stream ranges ``[start, stop)`` whose samples never reached the host;
    the recordings they touch are listed in each score's ``lossy`` (their decisions rest on
    incomplete data). One score per source that made decisions, controller first."""
    segments = replay.segments
    known = segments["label"] >= 0
    true = segments["label"][known].astype(np.int64)
    lost = lost_per_segment(segments, lost_ranges, offset)
    segment_ids = np.flatnonzero(known)
    names = tuple(replay.class_names)
    index = {name: k for k, name in enumerate(names)}
    scores = []
    for source in sorted({d.source for d in decisions}, key=lambda s: (s != "controller", s)):
        mine = [
            replace(d, label_index=index.get(d.label, -1)) for d in decisions if d.source == source
        ]
        labels, _, dk, _ = assign_decisions(mine, segments, 0, offset)
        touches, spurious = touches_per_segment(mine, replay, offset)
        touches = touches[known]
        labels, dk = labels[known], dk[known]
        lossy = tuple((int(k), int(lost[k]), int(lab), bool(lab == t))
                      for k, lab, t in zip(segment_ids, labels, true) if lost[k] > 0)
        scores.append(
            ReplayScore(
                source=source,
                class_names=names,
                recordings=int(known.sum()),
                correct=int(np.sum(labels == true)),
                dont_know=int(np.sum(dk & (labels >= 0))),
                no_decision=int(np.sum(labels < 0)),
                confusion=confusion_matrix(true, labels, len(names)),
                lossy=lossy,
                touches=int(touches.sum()),
                split=int(np.sum(touches > 1)),
                missed=int(np.sum(touches == 0)),
                spurious=spurious,
                dont_know_right=int(np.sum(dk & (labels >= 0) & (labels == true))),
            )
        )
    return scores


def touches_per_segment(decisions: Sequence[Any], replay: Any, offset: int = 0
                        ) -> tuple[np.ndarray, int]:
    """(touches on each replay segment, touches in the gaps): every decision counts on the
    segment its window ``[onset, offset)`` overlaps most (:func:`segment_of`)."""
    where = np.array([segment_of(replay, d.onset_sample, d.offset_sample, offset)
                      for d in decisions], np.int64).reshape(-1)
    counts = np.bincount(where[where >= 0], minlength=len(replay.segments)).astype(np.int64)
    return counts, int(np.sum(where < 0))


def segment_of(replay: Any, onset: int, offset_sample: int, stream_offset: int = 0) -> int:
    """Index of the replay segment the window ``[onset, offset_sample)`` overlaps most, or -1."""
    starts = stream_offset + replay.segments["start"].astype(np.int64)
    stops = starts + replay.segments["length"].astype(np.int64)
    overlap = np.minimum(stops, offset_sample) - np.maximum(starts, onset)
    k = int(np.argmax(overlap)) if overlap.size else -1
    return k if k >= 0 and overlap[k] > 0 else -1
