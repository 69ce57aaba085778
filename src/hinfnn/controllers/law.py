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
:class:`~hinfnn.protocols.Measurement`: joint angles, rates and the contact force at the tool,
which it maps into its task coordinates with its own nominal kinematics (:func:`measured_force`).
Nothing here imports :mod:`hinfnn.plant`.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from .. import _linalg as la
from .._declared import setup_program
from .._pytree import pytree_dataclass, static_field
from ..model.reduced import reduced_model
from ..protocols import Controller, ControllerOutput, Dissipation, Dissipative
from ..reference import RefSample
from . import terms as T
from .gains import Gains
from .network import block_bounds, join, split

#: Largest number of float64 values the controller keeps in one array inside the compiled loop
#: (512 bytes): XLA's CPU runtime runs a loop body's kernels inline only when no kernel touches a
#: larger buffer; one larger buffer sends the step's kernels through its thread pool, which costs
#: about as much as the step's arithmetic (docs/performance.md). The networks' weights Θ̂ (40 and
#: 120 values) travel as blocks, and P_p, Q_p of more than this many entries are used by their
#: m × m blocks.
BLOCK = 64


def split_blocks(A, m: int, limit: int | None = BLOCK):
    """The four m × m blocks (A11, A12, A21, A22) of a 2m × 2m matrix, or None when it has at most
    ``limit`` entries (used whole; None: never split)."""
    if A is None or not limit or (2 * m) ** 2 <= limit:
        return None
    return (A[:m, :m], A[:m, m:], A[m:, :m], A[m:, m:])


def _times(A, blocks, x, m, kernels: la.Kernels = la.DEFAULT):
    """A x for x = (a, b), by blocks when given."""
    mm = kernels.mm
    if blocks is None:
        return mm(A, x)
    a, b = x[:m], x[m:]
    A11, A12, A21, A22 = blocks
    return jnp.concatenate([mm(A11, a) + mm(A12, b), mm(A21, a) + mm(A22, b)])


def _lower_times(A, blocks, x, m, kernels: la.Kernels = la.DEFAULT):
    """(A x)[m:] (= B_pᵀ A x for B_p = [0; I]), by blocks when given."""
    mm = kernels.mm
    if blocks is None:
        return mm(A[m:], x)
    return mm(blocks[2], x[:m]) + mm(blocks[3], x[m:])


def force_multiplier(A_hat, F, kernels: la.Kernels = la.DEFAULT):
    """λ = (Â Âᵀ)⁻¹ Â F: the force sensor's reading on the NOMINAL constraint gradient
    (docs/paper-conventions.md, Measurements)."""
    return kernels.solve(kernels.mm(A_hat, A_hat.T), kernels.mm(A_hat, F))


def measured_force(J, J_p, force, kernels: la.Kernels = la.DEFAULT):
    """The task-space force F the controller works with, from the contact force at the tool point
    (:class:`~hinfnn.protocols.Measurement`), by its NOMINAL kinematics: F with Ĵᵀ F = Ĵ_pᵀ f (the
    same joint torque), F = (Ĵ Ĵᵀ)⁻¹ Ĵ Ĵ_pᵀ f, Ĵ_p the tool point's Jacobian. When the task
    coordinates are the tool point itself (``J_p`` None: the paper's arm, whose task coordinates
    are its tip position), F = f."""
    if J_p is None:
        return force
    mm = kernels.mm
    return kernels.spd_solve(mm(J, J.T), mm(J, mm(J_p.T, force)))


@pytree_dataclass
class ControllerState:
    """The controller's state: z of eq. (27) (k,) and the terms' state arrays by name
    (``theta_p``, ``theta_f`` for the networks), read as flat arrays by attribute
    (``state.theta_f``) or all at once (:meth:`arrays`).

    The arrays a term declares ``blocked`` are kept as tuples of blocks of at most
    :data:`BLOCK` values (the layout the compiled loop runs fastest with); build states with
    :meth:`ReducedOrderController.init`, which takes flat arrays."""

    z: jax.Array
    parts: dict

    def __getattr__(self, name):
        parts = self.__dict__.get("parts")
        if parts is not None and name in parts:
            v = parts[name]
            return join(v) if isinstance(v, tuple) else v
        raise AttributeError(name)

    def names(self) -> tuple[str, ...]:
        """("z", then the terms' arrays by name)."""
        return ("z", *sorted(self.parts))

    def arrays(self) -> dict:
        """{"z": z, name: flat array, ...}."""
        return {"z": self.z, **{name: getattr(self, name) for name in self.parts}}


@pytree_dataclass
class LawAux:
    """What the theorem bookkeeping needs of one evaluation of the law (its
    :attr:`~hinfnn.protocols.ControllerOutput.aux`): the reference sample, the terms' values, Ĵ
    and J̇̂ (or J̇̂ q̇ when J̇̂ is not formed) and the terms' context."""

    ref: RefSample
    values: tuple  # each term's value, in the controller's term order
    J: jax.Array
    J_dot: jax.Array | None
    ctx: T.Context
    Jd_qd: jax.Array | None = None


#: One evaluation of the law (the protocol's output; ``aux`` a :class:`LawAux`).
Output = ControllerOutput


@pytree_dataclass
class ReducedOrderController(Controller, Dissipative):
    """The law (24)–(27) with a tuple of terms. Build one with
    :func:`hinfnn.controllers.kinds.design` (or ``HinfController.design`` ...), which checks the
    gains against Theorem 1's bounds and solves the Riccati-like equation for P_p.

    ``block``: the largest array the state keeps inside the compiled loop (:data:`BLOCK`; None:
    arrays whole)."""

    arm: object  # nominal arm (model.Arm)
    surface: object  # nominal surface (model.Surface)
    gains: Gains  # normalized
    P_p: jax.Array  # (2m, 2m); NaN when not designed (FL-like with an infeasible ρ)
    terms: tuple
    sigma_stop: jax.Array = 0.0  # singularity guard: fault when σ_min(Ĵ) < sigma_stop (0: off)
    kind: str = static_field(default="")
    augmented: bool = static_field(default=False)
    block: int | None = static_field(default=BLOCK)
    P_blocks: tuple | None = None  # P_p's m × m blocks, taken outside a compiled loop (prepared)
    Q_blocks: tuple | None = None  # Q_p's, the same
    # the sampled controller's low-pass on the measured e_λ (hinfnn.controllers.sensing; None: none, the paper's)
    force_filter: object = None
    kernels: la.Kernels = la.kernels_field()  # how the law's linear algebra is written (hinfnn._linalg)
    fault_name: ClassVar[str] = "σ_min(Ĵ), below the singularity guard's stop"

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

    # --- the compiled loop's layout ---------------------------------------------------------------
    def _blocks(self, A, held):
        """The m × m blocks of P_p or Q_p: those :meth:`prepared` holds, else cut here (None when
        the matrix is used whole)."""
        return held if held is not None else split_blocks(A, self.m, self.block)

    def prepared(self) -> "ReducedOrderController":
        """This controller as a compiled loop holds it: P_p, Q_p and the networks' centres also
        held by the blocks the law reads (of at most :data:`BLOCK` values), cut once, outside the
        loop. XLA's CPU runtime runs a loop body's kernels one after the other, without its
        scheduler, only when no kernel touches more than 512 bytes; a block cut inside the loop
        reads the whole array (P_p of a 6-DOF arm on a plane is 10 × 10, 800 bytes; F_p's centres
        5 × 40, 1,600). The same numbers."""
        if self.block is None:
            return self
        return dataclasses.replace(
            self, P_blocks=split_blocks(self.P_p, self.m, self.block),
            Q_blocks=split_blocks(self.gains.Q_p, self.m, self.block),
            terms=tuple(t.prepared(self.block) for t in self.terms))

    # --- state -----------------------------------------------------------------------------------
    def init(self, **given) -> ControllerState:
        """Sec. VI initial state: z(0) = 0, every term's state 0, unless given by name as flat
        arrays (``init(theta_f=...)``; :meth:`ControllerState.arrays` of another state)."""
        parts = {}
        for term in self.terms:
            parts.update(term.init(self.m, self.k))
        if self.force_filter is not None:
            parts["lam_filter"] = jnp.zeros(self.force_filter.state_size(self.k))
        unknown = set(given) - set(parts) - {"z"}
        if unknown:
            raise TypeError(f"unknown state arrays {sorted(unknown)}; this controller has z"
                            + "".join(f", {n}" for n in parts))
        for name, value in given.items():
            if value is None or name == "z":
                continue
            parts[name] = jnp.asarray(value, dtype=float).reshape(parts[name].shape)
        for term in self.terms:
            for name, groups in term.blocked.items():
                parts[name] = split(parts[name], groups, self.block)
        z = jnp.zeros(self.k) if given.get("z") is None else jnp.asarray(given["z"], float).reshape(self.k)
        return ControllerState(z=z, parts=parts)

    def summary(self) -> dict:
        """The resolved design (:func:`hinfnn.controllers.summary.design_summary`)."""
        from .summary import design_summary

        return design_summary(self)

    def state_from_arrays(self, arrays: dict) -> ControllerState:
        """The state with the flat arrays ``arrays`` (:meth:`ControllerState.arrays`; NumPy or
        traced, with any leading batch axes), in the controller's layout."""
        parts = {}
        for name, tpl in self.init().parts.items():
            v = arrays[name]
            if isinstance(tpl, tuple):
                edges = np.cumsum([0] + [int(b.shape[-1]) for b in tpl])
                v = tuple(v[..., a:b] for a, b in zip(edges[:-1], edges[1:]))
            parts[name] = v
        return ControllerState(z=arrays["z"], parts=parts)

    def state_arrays(self, state: ControllerState) -> dict:
        """z and the terms' arrays, flat (:meth:`ControllerState.arrays`)."""
        return state.arrays()

    def constrain(self, state: ControllerState) -> ControllerState:
        """Applied after each integration step (Remark 2's radial clip for projected networks;
        identity otherwise)."""
        parts = dict(state.parts)
        for term in self.terms:
            parts.update(term.constrain(state.parts))
        return ControllerState(z=state.z, parts=parts)

    # --- measurement map (nominal kinematics, docs/paper-conventions.md "Measurements") ---------
    def observe(self, meas):
        """u1 = ĥ1(q), u̇1 = (Ĵ q̇)_1 and λ = (Â Âᵀ)⁻¹ Â F from the nominal model (F the measured
        tool force in task coordinates, :func:`measured_force`): what :meth:`evaluate` reads, from
        the arm's ĥ, Ĵ and Ĵ_p alone (the reduced-order model's M̄, C̄, Ḡ are not needed; a URDF
        arm's by 3 × 3 products, :meth:`hinfnn.model.urdf.UrdfChain.fk`: design programs call this)."""
        arm, k = self.arm, self.kernels
        x, J = arm.h(meas.q), arm.J(meas.q)
        F = measured_force(J, None if arm.task_is_point else arm.point_jacobian(meas.q), meas.force, k)
        return x[: self.m], k.mm(J, meas.qd)[: self.m], force_multiplier(self.surface.A_hat(x), F, k)

    # --- the control law -----------------------------------------------------------------------
    def evaluate(self, t, state: ControllerState, meas, ref) -> ControllerOutput:
        """τ, state derivative and signals at one instant. Implements eqs. (24)–(27) with the
        terms' eqs. (30)–(33), (41) added. ``state`` as :meth:`init` gives it; ``ref`` a
        reference (callable on t, e.g. :class:`~hinfnn.reference.CosineReference`)."""
        g = self.gains
        m = self.m
        r = ref(t)
        rm = reduced_model(self.arm, self.surface, meas.q, meas.qd)
        u1, u1_dot = rm.x[:m], rm.x_dot[:m]
        kern = self.kernels
        F = measured_force(rm.J, rm.J_p, meas.force, kern)
        lam = force_multiplier(rm.A_hat, F, kern)
        e_u1 = u1 - r.u1_d
        e_u1_dot = u1_dot - r.u1_d_dot
        e_lam = lam - r.lam_d
        dparts = {}
        if self.force_filter is not None:  # everything the law does with e_λ reads it low-passed
            x_f = state.parts["lam_filter"]
            dparts["lam_filter"] = self.force_filter.rate(e_lam, x_f)
            e_lam = self.force_filter.output(e_lam, x_f)
        x_p = jnp.concatenate([e_u1, e_u1_dot])
        s_p = _lower_times(self.P_p, self._blocks(self.P_p, self.P_blocks), x_p, m, kern)  # B_pᵀ P_p x_p
        # the nominal constraint's rate per constraint, D²ÂĴq̇ (λ̇ per unit stiffness on a penalty contact;
        # read by the force-rate term's "velocity" source only, so no other program computes it)
        theta_rate = kern.mm(rm.A_hat, rm.x_dot) / jnp.sum(rm.A_hat * rm.A_hat, axis=1)
        ctx = T.Context(t=jnp.asarray(t, dtype=float), ref=r, u1=u1, u1_dot=u1_dot, lam=lam, e_u1=e_u1,
                        e_u1_dot=e_u1_dot, e_lam=e_lam, z=state.z, x_p=x_p, s_p=s_p, gains=g, P_p=self.P_p,
                        theta_rate=theta_rate, augmented=self.augmented, kernels=kern)

        mm = kern.mm
        a = r.u1_d_ddot - mm(g.K_v, e_u1_dot) - mm(g.K_p, e_u1)
        b = r.lam_d + state.z
        signals, values = {}, []
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
            tau = kern.solve(rm.decoupling_matrix(), jnp.concatenate([lam_p, lam_f]))  # eq. (24)
        else:  # only C̄ (u̇1, 0) formed (reduced_model's "product" path): the same law
            c = rm.C_u1dot
            L = kern.spd_solve(rm.M11, rm.M21.T).T  # M̄21 M̄11⁻¹ (M̄11 symmetric positive definite)
            lam_p = mm(rm.M11, a) + c[:m] + rm.G1  # eq. (25)
            lam_f = mm(rm.Pi.T, b) + (c[m:] - mm(L, c[:m])) + (rm.G2 - mm(L, rm.G1))  # eq. (26)
            # eq. (24) without inverting: [B̄1; B̄2 − L B̄1] = P Sᵀ Ĵ⁻ᵀ with P = [[I, 0], [−L, I]],
            # so τ = Ĵᵀ S⁻ᵀ P⁻¹ [Λp; Λf], P⁻¹ y = (y1, y2 + L y1), S⁻ᵀ z = (z1 − Γᵀ z2, z2)
            y2 = lam_f + mm(L, lam_p)
            Gamma = rm.S[m:, :m]
            tau = mm(rm.J.T, jnp.concatenate([lam_p - mm(Gamma.T, y2), y2]))
        dz = -g.mu_z * state.z - g.alpha_z * e_lam  # eq. (27)
        signals = {"F": F, "u1": u1, "u1_dot": u1_dot, "lam": lam, "u1_d": r.u1_d, "u1_d_dot": r.u1_d_dot,
                   "lam_d": r.lam_d, "e_u1_dot": e_u1_dot, "z": state.z, **signals}
        if _closed_form_sigma(rm.J):  # the guard's measure in closed form, recorded at every sample
            sigma = sigma_min(rm.J)
            signals["sigma_min_J"] = sigma
            fault, fault_value, deferred = sigma < self.sigma_stop, sigma, None
        else:  # no singular values in the loop: the guard by a Cholesky test (singular), σ_min(Ĵ)
            # recorded per stored sample (deferred_fields) and at a stop (fault_measure)
            fault, fault_value, deferred = singular(rm.J, self.sigma_stop, kern), jnp.nan, {"J": rm.J}
        aux = LawAux(ref=r, values=tuple(values), J=rm.J, J_dot=rm.J_dot, ctx=ctx, Jd_qd=rm.Jd_qd)
        return ControllerOutput(tau=tau, dstate=ControllerState(z=dz, parts=dparts), e_u1=e_u1, e_lam=e_lam,
                                signals=signals, fault=fault, fault_value=fault_value, deferred=deferred, aux=aux)

    def deferred_fields(self, deferred) -> dict:
        """σ_min(Ĵ) of a stored sample (arms whose Ĵ is larger than 2 × 2), from the Ĵ the loop kept."""
        if deferred is None:
            return {}
        J = deferred["J"]
        return {"sigma_min_J": jnp.linalg.svd(J, compute_uv=False)[..., -1]}

    def fault_measure(self, t, state, meas, ref, value):
        """σ_min(Ĵ) where the run stopped, when the loop decided the guard without it (``value``
        NaN, arms whose Ĵ is larger than 2 × 2)."""
        out = self.evaluate(jnp.where(jnp.isnan(t), 0.0, t), state, meas, ref)
        if out.deferred is None:
            return value
        return jnp.where(jnp.isnan(value), self.deferred_fields(out.deferred)["sigma_min_J"], value)

    @property
    def needs_start(self) -> bool:
        """Whether some term sets its state from the first measurement (:meth:`start`)."""
        return self.force_filter is not None or any(type(term).start is not T.Term.start for term in self.terms)

    def start(self, t, state: ControllerState, meas, ref) -> ControllerState:
        """The state at the first sample, from the first measurement (a term's filter starts at
        its input, e.g. the force-rate filter at e_λ(0))."""
        if not self.needs_start:
            return state
        if self.force_filter is not None:  # the force filter at rest at the first measured e_λ
            parts = dict(state.parts)
            parts["lam_filter"] = self.force_filter.rest(self.observe(meas)[2] - ref(t).lam_d)
            state = ControllerState(z=state.z, parts=parts)
        out = self.evaluate(t, state, meas, ref)
        parts = dict(state.parts)
        for term in self.terms:
            parts.update(term.start(out.aux.ctx, state.parts))
        return ControllerState(z=state.z, parts=parts)

    # --- conveniences ---------------------------------------------------------------------------
    def torque(self, t, state, meas, ref):
        """τ of eq. (24)."""
        return self.evaluate(t, state, meas, ref).tau

    def derivative(self, t, state, meas, ref) -> ControllerState:
        """The state's time derivative: ż of eq. (27), the networks' updates (30)–(31)."""
        return self.evaluate(t, state, meas, ref).dstate

    def signals(self, t, state, meas, ref) -> dict:
        """Every named signal of :meth:`evaluate`, the errors and τ included."""
        out = self.evaluate(t, state, meas, ref)
        return {**out.signals, "e_u1": out.e_u1, "e_lam": out.e_lam, "tau": out.tau}

    # --- the theorems' bookkeeping ---------------------------------------------------------------
    def performance(self, state, out: ControllerOutput):
        """Integrand of the H∞ index, eq. (34) with Remark 3's weight α_λα_z/2 on e_λ, the same
        for every controller; and the extra terms of Remark 1's augmented index (0 otherwise).
        Implements eq. (34)."""
        g = self.gains
        c = out.aux.ctx
        k = self.kernels
        mm = k.mm
        j = (mm(c.x_p, _times(g.Q_p, self._blocks(g.Q_p, self.Q_blocks), c.x_p, self.m, k))
             + 0.5 * g.alpha_lam * g.alpha_z * mm(c.e_lam, c.e_lam)
             + g.alpha_lam * g.mu_z / (1.0 + g.beta_lam) * mm(state.z, state.z))
        extra = jnp.zeros_like(j)
        for term, value in zip(self.terms, out.aux.values):
            e = term.extra_performance(c, value) if self.augmented else None
            if e is not None:
                extra = extra + e
            d = term.extra_dissipation(c, state.parts)
            if d is not None:
                extra = extra + d
        return j, extra

    def storage(self, state, out: ControllerOutput):
        """Storage function V of eqs. (36)/(55) with Θ* = 0 (so Θ̃ = Θ̂ and ε = f), plus the
        terms' contributions: V = x_pᵀ P_p x_p + α_λ/(2(1+β_λ)) ‖z‖² + Σ V_term."""
        c = out.aux.ctx
        k = self.kernels
        V = (k.mm(c.x_p, _times(self.P_p, self._blocks(self.P_p, self.P_blocks), c.x_p, self.m, k))
             + 0.5 * c.c * k.mm(state.z, state.z))
        for term in self.terms:
            v = term.storage(c, state.parts)
            if v is not None:
                V = V + v
        return V

    def supply_residuals(self, out: ControllerOutput, u1_ddot):
        """f_p, f_f as the actual residuals of the error systems (28)–(29) / (52)–(53):
        f_p = ë_u1 + K_p e_u1 + K_v ė_u1 − Σ a_i,  f_f = e_λ − z − Σ b_j, with ë_u1 from the true
        motion (:meth:`u1_ddot`)."""
        g = self.gains
        c = out.aux.ctx
        f_p = (u1_ddot - out.aux.ref.u1_d_ddot) + self.kernels.mm(g.K_p, c.e_u1) + self.kernels.mm(g.K_v, c.e_u1_dot)
        f_f = c.e_lam - c.z
        for term, v in zip(self.terms, out.aux.values):
            if term.side == "position":
                f_p = f_p - v
            else:
                f_f = f_f - v
        return f_p, f_f

    def dissipation(self, state, out: ControllerOutput, qd, qdd) -> Dissipation:
        """The theorems' bookkeeping at one instant, given the true joint acceleration q̈ (from
        the plant, like an accelerometer): the integrand ``j`` of eq. (34) and Remark 1's
        ``j_extra``, the supply rate ρ²(‖f_p‖² + ‖f_f‖²), the storage ``V`` and the residuals
        ``f_p``, ``f_f``. Along any run, J(t) + V(t) − V(0) ≤ ∫ supply must hold (Theorems 1–2).
        A network learning with a dead zone (:class:`~hinfnn.controllers.network.Adaptation`) adds
        its bounded uncancelled rate to the supply, and leakage its dissipation to ``j_extra``
        (docs/beyond-the-paper.md, section 11)."""
        j, extra = self.performance(state, out)
        f_p, f_f = self.supply_residuals(out, self.u1_ddot(out, qd, qdd))
        supply = self.gains.rho**2 * (self.kernels.mm(f_p, f_p) + self.kernels.mm(f_f, f_f))
        for term in self.terms:  # a term's bounded rate the proof does not cancel (a network's dead zone)
            s = term.extra_supply(out.aux.ctx, state.parts)
            if s is not None:
                supply = supply + s
        return Dissipation(j=j, j_extra=extra, supply=supply, V=self.storage(state, out), f_p=f_p, f_f=f_f)

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

    def u1_ddot(self, out: ControllerOutput, qd, qdd):
        """d²/dt² of the measured u1 = ĥ1(q) along a motion with joint acceleration q̈:
        (Ĵ q̈ + J̇̂ q̇)_1 (the chain rule on the controller's own observation map)."""
        a = out.aux
        Jd_qd = self.kernels.mm(a.J_dot, qd) if a.J_dot is not None else a.Jd_qd
        return (self.kernels.mm(a.J, qdd) + Jd_qd)[: self.m]


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


def _closed_form_sigma(J) -> bool:
    """Whether :func:`sigma_min` has a closed form for this Ĵ (1 × 1 and 2 × 2)."""
    return J.shape in ((1, 1), (2, 2))


def singular(J, stop, kernels: la.Kernels = la.DEFAULT):
    """The singularity guard σ_min(Ĵ) < ``stop`` without the singular values (Ĵ square, larger than
    2 × 2): Ĵ Ĵᵀ − stop² I is not positive definite (a written-out Cholesky,
    :meth:`hinfnn._linalg.Kernels.positive_definite`: the same test up to the rounding of the pivots, and
    no LAPACK call in the loop); never when ``stop`` is 0 (the guard off)."""
    A = kernels.mm(J, J.T) - (stop * stop) * jnp.eye(J.shape[0], dtype=J.dtype)
    return (stop > 0.0) & ~kernels.positive_definite(A)


@jax.jit
def nominal_sigma_min(arm, q):
    """σ_min(Ĵ(q)) as one compiled program (the scenario check of the path against the
    singularity guard evaluates it along the reference)."""
    return sigma_min(arm.J(q))


@setup_program("nominal_jacobian_det")
def _nominal_jacobian_det(arm, q):
    """det Ĵ(q) as one compiled program (a new process lowers each eager operation separately)."""
    return jnp.linalg.det(arm.J(q))
