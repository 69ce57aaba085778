"""``hinfnn run`` as a library call: reserve the output folder, check that the runs fit, simulate,
write the result folder (metrics.json, trajectory.npz, scenario.toml, figures) atomically."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path


def result_name(sc) -> str:
    """The name a result of ``sc`` is filed under: the scenario's name, or the file's stem when
    the scenario is a file that does not set ``name`` itself (a file with only ``base = "paper"``
    is not the paper scenario)."""
    src = Path(sc.source) if sc.source and not sc.source.startswith("<") else None
    if src is not None and src.is_file():
        try:
            raw = tomllib.loads(src.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            raw = {}
        if "name" not in raw:
            return src.stem
    return sc.name


@dataclasses.dataclass
class RunResult:
    target: Path          # the folder written
    doc: dict             # metrics.json
    note: str | None      # why the folder is not the one asked for (or None)


def run_scenario(sc, *, out=None, force: bool = False, fields=None, progress=None, command: str = "",
                 log=print, figures: bool = True) -> RunResult:
    """Simulate every controller of ``sc`` and write the result folder.

    ``out``: the folder (None: ``results/runs/<name>-<UTC time>``), reserved before anything
    runs (:func:`hinfnn.io.reserve_output`; ``force`` as there). ``fields``: what the runs store
    (None: everything; ``"metrics"``; names). Refuses with :class:`hinfnn.resources.ResourceError`
    when the stored samples would not fit in memory; ``log`` gets one line with the estimate
    before a run longer than a minute and the note when the folder changed. ``figures=False``:
    no PNG files (everything else is the same; ``hinfnn plot`` draws them later).
    """
    from . import _startup, resources
    from .controllers import design_summary
    from .io import OutputFolder, atomic_write_bytes, atomic_write_text, dumps_json, reserve_output, \
        trajectory_npz_bytes
    from .results import metrics_document, run_entry
    from .sim import simulate_many

    reservation = reserve_output(out, command="run", name=result_name(sc), force=force)
    with reservation:
        runs = [sc.run(kind) for kind in sc.kinds]
        plan = resources.plan(runs, fields=fields)
        resources.check(plan, alternatives=lambda: resources.plan(runs, fields="metrics"))
        if reservation.note:
            log(f"hinfnn: {reservation.note}")
        if plan.seconds > 60:
            log(f"hinfnn: {plan.summary()}")
        with OutputFolder(reservation, kind="run", command=command) as folder:
            trajs = simulate_many(runs, progress=progress, fields=fields)
            _startup.mark("simulated")
            if progress is not None and hasattr(progress, "done"):
                progress.done()
            entries = [run_entry(r.name, trajs[r.name], overrides=dict(sc.overrides),
                                 design=design_summary(r.controller)) for r in runs]
            doc = metrics_document(sc, entries, command=command)
            atomic_write_text(folder.path / "metrics.json", dumps_json(doc))
            atomic_write_bytes(folder.path / "trajectory.npz",
                               trajectory_npz_bytes(trajs, sc.simulation.output_interval))
            atomic_write_text(folder.path / "scenario.toml", sc.to_toml())
            _startup.mark("files_written")
            if figures:
                from .report import run_figures  # matplotlib (0.5 s): imported once the simulation is done

                run_figures(trajs, folder.path)
                _startup.mark("figures_written")
    target = folder.moved_to or reservation.target
    note = None
    if folder.moved_to is not None:
        note = (f"files hinfnn did not write appeared in {reservation.target} during the run; "
                f"the result is in {folder.moved_to} instead")
    return RunResult(target=Path(target), doc=doc, note=note)
