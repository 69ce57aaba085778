"""hinfnn: robust position/force learning control of constrained manipulators.

Hwang & Hu's adaptive H∞ neural-network controller, the H∞-only and feedback-linearization-like
controllers it is compared with, the reduced-order constrained model they are built on, and a
fast JAX simulator of the true plant with stiff contact.

Importing hinfnn changes no process-wide setting: call :func:`configure` once (float64 and the
persistent compilation cache; the ``hinfnn`` command does it) before running anything.

The names below are imported on first use (``hinfnn.simulate`` imports JAX then, not
``import hinfnn``): the ``hinfnn`` command installs its signal handlers before JAX is loaded, so
Ctrl-C during start-up is handled like Ctrl-C at any other moment.
"""

from __future__ import annotations

import importlib

from .errors import ConfigError, DesignError, HinfnnError, SimulationError

__version__ = "0.2.0"

#: Public name -> the module that defines it (imported on first access).
_LAZY = {
    "configure": "._config",
    "cache_dir": "._cache", "enable_cache": "._cache", "clear_cache": "._cache",
    "FeedbackLinearization": ".controllers", "HinfController": ".controllers", "HinfNNController": ".controllers",
    "SampledController": ".controllers", "SampledLoop": ".controllers", "Gains": ".controllers",
    "TanhNetwork": ".controllers",
    "compute_metrics": ".metrics",
    "ImplicitSurface": ".model", "InclinedLine": ".model", "PlanarPointMassArm": ".model", "TwoLinkArm": ".model",
    "reduced_model": ".model",
    "PenaltyContact": ".plant", "RigidBodyPlant": ".plant", "SquareWave": ".plant",
    "Measurement": ".protocols", "RunStatus": ".status",
    "CosineReference": ".reference",
    "Scenario": ".scenario", "load_scenario": ".scenario",
    "Limits": ".sim", "Save": ".sim", "Trajectory": ".sim", "simulate": ".sim", "simulate_batch": ".sim",
    "simulate_many": ".sim",
    "LoadError": ".io", "load": ".io",
    # the sweep table reader imports pandas and pyarrow when called; `import hinfnn` imports neither
    "load_sweep": ".sweep.store",
}

__all__ = [
    "configure", "cache_dir", "enable_cache", "clear_cache",
    "FeedbackLinearization", "HinfController", "HinfNNController", "SampledController", "SampledLoop", "Gains",
    "TanhNetwork", "ConfigError", "DesignError", "SimulationError", "HinfnnError",
    "Measurement", "RunStatus", "TwoLinkArm", "PlanarPointMassArm", "InclinedLine", "ImplicitSurface", "reduced_model",
    "RigidBodyPlant", "PenaltyContact", "SquareWave", "CosineReference",
    "simulate", "simulate_batch", "simulate_many", "Limits", "Save", "Trajectory", "compute_metrics", "Scenario",
    "load_scenario", "load", "LoadError", "load_sweep", "__version__",
]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'hinfnn' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # the next access is a plain attribute
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
