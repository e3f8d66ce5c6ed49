"""A serial port for the host side of the link: termios in the compiled core.

Opens any tty, including the pseudo-terminal published by ``eskin-fw-sim`` (which
libserialport and most serial libraries cannot open), in raw mode::

    with SerialPort("/dev/pts/3") as port:
        port.write(encode_frame(CommandFrame(FrameType.START)))
        chunk = port.read(4096, timeout=0.1)     # b"" after 0.1 s of silence

A closed peer raises PeerClosedError instead of looking like silence; other failures raise
SerialPortError (an OSError) naming the port and the cause. Blocking calls release the GIL.

:meth:`SerialPort.start_reader` hands the reading to a thread of the compiled core that only
moves what arrives into a large queue (no Python, no GIL): :meth:`SerialPort.read` then takes
from the queue, and a reader of the bytes that is busy or descheduled for a while loses none
of them, where the driver's own buffers (about 20 KiB for a pseudo-terminal) would overflow
within tens of milliseconds of a fast stream. Where the system allows it, that thread runs
under the real-time policy (``realtime_priority``), ahead of the ordinary programs that would
otherwise keep it waiting that long on a loaded machine.
"""

from __future__ import annotations

import os
from typing import Any, Optional

from eskin import _core
from eskin.errors import PeerClosedError, SerialPortError

__all__ = ["PeerClosedError", "SerialPort", "SerialPortError"]


def _timeout(timeout: Optional[float]) -> float:
    if timeout is None:
        return -1.0
    if timeout < 0:
        raise ValueError(f"timeout must be >= 0 seconds or None, got {timeout}")
    return float(timeout)


class SerialPort:
    """A tty opened in raw mode (8N1, no flow control). ``baud`` is set (a pty ignores it)."""

    def __init__(self, path: str | os.PathLike[str], baud: int = 115200):
        self._port = _core.serial.SerialPort()
        self._reader: Optional[Any] = None
        self._check(self._port.open(os.fspath(path), int(baud)))

    # -- helpers --------------------------------------------------------------------------------
    def _check(self, status: str, message: str = "") -> None:
        if status in ("ok", "timeout"):
            return
        message = message or self._port.last_error or status
        cls = PeerClosedError if status == "peer_closed" else SerialPortError
        raise cls(status, message, int(self._port.last_errno))

    # -- properties -----------------------------------------------------------------------------
    @property
    def path(self) -> str:
        return str(self._port.path)

    @property
    def baud(self) -> int:
        return int(self._port.baud)

    @property
    def is_open(self) -> bool:
        return bool(self._port.is_open)

    def fileno(self) -> int:
        return int(self._port.fd)

    @property
    def in_waiting(self) -> int:
        """Bytes received and not yet read."""
        n, status = self._port.input_waiting()
        self._check(status)
        return int(n)

    @property
    def out_waiting(self) -> int:
        """Bytes written and not yet taken by the other side."""
        n, status = self._port.output_waiting()
        self._check(status)
        return int(n)

    def set_baud(self, baud: int) -> None:
        self._check(self._port.set_baud(int(baud)))

    # -- transfers ------------------------------------------------------------------------------
    def start_reader(self, capacity: int = 64 << 20, trickle_bytes: int = 0,
                     trickle_wait: float = 0.0, realtime_priority: int = 0) -> None:
        """Read the port from now on on a thread of the compiled core, into a queue of up to
        ``capacity`` bytes (what would overflow it is dropped and counted in
        :attr:`reader_overflow`); :meth:`read` takes from the queue. After a read of fewer
        than ``trickle_bytes`` the thread waits ``trickle_wait`` seconds before the next one
        (a port written a byte at a time is then taken in chunks). With
        ``realtime_priority`` > 0 the thread runs under the real-time policy SCHED_FIFO at
        that priority where the system allows it (:attr:`reader_realtime`). Once per port."""
        if self._reader is not None:
            return
        reader = _core.serial.PortReader(self._port, int(capacity), int(trickle_bytes),
                                         int(round(float(trickle_wait) * 1000)),
                                         int(realtime_priority))
        self._check(reader.start())
        self._reader = reader

    @property
    def reader_realtime(self) -> bool:
        """True when the reading thread runs under SCHED_FIFO (root, CAP_SYS_NICE or an
        RLIMIT_RTPRIO allowed it); False under the ordinary policy or without one."""
        return bool(self._reader.realtime) if self._reader is not None else False

    @property
    def reader_peak(self) -> int:
        """The most bytes the reading thread held at once (0 without one)."""
        return int(self._reader.peak) if self._reader is not None else 0

    @property
    def reader_overflow(self) -> int:
        """Bytes the reading thread read and dropped, its queue full (0 without one)."""
        return int(self._reader.overflow) if self._reader is not None else 0

    def read(self, size: int = 4096, timeout: Optional[float] = None) -> bytes:
        """Wait up to ``timeout`` s (None: forever) for input; return 1..size bytes, or b"" on
        timeout. Raises PeerClosedError once the other end has closed and nothing is left."""
        if self._reader is not None:
            data, status = self._reader.take(int(size), _timeout(timeout))
            if not data:
                self._check(status, self._reader.last_error)
            return bytes(data)
        data, status = self._port.blocking_read_next(int(size), _timeout(timeout))
        if data:
            return bytes(data)
        self._check(status)
        return b""

    def read_exact(self, size: int, timeout: Optional[float] = None) -> bytes:
        """Read ``size`` bytes unless the timeout expires first (then fewer are returned)."""
        if self._reader is not None:
            raise SerialPortError("busy", f"{self.path}: read_exact while the port is read "
                                  f"on a thread of its own (start_reader); use read", 0)
        data, status = self._port.blocking_read(int(size), _timeout(timeout))
        if not data:
            self._check(status)
        return bytes(data)

    def read_nonblocking(self, size: int = 4096) -> bytes:
        """Return what has arrived, without waiting (possibly b"")."""
        if self._reader is not None:
            return self.read(size, 0.0)
        data, status = self._port.nonblocking_read(int(size))
        if data:
            return bytes(data)
        self._check(status)
        return b""

    def write(self, data: bytes, timeout: Optional[float] = None) -> int:
        """Write all of ``data`` unless the timeout expires; return the bytes written."""
        n, status = self._port.blocking_write(bytes(data), _timeout(timeout))
        self._check(status)
        return int(n)

    def write_nonblocking(self, data: bytes) -> int:
        """Write what the driver takes right now; return the bytes written (possibly 0)."""
        n, status = self._port.nonblocking_write(bytes(data))
        self._check(status)
        return int(n)

    def flush(self, *, input: bool = True, output: bool = True) -> None:  # noqa: A002
        """Discard unread input and/or unsent output."""
        self._check(self._port.flush(bool(input), bool(output)))

    def drain(self, timeout: Optional[float] = None) -> bool:
        """Wait until the output is taken; False if the timeout expired first."""
        status = self._port.drain(_timeout(timeout))
        self._check(status)
        return status == "ok"

    def close(self) -> None:
        if self._reader is not None:
            self._reader.stop()  # before the descriptor goes
        self._check(self._port.close())

    def __enter__(self) -> SerialPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "open" if self.is_open else "closed"
        return f"SerialPort({self.path!r}, baud={self.baud}, {state})"
