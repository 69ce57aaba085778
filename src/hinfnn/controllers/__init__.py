"""Controllers: nominal model + measurement + reference -> torque (paper eqs. 17–54).

A controller is the reduced-order law (24)–(27) (:mod:`~hinfnn.controllers.law`) with added
terms (:mod:`~hinfnn.controllers.terms`); the paper's three controllers are compositions of
terms (:mod:`~hinfnn.controllers.kinds`). Each is designed once (gain checks, Riccati solve) and
then used through pure functions on an explicit state pytree. Nothing here imports
:mod:`hinfnn.plant`.
"""

from .gains import Gains
from .kinds import (KINDS, ROBUST, Composition, FeedbackLinearization, HinfController, HinfNNController, design,
                    drive_noise, register, robust_adaptation, unregister)
from .law import ControllerState, LawAux, Output, ReducedOrderController, force_multiplier, measured_force
from .network import CENTRE_PRESETS_F, Adaptation, CoordinateNetwork, TanhNetwork, centres_from, paper_network_f, paper_network_p
from .riccati import RiccatiSolution, design_riccati, solve_riccati_like
from .sampled import MeasurementError, SampledController, SampledLoop
from .summary import design_summary
from .terms import Context, ForceNetwork, ForceRate, PositionNetwork, RobustForce, RobustPosition, Term

__all__ = [
    "Gains", "KINDS", "Composition", "design", "register", "unregister", "ROBUST", "robust_adaptation",
    "drive_noise", "Adaptation",
    "FeedbackLinearization", "HinfController", "HinfNNController",
    "ControllerState", "LawAux", "Output", "ReducedOrderController", "force_multiplier", "measured_force",
    "Term", "Context", "RobustPosition", "RobustForce", "PositionNetwork", "ForceNetwork", "ForceRate",
    "TanhNetwork", "CoordinateNetwork", "CENTRE_PRESETS_F", "centres_from", "paper_network_p", "paper_network_f",
    "RiccatiSolution", "design_riccati", "solve_riccati_like",
    "SampledController", "SampledLoop", "MeasurementError", "design_summary",
]
