"""Running a sweep: its output folder, the checked draws and the plan in the manifest, the batches
on a backend, each finished batch written as a Parquet part, the table and the report.

The draws are checked and planned once (:mod:`hinfnn.sweep.worker`) and the plan is stored in the
manifest: a resumed sweep runs exactly the same batches. Batches run in this process
(``backend="local"``) or as Ray tasks (``backend="ray"``), :mod:`hinfnn.sweep.backends`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Callable

from ..errors import ConfigError, LoadError
from . import store
from .backends import auto_workers, make_backend
from .sampling import runs as all_runs
from .spec import SweepSpec
from .worker import CHECK_CHUNK, DEFAULT_MAX_BATCH, Batch, BatchJob, invalid_row, plan_batches

#: What the progress callback is told a sweep is doing.
CHECKING, SIMULATING = "checking draws", "simulating"


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


@dataclasses.dataclass
class SweepOutput:
    """Where a sweep goes (:func:`prepare_output`): ``target`` the folder the user gets; ``work`` the
    folder the sweep runs in (``target`` itself, or with ``--force`` a sibling that replaces
    ``target`` once the sweep is complete); ``resume`` whether ``work`` holds a sweep to continue;
    ``note`` why ``target`` is not the folder asked for (or None)."""

    target: Path
    work: Path
    resume: bool
    note: str | None = None

    @property
    def replacing(self) -> bool:
        return self.work != self.target


def prepare_output(out, spec: SweepSpec, *, resume: bool = False, force: bool = False) -> SweepOutput:
    """The folder rules of ``hinfnn sweep``, checked before anything runs (ConfigError keyed
    ``--out``, ``--resume`` or ``--force``).

    ``out`` (default ``results/<spec name>``) new or empty: the sweep runs there. ``resume``: ``out``
    must hold a sweep (its manifest) to continue. A folder that holds something else is kept and the
    sweep goes to ``OUT-2``, ``OUT-3`` … (said in ``note``), unless ``force``: then a folder a sweep
    wrote is replaced, like every other command's result, only once the new sweep is complete (the
    new one runs in ``.OUT.hinfnn-new`` beside it; an interrupted ``--force`` sweep is continued by
    the same command), and a folder with files a sweep did not write is refused, naming them. Where
    ``out`` cannot be renamed (a mount point, a symbolic link: :func:`hinfnn.io.folders.commits_inside`), the
    new sweep runs in a hidden folder inside it and is committed there. A place that cannot be written
    (a read-only disk, a broken link) is refused here, as is a missing pyarrow."""
    from ..io import reserve_output
    from ..io.folders import INSIDE_PREFIX, check_writable, commits_inside

    if resume and force:
        raise ConfigError("--resume continues the sweep in OUT, --force replaces it: give one", key="--force")
    store.require_pyarrow()
    out = Path(out) if out is not None else Path("results") / spec.name
    if str(out).strip() in ("", ".") or out.resolve() in (Path.cwd(), *Path.cwd().parents):
        raise ConfigError(f"{str(out)!r} is the current folder or one that contains it; give a new folder's name",
                          key="--out")
    if out.exists() and not out.is_dir():
        raise ConfigError(f"output path {out} exists and is not a folder", key="--out")
    check_writable(out)
    if resume:
        if not out.exists():
            raise ConfigError(f"nothing to resume: {out} does not exist (run the sweep without --resume to start it)",
                              key="--resume")
        if not store.is_sweep_folder(out) and not _interrupted_start(out, spec):
            raise ConfigError(f"{out} is not a sweep's folder (it has no {store.MANIFEST}); --resume continues a "
                              "sweep hinfnn started there", key="--resume")
        return SweepOutput(target=out, work=out, resume=True)
    if not out.exists() or not any(out.iterdir()):
        return SweepOutput(target=out, work=out, resume=False)
    if force:
        foreign = store.foreign_files(out) if store.is_sweep_folder(out) else sorted(p.name for p in out.iterdir())
        if foreign:
            shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
            raise ConfigError(f"{out} holds files a sweep did not write ({shown}); --force replaces only a sweep's "
                              "folder: choose another --out, or move those files away", key="--out")
        work = out / f"{INSIDE_PREFIX}sweep" if commits_inside(out) else out.with_name(f".{out.name}.hinfnn-new")
        again = store.is_sweep_folder(work) and store.read_manifest(work).get("fingerprint") == spec.fingerprint()
        if work.exists() and not again:
            import shutil

            shutil.rmtree(work)  # a replacement of another sweep, interrupted: hinfnn's own leftover
        return SweepOutput(target=out, work=work, resume=again)
    res = reserve_output(out, force=False)
    res.release(keep_parents=True)
    hint = " or --resume to continue the sweep in it" if store.is_sweep_folder(out) else ""
    return SweepOutput(target=res.target, work=res.target, resume=False,
                       note=f"{out} is not empty; writing to {res.target} instead (use --force to replace it{hint})")


def _interrupted_start(folder: Path, spec: SweepSpec) -> bool:
    """A sweep stopped before its manifest was written (killed while checking its draws, or a full
    disk): the folder holds only what a sweep writes first (:func:`hinfnn.sweep.store.started_only`),
    and its scenario.toml, if written, is this sweep's."""
    return store.started_only(folder) and (not (folder / "scenario.toml").exists() or _same_base(folder, spec))


def run_sweep(spec: SweepSpec, folder, *, backend: str = "local", address: str | None = None, resume: bool = False,
              max_batch: int | None = None, progress=None, log=None, command: str = "",
              report: bool = True, on_part: Callable[[int], None] | None = None,
              replaces: Path | None = None, workers: int | None = None) -> SweepResult:
    """Run (or with ``resume``, continue) the sweep ``spec`` into ``folder``.

    The folder must be new or empty unless ``resume``; resuming checks that the folder holds the
    same sweep (spec, base scenario, hinfnn version) and runs the batches whose part is missing,
    with the stored plan. The folder is locked for this process while the sweep runs
    (:class:`hinfnn.io.FolderLock`: a second sweep into it stops with a message). ``replaces``:
    a sweep folder the complete result replaces, atomically (``--force``). ``progress(done, total,
    what)`` (``what`` "checking draws": draws checked; "simulating": runs simulated, fractional
    within a batch); ``log(message)`` for one-line notes; ``on_part(batch_id)`` after each part is
    written. Returns a :class:`SweepResult`; the table is :func:`hinfnn.load_sweep` of the folder.
    ``max_batch``: cap on the batch size (default :data:`~hinfnn.sweep.worker.DEFAULT_MAX_BATCH`;
    ignored when resuming: the stored plan decides). ``workers``: with the local backend, how many
    batches run side by side in worker processes (None: one per core this process may use when one
    process would simulate for a minute or more, :func:`~hinfnn.sweep.backends.auto_workers`, else
    this process; 1: one after the other in this process, :class:`~hinfnn.sweep.backends.LocalBackend`).
    The workers are started with ``spawn``: as with any multiprocessing code, a script that calls
    this guards its entry point (``if __name__ == "__main__":``).
    """
    from .._config import require_x64
    from ..io import FolderLock
    from ..io.folders import check_writable

    require_x64()
    store.require_pyarrow()
    t_start = time.perf_counter()
    folder = Path(folder)
    log = log or (lambda m: None)
    progress = progress or (lambda done, total, what="": None)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"output path {folder} exists and is not a folder", key="--out")
    check_writable(folder)
    inside = replaces is not None and folder.parent.resolve() == Path(replaces).resolve()
    locks = ([] if inside else [FolderLock(folder)]) + ([FolderLock(replaces)] if replaces is not None else [])
    existed = folder.exists()
    try:
        try:
            folder.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise ConfigError(f"cannot create {folder.parent}: {err.strerror or err}", key="--out") from None
        for lock in locks:
            try:
                owner = lock.acquire()
            except OSError as err:
                raise ConfigError(f"cannot write in {lock.path.parent}: {err.strerror or err}", key="--out") from None
            if owner is not None:
                raise ConfigError(f"{lock.target} is in use by another hinfnn process"
                                  + (f" (pid {owner})" if owner > 0 else "") + "; wait for it to finish or stop it first",
                                  key="--out")
        result = _run(spec, folder, backend=backend, address=address, resume=resume, max_batch=max_batch,
                      progress=progress, log=log, command=command, report=report, on_part=on_part, t_start=t_start,
                      workers=workers, existed=existed)
        if replaces is not None:
            store.replace_folder(folder, replaces)
            result.folder = Path(replaces)
        return result
    finally:
        for lock in locks:
            lock.release()


def _run(spec, folder, *, backend, address, resume, max_batch, progress, log, command, report, on_part,
         t_start, workers=None, existed=True) -> SweepResult:
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
    elif folder.exists() and any(folder.iterdir()):
        # killed while checking the draws (sweep.toml written, no manifest yet): start again
        if not (resume and _interrupted_start(folder, spec)):
            raise ConfigError(f"{folder} exists and is not empty; choose another --out (or --force to replace it)",
                              key="--out")
    if backend == "local" and workers is None:  # worker processes when the simulation is worth their start
        sim = spec.base.simulation
        workers = auto_workers(len(runs), round(sim.t_final / sim.dt), n_joints)
    be = make_backend(backend, address, workers)  # before writing anything: a missing Ray leaves no folder behind
    ready: dict = {}
    try:
        if manifest is None:
            from ..io import atomic_write_text

            try:
                store.prepare_folder(folder)
                atomic_write_text(folder / "sweep.toml", spec.to_toml(resolved=True))
                atomic_write_text(folder / "scenario.toml", spec.base.to_toml())
                manifest, ready = _plan(spec, runs, by_id, folder, be, n_joints, fingerprint,
                                        max_batch or DEFAULT_MAX_BATCH, progress, log, command, __version__)
            except OSError:  # a full disk, say, before the manifest: leave no folder --resume would refuse
                store.remove_started(folder, remove_folder=not existed)
                raise
        else:
            store.prepare_folder(folder)
            if max_batch is not None and max_batch != manifest.get("max_batch"):
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

    if manifest.get("format") != store.FORMAT:
        raise ConfigError(f"{folder} is a sweep in the older format {manifest.get('format')!r} (its held_contact "
                          "counts the start's force build-up; this hinfnn judges contact after verdict.contact_after): "
                          "a resumed table would mix the two; start it again with --force", key="--resume")
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
        progress(len(checked) / max(1, len(spec.controllers)), n_draws, CHECKING)

    progress(0, n_draws, CHECKING)
    be.check(chunks, done)
    checked.sort(key=lambda c: c["run"])
    ready = {c["run"]: c.pop("ready") for c in checked if c["ok"]}
    invalid = [invalid_row(by_id[c["run"]], c) for c in checked if not c["ok"]]
    store.write_table(folder / store.PARTS / store.INVALID_PART, store.rows_table(invalid, spec, n_joints))
    batches = plan_batches(checked, max_batch, parallel=getattr(be, "parallel", 1), share=getattr(be, "share", None))
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
        raise LoadError(f"{folder / store.PLAN} does not belong to {folder / store.MANIFEST}")
    batches = [Batch(id=i, group=g, size=n, runs=tuple(r), shared=bool(sh)) for i, g, n, r, sh in plan["batches"]]
    done = store.done_batches(folder)
    if resume:
        store.check_parts(folder, done)  # a damaged part stops here, before any work, saying what to do
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
        progress(state["finished"] + sum(in_flight.values()), total, SIMULATING)

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
    """Per controller: runs, invalid, simulated, bounded, held_contact, did_its_job, diverged."""
    out = {k: dict(runs=0, invalid=0, simulated=0, bounded=0, held_contact=0, did_its_job=0, diverged=0)
           for k in controllers}
    for r in rows:
        c = out.setdefault(r["controller"], dict(runs=0, invalid=0, simulated=0, bounded=0, held_contact=0,
                                                  did_its_job=0, diverged=0))
        c["runs"] += 1
        if r["status"] == "invalid":
            c["invalid"] += 1
            continue
        c["simulated"] += 1
        c["bounded"] += bool(r["bounded"])
        c["held_contact"] += bool(r["held_contact"])
        c["did_its_job"] += bool(r.get("did_its_job"))
        c["not_judged"] = c.get("not_judged", 0) + (r["bounded"] and r["held_contact"] is None)
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
    from ..scenario.setup import KIND_COLORS

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
        "labels": {k: KINDS[k].label for k in spec.controllers}, "colors": {k: KIND_COLORS.get(k, "") for k in spec.controllers},
        "samples": spec.samples, "seed": spec.seed, "points": spec.points, "varied": varied,
        "metrics": list(spec.metrics), "map_metric": spec.map_metric, "max_out_of_contact": spec.max_out_of_contact,
        "t_final": spec.base.simulation.t_final, "dt": spec.base.simulation.dt,
        "overrides": [[k, v] for k, v in spec.overrides], "command": manifest.get("command", ""),
        "sessions": sessions, "batches": manifest.get("n_batches", 0), "groups": manifest.get("n_groups", 0),
        "check_wall_s": manifest.get("check_wall_s"), "hinfnn_version": manifest.get("hinfnn_version"),
    }


__all__ = ["run_sweep", "prepare_output", "SweepOutput", "SweepResult", "write_outputs", "outcome_counts", "CHECKING",
           "SIMULATING"]
