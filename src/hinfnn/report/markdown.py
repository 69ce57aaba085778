"""``report.md`` of the paper study: what was run and how, the claims, the metrics, the figures.

Every number and count in the report comes from the scenario and the results document
(``metrics.json``): the run count, the horizon and windows, the gains, the resolved β_λ, the
networks' layout, the v_p gains. Nothing is written from memory of the paper scenario.
"""

from __future__ import annotations

import datetime
import math

from .claims import CLAIMS, RULES, contacts, dependence, evaluate

#: The paper, by its full reference (the report is read without hinfnn's repository at hand).
PAPER = ("M.-C. Hwang and X. Hu, \"A Robust Position/Force Learning Controller of Manipulators via Nonlinear H∞ "
         "Control and Neural Networks\", IEEE Transactions on Systems, Man, and Cybernetics, Part B, 30(2), 2000")
CONVENTIONS = "hinfnn's `docs/paper-conventions.md`"


def _f(x, digits=4) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    if isinstance(x, bool):
        return "yes" if x else "**no**"
    if not isinstance(x, (int, float)):
        return str(x)
    ax = abs(x)
    if ax != 0 and (ax < 1e-3 or ax >= 1e5):
        return f"{x:.3e}"
    return f"{x:.{digits}g}"


def percent(fraction) -> str:
    """A fraction of time as a percentage, the same way in every table and sentence."""
    if not isinstance(fraction, (int, float)) or not math.isfinite(fraction):
        return "n/a"
    p = 100.0 * fraction
    if p == 0:
        return "0 %"
    return f"{p:.3g} %" if p >= 0.01 else f"{p:.2e} %"


def _short(subject: str) -> str:
    """'adaptive (paper-likely) vs H∞-only' -> 'paper-likely'; 'H∞-only' stays."""
    head = subject.split(" vs ")[0]
    if head.startswith("adaptive (") and head.endswith(")"):
        return head[len("adaptive ("):-1]
    return head


def _pair(v) -> str:
    if not isinstance(v, (list, tuple)):
        return _f(v)
    return " / ".join(_f(x) for x in v)


def _matrix(v) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(_matrix(x) for x in v) + "]"
    return _f(v)


def _design(doc, kind: str) -> dict | None:
    """The design summary of the first run of ``kind`` (every run of a kind shares its gains)."""
    return next((r.get("design") for r in doc["runs"] if r["controller"] == kind and r.get("design")), None)


def _networks_text(design: dict | None, key: str, inputs: str) -> str:
    nets = (design or {}).get("networks", {})
    n = nets.get(key)
    if not n:
        return "not used"
    step = f"step {_f(n['step'])}" if n["step"] is not None else "one unit"
    return (f"tanh(α({inputs} − c_i)), {n['units']} centres from {_f(n['first_centre'])} to {_f(n['last_centre'])} "
            f"({step}), α = {_f(n['slope'])}" + (f", projection radius {_f(n['radius'])}" if n["radius"] else ""))


def _modelling(sc, doc, damped: float) -> str:
    p, n, s = sc.plant, sc.nominal, sc.simulation
    g = sc.controller.gains
    d = _design(doc, "hinf") or _design(doc, "hinf_nn") or {}
    resolved = d.get("gains", {})
    bound = d.get("bounds", {}).get("beta_lam", {})
    beta = resolved.get("beta_lam")
    presets = sorted({r["overrides"].get("controller.network_f.preset") for r in doc["runs"]
                      if r["controller"] == "hinf_nn" and r["overrides"].get("controller.network_f.preset")})
    printed = _design(doc, "hinf_nn")
    nf_rows = []
    for r in doc["runs"]:
        if r["controller"] == "hinf_nn" and r.get("design") and r["name"] in ("hinf_nn", "hinf_nn_printed"):
            preset = r["overrides"].get("controller.network_f.preset", sc.controller.network_f.preset)
            nf_rows.append(f"`{preset}`: " + _networks_text(r["design"], "theta_f", "e_λ + z"))
    rows = [
        ("true arm", f"m1 = {p.arm.m1:g} kg, m2 = {p.arm.m2:g} kg, l1 = {p.arm.l1:g} m, l2 = {p.arm.l2:g} m, "
                     f"g = {p.arm.g:g} m/s²", "Sec. VI"),
        ("nominal arm", f"m̂1 = {n.arm.m1:g}, m̂2 = {n.arm.m2:g}, l̂1 = {n.arm.l1:g}, l̂2 = {n.arm.l2:g}", "Sec. VI"),
        ("surface", f"true δ = {p.surface.delta_deg:g}°, nominal δ̂ = {n.surface.delta_deg:g}°, "
                    f"d_G = {p.surface.d_G:g} m", "Sec. VI"),
        ("constraint scaling", f"`{n.surface.scaling}`"
         + (": θ̂ = (x1 − d_G) tan δ̂ − x2, λ > 0 pressing, normal force = λ / cos δ̂"
            if n.surface.scaling == "paper" else ": λ is the normal force in N"), "conventions: constraint sign"),
        ("contact", f"frictionless unilateral penalty spring on the TRUE surface, k = {p.contact.stiffness:g} N/m; "
                    f"damping {p.contact.damping:g} N·s/m (the paper has none) and {damped:g} N·s/m (sensitivity "
                    "study)", "conventions: contact"),
        ("disturbance", f"square wave ±{_pair(p.disturbance.amplitude)} N·m, period {p.disturbance.period:g} s, "
                        f"phase {p.disturbance.phase:g} s (+ first)", "conventions: disturbance phase"),
        ("measurements", "q, q̇ and the force vector F; u1, u̇1 from the NOMINAL kinematics, λ = ÂF/(ÂÂᵀ)",
         "conventions: measurements"),
        ("initial state", f"u1(0) = {sc.initial.u1:g} m, true end-effector on the true surface, elbow "
                          f"{sc.initial.elbow}, q̇ = 0, z = 0, weights 0", "conventions: initial state"),
        ("gains", f"ρ = {g.rho:g}, μ_z = {g.mu_z:g}, K_p = {g.K_p:g}, K_v = {g.K_v:g}, α_λ = {g.alpha_lam:g}, "
                  f"α_z = {g.alpha_z:g}, γ1 = {g.gamma_1:g}, γ2 = {g.gamma_2:g}, Q_p = {_matrix(resolved.get('Q_p'))}, "
                  f"R_p = {_matrix(resolved.get('R_p'))}", "Sec. VI; R_p is m × m: conventions, printed errors"),
        ("β_λ", f"{_f(beta)} " + ("(the minimum Theorem 1 allows, α_λα_z/(2ρ²) − 1)" if g.beta_lam == "min"
                                  else f"(Theorem 1's bound {_f(bound.get('bound'))})"), "conventions: β_λ"),
        ("F_p network", _networks_text(printed, "theta_p", "e_u1 + ė_u1"), "Sec. VI; α = 1: conventions"),
        ("F_f network", "; ".join(nf_rows) or _networks_text(printed, "theta_f", "e_λ + z"),
         "conventions: F_f centre step" + (f" (presets run: {', '.join(presets)})" if presets else "")),
        ("FL-like law", "with ü1d (printed: u̇1d)", "conventions: printed errors"),
        ("reduced model", "M̄ = SᵀĴ⁻ᵀM̂Ĵ⁻¹S, Ḡ = SᵀĴ⁻ᵀĜ; Coriolis C(2,1) = +q̇1", "conventions: printed errors"),
        ("Riccati", f"eq. ({(d.get('riccati') or {}).get('equation', '35')}) through the Hamiltonian's stable "
                    f"subspace, residual {_f((d.get('riccati') or {}).get('residual'))}, P ≻ 0, Hurwitz",
         "conventions: Riccati"),
        ("integration", f"fixed-step RK4, dt = {s.dt:g} s (steps land on the disturbance's switches), "
                        f"{s.control} control, horizon {s.t_final:g} s", "conventions: horizon (not in paper)"),
        ("J(t)", "eq. (34) integrated as a state, the same weights for every controller", "conventions: J"),
    ]
    out = ["| item | value | source |", "|---|---|---|"]
    out += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    return "\n".join(out)


def metrics_table(doc, *, markdown: bool = True) -> str:
    """The metrics of every run of a results document, as Markdown (the report) or as aligned
    text (``hinfnn run`` / ``show``): one table model, two renderings."""
    head = ["run", "status", "did its job", "RMS e_u1 (m)", "last 2 s", "RMS e_λ", "last 2 s", "J(T)", "peak τ (N·m)",
            "peak τ last 2 s", "RMS τ last 2 s", "out of contact", "dissipation holds"]
    rows = []
    for r in doc["runs"]:
        m = r["metrics"]
        status = r.get("status", "ok")
        if status != "ok":
            status = f"stopped at {_f(r.get('t_fail'))} s" + (" (partial metrics)" if r.get("partial") else "")
            if markdown and r.get("reason"):
                status += ": " + r["reason"].replace("|", "\\|")
        g = m.get
        rows.append([r.get("label") or r["name"] if markdown else r["name"], status, job_done(r), _f(g("rms_e_u1")),
                     _f(g("rms_e_u1_last2s")), _f(g("rms_e_lam")), _f(g("rms_e_lam_last2s")), _f(g("J_T")),
                     _pair(g("peak_abs_tau")), _pair(g("peak_abs_tau_last2s")), _pair(g("rms_tau_last2s")),
                     percent(g("fraction_out_of_contact")), _f(g("dissipation_holds_for_all_t"))])
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(row) + " |" for row in rows]
        return "\n".join(lines)
    keep = [0, 1, 2, 3, 4, 5, 6, 7, 8, 11, 12]
    head = [head[i] for i in keep]
    rows = [[row[i].replace("**", "") for i in keep] for row in rows]
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(head)]
    fmt = lambda cells: "  ".join(c.ljust(w) if i < 3 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))  # noqa: E731
    lines = [fmt(head), "-" * (sum(widths) + 2 * (len(widths) - 1))]
    lines += [fmt(row) for row in rows]
    lines += stopped_notes(doc)
    lines += [f"{r['name']}: {note}" for r in doc["runs"] for note in (r.get("verdict") or {}).get("notes", ())]
    return "\n".join(lines)


def job_done(run) -> str:
    """The run's verdicts in a few words (hinfnn.metrics.verdicts): "yes", or "no: contact lost,
    tracking off" ("-" for a document written before the verdicts)."""
    v = run.get("verdict")
    if not v:
        return "-"
    bad = [word for key, word in (("contact_held", "contact lost"), ("tracking_within_tolerance", "tracking off"),
                                  ("within_joint_limits", "joint limit")) if v.get(key) is False]
    return "no: " + ", ".join(bad) if bad else "yes"


def stopped_notes(doc) -> list[str]:
    """One line per run that stopped early: when, why, and what its metrics cover."""
    out = []
    for r in doc["runs"]:
        if r.get("status", "ok") == "ok":
            continue
        end = (r.get("metrics") or {}).get("t_end")
        cover = f"its metrics cover 0 to {_f(end)} s (partial)" if r.get("partial") else "no metrics"
        out.append(f"{r['name']}: stopped at t = {_f(r.get('t_fail'))} s: {r.get('reason') or 'unknown reason'}; {cover}")
    return out


def _gain(v) -> str:
    """A gain that is a 1×1 matrix prints as a number."""
    while isinstance(v, list) and len(v) == 1:
        v = v[0]
    return _matrix(v)


def design_text(doc) -> str:
    """The designed controllers of a results document as text (``hinfnn show``): for each
    distinct design, the runs that use it, the resolved gains (β_λ included), Theorem 1's bounds
    with their margins, P_p with the Riccati residual, v_p's gains and the networks."""
    groups: list[tuple[dict, list[str]]] = []
    for r in doc["runs"]:
        d = r.get("design")
        if not d:
            continue
        for known, names in groups:
            if known == d:
                names.append(r["name"])
                break
        else:
            groups.append((d, [r["name"]]))
    if not groups:
        return "no design recorded (metrics.json written before hinfnn 0.2)"
    lines = []
    for d, names in groups:
        g = d.get("gains", {})
        lines.append(f"design of {d.get('kind', '?')} (run{'s' if len(names) > 1 else ''} {', '.join(names)}): "
                     f"terms {' + '.join(d.get('terms', []))}" + (", augmented (Remark 1)" if d.get("augmented") else ""))
        lines.append("  gains     " + ", ".join(f"{k} = {_gain(g[k])}" for k in
                                                 ("K_p", "K_v", "rho", "mu_z", "alpha_z", "alpha_lam", "beta_lam",
                                                  "gamma_1", "gamma_2") if k in g))
        lines.append(f"            Q_p = {_matrix(g.get('Q_p'))}, R_p = {_matrix(g.get('R_p'))}")
        for key, b in (d.get("bounds") or {}).items():
            op = ">" if key == "alpha_lam" else ">="
            lines.append(f"  bound     {key} = {_f(b.get('value'))} {op} {_f(b.get('bound'))}, margin {_f(b.get('margin'))}"
                         f"  [{b.get('rule', '')}]")
        ric = d.get("riccati") or {}
        if "error" in ric:
            lines.append(f"  Riccati   {ric['error']}")
        else:
            eigs = ", ".join(_f(re) + (f"{im:+.3g}j" if im else "") for re, im in ric.get("closed_loop_eigs", []))
            lines.append(f"  P_p       {_matrix(d.get('P_p'))}  (eq. ({ric.get('equation', '?')}), residual "
                         f"{_f(ric.get('residual'))}, min eig {_f(ric.get('min_eig_P'))}, closed-loop eigenvalues {eigs}"
                         + (", Remark 4 holds" if ric.get("remark4_holds") else "") + ")")
        if "v_p_gains" in d:
            lines.append(f"  v_p       -{_matrix(d['v_p_gains'])} x_p  (R_p^-1 B_p^T P_p)")
        for key, n in (d.get("networks") or {}).items():
            step = f"step {_f(n['step'])}" if n.get("step") is not None else "one unit"
            lines.append(f"  network   {key}: {n['units']} tanh units, centres {_f(n['first_centre'])} to "
                         f"{_f(n['last_centre'])} ({step}), slope {_f(n['slope'])}"
                         + (f", projection radius {_f(n['radius'])}" if n.get("radius") else ""))
    return "\n".join(lines)


def _findings(metrics: dict, doc: dict, sc, damped: float, is_paper: bool) -> list[str]:
    """Sentences the numbers support, on why claims hold or fail. Each is stated only when the
    numbers it rests on are what it says (the study may run on a modified scenario)."""
    out = []
    g = metrics.get
    pct = lambda m: 100 * m["fraction_out_of_contact"]  # noqa: E731

    def ok(*ms):
        return all(m is not None and m.get("status") == "ok" for m in ms)

    fl, hinf, nn = g("fl"), g("hinf"), g("hinf_nn")
    if ok(fl, hinf, nn):
        bouncing = [name for name, m in (("FL-like", fl), ("H∞-only", hinf)) if pct(m) > 5.0]
        if bouncing and pct(nn) < 1.0:
            out.append(
                f"**Contact bouncing decides force tracking with the undamped contact.** Out of contact "
                f"{percent(fl['fraction_out_of_contact'])} of the time under the FL-like controller, "
                f"{percent(hinf['fraction_out_of_contact'])} under H∞-only and "
                f"{percent(nn['fraction_out_of_contact'])} under the adaptive controller (paper-likely): "
                f"{' and '.join(bouncing)} let the end-effector bounce on the undamped penalty contact, and "
                f"impacts dominate their RMS e_λ ({_f(fl['rms_e_lam'])}, {_f(hinf['rms_e_lam'])}); the "
                f"adaptive controller's F_f learns a term that keeps contact (RMS e_λ over the last 2 s "
                f"{_f(nn['rms_e_lam_last2s'])}).")
    fld, hinfd, nnd = g("fl_damped"), g("hinf_damped"), g("hinf_nn_damped")
    if ok(fld, hinfd, nnd):
        fr = [m["fraction_out_of_contact"] for m in (fld, hinfd, nnd)]
        state = "nothing bounces" if max(fr) < 1e-3 else "the contact still opens at times"
        out.append(
            f"**With {_f(damped)} N·s/m of contact damping {state}** (out of contact: FL-like {percent(fr[0])}, "
            f"H∞-only {percent(fr[1])}, adaptive {percent(fr[2])}); RMS e_λ over the last 2 s: FL-like "
            f"{_f(fld['rms_e_lam_last2s'])}, H∞-only {_f(hinfd['rms_e_lam_last2s'])}, adaptive "
            f"{_f(nnd['rms_e_lam_last2s'])}.")
    ex, exd = g("hinf_exact"), g("hinf_exact_damped")
    d = _design(doc, "hinf") or {}
    if ok(hinf, ex, hinfd, exd):
        amp = abs(sc.reference.u1_amplitude)
        text = (f"**Position error and model mismatch.** RMS e_u1 is {_f(hinfd['rms_e_u1'])} m for H∞-only "
                f"(damped contact) against a reference amplitude of {_f(amp)} m; with the TRUE parameters as "
                f"its nominal model (same disturbance) it is {_f(exd['rms_e_u1'])} m (undamped contact: "
                f"{_f(hinf['rms_e_u1'])} vs {_f(ex['rms_e_u1'])} m).")
        if exd["rms_e_u1"] < 0.5 * hinfd["rms_e_u1"]:
            text += " Most of the position error comes from the model mismatch, not the disturbance."
        vp, sp = d.get("v_p_gains"), d.get("s_p_gains")
        if vp and sp:
            gg = d["gains"]
            text += (f" The robustifying term v_p = −R_p⁻¹B_pᵀP_px_p has gains {_f(vp[0][0])} on e_u1 and "
                     f"{_f(vp[0][1])} on ė_u1 (against K_p = {_matrix(gg['K_p'])}, K_v = {_matrix(gg['K_v'])}), "
                     f"and F_p's update is driven by B_pᵀP_px_p = {_f(sp[0][0])} e_u1 + {_f(sp[0][1])} ė_u1 "
                     f"(times γ1 = {_f(gg['gamma_1'])}).")
        if ok(nn):
            text += (f" The adaptive controller's RMS e_u1 over the last 2 s is {_f(nn['rms_e_u1_last2s'])} m "
                     f"vs {_f(hinf['rms_e_u1_last2s'])} m for H∞-only (undamped).")
        out.append(text)
    pr, prd = g("hinf_nn_printed"), g("hinf_nn_printed_damped")
    if ok(pr, nn):
        c0 = sc.controller.network_f.centre_start
        text = (f"**The F_f centre step.** With the printed step 0.05 the centres span {_f(c0)} … "
                f"{_f(c0 + 0.05 * 119)}, so for e_λ + z above that every unit saturates at +1 and F_f is a single "
                f"integrator of e_λ. Undamped: RMS e_λ over the last 2 s {_f(pr['rms_e_lam_last2s'])} (step 0.5: "
                f"{_f(nn['rms_e_lam_last2s'])}), peak |τ1| over the last 2 s {_f(pr['peak_abs_tau_last2s'][0])} "
                f"N·m (step 0.5: {_f(nn['peak_abs_tau_last2s'][0])}), J(T) = {_f(pr['J_T'])} (step 0.5: "
                f"{_f(nn['J_T'])}).")
        if ok(prd):
            text += f" Damped: RMS e_λ over the last 2 s {_f(prd['rms_e_lam_last2s'])}."
        if is_paper:
            text += (" On the paper scenario the undamped step-0.05 run is chaotic: its metrics move by "
                     "about 3 % when u1(0) moves by 1e-9 m, so its digits beyond the second are not reproducible "
                     "across machines or JAX versions.")
        out.append(text)
    if ok(nn, hinf) and nn["peak_abs_tau"][0] > 2 * hinf["peak_abs_tau"][0]:
        out.append(
            f"**Learning costs torque.** The adaptive controller's peak |τ1| over the run is "
            f"{_f(nn['peak_abs_tau'][0])} N·m against {_f(nn['peak_abs_tau_last2s'][0])} N·m over the last "
            f"2 s (H∞-only: {_f(hinf['peak_abs_tau'][0])} N·m): the peak comes while F_f's weights grow and "
            "the force loop chatters at hundreds of Hz (Figs. 7–8, zoom A). The paper's Figs. 7–8 are not "
            "in the text we have, so whether it saw this transient cannot be checked."
            + (f" With the damped contact the peak is {_f(nnd['peak_abs_tau'][0])} N·m." if ok(nnd) else ""))
    partial = [r for r in doc["runs"] if r.get("status") != "ok"]
    if partial:
        out.append("**Runs that stopped early:** " + "; ".join(
            f"{r['label']} at t = {_f(r['t_fail'])} s ({r['reason']}); its metrics cover [0, {_f(r['metrics']['t_end'])}] s"
            for r in partial) + ".")
    return out


def study_report(scenario, doc: dict, figures: list[str], timings: dict, is_paper: bool = False) -> str:
    """The Markdown report of the paper study, from the scenario and the results document."""
    sc = scenario
    metrics = {r["name"]: {**r["metrics"], "status": r["status"]} for r in doc["runs"]}
    labels = {r["name"]: r.get("label", r["name"]) for r in doc["runs"]}
    runs = doc["runs"]
    damped_runs = [r for r in runs if r["name"].endswith("_damped")]
    damped = damped_runs[0]["overrides"].get("plant.contact.damping", 200.0) if damped_runs else 200.0
    models = contacts(damped)
    results = evaluate(metrics, sc.reference.u1_amplitude, sc.reference.lam_amplitude, models)
    deps = dependence(results)
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    horizons = sorted({r["metrics"]["t_end"] for r in runs if r["status"] == "ok"})
    T = sc.simulation.t_final
    per_model = {suffix: [r for r in runs if (r["name"].endswith("_damped")) == (suffix == "_damped")]
                 for suffix in models}
    kinds_run = sorted({labels[r["name"]].split(" (")[0].split(",")[0] for r in runs})
    lines = [
        "# Hwang & Hu, Sec. VI, reproduced by hinfnn",
        "",
        f"hinfnn {doc['hinfnn_version']}, {now}. Command: `{doc['command']}`. Paper: {PAPER}. Every choice "
        f"the paper leaves open, and every printed error hinfnn corrects, is in {CONVENTIONS}. The resolved "
        "scenario is `scenario.toml`; every number below is in `metrics.json` (with the designed controllers "
        "and units), every trajectory in `trajectory.npz` (`hinfnn.load(FOLDER)`).",
        "",
        "## What was run",
        "",
        f"{len(runs)} runs, each {T:g} s of the scenario `{sc.name}` with one controller, simulated together "
        f"(batched by controller structure): "
        + "; ".join(f"{len(rs)} with the {models[suffix]} contact" for suffix, rs in per_model.items() if rs)
        + f". Controllers: {', '.join(kinds_run)}. The exact-model runs give the H∞-only controller the TRUE "
        "arm and surface as its nominal model, to separate model mismatch from disturbance. The damped contact "
        "is a sensitivity study, not in the paper.",
        "",
        _modelling(sc, doc, damped),
        "",
        "## Claims",
        "",
        "Each claim is decided by a fixed rule written before looking at the results; no parameter was "
        "tuned to make a claim hold.",
        "",
    ]
    for c, statement in CLAIMS.items():
        rows = [r for r in results if r.claim == c]
        if not rows:
            continue
        lines += [f"### {c}. {statement}", "", f"Rule: {RULES[c]}. Verdict: {deps.get(c, '')}.", "",
                  "| contact | run | verdict | numbers |", "|---|---|---|---|"]
        for r in rows:
            verdict = "held" if r.held else ("undecided" if r.held is None else "**did not hold**")
            lines.append(f"| {r.contact} | {r.subject} | {verdict} | {r.evidence} |")
        lines.append("")
    lines += ["### Summary", "", "| claim | " + " | ".join(models.values()) + " |", "|---|" + "---|" * len(models)]
    for c in CLAIMS:
        cells = []
        for contact in models.values():
            rows = [r for r in results if r.claim == c and r.contact == contact and "not claimed" not in r.subject]
            if not rows:
                cells.append("–")
                continue
            cells.append(", ".join(
                f"{'held' if r.held else ('undecided' if r.held is None else 'did not hold')}"
                + (f" ({_short(r.subject)})" if len(rows) > 1 else "") for r in rows))
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    window = (f"t ≥ {_f(horizons[0] - 2.0)} s" if len(horizons) == 1 else
              "the last 2 s of each run")
    lines += ["", "## What the numbers show", ""]
    lines += [f"- {s}" for s in _findings(metrics, doc, sc, damped, is_paper)]
    lines += ["", "## Metrics", "",
              "Errors are measured as the controller sees them (nominal kinematics). λ is in the units of the "
              f"constraint scaling above. *last 2 s*: {window}. *dissipation holds*: at every saved t "
              "(Theorems 1–2; not claimed for FL-like). Units of every metric: `metrics.json`, \"units\".", "",
              metrics_table(doc), "", "## Figures", ""]
    captions = {
        "fig3_u1_fl": "Fig. 3: u1(t) under the FL-like controller",
        "fig4_lambda_fl": "Fig. 4: λ(t) under the FL-like controller",
        "fig5_u1": "Fig. 5: u1(t), H∞-only vs adaptive",
        "fig6_lambda": "Fig. 6: λ(t), H∞-only vs adaptive",
        "fig7_tau1": "Fig. 7: τ1(t)",
        "fig8_tau2": "Fig. 8: τ2(t)",
        "fig9_J": "Fig. 9: J(t) of eq. (34)",
    }
    for suffix, title in (("", "Undamped contact (the paper's)"), ("_damped", f"Damped contact ({damped:g} N·s/m)")):
        lines += [f"### {title}", ""]
        for stem, cap in captions.items():
            name = f"{stem}{suffix}.png"
            if name in figures:
                lines += [f"![{cap}]({name})", ""]
    if doc.get("beyond"):
        lines += beyond_section(doc["beyond"], figures)
        lines.append("")
    lines += ["## Timing", "", "| step | wall time (s) |", "|---|---|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in timings.items()]
    lines.append("")
    return "\n".join(lines)


#: The targets of the stabilised laws on the undamped contact ("Beyond the paper").
BEYOND_TARGETS = {
    "hinf": {"rms_e_lam": 2.0, "rms_e_u1": 0.02, "peak_abs_tau1_after_0.1s": 250.0},
    "hinf_nn": {"rms_e_lam": 1.2, "rms_e_u1": 0.02, "peak_abs_tau1_after_0.1s": 250.0},
}


def _target_row(case, m) -> tuple[str, bool | None]:
    t = BEYOND_TARGETS[case["kind"]]
    if m is None:
        return "not run", None
    if m.get("status") != "ok":
        return f"stopped at t = {_f(m.get('t_end'))} s", False
    checks = [
        (m["fraction_out_of_contact"] == 0.0, f"out of contact {percent(m['fraction_out_of_contact'])}"),
        (m["rms_e_lam"] <= t["rms_e_lam"], f"RMS e_λ {_f(m['rms_e_lam'])} (≤ {t['rms_e_lam']:g})"),
        (m["rms_e_u1"] <= t["rms_e_u1"], f"RMS e_u1 {_f(m['rms_e_u1'])} m (≤ {t['rms_e_u1']:g})"),
        (m["peak_abs_tau1_after_0.1s"] <= t["peak_abs_tau1_after_0.1s"],
         f"peak |τ1| after 0.1 s {_f(m['peak_abs_tau1_after_0.1s'])} N·m (≤ {t['peak_abs_tau1_after_0.1s']:g})"),
        (m["dissipation_holds_for_all_t"] is True, f"dissipation {'holds' if m['dissipation_holds_for_all_t'] else 'fails'}"),
    ]
    text = "; ".join(("" if ok else "**") + words + ("" if ok else "**") for ok, words in checks)
    return text, all(ok for ok, _ in checks)


def _qp_words(beyond: dict) -> str:
    """"weight the position error in Q_p = diag(…) (v_p's gains grow from … to …), " from the
    designs of the H∞-only runs, paper law and stabilised (empty when they are missing)."""
    def design(variant):
        return next((r.get("design") or {} for r in beyond["runs"] for c in beyond["cases"]
                     if c["name"] == r["name"] and c["kind"] == "hinf" and c["variant"] == variant
                     and c["mode"] == "cont"), {})

    paper, stable = design("paper"), design("stable")
    try:
        q = stable["gains"]["Q_p"]
        before, after = paper["v_p_gains"][0], stable["v_p_gains"][0]
    except (KeyError, IndexError, TypeError):
        return ""
    diag = ", ".join(f"{q[i][i]:g}" for i in range(len(q)))
    return (f"weight the position error in Q_p = diag({diag}) (v_p's gains grow from "
            f"{' and '.join(_f(g) for g in before)} to {' and '.join(_f(g) for g in after)}), ")


def beyond_section(beyond: dict, figures: list[str]) -> list[str]:
    """The "Beyond the paper" section of report.md from ``metrics.json``'s "beyond" part: what
    was run, the stabilised laws against the targets, the linearised contact modes before and
    after, the design numbers, the figures."""
    cases, metrics = beyond["cases"], {r["name"]: {**r["metrics"], "status": r["status"]} for r in beyond["runs"]}
    design = beyond.get("design", {})
    lines = ["## Beyond the paper: keeping contact on a stiff undamped surface", "",
             "Not in the paper (docs/beyond-the-paper.md has the derivations). With the contact a stiff spring "
             "instead of a rigid constraint, the force loop of every law of the paper has an unstable pair: "
             "m_s s³ + m_s μ_z s² + k_u K' s + k_u (K' μ_z + α_z) fails Routh's test by −α_z m_s k_u for every gain. "
             "The stabilised laws (scenario `paper-stable`) add a force-rate term −κṡ to v_λ (ṡ a filtered "
             "derivative of e_λ, its filter state in the controller; the storage function gains "
             "α_λα_zκ/(2(1+β_λ))‖s‖², so the dissipation inequality keeps its form and is checked along every run), "
             f"{_qp_words(beyond)}and stop at the nominal Jacobian's singularity guard.", ""]
    if design:
        text = (f"Design (the controller's own step, from its nominal model): κ = 2ζ√(K' m_n,max/k_min) = "
                f"{_f(design.get('kappa_continuous'))} s with ζ = {_f(design.get('zeta'))}, K' = "
                f"{_f(design.get('K_prime'))}, m_n,max = {_f(design.get('m_n_max'))} kg (the heaviest pose of the "
                f"path along the normal), k_min = {_f(design.get('stiffness_min'))} N/m; filter τ_f = "
                f"{_f(1e3 * design.get('tau_f', math.nan))} ms. Under 1 kHz zero-order hold: κ = "
                f"{_f(beyond.get('kappa_sampled'))} s (0.8 of the stable window's upper end at "
                f"{beyond.get('sampled_stiffness_max', 1e5):.0e} N/m), τ_f = "
                f"{_f(1e3 * (beyond.get('design_1kHz') or {}).get('tau_f', math.nan))} ms.")
        fast = beyond.get("design_10kHz") or {}
        if fast.get("kappa") is not None:
            text += (f" Under a 10 kHz hold (and on MuJoCo, which holds the torque over its 0.1-ms step): κ = "
                     f"{_f(fast['kappa'])} s, τ_f = {_f(1e3 * fast['tau_f'])} ms.")
        if beyond.get("sampled_1e6_error"):
            text += (f" A design for 1e6 N/m at 1 kHz is refused by the design step: “{beyond['sampled_1e6_error']}”. "
                     "The 1 kHz stabilised runs therefore use the 1e5 N/m design at every stiffness, and the 1e6 N/m "
                     "case shows what that costs.")
        lines += [text]
    mj = [c for c in cases if c["mode"] == "mujoco"]
    horizon = max((m.get("t_end", 0.0) for m in metrics.values() if m.get("status") == "ok"), default=0.0)
    lines += ["", "### The stabilised laws against the targets", "",
              "Targets, on the undamped contact over 10 s: never out of contact, RMS e_λ ≤ 2 (H∞-only) and ≤ 1.2 "
              "(adaptive), RMS e_u1 ≤ 0.02 m, peak |τ1| ≤ 250 N·m after the first 0.1 s, the dissipation "
              f"inequality at every sample. These runs are {horizon:g} s long"
              + ("." if horizon >= 10 else ": the targets are stated for 10 s, and over a shorter run the start's "
                 "transient weighs more in the RMS values."), "", "| case | measured | targets met |", "|---|---|---|"]
    held = []
    for c in cases:
        if c["variant"] != "stable" or c["mode"] in ("mujoco", "10kHz"):
            continue
        text, ok = _target_row(c, metrics.get(c["name"]))
        held.append(ok)
        lines.append(f"| {c['label']} | {text} | {'yes' if ok else ('**no**' if ok is False else 'n/a')} |")
    lines += ["", f"{sum(1 for h in held if h)} of {len(held)} stabilised cases meet every target.", "",
              "### Every case", "",
              "| case | status | RMS e_u1 (m) | RMS e_λ | RMS e_λ last 2 s | peak abs τ1 after 0.1 s (N·m) | out of contact | dissipation holds |",
              "|---|---|---|---|---|---|---|---|"]
    for c in cases:
        m = metrics.get(c["name"])
        if m is None:
            continue
        status = "ok" if m["status"] == "ok" else f"stopped at {_f(m.get('t_end'))} s"
        lines.append(f"| {c['label']} | {status} | {_f(m['rms_e_u1'])} | {_f(m['rms_e_lam'])} | "
                     f"{_f(m['rms_e_lam_last2s'])} | {_f(m['peak_abs_tau1_after_0.1s'])} | "
                     f"{percent(m['fraction_out_of_contact'])} | {_f(m['dissipation_holds_for_all_t'])} |")
    if mj:
        lines += ["", "### The same on MuJoCo", "",
                  "MuJoCo as the true plant (docs/mujoco.md: the same arm and surface as MJCF, the contact converted "
                  "from N/m), undamped 1e5 N/m contact, the controller every 0.1 ms with zero-order hold, beside the "
                  "built-in plant under the same 10 kHz hold:", "",
                  "| law | plant | status | RMS e_u1 (m) | RMS e_λ | out of contact |", "|---|---|---|---|---|---|"]
        for c in mj:
            twin = next((d for d in cases if d["kind"] == c["kind"] and d["variant"] == c["variant"]
                         and d["mode"] == "10kHz" and d["k"] == c["k"]), None)
            for case, plant in ((twin, "built-in"), (c, "MuJoCo")):
                m = metrics.get(case["name"]) if case else None
                if m is None:
                    continue
                status = "ok" if m["status"] == "ok" else f"stopped at {_f(m.get('t_end'))} s"
                law = f"{'H∞-only' if c['kind'] == 'hinf' else 'adaptive'}, {'paper' if c['variant'] == 'paper' else 'stabilised'}"
                lines.append(f"| {law} | {plant} | {status} | {_f(m['rms_e_u1'])} | {_f(m['rms_e_lam'])} | "
                             f"{percent(m['fraction_out_of_contact'])} |")
    elif beyond.get("mujoco_skipped"):
        lines += ["", f"(The MuJoCo side-by-side was skipped: {beyond['mujoco_skipped']}.)"]
    modes = beyond.get("contact_modes", [])
    if modes:
        lines += ["", "### The linearised contact mode, before and after", "",
                  "Eigenvalues of the simulator's own right-hand side (JAX Jacobian) at rest on the exact model with "
                  "a constant reference; the least damped mode of the force loop, |s| and ζ (negative: unstable). "
                  "For the FL-like and H∞-only laws they match the roots of the loop polynomial to rounding "
                  "(column *match*); the adaptive law's is at Θ̂ = 0.", "",
                  "| law | k (N/m) | paper law | stabilised | match (paper / stabilised) |", "|---|---|---|---|---|"]
        by = {(m["kind"], m["variant"], m["stiffness"]): m for m in modes}
        for kind in dict.fromkeys(m["kind"] for m in modes):
            for k in dict.fromkeys(m["stiffness"] for m in modes):
                a, b = by.get((kind, "paper", k)), by.get((kind, "stable", k))
                if not (a and b):
                    continue
                lines.append(f"| {'H∞-only' if kind == 'hinf' else 'adaptive'} | {k:.0e} | {a['mode']} | {b['mode']} | "
                             f"{_f(a['polynomial_match'])} / {_f(b['polynomial_match'])} |")
    lines += ["", "### Figures", ""]
    for name, cap in (("beyond_lambda_u1.png", "λ(t) and u1(t), paper law and stabilised, 1e5 N/m, continuous"),
                      ("beyond_bars.png", "RMS e_λ, RMS e_u1 and time out of contact, every case")):
        if name in figures:
            lines += [f"![{cap}]({name})", ""]
    return lines
