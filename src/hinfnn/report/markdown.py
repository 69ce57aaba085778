"""Tables of a results document (``metrics.json``): the metrics of every run, why a run stopped,
the designed controllers, as Markdown or aligned text (``hinfnn show``, every report)."""

from __future__ import annotations

import math


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
    off = [r["name"] for r in doc["runs"] if not _bookkeeping(doc, r)]
    if off:
        lines.append(f"{', '.join(off)}: J(T) and the dissipation verdict n/a: the run did not integrate the "
                     "theorems' bookkeeping (simulation.bookkeeping = false)")
    return "\n".join(lines)


def _bookkeeping(doc, run) -> bool:
    """Whether a run of a results document integrated the theorems' bookkeeping (its overrides,
    else the document's scenario; on by default)."""
    over = run.get("overrides") or {}
    if "simulation.bookkeeping" in over:
        return bool(over["simulation.bookkeeping"])
    sim = (doc.get("scenario") or {}).get("simulation") or {}
    return bool(sim.get("bookkeeping", True))


def job_done(run) -> str:
    """The run's verdicts in a few words (hinfnn.metrics.verdicts): "yes", or "no: contact lost,
    tracking off", with "(contact not judged)" when ``contact_held`` is None (null: no step after
    ``verdict.contact_after``) ("-" for a document written before the verdicts)."""
    v = run.get("verdict")
    if not v:
        return "-"
    bad = [word for key, word in (("contact_held", "contact lost"), ("tracking_within_tolerance", "tracking off"),
                                  ("within_joint_limits", "joint limit")) if v.get(key) is False]
    unjudged = " (contact not judged)" if "contact_held" in v and v["contact_held"] is None else ""
    return ("no: " + ", ".join(bad) if bad else "yes") + unjudged


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
        known = ("K_p", "K_v", "rho", "mu_z", "alpha_z", "alpha_lam", "beta_lam", "gamma_1", "gamma_2")
        names = [k for k in known if k in g] + [k for k in g if k not in known and k not in ("Q_p", "R_p")]
        lines.append("  gains     " + ", ".join(f"{k} = {_gain(g[k])}" for k in names))
        if "Q_p" in g or "R_p" in g:
            lines.append(f"            Q_p = {_matrix(g.get('Q_p'))}, R_p = {_matrix(g.get('R_p'))}")
        for key, b in (d.get("bounds") or {}).items():
            op = ">" if key == "alpha_lam" else ">="
            lines.append(f"  bound     {key} = {_f(b.get('value'))} {op} {_f(b.get('bound'))}, margin {_f(b.get('margin'))}"
                         f"  [{b.get('rule', '')}]")
        ric = d.get("riccati")
        if ric is None:
            pass
        elif "error" in ric:
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
