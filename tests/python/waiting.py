"""Waiting for an event in a test: a condition polled until it holds, or a deadline.

No test waits a fixed time for something to happen (a process to start, bytes to arrive, a
peer to read what it was sent): it waits for the thing itself, with a deadline that only a
failure reaches (tests/python/test_test_hygiene.py keeps it so)."""

from __future__ import annotations

import fcntl
import os
import select
import struct
import termios
import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def wait_until(condition: Callable[[], T], *, timeout: float = 60.0, what: str = "the event",
               interval: float = 0.01, required: bool = True) -> T:
    """``condition()`` called until it returns a true value, which is returned. Past
    ``timeout`` seconds: AssertionError naming ``what`` (``required=False``: its last false
    value)."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            if required:
                raise AssertionError(f"waited {timeout:g} s for {what}: it did not happen")
            return value
        time.sleep(interval)  # the poll interval of this wait


def unread_bytes(tty: str) -> int:
    """The bytes written to a pseudo-terminal that its reader has not read yet (FIONREAD on
    the terminal ``tty``, a path to it or to a link to it). A write to the other end reaches
    the terminal's input queue through the kernel's flip buffer, asynchronously; a poll of the
    terminal pushes what is pending there first (n_tty_poll), so bytes just written are counted
    too."""
    fd = os.open(tty, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        readable, _, _ = select.select([fd], [], [], 0)
        n = struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
        return max(n, 1) if readable else n
    finally:
        os.close(fd)


def wait_until_read(tty: str, *, timeout: float = 60.0) -> None:
    """Waits until the reader of ``tty`` has taken every byte written to it (before the
    writer closes its end, which would throw the rest away)."""
    wait_until(lambda: unread_bytes(tty) == 0, timeout=timeout,
               what=f"the reader of {tty} to take what was written to it")
