"""The truth: the plant a controller acts on but never sees (DESIGN: the one rule).

:class:`RigidBodyPlant` is hinfnn's own (rigid-body arm, penalty contact, disturbance); other
engines implement the same protocol (:class:`hinfnn.protocols.ContinuousPlant` or
:class:`~hinfnn.protocols.DiscretePlant`).
"""

from .contact import Friction, PenaltyContact
from .disturbance import SquareWave
from .rigid import ContactCache, JointState, RigidBodyPlant

__all__ = ["RigidBodyPlant", "JointState", "ContactCache", "PenaltyContact", "Friction", "SquareWave"]
