"""The real-time loop: one runner for any :class:`~hinfnn.robot.Robot` (docs/robot.md).

Each cycle, :func:`run_loop` reads the robot, passes the reading through the safety layer
(:mod:`hinfnn.robot.safety`), calls the sampled controller once
(:meth:`hinfnn.controllers.SampledLoop.update`: eq. (24) at the sample, its state advanced by
forward Euler over the time since the previous reading), clamps the torque and writes it, and
logs the cycle: the reading, the torque the law asked for and the one sent, whether the reading
reached the controller, the cycle's latency (from the reading's return to the write's) and its
lateness (the write against the robot's next tick: > 0 means the robot held the previous torque
once more). A rejected reading never reaches the controller: the previous torque is held and the
controller's state is not advanced. After a stop the robot is held (and, on a contact loss,
retracted) by the safety layer's hold for ``stop_time`` s (plus ``retract_time``), or as many cycles
when the robot's time stands still, then the loop ends.

:func:`trajectory` turns the log into a :class:`~hinfnn.sim.Trajectory` (the same fields as a
simulation's, by replaying the accepted readings through the same law, plus the loop's own), so
a robot run is written, loaded, shown, plotted and exported as a simulated one.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import math
import time

import numpy as np

from ..controllers.job import PROCESS
from ..protocols import Measurement, needs_start
from ..status import RunStatus
from . import safety as S
from .base import Robot
from .realtime import Scheduling, realtime

#: The loop's own recorded fields (beside those of the law; units in :data:`hinfnn.fields.FIELDS`).
LOOP_FIELDS = ("force_measured", "tau_law", "t_reading", "cycle_latency", "cycle_lateness", "missed_ticks", "control_h",
               "accepted", "safety_mode")

CONTROL, HOLD, RETRACT = 0, 1, 2
#: Events of one rule written to the log one by one (the rest are counted).
LOGGED_PER_RULE = 20


@dataclasses.dataclass
class LoopLog:
    """What one loop run did, cycle by cycle (NumPy arrays after :func:`run_loop` returns), its
    events (:class:`~hinfnn.robot.safety.Event`, at most :data:`LOGGED_PER_RULE` of each rule),
    ``counts`` (every event by rule), the ``stop`` that ended it (None: it reached t_final) and the
    robot's period; ``scheduling``: how the loop's thread was scheduled
    (:class:`~hinfnn.robot.realtime.Scheduling`)."""

    period: float
    rows: dict
    events: list
    counts: dict
    stop: S.Event | None
    seconds: float = 0.0
    scheduling: Scheduling | None = None

    def summary(self) -> dict:
        """Latency and lateness percentiles, late and rejected cycles, the ticks at which the robot
        held the previous torque (as the robot reports them: ``missed_ticks``), the events by rule:
        the ``robot`` entry of metrics.json."""
        lat = np.asarray(self.rows["cycle_latency"])
        late = np.asarray(self.rows["cycle_lateness"])
        missed = np.asarray(self.rows["missed_ticks"])
        runs = _runs(late > 0)

        def pct(a):
            a = a[np.isfinite(a)]
            return {k: (float(np.percentile(a, p)) if a.size else None)
                    for k, p in (("p50", 50), ("p90", 90), ("p99", 99), ("max", 100))}
        return {
            "period": self.period,
            "cycles": int(lat.size),
            "wall_seconds": self.seconds,
            "latency_s": pct(lat),
            "lateness_s": pct(late),
            "late_cycles": int(np.sum(late > 0)),
            "late_fraction": float(np.mean(late > 0)) if late.size else 0.0,
            "longest_late_run": int(max(runs, default=0)),
            "max_missed_in_a_row": int(np.max(missed)) if missed.size else 0,
            "missed_ticks": int(np.sum(missed > 0)),
            "missed_tick_fraction": float(np.mean(missed > 0)) if missed.size else 0.0,
            "rejected": sum(k for rule, k in self.counts.items() if S.RULES[rule] == "reject"),
            "events": dict(self.counts),
            "stop": None if self.stop is None else self.stop.to_dict(),
            "realtime": None if self.scheduling is None else self.scheduling.as_dict(),
        }

    def lines(self) -> list[str]:
        """The run's log: one line per logged event, then the counts."""
        out = [e.line() for e in self.events]
        out += [f"{rule}: {n} event(s)" for rule, n in sorted(self.counts.items())]
        out.append("stopped by " + self.stop.line() if self.stop is not None else "completed: reached t_final")
        return out


def _runs(flags) -> list[int]:
    out, n = [], 0
    for f in flags:
        if f:
            n += 1
        elif n:
            out.append(n)
            n = 0
    if n:
        out.append(n)
    return out


@contextlib.contextmanager
def _no_collection():
    """Python's cyclic garbage collector held off for the loop (a full collection of a large process
    takes milliseconds: a late cycle), re-enabled (if it was on) when the loop ends, whatever ends it.
    Collect before the robot starts (:func:`hinfnn.robot.run.run_robot` does: a full collection
    of a large process takes tens of milliseconds, which a started robot's watchdog counts). The
    loop's own allocations are freed by reference counting as usual."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def run_loop(robot: Robot, sampled, limits: S.SafetyLimits, *, t_final: float, gravity, point_jacobian,
             log=None, scheduling: str = "off", cpu=None, warm=None) -> LoopLog:
    """Drive ``robot`` with ``sampled`` (a :class:`hinfnn.controllers.SampledController`, its
    compiled update warmed up before the call) until the robot's time reaches ``t_final`` or the
    safety layer stops it. ``gravity(q)``, ``point_jacobian(q)``: the nominal arm's G and tool-point
    Jacobian as NumPy (the hold and the retraction). ``log(line)``: each event as it fires. The
    robot must be started; the loop does not stop it. Python's cyclic garbage collector is held
    off while the loop runs (:func:`_no_collection`; collect before starting the robot). ``scheduling``
    (:data:`hinfnn.robot.realtime.MODES`) and ``cpu``: the calling thread's real-time scheduling while
    the loop runs (:func:`hinfnn.robot.realtime.realtime`), recorded as the log's ``scheduling``.
    ``warm()``: called once on the scheduled thread, pinned to its CPU, before the first reading when
    the robot's clock waits for the first torque (:attr:`~hinfnn.robot.Robot.clock_waits`): the law's
    first calls are slower than the rest, and calls made where the loop then runs shorten its first
    cycle (not its second: docs/robot.md, "What was tested")."""
    with realtime(scheduling, cpu=cpu) as how, _no_collection():
        if warm is not None and getattr(robot, "clock_waits", False):
            warm()
        out = _drive(robot, sampled, limits, t_final=t_final, gravity=gravity, point_jacobian=point_jacobian, log=log)
    out.scheduling = how
    return out


def _drive(robot: Robot, sampled, limits: S.SafetyLimits, *, t_final: float, gravity, point_jacobian,
           log=None) -> LoopLog:
    period = robot.period
    loop = sampled.loop()
    phase_of = getattr(loop, "phase", None) or (lambda: None)
    n = robot.n
    rows = {k: [] for k in ("t", "q", "qd", "tau", *LOOP_FIELDS)}
    events, counts = [], {}
    stop = None
    mode = CONTROL
    t_prev = None
    tau_prev = None  # the first torque is clamped to the limits only (the robot's torque before is unknown)
    rejected_row, last_reject = 0, None
    low_since = None
    good = None  # the last accepted reading (q, qd, force)
    pressing = None  # the last accepted force at or above contact_loss_force (where the surface is)
    q_hold = dq = None
    t_stop = 0.0
    held = 0  # cycles since the stop
    perf = time.perf_counter
    start = perf()

    def note(ev: S.Event):
        counts[ev.rule] = counts.get(ev.rule, 0) + 1
        if counts[ev.rule] <= LOGGED_PER_RULE:
            events.append(ev)
            if log is not None:
                log(ev.line())

    while True:
        r = robot.read()
        w0 = perf()
        t_read = float(r.t)
        t = t_read if (t_prev is None or (math.isfinite(t_read) and t_read > t_prev)) else t_prev
        accepted = False
        tau_law = np.full(n, np.nan)
        h = math.nan
        if mode == CONTROL:
            ev = S.watchdog(limits, t, r.missed) or S.check_reading(limits, t_read, t_prev, r.q, r.qd, r.force)
            if ev is not None and ev.action == "reject":
                note(ev)
                rejected_row, last_reject = rejected_row + 1, ev
                ev = S.too_many_rejected(limits, t, rejected_row, ev)
            elif ev is None:
                rejected_row = 0
                ev = S.check_state(limits, t, r.q, r.qd, r.force)
                phase = phase_of()  # a job's phase (None: the paper's law alone, in contact throughout)
                if ev is None and phase is not None:
                    ev = S.no_contact(t, phase)
                if ev is None and phase in (None, PROCESS):
                    low_since, ev = S.contact_loss(limits, t, r.force, low_since)
                elif ev is None:
                    low_since = None  # approach, ramp, unload, lift-off: off the surface by design
                if ev is None:
                    h = period if t_prev is None else t_read - t_prev
                    tau_law = loop.update(t_read, h, r.q, r.qd, r.force)
                    accepted = True
                    good = (np.array(r.q), np.array(r.qd), np.array(r.force))
                    if np.linalg.norm(good[2]) >= limits.contact_loss_force:
                        pressing = good[2]
                    sent, clamps = S.clamp_torque(limits, t, tau_law, tau_prev)
                    for c in clamps:
                        if c.action == "stop":
                            ev = c
                        else:
                            note(c)
                    if ev is None:
                        tau_prev = sent
            if ev is not None and ev.action in ("stop", "retract"):
                note(ev)
                stop, t_stop = ev, t
                q_hold = good[0] if good is not None else np.array(r.q)
                mode = RETRACT if ev.action == "retract" else HOLD
                dq = np.zeros(n)
                if mode == RETRACT and pressing is not None:
                    dq = S.retract_step(point_jacobian(q_hold), pressing, limits.retract_distance)
        if mode != CONTROL:
            finite = np.all(np.isfinite(r.q)) and np.all(np.isfinite(r.qd))
            q_now, qd_now = (np.asarray(r.q), np.asarray(r.qd)) if finite else (q_hold, np.zeros(n))
            target = S.retract_target(limits, q_hold, dq, t_stop, t) if mode == RETRACT else q_hold
            want = S.hold_torque(limits, gravity(q_now), target, q_now, qd_now)
            sent, clamps = S.clamp_torque(limits, t, want, tau_prev)
            tau_prev = sent
        if tau_prev is None:  # stopped before a first torque: the hold's gravity torque at the start pose
            tau_prev = np.asarray(gravity(q_hold), dtype=float) if q_hold is not None and np.all(np.isfinite(q_hold)) \
                else np.zeros(n)
        robot.write(tau_prev)
        w1 = perf()
        if t_prev is None or t > t_prev:
            t_prev = t
        wall = r.wall if math.isfinite(r.wall) else w0
        for k, v in (("t", t), ("t_reading", t_read), ("q", r.q), ("qd", r.qd), ("force_measured", r.force),
                     ("tau", tau_prev), ("tau_law", tau_law), ("cycle_latency", w1 - w0),
                     ("cycle_lateness", w1 - (wall + period)), ("missed_ticks", r.missed), ("control_h", h),
                     ("accepted", 1.0 if accepted else 0.0), ("safety_mode", float(mode))):
            rows[k].append(np.array(v, dtype=float))
        if mode == CONTROL and t >= t_final - 1e-9:
            break
        if mode != CONTROL:  # the hold lasts its time, or as many cycles where the robot's time stands still
            held += 1
            span = limits.stop_time + (limits.retract_time if mode == RETRACT else 0.0)
            if t - t_stop >= span - 1e-9 or held > span / period + 0.5:
                break
    return LoopLog(period=period, rows={k: np.stack(v) for k, v in rows.items()}, events=events, counts=counts,
                   stop=stop, seconds=perf() - start)


def trajectory(log: LoopLog, sampled, info):
    """The run as a :class:`~hinfnn.sim.Trajectory`: the law's signals at each accepted reading
    (the accepted readings replayed, in order, through the same compiled law from its initial
    state: the loop's own numbers, eqs. (24)–(33)), held over the cycles whose reading was rejected
    and over the hold after a stop, with the loop's fields (:data:`LOOP_FIELDS`); τ is the torque
    sent. Status :attr:`~hinfnn.status.RunStatus.SAFETY_STOP` with the rule's time as t_fail when
    the safety layer stopped the run."""
    import jax

    from ..sim import Trajectory

    rows = log.rows
    m = len(rows["t"])
    state = sampled.init()
    started = not needs_start(sampled.controller)
    signals = None
    for i in range(m):
        if rows["accepted"][i]:
            meas = Measurement(q=rows["q"][i], qd=rows["qd"][i], force=rows["force_measured"][i])
            t = float(rows["t_reading"][i])
            if not started:
                state, started = sampled._start(t, state, meas), True
            h = float(rows["control_h"][i])
            _, sig = sampled._torque_and_signals(t, state, meas)
            _, state = sampled._update(t, h, state, meas)
            sig = jax.device_get(sig)
            if signals is None:
                signals = {k: np.full((m,) + np.shape(v), np.nan) for k, v in sig.items()}
            for k, v in sig.items():
                signals[k][i:] = v  # held until the next accepted reading
    arrays = {k: np.asarray(v) for k, v in rows.items()}
    for k, v in (signals or {}).items():
        if k != "tau":
            arrays[k] = v
    stop = log.stop
    status = np.asarray(0 if stop is None else int(RunStatus.SAFETY_STOP), dtype=np.int32)
    details = {} if stop is None else {"safety_rule": stop.rule, "safety_message": stop.message}
    return Trajectory(arrays=arrays, status=status, t_fail=np.asarray(math.nan if stop is None else stop.t),
                      fail_details=details, dt=log.period, save_every=1, info=info)


__all__ = ["LOOP_FIELDS", "LoopLog", "run_loop", "trajectory"]
