"""Unilateral penalty contact on the TRUE surface (docs/paper-conventions.md, Contact), and the
tool's friction along it.

Penetration p: the exact signed distance of the true surface at the tool point (for the
inclined line of Sec. VI: (x1 − d_G) sin δ − x2 cos δ). Normal force f_n = k p + c ṗ while
p > 0 (clipped at 0 so the surface never pulls), zero otherwise. The force the end-effector
exerts on the surface is F = f_n n (+ friction), n the unit inward normal; it enters the arm's
dynamics as +J_pᵀ F (eq. 1), J_p the tool point's Jacobian. The paper has no damping (c = 0 by
default) and no friction.
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


@pytree_dataclass
class Friction:
    """Coulomb + viscous friction of the tool sliding on the surface (the plant's; controllers do
    not model it). Default: off.

    With v_t the tool point's velocity along the surface (its component orthogonal to the
    normal) and f_n the normal force, the tool exerts on the surface the tangential force

        F_t = μ f_n tanh(|v_t| / v_s) v_t / |v_t|  +  c_v v_t      (while in contact, f_n > 0)

    i.e. the surface holds the tool back with −F_t. tanh(|v|/v_s) smooths Coulomb's sign(v) over
    |v| ≲ v_s, so the force is smooth for RK4 (its slope μ f_n / v_s sets the stiffness the step
    must resolve); at |v_t| → 0 the factor tanh(|v|/v_s)/|v| → 1/v_s is evaluated by its series.
    """

    coulomb: jax.Array = 0.0  # μ, -
    viscous: jax.Array = 0.0  # c_v, N·s/m
    v_smooth: jax.Array = 1e-3  # v_s, m/s

    def force(self, f_n, v_t):
        """F_t, the tangential force the tool exerts on the surface (same space as v_t)."""
        speed2 = jnp.sum(v_t * v_t)
        x2 = speed2 / self.v_smooth**2
        small = x2 < 1e-6
        speed = jnp.sqrt(jnp.where(small, 1.0, speed2))
        ratio = jnp.where(small, (1.0 - x2 / 3.0) / self.v_smooth, jnp.tanh(speed / self.v_smooth) / speed)
        in_contact = f_n > 0
        return jnp.where(in_contact, self.coulomb * f_n * ratio + self.viscous, 0.0) * v_t
