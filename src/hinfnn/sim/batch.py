"""Many runs at once: grouped by compiled structure, each group one ``vmap``-ed program."""

from __future__ import annotations

import concurrent.futures
import contextvars
import dataclasses
import os
import threading
from typing import Any

from .._pytree import structure_key
from ..errors import ConfigError, is_integer
from .plan import DEFAULT_SAVE_INTERVAL, StepPlan
from .simulate import Limits, RunProgram, simulate, simulate_batch
from .trajectory import RunInfo, Trajectory


@dataclasses.dataclass(frozen=True)
class Run:
    """One run to simulate: the objects and the options of :func:`~hinfnn.sim.simulate`."""

    name: str
    plant: Any
    controller: Any
    reference: Any
    q0: Any
    t_final: float
    dt: float
    control_period: float | None = None
    save_interval: float = DEFAULT_SAVE_INTERVAL
    limits: Limits = Limits()
    info: RunInfo = RunInfo()
    bookkeeping: bool = True  # the theorems' bookkeeping integrated (simulate's ``bookkeeping``)

    def plan(self, save_every: int | None = None) -> StepPlan:
        """The run's :class:`~hinfnn.sim.plan.StepPlan` (``save_every`` overrides the output
        interval)."""
        return StepPlan.make(self.t_final, self.dt, control_period=self.control_period,
                             save_interval=self.save_interval, save_every=save_every, discrete=self.plant.discrete)

    @property
    def n_steps(self) -> int:
        return self.plan().n_steps

    def group_key(self):
        """Runs with equal keys share one compiled program (and run as one batch): the pytree
        structure AND every leaf's shape and dtype (two networks of different sizes have the same
        structure but cannot be stacked), and the simulation settings."""
        return (*structure_key((self.plant, self.controller, self.reference, self.limits)), self.t_final, self.dt,
                self.control_period, self.save_interval, self.bookkeeping)


#: Most groups whose programs :func:`simulate_many` compiles at once (about 1-3 GB of memory each
#: while XLA compiles a 7-DOF arm's).
MAX_WORKERS = 8


def default_workers(groups: int) -> int:
    """How many groups' programs :func:`simulate_many` compiles at once by default: one per core this
    process may run on (``os.sched_getaffinity``), at most :data:`MAX_WORKERS` and the groups."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_WORKERS, groups))


class _Cancelled(Exception):
    """A group stopped between two chunks because another failed or the caller was interrupted."""


def simulate_many(runs: list[Run], *, progress=None, save_every: int | None = None,
                  fields=None, workers: int | None = None) -> dict[str, Trajectory]:
    """Simulate named runs, batching under ``vmap`` every group that shares a compiled program
    (same structure of plant, controller and reference, same simulation settings).

    Returns ``{name: Trajectory}`` in the order given. Runs that diverge are marked in their
    Trajectory's ``status``; they never stop the others. ``progress(steps_done, steps_total,
    what)`` is called after every compiled chunk (steps summed over all runs; ``what``: the names
    of the runs being simulated). A group of one
    runs without ``vmap`` (faster to trace and to run). ``save_every`` overrides the runs'
    ``save_interval`` for what is kept in memory.

    The groups' programs (each group its own) are compiled at once by ``workers`` threads
    (default :func:`default_workers`: one per core; 1: each group compiled and run after the
    other): XLA compiles without Python's lock, so while one group runs or compiles the next
    compiles. The groups still run one at a time (:data:`_RUNNING`). The numbers are the same bit for
    bit as compiled one after the other. Each thread runs in a copy of the caller's
    context (:mod:`contextvars`). If a group fails or the caller is interrupted,
    the others stop after their current chunk (a compile in progress finishes first) and the error
    is raised.
    """
    groups: dict = {}
    for run in runs:
        groups.setdefault(run.group_key(), []).append(run)
    total = sum(r.n_steps for r in runs)
    jobs = [(items, sum(r.n_steps for r in items)) for items in groups.values()]
    if workers is not None and (not is_integer(workers) or workers < 1):
        raise ConfigError(f"must be a whole number of threads >= 1 (or None: one per core), got {workers!r}",
                          key="workers")
    workers = None if workers is None else int(workers)
    n_workers = default_workers(len(jobs)) if workers is None else min(workers, len(jobs))
    out: dict[str, Trajectory] = {}
    if n_workers == 1:
        finished = 0
        for items, steps in jobs:
            names = [r.name for r in items]

            def report(done, _total, _what="", names=names, base=finished, width=len(items)):
                progress(base + done * width, total, ", ".join(names))

            out.update(_simulate_group(items, save_every, fields, report if progress else None))
            finished += steps
    else:
        out.update(_simulate_groups(jobs, total, n_workers, save_every, fields, progress))
    return {r.name: out[r.name] for r in runs}


def _simulate_group(items: list[Run], save_every, fields, report) -> dict[str, Trajectory]:
    """One group: its runs as one program (a single run without ``vmap``)."""
    first = items[0]
    common = dict(t_final=first.t_final, dt=first.dt, control_period=first.control_period,
                  save_interval=first.save_interval, save_every=save_every, fields=fields,
                  bookkeeping=first.bookkeeping, progress=report)
    if len(items) == 1:
        return {first.name: simulate(first.plant, first.controller, first.reference, q0=first.q0,
                                     limits=first.limits, info=first.info, raise_on_failure=False, **common)}
    traj = simulate_batch([r.plant for r in items], [r.controller for r in items],
                          [r.reference for r in items], q0=[r.q0 for r in items],
                          limits=[r.limits for r in items], infos=[r.info for r in items], **common)
    return {r.name: traj.member(j) for j, r in enumerate(items)}


def _lower_group(items: list[Run], save_every, fields):
    """The chunk program :func:`_simulate_group` will call first, lowered (None: not kept)."""
    first = items[0]
    return RunProgram.lower_ahead_batch([r.plant for r in items], [r.controller for r in items],
                                        [r.reference for r in items], q0=[r.q0 for r in items],
                                        limits=[r.limits for r in items], t_final=first.t_final, dt=first.dt,
                                        control_period=first.control_period, save_interval=first.save_interval,
                                        save_every=save_every, fields=fields, bookkeeping=first.bookkeeping)


def _simulate_groups(jobs, total, n_workers, save_every, fields, progress) -> dict[str, Trajectory]:
    """The groups by ``n_workers`` threads, each in a copy of the caller's context: each group's
    program compiled while the others compile or run (:func:`_lower_group` under :data:`_RUNNING`,
    then ``.compile()`` outside any lock), the groups run one at a time (:data:`_RUNNING`); ``progress``
    called with the steps of every group summed and the names of the runs simulating."""
    lock = threading.Lock()  # the progress sums
    stop = threading.Event()
    done = [0] * len(jobs)
    running: dict[int, str] = {}

    def report_for(g, width):
        def report(d, _total, _what=""):
            if stop.is_set():
                raise _Cancelled
            if progress is None:
                return
            with lock:
                done[g] = d * width
                what = ", ".join(running.values())
            progress(sum(done), total, what)

        return report

    def work(g, items):
        with _RUNNING:  # tracing and lowering (Python's work) and the arrays it makes, one at a time
            if stop.is_set():
                raise _Cancelled
            lowered = _lower_group(items, save_every, fields)
        if lowered is not None:  # its program compiled now, while another group compiles or runs
            lowered.compile()
        with _RUNNING:
            if stop.is_set():
                raise _Cancelled
            with lock:
                running[g] = ", ".join(r.name for r in items)
            try:
                return _simulate_group(items, save_every, fields, report_for(g, len(items)))
            finally:
                with lock:
                    running.pop(g, None)

    out: dict[str, Trajectory] = {}
    pool = concurrent.futures.ThreadPoolExecutor(n_workers, thread_name_prefix="hinfnn-group")
    try:
        futures = [pool.submit(contextvars.copy_context().run, work, g, items) for g, (items, _) in enumerate(jobs)]
        for f in concurrent.futures.as_completed(futures):
            out.update(f.result())  # the first error (or an interrupt while waiting) ends the wait
    except BaseException:
        stop.set()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
    return out


#: Held while a group of :func:`simulate_many` runs (and while one's program is lowered): one
#: program at a time executes. Two programs executing at once from two threads of one process hung
#: XLA's CPU runtime (a UR5 batch in groups on two threads, 2 of 3 tries; docs/performance.md);
#: XLA's compiler, which the threads run side by side, is not its runtime.
_RUNNING = threading.RLock()
