"""Run metrics: tracking errors, the H∞ index J(T) of eq. (34), torques, contact, and the
dissipation inequality of Theorems 1–2 as the two sides of

    J(T) + V(T) − V(0)  ≤  ρ² ∫₀ᵀ (‖f_p‖² + ‖f_f‖²) dt

(V the storage function of eq. 36/55 with Θ* = 0, f_p, f_f the actual residuals of the error
systems computed from the true motion; ``J_aug`` replaces J for Remark 1's augmented designs).
It follows from eq. (39)/(58) for every trajectory, so it must hold for the H∞-only and the
adaptive controllers; for the FL-like controller it is reported but not claimed.

All quantities come from a :class:`~hinfnn.sim.Trajectory`; nothing here runs a controller.
"""

from __future__ import annotations

import math

import numpy as np

METRIC_KEYS = (
    "rms_e_u1", "max_abs_e_u1", "rms_e_u1_last2s",
    "rms_e_lam", "max_abs_e_lam", "rms_e_lam_last2s",
    "J_T", "peak_abs_tau", "peak_abs_tau_last2s", "rms_tau_last2s", "tv_rate_tau_last2s",
    "fraction_out_of_contact", "dissipation_lhs", "dissipation_rhs", "dissipation_holds",
    "dissipation_min_margin", "dissipation_holds_for_all_t",
)
_PER_JOINT = ("peak_abs_tau", "peak_abs_tau_last2s", "rms_tau_last2s", "tv_rate_tau_last2s")


def _rms(x, axis=0):
    x = np.asarray(x, dtype=float)
    return np.sqrt(np.mean(x**2, axis=axis))


def compute_metrics(traj, last: float = 2.0) -> dict:
    """Metrics of one completed run (a dict of floats, lists and a bool; JSON-ready).

    ``*_last2s`` are over t ≥ t_final − ``last``. ``tv_rate_tau_last2s`` is the total variation
    of each τ_i per second over that window (how oscillatory the torque is).
    ``dissipation_min_margin`` is min over t > 0 of ρ²∫₀ᵗ(‖f_p‖²+‖f_f‖²) − (J(t) + V(t) − V(0)): the
    theorems claim the inequality for every T, not only the final one. For a run that did not
    complete, every value is NaN and the booleans are None.
    """
    if traj.batched:
        raise ValueError("compute_metrics takes one run; use traj.member(i) for a batch")
    if int(traj.status) != 0:
        out = {k: math.nan for k in METRIC_KEYS}
        for k in _PER_JOINT:
            out[k] = [math.nan] * traj.tau.shape[-1]
        out["dissipation_holds"] = out["dissipation_holds_for_all_t"] = None
        return out
    t = traj.t
    window = t >= t[-1] - last - 1e-9 * max(1.0, t[-1])
    e_u1 = np.linalg.norm(traj.e_u1.reshape(len(t), -1), axis=1)
    e_lam = np.linalg.norm(traj.e_lam.reshape(len(t), -1), axis=1)
    tau = traj.tau
    dt_s = t[1] - t[0] if len(t) > 1 else 1.0
    tw = tau[window]
    span = max(t[window][-1] - t[window][0], dt_s)
    # Peak and total variation over every step when the simulator recorded them (the stored
    # samples may be decimated), else from the samples. Sample i covers (t_{i-1}, t_i].
    first = int(np.argmax(window))
    if "tau_abs_max" in traj.arrays and "tau_variation" in traj.arrays:
        peak = traj.tau_abs_max
        peak_window = np.concatenate([np.abs(tau[first:first + 1]), peak[first + 1:]])
        variation = traj.tau_variation[first + 1:]
    else:
        peak = np.abs(tau)
        peak_window = peak[first:]
        variation = np.abs(np.diff(tw, axis=0))
    lhs = float(traj.J_aug[-1] + traj.V[-1] - traj.V[0])
    rhs = float(traj.supply[-1])
    holds = bool(lhs <= rhs) if np.isfinite(lhs) and np.isfinite(rhs) else None
    margin_t = (traj.supply - (traj.J_aug + traj.V - traj.V[0]))[1:]  # t > 0 (at t = 0 it is 0)
    margin = float(np.min(margin_t)) if margin_t.size else math.nan
    return {
        "rms_e_u1": float(_rms(e_u1)),
        "max_abs_e_u1": float(np.max(e_u1)),
        "rms_e_u1_last2s": float(_rms(e_u1[window])),
        "rms_e_lam": float(_rms(e_lam)),
        "max_abs_e_lam": float(np.max(e_lam)),
        "rms_e_lam_last2s": float(_rms(e_lam[window])),
        "J_T": float(traj.J[-1]),
        "peak_abs_tau": [float(v) for v in np.max(peak, axis=0)],
        "peak_abs_tau_last2s": [float(v) for v in np.max(peak_window, axis=0)],
        "rms_tau_last2s": [float(v) for v in _rms(tw)],
        "tv_rate_tau_last2s": [float(v) for v in np.sum(variation, axis=0) / span],
        "fraction_out_of_contact": float(np.mean(traj.normal_force <= 0.0)),
        "dissipation_lhs": lhs,
        "dissipation_rhs": rhs,
        "dissipation_holds": holds,
        "dissipation_min_margin": margin,
        "dissipation_holds_for_all_t": bool(margin >= 0) if np.isfinite(margin) else None,
    }
