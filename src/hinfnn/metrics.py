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
#: Trajectory fields that summarise every step between samples (see hinfnn.sim.simulate).
STEP_FIELDS = ("tau_abs_max", "tau_variation", "tau_sq", "e_u1_sq", "e_lam_sq", "steps_out_of_contact",
               "e_u1_abs_max", "e_lam_abs_max")
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
    first = int(np.argmax(window))  # the first sample of the window
    e_u1 = np.linalg.norm(traj.e_u1.reshape(len(t), -1), axis=1)
    e_lam = np.linalg.norm(traj.e_lam.reshape(len(t), -1), axis=1)
    tau = traj.tau
    dt_s = t[1] - t[0] if len(t) > 1 else 1.0
    span = max(t[-1] - t[first], dt_s)
    if all(k in traj.arrays for k in STEP_FIELDS):
        # Every step, whatever the storage: sample i summarises the steps in (t_{i-1}, t_i].
        per = int(traj.save_every)
        n_all, n_win = (len(t) - 1) * per + 1, (len(t) - 1 - first) * per + 1

        def rms(name, own):  # own: the window's first sample's own contribution
            total = np.sum(traj.arrays[name], axis=0)
            win = own + np.sum(traj.arrays[name][first + 1:], axis=0)
            return np.sqrt(total / n_all), np.sqrt(win / n_win)

        rms_u1, rms_u1_w = rms("e_u1_sq", e_u1[first] ** 2)
        rms_lam, rms_lam_w = rms("e_lam_sq", e_lam[first] ** 2)
        _, rms_tau_w = rms("tau_sq", tau[first] ** 2)
        max_u1, max_lam = np.max(traj.e_u1_abs_max), np.max(traj.e_lam_abs_max)
        peak = traj.tau_abs_max
        peak_window = np.concatenate([np.abs(tau[first:first + 1]), peak[first + 1:]])
        variation = traj.tau_variation[first + 1:]
        out_of_contact = np.sum(traj.steps_out_of_contact) / n_all
    else:  # a trajectory without the step summaries (e.g. fields=...): from the samples
        tw = tau[first:]
        rms_u1, rms_u1_w, rms_lam, rms_lam_w = _rms(e_u1), _rms(e_u1[first:]), _rms(e_lam), _rms(e_lam[first:])
        rms_tau_w = _rms(tw)
        max_u1, max_lam = np.max(e_u1), np.max(e_lam)
        peak = np.abs(tau)
        peak_window = peak[first:]
        variation = np.abs(np.diff(tw, axis=0))
        out_of_contact = np.mean(traj.normal_force <= 0.0)
    lhs = float(traj.J_aug[-1] + traj.V[-1] - traj.V[0])
    rhs = float(traj.supply[-1])
    holds = bool(lhs <= rhs) if np.isfinite(lhs) and np.isfinite(rhs) else None
    margin_t = (traj.supply - (traj.J_aug + traj.V - traj.V[0]))[1:]  # t > 0 (at t = 0 it is 0)
    margin = float(np.min(margin_t)) if margin_t.size else math.nan
    return {
        "rms_e_u1": float(rms_u1),
        "max_abs_e_u1": float(max_u1),
        "rms_e_u1_last2s": float(rms_u1_w),
        "rms_e_lam": float(rms_lam),
        "max_abs_e_lam": float(max_lam),
        "rms_e_lam_last2s": float(rms_lam_w),
        "J_T": float(traj.J[-1]),
        "peak_abs_tau": [float(v) for v in np.max(peak, axis=0)],
        "peak_abs_tau_last2s": [float(v) for v in np.max(peak_window, axis=0)],
        "rms_tau_last2s": [float(v) for v in rms_tau_w],
        "tv_rate_tau_last2s": [float(v) for v in np.sum(variation, axis=0) / span],
        "fraction_out_of_contact": float(out_of_contact),
        "dissipation_lhs": lhs,
        "dissipation_rhs": rhs,
        "dissipation_holds": holds,
        "dissipation_min_margin": margin,
        "dissipation_holds_for_all_t": bool(margin >= 0) if np.isfinite(margin) else None,
    }
