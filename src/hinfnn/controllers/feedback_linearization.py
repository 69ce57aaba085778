"""The feedback-linearization-like controller of Sec. VI (the paper's first comparison).

τ = [B̄1; B̄2 − M̄21 M̄11⁻¹ B̄1]⁻¹ [M̄11 (ü1d − K_v ė − K_p e) + C̄11 u̇1 + Ḡ1;
                                  Πᵀ (λd + z) + (C̄21 − M̄21 M̄11⁻¹ C̄11) u̇1 + (Ḡ2 − M̄21 M̄11⁻¹ Ḡ1)],
ż = −μ_z z − α_z e_λ.

Printed error fixed (NOTES.md): the paper prints u̇1d inside M̄11[·]; the law needs ü1d (with
u̇1d, e_u1 cannot go to zero even on an exact model; tests/test_controllers.py checks it does).
"""

from __future__ import annotations

from .._pytree import pytree_dataclass
from .base import ReducedOrderController, build_controller
from .gains import Gains


@pytree_dataclass
class FeedbackLinearization(ReducedOrderController):
    """Sec. VI FL-like controller: eq. (24) without v_p, v_λ and networks."""

    @classmethod
    def design(cls, arm_nom, surface_nom, gains: Gains | None = None) -> "FeedbackLinearization":
        """Validate the gains. P_p of eq. (35) is solved too, for the storage function used in
        the dissipation report only (NaN if ρ admits no solution: this law does not use it)."""
        ctrl, _ = build_controller(cls, arm_nom, surface_nom, gains or Gains.paper(), kind="fl",
                                   robust=False, learning=False, require_bounds=False,
                                   riccati_required=False)
        return ctrl
