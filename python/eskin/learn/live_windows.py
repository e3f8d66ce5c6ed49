"""Live touches of the training recordings, and the hold time that makes one gesture one touch.

Training takes one window per recording (``WindowConfig.select = "span"`` merges the touches
the detector finds in it), but a live stream cannot merge: every touch the detector ends is a
decision. A gesture with a pause in it (a press and its release, apart by the hold of a
press-and-hold: a piezo sensor answers changes, not force) gives two live touches when the
pause is longer than ``hold_s``. :func:`choose_hold` runs the stream detector over each
training recording alone, counts the touches it reports, and takes the smallest ``hold_s`` of
:data:`HOLD_GRID_S` at which at least :data:`ONE_TOUCH_SHARE` of the recordings give exactly
one touch, with a note saying what it chose and why (docs/preprocessing.md, "One gesture, one
live touch").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

__all__ = ["HOLD_GRID_S", "LIVE_GAP_S", "ONE_TOUCH_SHARE", "HoldChoice", "choose_hold",
           "live_touch_counts"]

#: the hold times tried, shortest first (the first is the detector's default)
HOLD_GRID_S = (0.15, 0.3, 0.6, 1.0, 1.5)
#: the share of training recordings that must give exactly one live touch
ONE_TOUCH_SHARE = 0.95
#: the quiet between two gestures a live stream is taken to have: the gap between recordings of
#: the stream ``eskin evaluate`` scores live (and ``eskin replay --gap`` can write); a hold
#: time must stay below it, or two gestures would merge into one touch
LIVE_GAP_S = 2.0


def live_touch_counts(recordings: Any, indices: Sequence[int], config: Any, rate: float,
                      hold_s: float | None = None) -> np.ndarray:
    """Touches the stream detector (``eskin.signal.preprocess.TouchDetector``, the C++ one the
    controller runs) reports on each recording ``indices`` of ``recordings`` (anything with
    ``recording(i)`` -> (rows, cols, T)) fed alone, start to end, with ``config`` (its
    ``hold_s`` replaced by ``hold_s`` when given)."""
    from eskin.signal.preprocess import TouchDetector

    cfg = config if hold_s is None else replace(config, hold_s=float(hold_s))
    counts = np.zeros(len(indices), np.int64)
    for k, i in enumerate(indices):
        r = np.asarray(recordings.recording(int(i)))
        det = TouchDetector(r.shape[:2], rate, cfg)
        x = np.ascontiguousarray(r.reshape(-1, r.shape[-1]).T)
        counts[k] = len(det.push(x)) + len(det.flush())
    return counts


@dataclass
class HoldChoice:
    """The hold time chosen (or kept), the notes to print and the record kept in the model
    (``training["live_touches"]``)."""

    config: Any
    notes: list[str] = field(default_factory=list)
    record: dict[str, Any] = field(default_factory=dict)


def _tally(counts: np.ndarray) -> dict[str, int]:
    return {"recordings": int(counts.size), "one": int(np.sum(counts == 1)),
            "split": int(np.sum(counts > 1)), "none": int(np.sum(counts == 0)),
            "touches": int(counts.sum())}


def _enough(t: dict[str, int], share: float) -> bool:
    return t["recordings"] == 0 or t["one"] >= share * t["recordings"]


def _grid(config: Any, gap_s: float) -> list[float]:
    """The hold times to try: the configured one, then the grid's longer ones below the live
    gap and below the longest window."""
    first = float(config.hold_s)
    cap = min(float(gap_s), float(config.max_window_s))
    return [first] + [h for h in HOLD_GRID_S if first < h < cap]


def _describe(t: dict[str, int]) -> str:
    parts = [f"{t['split']} of {t['recordings']} training recordings gave 2+ live touches"]
    if t["none"]:
        parts.append(f"{t['none']} gave none")
    return ", ".join(parts)


def choose_hold(recordings: Any, indices: Sequence[int], config: Any, rate: float, *,
                choose: bool = True, gap_s: float = LIVE_GAP_S,
                share: float = ONE_TOUCH_SHARE) -> HoldChoice:
    """``config`` with the ``hold_s`` at which one training recording gives one live touch.

    With ``choose`` False (the hold was given), ``config`` is kept and a note says when fewer
    than ``share`` of the recordings give one touch. Otherwise the hold times of
    :func:`_grid` are tried in order and the first that reaches ``share`` is taken; when none
    does, the one with the most single-touch recordings is taken, with a note saying how
    many still split."""
    tried: dict[float, dict[str, int]] = {}
    holds = _grid(config, gap_s) if choose else [float(config.hold_s)]
    for h in holds:
        tried[h] = _tally(live_touch_counts(recordings, indices, config, rate, h))
        if _enough(tried[h], share):
            break
    first = holds[0]
    best = next((h for h in tried if _enough(tried[h], share)), None)
    record = {"hold_s": first, "chosen": choose, "share": share, "gap_s": float(gap_s),
              "tried": {f"{h:g}": t for h, t in tried.items()}}
    if best == first:
        return HoldChoice(config, [], {**record, **tried[first]})
    if not choose:
        note = (f"hold_s = {first:g} s (given): {_describe(tried[first])} (a gesture with a "
                f"pause longer than hold_s, such as a press and its release, is two touches "
                f"live but one window in training); a longer --hold merges them")
        return HoldChoice(config, [note], {**record, **tried[first]})
    if best is None:
        best = max(tried, key=lambda h: (tried[h]["one"], -h))
        note = (f"hold_s = {best:g} s: no hold time up to {max(tried):g} s (below the "
                f"{gap_s:g} s between gestures of a live stream and the {config.max_window_s:g} "
                f"s longest window) gives one live touch on {100 * share:.0f} % of the training "
                f"recordings; at {first:g} s {_describe(tried[first])}, at {best:g} s "
                f"{_describe(tried[best])}")
    else:
        note = (f"hold_s = {best:g} s: at {first:g} s, {_describe(tried[first])} (a pause "
                f"inside a gesture, such as between a press and its release, ended the touch); "
                f"now {tried[best]['one']} of {tried[best]['recordings']} give one")
    record.update({"hold_s": best, **tried[best]})
    return HoldChoice(replace(config, hold_s=best), [note], record)
