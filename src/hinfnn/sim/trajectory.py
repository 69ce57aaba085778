"""The result of a run: plain NumPy arrays plus the configuration that produced them."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

#: Status codes of a run (``Trajectory.status``).
STATUS = {0: "ok", 1: "non-finite state", 2: "torque limit exceeded", 3: "penetration limit exceeded"}

#: Fields that summarise the steps since the previous sample, and how to merge two intervals.
INTERVAL_FIELDS = {"tau_abs_max": np.maximum, "tau_variation": np.add, "e_u1_sq": np.add,
                   "e_lam_sq": np.add, "tau_sq": np.add, "steps_out_of_contact": np.add,
                   "e_u1_abs_max": np.maximum, "e_lam_abs_max": np.maximum}

#: Arrays a Trajectory carries, with their units, for files and figures.
FIELDS = {
    "t": "s",
    "q": "rad",
    "qd": "rad/s",
    "u1": "m",
    "u1_dot": "m/s",
    "lam": "λ units (N·cos δ̂ with the paper's scaling)",
    "u1_d": "m",
    "u1_d_dot": "m/s",
    "lam_d": "λ units",
    "e_u1": "m",
    "e_u1_dot": "m/s",
    "e_lam": "λ units",
    "z": "λ units",
    "v_p": "m/s²",
    "v_lam": "λ units",
    "nn_p": "m/s²",
    "nn_f": "λ units",
    "tau": "N·m",
    "tau_abs_max": "N·m (max |τ_i| over the steps since the previous sample)",
    "tau_variation": "N·m (Σ|τ_i(t_k) − τ_i(t_k−1)| over the steps since the previous sample)",
    "tau_sq": "(N·m)² (Σ τ_i² over the steps since the previous sample, this one included)",
    "e_u1_sq": "m² (Σ ‖e_u1‖² over the steps since the previous sample, this one included)",
    "e_lam_sq": "(λ units)² (Σ ‖e_λ‖² over the steps since the previous sample, this one included)",
    "steps_out_of_contact": "- (steps with zero normal force since the previous sample, this one included)",
    "e_u1_abs_max": "m (max ‖e_u1‖ over the steps since the previous sample, this one included)",
    "e_lam_abs_max": "λ units (max ‖e_λ‖ over the steps since the previous sample, this one included)",
    "F": "N",
    "normal_force": "N",
    "penetration": "m",
    "disturbance": "N·m",
    "x_true": "m",
    "theta_p_norm": "-",
    "theta_f_norm": "-",
    "J": "-",
    "J_aug": "-",
    "supply": "-",
    "V": "-",
    "f_p": "m/s²",
    "f_f": "λ units",
}

#: Named selections for ``simulate(..., fields=...)``: ``"metrics"`` is what
#: :func:`hinfnn.compute_metrics` needs (17 of the 39 fields: 21 numbers per sample for the planar
#: arm instead of 48).
FIELD_SETS = {
    "all": tuple(FIELDS),
    "metrics": ("t", "e_u1", "e_lam", "tau", "normal_force", "J", "J_aug", "V", "supply", "tau_abs_max",
                "tau_variation", "tau_sq", "e_u1_sq", "e_lam_sq", "steps_out_of_contact", "e_u1_abs_max",
                "e_lam_abs_max"),
}


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """A simulated run (or a batch, with a leading batch axis on every array).

    ``J`` is the H∞ index of eq. (34) integrated as a state; ``J_aug`` adds Remark 1's terms
    when the controller is augmented (else equals ``J``); ``supply`` is ρ²∫(‖f_p‖² + ‖f_f‖²) dt
    with f_p, f_f the actual residuals of eqs. (28)–(29)/(52)–(53); ``V`` the storage function.
    ``final`` holds the full state at t_final (q, qd, z, theta_p, theta_f and the accumulators).
    ``status``/``t_fail``: 0 and NaN for a completed run, else the code of :data:`STATUS` and the
    time of the failing step. ``config`` is the run's full configuration (a plain dict).
    """

    arrays: dict[str, np.ndarray]
    status: np.ndarray
    t_fail: np.ndarray
    fail_details: dict[str, np.ndarray]
    config: dict[str, Any]
    dt: float
    save_every: int
    final: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def __getattr__(self, name):
        arrays = self.__dict__.get("arrays", {})
        if name in arrays:
            return arrays[name]
        raise AttributeError(name)

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
        cfg = self.config
        if isinstance(cfg, dict) and isinstance(cfg.get("members"), list):
            cfg = cfg["members"][i]
        return Trajectory(
            arrays={k: v[i] for k, v in self.arrays.items()},
            status=self.status[i], t_fail=self.t_fail[i],
            fail_details={k: v[i] for k, v in self.fail_details.items()},
            config=cfg, dt=self.dt, save_every=self.save_every,
            final={k: v[i] for k, v in self.final.items()})

    @property
    def ok(self):
        return np.asarray(self.status) == 0

    def decimated(self, max_interval: float) -> "Trajectory":
        """Every s-th sample, s the largest divisor of the step count with s·dt·save_every ≤
        ``max_interval``, so the samples stay uniform and the final one is kept."""
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
            if k in INTERVAL_FIELDS:  # sample i covers (t_{i-1}, t_i]: merge the stride intervals
                merged = INTERVAL_FIELDS[k].reduceat(np.take(v, np.arange(1, n_intervals + 1), axis=axis),
                                                     np.arange(0, n_intervals, stride), axis=axis)
                arrays[k] = np.concatenate([np.take(v, [0], axis=axis), merged], axis=axis)
            else:
                arrays[k] = np.take(v, idx, axis=axis)
        return dataclasses.replace(self, arrays=arrays, save_every=self.save_every * stride)
