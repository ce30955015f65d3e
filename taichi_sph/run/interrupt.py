"""Ctrl-C during a run: SIGINT calls a function (the time loop sets its `interrupted` flag, then stops at the
next step, checkpoints and exits 130) instead of raising KeyboardInterrupt mid-kernel; the previous handler
comes back afterwards."""

from __future__ import annotations

import signal
from contextlib import contextmanager


@contextmanager
def sigint_calls(on_interrupt):
    """Inside the block SIGINT calls `on_interrupt()` (outside the main thread nothing changes)."""
    old_handler = signal.getsignal(signal.SIGINT)

    def on_sigint(signum, frame):
        on_interrupt()

    try:
        signal.signal(signal.SIGINT, on_sigint)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        try:
            signal.signal(signal.SIGINT, old_handler)
        except ValueError:
            pass
