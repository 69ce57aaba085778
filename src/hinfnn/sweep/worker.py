"""A sweep's work, one piece at a time: a run's scenario from the base and the draw's values, the
checks that decide whether a run is valid, the batches of equal compiled structure, and one batch
run as one :func:`hinfnn.simulate_batch` call with its table rows. What a backend
(:mod:`hinfnn.sweep.backends`) runs in this process or on a Ray worker.

1. **Check.** Every run's scenario is built from the base scenario and the run's values and
   checked (:meth:`hinfnn.scenario.Scenario.check`: start pose, RK4 step against the contact,
   controller design ...). A run that fails is a row with status ``"invalid"``, the error's
   text and key; it is never simulated.
2. **Plan.** The valid runs are grouped by compiled structure (the pytree structure and leaf
   shapes of plant, controller, reference and limits, and the simulation settings: what
   :func:`hinfnn.simulate_batch` compiles one program for) and each group is cut into batches of
   equal size (the last one padded with a copy of its last member, whose result is dropped), so
   that a group compiles once. The batch size is capped by memory (the stored ``"metrics"``
   fields of every member, :func:`batch_cap`) and by ``max_batch``.
3. **Run.** Each batch is one :func:`hinfnn.simulate_batch` call (``fields="metrics"``), its
   members' metrics by :func:`hinfnn.compute_metrics` (partial up to t_fail for a member that
   stopped: status ``"diverged"``, ``t_fail`` and the reason).
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import math
import os
import socket
import time
from typing import Callable

import numpy as np

from ..errors import HinfnnError
from ..status import RunStatus
from .sampling import RunSpec
from .spec import PER_COORDINATE_METRICS

#: Largest batch by default: past a few hundred members the throughput gains little on one core
#: (docs/performance.md; larger batches gain only where XLA spreads their kernels over the
#: cores that the local backend's workers already use) and a killed sweep loses at most one batch
#: per worker.
DEFAULT_MAX_BATCH = 256
#: Fraction of the available memory a batch may hold.
MEMORY_FRACTION = 0.5
#: Draws checked per task (ray backend) or per progress update.
CHECK_CHUNK = 64
#: Errors that make a run "invalid" rather than stopping the sweep.
INVALID_ERRORS = (HinfnnError, ValueError, ArithmeticError, np.linalg.LinAlgError)


# --- building one run --------------------------------------------------------------------------------


def scenario_of(base: dict, source: str, values: dict, kinds):
    """The (unchecked) scenario of a draw: the base scenario with the draw's values and the
    controller kind(s)."""
    from ..scenario import Scenario

    items = list(values.items()) + [("controller.kind", kinds if isinstance(kinds, str) else list(kinds))]
    return Scenario.from_dict(base, items, source=source, check=False)


def compile_key(run) -> str:
    """What decides the compiled program of a run (:meth:`hinfnn.sim.batch.Run.group_key`: pytree
    structure and leaf shapes/dtypes of plant, controller, reference and limits, and the simulation
    settings) as a short hash, of the same text as before the key was shared."""
    treedef, shapes, *settings = run.group_key()
    text = repr((treedef, list(shapes), *settings))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def shared_key(sc, kind: str) -> str:
    """Runs with equal keys share their controller, reference and limits (a batch of them passes
    each once instead of stacking B copies)."""
    text = repr((sc.build()._design_key(kind), sc.reference, sc.simulation.torque_limit,
                 sc.simulation.penetration_limit))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def stored_samples(run) -> int:
    """Samples a run stores (t = 0 ... t_final every save_every steps)."""
    return run.plan().samples


def _plain(x):
    """A pytree leaf as plain Python/NumPy, keeping what decides the compiled program: a weakly
    typed scalar stays a Python number (a NumPy scalar would be strongly typed: another trace)."""
    if isinstance(x, (bool, int, float, complex)):
        return x
    if getattr(x, "weak_type", False):
        return x.item() if np.ndim(x) == 0 else x
    return np.asarray(x)


def own_stream(run, r: RunSpec):
    """``run`` with its plant's sensor noise on the draw's own stream (the sensor's key folded with
    the grid point and the sample: every draw its own noise, the same on every controller of the
    draw and on a resumed sweep); a run without a sensor model as it is."""
    sensor = run.plant.sensor
    if sensor is None:
        return run
    return dataclasses.replace(run, plant=run.plant.with_sensor(sensor.stream(r.point, r.sample)))


def _ready(run) -> tuple:
    """What a batch needs of a checked run besides what its members share: the plant's leaves
    and the start pose, as plain Python/NumPy values (small, picklable)."""
    import jax

    return tuple(_plain(x) for x in jax.tree.leaves(run.plant)), _plain(run.q0)


def check_runs(base: dict, source: str, runs: list[RunSpec]) -> list[dict]:
    """Check runs (those of one draw share one scenario build). For each: ``{"run", "ok": True,
    "group", "shared", "samples", "n_joints", "ready"}`` or ``{"run", "ok": False, "reason",
    "error_key"}``."""
    from ..scenario.checks import check

    out = []
    by_draw: dict = collections.OrderedDict()
    for r in runs:
        by_draw.setdefault((r.point, r.sample), []).append(r)
    for items in by_draw.values():
        kinds = [r.controller for r in items]
        try:
            sc = scenario_of(base, source, items[0].values, kinds)
        except INVALID_ERRORS as err:
            out += [_invalid(r, err) for r in items]
            continue
        for r in items:
            try:
                one = sc.single(r.controller)
                check(one)  # designs through the process's design cache (hinfnn.scenario.setup)
                run = own_stream(one.run(r.controller), r)
                out.append({"run": r.run, "ok": True, "group": compile_key(run), "shared": shared_key(one, r.controller),
                            "samples": stored_samples(run), "n_joints": int(run.plant.n), "ready": _ready(run)})
            except INVALID_ERRORS as err:
                out.append(_invalid(r, err))
    return out


def _invalid(r: RunSpec, err: Exception) -> dict:
    text = str(err)
    if not isinstance(err, HinfnnError):
        text = f"{type(err).__name__}: {text}"
    return {"run": r.run, "ok": False, "reason": text, "error_key": getattr(err, "key", None)}


# --- planning --------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Batch:
    """A planned batch: its number, compiled group, size (members + padding) and runs."""

    id: int
    group: str
    size: int
    runs: tuple
    shared: bool = False  # every member has the same controller, reference and limits


def bytes_per_member(samples: int, n_joints: int) -> int:
    """Memory one batch member needs: the stored ``"metrics"`` fields
    (:data:`hinfnn.fields.METRICS_FIELDS`, the τ fields one number per joint) held twice (the
    chunk records and the preallocated arrays), plus 256 kB of working memory."""
    from ..fields import METRICS_FIELDS

    numbers = sum(n_joints if f.startswith("tau") else 1 for f in METRICS_FIELDS)
    return 2 * samples * numbers * 8 + 256 * 1024


def batch_cap(samples: int, n_joints: int, max_batch: int = DEFAULT_MAX_BATCH, memory: int | None = None) -> int:
    """Largest batch: ``max_batch``, or fewer members if their stored fields would take more than
    :data:`MEMORY_FRACTION` of the available memory."""
    if memory is None:
        from ..resources import available_memory

        memory = available_memory() or 4 * 2**30
    return max(1, min(int(max_batch), int(MEMORY_FRACTION * memory // bytes_per_member(samples, n_joints))))


#: A group is cut into more batches than memory and ``max_batch`` ask for, so that every batch that
#: runs side by side (the local backend's worker processes) has one, only down to this many runs.
MIN_SPLIT = 8


def plan_batches(checked: list[dict], max_batch: int, memory: int | None = None, parallel: int = 1,
                 share: int | None = None) -> list[Batch]:
    """Batches of equal size per compiled group, in run order (see the module docstring).
    ``parallel``: how many batches run at once: a group is cut into at least that many batches
    while each keeps :data:`MIN_SPLIT` runs; ``share``: how many of them share this machine's
    memory (default ``parallel``), each getting that share of it."""
    share = parallel if share is None else share
    if share > 1:
        if memory is None:
            from ..resources import available_memory

            memory = available_memory() or 4 * 2**30
        memory = memory // share
    groups: dict = collections.OrderedDict()
    info, shared = {}, {}
    for c in sorted(checked, key=lambda c: c["run"]):
        if c["ok"]:
            groups.setdefault(c["group"], []).append(c["run"])
            info[c["group"]] = (c["samples"], c["n_joints"])
            shared[c["run"]] = c.get("shared")
    batches = []
    for group, ids in groups.items():
        cap = batch_cap(*info[group], max_batch=max_batch, memory=memory)
        k = max(-(-len(ids) // cap), min(parallel, len(ids) // MIN_SPLIT))
        size = -(-len(ids) // k)
        for i in range(k):
            chunk = tuple(ids[i * size:(i + 1) * size])
            same = len({shared[r] for r in chunk}) == 1 and shared[chunk[0]] is not None
            batches.append(Batch(id=len(batches), group=group, size=size, runs=chunk, shared=same))
    return batches


# --- running one batch ----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class BatchJob:
    """Everything a worker needs to run one batch: the base scenario (plain dict), the members,
    and, when the draws were checked in this session, each member's plant leaves and start pose
    (``ready``: then only the first member's scenario is built again)."""

    batch: Batch
    base: dict
    source: str
    members: tuple  # RunSpec, in the batch's order
    max_out_of_contact: float
    ready: tuple | None = None  # per member: (plant leaves, q0), see _ready


def _members(job: BatchJob) -> list:
    """(plant, q0) of every member and the controller, reference and limits: each shared one
    once (``batch.shared``) or a list."""
    import jax

    first = scenario_of(job.base, job.source, job.members[0].values, job.members[0].controller)
    run0 = own_stream(first.run(job.members[0].controller), job.members[0])
    if job.batch.shared and job.ready is not None:
        treedef = jax.tree.structure(run0.plant)
        plants = [jax.tree.unflatten(treedef, leaves) for leaves, _ in job.ready]
        q0s = [q0 for _, q0 in job.ready]
        return plants, q0s, run0.controller, run0.reference, run0.limits, run0
    runs = [run0]
    for r in job.members[1:]:
        sc = scenario_of(job.base, job.source, r.values, r.controller)
        runs.append(own_stream(sc.run(r.controller), r))
    plants, q0s = [r.plant for r in runs], [r.q0 for r in runs]
    if job.batch.shared:
        return plants, q0s, run0.controller, run0.reference, run0.limits, run0
    return plants, q0s, [r.controller for r in runs], [r.reference for r in runs], [r.limits for r in runs], run0


#: Fault injection for the tests: with this variable naming a file that does not exist, the first
#: batch to start (in a Ray task or a local worker process) creates it and kills its own process.
FAULT_ONCE_ENV = "HINFNN_SWEEP_FAULT_ONCE"


def fault_once() -> None:
    path = os.environ.get(FAULT_ONCE_ENV)
    if path:
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            return
        os.close(fd)
        os._exit(1)


def execute_batch(job: BatchJob, progress: Callable[[float], None] | None = None) -> dict:
    """Run one batch as one :func:`hinfnn.simulate_batch` call and return ``{"batch", "rows",
    "wall_s", "cpu_s", "host", "pid", "members", "size"}``; ``rows`` has one dict per member
    (padding dropped); ``cpu_s`` is the CPU time of the whole process meanwhile (all its threads).
    ``progress(fraction)`` is called after each compiled chunk."""
    from ..sim import simulate_batch

    t0, c0 = time.perf_counter(), time.process_time()
    plants, q0s, controllers, references, limits, first = _members(job)
    n_real, pad = len(plants), job.batch.size - len(plants)
    plants, q0s = plants + [plants[-1]] * pad, q0s + [q0s[-1]] * pad  # a copy of the last member
    if isinstance(controllers, list):
        controllers, references, limits = (x + [x[-1]] * pad for x in (controllers, references, limits))

    def report(done, total, what=""):
        if progress is not None:
            progress(done / total)

    traj = simulate_batch(plants, controllers, references, q0=q0s, t_final=first.t_final, dt=first.dt,
                          save_interval=first.save_interval, fields="metrics", control_period=first.control_period,
                          limits=limits, bookkeeping=first.bookkeeping, progress=report)
    from ..metrics import lam_is_normal_force

    sc = first.info.scenario
    normal = lam_is_normal_force(sc)  # the members' λ means what the first's does
    judging = _judging_of(sc, first.controller if not isinstance(controllers, list) else controllers[0])
    rows = [member_row(r, traj.member(j), job.max_out_of_contact, normal, **judging)
            for j, r in enumerate(job.members)]
    return {"batch": job.batch.id, "rows": rows, "wall_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - c0, "host": socket.gethostname(), "pid": os.getpid(), "members": n_real,
            "size": job.batch.size}


def _judging_of(scenario, controller) -> dict:
    """The verdict's tolerances and the motion coordinates' (name, unit) of a batch's runs (its
    first member's scenario: the spec varies the truth, not the verdict)."""
    if scenario is None or not hasattr(scenario, "verdict"):
        return {}
    try:
        names = scenario.coordinate_names()
    except Exception:  # noqa: BLE001 - judged in m, as compute_metrics does
        names = None
    m = int(getattr(controller, "m", 0) or 0)
    return {"tolerances": scenario.verdict.tolerances(), "coordinates": list(names[:m]) if names and m else None}


def member_row(r: RunSpec, traj, max_out_of_contact: float, normal: bool | None = None, tolerances=None,
               coordinates=None) -> dict:
    """The table row of one simulated run (``normal``: λ is the normal force, for its true force
    error: :func:`hinfnn.metrics.lam_is_normal_force`; ``tolerances``, ``coordinates``: the
    verdict's, :func:`hinfnn.metrics.verdicts`). Contact is judged after the verdict's
    ``contact_after`` (the force's build-up is not judged), as a single run's verdict judges it:
    ``held_contact`` is bounded and out of contact for at most ``max_out_of_contact`` of the
    steps after it (empty for a bounded run that ends before it: not judged); ``did_its_job`` is held
    contact and tracking within tolerance over the last 2 s."""
    from ..metrics import compute_metrics

    m = compute_metrics(traj, lam_is_normal_force=normal, tolerances=tolerances, coordinates=coordinates)
    verdict = m.pop("verdict", None) or {}
    code = int(traj.status)
    row = id_row(r)
    row.update(status=traj.run_status.outcome, reason=traj.reason, error_key=None,
               t_fail=float(traj.t_fail) if code != 0 else math.nan)
    for k, v in m.items():
        if isinstance(v, list) and k not in PER_COORDINATE_METRICS:
            row.update({f"{k}_{i + 1}": float(x) for i, x in enumerate(v)})
        else:
            row[k] = v
    bounded = code == 0
    row["bounded"] = bounded
    after = verdict.get("out_of_contact_after")
    judged = after is not None and math.isfinite(after)  # a bounded run no longer than contact_after: not judged
    row["out_of_contact_after"] = float(after) if judged else math.nan
    row["held_contact"] = bool(after <= max_out_of_contact) if bounded and judged else (None if bounded else False)
    row["tracked"] = bool(bounded and verdict.get("tracking_within_tolerance"))
    row["did_its_job"] = None if row["held_contact"] is None else bool(row["held_contact"] and row["tracked"])
    return row


def id_row(r: RunSpec) -> dict:
    return {"run": r.run, "point": r.point, "sample": r.sample, "controller": r.controller, **r.values}


def invalid_row(r: RunSpec, checked: dict) -> dict:
    row = id_row(r)
    row.update(status=RunStatus.INVALID.outcome, reason=checked["reason"], error_key=checked.get("error_key"),
               t_fail=math.nan)
    return row


__all__ = ["DEFAULT_MAX_BATCH", "MEMORY_FRACTION", "CHECK_CHUNK", "INVALID_ERRORS", "scenario_of", "compile_key",
           "shared_key", "stored_samples", "check_runs", "Batch", "bytes_per_member", "batch_cap", "plan_batches",
           "BatchJob", "execute_batch", "member_row", "id_row", "invalid_row", "own_stream"]
