"""A sweep on disk: Parquet parts written atomically as batches finish, a manifest, the table.

Layout of a sweep folder::

    sweep.toml          the spec as run (--samples and --set folded in): `hinfnn sweep sweep.toml`
                        runs it again
    scenario.toml       the resolved base scenario
    manifest.json       format, hinfnn version, the spec's fingerprint, the batches done with
                        their wall time and worker, the sessions (backend, start, wall time)
    plan.json           the batches: [id, compiled group, size, [run numbers]], fixed once the
                        draws are checked
    parts/invalid.parquet        the runs that could not start (status "invalid"), written
                                 before any batch runs
    parts/batch-000012.parquet   the rows of batch 12, written when it finished
    results.parquet     every row sorted by run, written when the last batch finished
    report.md, *.png    the report and its figures

Every file is written to a temporary sibling and renamed into place, so a part either exists
whole or not at all: a sweep killed at any moment loses at most the batches in flight, and
``--resume`` reruns exactly those (the plan in the manifest fixes the batches, so the resumed
table is bit-identical to an uninterrupted one). pyarrow and pandas are imported only here and
only when a table is read or written (``pip install hinfnn[sweep]``).
"""

from __future__ import annotations

import datetime
import json
import os
from pathlib import Path

from ..errors import ConfigError
from ..io import SWEEP_MANIFEST, LoadError, atomic_write, atomic_write_text, dumps_json
from ..io.folders import INSIDE_PREFIX
from ..metrics import METRIC_KEYS, UNITS
from .spec import BOOL_METRICS, PER_COORDINATE_METRICS, PER_JOINT_METRICS

FORMAT = "hinfnn-sweep-2"
#: Formats :func:`load_sweep` still reads: ``hinfnn-sweep-1`` tables judged ``held_contact`` over the whole
#: run (the start's force build-up included) and have no ``out_of_contact_after``, ``tracked``,
#: ``did_its_job`` columns; a sweep in that format cannot be resumed (its rows would mix two criteria).
READABLE_FORMATS = (FORMAT, "hinfnn-sweep-1")
MANIFEST = SWEEP_MANIFEST
PLAN = "plan.json"
PARTS = "parts"
RESULTS = "results.parquet"
INVALID_PART = "invalid.parquet"

#: Columns every table has, before the varied keys.
ID_COLUMNS = ("run", "point", "sample", "controller")
#: Columns after the varied keys, before the metrics.
STATUS_COLUMNS = ("status", "reason", "error_key", "t_fail")
#: Columns after the metrics.
TAIL_COLUMNS = ("t_end", "partial", "bounded", "held_contact", "out_of_contact_after", "tracked", "did_its_job")
STATUSES = ("ok", "diverged", "invalid")


def metric_columns(n_joints: int) -> list[str]:
    """The metric columns of the table: every metric of :func:`hinfnn.compute_metrics`, the
    per-joint ones as ``NAME_1`` ... ``NAME_n``, the per-coordinate ones as one list column."""
    cols = []
    for k in METRIC_KEYS:
        if k in PER_JOINT_METRICS:
            cols += [f"{k}_{i + 1}" for i in range(n_joints)]
        else:
            cols.append(k)
    return cols


def column_units(n_joints: int) -> dict[str, str]:
    units = {}
    for k in METRIC_KEYS:
        if k in PER_JOINT_METRICS:
            units.update({f"{k}_{i + 1}": UNITS[k] for i in range(n_joints)})
        else:
            units[k] = UNITS[k]
    units.update(t_fail="s", t_end="s", out_of_contact_after="-")
    return units


def varied_type(v) -> str:
    """The column type of a varied key: "double", "int64", "string" or "list<double>"."""
    if v.list_valued:
        return "list<double>"
    if not v.how.is_grid:
        return "double"
    values = v.how.grid()
    if all(isinstance(x, str) for x in values):
        return "string"
    if isinstance(v.base, int) and not isinstance(v.base, bool) and all(float(x).is_integer() for x in values
                                                                        if not isinstance(x, str)):
        return "int64"
    if all(isinstance(x, (int, float)) for x in values):
        return "double"
    return "string"


def schema(spec, n_joints: int):
    """The Arrow schema of a sweep's table (the same for every part)."""
    import pyarrow as pa

    types = {"double": pa.float64(), "int64": pa.int64(), "string": pa.string(),
             "list<double>": pa.list_(pa.float64())}
    fields = [pa.field("run", pa.int64()), pa.field("point", pa.int64()), pa.field("sample", pa.int64()),
              pa.field("controller", pa.string())]
    fields += [pa.field(v.key, types[varied_type(v)]) for v in spec.varied]
    fields += [pa.field("status", pa.string()), pa.field("reason", pa.string()), pa.field("error_key", pa.string()),
               pa.field("t_fail", pa.float64())]
    fields += [pa.field(c, pa.bool_() if c in BOOL_METRICS else pa.list_(pa.float64()) if c in PER_COORDINATE_METRICS
                        else pa.float64()) for c in metric_columns(n_joints)]
    fields += [pa.field("t_end", pa.float64()), pa.field("partial", pa.bool_()), pa.field("bounded", pa.bool_()),
               pa.field("held_contact", pa.bool_()), pa.field("out_of_contact_after", pa.float64()),
               pa.field("tracked", pa.bool_()), pa.field("did_its_job", pa.bool_())]
    meta = {"hinfnn_sweep": json.dumps({"format": FORMAT, "spec": spec.name, "units": column_units(n_joints)})}
    return pa.schema(fields, metadata=meta)


def _cell(value, kind: str):
    if value is None:
        return None
    if kind == "string":
        return value if isinstance(value, str) else repr(value)
    return value


def rows_table(rows: list[dict], spec, n_joints: int):
    """An Arrow table of rows (dicts with the table's columns; missing columns are null)."""
    import pyarrow as pa

    sch = schema(spec, n_joints)
    kinds = {v.key: varied_type(v) for v in spec.varied}
    cols = {}
    for f in sch:
        name = f.name
        kind = kinds.get(name)
        vals = [r.get(name) for r in rows]
        if kind is not None:
            vals = [_cell(x, kind) for x in vals]
        cols[name] = pa.array(vals, type=f.type)
    return pa.table(cols, schema=sch)


def write_table(path: Path, table) -> Path:
    """Write an Arrow table as Parquet, atomically."""
    import pyarrow.parquet as pq

    return atomic_write(Path(path), lambda p: pq.write_table(table, p, compression="zstd"))


# --- the folder ------------------------------------------------------------------------------------


def now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def part_name(batch_id: int) -> str:
    return f"batch-{batch_id:06d}.parquet"


def read_manifest(folder: Path) -> dict:
    """The manifest of a sweep folder (LoadError if missing, truncated or foreign)."""
    path = Path(folder) / MANIFEST
    if not path.exists():
        raise LoadError(f"{folder} is not a sweep folder (no {MANIFEST})")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, OSError) as err:
        raise LoadError(f"{path} is not valid JSON: {err}") from None
    if not isinstance(doc, dict) or doc.get("format") not in READABLE_FORMATS:
        raise LoadError(f"{path} is not a hinfnn sweep manifest (format {doc.get('format') if isinstance(doc, dict) else None!r}, "
                        f"expected {FORMAT!r})")
    return doc


def write_manifest(folder: Path, doc: dict) -> None:
    atomic_write_text(Path(folder) / MANIFEST, dumps_json(doc))


def write_plan(folder: Path, plan: dict) -> None:
    atomic_write_text(Path(folder) / PLAN, json.dumps(plan, separators=(",", ":")) + "\n")


def read_plan(folder: Path) -> dict:
    """The plan of a sweep folder (LoadError if missing, cut or not a plan: the sweep cannot be
    resumed then, only started again)."""
    path = Path(folder) / PLAN
    again = "; the sweep's batches are unknown without it: start the sweep again (--force)"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise LoadError(f"{folder} has no {PLAN}{again}") from None
    except (json.JSONDecodeError, UnicodeDecodeError, OSError) as err:
        raise LoadError(f"{path} is damaged (not valid JSON: {err}){again}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("batches"), list) or \
            not all(isinstance(b, list) and len(b) == 5 for b in doc["batches"]):
        raise LoadError(f"{path} is not a sweep's plan (no list of batches){again}")
    return doc


def require_pyarrow() -> None:
    """Refuse a sweep before anything is created when pyarrow, which writes its table, is missing."""
    try:
        import pyarrow  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        raise ConfigError("a sweep writes its table with pyarrow, which is not installed: pip install "
                          "'hinfnn[sweep]'", key="sweep") from None


def check_parts(folder: Path, batches) -> None:
    """Every finished part of ``batches`` readable (its Parquet footer intact), or a LoadError that
    names the damaged part and says that deleting it lets ``--resume`` compute its batch again."""
    import pyarrow.parquet as pq

    for b in sorted(batches):
        p = Path(folder) / PARTS / part_name(b)
        try:
            pq.read_metadata(p)
        except Exception as err:  # noqa: BLE001 - pyarrow raises several types for damaged files
            raise LoadError(_damaged_part(p, err)) from None


def _damaged_part(p: Path, err: Exception) -> str:
    fix = ("delete it and run the same command with --resume: its batch is computed again"
           if p.name.startswith("batch-") else "start the sweep again (--force)")
    return f"{p} is damaged (cut, or not Parquet: {type(err).__name__}: {err}); {fix}"


#: What a sweep writes before its manifest (a sweep stopped then holds nothing else).
_STARTED = {"sweep.toml", "scenario.toml", PLAN, PARTS}


def started_only(folder: Path) -> bool:
    """Whether ``folder`` holds only what a sweep writes before its manifest (and no manifest)."""
    folder = Path(folder)
    if not folder.is_dir() or is_sweep_folder(folder):
        return False
    names = {p.name for p in folder.iterdir() if not p.name.endswith(".part")}
    parts = folder / PARTS
    inside = {p.name for p in parts.iterdir() if not p.name.endswith(".part")} if parts.is_dir() else set()
    return bool(names) and names <= _STARTED and inside <= {INVALID_PART}


def remove_started(folder: Path, *, remove_folder: bool) -> None:
    """Remove what a sweep wrote before its manifest (and the folder, if it made it)."""
    folder = Path(folder)
    if not started_only(folder) and not (folder.is_dir() and not any(folder.iterdir())):
        return
    clean_temporaries(folder)
    for name in ("sweep.toml", "scenario.toml", PLAN, f"{PARTS}/{INVALID_PART}", PARTS):
        p = folder / name
        try:
            p.rmdir() if p.is_dir() else p.unlink()
        except OSError:
            pass
    if remove_folder:
        try:
            folder.rmdir()
        except OSError:
            pass


def done_batches(folder: Path) -> set[int]:
    """Batches whose part is on disk (a part exists only whole)."""
    parts = Path(folder) / PARTS
    out = set()
    if parts.is_dir():
        for p in parts.glob("batch-*.parquet"):
            try:
                out.add(int(p.stem.split("-", 1)[1]))
            except ValueError:
                continue
    return out


def clean_temporaries(folder: Path) -> int:
    """Remove the temporary files of writes that were interrupted (``.NAME.xxxx.part``)."""
    n = 0
    for sub in (Path(folder), Path(folder) / PARTS):
        if sub.is_dir():
            for p in sub.glob(".*.part"):
                try:
                    p.unlink()
                    n += 1
                except OSError:
                    pass
    return n


def read_parts(folder: Path):
    """Every row on disk (invalid part and batch parts) as one Arrow table sorted by run."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    parts = Path(folder) / PARTS
    files = sorted(parts.glob("*.parquet")) if parts.is_dir() else []
    tables = []
    for p in files:
        try:
            tables.append(pq.read_table(p))
        except Exception as err:  # noqa: BLE001 - pyarrow raises several types for damaged files
            raise LoadError(_damaged_part(p, err)) from None
    if not tables:
        return None
    table = pa.concat_tables(tables, promote_options="none")
    return table.sort_by("run")


def load_sweep(path):
    """The table of a sweep folder as a pandas DataFrame, one row per run, sorted by ``run``.

    Columns: ``run``, ``point``, ``sample``, ``controller``, the varied scenario keys (by their
    dotted names), ``status`` ("ok", "diverged" or "invalid"), ``reason``, ``error_key``,
    ``t_fail``, every metric of :func:`hinfnn.compute_metrics` (per-joint ones as ``NAME_1``,
    ``NAME_2``), ``t_end``, ``partial``, ``bounded``, ``held_contact``, ``out_of_contact_after``,
    ``tracked``, ``did_its_job`` (true/false columns are
    pandas' nullable boolean: invalid runs have no value). An unfinished sweep gives the rows
    written so far. ``df.attrs`` holds ``complete``, ``spec``, ``n_runs`` (planned), ``units``.
    Raises :class:`~hinfnn.io.LoadError` for a folder that is not a sweep.
    """
    try:
        import pandas as pd
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as err:  # pragma: no cover - the extra is part of the test install
        raise ConfigError(f"reading a sweep needs pandas and pyarrow (pip install 'hinfnn[sweep]'): {err}") from None

    folder = Path(path)
    if folder.is_file() and folder.suffix == ".parquet":
        table, manifest = pq.read_table(folder), {}
        complete = True
    else:
        manifest = read_manifest(folder)
        results = folder / RESULTS
        complete = manifest.get("status") == "complete" and results.exists()
        if complete:
            try:
                table = pq.read_table(results)
            except Exception as err:  # noqa: BLE001
                raise LoadError(f"{results} is not readable: {type(err).__name__}: {err}") from None
        else:
            read_plan(folder)  # an unfinished sweep's rows are only as good as its plan: a damaged one says so
            table = read_parts(folder)
            if table is None:
                raise LoadError(f"{folder} holds no finished runs yet")
    df = table.to_pandas(types_mapper={pa.bool_(): pd.BooleanDtype()}.get)
    meta = {}
    raw = (table.schema.metadata or {}).get(b"hinfnn_sweep")
    if raw:
        meta = json.loads(raw)
    df.attrs.update(complete=bool(complete), spec=manifest.get("spec", meta.get("spec")),
                    n_runs=manifest.get("n_runs", len(df)), units=meta.get("units", {}))
    return df


def is_sweep_folder(folder: Path) -> bool:
    return (Path(folder) / MANIFEST).exists()


def foreign_files(folder: Path) -> list[str]:
    """What in ``folder`` a sweep does not write (``--force`` refuses to delete a folder holding
    any): a sweep writes its manifest, plan, parts, table, report, figures, scenario and spec."""
    ours = {MANIFEST, PLAN, PARTS, RESULTS, INVALID_PART, "report.md", "scenario.toml", "sweep.toml"}
    return sorted(p.name for p in Path(folder).iterdir()
                  if p.name not in ours and not (p.suffix == ".png" and p.is_file()) and not p.name.startswith(".tmp")
                  and not p.name.startswith(INSIDE_PREFIX))


def prepare_folder(folder: Path) -> None:
    (Path(folder) / PARTS).mkdir(parents=True, exist_ok=True)


def replace_folder(new: Path, old: Path) -> None:
    """Put the complete sweep ``new`` in the place of the sweep ``old`` (``--force``), with the
    same atomic exchange as every result folder (:class:`hinfnn.io.OutputFolder`)."""
    from ..io.folders import replace_folder as replace

    replace(Path(new), Path(old))


__all__ = ["load_sweep", "read_manifest", "write_manifest", "rows_table", "write_table", "schema", "metric_columns",
           "FORMAT", "STATUSES"]
