"""Closed-loop simulation (RK4 in one ``lax.scan``), the step plan, the recorder, batches under ``vmap``."""

from .batch import Run, simulate_many
from .integrate import RK4
from .plan import StepPlan
from .recorder import FIELD_SETS, Accumulators
from .simulate import (Limits, RunProgram, Save, SimState, initial_state, release_programs, rhs, simulate,
                       simulate_batch, stack)
from .trajectory import RunInfo, Trajectory

__all__ = ["simulate", "release_programs", "simulate_batch", "simulate_many", "Run", "RunProgram", "Save", "stack",
           "initial_state", "rhs", "Limits", "SimState", "StepPlan", "RK4", "Trajectory", "RunInfo", "FIELD_SETS",
           "Accumulators"]
