"""The force measurement path of a sampled controller, designed for the sensor it has (not in the
paper; docs/beyond-the-paper.md, section 12).

A robot's force/torque sensor gives the contact force late (``delay`` whole samples of
transport delay) and noisy (white noise of standard deviation σ per axis at each sample). Two
things of the controller meet that noise: the proportional force feedback (v_λ of eq. (32)) and,
above all, the force-rate term −κṡ, whose ṡ is the backward difference of e_λ at the control
period h (gain κ/h on the noise). This module gives the controller

* :class:`ForceFilter`: a discrete low-pass (Butterworth of order 1 or 2, by the bilinear
  transform at the control period) on the measured force error e_λ = λ − λd, in front of
  everything the law does with it: eqs. (27), (31), (32) and the force-rate term all read the
  filtered e_λ. Its state is part of the controller's state (``lam_filter``), written as a rate
  (x_{k+1} − x_k)/h so that the controller's forward Euler step over h is exactly the discrete
  filter (sampled control only), and it starts at rest at the first measurement;
* :func:`sensed_force_loop`: the linearised force loop over one period of the zero-order hold
  (:func:`hinfnn.controllers.force_rate.sampled_force_loop`'s contact mode) with the filter's
  states, ``delay`` samples of transport delay on the measurement, the z-filter (27) and the
  adaptive law's force network at Θ̂_f = 0 (an integral action of gain g_f = γ2‖ξ_f(0)‖² on e_λ),
  driven by white sensor noise;
* :func:`noise_gains`: from it, by the discrete Lyapunov equation Σ = ΦΣΦᵀ + ΓΓᵀ, the RMS true
  force error and the RMS held force command per N of sensor noise;
* :func:`design_sensing`: the filter's order and cutoff and κ chosen together for the declared
  sensor: every candidate must keep the loop stable with damping ratio at least
  :data:`~hinfnn.controllers.force_rate.SAMPLED_ZETA_MIN` at each corner of the design's range
  (softest and stiffest contact, lightest and heaviest pose of the path), and among those the one
  with the least worst-corner RMS force error per N of noise is taken (ties: the least force
  command). None holding is a DesignError naming ``controller.sensor.delay``. Told the robot's
  torque-rate limit, it chooses among the candidates whose predicted 99th percentile of each
  joint's |Δτ|/h from the noise (:func:`predicted_torque_rate`) is within a share of it, and
  reports plainly when none is;
* :func:`force_error_bound`: the least RMS true force error ANY law holds on the same contact mode,
  delay and noise against a declared force disturbance (the LQG law, :func:`lqg_cost`), and
  :func:`fit_force_disturbance`, which identifies that disturbance from a run with an ideal sensor.

Nothing here imports :mod:`hinfnn.plant`: the sensor the design assumes is the controller's own
statement (``controller.sensor``), copied from the scenario's declared sensor by default.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import pytree_dataclass, static_field
from ..errors import DesignError


@pytree_dataclass
class ForceFilter:
    """A discrete low-pass on each component of e_λ: x_{k+1} = A x_k + B u_k, y_k = C x_k + D u_k
    (one state block of ``order`` values per constraint), at the control period ``period``.
    Build it with :func:`butterworth`."""

    A: jax.Array
    B: jax.Array
    C: jax.Array
    D: jax.Array
    period: jax.Array
    order: int = static_field(default=1)
    cutoff_hz: float = static_field(default=0.0)

    def state_size(self, k: int) -> int:
        return self.order * k

    def _blocks(self, x, k):
        return x.reshape(k, self.order)

    def output(self, lam, x):
        """y = C x + D u, per constraint (u = e_λ): the filter's output equation."""
        k = lam.shape[0]
        return self._blocks(x, k) @ self.C + self.D * lam

    def rate(self, lam, x):
        """(x_{k+1} − x_k)/h: the controller's forward Euler step over h gives the next state."""
        k = lam.shape[0]
        X = self._blocks(x, k)
        nxt = X @ self.A.T + lam[:, None] * self.B[None, :]
        return ((nxt - X) / self.period).reshape(-1)

    def rest(self, lam):
        """The state at rest with input u (the output then equals u: unit gain at DC)."""
        x1 = jnp.linalg.solve(jnp.eye(self.order) - self.A, self.B)
        return (lam[:, None] * x1[None, :]).reshape(-1)

    def matrices(self):
        """(A, B, C, D) as NumPy arrays (B, C as vectors, D a number)."""
        return (np.asarray(self.A, float), np.asarray(self.B, float), np.asarray(self.C, float),
                float(np.asarray(self.D)))


@functools.lru_cache(maxsize=256)
def butterworth_matrices(order: int, cutoff_hz: float, period: float):
    """(A, B, C, D) of the Butterworth low-pass of ``order`` (1 or 2) and ``cutoff_hz`` at the
    sampling ``period``: SciPy's bilinear design in its controllable canonical state space (B, C
    vectors, D a number). Raises DesignError (``force_filter.order``, ``force_filter.cutoff_hz``)
    for another order, or a cutoff not below the Nyquist frequency."""
    from scipy import signal

    order = int(order)
    if order not in (1, 2):
        raise DesignError(f"must be 0 (no filter), 1 or 2, got {order}", key="force_filter.order", value=order)
    nyquist = 0.5 / float(period)
    if not 0.0 < float(cutoff_hz) < nyquist:
        raise DesignError(f"must be between 0 and the Nyquist frequency {nyquist:g} Hz of the control period "
                          f"{period:g} s, got {cutoff_hz:g}", key="force_filter.cutoff_hz", value=cutoff_hz,
                          bound=nyquist)
    b, a = signal.butter(order, float(cutoff_hz), fs=1.0 / float(period))
    A, B, C, D = signal.tf2ss(b, a)
    return np.asarray(A, float), np.asarray(B[:, 0], float), np.asarray(C[0], float), float(D[0, 0])


def butterworth(order: int, cutoff_hz: float, period: float) -> ForceFilter:
    """The :class:`ForceFilter` of :func:`butterworth_matrices`."""
    A, B, C, D = butterworth_matrices(int(order), float(cutoff_hz), float(period))
    return ForceFilter(A=np.asarray(A), B=np.asarray(B), C=np.asarray(C), D=np.asarray(D),
                       period=np.asarray(float(period)), order=int(order), cutoff_hz=float(cutoff_hz))


#: Where the force-rate term's ṡ comes from (:class:`hinfnn.controllers.terms.ForceRate`).
FORCE_RATE_SOURCES = ("force", "velocity")


def check_source(source) -> None:
    """DesignError naming ``force_rate.source`` unless ``source`` is one of
    :data:`FORCE_RATE_SOURCES`."""
    if source not in FORCE_RATE_SOURCES:
        raise DesignError(f"must be \"force\" or \"velocity\", got {source!r}", key="force_rate.source",
                          value=source)


def _none():
    return np.zeros((0, 0)), np.zeros(0), np.zeros(0), 1.0


def _contact_rows(N, omega0_h, w, wn, h=None, damping_ratio=0.0):
    """(Φ, Γ) of an N-state one-period map with its first two rows filled: the undamped contact mode
    (e, ė/ω0) over one period of the zero-order hold, driven by the held command w (a row over the
    state) and its noise coefficient wn; with ``damping_ratio`` ζ > 0 (and the period ``h``) the
    contact damped by ζ (:func:`period_cost`)."""
    Phi, G = np.zeros((N, N)), np.zeros(N)
    if damping_ratio:
        P2, G2, _ = period_cost(omega0_h / h, h, damping_ratio)
        Phi[:2] = np.outer(G2, w)
        Phi[:2, :2] += P2
        G[:2] = G2 * wn
        return Phi, G
    c, sn = math.cos(omega0_h), math.sin(omega0_h)
    Phi[0] = (1.0 - c) * w
    Phi[0, 0] += c
    Phi[0, 1] += sn
    G[0] = (1.0 - c) * wn
    Phi[1] = sn * w
    Phi[1, 0] -= sn
    Phi[1, 1] += c
    G[1] = sn * wn
    return Phi, G


def _filter_rows(Phi, G, filt, i_f, ym, ymn):
    """The force filter's rows (its state from index ``i_f``) reading the measurement row ``ym``."""
    Af, Bf = filt
    nf = Af.shape[0]
    if nf:
        Phi[i_f:i_f + nf] = np.outer(Bf, ym)
        Phi[i_f:i_f + nf, i_f:i_f + nf] += Af
        G[i_f:i_f + nf] = Bf * ymn


def _integral_rows(Phi, G, ec, ecn, h, mu_z, alpha_z, g_f, i_z, i_nu):
    """The rows of z (eq. (27), forward Euler over h) and, with g_f > 0, of the force network's
    output ν (its integral action on e_c), both driven by the filtered error row ``ec``."""
    Phi[i_z] = -h * alpha_z * ec
    Phi[i_z, i_z] += 1.0 - h * mu_z
    G[i_z] = -h * alpha_z * ecn
    if g_f:
        Phi[i_nu] = h * g_f * ec
        Phi[i_nu, i_nu] += 1.0
        G[i_nu] = h * g_f * ecn


def sensed_force_loop(omega0_h: float, g_P: float, kappa: float, h: float, mu_z: float = 0.0, alpha_z: float = 0.0,
                      g_f: float = 0.0, delay: int = 0, filt=None, source: str = "force", rate_scale: float = 1.0,
                      damping_ratio: float = 0.0):
    """(Φ, Γ, w, w_n): the force loop over one period of the zero-order hold, linearised on the
    contact mode ω0 = √(k/m_n), with the measurement path of a real sensor (module docstring).

    State: (e, ė/ω0) the true force error and its rate at the sample; the ``delay`` last
    acquisitions y_j = e_j + n_j (newest first); the filter's state (``filt`` = (A, B, C, D),
    None: no filter); s (the force-rate filter, τ_f = h); z of eq. (27); and with g_f > 0 the
    network's output ν = ξ_fᵀΘ̂_f. The controller reads y_{k−d} (y_k itself without delay), filters
    it into e_c and holds the force command w = z − ν − g_P e_c − κ(e_c − s)/h; between samples e
    is the undamped contact mode driven by w. Γ: the noise n_k's column; w, w_n: the held command's
    row and its noise coefficient. With no delay, filter or network it is
    :func:`hinfnn.controllers.force_rate.sampled_force_loop` (the same matrix).

    ``source`` "velocity" (the force-rate term's ṡ from the joint rates,
    :class:`~hinfnn.controllers.terms.ForceRate`): the rate term reads the TRUE ė of ``delay``
    samples before (the joint rates are delayed with the force), scaled by ``rate_scale`` = k_s/k
    (the term's ṡ = k_s D²ÂĴq̇ is k_s/k times the contact's λ̇), and carries none of the force
    noise; the s state is replaced by the delay line of ė/ω0 (after the acquisitions'), and
    w = z − ν − g_P e_c − κ (k_s/k) ė_{k−d}.

    ``damping_ratio``: the contact's own damping ratio ζ (a damped pad; 0: the bare contact the
    design assumes), :func:`period_cost`'s contact mode (the rate term still reads ė)."""
    if source == "velocity":
        return _velocity_force_loop(omega0_h, g_P, kappa, h, mu_z, alpha_z, g_f, delay, filt, rate_scale,
                                    damping_ratio)
    Af, Bf, Cf, Df = _none() if filt is None else filt
    nf = Af.shape[0]
    d = int(delay)
    i_f = 2 + d
    i_s = i_f + nf
    i_z = i_s + 1
    i_nu = i_z + 1
    N = i_nu + (1 if g_f else 0)
    # the measurement the controller reads: a row over the state and its noise coefficient
    ym, ymn = np.zeros(N), 0.0
    if d == 0:
        ym[0], ymn = 1.0, 1.0
    else:
        ym[2 + d - 1] = 1.0
    ec, ecn = Df * ym, Df * ymn
    ec[i_f:i_f + nf] += Cf
    w, wn = -(g_P + kappa / h) * ec, -(g_P + kappa / h) * ecn
    w[i_s] += kappa / h
    w[i_z] += 1.0
    if g_f:
        w[i_nu] -= 1.0
    Phi, G = _contact_rows(N, omega0_h, w, wn, h, damping_ratio)
    if d:
        Phi[2, 0], G[2] = 1.0, 1.0
        for j in range(1, d):
            Phi[2 + j, 2 + j - 1] = 1.0
    _filter_rows(Phi, G, (Af, Bf), i_f, ym, ymn)
    Phi[i_s], G[i_s] = ec, ecn
    _integral_rows(Phi, G, ec, ecn, h, mu_z, alpha_z, g_f, i_z, i_nu)
    return Phi, G, w, wn


def _velocity_force_loop(omega0_h, g_P, kappa, h, mu_z, alpha_z, g_f, delay, filt, rate_scale, damping_ratio=0.0):
    """:func:`sensed_force_loop` with the "velocity" source (its docstring): state (e, ė/ω0, the
    ``delay`` acquisitions y, the ``delay`` past ė/ω0, the filter's, z, ν)."""
    Af, Bf, Cf, Df = _none() if filt is None else filt
    nf = Af.shape[0]
    d = int(delay)
    i_y, i_v = 2, 2 + d
    i_f = 2 + 2 * d
    i_z = i_f + nf
    i_nu = i_z + 1
    N = i_nu + (1 if g_f else 0)
    ym, ymn = np.zeros(N), 0.0
    vm = np.zeros(N)  # the ė/ω0 the rate term reads
    if d == 0:
        ym[0], ymn = 1.0, 1.0
        vm[1] = 1.0
    else:
        ym[i_y + d - 1] = 1.0
        vm[i_v + d - 1] = 1.0
    ec, ecn = Df * ym, Df * ymn
    ec[i_f:i_f + nf] += Cf
    w, wn = -g_P * ec, -g_P * ecn
    w = w - kappa * rate_scale * (omega0_h / h) * vm
    w[i_z] += 1.0
    if g_f:
        w[i_nu] -= 1.0
    Phi, G = _contact_rows(N, omega0_h, w, wn, h, damping_ratio)
    if d:
        Phi[i_y, 0], G[i_y] = 1.0, 1.0
        Phi[i_v, 1] = 1.0
        for j in range(1, d):
            Phi[i_y + j, i_y + j - 1] = 1.0
            Phi[i_v + j, i_v + j - 1] = 1.0
    _filter_rows(Phi, G, (Af, Bf), i_f, ym, ymn)
    _integral_rows(Phi, G, ec, ecn, h, mu_z, alpha_z, g_f, i_z, i_nu)
    return Phi, G, w, wn


def loop_damping(Phi, h: float):
    """(spectral radius, least damping ratio) of a one-period map, each eigenvalue z read as
    s = ln(z)/h, ζ = −Re s/|s| (eigenvalues at 0, the delay line's, have none and are skipped)."""
    z = np.linalg.eigvals(Phi)
    radius = float(np.max(np.abs(z))) if z.size else 0.0
    live = z[np.abs(z) > 1e-12]
    s = np.log(live.astype(complex)) / h
    zeta = min((-x.real / abs(x) for x in s if abs(x) > 0), default=1.0)
    return radius, float(zeta)


def noise_gains(Phi, G, w, wn):
    """(RMS true force error, RMS held force command) per unit of white measurement noise, from
    the stationary covariance Σ = ΦΣΦᵀ + GGᵀ (the discrete Lyapunov equation); inf when Φ is not
    stable."""
    from scipy.linalg import solve_discrete_lyapunov

    if np.max(np.abs(np.linalg.eigvals(Phi))) >= 1.0:
        return math.inf, math.inf
    S = solve_discrete_lyapunov(Phi, np.outer(G, G))
    return math.sqrt(max(S[0, 0], 0.0)), math.sqrt(max(float(w @ S @ w) + wn * wn, 0.0))


def command_rate(Phi, G, w, wn) -> float:
    """RMS change of the held force command from one sample to the next, w_k − w_{k−1}, per unit of
    white measurement noise (the stationary covariance of the loop augmented with the previous
    command; divide by h for a rate); inf when Φ is not stable."""
    from scipy.linalg import solve_discrete_lyapunov

    if np.max(np.abs(np.linalg.eigvals(Phi))) >= 1.0:
        return math.inf
    N = Phi.shape[0]
    P2 = np.zeros((N + 1, N + 1))
    P2[:N, :N] = Phi
    P2[N, :N] = w
    G2 = np.zeros(N + 1)
    G2[:N] = G
    G2[N] = wn
    S = solve_discrete_lyapunov(P2, np.outer(G2, G2))
    c = np.zeros(N + 1)
    c[:N] = w
    c[N] = -1.0
    return math.sqrt(max(float(c @ S @ c) + wn * wn, 0.0))


@dataclasses.dataclass(frozen=True)
class SensingDesign:
    """What :func:`design_sensing` chose, and its predictions (per N of sensor noise)."""

    order: int
    cutoff_hz: float | None
    kappa: float
    noise: float
    delay: int
    force_error_per_n: float  # RMS true force error per N of noise, worst corner of the range
    command_per_n: float  # RMS held force command per N of noise, same corner
    zeta: float  # least damping ratio over the corners
    candidates: int  # designs that held
    command_rate_per_n: float = math.nan  # RMS change of the held force command per second, per N, same corner
    source: str = "force"  # the force-rate term's ṡ: "force" (differenced e_λ) or "velocity" (joint rates)
    # the torque-rate limit the design was told (None: none), N·m/s per joint, and what it predicts
    torque_rate_limit: tuple | None = None
    torque_rate_share: float | None = None  # the share of the limit the noise's predicted p99 may use
    rate_noise: float | None = None  # the noise the rate is predicted at: max(noise, rate_noise_floor), N
    lever: tuple | None = None  # per joint: the largest joint torque per N of normal force on the path, N·m/N
    command_rate_max_per_n: float | None = None  # RMS command change per second per N, largest over the corners
    torque_rate_p99: tuple | None = None  # predicted 99th percentile of |Δτ_j|/h at the declared noise, N·m/s
    within_rate_limit: bool | None = None  # False: no candidate was within, the least rate was taken
    rate_warning: str | None = None  # the plain statement when no candidate is within the limit

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def corners(stiffness_min, stiffness_max, m_n_min, m_n_max):
    """The (k, m_n) corners of the design's range."""
    return [(k, m) for k in sorted({float(stiffness_min), float(stiffness_max)})
            for m in sorted({float(m_n_min), float(m_n_max)})]


def evaluate_design(order, cutoff_hz, kappa, *, h, g_P, mu_z, alpha_z, g_f, delay, pts, zeta_min=-math.inf,
                    source="force", stiffness_max=None, loop_out=None):
    """(least ζ, worst force error per N, its command per N) of one candidate over the corners
    ``pts``; ζ = −inf when a corner is unstable (the noise gains are inf then, and when the least ζ
    is below ``zeta_min``: not computed). ``source`` "velocity": the rate term reads the joint
    rates, scaled at each corner by ``stiffness_max``/k (:func:`sensed_force_loop`). ``loop_out``:
    a list that receives the worst corner's loop (for :func:`command_rate`)."""
    filt = None if not order else butterworth_matrices(int(order), float(cutoff_hz), float(h))
    loops, zmin = [], math.inf
    for k, m in pts:
        extra = {} if source == "force" else dict(source=source, rate_scale=float(stiffness_max) / k)
        loop = sensed_force_loop(math.sqrt(k / m) * h, g_P, kappa, h, mu_z, alpha_z, g_f, delay, filt, **extra)
        radius, zeta = loop_damping(loop[0], h)
        if radius >= 1.0:
            return -math.inf, math.inf, math.inf
        zmin = min(zmin, zeta)
        loops.append(loop)
    if zmin < zeta_min:
        return zmin, math.inf, math.inf
    e_w, w_w, worst = 0.0, 0.0, None
    for loop in loops:
        e, c = noise_gains(*loop)
        if e > e_w:
            e_w, w_w, worst = e, c, loop
    if loop_out is not None:
        loop_out.append(worst)
    return zmin, e_w, w_w


#: The "velocity" source's choice: among the candidates whose worst-corner force error is within
#: this factor of the least, the one whose held command changes least from sample to sample.
RATE_TOLERANCE = 1.10

#: The 99th percentile of |x|/σ for a zero-mean Gaussian x: the predicted 99th percentile of a
#: joint's |Δτ|/h is this times its RMS (the loop is linear and its input Gaussian).
P99_GAUSS = 2.5758


def max_command_rate(order, cutoff_hz, kappa, *, h, g_P, mu_z, alpha_z, g_f, delay, pts, source="force",
                     stiffness_max=None) -> float:
    """The RMS change of the held force command per second per unit of white measurement noise
    (:func:`command_rate` over h), largest over the corners ``pts`` of the design's range (the
    force error's worst corner need not be the rate's: the lightest pose moves fastest)."""
    filt = None if not order else butterworth_matrices(int(order), float(cutoff_hz), float(h))
    worst = 0.0
    for k, m in pts:
        extra = {} if source == "force" else dict(source=source, rate_scale=float(stiffness_max) / k)
        loop = sensed_force_loop(math.sqrt(k / m) * h, g_P, kappa, h, mu_z, alpha_z, g_f, delay, filt, **extra)
        worst = max(worst, command_rate(*loop) / h)
    return worst


def predicted_torque_rate(rate_per_n: float, noise: float, lever) -> np.ndarray:
    """The predicted 99th percentile of each joint's |Δτ_j|/h (N·m/s) from the force path: the
    held force command's RMS change per second per N (``rate_per_n``) times the noise σ (N)
    times the joint's lever (N·m per N of normal force), times :data:`P99_GAUSS`."""
    return P99_GAUSS * float(noise) * float(rate_per_n) * np.asarray(lever, dtype=float)


def design_sensing(*, h: float, g_P: float, mu_z: float, alpha_z: float, g_f: float, noise: float, delay: int,
                   stiffness_min: float, stiffness_max: float, m_n_min: float, m_n_max: float, order="design",
                   cutoff_hz="design", kappa="rule", zeta_min: float = 0.05, source: str = "force",
                   torque_rate_limit=None, lever=None, torque_rate_share: float = 1.0,
                   rate_noise_floor: float = 0.0,
                   _search_ok: bool = True) -> SensingDesign:
    """The force filter (``order`` 0, 1 or 2, or "design": each tried; ``cutoff_hz`` a number or
    "design": a grid from 5 Hz to 0.4 of the sampling rate) and κ ("rule": a grid from h/20 to
    100h; or a number) chosen together for a sensor of ``noise`` N and ``delay`` samples (module
    docstring); ``zeta_min``: the least damping ratio accepted at every corner (the force-rate
    design passes :data:`hinfnn.controllers.force_rate.SAMPLED_ZETA_MIN`, the same 0.05). Raises
    DesignError naming ``sensor.delay`` when no candidate holds; its bound is the
    softest contact the design holds with the same stiffest one (None: not even that one).

    ``source``: the force-rate term's ṡ, "force" (the differenced e_λ: the candidate of least
    worst-corner force error, ties the least command) or "velocity" (the joint rates, scaled by
    k_s/k with k_s = ``stiffness_max``: among the candidates within :data:`RATE_TOLERANCE` of the
    least force error, the one of least RMS command change per sample, :func:`command_rate`).

    ``torque_rate_limit`` (N·m/s, one per joint; None: no limit, the choice above unchanged) and
    ``lever`` (per joint, the largest joint torque per N of normal force on the path, N·m/N): a
    candidate is within the limit when its predicted 99th percentile of |Δτ_j|/h,
    :func:`predicted_torque_rate` of its :func:`max_command_rate` at the ``noise``, is at most
    ``torque_rate_share`` (0 < share <= 1) of the limit on every joint (the rest is left to the
    motion and the contact's own torque changes, which the noise loop does not see), the noise
    taken as at least ``rate_noise_floor`` N (the contact's own force changes pass the same path); the choice above is then made among those within it, and when none is,
    the candidate of least predicted rate is taken (ties: the least force error) and the record
    says so (``within_rate_limit`` False, ``rate_warning``): the robot's clamp still acts."""
    check_source(source)
    zeta_min = float(zeta_min)
    pts = corners(stiffness_min, stiffness_max, m_n_min, m_n_max)
    orders = (0, 1, 2) if order == "design" else (int(order),)
    kappas = np.geomspace(h / 20.0, 100.0 * h, 49) if kappa == "rule" else np.array([float(kappa)])
    best, count, held = None, 0, []
    for o in orders:
        cutoffs = [None] if o == 0 else (np.geomspace(5.0, 0.4 / h, 14) if cutoff_hz == "design"
                                           else [float(cutoff_hz)])
        for fc in cutoffs:
            for kap in kappas:
                worst = []
                zmin, e, c = evaluate_design(o, fc, float(kap), h=h, g_P=g_P, mu_z=mu_z, alpha_z=alpha_z, g_f=g_f,
                                             delay=delay, pts=pts, zeta_min=zeta_min, source=source,
                                             stiffness_max=stiffness_max, loop_out=worst)
                if not zmin >= zeta_min:
                    continue
                count += 1
                key = (round(e, 9), c)
                entry = (key, o, fc, float(kap), e, c, zmin, worst[0])
                held.append(entry)
                if best is None or key < best[0]:
                    best = entry
    rate = None
    if best is not None and torque_rate_limit is not None:  # the choice among those within the limit
        rate_noise = max(float(noise), float(rate_noise_floor))
        best, held, rate = _within_rate(held, torque_rate_limit, lever, rate_noise, torque_rate_share, h=h, g_P=g_P,
                                        mu_z=mu_z,
                                        alpha_z=alpha_z, g_f=g_f, delay=delay, pts=pts, source=source,
                                        stiffness_max=stiffness_max)
    if best is not None and source == "velocity":  # the least command change near the least error
        near = [(command_rate(*b[7]), b[4], b) for b in held if b[4] <= RATE_TOLERANCE * best[4]]
        best = min(near, key=lambda x: (x[0], x[1]))[2]
    if best is None:
        softest = None
        if _search_ok:  # the softest contact this delay and period hold with the stated stiffest one
            def ok(k_min):
                try:
                    design_sensing(h=h, g_P=g_P, mu_z=mu_z, alpha_z=alpha_z, g_f=g_f, noise=noise, delay=delay,
                                   stiffness_min=k_min, stiffness_max=stiffness_max, m_n_min=m_n_min,
                                   m_n_max=m_n_max, order=order, cutoff_hz=cutoff_hz, kappa=kappa,
                                   zeta_min=zeta_min, source=source, _search_ok=False)
                    return True
                except DesignError:
                    return False

            if ok(stiffness_max):
                lo, hi = float(stiffness_min), float(stiffness_max)
                for _ in range(10):  # on a log scale: a 1.1 % bracket over a decade
                    mid = math.sqrt(lo * hi)
                    lo, hi = (lo, mid) if ok(mid) else (mid, hi)
                softest = hi
        where = (f": with this delay the design holds contacts from {softest:.3g} N/m up to {stiffness_max:g} N/m "
                 f"(set controller.force_rate.stiffness_min >= {softest:.3g}), or shorten the control period"
                 if softest is not None else
                 ": it does not hold even the stiffest contact alone; shorten the control period or lower "
                 "controller.force_rate.stiffness_max")
        raise DesignError(
            f"no force filter and force-rate gain keep the sampled force loop stable with damping ratio >= "
            f"{zeta_min:g} over contacts {stiffness_min:g}..{stiffness_max:g} N/m and normal masses "
            f"{m_n_min:.4g}..{m_n_max:.4g} kg with {delay} sample(s) of measurement delay at {h:g} s"
            + (f" (the adaptive law's force network adds an integral action of gain {g_f:.4g} 1/s: lowering gamma_2 "
               "slows it)" if g_f else "") + where,
            key="sensor.delay", value=delay, bound=softest)
    _, o, fc, kap, e, c, zmin, loop = best
    extra = {}
    if rate is not None:
        r = rate[id(best)]
        p99 = predicted_torque_rate(r, rate_noise, lever)
        limit = np.asarray(torque_rate_limit, dtype=float)
        within = bool(np.all(p99 <= torque_rate_share * limit))
        warning = None
        if not within:
            j = int(np.argmax(p99 / limit))
            warning = (f"no force filter and kappa keep the sensor noise's torque rate within "
                       f"controller.actuator.torque_rate_share = {torque_rate_share:g} of "
                       f"controller.actuator.torque_rate_limit at the noise {rate_noise:g} N (the declared "
                       f"{noise:g} N, at least controller.actuator.rate_noise_floor): the least predicted "
                       f"99th percentile of |dtau|/h is {p99[j]:.4g} N m/s on joint {j + 1} against "
                       f"{torque_rate_share * limit[j]:.4g} of the limit {limit[j]:.4g} N m/s (the robot's clamp "
                       "still acts)")
        extra = dict(torque_rate_limit=tuple(float(v) for v in limit), torque_rate_share=float(torque_rate_share),
                     rate_noise=rate_noise,
                     lever=tuple(float(v) for v in lever),
                     command_rate_max_per_n=float(r), torque_rate_p99=tuple(float(v) for v in p99),
                     within_rate_limit=within, rate_warning=warning)
    return SensingDesign(order=o, cutoff_hz=None if fc is None else float(fc), kappa=kap, noise=float(noise),
                         delay=int(delay), force_error_per_n=e, command_per_n=c, zeta=zmin, candidates=count,
                         command_rate_per_n=command_rate(*loop) / h, source=source, **extra)


def _within_rate(held, torque_rate_limit, lever, noise, share, **loop_args):
    """(the least-error candidate within the torque-rate limit, the candidates the choice is made
    among, {id(candidate): its :func:`max_command_rate`}): :func:`design_sensing`'s choice within
    a rate limit. None within: the candidate of least rate (ties: least error) alone."""
    if lever is None:
        raise DesignError("a torque-rate limit needs the joints' levers (joint torque per N of normal force)",
                          key="actuator.torque_rate_limit", value=torque_rate_limit)
    limit = np.asarray(torque_rate_limit, dtype=float)
    lev = np.asarray(lever, dtype=float)
    if limit.shape != lev.shape or not np.all(limit > 0):
        raise DesignError(f"must be positive, one per joint ({lev.size}), got {limit.tolist()}",
                          key="actuator.torque_rate_limit", value=limit.tolist())
    if not 0.0 < float(share) <= 1.0:
        raise DesignError(f"must be in (0, 1], got {share}", key="actuator.torque_rate_share", value=share)
    rate = {id(b): max_command_rate(b[1], b[2], b[3], **loop_args) for b in held}
    within = [b for b in held if np.all(predicted_torque_rate(rate[id(b)], noise, lev) <= share * limit)]
    if within:
        return min(within, key=lambda b: b[0]), within, rate
    least = min(held, key=lambda b: (rate[id(b)], b[4]))
    return least, [least], rate


# --- the least force error any linear law holds (the LQG bound) -------------------------------------

def period_cost(omega0: float, h: float, damping_ratio: float = 0.0):
    """(Φ, Γ, Q̄) of the contact mode over one period of the zero-order hold: x = (e, ė/ω0) the
    force error and its scaled rate, ẋ = A x + B s with A = [[0, ω0], [−ω0, −2ζω0]], B = (0, ω0)
    (ë = ω0²(s − e) − 2ζω0ė: the held force command s pushes against the contact of ω0 = √(k/m_n),
    damped by ζ), x_{k+1} = Φ x_k + Γ s_k, and ∫_0^h e(t)² dt = (x, s)ᵀ Q̄ (x, s) (Van Loan's
    integral of the sampled-data cost: the true force error between the samples too)."""
    from scipy.linalg import expm

    A = np.array([[0.0, omega0], [-omega0, -2.0 * damping_ratio * omega0]])
    Ab = np.zeros((3, 3))
    Ab[:2, :2] = A
    Ab[1, 2] = omega0
    E = expm(Ab * h)
    M = np.zeros((6, 6))
    M[:3, :3] = -Ab.T
    M[0, 3] = 1.0  # C̄ᵀC̄ with C̄ = (1, 0, 0): the cost reads e
    M[3:, 3:] = Ab
    F = expm(M * h)
    Q = F[3:, 3:].T @ F[:3, 3:]
    return E[:2, :2], E[:2, 2], 0.5 * (Q + Q.T)


def lqg_law(Phi, Gam, W, C, V, Qbar, Mx, Mu):
    """(K, L) of the LQG law of :func:`lqg_cost`'s problem: u_k = −K x̂_{k|k},
    x̂_{k|k} = x̂_{k|k−1} + L (y_k − C x̂_{k|k−1}), x̂_{k+1|k} = Φ x̂_{k|k} + Γ u_k."""
    from scipy.linalg import solve_discrete_are

    Phi, Gam, C = np.atleast_2d(Phi), np.asarray(Gam, float).reshape(Phi.shape[0], -1), np.atleast_2d(C)
    W, V = np.atleast_2d(W), np.atleast_2d(V)
    Q = Mx.T @ Qbar @ Mx
    R = np.atleast_2d(Mu.T @ Qbar @ Mu)
    S_ = (Mx.T @ Qbar @ Mu).reshape(Phi.shape[0], -1)
    P = solve_discrete_are(Phi, Gam, Q, R, s=S_)
    K = np.linalg.solve(R + Gam.T @ P @ Gam, Gam.T @ P @ Phi + S_.T)
    Pf = solve_discrete_are(Phi.T, C.T, W, V)
    L = Pf @ C.T @ np.linalg.inv(C @ Pf @ C.T + V)
    return K, L


def lqg_cost(Phi, Gam, W, C, V, Qbar, Mx, Mu) -> float:
    """The least stationary cost per sample E[(Mx x + Mu u)ᵀ Q̄ (Mx x + Mu u)] any causal law
    u_k = f(y_0, …, y_k) holds on x_{k+1} = Φ x_k + Γ u_k + w_k, y_k = C x_k + n_k (w, n white,
    Gaussian, covariances W and V): the LQG law (Riccati equations of the control, with the cross
    term, and of the filter, the estimate x̂_{k|k} using y_k), its cost evaluated exactly on the
    closed loop (true state and estimator) by the discrete Lyapunov equation. Optimal among all
    laws, linear or not, for Gaussian noise (separation)."""
    from scipy.linalg import solve_discrete_lyapunov

    Phi, Gam, C = np.atleast_2d(Phi), np.asarray(Gam, float).reshape(Phi.shape[0], -1), np.atleast_2d(C)
    W, V = np.atleast_2d(W), np.atleast_2d(V)
    K, L = lqg_law(Phi, Gam, W, C, V, Qbar, Mx, Mu)
    n, ny = Phi.shape[0], C.shape[0]
    I = np.eye(n)
    # closed loop on (x, x̂_{k|k−1}), driven by (w, n): u = −K[(I − LC) x̂⁻ + L(Cx + n)]
    Ku_x, Ku_h, Ku_n = -K @ L @ C, -K @ (I - L @ C), -K @ L
    Acl = np.block([[Phi + Gam @ Ku_x, Gam @ Ku_h], [(Phi - Gam @ K) @ L @ C, (Phi - Gam @ K) @ (I - L @ C)]])
    Bcl = np.block([[I, Gam @ Ku_n], [np.zeros((n, n)), (Phi - Gam @ K) @ L]])
    Ncov = np.zeros((n + ny, n + ny))
    Ncov[:n, :n], Ncov[n:, n:] = W, V
    if np.max(np.abs(np.linalg.eigvals(Acl))) >= 1.0:
        return math.inf
    X = solve_discrete_lyapunov(Acl, Bcl @ Ncov @ Bcl.T)
    # the cost's argument (Mx x + Mu u) as a row map on (x, x̂⁻, n)
    G = np.hstack([Mx + Mu @ Ku_x, Mu @ Ku_h, Mu @ Ku_n])
    Z = np.zeros((2 * n + ny, 2 * n + ny))
    Z[:2 * n, :2 * n] = X
    Z[2 * n:, 2 * n:] = V
    return float(np.trace(G.T @ Qbar @ G @ Z))


def force_error_bound(*, omega0: float, h: float, noise: float, delay: int, disturbance: float,
                      disturbance_hz: float, damping_ratio: float = 0.0, rate_noise: float | None = None) -> float:
    """The least RMS TRUE force error (N, over continuous time) any law holds on the contact mode
    ω0 = √(k/m_n) (damping ratio ``damping_ratio``) under a zero-order hold at the period ``h``,
    reading the force error ``delay`` samples late with white noise of ``noise`` N at each sample,
    against a force disturbance d held with the command: a first-order Gauss–Markov process of RMS
    ``disturbance`` N and corner ``disturbance_hz`` (d_{k+1} = a d_k + √(1 − a²) D v_k,
    a = exp(−2π f_d h)). ``rate_noise`` (N/s; None: no such measurement): the law also reads the
    force error's rate ė, as late, with white noise of that RMS (the force-rate term's "velocity"
    source: the contact's rate from the joint rates). The model is :func:`sensed_force_loop`'s
    contact mode and delay line, the law any causal function of the measurements (:func:`lqg_cost`:
    the LQG law is the best, linear or not); the cost is ∫e² between the samples
    (:func:`period_cost`). With no disturbance the bound is 0 (a law that does nothing holds
    e = 0). Raises DesignError naming the key of a negative input."""
    for key, v in (("sensor.noise", noise), ("sensor.disturbance", disturbance),
                   ("sensor.disturbance_hz", disturbance_hz), ("sensor.delay", delay),
                   ("sensor.rate_noise", 0.0 if rate_noise is None else rate_noise)):
        if not (np.isfinite(v) and v >= 0):
            raise DesignError(f"must be finite and >= 0, got {v!r}", key=key, value=v, bound=0.0)
    if disturbance == 0.0:
        return 0.0
    model = bound_model(omega0=omega0, h=h, noise=noise, delay=delay, disturbance=disturbance,
                        disturbance_hz=disturbance_hz, damping_ratio=damping_ratio, rate_noise=rate_noise)
    return math.sqrt(max(lqg_cost(*model), 0.0) / float(h))


def bound_model(*, omega0, h, noise, delay, disturbance, disturbance_hz, damping_ratio=0.0, rate_noise=None):
    """(Φ, Γ, W, C, V, Q̄, M_x, M_u): :func:`force_error_bound`'s problem as :func:`lqg_cost` takes it
    (state (e, ė/ω0, d, the delay lines); the cost's argument (e, ė/ω0, the held force u + d))."""
    d = int(delay)
    rate = rate_noise is not None
    Phi2, Gam2, Qbar = period_cost(float(omega0), float(h), float(damping_ratio))
    a = math.exp(-2.0 * math.pi * float(disturbance_hz) * float(h))
    # (e, ė/ω0, d, e_{k−1} … e_{k−delay}, and with the rate (ė/ω0)_{k−1} … (ė/ω0)_{k−delay})
    n = 3 + d * (2 if rate else 1)
    Phi, Gam = np.zeros((n, n)), np.zeros((n, 1))
    Phi[:2, :2], Phi[:2, 2], Gam[:2, 0] = Phi2, Gam2, Gam2
    Phi[2, 2] = a
    for j in range(d):
        Phi[3 + j, 0 if j == 0 else 3 + j - 1] = 1.0
        if rate:
            Phi[3 + d + j, 1 if j == 0 else 3 + d + j - 1] = 1.0
    W = np.zeros((n, n))
    W[2, 2] = (1.0 - a * a) * float(disturbance) ** 2
    C = np.zeros((2 if rate else 1, n))
    C[0, 0 if d == 0 else 3 + d - 1] = 1.0
    # a sensor with no noise: a noise far below the disturbance's (the filter's Riccati needs V > 0)
    floor = 1e-6 * float(disturbance)
    V = np.diag([max(float(noise), floor) ** 2] + ([max(float(rate_noise) / float(omega0), floor) ** 2]
                                                    if rate else []))
    if rate:
        C[1, 1 if d == 0 else 3 + 2 * d - 1] = 1.0  # ė/ω0, its noise scaled alike
    Mx, Mu = np.zeros((3, n)), np.zeros((3, 1))
    Mx[0, 0] = Mx[1, 1] = Mx[2, 2] = 1.0  # (e, ė/ω0, s = u + d)
    Mu[2, 0] = 1.0
    return Phi, Gam, W, C, V, Qbar, Mx, Mu


def command_column(Phi, omega0_h: float, h: float, damping_ratio: float = 0.0) -> np.ndarray:
    """The column by which a force held with the command (a disturbance d added to w over the
    period) enters the one-period map ``Phi`` of :func:`sensed_force_loop` (its first two rows)."""
    return _contact_rows(Phi.shape[0], omega0_h, np.zeros(Phi.shape[0]), 1.0, h, damping_ratio)[1]


def fit_force_disturbance(error, h: float, Phi, g_d, *, band=(0.5, 200.0), corners=None):
    """(D, f_d): the first-order Gauss–Markov force disturbance of :func:`force_error_bound` (RMS D
    in N, corner f_d in Hz) that reproduces a measured force error through a loop: ``error`` the
    samples of the TRUE force error at the period ``h`` of a run with an ideal sensor, ``Phi`` the
    loop's one-period map (:func:`sensed_force_loop` of the law that ran), ``g_d`` the
    disturbance's column (:func:`command_column`). For each corner on a grid (``corners``, Hz;
    default 0.01 to 400 Hz) the spectrum the loop predicts, |e₀ᵀ(zI − Φ)⁻¹g_d|² times the
    disturbance's, is fitted to the measured one (Welch) in log over ``band`` (Hz): the corner of
    least log misfit is taken, and D so that the loop's predicted RMS error equals the measured."""
    from scipy import signal
    from scipy.linalg import solve_discrete_lyapunov

    e = np.asarray(error, dtype=float)
    fs = 1.0 / float(h)
    f, P = signal.welch(e, fs=fs, nperseg=min(len(e), 2048), detrend=False)
    sel = (f >= band[0]) & (f <= band[1])
    f, P = f[sel], P[sel]
    n = Phi.shape[0]
    z = np.exp(2j * np.pi * f * h)
    T = np.array([np.linalg.solve(zk * np.eye(n) - Phi, g_d)[0] for zk in z])
    corners = np.geomspace(0.01, 400.0, 111) if corners is None else np.asarray(corners, dtype=float)
    best = None
    for fd in corners:
        a = math.exp(-2.0 * math.pi * fd * h)
        Sd = (1.0 - a * a) / np.abs(1.0 - a / z) ** 2  # unit variance
        r = np.log(P) - np.log(np.abs(T) ** 2 * Sd * 2.0 / fs)
        miss = float(np.var(r))
        if best is None or miss < best[0]:
            best = (miss, fd, a)
    _, fd, a = best
    # the loop with the disturbance's state: its predicted error variance per unit D²
    Pa = np.zeros((n + 1, n + 1))
    Pa[:n, :n], Pa[:n, n], Pa[n, n] = Phi, g_d, a
    Ga = np.zeros(n + 1)
    Ga[n] = math.sqrt(1.0 - a * a)
    X = solve_discrete_lyapunov(Pa, np.outer(Ga, Ga))
    D = math.sqrt(float(np.mean(e * e)) / X[0, 0])
    return D, float(fd)


__all__ = ["ForceFilter", "butterworth", "sensed_force_loop", "noise_gains", "command_rate", "loop_damping",
           "design_sensing", "SensingDesign", "max_command_rate", "predicted_torque_rate", "P99_GAUSS",
           "period_cost", "lqg_cost", "lqg_law", "force_error_bound", "bound_model",
           "command_column", "fit_force_disturbance"]
