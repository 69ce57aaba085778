"""What a controller measures: joint angles and rates and a force sensor (NOTES.md, Measurements).

Shared by :mod:`hinfnn.plant` (which produces it from the truth) and :mod:`hinfnn.controllers`
(which consume it); neither imports the other.
"""

from __future__ import annotations

import jax

from ._pytree import pytree_dataclass


@pytree_dataclass
class Measurement:
    """q, q̇ (n,) and F (n,): the task-space force the end-effector exerts on the surface."""

    q: jax.Array
    qd: jax.Array
    F: jax.Array
