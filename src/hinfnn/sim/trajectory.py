"""The result of a run: plain NumPy arrays, what produced them, and how it ended."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..fields import FIELDS, SUMMARY_FIELDS

#: Status codes of a run (``Trajectory.status``).
STATUS = {0: "ok", 1: "non-finite state", 2: "torque limit exceeded", 3: "penetration limit exceeded",
          4: "stopped by the controller's singularity guard", 5: "joint limit crossed"}

_MERGE = {"max": np.maximum, "sum": np.add}


@dataclasses.dataclass(frozen=True)
class RunInfo:
    """What a run was: its name, controller kind and how reports show it (label, colour), and
    the resolved scenario it came from (a :class:`hinfnn.scenario.Scenario`, or None for runs
    built by hand)."""

    name: str = ""
    kind: str = ""
    label: str = ""
    color: str = ""
    scenario: Any = None


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """A simulated run (or a batch, with a leading batch axis on every array).

    ``arrays`` holds the recorded fields (names and units in :data:`hinfnn.fields.FIELDS`;
    :attr:`units`), sampled every ``save_every`` steps of ``dt``. ``J`` is the H∞ index of
    eq. (34) integrated as a state; ``J_aug`` adds Remark 1's terms when the controller is
    augmented (else equals ``J``); ``supply`` is ρ²∫(‖f_p‖² + ‖f_f‖²) dt with f_p, f_f the actual
    residuals of eqs. (28)–(29)/(52)–(53); ``V`` the storage function. ``final`` holds the full
    state at t_final (q, qd, the controller state's arrays and the accumulators).
    ``status``/``t_fail``: 0 and NaN for a completed run, else the code of :data:`STATUS` and the
    time of the failing step. ``info``: a :class:`RunInfo` (a tuple of them for a batch).
    """

    arrays: dict[str, np.ndarray]
    status: np.ndarray
    t_fail: np.ndarray
    fail_details: dict[str, np.ndarray]
    dt: float
    save_every: int
    final: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    info: Any = RunInfo()

    def __getattr__(self, name):
        arrays = self.__dict__.get("arrays", {})
        if name in arrays:
            return arrays[name]
        raise AttributeError(name)

    @property
    def units(self) -> dict[str, str]:
        """The unit of every stored array."""
        return {k: (FIELDS[k].unit if k in FIELDS else "-") for k in self.arrays}

    @property
    def scenario(self):
        """The resolved scenario of a single run (None for runs built by hand)."""
        return self.info.scenario if isinstance(self.info, RunInfo) else None

    @property
    def batched(self) -> bool:
        return self.arrays["t"].ndim == 2

    @property
    def batch_size(self) -> int:
        return self.arrays["t"].shape[0] if self.batched else 1

    def __len__(self) -> int:
        return self.batch_size

    def member(self, i: int) -> "Trajectory":
        """Run ``i`` of a batch as a single Trajectory."""
        if not self.batched:
            if i != 0:
                raise IndexError(i)
            return self
        info = self.info[i] if isinstance(self.info, tuple) else RunInfo()
        return Trajectory(
            arrays={k: v[i] for k, v in self.arrays.items()},
            status=self.status[i], t_fail=self.t_fail[i],
            fail_details={k: v[i] for k, v in self.fail_details.items()},
            dt=self.dt, save_every=self.save_every,
            final={k: v[i] for k, v in self.final.items()}, info=info)

    @property
    def ok(self):
        return np.asarray(self.status) == 0

    def decimated(self, max_interval: float) -> "Trajectory":
        """Every s-th sample, s the largest divisor of the step count with s·dt·save_every ≤
        ``max_interval``, so the samples stay uniform and the final one is kept; the step
        summaries are merged over the dropped samples."""
        interval = self.dt * self.save_every
        limit = max(1, int(np.floor(max_interval / interval + 1e-9)))
        n_intervals = self.arrays["t"].shape[-1] - 1
        stride = max(s for s in range(1, limit + 1) if n_intervals % s == 0) if n_intervals else 1
        if stride == 1:
            return self
        idx = np.arange(0, n_intervals + 1, stride)
        axis = 1 if self.batched else 0
        arrays = {}
        for k, v in self.arrays.items():
            if k in SUMMARY_FIELDS:  # sample i covers (t_{i-1}, t_i]: merge the stride intervals
                merged = _MERGE[SUMMARY_FIELDS[k]].reduceat(np.take(v, np.arange(1, n_intervals + 1), axis=axis),
                                                            np.arange(0, n_intervals, stride), axis=axis)
                arrays[k] = np.concatenate([np.take(v, [0], axis=axis), merged], axis=axis)
            else:
                arrays[k] = np.take(v, idx, axis=axis)
        return dataclasses.replace(self, arrays=arrays, save_every=self.save_every * stride)
