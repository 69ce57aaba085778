"""Simulating an experiment's cases and writing its result folder: the one pipeline every workflow
(``hinfnn run``, ``compare``, ``gallery``, ``reproduce``) goes through.

:func:`simulate_cases` builds each case's run (its scenario's objects, built once), simulates them
batched by compiled structure (:func:`hinfnn.sim.simulate_many`) and computes their metrics;
:func:`write_result` writes ``metrics.json``, the trajectories and ``scenario.toml`` into a folder;
:func:`result_folder` reserves the output folder before anything runs and puts the complete result
in place atomically (:mod:`hinfnn.io.folders`); :func:`check_memory` refuses what would not fit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from pathlib import Path
from typing import Callable

from .case import Case


@dataclasses.dataclass
class Outcome:
    """What simulating an experiment's cases gave: the cases, their trajectories, metrics (with
    any ``extra`` ones) and designed controllers, by case name, and the wall time."""

    cases: list[Case]
    trajectories: dict
    metrics: dict
    designs: dict
    seconds: float

    def entries(self) -> list[dict]:
        """The runs of ``metrics.json``, in case order."""
        from ..results import run_entry

        return [run_entry(c.name, self.trajectories[c.name], overrides=c.overrides, design=self.designs[c.name],
                          metrics=self.metrics[c.name], tags=self.trajectories[c.name].info.tags)
                for c in self.cases]

    def select(self, **tags) -> dict:
        """{name: Trajectory} of the cases whose tags have these values, in case order."""
        return {c.name: self.trajectories[c.name] for c in self.cases
                if all(self.trajectories[c.name].info.tags.get(k) == v for k, v in tags.items())}


def build_runs(cases: list[Case]) -> list:
    """The :class:`~hinfnn.sim.Run` of every case (each scenario's objects built once)."""
    return [c.run() for c in cases]


def simulate_cases(cases: list[Case], *, runs=None, progress=None, save_every: int | None = None, fields=None,
                   extra: Callable | None = None) -> Outcome:
    """Simulate the cases (``runs``: their :func:`build_runs` when already built), batched by
    compiled structure, and compute their metrics (``extra(traj, metrics)`` may add some).
    ``save_every`` overrides the runs' output interval for what is kept in memory (1: every step);
    ``fields`` what they store (None: everything)."""
    from ..metrics import compute_metrics
    from ..sim import simulate_many

    runs = build_runs(cases) if runs is None else runs
    t0 = time.perf_counter()
    trajs = simulate_many(runs, progress=progress, save_every=save_every, fields=fields)
    seconds = time.perf_counter() - t0
    metrics = {}
    controllers = {r.name: r.controller for r in runs}
    for name, traj in trajs.items():
        m = compute_metrics(traj)
        explain(m, controllers.get(name), traj)
        if extra is not None:
            extra(traj, m)
        metrics[name] = m
    designs = {r.name: r.controller.summary() for r in runs}
    return Outcome(cases=list(cases), trajectories=trajs, metrics=metrics, designs=designs, seconds=seconds)


def explain(m: dict, controller, traj) -> None:
    """Add to the notes of a run that did not do its job what its networks say about it
    (:func:`hinfnn.metrics.projection_notes`: weights held on their projection ball)."""
    from ..metrics import projection_notes

    v = m.get("verdict") or {}
    if controller is None or (v.get("contact_held") is not False and v.get("tracking_within_tolerance") is not False):
        return
    v["notes"] = list(v.get("notes", ())) + projection_notes(controller, traj)


def check_memory(runs, *, fields=None, log=print):
    """Refuse (:class:`hinfnn.resources.ResourceError`) runs whose stored samples would not fit in
    the available memory, saying how to store less; log the estimate before a run longer than a
    minute. Returns the plan."""
    from .. import resources

    plan = resources.plan(runs, fields=fields)
    resources.check(plan, alternatives=lambda: resources.plan(runs, fields="metrics"))
    if plan.seconds > 60:
        log(f"hinfnn: {plan.summary()}")
    return plan


def run_cases(cases: list[Case], folder: Path, base, *, command: str, runs=None, fields=None, progress=None,
              log=print, save_every: int | None = None, memory: bool = True, document: Callable | None = None,
              npz: str = "trajectory.npz", scenario_file: bool = True) -> tuple[Outcome, dict]:
    """An experiment's cases from their runs to their result folder, the one choreography of every
    workflow: build each case's run (``runs``: already built), refuse what would not fit in memory
    (:func:`check_memory`; ``memory=False``: the caller planned it), simulate them batched by
    compiled structure (:func:`simulate_cases`) and write ``folder`` (:func:`write_result` of the
    base scenario ``base``; ``document(outcome)`` returns entries added to ``metrics.json``).
    Returns the outcome and the metrics document."""
    runs = build_runs(cases) if runs is None else runs
    if memory:
        check_memory(runs, fields=fields, log=log)
    outcome = simulate_cases(cases, runs=runs, progress=progress, save_every=save_every, fields=fields)
    doc = write_result(folder, base, outcome, command=command, npz=npz, scenario_file=scenario_file,
                       extra=None if document is None else document(outcome))
    return outcome, doc


def write_result(folder: Path, base, outcome: Outcome, *, command: str, npz: str = "trajectory.npz",
                 save_interval: float | None = None, fields=None, extra: dict | None = None,
                 scenario_file: bool = True) -> dict:
    """Write an outcome into ``folder``: ``metrics.json`` (the results document of ``base`` with
    its runs, and ``extra`` entries), the trajectories (``npz``, decimated to ``save_interval``:
    default the base scenario's output interval; ``fields``: only these) and ``scenario.toml``
    (the base scenario). Returns the document."""
    from ..io import atomic_write_bytes, atomic_write_text, dumps_json, trajectory_npz_bytes
    from ..results import metrics_document

    doc = metrics_document(base, outcome.entries(), command=command)
    doc.update(extra or {})
    folder = Path(folder)
    atomic_write_text(folder / "metrics.json", dumps_json(doc))
    interval = base.simulation.output_interval if save_interval is None else save_interval
    atomic_write_bytes(folder / npz, trajectory_npz_bytes(outcome.trajectories, interval, fields=fields))
    if scenario_file:
        atomic_write_text(folder / "scenario.toml", base.to_toml())
    return doc


@dataclasses.dataclass
class Written:
    """Where a result folder went (``path``, after the block), why not where asked (``note``,
    logged when the folder was reserved) and why not where reserved (``moved``: files hinfnn did not
    write appeared there meanwhile; logged too)."""

    path: Path
    note: str | None = None
    moved: str | None = None


@contextlib.contextmanager
def result_folder(out, *, command: str, name: str, kind: str, force: bool = False, log=print,
                  command_line: str = ""):
    """Reserve the output folder of a command before anything runs (:func:`hinfnn.io.reserve_output`:
    ``out`` None is ``results/<command>s/<name>-<UTC time>``), yield a :class:`Written` whose
    ``path`` is a temporary folder to write into, and put the complete folder in place when the
    block ends (on an error or an interrupt the target is left as it was). After the block,
    ``path`` is where the result is."""
    from ..io import OutputFolder, reserve_output

    reservation = reserve_output(out, command=command, name=name, force=force)
    with reservation:
        if reservation.note:
            log(f"hinfnn: {reservation.note}")
        with OutputFolder(reservation, kind=kind, command=command_line) as folder:
            written = Written(path=folder.path, note=reservation.note)
            yield written
    written.path = Path(folder.moved_to or reservation.target)
    if folder.moved_to is not None:
        written.moved = (f"files hinfnn did not write appeared in {reservation.target} during the run; "
                         f"the result is in {folder.moved_to} instead")
        log(f"hinfnn: {written.moved}")


__all__ = ["Outcome", "build_runs", "simulate_cases", "check_memory", "explain", "run_cases", "write_result", "result_folder",
           "Written"]
