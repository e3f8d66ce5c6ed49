"""The emulated controller: the firmware image ``eskin-fw`` (mcu/eskin_fw.cpp, docs/mcu.md) on
QEMU's mps2-an386 board, its UART0 on a pseudo-terminal (``-serial pty``).

:class:`QemuController` starts ``qemu-system-arm`` with the image, the model in the firmware's
flash slot and the recording (an eskin replay file) in the board's PSRAM, both loaded by QEMU
before reset (``-device loader``), and gives the pty's path; a host then opens it like any
controller port (``eskin listen``, :class:`eskin.link.LinkListener`). The firmware streams
from the host's first START: QEMU's pty discards what the board writes while no host has it
open, and notices a host only by polling it. Real time by default; ``icount=N`` runs QEMU with
``-icount shift=N`` (one instruction per 2^N ns of the board's clock) and turns on the
firmware's profiling (its handlers and main loop time themselves: instruction counts).
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import struct
import subprocess
import threading
from pathlib import Path
from typing import Optional

from eskin.errors import QemuControllerError

__all__ = ["QemuController", "QemuControllerError", "priority"]

#: where the firmware expects the model (its flash slot) and the recording (PSRAM)
MODEL_SLOT = 0x00040000
MODEL_SLOT_BYTES = 0x00100000 - MODEL_SLOT - 16
REPLAY_ADDRESS = 0x21000000
REPLAY_MAX_BYTES = 16 << 20
_PTY = re.compile(rb"char device redirected to (/dev/pts/\d+)")
_REPO = Path(__file__).resolve().parents[3]

# On a busy machine the board's real time is the emulator's: QEMU moves every UART byte with a
# write(2) on the pty and raises the TX interrupt after it. With the right to (root), QEMU runs
# at nice -15, still under the ordinary fair scheduler (nothing can be starved for long).
QEMU_NICE = -15


def priority(nice: int) -> list[str]:
    """A ``nice -n`` prefix when this process may raise priority (root), else nothing."""
    if hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("nice"):
        return ["nice", "-n", str(nice)]
    return []


def firmware_image() -> Path:
    """The firmware image: $ESKIN_MCU_FW, else build/mcu/mcu/eskin-fw.elf of the source tree."""
    env = os.environ.get("ESKIN_MCU_FW")
    path = Path(env) if env else _REPO / "build" / "mcu" / "mcu" / "eskin-fw.elf"
    if not path.is_file():
        raise QemuControllerError(
            f"{path}: no controller firmware image; build it with `make mcu-link` (or set "
            f"ESKIN_MCU_FW)")
    return path


def model_slot_image(model: Path, out: Path, profile: bool = False) -> Path:
    """The firmware's model slot: ``ESKM``, size, flags (bit 0: profile), reserved, model."""
    data = Path(model).read_bytes()
    if len(data) > MODEL_SLOT_BYTES:
        raise QemuControllerError(
            f"{model}: {len(data)} bytes, the firmware's model slot holds {MODEL_SLOT_BYTES}")
    out.write_bytes(b"ESKM" + struct.pack("<III", len(data), int(profile), 0) + data)
    return out


def qemu_command(elf: Path, slot: Path, replay: Path, icount: Optional[int] = None) -> list[str]:
    cmd = ["qemu-system-arm", "-M", "mps2-an386", "-cpu", "cortex-m4", "-nographic",
           "-monitor", "none", "-serial", "pty", "-semihosting-config",
           "enable=on,target=native", "-kernel", str(elf),
           "-device", f"loader,file={slot},addr={MODEL_SLOT:#x},force-raw=on",
           "-device", f"loader,file={replay},addr={REPLAY_ADDRESS:#x},force-raw=on"]
    if icount is not None:
        cmd += ["-icount", f"shift={icount},sleep=on"]
    return cmd


class QemuController:
    """``with QemuController(model, replay, workdir) as qc: ... qc.pty ...``; the board's
    console (QEMU's stdout: start-up errors, the firmware's ``FW:`` line) is in
    ``workdir/qemu.log`` and :meth:`console`."""

    def __init__(self, model: Path, replay: Path, workdir: Path, *,
                 elf: Optional[Path] = None, icount: Optional[int] = None) -> None:
        if shutil.which("qemu-system-arm") is None:
            raise QemuControllerError("qemu-system-arm is not installed (make mcu-deps)")
        self.elf = Path(elf) if elf is not None else firmware_image()
        self.model, self.replay = Path(model), Path(replay)
        if self.replay.stat().st_size > REPLAY_MAX_BYTES:
            raise QemuControllerError(
                f"{replay}: larger than the 16 MB of PSRAM the firmware reads it from")
        self.workdir = Path(workdir)
        self.icount = icount
        self.log_path = self.workdir / "qemu.log"
        self.pty = ""
        self._proc: Optional[subprocess.Popen] = None
        self._reader: Optional[threading.Thread] = None

    def start(self, timeout: float = 30.0) -> str:
        self.workdir.mkdir(parents=True, exist_ok=True)
        slot = model_slot_image(self.model, self.workdir / "model-slot.bin",
                                profile=self.icount is not None)
        log = open(self.log_path, "wb")
        self._proc = subprocess.Popen(
            priority(QEMU_NICE) + qemu_command(self.elf, slot, self.replay, self.icount),
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
        found: list[str] = []
        ready = threading.Event()
        proc = self._proc

        def copy_console() -> None:  # QEMU's stdout: the pty's name, then the board's console
            assert proc.stdout is not None
            for line in iter(proc.stdout.readline, b""):
                log.write(line)
                log.flush()
                m = _PTY.search(line)
                if m and not found:
                    found.append(m.group(1).decode())
                    ready.set()
            log.close()
            ready.set()

        self._reader = threading.Thread(target=copy_console, daemon=True)
        self._reader.start()
        ready.wait(timeout)
        if not found:
            self.stop()
            raise QemuControllerError("QEMU gave no pty: " + self.console()[-1000:])
        self.pty = found[0]
        return self.pty

    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def console(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def stop(self) -> str:
        """Stop QEMU (the whole process group); returns the board's console."""
        proc = self._proc
        if proc is not None and proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        if self._reader is not None:
            self._reader.join(10)
        if proc is not None and proc.stdout is not None and not proc.stdout.closed:
            proc.stdout.close()  # the console's pipe (its reader has ended with QEMU)
        return self.console()

    def __enter__(self) -> "QemuController":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
