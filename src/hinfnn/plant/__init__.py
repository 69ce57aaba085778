"""The truth: the plant a controller acts on but never sees (DESIGN.md, The one rule)."""

from .contact import PenaltyContact
from .disturbance import SquareWave
from .plant import Plant

__all__ = ["Plant", "PenaltyContact", "SquareWave"]
