"""Figures and reports of runs; they consume Trajectories, never a controller."""

from .claims import CLAIMS, RULES, ClaimResult, evaluate
from .figures import paper_figures, run_figures
from .markdown import study_report

__all__ = ["paper_figures", "run_figures", "study_report", "evaluate", "ClaimResult", "CLAIMS", "RULES"]
