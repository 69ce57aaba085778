"""Robust gain tuning over a declared uncertainty (``hinfnn design --tune SPEC``), and the check
that a sweep's drawn contact lies inside what the controller was designed for
(docs/sweeps.md, "Tuning the gains over a spec"; not in the paper: docs/beyond-the-paper.md).

**The range check** (:func:`range_notes`, :func:`require_holdable`): the spec declares the
plants it draws (``plant.contact.stiffness`` from a grid or a distribution); the force-rate
term's design (:func:`hinfnn.controllers.force_rate.design_force_rate`) states the stiffness range
it was made for and, under sampled control, the stiffest contact the control period holds.
``hinfnn sweep`` prints a warning naming the key, the declared range, the design's range and
the largest range the design holds at the control period before any run; the tuner refuses a
declared range that no design holds at the period (the same numbers), before anything runs.

**The tuner** (:func:`tune`): a seeded cross-entropy method over a few design parameters, each
a factor on the base scenario's value on a log scale (:data:`KNOBS`): the natural frequency of
the nominal error dynamics (K_p × s², K_v × s, the velocity half of Q_p × 1/s², so that the
Riccati weights keep their structure), the Riccati weight Q_p's scale, α_λ (β_λ then follows
from Theorem 1's bound, ``beta_lam = "min"``), α_z, and the force-rate term's damping ratio ζ*
with its stiffness range set to the spec's declared one (the term is added where the base
scenario has none), or, where the base design chose κ for the declared sensor (ζ* sets nothing
there), a factor on that κ, and, where a noisy sensor makes the networks' update laws project
(Remark 2; docs/beyond-the-paper.md section 11), a factor on the force network's projection radius
(:func:`default_knobs`): the design's radius lets F_f give the largest |λ_d| and no more, while a
heavy arm whose masses are uncertain presses on the surface with a larger error than that. A
candidate is one set of factors; its design is the scenario's own
(Theorem 1's bounds, the Riccati equation, the force-rate design): a candidate the design
refuses scores −1 and is recorded with the refusal. A feasible candidate is scored on a fixed set
of tuning draws (draws 0 … N−1 of the spec's seeded streams): the share of draws that *did their
job* (:func:`hinfnn.metrics.verdicts`: bounded, so within the torque and penetration limits, contact
held after ``verdict.contact_after``, tracking within tolerance over the last 2 s), plus a small
tie-break (a hundredth of the mean log10 of how far the worst criterion is from its tolerance,
and of half how far the other criteria are beyond theirs) so that the search moves where the
share is flat. Every generation's candidates and draws are
one :func:`hinfnn.simulate_batch` call per compiled structure. The best candidate and the base
design are then both run on held-out draws (N … N+M−1, never used in tuning) at the spec's own
horizon: the before/after shares with 95 % Wilson intervals.

The draws vary the truth only (``plant.*``, ``initial.*``): the controller is designed once per
candidate, from the nominal model, and never sees a draw.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable

import numpy as np

from ..errors import ConfigError, DesignError, HinfnnError

#: The stiffness key a spec draws the contact with.
STIFFNESS_KEY = "plant.contact.stiffness"


# --- the declared range and the design's -------------------------------------------------------------


def declared_range(spec, key: str) -> tuple[float, float] | None:
    """(lowest, highest) value a spec gives ``key`` (a grid's extremes, a distribution's support;
    ``relative``: the base value ± percent), or None when the key is not varied. An untruncated
    normal has an unbounded support: ±inf."""
    for v in spec.varied:
        if v.key != key:
            continue
        how = v.how
        if how.is_grid:
            vals = [float(x) for x in how.grid() if not isinstance(x, str)]
            return (min(vals), max(vals)) if vals else None
        base = np.asarray(v.base, dtype=float)
        if how.distribution == "relative":
            return float(np.min(base)) * (1 - how.percent / 100), float(np.max(base)) * (1 + how.percent / 100)
        lo = how.low if how.low is not None else -math.inf
        hi = how.high if how.high is not None else math.inf
        return float(lo), float(hi)
    return None


def _rate_record(ctrl) -> dict | None:
    """The force-rate term's design record of a built controller (None: it has no force-rate term)."""
    from ..controllers import terms as T

    term = ctrl.term(T.ForceRate)
    if term is None or float(term.kappa) == 0.0:
        return None
    return dict(term.design)


def _force_rate_design(scenario, kind: str) -> dict | None:
    """The force-rate term's design record of ``kind`` (None: the law has no force-rate term)."""
    return _rate_record(scenario.single(kind).build_controller(kind))


def range_notes(spec) -> list[str]:
    """One line per controller whose design does not cover the contact stiffness the spec draws:
    the key, the declared range, the design's (``controller.force_rate.stiffness_min/max``) and,
    under sampled control, the largest range the design holds at the control period. A law
    without the force-rate term is noted when the spec draws the stiffness and the contact's
    damping: that damping is then the contact mode's only damping (docs/sweeps.md). Empty when
    the spec does not vary the stiffness or every design covers it."""
    declared = declared_range(spec, STIFFNESS_KEY)
    if declared is None:
        return []
    lo, hi = declared
    notes = []
    for kind in spec.controllers:
        try:
            d = _force_rate_design(spec.base, kind)
        except HinfnnError:
            continue  # the base scenario's check has already passed; nothing to compare
        if d is None:
            damping = declared_range(spec, "plant.contact.damping")
            if kind != "fl" and damping is not None:
                notes.append(f"{STIFFNESS_KEY}: the {kind} law has no force-rate term (controller.force_rate.kappa = 0): "
                             f"the contact mode's damping is the drawn plant.contact.damping alone "
                             f"[{damping[0]:g}, {damping[1]:g}] N s/m; `hinfnn design --tune` can add the term")
            continue
        smin, smax = float(d["stiffness_min"]), float(d["stiffness_max"])
        if lo >= smin * (1 - 1e-9) and hi <= smax * (1 + 1e-9):
            continue
        limit = d.get("stiffness_limit")
        text = (f"{STIFFNESS_KEY}: the spec draws [{lo:g}, {hi:g}] N/m but the {kind} design is for "
                f"[{smin:g}, {smax:g}] N/m (controller.force_rate.stiffness_min/max)")
        if limit:
            period = d.get("period")
            own = stiffest_held(d, spec.base.controller.gains)
            text += (f"; under sampled control at {period:g} s its κ = {float(d['kappa']):.3g} s keeps the contact "
                     f"mode stable with ζ >= {SAMPLED_ZETA_MIN():g} up to {own:.3g} N/m, and no design at this period "
                     f"keeps contacts stiffer than {limit:.3g} N/m stable"
                     + (" (the declared range is wider: the draws above it cannot be held)" if hi > limit else
                        " (set controller.force_rate.stiffness_max to the declared range)"))
            wide = _softest_zeta(spec.base, kind, max(lo, smin) if lo > 0 else smin, min(hi, 0.999 * limit))
            if wide is not None:
                text += (f"; a design up to {min(hi, 0.999 * limit):.3g} N/m has a smaller κ = {wide[0]:.3g} s that damps "
                         f"the softest contact only with ζ = {wide[1]:.2f} (the shipped design: "
                         f"{float(d['zeta_softest']):.2f}; docs/sweeps.md measured soft contacts stopping below "
                         "about 0.25)")
        notes.append(text)
    return notes


def _softest_zeta(scenario, kind: str, lo: float, hi: float):
    """(κ, ζ at the softest contact) of the force-rate design for [lo, hi], or None when the
    design refuses it."""
    over = {"controller.force_rate.stiffness_min": lo, "controller.force_rate.stiffness_max": hi,
            "controller.force_rate.kappa": "rule"}
    try:
        d = _force_rate_design(scenario.single(kind).with_overrides(over), kind)
    except HinfnnError:
        return None
    return None if d is None else (float(d["kappa"]), float(d["zeta_softest"]))


def SAMPLED_ZETA_MIN() -> float:  # noqa: N802 - the design's constant, read where it is defined
    from ..controllers.force_rate import SAMPLED_ZETA_MIN as z

    return z


def stiffest_held(design: dict, gains) -> float:
    """The stiffest contact (N/m) at which a sampled force-rate design's own κ keeps the sampled
    force loop stable with a damping ratio of at least the design's minimum
    (:func:`hinfnn.controllers.force_rate.sampled_damping`, at the lightest pose of the path; the
    design's lower stiffness when even that fails)."""
    from ..controllers.force_rate import jury_window, sampled_damping

    h, mn, kap = float(design["period"]), float(design["m_n_min"]), float(design["kappa"])
    g_P = float(design["K_prime"]) - 1.0
    mu_z, alpha_z = float(gains.mu_z), float(gains.alpha_z)

    def ok(k):
        x = math.sqrt(k / mn) * h
        w = jury_window(x, g_P, h)
        return w is not None and w[0] < kap < w[1] and sampled_damping(x, g_P, kap, h, mu_z, alpha_z)[1] >= \
            SAMPLED_ZETA_MIN()

    lo, hi = float(design["stiffness_min"]), 1e10
    if not ok(lo):
        return lo
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def require_holdable(scenario, kind: str, lo: float, hi: float) -> None:
    """Refuse (DesignError naming ``plant.contact.stiffness``) a declared stiffness range
    [lo, hi] that no force-rate design holds at the scenario's control period, with the largest
    range that can be held; continuous control holds any range."""
    period = scenario.control_period
    if period is None:
        return
    fr = {"controller.force_rate.stiffness_min": lo, "controller.force_rate.stiffness_max": hi,
          "controller.force_rate.kappa": "rule"}
    try:
        scenario.single(kind).with_overrides(fr).build_controller(kind)
    except DesignError as err:
        bound = getattr(err, "bound", None)
        if bound is None:
            raise
        raise DesignError(f"the spec declares contacts up to {hi:g} N/m, which no force-rate design holds at the "
                          f"control period {period:g} s: the largest range a design can hold there is at most "
                          f"[{lo:g}, {bound:.3g}] N/m, its soft end then barely damped (narrow the spec's "
                          f"{STIFFNESS_KEY}, or shorten simulation.control_period). The design said: {err}", key=STIFFNESS_KEY, value=hi,
                          bound=bound) from None


# --- the design parameters ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Knob:
    """A design parameter the tuner moves: ``name``, its range (``lo``, ``hi``) searched on a log
    scale, and what it sets (:func:`candidate_overrides`)."""

    name: str
    lo: float
    hi: float
    doc: str


#: The design parameters, each a factor on the base scenario's value (``zeta``: the damping ratio
#: itself).
KNOBS = (
    Knob("omega", 0.5, 2.0, "natural frequency of the nominal error dynamics: K_p × s², K_v × s, Q_p's velocity "
                            "half × 1/s²"),
    Knob("q", 0.1, 10.0, "Riccati weight Q_p × s"),
    Knob("alpha_lam", 0.25, 8.0, "force weight α_λ × s (β_λ from Theorem 1's bound)"),
    Knob("alpha_z", 0.25, 4.0, "α_z × s of eq. (27)"),
    Knob("zeta", 0.1, 2.0, "the force-rate rule's damping ratio ζ* at the softest declared contact"),
    Knob("kappa", 0.5, 2.0, "the force-rate gain κ × s, on the κ the design chooses for the declared sensor and "
                            "the spec's stiffness range (ζ* does not set it)"),
    Knob("radius_f", 0.5, 16.0, "the force network's projection radius × s, on the base design's (Remark 2's ball, "
                                "where a noisy sensor makes the update laws project)"),
)
KNOB_NAMES = tuple(k.name for k in KNOBS)
#: The knobs every search moves; the force-rate term's is added by :func:`default_knobs`.
GAIN_KNOBS = ("omega", "q", "alpha_lam", "alpha_z")


def _base_facts(scenario, kind: str) -> tuple[dict | None, float | None]:
    """``kind``'s design of ``scenario`` built once: its force-rate design record (None: no
    force-rate term) and its force network's projection radius (None: its update law does not
    project); (None, None) where the design refuses the scenario."""
    from ..controllers import terms as T

    try:
        ctrl = scenario.single(kind).build_controller(kind)
    except HinfnnError:
        return None, None
    net = ctrl.term(T.ForceNetwork)
    radius = float(net.network.radius) if net is not None and bool(net.network.project) else None
    return _rate_record(ctrl), radius


def _base_design(scenario, kind: str) -> dict | None:
    """:func:`_force_rate_design`, None where the design refuses the base scenario."""
    return _base_facts(scenario, kind)[0]


def force_radius(scenario, kind: str) -> float | None:
    """The projection radius of the force network F_f in ``kind``'s design of ``scenario``
    (Remark 2's ball: ``controller.adaptation.radius_f``, by default the least-norm weights giving the
    largest |λ_d| at zero error, docs/beyond-the-paper.md section 11), or None where its update law
    does not project (an ideal sensor, ``controller.adaptation.robust`` other than projection, a law
    without F_f) or the design refuses the scenario."""
    return _base_facts(scenario, kind)[1]


def _sensed(design: dict | None) -> dict | None:
    return design if design is not None and design.get("sensing") is not None else None


def _default_knobs(kind: str, design: dict | None, radius: float | None = None) -> tuple:
    if kind == "fl":
        return GAIN_KNOBS
    return (GAIN_KNOBS + (("kappa",) if _sensed(design) is not None else ("zeta",))
            + (("radius_f",) if radius is not None else ()))


def sensed_design(scenario, kind: str) -> dict | None:
    """The base force-rate design when its κ was chosen for the declared sensor (sampled control with
    a delay, noise or a force filter: :func:`hinfnn.controllers.sensing.design_sensing`), else None.
    Such a κ does not depend on the rule's ζ*: the ``zeta`` knob would move nothing there."""
    return _sensed(_base_design(scenario, kind))


def default_knobs(scenario, kind: str) -> tuple:
    """The knobs a search moves by default: :data:`GAIN_KNOBS` and the force-rate term's, ``kappa``
    (a factor on κ) where the base design chose κ for the declared sensor, ``zeta`` (the rule's
    damping ratio, adding the term where there is none) otherwise, and ``radius_f`` where the force
    network's update law projects (:func:`force_radius`); none of these for the FL-like law."""
    if kind == "fl":
        return GAIN_KNOBS
    return _default_knobs(kind, *_base_facts(scenario, kind))


def _scaled(x, s):
    a = np.asarray(x, dtype=float) * s
    return float(a) if a.ndim == 0 else a.tolist()


def candidate_overrides(scenario, values: dict, stiffness: tuple[float, float] | None,
                        kappa: float | None = None, radius_f: float | None = None) -> list[tuple[str, object]]:
    """The scenario keys a candidate sets: ``values`` maps knob names to their value (missing:
    the base design's). The force-rate term is set only when ``zeta`` or ``kappa`` is given, with
    its stiffness range the declared one; ``kappa``: the base design's κ (s), which the knob
    scales; ``radius_f``: the base design's projection radius of F_f (:func:`force_radius`), which
    the knob of that name scales."""
    g = scenario.controller.gains
    out = []
    s = values.get("omega")
    q = values.get("q", 1.0)
    if s is not None or "q" in values:
        s = 1.0 if s is None else s
        if s != 1.0:
            out += [("controller.gains.K_p", _scaled(g.K_p, s * s)), ("controller.gains.K_v", _scaled(g.K_v, s))]
        Q = np.asarray(g.Q_p, dtype=float)
        if Q.ndim == 0:
            Qn = Q * q
        else:
            n = Q.shape[0]
            d = np.ones(n)
            d[n // 2:] = 1.0 / s
            Qn = (Q * d * d * q) if Q.ndim == 1 else (np.diag(d) @ Q @ np.diag(d) * q)
        out.append(("controller.gains.Q_p", float(Qn) if Qn.ndim == 0 else Qn.tolist()))
    if "alpha_lam" in values:
        out.append(("controller.gains.alpha_lam", float(g.alpha_lam) * values["alpha_lam"]))
        if isinstance(g.beta_lam, str):
            out.append(("controller.gains.beta_lam", "min"))
    if "alpha_z" in values:
        out.append(("controller.gains.alpha_z", float(g.alpha_z) * values["alpha_z"]))
    if "kappa" in values:
        if kappa is None:
            raise ConfigError("the kappa knob scales the base design's force-rate gain: the base scenario has no "
                              "force-rate term (controller.force_rate.kappa = 0; the zeta knob adds one)",
                              key="--knobs")
        out.append(("controller.force_rate.kappa", float(kappa) * float(values["kappa"])))
    if "radius_f" in values:
        if radius_f is None:
            raise ConfigError("the radius_f knob scales the force network's projection radius, and the base "
                              "design does not project (controller.adaptation.robust resolves to another law: an "
                              "ideal sensor, or a law without F_f)", key="--knobs")
        out.append(("controller.adaptation.radius_f", float(radius_f) * float(values["radius_f"])))
    if "zeta" in values:
        out += [("controller.force_rate.kappa", "rule"), ("controller.force_rate.zeta", float(values["zeta"]))]
    if "zeta" in values or "kappa" in values:
        if stiffness is not None:
            out += [("controller.force_rate.stiffness_min", float(stiffness[0])),
                    ("controller.force_rate.stiffness_max", float(stiffness[1]))]
    return out


# --- one evaluation: candidates × draws as batched runs ------------------------------------------------


@dataclasses.dataclass
class Outcome:
    """What one member (a candidate's controller on one draw) did."""

    bounded: bool
    held: bool | None
    tracked: bool
    done: bool
    badness: float  # the worst criterion over its tolerance (>= 10 for a run that stopped)
    worst: str = ""  # which criterion that is: a motion coordinate's name, "force", "contact" or "stopped"
    others: float = 0.0  # sum of log10(ratio) over the OTHER criteria beyond their tolerance (0: none)


@dataclasses.dataclass
class Draws:
    """The draws a candidate is judged on: their values, the plants and start poses (built once),
    the compiled-structure key of each; ``invalid``: draws that cannot start (not judged)."""

    indices: list
    values: list
    plants: list
    q0s: list
    keys: list
    invalid: list


def build_draws(spec, kind: str, indices, base) -> Draws:
    """The plants and start poses of draws ``indices`` of the spec's seeded streams (the truth
    only: a spec that varies a controller or nominal key is refused)."""
    from .sampling import draw_values
    from .worker import scenario_of

    bad = [v.key for v in spec.varied if not v.key.startswith(("plant.", "initial."))]
    if bad:
        raise ConfigError(f"varies {bad[0]}: tuning draws the truth only (plant.*, initial.*); the controller is "
                          "designed from the nominal model", key=f"vary.{bad[0]}")
    if spec.grid_keys:
        raise ConfigError(f"has a grid ({spec.grid_keys[0]}): tuning takes random draws only", key=f"vary.{spec.grid_keys[0]}")
    drawn = draw_values(spec, list(indices))
    base_dict = base.to_dict()
    out = Draws([], [], [], [], [], [])
    ctrl = base.single(kind).build_controller(kind)
    for j, i in enumerate(indices):
        values = {k: vals[j] for k, vals in drawn.items()}
        try:
            sc = scenario_of(base_dict, base.source, values, kind)
            r = sc.run(kind, controller=ctrl)
            q0 = r.q0
        except (HinfnnError, ValueError, ArithmeticError, np.linalg.LinAlgError) as err:
            out.invalid.append((i, str(err)))
            continue
        out.indices.append(i)
        out.values.append(values)
        out.plants.append(r.plant)
        out.q0s.append(q0)
        out.keys.append(_structure(r.plant))
    return out


def _structure(x) -> str:
    import jax

    leaves, treedef = jax.tree.flatten(x)
    return repr((treedef, [getattr(v, "shape", ()) for v in leaves]))


def evaluate(scenario, kind: str, controllers: list, draws: Draws, *, t_final: float | None = None,
             log: Callable[[str], None] | None = None) -> list[list[Outcome]]:
    """Run every controller on every draw (one :func:`hinfnn.simulate_batch` call per compiled
    structure) and judge each member with the scenario's verdict: ``out[c][d]``."""
    from ..metrics import compute_metrics, lam_is_normal_force
    from ..sim import simulate_batch

    r0 = scenario.run(kind, controller=controllers[0])
    tol = scenario.verdict.tolerances()
    names = scenario.coordinate_names()
    normal = lam_is_normal_force(scenario)
    tf = float(t_final if t_final is not None else r0.t_final)
    out = [[None] * len(draws.plants) for _ in controllers]
    groups: dict = {}
    for c, ctrl in enumerate(controllers):
        for d in range(len(draws.plants)):
            groups.setdefault((_structure(ctrl), draws.keys[d]), []).append((c, d))
    for members in groups.values():
        t0 = time.perf_counter()
        traj = simulate_batch([draws.plants[d] for _, d in members], [controllers[c] for c, _ in members],
                              r0.reference, q0=[draws.q0s[d] for _, d in members], t_final=tf, dt=r0.dt,
                              save_interval=r0.save_interval, fields="metrics", control_period=r0.control_period,
                              limits=r0.limits, bookkeeping=False)
        m_ = int(controllers[0].m)
        coords = list(names[:m_]) if names else [(f"u1[{i + 1}]" if m_ > 1 else "u1", "m") for i in range(m_)]
        for j, (c, d) in enumerate(members):
            member = traj.member(j)
            m = compute_metrics(member, tolerances=tol, lam_is_normal_force=normal, coordinates=coords)
            out[c][d] = _outcome(m, int(np.asarray(member.status)), tol, coords)
        if log:
            log(f"{len(members)} runs of {tf:g} s in {time.perf_counter() - t0:.1f} s")
    return out


def _outcome(m: dict, status: int, tol: dict, coords) -> Outcome:
    v = m["verdict"]
    bounded = status == 0
    held = v["contact_held"]
    tracked = bool(v["tracking_within_tolerance"])
    done = bool(bounded and held is not False and tracked)
    if not bounded:
        return Outcome(False, held, False, False, 10.0, "stopped")
    ratios = []
    for (name, unit), e in zip(coords or [], m["rms_e_u1_each_last2s"]):
        ratios.append((e / (tol["angle_tolerance"] if unit == "rad" else tol["position_tolerance"]), name))
    if v.get("force_error_ratio_last2s") is not None:
        ratios.append((v["force_error_ratio_last2s"] / tol["force_tolerance"], "force"))
    out_after = v.get("out_of_contact_after")
    if out_after is not None and math.isfinite(out_after):
        ratios.append((out_after / max(tol["out_of_contact"], 1e-3), "contact"))
    finite = [r for r in ratios if math.isfinite(r[0])]
    bad, worst = max(finite or [(10.0, "stopped")], key=lambda r: r[0])
    others = sum(math.log10(r) for r, name in finite if name != worst and r > 1.0)
    return Outcome(True, held, tracked, done, float(bad), worst, float(others))


def score(outcomes: list[Outcome]) -> float:
    """The share of draws that did their job, plus a hundredth of a tie-break: minus the mean of
    log10 of the worst criterion over its tolerance (clipped to [0.1, 10]), minus half the mean of
    how far the other criteria are beyond theirs (:attr:`Outcome.others`, clipped to 1). The second
    part is 0 where only the worst criterion misses its tolerance; where several do, it keeps the
    search from giving up one criterion (the tool's tracking) for the worst (the force), which a
    draw needs too."""
    if not outcomes:
        return -1.0
    share = sum(o.done for o in outcomes) / len(outcomes)
    tie = -float(np.mean([math.log10(min(max(o.badness, 0.1), 10.0)) for o in outcomes]))
    tie -= 0.5 * float(np.mean([min(o.others, 1.0) for o in outcomes]))
    return share + 0.01 * tie


# --- the search --------------------------------------------------------------------------------------


@dataclasses.dataclass
class Candidate:
    values: dict
    overrides: list
    score: float = -1.0
    done: int = 0
    judged: int = 0
    error: str | None = None
    generation: int = 0


@dataclasses.dataclass
class TuneResult:
    """What :func:`tune` found: the base and best candidates, every candidate tried, the held-out
    outcomes (before: the base design; after: the best) and the cost."""

    base: Candidate
    best: Candidate
    history: list
    knobs: tuple
    tuning_draws: list
    held_out_draws: list
    held_out_before: list
    held_out_after: list
    invalid: list
    wall_s: float
    runs: int
    tuned: object  # the tuned Scenario
    stiffness: tuple | None
    held_out_values: list = dataclasses.field(default_factory=list)  # each held-out draw's drawn values


def _to_values(u: np.ndarray, knobs) -> dict:
    return {k.name: float(math.exp(math.log(k.lo) + float(np.clip(x, 0, 1)) * (math.log(k.hi) - math.log(k.lo))))
            for k, x in zip(knobs, u)}


def _to_unit(values: dict, knobs) -> np.ndarray:
    return np.array([(math.log(values[k.name]) - math.log(k.lo)) / (math.log(k.hi) - math.log(k.lo)) for k in knobs])


def cross_entropy(objective: Callable, start, *, generations: int, population: int, seed: int, std: float = 0.25,
                  elite: float = 0.25, smoothing: float = 0.7, min_std: float = 0.04, explore: bool = True):
    """Maximise ``objective(points, generation) -> scores`` over the unit box by a seeded
    cross-entropy method: each generation evaluates the current mean and ``population − 1``
    other points as one call, then moves the mean and the spread towards the best ``elite`` share
    (at least two; candidates scored −1, refused, are never elite) with ``smoothing``. The other
    points are Gaussian samples around the mean (clipped to [0, 1]); with ``explore`` the first
    generation's are a seeded Latin hypercube over the whole box instead, so that a good region
    far from ``start`` (a knob at the end of its range, two spreads away) can be found at all.
    Returns (best point, best score); the same seed gives the same points."""
    from scipy.stats import qmc

    rng = np.random.default_rng(seed)
    mean = np.clip(np.asarray(start, dtype=float), 0.0, 1.0)
    sd = np.full(mean.shape, float(std))
    best_u, best_s = mean, -math.inf
    for g in range(1, generations + 1):
        if g == 1 and explore and population > 1:
            box = qmc.LatinHypercube(d=mean.size, seed=rng).random(population - 1)
            us = [mean] + [np.asarray(u, dtype=float) for u in box]
        else:
            us = [mean] + [np.clip(mean + sd * rng.standard_normal(mean.shape), 0.0, 1.0)
                           for _ in range(population - 1)]
        scores = list(objective(us, g))
        ranked = sorted(range(len(us)), key=lambda i: -scores[i])
        for i in ranked[:1]:
            if scores[i] > best_s:
                best_u, best_s = us[i], scores[i]
        top = [us[i] for i in ranked[:max(2, int(round(population * elite)))] if scores[i] > -1.0]
        if top:
            mean = (1 - smoothing) * mean + smoothing * np.mean(top, axis=0)
            sd = np.maximum((1 - smoothing) * sd + smoothing * np.std(top, axis=0), min_std)
    return best_u, best_s


def tune(spec, *, kind: str | None = None, knobs=None, draws: int = 16, held_out: int = 64,
         generations: int = 4, population: int = 8, seed: int = 0, t_final: float | None = None,
         log: Callable[[str], None] | None = None) -> TuneResult:
    """Tune the base scenario's design over the spec's draws (see the module docstring): a
    cross-entropy search, seeded by ``seed``, of ``population`` candidates per generation over
    ``generations`` generations on ``draws`` tuning draws (runs of ``t_final`` s, default the
    scenario's), then the base and the best design on ``held_out`` other draws at the scenario's
    horizon. ``knobs``: which of :data:`KNOBS` to move (None: :func:`default_knobs`). Raises
    DesignError before any run when the declared stiffness range cannot be held at the control
    period; ConfigError for ``zeta`` where the base design chose κ for the declared sensor (ζ* sets
    nothing there: ``kappa`` scales that κ), and for ``kappa`` where the base has no force-rate term."""
    log = log or (lambda s: None)
    t_start = time.perf_counter()
    base = spec.base
    kinds = list(spec.controllers)
    kind = kind or kinds[0]
    if kind not in kinds:
        raise ConfigError(f"{kind!r} is not a controller of the spec (it lists {kinds})", key="--kind")
    explicit = knobs is not None
    # the base design, built once: the default knobs and the zeta/kappa/radius_f checks read it
    design, radius = (None, None) if kind == "fl" else _base_facts(base, kind)
    knobs = tuple(knobs) if explicit else _default_knobs(kind, design, radius)
    unknown = [k for k in knobs if k not in KNOB_NAMES]
    if unknown:
        raise ConfigError(f"unknown knob {unknown[0]!r} (the knobs: {', '.join(KNOB_NAMES)})", key="--knobs")
    for name, value, lo in (("--tune-draws", draws, 1), ("--held-out", held_out, 0), ("--generations", generations, 0),
                            ("--population", population, 2)):
        if int(value) != value or value < lo:
            raise ConfigError(f"must be a whole number >= {lo}, got {value}", key=name)
    if kind == "fl":
        knobs = tuple(k for k in knobs if k not in ("zeta", "kappa", "radius_f"))
    sensed = _sensed(design)
    if "zeta" in knobs and sensed is not None:
        raise ConfigError(f"the {kind} design chose its force-rate gain for the declared sensor (κ = "
                          f"{float(sensed['kappa']):.3g} s with its delay and noise): the rule's damping ratio ζ* "
                          "sets nothing there; the kappa knob scales that κ", key="--knobs")
    base_kappa = None
    if "kappa" in knobs:
        if design is None:
            raise ConfigError(f"the kappa knob scales the base design's force-rate gain, and the {kind} law of "
                              f"{base.name} has none (controller.force_rate.kappa = 0; the zeta knob adds the term)",
                              key="--knobs")
        base_kappa = float(design["kappa"])
    if "radius_f" in knobs and radius is None:
        raise ConfigError(f"the radius_f knob scales the force network's projection radius, and the {kind} law of "
                          f"{base.name} does not project it (controller.adaptation.robust = "
                          f"{base.controller.adaptation.robust!r} with this sensor; \"projection\", or \"auto\" with a "
                          "noisy sensor, projects)", key="--knobs")
    use = tuple(k for k in KNOBS if k.name in knobs)
    stiffness = declared_range(spec, STIFFNESS_KEY)
    if stiffness is not None and not all(math.isfinite(x) for x in stiffness):
        stiffness = None
    if stiffness is not None:
        require_holdable(base, kind, *stiffness)  # before anything runs: a range no design holds is refused
    if base_kappa is not None and stiffness is not None and (
            float(design["stiffness_min"]), float(design["stiffness_max"])) != tuple(stiffness):
        # the candidates' force-rate term is for the declared range: the kappa knob scales the κ the design
        # chooses for that range (the base design's, made for another, may hold none of it)
        ranged = _base_design(base.with_overrides([("controller.force_rate.stiffness_min", float(stiffness[0])),
                                                   ("controller.force_rate.stiffness_max", float(stiffness[1]))]),
                              kind)
        if ranged is not None:
            base_kappa = float(ranged["kappa"])
            log(f"kappa knob: factors on κ = {base_kappa:.4g} s, the design for the declared stiffness "
                f"[{stiffness[0]:g}, {stiffness[1]:g}] N/m (the base design's: {float(design['kappa']):.4g} s)")

    base_values = {}
    if "zeta" in knobs:
        fr = base.controller.force_rate
        has = not (isinstance(fr.kappa, (int, float)) and float(fr.kappa) == 0.0)
        base_values["zeta"] = float(fr.zeta) if has else None
    base_cand = Candidate(values={}, overrides=[])
    log(f"tuning draws 0..{draws - 1}, held-out draws {draws}..{draws + held_out - 1} of {spec.name} (seed {spec.seed})")
    tdraws = build_draws(spec, kind, range(draws), base)
    n_runs = 0

    def run_generation(cands: list[Candidate], d: Draws, tf) -> None:
        nonlocal n_runs
        ctrls, ok = [], []
        for c in cands:
            try:
                sc = base.single(kind).with_overrides(c.overrides) if c.overrides else base.single(kind)
                ctrls.append(sc.build_controller(kind))
                ok.append(c)
            except (HinfnnError, ValueError, ArithmeticError, np.linalg.LinAlgError) as err:
                c.error, c.score = str(err), -1.0
        if not ok or not d.plants:
            return
        res = evaluate(base.single(kind), kind, ctrls, d, t_final=tf, log=log)
        n_runs += len(ok) * len(d.plants)
        for c, outs in zip(ok, res):
            c.score, c.done, c.judged = score(outs), sum(o.done for o in outs), len(outs)

    history: list[Candidate] = []
    run_generation([base_cand], tdraws, t_final)
    history.append(base_cand)
    log(f"base design: {base_cand.done}/{base_cand.judged} tuning draws did their job (score {base_cand.score:.4f})")
    log("knobs: " + ", ".join(k.name for k in use) + ("" if explicit else " (the default for this design)"))
    start = {k.name: 1.0 for k in use}
    if "zeta" in start:
        start["zeta"] = base_values.get("zeta") or 0.7
    best = base_cand

    def objective(us, g):
        nonlocal best
        cands = []
        for u in us:
            vals = _to_values(u, use)
            cands.append(Candidate(values=vals, overrides=candidate_overrides(base, vals, stiffness, base_kappa, radius),
                                   generation=g))
        run_generation(cands, tdraws, t_final)
        history.extend(cands)
        top = max(cands, key=lambda c: c.score)
        if top.score > best.score:
            best = top
        log(f"generation {g}: best {top.done}/{top.judged} ({top.score:.4f}) at "
            + ", ".join(f"{k}={v:.3g}" for k, v in top.values.items())
            + f"; {sum(c.error is not None for c in cands)} refused by the design")
        return [c.score for c in cands]

    if use and generations:
        cross_entropy(objective, np.clip(_to_unit(start, use), 0.0, 1.0), generations=generations,
                      population=population, seed=seed)
    # held out: the base and the best at the scenario's horizon
    hdraws = build_draws(spec, kind, range(draws, draws + held_out), base) if held_out else Draws([], [], [], [], [], [])
    before = after = []
    if hdraws.plants:
        ctrl_b = base.single(kind).build_controller(kind)
        pair = [ctrl_b] if best is base_cand else [ctrl_b, base.single(kind).with_overrides(best.overrides)
                                                   .build_controller(kind)]
        res = evaluate(base.single(kind), kind, pair, hdraws, log=log)
        n_runs += len(pair) * len(hdraws.plants)
        before, after = res[0], res[-1]
    tuned = base.with_overrides(best.overrides) if best.overrides else base
    return TuneResult(base=base_cand, best=best, history=history, knobs=use, tuning_draws=tdraws.indices,
                      held_out_draws=hdraws.indices, held_out_before=before, held_out_after=after,
                      invalid=tdraws.invalid + hdraws.invalid, wall_s=time.perf_counter() - t_start, runs=n_runs,
                      tuned=tuned, stiffness=stiffness, held_out_values=hdraws.values)


__all__ = ["declared_range", "range_notes", "require_holdable", "Knob", "KNOBS", "KNOB_NAMES", "GAIN_KNOBS",
           "default_knobs", "sensed_design", "force_radius", "candidate_overrides",
           "stiffest_held", "build_draws", "evaluate", "score", "cross_entropy", "tune", "TuneResult", "Candidate", "Outcome", "Draws", "STIFFNESS_KEY"]
