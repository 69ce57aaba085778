"""A saved run's trajectories as a table: CSV, Parquet, pandas.

One row per stored sample; the first column is ``run`` (the run's name), then ``t [s]`` and one
column per component of every stored field, named with the field, the component (1-based, as
the paper's τ1, τ2; none for a field of one number per sample) and the unit of
:data:`hinfnn.fields.FIELDS`: ``tau_1 [N·m]``,
``tau_2 [N·m]``, ``lam [λ units]``, ``J [-]``. Runs are stacked in the folder's order; a field
one run does not store is empty (NaN) in the others' rows. A run that stopped early (diverged)
is exported up to its last sample at or before ``t_fail`` (the simulator repeats the last good
state after it), as its metrics and figures are.

CSV numbers are written exactly (Python's shortest round-trip representation: reading them
back gives the same float64 bits as ``trajectory.npz``); ``nan`` marks a missing value.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from .errors import ConfigError, LoadError
from .fields import unit


def _rows_of(traj) -> int:
    """Samples that belong to the run: all, or those up to t_fail for a run that stopped."""
    t = np.asarray(traj.arrays["t"])
    if int(np.asarray(traj.status).reshape(())) == 0:
        return len(t)
    tf = float(np.asarray(traj.t_fail).reshape(()))
    if not math.isfinite(tf):
        return len(t)
    return max(1, int(np.searchsorted(t, tf + 1e-12 * max(1.0, abs(tf)), side="right")))


def field_columns(name: str, arr: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The columns of one field: ``name [unit]`` for one number per sample (a scalar or a
    vector of one, as u1 and λ of the planar arm), else ``name_i [unit]`` (``name_i_j`` for
    matrices) for each component, 1-based."""
    arr = np.asarray(arr)
    u = unit(name)
    if arr.ndim == 1 or math.prod(arr.shape[1:]) == 1:
        return [(f"{name} [{u}]", arr.reshape(arr.shape[0]))]
    flat = arr.reshape(arr.shape[0], -1)
    return [(f"{name}_{'_'.join(str(i + 1) for i in idx)} [{u}]", flat[:, k])
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
        n = _rows_of(traj)
        cols = {}
        keys = ["t"] + [k for k in traj.arrays if k != "t"]
        for k in keys:
            for col, values in field_columns(k, np.asarray(traj.arrays[k])[:n]):
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


def _text(v) -> str:
    return repr(v) if isinstance(v, float) else str(v)


def csv_text(result, run: str | None = None) -> str:
    """The table as CSV text (header row, then one row per sample)."""
    runs, cols, data = table(result, run)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["run", *cols])
    columns = [runs] + [list(map(_text, data[c].tolist())) for c in cols]
    w.writerows(zip(*columns))
    return buf.getvalue()


def _pandas():
    try:
        import pandas as pd
    except ImportError:
        raise ConfigError("needs pandas (pip install 'hinfnn[export]')", key="pandas") from None
    return pd


def to_pandas(result, run: str | None = None):
    """The table as a :class:`pandas.DataFrame` (column ``run``, then the fields with units)."""
    pd = _pandas()
    runs, cols, data = table(result, run)
    frame = {"run": pd.Series(runs, dtype="string") if runs else pd.Series([], dtype="string")}
    frame.update({c: data[c] for c in cols})
    return pd.DataFrame(frame)


def parquet_bytes(result, run: str | None = None) -> bytes:
    """The table as Parquet (pyarrow), with the units also in the schema's metadata."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise ConfigError("needs pyarrow (pip install 'hinfnn[export]')", key="--parquet") from None
    runs, cols, data = table(result, run)
    tbl = pa.table({"run": pa.array(runs, type=pa.string()), **{c: pa.array(data[c]) for c in cols}})
    tbl = tbl.replace_schema_metadata({"hinfnn.units": "column names end with [unit]; λ units: see "
                                                        "docs/paper-conventions.md"})
    buf = io.BytesIO()
    pq.write_table(tbl, buf)
    return buf.getvalue()


def default_name(fmt: str, run: str | None) -> str:
    """``trajectory.csv`` or ``trajectory-NAME.csv`` (``fmt``: csv or parquet)."""
    return f"trajectory{'-' + run if run else ''}.{fmt}"


def export(folder, fmt: str, *, run: str | None = None, out=None) -> Path:
    """Write the table of the result ``folder`` as ``fmt`` ("csv" or "parquet") to ``out``
    (default: ``FOLDER/trajectory[-RUN].FMT``, recorded in the folder's marker). Returns the path."""
    from .io import add_to_marker, atomic_write_bytes, atomic_write_text, load

    if fmt not in ("csv", "parquet"):
        raise ConfigError(f"unknown format {fmt!r}; allowed: csv, parquet", key="format")
    folder = Path(folder)
    result = load(folder)
    target = Path(out) if out is not None else (folder if folder.is_dir() else folder.parent) / default_name(fmt, run)
    if target.is_dir():
        target = target / default_name(fmt, run)
    if not target.parent.is_dir():
        raise ConfigError(f"{target.parent} is not an existing folder", key="--out")
    try:
        if fmt == "csv":
            atomic_write_text(target, csv_text(result, run))
        else:
            atomic_write_bytes(target, parquet_bytes(result, run))
    except PermissionError as err:
        raise ConfigError(f"cannot write {target}: {err.strerror}", key="--out") from None
    if target.parent.resolve() == (folder if folder.is_dir() else folder.parent).resolve():
        add_to_marker(target.parent, [target.name])
    return target


__all__ = ["table", "csv_text", "to_pandas", "parquet_bytes", "export", "field_columns"]
