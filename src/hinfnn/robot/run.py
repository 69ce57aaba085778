"""``hinfnn robot run`` as a library call: a scenario's controller on a robot, recorded as a result
folder (metrics.json, trajectory.npz, scenario.toml, robot.log, figures), atomically."""

from __future__ import annotations

import dataclasses
import gc
import time

import numpy as np

from ..errors import ConfigError
from .base import require_sampled
from .loop import run_loop, trajectory
from .realtime import check_mode, loop_cpu
from .safety import SafetyLimits

#: The robots ``hinfnn robot run --robot`` knows.
ROBOTS = ("virtual", "franka")


@dataclasses.dataclass
class RobotRunResult:
    target: object        # the folder written
    doc: dict             # metrics.json
    log: object           # the LoopLog
    note: str | None      # why the result is not in the reserved folder, or None


def safety_limits(sc, setup=None) -> SafetyLimits:
    """The safety layer's limits of a scenario: its ``[safety]`` section, its control period, the
    nominal arm's URDF effort and joint limits (an arm without them: ``simulation.torque_limit``
    and no joint limits)."""
    setup = setup or sc.build()
    arm = setup.nominal_arm
    chain = getattr(arm, "chain", None)
    get = (lambda name: None if chain is None else np.asarray(getattr(chain, name), dtype=float))
    return SafetyLimits.from_config(sc.safety, period=sc.simulation.control_period, n=int(arm.n),
                                    effort=get("effort_limit"), lower=get("lower"), upper=get("upper"),
                                    fallback_torque=sc.simulation.torque_limit)


def for_the_robot(sc):
    """The scenario as a robot runs it: a controller whose torque-rate limit is "declared"
    (``controller.actuator.torque_rate_limit``, its default) is designed within the tighter of the
    declared motors' limit (``plant.actuator.torque_rate_limit``) and the safety layer's clamp
    (``safety.torque_rate_limit``): the torque rate the loop will let through. Any other value, and
    a scenario whose rate limit is already the clamp's or tighter, is returned unchanged."""
    if sc.controller.actuator.torque_rate_limit != "declared":
        return sc
    declared = sc.build().declared_torque_rate
    clamp = float(sc.safety.torque_rate_limit)
    if declared is not None and np.all(np.asarray(declared, dtype=float) <= clamp):
        return sc
    limit = clamp if declared is None else np.minimum(np.asarray(declared, dtype=float), clamp)
    value = repr(float(limit)) if np.ndim(limit) == 0 else "[" + ", ".join(repr(float(v)) for v in limit) + "]"
    return sc.with_overrides([f"controller.actuator.torque_rate_limit={value}"])


def _single(sc):
    if len(sc.kinds) != 1:
        raise ConfigError(f"a robot runs one controller: give one kind, got {sc.kinds}", key="controller.kind")
    require_sampled(sc)
    return sc.kinds[0]


def make_robot(sc, robot: str, faults=(), host: str = "127.0.0.1", scheduling: str = "auto",
               loop_on: int | None = None):
    """The robot named ``robot`` (:data:`ROBOTS`) for scenario ``sc`` (``host``: the Franka's
    address; ``scheduling``: the virtual robot's served clock's, :mod:`hinfnn.robot.realtime`, on
    every CPU but ``loop_on``, the loop's, when that is given)."""
    if robot == "virtual":
        import os

        from .virtual import VirtualRobot

        others = set(os.sched_getaffinity(0)) - {loop_on} if loop_on is not None else set()
        return VirtualRobot(sc, faults=faults, scheduling=scheduling, cpus=others or None)
    if robot == "franka":
        if faults:
            raise ConfigError("faults are injected in the virtual robot only", key="faults")
        from .franka import FrankaRobot

        return FrankaRobot(sc, host=host)
    raise ConfigError(f"unknown robot {robot!r}; allowed: {', '.join(ROBOTS)}", key="--robot")


#: Samples a throwaway loop runs before the robot starts (:func:`prepared`).
WARM_SAMPLES = 3


def prepared(sc):
    """(sampled controller, limits, gravity(q), point_jacobian(q), warm()) of a scenario's one
    controller, every compiled function warmed up (a first call compiles: never inside the loop);
    ``warm()`` runs the warm-up again (:func:`hinfnn.robot.loop.run_loop` calls it on the loop's own
    thread and CPU)."""
    import jax

    from ..controllers.sampled import SampledController

    kind = _single(sc)
    setup = sc.build()
    controller = setup.controller(kind)
    sampled = SampledController(controller, setup.reference)
    limits = safety_limits(sc, setup)
    arm = controller.arm
    gravity_fn, jac_fn = jax.jit(arm.G), jax.jit(arm.point_jacobian)
    n, d = sampled.n_joints, sampled.force_size
    q = np.zeros(n)
    gravity = (lambda q: np.asarray(gravity_fn(np.asarray(q, dtype=float))))
    point_jacobian = (lambda q: np.asarray(jac_fn(np.asarray(q, dtype=float))))
    gravity(q), point_jacobian(q)
    # a loop run for a few samples at the start pose: its first update (the start at the first sample)
    # and the next ones (the update on the state the previous one gave back) each do work once
    q_start = np.asarray(setup.start_q, dtype=float)

    def warm():  # a throwaway loop, a few samples at the start pose (run again on the loop's own thread)
        loop = sampled.loop()
        for k in range(WARM_SAMPLES):
            loop.update(k * limits.period, limits.period, q_start, np.zeros(n), np.zeros(d))
    warm()  # its first update also compiles the controller's start (SampledLoop starts it there)
    return sampled, limits, gravity, point_jacobian, warm


def run_robot(sc, *, robot="virtual", faults=(), out=None, force: bool = False, command: str = "", log=print,
              figures: bool = True, event_log=None, host: str = "127.0.0.1", scheduling: str = "auto",
              cpu="auto") -> RobotRunResult:
    """Run the scenario's one controller on ``robot`` (a :class:`~hinfnn.robot.Robot`, or a name of
    :data:`ROBOTS`; ``faults`` for the virtual one) for ``simulation.t_final`` s of robot time,
    through the safety layer, and write the result folder as ``hinfnn run`` does (reserved before
    anything runs, put in place when complete: a run that fails leaves nothing): metrics.json (the
    run, and ``robot``: latency, lateness, late and rejected cycles, the safety events and the stop),
    trajectory.npz, scenario.toml, robot.log (the events, one per line) and figures. A stop by the
    safety layer is a result (status ``diverged``, the rule in its reason), not an error.
    ``event_log(line)``: each safety event as it fires; ``host``: the Franka's address (``robot =
    "franka"``). A robot with a ``report()`` method adds its dict as ``robot.device``. ``scheduling``
    ("auto", "enforce", "off") and ``cpu``: the loop thread's real-time scheduling
    (:func:`hinfnn.robot.realtime.realtime`; "auto": SCHED_FIFO where the process may) and CPU
    (None: any; "auto": the last of two or more, :func:`hinfnn.robot.realtime.loop_cpu`), recorded
    as ``robot.realtime``; the virtual robot's served clock is scheduled the same way, on the other
    CPUs."""
    from ..experiment import Outcome, cases, result_folder, write_result
    from ..experiment.result import explain
    from ..io import atomic_write_text
    from ..metrics import compute_metrics
    from ..workflows.run import result_name

    _single(sc)
    check_mode(scheduling, key="scheduling")
    cpu = loop_cpu(cpu, scheduling)
    sc = for_the_robot(sc)
    case = cases(sc, tags={"robot": robot if isinstance(robot, str) else type(robot).__name__})[0]
    with result_folder(out, command="robot", name=result_name(sc), kind="run", force=force, log=log,
                       command_line=command) as written:
        sampled, limits, gravity, jacobian, warm = prepared(sc)
        bot = make_robot(sc, robot, faults, host, scheduling, cpu) if isinstance(robot, str) else robot
        gc.collect()  # before the robot starts: the loop holds the collector off (hinfnn.robot.loop)
        t0 = time.perf_counter()
        with bot:
            loop_log = run_loop(bot, sampled, limits, t_final=sc.simulation.t_final, gravity=gravity,
                                point_jacobian=jacobian, log=event_log, scheduling=scheduling, cpu=cpu, warm=warm)
        traj = trajectory(loop_log, sampled, case.info())
        metrics = compute_metrics(traj)
        explain(metrics, sampled.controller, traj)
        outcome = Outcome(cases=[case], trajectories={case.name: traj}, metrics={case.name: metrics},
                          designs={case.name: sampled.controller.summary()}, seconds=time.perf_counter() - t0)
        summary = {**loop_log.summary(), "limits": limits.summary()}
        if callable(getattr(bot, "report", None)):
            summary["device"] = bot.report()
        doc = write_result(written.path, sc, outcome, command=command, save_interval=sc.simulation.control_period,
                           extra={"robot": summary})
        atomic_write_text(written.path / "robot.log", "\n".join(loop_log.lines()) + "\n")
        if figures:
            from ..report import run_figures

            run_figures(outcome.trajectories, written.path)
    return RobotRunResult(target=written.path, doc=doc, log=loop_log, note=written.moved)


__all__ = ["ROBOTS", "RobotRunResult", "for_the_robot", "safety_limits", "make_robot", "prepared", "run_robot"]
