"""Figures and reports of runs; they consume Trajectories, never a controller."""

from .figures import paper_figures, run_figures

__all__ = ["paper_figures", "run_figures"]
