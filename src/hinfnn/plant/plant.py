"""The truth: true arm, true surface with penalty contact, joint disturbance, sensors.

Only the simulator holds a :class:`Plant`; controllers receive what :meth:`Plant.measure`
returns (q, q̇ and the contact force vector F), never the plant itself.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from .. import _linalg as la
from .._pytree import pytree_dataclass
from ..measurement import Measurement
from .contact import PenaltyContact
from .disturbance import SquareWave


@pytree_dataclass
class Plant:
    """True arm and surface (model types, true parameters), contact law and disturbance."""

    arm: object
    surface: object
    contact: PenaltyContact
    disturbance: SquareWave

    def contact_state(self, q, qd, terms=None):
        """(F, f_n, p): force vector on the surface, normal force, penetration depth."""
        t = terms if terms is not None else self.arm.terms(q, qd)
        x = t.x
        x_dot = la.mm(t.J, qd)
        p, p_dot = jax.jvp(self.surface.signed_distance, (x,), (x_dot,))
        f_n = self.contact.normal_force(p, p_dot)
        return f_n * self.surface.inward_normal(x), f_n, p

    def measure(self, q, qd) -> Measurement:
        """Sensors: joint angles, joint rates and the force sensor's F (exact, noise-free)."""
        F, _, _ = self.contact_state(q, qd)
        return Measurement(q=q, qd=qd, F=F)

    def acceleration(self, q, qd, tau, w, F=None, terms=None):
        """q̈ from eq. (1): M q̈ + C q̇ + G + Jᵀ F = τ + ω with the TRUE parameters."""
        t = terms if terms is not None else self.arm.terms(q, qd)
        if F is None:
            F = self.contact_state(q, qd, t)[0]
        return self.arm.forward_dynamics(q, qd, tau + w - la.mm(t.J.T, F), terms=t)

    def initial_q(self, u1_0, elbow_up: bool = True):
        """Joint angles with the TRUE end-effector at x1 = u1_0 on the TRUE surface, zero
        penetration (NOTES.md, Initial state: elbow up, q2 < 0). One compiled program (not a
        dozen eager operations: a new process lowers each of them, about 5 ms apiece)."""
        return _initial_q(self, jnp.asarray(u1_0, dtype=float), bool(elbow_up))


    def contact_terms(self, q):
        """J(q), M(q) of the true arm and the surface's inward normal at h(q), for design-time
        checks (one compiled program)."""
        return _contact_terms(self, jnp.asarray(q, dtype=float))


@jax.jit
def _contact_terms(plant, q):
    t = plant.arm.terms(q, jnp.zeros_like(q))
    return t.J, t.M, plant.surface.inward_normal(t.x)


@functools.partial(jax.jit, static_argnames="elbow_up")
def _initial_q(plant, u1_0, elbow_up):
    x1 = jnp.atleast_1d(u1_0)
    x = jnp.concatenate([x1, plant.surface.Omega(x1)])
    if hasattr(plant.arm, "inverse_kinematics_closed"):
        return plant.arm.inverse_kinematics_closed(x, elbow_up=elbow_up)
    guess = jnp.full(plant.arm.n, 0.3) * (1.0 if elbow_up else -1.0)
    return plant.arm.inverse_kinematics(x, guess)


__all__ = ["Plant", "PenaltyContact", "SquareWave"]
