"""What the commands share: the progress display, the command line as typed, small parsers of
option values."""

from __future__ import annotations

import sys
import time

from .. import _signals


class Progress:
    """Progress on stderr with an ETA, never with ``--quiet``: the progress callback of every
    workflow, ``progress(done, total, what)`` (``what``: the runs of the chunk being simulated). On a
    terminal: a tqdm bar (steps done, rate, time left) once a run has lasted 3 s; otherwise (a log
    file, a pipe) one line every 10 s, ``LABEL: 12.0 % (10 s, about 73 s left)``. The time left is
    the steps left at the rate since the part's first call, which comes after its first chunk:
    the tracing and compiling before that chunk (most of an arm's first minute) would otherwise be
    taken for the pace of the run (a short run would say minutes left with seconds to go); until
    a second call there is no estimate. A call with another total starts a new part of the work
    (its own bar, rate and time left)."""

    def __init__(self, quiet: bool, label: str, stream=None):
        self.quiet = quiet
        self.label = label
        self.stream = stream or sys.stderr
        self.bar = None
        self.t0 = time.perf_counter()
        self.last = 0.0
        self.total = None
        self.first = None  # (steps, time) at the part's first call: where its rate is measured from
        self.shown = None  # (steps, total) of the last line: the end of a part is said once
        try:
            self.tty = self.stream.isatty()
        except (AttributeError, ValueError):
            self.tty = False

    def __call__(self, done: int, total: int, what: str = ""):
        _signals.check()  # between chunks: a signal swallowed inside a callback ends the command here
        if self.quiet:
            return
        if self.total is not None and total != self.total:  # a new part of the work (its own total)
            self.stage(self.label)
        self.total = total
        if self.tty:
            self._bar(done, total, what)
            return
        now = time.perf_counter()
        if self.first is None:
            self.first = (done, now)
        elapsed = now - self.t0
        if elapsed < 3.0 or (now - self.last < 10.0 and done < total) or self.shown == (done, total):
            return
        self.shown = (done, total)
        self.last = now
        frac = done / max(total, 1)
        steps, since = done - self.first[0], now - self.first[1]
        eta = ""
        if steps > 0 and since > 0 and done < total:
            eta = f", about {_duration((total - done) * since / steps)} left"
        msg = f"{self.label}: {100 * frac:5.1f} %  ({_duration(elapsed)}{eta})"
        if what:
            msg += f"  [{what}]"
        print(msg, file=self.stream, flush=True)

    def _bar(self, done, total, what):
        if self.bar is None:
            from tqdm import tqdm

            # from the steps done by the first call (its chunk's compile is not the run's pace)
            self.bar = tqdm(total=total, initial=done, desc=self.label, unit="step", unit_scale=True, delay=3.0,
                            file=self.stream, leave=False, dynamic_ncols=True, mininterval=0.5)
        if what:
            self.bar.set_postfix_str(what[:40], refresh=False)
        self.bar.update(done - self.bar.n)

    def done(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def stage(self, label: str):
        """A new part of the work with its own steps (its own bar, rate and time left)."""
        self.done()
        self.label = label
        self.t0 = time.perf_counter()
        self.last = 0.0
        self.total = None
        self.first = None
        self.shown = None


def _duration(seconds: float) -> str:
    from ..resources import duration

    return duration(seconds)


def command_line(args) -> str:
    """The command as the user typed it (for the files that record how they were made)."""
    import shlex

    return "hinfnn " + " ".join(shlex.quote(a) for a in getattr(args, "argv", []))


def log_stderr(message: str) -> None:
    print(message, file=sys.stderr)


def fields_option(text: str):
    """``--fields``: all -> None, metrics -> "metrics", else the names (checked: ConfigError keyed
    ``--fields``)."""
    from ..errors import ConfigError
    from ..sim.recorder import select

    text = text.strip()
    if text in ("all", ""):
        return None
    fields = "metrics" if text == "metrics" else [f.strip() for f in text.split(",") if f.strip()]
    try:
        select(fields)  # unknown names: before anything runs
    except ConfigError as err:
        raise ConfigError(str(err).removeprefix("fields: "), key="--fields") from None
    return fields


def zoom_option(text: str | None):
    """``--zoom A0:A1,B0:B1`` -> [(A0, A1), (B0, B1)]."""
    if text is None:
        return None
    from ..errors import ConfigError

    try:
        windows = [tuple(float(x) for x in part.split(":")) for part in text.split(",")]
    except ValueError:
        windows = []
    if len(windows) != 2 or any(len(w) != 2 or not w[0] < w[1] for w in windows):
        raise ConfigError(f"must be two time windows START:END,START:END with START < END, got {text!r}",
                          key="--zoom")
    return windows


def size_text(n: int) -> str:
    """Bytes for people: ``512 B``, ``473.5 kB``, ``1.2 MB``."""
    from ..resources import size

    return size(n)
