"""A Franka arm (FR3, Panda) through libfranka's Python bindings ``pylibfranka``: 1 kHz torque control.

:class:`FrankaRobot` is a :class:`~hinfnn.robot.Robot` for :func:`hinfnn.robot.run_loop`: it
connects to the arm's controller (or to ``franka-sim``, a server speaking the same protocol over
MuJoCo, on 127.0.0.1: docs/robot.md), moves the arm to the scenario's start pose with libfranka's
joint position interface when it is not there, then opens libfranka's torque interface
(``Robot.start_torque_control``: ``readOnce`` / ``writeOnce`` once per millisecond) for the loop.

What the interface requires, and how it is met:

* **Gravity.** The Franka adds the gravity torque of its own model to every torque it is sent, so a
  torque written is the torque beyond gravity. The law's torque τ contains the nominal Ĝ(q) (eq. (24));
  :meth:`FrankaRobot.write` therefore sends τ − Ĝ(q), Ĝ at the last reading's q. A held pose then
  needs τ_write ≈ 0 where the law asks τ ≈ Ĝ (tests/test_franka.py checks it on franka-sim).
* **Torque rate.** libfranka rejects a torque that changes by more than 1000 N·m/s
  (:data:`TORQUE_RATE_LIMIT`): the safety layer's rate clamp (``safety.torque_rate_limit``) limits
  the law's torque, and the written torque (which moves with Ĝ(q) as well) is clamped once more to
  that rate and to the joints' effort limits (counted: ``rate_clamped``, ``torque_clamped``).
* **The reading.** t: the robot's own time (the sum of ``readOnce``'s durations, 1 ms per tick);
  q, q̇ from the robot state; ``missed``: ticks that passed since the previous reading beyond one
  (the robot held the previous torque over them).
* **The contact force.** The robot's estimated external wrench ``O_F_ext_hat_K`` (its first three
  entries: the force the robot applies to the environment, base frame) when it reports one (not
  all zero), otherwise the generalized-momentum observer of :mod:`hinfnn.robot.observer` on q, q̇
  and the written torques with the NOMINAL model (franka-sim leaves ``O_F_ext_hat_K`` at zero).
  ``force_source`` = ``"auto"`` (that rule), ``"robot"`` or ``"observer"``.

``pylibfranka`` is imported only by :meth:`FrankaRobot.start` (``pip install 'hinfnn[franka]'``;
ConfigError naming ``--robot`` without it).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import ConfigError, SimulationError
from .base import Reading, Robot, require_sampled
from .observer import MomentumObserver
from .realtime import restore_scheduling, thread_scheduling

#: libfranka's control period, s.
PERIOD = 1e-3
#: libfranka's limit on the rate of change of a commanded joint torque, N·m/s.
TORQUE_RATE_LIMIT = 1000.0
#: The force sources :class:`FrankaRobot` knows.
FORCE_SOURCES = ("auto", "robot", "observer")
#: How long the move to the start pose holds q0 before it ends, s.
SETTLE_TIME = 0.5
#: The move to the start pose comes from this far off the surface (m, along its normal) ...
APPROACH = 0.02
#: ... in this long, s.
APPROACH_TIME = 1.5
#: Default bandwidth of the momentum observer, 1/s (time constant 10 ms).
OBSERVER_GAIN = 100.0

_MISSING = "--robot franka needs libfranka's Python bindings: pip install 'hinfnn[franka]' (pylibfranka)"


def require_pylibfranka():
    """Import and return ``pylibfranka``, or raise :class:`ConfigError` (``--robot``)."""
    try:
        import pylibfranka
    except ImportError as err:
        raise ConfigError(_MISSING, key="--robot") from err
    return pylibfranka


def quintic(s: float) -> float:
    """The rest-to-rest quintic 10 s³ − 15 s⁴ + 6 s⁵ on s ∈ [0, 1] (zero velocity and acceleration at
    both ends; its largest slope is 1.875)."""
    s = min(max(s, 0.0), 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def franka_sim_mjcf(scenario) -> str:
    """The MJCF of the scenario's true MuJoCo plant (``plant.engine = "mujoco"``: the arm, the tool
    sphere, the surface and their calibrated contact pair) as ``franka-sim`` loads it through its
    ``FR3_MJCF`` variable: what the server simulates is then what ``hinfnn run`` simulates offline.
    franka-sim's MuJoCo (< 3.3) has no contact sensor (the server does not read it): it is left out;
    bodies merged from several URDF links (``link7+link8``) take their first link's name (franka-sim
    finds the arm by ``joint1`` … ``joint7`` and ``link7``). The server adds gravity compensation
    and a ground plane itself."""
    import re

    if scenario.plant.engine != "mujoco":
        raise ConfigError(f"franka-sim simulates a MuJoCo model: set plant.engine = \"mujoco\", got "
                          f"{scenario.plant.engine!r}", key="plant.engine")
    xml = scenario.build_plant().xml
    xml = re.sub(r"\s*<sensor>.*?</sensor>", "", xml, flags=re.S)
    return re.sub(r'<body name="([^"+]+)\+[^"]*"', r'<body name="\1"', xml)


def _lifted(arm, surface, q0, distance: float) -> np.ndarray:
    """The joint angles that put the tool point ``distance`` m off the nominal surface along its
    normal at the start pose (the world's z where the surface has no Cartesian normal): three
    Newton steps on the tool point from q0, minimum-norm in the joints."""
    import jax
    import jax.numpy as jnp

    point, jac = jax.jit(arm.point), jax.jit(arm.point_jacobian)
    p0 = np.asarray(point(jnp.asarray(q0)))
    normal = getattr(surface, "normal", None)
    n = np.asarray(normal(jnp.asarray(p0)), dtype=float) if callable(normal) else np.array([0.0, 0.0, -1.0])
    target = p0 - distance * n / np.linalg.norm(n)  # the normal points into the material
    q = np.array(q0, dtype=float)
    for _ in range(3):
        q = q + np.linalg.pinv(np.asarray(jac(jnp.asarray(q)))) @ (target - np.asarray(point(jnp.asarray(q))))
    return q


class FrankaRobot(Robot):
    """A Franka through ``pylibfranka``: ``FrankaRobot(scenario, host="127.0.0.1", ...)``.

    ``scenario``: a single-controller :class:`~hinfnn.scenario.Scenario` with a 7-joint nominal arm,
    ``simulation.control = "sampled"`` and ``simulation.control_period = 0.001`` (ConfigError naming
    the key otherwise). ``force_source``, ``observer_gain`` (1/s): the contact force (module
    docstring; the observer's M̂ is the nominal arm's, with the motors' armature where the scenario
    states one (``nominal.arm.armature``); ``observer_armature``: reflected inertia per joint,
    kg·m², added to it beyond that).
    ``move_to_start``: move the arm to the scenario's start pose q0 first when it is
    more than ``start_tolerance`` rad away on a joint (a quintic joint motion at most
    ``move_speed`` rad/s); False: a ConfigError naming ``initial.u1`` instead. ``realtime``:
    libfranka's real-time scheduling check (``"ignore"``, as for a simulator or a machine without
    a real-time kernel, or ``"enforce"``). ``collision_torque`` (N·m) and ``collision_force``
    (N): the robot's own reflex thresholds, set before the job (a contact job presses on purpose).
    """

    n = 7
    period = PERIOD

    def __init__(self, scenario, host: str = "127.0.0.1", *, force_source: str = "auto",
                 observer_gain: float = OBSERVER_GAIN, observer_armature=0.0, move_to_start: bool = True,
                 move_speed: float = 0.5, start_tolerance: float = 1e-3, realtime: str = "ignore",
                 collision_torque: float = 100.0, collision_force: float = 100.0):
        require_sampled(scenario)
        if abs(scenario.simulation.control_period - PERIOD) > 1e-12:
            raise ConfigError(f"a Franka is controlled at 1 kHz: set simulation.control_period = 0.001, got "
                              f"{scenario.simulation.control_period!r}", key="simulation.control_period")
        if force_source not in FORCE_SOURCES:
            raise ConfigError(f"unknown force source {force_source!r}; allowed: {', '.join(FORCE_SOURCES)}",
                              key="force_source")
        if realtime not in ("ignore", "enforce"):
            raise ConfigError(f"must be \"ignore\" or \"enforce\", got {realtime!r}", key="realtime")
        for key, v in (("move_speed", move_speed), ("start_tolerance", start_tolerance),
                       ("collision_torque", collision_torque), ("collision_force", collision_force)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"must be a finite number > 0, got {v!r}", key=key)
        setup = scenario.build()
        arm = setup.nominal_arm
        if int(arm.n) != 7 or int(arm.space_dim) != 3:
            raise ConfigError(f"a Franka has 7 joints in 3-D space: the nominal arm has {int(arm.n)} joints "
                              f"in {int(arm.space_dim)}-D", key="nominal.arm")
        self.scenario, self.host = scenario, str(host)
        self.d = 3
        self.force_source = force_source
        self.move_to_start, self.move_speed, self.start_tolerance = bool(move_to_start), float(move_speed), \
            float(start_tolerance)
        self.realtime = realtime
        self.collision_torque, self.collision_force = float(collision_torque), float(collision_force)
        self.q0 = np.asarray(setup.q0, dtype=float)
        chain = getattr(arm, "chain", None)
        effort = None if chain is None else np.asarray(chain.effort_limit, dtype=float)
        self.effort = np.where(np.isfinite(effort) & (effort > 0), effort, np.inf) if effort is not None \
            else np.full(7, np.inf)
        self.q_above = _lifted(arm, setup.nominal_surface, self.q0, APPROACH)
        # compiled here, before any connection
        self.observer = MomentumObserver(arm, observer_gain, observer_armature)
        self._pf = self._robot = self._ctrl = None
        self._reset()

    def _reset(self):
        self._t = 0.0
        self._obs = self.observer.init()
        self._G = np.zeros(7)
        self._tau_w = np.zeros(7)  # the last torque written beyond gravity (none before the first: zero)
        self._first = None      # the reading taken when the torque interface opened
        self._scheduling = None  # the thread's scheduling before start (restored by stop)
        self.rate_clamped = 0   # writes whose change was clamped to TORQUE_RATE_LIMIT
        self.torque_clamped = 0  # writes clamped to the effort limits
        self.moved = 0.0        # largest joint motion of the move to the start pose, rad
        self.force_sources = {"robot": 0, "observer": 0}
        self.success_rate_min = math.nan  # lowest control_command_success_rate seen (from the 100th write on)
        self.written = 0

    # --- Robot ------------------------------------------------------------------------------------
    def start(self) -> None:
        """Connect, set the collision thresholds, move to the start pose when needed, open the torque
        interface and take the first reading (the loop's t = 0)."""
        pf = require_pylibfranka()
        if self._robot is not None:
            raise SimulationError("the Franka is already started")
        self._reset()
        self._pf = pf
        rt = pf.RealtimeConfig.kIgnore if self.realtime == "ignore" else pf.RealtimeConfig.kEnforce
        self._scheduling = thread_scheduling()  # libfranka raises this thread to SCHED_FIFO 99 and leaves it there
        try:
            self._robot = pf.Robot(self.host, rt)
            t, f = [self.collision_torque] * 7, [self.collision_force] * 6
            self._robot.set_collision_behavior(t, t, f, f)
            q = np.asarray(self._robot.read_once().q, dtype=float)
            far = float(np.max(np.abs(q - self.q0)))
            if far > self.start_tolerance:
                if not self.move_to_start:
                    raise ConfigError(f"the arm is {far:.4g} rad from the scenario's start pose q0 = "
                                      f"{np.round(self.q0, 4).tolist()} (allowed: {self.start_tolerance:g} rad); move "
                                      "it there first or let FrankaRobot do it (move_to_start=True)", key="initial.u1")
                self._move(q)
            self._ctrl = self._robot.start_torque_control()
            state, _ = self._ctrl.readOnce()
        except (ConfigError, SimulationError):
            self._close()
            raise
        except Exception as err:  # pylibfranka's NetworkException, ControlException, ...
            self._close()
            raise SimulationError(f"the Franka at {self.host} could not start: {type(err).__name__}: {err}") from None
        self._first = self._reading(state, 0.0)

    def _move(self, q) -> None:
        """Joint position motions (libfranka's joint impedance controller): from q to
        :attr:`q_above` (the start pose lifted by :data:`APPROACH` off the surface, in free space),
        then down to q0 in :data:`APPROACH_TIME`, q0 then held for :data:`SETTLE_TIME`."""
        pf = self._pf
        self.moved = float(np.max(np.abs(self.q0 - q)))
        ctrl = self._robot.start_joint_position_control(pf.ControllerMode.JointImpedance)
        legs = [(q, self.q_above, max(1.0, 1.875 * float(np.max(np.abs(self.q_above - q))) / self.move_speed), 0.0),
                (self.q_above, self.q0, APPROACH_TIME, SETTLE_TIME)]
        for i, (a, b, T, hold) in enumerate(legs):
            t = 0.0
            while True:
                _, d = ctrl.readOnce()
                t += d.to_sec()
                cmd = pf.JointPositions(list(a + (b - a) * quintic(t / T)))
                if t >= T + hold:
                    if i == len(legs) - 1:
                        cmd.motion_finished = True
                    ctrl.writeOnce(cmd)
                    break
                ctrl.writeOnce(cmd)

    def read(self) -> Reading:
        """The next robot state as a :class:`~hinfnn.robot.Reading` (blocks until it comes)."""
        if self._first is not None:
            r, self._first = self._first, None
            return r
        try:
            state, d = self._ctrl.readOnce()
        except Exception as err:
            raise SimulationError(f"the Franka sent no state after t = {self._t:.6g} s: {type(err).__name__}: {err}",
                                  t_fail=self._t) from None
        return self._reading(state, float(d.to_sec()))

    def _reading(self, state, dt: float) -> Reading:
        wall = time.perf_counter()
        self._t += dt
        q = np.array(state.q, dtype=float)
        qd = np.array(state.dq, dtype=float)
        tau = self._tau_w
        self._obs, force, _, self._G = self.observer.step(self._obs, q, qd, tau, dt if dt > 0 else PERIOD)
        wrench = np.array(state.O_F_ext_hat_K, dtype=float)[:3]
        use_robot = self.force_source == "robot" or (self.force_source == "auto" and np.any(wrench != 0.0))
        if use_robot:
            force = wrench
        self.force_sources["robot" if use_robot else "observer"] += 1
        rate = float(state.control_command_success_rate)  # over the last 100 ticks: judged once 100 writes went
        if self.written >= 100 and not rate >= self.success_rate_min:
            self.success_rate_min = rate
        missed = max(0, int(round(dt / PERIOD)) - 1)
        return Reading(t=self._t, q=q, qd=qd, force=np.asarray(force, dtype=float), missed=missed, wall=wall)

    def write(self, tau) -> None:
        """Send τ − Ĝ(q) (the robot adds its gravity), clamped to the effort limits and to
        :data:`TORQUE_RATE_LIMIT` per period from the previous write."""
        tau_w = np.asarray(tau, dtype=float) - self._G
        clipped = np.clip(tau_w, -self.effort, self.effort)
        self.torque_clamped += int(np.any(clipped != tau_w))
        step = TORQUE_RATE_LIMIT * PERIOD  # from the previous write (zero before the first one)
        limited = np.clip(clipped, self._tau_w - step, self._tau_w + step)
        self.rate_clamped += int(np.any(limited != clipped))
        clipped = limited
        if not np.all(np.isfinite(clipped)):  # never sent: the loop's safety layer stops on it first
            clipped = self._tau_w
        try:
            self._ctrl.writeOnce(self._pf.Torques(clipped.tolist()))
        except Exception as err:
            raise SimulationError(f"the Franka refused the torque at t = {self._t:.6g} s: {type(err).__name__}: {err}",
                                  t_fail=self._t) from None
        self._tau_w = clipped
        self.written += 1

    def stop(self) -> None:
        """Finish the torque motion (the last torque written again, ``motion_finished``) and
        disconnect; the robot then holds its pose under its own control."""
        if self._robot is None:
            return
        try:
            if self._ctrl is not None:
                last = self._pf.Torques(self._tau_w.tolist())
                last.motion_finished = True
                self._ctrl.writeOnce(last)
        except Exception:  # noqa: BLE001 - stopping must not raise over the error that led here
            pass
        self._close()

    def _close(self):
        ctrl, robot, self._ctrl, self._robot = self._ctrl, self._robot, None, None
        del ctrl
        if robot is not None:
            try:
                robot.stop()
            except Exception:  # noqa: BLE001
                pass
            del robot
        restore_scheduling(self._scheduling)  # the thread as it was before start
        self._scheduling = None

    def report(self) -> dict:
        """What the robot did beside the loop (metrics.json ``robot.device``)."""
        return {"robot": "franka", "host": self.host, "force_source": self.force_source,
                "readings_by_force_source": dict(self.force_sources), "observer_gain": self.observer.gain,
                "moved_to_start_rad": self.moved, "rate_clamped_writes": self.rate_clamped,
                "effort_clamped_writes": self.torque_clamped, "writes": self.written,
                "control_command_success_rate_min": None if math.isnan(self.success_rate_min)
                else self.success_rate_min}


__all__ = ["PERIOD", "TORQUE_RATE_LIMIT", "FORCE_SOURCES", "OBSERVER_GAIN", "require_pylibfranka", "quintic",
           "franka_sim_mjcf", "FrankaRobot"]
