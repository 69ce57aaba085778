"""Opt-in startup timing for ``hinfnn run`` (``HINFNN_TRACE_STARTUP=1``), read by
``benchmarks/startup.py``: where the time to the first simulated step goes."""

from __future__ import annotations

import math
import sys
import time

TRACE_ENV = "HINFNN_TRACE_STARTUP"

#: The trace of this process while ``hinfnn run`` traces (None otherwise), for :func:`mark`.
ACTIVE: StartupTrace | None = None


def mark(name: str) -> None:
    """Record a named point on the active trace (``simulated``, ``files_written``, ...); a no-op
    when nothing traces."""
    if ACTIVE is not None:
        ACTIVE.mark(name)


def _process_age() -> float | None:
    """Seconds since this process started (Linux: /proc/self/stat start time against
    CLOCK_BOOTTIME, the clock it is counted in; resolution one clock tick, 10 ms). None elsewhere."""
    import os

    try:
        with open("/proc/self/stat", "rb") as f:
            stat = f.read()
        start_ticks = int(stat[stat.rindex(b")") + 2:].split()[19])  # field 22, starttime
        return time.clock_gettime(time.CLOCK_BOOTTIME) - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def _covered(spans) -> float:
    """Total length of the union of (start, end) intervals (nested ones count once)."""
    total, end = 0.0, -math.inf
    for a, b in sorted(spans):
        if b <= end:
            continue
        total += b - max(a, end)
        end = b
    return total


class StartupTrace:
    """Where the time to the first simulated step goes, printed to stderr for benchmarks.

    Opt-in with ``HINFNN_TRACE_STARTUP=1`` (``hinfnn run`` only). Right after the first compiled
    chunk of steps returns, one line::

        hinfnn-startup: first-chunk <seconds since process start> {json}

    (seconds from /proc, None where there is no /proc), and when the run is done::

        hinfnn-startup: done {json}

    The JSON gives seconds since :func:`main` was entered (``since_main``; everything before it is
    interpreter start and ``import hinfnn``: ``age_at_main``), the points ``imports_done`` and
    ``scenario_loaded`` (seconds since main), and JAX's own time spans
    (``jax.monitoring``) between main and the first chunk, each counted once even when nested:
    ``compile`` (XLA compilation or loading from the persistent cache, ``cache_load`` of it),
    ``lower`` (jaxpr → StableHLO, outside compile) and ``trace`` (Python → jaxpr, outside both),
    with the number of programs (``programs``) and persistent cache hits, the names of the
    functions traced (``traced``: the run's chunk program is not among them when it was kept,
    :mod:`hinfnn._programs`), and the CPU time of
    the process so far, all threads (``cpu``: tells a slow start from a busy machine). ``done`` adds
    ``chunk`` (wall time of the second chunk alone: what running a chunk costs once compiled), the
    points marked after the first chunk (``simulated``, ``files_written``, ``figures_written``:
    seconds since main, see :func:`mark`) and the CPU time at the end (``cpu``).
    """

    _NAMES = {"/jax/core/compile/jaxpr_trace_duration": "trace",
              "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
              "/jax/core/compile/backend_compile_duration": "compile"}

    def __init__(self):
        import jax.monitoring as mon

        self.t_main = time.time()
        self.age_at_main = _process_age()
        self.spans: dict[str, list] = {v: [] for v in self._NAMES.values()}
        self.cache_load = 0.0
        self.cache_hits = 0
        self.traced: set[str] = set()
        self.marks: dict[str, float] = {}
        self.first: dict | None = None
        self.chunk_times: list[float] = []
        mon.register_event_time_span_listener(self._on_span)
        mon.register_event_duration_secs_listener(self._on_duration)
        mon.register_event_listener(self._on_event)

    @classmethod
    def from_env(cls) -> StartupTrace | None:
        """A trace (and the :data:`ACTIVE` one) when ``HINFNN_TRACE_STARTUP`` asks for it, else None."""
        import os

        global ACTIVE
        if os.environ.get(TRACE_ENV, "").strip() in ("", "0"):
            return None
        ACTIVE = cls()
        return ACTIVE

    def _on_span(self, event, start, end, **_):
        name = self._NAMES.get(event)
        if name is not None:
            self.spans[name].append((start, end))

    def _on_duration(self, event, seconds, **kw):
        if event == "/jax/compilation_cache/cache_retrieval_time_sec":
            self.cache_load += seconds
        elif event == "/jax/core/compile/jaxpr_trace_duration" and kw.get("fun_name"):
            self.traced.add(str(kw["fun_name"]))

    def _on_event(self, event, **_):
        if event == "/jax/compilation_cache/cache_hits":
            self.cache_hits += 1

    def mark(self, name: str):
        """Seconds since main at a named point (e.g. ``scenario_loaded``)."""
        self.marks[name] = time.time() - self.t_main

    def wrap(self, progress):
        """``progress`` that also records the first chunks (called after each chunk)."""

        def traced(done, total, what=""):
            self.chunk_times.append(time.time())
            if len(self.chunk_times) == 1:
                self._first_chunk()
            progress(done, total, what)

        return traced

    def _first_chunk(self):
        import json

        now = self.chunk_times[0]
        age = _process_age()
        clip = {k: [(max(a, self.t_main), min(b, now)) for a, b in v if b > self.t_main and a < now]
                for k, v in self.spans.items()}
        c = _covered(clip["compile"])
        lc = _covered(clip["compile"] + clip["lower"])
        tlc = _covered(clip["compile"] + clip["lower"] + clip["trace"])
        self.first = dict(since_main=now - self.t_main, age_at_main=self.age_at_main, **self.marks,
                          trace=tlc - lc, lower=lc - c, compile=c, cache_load=self.cache_load,
                          cache_hits=self.cache_hits, programs=len(clip["compile"]),
                          traced=sorted(self.traced), cpu=time.process_time())
        print(f"hinfnn-startup: first-chunk {'None' if age is None else f'{age:.4f}'} "
              f"{json.dumps(self.first)}", file=sys.stderr, flush=True)

    def done(self):
        import json

        t = self.chunk_times
        info = dict(chunk=(t[1] - t[0]) if len(t) > 1 else None, chunks=len(t),
                    total_since_main=time.time() - self.t_main, cpu=time.process_time(),
                    **{k: v for k, v in self.marks.items() if k not in (self.first or {})})
        print(f"hinfnn-startup: done {json.dumps(info)}", file=sys.stderr, flush=True)

    def close(self):
        """Stop listening to JAX (matters when :func:`main` is called in-process)."""
        import jax.monitoring as mon

        global ACTIVE
        if ACTIVE is self:
            ACTIVE = None
        mon.unregister_event_time_span_listener(self._on_span)
        mon.unregister_event_duration_listener(self._on_duration)
        mon.unregister_event_listener(self._on_event)
