"""The reduced-order decoupling law (24)/(51), composed of terms.

    τ  = [B̄1; B̄2 − M̄21 M̄11⁻¹ B̄1]⁻¹ [Λp; Λf]                                   (24), (51)
    Λp = M̄11 [ü1d − K_v ė_u1 − K_p e_u1 + Σ a_i] + C̄11 u̇1 + Ḡ1                 (25)
    Λf = Πᵀ [λd + z + Σ b_j] + [C̄21 − M̄21 M̄11⁻¹ C̄11] u̇1 + [Ḡ2 − M̄21 M̄11⁻¹ Ḡ1]   (26)
    ż  = −μ_z z − α_z e_λ                                                        (27)

Without terms this is the feedback-linearization-like law of Sec. VI (the paper's CT parts,
eqs. 43, 49, 50); the position terms a_i and force terms b_j (:mod:`hinfnn.controllers.terms`)
make it the H∞-only law of Theorem 2 (v_p, v_λ) or the adaptive law of Theorem 1 (v_p, v_λ and
the networks). :mod:`hinfnn.controllers.kinds` lists these compositions.

A controller is built from the NOMINAL arm and surface and sees only a
:class:`~hinfnn.protocols.Measurement`; nothing here imports :mod:`hinfnn.plant`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .. import _linalg as la
from .._pytree import pytree_dataclass, static_field
from ..model.reduced import reduced_model
from ..reference import RefSample
from . import terms as T
from .gains import Gains


#: Largest 2m × 2m matrix (P_p, Q_p) used whole inside the compiled loop. XLA's CPU runtime runs a
#: loop body's kernels inline only when no kernel touches a buffer of more than 512 bytes
#: (:mod:`hinfnn._devices`, ``blocks``); P_p of a 6-DOF arm (m = 5) has 800. Larger ones are
#: split into their four m × m blocks at design time (:func:`split_blocks`) and used by blocks.
WHOLE = 64


def split_blocks(A, m: int):
    """The four m × m blocks (A11, A12, A21, A22) of a 2m × 2m matrix, or None when it is small
    enough to be used whole in the loop (at most :data:`WHOLE` entries)."""
    if A is None or (2 * m) ** 2 <= WHOLE:
        return None
    A = jnp.asarray(A)
    return (A[:m, :m], A[:m, m:], A[m:, :m], A[m:, m:])


def _times(A, blocks, x, m):
    """A x for x = (a, b), by blocks when given."""
    if blocks is None:
        return la.mm(A, x)
    a, b = x[:m], x[m:]
    A11, A12, A21, A22 = blocks
    return jnp.concatenate([la.mm(A11, a) + la.mm(A12, b), la.mm(A21, a) + la.mm(A22, b)])


def _lower_times(A, blocks, x, m):
    """(A x)[m:] (= B_pᵀ A x for B_p = [0; I]), by blocks when given."""
    if blocks is None:
        return la.mm(A[m:], x)
    return la.mm(blocks[2], x[:m]) + la.mm(blocks[3], x[m:])


def force_multiplier(A_hat, F):
    """λ = (Â Âᵀ)⁻¹ Â F: the force sensor's reading on the NOMINAL constraint gradient
    (docs/paper-conventions.md, Measurements)."""
    return la.solve(la.mm(A_hat, A_hat.T), la.mm(A_hat, F))


@pytree_dataclass
class ControllerState:
    """The controller's state: z of eq. (27) (k,) and the terms' state arrays by name
    (``theta_p``, ``theta_f`` for the networks), readable as attributes (``state.theta_f``).

    Public state is always flat arrays; inside the compiled loop the arrays a term declares
    ``blocked`` travel as tuples of blocks (:meth:`ReducedOrderController.to_loop`)."""

    z: jax.Array
    parts: dict

    def __getattr__(self, name):
        parts = self.__dict__.get("parts")
        if parts is not None and name in parts:
            return parts[name]
        raise AttributeError(name)

    def names(self) -> tuple[str, ...]:
        """("z", then the terms' arrays by name)."""
        return ("z", *sorted(self.parts))


@pytree_dataclass
class Output:
    """One evaluation of the law: τ, the state derivative, the recorded signals, and what the
    theorem bookkeeping needs (the reference sample, the terms' values, Ĵ and J̇̂)."""

    tau: jax.Array
    dstate: ControllerState
    signals: dict
    ref: RefSample
    values: tuple  # each term's value, in the controller's term order
    J: jax.Array
    J_dot: jax.Array | None
    ctx: T.Context
    fault: jax.Array  # True when the law cannot be trusted at this sample (singularity guard)
    Jd_qd: jax.Array | None = None  # J̇̂ q̇ when J̇̂ is not formed


@pytree_dataclass
class ReducedOrderController:
    """The law (24)–(27) with a tuple of terms. Build one with
    :func:`hinfnn.controllers.kinds.design` (or ``HinfController.design`` ...), which checks the
    gains against Theorem 1's bounds and solves the Riccati-like equation for P_p."""

    arm: object  # nominal arm (model.Arm)
    surface: object  # nominal surface (model.Surface)
    gains: Gains  # normalized
    P_p: jax.Array  # (2m, 2m); NaN when not designed (FL-like with an infeasible ρ)
    terms: tuple
    sigma_stop: jax.Array = 0.0  # singularity guard: fault when σ_min(Ĵ) < sigma_stop (0: off)
    kind: str = static_field(default="")
    augmented: bool = static_field(default=False)
    P_blocks: tuple | None = None  # P_p by m × m blocks for large m (split_blocks), set by design()
    Q_blocks: tuple | None = None  # gains.Q_p likewise

    # --- sizes -----------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return int(self.arm.n)

    @property
    def m(self) -> int:
        return self.surface.m

    @property
    def k(self) -> int:
        return self.surface.k

    def term(self, cls):
        """The first term of class ``cls``, or None."""
        return next((t for t in self.terms if isinstance(t, cls)), None)

    @property
    def network_p(self):
        t = self.term(T.PositionNetwork)
        return t.network if t is not None else None

    @property
    def network_f(self):
        t = self.term(T.ForceNetwork)
        return t.network if t is not None else None

    # --- state -----------------------------------------------------------------------------------
    def init(self, **given) -> ControllerState:
        """Sec. VI initial state: z(0) = 0, every term's state 0, unless given by name
        (``init(theta_f=...)``)."""
        parts = {}
        for term in self.terms:
            parts.update(term.init(self.m, self.k))
        unknown = set(given) - set(parts) - {"z"}
        if unknown:
            raise TypeError(f"unknown state arrays {sorted(unknown)}; this controller has z"
                            + "".join(f", {n}" for n in parts))
        for name, value in given.items():
            if value is None:
                continue
            if name == "z":
                continue
            parts[name] = jnp.asarray(value, dtype=float).reshape(parts[name].shape)
        z = jnp.zeros(self.k) if given.get("z") is None else jnp.asarray(given["z"], float).reshape(self.k)
        return ControllerState(z=z, parts=parts)

    def to_loop(self, state: ControllerState) -> ControllerState:
        """The state in the compiled loop's layout (:mod:`hinfnn._devices`, ``blocks``)."""
        return ControllerState(z=state.z, parts=T.to_loop(self.terms, state.parts))

    def from_loop(self, state: ControllerState) -> ControllerState:
        """Inverse of :meth:`to_loop`: flat arrays."""
        return ControllerState(z=state.z, parts=T.from_loop(self.terms, state.parts))

    def constrain(self, state: ControllerState) -> ControllerState:
        """Applied after each integration step (Remark 2's radial clip for projected networks;
        identity otherwise). Loop layout."""
        parts = dict(state.parts)
        for term in self.terms:
            parts.update(term.constrain(state.parts))
        return ControllerState(z=state.z, parts=parts)

    # --- measurement map (nominal kinematics, docs/paper-conventions.md "Measurements") ---------
    def observe(self, meas):
        """u1 = ĥ1(q), u̇1 = (Ĵ q̇)_1 and λ = (Â Âᵀ)⁻¹ Â F from the nominal model."""
        x = self.arm.h(meas.q)
        x_dot = la.mm(self.arm.J(meas.q), meas.qd)
        return x[: self.m], x_dot[: self.m], force_multiplier(self.surface.A_hat(x), meas.F)

    # --- the control law -----------------------------------------------------------------------
    def evaluate(self, t, state: ControllerState, meas, ref) -> Output:
        """τ, state derivative and signals at one instant. Implements eqs. (24)–(27) with the
        terms' eqs. (30)–(33), (41) added. ``state`` in the loop's layout (:meth:`to_loop`);
        ``ref`` a reference (callable on t, e.g. :class:`~hinfnn.reference.CosineReference`)."""
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
        s_p = _lower_times(self.P_p, self.P_blocks, x_p, m)  # B_pᵀ P_p x_p
        ctx = T.Context(t=jnp.asarray(t, dtype=float), ref=r, u1=u1, u1_dot=u1_dot, lam=lam, e_u1=e_u1,
                        e_u1_dot=e_u1_dot, e_lam=e_lam, z=state.z, x_p=x_p, s_p=s_p, gains=g, P_p=self.P_p,
                        augmented=self.augmented)

        mm = la.mm
        a = r.u1_d_ddot - mm(g.K_v, e_u1_dot) - mm(g.K_p, e_u1)
        b = r.lam_d + state.z
        dparts, signals, values = {}, {}, []
        for term in self.terms:
            value, d, sig = term.evaluate(ctx, state.parts)
            if term.side == "position":
                a = a + value
            else:
                b = b + value
            values.append(value)
            dparts.update(d)
            signals.update(sig)
        if rm.C_bar is not None:  # closed-form arms (the Sec. VI arm): C̄ formed
            lam_p = mm(rm.M11, a) + mm(rm.C11, u1_dot) + rm.G1  # eq. (25)
            C_f, G_f = rm.force_terms()
            lam_f = mm(rm.Pi.T, b) + mm(C_f, u1_dot) + G_f  # eq. (26)
            tau = la.solve(rm.decoupling_matrix(), jnp.concatenate([lam_p, lam_f]))  # eq. (24)
        else:  # only C̄ (u̇1, 0) formed (reduced_model's "product" path): the same law
            c = rm.C_u1dot
            L = la.spd_solve(rm.M11, rm.M21.T).T  # M̄21 M̄11⁻¹ (M̄11 symmetric positive definite)
            lam_p = mm(rm.M11, a) + c[:m] + rm.G1  # eq. (25)
            lam_f = mm(rm.Pi.T, b) + (c[m:] - mm(L, c[:m])) + (rm.G2 - mm(L, rm.G1))  # eq. (26)
            # eq. (24) without inverting: [B̄1; B̄2 − L B̄1] = P Sᵀ Ĵ⁻ᵀ with P = [[I, 0], [−L, I]],
            # so τ = Ĵᵀ S⁻ᵀ P⁻¹ [Λp; Λf], P⁻¹ y = (y1, y2 + L y1), S⁻ᵀ z = (z1 − Γᵀ z2, z2)
            y2 = lam_f + mm(L, lam_p)
            Gamma = rm.S[m:, :m]
            tau = mm(rm.J.T, jnp.concatenate([lam_p - mm(Gamma.T, y2), y2]))
        dz = -g.mu_z * state.z - g.alpha_z * e_lam  # eq. (27)
        sigma = sigma_min(rm.J)
        signals = {"u1": u1, "u1_dot": u1_dot, "lam": lam, "u1_d": r.u1_d, "u1_d_dot": r.u1_d_dot,
                   "lam_d": r.lam_d, "e_u1": e_u1, "e_u1_dot": e_u1_dot, "e_lam": e_lam, "z": state.z,
                   "tau": tau, "sigma_min_J": sigma, **signals}
        return Output(tau=tau, dstate=ControllerState(z=dz, parts=dparts), signals=signals, ref=r,
                      values=tuple(values), J=rm.J, J_dot=rm.J_dot, ctx=ctx, fault=sigma < self.sigma_stop,
                      Jd_qd=rm.Jd_qd)

    @property
    def needs_start(self) -> bool:
        """Whether some term sets its state from the first measurement (:meth:`start`)."""
        return any(type(term).start is not T.Term.start for term in self.terms)

    def start(self, t, state: ControllerState, meas, ref) -> ControllerState:
        """The state at the first sample, from the first measurement (a term's filter starts at
        its input, e.g. the force-rate filter at e_λ(0)). Loop layout."""
        if not self.needs_start:
            return state
        out = self.evaluate(t, state, meas, ref)
        parts = dict(state.parts)
        for term in self.terms:
            parts.update(term.start(out.ctx, state.parts))
        return ControllerState(z=state.z, parts=parts)

    def sample(self, t, period, state: ControllerState, meas, ref, out: Output | None = None):
        """The sampled-data update (zero-order hold): τ_k of eq. (24) at the sample and the state
        advanced by forward Euler over the period, then constrained (Remark 2's clip). Loop
        layout. The one definition used by the simulator's sampled mode and by
        :class:`~hinfnn.controllers.sampled.SampledController` (``out``: this sample's
        :meth:`evaluate`, when the caller has it)."""
        out = self.evaluate(t, state, meas, ref) if out is None else out
        new = self.constrain(jax.tree.map(lambda x, d: x + period * d, state, out.dstate))
        return out.tau, new

    # --- public conveniences on flat state ------------------------------------------------------
    def torque(self, t, state, meas, ref):
        """τ of eq. (24) (flat state, as :meth:`init` returns it)."""
        return self.evaluate(t, self.to_loop(state), meas, ref).tau

    def derivative(self, t, state, meas, ref) -> ControllerState:
        """The state's time derivative: ż of eq. (27), the networks' updates (30)–(31) (flat)."""
        return self.from_loop(self.evaluate(t, self.to_loop(state), meas, ref).dstate)

    def signals(self, t, state, meas, ref) -> dict:
        """Every named signal of :meth:`evaluate` (flat state)."""
        return self.evaluate(t, self.to_loop(state), meas, ref).signals

    # --- the theorems' bookkeeping ---------------------------------------------------------------
    def performance(self, state, out: Output):
        """Integrand of the H∞ index, eq. (34) with Remark 3's weight α_λα_z/2 on e_λ, the same
        for every controller; and the extra terms of Remark 1's augmented index (0 otherwise).
        Implements eq. (34)."""
        g = self.gains
        c = out.ctx
        mm = la.mm
        j = (mm(c.x_p, _times(g.Q_p, self.Q_blocks, c.x_p, self.m)) + 0.5 * g.alpha_lam * g.alpha_z * mm(c.e_lam, c.e_lam)
             + g.alpha_lam * g.mu_z / (1.0 + g.beta_lam) * mm(state.z, state.z))
        extra = jnp.zeros_like(j)
        for term, value in zip(self.terms, out.values):
            e = term.extra_performance(c, value) if self.augmented else None
            if e is not None:
                extra = extra + e
            d = term.extra_dissipation(c, state.parts)
            if d is not None:
                extra = extra + d
        return j, extra

    def storage(self, state, out: Output):
        """Storage function V of eqs. (36)/(55) with Θ* = 0 (so Θ̃ = Θ̂ and ε = f), plus the
        terms' contributions: V = x_pᵀ P_p x_p + α_λ/(2(1+β_λ)) ‖z‖² + Σ V_term."""
        c = out.ctx
        V = la.mm(c.x_p, _times(self.P_p, self.P_blocks, c.x_p, self.m)) + 0.5 * c.c * la.mm(state.z, state.z)
        for term in self.terms:
            v = term.storage(c, state.parts)
            if v is not None:
                V = V + v
        return V

    def supply_residuals(self, out: Output, u1_ddot):
        """f_p, f_f as the actual residuals of the error systems (28)–(29) / (52)–(53):
        f_p = ë_u1 + K_p e_u1 + K_v ė_u1 − Σ a_i,  f_f = e_λ − z − Σ b_j, with ë_u1 from the true
        motion (:meth:`u1_ddot`)."""
        g = self.gains
        c = out.ctx
        f_p = (u1_ddot - out.ref.u1_d_ddot) + la.mm(g.K_p, c.e_u1) + la.mm(g.K_v, c.e_u1_dot)
        f_f = c.e_lam - c.z
        for term, v in zip(self.terms, out.values):
            if term.side == "position":
                f_p = f_p - v
            else:
                f_f = f_f - v
        return f_p, f_f

    def dissipation(self, state, out: Output, qd, qdd) -> dict:
        """The theorems' bookkeeping at one instant, given the true joint acceleration q̈ (from
        the plant, like an accelerometer): the integrand ``j`` of eq. (34) and Remark 1's
        ``j_extra``, the supply rate ρ²(‖f_p‖² + ‖f_f‖²), the storage ``V`` and the residuals
        ``f_p``, ``f_f``. Along any run, J(t) + V(t) − V(0) ≤ ∫ supply must hold (Theorems 1–2)."""
        j, extra = self.performance(state, out)
        f_p, f_f = self.supply_residuals(out, self.u1_ddot(out, qd, qdd))
        supply = self.gains.rho**2 * (la.mm(f_p, f_p) + la.mm(f_f, f_f))
        return {"j": j, "j_extra": extra, "supply": supply, "V": self.storage(state, out), "f_p": f_p, "f_f": f_f}

    # --- design-time checks ----------------------------------------------------------------------
    def check_start(self, q0, min_abs_det: float = 1e-6) -> None:
        """The start pose must be finite and the nominal Jacobian Ĵ(q0) nonsingular (A1).
        Raises :class:`~hinfnn.errors.DesignError` keyed ``initial.u1``."""
        import numpy as np

        from ..errors import DesignError

        q0 = np.asarray(q0, dtype=float)
        if not np.all(np.isfinite(q0)):
            raise DesignError(f"the start pose is unreachable: q0 = {q0.tolist()} (u1(0) is out of the "
                              "true arm's reach on the true surface)", key="initial.u1")
        det = float(_nominal_jacobian_det(self.arm, jnp.asarray(q0)))
        if not abs(det) >= min_abs_det:
            raise DesignError(f"the nominal Jacobian is singular at the start pose q0 = {np.round(q0, 6).tolist()} "
                              f"(|det J| = {abs(det):.3g} < {min_abs_det:g}): (A1) fails", key="initial.u1")

    def u1_ddot(self, out: Output, qd, qdd):
        """d²/dt² of the measured u1 = ĥ1(q) along a motion with joint acceleration q̈:
        (Ĵ q̈ + J̇̂ q̇)_1 (the chain rule on the controller's own observation map)."""
        Jd_qd = la.mm(out.J_dot, qd) if out.J_dot is not None else out.Jd_qd
        return (la.mm(out.J, qdd) + Jd_qd)[: self.m]


def sigma_min(J):
    """The smallest singular value of Ĵ (closed form for 2 × 2; the singularity guard's measure:
    the torque of (24) grows like 1/σ_min near a singularity)."""
    if J.shape == (1, 1):
        return jnp.abs(J[0, 0])
    if J.shape == (2, 2):
        a = jnp.sum(J * J)
        det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
        return jnp.sqrt(jnp.maximum(0.5 * (a - jnp.sqrt(jnp.maximum(a * a - 4.0 * det * det, 0.0))), 0.0))
    return jnp.linalg.svd(J, compute_uv=False)[-1]


@jax.jit
def nominal_sigma_min(arm, q):
    """σ_min(Ĵ(q)) as one compiled program (the scenario check of the path against the
    singularity guard evaluates it along the reference)."""
    return sigma_min(arm.J(q))


@jax.jit
def _nominal_jacobian_det(arm, q):
    """det Ĵ(q) as one compiled program (a new process lowers each eager operation separately)."""
    return jnp.linalg.det(arm.J(q))
