"""Suboptimal H∞-only position/force controller, Theorem 2 (Sec. V).

τ of eq. (51): eq. (24) without the networks, with v_p = −R_p⁻¹ B_pᵀ P_p x_p (33),
v_λ = −β_λ/2 e_λ (32) or −β_λ e_λ under Remark 1 (41), ż of eq. (27), and P_p from the
Riccati-like eq. (35), or (40) under Remark 1.
"""

from __future__ import annotations

from .._pytree import pytree_dataclass
from .base import ReducedOrderController, build_controller
from .gains import Gains


@pytree_dataclass
class HinfController(ReducedOrderController):
    """Theorem 2: eq. (51) with (27), (32), (33) and P_p of eq. (35)."""

    @classmethod
    def design(cls, arm_nom, surface_nom, gains: Gains | None = None, *,
               augmented: bool = False) -> "HinfController":
        """Check Theorem 2's bounds and solve eq. (35) (eq. (40) if ``augmented``, Remark 1).

        Raises :class:`~hinfnn.errors.DesignError` naming the condition that failed.
        """
        ctrl, _ = build_controller(cls, arm_nom, surface_nom, gains or Gains.paper(), kind="hinf",
                                   robust=True, learning=False, augmented=augmented)
        return ctrl
