"""A saved run's trajectories as a table: CSV, Parquet, pandas.

One row per stored sample; the first column is ``run`` (the run's name), then ``t [s]`` and one
column per component of every stored field, named with the field, the component (1-based, as
the paper's τ1, τ2; none for a field of one number per sample) and the component's unit as the
run declares it (:func:`hinfnn.fields.component_units`: a joint's rad or m and its effort N·m or
N, a task coordinate's m or rad and the force or moment conjugate to it, λ's unit from the
constraint), else the field's unit of :data:`hinfnn.fields.FIELDS`: ``tau_1 [N·m]``, ``q_7 [m]``,
``e_u1_3 [rad]``, ``F_4 [N·m]``, ``lam [N]``, ``J [-]`` (:func:`hinfnn.io.formats.table`). Runs are stacked in the folder's order; a field one run does
not store is empty (NaN) in the others' rows. A run that stopped early (diverged) is exported up
to its last sample at or before ``t_fail`` (the simulator repeats the last good state after it),
as its metrics and figures are.

CSV numbers are written exactly (Python's shortest round-trip representation: reading them
back gives the same float64 bits as ``trajectory.npz``); ``nan`` marks a missing value.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from ..errors import ConfigError
from .folders import add_to_marker, atomic_write_bytes, atomic_write_text
from .formats import table
from .load import load


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


def parquet_bytes(result, run: str | None = None) -> bytes:
    """The table as Parquet (pyarrow), with the units also in the schema's metadata."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise ConfigError("needs pyarrow (pip install 'hinfnn[export]')", key="--parquet") from None
    runs, cols, data = table(result, run)
    tbl = pa.table({"run": pa.array(runs, type=pa.string()), **{c: pa.array(data[c]) for c in cols}})
    tbl = tbl.replace_schema_metadata({"hinfnn.units": "column names end with [unit], each component's from the run's "
                                                        "joints, task coordinates and constraint"})
    buf = io.BytesIO()
    pq.write_table(tbl, buf)
    return buf.getvalue()


def default_name(fmt: str, run: str | None) -> str:
    """``trajectory.csv`` or ``trajectory-NAME.csv`` (``fmt``: csv or parquet)."""
    return f"trajectory{'-' + run if run else ''}.{fmt}"


def export(folder, fmt: str, *, run: str | None = None, out=None) -> Path:
    """Write the table of the result ``folder`` as ``fmt`` ("csv" or "parquet") to ``out``
    (default: ``FOLDER/trajectory[-RUN].FMT``, recorded in the folder's marker). Returns the path."""
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


__all__ = ["csv_text", "parquet_bytes", "export", "default_name"]
