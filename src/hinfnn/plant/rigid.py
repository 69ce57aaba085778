"""The built-in true plant: rigid-body arm, penalty contact on the true surface, disturbance.

Paper eq. (1) with the TRUE parameters, ``M(q) q̈ + C(q, q̇) q̇ + G(q) + Jᵀ(q) F = τ + ω``, F the
force of a frictionless unilateral penalty contact on the TRUE surface
(:class:`~hinfnn.plant.contact.PenaltyContact`), ω the joint disturbance
(:class:`~hinfnn.plant.disturbance.SquareWave`). A continuous plant in the sense of
:class:`hinfnn.protocols.Plant`: the simulator integrates it with the controller (RK4), and
only the measurements of :meth:`RigidBodyPlant.sense` reach the controller.
"""

from __future__ import annotations

import functools
from typing import ClassVar

import jax
import jax.numpy as jnp

from .. import _linalg as la
from .._pytree import pytree_dataclass
from ..protocols import Measurement
from .contact import PenaltyContact
from .disturbance import SquareWave


@pytree_dataclass
class JointState:
    """The state of a rigid-body plant: joint angles and rates."""

    q: jax.Array
    qd: jax.Array


@pytree_dataclass
class ContactCache:
    """What :meth:`RigidBodyPlant.sense` computes at one state, reused by ``derivative`` and
    ``diagnostics``: the true arm's terms, the contact force F, normal force and penetration."""

    terms: object
    F: jax.Array
    normal_force: jax.Array
    penetration: jax.Array


@pytree_dataclass
class RigidBodyPlant:
    """True arm and surface (model types, true parameters), contact law and disturbance."""

    arm: object
    surface: object
    contact: PenaltyContact
    disturbance: SquareWave
    discrete: ClassVar[bool] = False

    @property
    def n(self) -> int:
        return int(self.arm.n)

    # --- the protocol ------------------------------------------------------------------------------
    def initial_state(self, q0, qd0=None) -> JointState:
        q0 = jnp.asarray(q0, dtype=float)
        return JointState(q=q0, qd=jnp.zeros_like(q0) if qd0 is None else jnp.asarray(qd0, dtype=float))

    def joints(self, state: JointState):
        return state.q, state.qd

    def step_input(self, t, dt):
        """The disturbance held over [t, t + dt): its value at the midpoint (steps land on its
        switches when dt divides them; the scenario loader checks)."""
        return self.disturbance(t + 0.5 * dt)

    def sense(self, t, state: JointState):
        """Sensors: joint angles, rates and the force sensor's F (exact, noise-free)."""
        at = self.arm.terms(state.q, state.qd)  # the true arm's kinematics and dynamics, once
        F, f_n, p = self.contact_state(state.q, state.qd, at)
        return Measurement(q=state.q, qd=state.qd, F=F), ContactCache(terms=at, F=F, normal_force=f_n, penetration=p)

    def derivative(self, t, state: JointState, tau, w, cache: ContactCache):
        """(q̇, q̈) and q̈ from eq. (1) with the TRUE parameters."""
        t_ = cache.terms
        qdd = self.arm.forward_dynamics(state.q, state.qd, tau + w - la.mm(t_.J.T, cache.F), terms=t_)
        return JointState(q=state.qd, qd=qdd), qdd

    def diagnostics(self, state: JointState, w, cache: ContactCache) -> dict:
        return {"q": state.q, "qd": state.qd, "F": cache.F, "normal_force": cache.normal_force,
                "penetration": cache.penetration, "disturbance": w, "x_true": cache.terms.x}

    # --- contact and start pose ---------------------------------------------------------------------
    def contact_state(self, q, qd, terms=None):
        """(F, f_n, p): force vector on the surface, normal force, penetration depth."""
        t = terms if terms is not None else self.arm.terms(q, qd)
        x_dot = la.mm(t.J, qd)
        p, p_dot = jax.jvp(self.surface.signed_distance, (t.x,), (x_dot,))
        f_n = self.contact.normal_force(p, p_dot)
        return f_n * self.surface.inward_normal(t.x), f_n, p

    def measure(self, q, qd) -> Measurement:
        """The measurement at (q, q̇) (:meth:`sense` without its cache)."""
        return self.sense(0.0, JointState(q=jnp.asarray(q, dtype=float), qd=jnp.asarray(qd, dtype=float)))[0]

    def initial_q(self, u1_0, elbow_up: bool = True):
        """Joint angles with the TRUE end-effector at x1 = u1_0 on the TRUE surface, zero
        penetration (docs/paper-conventions.md, Initial state: elbow up, q2 < 0). One compiled
        program (a new process lowers each eager operation separately, about 5 ms apiece)."""
        return _initial_q(self, jnp.asarray(u1_0, dtype=float), bool(elbow_up))

    def effective_mass(self, q):
        """The true arm's effective mass along the surface's normal at q, 1 / (nᵀ J M⁻¹ Jᵀ n)
        (one compiled program): what a contact of stiffness k oscillates with, ω = √(k/m_eff)."""
        return _effective_mass(self, jnp.asarray(q, dtype=float))


@jax.jit
def _effective_mass(plant, q):
    t = plant.arm.terms(q, jnp.zeros_like(q))
    n = plant.surface.inward_normal(t.x)
    Jn = la.mm(t.J.T, n)
    return 1.0 / la.mm(Jn, jnp.linalg.solve(t.M, Jn))


@functools.partial(jax.jit, static_argnames="elbow_up")
def _initial_q(plant, u1_0, elbow_up):
    x1 = jnp.atleast_1d(u1_0)
    x = jnp.concatenate([x1, plant.surface.Omega(x1)])
    if hasattr(plant.arm, "inverse_kinematics_closed"):
        return plant.arm.inverse_kinematics_closed(x, elbow_up=elbow_up)
    guess = jnp.full(plant.arm.n, 0.3) * (1.0 if elbow_up else -1.0)
    return plant.arm.inverse_kinematics(x, guess)
