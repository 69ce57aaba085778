"""The contact modes behind benchmarks/stiff_arms.py: for each arm's ``-stable`` scenario and law,
the least damped force-loop mode of the linearised closed loop (the simulator's right-hand side on
the exact nominal model, at rest at the reference's offsets) with the paper's law (κ = 0) and with
the force-rate term, at k = 1e4, 1e5, 1e6 N/m; and the spectral radius of the linearised 1 kHz
sampled loop (the design for 1e4 … 1e5 N/m at k ≤ 1e5, for 1e4 … 1e6 at 1e6 when the design
accepts it). Printed as a table; ``--json`` writes it.

    python benchmarks/stiff_arms_modes.py [--arms ...] [--kinds ...] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys

ARMS = ("ur5-table", "ur5-sphere", "planar3-drum")
KINDS = ("hinf", "hinf_nn")
STIFFNESS = (1e4, 1e5, 1e6)


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--arms", nargs="+", default=list(ARMS))
    p.add_argument("--kinds", nargs="+", default=list(KINDS))
    p.add_argument("--no-sampled", action="store_true")
    p.add_argument("--json")
    args = p.parse_args(argv)

    import hinfnn as H
    from hinfnn import analysis as A

    H.configure()
    rows = []
    for arm in args.arms:
        for kind in args.kinds:
            sc = H.load_scenario(f"{arm}-stable", {"controller.kind": kind, "controller.force_rate.stiffness_max": 1e6})
            ctrl = sc.build_controller()
            for k in STIFFNESS:
                for variant, c in (("paper", A.with_kappa(ctrl, 0.0)), ("stable", ctrl)):
                    r = A.contact_modes(sc, kind, k, ctrl=c)
                    row = dict(arm=arm, kind=kind, k=k, variant=variant, mode="cont", kappa=r["kappa"],
                               least=str(r["least_damped"]), s=[r["least_damped"].s.real, r["least_damped"].s.imag],
                               stable=r["stable"], match=r["polynomial_match"], m_s=r["constants"]["m_s"],
                               force=[[e.real, e.imag] for e in r["force_eigenvalues"]])
                    rows.append(row)
                    print(f"{arm:<13} {kind:<8} {k:>7.0e} {variant:<7} cont  kappa {r['kappa']:.4g}: {row['least']:<28} "
                          f"{'stable' if row['stable'] else 'UNSTABLE'}  (poly {row['match']})", flush=True)
            if args.no_sampled:
                continue
            for k in STIFFNESS:
                over = {"controller.kind": kind, "simulation.control": "sampled",
                        "controller.force_rate.stiffness_max": 1e5 if k <= 1e5 else k}
                try:
                    sc1 = H.load_scenario(f"{arm}-stable", over)
                except H.DesignError as err:
                    print(f"{arm:<13} {kind:<8} {k:>7.0e} stable  1kHz  refused: {err}", flush=True)
                    rows.append(dict(arm=arm, kind=kind, k=k, variant="stable", mode="1kHz", refused=str(err)))
                    sc1 = H.load_scenario(f"{arm}-stable", {**over, "controller.force_rate.stiffness_max": 1e5})
                    variants = (("paper", A.with_kappa(sc1.build_controller(), 0.0)),)
                else:
                    c1 = sc1.build_controller()
                    variants = (("paper", A.with_kappa(c1, 0.0)), ("stable", c1))
                for variant, c in variants:
                    plant, ref, q_eq, _, _ = A.operating_point(sc1, k, ctrl=c)
                    s = A.sampled_modes(plant, c, ref, q_eq, 1e-3, sc1.simulation.dt)
                    fr = c.term(H.controllers.ForceRate)
                    rows.append(dict(arm=arm, kind=kind, k=k, variant=variant, mode="1kHz", radius=s["radius"],
                                     least=str(s["least_damped"]), stable=s["stable"], kappa=float(fr.kappa)))
                    print(f"{arm:<13} {kind:<8} {k:>7.0e} {variant:<7} 1kHz  kappa {float(fr.kappa):.4g}: radius "
                          f"{s['radius']:.5f} least {s['least_damped']}", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
