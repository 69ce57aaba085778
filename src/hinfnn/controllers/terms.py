"""The additive terms of the paper's law (24), each one small object.

The paper itself splits its law into a computed-torque part and added terms (eqs. 42–49):
Λp = ΛP_CT + ΛP_NN + ΛP_v and Λf = ΛF_CT + ΛF_NN + ΛF_v. hinfnn keeps that split. The CT part
(eqs. 43, 49, 50: decoupling, PD, the z-filter and the force feedforward) is the law itself
(:class:`~hinfnn.controllers.law.ReducedOrderController`); everything added to it is a
:class:`Term`:

* a *position* term adds its value a_i inside M̄11[·] of eq. (25); a *force* term adds b_j
  inside Πᵀ[·] of eq. (26);
* a term may carry state (the networks' weights Θ̂, a filter), integrated with the plant;
* a term declares its contribution to the storage function V (eqs. 36/55) and to the augmented
  performance index of Remark 1, so the theorem bookkeeping follows the composition;
* the supply residuals follow from the values: f_p = ë_u1 + K_p e_u1 + K_v ė_u1 − Σ a_i and
  f_f = e_λ − z − Σ b_j (eqs. 28–29 / 52–53 solved for the lumped uncertainty).

A new term is a pytree dataclass subclassing :class:`Term`; the three controllers of the paper
are compositions of the terms below (:mod:`hinfnn.controllers.kinds`).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from .. import _linalg as la
from .._pytree import Note, pytree_dataclass, static_field
from ..reference import RefSample
from .gains import Gains
from .network import Adaptation, TanhNetwork, block_bounds, sq_norm


@pytree_dataclass
class Context:
    """What every term may read at one instant: time, reference sample, the measured motion and
    force in the controller's coordinates, their errors, the z-filter state, x_p and
    s_p = B_pᵀ P_p x_p (the drive of v_p and of F_p's update), the gains and P_p, and
    ``theta_rate``: the NOMINAL constraint's rate from the measured joint rates, per constraint
    over its gradient's squared norm, D²Â Ĵ q̇ (D = diag(1/‖Â_i‖)): λ̇ per unit of contact
    stiffness on a penalty contact (λ = k D²θ̂, docs/beyond-the-paper.md sections 1 and 7)."""

    t: jax.Array
    ref: RefSample
    u1: jax.Array
    u1_dot: jax.Array
    lam: jax.Array
    e_u1: jax.Array
    e_u1_dot: jax.Array
    e_lam: jax.Array
    z: jax.Array
    x_p: jax.Array
    s_p: jax.Array
    gains: Gains
    P_p: jax.Array
    theta_rate: jax.Array | None = None
    augmented: bool = static_field(default=False)
    kernels: la.Kernels = la.kernels_field()  # the controller's (hinfnn._linalg.Kernels): how terms write their algebra

    @property
    def c(self):
        """α_λ / (1 + β_λ): the weight of ‖z‖²/2 in V (eq. 36)."""
        return self.gains.alpha_lam / (1.0 + self.gains.beta_lam)


class Term:
    """Base class of the law's terms (subclasses are pytree dataclasses).

    Class attributes: ``side`` ("position" or "force"), ``fields`` (the signals it records:
    name -> (unit, meaning); registered with the recorder's field table), ``blocked`` (its state
    arrays the controller carries in blocks inside the compiled loop: name -> number of equal
    groups, see :func:`hinfnn.controllers.network.split`).
    """

    side: ClassVar[str] = "position"
    fields: ClassVar[dict[str, tuple[str, str]]] = {}
    blocked: ClassVar[dict[str, int]] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.fields:
            from ..fields import declare

            for name, (unit, doc) in cls.fields.items():
                # a position-side signal in m (m/s², ...) has one component per motion coordinate,
                # each in its coordinate's unit; λ units: per constraint (hinfnn.fields.declare)
                motion = cls.side == "position" and unit.startswith("m")
                declare(name, unit, doc, per=("motion", "{}" + unit[1:]) if motion else None)

    def state_sizes(self, m: int, k: int) -> dict[str, int]:
        """Sizes of its state arrays (flat), by name; {} for a static term."""
        return {}

    def init(self, m: int, k: int) -> dict:
        """Initial state (Sec. VI: zero), flat arrays by name."""
        return {name: jnp.zeros(size) for name, size in self.state_sizes(m, k).items()}

    def prepared(self, block: int | None):
        """This term as a compiled loop holds it (:meth:`ReducedOrderController.prepared`):
        constant arrays it reads by blocks also held as those blocks. Default: itself."""
        return self

    def evaluate(self, ctx: Context, parts: dict):
        """(value, state derivative {name: array}, signals {name: array}) at one instant.
        ``parts`` holds every state array of the controller, the ``blocked`` ones as tuples of
        blocks (the derivative in the same layout)."""
        raise NotImplementedError

    def storage(self, ctx: Context, parts: dict):
        """Its contribution to the storage function V, or None."""
        return None

    def extra_performance(self, ctx: Context, value):
        """Its contribution to the augmented performance index (Remark 1), or None."""
        return None

    def extra_dissipation(self, ctx: Context, parts: dict):
        """A non-negative rate the term dissipates beyond the theorem's, added to the left-hand
        side of the dissipation check (J_aug), or None. The inequality then holds in its
        stricter form."""
        return None

    def extra_supply(self, ctx: Context, parts: dict):
        """A non-negative rate the term adds to the supply side of the dissipation check (a term
        the theorem's proof does not cancel, bounded: the dead zone of
        :class:`~hinfnn.controllers.network.Adaptation`), or None. The check then holds in the
        weaker form the modified law still guarantees."""
        return None

    def start(self, ctx: Context, parts: dict) -> dict:
        """Its state at the first sample, from the first measurement (default: unchanged)."""
        return {}

    def constrain(self, parts: dict) -> dict:
        """Its state after an integration step put back where the theory keeps it (identity)."""
        return {}

    def check(self, m: int, k: int) -> None:
        """Design-time checks (sizes); raises DesignError."""


@pytree_dataclass
class RobustPosition(Term):
    """v_p = −R_p⁻¹ B_pᵀ P_p x_p, eq. (33) (ΛP_v of eq. 45). Augmented performance (Remark 1):
    adds ‖v_p‖²_{R_p}."""

    side: ClassVar[str] = "position"
    fields: ClassVar[dict] = {"v_p": ("m/s²", "robustifying position term v_p, eq. (33)")}

    def evaluate(self, ctx, parts):
        v_p = -ctx.kernels.spd_solve(ctx.gains.R_p, ctx.s_p)  # R_p symmetric positive definite (the design checks it)
        return v_p, {}, {"v_p": v_p}

    def extra_performance(self, ctx, value):
        return ctx.kernels.mm(value, ctx.kernels.mm(ctx.gains.R_p, value))


@pytree_dataclass
class RobustForce(Term):
    """v_λ = −(β_λ/2) e_λ, eq. (32) (ΛF_v of eq. 47), or −β_λ e_λ with Remark 1 (eq. 41), which
    also adds α_λα_z/(2β_λ(1+β_λ)) ‖v_λ‖² to the augmented performance index."""

    side: ClassVar[str] = "force"
    fields: ClassVar[dict] = {"v_lam": ("λ units", "robustifying force term v_λ, eq. (32) or (41)")}

    def evaluate(self, ctx, parts):
        g = ctx.gains
        v_lam = -(g.beta_lam if ctx.augmented else 0.5 * g.beta_lam) * ctx.e_lam
        return v_lam, {}, {"v_lam": v_lam}

    def extra_performance(self, ctx, value):
        g = ctx.gains
        return g.alpha_lam * g.alpha_z / (2.0 * g.beta_lam * (1.0 + g.beta_lam)) * ctx.kernels.mm(value, value)


class _NetworkTerm(Term):
    """−Ξ Θ̂ of a tanh network (eqs. 17–19) whose weights learn by eq. (30) or (31), or by the
    robust modification ``adaptation`` (:class:`~hinfnn.controllers.network.Adaptation`: dead
    zone, leakage; None: the paper's law)."""

    key: ClassVar[str]
    out: ClassVar[str]

    def state_sizes(self, m, k):
        return {self.key: self.network.size}

    @property
    def blocked(self):  # type: ignore[override]
        return {self.key: self.network.n_out}

    def check(self, m, k):
        from ..errors import DesignError

        dim = m if self.side == "position" else k
        if self.network.n_out != dim:
            raise DesignError(f"must have {dim} outputs, has {self.network.n_out}",
                              key=f"{'network_p' if self.side == 'position' else 'network_f'}.n_out")

    def _io(self, ctx):
        raise NotImplementedError

    def _weight(self, ctx):
        """w of the storage w‖Θ̂‖² (eq. 36)."""
        raise NotImplementedError

    def prepared(self, block):
        return dataclasses.replace(self, network=self.network.with_centre_blocks(block_bounds(self.network.n_units, block)))

    def evaluate(self, ctx, parts):
        a, b, drive, gamma = self._io(ctx)
        theta = parts[self.key]
        xi = self.network.features_blocks(a, b, self.network.layout(theta))
        nn = self.network.output_blocks(xi, theta)
        signals = {self.out: nn, f"{self.key}_norm": jnp.sqrt(sq_norm(theta))}
        if self.adaptation is None:
            d_theta = self.network.update_blocks(xi, drive, theta, gamma)
        else:
            d_theta = self.adaptation.update_blocks(self.network, xi, drive, theta, gamma)
            signals[f"{self.key}_gate"] = self.adaptation.gate(drive)
        return -nn, {self.key: d_theta}, signals

    def _storage_rate(self, ctx, parts):
        a, b, drive, gamma = self._io(ctx)
        theta = parts[self.key]
        xi = self.network.features_blocks(a, b, self.network.layout(theta))
        return self.adaptation.storage_rate(self.network, xi, drive, theta, gamma, self._weight(ctx))

    def extra_dissipation(self, ctx, parts):
        """The leakage's 2wℓ‖Θ̂‖² (:meth:`Adaptation.storage_rate`); None for eq. (30)/(31)."""
        return None if self.adaptation is None else self._storage_rate(ctx, parts)[0]

    def extra_supply(self, ctx, parts):
        """The dead zone's bound 2wγ min(‖s‖, d)‖ΞΘ̂‖ (:meth:`Adaptation.storage_rate`); None for
        eq. (30)/(31)."""
        return None if self.adaptation is None else self._storage_rate(ctx, parts)[1]

    def storage(self, ctx, parts):
        return self._weight(ctx) * sq_norm(parts[self.key])

    def constrain(self, parts):
        return {self.key: self.network.clip_blocks(parts[self.key])}


@pytree_dataclass
class PositionNetwork(_NetworkTerm):
    """−Ξ_p Θ̂_p (ΛP_NN of eq. 44), F_p's input (e_u1, ė_u1), update Θ̂̇p = γ1 Ξpᵀ B_pᵀP_p x_p
    (eq. 30, with Remark 2's projection when the network has a radius). Storage ‖Θ̂p‖²/γ1
    (eq. 36 with Θ* = 0)."""

    network: TanhNetwork
    adaptation: Adaptation | None = None
    side: ClassVar[str] = "position"
    key: ClassVar[str] = "theta_p"
    out: ClassVar[str] = "nn_p"
    fields: ClassVar[dict] = {
        "nn_p": ("m/s²", "F_p's output Ξ_p Θ̂_p, eq. (19)"),
        "theta_p_norm": ("-", "‖Θ̂_p‖"),
        "theta_p_gate": ("-", "the dead zone's gate g on eq. (30)'s drive (0: inside the zone, not learning)"),
    }

    def _io(self, ctx):
        return ctx.e_u1, ctx.e_u1_dot, ctx.s_p, ctx.gains.gamma_1

    def _weight(self, ctx):
        return 1.0 / ctx.gains.gamma_1


@pytree_dataclass
class ForceNetwork(_NetworkTerm):
    """−Ξ_f Θ̂_f (ΛF_NN of eq. 48), F_f's input (e_λ, z), update Θ̂̇f = γ2 Ξfᵀ e_λ (eq. 31,
    with Remark 2's projection when the network has a radius). Storage
    α_λα_z/(2γ2(1+β_λ)) ‖Θ̂f‖² (eq. 36's α_λ/(γ2(1+β_λ)) for α_z = 2, Remark 3 in general)."""

    network: TanhNetwork
    adaptation: Adaptation | None = None
    side: ClassVar[str] = "force"
    key: ClassVar[str] = "theta_f"
    out: ClassVar[str] = "nn_f"
    fields: ClassVar[dict] = {
        "nn_f": ("λ units", "F_f's output Ξ_f Θ̂_f, eq. (19)"),
        "theta_f_norm": ("-", "‖Θ̂_f‖"),
        "theta_f_gate": ("-", "the dead zone's gate g on eq. (31)'s drive (0: inside the zone, not learning)"),
    }

    def _io(self, ctx):
        return ctx.e_lam, ctx.z, ctx.e_lam, ctx.gains.gamma_2

    def _weight(self, ctx):
        return 0.5 * ctx.c * ctx.gains.alpha_z / ctx.gains.gamma_2


@pytree_dataclass
class ForceRate(Term):
    """A force-rate term added to v_λ (not in the paper; docs/beyond-the-paper.md):

        b = −κ ṡ,

    ṡ the force error's rate from one of two sources (``source``):

    * "force": τ_f ṡ = e_λ − s, a first-order filtered derivative of e_λ with time constant τ_f; the
      filter state s is part of the controller state and starts at s(0) = e_λ(0) (no kick at the
      first sample);
    * "velocity": ṡ = k_s D²Â Ĵ q̇ (:attr:`Context.theta_rate`), the contact force's rate a penalty
      contact of stiffness k_s would give from the measured joint rates (λ = k D²θ̂ on the nominal
      constraint, sections 1 and 7; ``stiffness`` = k_s, the design's stiffest contact). The
      encoders' rates carry almost none of the force sensor's noise; the rate is the measurement's
      (λd's own rate is not differenced: no kick when λd moves); no state.

    It damps the contact mode that every law of the paper leaves unstable on a compliant surface
    (the loop polynomial m_s s³ + m_s μ_z s² + k_u K's + k_u(K'μ_z + α_z) fails Routh's test by
    −α_z m_s k_u).

    Storage, "force": with c = α_λ/(1+β_λ), e_λ = s + τ_f ṡ makes the new cross term of (38) an
    exact derivative, −cα_zκ e_λᵀṡ = −d/dt(cα_zκ/2 ‖s‖²) − cα_zκτ_f ‖ṡ‖², so V gains cα_zκ/2 ‖s‖²
    and (39) keeps its form with the extra dissipation cα_zκτ_f ‖ṡ‖² (added to J_aug by the
    bookkeeping: the stricter check). "velocity": no such identity ties ṡ to e_λ; the cross term
    x = cα_zκ e_λᵀṡ (the rate −x enters V̇) is carried as it is, its positive part as extra
    dissipation and its negative part as extra supply (exact; the same inequality as a storage
    cα_zκ/2 ‖e_λ‖² with the mismatch cα_zκ e_λᵀ(ė_λ − ṡ) as supply, docs/beyond-the-paper.md
    section 12)."""

    kappa: jax.Array
    tau_f: jax.Array
    # the design step's record ((name, value), ...), a Note: it never decides a program
    design: tuple = static_field(default=Note())
    stiffness: jax.Array | None = None  # k_s of the "velocity" source, N/m (None: "force")
    source: str = static_field(default="force")
    side: ClassVar[str] = "force"
    fields: ClassVar[dict] = {
        "v_rate": ("λ units", "force-rate term −κ ṡ added to v_λ (not in the paper)"),
        "s_lam": ("λ units", "filtered e_λ, the force-rate term's state"),
        "lam_rate": ("λ units/s", "the force-rate term's ṡ from the joint rates, k_s D²ÂĴq̇ (source \"velocity\")"),
    }

    def state_sizes(self, m, k):
        return {} if self.source == "velocity" else {"s_lam": k}

    def _s_dot(self, ctx, parts):
        if self.source == "velocity":
            return self.stiffness * ctx.theta_rate
        return (ctx.e_lam - parts["s_lam"]) / self.tau_f

    def evaluate(self, ctx, parts):
        s_dot = self._s_dot(ctx, parts)
        v = -self.kappa * s_dot
        if self.source == "velocity":
            return v, {}, {"v_rate": v, "lam_rate": s_dot}
        return v, {"s_lam": s_dot}, {"v_rate": v, "s_lam": parts["s_lam"]}

    def storage(self, ctx, parts):
        if self.source == "velocity":
            return None
        s = parts["s_lam"]
        return 0.5 * ctx.c * ctx.gains.alpha_z * self.kappa * ctx.kernels.mm(s, s)

    def _cross(self, ctx, parts):
        """x = cα_zκ e_λᵀṡ: the term's cross term in V̇ is −x."""
        return ctx.c * ctx.gains.alpha_z * self.kappa * ctx.kernels.mm(ctx.e_lam, self._s_dot(ctx, parts))

    def extra_dissipation(self, ctx, parts):
        if self.source == "velocity":
            return jnp.maximum(self._cross(ctx, parts), 0.0)
        s_dot = self._s_dot(ctx, parts)
        return ctx.c * ctx.gains.alpha_z * self.kappa * self.tau_f * ctx.kernels.mm(s_dot, s_dot)

    def extra_supply(self, ctx, parts):
        """"velocity": the negative part of −x (:meth:`_cross`); None for "force"."""
        if self.source == "velocity":
            return jnp.maximum(-self._cross(ctx, parts), 0.0)
        return None

    def start(self, ctx, parts):
        return {} if self.source == "velocity" else {"s_lam": ctx.e_lam}

    def check(self, m, k):
        from ..errors import DesignError
        from .sensing import check_source

        check_source(self.source)
        if self.source == "velocity" and self.stiffness is None:
            raise DesignError("the \"velocity\" source needs the design's stiffest contact k_s",
                              key="force_rate.stiffness_max", value=None)
