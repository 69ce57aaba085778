"""The ``hinfnn`` command: argument parsing and printing only; the work is in the library. One module
per command (``hinfnn.cli.run`` for ``hinfnn run`` ...), the parser in :mod:`hinfnn.cli._parser`.

Exit codes: 0 success; 2 user error (bad scenario, bad override, infeasible design, bad or busy
output folder, not enough memory, unreadable result) with a one-line message; 1 anything else
(including a run that diverged); 130 interrupted (Ctrl-C, SIGINT); 143 terminated (SIGTERM).
``--debug`` shows tracebacks. Python warnings are printed as one line ``hinfnn: warning: ...``.

Nothing heavy is imported at module level: :func:`main` installs the signal handlers first, so
Ctrl-C or SIGTERM while JAX loads ends the command like at any other moment. The ``hinfnn``
program also tunes its own process (:func:`program_gc`, :func:`fast_exit`).
"""

from __future__ import annotations

from .. import _signals  # noqa: I001  (first: nothing else to import before the handlers)

import importlib
import os
import sys

from ._parser import _parser

#: Command name -> (module of hinfnn.cli, function).
COMMANDS = {"run": ("run", "main"), "reproduce": ("reproduce", "main"), "design": ("design", "main"),
            "compare": ("compare", "main"), "gallery": ("gallery", "main"), "sweep": ("sweep", "main"),
            "show": ("results", "show"), "plot": ("results", "plot"), "export": ("results", "export"),
            "keys": ("info", "keys"), "scenarios": ("info", "scenarios"), "cache": ("info", "cache"),
            "robot": ("robot", "main")}


def _command(name: str):
    module, fn = COMMANDS[name]
    return getattr(importlib.import_module(f".{module}", __name__), fn)


def _interrupted_exit(code: int, argv) -> int:
    """An interrupt that arrives while XLA compiles leaves its compiler threads running, and
    interpreter finalisation then crashes (SIGSEGV). The output is already cleaned up: a program
    run (argv None) leaves at once; an in-process call returns the code."""
    if argv is None:
        import os

        sys.stdout.flush()
        sys.stderr.flush()
        mp = sys.modules.get("multiprocessing.util")
        if mp is not None:  # a sweep's worker processes: their semaphores released, as a normal exit does
            mp._run_finalizers(0)
        os._exit(code)
    return code


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    """``warnings.showwarning`` of the command: ``hinfnn: warning: TEXT`` on one line, without the
    source file and line a user cannot act on."""
    text = " ".join(str(message).split())
    text = text.removeprefix("hinfnn: ").removeprefix("warning: ")
    try:
        print(f"hinfnn: warning: {text}", file=file or sys.stderr)
    except (OSError, ValueError):
        pass


def main(argv=None) -> int:
    # First: Ctrl-C / SIGTERM from here on, JAX's import included, end the command cleanly.
    previous = _signals.install()
    import warnings

    saved_showwarning = warnings.showwarning
    warnings.showwarning = _one_line_warning
    if argv is None:  # a program: a signal held too long during an import ends it at once
        _signals.on_hard_exit = _hard_exit
        program_gc()
    box: dict = {}
    try:
        code = _main(argv, box)
    except KeyboardInterrupt as err:
        _signals.ignore()  # a second Ctrl-C while leaving changes nothing
        print(f"hinfnn: interrupted; {getattr(err, 'hinfnn_note', 'no output was written')}", file=sys.stderr)
        return _interrupted_exit(_signals.EXIT_INTERRUPTED, argv)
    except _signals.Terminated as err:
        _signals.ignore()
        print(f"hinfnn: terminated; {getattr(err, 'hinfnn_note', 'no output was written')}", file=sys.stderr)
        return _interrupted_exit(_signals.EXIT_TERMINATED, argv)
    finally:
        trace = getattr(box.get("args"), "startup_trace", None)
        if trace is not None:
            trace.close()
        warnings.showwarning = saved_showwarning
        _signals.on_hard_exit = None
        _signals.restore(previous)
    if argv is None and "jax" in sys.modules:  # a program that loaded JAX: skip the interpreter's teardown
        fast_exit(code if isinstance(code, int) else 1)
    return code


# --- the process --------------------------------------------------------------------------------

#: Python's garbage-collector thresholds in the ``hinfnn`` program; the default is (700, 10, 10).
#: Importing JAX and tracing a program allocate millions of short-lived objects, and each collection
#: walks them (docs/performance.md: ``python benchmarks/run.py --cases program_gc``).
#: ``HINFNN_DEFAULT_GC=1`` keeps Python's default (the benchmark's A/B). :func:`main` called from
#: Python keeps Python's default.
PROGRAM_GC_THRESHOLD = (100_000, 50, 100)


def program_gc() -> None:
    """Set :data:`PROGRAM_GC_THRESHOLD` (the ``hinfnn`` program calls it first, before JAX is
    imported)."""
    import gc

    if os.environ.get("HINFNN_DEFAULT_GC") != "1":
        gc.set_threshold(*PROGRAM_GC_THRESHOLD)


def fast_exit(code: int) -> None:
    """End the ``hinfnn`` program now with ``code``: flush stdout and stderr, run the ``atexit``
    handlers, then ``os._exit``, skipping the interpreter's teardown of JAX, XLA and matplotlib
    objects (docs/performance.md). ``HINFNN_SLOW_EXIT=1`` returns instead."""
    if os.environ.get("HINFNN_SLOW_EXIT") == "1":
        return
    import atexit

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more can be said there
            pass
    os._exit(code)


def _hard_exit(signum: int) -> None:
    import os
    import signal

    _signals.ignore()
    word = "interrupted" if signum == signal.SIGINT else "terminated"
    print(f"hinfnn: {word}; no output was written", file=sys.stderr)
    sys.stderr.flush()
    os._exit(_signals.EXIT_INTERRUPTED if signum == signal.SIGINT else _signals.EXIT_TERMINATED)


def _main(argv, box: dict) -> int:
    parser = _parser()
    args = box["args"] = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        if args.command not in ("keys", "scenarios", "show", "plot", "export"):
            from .._config import configure

            # a robot loop's process runs every compiled call on its own thread (docs/robot.md)
            configure(async_dispatch=False if args.command == "robot" else None)
        if args.command == "run":
            from .._startup import StartupTrace

            args.startup_trace = StartupTrace.from_env()
        return _command(args.command)(args)
    except (KeyboardInterrupt, _signals.Terminated):
        raise
    except BrokenPipeError:  # `hinfnn export DIR --csv --out - | head`: the reader has left
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # no second error when Python flushes stdout at exit
        return 1
    except BaseException as err:  # noqa: BLE001 - the CLI's last line of defence
        if isinstance(err, SystemExit):
            raise
        from ..errors import ConfigError, DesignError, LoadError

        if getattr(args, "debug", False):
            raise
        if isinstance(err, (ConfigError, DesignError, LoadError)):
            kind = type(err).__name__
            text = "\\n".join(str(err).splitlines())
            print(f"hinfnn: {kind}: {text}", file=sys.stderr)
            return 2
        text = " ".join(str(err).split())
        print(f"hinfnn: error: {type(err).__name__}: {text} (run with --debug for the traceback)", file=sys.stderr)
        return 1

