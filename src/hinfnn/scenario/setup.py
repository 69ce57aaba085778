"""A scenario's objects, built once: :meth:`hinfnn.scenario.Scenario.build` returns a :class:`Setup`.

Each object is built the first time it is asked for and kept (the scenario checks ask for them in
the order their messages need, so a bad value is named by the check that reads it first): the task
map, the true plant, the nominal arm and the controller's constraint, the reference, the start pose,
the designed controllers by kind, the simulation options and the names of the coordinates and
joints. Designed controllers are also kept per process by everything their design reads (the
nominal arm and constraint by value, the controller section, the control period, the reference's
span and the start pose), so the draws of a sweep that vary only the truth design each controller
once.
"""

from __future__ import annotations

import collections
import functools
import math

import numpy as np

from ..errors import ConfigError


class Setup:
    """The objects of one scenario (read-only; each built once, on first use)."""

    def __init__(self, scenario):
        self.scenario = scenario
        self._controllers: dict = {}

    # --- the models -----------------------------------------------------------------------------
    @functools.cached_property
    def task(self):
        """The task map (:mod:`hinfnn.model.taskmap`) both arms are built with; None for the arm's
        native coordinates (the two_link arm of Sec. VI)."""
        sc = self.scenario
        if not sc.nominal.arm.task_maps and sc.task.map != "native":
            raise ConfigError(f"the {sc.nominal.arm.model!r} arm has only its native task coordinates (the tip "
                              "position); use arm model \"planar\" or \"urdf\" for other coordinates", key="task.map")
        geometry = sc.nominal.surface.build() if sc.task.fitted else None
        base = sc.task.build(sc.nominal.arm, geometry)
        if not sc.task.extra:
            return base
        from ..model.augmented import AugmentedTask

        if base is None:
            base = sc.nominal.arm.native_task()
        if base is None:
            sc.task.extra_coordinates(None)  # the two_link arm: a ConfigError
        return AugmentedTask(base=base, extra=sc.task.extra_coordinates(sc.nominal.arm.joint_chain("nominal.arm")))

    @functools.cached_property
    def plant(self):
        """The true plant (``plant.engine`` chooses the class)."""
        from ..sim.simulate import check_instruments

        sc = self.scenario
        plant = sc.plant.build(task=self.task, dt=sc.simulation.dt, control_period=self.control_period)
        check_instruments(plant, self.control_period is not None)  # a sensor needs control samples
        return plant

    @functools.cached_property
    def nominal_arm(self):
        return self.scenario.nominal.arm.build(self.task, key="nominal.arm")

    @functools.cached_property
    def nominal_surface(self):
        """The nominal surface as its kind builds it: a task-space constraint or a Cartesian shape."""
        return self.scenario.nominal.surface.build()

    @functools.cached_property
    def constraint(self):
        """The controller's constraint θ̂(x) in task coordinates: the nominal surface itself for a
        task-space kind; for a Cartesian shape, θ̂ = d in fitted coordinates
        (:class:`~hinfnn.model.surface.FittedConstraint`) or θ̂(x) = θ(point(x))
        (:class:`~hinfnn.model.surface.TaskConstraint`), with m = n − 1 and k = 1."""
        from ..model.geometry import Geometry
        from ..model.surface import FittedConstraint, TaskConstraint

        sc = self.scenario
        surface = self.nominal_surface
        if not isinstance(surface, Geometry):
            return surface
        m = self.nominal_arm.n - 1
        if sc.task.fitted:
            return FittedConstraint(m=m, k=1)
        task = self.task if sc.task.map != "native" else sc.nominal.arm.native_task()
        if task is None:
            raise ConfigError(f"a {sc.nominal.surface.kind!r} surface needs task coordinates that contain the tool "
                              "point: set task.map", key="task.map")
        return TaskConstraint(geometry=surface, task=task, m=m, k=1)

    @functools.cached_property
    def reference(self):
        """The reference for the constraint's m motion and k force coordinates. With extra task
        coordinates (``task.extra``) whose reference the lists do not give (numbers, or lists of
        m − e), those hold their start values (:attr:`extra_start`)."""
        c = self.constraint
        ref = self.scenario.reference
        e = len(self.scenario.task.extra)
        if e and ref.sizes()[0] != c.m:
            built = ref.build(m=c.m - e, k=c.k)
            if not hasattr(built, "holding"):
                raise ConfigError(f"a {ref.kind!r} reference cannot hold the {e} extra task coordinates (task.extra) "
                                  f"at their start values: give all {c.m} motion coordinates", key="reference.kind")
            return built.holding(self.extra_start)
        return ref.build(m=c.m, k=c.k)

    @functools.cached_property
    def extra_start(self):
        """The extra task coordinates' values at the start pose (the nominal arm's h at the true
        start pose q0): what their default reference holds. None without extra coordinates."""
        e = len(self.scenario.task.extra)
        if not e:
            return None
        m = self.nominal_arm.n - 1
        return np.asarray(self.nominal_arm.h(self.q0))[m - e:m]

    @functools.cached_property
    def q0(self) -> np.ndarray:
        """The start pose: the TRUE arm's tool at u1(0) on the TRUE surface (NaN when not found)."""
        return self.start_pose(self.plant)

    @functools.cached_property
    def start_q(self) -> np.ndarray:
        """Where the truth starts: :attr:`q0` (on the true surface) for ``job.start = "contact"``;
        for ``"approach"`` the joint angles with the NOMINAL tool ``job.approach_height`` above the
        NOMINAL surface along its normal, at the motion coordinates of :attr:`q0`
        (:func:`hinfnn.controllers.job.approach_pose`, compiled: :data:`hinfnn.compiled.approach_pose`): where the robot believes the part is."""
        job = self.scenario.job
        if not job.approach:
            return self.q0
        from ..compiled import approach_pose

        q, residual = approach_pose(self.nominal_arm, self.constraint, np.asarray(self.q0, dtype=float),
                                    float(job.approach_height))
        q = np.asarray(q)
        if not (np.all(np.isfinite(q)) and float(residual) < 1e-9):
            raise ConfigError(f"the approach's start pose, {job.approach_height:g} m above the nominal surface at "
                              f"initial.u1 = {self.scenario.initial.u1}, is out of the nominal arm's reach (residual "
                              f"{float(residual):.3g})", key="job.approach_height")
        return q

    def start_pose(self, plant) -> np.ndarray:
        """The start pose of ``initial`` on ``plant`` (the scenario's own plant: :attr:`q0`)."""
        init = self.scenario.initial
        if getattr(plant, "cartesian", False):
            q = plant.initial_q(init.u1, elbow_up=init.elbow == "up", q_guess=init.q_guess or None)
        else:
            q = plant.initial_q(init.u1, elbow_up=init.elbow == "up")
        return np.asarray(q)

    # --- the controllers ------------------------------------------------------------------------
    def controller(self, kind: str | None = None):
        """The controller ``kind`` (default: the scenario's only kind), designed from the NOMINAL
        model (:class:`~hinfnn.errors.DesignError` with the dotted key of what failed)."""
        kind = kind or only(self.scenario.kinds)
        if kind not in self._controllers:
            law = _DESIGNS.get(self._design_key(kind), lambda: self._design(kind))
            self._controllers[kind] = self._job(law)
        return self._controllers[kind]

    def _job(self, law):
        """``law`` in the phases of ``[job]`` (:class:`~hinfnn.controllers.job.JobController`) when
        the job starts with an approach; the law itself otherwise (the paper's start in contact)."""
        sc = self.scenario
        job = sc.job
        if not job.approach:
            return law
        if self.control_period is None:
            raise ConfigError("a job with an approach runs under sampled control (its phases switch at samples): set "
                              "simulation.control = \"sampled\", or job.start = \"contact\"", key="job.start")
        noise = sc.controller.sensor.resolved(self.declared_sensor)[0]
        job.check_sensor(sc.plant.sensor, noise)
        from ..controllers.job import JobController, job_params

        return JobController(law=law, job=job_params(job, job.contact_threshold(noise)), kind=law.kind)

    def _design_inputs(self):
        """(u1_path, q_start): the reference's path and the start pose the force-rate rule reads
        (:func:`~hinfnn.scenario.checks.design_path`), or (None, None) without the term."""
        if self.scenario.controller.force_rate.kappa == 0.0:
            return None, None
        if "_path" not in self.__dict__:
            from .checks import design_path

            self._path = design_path(self.scenario)
        return self._path, self.q0

    def _design_key(self, kind: str):
        """Everything the design reads: the nominal arm and constraint (by value), the controller
        section, the control period, and for the force-rate rule the reference's path and start pose."""
        from .._pytree import value_key

        u1_path, q_start = self._design_inputs()
        path = None if u1_path is None else np.asarray(u1_path, float).tobytes()
        start = None if q_start is None else np.asarray(q_start, float).tobytes()
        models = value_key((self.nominal_arm, self.constraint))
        adapt = self._adaptation_inputs()
        adapt = None if adapt is None else repr({k: np.asarray(v, float).tobytes() for k, v in adapt.items()})
        return kind, models, repr(self.scenario.controller), self.control_period, path, start, adapt, \
            self.declared_sensor, repr(self.declared_torque_rate)

    def _adaptation_inputs(self) -> dict | None:
        """What the robust update laws' design reads (``controller.adaptation``, not "none", nor
        "auto" with an ideal sensor): the start pose, the largest |λd| over the run and the
        sensor noise the design assumes (``controller.sensor.noise``; by default the DECLARED
        ``plant.sensor``'s, its data sheet), or None with the paper's laws."""
        sc = self.scenario
        sensor = sc.plant.sensor
        force_noise = sc.controller.sensor.resolved(self.declared_sensor)[0]
        noisy = bool(force_noise or np.any(sensor.q_noise) or np.any(sensor.qd_noise))
        if sc.controller.adaptation.resolved(noisy) == "none":
            return None
        if "_adapt" not in self.__dict__:
            import jax
            import jax.numpy as jnp

            ts = jnp.linspace(0.0, float(sc.simulation.t_final), 2001)
            lam_d = np.asarray(jax.vmap(lambda t: self.reference(t).lam_d)(ts))
            self._adapt = dict(q=np.asarray(self.q0, float), lam_max=float(np.max(np.abs(lam_d))),
                               force_noise=float(force_noise), q_noise=np.asarray(sensor.q_noise, float),
                               qd_noise=np.asarray(sensor.qd_noise, float))
        return self._adapt

    def _design(self, kind: str):
        u1_path, q_start = self._design_inputs()
        return self.scenario.controller.build(kind, self.nominal_arm, self.constraint, u1_path=u1_path,
                                              q_start=q_start, period=self.control_period,
                                              adaptation=self._adaptation_inputs(),
                                              declared=self.declared_sensor,
                                              declared_rate=self.declared_torque_rate)

    @property
    def declared_sensor(self) -> tuple[float, int]:
        """(force noise σ, N; delay, samples) of the scenario's declared sensor (plant.sensor): what
        controller.sensor defaults to. Read here, where the scenario is built, and handed to the
        design as numbers: the scenario is the user's statement, so the controller still never
        reads the plant."""
        sens = getattr(self.scenario.plant, "sensor", None)
        if sens is None:
            return 0.0, 0
        return float(sens.force_noise), int(sens.delay)

    @property
    def declared_torque_rate(self):
        """The scenario's declared torque-rate limit of the motors (plant.actuator.torque_rate_limit:
        a number or a tuple, N·m/s), or None ("none", or a plant without motors): what
        controller.actuator.torque_rate_limit defaults to, handed to the design as numbers."""
        act = getattr(self.scenario.plant, "actuator", None)
        value = None if act is None else act.torque_rate_limit
        return None if value is None or (isinstance(value, str) and value == "none") else value

    # --- the simulation -------------------------------------------------------------------------
    @property
    def control_period(self) -> float | None:
        """The period the controller runs at: ``simulation.control_period`` under sampled control,
        the simulation step for a plant that steps itself (MuJoCo: the torque is held over each of
        its steps), None for continuous control. The controller is designed for it."""
        sc = self.scenario
        if sc.simulation.control == "sampled":
            return sc.simulation.control_period
        return sc.simulation.dt if type(sc.plant).discrete else None

    @functools.cached_property
    def limits(self):
        return self.scenario.simulation.limits()

    def options(self) -> dict:
        """Keyword arguments of :func:`hinfnn.simulate` for this scenario."""
        s = self.scenario.simulation
        return dict(t_final=s.t_final, dt=s.dt, save_interval=s.output_interval, control_period=self.control_period,
                    limits=self.limits, bookkeeping=s.bookkeeping)

    def plan(self):
        """The :class:`~hinfnn.sim.plan.StepPlan` of a run of this scenario."""
        from ..sim.plan import StepPlan

        s = self.scenario.simulation
        return StepPlan.make(s.t_final, s.dt, control_period=self.control_period, save_interval=s.output_interval,
                             discrete=type(self.scenario.plant).discrete)

    def run(self, kind: str | None = None, name: str | None = None, *, info=None, controller=None):
        """The :class:`hinfnn.sim.Run` of one controller kind (default: the only one)."""
        from ..sim import Run, RunInfo

        kind = kind or only(self.scenario.kinds)
        info = info or RunInfo(name=name or kind, kind=kind, scenario=self.scenario.single(kind))
        return Run(name=name or kind, plant=self.plant, controller=controller or self.controller(kind),
                   reference=self.reference, q0=self.start_q, info=info, **self.options())

    def check_start(self, kind: str | None = None) -> None:
        """What a run of ``kind`` checks before anything is compiled, as :func:`hinfnn.simulate`
        checks it: the plant and the controller fit each other (:func:`hinfnn.protocols.check`),
        the step plan, the plant's state at the start pose (MuJoCo: its first forward pass and the
        task coordinates sensed from it) and the start pose for the controller
        (``check_start``). ``hinfnn design`` runs it, so that it refuses what ``hinfnn run``
        refuses, with the same message."""
        from ..protocols import check
        from ..sim.simulate import initial_state

        r = self.run(kind)
        check(r.plant, r.controller)
        self.plan()
        y0 = initial_state(r.plant, r.controller, q0=r.q0)
        r.controller.check_start(r.plant.joints(y0.plant)[0])

    # --- names ----------------------------------------------------------------------------------
    @functools.cached_property
    def coordinate_names(self) -> list[tuple[str, str]] | None:
        """Names and units of the task coordinates (motion coordinates first, the constrained one
        last), or None for the native coordinates of the two_link arm (x1, x2)."""
        return None if self.task is None else self.task.names()

    @functools.cached_property
    def joint_names(self) -> list[str]:
        """The moving joints' names (URDF), or joint1 … jointn."""
        chain = getattr(self.nominal_arm, "chain", None)
        n = self.nominal_arm.n
        return list(chain.joint_names) if chain is not None else [f"joint{i + 1}" for i in range(n)]

    @functools.cached_property
    def joint_units(self) -> list[str]:
        """Each moving joint's unit: m for a prismatic joint (URDF), else rad."""
        chain = getattr(self.nominal_arm, "chain", None)
        types = chain.joint_types if chain is not None else ("revolute",) * self.nominal_arm.n
        return ["m" if kind == "prismatic" else "rad" for kind in types]


#: Colours of the shipped controller kinds in figures (other kinds take the next free colour of
#: the report's palette).
KIND_COLORS = {"fl": "#7b3294", "hinf": "#1f5fbf", "hinf_nn": "#d62728"}


def describe(scenario) -> dict:
    """The facts a report shows of a run of ``scenario`` (one controller kind): the controller's
    label and colour, whether it learns (and its F_f centre preset), the contact, the scaling of λ,
    the task coordinates' and joints' names, the joints' and λ's units (what exports label each
    component with: :func:`hinfnn.fields.component_units`) and the reference's periods."""
    from ..controllers import KINDS

    kind = scenario.kinds[0]
    comp = KINDS.get(kind)
    ctrl = scenario.controller
    learning = comp is not None and comp.learns
    ref = scenario.reference
    periods = [float(v) for key in ("u1_period", "lam_period")
               for v in (getattr(ref, key) if isinstance(getattr(ref, key, ()), tuple) else (getattr(ref, key, math.nan),))
               if isinstance(v, (int, float)) and math.isfinite(v)]
    try:
        coordinates, joints = scenario.coordinate_names(), scenario.joint_names()
        setup = scenario.build()
        joint_units, lambda_unit = setup.joint_units, setup.constraint.lambda_unit
    except Exception:  # noqa: BLE001 - a description never fails over a label
        coordinates, joints, joint_units, lambda_unit = None, None, None, None
    return {
        "kind": kind, "label": comp.label if comp is not None else kind, "color": KIND_COLORS.get(kind, ""),
        "networks": learning, "f_f_preset": ctrl.network_f.preset if learning else None,
        "augmented": bool(ctrl.augmented),
        "contact_stiffness": float(scenario.plant.contact.stiffness),
        "contact_damping": float(scenario.plant.contact.damping),
        "lambda_scaling": getattr(scenario.nominal.surface, "scaling", None),
        "coordinates": [list(c) for c in coordinates] if coordinates else None,
        "joints": list(joints) if joints else None,
        "joint_units": joint_units,
        "lambda_unit": lambda_unit,
        "reference_periods": periods,
        "engine": scenario.plant.engine,
        "control": scenario.simulation.control,
    }


def only(kinds):
    """The one controller kind of a scenario (a ConfigError naming them when there are several)."""
    if len(kinds) != 1:
        raise ConfigError(f"the scenario lists {len(kinds)} controllers {list(kinds)}; name one", key="controller.kind")
    return kinds[0]


class _DesignCache:
    """Designed controllers by what their design reads (a bounded, least-recently-used map)."""

    def __init__(self, size: int = 64):
        self.size = size
        self._d: collections.OrderedDict = collections.OrderedDict()

    def get(self, key, design):
        if key in self._d:
            self._d.move_to_end(key)
            return self._d[key]
        value = design()
        self._d[key] = value
        if len(self._d) > self.size:
            self._d.popitem(last=False)
        return value

    def clear(self) -> None:
        self._d.clear()


#: The process's designed controllers (:meth:`Setup.controller`).
_DESIGNS = _DesignCache()

__all__ = ["Setup", "only", "describe", "KIND_COLORS"]
