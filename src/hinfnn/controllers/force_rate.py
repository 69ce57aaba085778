"""Design of the force-rate term (not in the paper; docs/beyond-the-paper.md): κ from the contact's
stiffness range and the arm's effective mass along the constraint normal, at design time.

On a compliant contact the force loop of the paper's laws is, linearised about the path,

    m_s s³ + m_s μ_z s² + k_u K' s + k_u (K' μ_z + α_z) = 0,    K' = 1 + β_λ/2 (1 for FL-like),

with m_s = Π²/(Â Ĵ M̂⁻¹ Ĵᵀ Âᵀ) the arm's effective mass in the constraint coordinate u2 and
k_u = kΠ²/(ÂÂᵀ) the contact stiffness in the same coordinate (k_u/m_s = k/m_n, m_n = ÂÂᵀ/(ÂĴM̂⁻¹ĴᵀÂᵀ)
the physical effective mass along the unit normal); Routh's test fails by −α_z m_s k_u for
every gain. The term −κṡ adds κ k_u s to it: the contact mode m_s s² + k_u κ s + k_u K' has the
damping ratio ζ = (κ/2)√(k/(m_n K')), which grows with the stiffness and falls with the mass,
so the rule places ζ* at the softest contact and the heaviest pose of the path:

    κ = 2 ζ* √(K' m_n,max / k_min)     (the same number in either constraint scaling).

Under zero-order hold at period h (filter time constant τ_f = h: ṡ the backward difference of
e_λ), the undamped contact mode ω0 = √(k/m_n) with the feedback g_P + κ(1 − z⁻¹)/h
(g_P = K' − 1) is stable if and only if K = κ/h satisfies K(2c − 2aK − g_P a) > g_P and aK < 1,
c = cos ω0h, a = 1 − c (Jury's test). κ must then also stay below 0.8 of that window's upper
end at the stiffest contact and the lightest pose; an empty window is a DesignError.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

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

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


@jax.jit
def normal_mass(arm, surface, q):
    """m_n = ÂÂᵀ/(Â Ĵ M̂⁻¹ Ĵᵀ Âᵀ): the model's effective mass along the surface's unit normal at q
    (k = 1)."""
    t = arm.terms(q, jnp.zeros_like(q))
    A = surface.A_hat(t.x)
    AJ = A @ t.J
    return (A @ A.T)[0, 0] / (AJ @ jnp.linalg.solve(t.M, AJ.T))[0, 0]


#: :func:`path_poses` kept per process, by value: a scenario's check and its force-rate design solve
#: the same path, and `hinfnn reproduce` loads the same nominal model in 35 scenarios.
_PATHS: dict = {}
_PATHS_MAX = 64


def path_poses(arm, surface, u1_range, q_start, n: int = 41):
    """Nominal poses with the end-effector on the nominal surface at u1 across ``u1_range``
    (inverse kinematics, continued from ``q_start``): [(u1, q)], solved once per process for the
    same arm, surface, range, start and count."""
    key = value_key((arm, surface, (float(u1_range[0]), float(u1_range[1])), np.asarray(q_start, dtype=float), n))
    if key not in _PATHS:
        if len(_PATHS) >= _PATHS_MAX:
            _PATHS.pop(next(iter(_PATHS)))
        _PATHS[key] = tuple(_solve_path(arm, surface, u1_range, q_start, n))
    return list(_PATHS[key])


def _solve_path(arm, surface, u1_range, q_start, n):
    lo, hi = u1_range
    poses = []
    q = jnp.asarray(q_start, dtype=float)
    closed = getattr(arm, "inverse_kinematics_closed", None)
    elbow_up = bool(np.asarray(q_start)[-1] < 0) if closed is not None else True
    for u1 in np.linspace(lo, hi, n):
        x1 = jnp.atleast_1d(jnp.asarray(u1, dtype=float))
        x = jnp.concatenate([x1, surface.Omega(x1)])
        q = closed(x, elbow_up=elbow_up) if closed is not None else arm.inverse_kinematics(x, q)
        poses.append((float(u1), q))
    return poses


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
    lo, hi = max(r[0], 0.0), min(r[1], 1.0 / a)
    return (lo * h, hi * h) if hi > lo else None


def design_force_rate(arm, surface, gains, *, robust: bool, u1_range, q_start, kappa="rule", tau_f="auto",
                      zeta: float = 0.7, stiffness_min: float = 1e4, stiffness_max: float = 1e6,
                      period: float | None = None, margin: float = 0.8) -> ForceRateDesign:
    """κ and τ_f for the force-rate term from the NOMINAL model (the controller's knowledge) and
    the stated range of contact stiffness. ``kappa``: "rule" or a number (s); ``tau_f``: "auto"
    (1 ms, or the control period under sampled control) or a number (s). Raises DesignError when
    no κ stabilises the sampled loop at ``stiffness_max``, or when a given κ lies outside the
    sampled loop's stable window."""
    if surface.k != 1:
        raise DesignError("the force-rate rule is derived for one constraint (k = 1); give kappa as a number",
                          key="force_rate.kappa", value=kappa)
    K_prime = 1.0 + 0.5 * float(gains.beta_lam) if robust else 1.0
    masses = [float(normal_mass(arm, surface, q)) for _, q in path_poses(arm, surface, u1_range, q_start)]
    if not all(math.isfinite(mn) and mn > 0 for mn in masses):
        raise DesignError(f"the nominal effective mass along the normal is not positive and finite on the path "
                          f"u1 in [{u1_range[0]:g}, {u1_range[1]:g}] (a singular pose?)", key="force_rate.kappa")
    mn_max, mn_min = max(masses), min(masses)
    kappa_cont = 2.0 * zeta * math.sqrt(K_prime * mn_max / stiffness_min)
    rule = kappa == "rule"
    k_value = kappa_cont if rule else float(kappa)
    tf = (period if period is not None else 1e-3) if tau_f == "auto" else float(tau_f)
    window = None
    if period is not None:
        g_P = K_prime - 1.0
        omega0_h = math.sqrt(stiffness_max / mn_min) * period
        window = jury_window(omega0_h, g_P, period)
        if window is None:
            raise DesignError(
                f"no force-rate gain stabilises the sampled force loop at the stiffest contact {stiffness_max:g} N/m "
                f"with control period {period:g} s (ω0 h = {omega0_h:.3f} rad per sample, proportional gain "
                f"{g_P:.3f}): lower force_rate.stiffness_max, or control faster", key="force_rate.stiffness_max",
                value=stiffness_max)
        if rule:
            k_value = min(kappa_cont, margin * window[1])
        elif not window[0] < k_value < window[1]:
            raise DesignError(f"κ = {k_value:g} s is outside the sampled loop's stable window "
                              f"({window[0]:.3g}, {window[1]:.3g}) s at {stiffness_max:g} N/m", key="force_rate.kappa",
                              value=k_value)
    return ForceRateDesign(kappa=k_value, tau_f=tf, rule=rule, zeta=zeta, stiffness_min=stiffness_min,
                           stiffness_max=stiffness_max, m_n_max=mn_max, m_n_min=mn_min, K_prime=K_prime,
                           kappa_continuous=kappa_cont, period=period, window=window)
