"""Running a sweep: check every draw, group the runs by compiled structure, run each group as
``vmap`` batches sized to memory, write each finished batch as a Parquet part.

1. **Check.** Every run's scenario is built from the base scenario and the run's values and
   checked (:meth:`hinfnn.scenario.Scenario.check`: start pose, RK4 step against the contact,
   controller design ...). A run that fails is a row with status ``"invalid"``, the error's
   text and key; it is never simulated.
2. **Plan.** The valid runs are grouped by compiled structure (the pytree structure and leaf
   shapes of plant, controller, reference and limits, and the simulation settings: what
   :func:`hinfnn.simulate_batch` compiles one program for) and each group is cut into batches of
   equal size (the last one padded with a copy of its last member, whose result is dropped), so
   that a group compiles once. The batch size is capped by memory (the stored ``"metrics"``
   fields of every member, :func:`batch_cap`) and by ``max_batch``. The plan is stored in the
   manifest: a resumed sweep runs exactly the same batches.
3. **Run.** Each batch is one :func:`hinfnn.simulate_batch` call (``fields="metrics"``), its
   members' metrics by :func:`hinfnn.compute_metrics` (partial up to t_fail for a member that
   stopped: status ``"diverged"``, ``t_fail`` and the reason), written as one Parquet part as
   soon as it finishes. Batches run in this process (``backend="local"``) or as Ray tasks
   (``backend="ray"``, :mod:`hinfnn.sweep.ray_backend`).
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import math
import os
import shutil
import socket
import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import ConfigError, HinfnnError
from . import store
from .sampling import RunSpec, runs as all_runs
from .spec import PER_COORDINATE_METRICS, SweepSpec

#: Largest batch by default: past a few hundred members the throughput gains little (on the
#: project's 2-core machine 202,000 trajectory-steps/s at 100 members, 237,000 at 1,000) and a
#: killed sweep loses at most one batch.
DEFAULT_MAX_BATCH = 256
#: Fraction of the available memory a batch may hold.
MEMORY_FRACTION = 0.5
#: Draws checked per task (ray backend) or per progress update.
CHECK_CHUNK = 64
#: Errors that make a run "invalid" rather than stopping the sweep.
INVALID_ERRORS = (HinfnnError, ValueError, ArithmeticError, np.linalg.LinAlgError)


# --- building one run ---------------------------------------------------------------------------------


class _Designs:
    """Designed controllers by (kind, nominal model, controller section): a sweep that varies
    only the truth designs each controller once per process."""

    def __init__(self, size: int = 64):
        self.size = size
        self._d: collections.OrderedDict = collections.OrderedDict()

    @staticmethod
    def key(sc, kind: str) -> str:
        # the sections are frozen dataclasses: their repr lists every value (floats exactly)
        return repr((kind, sc.nominal, sc.controller))

    def get(self, sc, kind: str):
        k = self.key(sc, kind)
        if k in self._d:
            self._d.move_to_end(k)
            return self._d[k], k
        ctrl = sc.build_controller(kind)
        self._d[k] = ctrl
        if len(self._d) > self.size:
            self._d.popitem(last=False)
        return ctrl, k


_DESIGNS = _Designs()


class _CachedDesigns:
    """A scenario whose ``build_controller`` answers from the design cache, for
    :func:`hinfnn.scenario.checks.check` (what :meth:`Scenario.check` runs): the same checks,
    without designing the same controller again for every draw."""

    def __init__(self, sc):
        self._sc = sc

    def __getattr__(self, name):
        return getattr(self._sc, name)

    def build_controller(self, kind: str | None = None):
        return _DESIGNS.get(self._sc, kind or self._sc.kinds[0])[0]


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


def shared_key(sc, design_key: str) -> str:
    """Runs with equal keys share their controller, reference and limits (a batch of them passes
    each once instead of stacking B copies)."""
    text = repr((design_key, sc.reference, sc.simulation.torque_limit, sc.simulation.penetration_limit))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def stored_samples(run) -> int:
    """Samples a run stores (t = 0 ... t_final every save_every steps)."""
    from ..sim.simulate import steps

    n_steps, _, save_every = steps(run.t_final, run.dt, None, run.control_period, run.save_interval,
                                   bool(getattr(run.plant, "discrete", False)))
    return n_steps // save_every + 1


def _plain(x):
    """A pytree leaf as plain Python/NumPy, keeping what decides the compiled program: a weakly
    typed scalar stays a Python number (a NumPy scalar would be strongly typed: another trace)."""
    if isinstance(x, (bool, int, float, complex)):
        return x
    if getattr(x, "weak_type", False):
        return x.item() if np.ndim(x) == 0 else x
    return np.asarray(x)


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
                check(_CachedDesigns(one))
                ctrl, design_key = _DESIGNS.get(one, r.controller)
                run = one.run(r.controller, controller=ctrl)
                out.append({"run": r.run, "ok": True, "group": compile_key(run), "shared": shared_key(one, design_key),
                            "samples": stored_samples(run), "n_joints": int(run.plant.n), "ready": _ready(run)})
            except INVALID_ERRORS as err:
                out.append(_invalid(r, err))
    return out


def _invalid(r: RunSpec, err: Exception) -> dict:
    text = str(err)
    if not isinstance(err, HinfnnError):
        text = f"{type(err).__name__}: {text}"
    return {"run": r.run, "ok": False, "reason": text, "error_key": getattr(err, "key", None)}


# --- planning ---------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Batch:
    """A planned batch: its number, compiled group, size (members + padding) and runs."""

    id: int
    group: str
    size: int
    runs: tuple
    shared: bool = False  # every member has the same controller, reference and limits


def available_memory() -> int:
    """Bytes of memory available to this process (MemAvailable, capped by a cgroup limit)."""
    avail = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
                break
    except OSError:
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
        except (ValueError, OSError, AttributeError):
            avail = 4 * 2**30
    for limit_file in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(limit_file).read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            avail = min(avail, int(text))
    return int(avail)


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
    memory = available_memory() if memory is None else memory
    return max(1, min(int(max_batch), int(MEMORY_FRACTION * memory // bytes_per_member(samples, n_joints))))


def plan_batches(checked: list[dict], max_batch: int, memory: int | None = None) -> list[Batch]:
    """Batches of equal size per compiled group, in run order (see the module docstring)."""
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
        k = -(-len(ids) // cap)
        size = -(-len(ids) // k)
        for i in range(k):
            chunk = tuple(ids[i * size:(i + 1) * size])
            same = len({shared[r] for r in chunk}) == 1 and shared[chunk[0]] is not None
            batches.append(Batch(id=len(batches), group=group, size=size, runs=chunk, shared=same))
    return batches


# --- running one batch ------------------------------------------------------------------------------------


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
    ctrl, _ = _DESIGNS.get(first, job.members[0].controller)
    run0 = first.run(job.members[0].controller, controller=ctrl)
    if job.batch.shared and job.ready is not None:
        treedef = jax.tree.structure(run0.plant)
        plants = [jax.tree.unflatten(treedef, leaves) for leaves, _ in job.ready]
        q0s = [q0 for _, q0 in job.ready]
        return plants, q0s, run0.controller, run0.reference, run0.limits, run0
    runs = [run0]
    for r in job.members[1:]:
        sc = scenario_of(job.base, job.source, r.values, r.controller)
        runs.append(sc.run(r.controller, controller=_DESIGNS.get(sc, r.controller)[0]))
    plants, q0s = [r.plant for r in runs], [r.q0 for r in runs]
    if job.batch.shared:
        return plants, q0s, run0.controller, run0.reference, run0.limits, run0
    return plants, q0s, [r.controller for r in runs], [r.reference for r in runs], [r.limits for r in runs], run0


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

    def report(done, total):
        if progress is not None:
            progress(done / total)

    traj = simulate_batch(plants, controllers, references, q0=q0s, t_final=first.t_final, dt=first.dt,
                          save_interval=first.save_interval, fields="metrics", control_period=first.control_period,
                          limits=limits, progress=report)
    rows = [member_row(r, traj.member(j), job.max_out_of_contact) for j, r in enumerate(job.members)]
    return {"batch": job.batch.id, "rows": rows, "wall_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - c0, "host": socket.gethostname(), "pid": os.getpid(), "members": n_real,
            "size": job.batch.size}


def member_row(r: RunSpec, traj, max_out_of_contact: float) -> dict:
    """The table row of one simulated run."""
    from ..metrics import compute_metrics
    from ..sim.simulate import failure_reason

    m = compute_metrics(traj)
    code = int(traj.status)
    row = id_row(r)
    row.update(status="ok" if code == 0 else "diverged",
               reason=None if code == 0 else failure_reason(code, {k: float(v) for k, v in traj.fail_details.items()}),
               error_key=None, t_fail=float(traj.t_fail) if code != 0 else math.nan)
    for k, v in m.items():
        if isinstance(v, list) and k not in PER_COORDINATE_METRICS:
            row.update({f"{k}_{i + 1}": float(x) for i, x in enumerate(v)})
        else:
            row[k] = v
    bounded = code == 0
    row["bounded"] = bounded
    frac = row.get("fraction_out_of_contact", math.nan)
    row["held_contact"] = bool(bounded and frac <= max_out_of_contact)
    return row


def id_row(r: RunSpec) -> dict:
    return {"run": r.run, "point": r.point, "sample": r.sample, "controller": r.controller, **r.values}


def invalid_row(r: RunSpec, checked: dict) -> dict:
    row = id_row(r)
    row.update(status="invalid", reason=checked["reason"], error_key=checked.get("error_key"), t_fail=math.nan)
    return row


# --- the backends ----------------------------------------------------------------------------------------


class LocalBackend:
    """Batches run one after the other in this process (JAX uses the machine's cores)."""

    name = "local"

    def describe(self) -> str:
        return f"local ({os.cpu_count()} cores)"

    def check(self, chunks, on_done):
        for chunk in chunks:
            on_done(check_runs(*chunk))

    def run(self, jobs, on_done, progress):
        for job in jobs:
            on_done(execute_batch(job, progress=lambda f, job=job: progress(job, f)))

    def close(self):
        pass


def make_backend(name: str, address: str | None = None):
    if name == "local":
        if address is not None:
            raise ConfigError("--address is for the ray backend", key="--address")
        return LocalBackend()
    if name == "ray":
        from .ray_backend import RayBackend

        return RayBackend(address=address)
    raise ConfigError(f"must be 'local' or 'ray', got {name!r}", key="--backend")


# --- the sweep ----------------------------------------------------------------------------------------------


@dataclasses.dataclass
class SweepResult:
    """What :func:`run_sweep` did: where, how many runs of each outcome, how long."""

    folder: Path
    n_runs: int
    counts: dict            # controller -> {"runs", "invalid", "simulated", "bounded", "held_contact", "diverged"}
    simulated_now: int      # runs simulated by this call (a resumed sweep: the rest)
    wall_s: float           # this call, start to finish
    run_wall_s: float       # the batches (compilation included)
    backend: str
    resumed: bool
    already_done: int       # runs found finished on disk

    @property
    def runs_per_s(self) -> float:
        return self.simulated_now / self.run_wall_s if self.run_wall_s > 0 else math.nan


def run_sweep(spec: SweepSpec, folder, *, backend: str = "local", address: str | None = None, resume: bool = False,
              max_batch: int | None = None, progress=None, log=None, command: str = "",
              report: bool = True, on_part: Callable[[int], None] | None = None) -> SweepResult:
    """Run (or with ``resume``, continue) the sweep ``spec`` into ``folder``.

    The folder must be new or empty unless ``resume``; resuming checks that the folder holds the
    same sweep (spec, base scenario, hinfnn version) and runs the batches whose part is missing,
    with the stored plan. ``progress(phase, done, total)`` (phase ``"check"``: draws checked;
    ``"run"``: runs simulated, fractional within a batch); ``log(message)`` for one-line notes;
    ``on_part(batch_id)`` after each part is written. Returns a :class:`SweepResult`; the table is
    :func:`hinfnn.load_sweep` of the folder. ``max_batch``: cap on the batch size (default
    :data:`DEFAULT_MAX_BATCH`; ignored when resuming: the stored plan decides).
    """
    from .._config import require_x64

    require_x64()
    t_start = time.perf_counter()
    folder = Path(folder)
    log = log or (lambda m: None)
    progress = progress or (lambda phase, done, total: None)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"output path {folder} exists and is not a folder", key="--out")
    lock = store.FolderLock(folder)
    try:
        if folder.is_dir():
            lock.acquire()  # a sweep still running in this folder: stop here
        return _run(spec, folder, lock, backend=backend, address=address, resume=resume, max_batch=max_batch,
                    progress=progress, log=log, command=command, report=report, on_part=on_part, t_start=t_start)
    finally:
        lock.release()


def _run(spec, folder, lock, *, backend, address, resume, max_batch, progress, log, command, report, on_part,
         t_start) -> SweepResult:
    from .. import __version__

    runs = all_runs(spec)
    by_id = {r.run: r for r in runs}
    n_joints = int(spec.base.build_plant().n)
    fingerprint = spec.fingerprint()
    manifest = None
    if store.is_sweep_folder(folder):
        if not resume:
            raise ConfigError(f"{folder} already holds a sweep; resume it with --resume or choose another --out",
                              key="--out")
        manifest = store.read_manifest(folder)
        _check_same_sweep(manifest, spec, fingerprint, folder)
        store.clean_temporaries(folder)
    elif folder.exists() and any(p.name != store.FolderLock.NAME for p in folder.iterdir()):
        # killed while checking the draws (sweep.toml written, no manifest yet): start again
        if not (resume and (folder / "scenario.toml").exists() and _same_base(folder, spec)):
            raise ConfigError(f"{folder} exists and is not empty; choose another --out (or --force to replace it)",
                              key="--out")
    elif resume:
        log(f"nothing to resume in {folder}: starting the sweep")
    be = make_backend(backend, address)  # before writing anything: a missing Ray leaves no folder behind
    ready: dict = {}
    try:
        store.prepare_folder(folder)
        lock.acquire()
        if manifest is None:
            from ..io import atomic_write_text

            atomic_write_text(folder / "sweep.toml", spec.to_toml(resolved=True))
            atomic_write_text(folder / "scenario.toml", spec.base.to_toml())
        if manifest is None:
            manifest, ready = _plan(spec, runs, by_id, folder, be, n_joints, fingerprint,
                                    max_batch or DEFAULT_MAX_BATCH, progress, log, command, __version__)
        elif max_batch is not None and max_batch != manifest.get("max_batch"):
            log(f"resuming with the stored plan (batches of at most {manifest.get('max_batch')} runs); "
                "--batch-size is ignored")
        result = _execute(spec, manifest, by_id, ready, folder, be, n_joints, progress, log, command, on_part,
                          resume, t_start)
    finally:
        be.close()
    if report:
        write_outputs(folder, spec, manifest)
    return result


def _same_base(folder: Path, spec: SweepSpec) -> bool:
    try:
        return (folder / "scenario.toml").read_text(encoding="utf-8") == spec.base.to_toml()
    except OSError:
        return False


def _check_same_sweep(manifest: dict, spec: SweepSpec, fingerprint: str, folder: Path) -> None:
    from .. import __version__

    if manifest.get("fingerprint") != fingerprint:
        raise ConfigError(f"{folder} holds a different sweep (its spec, --samples, --set or base scenario differ: "
                          f"see {folder / 'sweep.toml'}); resume with the same arguments, e.g. "
                          f"`hinfnn sweep {folder / 'sweep.toml'} --out {folder} --resume`", key="--resume")
    if manifest.get("hinfnn_version") != __version__:
        raise ConfigError(f"{folder} was started by hinfnn {manifest.get('hinfnn_version')}, this is {__version__}: "
                          "a resumed table would mix two versions' numbers", key="--resume")


def _plan(spec, runs, by_id, folder, be, n_joints, fingerprint, max_batch, progress, log, command, version):
    """Check every run, write the invalid rows, plan the batches, write the manifest."""
    t0 = time.perf_counter()
    base = spec.base.to_dict()
    chunks, current = [], []
    for r in runs:  # chunks of whole draws
        if current and len(current) >= CHECK_CHUNK * len(spec.controllers) and \
                (r.point, r.sample) != (current[-1].point, current[-1].sample):
            chunks.append((base, spec.base.source, current))
            current = []
        current.append(r)
    if current:
        chunks.append((base, spec.base.source, current))
    checked: list[dict] = []
    n_draws = spec.points * spec.samples

    def done(part):
        checked.extend(part)
        progress("check", len(checked) / max(1, len(spec.controllers)), n_draws)

    progress("check", 0, n_draws)
    be.check(chunks, done)
    checked.sort(key=lambda c: c["run"])
    ready = {c["run"]: c.pop("ready") for c in checked if c["ok"]}
    invalid = [invalid_row(by_id[c["run"]], c) for c in checked if not c["ok"]]
    store.write_table(folder / store.PARTS / store.INVALID_PART, store.rows_table(invalid, spec, n_joints))
    batches = plan_batches(checked, max_batch)
    log(f"checked {len(runs)} runs in {time.perf_counter() - t0:.1f} s: {len(invalid)} invalid, "
        f"{len(runs) - len(invalid)} to simulate in {len(batches)} batches "
        f"({len({b.group for b in batches})} compiled programs)")
    manifest = {
        "format": store.FORMAT, "hinfnn_version": version, "spec": spec.name, "fingerprint": fingerprint,
        "command": command, "created": store.now(), "status": "running", "n_runs": len(runs),
        "n_invalid": len(invalid), "controllers": list(spec.controllers), "max_batch": max_batch,
        "check_wall_s": round(time.perf_counter() - t0, 3), "n_batches": len(batches),
        "n_groups": len({b.group for b in batches}), "done": {}, "sessions": [],
    }
    store.write_plan(folder, {"fingerprint": fingerprint, "max_batch": max_batch,
                              "batches": [[b.id, b.group, b.size, list(b.runs), b.shared] for b in batches]})
    store.write_manifest(folder, manifest)
    return manifest, ready


def _execute(spec, manifest, by_id, ready, folder, be, n_joints, progress, log, command, on_part, resume, t_start):
    plan = store.read_plan(folder)
    if plan.get("fingerprint") != manifest.get("fingerprint"):
        raise store.LoadError(f"{folder / store.PLAN} does not belong to {folder / store.MANIFEST}")
    batches = [Batch(id=i, group=g, size=n, runs=tuple(r), shared=bool(sh)) for i, g, n, r, sh in plan["batches"]]
    done = store.done_batches(folder)
    pending = [b for b in batches if b.id not in done]
    total = sum(len(b.runs) for b in batches)
    finished = sum(len(b.runs) for b in batches if b.id in done)
    if resume and done:
        log(f"resuming: {len(done)} of {len(batches)} batches ({finished} runs) already done")
    base = spec.base.to_dict()
    jobs = [BatchJob(batch=b, base=base, source=spec.base.source, members=tuple(by_id[i] for i in b.runs),
                     max_out_of_contact=spec.max_out_of_contact,
                     ready=tuple(ready[i] for i in b.runs) if all(i in ready for i in b.runs) else None)
            for b in pending]
    ready.clear()
    in_flight: dict[int, float] = {}
    state = {"finished": finished}
    session = {"backend": be.describe(), "started": store.now(), "command": command, "batches": 0, "runs": 0,
               "wall_s": 0.0}
    manifest.setdefault("sessions", []).append(session)
    t_run = time.perf_counter()

    def show():
        progress("run", state["finished"] + sum(in_flight.values()), total)

    def on_progress(job, fraction):
        in_flight[job.batch.id] = fraction * len(job.members)
        show()

    def on_done(res):
        b = res["batch"]
        table = store.rows_table(res["rows"], spec, n_joints)
        store.write_table(folder / store.PARTS / store.part_name(b), table)
        in_flight.pop(b, None)
        state["finished"] += res["members"]
        manifest["done"][str(b)] = {"wall_s": round(res["wall_s"], 3), "cpu_s": round(res.get("cpu_s", 0.0), 3),
                                    "host": res["host"], "pid": res["pid"], "finished": store.now()}
        session["batches"] += 1
        session["runs"] += res["members"]
        session["wall_s"] = round(time.perf_counter() - t_run, 3)
        store.write_manifest(folder, manifest)
        show()
        if on_part is not None:
            on_part(b)

    show()
    be.run(jobs, on_done, on_progress)
    run_wall = time.perf_counter() - t_run
    session["wall_s"] = round(run_wall, 3)
    session["finished"] = store.now()
    if not store.done_batches(folder) >= {b.id for b in batches}:  # pragma: no cover - a backend bug
        raise RuntimeError("some batches did not finish")
    table = store.read_parts(folder)
    store.write_table(folder / store.RESULTS, table)
    manifest["status"] = "complete"
    manifest["completed"] = store.now()
    store.write_manifest(folder, manifest)
    counts = outcome_counts(table.to_pylist() if table is not None else [], spec.controllers)
    return SweepResult(folder=folder, n_runs=manifest["n_runs"], counts=counts, simulated_now=session["runs"],
                       wall_s=time.perf_counter() - t_start, run_wall_s=run_wall, backend=be.name, resumed=resume,
                       already_done=finished)


def outcome_counts(rows: list[dict], controllers) -> dict:
    """Per controller: runs, invalid, simulated, bounded, held_contact, diverged."""
    out = {k: dict(runs=0, invalid=0, simulated=0, bounded=0, held_contact=0, diverged=0) for k in controllers}
    for r in rows:
        c = out.setdefault(r["controller"], dict(runs=0, invalid=0, simulated=0, bounded=0, held_contact=0,
                                                  diverged=0))
        c["runs"] += 1
        if r["status"] == "invalid":
            c["invalid"] += 1
            continue
        c["simulated"] += 1
        c["bounded"] += bool(r["bounded"])
        c["held_contact"] += bool(r["held_contact"])
        c["diverged"] += r["status"] == "diverged"
    return out


def write_outputs(folder: Path, spec: SweepSpec, manifest: dict | None = None) -> list[Path]:
    """report.md and the figures of a finished sweep (written atomically)."""
    from ..report.sweep import write_sweep_report

    manifest = manifest or store.read_manifest(folder)
    df = store.load_sweep(folder)
    return write_sweep_report(df, report_meta(spec, manifest), folder)


def report_meta(spec: SweepSpec, manifest: dict) -> dict:
    """What the report needs besides the table, as plain data (reports never import
    controllers)."""
    from ..controllers import KINDS

    sessions = manifest.get("sessions", [])
    varied = []
    for v in spec.varied:
        entry = {"key": v.key, "how": v.how.describe(), "grid": v.how.is_grid, "kind": v.how.kind,
                 "log": v.how.kind in ("logspace", "log-uniform")}
        if v.how.is_grid:
            entry["values"] = v.how.grid()
        varied.append(entry)
    return {
        "name": spec.name, "description": spec.description, "scenario": spec.base.name,
        "scenario_source": spec.base.source, "controllers": list(spec.controllers),
        "labels": {k: KINDS[k].label for k in spec.controllers}, "colors": {k: KINDS[k].color for k in spec.controllers},
        "samples": spec.samples, "seed": spec.seed, "points": spec.points, "varied": varied,
        "metrics": list(spec.metrics), "map_metric": spec.map_metric, "max_out_of_contact": spec.max_out_of_contact,
        "t_final": spec.base.simulation.t_final, "dt": spec.base.simulation.dt,
        "overrides": [[k, v] for k, v in spec.overrides], "command": manifest.get("command", ""),
        "sessions": sessions, "batches": manifest.get("n_batches", 0), "groups": manifest.get("n_groups", 0),
        "check_wall_s": manifest.get("check_wall_s"), "hinfnn_version": manifest.get("hinfnn_version"),
    }


def clear_folder(folder: Path) -> None:
    """Remove a folder's content (``--force``)."""
    folder = Path(folder)
    if folder.is_dir():
        shutil.rmtree(folder)


__all__ = ["run_sweep", "SweepResult", "execute_batch", "check_runs", "plan_batches", "batch_cap", "Batch", "BatchJob",
           "DEFAULT_MAX_BATCH", "write_outputs", "outcome_counts"]
