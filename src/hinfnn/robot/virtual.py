"""A virtual robot: hinfnn's MuJoCo plant served in its own process, in wall-clock real time.

:class:`VirtualRobot` starts a server process (``multiprocessing``, spawned) that builds the
scenario's true plant (``plant.engine = "mujoco"``: :class:`hinfnn.plant.mujoco.MujocoPlant`) at
the scenario's start pose and then advances it by one control period h at each tick of the wall
clock (t0 + k h), holding the newest torque the loop wrote (zero-order hold), and publishes the
reading of each new state. The truth's sensor and motors (``[plant.sensor]``, ``[plant.actuator]``:
:mod:`hinfnn.plant.instruments`) act as in a simulation: the published reading is what the sensor
gives at that sample (noise from the same seeded stream, bias, delay, bandwidth), and the torque
that drives the plant is the written one through the motors' torque and rate limits less the
joints' friction. The loop and the server share two small blocks of memory (a reading and
a command, each behind a sequence counter): the loop reaches the plant only through the
:class:`~hinfnn.robot.Robot` interface, so the timing, the jitter and the late cycles are real.
A tick at which no fresh torque has arrived since the previous one holds the old torque again and
counts as missed (:attr:`~hinfnn.robot.Reading.missed`: missed ticks in a row). In real time a
reading is stamped (:attr:`~hinfnn.robot.Reading.wall`) with its tick, so the torque for it is due
one period after that stamp and the loop's lateness is against the robot's next tick. A sensor at
least one sample late (``plant.sensor.delay`` ≥ 1, as a real robot's reading is) gives at a tick a
reading known before it (:meth:`hinfnn.plant.instruments.Sensor.upcoming`): the server publishes it
at the tick and then steps the plant and acquires the new sample while the loop computes, so the
loop has the whole period, with the same readings and torques as stepping first. With an ideal or
undelayed sensor the server steps the plant after the tick and publishes then, so the loop has a
period less that step's time to answer. The first reading has no tick (NaN): the clock starts with
the first torque. The server runs every compiled call on its own thread (JAX's CPU async dispatch
off). A server held up by its own machine for more than half a period moves its clock on by the delay (counted in
:attr:`VirtualRobot.server_behind`) rather than stepping the plant several times in a row with a
stale torque: a real robot's clock never lags, so the lateness a run sees is the loop's own.

Faults for tests (:class:`Fault`), applied to what the server publishes, at robot time: a force
spike (``force_spike``, ``value`` N added along the measured force), a sensor dropout (``dropout``:
the previous reading published again, its time not advancing), a NaN reading (``nan``: q of
``joint``), a lost contact (``lost_contact``: the force reads zero, as if the part were taken
away), a joint at its limit (``joint_limit``: q of ``joint`` reads ``value`` inside its upper
limit), time going backwards (``time_back``: ``value`` s earlier); and on the loop's side a
stalled cycle (``stall``: the write is delayed by ``duration`` s, as if the loop's process had
been descheduled).
"""

from __future__ import annotations

import dataclasses
import gc
import math
import time
from pathlib import Path

import numpy as np

from ..errors import ConfigError, SimulationError
from .realtime import check_cpu, check_mode
from .realtime import realtime as scheduled
from .base import Reading, Robot, require_sampled

#: The fault kinds :class:`VirtualRobot` injects (``stall`` on the loop's side, the others in the server).
FAULTS = ("force_spike", "dropout", "nan", "lost_contact", "joint_limit", "time_back", "stall")

# the server's state word
_STARTING, _READY, _RUNNING, _STOP, _ENDED = 0, 1, 2, 3, 4
#: How long the server may take to build its plant, s (a first MuJoCo scene and its step's compile).
START_TIMEOUT = 300.0


@dataclasses.dataclass(frozen=True)
class Fault:
    """A fault injected at robot time ``t`` (s) for ``duration`` s (0: one reading); ``value`` and
    ``joint`` (0-based) as the kind needs them (module docstring)."""

    kind: str
    t: float
    duration: float = 0.0
    value: float = 0.0
    joint: int = 0

    def __post_init__(self):
        if self.kind not in FAULTS:
            raise ConfigError(f"unknown fault {self.kind!r}; allowed: {', '.join(FAULTS)}", key="fault.kind")
        for name in ("t", "duration", "value"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)) or (name != "value" and v < 0):
                raise ConfigError(f"must be a finite number{'' if name == 'value' else ' >= 0'}, got {v!r}",
                                  key=f"fault.{name}")

    def active(self, t: float, fired: bool) -> bool:
        """Whether the fault applies to a reading at robot time ``t`` (``fired``: it applied before)."""
        return t >= self.t - 1e-12 and (t <= self.t + self.duration + 1e-12 or not fired)


def _publish(buf: np.ndarray, values) -> None:
    buf[0] += 1.0  # odd: being written
    buf[1:] = values
    buf[0] += 1.0


#: How long before a tick the served clock, and the loop awaiting a reading, stop sleeping and wait
#: awake, s: a core that goes idle in a sleep can take hundreds of microseconds to wake (in a virtual
#: machine, its virtual CPU is descheduled by the host), which a 1-kHz loop cannot spare.
SPIN = 2e-4


def _on_host(meas) -> tuple:
    """(q, q̇, force) of a measurement as NumPy arrays (what :func:`serve` publishes)."""
    return tuple(np.array(a, dtype=float) for a in (meas.q, meas.qd, meas.force))


def _snapshot(buf: np.ndarray):
    """(seq, copy of the values), or (None, None) while the block is being written."""
    s0 = buf[0]
    if int(s0) % 2:
        return None, None
    vals = buf[1:].copy()
    return (s0, vals) if buf[0] == s0 else (None, None)


def _blocks(buf, n: int, d: int):
    """The reading, command and state blocks in one shared buffer (each with its counter first)."""
    a = np.ndarray((4 + 2 * n + d + 1 + n + 2,), dtype=np.float64, buffer=buf)
    r = 4 + 2 * n + d
    return a[:r], a[r:r + 1 + n], a[r + 1 + n:]


def serve(config: dict) -> None:
    """The server process (``python -m hinfnn.robot._server``, its ``config`` pickled on stdin):
    build the plant, schedule its thread (``config["scheduling"]``, in real time only: :mod:`.realtime`),
    say ``ready`` and how it is scheduled (JSON) on stdout, wait for ``start`` on stdin, then step the
    plant in real time until told to stop."""
    import contextlib
    import json
    import sys
    from multiprocessing import resource_tracker, shared_memory

    shm = shared_memory.SharedMemory(name=config["shm"])
    resource_tracker.unregister(shm._name, "shared_memory")  # the loop's process owns it
    R, C, S = _blocks(shm.buf, config["n"], config["d"])
    period, faults, limit, realtime = config["period"], config["faults"], config["limit"], config["realtime"]

    def say(what):
        sys.stdout.write(what.replace("\n", " ") + "\n")
        sys.stdout.flush()
    try:
        import jax
        import jax.numpy as jnp

        import hinfnn
        from hinfnn.scenario import Scenario

        hinfnn.configure(async_dispatch=False)  # every compiled call on this (real-time) thread
        sc = Scenario.from_dict(config["scenario"], source=config["source"], check=False)
        setup = sc.build()
        plant = setup.plant
        state = plant.initial_state(np.asarray(setup.start_q, dtype=float))
        n = int(plant.n)
        step = jax.jit(lambda t, s, tau: plant.step(t, s, tau, period)[0])
        step(0.0, state, jnp.zeros(n)).q.block_until_ready()  # compiled before the clock starts
        upper = np.asarray(plant.joint_limits()[1], dtype=float)
        # the truth's sensor and motors (plant.sensor, plant.actuator), as the simulator applies them
        sensor, act = plant.sensor, plant.actuator
        if sensor is not None:
            from hinfnn.protocols import Measurement

            def true_reading(s):
                return Measurement(q=s.q, qd=s.qd, force=s.force)

            sense = jax.jit(lambda k, s, st: sensor.read(k, period, true_reading(s), st))
            sensed = sensor.start(true_reading(state))
            sense(0, state, sensed)[0].q.block_until_ready()

            if sensor.delay >= 1:  # the sensor's state after acquiring sample k, and its reading at k + 1
                def _acquire(k, s, st):
                    st = sensor.read(k, period, true_reading(s), st)[1]
                    return st, sensor.upcoming(st)

                acquire = jax.jit(_acquire)
                acquire(0, state, sensed)[0].out.q.block_until_ready()
        if act is not None:
            def _drive(tau, previous, first, qd):
                applied = act.apply(tau, previous, period, first)
                return applied, applied - act.friction(qd)

            actuate = jax.jit(_drive)
            applied = jnp.zeros(n)
            actuate(jnp.zeros(n), applied, True, state.qd)[0].block_until_ready()
    except Exception as err:  # noqa: BLE001 - reported to the loop's process as one line
        say(f"error {type(err).__name__}: {' '.join(str(err).split())}")
        return
    hold = contextlib.ExitStack()  # the process's thread stays scheduled so until the process ends
    try:
        how = hold.enter_context(scheduled(config["scheduling"] if realtime else "off",
                                           cpu=None if not realtime or config["cpus"] is None else set(config["cpus"])))
    except SimulationError as err:
        say(f"error {err}")
        return
    S[0] = _READY
    say("ready " + json.dumps(how.as_dict()))
    if sys.stdin.readline().strip() != "start":
        return
    fired = [False] * len(faults)
    prev = None
    if sensor is None:
        sensed = None

    # A sensor at least one sample late (delay d >= 1, as a real robot's reading is) gives at sample k
    # an acquisition of sample k - d <= k - 1: it is known before the plant is stepped to sample k, so
    # the reading is published at the tick and the plant stepped after it, while the loop computes (the
    # same readings and torques as stepping first; lock-step runs take the same path). With an ideal or
    # undelayed sensor the plant is stepped first.
    ahead = sensor is not None and sensor.delay >= 1
    upcoming = None

    def publish(k, state, missed, tick=None, reading=None):
        nonlocal prev, sensed
        t = k * period
        if reading is None:
            reading = state
            if sensor is not None:  # what the robot's sensor gives at sample k (noise, bias, delay, bandwidth)
                reading, sensed = sense(k, state, sensed)
            reading = _on_host(reading)
        q, qd, force = reading  # NumPy arrays made for this reading (a fault may change them)
        for i, f in enumerate(faults):
            if f.kind == "stall" or not f.active(t, fired[i]):
                continue
            fired[i] = True
            if f.kind == "force_spike":
                fn = np.linalg.norm(force)
                force = force + f.value * (force / fn if fn > 0 else np.eye(len(force))[-1])
            elif f.kind == "dropout" and prev is not None:
                _publish(R, prev)
                return
            elif f.kind == "nan":
                q[f.joint] = math.nan
            elif f.kind == "lost_contact":
                force = np.zeros_like(force)
            elif f.kind == "joint_limit":
                q[f.joint] = upper[f.joint] - f.value
            elif f.kind == "time_back":
                t = t - f.value
        prev = np.concatenate([[t, time.perf_counter() if tick is None else tick, float(missed)], q, qd, force])
        _publish(R, prev)

    S[0] = _RUNNING
    publish(0, state, 0, math.nan if realtime else None)  # no tick yet: the clock starts with the first torque
    if ahead:
        upcoming = _on_host(sensor.upcoming(sensed))
    gc.collect()  # the served plant's clock must not stop for a collection (the loop's side does the same)
    gc.disable()
    while C[0] < 2 and S[0] == _RUNNING:  # the clock starts with the first torque (the arm held until then)
        time.sleep(1e-4)
    t0 = time.perf_counter()
    k, last, missed, behind = 0, 0.0, 0, 0
    while S[0] == _RUNNING and (k + 1) * period <= limit + 1e-9:
        if realtime:
            deadline = t0 + (k + 1) * period
            wait = deadline - time.perf_counter()
            if wait > SPIN:  # asleep until just before the tick, then awake on the clock (:data:`SPIN`)
                time.sleep(wait - SPIN)
            if wait > 0:
                while time.perf_counter() < deadline:
                    pass
            elif wait < -0.5 * period:  # the server itself was held up: its clock slips (a robot never lags)
                t0 -= wait
                behind += 1
        else:  # lock-step: the next tick when the torque of this one has come
            while C[0] == last and S[0] == _RUNNING:
                time.sleep(2e-5)
        seq, tau = _snapshot(C)
        while seq is None:
            seq, tau = _snapshot(C)
        if seq == last:
            missed += 1
        else:
            missed, last = 0, seq
        if not np.all(np.isfinite(tau)):  # never given to the engine: the robot's own guard
            tau = np.zeros(n)
        drive = jnp.asarray(tau)
        if act is not None:  # the motors: torque and rate limits, then the joints' friction
            applied, drive = actuate(drive, applied, k == 0, state.qd)
        # in real time a reading is stamped with its tick (the torque for it is due one period later),
        # not with when the step that made it ended: the loop's lateness is against the robot's next tick
        tick = t0 + (k + 1) * period if realtime else None
        if ahead:  # the reading of sample k + 1 at its tick, before the plant is stepped to it
            publish(k + 1, None, missed, tick, reading=upcoming)
        state = step(k * period, state, drive)
        k += 1
        if ahead:  # the new sample acquired, and the reading it makes due at the next tick
            sensed, upcoming = acquire(k, state, sensed)
            upcoming = _on_host(upcoming)
        else:
            publish(k, state, missed, tick)
    S[1] = behind
    S[0] = _ENDED
    del R, C, S
    shm.close()


class VirtualRobot(Robot):
    """The scenario's MuJoCo plant as a robot, in its own process, in wall-clock real time.

    ``VirtualRobot(scenario, faults=(), limit=None)``: ``scenario`` a single-controller
    :class:`~hinfnn.scenario.Scenario` with ``plant.engine = "mujoco"`` (ConfigError naming
    ``plant.engine`` otherwise) and ``simulation.control = "sampled"``; the robot's period is the
    scenario's control period. ``limit``: the server ends after this much robot time, s (default:
    ``simulation.t_final`` plus a second for the stop). ``faults``: :class:`Fault` items. Use it
    as a context manager or call :meth:`start` / :meth:`stop`; the server process ends with
    :meth:`stop`, when the loop's process ends, or at ``limit``. ``realtime=False``: lock-step, for
    tests of behaviour that must not depend on the machine's load: each tick waits for the torque
    of the previous reading (no late cycles; the same numbers as a simulation of the same job).
    ``scheduling`` ("auto", "enforce", "off"): the served clock's thread under SCHED_FIFO in real
    time (:mod:`hinfnn.robot.realtime`; a real robot's controller runs on its own real-time computer),
    on ``cpus`` (a collection of CPUs; None: any), reported by :meth:`report`; lock-step runs are never
    real-time scheduled nor pinned.
    """

    clock_waits = True  # the served clock starts with the first torque (the arm held until then)

    def __init__(self, scenario, faults=(), limit: float | None = None, realtime: bool = True,
                 scheduling: str = "auto", cpus=None):
        if scenario.plant.engine != "mujoco":
            raise ConfigError(f"the virtual robot serves the MuJoCo plant: set plant.engine = \"mujoco\", got "
                              f"{scenario.plant.engine!r}", key="plant.engine")
        require_sampled(scenario)
        self.scenario = scenario
        self.realtime = bool(realtime)
        self.scheduling = check_mode(scheduling, key="scheduling")
        self.cpus = check_cpu(None if cpus is None else frozenset(cpus), key="cpus")
        #: How the server's clock thread is scheduled (:meth:`hinfnn.robot.realtime.Scheduling.as_dict`),
        #: once started.
        self.server_scheduling: dict | None = None
        self.period = float(scenario.simulation.control_period)
        self.faults = tuple(faults)
        for f in self.faults:
            if not isinstance(f, Fault):
                raise ConfigError(f"must be hinfnn.robot.Fault items, got {type(f).__name__}", key="faults")
        arm = scenario.build().nominal_arm  # its sizes: the plant itself is built in the server only
        self.n, self.d = int(arm.n), int(arm.space_dim)
        self.limit = float(scenario.simulation.t_final + scenario.safety.stop_time + scenario.safety.retract_time
                           + 1.0 if limit is None else limit)
        self._proc = None
        self.server_behind = 0
        self._last = 0.0  # the reading's counter: 0 before the first one, then 2, 4, ...
        self._next = 0.0
        self._stalls = [f for f in self.faults if f.kind == "stall"]
        self._stalled = [False] * len(self._stalls)
        self._t = 0.0

    def start(self) -> None:
        """Start the server process, wait until its plant is built and its step compiled, start the
        clock."""
        import os
        import json
        import pickle
        import subprocess
        import sys
        from multiprocessing import shared_memory

        if self._proc is not None:
            raise SimulationError("the virtual robot is already started")
        n, d = self.n, self.d
        self._shm = shared_memory.SharedMemory(create=True, size=8 * (4 + 2 * n + d + 1 + n + 2))
        self._r, self._c, self._s = _blocks(self._shm.buf, n, d)
        self._r[:] = 0.0
        self._c[:] = 0.0
        self._s[:] = 0.0
        src = str(Path(__file__).resolve().parents[2])  # the hinfnn this process runs, first on the server's path
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([src, *filter(None, [os.environ.get("PYTHONPATH")])])}
        self._proc = subprocess.Popen([sys.executable, "-m", "hinfnn.robot._server"], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, env=env)
        config = {"scenario": self.scenario.to_dict(), "source": self.scenario.source, "period": self.period,
                  "faults": self.faults, "limit": self.limit, "shm": self._shm.name, "n": n, "d": d,
                  "realtime": self.realtime, "scheduling": self.scheduling,
                  "cpus": None if self.cpus is None else sorted(self.cpus)}
        self._proc.stdin.write(pickle.dumps(config))
        self._proc.stdin.flush()
        line = self._proc.stdout.readline().decode(errors="replace").strip()
        if line.split(" ", 1)[0] != "ready":
            detail = line[len("error "):] if line.startswith("error ") else \
                f"its process ended (exit code {self._proc.poll()})"
            self._end()
            raise SimulationError(f"the virtual robot could not start: {detail}")
        self.server_scheduling = json.loads(line[len("ready"):] or "null")
        self._proc.stdin.write(b"start\n")
        self._proc.stdin.flush()

    def read(self) -> Reading:
        """The next reading (the newest when several came since the last call); blocks until it
        comes. A SimulationError when the server ended or sends nothing for a second."""
        r = self._r
        give_up = time.perf_counter() + max(1.0, 100 * self.period)
        nap = self._next - time.perf_counter() - SPIN  # the next tick is not due before then
        if nap > 0:
            time.sleep(nap)
        while True:
            seq, vals = _snapshot(r)
            if seq is not None and seq > self._last:
                break
            if time.perf_counter() > give_up or self._proc.poll() is not None:
                raise SimulationError(f"the virtual robot sent no reading after t = {self._t:.6g} s "
                                      f"(server {'ended' if self._proc.poll() is not None else 'silent'})",
                                      t_fail=self._t)
            if not self.realtime or time.perf_counter() > self._next + self.period:
                time.sleep(2e-5)  # in real time the reading is awaited awake, up to a period late (:data:`SPIN`)
        self._last = seq
        n, d = self.n, self.d
        self._t = float(vals[0])
        self._next = float(vals[1]) + self.period
        return Reading(t=float(vals[0]), q=vals[3:3 + n], qd=vals[3 + n:3 + 2 * n], force=vals[3 + 2 * n:3 + 2 * n + d],
                       missed=int(vals[2]), wall=float(vals[1]))

    def write(self, tau) -> None:
        """Send the torque the server holds from its next tick (N·m, n values)."""
        for i, f in enumerate(self._stalls):
            if not self._stalled[i] and self._t >= f.t - 1e-12:
                self._stalled[i] = True
                time.sleep(f.duration)
        _publish(self._c, np.asarray(tau, dtype=float))

    def report(self) -> dict:
        """The served clock's side of the run (the result's ``robot.device``): how its thread was
        scheduled (:class:`hinfnn.robot.realtime.Scheduling` as a dict; None before a start) and the
        ticks at which it was itself a period or more behind."""
        return {"robot": "virtual", "server_realtime": self.server_scheduling, "server_behind": self.server_behind}

    def stop(self) -> None:
        """Stop the server's clock and its process."""
        if self._proc is None:
            return
        self._s[0] = _STOP
        self._end()

    def _end(self):
        import subprocess

        proc, self._proc = self._proc, None
        self.server_behind = int(self._s[1])  # ticks at which the server was a period or more behind
        try:
            proc.stdin.close()
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            proc.terminate()
            proc.wait(5.0)
        finally:
            proc.stdout.close()
            self._r = self._c = self._s = None
            self._shm.close()
            self._shm.unlink()



__all__ = ["FAULTS", "Fault", "VirtualRobot"]
