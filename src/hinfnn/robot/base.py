"""The robot interface the loop runner drives (docs/robot.md): start, read, write, stop.

A robot gives the loop, once per control period, a :class:`Reading` (its own time and what its
sensors measured) and takes a joint torque to hold until the next one. Everything else (the
controller, the safety layer, the log) is the loop's (:func:`hinfnn.robot.run_loop`).
"""

from __future__ import annotations

import abc
import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class Reading:
    """What a robot reports once per control period.

    ``t``: the robot's time, s (from its start). ``q``, ``qd``: joint angles and rates (n,).
    ``force``: the contact force the tool exerts on the surface at the tool point, in the base
    frame's Cartesian axes (d,): what a force/torque sensor at the tool gives
    (:class:`hinfnn.protocols.Measurement`). ``tau_ext``: the external joint torques when the
    robot estimates them instead (None here: every robot hinfnn drives today has a force sensor).
    ``missed``: control periods in a row, up to this reading, in which the robot got no fresh
    torque and held the previous one (0 when every torque arrived in time). ``wall``: the robot's
    ``time.perf_counter()`` of the tick the reading belongs to (same clock as the loop's on one
    machine; the torque for it is due one period later), or NaN when unknown or when no tick is due
    yet (the virtual robot's first reading: its clock starts with the first torque). The loop
    counts a cycle's lateness from this stamp, or from the reading's return when it is NaN.
    """

    t: float
    q: np.ndarray
    qd: np.ndarray
    force: np.ndarray
    tau_ext: np.ndarray | None = None
    missed: int = 0
    wall: float = float("nan")


class Robot(abc.ABC):
    """A torque-controlled arm as the loop sees it.

    * ``period``: the control period the robot runs at, s;
    * :meth:`start`: connect and start the robot's clock (the first reading is at t = 0);
    * :meth:`read`: block until the next reading and return it (the newest when several came);
    * :meth:`write`: the joint torque to hold from now until the next write, N·m (n,);
    * :meth:`stop`: hold the robot still and disconnect (idempotent; also on errors).

    A robot is a context manager: ``with robot: ...`` starts and stops it.

    ``clock_waits``: whether the robot's clock starts only with the first torque written (the
    virtual robot's: the arm is held until then), so that the loop may first warm its law up on the
    thread and CPU it will run on (:func:`hinfnn.robot.loop.run_loop`'s ``warm``); False (a Franka,
    whose torque interface runs once started) leaves the first cycle to the first reading.
    """

    period: float
    n: int
    clock_waits: bool = False

    @abc.abstractmethod
    def start(self) -> None: ...

    @abc.abstractmethod
    def read(self) -> Reading: ...

    @abc.abstractmethod
    def write(self, tau) -> None: ...

    @abc.abstractmethod
    def stop(self) -> None: ...

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()
        return False


def require_sampled(scenario) -> None:
    """A robot runs the controller at a fixed rate: ConfigError naming ``simulation.control``
    unless the scenario's control is sampled."""
    from ..errors import ConfigError

    if scenario.simulation.control != "sampled":
        raise ConfigError("a robot runs the controller at a fixed rate: set simulation.control = \"sampled\", got "
                          f"{scenario.simulation.control!r}", key="simulation.control")


__all__ = ["Reading", "Robot", "require_sampled"]
