"""How a run ended: one enumeration, with its messages, for the simulator, metrics, results,
sweeps and reports (diffrax's ``RESULTS`` habit).

The simulator stores a run's status as the integer value of a :class:`RunStatus` member (it
travels through compiled programs and ``.npz`` files as an int32), with the time of the failing
step and the numbers that decided it (``fail_details``). Everything that says how a run ended in
words asks this module: :meth:`RunStatus.describe` for one line with the numbers,
:attr:`RunStatus.outcome` for the three words the sweep tables and reports use ("ok",
"diverged": stopped early, "invalid": never started because its scenario failed a check).
"""

from __future__ import annotations

import enum
import math

#: The three outcomes of a run as sweep tables and reports name them.
OUTCOMES = ("ok", "diverged", "invalid")


class RunStatus(enum.IntEnum):
    """Why a run ended. ``OK``: it reached t_final; the others stopped it at ``t_fail`` (its metrics
    are kept up to then, marked partial), except ``INVALID`` (a sweep's draw that could not start)."""

    OK = 0
    NONFINITE = 1
    TORQUE_LIMIT = 2
    PENETRATION_LIMIT = 3
    CONTROLLER_FAULT = 4
    PLANT_FAULT = 5
    SAFETY_STOP = 6
    INVALID = -1

    @property
    def message(self) -> str:
        """The status in a few words."""
        return _MESSAGES[self]

    @property
    def outcome(self) -> str:
        """"ok", "diverged" (stopped early) or "invalid" (never started)."""
        if self is RunStatus.OK:
            return "ok"
        return "invalid" if self is RunStatus.INVALID else "diverged"

    def describe(self, details: dict | None = None) -> str:
        """Why the run stopped, in words, with the numbers that decided it (``details``: the
        trajectory's ``fail_details``: the numbers, the names the controller and the plant give
        their fault measures, ``controller_fault`` and ``plant_fault``, the plant's name for
        the item of its fault, ``fault_item``, and for a robot run the safety rule that stopped it,
        ``safety_rule``, with its message and values, ``safety_message``)."""
        d = details or {}
        what = self.message
        if self is RunStatus.NONFINITE:
            parts = int(_num(d.get("nonfinite_parts"), 0))
            names = [n for i, n in enumerate(NONFINITE_PARTS) if parts & (1 << i)]
            return (f"{what} ({', '.join(names) or 'state'}; peak |tau| at the step before = "
                    f"{_num(d.get('tau_peak')):.4g} N·m)")
        if self is RunStatus.TORQUE_LIMIT:
            return f"{what} (peak |tau| = {_num(d.get('tau_peak')):.4g} N·m)"
        if self is RunStatus.PENETRATION_LIMIT:
            return f"{what} (penetration = {_num(d.get('penetration')):.4g} m)"
        if self is RunStatus.SAFETY_STOP:  # a robot run (hinfnn.robot): the rule that fired, in words
            return f"{what}: {d.get('safety_rule') or 'a rule'} ({d.get('safety_message') or 'no details'})"
        if self in (RunStatus.CONTROLLER_FAULT, RunStatus.PLANT_FAULT):
            name = d.get("controller_fault" if self is RunStatus.CONTROLLER_FAULT else "plant_fault")
            item = d.get("fault_item") if self is RunStatus.PLANT_FAULT else None
            at = f" at {item}" if item else ""
            return f"{what} ({name or 'its measure'} = {_num(d.get('fault_value')):.4g}{at})"
        return what


_MESSAGES = {
    RunStatus.OK: "ok",
    RunStatus.NONFINITE: "non-finite state",
    RunStatus.TORQUE_LIMIT: "torque limit exceeded",
    RunStatus.PENETRATION_LIMIT: "penetration limit exceeded",
    RunStatus.CONTROLLER_FAULT: "stopped by the controller's guard",
    RunStatus.PLANT_FAULT: "stopped by the plant's guard",
    RunStatus.SAFETY_STOP: "stopped by the robot's safety layer",
    RunStatus.INVALID: "not simulated: the scenario failed a check",
}

#: Bits of ``fail_details["nonfinite_parts"]``: which part of the state became non-finite.
NONFINITE_PARTS = ("plant state (q, q̇)", "controller state", "accumulated J, V-supply")


def _num(x, default=math.nan) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return default


def status_of(code) -> RunStatus:
    """The member of an integer code (as stored in a Trajectory or a file)."""
    return RunStatus(int(code))


__all__ = ["RunStatus", "OUTCOMES", "NONFINITE_PARTS", "status_of"]
