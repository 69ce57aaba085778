"""The closed loop linearised: eigenvalues of the simulator's own right-hand side, and the force
loop's polynomial (docs/beyond-the-paper.md), for any arm and surface with one constraint.

The operating point is a true equilibrium of the closed loop: the EXACT-model plant (the true arm
and surface are the controller's nominal ones, no disturbance, no friction) at rest on the
surface with a constant reference (u1d, λd) and the penetration that makes λ = λd; every filter
at its rest value and the networks' weights zero. The Jacobian of the simulator's right-hand side
(JAX ``jacfwd`` of it, through :func:`_simulator_rhs`) there has the local exponents as
eigenvalues.

On the exact model the law cancels the reduced dynamics: row 2 of eq. (9) minus M̄21M̄11⁻¹ × row 1
becomes m_s ü2 + Πᵀλ = Πᵀ(λd + z + Σ b_j) for every pose, so the force loop (u2, u̇2, z, the
force-rate filter s, F_f's weights) does not depend on the position loop (u1, u̇1, F_p's
weights), while the position loop is driven by ü2 (through M̄11⁻¹M̄12). In the coordinates
(u, u̇, controller state) the Jacobian is block triangular (:func:`split_loops` checks it), and
the force block's eigenvalues are the roots of

    [m_s s²(τ_f s + 1) + k_u K'(τ_f s + 1) + k_u κ s](s + μ_z) + α_z k_u (τ_f s + 1)

(κ = 0, τ_f = 0: the cubic m_s s³ + m_s μ_z s² + k_u K' s + k_u(K' μ_z + α_z)), with
m_s = Π²/(ÂĴM̂⁻¹ĴᵀÂᵀ), k_u = kΠ²/(ÂÂᵀ), K' = 1 + β_λ/2 (1 for FL-like). For the adaptive law at
Θ̂ = 0 the network adds an integral action of gain g_f = γ2‖ξ_f(0)‖² on e_λ (the polynomial is
then multiplied by s and gains g_f k_u(τ_f s + 1)(s + μ_z)). The networks' weight directions
that neither move nor act at Θ̂ = 0 (all but ξ_f(0) for F_f, all but ξ_p(0) ⊗ ℝᵐ for F_p)
are an exact invariant subspace with eigenvalue 0 (1 for the sampled map); they are split off
(:func:`_drop_neutral`) and counted.

Sampled control (zero-order hold at period h, the simulator's sampled mode): the map over one
period (the controller's sample update, then the plant integrated by RK4 steps with the torque
held) linearised at the same point; the loop is stable when its spectral radius is below 1
(:func:`sampled_modes`, :func:`sampled_kappa_scan`).

:func:`design_report` gathers a scenario's whole design (gains, Riccati, force-rate design,
singularity and start-pose checks along the path, contact modes before and after the force-rate
term) for ``hinfnn design``; :func:`format_design_report` prints it.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ._programs import jit_by_joints
from .controllers import terms as T
from .plant import PenaltyContact, RigidBodyPlant, SquareWave
from .reference import CosineReference


# --- the simulator's right-hand side: the one place this module uses the simulator's internals ----


def _simulator_rhs(plant, ctrl, ref, t, plant_state, xc, held=None, sampled=False):
    """(d plant_state/dt, d xc/dt) of the simulator's own right-hand side (:func:`hinfnn.sim.rhs`)
    at (plant_state, xc) with no disturbance, the accumulators of the bookkeeping left out.
    ``held``, ``sampled``: the torque held by the sampled mode (the controller state then does
    not move between samples). With its plant part (:func:`hinfnn.sim.simulate.plant_rhs`, in
    :func:`_held_plant_jacobian`), the only use of the simulator in this module."""
    from .sim.recorder import Accumulators
    from .sim.simulate import SimState, rhs

    n = plant.n
    held = jnp.zeros(n) if held is None else held
    y = SimState(plant=plant_state, xc=xc, acc=Accumulators.zero())
    # book=False: the accumulators' rates are not returned, so their integrands are not traced (nor
    # differentiated) only for XLA to drop them (the loop Jacobian traces faster)
    dy, _ = rhs(plant, ctrl, ref, t, y, jnp.zeros(n), held, sampled, book=False)
    return dy.plant, dy.xc


# --- operating point ------------------------------------------------------------------------------


def constant_reference(u1d, lam_d) -> CosineReference:
    """u1d and λd held constant (numbers or per-coordinate sequences)."""
    a = lambda v: jnp.atleast_1d(jnp.asarray(v, dtype=float))  # noqa: E731
    u, lam = a(u1d), a(lam_d)
    return CosineReference(u1_offset=u, u1_amplitude=jnp.zeros_like(u), u1_omega=jnp.full_like(u, math.pi),
                           u1_phase=jnp.zeros_like(u), lam_offset=lam, lam_amplitude=jnp.zeros_like(lam),
                           lam_omega=jnp.full_like(lam, math.pi), lam_phase=jnp.zeros_like(lam))


def exact_plant(arm, surface, stiffness: float, damping: float = 0.0) -> RigidBodyPlant:
    """The controller's nominal arm and surface as the true plant (for a Cartesian surface: the
    nominal geometry, contact at the tool point), with a penalty contact, no disturbance and no
    friction."""
    return RigidBodyPlant(arm=arm, surface=surface, contact=PenaltyContact(stiffness=float(stiffness),
                                                                           damping=float(damping)),
                          disturbance=SquareWave.none(arm.n))


@jit_by_joints
def _A_J_M(arm, surface, q):
    return surface.A_hat(arm.h(q)), arm.J(q), arm.M(q)  # a URDF arm's by 3 × 3 products (UrdfChain.fk)


def loop_constants(arm, surface, stiffness: float, q) -> dict:
    """m_s, k_u (and m_n, ÂÂᵀ, Π) of the force loop at pose q (k = 1), on the controller's
    constraint ``surface`` in the arm's task coordinates."""
    A, J, M = (np.asarray(a) for a in _A_J_M(arm, surface, jnp.asarray(q, dtype=float)))
    D = float((A @ J @ np.linalg.solve(M, J.T @ A.T))[0, 0])
    a2 = float((A @ A.T)[0, 0])
    pi = float(A[0, surface.m])
    return dict(m_s=pi * pi / D, k_u=stiffness * pi * pi / a2, m_n=a2 / D, a2=a2, Pi=pi)


def equilibrium_q(plant, u1d, lam_d, elbow_up: bool = True, ctrl=None, q_guess=None):
    """Joint angles at rest with the motion coordinates at u1d and the contact force making
    λ = λd.

    The Sec. VI arm on its line (no ``ctrl``): closed form (λ = kθ/ÂÂᵀ for a penalty spring on a
    line). Any arm with the controller ``ctrl`` (its task coordinates and constraint): Newton
    steps on (ĥ1(q) − u1d, λ(q) − λd), λ the controller's reading of the plant's force sensor,
    from the pose with the linear estimate of the penetration (found from ``q_guess``)."""
    if ctrl is None:
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
    q_guess = jnp.zeros(plant.n) if q_guess is None else jnp.asarray(q_guess, dtype=float)
    u1d = jnp.atleast_1d(jnp.asarray(u1d, dtype=float))
    lam_d = jnp.atleast_1d(jnp.asarray(lam_d, dtype=float))
    q, res = _equilibrium_guess(plant, ctrl, u1d, lam_d, q_guess)
    if not float(res) < 1e-10:  # the linear estimate of the penetration is not exact here: Newton on λ too
        q, res = _equilibrium_newton(plant, ctrl, u1d, lam_d, q)
    return np.asarray(q) if float(res) < 1e-10 else np.full(plant.n, np.nan)


def _lm(residual, q, iterations):
    """Damped Newton (Levenberg–Marquardt) steps on residual(q) = 0, at most 0.5 rad a step."""
    n = q.shape[0]

    def body(_, q):
        r = residual(q)
        Jr = jax.jacfwd(residual)(q)
        step = jnp.linalg.solve(Jr.T @ Jr + 1e-12 * jnp.eye(n), Jr.T @ r)
        return q - jnp.minimum(1.0, 0.5 / jnp.maximum(jnp.max(jnp.abs(step)), 1e-300)) * step

    return jax.lax.fori_loop(0, iterations, body, q)


def _balance(plant, ctrl, u1d, lam_d, q):
    """(ĥ1(q) − u1d, (λ(q) − λd)/max(|λd|, 1)) at rest: u1 and λ the controller's reading of the
    plant's sensors (:meth:`~hinfnn.controllers.law.ReducedOrderController.observe`)."""
    u1, _, lam = ctrl.observe(plant.measure(q, jnp.zeros_like(q)))
    return jnp.concatenate([u1 - u1d, (lam - lam_d) / jnp.maximum(jnp.abs(lam_d), 1.0)])


@jit_by_joints
def _equilibrium_guess(plant, ctrl, u1d, lam_d, q):
    """The pose at x = (u1d, Ω(u1d) + u2), u2 from the linear estimate θ = λd ÂÂᵀ/k (exact for a
    penalty spring on a plane or line and for fitted coordinates), by Newton steps on ĥ(q) = x
    alone; and the largest residual of :func:`_balance` there."""
    arm, surf, m = ctrl.arm, ctrl.surface, ctrl.m
    x_on = jnp.concatenate([u1d, surf.Omega(u1d)])
    A = surf.A_hat(x_on)
    theta = lam_d * jnp.diag(A @ A.T) / plant.contact.stiffness
    x = x_on.at[m:].add(theta / jnp.diag(A[:, m:]))
    q = _lm(lambda q: arm.h(q) - x, q, 60)
    return q, jnp.max(jnp.abs(_balance(plant, ctrl, u1d, lam_d, q)))


@jit_by_joints
def _equilibrium_newton(plant, ctrl, u1d, lam_d, q):
    """Newton steps on :func:`_balance` from q (a pose in contact)."""
    q = _lm(lambda q: _balance(plant, ctrl, u1d, lam_d, q), q, 30)
    return q, jnp.max(jnp.abs(_balance(plant, ctrl, u1d, lam_d, q)))


# --- the state's layout -----------------------------------------------------------------------------


def state_names(ctrl) -> list[str]:
    """For each entry of the flattened closed-loop state (q, q̇, then the controller's state in
    the loop's layout): "q", "qd", or the controller state's name ("z", "s_lam", "theta_p" ...)."""
    xc = ctrl.init()
    n = ctrl.n
    names = ["q"] * n + ["qd"] * n
    for path, leaf in jax.tree_util.tree_flatten_with_path(xc)[0]:
        keys = [p.key for p in path if isinstance(p, jax.tree_util.DictKey)]
        attrs = [p.name for p in path if isinstance(p, jax.tree_util.GetAttrKey)]
        names += [str(keys[0]) if keys else attrs[0]] * int(np.size(leaf))
    return names


def _unflatten(plant, ctrl, y):
    """(plant state, controller state in the loop's layout) from the flat vector."""
    n = plant.n
    xc = ctrl.init()
    leaves, treedef = jax.tree.flatten(xc)
    parts, i = [], 2 * n
    for leaf in leaves:
        size = int(np.size(leaf))
        parts.append(y[i:i + size].reshape(np.shape(leaf)))
        i += size
    return plant.initial_state(y[:n], y[n:2 * n]), jax.tree.unflatten(treedef, parts)


def _flatten(plant, plant_state, xc):
    q, qd = plant.joints(plant_state)
    return jnp.concatenate([q, qd] + [jnp.ravel(leaf) for leaf in jax.tree.leaves(xc)])


def rest_state(ctrl, q_eq) -> np.ndarray:
    """The flat closed-loop state at rest at q_eq: q̇ = 0, z = 0, every term's state 0 (the
    force-rate filter at e_λ = 0, the networks' weights 0)."""
    xc = ctrl.init()
    return np.concatenate([np.asarray(q_eq, dtype=float), np.zeros(ctrl.n)]
                          + [np.ravel(np.asarray(leaf)) for leaf in jax.tree.leaves(xc)])


@jit_by_joints
def _loop_jacobian(plant, ctrl, ref, y0):
    """(A, f(y0)): A column by column, one forward-mode product A e_i per step of a ``lax.map``
    (the program holds one right-hand side's JVP, where ``jax.jacfwd`` holds it batched over
    every column: the same matrix to 2e-16, compiled in less time)."""
    def f(y):
        ps, xc = _unflatten(plant, ctrl, y)
        dps, dxc = _simulator_rhs(plant, ctrl, ref, 0.0, ps, xc)
        return _flatten(plant, dps, dxc)

    # each JVP's primal is f(y0): taken from the first column's rather than traced a second time
    values, columns = jax.lax.map(lambda e: jax.jvp(f, (y0,), (e,)), jnp.eye(y0.shape[0], dtype=y0.dtype))
    return columns.T, values[0]


def closed_loop_jacobian(plant, ctrl, ref, q_eq):
    """(A, y*, residual): the Jacobian of the closed loop's right-hand side over (q, q̇,
    controller state) at the state y* = (q_eq, 0, rest state), and max|f(y*)| (≈ 0 at an
    equilibrium). One compiled program per plant, controller and reference structure."""
    y0 = jnp.asarray(rest_state(ctrl, q_eq))
    A, f0 = _loop_jacobian(plant, ctrl, ref, y0)
    return np.asarray(A), np.asarray(y0), float(np.max(np.abs(np.asarray(f0))))


@jit_by_joints(static_argnames="n_sub")
def sampled_map_direct(plant, ctrl, ref, y0, period, n_sub):
    """(Jacobian at y0, value at y0) of the closed loop over one control period under zero-order
    hold, differentiated whole (as the simulator's sampled mode: the controller's sample update at
    the start, then ``n_sub`` RK4 steps of the plant with the torque held and the controller state
    still): the oracle of :func:`sampled_map_jacobian` (one large program per structure)."""

    def phi(y):
        ps, xc = _unflatten(plant, ctrl, y)
        meas, _ = plant.sense(0.0, ps)
        tau, xc = ctrl.sample(0.0, period, xc, meas, ref)
        dt = period / n_sub

        def f(p):
            return _simulator_rhs(plant, ctrl, ref, 0.0, p, xc, tau, True)[0]

        a = jnp.array([0.0, 0.5, 0.5, 1.0])
        b = jnp.array([1.0, 2.0, 2.0, 1.0]) / 6.0

        def step(p, _):  # classical RK4, its four stages as a loop (one right-hand side in the program)
            def stage(i, carry):
                k, acc = carry
                k = f(jax.tree.map(lambda x, d: x + a[i] * dt * d, p, k))
                return k, jax.tree.map(lambda s_, d: s_ + b[i] * dt * d, acc, k)

            zero = jax.tree.map(jnp.zeros_like, p)
            _, acc = jax.lax.fori_loop(0, 4, stage, (zero, zero))
            return jax.tree.map(lambda x, d: x + d, p, acc), None

        ps, _ = jax.lax.scan(step, ps, None, length=n_sub)
        return _flatten(plant, ps, xc)

    return jax.jacfwd(phi)(y0), phi(y0)


# --- splitting the spectrum ------------------------------------------------------------------------


def _drop_neutral(A, candidates, shift: float = 0.0, tol: float = 1e-9):
    """(W, count): an orthonormal basis W of the complement of the directions among the
    ``candidates`` coordinates (the networks' weights) that neither act on the loop nor are driven
    by it: (A − shift·I)Z = 0 and Zᵀ(A − shift·I) = 0 (eigenvalue ``shift``, exactly invariant).
    The loop's other eigenvalues are those of WᵀAW."""
    N = A.shape[0]
    idx = np.flatnonzero(candidates)
    if idx.size == 0:
        return np.eye(N), 0
    B = A - shift * np.eye(N)
    scale = max(np.max(np.abs(B)), 1e-300)
    # directions v of the candidates' space with B v = 0 and vᵀ B = 0
    stacked = np.concatenate([B[:, idx], B[idx, :].T], axis=0)
    _, sv, Vt = np.linalg.svd(stacked, full_matrices=True)
    rank = int(np.sum(sv > tol * scale))
    Zc = Vt[rank:].T  # (len(idx), count)
    Z = np.zeros((N, Zc.shape[1]))
    Z[idx] = Zc
    if Z.shape[1] == 0:
        return np.eye(N), 0
    Q, _ = np.linalg.qr(np.concatenate([Z, np.eye(N)], axis=1))
    W = Q[:, Z.shape[1]:N]
    return W, Z.shape[1]


@jit_by_joints
def _u_jacobian(arm, surface, q):
    """∂u/∂q, u = (u1, u2) of eq. (6) at ĥ(q)."""
    return jax.jacfwd(lambda q: surface.to_u(arm.h(q)))(q)


def split_loops(A, ctrl, q_eq, names) -> dict:
    """The Jacobian A in the coordinates (u, u̇, controller state), u = (u1, u2) of eq. (6) on the
    controller's constraint, split into the force loop (u2, u̇2, z, the force-rate filter, F_f's
    weights) and the position loop (u1, u̇1, F_p's weights). Returns both blocks' eigenvalues
    (neutral network directions dropped, counted in ``neutral``) and ``coupling``: the largest
    entry of the force rows in the position columns relative to the largest of A (0 on the exact
    model: the force loop does not depend on the position loop)."""
    n, m = ctrl.n, ctrl.m
    Du = np.asarray(_u_jacobian(ctrl.arm, ctrl.surface, jnp.asarray(q_eq, dtype=float)))
    N = A.shape[0]
    Tm = np.eye(N)
    Tm[:n, :n] = Du
    Tm[n:2 * n, n:2 * n] = Du
    Ap = Tm @ A @ np.linalg.inv(Tm)
    pos = np.zeros(N, bool)
    pos[:m] = True
    pos[n:n + m] = True
    for i, name in enumerate(names):
        if name == "theta_p":
            pos[i] = True
    force = ~pos
    scale = max(np.max(np.abs(Ap)), 1e-300)
    coupling = float(np.max(np.abs(Ap[np.ix_(force, pos)]))) / scale if pos.any() and force.any() else 0.0
    out = {"coupling": coupling, "neutral": 0}
    for label, sel, net in (("force", force, "theta_f"), ("position", pos, "theta_p")):
        block = Ap[np.ix_(sel, sel)]
        cand = np.array([names[i] == net for i in np.flatnonzero(sel)])
        W, dropped = _drop_neutral(block, cand)
        out[label] = np.linalg.eigvals(W.T @ block @ W)
        out["neutral"] += dropped
    return out


# --- the polynomial -------------------------------------------------------------------------------


def force_loop_polynomial(m_s, k_u, K_prime, mu_z, alpha_z, kappa=0.0, tau_f=0.0, g_f=0.0, filt=None,
                          rate_filtered=True) -> np.ndarray:
    """Coefficients (highest power first) of the force loop's characteristic polynomial (module
    docstring); with ``g_f`` > 0 the adaptive law's linearised network (the polynomial then has
    one degree more).

    ``filt`` (docs/beyond-the-paper.md section 12): the force filter's transfer function
    F = N_f/D_f as (N_f, D_f) coefficient arrays, in front of the proportional term, z, the
    network and (``rate_filtered``, the differenced force) the force-rate term; the joint rates'
    term (``rate_filtered`` False, τ_f = 0) reads the unfiltered rate. The loop
    m_s s² + k_u(1 + g_P F) + k_u κ s R + α_z k_u F/(s + μ_z) + k_u g_f F/s = 0 (R = F/(τ_f s + 1)
    or 1) is multiplied by D_f (τ_f s + 1)(s + μ_z) (and s with the network)."""
    P, add = np.polymul, np.polyadd
    if filt is not None:
        Nf, Df = (np.atleast_1d(np.asarray(c, dtype=float)) for c in filt)
        Tf = [tau_f, 1.0]
        base = P(add(P([m_s, 0.0, 0.0], Df), add(P([k_u], Df), P([k_u * (K_prime - 1.0)], Nf))), Tf)
        rate = P([k_u * kappa, 0.0], Nf if rate_filtered else P(Df, Tf))
        inner = add(base, rate)
        z_part = P([alpha_z * k_u], P(Nf, Tf))
        if g_f == 0.0:
            return add(P(inner, [1.0, mu_z]), z_part)
        inner = add(P(inner, [1.0, 0.0]), P([k_u * g_f], P(Nf, Tf)))
        return add(P(inner, [1.0, mu_z]), P(z_part, [1.0, 0.0]))
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
    """g_f = γ2‖ξ_f‖² at the inputs (e_λ, z): the adaptive law's integral gain on e_λ at Θ̂_f = 0
    (:func:`hinfnn.controllers.network.integral_gain` of the controller's F_f)."""
    from .controllers.network import integral_gain

    return integral_gain(ctrl.network_f, ctrl.gains.gamma_2, e_lam, z)


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

    def as_dict(self) -> dict:
        return dict(mode=str(self), s=[float(self.s.real), float(self.s.imag)], omega=self.omega, zeta=self.zeta)


def least_damped(eigs) -> complex:
    """The least damped oscillatory eigenvalue (largest Re s/|s|), or the rightmost real one."""
    eigs = list(eigs)
    oscillatory = [e for e in eigs if abs(e.imag) > 1e-9 * max(1.0, abs(e))]
    return complex(max(oscillatory, key=lambda e: e.real / abs(e)) if oscillatory else max(eigs, key=lambda e: e.real))


def _law(ctrl):
    """The law a job's controller wraps (:class:`hinfnn.controllers.job.JobController`), else the
    controller itself: the loop linearised here is the law's, in contact."""
    return getattr(ctrl, "law", ctrl)


def with_kappa(ctrl, kappa: float):
    """The same controller with the force-rate term's κ replaced (0: the paper's law, same compiled
    structure; the term's filter then acts on nothing)."""
    terms = tuple(dataclasses.replace(t, kappa=jnp.asarray(float(kappa))) if isinstance(t, T.ForceRate) else t
                  for t in ctrl.terms)
    return dataclasses.replace(ctrl, terms=terms)


# --- the scenario's operating point ---------------------------------------------------------------


def _reference_offsets(scenario):
    """The reference's mean values (u1d, λd): its offsets, one per coordinate."""
    ref = scenario.build_reference()
    return np.asarray(ref.u1_offset, dtype=float), np.asarray(ref.lam_offset, dtype=float)


def _scalar_or_list(a):
    a = np.ravel(np.asarray(a, dtype=float))
    return float(a[0]) if a.size == 1 else a.tolist()


def operating_point(scenario, stiffness: float, u1d=None, lam_d=None, ctrl=None):
    """(exact plant, constant reference, q_eq, u1d, λd) of the scenario's nominal model with an
    undamped contact of ``stiffness``, at rest at (u1d, λd) (default: the reference's offsets).
    ``ctrl``: a controller of the scenario (its task coordinates and constraint)."""
    u0, l0 = _reference_offsets(scenario)
    u1d = u0 if u1d is None else np.atleast_1d(np.asarray(u1d, dtype=float))
    lam_d = l0 if lam_d is None else np.atleast_1d(np.asarray(lam_d, dtype=float))
    arm, surface = scenario.build().nominal_arm, scenario.build().nominal_surface
    plant = exact_plant(arm, surface, stiffness)
    ref = constant_reference(u1d, lam_d)
    closed = hasattr(arm, "inverse_kinematics_closed") and not plant.cartesian and u1d.size == 1
    if closed:
        q_eq = equilibrium_q(plant, float(u1d[0]), float(lam_d[0]), elbow_up=scenario.initial.elbow == "up")
    else:
        ctrl = _law(ctrl if ctrl is not None else scenario.build_controller(scenario.kinds[0]))
        q_eq = equilibrium_q(plant, u1d, lam_d, ctrl=ctrl, q_guess=scenario.initial_q())
    return plant, ref, np.asarray(q_eq, dtype=float), u1d, lam_d


def _linearise(plant, ctrl, ref, q_eq, stiffness) -> dict:
    """The continuous loop's spectrum at q_eq, split, against the polynomial."""
    names = state_names(ctrl)
    A, _, residual = closed_loop_jacobian(plant, ctrl, ref, q_eq)
    fr = ctrl.term(T.ForceRate)
    kappa, tau = (float(fr.kappa), float(fr.tau_f)) if fr is not None else (0.0, 0.0)
    if fr is not None and kappa == 0.0:  # the paper's law: the filter state acts on nothing; leave it out
        keep = np.array([nm != "s_lam" for nm in names])
        A = A[np.ix_(keep, keep)]
        names = [nm for nm in names if nm != "s_lam"]
        tau = 0.0
    parts = split_loops(A, ctrl, q_eq, names)
    net_idx = np.array([nm in ("theta_p", "theta_f") for nm in names])
    W, neutral = _drop_neutral(A, net_idx)
    eigs = np.linalg.eigvals(W.T @ A @ W)
    c = loop_constants(ctrl.arm, ctrl.surface, stiffness, q_eq)
    g = ctrl.gains
    g_f = network_gain(ctrl)
    kappa_loop = kappa
    velocity = fr is not None and fr.source == "velocity"
    if velocity:  # ṡ = (k_s/k) λ̇ from the joint rates: no filter state
        kappa_loop, tau = kappa * float(fr.stiffness) / float(stiffness), 0.0
    poly = force_loop_polynomial(c["m_s"], c["k_u"], k_prime(ctrl), float(g.mu_z), float(g.alpha_z), kappa_loop, tau,
                                 g_f, filt=_filter_transfer(ctrl), rate_filtered=not velocity)
    roots = np.roots(poly)
    force = sorted(parts["force"], key=lambda e: -e.real)
    matched = None
    if len(force) == len(roots):
        rest, diffs = list(force), []
        for r in roots:
            j = int(np.argmin([abs(e - r) for e in rest]))
            diffs.append(abs(rest.pop(j) - r) / abs(r))
        matched = max(diffs)
    return dict(residual=residual, eigenvalues=eigs, force_eigenvalues=np.array(force),
                position_eigenvalues=np.array(sorted(parts["position"], key=lambda e: -e.real)),
                coupling=parts["coupling"], neutral=neutral, roots=roots, polynomial_match=matched,
                least_damped=Mode(least_damped(force)), constants=c, kappa=kappa, tau_f=tau, g_f=g_f,
                stable=bool(np.all(eigs.real < 0)))


def _filter_transfer(ctrl):
    """(N_f, D_f) of the law's force filter as the continuous loop sees it (its state's rate
    ((A − I)x + Bu)/h, output Cx + Du), or None without a filter."""
    f = ctrl.force_filter
    if f is None:
        return None
    from scipy import signal

    A_, B, C, D = f.matrices()
    h = float(np.asarray(f.period))
    num, den = signal.ss2tf((A_ - np.eye(A_.shape[0])) / h, (B / h)[:, None], C[None, :], np.array([[D]]))
    return np.asarray(num[0], dtype=float), np.asarray(den, dtype=float)


def contact_modes(scenario, kind: str, stiffness: float, u1d=None, lam_d=None, ctrl=None) -> dict:
    """The linearised closed loop of the scenario's controller ``kind`` (its design, its gains, or
    ``ctrl``) on the exact model with contact stiffness ``stiffness`` (undamped), at rest at
    (u1d, λd) (default: the reference's offsets). Returns the eigenvalues of the closed loop
    (neutral network directions dropped), those of the force and position loops, the least
    damped force mode, the polynomial's roots (FL-like, H∞-only, and the adaptive law at Θ̂ = 0)
    and the largest relative difference between the two, and whether the loop is stable."""
    ctrl = _law(ctrl if ctrl is not None else scenario.build_controller(kind))
    plant, ref, q_eq, u1d, lam_d = operating_point(scenario, stiffness, u1d, lam_d, ctrl=ctrl)
    if not np.all(np.isfinite(q_eq)):
        from .errors import DesignError

        raise DesignError(f"no rest pose with u1 = {_scalar_or_list(u1d)} and λ = {_scalar_or_list(lam_d)} on the "
                          f"nominal model at {stiffness:g} N/m (out of reach?)", key="reference.u1_offset")
    out = _linearise(plant, ctrl, ref, q_eq, stiffness)
    return dict(kind=kind, stiffness=stiffness, u1d=_scalar_or_list(u1d), lam_d=_scalar_or_list(lam_d),
                q=q_eq.tolist(), **out)


@jit_by_joints
def _held_plant_jacobian(plant, y_p, tau):
    """(∂(q̇, q̈)/∂(q, q̇), ∂(q̇, q̈)/∂τ, (q̇, q̈)) of the simulator's right-hand side in its sampled
    mode (the torque held at ``tau``, the controller's output not applied) at the plant state y_p;
    column by column as :func:`_loop_jacobian`. The plant alone (:func:`hinfnn.sim.simulate.plant_rhs`):
    the whole right-hand side, controller included, takes several times longer to trace."""
    from .sim.simulate import plant_rhs

    n = plant.n

    def g(v):
        yp, tau = v[:2 * n], v[2 * n:]
        d, _ = plant_rhs(plant, 0.0, plant.initial_state(yp[:n], yp[n:]), tau, jnp.zeros(n))
        q_dot, qd_dot = plant.joints(d)
        return jnp.concatenate([q_dot, qd_dot])

    v0 = jnp.concatenate([y_p, tau])
    values, columns = jax.lax.map(lambda e: jax.jvp(g, (v0,), (e,)), jnp.eye(v0.shape[0], dtype=v0.dtype))
    return columns[:2 * n].T, columns[2 * n:].T, values[0]


def sampled_map_jacobian(plant, ctrl, ref, q_eq, period: float, dt: float):
    """The Jacobian Φ of the simulator's sampled loop over one control period (zero-order hold:
    the controller's sample update, then period/dt RK4 steps of the plant with the torque held and
    the controller state still) at the rest state y* = (q_eq, 0, rest state), composed from the
    continuous loop's Jacobian A (:func:`closed_loop_jacobian`) and the held plant's:

    with P = ∂f_plant/∂y_p at the held τ*, B = ∂f_plant/∂τ, the law's gains K = B⁺(A_plant rows − [P 0])
    and D = A's controller rows, RK4 on the linear plant gives per step R = Σ_{j≤4}(dtP)^j/j! and
    dt·Σ_{j≤3}(dtP)^j/(j+1)!·B, so Φ = [[R^N + W K_y, W K_x], [h D_y, I + h D_x]], W the input
    matrix over the N steps. At an equilibrium the RK4 stages all start at y*, so this is the
    linearisation of the simulator's sampled map itself (tested against ``jacfwd`` of it)."""
    Rn, W, Kmat, A, n = _sampled_parts(plant, ctrl, ref, q_eq, period, dt)
    m = A.shape[0] - 2 * n
    top = np.concatenate([Rn, np.zeros((2 * n, m))], axis=1) + W @ Kmat
    bottom = np.concatenate([period * A[2 * n:, :2 * n], np.eye(m) + period * A[2 * n:, 2 * n:]], axis=1)
    return np.concatenate([top, bottom], axis=0)


def _sampled_parts(plant, ctrl, ref, q_eq, period: float, dt: float):
    """(R^N, W, K, A, n) of :func:`sampled_map_jacobian`: the held plant's map over the period, its
    input matrix, the law's torque gains on (y_p, x_c) and the continuous loop's Jacobian."""
    n = plant.n
    A, y0, _ = closed_loop_jacobian(plant, ctrl, ref, q_eq)
    y_p = jnp.asarray(y0[:2 * n])
    _, Jt, f0 = _held_plant_jacobian(plant, y_p, jnp.zeros(n))
    B = np.asarray(Jt)[n:]
    tau_star = -np.linalg.solve(B, np.asarray(f0)[n:])  # q̈ is affine in τ: at rest q̈(τ*) = 0
    P, Jt, _ = (np.asarray(a) for a in _held_plant_jacobian(plant, y_p, jnp.asarray(tau_star)))
    Bfull = Jt
    Kmat = np.linalg.lstsq(Bfull, A[:2 * n] - np.concatenate([P, np.zeros((2 * n, A.shape[1] - 2 * n))], axis=1),
                           rcond=None)[0]  # τ's gains on (y_p, xc)
    N = int(round(period / dt))
    X = dt * P
    I = np.eye(2 * n)
    X2 = X @ X
    X3 = X2 @ X
    R = I + X + X2 / 2 + X3 / 6 + X3 @ X / 24
    S = I + X / 2 + X2 / 6 + X3 / 24
    Rn, sumR = I.copy(), np.zeros_like(I)
    for _ in range(N):
        sumR += Rn
        Rn = Rn @ R
    W = sumR @ (dt * S @ Bfull)
    return Rn, W, Kmat, A, n


@jit_by_joints
def _force_jacobians(plant, ctrl, ref, y0):
    """(∂τ/∂F, ∂ẋ_c/∂F, ∂λ/∂y_p) at the flat rest state y0: the law's torque and state rate per
    unit of the measured tool force F (base frame), and the controller's reading of the TRUE force
    (its λ from the plant's noiseless sensor, before any filter) per unit of the plant state."""
    ps, xc = _unflatten(plant, ctrl, y0)
    meas, _ = plant.sense(0.0, ps)
    n = plant.n

    def law(F):
        out = ctrl.evaluate(0.0, xc, dataclasses.replace(meas, force=F), ref)
        return out.tau, jnp.concatenate([jnp.ravel(leaf) for leaf in jax.tree.leaves(out.dstate)])

    dtau, dx = jax.jacfwd(law)(meas.force)

    def true_lam(yp):
        m2, _ = plant.sense(0.0, plant.initial_state(yp[:n], yp[n:]))
        return ctrl.observe(m2)[2]

    return dtau, dx, jax.jacfwd(true_lam)(y0[:2 * n])


def sensed_sampled_loop(plant, ctrl, ref, q_eq, period: float, dt: float, delay: int = 0) -> dict:
    """The sampled loop of :func:`sampled_map_jacobian` with a real sensor: the controller reads
    the plant's state of ``delay`` samples before (q, q̇ and force alike: the plant's state of the
    last ``delay`` samples joins the state, oldest last) plus white noise on each axis of the
    measured tool force. Returns the one-period map ``Phi`` over (y_p, x_c, y_p,k−1 … y_p,k−d),
    the noise's input ``Gamma`` (one column per force axis), the held torque's rows ``C_tau`` and
    noise gains ``D_tau``, the true λ's row ``C_lam`` and the network directions to drop
    (``neutral``: the candidates' mask)."""
    Rn, W, K, A, n = _sampled_parts(plant, ctrl, ref, q_eq, period, dt)
    y0 = jnp.asarray(rest_state(ctrl, q_eq))
    dtau, dx, dlam = (np.asarray(a) for a in _force_jacobians(plant, ctrl, ref, y0))
    m = A.shape[0] - 2 * n
    p, d = 2 * n, int(delay)
    N = p + m + d * p
    read = slice(0, p) if d == 0 else slice(p + m + (d - 1) * p, p + m + d * p)  # the y_p the controller reads
    Ky, Kx = K[:, :p], K[:, p:]
    Dy, Dx = A[p:, :p], A[p:, p:]
    Phi = np.zeros((N, N))
    Phi[:p, :p] = Rn
    Phi[:p, read] += W @ Ky
    Phi[:p, p:p + m] += W @ Kx
    Phi[p:p + m, read] += period * Dy
    Phi[p:p + m, p:p + m] += np.eye(m) + period * Dx
    if d:
        Phi[p + m:p + m + p, :p] = np.eye(p)
        for j in range(1, d):
            Phi[p + m + j * p:p + m + (j + 1) * p, p + m + (j - 1) * p:p + m + j * p] = np.eye(p)
    Gamma = np.zeros((N, dtau.shape[1]))
    Gamma[:p] = W @ dtau
    Gamma[p:p + m] = period * dx
    C_tau = np.zeros((n, N))
    C_tau[:, read] += Ky
    C_tau[:, p:p + m] += Kx
    C_lam = np.zeros((dlam.shape[0], N))
    C_lam[:, :p] = dlam
    names = state_names(ctrl)[p:]
    neutral = np.zeros(N, bool)
    neutral[p:p + m] = [nm in ("theta_p", "theta_f") for nm in names]
    return dict(Phi=Phi, Gamma=Gamma, C_tau=C_tau, D_tau=dtau, C_lam=C_lam, neutral=neutral, delay=d, period=period)


def noise_response(loop: dict) -> dict:
    """The stationary response of :func:`sensed_sampled_loop` to white force-sensor noise of 1 N
    per axis (the discrete Lyapunov equation Σ = ΦΣΦᵀ + ΓΓᵀ, the neutral network directions
    dropped): RMS commanded torque per joint (N·m per N of noise), RMS true λ error (λ units per
    N), RMS torque rate per joint (``tau_rate_per_n``: the held torque's change from one sample to
    the next over the period, N·m/s per N), the spectral radius; the gains are inf when the loop
    is not stable.

    The rate: with x_k = Φx_{k−1} + Γn_{k−1} and τ_k = Cx_k + Dn_k, τ_k − τ_{k−1} =
    C(Φ − I)x_{k−1} + (CΓ − D)n_{k−1} + Dn_k, three independent parts."""
    from scipy.linalg import solve_discrete_lyapunov

    Phi, G = loop["Phi"], loop["Gamma"]
    Wb, dropped = _drop_neutral(Phi, loop["neutral"], shift=1.0)
    Pr, Gr = Wb.T @ Phi @ Wb, Wb.T @ G
    radius = float(np.max(np.abs(np.linalg.eigvals(Pr))))
    if radius >= 1.0:
        n = loop["C_tau"].shape[0]
        return dict(radius=radius, stable=False, tau_per_n=[math.inf] * n, lam_per_n=math.inf,
                    tau_rate_per_n=[math.inf] * n, neutral=dropped)
    S = solve_discrete_lyapunov(Pr, Gr @ Gr.T)
    Ct, Cl = loop["C_tau"] @ Wb, loop["C_lam"] @ Wb
    D = loop["D_tau"]
    tau = np.sqrt(np.maximum(np.diag(Ct @ S @ Ct.T) + np.sum(D ** 2, axis=1), 0.0))
    lam = np.sqrt(np.maximum(np.diag(Cl @ S @ Cl.T), 0.0))
    Cd, Gd = Ct @ (Pr - np.eye(Pr.shape[0])), Ct @ Gr - D
    rate = np.sqrt(np.maximum(np.diag(Cd @ S @ Cd.T) + np.sum(Gd ** 2, axis=1) + np.sum(D ** 2, axis=1), 0.0))
    period = float(loop.get("period", 1.0))
    return dict(radius=radius, stable=True, tau_per_n=tau.tolist(), lam_per_n=float(lam.max()),
                tau_rate_per_n=(rate / period).tolist(), neutral=dropped)


def largest_noise(tau_per_n, limits, sigmas: float = 3.0) -> float:
    """The largest sensor noise σ (N) with ``sigmas`` × the RMS commanded torque within each
    joint's limit (inf without limits)."""
    t = np.asarray(tau_per_n, dtype=float)
    lim = np.broadcast_to(np.asarray(limits, dtype=float), t.shape)
    with np.errstate(divide="ignore"):
        ratio = np.where(t > 0, lim / (sigmas * t), np.inf)
    return float(np.min(ratio))


def sampled_modes(plant, ctrl, ref, q_eq, period: float, dt: float) -> dict:
    """The sampled loop (zero-order hold at ``period``, plant integrated by RK4 steps of ``dt``)
    linearised at q_eq (:func:`sampled_map_jacobian`): the eigenvalues of its one-period map
    (neutral network directions, at 1, dropped), the spectral radius, and the least damped mode as
    its continuous equivalent s = ln(z)/period."""
    Phi = sampled_map_jacobian(plant, ctrl, ref, q_eq, period, dt)
    names = state_names(ctrl)
    W, neutral = _drop_neutral(Phi, np.array([nm in ("theta_p", "theta_f") for nm in names]), shift=1.0)
    z = np.linalg.eigvals(W.T @ Phi @ W)
    s = np.log(z.astype(complex)) / period
    return dict(eigenvalues=z, radius=float(np.max(np.abs(z))), stable=bool(np.max(np.abs(z)) < 1.0),
                least_damped=Mode(least_damped(s)), neutral=neutral)


def sampled_kappa_scan(plant, ctrl, ref, q_eq, period: float, dt: float, kappas) -> np.ndarray:
    """The sampled loop's spectral radius for each κ of ``kappas`` (the controller's force-rate
    term's κ replaced; one compiled program for all): the brute-force check of the Jury window."""
    return np.array([sampled_modes(plant, with_kappa(ctrl, k), ref, q_eq, period, dt)["radius"] for k in kappas])


# --- the design report (`hinfnn design`) -------------------------------------------------------------


def _c(z) -> list:
    z = complex(z)
    return [float(z.real), float(z.imag)]


def _modes_entry(r: dict) -> dict:
    """The JSON-ready part of :func:`contact_modes`' result the report keeps."""
    return dict(**r["least_damped"].as_dict(), stable=r["stable"], kappa=r["kappa"], tau_f=r["tau_f"],
                force=[_c(e) for e in r["force_eigenvalues"]], position=[_c(e) for e in r["position_eigenvalues"]],
                polynomial_match=r["polynomial_match"], coupling=r["coupling"], residual=r["residual"],
                m_s=r["constants"]["m_s"], m_n=r["constants"]["m_n"])


def _with_force_rate(scenario, kappa):
    """The scenario with controller.force_rate.kappa replaced (no checks run again)."""
    c = scenario.controller
    return dataclasses.replace(scenario, controller=dataclasses.replace(
        c, force_rate=dataclasses.replace(c.force_rate, kappa=kappa)))


def path_report(scenario, ctrl, q0) -> dict:
    """The nominal model along the reference's path (:func:`hinfnn.scenario.checks.design_path`):
    σ_min(Ĵ) (the singularity guard's measure) and the normal mass m_n (its extreme eigenvalues
    for k > 1), their extremes and where; and the start pose's checks (σ_min(Ĵ(q0)), |det Ĵ(q0)|)."""
    from .controllers.force_rate import path_poses, pose_measures
    from .scenario.checks import design_path, design_span

    poses = path_poses(ctrl.arm, ctrl.surface, design_path(scenario), q0)
    rows = [(u1, *(float(v) for v in pose_measures(ctrl.arm, ctrl.surface, jnp.asarray(q)))) for u1, q in poses]
    found = [r for r in rows if all(math.isfinite(v) for v in r[1:])]
    span, words = design_span(scenario)
    out = dict(points=len(rows), found=len(found), singularity_stop=float(ctrl.sigma_stop), span=span,
               span_words=words)
    if found:
        worst = min(found, key=lambda r: r[3])
        heavy = max(found, key=lambda r: r[2])
        light = min(found, key=lambda r: r[1])
        out.update(sigma_min=worst[3], u1_sigma_min=_scalar_or_list(worst[0]), m_n_max=heavy[2],
                   u1_m_n_max=_scalar_or_list(heavy[0]), m_n_min=light[1], u1_m_n_min=_scalar_or_list(light[0]))
    q0 = jnp.asarray(q0, dtype=float)
    _, _, s0 = (float(v) for v in pose_measures(ctrl.arm, ctrl.surface, q0))
    out["start"] = dict(q0=np.asarray(q0).tolist(), sigma_min=s0,
                        abs_det=abs(float(_jacobian_det(ctrl.arm, q0))))
    return out


@jit_by_joints
def _jacobian_det(arm, q):
    return jnp.linalg.det(arm.J(q))


def design_report(scenario) -> dict:
    """Everything ``hinfnn design`` prints, JSON-ready: per controller kind the resolved design
    (:meth:`~hinfnn.controllers.law.ReducedOrderController.summary`: gains, bounds, P_p and the Riccati solution, the
    networks, the force-rate design) and its contact modes on the exact nominal model at rest at
    the reference's offsets, before and after the force-rate term (κ = 0 and κ as designed, or by
    the rule when the scenario has none), at the plant's contact stiffness and at the design's
    softest and stiffest contacts; under sampled control the sampled loop's spectral radius too;
    and the nominal model along the reference's path (σ_min(Ĵ), normal masses, the start pose).
    A variant the design refuses is reported with the refusal."""
    from .errors import ConfigError, DesignError

    k_plant = float(scenario.plant.contact.stiffness)
    fr_cfg = scenario.controller.force_rate
    sigma, delay, limits = _sensor_facts(scenario)
    period = scenario.control_period
    q0 = scenario.initial_q()
    out = dict(scenario=scenario.name, arm=scenario.nominal.arm.model, surface=scenario.nominal.surface.kind,
               stiffness=k_plant, control_period=period, kinds={})
    path = None
    for kind in scenario.kinds:
        one = scenario.single(kind)
        one.build().check_start(kind)  # what `hinfnn run` refuses before it compiles, refused here too
        ctrl = _law(one.build_controller(kind))
        d = ctrl.summary()
        if path is None:
            path = path_report(one, ctrl, q0)
        term = ctrl.term(T.ForceRate)
        rule_error = None
        if term is not None and float(term.kappa) != 0.0:
            after = ctrl
            labels = ("as designed", "without the force-rate term (the paper's law, kappa = 0)")
        else:
            labels = ("as designed (the paper's law)", "with the force-rate term (kappa by the rule)")
            try:
                after = _law(_with_force_rate(one, "rule").build_controller(kind))
            except (DesignError, ConfigError) as err:
                after, rule_error = None, str(err)
        before = with_kappa(after, 0.0) if after is not None else ctrl
        fr = after.term(T.ForceRate) if after is not None else None
        design = dict(fr.design) if fr is not None else {}
        stiffnesses = sorted({k_plant, float(design.get("stiffness_min", fr_cfg.stiffness_min)),
                              float(design.get("stiffness_max", fr_cfg.stiffness_max))})
        modes = dict(pose=None, stiffnesses=stiffnesses, variants={})
        variants = (after, before) if labels[0] == "as designed" else (before, after)
        for label, c in zip(labels, variants):
            if c is None:
                modes["variants"][label] = dict(error=rule_error)
                continue
            entries = {}
            for k in stiffnesses:
                try:
                    r = contact_modes(one, kind, k, ctrl=c)
                    modes["pose"] = dict(u1=r["u1d"], lam=r["lam_d"], q=r["q"])
                    entries[f"{k:g}"] = _modes_entry(r)
                except (DesignError, ConfigError) as err:
                    entries[f"{k:g}"] = dict(error=str(err))
            if period is not None and "q" in (modes["pose"] or {}):
                plant, ref, q_eq, _, _ = operating_point(one, k_plant, ctrl=c)
                s = sampled_modes(plant, c, ref, q_eq, period, scenario.simulation.dt)
                entries["sampled"] = dict(stiffness=k_plant, period=period, radius=s["radius"], stable=s["stable"],
                                          **s["least_damped"].as_dict())
                nr = noise_response(sensed_sampled_loop(plant, c, ref, q_eq, period, scenario.simulation.dt, delay))
                entries["noise"] = dict(stiffness=k_plant, sigma=sigma, delay=delay, torque_limit=limits,
                                        largest_sigma=largest_noise(nr["tau_per_n"], limits), **nr)
            modes["variants"][label] = entries
        d["contact_modes"] = modes
        bound = _force_error_bound(scenario, path, stiffnesses, sigma, delay, period)
        if bound is not None:
            d["force_error_bound"] = bound
        out["kinds"][kind] = d
    out["path"] = path
    return out


def _force_error_bound(scenario, path, stiffnesses, sigma, delay, period):
    """The least RMS true force error any law holds at the sensor (σ, delay) against the disturbance
    of ``controller.sensor`` (:func:`hinfnn.controllers.sensing.force_error_bound`), on the design's
    linearised contact mode at each stiffness of ``stiffnesses``, the worst of the path's normal
    masses; None without sampled control, a declared disturbance or the path's masses."""
    from .controllers.sensing import force_error_bound

    cs = scenario.controller.sensor
    if period is None or not cs.disturbance or not path or "m_n_min" not in path:
        return None
    masses = (float(path["m_n_min"]), float(path["m_n_max"]))
    at = {f"{k:g}": max(force_error_bound(omega0=math.sqrt(k / m), h=float(period), noise=sigma, delay=delay,
                                          disturbance=float(cs.disturbance), disturbance_hz=float(cs.disturbance_hz))
                        for m in masses) for k in stiffnesses}
    return dict(sigma=sigma, delay=delay, disturbance=float(cs.disturbance), disturbance_hz=float(cs.disturbance_hz),
                m_n=list(masses), at=at)


def _sensor_facts(scenario):
    """(σ, delay, torque limits per joint) the noise gains are reported for: the sensor the
    controller's design assumes (controller.sensor, by default the scenario's declared
    plant.sensor) and the true motors' limits (inf: none)."""
    declared = scenario.build().declared_sensor
    cs = scenario.controller.sensor
    sigma = declared[0] if cs.noise == "declared" else float(cs.noise)
    delay = declared[1] if cs.delay == "declared" else int(cs.delay)
    act = getattr(scenario.build().plant, "actuator", None)
    n = scenario.build().plant.n
    limits = [math.inf] * n if act is None else np.broadcast_to(np.asarray(act.torque_limit, float), (n,)).tolist()
    return float(sigma), int(delay), limits


def _fmt_list(v, spec=".4g"):
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(format(float(x), spec) for x in v) + "]"
    return format(float(v), spec)


def _fmt_matrix(a) -> str:
    """A matrix for a line of text: ``diag[...]`` when every off-diagonal entry is below 1e-12 of
    the largest entry (rounding of the solvers), ``diag[...] + off-diagonal up to x`` when the
    off-diagonal is small against the diagonal but real, else its rows; a scalar as a number."""
    a = np.atleast_2d(np.asarray(a, dtype=float))
    if a.size == 1:
        return format(float(a[0, 0]), ".4g")
    if a.shape[0] == a.shape[1] and a.shape[0] > 2:
        d = np.diag(a)
        off = np.abs(a - np.diag(d)).max()
        scale = max(np.abs(a).max(), 1e-300)
        if off <= 1e-12 * scale:
            return "diag" + _fmt_list(d.tolist())
        return "diag" + _fmt_list(d.tolist()) + f" + off-diagonal up to {off:.4g}"
    return "[" + ", ".join(_fmt_list(row.tolist()) for row in a) + "]"


def format_design_report(rep: dict) -> str:
    """The text of ``hinfnn design`` from :func:`design_report`'s dict."""

    lines = []
    for kind, d in rep["kinds"].items():
        g = d["gains"]
        lines.append(f"{kind}: terms {', '.join(d['terms']) or '(none: the CT law)'}{', augmented' if d['augmented'] else ''}")
        lines.append(f"  gains: K_p {_fmt_matrix(g['K_p'])}, K_v {_fmt_matrix(g['K_v'])}, rho {g['rho']:g}, mu_z {g['mu_z']:g}, alpha_z {g['alpha_z']:g}, "
                     f"alpha_lam {g['alpha_lam']:g}, beta_lam {g['beta_lam']:.6g}, gamma_1 {g['gamma_1']:g}, "
                     f"gamma_2 {g['gamma_2']:g}, Q_p {_fmt_matrix(g['Q_p'])}, R_p {_fmt_matrix(g['R_p'])}")
        for name, b in d["bounds"].items():
            lines.append(f"  bound {name}: {b['value']:.6g} vs {b['bound']:.6g} (margin {b['margin']:+.4g}): {b['rule']}")
        lines.append(f"  P_p {_fmt_matrix(d['P_p'])}  (--json: every entry)")
        ric = d.get("riccati", {})
        if "residual" in ric:
            eig = ", ".join(f"{re:.4g}" if abs(im) <= 1e-9 * max(1.0, abs(re)) else f"{re:.4g}{im:+.4g}j"
                            for re, im in ric["closed_loop_eigs"])
            lines.append(f"  Riccati eq. ({ric['equation']}): residual {ric['residual']:.2e}, min eig P "
                         f"{ric['min_eig_P']:.4g}, closed loop {eig}, Remark 4's condition "
                         f"{'holds' if ric['remark4_holds'] else 'fails'}")
        else:
            lines.append(f"  Riccati: {ric.get('error')}")
        if "v_p_gains" in d:
            row = np.asarray(d["v_p_gains"][0], dtype=float)
            row = np.where(np.abs(row) <= 1e-12 * max(np.abs(row).max(), 1e-300), 0.0, row)
            lines.append(f"  v_p = -[{', '.join(f'{v:.4g}' for v in row)}] x_p"
                         + (" (first row)" if len(d["v_p_gains"]) > 1 else ""))
        for key, n in d.get("networks", {}).items():
            lines.append(f"  network {key}: {n['units']} units, centres {_fmt_list(n['first_centre'], 'g')} .. "
                         f"{_fmt_list(n['last_centre'], 'g')}, slope {_fmt_list(n['slope'], 'g')}"
                         + (f", radius {n['radius']:g}" if n["radius"] else ""))
            if n.get("adaptation"):  # the robust update law (docs/beyond-the-paper.md, section 11)
                a = n["adaptation"]
                lines.append(f"    update law: dead zone {a['dead_zone']:.4g}, leakage {a['leak']:.4g} 1/s + "
                             f"{a['e_gain']:.4g} |s|, the drive's noise RMS {a['drive_noise_rms']:.4g}")
        fr = d.get("force_rate")
        if fr:
            lines.append(f"  force rate: kappa {fr['kappa']:.4g} s ({'rule' if fr['rule'] else 'given'}: zeta {fr['zeta']:g}, "
                         f"K' {fr['K_prime']:.4g}, m_n {fr['m_n_min']:.4g}..{fr['m_n_max']:.4g} kg on "
                         f"{fr.get('path_points', 0)} poses of the path, k {fr['stiffness_min']:g}..{fr['stiffness_max']:g} "
                         f"N/m), tau_f {fr['tau_f']:g} s, zeta at the softest contact {fr.get('zeta_softest', math.nan):.3g}"
                         + (f", sampled window {fr['window'][0]:.3g}..{fr['window'][1]:.3g} s (at {fr['period']:g} s the "
                            f"loop holds up to {fr['stiffness_limit']:.3g} N/m)" if fr.get("window") else "")
                         + (f"; ds/dt from the joint rates (source \"velocity\", k_s {fr['stiffness_max']:g} N/m)"
                            if fr.get("source") == "velocity" else ""))
            sd = fr.get("sensing")
            if sd:
                filt = (f"Butterworth order {sd['order']} at {sd['cutoff_hz']:.4g} Hz" if sd["order"] else "none")
                lines.append(f"  force filter and kappa designed for the sensor (noise {sd['noise']:g} N, delay "
                             f"{sd['delay']} sample(s)): filter {filt}, kappa {sd['kappa']:.4g} s; least damping "
                             f"{sd['zeta']:.3g} over the range; worst RMS force error "
                             f"{sd['force_error_per_n']:.3g} per N "
                             f"of noise, RMS force command {sd['command_per_n']:.3g} per N, its RMS rate "
                             f"{sd.get('command_rate_per_n', math.nan):.3g} per s per N ({sd['candidates']} "
                             f"candidates held; force-rate source \"{sd.get('source', 'force')}\")")
                if sd.get("torque_rate_limit") is not None:
                    lines.append(f"  torque-rate limit {_fmt_list(list(sd['torque_rate_limit']))} N m/s, "
                                 f"{sd.get('torque_rate_share', 1.0):g} of it for the noise (controller.actuator): "
                                 f"the sensor noise's predicted p99 of |dtau|/h "
                                 f"{_fmt_list(list(sd['torque_rate_p99']))} N m/s at noise "
                                 f"{sd.get('rate_noise', sd['noise']):g} N (RMS command "
                                 f"change {sd['command_rate_max_per_n']:.4g} per s per N at its worst corner, levers "
                                 f"{_fmt_list(list(sd['lever']), '.3g')} N m per N)"
                                 + (": within" if sd.get("within_rate_limit") else ": NOT within"))
                if sd.get("rate_warning"):
                    lines.append(f"  WARNING: {sd['rate_warning']}")
        fb = d.get("force_error_bound")
        if fb:
            lines.append(f"  least force error any law holds at sensor noise {fb['sigma']:g} N with {fb['delay']} "
                         f"sample(s) of delay, against a force disturbance of {fb['disturbance']:g} N RMS at "
                         f"{fb['disturbance_hz']:g} Hz (controller.sensor.disturbance): "
                         + ", ".join(f"{v:.3g} N at {k} N/m" for k, v in fb["at"].items())
                         + f" (RMS over time, the worst of m_n {fb['m_n'][0]:.4g}..{fb['m_n'][1]:.4g} kg; the "
                         "LQG law on the linearised contact mode)")
        if d["singularity_stop"] > 0:
            lines.append(f"  singularity guard: stop when sigma_min(J) < {d['singularity_stop']:g}")
        cm = d["contact_modes"]
        pose = cm.get("pose") or {}
        where = f" at rest at u1 = {_fmt_list(pose['u1'])}, lambda = {_fmt_list(pose['lam'])}" if pose else ""
        lines.append(f"  contact modes (linearised closed loop on the exact nominal model{where}):")
        for label, entries in cm["variants"].items():
            if "error" in entries:
                lines.append(f"    {label}: {entries['error']}")
                continue
            for key, m in entries.items():
                if "error" in m:
                    lines.append(f"    {label}, {key} N/m: {m['error']}")
                elif key == "noise":
                    if not m["stable"]:
                        lines.append(f"    {label}, sensor noise with {m['delay']} sample(s) of delay: the "
                                     f"sampled loop is UNSTABLE (spectral radius {m['radius']:.5g})")
                        continue
                    limits = np.array([math.inf if v is None else v for v in m["torque_limit"]], dtype=float)
                    lim = ("" if not np.all(np.isfinite(limits)) else
                           f"; 3 sigma of torque within the limits up to sensor noise {m['largest_sigma']:.3g} N")
                    lines.append(f"    {label}, noise gains with {m['delay']} sample(s) of delay at "
                                 f"{m['stiffness']:g} N/m: "
                                 f"RMS torque per N of sensor noise {_fmt_list(m['tau_per_n'], '.3g')} N m, RMS torque "
                                 f"rate per N {_fmt_list(m.get('tau_rate_per_n', []), '.3g')} N m/s, RMS true "
                                 f"force error {m['lam_per_n']:.3g} per N{lim}"
                                 + (f" (declared noise {m['sigma']:g} N: force error "
                                    f"{m['sigma'] * m['lam_per_n']:.3g}, "
                                    f"torque {_fmt_list([m['sigma'] * v for v in m['tau_per_n']], '.3g')} N m RMS)"
                                    if m["sigma"] > 0 else ""))
                elif key == "sampled":
                    lines.append(f"    {label}, sampled at {m['period']:g} s, {m['stiffness']:g} N/m: spectral radius "
                                 f"{m['radius']:.5g} ({'stable' if m['stable'] else 'UNSTABLE'}), least damped {m['mode']}")
                else:
                    lines.append(f"    contact mode at {float(key):g} N/m, {label}: {m['mode']} "
                                 f"({'stable' if m['stable'] else 'UNSTABLE'}; kappa {m['kappa']:.4g} s, m_s {m['m_s']:.4g})")
    p = rep.get("path") or {}
    if p:
        covered = (f"u1d(t) on 0..{p['span']:g} s: {p['span_words']}" if p.get("span") is not None
                   else p.get("span_words"))
        lines.append(f"path: {p['found']} of {p['points']} poses of the reference on the nominal model"
                     + (f" ({covered})" if covered else "")
                     + (f"; sigma_min(J) >= {p['sigma_min']:.4g} (at u1 = {_fmt_list(p['u1_sigma_min'])}), normal mass "
                        f"{p['m_n_min']:.4g}..{p['m_n_max']:.4g} kg (heaviest at u1 = {_fmt_list(p['u1_m_n_max'])})"
                        if "sigma_min" in p else ""))
        s = p["start"]
        lines.append(f"start pose q0 = {_fmt_list(s['q0'])}: sigma_min(J) {s['sigma_min']:.4g}, |det J| {s['abs_det']:.4g}"
                     + (f"; singularity guard at {p['singularity_stop']:g}" if p["singularity_stop"] > 0 else ""))
    return "\n".join(lines)
