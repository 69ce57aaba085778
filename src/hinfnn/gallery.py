"""The gallery: the shipped arms-and-surfaces scenarios run end to end into one report.

``hinfnn gallery`` runs ``planar3-drum``, ``ur5-table`` and ``ur5-sphere`` (not the paper: that
is ``hinfnn reproduce``), each with the controllers it lists, and writes one folder::

    OUT/report.md                  setup, design, metrics and figures of every scenario, and the
                                   issue's expectations checked (status, dissipation, e_λ)
    OUT/<scenario>/metrics.json    as ``hinfnn run`` writes them
    OUT/<scenario>/trajectory.npz
    OUT/<scenario>/scenario.toml
    OUT/<scenario>/*.png

The folder appears only when everything is written (:class:`hinfnn.io.OutputFolder`).
"""

from __future__ import annotations

import time
from pathlib import Path

from .scenario import Scenario

#: The shipped scenarios the gallery runs, in order.
GALLERY = ("planar3-drum", "ur5-table", "ur5-sphere")


def gallery_scenarios(overrides=(), only=None) -> list[Scenario]:
    """The gallery's scenarios with ``overrides`` applied to each (every check run first, so a bad
    override fails before anything is simulated)."""
    names = list(only) if only else list(GALLERY)
    unknown = [n for n in names if n not in GALLERY]
    if unknown:
        from .errors import ConfigError

        raise ConfigError(f"{unknown} not in the gallery; allowed: {', '.join(GALLERY)}", key="only")
    return [Scenario.load(name, overrides) for name in names]


def run_gallery(out: Path | None = None, *, overrides=(), only=None, force: bool = False, progress=None, log=print,
                command: str = "hinfnn gallery") -> Path:
    """Run the gallery and write ``out`` atomically (default ``results/gallery``;
    reserved as for every command: :func:`hinfnn.io.reserve_output`); returns the folder
    written."""
    from .controllers import design_summary
    from .io import OutputFolder, atomic_write_bytes, atomic_write_text, dumps_json, reserve_output, \
        trajectory_npz_bytes
    from .report import run_figures
    from .report.gallery import gallery_report
    from .results import metrics_document, run_entry
    from .sim import simulate_many

    scenarios = gallery_scenarios(overrides, only)
    reservation = reserve_output(out, command="gallery", name="gallery", force=force)
    sections = []
    with reservation, OutputFolder(reservation, kind="gallery", command=command) as folder:
        if reservation.note:
            log(f"hinfnn: {reservation.note}")
        for sc in scenarios:
            t0 = time.perf_counter()
            runs = [sc.run(kind) for kind in sc.kinds]
            trajs = simulate_many(runs, progress=(lambda d, t, names, n=sc.name: progress(d, t, [n, *names]))
                                  if progress else None)
            seconds = time.perf_counter() - t0
            entries = [run_entry(r.name, trajs[r.name], overrides=dict(sc.overrides),
                                 design=design_summary(r.controller)) for r in runs]
            doc = metrics_document(sc, entries, command=command)
            sub = folder.path / sc.name
            sub.mkdir()
            atomic_write_text(sub / "metrics.json", dumps_json(doc))
            atomic_write_bytes(sub / "trajectory.npz", trajectory_npz_bytes(trajs, sc.simulation.output_interval))
            atomic_write_text(sub / "scenario.toml", sc.to_toml())
            t1 = time.perf_counter()
            figures = [Path(p).name for p in run_figures(trajs, sub)]
            sections.append({"scenario": sc, "doc": doc, "figures": figures, "seconds": seconds,
                             "figure_seconds": time.perf_counter() - t1})
            log(f"{sc.name}: {len(runs)} runs in {seconds:.0f} s")
        atomic_write_text(folder.path / "report.md", gallery_report(sections, command=command))
    return Path(folder.moved_to or reservation.target)


__all__ = ["GALLERY", "gallery_scenarios", "run_gallery"]
