"""Waiting for an event in a test: a condition polled until it holds, or a deadline.

No test waits a fixed time for something to happen (a process to start, bytes to arrive, a
peer to read what it was sent): it waits for the thing itself, with a deadline that only a
failure reaches (tests/python/test_test_hygiene.py keeps it so)."""

from __future__ import annotations

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

