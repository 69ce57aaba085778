"""Typed errors. Each names the field, the value and what is allowed (docs/architecture.md)."""

from __future__ import annotations

import numbers


def is_integer(value) -> bool:
    """A whole number as a user may give one: a Python or NumPy integer (``np.int64(2)``), not a
    bool. The checks that take counts (threads, draws, steps) use it, then ``int(value)``."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def is_real(value) -> bool:
    """A real number as a user may give one: a Python or NumPy int or float (``np.float32(0.05)``),
    not a bool (``np.True_`` is not a number either). The checks then take ``float(value)``."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


class HinfnnError(Exception):
    """Base class of every error hinfnn raises on purpose."""


class ConfigError(HinfnnError, ValueError):
    """A scenario value, file or command-line override is invalid.

    ``key`` is the dotted path of the offending value (``plant.arm.m1``) when there is one.
    """

    def __init__(self, message: str, key: str | None = None):
        self.key = key
        super().__init__(f"{key}: {message}" if key else message)


class DesignError(HinfnnError, ValueError):
    """A controller cannot be designed with the given model and gains.

    Raised at construction (``Controller.design``) when a condition of Theorem 1/2 or of a
    Remark fails (beta_lam below its bound, no stabilising Riccati solution, R_p of the wrong
    shape, singular Jacobian at the start pose ...). ``key`` names the gain when there is one,
    ``value`` and ``bound`` give the numbers that decided it.
    """

    def __init__(self, message: str, key: str | None = None, value=None, bound=None):
        self.key = key
        self.value = value
        self.bound = bound
        super().__init__(f"{key}: {message}" if key else message)


class SimulationError(HinfnnError, RuntimeError):
    """A run failed: non-finite state, torque or penetration past its limit.

    ``t_fail`` is the time of the first failing step and ``details`` the offending quantities.
    """

    def __init__(self, message: str, t_fail: float | None = None, details: dict | None = None):
        self.t_fail = t_fail
        self.details = details or {}
        super().__init__(message)


class LoadError(HinfnnError, ValueError):
    """A result file is missing, truncated, or not written by hinfnn."""


class HinfnnWarning(UserWarning):
    """Something the user should know that does not stop a command (the ``hinfnn`` command
    prints it as one line ``hinfnn: warning: ...``)."""
