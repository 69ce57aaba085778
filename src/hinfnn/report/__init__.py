"""Figures and reports of runs; they consume Trajectories, never a controller.

The figure functions are imported on first use (matplotlib takes 0.5–0.7 s to import), so that
``from hinfnn.report.markdown import metrics_table`` or a run without figures does not pay it.
"""

from .claims import CLAIMS, RULES, ClaimResult, evaluate
from .markdown import study_report

__all__ = ["paper_figures", "run_figures", "study_report", "evaluate", "ClaimResult", "CLAIMS", "RULES"]


def __getattr__(name):
    if name in ("paper_figures", "run_figures"):
        from . import figures

        return getattr(figures, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
