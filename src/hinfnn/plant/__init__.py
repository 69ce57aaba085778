"""The truth: the plant a controller acts on but never sees (DESIGN: the one rule).

:class:`RigidBodyPlant` is hinfnn's own (rigid-body arm, penalty contact, disturbance); other
engines implement the same :class:`hinfnn.protocols.Plant` protocol.
"""

from .contact import Friction, PenaltyContact
from .disturbance import SquareWave
from .rigid import ContactCache, JointState, RigidBodyPlant

__all__ = ["RigidBodyPlant", "JointState", "ContactCache", "PenaltyContact", "Friction", "SquareWave"]
