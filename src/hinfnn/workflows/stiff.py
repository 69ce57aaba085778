"""Stiff contact on every arm: the paper's laws against the stabilised ones on a bare, undamped
contact (``hinfnn gallery --beyond``), the arms' counterpart of the paper study's "Beyond the paper".

For each gallery arm (``planar3-drum``, ``ur5-table``, ``ur5-sphere``) the shipped ``<arm>-stable``
scenario (its model errors, friction, payload and disturbance; contact damping 0; the paper's ideal
sensor and motors, :data:`IDEAL_INSTRUMENTS`, whatever sensor the scenario declares) runs with

* both robust laws (H∞-only ``hinf`` and adaptive ``hinf_nn``),
* the paper's law (the same controller with the force-rate gain κ = 0: the term's filter then acts
  on nothing, so the law, its storage and its dissipation are the paper's) and the stabilised one
  (κ by the design rule, docs/beyond-the-paper.md section 7),
* contact stiffness k = 1e4, 1e5, 1e6 N/m,
* continuous control and a 1 kHz zero-order hold.

The stabilised design states the stiffness range it is for: 1e4 … 1e6 N/m in continuous time; at
1 kHz 1e4 … 1e5 N/m for the k = 1e4 and 1e5 runs and 1e4 … 1e6 N/m for the k = 1e6 run, which the
design refuses where a 1 kHz loop cannot hold it (the refusal, a DesignError naming the key, the
stiffest contact and the longest period that work, is reported instead of a run). Each arm's
linearised contact modes (:func:`hinfnn.analysis.contact_modes`, continuous) are reported before
and after the force-rate term.

The targets (checked in the report): continuous, every stiffness: status ok, no step out of contact
after :data:`AFTER` s, RMS e_λ over the last 2 s at most 2 % (adaptive) / 10 % (H∞-only) of the mean
force reference, dissipation inequality at every sample; 1 kHz, k ≤ 1e5: status ok, no step out of
contact after :data:`AFTER` s, RMS e_λ over the last 2 s at most 5 % (adaptive).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ..experiment import Case, simulate_cases
from ..scenario import Scenario

#: The arms of the comparison (each has a shipped ``<arm>-stable`` scenario).
STIFF_ARMS = ("planar3-drum", "ur5-table", "ur5-sphere")
#: Contact stiffnesses (N/m, undamped).
STIFF_STIFFNESS = (1e4, 1e5, 1e6)
#: The laws compared.
STIFF_KINDS = ("hinf", "hinf_nn")
#: Control modes: continuous and a 1 kHz zero-order hold.
STIFF_MODES = {"cont": {"simulation.control": "continuous"}, "1kHz": {"simulation.control": "sampled", "simulation.control_period": 1e-3}}
#: The start's transient excluded from "out of contact" and the torque peak (s).
AFTER = 0.2
#: Targets: the largest RMS e_λ over the last 2 s, as a fraction of the mean force reference, by
#: (kind, mode); None where the issue sets none.
TARGET_FORCE = {("hinf_nn", "cont"): 0.02, ("hinf", "cont"): 0.10, ("hinf_nn", "1kHz"): 0.05, ("hinf", "1kHz"): None}
#: What the trajectory files keep (enough to redraw the figures).
STIFF_FIELDS = ("t", "u1", "u1_d", "lam", "lam_d", "e_u1", "e_lam", "tau", "penetration", "normal_force",
                "tau_abs_max", "steps_out_of_contact")
MODE_WORDS = {"cont": "continuous", "1kHz": "ZOH 1 kHz"}
#: The comparison's sensor and motors: the paper's (ideal sensor, no torque limit, no force filter),
#: whatever the ``-stable`` scenario declares (a robot's: ``hinfnn gallery --sensor`` compares those).
IDEAL_INSTRUMENTS = {"plant.sensor.force_noise": 0.0, "plant.sensor.delay": 0, "plant.actuator.torque_limit": "none",
                     "controller.force_filter.order": 0}


def stiffness_max(mode: str, k: float) -> float:
    """The stiffest contact the stabilised design is asked to hold in ``mode`` for a run at ``k``."""
    return max(STIFF_STIFFNESS) if mode == "cont" else max(1e5, k)


def stiff_cases(arm: str, overrides=()) -> tuple[list[Case], dict[str, str]]:
    """The cases of one arm and the stabilised designs refused ({case name: the DesignError's text}).
    ``overrides``: the user's, applied to every case (before the comparison's own)."""
    from ..controllers import KINDS
    from ..errors import DesignError

    base = Scenario.load(f"{arm}-stable", overrides)
    cases, refused = [], {}
    for kind in STIFF_KINDS:
        for mode, mode_over in STIFF_MODES.items():
            for k in STIFF_STIFFNESS:
                common = {**IDEAL_INSTRUMENTS, "controller.kind": kind, "plant.contact.stiffness": k,
                          "plant.contact.damping": 0.0, **mode_over}
                for variant in ("paper", "stable"):
                    o = dict(common)
                    if variant == "paper":  # κ = 0 needs no design range: the design's own for the mode
                        o["controller.force_rate.kappa"] = 0.0
                    else:
                        o["controller.force_rate.stiffness_max"] = stiffness_max(mode, k)
                    name = f"{kind}_{variant}_{mode}_k{k:.0e}".replace("+0", "")
                    label = (f"{KINDS[kind].label}, {'paper law (κ = 0)' if variant == 'paper' else 'stabilised'}, "
                             f"{MODE_WORDS[mode]}, k = {k:.0e} N/m").replace("+0", "")
                    try:
                        sc = base.with_overrides(o)
                    except DesignError as err:
                        refused[name] = str(err)
                        continue
                    cases.append(Case(name, sc, overrides=o, label=label,
                                      tags={"arm": arm, "variant": variant, "mode": mode, "stiffness": float(k)}))
    return cases, refused


def _after(traj, m):
    """Out-of-contact share and peak |τ| over the steps after :data:`AFTER` s; the mean force
    reference over the last 2 s."""
    t = np.asarray(traj.t)
    after = t > AFTER
    steps = np.asarray(traj.steps_out_of_contact)
    per = int(traj.save_every)
    m[f"out_of_contact_after_{AFTER:g}s"] = (float(np.sum(steps[after]) / (per * int(np.sum(after))))
                                            if np.any(after) else math.nan)
    m[f"peak_abs_tau_after_{AFTER:g}s"] = (float(np.max(np.asarray(traj.tau_abs_max)[after]))
                                          if np.any(after) else math.nan)
    window = t >= t[-1] - 2.0 - 1e-9
    lam_d = np.asarray(traj.lam_d).reshape(len(t), -1)[window]
    m["mean_abs_lam_d_last2s"] = float(np.mean(np.linalg.norm(lam_d, axis=1))) if len(lam_d) else math.nan


def modes_of(arm: str, overrides=(), kinds=STIFF_KINDS) -> list[dict]:
    """The least damped force mode of the linearised continuous loop, paper law (κ = 0) and
    stabilised, per law and stiffness (:func:`hinfnn.analysis.contact_modes`)."""
    from ..analysis import contact_modes, with_kappa

    rows = []
    for kind in kinds:
        sc = Scenario.load(f"{arm}-stable", overrides).with_overrides(
            {**IDEAL_INSTRUMENTS, **STIFF_MODES["cont"], "controller.kind": kind, "plant.contact.damping": 0.0,
             "controller.force_rate.stiffness_max": max(STIFF_STIFFNESS)})
        ctrl = sc.build_controller(kind)
        for k in STIFF_STIFFNESS:
            for variant, c in (("paper", with_kappa(ctrl, 0.0)), ("stable", ctrl)):
                r = contact_modes(sc, kind, k, ctrl=c)
                rows.append(dict(arm=arm, kind=kind, stiffness=k, variant=variant, kappa=float(r["kappa"]),
                                 stable=bool(r["stable"]), **r["least_damped"].as_dict()))
    return rows


def build_stiff_runs(cases: list[Case]) -> list:
    """The runs of the cases, the paper law's with the controller of the stabilised case of the
    same law and mode (the lowest stiffness's design), its κ set to 0
    (:func:`hinfnn.analysis.with_kappa`): the same law as the case's own design (κ = 0 there too),
    and the same compiled structure, so the paper and stabilised runs of a law and mode simulate
    as one batch."""
    from ..analysis import with_kappa

    runs = [c.run() for c in cases]
    stable = {}
    for c, r in zip(cases, runs):
        if c.tags["variant"] == "stable":
            stable.setdefault((c.kind, c.tags["mode"]), r.controller)
    out = []
    for c, r in zip(cases, runs):
        ctrl = stable.get((c.kind, c.tags["mode"])) if c.tags["variant"] == "paper" else None
        out.append(r if ctrl is None else dataclasses.replace(r, controller=with_kappa(ctrl, 0.0)))
    return out


def run_stiff(arm: str, overrides=(), progress=None) -> dict:
    """Simulate one arm's comparison and linearise it. Returns {"arm", "outcome", "refused",
    "modes", "seconds"}."""
    from ..fields import METRICS_FIELDS

    t0 = time.perf_counter()
    cases, refused = stiff_cases(arm, overrides)
    outcome = simulate_cases(cases, runs=build_stiff_runs(cases), progress=progress, save_every=1,
                             fields=STIFF_FIELDS + METRICS_FIELDS, extra=_after)
    modes = modes_of(arm, overrides)
    return dict(arm=arm, outcome=outcome, refused=refused, modes=modes, seconds=time.perf_counter() - t0)


def stiff_document(result: dict) -> dict:
    """The part of metrics.json of one arm's comparison: cases (from their tags), runs, refusals,
    contact modes, and each case's targets checked (:func:`targets`)."""
    outcome = result["outcome"]
    cases = [dict(name=c.name, kind=c.kind, variant=c.tags["variant"], mode=c.tags["mode"], k=c.tags["stiffness"],
                  label=c.label) for c in outcome.cases]
    runs = outcome.entries()
    checks = {c["name"]: targets(c, r) for c, r in zip(cases, runs)}
    return dict(arm=result["arm"], cases=cases, runs=runs, refused=result["refused"], contact_modes=result["modes"],
                targets=checks)


def targets(case: dict, run: dict) -> dict | None:
    """The issue's targets for a stabilised case: {what: (value, held)}; None for the paper law and
    for a 1 kHz run at a stiffness the 1 kHz design is not for."""
    if case["variant"] != "stable" or (case["mode"] == "1kHz" and case["k"] > 1e5):
        return None
    m = run["metrics"]
    out = {"status ok": (run["status"], run["status"] == "ok"),
           f"no step out of contact after {AFTER:g} s": (m[f"out_of_contact_after_{AFTER:g}s"],
                                                         m[f"out_of_contact_after_{AFTER:g}s"] == 0.0)}
    ratio = m["rms_e_lam_last2s"] / m["mean_abs_lam_d_last2s"] if m["mean_abs_lam_d_last2s"] else math.nan
    limit = TARGET_FORCE[(case["kind"], case["mode"])]
    if limit is not None:
        out[f"RMS e_λ last 2 s ≤ {limit:.0%} of mean λd"] = (ratio, bool(ratio <= limit))
    if case["mode"] == "cont":
        out["dissipation at every sample"] = (m["dissipation_holds_for_all_t"], m["dissipation_holds_for_all_t"] is True)
    return out


__all__ = ["STIFF_ARMS", "STIFF_STIFFNESS", "STIFF_KINDS", "STIFF_MODES", "STIFF_FIELDS", "AFTER", "stiff_cases",
           "modes_of", "build_stiff_runs", "run_stiff", "stiff_document", "targets", "stiffness_max"]
