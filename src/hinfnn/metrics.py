"""Run metrics: tracking errors, the H∞ index J(T) of eq. (34), torques, contact, and the
dissipation inequality of Theorems 1–2 as the two sides of

    J(T) + V(T) − V(0)  ≤  ρ² ∫₀ᵀ (‖f_p‖² + ‖f_f‖²) dt

(V the storage function of eq. 36/55 with Θ* = 0, f_p, f_f the actual residuals of the error
systems computed from the true motion; ``J_aug`` replaces J for Remark 1's augmented designs).
For a correct implementation it holds along every trajectory of the H∞-only and adaptive
controllers *by construction* (f_p and f_f are defined as the residuals, and eqs. 39/58 bound
V̇ pointwise): checking it checks the implementation against the theorem, not the paper's
practical claim that the controllers track well. For the FL-like controller it is reported but
not claimed.

All quantities come from a :class:`~hinfnn.sim.Trajectory`; nothing here runs a controller.
A run that stopped early (diverged) gets its metrics over [0, t_fail] (the step that stopped it
included), marked ``partial``. A verdict is None ("not judged") where nothing was judged.
"""

from __future__ import annotations

import math

import numpy as np

from .fields import SUMMARY_FIELDS
from .status import RunStatus

METRIC_KEYS = (
    "rms_e_u1", "max_abs_e_u1", "rms_e_u1_last2s",
    "rms_e_lam", "max_abs_e_lam", "rms_e_lam_last2s",
    "J_T", "peak_abs_tau", "peak_abs_tau_last2s", "rms_tau_last2s", "tv_rate_tau_last2s",
    "fraction_out_of_contact", "dissipation_lhs", "dissipation_rhs", "dissipation_holds",
    "dissipation_min_margin", "dissipation_holds_for_all_t",
    "rms_e_u1_each", "rms_e_u1_each_last2s", "rms_e_lam_each", "rms_e_lam_each_last2s", "min_task_margin",
    "rms_normal_force_error", "rms_normal_force_error_last2s", "fraction_torque_saturated",
)
#: Units of the metrics (machine-readable output carries them: metrics.json "units").
UNITS = {
    "rms_e_u1": "m", "max_abs_e_u1": "m", "rms_e_u1_last2s": "m",
    "rms_e_lam": "λ units", "max_abs_e_lam": "λ units", "rms_e_lam_last2s": "λ units",
    "J_T": "-", "peak_abs_tau": "N·m", "peak_abs_tau_last2s": "N·m", "rms_tau_last2s": "N·m",
    "tv_rate_tau_last2s": "N·m/s", "fraction_out_of_contact": "-", "dissipation_lhs": "-",
    "dissipation_rhs": "-", "dissipation_holds": "bool", "dissipation_min_margin": "-",
    "dissipation_holds_for_all_t": "bool", "t_end": "s", "partial": "bool",
    "rms_e_u1_each": "m or rad", "rms_e_u1_each_last2s": "m or rad", "rms_e_lam_each": "λ units",
    "rms_e_lam_each_last2s": "λ units", "min_task_margin": "rad or m",
    "rms_normal_force_error": "N", "rms_normal_force_error_last2s": "N", "fraction_torque_saturated": "-",
}
#: The verdicts and what they rest on (:func:`verdicts`): ``compute_metrics(...)["verdict"]``, one
#: dict (metrics.json: each run's "verdict", next to its status); not among :data:`METRIC_KEYS` (a
#: sweep's numeric columns: a sweep's table does not have them yet). ``min_joint_limit_margin`` (and
#: ``_each``, per joint) is None when the arm records no limits.
VERDICT_KEYS = ("contact_held", "tracking_within_tolerance", "within_joint_limits", "notes",
                "out_of_contact_after", "force_error_ratio_last2s", "min_joint_limit_margin",
                "min_joint_limit_margin_each")
UNITS.update({"contact_held": "bool", "tracking_within_tolerance": "bool", "within_joint_limits": "bool",
              "notes": "-", "out_of_contact_after": "-", "force_error_ratio_last2s": "-",
              "min_joint_limit_margin": "rad or m", "min_joint_limit_margin_each": "rad or m"})
#: A job's entry (``compute_metrics(...)["job"]``, only for a run that records its ``phase``).
JOB_KEYS = ("contact_time", "process_start", "peak_normal_force_touch", "peak_touch_over_lam_d",
            "out_of_contact_process", "last_phase")
UNITS.update({"contact_time": "s", "process_start": "s", "peak_normal_force_touch": "N", "peak_touch_over_lam_d": "-",
              "out_of_contact_process": "-", "last_phase": "-"})
#: The verdicts' tolerances when the scenario does not give them (``[verdict]``, the same defaults).
DEFAULT_TOLERANCES = {"position_tolerance": 0.005, "angle_tolerance": 0.02, "force_tolerance": 0.1,
                      "contact_after": 0.5, "out_of_contact": 0.0}
#: Trajectory fields that summarise every step between samples (see hinfnn.sim.recorder).
STEP_FIELDS = tuple(SUMMARY_FIELDS)


def _rms(x, axis=0):
    x = np.asarray(x, dtype=float)
    return np.sqrt(np.mean(x**2, axis=axis))


def compute_metrics(traj, last: float = 2.0, *, tolerances: dict | None = None, coordinates=None,
                    lam_is_normal_force: bool | None = None) -> dict:
    """Metrics of one run (a dict of floats, lists and bools; JSON-ready).

    ``*_last2s`` are over t ≥ t_end − ``last``. ``tv_rate_tau_last2s`` is the total variation
    of each τ_i per second over that window (how oscillatory the torque is).
    ``rms_e_u1_each`` and ``rms_e_lam_each`` (and their ``_last2s``) are per coordinate (the
    overall ``rms_e_u1`` is the root of the sum of their squares); ``min_task_margin`` is the closest the
    true pose's task coordinates came to their singularities (rad or m; None when not recorded).
    ``rms_e_lam*`` are the controller's MEASURED force error e_λ (what its sensor gave it);
    ``rms_normal_force_error`` (and ``_last2s``) the TRUE one, the plant's normal force minus λd
    over the stored samples (N; None where λ is not a normal force: a nominal constraint without
    ``scaling = "unit"``; ``lam_is_normal_force`` says it for a run whose trajectory carries no
    scenario, None: the scenario's, and none: not); ``fraction_torque_saturated`` the share of
    stored samples with a joint's applied torque at its limit (``plant.actuator``; 0 without one).
    ``dissipation_min_margin`` is min over t > 0 of ρ²∫₀ᵗ(‖f_p‖²+‖f_f‖²) − (J(t) + V(t) − V(0)): the
    theorems claim the inequality for every T, not only the final one. With a robust update law
    (``controller.adaptation``) the inequality checked is the modified law's, (39'') of
    docs/beyond-the-paper.md section 11: the leakage's dissipation counted in J_aug, the dead zone's
    bound in the supply. The residuals are solved from the measured errors, so a noisy sensor's
    noise is part of the supply: the check bounds the errors the law measured, not the true force
    (``rms_normal_force_error``). ``t_end`` is the time the
    metrics cover; for a run that stopped early (``partial``) it is the step that stopped it: its
    metrics cover every step it ran, the one that stopped it included (the step summaries of the
    first sample after the stop, :class:`hinfnn.sim.simulate.Carry`), so ``peak_abs_tau`` holds the
    torque its reason names and ``min_joint_limit_margin`` the margin that stopped it (a trajectory
    stored without the step summaries: the samples up to t_fail).
    ``verdict["out_of_contact_after"]`` is None when no step came after ``contact_after``.

    ``verdict`` (:data:`VERDICT_KEYS`, :func:`verdicts`) judges the run against ``tolerances``
    (keys of :data:`DEFAULT_TOLERANCES`) with the motion coordinates' ``coordinates`` ((name, unit)
    pairs); both default to the run's scenario (``[verdict]``, the task coordinates' names), and
    without one to :data:`DEFAULT_TOLERANCES` with every coordinate in m.
    """
    if traj.batched:
        raise ValueError("compute_metrics takes one run; use traj.member(i) for a batch")
    end = traj.valid_samples()
    arr = {k: np.asarray(v)[:end] for k, v in traj.arrays.items()}
    t = arr["t"]
    partial = int(traj.status) != 0
    n = len(t)
    summaries = all(k in arr for k in STEP_FIELDS)
    # a run that stopped between two samples: the next sample summarises the steps up to the stop
    # (hinfnn.sim.simulate.Carry), and holds the state at the stopping step (its joint-limit margin)
    stop, per = _stopping_step(traj), int(traj.save_every)
    tail = bool(summaries and stop is not None and stop > (n - 1) * per and len(traj.arrays["t"]) > n)
    steps = np.full(n + tail, per, dtype=float)  # the steps each sample summarises
    steps[0] = 1
    if tail:
        steps[-1] = stop - (n - 1) * per
        arr.update({k: np.asarray(traj.arrays[k])[:n + 1] for k in (*STEP_FIELDS, "joint_limit_margin")
                    if k in traj.arrays})
    t_end = stop * float(traj.dt) if tail else float(t[-1])
    window = t >= t_end - last - 1e-9 * max(1.0, t_end)
    first = int(np.argmax(window))  # the first sample of the window
    e_u1 = np.linalg.norm(arr["e_u1"].reshape(n, -1), axis=1)
    e_lam = np.linalg.norm(arr["e_lam"].reshape(n, -1), axis=1)
    tau = arr["tau"]
    dt_s = t[1] - t[0] if n > 1 else 1.0
    span = max(t_end - t[first], dt_s)
    if summaries:
        # Every step, whatever the storage: sample i summarises the steps in (t_{i-1}, t_i].
        n_all, n_win = np.sum(steps), np.sum(steps[first + 1:]) + 1

        def ms(name, own):  # mean squares per component; own: the window's first sample's own contribution
            x = arr[name].reshape(len(steps), -1)
            return np.sum(x, axis=0) / n_all, (own + np.sum(x[first + 1:], axis=0)) / n_win

        (u1_ms, u1_ms_w), (lam_ms, lam_ms_w) = (ms(f"e_{s}_sq", arr[f"e_{s}"].reshape(n, -1)[first] ** 2)
                                                for s in ("u1", "lam"))
        u1_each, u1_each_w, lam_each, lam_each_w = (np.sqrt(v) for v in (u1_ms, u1_ms_w, lam_ms, lam_ms_w))
        rms_u1, rms_u1_w, rms_lam, rms_lam_w = (np.sqrt(np.sum(v)) for v in (u1_ms, u1_ms_w, lam_ms, lam_ms_w))
        rms_tau_w = np.sqrt(ms("tau_sq", tau[first] ** 2)[1])
        max_u1, max_lam = np.max(arr["e_u1_abs_max"]), np.max(arr["e_lam_abs_max"])
        peak = arr["tau_abs_max"]
        peak_window = np.concatenate([np.abs(tau[first:first + 1]), peak[first + 1:]])
        variation = arr["tau_variation"][first + 1:]
        out_of_contact = np.sum(arr["steps_out_of_contact"]) / n_all
    else:  # a trajectory without the step summaries (e.g. fields=...): from the samples
        tw = tau[first:]
        rms_u1, rms_u1_w, rms_lam, rms_lam_w = _rms(e_u1), _rms(e_u1[first:]), _rms(e_lam), _rms(e_lam[first:])

        def each(name, rows=slice(None)):
            x = np.asarray(arr[name], dtype=float).reshape(n, -1)[rows]
            return np.sqrt(np.mean(x**2, axis=0))

        u1_each, u1_each_w, lam_each, lam_each_w = (each("e_u1"), each("e_u1", slice(first, None)), each("e_lam"),
                                                    each("e_lam", slice(first, None)))
        rms_tau_w = _rms(tw)
        max_u1, max_lam = np.max(e_u1), np.max(e_lam)
        peak = np.abs(tau)
        peak_window = peak[first:]
        variation = np.abs(np.diff(tw, axis=0))
        out_of_contact = (np.mean(arr["penetration"] < -1e-9) if "penetration" in arr else
                          np.mean(arr["normal_force"] <= 0.0) if "normal_force" in arr else math.nan)
    if all(k in arr for k in ("J_aug", "V", "supply", "J")):
        lhs = float(arr["J_aug"][-1] + arr["V"][-1] - arr["V"][0])
        rhs = float(arr["supply"][-1])
        holds = bool(lhs <= rhs) if np.isfinite(lhs) and np.isfinite(rhs) else None
        margin_t = (arr["supply"] - (arr["J_aug"] + arr["V"] - arr["V"][0]))[1:]  # t > 0 (at t = 0 it is 0)
        margin = float(np.min(margin_t)) if margin_t.size else math.nan
        J_T = float(arr["J"][-1])
    else:  # a controller without the theorems' bookkeeping
        lhs = rhs = margin = J_T = math.nan
        holds = None
    margin_task = float(np.min(arr["task_margin"])) if "task_margin" in arr else None
    # contact after the build-up, the force error relative to the force asked, the joints' limits
    tol, coords = _judging(traj, tolerances, coordinates, arr["e_u1"].reshape(n, -1).shape[1])
    # None when no step came after contact_after: nothing was judged
    phase = np.asarray(arr["phase"], dtype=float).reshape(n) if "phase" in arr else None
    if summaries:
        t_sum = np.append(t, t_end) if tail else t  # the last step each sample summarises
        after = t_sum > tol["contact_after"] + 1e-9 * max(1.0, abs(tol["contact_after"]))
        if phase is not None:  # a job (hinfnn.controllers.job): contact is judged in its process phase only
            after = _in_process(np.append(phase, phase[-1]) if tail else phase)
        steps_after = float(np.sum(steps[after]))
        out_after = float(np.sum(arr["steps_out_of_contact"][after]) / steps_after) if steps_after else None
    elif "penetration" in arr:
        after = t > tol["contact_after"] + 1e-9 * max(1.0, abs(tol["contact_after"]))
        if phase is not None:
            after = _in_process(phase)
        out_after = float(np.mean(arr["penetration"][after] < -1e-9)) if after.any() else None
    else:
        out_after = math.nan
    lam_scale = float(np.mean(np.linalg.norm(arr["lam_d"].reshape(n, -1)[first:], axis=1))) if "lam_d" in arr else math.nan
    true_force = _normal_force_error(traj, arr, n, lam_is_normal_force)
    rms_true, rms_true_w = (None, None) if true_force is None else (float(_rms(true_force)),
                                                                    float(_rms(true_force[first:])))
    # the force-tracking verdict reads the TRUE force where λ is one, else the controller's measured e_λ
    ratio = float((rms_lam_w if rms_true_w is None else rms_true_w) / lam_scale) if lam_scale > 0 else None
    if "joint_limit_margin" in arr:
        each = np.min(arr["joint_limit_margin"].reshape(len(arr["joint_limit_margin"]), -1), axis=0)
        margin_joints = [float(v) if math.isfinite(v) else None for v in each]
        finite = [v for v in margin_joints if v is not None]
        margin_joint = min(finite) if finite else None
    else:
        margin_joints, margin_joint = None, None
    job = None if phase is None else _job_metrics(t, phase, arr, n, out_after)
    return {
        **({} if job is None else {"job": job}),
        "rms_e_u1_each": [float(v) for v in u1_each],
        "rms_e_u1_each_last2s": [float(v) for v in u1_each_w],
        "rms_e_lam_each": [float(v) for v in lam_each],
        "rms_e_lam_each_last2s": [float(v) for v in lam_each_w],
        "min_task_margin": margin_task if margin_task is None or math.isfinite(margin_task) else None,
        "rms_normal_force_error": rms_true,
        "rms_normal_force_error_last2s": rms_true_w,
        "fraction_torque_saturated": float(np.mean(arr["torque_saturated"])) if "torque_saturated" in arr else 0.0,
        "rms_e_u1": float(rms_u1),
        "max_abs_e_u1": float(max_u1),
        "rms_e_u1_last2s": float(rms_u1_w),
        "rms_e_lam": float(rms_lam),
        "max_abs_e_lam": float(max_lam),
        "rms_e_lam_last2s": float(rms_lam_w),
        "J_T": J_T,
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
        "t_end": t_end,
        "partial": partial,
        "verdict": {**verdicts(u1_each_w, out_after, ratio, margin_joint, partial=partial, status=int(traj.status),
                               tolerances=tol, coordinates=coords),
                    "out_of_contact_after": out_after, "force_error_ratio_last2s": ratio,
                    "min_joint_limit_margin": margin_joint, "min_joint_limit_margin_each": margin_joints},
    }


#: The phase in which a job's contact is judged (:data:`hinfnn.controllers.job.PHASES`: "process").
PROCESS_PHASE = 2
#: A job's touch: its approach and force ramp and this long of its process after them, s (the
#: ramp's overshoot, if any, comes just after its end).
TOUCH_SETTLE = 0.5


def _in_process(phase):
    """The samples of a job's process phase, whose steps the contact verdict judges (the approach,
    the force ramp, the unload and the lift-off are not: the tool is meant to leave or reach the
    surface there)."""
    return np.asarray(phase) == PROCESS_PHASE


def _job_metrics(t, phase, arr, n: int, out_after) -> dict:
    """A job's phases (:mod:`hinfnn.controllers.job`): when contact was found and the process
    began (None: never), the largest normal force during the touch (the approach, the ramp and
    :data:`TOUCH_SETTLE` s of the process: the plant's normal force, or a robot run's measured
    force, N), the largest measured λ there over the largest λd, the share of the process's steps
    off the surface, and the last phase reached."""
    def first(mask):
        i = np.nonzero(mask)[0]
        return (float(t[i[0]]), int(i[0])) if i.size else (None, None)
    contact_t, _ = first(phase >= 1)
    process_t, _ = first(phase >= PROCESS_PHASE)
    force = (np.asarray(arr["normal_force"], dtype=float).reshape(n) if "normal_force" in arr else
             np.linalg.norm(np.asarray(arr["force_measured"], dtype=float).reshape(n, -1), axis=1)
             if "force_measured" in arr else None)
    peak = ratio = None
    if contact_t is not None:
        end = np.inf if process_t is None else process_t + TOUCH_SETTLE
        touch = t <= end + 1e-12
        if force is not None:
            peak = float(np.max(force[touch]))
        lam_d = float(np.max(np.abs(arr["lam_d"]))) if "lam_d" in arr else math.nan
        if "lam" in arr and lam_d > 0:  # in λ's units, as λd (λ is the normal force for a unit constraint)
            ratio = float(np.max(np.asarray(arr["lam"], dtype=float).reshape(n, -1)[touch])) / lam_d
    return {"contact_time": contact_t, "process_start": process_t, "peak_normal_force_touch": peak,
            "peak_touch_over_lam_d": ratio, "out_of_contact_process": out_after, "last_phase": int(phase[-1])}


def _stopping_step(traj) -> int | None:
    """The index of the step that stopped a (single) run (the last step its summaries count), or
    None for a run that completed or whose stop time is unknown. A non-finite state is found after
    its step (t_fail = t_k + dt); the other stops at the step's start (t_fail = t_k)."""
    code = int(traj.status)
    tf = float(np.asarray(traj.t_fail).reshape(()))
    if code == 0 or not math.isfinite(tf):
        return None
    k = int(round(tf / float(traj.dt)))
    return k - 1 if code == int(RunStatus.NONFINITE) else k


def lam_is_normal_force(scenario) -> bool:
    """Whether λ is the normal force in N in runs of ``scenario``: its nominal constraint's
    ``scaling`` is "unit" (the Cartesian surfaces; the paper's line has λ = f_n cos δ)."""
    surface = getattr(getattr(scenario, "nominal", None), "surface", None)
    return getattr(surface, "scaling", None) == "unit"


def _normal_force_error(traj, arr: dict, n: int, flag: bool | None = None):
    """The TRUE normal force minus λd at each stored sample (N), where λ is a normal force
    (``flag``; None: as the run's scenario says, :func:`lam_is_normal_force`) and one force
    coordinate; None otherwise (e.g. the paper's line; a run built by hand) or when the run did
    not store both."""
    flag = lam_is_normal_force(getattr(traj, "scenario", None)) if flag is None else flag
    if not flag or "normal_force" not in arr or "lam_d" not in arr:
        return None
    lam_d = np.asarray(arr["lam_d"], dtype=float).reshape(n, -1)
    if lam_d.shape[1] != 1:
        return None
    return np.asarray(arr["normal_force"], dtype=float).reshape(n) - lam_d[:, 0]


def _judging(traj, tolerances, coordinates, m: int):
    """The tolerances and the motion coordinates' (name, unit) a run is judged with."""
    sc = getattr(traj, "scenario", None)
    tol = dict(DEFAULT_TOLERANCES)
    if tolerances is None and sc is not None and hasattr(sc, "verdict"):
        tolerances = sc.verdict.tolerances()
    tol.update(tolerances or {})
    if coordinates is None and sc is not None:
        try:
            names = sc.coordinate_names()
        except Exception:  # noqa: BLE001 - a scenario that no longer builds: judge in m
            names = None
        coordinates = names[:m] if names else None
    if coordinates is None or len(coordinates) != m:
        coordinates = [(f"u1[{i + 1}]" if m > 1 else "u1", "m") for i in range(m)]
    return tol, list(coordinates)


#: The networks whose update law may project (Remark 2): the recorded norm, the radius's scenario key.
_BALLS = {"theta_p": ("F_p", "controller.adaptation.radius_p", "9.81 per output"),
          "theta_f": ("F_f", "controller.adaptation.radius_f", "the largest |λd|")}
#: The share of the last 2 s a network's weights must sit on their ball for :func:`projection_notes`.
ON_BALL_SHARE = 0.5


def projection_notes(controller, traj, last: float = 2.0) -> list[str]:
    """One line per network of ``controller`` whose update law projects (Remark 2; not the paper's
    eqs. (30)–(31) as printed: docs/beyond-the-paper.md section 11) and whose weights sat on the
    ball's surface, ‖Θ̂‖ ≥ (1 − 1e-6) r, for at least :data:`ON_BALL_SHARE` of the stored samples of
    the last ``last`` s of ``traj``: the network wanted to give more than the ball lets it, so the
    uncertainty it learns is larger than its radius assumes (on the iiwa 14 with its masses 20 %
    off, F_f's design ball of 15 N against a force-side uncertainty of 16–34 N:
    docs/arms-and-surfaces.md). Empty when no network projects or none sat there; the run's
    summary prints these lines after the verdict's notes when the run did not do its job."""
    if getattr(traj, "batched", False):
        raise ValueError("projection_notes takes one run; use traj.member(i) for a batch")
    end = traj.valid_samples()
    t = np.asarray(traj.arrays["t"])[:end]
    if len(t) == 0:
        return []
    window = t >= t[-1] - last - 1e-9 * max(1.0, float(t[-1]))
    out = []
    for term in getattr(controller, "terms", ()):
        net, key = getattr(term, "network", None), getattr(term, "key", None)
        if net is None or key not in _BALLS or not bool(getattr(net, "project", False)):
            continue
        field = f"{key}_norm"
        if field not in traj.arrays:
            continue
        r = float(np.asarray(net.radius))
        norm = np.asarray(traj.arrays[field])[:end][window]
        on = float(np.mean(norm >= (1.0 - 1e-6) * r)) if len(norm) else 0.0
        if on >= ON_BALL_SHARE:
            name, k, what = _BALLS[key]
            out.append(f"{name}'s weights sat on their projection ball (radius {r:.3g}, {k}) for {on:.0%} of the "
                       f"last {last:g} s: the uncertainty it learns is larger than the ball lets it give (by "
                       f"default {what} at zero error); a larger {k.rsplit('.', 1)[1]}, or `hinfnn design --tune` "
                       f"with the {k.rsplit('.', 1)[1]} knob")
    return out


def verdicts(rms_each_last, out_after, force_ratio, joint_margin, *, partial: bool, status: int, tolerances: dict,
             coordinates) -> dict:
    """Whether a run did its job, next to its status:

    * ``contact_held``: the share of steps with the tool off the true surface after
      ``contact_after`` is at most ``out_of_contact``; None (not judged) when the run has no step
      after ``contact_after`` (``out_after`` None: a run shorter than it, or one that stopped
      before it) or no contact measure (NaN);
    * ``tracking_within_tolerance``: over the last 2 s, the RMS error of each motion coordinate is
      at most ``position_tolerance`` (coordinates in m) or ``angle_tolerance`` (rad), and the RMS
      force error (the TRUE normal force's where λ is one, else the measured e_λ's) at most
      ``force_tolerance`` times the mean |λd| there; False for a run that stopped early;
    * ``within_joint_limits``: no joint passed its limit (None: the arm has none recorded);

    and ``notes``, one line per failed criterion with its numbers."""
    notes = []
    tol = tolerances
    contact = bool(out_after <= tol["out_of_contact"]) if out_after is not None and math.isfinite(out_after) else None
    if out_after is None:
        notes.append(f"contact not judged: no step after {tol['contact_after']:g} s (verdict.contact_after)")
    if contact is False:
        notes.append(f"off the surface for {out_after:.2%} of the steps after {tol['contact_after']:g} s (allowed: "
                     f"{tol['out_of_contact']:.2%})")
    track = True
    for (name, unit), v in zip(coordinates, rms_each_last):
        limit = tol["angle_tolerance"] if unit == "rad" else tol["position_tolerance"]
        if not v <= limit:
            track = False
            notes.append(f"{name}: RMS error {v:.3g} {unit} over the last 2 s (allowed: {limit:g} {unit})")
    if force_ratio is not None and not force_ratio <= tol["force_tolerance"]:
        track = False
        notes.append(f"force: RMS error over the last 2 s {force_ratio:.1%} of the mean |λd| (allowed: "
                     f"{tol['force_tolerance']:.0%})")
    if partial:
        track = False
        notes.append("the run stopped early (status ≠ ok): it did not finish its task")
    past = status == int(RunStatus.PLANT_FAULT) and joint_margin is not None
    limits = None if joint_margin is None else bool(not past and joint_margin >= 0)
    if limits is False:
        notes.append("a joint passed its limit (the run stopped there)" if past else
                     f"a joint passed its limit (by {-joint_margin:.3g} rad or m)")
    return {"contact_held": contact, "tracking_within_tolerance": track, "within_joint_limits": limits,
            "notes": notes}
