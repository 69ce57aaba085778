"""What a controller may know: arm and surface models and the reduced-order model (eqs. 1–16).

Nothing here imports :mod:`hinfnn.plant`: the same types describe the nominal model (given to
controllers) and the truth (held by the plant).
"""

from .arm import Arm, PlanarPointMassArm
from .planar import TwoLinkArm
from .reduced import ReducedModel, reduced_model
from .surface import ImplicitSurface, InclinedLine, Surface
from .taskmap import PlanarTaskMap, PoseTaskMap, PositionTaskMap
from .urdf import UrdfArm, UrdfChain, UrdfError, load_urdf

__all__ = [
    "Arm",
    "PlanarPointMassArm",
    "TwoLinkArm",
    "Surface",
    "InclinedLine",
    "ImplicitSurface",
    "ReducedModel",
    "reduced_model",
    "UrdfArm",
    "UrdfChain",
    "UrdfError",
    "load_urdf",
    "PlanarTaskMap",
    "PositionTaskMap",
    "PoseTaskMap",
]
