"""Many links, one host: every patch of a skin read at once (docs/skin.md).

:class:`SkinListener` holds one :class:`~eskin.link.listener.LinkListener` per patch, each on
its own port and in its own thread (the port reads wait without the GIL), all classifying
through one :class:`~eskin.link.skin_classifier.SkinClassifier` and recording into one campaign
through one :class:`~eskin.link.skin_recorder.SkinRecorder`. :meth:`SkinListener.run` returns
a :class:`SkinReport`: each patch's link statistics and decisions, and the agreement of the
host's decisions with the controller's (the same touch window, label and don't-know).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from eskin.data.skin import Skin
from eskin.link.events import Decision, LinkEvent, LinkStats, Stats
from eskin.link.listener import LinkListener
from eskin.link.serial_port import SerialPortError
from eskin.link.skin_classifier import SkinClassifier
from eskin.link.skin_recorder import SkinRecorder

__all__ = ["PatchReport", "SkinListener", "SkinReport", "agreement"]


def agreement(decisions: list[Decision]) -> tuple[int, int]:
    """(host decisions equal to a controller decision, decisions compared): a controller and
    a host decision agree when they have the same window, label and don't-know; compared is
    the larger of the two counts (a decision only one side made is a disagreement)."""
    ctrl = {(d.onset_sample, d.offset_sample): (d.label, d.dont_know)
            for d in decisions if d.source == "controller"}
    host = [d for d in decisions if d.source == "host"]
    same = sum(ctrl.get((d.onset_sample, d.offset_sample)) == (d.label, d.dont_know)
               for d in host)
    return same, max(len(ctrl), len(host))


@dataclass
class PatchReport:
    """One patch's link: its port, final statistics, decisions, and an error that ended it."""

    patch_id: str
    port: str
    stats: LinkStats = field(default_factory=LinkStats)
    decisions: list[Decision] = field(default_factory=list)
    error: str = ""

    @property
    def agree(self) -> tuple[int, int]:
        return agreement(self.decisions)

    @property
    def lost(self) -> int:
        """Samples lost on this link: the listener's count, or, when the link ended before
        the controller's final STATUS reconciled it, at least what the controller's last
        STATUS says it sent beyond what arrived."""
        st = self.stats
        return max(st.lost_samples, st.controller_samples_sent - st.samples)


@dataclass
class SkinReport:
    """Every patch's report, in skin order, and the whole skin's sums."""

    patches: list[PatchReport]
    recordings: int = 0

    def total(self, name: str) -> int:
        return sum(int(getattr(p.stats, name)) for p in self.patches)

    @property
    def agree(self) -> tuple[int, int]:
        pairs = [p.agree for p in self.patches]
        return sum(a for a, _ in pairs), sum(n for _, n in pairs)

    def summary(self) -> str:
        """patches=K frames=N lost=N crc_errors=N decisions=N agree=A/N (decisions: the
        controllers')."""
        a, n = self.agree
        lost = sum(p.lost for p in self.patches)
        return (f"patches={len(self.patches)} frames={self.total('frames')} "
                f"lost={lost} crc_errors={self.total('crc_errors')} "
                f"decisions={self.total('decisions_controller')} agree={a}/{n}")

    @property
    def errors(self) -> list[str]:
        return [f"{p.patch_id}: {p.error}" for p in self.patches if p.error]


class SkinListener:
    """Every patch of ``skin`` on its port (``ports``: patch id -> port path); ``replays``:
    patch id -> the replay file its controller streams (recordings then follow its segments);
    ``record``: one campaign file for every patch's recordings."""

    def __init__(self, skin: Skin, ports: Mapping[str, str], *, backend: str = "auto",
                 record: Optional[Path] = None, overwrite: bool = False,
                 replays: Optional[Mapping[str, Any]] = None, reconnect: bool = False,
                 record_source: str = "recorded") -> None:
        missing = [p.id for p in skin.patches if p.id not in ports]
        if missing:
            raise ValueError(f"{skin.path}: no port for patch {missing[0]!r}")
        self.skin = skin
        self.ports = dict(ports)
        self.classifier = SkinClassifier(skin, backend)
        self.recorder = None if record is None else SkinRecorder(
            Path(record), skin.ids, overwrite=overwrite,
            attrs={"skin_name": skin.name, "skin_file": str(skin.path or "")})
        replays = dict(replays or {})
        self.listeners = {p.id: self._listener(p.id, replays.get(p.id), reconnect,
                                               record_source) for p in skin.patches}
        self.reports = {pid: PatchReport(pid, self.ports[pid]) for pid in skin.ids}
        self._lock = threading.Lock()

    def _listener(self, pid: str, replay: Any, reconnect: bool, source: str) -> LinkListener:
        view = self.classifier.patch_view(pid)
        if replay is not None and not hasattr(replay, "segments"):
            from eskin.data.replay import read_replay_file

            replay = read_replay_file(replay)
        recorder = None
        if self.recorder is not None:
            from eskin.link.host_classifier import max_touch_s

            recorder = self.recorder.recorder(
                pid, policy="segment" if replay is not None else "touch", replay=replay,
                replay_offset=0, context_s=0.5, source=source, attrs={}, port=self.ports[pid],
                host_names=list(view.class_names) if view is not None else [],
                max_touch_s=max_touch_s(view))
        return LinkListener(self.ports[pid], model=view, replay=replay, recorder=recorder,
                            reconnect=reconnect, stats_interval=None)

    def open(self, timeout_s: float = 0.0) -> SkinListener:
        """Open every port, retrying for ``timeout_s`` seconds while one is not there yet (a
        controller still starting)."""
        deadline = time.monotonic() + timeout_s
        for pid, link in self.listeners.items():
            while True:
                try:
                    link.open()
                    break
                except SerialPortError as exc:
                    if time.monotonic() >= deadline:
                        raise SerialPortError(exc.status, f"patch {pid!r}: {exc}") from None
                    time.sleep(0.05)
        return self

    def run(self, *, duration: Optional[float] = None, until_eof: bool = False,
            on_event: Optional[Callable[[str, LinkEvent], None]] = None) -> SkinReport:
        """Read every link until each has ended (see LinkListener.events); ``on_event(patch,
        event)`` sees every event, one call at a time. Ctrl-C stops every link, and the
        recordings received so far are kept (:meth:`close`)."""
        threads = [threading.Thread(target=self._pump, args=(pid, duration, until_eof,
                                                             on_event), daemon=True)
                   for pid in self.listeners]
        for t in threads:
            t.start()
        try:
            for t in threads:
                while t.is_alive():  # short joins: Ctrl-C reaches this thread
                    t.join(0.1)
        except KeyboardInterrupt:
            self.stop()
            for t in threads:
                t.join()
            raise
        return self.report()

    def _pump(self, pid: str, duration: Optional[float], until_eof: bool,
              on_event: Optional[Callable[[str, LinkEvent], None]]) -> None:
        report = self.reports[pid]
        try:
            for ev in self.listeners[pid].events(duration=duration, until_eof=until_eof):
                if isinstance(ev, Decision):
                    report.decisions.append(ev)
                elif isinstance(ev, Stats):
                    report.stats = ev.stats
                if on_event is not None:
                    with self._lock:
                        on_event(pid, ev)
        except (ValueError, OSError) as exc:  # this link ends; the others go on
            report.error = str(exc)
            report.stats = self.listeners[pid].stats

    def stop(self) -> None:
        for link in self.listeners.values():
            link.stop()

    def report(self) -> SkinReport:
        recordings = self.recorder.recordings if self.recorder is not None else 0
        return SkinReport([self.reports[pid] for pid in self.skin.ids], recordings)

    def close(self) -> None:
        """Close every port, then finish the campaign file (idempotent)."""
        try:
            for link in self.listeners.values():
                link.close()
        finally:
            if self.recorder is not None:
                self.recorder.close()

    def __enter__(self) -> SkinListener:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
