"""The contact force without a force sensor: a generalized-momentum observer on the NOMINAL arm.

A robot that measures q and q̇ and knows the torque it applied can estimate the external joint
torque from its momentum p = M(q) q̇ (De Luca and Mattone's observer; docs/robot.md, "The contact
force without a force sensor"). With M q̈ + C(q, q̇) q̇ + G(q) = τ + τ_ext and Ṁ = C + Cᵀ,
ṗ = τ + Cᵀq̇ − G + τ_ext, and the residual

    r(t) = K_O ( M̂(q) q̇ − p(0) − ∫₀ᵗ (τ + Ĉᵀ(q, q̇) q̇ − Ĝ(q) + r) ds )

obeys ṙ = K_O (τ_ext − r) when the nominal model (hats) is the truth: a first-order lag of time
constant 1/K_O behind τ_ext, with no acceleration and no force sensor needed. The tool's contact
force follows from τ_ext = J_pᵀ F_robot (F_robot the force the surface exerts on the tool at the tool
point): the force the tool exerts on the surface, as a force sensor would report it
(:class:`hinfnn.robot.Reading`), is F = −pinv(J_pᵀ) r.

A gravity-compensating robot (a Franka) adds G(q) to every torque itself: the net torque τ − G is
then exactly the torque hinfnn writes, and the observer is given that (``tau_net``). Anything the
nominal model lacks (a payload, joint friction, motor inertia) shows in r as an external torque.

The update runs once per control period on NumPy inputs, as one compiled JAX program
(:meth:`MomentumObserver.step`), with the nominal gravity torque Ĝ(q) it needs anyway returned
beside the force (the robot subtracts it from the law's torque).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import ConfigError


@dataclasses.dataclass
class ObserverState:
    """The observer's memory: ``p0`` (M̂ q̇ at the first sample), ``integral`` (∫ of the model's
    momentum rate and r up to the last sample), ``r`` (the residual), ``ctq`` (Ĉᵀq̇ at the last
    sample), ``started``."""

    p0: np.ndarray
    integral: np.ndarray
    r: np.ndarray
    ctq: np.ndarray
    started: bool = False


class MomentumObserver:
    """``MomentumObserver(arm, gain, armature=0)``: the generalized-momentum observer of module
    docstring on the nominal ``arm`` (a :class:`hinfnn.model.arm.Arm`: M, C, G and the tool point's
    Jacobian), ``gain`` K_O in 1/s (the residual's bandwidth; K_O h must stay below 1 at the sample
    period h), ``armature``: motors' reflected inertia per joint (kg·m², a number or one per
    joint) added to M̂'s diagonal beyond the nominal arm's own (a chain's ``armature``, the
    scenario's ``nominal.arm.armature``, is in ``arm.M`` already): the observer would read an
    inertia the model lacks, times q̈, as an external torque.

    ``init()`` gives the state; ``step(state, q, qd, tau_net, h)`` advances it to a new sample
    and returns ``(state, force, r, G)``: the estimated contact force the tool exerts (d,), the
    residual r ≈ τ_ext (n,) and Ĝ(q) (n,), all NumPy. ``tau_net``: the net torque applied since
    the previous sample, τ − G (for a gravity-compensating robot, the torque written to it).
    """

    def __init__(self, arm, gain: float = 100.0, armature=0.0):
        import jax
        import jax.numpy as jnp

        gain = float(gain)
        if not (np.isfinite(gain) and gain > 0):
            raise ConfigError(f"must be a finite number > 0 (1/s), got {gain!r}", key="observer_gain")
        self.arm, self.gain = arm, gain
        self.n = int(arm.n)
        self.d = int(arm.space_dim)
        a = np.broadcast_to(np.asarray(armature, dtype=float), (self.n,)).copy() if np.size(armature) in (1, self.n) \
            else None
        if a is None or not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ConfigError(f"must be a number or {self.n} numbers >= 0 (kg m^2), got {armature!r}", key="armature")
        self.armature = a

        def momentum_terms(q, qd):
            M = arm.M(q) + jnp.diag(a)  # the motors' reflected inertia (constant: Ṁ and Ĉ unchanged)
            ctq = arm.M_dot(q, qd) @ qd - arm.C_times(q, qd, qd)  # Ĉᵀq̇ = Ṁq̇ − Ĉq̇ (Ṁ = Ĉ + Ĉᵀ)
            return M @ qd, ctq, arm.G(q), arm.point_jacobian(q)

        def step(p0, integral, r, ctq_prev, q, qd, tau_net, h, first):
            """Implements the residual of the module docstring (De Luca's momentum observer),
            discretised by forward Euler: the integral advanced over the last period with the
            previous sample's terms, then r = K_O (M̂ q̇ − p0 − ∫)."""
            p, ctq, G, Jp = momentum_terms(q, qd)
            p0 = jnp.where(first, p, p0)
            integral = jnp.where(first, jnp.zeros_like(p), integral + h * (tau_net + ctq_prev + r))
            r = gain * (p - p0 - integral)
            # F = −pinv(J_pᵀ) r (J_p of full row rank): the force the tool exerts
            force = -jnp.linalg.solve(Jp @ Jp.T, Jp @ r)
            return p0, integral, r, ctq, force, G

        self._step = jax.jit(step)
        z = np.zeros(self.n)
        self._step(z, z, z, z, z, z, z, 1e-3, True)  # compiled here, never inside a loop

    def init(self) -> ObserverState:
        z = np.zeros(self.n)
        return ObserverState(p0=z, integral=z, r=z, ctq=z, started=False)

    def step(self, state: ObserverState, q, qd, tau_net, h: float):
        """Advance to the sample (q, q̇) taken ``h`` s after the previous one, ``tau_net`` applied in
        between (ignored at the first sample). Returns ``(state, force, r, G)``."""
        out = self._step(state.p0, state.integral, state.r, state.ctq, np.asarray(q, dtype=float),
                         np.asarray(qd, dtype=float), np.asarray(tau_net, dtype=float), float(h),
                         not state.started)
        p0, integral, r, ctq, force, G = (np.asarray(a) for a in out)
        return ObserverState(p0=p0, integral=integral, r=r, ctq=ctq, started=True), force, r, G


__all__ = ["ObserverState", "MomentumObserver"]
