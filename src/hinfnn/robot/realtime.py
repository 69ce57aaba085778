"""Real-time scheduling of the robot loop's thread (docs/robot.md, "Real-time scheduling").

A 1-kHz loop on a general-purpose kernel is late when the scheduler gives its core to something
else for more than the slack of one period. A robot's control process therefore runs its loop under
the kernel's real-time policy ``SCHED_FIFO``: a runnable FIFO thread preempts every ordinary
(``SCHED_OTHER``) thread at once and keeps its core until it blocks. libfranka does the same
(``RealtimeConfig::kEnforce``, its default: the control thread at the highest FIFO priority, or an
exception), and so does ros2_control's controller manager.

:func:`realtime` sets it for the calling thread only, for the duration of a ``with`` block, and
puts the thread's previous policy, priority and CPU set back afterwards, so a long-lived Python
process (a notebook, a test run) is left as it was. Three modes (:data:`MODES`):

* ``"auto"`` (the default of ``hinfnn robot run``): ``SCHED_FIFO`` at :data:`PRIORITY` where the
  process may (root, ``CAP_SYS_NICE`` or an ``rtprio`` limit in ``/etc/security/limits.conf``),
  otherwise the ordinary policy, with the reason recorded;
* ``"enforce"``: ``SCHED_FIFO`` or a :class:`~hinfnn.errors.SimulationError` saying why, before the
  robot starts (libfranka's ``kEnforce``);
* ``"off"``: the ordinary policy.

``cpu``: pin the thread to this CPU, or these CPUs (``os.sched_setaffinity``), while it runs; None
leaves its CPU set alone. :func:`loop_cpu` resolves ``"auto"`` (the default of ``hinfnn robot
run``): the process's last CPU where it has two or more and the loop is real-time scheduled, so that
the loop's thread is not moved between cores nor queued behind another real-time thread (the virtual
robot's served clock then runs on the other CPUs). The kernel's real-time throttling
(``/proc/sys/kernel/sched_rt_runtime_us``, 95 % by default) still leaves the other threads 5 % of
each core, so a loop that never blocks cannot freeze the machine. Memory is not locked
(``mlockall``): the loop allocates nothing large once it runs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os

from ..errors import ConfigError, SimulationError

#: The scheduling modes: "auto" (real time where permitted), "enforce" (real time or an error), "off".
MODES = ("auto", "enforce", "off")
#: The loop thread's SCHED_FIFO priority (1..99): above the kernel's threaded interrupt handlers' 50,
#: below its own watchdog and migration threads' 99.
PRIORITY = 80


@dataclasses.dataclass(frozen=True)
class Scheduling:
    """How a loop thread was scheduled: ``policy`` ("SCHED_FIFO" or "SCHED_OTHER"), ``priority``
    (0 for SCHED_OTHER), ``cpus`` (the CPUs it could run on), ``mode`` (as asked) and ``note`` (why
    it is not real time when it was asked for, else empty)."""

    policy: str
    priority: int
    cpus: tuple[int, ...]
    mode: str
    note: str = ""

    @property
    def realtime(self) -> bool:
        """Whether the thread ran under SCHED_FIFO."""
        return self.policy == "SCHED_FIFO"

    def as_dict(self) -> dict:
        """JSON-ready fields (the run's ``robot.realtime`` in metrics.json)."""
        return {"policy": self.policy, "priority": self.priority, "cpus": list(self.cpus), "mode": self.mode,
                "note": self.note}

    def line(self) -> str:
        """One line for the log and the CLI."""
        where = f" on CPU {','.join(map(str, self.cpus))}" if self.cpus else ""
        what = f"{self.policy} priority {self.priority}" if self.realtime else self.policy
        return f"{what}{where}" + (f" ({self.note})" if self.note else "")


def check_mode(mode, key: str = "realtime") -> str:
    """``mode`` if it is one of :data:`MODES`, else a ConfigError naming ``key``."""
    if mode not in MODES:
        raise ConfigError(f"must be one of {', '.join(map(repr, MODES))}, got {mode!r}", key=key)
    return mode


def check_cpu(cpu, key: str = "cpu"):
    """``cpu`` if it is None, ``"auto"``, a CPU this process may run on or a non-empty collection of
    them (as a frozenset), else a ConfigError naming ``key``."""
    if cpu is None or cpu == "auto":
        return cpu
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    many = isinstance(cpu, (set, frozenset, list, tuple))
    items = list(cpu) if many else [cpu]
    if not items or any(isinstance(c, bool) or not isinstance(c, int) or (allowed and c not in allowed) for c in items):
        raise ConfigError(f"must be \"auto\", None or CPUs this process may run on "
                          f"({', '.join(map(str, allowed)) or 'none known'}), got {cpu!r}", key=key)
    return frozenset(items) if many else cpu


def loop_cpu(cpu, mode: str) -> int | None:
    """The loop thread's CPU: ``cpu`` as given (None: any), or for ``"auto"`` the last CPU this
    process may run on when it may run on two or more and ``mode`` is not "off" (else None)."""
    cpu = check_cpu(cpu)
    if cpu != "auto":
        return cpu
    cpus = _cpus()
    return cpus[-1] if mode != "off" and len(cpus) >= 2 else None


def _policy_name(policy: int) -> str:
    return "SCHED_FIFO" if policy == getattr(os, "SCHED_FIFO", -1) else \
        "SCHED_RR" if policy == getattr(os, "SCHED_RR", -1) else "SCHED_OTHER"


def _cpus() -> tuple[int, ...]:
    return tuple(sorted(os.sched_getaffinity(0))) if hasattr(os, "sched_getaffinity") else ()


def thread_scheduling():
    """The calling thread's (policy, sched_param), for :func:`restore_scheduling`; None where the
    platform has no scheduling calls."""
    return (os.sched_getscheduler(0), os.sched_getparam(0)) if hasattr(os, "sched_getscheduler") else None


def restore_scheduling(saved) -> None:
    """Put back what :func:`thread_scheduling` saved (a refusal is ignored: lowering is always
    permitted, raising was permitted when it was saved)."""
    if saved is not None:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, saved[0], saved[1])


@contextlib.contextmanager
def realtime(mode: str = "auto", priority: int = PRIORITY, cpu=None):
    """The calling thread under SCHED_FIFO at ``priority`` (and on ``cpu``, if given) inside the
    ``with`` block, as ``mode`` asks (:data:`MODES`; ``cpu``: a CPU or a collection of CPUs, or
    "auto": :func:`loop_cpu`); yields the :class:`Scheduling` it got. On
    exit the thread's previous policy, priority and CPU set are restored, whatever ends the block.
    ``mode = "enforce"`` raises :class:`~hinfnn.errors.SimulationError` when the kernel refuses. A
    thread already real-time scheduled at ``priority`` or above (libfranka sets its control thread to
    the highest) is left as it is."""
    check_mode(mode)
    cpu = loop_cpu(cpu, mode)
    if not 1 <= int(priority) <= 99:
        raise ConfigError(f"must be a SCHED_FIFO priority in 1..99, got {priority!r}", key="priority")
    can = hasattr(os, "sched_setscheduler") and hasattr(os, "SCHED_FIFO")
    old_affinity = _cpus() if cpu is not None and hasattr(os, "sched_setaffinity") else None
    old = thread_scheduling() if can else None
    already = can and old[0] in (os.SCHED_FIFO, os.SCHED_RR) and old[1].sched_priority >= int(priority)
    note = ""
    try:
        if old_affinity is not None:
            os.sched_setaffinity(0, set(cpu) if isinstance(cpu, frozenset) else {cpu})
        if mode != "off" and not already:
            if not can:
                note = "this platform has no SCHED_FIFO"
            else:
                try:
                    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
                except OSError as err:
                    note = (f"the kernel refused SCHED_FIFO ({err.strerror or err}): run as root, with "
                            "CAP_SYS_NICE, or with an rtprio limit of at least the priority in "
                            "/etc/security/limits.conf")
            if note and mode == "enforce":
                raise SimulationError(f"real-time scheduling was asked for (scheduling = \"enforce\") but {note}")
        policy = _policy_name(os.sched_getscheduler(0)) if can else "SCHED_OTHER"
        prio = int(os.sched_getparam(0).sched_priority) if can else 0
        yield Scheduling(policy=policy, priority=prio, cpus=_cpus(), mode=mode, note=note)
    finally:
        if old is not None and not already:
            restore_scheduling(old)
        if old_affinity is not None:
            with contextlib.suppress(OSError):
                os.sched_setaffinity(0, set(old_affinity))


__all__ = ["MODES", "PRIORITY", "Scheduling", "check_cpu", "check_mode", "loop_cpu", "realtime", "restore_scheduling",
           "thread_scheduling"]
