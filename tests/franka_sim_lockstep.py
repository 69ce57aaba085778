"""``run-franka-sim-server`` with its physics stepped once per published robot state (franka-sim 1.1.7).

Run with franka-sim's own Python (its environment, not hinfnn's), with the server's own arguments:
``FR3_MJCF=scene.xml .franka-env/bin/python tests/franka_sim_lockstep.py --no-gripper``.

Why: franka-sim runs its MuJoCo physics in one thread paced to the wall clock and publishes robot
states from another at 1 kHz. On a machine that cannot hold real time (2 cores shared with the test
suite: measured real-time factors of 0.24-0.7 in franka-sim's own log), the physics advances less
than 1 ms between two states that the client is told are 1 ms apart, by a varying amount. A
controller integrating its state over the robot's time, and a momentum observer integrating the
torques over it, then see physics that runs slower than their clock: the force estimate is off by
the missing fraction of every torque (docs/robot.md, "Tested on loopback").

This wrapper changes only the pacing, as hinfnn's lock-step VirtualRobot does: the physics thread
no longer steps; the state-publishing thread advances the physics by one 1 ms step before it takes
each state (applying the newest command, as franka-sim does), after waiting (at most ``WAIT_S``) for
the client's answer to the previous state. The protocol, the server's checks (communication
constraints, motion limits, torque rate) and the MuJoCo model are franka-sim's own.
"""

import os
import threading
import time

import mujoco
import numpy as np

from franka_sim import mujoco_franka_sim as _sim
from franka_sim.server import state_stream as _stream

#: The longest the publishing thread waits for the client's answer to the previous state, s.
WAIT_S = 0.05

_local = threading.local()
_lock = threading.Lock()


def _idle_physics(self):
    """The physics thread: steps nothing (the publishing thread does), only waits for the stop."""
    while self.running:
        time.sleep(0.01)


_get_state = _sim.MujocoFrankaSim.get_robot_state


def _get_state_stepped(self):
    server = getattr(_local, "server", None)
    if server is None:  # any other thread: the snapshot as it is
        return _get_state(self)
    published = getattr(server, "_last_published_message_id", 0) or 0
    if getattr(server, "_hinfnn_streaming", False) and published:
        give_up = time.perf_counter() + WAIT_S
        while getattr(server, "_hinfnn_answered", 0) < published and time.perf_counter() < give_up:
            time.sleep(2e-5)
    with _lock:
        self.step(1)  # apply the newest command, one mj_step, publish the snapshot
        if _truth is not None:
            _record(self)
    return _get_state(self)


#: ``HINFNN_FRANKA_SIM_TRUTH=path.npy``: the true contact force of every step so far is written there
#: at the end of each motion (the test compares the robot's force estimate with it).
_truth_path = os.environ.get("HINFNN_FRANKA_SIM_TRUTH")
_truth = [] if _truth_path else None


def _record(sim):
    """One row per physics step: the contact force the tool exerts on the surface (world frame,
    summed over the contacts) and q."""
    m, d = sim.model, sim.data
    force = np.zeros(3)
    f6 = np.zeros(6)
    for i in range(d.ncon):
        c = d.contact[i]
        mujoco.mj_contactForce(m, d, i, f6)
        frame = np.asarray(c.frame).reshape(3, 3)  # rows: the contact normal (geom1 -> geom2) and tangents
        on_geom2 = frame.T @ f6[:3]  # the force geom1 exerts on geom2 (world)
        # the pair is (surface, tool tip): the force the tool exerts on the surface is the opposite
        force -= on_geom2
    _truth.append(np.concatenate([[d.time], force, d.qpos[sim.arm_qpos_adr]]))


def _save_truth():
    if _truth:
        tmp = _truth_path + ".part.npy"
        np.save(tmp, np.asarray(_truth))
        os.replace(tmp, _truth_path)


_transmit = _stream.StateStreamMixin.start_robot_state_transmission


def _transmit_marked(self, *args, **kwargs):
    _local.server = self
    try:
        return _transmit(self, *args, **kwargs)
    finally:
        _local.server = None


def _patch_server():
    from franka_sim import franka_sim_server as _server

    cls = _server.FrankaSimServer
    dispatch = cls._dispatch_control_command
    finish = cls._finish_motion

    def dispatched(self, command, *args, **kwargs):
        self._hinfnn_answered = int(command["message_id"])
        self._hinfnn_streaming = True
        return dispatch(self, command, *args, **kwargs)

    def finished(self, command, *args, **kwargs):
        self._hinfnn_streaming = False
        out = finish(self, command, *args, **kwargs)
        with _lock:
            _save_truth()
        return out

    cls._dispatch_control_command = dispatched
    cls._finish_motion = finished


_sim.MujocoFrankaSim.run_simulation = _idle_physics
_sim.MujocoFrankaSim.get_robot_state = _get_state_stepped
_stream.StateStreamMixin.start_robot_state_transmission = _transmit_marked
_patch_server()

if __name__ == "__main__":
    from franka_sim.run_server import main

    main()
