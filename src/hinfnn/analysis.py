"""The closed loop linearised: eigenvalues of the simulator's own right-hand side, and the force
loop's polynomial (docs/beyond-the-paper.md).

The operating point is a true equilibrium of the closed loop: the EXACT-model plant (the true arm
and surface are the controller's nominal ones, no disturbance) at rest on the surface with a
constant reference (u1d, λd) and the penetration that makes λ = λd; every filter at its rest
value and the networks' weights zero. The Jacobian of the simulator's right-hand side (JAX
``jacfwd`` of :func:`hinfnn.sim.rhs`) there has the local exponents as eigenvalues. On
the exact model the law cancels the reduced dynamics, so the force loop (u2, u̇2, z, the force-rate
filter s) decouples from the position loop (u1, u̇1) and its eigenvalues are the roots of

    [m_s s²(τ_f s + 1) + k_u K'(τ_f s + 1) + k_u κ s](s + μ_z) + α_z k_u (τ_f s + 1)

(κ = 0, τ_f = 0: the cubic m_s s³ + m_s μ_z s² + k_u K' s + k_u(K' μ_z + α_z)), with
m_s = Π²/(ÂĴM̂⁻¹ĴᵀÂᵀ), k_u = kΠ²/(ÂÂᵀ), K' = 1 + β_λ/2 (1 for FL-like). For the adaptive law at
Θ̂ = 0 the network adds an integral action of gain g_f = γ2‖ξ_f(0)‖² on e_λ (the polynomial is
then multiplied by s and gains g_f k_u(τ_f s + 1)(s + μ_z)).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .controllers import terms as T
from .plant import PenaltyContact, RigidBodyPlant, SquareWave
from .reference import CosineReference
from .sim.recorder import Accumulators
from .errors import HinfnnError
from .sim.simulate import SimState, rhs


def constant_reference(u1d: float, lam_d: float) -> CosineReference:
    """u1d and λd held constant."""
    a = lambda v: jnp.array([float(v)])  # noqa: E731
    return CosineReference(u1_offset=a(u1d), u1_amplitude=a(0.0), u1_omega=a(math.pi), u1_phase=a(0.0),
                           lam_offset=a(lam_d), lam_amplitude=a(0.0), lam_omega=a(math.pi), lam_phase=a(0.0))


def exact_plant(arm, surface, stiffness: float, damping: float = 0.0) -> RigidBodyPlant:
    """The controller's nominal arm and surface as the true plant, with a penalty contact and no
    disturbance."""
    return RigidBodyPlant(arm=arm, surface=surface, contact=PenaltyContact(stiffness=float(stiffness),
                                                                           damping=float(damping)),
                          disturbance=SquareWave.none(arm.n))


def loop_constants(arm, surface, stiffness: float, q) -> dict:
    """m_s, k_u (and m_n, ÂÂᵀ, Π) of the force loop at pose q (k = 1)."""
    t = arm.terms(jnp.asarray(q, dtype=float), jnp.zeros(arm.n))
    A = np.asarray(surface.A_hat(t.x))
    J, M = np.asarray(t.J), np.asarray(t.M)
    D = float((A @ J @ np.linalg.solve(M, J.T @ A.T))[0, 0])
    a2 = float((A @ A.T)[0, 0])
    pi = float(A[0, surface.m])
    return dict(m_s=pi * pi / D, k_u=stiffness * pi * pi / a2, m_n=a2 / D, a2=a2, Pi=pi)


def equilibrium_q(plant: RigidBodyPlant, u1d: float, lam_d: float, elbow_up: bool = True):
    """Joint angles with x1 = u1d and the penetration that makes λ = λd on the plant's surface
    (λ = kθ/ÂÂᵀ for a penalty spring on a line)."""
    surf, arm = plant.surface, plant.arm
    x1 = jnp.array([float(u1d)])
    x_on = jnp.concatenate([x1, surf.Omega(x1)])
    A = np.asarray(surf.A_hat(x_on))
    theta = lam_d * float((A @ A.T)[0, 0]) / float(plant.contact.stiffness)
    u2 = theta / float(A[0, surf.m])
    x = x_on.at[surf.m:].add(u2)
    if hasattr(arm, "inverse_kinematics_closed"):
        return arm.inverse_kinematics_closed(x, elbow_up=elbow_up)
    return arm.inverse_kinematics(x, jnp.full(arm.n, 0.3) * (1.0 if elbow_up else -1.0))


def closed_loop_jacobian(plant, ctrl, ref, q_eq):
    """(A, y*, residual): the Jacobian of the closed loop's right-hand side over (q, q̇, controller
    state) at the state y* = (q_eq, 0, rest state), and max|f(y*)| (≈ 0 at an equilibrium)."""
    xc0 = ctrl.init()
    meas, _ = plant.sense(0.0, plant.initial_state(q_eq))
    xc0 = ctrl.start(0.0, xc0, meas, ref)  # filters at their rest value
    leaves, treedef = jax.tree.flatten(xc0)
    sizes = [int(np.size(leaf)) for leaf in leaves]
    n = plant.n

    def unflat(y):
        parts, i = [], 2 * n
        for leaf, size in zip(leaves, sizes):
            parts.append(y[i:i + size].reshape(np.shape(leaf)))
            i += size
        return SimState(plant=plant.initial_state(y[:n], y[n:2 * n]), xc=jax.tree.unflatten(treedef, parts),
                        acc=Accumulators.zero())

    def f(y):
        dy, _ = rhs(plant, ctrl, ref, 0.0, unflat(y), jnp.zeros(n))
        q_dot, qd_dot = plant.joints(dy.plant)
        return jnp.concatenate([q_dot, qd_dot] + [jnp.ravel(leaf) for leaf in jax.tree.leaves(dy.xc)])

    y0 = jnp.concatenate([jnp.asarray(q_eq, dtype=float), jnp.zeros(n)] + [jnp.ravel(leaf) for leaf in leaves])
    A = np.asarray(jax.jit(jax.jacfwd(f))(y0))
    return A, np.asarray(y0), float(np.max(np.abs(np.asarray(jax.jit(f)(y0)))))


def force_loop_polynomial(m_s, k_u, K_prime, mu_z, alpha_z, kappa=0.0, tau_f=0.0, g_f=0.0) -> np.ndarray:
    """Coefficients (highest power first) of the force loop's characteristic polynomial (module
    docstring); with ``g_f`` > 0 the adaptive law's linearised network (the polynomial then has
    one degree more)."""
    P, add = np.polymul, np.polyadd
    if g_f == 0.0:
        inner = add(add(P([m_s, 0, 0], [tau_f, 1]), P([k_u * K_prime], [tau_f, 1])), [k_u * kappa, 0])
        return add(P(inner, [1, mu_z]), P([alpha_z * k_u], [tau_f, 1]))
    inner = add(add(P([m_s, 0, 0, 0], [tau_f, 1]), P([k_u * K_prime, 0], [tau_f, 1])), [k_u * kappa, 0, 0])
    inner = add(inner, P([k_u * g_f], [tau_f, 1]))
    return add(P(inner, [1, mu_z]), P([alpha_z * k_u, 0], [tau_f, 1]))


def k_prime(ctrl) -> float:
    """K' = 1 + β_λ/2 for a law with v_λ of eq. (32), 1 without (FL-like)."""
    return 1.0 + 0.5 * float(ctrl.gains.beta_lam) if ctrl.term(T.RobustForce) is not None else 1.0


def network_gain(ctrl, e_lam: float = 0.0, z: float = 0.0) -> float:
    """g_f = γ2‖ξ_f‖² at the inputs (e_λ, z): the adaptive law's integral gain on e_λ at Θ̂_f = 0."""
    net = ctrl.network_f
    if net is None:
        return 0.0
    xi = np.asarray(net.features(jnp.array([e_lam]), jnp.array([z])))
    return float(ctrl.gains.gamma_2) * float(xi @ xi)


@dataclasses.dataclass(frozen=True)
class Mode:
    """An eigenvalue as an oscillation: |s| (rad/s) and damping ratio ζ = −Re s/|s|."""

    s: complex

    @property
    def omega(self) -> float:
        return abs(self.s)

    @property
    def zeta(self) -> float:
        return -self.s.real / abs(self.s) if abs(self.s) > 0 else math.nan

    def __str__(self) -> str:
        if abs(self.s.imag) < 1e-9 * max(1.0, abs(self.s)):
            return f"real {self.s.real:.4g}"
        return f"{self.omega:.4g} rad/s, ζ {self.zeta:+.3g}"


def contact_modes(scenario, kind: str, stiffness: float, u1d: float | None = None, lam_d: float | None = None) -> dict:
    """The linearised force loop of the scenario's controller ``kind`` (its design, its gains) on
    the exact model with contact stiffness ``stiffness`` (undamped), at rest at (u1d, λd)
    (default: the reference's mean values). Returns the eigenvalues of the closed loop, those of
    the force loop (all but the position loop's two), the least damped force mode, the
    polynomial's roots (FL-like and H∞-only, and the adaptive law at Θ̂ = 0) and the largest
    relative difference between the two."""
    ref_cfg = scenario.reference
    u1d = ref_cfg.u1_offset if u1d is None else u1d
    lam_d = ref_cfg.lam_offset if lam_d is None else lam_d
    arm, surface = scenario.nominal.arm.build(), scenario.nominal.surface.build()
    ctrl = scenario.build_controller(kind)
    plant = exact_plant(arm, surface, stiffness)
    q_eq = equilibrium_q(plant, u1d, lam_d, elbow_up=scenario.initial.elbow == "up")
    A, _, residual = closed_loop_jacobian(plant, ctrl, constant_reference(u1d, lam_d), q_eq)
    eigs = np.linalg.eigvals(A)
    c = loop_constants(arm, surface, stiffness, q_eq)
    g = ctrl.gains
    fr = ctrl.term(T.ForceRate)
    kappa, tau = (float(fr.kappa), float(fr.tau_f)) if fr is not None else (0.0, 0.0)
    g_f = network_gain(ctrl)
    poly = force_loop_polynomial(c["m_s"], c["k_u"], k_prime(ctrl), float(g.mu_z), float(g.alpha_z), kappa, tau, g_f)
    roots = np.roots(poly)
    # the position loop: s² + (K_v + g_v)s + (K_p + g_p), g = R_p⁻¹B_pᵀP_p x_p when v_p is present
    gp = np.zeros(2)
    if ctrl.term(T.RobustPosition) is not None:
        gp = np.linalg.solve(np.atleast_2d(np.asarray(g.R_p)), np.asarray(ctrl.P_p)[1:]).ravel()
    pos = np.roots([1.0, float(np.asarray(g.K_v).reshape(-1)[0]) + gp[1], float(np.asarray(g.K_p).reshape(-1)[0]) + gp[0]])
    pool = list(eigs)
    for r in pos:
        pool.pop(int(np.argmin([abs(e - r) for e in pool])))
    force = sorted(pool, key=lambda e: -e.real)
    diffs = []
    rest = list(force)
    for r in roots:
        j = int(np.argmin([abs(e - r) for e in rest]))
        diffs.append(abs(rest.pop(j) - r) / abs(r))
    # the network's weights are states of the full loop (n_units of them, with eigenvalues near 0):
    # compare with the polynomial only where every force-loop eigenvalue is accounted for
    matched = max(diffs) if len(force) == len(roots) else None
    oscillatory = [e for e in force if abs(e.imag) > 1e-9 * max(1.0, abs(e))]
    least = max(oscillatory, key=lambda e: e.real / abs(e)) if oscillatory else max(force, key=lambda e: e.real)
    return dict(kind=kind, stiffness=stiffness, u1d=u1d, lam_d=lam_d, q=np.asarray(q_eq).tolist(),
                residual=residual, eigenvalues=eigs, force_eigenvalues=np.array(force), roots=roots,
                polynomial_match=matched, least_damped=Mode(complex(least)), constants=c, kappa=kappa, tau_f=tau,
                g_f=g_f, stable=bool(all(e.real < 0 for e in eigs if abs(e) > 1e-8 * np.max(np.abs(eigs)))))


def design_report(scenario) -> dict:
    """What ``hinfnn design`` prints, by controller kind: the designed controller
    (:func:`~hinfnn.controllers.design_summary`) and the least damped linearised contact mode at the
    scenario's contact stiffness, as designed and with the force-rate term toggled (κ by the rule
    when it is off, 0 when it is on; a design the toggled variant refuses is reported as its
    error)."""
    k = scenario.plant.contact.stiffness
    out = {}
    for kind in scenario.kinds:
        one = scenario.single(kind)
        d = one.build_controller(kind).summary()
        with_term = one.controller.force_rate.kappa != 0.0
        toggled = ("without the force-rate term" if with_term else "with the force-rate term (kappa by the rule)",
                   {"controller.force_rate.kappa": 0.0 if with_term else "rule"})
        modes = {}
        for label, overrides in (("as designed", None), toggled):
            try:
                variant = one if overrides is None else one.with_overrides(overrides)
                r = contact_modes(variant, kind, k)
                modes[label] = dict(mode=str(r["least_damped"]), omega=r["least_damped"].omega,
                                    zeta=r["least_damped"].zeta, stable=r["stable"], kappa=r["kappa"])
            except HinfnnError as err:  # a design the other variant refuses is information
                modes[label] = dict(error=str(err))
        d["contact_mode"] = dict(stiffness=k, **modes)
        out[kind] = d
    return out
