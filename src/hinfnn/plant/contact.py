"""Frictionless unilateral penalty contact on the TRUE surface (docs/paper-conventions.md, Contact).

Penetration p = θ(x)/‖∇θ(x)‖ (for the inclined line: (x1 − d_G) sin δ − x2 cos δ), normal
force f_n = k p + c ṗ while p > 0 (clipped at 0 so the surface never pulls), zero otherwise.
The force the end-effector exerts on the surface is F = f_n n, n the unit inward normal; it
enters the arm's dynamics as +Jᵀ F (eq. 1). The paper has no damping (c = 0 by default).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._pytree import pytree_dataclass


@pytree_dataclass
class PenaltyContact:
    """Stiffness k (N/m) and optional damping c (N·s/m)."""

    stiffness: jax.Array = 1e5
    damping: jax.Array = 0.0

    def normal_force(self, p, p_dot):
        """f_n = max(0, k p + c ṗ) for p > 0, else 0."""
        return jnp.where(p > 0, jnp.maximum(self.stiffness * p + self.damping * p_dot, 0.0), 0.0)
