"""Redraw the figures of a saved result (``hinfnn plot``) from its ``trajectory.npz``."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import ConfigError
from .figures import PAPER_FIGURES, RUN_FIGURES, paper_figures, run_figures


def is_study(folder: Path) -> bool:
    """Whether a result folder holds the paper study (``hinfnn reproduce``) rather than runs."""
    from ..io import read_marker

    marker = read_marker(folder)
    if marker is not None:
        return marker.get("kind") == "study"
    return (Path(folder) / "report.md").exists()


def replot(folder, *, only: Sequence[str] | None = None, out=None,
           zoom_windows: Sequence[tuple[float, float]] | None = None) -> list[Path]:
    """Draw the figures of the result ``folder`` again from its trajectory.npz: a run's figures
    (:func:`run_figures`) or, for the paper study, Figs. 3–9 for both contacts
    (:func:`paper_figures`). ``only``: the figures to draw (names without ``.png``); ``out``:
    another folder for them (created if needed; files there that hinfnn did not write are never
    replaced); ``zoom_windows``: the two (start, end) times of the zoom panels. Returns the
    paths written. The study's own figures were drawn from every step; redrawn ones use the
    stored samples (``simulation.output_interval``)."""
    from ..io import MARKER, add_to_marker, foreign_files, load
    from ..io.folders import check_writable

    folder = Path(folder)
    result = load(folder)
    study = folder.is_dir() and is_study(folder)
    names = PAPER_FIGURES if study else RUN_FIGURES
    if only is not None:
        unknown = [n for n in only if n not in names]
        if unknown:
            raise ConfigError(f"unknown figure(s) {', '.join(unknown)}; this {'study' if study else 'result'} "
                              f"has {', '.join(names)}", key="--figures")
    if zoom_windows is not None:
        _check_zoom(result.trajectories.values(), zoom_windows)
    dest = Path(out) if out is not None else (folder if folder.is_dir() else folder.parent)
    key = "--out" if out is not None else "plot"
    if dest.exists() or dest.is_symlink():
        if not dest.is_dir():
            raise ConfigError(f"{dest} exists and is not a folder" + (" (a broken symbolic link)" if not dest.exists()
                                                                      else ""), key=key)
        pngs = {f"{n}{s}.png" for n in (only or names) for s in (("", "_damped") if study else ("",))}
        clash = sorted(set(foreign_files(dest)) & pngs)
        if clash:
            raise ConfigError(f"{dest} holds {', '.join(clash)} that hinfnn did not write (not listed in its "
                              f"{MARKER}); plot replaces only figures hinfnn drew: choose another --out, or move "
                              "them away", key=key)
    check_writable(dest, key=key)
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"cannot create folder {dest}: {err.strerror or err}", key=key) from None
    if study:  # the study's runs by their contact tag (their ``figures`` tag says which figures)
        written = []
        for contact, suffix in (("undamped", ""), ("damped", "_damped")):
            runs = {n: t for n, t in result.trajectories.items() if t.info.tags.get("contact") == contact}
            written += paper_figures(runs, dest, suffix=suffix, only=only, zoom_windows=zoom_windows)
    else:
        written = run_figures(result.trajectories, dest, only=only, zoom_windows=zoom_windows)
    add_to_marker(dest, [p.name for p in written])
    return written


def _check_zoom(trajectories, windows) -> None:
    """Each zoom window holds at least one stored sample of the runs (up to each run's stop):
    else its panels would be empty, a ConfigError naming ``--zoom``, the window and what the runs
    cover."""
    times = [np.asarray(t.arrays["t"])[:t.valid_samples()] for t in trajectories]
    for a, b in windows:
        if not any(np.any((t >= a) & (t <= b)) for t in times):
            lo = min((float(t[0]) for t in times if t.size), default=0.0)
            hi = max((float(t[-1]) for t in times if t.size), default=0.0)
            raise ConfigError(f"the window {a:g}:{b:g} s holds no stored sample of the runs (they cover {lo:g} to "
                              f"{hi:g} s); give windows inside the runs", key="--zoom")

