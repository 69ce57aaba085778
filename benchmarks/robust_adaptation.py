"""Robust adaptation under a noisy force sensor (issue 54): the networks' update laws (30)–(31)
as the paper gives them against their robust modifications (``controller.adaptation.robust``:
dead zone, σ-modification, e-modification, projection with the design's radii), measured on
short runs with white noise of σ on each axis of the sensed tool force (no delay, no bias).

Cases: scenario × σ × option, each scenario's runs of one option one batch of ``simulate_many``
(the dead zone, σ- and e-modification share one compiled program: their parameters are data).
A batch member's sensor noise folds in its index (``plant.sensor.seed``): the runs of one batch
see independent draws of the same noise.

Columns: status (the simulator's stop, or ok), the TRUE normal-force RMS error over the last 2 s
(N), the share of the steps after 0.5 s out of contact, the peak |τ| after 0.2 s (N·m, largest
joint), the networks' weight norms at the end and their growth over the last 2 s (the drift),
whether the dissipation inequality held at every sample, and its margin over the supply.

Usage::

    python benchmarks/robust_adaptation.py --scenario ur5-polish --t-final 5 --json out.json
    python benchmarks/robust_adaptation.py --scenario ur5-table-stable --set simulation.control=sampled \\
        --sigmas 1 2 --options none sigma

One process, one batch at a time. Timing and numbers live here, never in tests/.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

OPTIONS = ("none", "dead_zone", "sigma", "e_mod", "projection")


def row(name, traj, metrics, t_final):
    a = {k: np.asarray(v) for k, v in traj.arrays.items()}
    end = traj.valid_samples()
    t = a["t"][:end]
    tau = np.abs(a["tau"][:end]).reshape(end, -1)
    after = t >= 0.2
    peak = float(np.max(tau[after])) if after.any() else math.nan
    out = {"case": name, "status": int(traj.status), "t_end": float(metrics["t_end"]),
           "force_err_last2s": metrics["rms_normal_force_error_last2s"],
           "e_lam_meas_last2s": metrics["rms_e_lam_last2s"],
           "out_of_contact_after": metrics["verdict"]["out_of_contact_after"],
           "peak_tau_after_0.2s": peak, "saturated": metrics["fraction_torque_saturated"],
           "dissipation_holds": metrics["dissipation_holds_for_all_t"],
           "dissipation_margin": metrics["dissipation_min_margin"], "supply": metrics["dissipation_rhs"]}
    w = t >= t[-1] - 2.0
    for key in ("theta_p_norm", "theta_f_norm"):
        if key in a:
            x = a[key][:end]
            out[key] = float(x[-1])
            out[key + "_growth_last2s"] = float(x[-1] - x[w][0])
            out[key + "_max"] = float(np.max(x))
    for key in ("theta_p_gate", "theta_f_gate"):
        if key in a:
            out[key + "_zero_fraction"] = float(np.mean(a[key][:end] == 0.0))
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="ur5-polish")
    p.add_argument("--sigmas", type=float, nargs="+", default=[1.0, 2.0, 2.5, 5.0])
    p.add_argument("--options", nargs="*", default=list(OPTIONS), choices=OPTIONS)
    p.add_argument("--t-final", type=float, default=5.0)
    p.add_argument("--set", action="append", default=[], help="KEY=VALUE, every case")
    p.add_argument("--variant", action="append", default=[],
                   help="NAME:KEY=VALUE[,KEY=VALUE]: also run option NAME's runs with these overrides")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)

    import hinfnn
    from hinfnn.experiment import Case, simulate_cases
    from hinfnn.scenario.core import load_scenario, override_items

    hinfnn.configure()
    base = [("simulation.t_final", args.t_final), *override_items(args.set)]
    groups = [(o, o, []) for o in args.options]
    for v in args.variant:
        label, sets = v.split(":", 1)
        opt = label.split("@")[0]
        groups.append((label, opt, override_items(sets.split(","))))
    rows = []
    for label, opt, extra in groups:
        cases = []
        for s in args.sigmas:
            sets = [*base, ("plant.sensor.force_noise", s), ("controller.adaptation.robust", opt), *extra]
            sc = load_scenario(args.scenario, sets)
            name = f"{label}-s{s:g}"
            kind = "hinf_nn" if "hinf_nn" in sc.kinds else sc.kinds[0]
            cases.append(Case(name=name, scenario=sc.single(kind), tags={"option": label, "sigma": s}))
        t0 = time.perf_counter()
        try:
            outcome = simulate_cases(cases)
        except Exception as err:  # a design refused: say so
            print(f"{label}: {type(err).__name__}: {err}", flush=True)
            continue
        dt = time.perf_counter() - t0
        for c in cases:
            r = row(c.name, outcome.trajectories[c.name], outcome.metrics[c.name], args.t_final)
            r.update(option=label, sigma=c.tags["sigma"], seconds=dt / len(cases), scenario=args.scenario)
            rows.append(r)
            print(json.dumps(r), flush=True)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(rows, f, indent=1)
    return rows


if __name__ == "__main__":
    main()
