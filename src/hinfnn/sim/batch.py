"""Many runs at once: grouped by compiled structure, each group one ``vmap``-ed program."""

from __future__ import annotations

import dataclasses
from typing import Any

from .._pytree import structure_key
from .plan import DEFAULT_SAVE_INTERVAL, StepPlan
from .simulate import Limits, simulate, simulate_batch
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


def simulate_many(runs: list[Run], *, progress=None, save_every: int | None = None,
                  fields=None) -> dict[str, Trajectory]:
    """Simulate named runs, batching under ``vmap`` every group that shares a compiled program
    (same structure of plant, controller and reference, same simulation settings).

    Returns ``{name: Trajectory}`` in the order given. Runs that diverge are marked in their
    Trajectory's ``status``; they never stop the others. ``progress(steps_done, steps_total,
    what)`` is called after every compiled chunk (steps summed over all runs; ``what``: the names
    of the runs being simulated). A group of one
    runs without ``vmap`` (faster to trace and to run). ``save_every`` overrides the runs'
    ``save_interval`` for what is kept in memory.
    """
    groups: dict = {}
    for run in runs:
        groups.setdefault(run.group_key(), []).append(run)
    out: dict[str, Trajectory] = {}
    total = sum(r.n_steps for r in runs)
    finished = 0
    for items in groups.values():
        first = items[0]
        names = [r.name for r in items]

        def report(done, _total, _what="", names=names, base=finished, width=len(items)):
            if progress:
                progress(base + done * width, total, ", ".join(names))

        common = dict(t_final=first.t_final, dt=first.dt, control_period=first.control_period,
                      save_interval=first.save_interval, save_every=save_every, fields=fields,
                      bookkeeping=first.bookkeeping, progress=report if progress else None)
        if len(items) == 1:
            out[first.name] = simulate(first.plant, first.controller, first.reference, q0=first.q0,
                                       limits=first.limits, info=first.info, raise_on_failure=False, **common)
        else:
            traj = simulate_batch([r.plant for r in items], [r.controller for r in items],
                                  [r.reference for r in items], q0=[r.q0 for r in items],
                                  limits=[r.limits for r in items], infos=[r.info for r in items], **common)
            for j, r in enumerate(items):
                out[r.name] = traj.member(j)
        finished += first.n_steps * len(items)
    return {r.name: out[r.name] for r in runs}
