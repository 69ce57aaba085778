"""Helpers of the robot-loop tests (tests/test_robot.py, tests/test_job.py)."""

from __future__ import annotations

import numpy as np

from hinfnn.robot import Robot

#: The scripted robot's control period, s.
PERIOD = 1e-3


class ScriptedRobot(Robot):
    """Gives the readings of a list, in order (the last one again once they run out), and keeps
    what was written; a two-joint robot at :data:`PERIOD`."""

    def __init__(self, readings):
        self.readings = list(readings)
        self.period, self.n = PERIOD, 2
        self.written = []
        self.i = 0

    def start(self):
        pass

    def stop(self):
        pass

    def read(self):
        r = self.readings[min(self.i, len(self.readings) - 1)]
        self.i += 1
        return r

    def write(self, tau):
        self.written.append(np.array(tau))
