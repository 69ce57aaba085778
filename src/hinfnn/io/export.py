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

A file is written only where nothing is, or over a file hinfnn wrote (one its folder's marker
lists): every other existing file is the user's and is refused (:func:`export_target`), before
anything is written. The file is written aside and renamed into place.

CSV numbers are written exactly (Python's shortest round-trip representation: reading them
back gives the same float64 bits as ``trajectory.npz``); ``nan`` marks a missing value.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

from ..errors import ConfigError, LoadError
from .folders import MARKER, add_to_marker, atomic_write, check_writable, owns
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


def _result_dir(folder: Path) -> Path:
    return folder if folder.is_dir() else folder.parent


def export_target(folder, fmt: str, *, run: str | None = None, out=None) -> Path:
    """Where :func:`export` writes the table of the result ``folder`` as ``fmt``, checked before
    anything is written (:class:`~hinfnn.errors.ConfigError` keyed ``--out``, or ``export`` without
    ``out``): ``out`` a new file, an existing folder (``FOLDER/trajectory[-RUN].FMT`` in it) or a
    file hinfnn wrote (listed in its folder's marker); a symbolic link is followed. Any other
    existing file, a broken link, a folder that does not exist or cannot be written is refused."""
    if fmt not in ("csv", "parquet"):
        raise ConfigError(f"unknown format {fmt!r}; allowed: csv, parquet", key="format")
    folder = Path(folder)
    if not folder.exists():
        raise LoadError(f"{folder} does not exist")
    key = "--out" if out is not None else "export"
    target = Path(out) if out is not None else _result_dir(folder) / default_name(fmt, run)
    if target.is_dir():
        target = target / default_name(fmt, run)
    if target.is_symlink():
        if not target.exists():
            check_writable(target, key=key)  # a broken link: refused, saying so
        target = target.resolve()  # the link stays; the file it points to is what is written
    if not target.parent.is_dir():
        raise ConfigError(f"{target.parent} is not an existing folder", key=key)
    if target.exists() or target.is_symlink():
        if not target.is_file() or not owns(target):
            why = (f"not listed in {target.parent / MARKER}" if (target.parent / MARKER).exists()
                   else f"its folder has no {MARKER} listing what hinfnn wrote")
            raise ConfigError(f"{target} exists and hinfnn did not write it ({why}); export replaces only a file "
                              "hinfnn wrote: give a new file's path with --out, or move that file away", key=key)
    check_writable(target.parent, key=key)
    return target


def export(folder, fmt: str, *, run: str | None = None, out=None, target: Path | None = None) -> Path:
    """Write the table of the result ``folder`` as ``fmt`` ("csv" or "parquet") to ``out``
    (default: ``FOLDER/trajectory[-RUN].FMT``; checked by :func:`export_target`, or ``target``
    already checked). A file written into a result folder is recorded in its marker. Returns
    the path."""
    folder = Path(folder)
    result = load(folder)
    target = export_target(folder, fmt, run=run, out=out) if target is None else Path(target)
    data = csv_text(result, run) if fmt == "csv" else parquet_bytes(result, run)
    data = data.encode("utf-8") if isinstance(data, str) else data
    try:  # only a file hinfnn wrote is replaced: one that appeared meanwhile is kept
        atomic_write(target, lambda p: p.write_bytes(data), replace=target.exists() and owns(target))
    except FileExistsError:
        raise ConfigError(f"{target} appeared while the table was written; it is kept: give a new file's path",
                          key="--out" if out is not None else "export") from None
    except OSError as err:
        raise ConfigError(f"cannot write {target}: {err.strerror or err}",
                          key="--out" if out is not None else "export") from None
    add_to_marker(target.parent, [target.name])  # in a result folder: recorded as hinfnn's
    return target


__all__ = ["csv_text", "parquet_bytes", "export", "export_target", "default_name"]
