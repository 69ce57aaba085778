"""hinfnn: robust position/force learning control of constrained manipulators.

Hwang & Hu's adaptive H∞ neural-network controller, the H∞-only and feedback-linearization-like
controllers it is compared with, the reduced-order constrained model they are built on, and a
fast JAX simulator of the true plant with stiff contact.

Importing hinfnn changes no process-wide setting: call :func:`configure` once (float64 and the
persistent compilation cache; the ``hinfnn`` command does it) before running anything.
"""

from ._config import configure
from ._cache import cache_dir, clear_cache, enable_cache
from .controllers import (FeedbackLinearization, Gains, HinfController, HinfNNController, SampledController,
                          SampledLoop, TanhNetwork)
from .errors import ConfigError, DesignError, HinfnnError, SimulationError
from .metrics import compute_metrics
from .model import ImplicitSurface, InclinedLine, PlanarPointMassArm, TwoLinkArm, reduced_model
from .plant import PenaltyContact, RigidBodyPlant, SquareWave
from .protocols import Measurement
from .reference import CosineReference
from .scenario import Scenario, load_scenario
from .sim import Limits, Trajectory, simulate, simulate_batch, simulate_many
from .io import LoadError, load

__version__ = "0.2.0"


def __getattr__(name):
    # the sweep table reader imports pandas and pyarrow when called; `import hinfnn` imports neither
    if name == "load_sweep":
        from .sweep.store import load_sweep

        return load_sweep
    raise AttributeError(f"module 'hinfnn' has no attribute {name!r}")


__all__ = [
    "configure", "cache_dir", "enable_cache", "clear_cache",
    "FeedbackLinearization", "HinfController", "HinfNNController", "SampledController", "SampledLoop", "Gains",
    "TanhNetwork", "ConfigError", "DesignError", "SimulationError", "HinfnnError",
    "Measurement", "TwoLinkArm", "PlanarPointMassArm", "InclinedLine", "ImplicitSurface", "reduced_model",
    "RigidBodyPlant", "PenaltyContact", "SquareWave", "CosineReference",
    "simulate", "simulate_batch", "simulate_many", "Limits", "Trajectory", "compute_metrics", "Scenario",
    "load_scenario", "load", "LoadError", "load_sweep", "__version__",
]
