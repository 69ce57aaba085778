"""Controllers: nominal model + measurement + reference -> torque (paper eqs. 17–54).

Each controller is designed once (``Controller.design``: gain checks, Riccati solve) and then
used through pure functions on an explicit state pytree: ``init``, ``torque``, ``derivative``.
Nothing here imports :mod:`hinfnn.plant`.
"""

from .base import ControllerState, ReducedOrderController, Signals
from .feedback_linearization import FeedbackLinearization
from .gains import Gains
from .hinf import HinfController
from .hinf_nn import HinfNNController
from .network import CENTRE_PRESETS_F, TanhNetwork, centres_from, paper_network_f, paper_network_p
from .riccati import RiccatiSolution, design_riccati, solve_riccati_like
from .sampled import MeasurementError, SampledController, SampledLoop

__all__ = [
    "ControllerState",
    "ReducedOrderController",
    "Signals",
    "FeedbackLinearization",
    "HinfController",
    "HinfNNController",
    "Gains",
    "TanhNetwork",
    "CENTRE_PRESETS_F",
    "centres_from",
    "paper_network_p",
    "paper_network_f",
    "RiccatiSolution",
    "design_riccati",
    "solve_riccati_like",
    "SampledController",
    "SampledLoop",
    "MeasurementError",
]
