"""hinfnn: robust position/force learning control of constrained manipulators.

Hwang & Hu's adaptive H∞ neural-network controller, the H∞-only and feedback-linearization-like
controllers it is compared with, the reduced-order constrained model they are built on, and a
fast JAX simulator of the true plant with stiff contact.
"""

from . import _config  # noqa: F401  (float64 on the CPU before anything else)
from .controllers import (
    FeedbackLinearization,
    Gains,
    HinfController,
    HinfNNController,
    SampledController,
    TanhNetwork,
)
from .errors import ConfigError, DesignError, HinfnnError, SimulationError
from .measurement import Measurement
from .model import ImplicitSurface, InclinedLine, PlanarPointMassArm, TwoLinkArm, reduced_model
from .plant import PenaltyContact, Plant, SquareWave
from .reference import CosineReference
from .sim import Limits, Trajectory, simulate, simulate_batch
from .metrics import compute_metrics
from .scenario import Scenario, load_scenario
from .io import LoadError, load
from ._cache import cache_dir, clear_cache, enable_cache

__version__ = "0.1.0"

__all__ = [
    "FeedbackLinearization", "HinfController", "HinfNNController", "SampledController", "Gains", "TanhNetwork",
    "ConfigError", "DesignError", "SimulationError", "HinfnnError",
    "Measurement", "TwoLinkArm", "PlanarPointMassArm", "InclinedLine", "ImplicitSurface",
    "reduced_model", "Plant", "PenaltyContact", "SquareWave", "CosineReference",
    "simulate", "simulate_batch", "Limits", "Trajectory", "compute_metrics", "Scenario",
    "load_scenario", "load", "LoadError", "cache_dir", "enable_cache", "clear_cache", "__version__",
]
