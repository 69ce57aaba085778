"""Closed-loop simulation (RK4 in one ``lax.scan``), batches under ``vmap``, Trajectory."""

from .integrate import rk4_step
from .simulate import Limits, initial_state, simulate, simulate_batch, stack
from .trajectory import FIELDS, STATUS, Trajectory

__all__ = ["simulate", "simulate_batch", "stack", "initial_state", "Limits", "rk4_step",
           "Trajectory", "STATUS", "FIELDS"]
