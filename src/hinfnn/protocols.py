"""The seams of hinfnn: what the simulator asks of a plant and of a controller.

``sim/`` knows plants and controllers only through these protocols (a test checks its imports);
``controllers/`` and ``model/`` never import ``plant/`` (a controller never sees the truth). A
new plant (a physics engine) or a new controller is a class with these methods plus one registry
line (:mod:`hinfnn.scenario.registry`); nothing in ``sim/`` changes.

Everything that runs per time step is a pure JAX function of immutable pytrees, so that one
run and a ``vmap`` batch of ten thousand are the same program.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import jax

from ._pytree import pytree_dataclass


@pytree_dataclass
class Measurement:
    """What a controller measures (one sample).

    ``q``, ``qd``: joint angles (rad) and rates (rad/s), shape (n,); ``F``: the generalised
    contact force in TASK coordinates, shape (n,): the force the end-effector exerts on the
    surface, such that its joint torque is Jᵀ(q) F (J = ∂h/∂q, h the task coordinates). For the
    planar arm of the paper's Sec. VI the task coordinates are the end-effector's position, so F
    is the contact force vector in newtons.
    """

    q: jax.Array
    qd: jax.Array
    F: jax.Array


@runtime_checkable
class Plant(Protocol):
    """The truth: true arm and surface, contact, friction, disturbance (never seen by a controller).

    A *continuous* plant (``discrete = False``, the built-in one) is integrated with the
    controller by the simulator's RK4; a *discrete* one (a physics engine such as MuJoCo) advances
    itself by ``step`` and is driven through the sampled-data path (zero-order hold).
    """

    n: int           # number of joints
    discrete: bool   # a class attribute

    def initial_state(self, q0, qd0) -> Any:
        """The plant state (a pytree) at joint angles q0 and rates qd0."""

    def joints(self, state) -> tuple[jax.Array, jax.Array]:
        """(q, q̇) of a state."""

    def step_input(self, t, dt) -> jax.Array:
        """What the plant holds over the step [t, t + dt) (the joint disturbance at its midpoint)."""

    def sense(self, t, state) -> tuple[Measurement, Any]:
        """The controller's measurement and a cache of what the plant computed for it (reused by
        ``derivative`` and ``diagnostics`` at the same state)."""

    def diagnostics(self, state, w, cache) -> dict:
        """Recorded quantities of the truth: ``F``, ``normal_force``, ``penetration``,
        ``disturbance``, ``x_true`` (see :data:`hinfnn.sim.recorder.FIELDS` for units)."""

    # continuous plants
    def derivative(self, t, state, tau, w, cache) -> tuple[Any, jax.Array]:
        """(d state / dt, q̈) under torque τ and the held input w."""

    # discrete plants
    def step(self, t, state, tau, dt) -> tuple[Any, jax.Array]:
        """(state after dt with τ held, q̈ over the step)."""


@runtime_checkable
class Controller(Protocol):
    """A control law built from a NOMINAL model; it sees only :class:`Measurement` s.

    ``evaluate`` returns an output pytree with ``tau`` (n,), ``dstate`` (the state's time
    derivative, same structure as the state) and ``signals`` (a dict of named arrays, recorded by
    the simulator; their units are declared in :data:`hinfnn.sim.recorder.FIELDS`). ``sample`` is
    the zero-order-hold update of the sampled-data path (one definition, used by the simulator
    and by :class:`hinfnn.SampledController`).

    The theorem bookkeeping (the dissipation inequality of Theorems 1–2) needs four more
    methods, ``performance``, ``storage``, ``supply_residuals`` and ``u1_ddot``; a controller
    without them runs, with J, V and the supply not recorded.
    """

    n: int
    #: sizes of e_u1 and e_λ in ``signals`` (the motion and force coordinates; 1 if not given)
    m: int
    k: int

    def init(self) -> Any: ...

    def evaluate(self, t, state, measurement: Measurement, reference) -> Any: ...

    def sample(self, t, period, state, measurement: Measurement, reference) -> tuple[jax.Array, Any]: ...

    def constrain(self, state) -> Any: ...

    def to_loop(self, state) -> Any: ...

    def from_loop(self, state) -> Any: ...


__all__ = ["Measurement", "Plant", "Controller"]
