"""The events :class:`eskin.link.LinkListener` yields, and its statistics (see the listener's
module docstring for what each one means)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Optional, Union

import numpy as np

from eskin.link.frame_checks import Rejection
from eskin.link.protocol import DecoderStats, InfoFrame, StatusFrame
from eskin.link.recorder import Recorded

__all__ = ["Connection", "DataBlock", "Decision", "InfoEvent", "LinkEvent", "LinkStats",
           "Recorded", "Rejection", "Stats", "StatusEvent"]


@dataclass(frozen=True, eq=False)
class DataBlock:
    """Consecutive samples as received: int16 ``(n, rows, cols)``, stream indices
    ``first_sample`` .. ``first_sample + n``; ``lost_before`` samples were lost just before."""

    first_sample: int
    samples: np.ndarray
    timestamp_us: int = 0
    overrun: bool = False
    lost_before: int = 0

    @property
    def end_sample(self) -> int:
        return self.first_sample + int(self.samples.shape[0])


@dataclass(frozen=True)
class Decision:
    """A decision on one touch, from the controller (a DECISION frame) or from this host.

    ``onset_sample``/``offset_sample``: the touch window ``[onset, offset)`` in stream indices;
    ``label``: a class name (None when the class is unknown, e.g. no INFO yet); ``label_index``
    indexes the class names (-1: none); ``values``: one decision value per binary machine;
    ``dont_know``: no machine or several machines claimed the touch. ``latency_us``: for the
    controller, its reported latency; for the host, the time from receiving the frame that ended
    the touch to the decision. ``lost_samples``: host only, samples of the window that were lost.
    """

    source: str
    onset_sample: int
    offset_sample: int
    label: Optional[str]
    label_index: int
    values: tuple[float, ...]
    dont_know: bool = False
    decided_sample: int = 0
    latency_us: float = 0.0
    lost_samples: int = 0

    def as_dict(self) -> dict[str, Any]:
        """The JSON object ``eskin listen --jsonl`` writes for this decision: strict JSON, a
        non-finite decision value is ``null`` and ``nonfinite_values`` is true."""
        return {
            "type": "decision",
            "source": self.source,
            "onset_sample": int(self.onset_sample),
            "offset_sample": int(self.offset_sample),
            "decided_sample": int(self.decided_sample),
            "label": self.label,
            "label_index": int(self.label_index),
            "values": [float(v) if math.isfinite(v) else None for v in self.values],
            "nonfinite_values": not all(math.isfinite(v) for v in self.values),
            "dont_know": bool(self.dont_know),
            "latency_us": float(self.latency_us),
            "lost_samples": int(self.lost_samples),
        }


@dataclass(frozen=True)
class StatusEvent:
    status: StatusFrame


@dataclass(frozen=True)
class InfoEvent:
    info: InfoFrame


@dataclass(frozen=True)
class Connection:
    """``state``: "connected", "disconnected" (the peer closed the port) or "reconnected"."""

    state: str
    path: str
    reason: str = ""


@dataclass(frozen=True)
class LinkStats(DecoderStats):
    """Everything counted on the link (see the module docstring).

    The decoder counters inherited from :class:`DecoderStats` (``bytes`` ..
    ``sample_index_resets``, and ``rejected``) are this host's; the ``controller_*`` ones are
    the controller's cumulative counters from its last STATUS. ``absurd_frames``: frames sound
    on the wire whose fields were refused (each also a :class:`Rejection` event);
    ``unexpected_frames``: sound frames of a type only a host sends (START, STOP, PING,
    INFO_REQUEST), skipped; ``nonfinite_decisions``: decisions with a NaN or infinite decision
    value (kept, and written as ``null`` by ``--jsonl``). Every frame decoded is a DATA,
    DECISION, STATUS, INFO or PONG frame used, an absurd one or an unexpected one: ``frames`` =
    ``data_frames`` used + decisions from the controller + ``status_frames`` + INFO frames +
    ``pong_frames`` + ``absurd_frames`` + ``unexpected_frames``.

    ``lost_decisions``: DECISION frames the controller sent that this host did not take (lost
    on the link or refused), known from a STATUS sent while the controller is not streaming
    (:func:`eskin.link.receiver.unreceived_decisions`); with the controller's own
    ``controller_decisions_dropped`` (decisions it could not send), every decision it made is
    accounted for: made = ``decisions_controller`` + ``lost_decisions`` +
    ``controller_decisions_dropped`` once it has stopped.
    """

    elapsed_s: float = 0.0
    absurd_frames: int = 0
    unexpected_frames: int = 0
    nonfinite_decisions: int = 0
    pong_frames: int = 0
    overrun_frames: int = 0
    status_frames: int = 0
    decisions_controller: int = 0
    decisions_host: int = 0
    recordings: int = 0
    disconnects: int = 0
    reconnects: int = 0
    controller_samples_sent: int = 0
    controller_dropped_samples: int = 0
    controller_overrun_events: int = 0
    controller_rx_errors: int = 0
    controller_faults_injected: int = 0
    lost_decisions: int = 0
    controller_decisions_sent: int = 0
    controller_decisions_dropped: int = 0
    controller_frames_dropped: int = 0
    controller_pacing_p50_us: float = 0.0
    controller_pacing_p99_us: float = 0.0
    controller_state: str = "unknown"

    @property
    def rate_samples_per_s(self) -> float:
        return self.samples / self.elapsed_s if self.elapsed_s > 0 else 0.0

    def as_dict(self) -> dict[str, Any]:  # type: ignore[override]
        d: dict[str, Any] = dataclasses.asdict(self)
        d["rejected"] = self.rejected
        return d


@dataclass(frozen=True)
class Stats:
    stats: LinkStats


LinkEvent = Union[DataBlock, Decision, StatusEvent, InfoEvent, Recorded, Connection, Stats,
                  Rejection]
