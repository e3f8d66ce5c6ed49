"""Recording the received stream to a campaign file: one recording per replay segment (with
its true class and contact interval) or one per touch the host detects (``context_s`` around
it), written through :class:`eskin.CampaignWriter` (see :class:`eskin.link.LinkListener`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from eskin.link.stream import SampleHistory

__all__ = ["Recorded", "StreamRecorder"]


@dataclass(frozen=True)
class Recorded:
    """Recording ``index`` of the campaign file: stream samples ``[start, stop)``."""

    index: int
    start: int
    stop: int
    label: str
    lost_samples: int = 0


class StreamRecorder:
    """Cuts recordings out of a :class:`SampleHistory` and appends them to a campaign file,
    opened at the first recording (the grid and rate are known then)."""

    def __init__(self, path: Path, *, policy: str, replay: Any, replay_offset: int,
                 context_s: float, overwrite: bool, source: str, attrs: dict[str, Any],
                 port: str, host_names: list[str], max_touch_s: float) -> None:
        self.path = Path(path)
        self.policy = policy
        self.replay = replay
        self.replay_offset = int(replay_offset)
        self.context_s = float(context_s)
        self.overwrite = bool(overwrite)
        self.source = source
        self.attrs = {**attrs, "recorded_by": "eskin.link.LinkListener",
                      "record_policy": policy, "port": port}
        self.host_names = list(host_names)
        self.max_touch_s = float(max_touch_s)
        self.recordings = 0
        self._writer: Any = None
        self._with_contact = False
        self._pending: list[tuple[int, int, str]] = []  # touches (start, stop, label) to record
        self._next_segment = 0

    def history_s(self, rate: float) -> float:
        """Seconds of history the recordings need."""
        if self.policy == "segment":
            segs = self.replay.segments
            longest = int(segs["length"].max()) if len(segs) else 0
            return longest / rate + 1.0
        return self.max_touch_s + 2 * self.context_s + 1.0

    def size_problem(self, grid: tuple[int, int], rate: float) -> Optional[str]:
        """Why recordings of this grid and rate cannot be written (over the campaign format's
        size limits, a rate outside its range, or the memory), or None."""
        from eskin.data.campaign import check_sizes
        from eskin.data.limits import MAX_SAMPLE_RATE_HZ, MIN_SAMPLE_RATE_HZ

        if not MIN_SAMPLE_RATE_HZ <= rate <= MAX_SAMPLE_RATE_HZ:
            return (f"a campaign's sample rate is {MIN_SAMPLE_RATE_HZ:g} to "
                    f"{MAX_SAMPLE_RATE_HZ:g} Hz")
        seconds = self.history_s(rate) - 1.0
        try:
            check_sizes(str(self.path), 0, grid[0], grid[1], int(math.ceil(seconds * rate)) + 1)
        except ValueError as exc:
            return str(exc)
        return None

    def touch(self, start: int, stop: int, label: str) -> None:
        """A touch to record once ``context_s`` after it has arrived (policy "touch" only: the
        "segment" policy records the replay file's segments, and a touch given to it would
        wait for ever)."""
        if self.policy != "touch":
            raise ValueError(f"StreamRecorder.touch: the {self.policy!r} policy records no "
                             f"touches")
        self._pending.append((start, stop, label))

    def ready(self, h: SampleHistory, rate: float, volts_per_count: float,
              final: bool = False) -> list[Recorded]:
        """Append the recordings whose samples are all in ``h`` (``final``: every pending touch,
        with what was received)."""
        if self.policy == "segment":
            return self._segments(h, rate, volts_per_count)
        ctx = int(round(self.context_s * rate))
        out, keep = [], []
        for start, stop, label in self._pending:
            a, b = start - ctx, stop + ctx
            if h.end < b and not final:
                keep.append((start, stop, label))
                continue
            names = self._names(h, rate, volts_per_count)
            out.append(self._append(h, max(a, h.begin), min(b, h.end), names.index(label), None))
        self._pending = keep
        return out

    def _segments(self, h: SampleHistory, rate: float, vpc: float) -> list[Recorded]:
        out = []
        segs = self.replay.segments
        while self._next_segment < len(segs):
            seg = segs[self._next_segment]
            start = self.replay_offset + int(seg["start"])
            stop = start + int(seg["length"])
            if h.end < stop:
                break  # not there yet (a segment never completed is never written)
            self._next_segment += 1
            if h.begin > start:
                continue  # not fully received: joined late, or a long hole inside it
            label = int(seg["label"])
            names = self._names(h, rate, vpc)
            modality = label if label >= 0 else len(names) - 1
            ci = None
            if self._with_contact:
                ci = (int(seg["contact_onset"]), int(seg["contact_offset"]))
            out.append(self._append(h, start, stop, modality, ci))
        return out

    def _names(self, h: SampleHistory, rate: float, vpc: float) -> list[str]:
        if self._writer is None:
            self._open(h.grid, rate, vpc)
        return list(self._writer.modalities)

    def _open(self, grid: tuple[int, int], rate: float, vpc: float) -> None:
        settings = self.writer_settings(grid, rate, vpc)
        self._with_contact = bool(settings["contact_interval"])
        self._writer = self.make_writer(settings)

    def make_writer(self, settings: dict[str, Any]) -> Any:
        """The campaign writer of ``settings`` (a skin's recorders share one instead)."""
        from eskin.data.campaign import CampaignWriter

        return CampaignWriter(self.path, **settings)

    def writer_settings(self, grid: tuple[int, int], rate: float, vpc: float
                        ) -> dict[str, Any]:
        """The CampaignWriter arguments of this stream's recordings (but the path)."""
        attrs = dict(self.attrs)
        with_contact = False
        if self.policy == "segment":
            names = list(self.replay.class_names) or []
            if not names or np.any(self.replay.segments["label"] < 0):
                names.append("unknown")
            n_samples = int(self.replay.segments["length"].max())
            attrs["labels"] = "true classes from the replay file"
            attrs["replay_file"] = str(self.replay.path)
            with_contact = bool(np.all(self.replay.segments["contact_onset"] >= 0))
        else:
            names = [*self.host_names, "unknown"]
            n_samples = int(math.ceil((self.max_touch_s + 2 * self.context_s) * rate)) + 1
            attrs["labels"] = ("the host's decisions (not ground truth); unknown = don't know"
                               if self.host_names else "none (unknown)")
        return dict(grid_shape=grid, n_samples=n_samples, sample_rate_hz=rate,
                    volts_per_count=vpc, modalities=names, source=self.source, attrs=attrs,
                    contact_interval=with_contact, overwrite=self.overwrite,
                    extra_fields={"stream_start": np.int64, "lost_samples": np.int32})

    def _append(self, h: SampleHistory, start: int, stop: int, modality: int,
                contact: Optional[tuple[int, int]]) -> Recorded:
        samples, lost = h.get(start, stop)
        stop = start + samples.shape[0]
        rec = np.ascontiguousarray(np.moveaxis(samples, 0, -1))
        n_lost = int(lost.sum())
        try:
            idx = self._writer.append(
                rec, modality=modality, participant=-1, direction=255, run=0,
                contact_interval=contact, extra={"stream_start": start, "lost_samples": n_lost})
        except OSError as exc:  # a full or failing disk: stop recording, keep what was written
            self._writer.keep()
            raise OSError(exc.errno, f"{exc.strerror}; `eskin recover {self.path}` builds the "
                          f"campaign from them") from exc
        self.recordings += 1
        return Recorded(idx, start, stop, self._writer.modalities[modality], n_lost)

    @property
    def grid(self) -> Optional[tuple[int, int]]:
        """The grid of the file being written (None before the first recording)."""
        return None if self._writer is None else self._writer.grid_shape

    def close(self) -> None:
        """Finish the campaign file (nothing is written if no recording was due)."""
        if self._writer is not None:
            self._writer.close()
