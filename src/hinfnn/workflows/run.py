"""``hinfnn run`` as a library call: one case per controller of a scenario, simulated and written as
a result folder (metrics.json, trajectory.npz, scenario.toml, figures), atomically."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..experiment import cases, result_folder, run_cases
from ..scenario.core import parse_toml


def result_name(sc) -> str:
    """The name a result of ``sc`` is filed under: the scenario's name, or the file's stem when
    the scenario is a file that does not set ``name`` itself (a file with only ``base = "paper"``
    is not the paper scenario)."""
    src = Path(sc.source) if sc.source and not sc.source.startswith("<") else None
    if src is not None and src.is_file():
        try:
            raw = parse_toml(src.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            raw = {}
        if "name" not in raw:
            return src.stem
    return sc.name


@dataclasses.dataclass
class RunResult:
    target: Path          # the folder written
    doc: dict             # metrics.json
    note: str | None      # why the result is not in the reserved folder (files appeared there meanwhile), or None


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
    from .. import _startup

    todo = cases(sc, overrides=dict(sc.overrides))
    with result_folder(out, command="run", name=result_name(sc), kind="run", force=force, log=log,
                       command_line=command) as written:
        def done(outcome):  # simulated: the files are written next
            _startup.mark("simulated")
            if progress is not None and hasattr(progress, "done"):
                progress.done()
            return None

        outcome, doc = run_cases(todo, written.path, sc, command=command, fields=fields, progress=progress, log=log,
                                 document=done)
        _startup.mark("files_written")
        if figures:
            from ..report import run_figures  # matplotlib: imported once the simulation is done

            run_figures(outcome.trajectories, written.path)
            _startup.mark("figures_written")
    return RunResult(target=written.path, doc=doc, note=written.moved)


__all__ = ["result_name", "RunResult", "run_scenario"]
