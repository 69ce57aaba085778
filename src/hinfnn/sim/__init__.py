"""Closed-loop simulation (RK4 in one ``lax.scan``), the recorder, batches under ``vmap``."""

from .batch import Run, simulate_many
from .integrate import rk4_step
from .recorder import FIELD_SETS, Accumulators
from .simulate import Limits, SimState, initial_state, simulate, simulate_batch, stack
from .trajectory import STATUS, RunInfo, Trajectory

__all__ = ["simulate", "simulate_batch", "simulate_many", "Run", "stack", "initial_state", "Limits", "SimState",
           "rk4_step", "Trajectory", "RunInfo", "STATUS", "FIELD_SETS", "Accumulators"]
