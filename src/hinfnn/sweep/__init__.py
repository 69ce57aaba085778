"""Robustness sweeps: a scenario's keys varied on grids and by seeded draws, every run of every
controller simulated in ``vmap`` batches, one Parquet table of outcomes and metrics, robustness
maps, distributions and a report (``hinfnn sweep``; ``docs/sweeps.md``).

``load_spec(name_or_path)`` reads a spec (:mod:`~hinfnn.sweep.spec`), ``run_sweep(spec, folder)``
runs it (:mod:`~hinfnn.sweep.run`; backends local and Ray), ``load_sweep(folder)`` returns the
table as a pandas DataFrame (:mod:`~hinfnn.sweep.store`). Importing this package imports neither
pandas, pyarrow nor Ray.
"""

from .spec import SweepSpec, VarySpec, load_spec, spec_from_dict, spec_names


def __getattr__(name):
    if name in ("run_sweep", "prepare_output", "SweepResult"):
        from . import run

        return getattr(run, name)
    if name == "DEFAULT_MAX_BATCH":
        from .worker import DEFAULT_MAX_BATCH

        return DEFAULT_MAX_BATCH
    if name == "load_sweep":
        from .store import load_sweep

        return load_sweep
    raise AttributeError(f"module 'hinfnn.sweep' has no attribute {name!r}")


__all__ = ["SweepSpec", "VarySpec", "load_spec", "spec_from_dict", "spec_names", "run_sweep", "prepare_output",
           "SweepResult", "load_sweep", "DEFAULT_MAX_BATCH"]
