"""A serial port for the host side of the link: termios in the compiled core.

Opens any tty, including the pseudo-terminal published by ``eskin-fw-sim`` (which
libserialport and most serial libraries cannot open), in raw mode::

    with SerialPort("/dev/pts/3") as port:
        port.write(encode_frame(CommandFrame(FrameType.START)))
        chunk = port.read(4096, timeout=0.1)     # b"" after 0.1 s of silence

A closed peer raises PeerClosedError instead of looking like silence; other failures raise
SerialPortError (an OSError) naming the port and the cause. Blocking calls release the GIL.
"""

from __future__ import annotations

import os
from typing import Optional

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
        self._check(self._port.open(os.fspath(path), int(baud)))

    # -- helpers --------------------------------------------------------------------------------
    def _check(self, status: str) -> None:
        if status in ("ok", "timeout"):
            return
        message = self._port.last_error or status
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
    def read(self, size: int = 4096, timeout: Optional[float] = None) -> bytes:
        """Wait up to ``timeout`` s (None: forever) for input; return 1..size bytes, or b"" on
        timeout. Raises PeerClosedError once the other end has closed and nothing is left."""
        data, status = self._port.blocking_read_next(int(size), _timeout(timeout))
        if data:
            return bytes(data)
        self._check(status)
        return b""

    def read_exact(self, size: int, timeout: Optional[float] = None) -> bytes:
        """Read ``size`` bytes unless the timeout expires first (then fewer are returned)."""
        data, status = self._port.blocking_read(int(size), _timeout(timeout))
        if not data:
            self._check(status)
        return bytes(data)

    def read_nonblocking(self, size: int = 4096) -> bytes:
        """Return what has arrived, without waiting (possibly b"")."""
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
        self._check(self._port.close())

    def __enter__(self) -> SerialPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "open" if self.is_open else "closed"
        return f"SerialPort({self.path!r}, baud={self.baud}, {state})"
