"""Signals for the ``hinfnn`` command, installed before anything heavy is imported.

Ctrl-C (SIGINT) raises :class:`KeyboardInterrupt` and SIGTERM raises :class:`Terminated`, at any
moment, JAX's import included, so that the command cleans up (no output folder is left half
written), prints one line and exits with 130 or 143. This module imports nothing but the standard
library: :func:`hinfnn.cli.main` installs the handlers as its first statement.

An exception raised inside the initialisation of a compiled extension module (NumPy's, jaxlib's)
turns into an ImportError or aborts the process (a C++ exception through nanobind), so a signal
that arrives while a module is being imported is held until the import is done (checked every
50 ms with SIGALRM) and raised then; if the import takes longer than :data:`HOLD_SECONDS` after
the signal, or a second signal comes, the command reports it and leaves at once
(``on_hard_exit``).
"""

from __future__ import annotations

import signal
import sys
import time

#: Exit codes of the ``hinfnn`` command (documented in ``hinfnn --help`` and docs/results.md).
EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143
#: Longest wait for an import to finish before a held signal ends the process anyway, s.
HOLD_SECONDS = 3.0
_RECHECK = 0.05


class Terminated(BaseException):
    """Raised from the SIGTERM handler so that cleanup runs as for Ctrl-C (a BaseException, like
    KeyboardInterrupt: ``except Exception`` blocks do not swallow it)."""


_pending: tuple[int, float] | None = None  # a signal held during an import: (signum, when)
#: Called with the signal number when a held signal cannot wait any longer (the CLI prints its
#: line and leaves with os._exit); None: raise it anyway.
on_hard_exit = None


def _in_import(frame) -> bool:
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


_delivered: int | None = None  # the last signal raised as an exception, until the command handles it


def _raise(signum):
    global _delivered
    _delivered = signum
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(f"terminated by signal {signum}")


def _give_up(signum):
    global _pending
    _pending = None
    with _suppress():
        signal.setitimer(signal.ITIMER_REAL, 0)
    if on_hard_exit is not None:
        on_hard_exit(signum)
    _raise(signum)


def handler(signum, frame):
    """The SIGINT/SIGTERM handler (also used by :class:`hinfnn.io.OutputFolder` for SIGTERM)."""
    global _pending
    if _pending is not None:  # a second signal while one is held: leave now
        _give_up(signum)
    if _in_import(frame) and signal.getsignal(signal.SIGALRM) is _alarm:
        _pending = (signum, time.monotonic())
        signal.setitimer(signal.ITIMER_REAL, _RECHECK)
        return
    _raise(signum)


def _alarm(signum, frame):
    global _pending
    if _pending is None:
        return
    held, since = _pending
    if _in_import(frame):
        if time.monotonic() - since < HOLD_SECONDS:
            signal.setitimer(signal.ITIMER_REAL, _RECHECK)
            return
        _give_up(held)
    _pending = None
    _raise(held)


def check() -> None:
    """Raise again a signal whose exception Python swallowed. The handler raises wherever the
    interpreter happens to be; inside a garbage-collection callback (JAX registers one) or a
    ``__del__``, Python prints "Exception ignored in ..." and goes on, so the command would finish
    as if never interrupted. The command calls this between steps of its work and before it puts
    a result in place."""
    global _delivered
    if _delivered is not None:
        signum, _delivered = _delivered, None
        _raise(signum)


def _unraisable(info) -> None:
    """sys.unraisablehook while the handlers are installed: our own KeyboardInterrupt or
    Terminated raised where Python cannot propagate it is kept for :func:`check` and not printed
    (the command prints its one line); anything else goes to the previous hook."""
    if _delivered is not None and info.exc_type in (KeyboardInterrupt, Terminated):
        return
    _previous_unraisable(info)


_previous_unraisable = sys.__unraisablehook__


class _suppress:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return exc[0] is not None and issubclass(exc[0], (ValueError, OSError))


def install() -> dict:
    """SIGINT -> KeyboardInterrupt, SIGTERM -> :class:`Terminated` (held during imports). A
    signal the process inherited as ignored (``nohup``, a background job of a script) stays
    ignored. Returns the previous handlers for :func:`restore` (empty outside the main thread,
    where handlers cannot be set)."""
    global _pending, _delivered, _previous_unraisable
    _pending = _delivered = None
    previous = {}
    if sys.unraisablehook is not _unraisable:
        _previous_unraisable = sys.unraisablehook
        sys.unraisablehook = _unraisable
    try:
        for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGALRM):
            old = signal.getsignal(signum)
            previous[signum] = old
            if signum != signal.SIGALRM and old is signal.SIG_IGN:
                continue
            signal.signal(signum, _alarm if signum == signal.SIGALRM else handler)
    except ValueError:  # not the main thread
        pass
    return previous


def ignore() -> None:
    """Ignore further SIGINT/SIGTERM (while the command reports an interrupt and leaves)."""
    global _pending, _delivered
    _pending = _delivered = None
    for signum in (signal.SIGINT, signal.SIGTERM):
        with _suppress():
            signal.signal(signum, signal.SIG_IGN)
    with _suppress():
        signal.setitimer(signal.ITIMER_REAL, 0)


def restore(previous: dict) -> None:
    global _pending, _delivered
    _pending = _delivered = None
    if sys.unraisablehook is _unraisable:
        sys.unraisablehook = _previous_unraisable
    with _suppress():
        signal.setitimer(signal.ITIMER_REAL, 0)
    for signum, handler in previous.items():
        with _suppress():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)
