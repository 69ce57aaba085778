"""Signals for the ``hinfnn`` command, installed before anything heavy is imported.

Ctrl-C (SIGINT) raises :class:`KeyboardInterrupt` and SIGTERM raises :class:`Terminated`, at any
moment, JAX's import included, so that the command cleans up (no output folder is left half
written), prints one line and exits with 130 or 143. This module imports nothing but the standard
library: :func:`hinfnn.cli.main` installs the handlers as its first statement.
"""

from __future__ import annotations

import signal

#: Exit codes of the ``hinfnn`` command (documented in ``hinfnn --help`` and docs/results.md).
EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143


class Terminated(BaseException):
    """Raised from the SIGTERM handler so that cleanup runs as for Ctrl-C (a BaseException, like
    KeyboardInterrupt: ``except Exception`` blocks do not swallow it)."""


def _raise_terminated(signum, frame):
    raise Terminated(f"terminated by signal {signum}")


def install() -> dict:
    """SIGINT -> KeyboardInterrupt, SIGTERM -> :class:`Terminated`. Returns the previous
    handlers for :func:`restore` (empty outside the main thread, where handlers cannot be set)."""
    previous = {}
    try:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, signal.default_int_handler)
        previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not the main thread
        pass
    return previous


def ignore() -> None:
    """Ignore further SIGINT/SIGTERM (while the command reports an interrupt and leaves)."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(signum, signal.SIG_IGN)
        except ValueError:
            pass


def restore(previous: dict) -> None:
    for signum, handler in previous.items():
        try:
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)
        except ValueError:
            pass
