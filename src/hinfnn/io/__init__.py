"""Results on disk: folders (reserved, written atomically, marked), file formats, loading, export.

:mod:`~hinfnn.io.folders` reserves and locks output folders (results and sweeps) and puts a
complete result in place atomically; :mod:`~hinfnn.io.formats` writes ``metrics.json`` and
``trajectory.npz`` and makes the table of a run's samples; :mod:`~hinfnn.io.load` reads a result
back (:func:`load`, :func:`load_metrics`); :mod:`~hinfnn.io.export` writes the table as CSV or
Parquet.
"""

from ..errors import LoadError
from .folders import (MARKER, FolderLock, OutputFolder, Reservation, add_to_marker, atomic_write, atomic_write_bytes,
                      atomic_write_text, default_output, foreign_files, read_marker, reserve_output, safe_name,
                      timestamp, write_marker)
from .formats import FORMAT, SWEEP_MANIFEST, dumps_json, table, to_pandas, trajectory_npz_bytes
from .load import SavedResult, load, load_metrics, load_npz, not_a_sweep

__all__ = ["LoadError", "MARKER", "FolderLock", "OutputFolder", "Reservation", "add_to_marker", "atomic_write",
           "atomic_write_bytes", "atomic_write_text", "default_output", "foreign_files", "read_marker",
           "reserve_output", "safe_name", "timestamp", "write_marker", "FORMAT", "SWEEP_MANIFEST", "dumps_json",
           "table", "to_pandas", "trajectory_npz_bytes", "SavedResult", "load", "load_metrics", "load_npz",
           "not_a_sweep"]
