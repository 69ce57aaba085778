"""What the paper's three controllers share: the reduced-order decoupling law (24)/(51).

All three compute τ = [B̄1; B̄2 − M̄21 M̄11⁻¹ B̄1]⁻¹ [Λp; Λf] with

    Λp = M̄11 [ü1d − K_v ė_u1 − K_p e_u1 + v_p − Ξp Θ̂p] + C̄11 u̇1 + Ḡ1          (25)
    Λf = Πᵀ [λd + z + v_λ − Ξf Θ̂f] + [C̄21 − M̄21 M̄11⁻¹ C̄11] u̇1 + [Ḡ2 − M̄21 M̄11⁻¹ Ḡ1]   (26)
    ż  = −μ_z z − α_z e_λ                                                       (27)

and differ in which terms are present:

================  =====================  ==========================  ===========
controller        v_p (33)               v_λ                         networks
================  =====================  ==========================  ===========
FL-like (VI)      0                      0                           no
H∞-only (Th. 2)   −R_p⁻¹ B_pᵀ P_p x_p    −β_λ/2 e_λ (32)             no
adaptive (Th. 1)  −R_p⁻¹ B_pᵀ P_p x_p    −β_λ/2 e_λ, or −β_λ e_λ     (30), (31)
                                         (Remark 1, eq. 41)
================  =====================  ==========================  ===========

A controller is built from the NOMINAL arm and surface and sees only a
:class:`~hinfnn.measurement.Measurement`; it never imports :mod:`hinfnn.plant`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import pytree_dataclass, static_field
from .. import _linalg as la
from ..errors import DesignError
from ..model.reduced import reduced_model
from .gains import Gains
from .riccati import design_riccati
from .network import TanhNetwork, sq_norm


def force_multiplier(A_hat, F):
    """λ = (Â Âᵀ)⁻¹ Â F: the force sensor's reading on the NOMINAL constraint gradient
    (NOTES.md, Measurements)."""
    return la.solve(la.mm(A_hat, A_hat.T), la.mm(A_hat, F))


@pytree_dataclass
class ControllerState:
    """Internal state integrated with the plant: z (k,), Θ̂p (m·j_p,), Θ̂f (k·j_f,).

    Controllers without networks carry empty weight vectors, so every controller has the same
    state structure. Inside the simulator the weights are carried as tuples of blocks
    (:meth:`ReducedOrderController.blocked`, see :mod:`hinfnn.controllers.network`); every
    method of a controller accepts either form and returns the form it was given.
    """

    z: jax.Array
    theta_p: jax.Array
    theta_f: jax.Array


@pytree_dataclass
class Signals:
    """Everything a controller computes at one instant (for torque, logging and the theorems)."""

    u1: jax.Array
    u1_dot: jax.Array
    lam: jax.Array
    e_u1: jax.Array
    e_u1_dot: jax.Array
    e_lam: jax.Array
    v_p: jax.Array
    v_lam: jax.Array
    nn_p: jax.Array  # Ξp Θ̂p
    nn_f: jax.Array  # Ξf Θ̂f
    tau: jax.Array


@pytree_dataclass
class ReducedOrderController:
    """Base of the three controllers; use their ``design`` class methods to build one."""

    arm: object  # nominal arm (model.Arm)
    surface: object  # nominal surface (model.Surface)
    gains: Gains  # normalized
    P_p: jax.Array  # (2m, 2m); NaN when not designed (FL-like with an infeasible ρ)
    network_p: TanhNetwork | None
    network_f: TanhNetwork | None
    kind: str = static_field(default="")
    robust: bool = static_field(default=False)
    learning: bool = static_field(default=False)
    augmented: bool = static_field(default=False)

    # --- sizes ---------------------------------------------------------------------------------
    @property
    def m(self) -> int:
        return self.surface.m

    @property
    def k(self) -> int:
        return self.surface.k

    # --- measurement map (nominal kinematics, NOTES.md "Measurements") ------------------------
    def observe(self, meas):
        """u1 = ĥ1(q), u̇1 = (Ĵ q̇)_1 and λ = (Â Âᵀ)⁻¹ Â F from the nominal model."""
        x = self.arm.h(meas.q)
        x_dot = la.mm(self.arm.J(meas.q), meas.qd)
        return x[: self.m], x_dot[: self.m], force_multiplier(self.surface.A_hat(x), meas.F)

    def u1_ddot(self, q, qd, qdd):
        """d²/dt² of the measured u1 = ĥ1(q): (Ĵ q̈ + J̇̂ q̇)_1 (used by the dissipation check)."""
        at = self.arm.terms(q, qd)
        return (la.mm(at.J, qdd) + la.mm(at.J_dot, qd))[: self.m]

    # --- state -----------------------------------------------------------------------------------
    def init(self, theta_p=None, theta_f=None) -> ControllerState:
        """Sec. VI initial controller state: z(0) = 0, all weights 0."""
        n_p = self.network_p.size if self.learning else 0
        n_f = self.network_f.size if self.learning else 0
        zeros = jnp.zeros
        return ControllerState(
            z=zeros(self.k),
            theta_p=zeros(n_p) if theta_p is None else jnp.asarray(theta_p, float).reshape(n_p),
            theta_f=zeros(n_f) if theta_f is None else jnp.asarray(theta_f, float).reshape(n_f),
        )

    def blocked(self, xc: ControllerState) -> ControllerState:
        """The same state with Θ̂p, Θ̂f as tuples of ≤ 64-unit blocks (what the simulator carries)."""
        if not self.learning:
            return xc
        return ControllerState(z=xc.z, theta_p=self.network_p.split(xc.theta_p),
                               theta_f=self.network_f.split(xc.theta_f))

    def flat(self, xc: ControllerState) -> ControllerState:
        """Inverse of :meth:`blocked`: Θ̂p, Θ̂f as flat vectors."""
        return ControllerState(z=xc.z, theta_p=TanhNetwork.join(xc.theta_p),
                               theta_f=TanhNetwork.join(xc.theta_f))

    def constrain(self, xc: ControllerState) -> ControllerState:
        """Applied by the simulator after each integration step: with Remark 2's projection, put
        Θ̂ back on the ball ‖Θ̂‖ ≤ d if the step overshot it. The projected flow is tangent to the
        sphere, but its switch at ‖Θ̂‖ = d lets a fixed RK4 step cross by O(dt); the radial clip
        makes the guarantee ‖Θ̂(t)‖ ≤ d hold exactly (it only shrinks V). Identity otherwise."""
        if not self.learning:
            return xc

        def clip(net, theta):
            if not net.project:
                return theta
            scale = jnp.minimum(1.0, net.radius / jnp.maximum(jnp.sqrt(sq_norm(theta)), 1e-300))
            return tuple(t * scale for t in theta) if isinstance(theta, tuple) else theta * scale

        return ControllerState(z=xc.z, theta_p=clip(self.network_p, xc.theta_p),
                               theta_f=clip(self.network_f, xc.theta_f))

    # --- the control law ---------------------------------------------------------------------
    def step_terms(self, t, xc: ControllerState, meas, ref):
        """Torque, state derivative and signals at one instant. Implements Eqs. (24)–(33), (41), (51).

        ``ref`` is a reference (callable on t, e.g. :class:`~hinfnn.reference.CosineReference`).
        """
        g = self.gains
        m = self.m
        r = ref(t)
        rm = reduced_model(self.arm, self.surface, meas.q, meas.qd)
        u1, u1_dot = rm.x[:m], rm.x_dot[:m]
        lam = force_multiplier(rm.A_hat, meas.F)
        e_u1 = u1 - r.u1_d
        e_u1_dot = u1_dot - r.u1_d_dot
        e_lam = lam - r.lam_d
        x_p = jnp.concatenate([e_u1, e_u1_dot])
        s_p = la.mm(self.P_p[m:], x_p)  # B_pᵀ P_p x_p

        zeros_m, zeros_k = jnp.zeros_like(e_u1), jnp.zeros_like(e_lam)
        if self.robust:
            v_p = -la.solve(g.R_p, s_p)  # eq. (33)
            v_lam = -(g.beta_lam if self.augmented else 0.5 * g.beta_lam) * e_lam  # (41) / (32)
        else:
            v_p, v_lam = zeros_m, zeros_k
        if self.learning:
            xi_p = self.network_p.features_blocks(e_u1, e_u1_dot)
            xi_f = self.network_f.features_blocks(e_lam, xc.z)
            nn_p = self.network_p.output_blocks(xi_p, xc.theta_p)
            nn_f = self.network_f.output_blocks(xi_f, xc.theta_f)
        else:
            nn_p, nn_f = zeros_m, zeros_k

        mm = la.mm
        a = r.u1_d_ddot - mm(g.K_v, e_u1_dot) - mm(g.K_p, e_u1) + v_p - nn_p
        lam_p = mm(rm.M11, a) + mm(rm.C11, u1_dot) + rm.G1  # eq. (25)
        C_f, G_f = rm.force_terms()
        lam_f = mm(rm.Pi.T, r.lam_d + xc.z + v_lam - nn_f) + mm(C_f, u1_dot) + G_f  # eq. (26)
        tau = la.solve(rm.decoupling_matrix(), jnp.concatenate([lam_p, lam_f]))  # (24)

        dz = -g.mu_z * xc.z - g.alpha_z * e_lam  # eq. (27)
        if self.learning:
            d_theta_p = self.network_p.update_blocks(xi_p, s_p, xc.theta_p, g.gamma_1)  # eq. (30)
            d_theta_f = self.network_f.update_blocks(xi_f, e_lam, xc.theta_f, g.gamma_2)  # eq. (31)
        else:
            d_theta_p, d_theta_f = xc.theta_p, xc.theta_f  # empty arrays
        dxc = ControllerState(z=dz, theta_p=d_theta_p, theta_f=d_theta_f)
        sig = Signals(u1=u1, u1_dot=u1_dot, lam=lam, e_u1=e_u1, e_u1_dot=e_u1_dot, e_lam=e_lam,
                      v_p=v_p, v_lam=v_lam, nn_p=nn_p, nn_f=nn_f, tau=tau)
        return tau, dxc, sig

    def torque(self, t, xc, meas, ref):
        """τ of eq. (24) (eq. 51 without networks; the Sec. VI FL-like law without v_p, v_λ)."""
        return self.step_terms(t, xc, meas, ref)[0]

    def derivative(self, t, xc, meas, ref) -> ControllerState:
        """(ż, dΘ̂p/dt, dΘ̂f/dt) of eqs. (27), (30), (31)."""
        return self.step_terms(t, xc, meas, ref)[1]

    def signals(self, t, xc, meas, ref) -> Signals:
        return self.step_terms(t, xc, meas, ref)[2]

    # --- the theorems' bookkeeping -----------------------------------------------------------
    def performance_rate(self, xc, sig):
        """Integrand of the H∞ index, eq. (34) (Remark 3's weight α_λ α_z/2 on e_λ).

        Returns (eq. 34 integrand, extra terms of Remark 1's augmented index or 0).
        """
        g = self.gains
        x_p = jnp.concatenate([sig.e_u1, sig.e_u1_dot])
        mm = la.mm
        j = (mm(x_p, mm(g.Q_p, x_p)) + 0.5 * g.alpha_lam * g.alpha_z * mm(sig.e_lam, sig.e_lam)
             + g.alpha_lam * g.mu_z / (1.0 + g.beta_lam) * mm(xc.z, xc.z))
        if self.augmented:
            extra = mm(sig.v_p, mm(g.R_p, sig.v_p)) + (
                g.alpha_lam * g.alpha_z / (2.0 * g.beta_lam * (1.0 + g.beta_lam)) * mm(sig.v_lam, sig.v_lam))
        else:
            extra = jnp.zeros_like(j)
        return j, extra

    def storage(self, xc, sig):
        """Storage function V of eqs. (36)/(55), with Θ* = 0 (so Θ̃ = Θ̂ and ε = f).

        V = x_pᵀ P_p x_p + α_λ/(2(1+β_λ)) ‖z‖² + ‖Θ̂p‖²/γ1 + α_λ α_z/(2 γ2 (1+β_λ)) ‖Θ̂f‖²
        (the last weight is eq. 36's α_λ/(γ2(1+β_λ)) generalised to any α_z, Remark 3).
        """
        g = self.gains
        x_p = jnp.concatenate([sig.e_u1, sig.e_u1_dot])
        c = g.alpha_lam / (1.0 + g.beta_lam)
        return (la.mm(x_p, la.mm(self.P_p, x_p)) + 0.5 * c * la.mm(xc.z, xc.z) + sq_norm(xc.theta_p) / g.gamma_1
                + 0.5 * c * g.alpha_z / g.gamma_2 * sq_norm(xc.theta_f))

    def supply_residuals(self, t, xc, sig, u1_ddot, ref):
        """f_p, f_f as the actual residuals of the error systems (28)–(29) / (52)–(53).

        f_p = ë_u1 + K_p e_u1 + K_v ė_u1 − v_p + Ξp Θ̂p,   f_f = e_λ − z − v_λ + Ξf Θ̂f,
        with ë_u1 from the true motion (``u1_ddot`` supplied by the simulator).
        """
        g = self.gains
        r = ref(t)
        f_p = (u1_ddot - r.u1_d_ddot) + la.mm(g.K_p, sig.e_u1) + la.mm(g.K_v, sig.e_u1_dot) - sig.v_p + sig.nn_p
        f_f = sig.e_lam - xc.z - sig.v_lam + sig.nn_f
        return f_p, f_f


def build_controller(cls, arm, surface, gains, *, kind, robust, learning, augmented=False,
                     network_p=None, network_f=None, require_bounds=True, riccati_required=True):
    """Shared design step: validate gains, solve the Riccati-like equation, check networks.

    Returns ``(controller, RiccatiSolution | None)``.
    """
    g = gains.normalized(surface.m, surface.k, require_bounds=require_bounds)
    try:
        sol = design_riccati(g, "40" if augmented else "35")
        P = jnp.asarray(sol.P)
    except DesignError:
        if riccati_required:
            raise
        sol, P = None, jnp.full((2 * surface.m, 2 * surface.m), jnp.nan)
    if learning:
        for name, net, dim in (("network_p", network_p, surface.m), ("network_f", network_f, surface.k)):
            if net is None:
                raise DesignError("the adaptive controller needs both networks", key=name)
            if net.n_out != dim:
                raise DesignError(f"must have {dim} outputs, has {net.n_out}", key=f"{name}.n_out")
            for wname in ("w_a", "w_b"):
                w = np.asarray(getattr(net, wname))
                if w.size not in (1, dim):
                    raise DesignError(f"must have 1 or {dim} entries, got {w.size}", key=f"{name}.{wname}")
    ctrl = cls(arm=arm, surface=surface, gains=g, P_p=P,
               network_p=network_p if learning else None, network_f=network_f if learning else None,
               kind=kind, robust=robust, learning=learning, augmented=augmented)
    return ctrl, sol

