"""Experiments: run cases (a name, a scenario with one controller, tags) and the one pipeline that
simulates them and writes their result folder. Every workflow (``hinfnn run``, ``compare``,
``gallery``, ``reproduce``) builds a list of cases and a report text on top of it."""

from .case import Case, cases
from .result import (Outcome, Written, build_runs, check_memory, result_folder, run_cases, simulate_cases,
                     write_result)

__all__ = ["Case", "cases", "Outcome", "Written", "build_runs", "simulate_cases",
           "check_memory", "run_cases", "write_result", "result_folder"]
