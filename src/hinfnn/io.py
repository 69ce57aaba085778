"""Results on disk: atomic output folders, saving runs, loading them back.

A result folder holds ``metrics.json``, ``trajectory.npz``, ``scenario.toml`` and figures. It is
written as a whole: every file goes to a hidden temporary sibling folder first, and only a
complete folder is renamed into place (:class:`OutputFolder`). An interrupted or failed run
(exception, SIGINT, SIGTERM) removes the temporary folder and leaves the target as it was.

``trajectory.npz`` stores, for each run NAME, the arrays as ``NAME/FIELD``, the run's resolved
scenario as ``NAME/__scenario__`` (TOML text) and its status; plus ``__format__``,
``__hinfnn_version__`` and ``__runs__`` (the names in order). :func:`load` reads a folder (or the
npz file) back.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import os
import shutil
import signal
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .errors import HinfnnError

FORMAT = "hinfnn-trajectory-1"


class LoadError(HinfnnError, ValueError):
    """A result file is missing, truncated, or not written by hinfnn."""


def version() -> str:
    from . import __version__

    return __version__


# --- atomic files and folders ------------------------------------------------------------------


def atomic_write(path: Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp)`` for a temporary file beside ``path``, then rename it to ``path``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual mode
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: Path, text: str) -> Path:
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))


def atomic_write_bytes(path: Path, data: bytes) -> Path:
    return atomic_write(path, lambda p: p.write_bytes(data))


def _is_empty_dir(p: Path) -> bool:
    return p.is_dir() and not any(p.iterdir())


def choose_output(out: Path, force: bool) -> tuple[Path, str | None]:
    """Where to write: ``out`` if it is missing or empty or ``force``; else the first free
    ``out-2``, ``out-3`` … . Returns the folder and a sentence saying why it changed (or None)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        from .errors import ConfigError

        raise ConfigError(f"output path {out} exists and is not a folder", key="--out")
    if not out.exists() or _is_empty_dir(out) or force:
        return out, None
    i = 2
    while Path(f"{out}-{i}").exists():
        i += 1
    new = Path(f"{out}-{i}")
    return new, f"{out} is not empty; writing to {new} instead (use --force to replace it)"


class _Interrupted(BaseException):
    """Raised from the SIGTERM handler so that cleanup runs as for Ctrl-C."""


@contextlib.contextmanager
def _terminate_as_exception():
    def handler(signum, frame):
        raise _Interrupted(f"terminated by signal {signum}")

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not in the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class OutputFolder:
    """Context manager: files written into ``.path`` (a temporary folder) appear in ``target``
    only if the block completes; otherwise the target stays exactly as it was.

    With an existing target (``--force``) the old folder is moved aside, the new one renamed in
    and the old one deleted, with SIGINT/SIGTERM blocked during the two renames.
    """

    def __init__(self, target: Path):
        self.target = Path(target)
        self.path: Path | None = None

    def __enter__(self) -> "OutputFolder":
        self.target.parent.mkdir(parents=True, exist_ok=True)
        self.path = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.partial-", dir=self.target.parent))
        os.chmod(self.path, 0o777 & ~_umask())  # mkdtemp makes 0700
        self._signals = _terminate_as_exception()
        self._signals.__enter__()
        return self

    def __exit__(self, exc_type, exc, tb):
        try:
            if exc_type is None:
                self._commit()
        finally:
            if self.path is not None and self.path.exists():
                shutil.rmtree(self.path, ignore_errors=True)
            self._signals.__exit__(None, None, None)
        return False

    def _commit(self):
        blocked = {signal.SIGINT, signal.SIGTERM}
        old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, blocked)
        try:
            backup = None
            if self.target.exists():
                backup = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.old-", dir=self.target.parent))
                backup.rmdir()
                os.replace(self.target, backup)
            os.replace(self.path, self.target)
            if backup is not None:
                shutil.rmtree(backup, ignore_errors=True)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)


# --- saving ---------------------------------------------------------------------------------


def _json_default(o):
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _nan_to_none(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _nan_to_none(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_nan_to_none(v) for v in x]
    return x


def dumps_json(obj) -> str:
    """JSON with NaN/inf as null (strict JSON that any reader accepts)."""
    return json.dumps(_nan_to_none(obj), indent=2, default=_json_default, allow_nan=False) + "\n"


def trajectory_npz_bytes(runs: dict, max_interval: float | None = 1e-3, fields=None) -> bytes:
    """The ``trajectory.npz`` content for named Trajectories (decimated to ``max_interval``;
    ``fields``: only these arrays)."""
    payload: dict[str, Any] = {
        "__format__": np.array(FORMAT),
        "__hinfnn_version__": np.array(version()),
        "__runs__": np.array(list(runs), dtype=str),
    }
    for name, traj in runs.items():
        if "/" in name:
            raise ValueError(f"run name {name!r} must not contain '/'")
        t = traj.decimated(max_interval) if max_interval else traj
        for field, arr in t.arrays.items():
            if fields is None or field in fields:
                payload[f"{name}/{field}"] = arr
        for field, arr in t.final.items():
            payload[f"{name}/__final__/{field}"] = arr
        payload[f"{name}/__status__"] = np.asarray(t.status)
        payload[f"{name}/__t_fail__"] = np.asarray(t.t_fail)
        payload[f"{name}/__dt__"] = np.asarray(t.dt)
        payload[f"{name}/__save_every__"] = np.asarray(t.save_every)
        info = t.info
        payload[f"{name}/__scenario__"] = np.array(info.scenario.to_toml() if info.scenario is not None else "")
        payload[f"{name}/__kind__"] = np.array(info.kind)
        payload[f"{name}/__label__"] = np.array(info.label)
        payload[f"{name}/__color__"] = np.array(info.color)
    buf = io.BytesIO()
    np.savez_compressed(buf, **payload)
    return buf.getvalue()


# --- loading ----------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SavedResult:
    """What :func:`load` returns: the runs, their scenarios, the folder's metrics."""

    trajectories: dict
    scenario: Any  # the folder's resolved Scenario (None if only an npz was given)
    metrics: dict | None
    version: str
    path: Path

    @property
    def trajectory(self):
        """The single run's Trajectory (an error if the folder holds several)."""
        if len(self.trajectories) != 1:
            raise LoadError(f"{self.path} holds {len(self.trajectories)} runs "
                            f"({', '.join(self.trajectories)}); use .trajectories[name]")
        return next(iter(self.trajectories.values()))


def load_npz(path: Path) -> tuple[dict, str]:
    """Read a ``trajectory.npz``: ({name: Trajectory}, hinfnn version)."""
    from .scenario import Scenario
    from .scenario.core import parse_toml
    from .sim.trajectory import RunInfo, Trajectory

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
            out[name] = Trajectory(
                arrays=arrays, status=data[prefix + "__status__"], t_fail=data[prefix + "__t_fail__"],
                fail_details={}, dt=float(data[prefix + "__dt__"]), save_every=int(data[prefix + "__save_every__"]),
                final=final, info=RunInfo(name=name, scenario=scenario, **meta))
        except KeyError as err:
            raise LoadError(f"{path}: run {name!r} is incomplete (missing {err})") from None
        if "t" not in arrays:
            raise LoadError(f"{path}: run {name!r} has no time array")
    return out, str(data["__hinfnn_version__"])


def load(path: str | Path) -> SavedResult:
    """Load a result folder written by ``hinfnn run``/``reproduce`` (or a ``trajectory.npz``).

    Returns the Trajectories by run name, the resolved scenario and the metrics.
    Raises :class:`LoadError` for a missing, truncated or foreign file.
    """
    from .errors import ConfigError
    from .scenario import Scenario

    path = Path(path)
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
    metrics = None
    m_file = folder / "metrics.json"
    if m_file.exists():
        try:
            metrics = json.loads(m_file.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise LoadError(f"{m_file} is not valid JSON (truncated?): {err}") from None
        if not isinstance(metrics, dict) or not isinstance(metrics.get("runs"), list):
            raise LoadError(f"{m_file} is not a hinfnn metrics file (no \"runs\" list)")
    return SavedResult(trajectories=runs, scenario=scenario, metrics=metrics, version=ver, path=path)
