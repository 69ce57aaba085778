"""Helpers for tests that start hinfnn as a child process."""

from __future__ import annotations

import contextlib
import signal


@contextlib.contextmanager
def interruptible():
    """A child started inside gets Ctrl-C at its default, as from a terminal. A suite started in the
    background without job control (``(make test &)``) has SIGINT ignored, which its children
    inherit and hinfnn keeps, as background jobs should; a handler is not inherited across exec,
    so one is set while the child starts (not ``preexec_fn``: Python code between fork and exec
    in a multithreaded process, which JAX warns may deadlock)."""
    old = signal.getsignal(signal.SIGINT)
    if old is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        if old is signal.SIG_IGN:
            signal.signal(signal.SIGINT, old)
