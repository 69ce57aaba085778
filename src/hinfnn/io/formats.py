"""The formats of hinfnn's files: ``metrics.json`` as strict JSON, ``trajectory.npz``, and the
table of a saved run's samples (the rows of ``hinfnn export`` and ``to_pandas``).

``trajectory.npz`` stores, for each run NAME, the arrays as ``NAME/FIELD``, the run's resolved
scenario as ``NAME/__scenario__`` (TOML text), its tags (JSON text), status and time step; plus
``__format__``, ``__hinfnn_version__``, ``__runs__`` (the names in order) and ``__units__`` (JSON
text: the unit of every stored field).
"""

from __future__ import annotations

import io
import json
import math
from typing import Any

import numpy as np

from ..errors import ConfigError, LoadError
from ..fields import component_units, unit

FORMAT = "hinfnn-trajectory-1"
#: The file that makes a folder a sweep's (:mod:`hinfnn.sweep.store` writes it; :func:`hinfnn.load`
#: refuses such a folder, saying where its results are).
SWEEP_MANIFEST = "manifest.json"


def version() -> str:
    from .. import __version__

    return __version__


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
    stored = sorted({f for traj in runs.values() for f in traj.arrays if fields is None or f in fields})
    payload: dict[str, Any] = {
        "__format__": np.array(FORMAT),
        "__hinfnn_version__": np.array(version()),
        "__runs__": np.array(list(runs), dtype=str),
        "__units__": np.array(json.dumps({f: unit(f) for f in stored}, ensure_ascii=False)),
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
        payload[f"{name}/__tags__"] = np.array(json.dumps(_nan_to_none(dict(info.tags)), default=_json_default,
                                                          ensure_ascii=False))
    buf = io.BytesIO()
    np.savez_compressed(buf, **payload)
    return buf.getvalue()


# --- the table of a saved run's samples ------------------------------------------------------


def field_columns(name: str, arr: np.ndarray, tags: dict | None = None) -> list[tuple[str, np.ndarray]]:
    """The columns of one field: ``name [unit]`` for one number per sample (a scalar or a
    vector of one, as u1 and λ of the planar arm), else ``name_i [unit]`` (``name_i_j`` for
    matrices) for each component, 1-based. Each component's unit is the one the run's ``tags``
    declare for it (:func:`hinfnn.fields.component_units`: a joint's rad or m, a task coordinate's,
    λ's), else the field's unit."""
    arr = np.asarray(arr)
    count = math.prod(arr.shape[1:])
    units = component_units(name, count, tags) if arr.ndim == 2 or count == 1 else None
    units = units or [unit(name)] * count
    if arr.ndim == 1 or count == 1:
        return [(f"{name} [{units[0]}]", arr.reshape(arr.shape[0]))]
    flat = arr.reshape(arr.shape[0], -1)
    return [(f"{name}_{'_'.join(str(i + 1) for i in idx)} [{units[k]}]", flat[:, k])
            for k, idx in enumerate(np.ndindex(arr.shape[1:]))]


def _selected(result, run: str | None) -> list[tuple[str, object]]:
    trajs = result.trajectories
    if run is None:
        return list(trajs.items())
    if run not in trajs:
        raise LoadError(f"{result.path} has no run {run!r} (runs: {', '.join(trajs)})")
    return [(run, trajs[run])]


def table(result, run: str | None = None) -> tuple[list[str], list[str], dict[str, np.ndarray]]:
    """``(run names per row, column names, {column: values})`` of a :class:`~hinfnn.io.SavedResult`
    (``run``: only that run)."""
    per_run = []
    order: list[str] = []
    for name, traj in _selected(result, run):
        n = traj.valid_samples()
        cols = {}
        keys = ["t"] + [k for k in traj.arrays if k != "t"]
        for k in keys:
            for col, values in field_columns(k, np.asarray(traj.arrays[k])[:n], dict(traj.info.tags or {})):
                cols[col] = values
                if col not in order:
                    order.append(col)
        per_run.append((name, n, cols))
    runs = [name for name, n, _ in per_run for _ in range(n)]
    data = {}
    for col in order:
        parts = []
        for _, n, cols in per_run:
            v = cols.get(col)
            parts.append(np.asarray(v) if v is not None else np.full(n, np.nan))
        data[col] = np.concatenate(parts) if parts else np.empty(0)
    return runs, order, data


def to_pandas(result, run: str | None = None):
    """The table as a :class:`pandas.DataFrame` (column ``run``, then the fields with units)."""
    try:
        import pandas as pd
    except ImportError:
        raise ConfigError("needs pandas (pip install 'hinfnn[export]')", key="pandas") from None
    runs, cols, data = table(result, run)
    frame = {"run": pd.Series(runs, dtype="string") if runs else pd.Series([], dtype="string")}
    frame.update({c: data[c] for c in cols})
    return pd.DataFrame(frame)


__all__ = ["FORMAT", "dumps_json", "trajectory_npz_bytes", "table", "field_columns", "to_pandas", "version"]
