"""Reading saved results back: a result folder or its ``trajectory.npz``, and ``metrics.json``."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import HinfnnError, LoadError
from .formats import FORMAT, SWEEP_MANIFEST


# --- loading ----------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SavedResult:
    """What :func:`load` returns: the runs, their scenarios, the folder's metrics."""

    trajectories: dict
    scenario: Any  # the folder's resolved Scenario (None if only an npz was given)
    metrics: dict | None
    version: str
    path: Path

    def to_pandas(self, run: str | None = None):
        """The trajectories as a pandas DataFrame: one row per stored sample, a ``run`` column,
        then one column per field component with its unit (``tau_1 [N·m]``); ``run`` selects
        one run. The same table as ``hinfnn export`` (see :mod:`hinfnn.io.export`)."""
        from .formats import to_pandas

        return to_pandas(self, run)

    @property
    def trajectory(self):
        """The single run's Trajectory (an error if the folder holds several)."""
        if len(self.trajectories) != 1:
            raise LoadError(f"{self.path} holds {len(self.trajectories)} runs "
                            f"({', '.join(self.trajectories)}); use .trajectories[name]")
        return next(iter(self.trajectories.values()))


def _legacy_tags(name: str) -> dict:
    """The study tags of a run of a paper-study folder written before runs carried tags (its runs
    were told apart by their names: ``hinf_nn_printed_damped``, ``hinf_exact``)."""
    base, damped = (name[:-len("_damped")], True) if name.endswith("_damped") else (name, False)
    if base not in ("fl", "hinf", "hinf_nn", "hinf_nn_printed", "hinf_exact"):
        return {}
    return {"contact": "damped" if damped else "undamped",
            "figures": None if base == "hinf_exact" else ("figs3-4" if base == "fl" else "figs5-9")}


def load_npz(path: Path) -> tuple[dict, str]:
    """Read a ``trajectory.npz``: ({name: Trajectory}, hinfnn version)."""
    from ..scenario import Scenario, describe
    from ..scenario.core import parse_toml
    from ..sim.trajectory import RunInfo, Trajectory

    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise LoadError(f"{path} does not exist") from None
    except Exception as err:  # BadZipFile, zlib.error, NotImplementedError, ValueError, OSError ...
        raise LoadError(f"{path} is not a readable hinfnn trajectory file (truncated or foreign): "
                        f"{type(err).__name__}: {err}") from None
    fmt = str(data.get("__format__", ""))
    if fmt != FORMAT:
        raise LoadError(f"{path} is not a hinfnn trajectory file (format {fmt or 'missing'!r}, "
                        f"expected {FORMAT!r})")
    if "__runs__" not in data or "__hinfnn_version__" not in data:
        raise LoadError(f"{path} is incomplete: no __runs__ or __hinfnn_version__")
    out = {}
    for name in [str(n) for n in np.atleast_1d(data["__runs__"])]:
        prefix = f"{name}/"
        try:
            arrays = {k[len(prefix):]: v for k, v in data.items()
                      if k.startswith(prefix) and "/__" not in k[len(prefix) - 1:]}
            final = {k[len(prefix) + 10:]: v for k, v in data.items() if k.startswith(prefix + "__final__/")}
            text = str(data[prefix + "__scenario__"])
            scenario = None
            if text:
                try:
                    scenario = Scenario.from_dict(parse_toml(text, f"{path}:{name}"), source=f"{path}:{name}",
                                                  check=False)
                except HinfnnError as err:
                    raise LoadError(f"{path}: run {name!r} has a scenario hinfnn cannot read: {err}") from None
            meta = {k: str(data[prefix + f"__{k}__"]) if prefix + f"__{k}__" in data else ""
                    for k in ("kind", "label", "color")}
            if prefix + "__tags__" in data:
                tags = json.loads(str(data[prefix + "__tags__"]))
            else:  # written before runs carried tags: what a report shows, from the stored scenario
                tags = {**(describe(scenario) if scenario is not None else {}), **_legacy_tags(name)}
            out[name] = Trajectory(
                arrays=arrays, status=data[prefix + "__status__"], t_fail=data[prefix + "__t_fail__"],
                fail_details={}, dt=float(data[prefix + "__dt__"]), save_every=int(data[prefix + "__save_every__"]),
                final=final, info=RunInfo(name=name, scenario=scenario, tags=tags, **meta))
        except KeyError as err:
            raise LoadError(f"{path}: run {name!r} is incomplete (missing {err})") from None
        if "t" not in arrays:
            raise LoadError(f"{path}: run {name!r} has no time array")
    return out, str(data["__hinfnn_version__"])


def not_a_sweep(folder) -> Path:
    """``folder``, unless it is a sweep's (a LoadError saying where a sweep's results are)."""
    if Path(folder).is_dir() and (Path(folder) / SWEEP_MANIFEST).exists():
        raise LoadError(f"{folder} is a sweep (it has {SWEEP_MANIFEST}), not a run's result: its table is "
                        f"{Path(folder) / 'results.parquet'} (hinfnn.load_sweep), its report and figures are "
                        f"{Path(folder) / 'report.md'} and the PNG files beside it")
    return folder


def load(path: str | Path) -> SavedResult:
    """Load a result folder written by ``hinfnn run``/``reproduce`` (or a ``trajectory.npz``).

    Returns the Trajectories by run name, the resolved scenario and the metrics.
    Raises :class:`LoadError` for a missing, truncated or foreign file, and for a sweep's folder
    (read with :func:`hinfnn.load_sweep`).
    """
    from ..errors import ConfigError
    from ..scenario import Scenario

    path = Path(not_a_sweep(path))
    folder = path if path.is_dir() else path.parent
    npz = path if path.is_file() else path / "trajectory.npz"
    if not folder.exists():
        raise LoadError(f"{folder} does not exist")
    runs, ver = load_npz(npz)
    scenario = None
    sc_file = folder / "scenario.toml"
    if path.is_dir():
        if not sc_file.exists():
            raise LoadError(f"{folder} has no scenario.toml")
        try:
            scenario = Scenario.load(sc_file, check=False)
        except ConfigError as err:
            raise LoadError(f"{sc_file} is not a valid hinfnn scenario: {err}") from None
    m_file = folder / "metrics.json"
    metrics = load_metrics(m_file) if m_file.exists() else None
    return SavedResult(trajectories=runs, scenario=scenario, metrics=metrics, version=ver, path=path)


def _check_metrics_format(m_file: Path, fmt) -> None:
    """A metrics document hinfnn can read: no ``format`` (hand-written), or ``hinfnn-metrics-N``
    with N at most this hinfnn's; a newer one (or another format) is refused, not read silently."""
    from ..results import FORMAT as METRICS_FORMAT

    if fmt is None:
        return
    mine = int(METRICS_FORMAT.rsplit("-", 1)[1])
    m = re.fullmatch(r"hinfnn-metrics-(\d+)", str(fmt))
    if m is None:
        raise LoadError(f"{m_file} is not a hinfnn metrics file (format {fmt!r}; this hinfnn reads "
                        f"hinfnn-metrics-1 to {METRICS_FORMAT})")
    if int(m.group(1)) > mine:
        raise LoadError(f"{m_file} was written by a newer hinfnn (format {fmt}; this hinfnn reads up to "
                        f"{METRICS_FORMAT}): upgrade hinfnn to read it")


def load_metrics(path: str | Path) -> dict:
    """The results document (``metrics.json``) of a result folder, or of the file given, checked
    for the layout hinfnn writes (a ``runs`` list of objects with ``name`` and ``metrics``).
    Needs nothing else of the folder. Raises :class:`LoadError` naming the file."""
    path = Path(path)
    m_file = path / "metrics.json" if path.is_dir() else path
    if not m_file.exists():
        where = path if path.is_dir() else path.parent
        raise LoadError(f"{where} does not exist" if not where.exists() else f"{where} has no metrics.json")
    try:
        metrics = json.loads(m_file.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise LoadError(f"{m_file} is not valid JSON (truncated?): {err}") from None
    except OSError as err:
        raise LoadError(f"{m_file} cannot be read: {err.strerror or err}") from None
    if not isinstance(metrics, dict) or not isinstance(metrics.get("runs"), list):
        raise LoadError(f"{m_file} is not a hinfnn metrics file (no \"runs\" list)")
    _check_metrics_format(m_file, metrics.get("format"))
    for i, run in enumerate(metrics["runs"]):
        if not isinstance(run, dict) or not isinstance(run.get("name"), str) or not isinstance(run.get("metrics"), dict):
            raise LoadError(f"{m_file} is not a hinfnn metrics file (run {i} has no \"name\" and \"metrics\")")
    return metrics
