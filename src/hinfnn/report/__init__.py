"""Figures and tables of runs, from Trajectories, their tags and results documents only: never a
controller, a plant or a scenario (a workflow composes its own report text from these).

The figure functions are imported on first use (matplotlib is slow to import), so that
``from hinfnn.report.markdown import metrics_table`` or a run without figures does not pay it.
"""

__all__ = ["paper_figures", "run_figures", "beyond_figures"]


def __getattr__(name):
    if name in __all__:
        from . import figures

        return getattr(figures, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
