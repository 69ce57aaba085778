"""The seams of hinfnn: what the simulator asks of a plant and of a controller, and nothing more.

These abstract base classes are the whole contract (diffrax's ``AbstractSolver`` habit): the
simulator calls only the methods declared here and reads no field of a plant's or a controller's
state. A plant is a :class:`ContinuousPlant` (integrated with the controller by the simulator's
RK4) or a :class:`DiscretePlant` (a physics engine that advances itself); a controller is a
:class:`Controller`, and one that also does the theorem bookkeeping of Theorems 1–2 declares the
:class:`Dissipative` capability. :func:`check` verifies both once, before anything is traced.

``sim/`` knows plants and controllers only through this module; ``controllers/`` and ``model/``
never import ``plant/`` (a controller never sees the truth). A new plant or controller family is a
subclass plus one registry line (:mod:`hinfnn.scenario.registry`, :mod:`hinfnn.controllers.kinds`);
``tests/test_seams.py`` adds a toy of each from the test file alone.

Everything that runs per time step is a pure JAX function of immutable pytrees (subclasses are
:func:`hinfnn._pytree.pytree_dataclass` es), so one run and a ``vmap`` batch of ten thousand are
the same program.
"""

from __future__ import annotations

import abc
import dataclasses
import typing
from typing import Any, ClassVar

import jax
import jax.numpy as jnp

from ._pytree import pytree_dataclass


@pytree_dataclass
class Measurement:
    """What a controller measures at one sample, as a robot's sensors give it.

    ``q``, ``qd``: joint angles (rad; m for prismatic joints) and rates, shape (n,).
    ``force``: the contact force the tool exerts on the surface, at the tool point, in the base
    frame's Cartesian axes of the arm (2 components for a planar arm, in the plane's coordinates;
    3 for a spatial one), in N: what a force/torque sensor at the tool gives once moved to the tool
    point and turned into the base frame. A point contact has no moment about the tool point, so
    this is the whole wrench there. The controller maps it into its own task coordinates with its
    NOMINAL kinematics (:func:`hinfnn.controllers.law.measured_force`).
    """

    q: jax.Array
    qd: jax.Array
    force: jax.Array


@pytree_dataclass
class PlantRecord:
    """What the plant records at one instant: the penetration of the true surface (m, < 0: the
    tool is above it; the recorder's contact bookkeeping needs it), a fault flag that stops the run
    (:attr:`hinfnn.status.RunStatus.PLANT_FAULT`, e.g. a joint past its limit) with the measure
    that decided it and the item it is of (``fault_index``: a joint, numbered from 0; -1: none),
    and any further named signals (units in :data:`hinfnn.fields.FIELDS`)."""

    penetration: jax.Array
    signals: dict
    fault: jax.Array = False
    fault_value: jax.Array = jnp.nan
    fault_index: jax.Array = -1


class Plant(abc.ABC):
    """The truth: true arm and surface, contact, friction, disturbance (never seen by a controller).

    Subclasses set ``n`` (number of joints, a static int) and implement the abstract methods;
    ``fault_name`` names the measure of :attr:`PlantRecord.fault_value` in failure messages and
    :meth:`fault_item` the item of :attr:`PlantRecord.fault_index`.
    Use :class:`ContinuousPlant` or :class:`DiscretePlant`.
    """

    discrete: ClassVar[bool]
    fault_name: ClassVar[str] = "plant fault measure"
    #: The robot's sensor between the truth and the controller (None: ideal, the measurement is
    #: :meth:`sense`'s). A plant that has one sets it (:class:`hinfnn.plant.instruments.Sensor`):
    #: the simulator gives its state ``start(measurement at t = 0)`` and at each control sample k
    #: of period T asks ``read(k, T, true measurement, state) -> (measurement, state)``.
    sensor: ClassVar = None
    #: The robot's motors (None: ideal, τ applied as commanded). A plant that has one sets it
    #: (:class:`hinfnn.plant.instruments.Actuator`): the plant is driven by the applied torque,
    #: ``apply(τ, previous, T, first)`` at each sample (``saturate(τ)`` under continuous control,
    #: where ``rate_limited`` must be False), less ``friction(q̇)``; ``saturated(applied)`` is
    #: recorded.
    actuator: ClassVar = None

    def fault_item(self, index: int) -> str:
        """The name of item ``index`` of a fault (:attr:`PlantRecord.fault_index`) in messages."""
        return f"item {index}"

    def with_sensor(self, sensor) -> "Plant":
        """The same plant with another :attr:`sensor` (a batch member's own noise stream)."""
        return dataclasses.replace(self, sensor=sensor)

    @abc.abstractmethod
    def initial_state(self, q0, qd0=None) -> Any:
        """The plant state (a pytree) at joint angles q0 and rates qd0 (default 0)."""

    @abc.abstractmethod
    def initial_q(self, u1_0, **options):
        """Joint angles with the TRUE tool at motion coordinate(s) ``u1_0`` on the TRUE surface
        (NaN when out of reach); ``options`` are the plant's own (a branch, a guess)."""

    @abc.abstractmethod
    def joints(self, state) -> tuple[jax.Array, jax.Array]:
        """(q, q̇) of a state."""

    @abc.abstractmethod
    def step_input(self, t, dt) -> jax.Array:
        """What the plant holds over the step [t, t + dt) (the joint disturbance at its midpoint)."""

    @abc.abstractmethod
    def sense(self, t, state) -> tuple[Measurement, Any]:
        """The controller's :class:`Measurement` and a cache of what the plant computed for it
        (reused by ``derivative`` and ``record`` at the same state)."""

    @abc.abstractmethod
    def record(self, state, w, cache) -> PlantRecord:
        """What is recorded of the truth at this state (``w``: the held input)."""


class ContinuousPlant(Plant):
    """A plant integrated with the controller by the simulator's RK4 (the built-in one)."""

    discrete: ClassVar[bool] = False

    @abc.abstractmethod
    def derivative(self, t, state, tau, w, cache) -> tuple[Any, jax.Array]:
        """(d state / dt, q̈) under torque τ and the held input w."""


class DiscretePlant(Plant):
    """A plant that advances itself (a physics engine such as MuJoCo), driven through the
    sampled-data path: the torque is held over each of its steps."""

    discrete: ClassVar[bool] = True

    @abc.abstractmethod
    def step(self, t, state, tau, dt) -> tuple[Any, jax.Array]:
        """(state after dt with τ held, q̈ over the step)."""


@pytree_dataclass
class ControllerOutput:
    """One evaluation of a controller.

    ``tau`` (n,): the joint torque; ``dstate``: the time derivative of the controller state (same
    structure); ``e_u1`` (m,) and ``e_lam`` (k,): the motion and force errors (the recorder's
    metrics are built on them); ``signals``: further named signals to record (units in
    :data:`hinfnn.fields.FIELDS`); ``fault``: True when the law cannot be trusted at this sample
    (the simulator stops the run with :attr:`~hinfnn.status.RunStatus.CONTROLLER_FAULT`, the
    sampled controller returns NaN), with the measure that decided it (NaN: the measure is
    computed once, where the run stopped, by :meth:`PerSample.fault_measure`); ``deferred``:
    what :meth:`PerSample.deferred_fields` computes recorded fields from, once per stored sample
    rather than at every stage (None: nothing); ``aux``: whatever the controller's own bookkeeping
    needs of this evaluation (opaque to the simulator).
    """

    tau: jax.Array
    dstate: Any
    e_u1: jax.Array
    e_lam: jax.Array
    signals: dict
    fault: jax.Array = False
    fault_value: jax.Array = jnp.nan
    deferred: Any = None
    aux: Any = None


class Controller(abc.ABC):
    """A control law built from a NOMINAL model; it sees only :class:`Measurement` s.

    Subclasses set ``n`` (joints), ``m`` (size of e_u1) and ``k`` (size of e_λ) as ints, ``kind``
    (the name results file it under), and implement :meth:`init` and :meth:`evaluate`; the other
    five methods have defaults. The state is any pytree, in whatever layout the controller computes
    fastest with: the simulator carries it opaquely and asks :meth:`state_arrays` for the named
    arrays a result keeps. What a controller may add is declared as a capability, each checked in
    one place (the functions below): :class:`Constrained`, :class:`Starting`, :class:`Prepared`,
    :class:`PerSample` and :class:`Dissipative`.
    """

    kind: str = ""
    fault_name: ClassVar[str] = "controller fault measure"

    @abc.abstractmethod
    def init(self) -> Any:
        """The controller state at t = 0."""

    @abc.abstractmethod
    def evaluate(self, t, state, measurement: Measurement, reference) -> ControllerOutput:
        """τ, the state derivative and the signals at one instant (``reference`` is callable on t)."""

    def sample(self, t, period, state, measurement: Measurement, reference, out: ControllerOutput | None = None):
        """The zero-order-hold update of the sampled-data path: (τ at the sample, the state
        advanced by forward Euler over ``period`` and constrained, :func:`constrain`). One
        definition, used by the simulator and by :class:`hinfnn.SampledController` (``out``: this
        sample's :meth:`evaluate`, when the caller has it)."""
        out = self.evaluate(t, state, measurement, reference) if out is None else out
        return out.tau, constrain(self, jax.tree.map(lambda x, d: x + period * d, state, out.dstate))

    def start(self, t, state, measurement: Measurement, reference):
        """The state at the first sample, from the first measurement (identity; a controller whose
        start changes the state declares it, :class:`Starting`)."""
        return state

    def check_start(self, q0) -> None:
        """Design-time check of the start pose (raise :class:`~hinfnn.errors.DesignError`)."""

    def summary(self) -> dict:
        """The designed controller as plain numbers (``metrics.json``, ``hinfnn show`` and
        ``hinfnn design``). Default: its kind."""
        return {"kind": self.kind}

    def state_arrays(self, state) -> dict:
        """The state's arrays by name, flat (what a result keeps of the final state). Default:
        every leaf, named by its path in the pytree."""
        leaves = jax.tree_util.tree_flatten_with_path(state)[0]
        return {_path_name(path): leaf for path, leaf in leaves}


@typing.runtime_checkable
class Constrained(typing.Protocol):
    """The capability of a controller whose state is put back where the theory keeps it after an
    integration step (e.g. Remark 2's projection of the weights onto their ball)."""

    def constrain(self, state):
        """The state after the step, constrained."""


@typing.runtime_checkable
class Starting(typing.Protocol):
    """The capability of a controller whose :meth:`Controller.start` changes the state (a filter
    that starts at its first input): ``needs_start`` says whether it does, for this design."""

    @property
    def needs_start(self) -> bool:
        """Whether :meth:`Controller.start` changes the state."""


@typing.runtime_checkable
class Prepared(typing.Protocol):
    """The capability of a controller held by the compiled loop in another form, made once outside
    the loop (its constant matrices also held by the blocks the law reads; the same numbers): the
    only layout hook of the seam."""

    def prepared(self):
        """This controller as the compiled loop holds it."""


@typing.runtime_checkable
class PerSample(typing.Protocol):
    """The capability of a controller that computes some recorded fields once per stored sample
    rather than at every RK4 stage, and the measure of the fault that stopped a run once, where it
    stopped (its loop deciding the fault by a cheaper test)."""

    def deferred_fields(self, deferred) -> dict:
        """Recorded fields from :attr:`ControllerOutput.deferred`, once per stored sample."""

    def fault_measure(self, t, state, measurement: Measurement, reference, value):
        """The measure of the fault at the state where the run stopped, given the
        :attr:`ControllerOutput.fault_value` the loop recorded there (``value``)."""


def constrain(controller, state):
    """``controller.constrain(state)`` for a :class:`Constrained` controller; else ``state``."""
    return controller.constrain(state) if isinstance(controller, Constrained) else state


def needs_start(controller) -> bool:
    """Whether ``controller``'s start changes its state (:class:`Starting`; else False)."""
    return bool(controller.needs_start) if isinstance(controller, Starting) else False


def prepared(controller):
    """``controller`` as the compiled loop holds it (:class:`Prepared`; else itself)."""
    return controller.prepared() if isinstance(controller, Prepared) else controller


def deferred_fields(controller, deferred) -> dict:
    """The fields ``controller`` computes once per stored sample (:class:`PerSample`; else none)."""
    return controller.deferred_fields(deferred) if isinstance(controller, PerSample) else {}


def fault_measure(controller, t, state, measurement: Measurement, reference, value):
    """The measure of the fault that stopped a run (:class:`PerSample`; else the loop's ``value``)."""
    if isinstance(controller, PerSample):
        return controller.fault_measure(t, state, measurement, reference, value)
    return value


@pytree_dataclass
class Dissipation:
    """The theorem bookkeeping at one instant (Theorems 1–2): the integrand ``j`` of the H∞ index
    (eq. 34) and ``j_extra`` (Remark 1's and the terms' additions), the supply rate
    ρ²(‖f_p‖² + ‖f_f‖²), the storage ``V`` and the residuals ``f_p``, ``f_f``."""

    j: jax.Array
    j_extra: jax.Array
    supply: jax.Array
    V: jax.Array
    f_p: jax.Array
    f_f: jax.Array


class Dissipative(abc.ABC):
    """The capability of a controller whose runs check the dissipation inequality
    J(T) + V(T) − V(0) ≤ ∫ supply (the simulator integrates J and the supply with the state)."""

    @abc.abstractmethod
    def dissipation(self, state, out: ControllerOutput, qd, qdd) -> Dissipation:
        """The bookkeeping at one instant, given the true joint acceleration q̈ (from the plant,
        like an accelerometer)."""


def _path_name(path) -> str:
    parts = []
    for p in path:
        key = getattr(p, "key", getattr(p, "name", getattr(p, "idx", None)))
        parts.append(str(key))
    return ".".join(parts) or "state"


def check(plant, controller) -> None:
    """Verify once, before anything is traced, that ``plant`` and ``controller`` implement the
    protocols (a TypeError saying what is missing otherwise)."""
    if not isinstance(plant, (ContinuousPlant, DiscretePlant)):
        raise TypeError(f"the plant must be a hinfnn.protocols.ContinuousPlant or DiscretePlant, got "
                        f"{type(plant).__name__}")
    if not isinstance(controller, Controller):
        raise TypeError(f"the controller must be a hinfnn.protocols.Controller, got {type(controller).__name__}")
    for who, obj, names in (("plant", plant, ("n",)), ("controller", controller, ("n", "m", "k"))):
        for name in names:
            if not isinstance(getattr(obj, name, None), int):
                raise TypeError(f"the {who} {type(obj).__name__} must give {name} as an int")
    if controller.n != plant.n:
        raise TypeError(f"the controller is for {controller.n} joints, the plant has {plant.n}")


__all__ = ["Measurement", "PlantRecord", "Plant", "ContinuousPlant", "DiscretePlant", "ControllerOutput",
           "Controller", "Constrained", "Starting", "Prepared", "PerSample", "Dissipation", "Dissipative", "check",
           "constrain", "needs_start", "prepared", "deferred_fields", "fault_measure"]
