"""Design of the force-rate term (not in the paper; docs/beyond-the-paper.md): κ from the contact's
stiffness range and the arm's effective mass along the constraint normal, at design time, for any
arm and any constraint (sections 3 and 7).

On a compliant contact the force loop of the paper's laws is, linearised about the path,

    m_s s³ + m_s μ_z s² + k_u K' s + k_u (K' μ_z + α_z) = 0,    K' = 1 + β_λ/2 (1 for FL-like),

with m_s = Π²/(Â Ĵ M̂⁻¹ Ĵᵀ Âᵀ) the arm's effective mass in the constraint coordinate u2 (the Schur
complement M̄22 − M̄21M̄11⁻¹M̄12 of eq. (9)'s M̄, for any arm with a square Ĵ) and k_u = kΠ²/(ÂÂᵀ)
the contact stiffness in the same coordinate (k_u/m_s = k/m_n, m_n = ÂÂᵀ/(ÂĴM̂⁻¹ĴᵀÂᵀ) the
physical effective mass along the unit normal; in coordinates fitted to a Cartesian surface Â = [0 … 0 1]
and m_n = 1/(nᵀJ_pM̂⁻¹J_pᵀn)); Routh's test fails by −α_z m_s k_u for every gain. The term −κṡ adds
κ k_u s to it: the contact mode m_s s² + k_u κ s + k_u K' has the damping ratio
ζ = (κ/2)√(k/(m_n K')), which grows with the stiffness and falls with the mass, so the rule places
ζ* at the softest contact and the heaviest pose of the reference's path:

    κ = 2 ζ* √(K' m_n,max / k_min)     (the same number in either constraint scaling).

For k > 1 constraints with one stiffness on every normal, the loop in the normal displacements is
M_N p̈ + κk ṗ + K'k p = 0, M_N = (NĴM̂⁻¹ĴᵀNᵀ)⁻¹ (N the unit normals): its damping is proportional to
its stiffness, so its modes decouple along the eigenvectors of M_N with ζ_i = (κ/2)√(k/(μ_i K')),
and the rule holds with m_n,max, m_n,min the largest and smallest eigenvalue μ of M_N on the path.

Under zero-order hold at period h (filter time constant τ_f = h: ṡ the backward difference of
e_λ), the undamped contact mode ω0 = √(k/m_n) with the feedback g_P + κ(1 − z⁻¹)/h
(g_P = K' − 1) is stable if and only if K = κ/h satisfies K(2c − 2aK − g_P a) > g_P and aK < 1,
c = cos ω0h, a = 1 − c (Jury's test). κ must then also stay below 0.8 of that window's upper
end at the stiffest contact and the lightest pose, and the sampled loop (with z) must keep a
damping ratio of at least SAMPLED_ZETA_MIN there; an empty window or a thinner margin is a
DesignError that names the stiffest contact the period holds and the longest period that holds
k_max.

The poses are the NOMINAL model's (the controller's knowledge; nothing here imports
:mod:`hinfnn.plant`): inverse kinematics onto the nominal constraint at the reference's path, by
damped Newton steps continued from the start pose (the closed form for the Sec. VI arm).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._declared import design_program
from .._pytree import value_key
from ..errors import DesignError


@dataclasses.dataclass(frozen=True)
class ForceRateDesign:
    """What the design step decided, and why (the numbers ``hinfnn design`` prints)."""

    kappa: float
    tau_f: float
    rule: bool
    zeta: float
    stiffness_min: float
    stiffness_max: float
    m_n_max: float
    m_n_min: float
    K_prime: float
    kappa_continuous: float
    period: float | None = None
    window: tuple | None = None  # the sampled loop's stable κ window at the stiffest contact, s
    constraints: int = 1  # k; for k > 1 m_n_max/m_n_min are the extreme eigenvalues of M_N on the path
    path_points: int = 0  # poses of the reference's path the masses were taken at
    u1_m_n_max: float | tuple | None = None  # where on the path the normal mass is largest
    zeta_softest: float | None = None  # ζ of the contact mode at stiffness_min and m_n_max with this κ
    stiffness_limit: float | None = None  # sampled: the stiffest contact the window holds at this period, N/m
    period_limit: float | None = None  # sampled: the longest control period that holds stiffness_max, s
    zeta_sampled: float | None = None  # sampled: the least damping of the sampled force loop at stiffness_max
    sensing: dict | None = None  # the force filter and κ designed for the declared sensor (controllers.sensing)
    source: str = "force"  # the term's ṡ: "force" (differenced e_λ) or "velocity" (joint rates, ForceRate)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


@jax.jit
def normal_mass(arm, surface, q):
    """m_n = ÂÂᵀ/(Â Ĵ M̂⁻¹ Ĵᵀ Âᵀ): the model's effective mass along the constraint's unit normal at q
    (k = 1), for any arm and constraint (docs/beyond-the-paper.md, section 7).

    With Â = ∂θ̂/∂x, ÂĴ = ∂θ̂/∂q is the constraint's gradient in joint space; for a Cartesian
    surface (θ̂ the signed distance of the tool point p, fitted coordinates) ÂĴ = nᵀJ_p and
    ÂÂᵀ = 1, so m_n = 1/(nᵀ J_p M̂⁻¹ J_pᵀ n): the inverse of the normal entry of the tool point's
    inverse operational-space inertia J_p M̂⁻¹ J_pᵀ. For the Sec. VI line (paper scaling,
    Â = [tan δ, −1]) it is the expression of the two-link case."""
    A = surface.A_hat(arm.h(q))  # h, J, M alone: a URDF arm's by 3 × 3 products (UrdfChain.fk)
    AJ = A @ arm.J(q)
    return (A @ A.T)[0, 0] / (AJ @ jnp.linalg.solve(arm.M(q), AJ.T))[0, 0]


@jax.jit
def normal_mass_matrix(arm, surface, q):
    """M_N = (N Ĵ M̂⁻¹ Ĵᵀ Nᵀ)⁻¹, N = DÂ the constraints' unit normals (D = diag(1/‖Â_i‖)): the
    effective-mass matrix along the k normals at q (k × k; for k = 1 the m_n of
    :func:`normal_mass`). docs/beyond-the-paper.md, section 7."""
    A = surface.A_hat(arm.h(q))
    N = A / jnp.linalg.norm(A, axis=1, keepdims=True)
    NJ = N @ arm.J(q)
    return jnp.linalg.inv(NJ @ jnp.linalg.solve(arm.M(q), NJ.T))


@jax.jit
def normal_lever(arm, surface, q):
    """Per joint, the joint torque per N of force along the constraints' unit normals at q:
    |(Ĵᵀn̂)_j| for one constraint (n̂ = Âᵀ/‖Â‖), and for several the root sum of squares over
    them, ‖(NĴ)_{:,j}‖ (N = DÂ, independent noise on each normal). What turns the force path's
    command rate into joint torque rates (docs/beyond-the-paper.md, section 12)."""
    A = surface.A_hat(arm.h(q))
    N = A / jnp.linalg.norm(A, axis=1, keepdims=True)
    return jnp.sqrt(jnp.sum((N @ arm.J(q)) ** 2, axis=0))


@design_program
def pose_measures(arm, surface, q):
    """(smallest, largest normal mass, σ_min(Ĵ)) at the pose q: m_n twice for one constraint, the
    extreme eigenvalues of M_N for several; σ_min(Ĵ) the singularity guard's measure. One
    compiled program per arm and constraint structure."""
    from .law import sigma_min

    if surface.k == 1:
        mn = normal_mass(arm, surface, q)
        lo = hi = mn
    else:
        ev = jnp.linalg.eigvalsh(normal_mass_matrix(arm, surface, q))
        lo, hi = ev[0], ev[-1]
    return lo, hi, sigma_min(arm.J(q))


@jax.jit
def reference_points(ref, t):
    """u1d of reference ``ref`` at the times ``t`` (N,), as one compiled program: (N, m)."""
    return jax.vmap(lambda ti: ref(ti).u1_d)(t)


#: :func:`path_poses` kept per process, by value: a scenario's check and its force-rate design solve
#: the same path, and `hinfnn reproduce` loads the same nominal model in 35 scenarios.
_PATHS: dict = {}
_PATHS_MAX = 64


def _path_points(u1_path, n: int) -> np.ndarray:
    """The motion coordinates of the path's points, (N, m): ``n`` evenly spaced points of a span
    (lo, hi) (m = 1), or the given points."""
    a = np.asarray(u1_path, dtype=float)
    if a.ndim == 1 and a.shape == (2,):
        return np.linspace(a[0], a[1], n)[:, None]
    if a.ndim != 2 or a.shape[0] < 1:
        raise ValueError(f"u1_path must be a span (lo, hi) or an (N, m) array of points, got shape {a.shape}")
    return a


def path_poses(arm, surface, u1_path, q_start, n: int = 41):
    """Nominal poses with the end-effector on the nominal constraint at the path's points
    (inverse kinematics of the NOMINAL model, continued from ``q_start``): [(u1, q)], solved once
    per process for the same arm, surface, path, start and count. ``u1_path``: the span (lo, hi)
    of a single motion coordinate (``n`` evenly spaced points) or an (N, m) array of points
    (u1d(t) sampled along the run). u1 is a float for a span, an (m,) array otherwise. A pose
    that is not found (out of reach, or the Newton iteration left the branch of ``q_start``) is
    NaN."""
    span = np.asarray(u1_path, dtype=float).shape == (2,)
    key = value_key((arm, surface, np.asarray(u1_path, dtype=float), np.asarray(q_start, dtype=float), n))
    if key not in _PATHS:
        if len(_PATHS) >= _PATHS_MAX:
            _PATHS.pop(next(iter(_PATHS)))
        _PATHS[key] = tuple(_solve_path(arm, surface, _path_points(u1_path, n), q_start, span))
    return list(_PATHS[key])


def _solve_path(arm, surface, points, q_start, span):
    closed = getattr(arm, "inverse_kinematics_closed", None)
    if closed is not None and points.shape[1] == 1:  # the Sec. VI arm: closed form, the branch of q_start
        poses = []
        elbow_up = bool(np.asarray(q_start)[-1] < 0)
        for u1 in points[:, 0]:
            x1 = jnp.atleast_1d(jnp.asarray(u1, dtype=float))
            x = jnp.concatenate([x1, surface.Omega(x1)])
            poses.append((float(u1), closed(x, elbow_up=elbow_up)))
        return poses
    qs = np.asarray(_newton_path(arm, surface, jnp.asarray(points), jnp.asarray(q_start, dtype=float)))
    return [(float(u[0]) if span else u, q) for u, q in zip(points, qs)]


@design_program
def _newton_path(arm, surface, points, q_start):
    """Poses along the path by damped Newton (Levenberg–Marquardt) steps on h(q) = (u1, Ω(u1)),
    each started from the previous pose (steps of at most 0.5 rad, as the start-pose solver of the
    plant); NaN where the residual is not below 1e-10."""
    n = q_start.shape[0]

    def pose(q, u1):
        x = jnp.concatenate([u1, surface.Omega(u1)])

        def body(_, q):
            r = arm.h(q) - x
            Jr = arm.J(q)
            step = jnp.linalg.solve(Jr.T @ Jr + 1e-12 * jnp.eye(n), Jr.T @ r)
            scale = jnp.minimum(1.0, 0.5 / jnp.maximum(jnp.max(jnp.abs(step)), 1e-300))
            return q - scale * step

        q_new = jax.lax.fori_loop(0, 60, body, q)
        ok = jnp.max(jnp.abs(arm.h(q_new) - x)) < 1e-10
        return jnp.where(ok, q_new, q), jnp.where(ok, q_new, jnp.nan)  # continue from the last pose found

    _, qs = jax.lax.scan(pose, q_start, points)
    return qs


def jury_window(omega0_h: float, g_P: float, h: float):
    """The κ interval (s) that stabilises the sampled contact mode (see the module docstring), or
    None when it is empty."""
    c = math.cos(omega0_h)
    a = 1.0 - c
    A, B, C = -2.0 * a, 2.0 * c - g_P * a, -g_P
    disc = B * B - 4.0 * A * C
    if a <= 0 or disc <= 0:
        return None
    r = sorted([(-B + math.sqrt(disc)) / (2 * A), (-B - math.sqrt(disc)) / (2 * A)])
    lo, hi = (r[0] if r[0] > 0 else 0.0), min(r[1], 1.0 / a)
    return (lo * h, hi * h) if hi > lo else None


def jury_limit(g_P: float) -> float:
    """The largest ω0h at which :func:`jury_window` is not empty for the proportional gain g_P
    (bisection to 1e-12): the sampled loop holds contacts up to k = m_n,min (ω0h/h)² at period h,
    and a contact k_max needs h ≤ ω0h / √(k_max/m_n,min). π/2 for g_P = 0."""
    lo, hi = 0.0, math.pi
    if jury_window(1e-6, g_P, 1.0) is None:
        return 0.0
    while hi - lo > 1e-12:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if jury_window(mid, g_P, 1.0) is not None else (lo, mid)
    return lo


#: The least damping ratio the design accepts for the sampled force loop at the stiffest contact
#: and the lightest pose (:func:`sampled_damping`). Measured (docs/beyond-the-paper.md, section 7):
#: on the UR5 table at 1e6 N/m and 1 kHz the Jury window is not empty, but the best κ leaves that
#: loop ζ ≈ 0.03 and the adaptive law's run stops at the torque limit; the accepted designs of the
#: shipped scenarios at 1 kHz have ζ ≥ 0.07.
SAMPLED_ZETA_MIN = 0.05


def sampled_force_loop(omega0_h: float, g_P: float, kappa: float, h: float, mu_z: float = 0.0,
                       alpha_z: float = 0.0) -> np.ndarray:
    """The force loop over one period of the zero-order hold, linearised on the contact mode
    ω0 = √(k/m_n) (docs/beyond-the-paper.md, section 7): state (e_λ, ė_λ/ω0, s, z) at the samples,
    e_λ between samples the undamped mode driven by the held w = z − g_P e_λ − κ(e_λ − s)/h
    (the filter with τ_f = h: s_{j+1} = e_λ,j, the backward difference), z by forward Euler of (27).
    With μ_z = α_z = 0 (z left out: the first three states) its stable κ are exactly Jury's window."""
    c, sn = math.cos(omega0_h), math.sin(omega0_h)
    w = np.array([-g_P - kappa / h, 0.0, kappa / h, 1.0])
    A = np.zeros((4, 4))
    A[0] = np.array([c, sn, 0.0, 0.0]) + (1.0 - c) * w
    A[1] = np.array([-sn, c, 0.0, 0.0]) + sn * w
    A[2, 0] = 1.0
    A[3, 0], A[3, 3] = -h * alpha_z, 1.0 - h * mu_z
    return A


def sampled_damping(omega0_h: float, g_P: float, kappa: float, h: float, mu_z: float, alpha_z: float):
    """(spectral radius, least damping ratio) of :func:`sampled_force_loop`, each eigenvalue z read
    as s = ln(z)/h, ζ = −Re s/|s|."""
    z = np.linalg.eigvals(sampled_force_loop(omega0_h, g_P, kappa, h, mu_z, alpha_z))
    s = np.log(z.astype(complex)) / h
    zeta = min(-x.real / abs(x) for x in s)
    return float(np.max(np.abs(z))), float(zeta)


def _sampled_kappa(kappa_cont, omega0_h, g_P, h, margin):
    """The rule's κ under sampled control: min(κ_rule, margin × the Jury window's upper end), or
    None when the window is empty."""
    window = jury_window(omega0_h, g_P, h)
    return None if window is None else min(kappa_cont, margin * window[1])


def _largest(ok, lo, hi, steps=60):
    """The largest x in [lo, hi] with ok(x) (bisection on a log scale; ok(lo) holds), or hi."""
    if ok(hi):
        return hi
    for _ in range(steps):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def design_force_rate(arm, surface, gains, *, robust: bool, u1_path=None, q_start, kappa="rule", tau_f="auto",
                      zeta: float = 0.7, stiffness_min: float = 1e4, stiffness_max: float = 1e6,
                      period: float | None = None, margin: float = 0.8, u1_range=None,
                      sensing: dict | None = None, source: str = "force") -> ForceRateDesign:
    """κ and τ_f for the force-rate term from the NOMINAL model (the controller's knowledge) and
    the stated range of contact stiffness, for any arm and constraint (docs/beyond-the-paper.md,
    sections 3 and 7).

    ``u1_path``: the reference's path in the motion coordinates, a span (lo, hi) for m = 1 or an
    (N, m) array of points (``u1_range`` is its former name); the poses are the NOMINAL model's
    inverse kinematics onto the nominal constraint, continued from ``q_start``. m_n,max and
    m_n,min are the largest and smallest normal mass on them (for k > 1 constraints: the extreme
    eigenvalues of the effective-mass matrix M_N along the unit normals, the same contact
    stiffness range on each). ``kappa``: "rule" (κ = 2ζ√(K' m_n,max/k_min); under sampled control
    min(that, ``margin`` × the Jury window's upper end at k_max and m_n,min)) or a number (s);
    ``tau_f``: "auto" (1 ms, or the control period under sampled control) or a number (s).

    Raises DesignError when a pose of the path is not found or is singular, when no κ stabilises
    the sampled loop at ``stiffness_max`` (the message gives the stiffest contact this period
    holds and the longest period that holds ``stiffness_max``), or when a given κ lies outside
    the sampled loop's stable window.

    ``sensing`` (sampled control; :func:`hinfnn.controllers.sensing.design_sensing`): the force
    filter's ``order`` and ``cutoff_hz`` (numbers or "design"), the sensor's ``noise`` (N) and
    ``delay`` (samples), the network's integral gain ``g_f`` and optionally ``torque_rate_limit``
    (N·m/s, a number or one per joint; the choice is made within ``torque_rate_share`` of it at a
    noise of at least ``rate_noise_floor``, with
    each joint's largest :func:`normal_lever` over the path's poses): κ ("rule") and the filter are then
    chosen together on the loop with the filter, the delay and the network (the ideal sensor's
    Jury window does not apply), and the choice is kept in ``sensing``.

    ``source`` (:class:`hinfnn.controllers.terms.ForceRate`): "force" (ṡ the differenced e_λ) or
    "velocity" (ṡ = k_s D²ÂĴq̇ from the joint rates, k_s = ``stiffness_max``). With "velocity" the
    term's damping is k_s/k times the force source's at a contact k, so the least damping of the
    range is at its stiffest contact: the rule is κ = 2ζ*√(K' m_n,max/k_max) under continuous
    control, and under sampled control κ and the filter always come from
    :func:`~hinfnn.controllers.sensing.design_sensing` (``sensing`` None: no filter, an ideal
    sensor)."""
    from .sensing import check_source

    check_source(source)
    velocity = source == "velocity"
    if velocity and period is not None and sensing is None:
        sensing = dict(order=0, cutoff_hz="design", noise=0.0, delay=0, g_f=0.0)
    from .._config import require_x64

    require_x64()
    path = u1_path if u1_path is not None else u1_range
    if path is None:
        raise DesignError("the force-rate design needs the reference's path (u1_path)", key="force_rate.kappa",
                          value=kappa)
    K_prime = 1.0 + 0.5 * float(gains.beta_lam) if robust else 1.0
    poses = path_poses(arm, surface, path, q_start)
    measures = [tuple(float(v) for v in pose_measures(arm, surface, jnp.asarray(q))) for _, q in poses]
    bad = next((i for i, (lo, hi, _) in enumerate(measures)
                if not (math.isfinite(lo) and math.isfinite(hi) and lo > 0)), None)
    if bad is not None:
        u1 = poses[bad][0]
        where = f"{u1:.4g}" if isinstance(u1, float) else "[" + ", ".join(f"{v:.4g}" for v in np.ravel(u1)) + "]"
        raise DesignError(f"the nominal model has no pose on the nominal surface at u1 = {where} of the reference's "
                          "path, or the pose is singular (the effective mass along the normal is not positive and "
                          "finite there): move the reference into the arm's reach", key="force_rate.kappa",
                          value=kappa)
    mn_max = max(hi for _, hi, _ in measures)
    mn_min = min(lo for lo, _, _ in measures)
    i_max = max(range(len(measures)), key=lambda i: measures[i][1])
    u1_heavy = poses[i_max][0]
    u1_heavy = u1_heavy if isinstance(u1_heavy, float) else tuple(float(v) for v in np.ravel(u1_heavy))
    kappa_cont = 2.0 * zeta * math.sqrt(K_prime * mn_max / (stiffness_max if velocity else stiffness_min))
    rule = kappa == "rule"
    k_value = kappa_cont if rule else float(kappa)
    tf = (period if period is not None else 1e-3) if tau_f == "auto" else float(tau_f)
    window = stiffness_limit = period_limit = zeta_sampled = None
    if sensing is not None:
        from .sensing import design_sensing

        if period is None:
            raise DesignError("the force filter and the sensor's delay are designed for sampled control",
                              key="force_filter.order", value=sensing.get("order"))
        rate_limit, lever = sensing.get("torque_rate_limit"), None
        if rate_limit is not None:  # the largest lever of each joint over the path's poses
            lever = np.max([np.asarray(normal_lever(arm, surface, jnp.asarray(q)), float) for _, q in poses], axis=0)
            rate_limit = np.broadcast_to(np.asarray(rate_limit, dtype=float), lever.shape)
        sd = design_sensing(h=float(period), g_P=K_prime - 1.0, mu_z=float(gains.mu_z), alpha_z=float(gains.alpha_z),
                            g_f=float(sensing.get("g_f", 0.0)), noise=float(sensing.get("noise", 0.0)),
                            delay=int(sensing.get("delay", 0)), stiffness_min=stiffness_min,
                            stiffness_max=stiffness_max, m_n_min=mn_min, m_n_max=mn_max,
                            order=sensing.get("order", "design"), cutoff_hz=sensing.get("cutoff_hz", "design"),
                            kappa="rule" if rule else float(kappa), zeta_min=SAMPLED_ZETA_MIN, source=source,
                            torque_rate_limit=rate_limit, lever=lever,
                            torque_rate_share=float(sensing.get("torque_rate_share", 1.0)),
                            rate_noise_floor=float(sensing.get("rate_noise_floor", 0.0)))
        k_value = sd.kappa
        zeta_soft = _zeta_softest(k_value, stiffness_min, stiffness_max, mn_max, K_prime, velocity)
        return ForceRateDesign(kappa=k_value, tau_f=tf, rule=rule, zeta=zeta, stiffness_min=stiffness_min,
                               stiffness_max=stiffness_max, m_n_max=mn_max, m_n_min=mn_min, K_prime=K_prime,
                               kappa_continuous=kappa_cont, period=period, constraints=int(surface.k),
                               path_points=len(poses), u1_m_n_max=u1_heavy, zeta_softest=zeta_soft,
                               zeta_sampled=sd.zeta, sensing=sd.as_dict(), source=source)
    if period is not None:
        g_P = K_prime - 1.0
        mu_z, alpha_z = float(gains.mu_z), float(gains.alpha_z)
        omega0_h = math.sqrt(stiffness_max / mn_min) * period

        def accepted(k_max, h):  # the rule's κ (or the given one) keeps the margin at k_max, period h
            x = math.sqrt(k_max / mn_min) * h
            kap = _sampled_kappa(kappa_cont, x, g_P, h, margin) if rule else float(kappa)
            w = jury_window(x, g_P, h)
            if kap is None or w is None or not w[0] < kap < w[1]:
                return False
            return sampled_damping(x, g_P, kap, h, mu_z, alpha_z)[1] >= SAMPLED_ZETA_MIN

        x_max = jury_limit(g_P)
        k_top = mn_min * (x_max / period) ** 2  # the window closes here
        stiffness_limit = (_largest(lambda k: accepted(k, period), stiffness_min, k_top)
                           if k_top > stiffness_min and accepted(stiffness_min, period) else 0.0)
        period_limit = _largest(lambda h: accepted(stiffness_max, h), 1e-9, x_max / math.sqrt(stiffness_max / mn_min))
        window = jury_window(omega0_h, g_P, period)
        if window is None:
            raise DesignError(
                f"no force-rate gain stabilises the sampled force loop at the stiffest contact {stiffness_max:g} N/m "
                f"with control period {period:g} s (ω0 h = {omega0_h:.3f} rad per sample at the lightest pose of the "
                f"path, m_n,min = {mn_min:.4g} kg; proportional gain β_λ/2 = {g_P:.3f}; the window closes at ω0 h = "
                f"{x_max:.3f}): at this period the design holds contacts up to {stiffness_limit:.3g} N/m (set "
                f"controller.force_rate.stiffness_max <= {stiffness_limit:.3g}), or a {stiffness_max:g} N/m contact "
                f"needs simulation.control_period <= {period_limit:.3g} s", key="force_rate.stiffness_max",
                value=stiffness_max, bound=stiffness_limit)
        if rule:
            k_value = min(kappa_cont, margin * window[1])
        elif not window[0] < k_value < window[1]:
            raise DesignError(f"κ = {k_value:g} s is outside the sampled loop's stable window "
                              f"({window[0]:.3g}, {window[1]:.3g}) s at {stiffness_max:g} N/m", key="force_rate.kappa",
                              value=k_value)
        zeta_sampled = sampled_damping(omega0_h, g_P, k_value, period, mu_z, alpha_z)[1]
        if zeta_sampled < SAMPLED_ZETA_MIN:
            raise DesignError(
                f"the sampled force loop at the stiffest contact {stiffness_max:g} N/m and control period {period:g} s "
                f"is stable with κ = {k_value:.3g} s but its contact mode keeps only ζ = {zeta_sampled:.3f} (at the "
                f"lightest pose of the path, m_n,min = {mn_min:.4g} kg; the design asks ζ >= {SAMPLED_ZETA_MIN:g}, "
                f"below which the adaptive law's weights drift): at this period the design holds contacts up to "
                f"{stiffness_limit:.3g} N/m (set controller.force_rate.stiffness_max <= {stiffness_limit:.3g}), or a "
                f"{stiffness_max:g} N/m contact needs simulation.control_period <= {period_limit:.3g} s",
                key="force_rate.stiffness_max", value=stiffness_max, bound=stiffness_limit)
    # the damping ratio the chosen κ gives the contact mode at the softest contact and the heaviest pose
    zeta_soft = _zeta_softest(k_value, stiffness_min, stiffness_max, mn_max, K_prime, velocity)
    return ForceRateDesign(kappa=k_value, tau_f=tf, rule=rule, zeta=zeta, stiffness_min=stiffness_min,
                           stiffness_max=stiffness_max, m_n_max=mn_max, m_n_min=mn_min, K_prime=K_prime,
                           kappa_continuous=kappa_cont, period=period, window=window, constraints=int(surface.k),
                           path_points=len(poses), u1_m_n_max=u1_heavy, zeta_softest=zeta_soft,
                           stiffness_limit=stiffness_limit, period_limit=period_limit, zeta_sampled=zeta_sampled,
                           source=source)


def _zeta_softest(kappa, k_min, k_max, mn_max, K_prime, velocity):
    """ζ = (κ/2)√(k/(m_n K')) of the contact mode at the softest contact and the heaviest pose; with
    the "velocity" source the term's damping is k_max/k_min times the force source's there."""
    return 0.5 * kappa * (k_max / k_min if velocity else 1.0) * math.sqrt(k_min / (mn_max * K_prime))
