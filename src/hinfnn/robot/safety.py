"""The safety layer of a robot loop: what is clamped, what is rejected before it reaches the
controller, and what stops the robot (docs/robot.md).

Every rule is a pure function of NumPy numbers (the loop runs it once per cycle, outside any
compiled program) and its limits (:class:`SafetyLimits`, from the scenario's ``[safety]`` section
and the nominal arm). A rule that fires returns an :class:`Event`: its name, the robot time, what
it does (``reject``: the reading never reaches the controller and the previous torque is held;
``stop``: the robot holds its position and the loop ends; ``retract``: it holds, backs away from
the surface and the loop ends; ``clamp``: the torque is limited) and the values that decided it.

The rules, in the order the loop applies them to each reading:

1. :func:`check_reading` — a non-finite reading (``nonfinite_reading``: stop); time that is
   negative (``time_negative``), does not advance (``time_not_advancing``) or jumps by more than
   ``max_period_ratio`` control periods (``period_too_long``); a force or a joint rate outside the
   sensor's range (``force_out_of_range``, ``velocity_out_of_range``): rejected.
2. :func:`check_state` on an accepted reading — the force ceiling (``force_limit``), the joint
   speed (``velocity_limit``) and the joints' limits less a margin (``joint_limit_margin``): stop.
3. :func:`contact_loss` — the force below ``contact_loss_force`` for ``contact_loss_time`` after
   ``contact_loss_after`` (``contact_loss``): hold and retract; for a job
   (:mod:`hinfnn.controllers.job`) only in its process phase (the tool is meant to be off the
   surface in the approach and the lift-off, and the force builds up in the ramp). A job whose
   guarded move found no contact (``no_contact``, :func:`no_contact`): stop.
4. :func:`watchdog` — ``watchdog_misses`` control periods in a row without a fresh torque at the
   robot (``watchdog``): stop; :func:`too_many_rejected` — ``max_rejected`` readings rejected in a
   row (``rejected_readings``): stop.
5. :func:`clamp_torque` on the controller's torque — a non-finite torque (``nonfinite_torque``:
   stop), then each joint's torque to ±``torque_limit`` and its change per period to
   ``torque_rate_limit`` · h (``torque_limit``, ``torque_rate_limit``: clamp).

After a stop the robot is held by :func:`hold_torque` (a joint-space spring and damper about the
pose where it stopped, plus the nominal gravity torque), through the same clamps.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

#: Every rule's name, with what it does when it fires.
RULES = {
    "nonfinite_reading": "stop",
    "time_negative": "reject",
    "time_not_advancing": "reject",
    "period_too_long": "reject",
    "force_out_of_range": "reject",
    "velocity_out_of_range": "reject",
    "force_limit": "stop",
    "velocity_limit": "stop",
    "joint_limit_margin": "stop",
    "contact_loss": "retract",
    "no_contact": "stop",
    "watchdog": "stop",
    "rejected_readings": "stop",
    "nonfinite_torque": "stop",
    "torque_limit": "clamp",
    "torque_rate_limit": "clamp",
}


@dataclasses.dataclass(frozen=True)
class Event:
    """A rule that fired: ``rule`` (a key of :data:`RULES`), the robot time ``t`` (s), ``action``
    (``reject``, ``stop``, ``retract`` or ``clamp``), ``message`` (what happened, with the values
    and the limit) and ``values`` (the numbers, JSON-ready)."""

    rule: str
    t: float
    message: str
    values: dict = dataclasses.field(default_factory=dict)

    @property
    def action(self) -> str:
        return RULES[self.rule]

    def line(self) -> str:
        """One line for the run's log."""
        return f"t = {self.t:.6f} s: {self.rule} ({self.action}): {self.message}"

    def to_dict(self) -> dict:
        return {"rule": self.rule, "t": self.t, "action": self.action, "message": self.message,
                "values": self.values}


@dataclasses.dataclass(frozen=True)
class SafetyLimits:
    """The limits the rules check, as NumPy numbers (one per joint where per joint)."""

    period: float
    torque: np.ndarray
    torque_rate: float
    force_limit: float
    force_range: float
    velocity_limit: float
    velocity_range: float
    lower: np.ndarray
    upper: np.ndarray
    joint_margin: float
    contact_loss_force: float
    contact_loss_time: float
    contact_loss_after: float
    retract_distance: float
    retract_time: float
    hold_stiffness: float
    hold_damping: float
    stop_time: float
    max_period_ratio: float
    max_rejected: int
    watchdog_misses: int

    @classmethod
    def from_config(cls, safety, *, period: float, n: int, effort=None, lower=None, upper=None,
                    fallback_torque: float = math.inf) -> "SafetyLimits":
        """From a scenario's ``[safety]`` section (:class:`~hinfnn.scenario.sections.SafetyConfig`),
        the control period and the nominal arm's joints: ``effort`` (the URDF's effort limits, the
        torque clamp when ``safety.torque_limit`` is empty; an unlimited joint takes
        ``fallback_torque``), ``lower``/``upper`` (joint limits, ±inf where none). A
        ``torque_limit`` of another length than the arm's joints is a ConfigError naming it."""
        from ..errors import ConfigError

        if safety.torque_limit:
            if len(safety.torque_limit) not in (1, n):
                raise ConfigError(f"must give one value or one per joint ({n}), got {len(safety.torque_limit)}: "
                                  f"{list(safety.torque_limit)}", key="safety.torque_limit")
            torque = np.broadcast_to(np.asarray(safety.torque_limit, dtype=float), (n,)).copy()
        else:
            torque = np.full(n, math.inf) if effort is None else np.asarray(effort, dtype=float).copy()
            torque[~np.isfinite(torque) | (torque <= 0)] = fallback_torque
        full = (lambda v, fill: np.full(n, fill) if v is None else np.asarray(v, dtype=float))
        return cls(period=float(period), torque=torque, torque_rate=float(safety.torque_rate_limit),
                   force_limit=float(safety.force_limit), force_range=float(safety.force_range),
                   velocity_limit=float(safety.velocity_limit), velocity_range=float(safety.velocity_range),
                   lower=full(lower, -math.inf), upper=full(upper, math.inf),
                   joint_margin=float(safety.joint_limit_margin), contact_loss_force=float(safety.contact_loss_force),
                   contact_loss_time=float(safety.contact_loss_time),
                   contact_loss_after=float(safety.contact_loss_after),
                   retract_distance=float(safety.retract_distance), retract_time=float(safety.retract_time),
                   hold_stiffness=float(safety.hold_stiffness), hold_damping=float(safety.hold_damping),
                   stop_time=float(safety.stop_time), max_period_ratio=float(safety.max_period_ratio),
                   max_rejected=int(safety.max_rejected), watchdog_misses=int(safety.watchdog_misses))

    @property
    def max_period(self) -> float:
        """The longest time between two readings the controller is given, s."""
        return self.max_period_ratio * self.period

    def summary(self) -> dict:
        """The limits as plain numbers (None for an unlimited value), for the run's log."""
        def num(v):
            if np.ndim(v):
                return [num(x) for x in np.asarray(v).tolist()]
            if isinstance(v, (int, np.integer)):
                return int(v)
            return float(v) if math.isfinite(v) else None
        return {f.name: num(getattr(self, f.name)) for f in dataclasses.fields(self)}


def _vec(a) -> list:
    return [float(x) for x in np.asarray(a, dtype=float).reshape(-1)]


def check_reading(limits: SafetyLimits, t: float, t_prev: float | None, q, qd, force) -> Event | None:
    """Rule 1: whether a reading may reach the controller. ``t_prev``: the time of the previous
    reading (None for the first). A non-finite value anywhere: ``nonfinite_reading`` (stop);
    t < 0, t ≤ t_prev, t − t_prev > ``max_period``, ‖force‖ > ``force_range``, max |q̇_i| >
    ``velocity_range``: a rejection. None: the reading is usable."""
    parts = {"t": np.asarray(t, dtype=float), "q": np.asarray(q, dtype=float), "qd": np.asarray(qd, dtype=float),
             "force": np.asarray(force, dtype=float)}
    bad = [k for k, v in parts.items() if not np.all(np.isfinite(v))]
    tt = float(t) if np.isfinite(parts["t"]).all() else math.nan
    if bad:
        return Event("nonfinite_reading", tt if math.isfinite(tt) else (t_prev or 0.0),
                     f"non-finite {', '.join(bad)} in the reading", {k: _vec(parts[k]) for k in bad})
    if tt < 0.0:
        return Event("time_negative", tt, f"reading time {tt:g} s < 0", {"t": tt})
    if t_prev is not None:
        h = tt - t_prev
        if h <= 0.0:
            return Event("time_not_advancing", tt, f"reading time {tt:.9g} s does not advance past the previous "
                         f"{t_prev:.9g} s", {"t": tt, "t_prev": t_prev})
        if h > limits.max_period:
            return Event("period_too_long", tt, f"{h:.6g} s since the previous reading, more than "
                         f"{limits.max_period_ratio:g} periods ({limits.max_period:.6g} s)",
                         {"h": h, "max_period": limits.max_period})
    fn = float(np.linalg.norm(parts["force"]))
    if fn > limits.force_range:
        return Event("force_out_of_range", tt, f"force reading {fn:.6g} N outside the sensor's range "
                     f"({limits.force_range:g} N)", {"force": _vec(parts["force"]), "force_range": limits.force_range})
    vmax = float(np.max(np.abs(parts["qd"]))) if parts["qd"].size else 0.0
    if vmax > limits.velocity_range:
        j = int(np.argmax(np.abs(parts["qd"])))
        return Event("velocity_out_of_range", tt, f"joint {j + 1} rate reading {parts['qd'][j]:.6g} outside the "
                     f"sensor's range ({limits.velocity_range:g})", {"joint": j + 1, "qd": _vec(parts["qd"])})
    return None


def check_state(limits: SafetyLimits, t: float, q, qd, force) -> Event | None:
    """Rule 2, on an accepted reading: ‖force‖ > ``force_limit``, a joint rate above
    ``velocity_limit``, a joint within ``joint_margin`` of its limit: a stop. None: go on."""
    force = np.asarray(force, dtype=float)
    fn = float(np.linalg.norm(force))
    if fn > limits.force_limit:
        return Event("force_limit", float(t), f"contact force {fn:.6g} N above the ceiling {limits.force_limit:g} N",
                     {"force": _vec(force), "force_limit": limits.force_limit})
    qd = np.asarray(qd, dtype=float)
    if qd.size and float(np.max(np.abs(qd))) > limits.velocity_limit:
        j = int(np.argmax(np.abs(qd)))
        return Event("velocity_limit", float(t), f"joint {j + 1} moves at {qd[j]:.6g}, above the limit "
                     f"{limits.velocity_limit:g}",
                     {"joint": j + 1, "qd": _vec(qd), "velocity_limit": limits.velocity_limit})
    q = np.asarray(q, dtype=float)
    margin = np.minimum(q - limits.lower, limits.upper - q)
    if margin.size and float(np.min(margin)) < limits.joint_margin:
        j = int(np.argmin(margin))
        return Event("joint_limit_margin", float(t), f"joint {j + 1} at {q[j]:.6g} is {margin[j]:.4g} from its limit "
                     f"[{limits.lower[j]:.6g}, {limits.upper[j]:.6g}] (margin {limits.joint_margin:g})",
                     {"joint": j + 1, "q": _vec(q), "margin": float(margin[j])})
    return None


def contact_loss(limits: SafetyLimits, t: float, force, low_since: float | None) -> tuple[float | None, Event | None]:
    """Rule 3: ``(low_since, event)``. ``low_since`` is the time the force fell below
    ``contact_loss_force`` (None while it is above, or before ``contact_loss_after``); the event
    fires once it has stayed below for ``contact_loss_time``."""
    fn = float(np.linalg.norm(np.asarray(force, dtype=float)))
    if t < limits.contact_loss_after or fn >= limits.contact_loss_force:
        return None, None
    since = t if low_since is None else low_since
    if t - since >= limits.contact_loss_time - 1e-12:
        return since, Event("contact_loss", float(t), f"contact force {fn:.4g} N below {limits.contact_loss_force:g} N "
                            f"since t = {since:.6f} s", {"force": _vec(force), "since": since})
    return since, None


def no_contact(t: float, phase) -> Event | None:
    """Rule 3, for a job: its guarded move went its whole travel without finding contact
    (:data:`hinfnn.controllers.job.NO_CONTACT`, phase 5): a stop."""
    from ..controllers.job import NO_CONTACT

    if phase != NO_CONTACT:
        return None
    return Event("no_contact", float(t), "the job's approach went its whole travel (job.approach_height + "
                 "job.approach_margin) without the force reaching job.contact_force", {"phase": int(phase)})


def watchdog(limits: SafetyLimits, t: float, missed_in_a_row: int) -> Event | None:
    """Rule 4: the robot reports ``missed_in_a_row`` control periods in a row that got no fresh
    torque (it held the previous one): at ``watchdog_misses`` or more, a stop."""
    if missed_in_a_row >= limits.watchdog_misses:
        return Event("watchdog", float(t), f"{missed_in_a_row} control periods in a row without a fresh torque "
                     f"(limit {limits.watchdog_misses})", {"missed_in_a_row": int(missed_in_a_row)})
    return None


def too_many_rejected(limits: SafetyLimits, t: float, rejected_in_a_row: int, last: Event) -> Event | None:
    """Rule 4: ``max_rejected`` readings rejected in a row (the last one by ``last``): a stop."""
    if rejected_in_a_row >= limits.max_rejected:
        return Event("rejected_readings", float(t), f"{rejected_in_a_row} readings rejected in a row, the last by "
                     f"{last.rule} ({last.message})", {"rejected_in_a_row": int(rejected_in_a_row), "last": last.rule})
    return None


def clamp_torque(limits: SafetyLimits, t: float, tau, tau_prev, h: float | None = None):
    """Rule 5: ``(τ sent, events)``. A non-finite τ: ``nonfinite_torque`` (the caller stops; τ sent
    is ``tau_prev``); otherwise each τ_i clipped to ±``torque`` and its change from ``tau_prev``
    to ``torque_rate`` · h (h: the control period by default), with a ``torque_limit`` or
    ``torque_rate_limit`` event naming the joints clamped. ``tau_prev`` None (the first torque of
    a run: what the robot applied before is unknown): the torque limits only."""
    tau = np.asarray(tau, dtype=float)
    prev = None if tau_prev is None else np.asarray(tau_prev, dtype=float)
    if not np.all(np.isfinite(tau)):
        bad = Event("nonfinite_torque", float(t), "the controller returned a non-finite torque", {"tau": _vec(tau)})
        return (None if prev is None else prev.copy()), [bad]
    events = []
    out = np.clip(tau, -limits.torque, limits.torque)
    hit = np.nonzero(out != tau)[0]
    if hit.size:
        events.append(Event("torque_limit", float(t), f"joints {[int(j) + 1 for j in hit]} clamped to their torque "
                            "limits", {"tau": _vec(tau), "limit": _vec(limits.torque)}))
    if prev is None:
        return out, events
    step = limits.torque_rate * (limits.period if h is None else h)
    rated = np.clip(out, prev - step, prev + step)
    hit = np.nonzero(rated != out)[0]
    if hit.size:
        events.append(Event("torque_rate_limit", float(t), f"joints {[int(j) + 1 for j in hit]} clamped to "
                            f"{limits.torque_rate:g} N·m/s", {"tau": _vec(out), "tau_prev": _vec(prev)}))
    return rated, events


def hold_torque(limits: SafetyLimits, gravity, q_target, q, qd):
    """The torque that holds the robot after a stop: τ = G(q) + K (q* − q) − D q̇, with K, D the
    ``hold_stiffness``/``hold_damping`` of every joint and G the nominal gravity torque at q."""
    return (np.asarray(gravity, dtype=float) + limits.hold_stiffness * (np.asarray(q_target) - np.asarray(q))
            - limits.hold_damping * np.asarray(qd))


def retract_target(limits: SafetyLimits, q_hold, dq, since: float, t: float):
    """The hold's joint target during a retraction: from ``q_hold`` to ``q_hold + dq`` along a
    smooth ramp s(τ) = 3τ² − 2τ³, τ = (t − since)/``retract_time`` clipped to [0, 1]."""
    s = min(max((t - since) / limits.retract_time, 0.0), 1.0)
    return np.asarray(q_hold) + (3 * s * s - 2 * s ** 3) * np.asarray(dq)


def retract_step(point_jacobian, force, distance: float):
    """The joint displacement that moves the tool point ``distance`` against the last measured
    contact force (away from the surface): Δq = J_p⁺ (−distance · F/‖F‖), J_p the nominal tool
    point's Jacobian. Zero when no force was measured."""
    f = np.asarray(force, dtype=float)
    fn = float(np.linalg.norm(f))
    J = np.asarray(point_jacobian, dtype=float)
    if not fn > 0 or not np.all(np.isfinite(J)):
        return np.zeros(J.shape[-1])
    return np.linalg.pinv(J) @ (-distance * f / fn)


__all__ = ["RULES", "Event", "SafetyLimits", "check_reading", "check_state", "contact_loss", "no_contact", "watchdog",
           "too_many_rejected", "clamp_torque", "hold_torque", "retract_target", "retract_step"]
