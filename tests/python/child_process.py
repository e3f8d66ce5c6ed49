"""Helpers for tests that start a child process and signal it."""

from __future__ import annotations

import signal


def interruptible() -> None:
    """``preexec_fn`` of a child that a test interrupts with SIGINT: Ctrl-C's default action,
    as in a terminal. A test run started in the background by a non-interactive shell (``make
    test &``, many CI runners) inherits SIGINT ignored, and Python keeps an inherited SIG_IGN:
    the child would then raise no KeyboardInterrupt and run on."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
