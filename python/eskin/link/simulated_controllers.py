"""The simulated controllers of a skin: one ``eskin-fw-sim`` process per simulated patch.

:class:`SimulatedControllers` starts, for every patch of a skin description whose ``link`` is
``"simulated"``, an ``eskin-fw-sim`` streaming that patch's replay file (``FOLDER/ID.eskr``, as
``eskin simulate --skin`` writes them) over its own pseudo-terminal, classifying on board with
the patch's model when it names one; each publishes its port as the symlink ``FOLDER/ID.tty``
too. :meth:`SimulatedControllers.stop` ends every one of them (SIGTERM, by process id).
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from eskin.data.skin import Skin

__all__ = ["Controller", "SimulatedControllers", "link_path", "replay_path"]


def replay_path(folder: Path, patch_id: str) -> Path:
    """Where ``eskin simulate --skin`` writes the replay of patch ``patch_id``."""
    return Path(folder) / f"{patch_id}.eskr"


def link_path(folder: Path, patch_id: str) -> Path:
    """The symlink to the pseudo-terminal of patch ``patch_id``'s simulated controller."""
    return Path(folder) / f"{patch_id}.tty"


@dataclass
class Controller:
    """One running ``eskin-fw-sim``: its patch, process and pseudo-terminal."""

    patch_id: str
    process: subprocess.Popen
    pty: str
    link: Path
    stats: Optional[dict[str, Any]] = None


class SimulatedControllers:
    """One ``eskin-fw-sim`` per simulated patch of ``skin``, its replay from ``folder``.

    ``speed``, ``wait_start``, ``hold_s``, ``loop`` and ``tx_buffer`` are ``eskin-fw-sim``'s
    options of those names (speed 0: as fast as the host reads, which loses nothing). The
    transmit queue is by default 1 MiB when paced (a host stalled for a moment by a busy machine
    loses nothing) and eskin-fw-sim's own 16 KiB unpaced: unpaced, the controller waits for
    room in its queue, and a large one would let it finish its replay (and, after ``hold_s``,
    close its port) with more queued than a slow host reads in that time."""

    def __init__(self, skin: Skin, folder: Path, *, speed: float = 1.0, wait_start: bool = True,
                 hold_s: float = 1.0, loop: bool = False,
                 tx_buffer: Optional[int] = None) -> None:
        self.skin = skin
        self.folder = Path(folder)
        if tx_buffer is None:
            tx_buffer = 1 << 20 if speed > 0 else 1 << 14
        self.args = ["--speed", f"{speed:g}", "--hold", f"{hold_s:g}", "--tx-buffer",
                     str(int(tx_buffer)), "--quiet", *(["--wait-start"] if wait_start else []),
                     *(["--loop"] if loop else [])]
        self.controllers: list[Controller] = []
        patches = [p for p in skin.patches if p.simulated]
        if not patches:
            raise ValueError(f"{skin.path}: no patch has link = \"simulated\": nothing to start")
        for p in patches:
            replay = replay_path(self.folder, p.id)
            if not replay.is_file():
                raise FileNotFoundError(f"{replay}: no replay for patch {p.id!r} (`eskin "
                                        f"simulate --skin {skin.path} -o {self.folder}` "
                                        f"writes one per patch)")
            if p.model is not None and not p.model.is_file():
                raise FileNotFoundError(f"model file {p.model} of patch {p.id!r} does not exist")
        self._patches = patches

    def start(self, timeout_s: float = 20.0) -> SimulatedControllers:
        """Start every controller; returns once each has published its pseudo-terminal."""
        from eskin._paths import find_executable

        exe = str(find_executable("eskin-fw-sim"))
        try:
            for p in self._patches:
                link = link_path(self.folder, p.id)
                model = ["--model", str(p.model)] if p.model is not None else []
                proc = subprocess.Popen(
                    [exe, str(replay_path(self.folder, p.id)), *model, *self.args,
                     "--link", str(link)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                    text=True)
                pty = published_pty(proc, timeout_s, f"eskin-fw-sim of patch {p.id!r}")
                self.controllers.append(Controller(p.id, proc, pty, link))
        except BaseException:
            self.stop()
            raise
        return self

    def running(self) -> int:
        return sum(c.process.poll() is None for c in self.controllers)

    def wait(self, poll_s: float = 0.1) -> None:
        """Wait until every controller has exited (its replay over, and its hold)."""
        while self.running():
            time.sleep(poll_s)
        self._collect()

    def stop(self, timeout_s: float = 5.0) -> None:
        """End every controller still running (SIGTERM, then SIGKILL after ``timeout_s``)."""
        for c in self.controllers:
            if c.process.poll() is None:
                c.process.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + timeout_s
        for c in self.controllers:
            try:
                c.process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                c.process.kill()
                c.process.wait()
        self._collect()

    def _collect(self) -> None:
        """Each controller's final ``STATS {json}`` line (None when it printed none)."""
        for c in self.controllers:
            if c.stats is not None or c.process.stdout is None:
                continue
            out = c.process.stdout.read() or ""
            for line in out.splitlines():
                if line.startswith("STATS "):
                    c.stats = json.loads(line[6:])
            c.process.stdout.close()
            if c.process.stderr is not None:
                c.process.stderr.close()

    def __enter__(self) -> SimulatedControllers:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def published_pty(proc: subprocess.Popen, timeout_s: float, what: str) -> str:
    """The pseudo-terminal an ``eskin-fw-sim`` process prints first ("PTY path"); an OSError
    naming ``what`` (and the simulator's own message) when none comes within ``timeout_s``."""
    found: list[str] = []
    reader = threading.Thread(target=lambda: found.append(proc.stdout.readline()),  # type: ignore
                              daemon=True)
    reader.start()
    reader.join(timeout_s)
    if not found or not found[0].startswith("PTY "):
        proc.kill()
        err = proc.stderr.read() if proc.stderr is not None else ""
        raise OSError(f"{what} did not publish its pseudo-terminal (first line "
                      f"{found[0] if found else 'none'!r}): {(err or '').strip() or 'no output'}")
    return found[0][4:].strip()
