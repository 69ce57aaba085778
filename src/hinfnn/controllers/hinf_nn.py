"""Adaptive H∞ neural-network position/force controller, Theorem 1 (Sec. IV) and Remarks 1–3.

τ of eq. (24) with Λp (25), Λf (26), ż (27), update laws (30)–(31), v_λ (32), v_p (33) and P_p
of eq. (35). Variants: Remark 1 (``augmented=True``: eq. (40) and v_λ = −β_λ e_λ), Remark 2
(networks built with a projection ``radius``), Remark 3 (any α_z > 0, with its bounds on α_λ
and β_λ checked by :meth:`~hinfnn.controllers.gains.Gains.normalized`).
"""

from __future__ import annotations

from .._pytree import pytree_dataclass
from .base import ReducedOrderController, build_controller
from .gains import Gains
from .network import TanhNetwork, paper_network_f, paper_network_p


@pytree_dataclass
class HinfNNController(ReducedOrderController):
    """Theorem 1: the adaptive H∞ NN controller."""

    @classmethod
    def design(cls, arm_nom, surface_nom, gains: Gains | None = None, *,
               network_p: TanhNetwork | None = None, network_f: TanhNetwork | None = None,
               centre_preset: str = "paper-likely", augmented: bool = False) -> "HinfNNController":
        """Check Theorem 1's bounds, solve eq. (35) (or (40)), and attach the networks.

        Without explicit networks, the Sec. VI ones are used, F_f with ``centre_preset``
        (``"paper-likely"``: step 0.5, or ``"paper-printed"``: step 0.05; NOTES.md).
        """
        network_p = network_p or paper_network_p()
        network_f = network_f or paper_network_f(centre_preset)
        ctrl, _ = build_controller(cls, arm_nom, surface_nom, gains or Gains.paper(), kind="hinf_nn",
                                   robust=True, learning=True, augmented=augmented,
                                   network_p=network_p, network_f=network_f)
        return ctrl
