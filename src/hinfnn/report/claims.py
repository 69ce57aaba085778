"""The paper's Sec. VI claims checked against run metrics (docs/paper-conventions.md, "What the
paper claims").

Each claim has a stated, fixed decision rule (:data:`RULES`); the rule is applied to the metrics
of the study's runs, never tuned to the outcome. A claim is evaluated separately for each contact
model and each F_f centre preset, so the report can say which modelling choice it depends on.

Run names follow :mod:`hinfnn.study`: ``fl``, ``hinf``, ``hinf_nn`` (preset paper-likely) and
``hinf_nn_printed`` (preset paper-printed), with a suffix per contact model (``""`` for the
paper's undamped contact, ``"_damped"`` for the study's damped contact).

Claim 5 is of another nature than claims 1–4: f_p and f_f are computed as the residuals of the
error systems, so for a correct implementation the dissipation inequality holds by construction
(eqs. 39/58 bound V̇ pointwise). Its verdict checks the implementation against the theorem, not
the paper's practical claim that the controllers track well.
"""

from __future__ import annotations

import dataclasses
import math

CLAIMS = {
    1: "The FL-like controller does not track force or position well (Figs. 3–4).",
    2: "The adaptive H∞ NN controller tracks both u1 and λ better than the H∞-only one (Figs. 5–6).",
    3: "After a period of learning, its torques are smaller and less oscillatory (Figs. 7–8).",
    4: "Its performance index J(t) is lower (Fig. 9).",
    5: "The dissipation inequalities (34) and (54) hold along every trajectory (Theorems 1–2).",
}

RULES = {
    1: "held if the FL-like run's RMS e_u1 AND its RMS e_λ over the last 2 s both exceed 10 % of the "
       "reference's amplitude",
    2: "held if the adaptive run's RMS e_u1 and RMS e_λ are both below the H∞-only run's, over the "
       "whole run AND over the last 2 s (four comparisons)",
    3: "held if, over the last 2 s, the adaptive run's peak |τ_i| and its torque total variation per "
       "second are both below the H∞-only run's, for both joints (four comparisons)",
    4: "held if the adaptive run's J(T) is below the H∞-only run's",
    5: "held if J(t) + V(t) − V(0) ≤ ρ²∫₀ᵗ(‖f_p‖² + ‖f_f‖²) at every saved t, for the run (H∞-only "
       "and adaptive runs; reported for the FL-like run but not claimed there). With f_p, f_f the "
       "residuals of the error systems this holds by construction for a correct implementation: "
       "the verdict checks hinfnn's code against the theorem, not the paper's practical claim",
}

CONTACTS = {"": "undamped (paper)", "_damped": "damped 200 N·s/m"}


def contacts(damped: float) -> dict[str, str]:
    """The contact models of the study, by run-name suffix."""
    return {"": "undamped (paper)", "_damped": f"damped {damped:g} N·s/m"}
PRESETS = {"hinf_nn": "paper-likely", "hinf_nn_printed": "paper-printed"}


@dataclasses.dataclass(frozen=True)
class ClaimResult:
    claim: int
    contact: str
    subject: str  # preset or run the row is about
    held: bool | None  # None: a run it needs is missing or diverged
    evidence: str


def _fmt(x, unit="") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    ax = abs(x)
    s = f"{x:.4g}" if 1e-3 <= ax < 1e5 or ax == 0 else f"{x:.3e}"
    return s + (f" {unit}" if unit else "")


def _ok(m) -> bool:
    return m is not None and m.get("status", "ok") == "ok"


def _cmp(name, a, b, unit="") -> tuple[bool, str]:
    held = a < b
    return held, f"{name}: {_fmt(a, unit)} {'<' if held else '≥'} {_fmt(b, unit)}"


def evaluate(metrics: dict, u1_amplitude: float, lam_amplitude: float,
             contact_models: dict[str, str] | None = None) -> list[ClaimResult]:
    """Apply :data:`RULES` to ``metrics`` (run name -> metrics dict with a "status" key)."""
    out: list[ClaimResult] = []
    for suffix, contact in (contact_models or CONTACTS).items():
        fl = metrics.get("fl" + suffix)
        hinf = metrics.get("hinf" + suffix)
        if fl is not None:
            if _ok(fl):
                tu, tl = 0.1 * abs(u1_amplitude), 0.1 * abs(lam_amplitude)
                pu, pl = fl["rms_e_u1_last2s"] > tu, fl["rms_e_lam_last2s"] > tl
                ev = (f"RMS e_u1 (last 2 s) {_fmt(fl['rms_e_u1_last2s'], 'm')} "
                      f"{'>' if pu else '≤'} {_fmt(tu, 'm')}; RMS e_λ (last 2 s) "
                      f"{_fmt(fl['rms_e_lam_last2s'])} {'>' if pl else '≤'} {_fmt(tl)}; out of contact "
                      f"{100 * fl['fraction_out_of_contact']:.1f} % of the time")
                out.append(ClaimResult(1, contact, "FL-like", pu and pl, ev))
            else:
                out.append(ClaimResult(1, contact, "FL-like", None, "the FL-like run diverged"))
        for key, preset in PRESETS.items():
            nn = metrics.get(key + suffix)
            if nn is None:
                continue
            subject = f"adaptive ({preset}) vs H∞-only"
            if not (_ok(nn) and _ok(hinf)):
                for c in (2, 3, 4):
                    out.append(ClaimResult(c, contact, subject, None, "a run it needs diverged or is missing"))
            else:
                checks = [
                    _cmp("RMS e_u1", nn["rms_e_u1"], hinf["rms_e_u1"], "m"),
                    _cmp("RMS e_u1 last 2 s", nn["rms_e_u1_last2s"], hinf["rms_e_u1_last2s"], "m"),
                    _cmp("RMS e_λ", nn["rms_e_lam"], hinf["rms_e_lam"]),
                    _cmp("RMS e_λ last 2 s", nn["rms_e_lam_last2s"], hinf["rms_e_lam_last2s"]),
                ]
                out.append(ClaimResult(2, contact, subject, all(c[0] for c in checks),
                                       "; ".join(c[1] for c in checks)))
                checks = []
                for i in range(len(nn["peak_abs_tau_last2s"])):
                    checks.append(_cmp(f"peak |τ{i + 1}| last 2 s", nn["peak_abs_tau_last2s"][i],
                                       hinf["peak_abs_tau_last2s"][i], "N·m"))
                    checks.append(_cmp(f"TV rate τ{i + 1} last 2 s", nn["tv_rate_tau_last2s"][i],
                                       hinf["tv_rate_tau_last2s"][i], "N·m/s"))
                out.append(ClaimResult(3, contact, subject, all(c[0] for c in checks),
                                       "; ".join(c[1] for c in checks)))
                held, ev = _cmp("J(T)", nn["J_T"], hinf["J_T"])
                out.append(ClaimResult(4, contact, subject, held, ev))
        for key, label in (("hinf", "H∞-only"), ("hinf_nn", "adaptive (paper-likely)"),
                           ("hinf_nn_printed", "adaptive (paper-printed)"), ("fl", "FL-like (not claimed)")):
            m = metrics.get(key + suffix)
            if m is None:
                continue
            if not _ok(m):
                out.append(ClaimResult(5, contact, label, None, "the run diverged"))
                continue
            held = bool(m["dissipation_holds_for_all_t"])
            ev = (f"at T: {_fmt(m['dissipation_lhs'])} {'≤' if m['dissipation_holds'] else '>'} "
                  f"{_fmt(m['dissipation_rhs'])}; smallest margin over t {_fmt(m['dissipation_min_margin'])}")
            out.append(ClaimResult(5, contact, label, held, ev))
    return out


def dependence(results: list[ClaimResult]) -> dict[int, str]:
    """For each claim, which modelling choice its verdict depends on (from the rows)."""
    text = {}
    for c in CLAIMS:
        rows = [r for r in results if r.claim == c and not (c == 5 and "not claimed" in r.subject)]
        verdicts = {(r.contact, r.subject): r.held for r in rows}
        if not rows:
            continue
        if any(v is None for v in verdicts.values()):
            text[c] = "undecided for some runs (diverged)"
            continue
        values = set(verdicts.values())
        if len(values) == 1:
            text[c] = ("held in every variant" if values == {True} else "did not hold in any variant")
            continue
        by_contact = {}
        by_subject = {}
        for (contact, subject), v in verdicts.items():
            by_contact.setdefault(contact, set()).add(v)
            by_subject.setdefault(subject, set()).add(v)
        parts = []
        if all(len(v) == 1 for v in by_contact.values()):
            held_in = [k for k, v in by_contact.items() if v == {True}]
            parts.append(f"depends on the contact model: held only with the {', '.join(held_in)} contact")
        elif all(len(v) == 1 for v in by_subject.values()):
            held_in = [k for k, v in by_subject.items() if v == {True}]
            parts.append(f"depends on the F_f centre step / run: held only for {', '.join(held_in)}")
        else:
            held = [f"{k[1]}, {k[0]}" for k, v in verdicts.items() if v]
            parts.append(f"depends on both the contact model and the centre step: held only for "
                         f"{'; '.join(held)}")
        text[c] = parts[0]
    return text
