"""The built-in true plant: rigid-body arm, penalty contact on the true surface, disturbance.

Paper eq. (1) with the TRUE parameters, ``M(q) q̈ + C(q, q̇) q̇ + G(q) + Jᵀ(q) F = τ + ω``, F the
force of a unilateral penalty contact on the TRUE surface
(:class:`~hinfnn.plant.contact.PenaltyContact`) with optional friction
(:class:`~hinfnn.plant.contact.Friction`), ω the joint disturbance
(:class:`~hinfnn.plant.disturbance.SquareWave`). A :class:`hinfnn.protocols.ContinuousPlant`: the
simulator integrates it with the controller (RK4), and only the measurements of
:meth:`RigidBodyPlant.sense` reach the controller: joint angles, rates and the contact force at
the tool point in the base frame, as a force/torque sensor at the tool gives it (the controller
maps it into its task coordinates with its NOMINAL kinematics).

Two kinds of true surface:

* a constraint in task coordinates (:class:`~hinfnn.model.surface.Surface`, e.g. the inclined
  line of Sec. VI, whose task coordinates are the tip position): penetration θ/‖∇θ‖ at h(q), the
  force F = f_n n in task coordinates (= the tip's Cartesian coordinates), joint torque JᵀF (the
  paper's arm, numbers unchanged);
* a Cartesian shape (:mod:`hinfnn.model.geometry`): the penetration is its EXACT signed distance
  at the tool point p (the arm's :meth:`~hinfnn.model.arm.Arm.point`, in its Cartesian space),
  the contact force F_c = f_n n + F_t (friction) acts at p, its joint torque is τ_c = J_pᵀ F_c,
  and the force sensor reads F_c.
"""

from __future__ import annotations

import functools
from typing import ClassVar

import jax
import jax.numpy as jnp

from .. import _linalg as la
from .._declared import setup_program
from .._pytree import pytree_dataclass
from ..model.geometry import Geometry
from ..protocols import ContinuousPlant, Measurement, PlantRecord
from .contact import Friction, PenaltyContact
from .disturbance import SquareWave
from .instruments import Actuator, Sensor
from .limits import limit_record


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
    F: jax.Array  # the contact force at the tool point (task coordinates = Cartesian for a task-space surface)
    normal_force: jax.Array
    penetration: jax.Array
    tau_c: jax.Array | None = None  # joint torque of the contact (Cartesian surfaces)
    friction: jax.Array | None = None  # its tangential part F_t (Cartesian surfaces)
    L_M: jax.Array | None = None  # Cholesky factor of the true M (Cartesian surfaces)


@pytree_dataclass
class RigidBodyPlant(ContinuousPlant):
    """True arm and surface (model types, true parameters), contact law and disturbance. A joint
    past its limit (a URDF chain's; :meth:`joint_limits`) stops the run
    (:attr:`~hinfnn.status.RunStatus.PLANT_FAULT`, the margin of that joint)."""

    fault_name: ClassVar[str] = "joint limit margin (rad or m, < 0: past the true arm's URDF limit)"

    arm: object
    surface: object
    contact: PenaltyContact
    disturbance: SquareWave
    friction: Friction | None = None
    sensor: Sensor | None = None  # the robot's sensor (None: ideal; hinfnn.plant.instruments)
    actuator: Actuator | None = None  # the robot's motors (None: ideal)
    kernels: la.Kernels = la.kernels_field()  # how its linear algebra is written (hinfnn._linalg.Kernels)

    @property
    def cartesian(self) -> bool:
        """True when the true surface is a Cartesian shape (contact at the tool point)."""
        return isinstance(self.surface, Geometry)

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
        """Sensors: joint angles, rates and the contact force at the tool point (exact, noise-free)."""
        if self.cartesian:
            return self._sense_cartesian(state)
        at = self.arm.terms(state.q, state.qd)  # the true arm's kinematics and dynamics, once
        F, f_n, p = self.contact_state(state.q, state.qd, at)
        return Measurement(q=state.q, qd=state.qd, force=F), ContactCache(terms=at, F=F, normal_force=f_n,
                                                                            penetration=p)

    def _sense_cartesian(self, state: JointState):
        at = self.arm.plant_terms(state.q, state.qd)  # x, J, M, C q̇ + G, tool point p and J_p
        p_dot = self.kernels.mm(at.J_p, state.qd)
        d, d_dot = jax.jvp(self.surface.signed_distance, (at.p,), (p_dot,))  # exact penetration
        n = self.surface.normal(at.p)
        f_n = self.contact.normal_force(d, d_dot)
        F_c = f_n * n
        F_t = jnp.zeros_like(F_c)
        if self.friction is not None:
            v_t = p_dot - self.kernels.mm(n, p_dot) * n
            F_t = self.friction.force(f_n, v_t)
            F_c = F_c + F_t
        tau_c = self.kernels.mm(at.J_p.T, F_c)
        L_M = self.kernels.chol(at.M)
        return (Measurement(q=state.q, qd=state.qd, force=F_c),
                ContactCache(terms=at, F=F_c, normal_force=f_n, penetration=d, tau_c=tau_c, friction=F_t, L_M=L_M))

    def derivative(self, t, state: JointState, tau, w, cache: ContactCache):
        """(q̇, q̈) and q̈ from eq. (1) with the TRUE parameters."""
        t_ = cache.terms
        if cache.tau_c is None:  # the paper's path, unchanged
            qdd = self.arm.forward_dynamics(state.q, state.qd, tau + w - self.kernels.mm(t_.J.T, cache.F), terms=t_)
        else:
            qdd = self.kernels.chol_solve(cache.L_M, tau + w - cache.tau_c - t_.bias)
        return JointState(q=state.qd, qd=qdd), qdd

    def record(self, state: JointState, w, cache: ContactCache) -> PlantRecord:
        out = {"q": state.q, "qd": state.qd, "normal_force": cache.normal_force, "disturbance": w,
               "x_true": cache.terms.x}
        if self.cartesian:
            out["F_contact"] = cache.F
            out["friction_force"] = jnp.sqrt(jnp.sum(cache.friction**2))
            out["task_margin"] = self.arm.task_margin(state.q)
        if hasattr(self.arm, "chain"):  # a chain has joint limits (±inf where none): the run stops past them
            lo, hi = self.joint_limits()
            return limit_record(cache.penetration, out, state.q, lo, hi)
        return PlantRecord(penetration=cache.penetration, signals=out)

    def fault_item(self, index: int) -> str:
        """The joint ``index`` by its name (the URDF's)."""
        names = getattr(getattr(self.arm, "chain", None), "joint_names", ()) or ()
        return f"joint {index + 1} ({names[index]})" if 0 <= index < len(names) else f"joint {index + 1}"

    def joint_limits(self):
        """(lower, upper) of the TRUE arm's joints (its URDF's; rad or m, ±inf where none)."""
        chain = getattr(self.arm, "chain", None)
        if chain is None:
            return jnp.full(self.n, -jnp.inf), jnp.full(self.n, jnp.inf)
        return chain.lower, chain.upper

    # --- contact and start pose ---------------------------------------------------------------------
    def contact_state(self, q, qd, terms=None):
        """(F, f_n, p): the force on the surface at the tool point (task coordinates for a
        task-space surface, Cartesian for a shape), normal force, penetration depth."""
        if self.cartesian:
            _, c = self._sense_cartesian(JointState(q=q, qd=qd))
            return c.F, c.normal_force, c.penetration
        t = terms if terms is not None else self.arm.terms(q, qd)
        x_dot = self.kernels.mm(t.J, qd)
        p, p_dot = jax.jvp(self.surface.signed_distance, (t.x,), (x_dot,))
        f_n = self.contact.normal_force(p, p_dot)
        n = self.surface.inward_normal(t.x)
        if self.friction is None:
            return f_n * n, f_n, p
        # task coordinates = the tip position here (Sec. VI): friction along the line
        return f_n * n + self.friction.force(f_n, x_dot - self.kernels.mm(n, x_dot) * n), f_n, p

    def diagnostics(self, state: JointState, w, cache: ContactCache) -> dict:
        """The recorded signals with the penetration, as one dict (:meth:`record`)."""
        r = self.record(state, w, cache)
        return {**r.signals, "penetration": r.penetration}

    def measure(self, q, qd) -> Measurement:
        """The measurement at (q, q̇) (:meth:`sense` without its cache)."""
        return self.sense(0.0, JointState(q=jnp.asarray(q, dtype=float), qd=jnp.asarray(qd, dtype=float)))[0]

    def initial_q(self, u1_0, elbow_up: bool = True, q_guess=None, within_limits: bool = True):
        """Joint angles with the TRUE end-effector at x1 = u1_0 on the TRUE surface, zero
        penetration (docs/paper-conventions.md, Initial state: elbow up, q2 < 0). One compiled
        program (a new process lowers each eager operation separately).

        Cartesian surfaces: the first n − 1 task coordinates of the TRUE arm equal ``u1_0`` and
        the tool point is on the true surface (signed distance 0), solved by damped Newton
        steps from ``q_guess`` (joint angles near the intended branch; default: the arm's
        zero pose), kept within the joint limits (:meth:`joint_limits`; ``within_limits=False``:
        not); NaN when that does not converge (out of reach, or another branch)."""
        if self.cartesian:
            u1 = jnp.atleast_1d(jnp.asarray(u1_0, dtype=float))
            guess = jnp.zeros(self.n) if q_guess is None else jnp.asarray(q_guess, dtype=float)
            lo, hi = self.joint_limits() if within_limits else (jnp.full(self.n, -jnp.inf), jnp.full(self.n, jnp.inf))
            return _initial_q_cartesian(self, u1, guess, lo, hi)
        return _initial_q(self, jnp.asarray(u1_0, dtype=float), bool(elbow_up))

    def effective_mass(self, q):
        """The true arm's effective mass along the surface's normal at q, 1 / (nᵀ J M⁻¹ Jᵀ n)
        (one compiled program): what a contact of stiffness k oscillates with, ω = √(k/m_eff)."""
        return _effective_mass(self, jnp.asarray(q, dtype=float))


@setup_program("effective_mass")
def _effective_mass(plant, q):
    if plant.cartesian:  # the tool point, its Jacobian and M alone (a URDF arm's by 3 × 3 products, UrdfChain.fk)
        arm = plant.arm
        Jn = plant.kernels.mm(arm.point_jacobian(q).T, plant.surface.normal(arm.point(q)))
        M = arm.M(q)
    else:
        t = plant.arm.terms(q, jnp.zeros_like(q))
        Jn = plant.kernels.mm(t.J.T, plant.surface.inward_normal(t.x))
        M = t.M
    return 1.0 / plant.kernels.mm(Jn, jnp.linalg.solve(M, Jn))


@setup_program("initial_q_cartesian")
def _initial_q_cartesian(plant, u1, q, lo, hi):
    """Damped Newton (Levenberg–Marquardt) on r(q) = (h(q)[:m] − u1, d(p(q))) = 0, projected onto
    the joint limits [lo, hi]: the guess is clipped into them, a joint at a limit that the step
    would push past it is held (its column dropped from that step), every iterate is clipped."""
    arm, surf = plant.arm, plant.surface
    m = u1.shape[0]

    def residual(q):
        return jnp.concatenate([arm.h(q)[:m] - u1, jnp.atleast_1d(surf.signed_distance(arm.point(q)))])

    def lm_step(Jr, r):
        A = Jr.T @ Jr + 1e-10 * jnp.eye(Jr.shape[1])
        return jnp.linalg.solve(A, Jr.T @ r)

    def body(_, q):
        r = residual(q)
        Jr = jax.jacfwd(residual)(q)
        step = lm_step(Jr, r)  # q − step
        held = ((q <= lo) & (step > 0)) | ((q >= hi) & (step < 0))
        step = jnp.where(held, 0.0, lm_step(jnp.where(held[None, :], 0.0, Jr), r))
        scale = jnp.minimum(1.0, 0.5 / jnp.maximum(jnp.max(jnp.abs(step)), 1e-300))  # ≤ 0.5 rad a step
        return jnp.clip(q - scale * step, lo, hi)

    q = jax.lax.fori_loop(0, 100, body, jnp.clip(q, lo, hi))
    ok = jnp.max(jnp.abs(residual(q))) < 1e-10
    return jnp.where(ok, q, jnp.nan)


@functools.partial(jax.jit, static_argnames="elbow_up")
def _initial_q(plant, u1_0, elbow_up):
    x1 = jnp.atleast_1d(u1_0)
    x = jnp.concatenate([x1, plant.surface.Omega(x1)])
    if hasattr(plant.arm, "inverse_kinematics_closed"):
        return plant.arm.inverse_kinematics_closed(x, elbow_up=elbow_up)
    guess = jnp.full(plant.arm.n, 0.3) * (1.0 if elbow_up else -1.0)
    return plant.arm.inverse_kinematics(x, guess)
