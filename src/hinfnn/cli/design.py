"""``hinfnn design``: the designed controller(s) of a scenario, as text or JSON."""

from __future__ import annotations

import json


def main(args) -> int:
    from ..analysis import design_report
    from ..io import dumps_json
    from ..scenario import Scenario

    out = design_report(Scenario.load(args.scenario, args.overrides))
    if args.json:
        print(dumps_json(out), end="")
        return 0
    for kind, d in out.items():
        g = d["gains"]
        print(f"{kind}: terms {', '.join(d['terms']) or '(none: the CT law)'}{', augmented' if d['augmented'] else ''}")
        print(f"  gains: K_p {g['K_p']}, K_v {g['K_v']}, rho {g['rho']:g}, mu_z {g['mu_z']:g}, alpha_z {g['alpha_z']:g}, "
              f"alpha_lam {g['alpha_lam']:g}, beta_lam {g['beta_lam']:.6g}, gamma_1 {g['gamma_1']:g}, "
              f"gamma_2 {g['gamma_2']:g}, Q_p {g['Q_p']}, R_p {g['R_p']}")
        for name, b in d["bounds"].items():
            print(f"  bound {name}: {b['value']:.6g} vs {b['bound']:.6g} (margin {b['margin']:+.4g}): {b['rule']}")
        print(f"  P_p {json.dumps(d['P_p'])}")
        ric = d.get("riccati", {})
        if "residual" in ric:
            eig = ", ".join(f"{re:.4g}{im:+.4g}j" for re, im in ric["closed_loop_eigs"])
            print(f"  Riccati eq. ({ric['equation']}): residual {ric['residual']:.2e}, min eig P {ric['min_eig_P']:.4g}, "
                  f"closed loop {eig}, Remark 4's condition {'holds' if ric['remark4_holds'] else 'fails'}")
        else:
            print(f"  Riccati: {ric.get('error')}")
        if "v_p_gains" in d:
            print(f"  v_p = -[{', '.join(f'{v:.4g}' for v in d['v_p_gains'][0])}] x_p")
        for key, n in d.get("networks", {}).items():
            print(f"  network {key}: {n['units']} units, centres {n['first_centre']:g} .. {n['last_centre']:g}, "
                  f"slope {n['slope']:g}" + (f", radius {n['radius']:g}" if n["radius"] else ""))
        fr = d.get("force_rate")
        if fr:
            print(f"  force rate: kappa {fr['kappa']:.4g} s ({'rule' if fr['rule'] else 'given'}: zeta {fr['zeta']:g}, "
                  f"K' {fr['K_prime']:.4g}, m_n {fr['m_n_min']:.4g}..{fr['m_n_max']:.4g} kg, k {fr['stiffness_min']:g}"
                  f"..{fr['stiffness_max']:g} N/m), tau_f {fr['tau_f']:g} s"
                  + (f", sampled window {fr['window'][0]:.3g}..{fr['window'][1]:.3g} s" if fr.get("window") else ""))
        if d["singularity_stop"] > 0:
            print(f"  singularity guard: stop when sigma_min(J) < {d['singularity_stop']:g}")
        cm = d["contact_mode"]
        for label, m in cm.items():
            if label == "stiffness":
                continue
            text = m.get("error") or f"{m['mode']} ({'stable' if m['stable'] else 'UNSTABLE'})"
            print(f"  contact mode at {cm['stiffness']:g} N/m, {label}: {text}")
    return 0
