"""Stiff contact on every arm (issue 30): the paper's laws against the stabilised ones (force-rate
term, κ by the design rule) on an UNDAMPED contact, measured on 10-s runs, printed as a table.

Cases: arm ∈ {ur5-table, ur5-sphere, planar3-drum} × law ∈ {H∞-only, adaptive} × {paper law,
stabilised} × k ∈ {1e4, 1e5, 1e6} N/m × {continuous, 1 kHz zero-order hold}, each on the shipped
``<arm>-stable`` scenario (its friction, model errors and disturbance; contact damping 0) with the
stiffness overridden.

The stabilised design states the range of contact stiffness it is for: 1e4 … 1e6 N/m in
continuous time; at 1 kHz 1e4 … 1e5 N/m for the k = 1e4 and 1e5 runs and 1e4 … 1e6 N/m for the
k = 1e6 run, which the design refuses where the sampled loop cannot hold it (the refusal is
printed instead of a run). The paper's law is the same controller with κ = 0 (the term's filter
then acts on nothing: the law, its storage and its dissipation are the paper's; one compiled
program for both, so the runs of an arm, law and mode are one batch of ``simulate_many``).

Columns: status (0 ok, else the simulator's code), the fraction of the steps after 0.2 s out of
contact, RMS e_λ over the last 2 s in % of the mean λd there, RMS e_u1 over the last 2 s, the
peak |τ| after 0.2 s, whether the dissipation inequality held at every sample, and the seconds
the batch took (compile included, divided among its runs).

Usage::

    python benchmarks/stiff_arms.py                                  # everything (~30-60 min on 2 cores)
    python benchmarks/stiff_arms.py --arms ur5-table --kinds hinf --modes cont --t-final 2
    python benchmarks/stiff_arms.py --json benchmarks/results/stiff_arms.json

One process, one batch at a time. Timing and numbers live here, never in tests/.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time

import numpy as np

#: the paper's ideal sensor and motors (hinfnn.workflows.stiff.IDEAL_INSTRUMENTS): the -stable scenarios declare a robot's
IDEAL_INSTRUMENTS = {"plant.sensor.force_noise": 0.0, "plant.sensor.delay": 0, "plant.actuator.torque_limit": "none",
                     "controller.force_filter.order": 0}

ARMS = ("ur5-table", "ur5-sphere", "planar3-drum")
KINDS = ("hinf", "hinf_nn")
STIFFNESS = (1e4, 1e5, 1e6)
#: (the -stable scenarios declare a robot's sensor: the comparison keeps the paper's ideal one)
MODES = {"cont": {**IDEAL_INSTRUMENTS, "simulation.control": "continuous"},
         "1kHz": {**IDEAL_INSTRUMENTS, "simulation.control": "sampled", "simulation.control_period": 1e-3}}
#: The stated range of contact stiffness of the stabilised design, per mode and case stiffness.
K_MAX = {"cont": lambda k: 1e6, "1kHz": lambda k: 1e5 if k <= 1e5 else k}
FIELDS = ("lam_d",)
AFTER = 0.2  # s: the start's transient excluded from the out-of-contact fraction and the torque peak


def case_name(arm, kind, variant, mode, k):
    return f"{arm}/{kind}/{variant}/{mode}/k{k:.0e}".replace("+0", "")


def build_runs(arm, kind, mode, stiffnesses, t_final, extra=None):
    """([(name, Run)], {name: refusal}) of one arm, law and mode (``extra``: more overrides)."""
    import hinfnn as H
    from hinfnn.analysis import with_kappa

    runs, refused = [], {}
    for k in stiffnesses:
        base = {"controller.kind": kind, "plant.contact.stiffness": k, "plant.contact.damping": 0.0,
                "simulation.t_final": t_final, **MODES[mode], **(extra or {})}
        paper_design = {**base, "controller.force_rate.stiffness_max": 1e6 if mode == "cont" else 1e5}
        sc_paper = H.load_scenario(f"{arm}-stable", paper_design)
        r = sc_paper.run(kind)
        runs.append(dataclasses.replace(r, name=case_name(arm, kind, "paper", mode, k),
                                        controller=with_kappa(r.controller, 0.0)))
        try:
            sc = H.load_scenario(f"{arm}-stable", {**base, "controller.force_rate.stiffness_max": K_MAX[mode](k)})
        except H.DesignError as err:
            refused[case_name(arm, kind, "stable", mode, k)] = str(err)
            continue
        runs.append(dataclasses.replace(sc.run(kind), name=case_name(arm, kind, "stable", mode, k)))
    return runs, refused


def measure(traj) -> dict:
    import hinfnn as H

    m = H.compute_metrics(traj)
    t = np.asarray(traj.t)
    after = t > AFTER
    steps = np.asarray(traj.steps_out_of_contact)
    per = int(traj.save_every)
    out_after = float(np.sum(steps[after]) / max(1, per * int(np.sum(after))))
    window = t >= t[-1] - 2.0 - 1e-9
    mean_force = float(np.mean(np.linalg.norm(np.asarray(traj.lam_d).reshape(len(t), -1)[window], axis=1)))
    peak = float(np.max(np.asarray(traj.tau_abs_max)[after])) if np.any(after) else math.nan
    return dict(status=int(traj.status), t_end=m["t_end"], out_of_contact_after=out_after,
                rms_e_lam_last2s=m["rms_e_lam_last2s"], mean_force=mean_force,
                e_lam_pct=100.0 * m["rms_e_lam_last2s"] / mean_force if mean_force > 0 else math.nan,
                rms_e_u1_last2s=m["rms_e_u1_last2s"], peak_tau_after=peak,
                dissipation=m["dissipation_holds_for_all_t"], out_of_contact_all=m["fraction_out_of_contact"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--arms", nargs="+", default=list(ARMS), choices=ARMS)
    p.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    p.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    p.add_argument("--stiffness", nargs="+", type=float, default=list(STIFFNESS))
    p.add_argument("--t-final", type=float, default=10.0)
    p.add_argument("--json", help="write the rows here")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a scenario override for every case (e.g. controller.gains.beta_lam=12)")
    args = p.parse_args(argv)

    import hinfnn as H
    from hinfnn.fields import METRICS_FIELDS

    from hinfnn.scenario import parse_override

    H.configure()
    extra = dict(parse_override(item) for item in args.set)
    rows, refusals = [], {}
    print(f"{'case':<44} {'st':>2} {'out>0.2s':>8} {'eλ%':>7} {'eu1 m':>8} {'peak τ':>9} {'diss':>5} {'s/run':>6}",
          flush=True)
    for arm in args.arms:
        for kind in args.kinds:
            for mode in args.modes:
                runs, refused = build_runs(arm, kind, mode, args.stiffness, args.t_final, extra)
                refusals.update(refused)
                t0 = time.perf_counter()
                trajs = H.simulate_many(runs, fields=tuple(METRICS_FIELDS) + FIELDS)
                per_run = (time.perf_counter() - t0) / max(1, len(runs))
                for r in runs:
                    row = dict(case=r.name, seconds=per_run, **measure(trajs[r.name]))
                    rows.append(row)
                    print(f"{r.name:<44} {row['status']:>2} {100 * row['out_of_contact_after']:>7.2f}% "
                          f"{row['e_lam_pct']:>6.2f}% {row['rms_e_u1_last2s']:>8.2e} {row['peak_tau_after']:>9.3g} "
                          f"{str(row['dissipation']):>5} {per_run:>6.1f}", flush=True)
                for name, why in refused.items():
                    print(f"{name:<44} refused by the design: {why}", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(rows=rows, refusals=refusals, t_final=args.t_final, overrides=args.set), f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
