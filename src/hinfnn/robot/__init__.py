"""The controller on a robot: the :class:`Robot` interface, the real-time loop with its safety layer,
and a :class:`VirtualRobot` (docs/robot.md).

* :class:`Robot`, :class:`Reading` — start, read → (t, q, q̇, force), write τ, stop;
* :func:`run_loop` — one loop runner for any robot: the sampled controller once per period, the
  safety layer (:mod:`hinfnn.robot.safety`), latency and lateness of every cycle;
* :func:`run_robot` — a scenario on a robot, written as a result folder (``hinfnn robot run``);
* :class:`VirtualRobot`, :class:`Fault` — the scenario's MuJoCo plant in its own process, in real
  time, with faults to inject;
* :class:`FrankaRobot` — a Franka through libfranka's ``pylibfranka`` (imported when it starts);
* :class:`MomentumObserver` — the contact force from q, q̇ and the torques, without a force sensor;
* :mod:`hinfnn.robot.realtime` — the loop thread under the kernel's real-time policy (SCHED_FIFO)
  while it runs (:class:`Scheduling`: how it was scheduled).
"""

from .base import Reading, Robot
from .loop import LoopLog, run_loop, trajectory
from .run import ROBOTS, RobotRunResult, run_robot, safety_limits
from .safety import RULES, Event, SafetyLimits
from .franka import FrankaRobot
from .observer import MomentumObserver
from .realtime import Scheduling
from .virtual import FAULTS, Fault, VirtualRobot

__all__ = ["Reading", "Robot", "LoopLog", "run_loop", "trajectory", "ROBOTS", "RobotRunResult", "run_robot",
           "safety_limits", "RULES", "Event", "SafetyLimits", "FAULTS", "Fault", "VirtualRobot", "FrankaRobot",
           "MomentumObserver", "Scheduling"]
