"""Closed-loop simulation (RK4 in one ``lax.scan``), the step plan, the recorder, batches under ``vmap``."""

from .batch import Run, simulate_many
from .integrate import rk4_step
from .plan import StepPlan
from .recorder import FIELD_SETS, Accumulators
from .simulate import (Limits, RunProgram, SimState, initial_state, release_programs, rhs, simulate, simulate_batch,
                       stack)
from .trajectory import RunInfo, Trajectory

__all__ = ["simulate", "release_programs", "simulate_batch", "simulate_many", "Run", "RunProgram", "stack",
           "initial_state", "rhs", "Limits", "SimState", "StepPlan", "rk4_step", "Trajectory", "RunInfo", "FIELD_SETS",
           "Accumulators"]
