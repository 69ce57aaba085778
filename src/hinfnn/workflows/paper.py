"""The paper's Sec. VI study end to end (``hinfnn reproduce``): the cases, their figures, the claims
and the report, and the "Beyond the paper" comparison beside it.

:func:`study_cases` lists the study: FL-like, H∞-only and adaptive H∞ NN with both F_f centre
presets on the paper scenario, each with the paper's undamped contact and with a damped contact
(200 N·s/m) as a sensitivity study, plus a diagnostic H∞-only run with an exact nominal model (to
separate model mismatch from disturbance in the position error). :func:`beyond_cases` lists the
comparison: the paper's laws against the stabilised ones (scenario ``paper-stable``) at three
contact stiffnesses, continuous and at 1 kHz (and on MuJoCo when it is installed).
:func:`reproduce` runs both and writes the result folder.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from ..experiment import Case, result_folder, run_cases, simulate_cases
from ..scenario import Scenario

DAMPED = 200.0  # N·s/m, the sensitivity study's contact damping

#: (run name, controller kind, overrides); "" / "_damped" suffixes are added per contact model.
STUDY = [
    ("fl", "fl", {}),
    ("hinf", "hinf", {}),
    ("hinf_nn", "hinf_nn", {"controller.network_f.preset": "paper-likely"}),
    ("hinf_nn_printed", "hinf_nn", {"controller.network_f.preset": "paper-printed"}),
]
#: The study's contact models: (name suffix, contact tag, damping in N·s/m).
CONTACTS = (("", "undamped", 0.0), ("_damped", "damped", DAMPED))


def exact_model_overrides(sc: Scenario) -> dict:
    """Overrides that give the controller the TRUE arm and surface as its nominal model."""
    arm = sc.plant.arm
    out = {f"nominal.arm.{k}": getattr(arm, k) for k in ("m1", "m2", "l1", "l2", "g")}
    out["nominal.surface.delta_deg"] = sc.plant.surface.delta_deg
    out["nominal.surface.d_G"] = sc.plant.surface.d_G
    return out


def study_cases(base: Scenario) -> list[Case]:
    """The study's cases on top of ``base``, tagged with their contact model and the paper's figures
    they appear in (``figures``: "figs3-4" for the FL-like law, "figs5-9" for the others, None for
    the diagnostic exact-model run)."""
    from ..controllers import KINDS

    out = []
    for suffix, contact, damping in CONTACTS:
        for name, kind, over in STUDY:
            o = {**over, "plant.contact.damping": damping, "controller.kind": kind}
            sc = base.with_overrides(o)
            label = KINDS[kind].label + (f" ({sc.controller.network_f.preset})" if KINDS[kind].learns else "")
            out.append(Case(name + suffix, sc, overrides=o, label=_contact_label(label, contact, damping),
                            tags={"contact": contact, "figures": "figs3-4" if kind == "fl" else "figs5-9"}))
        o = {**exact_model_overrides(base), "plant.contact.damping": damping, "controller.kind": "hinf"}
        out.append(Case("hinf_exact" + suffix, base.with_overrides(o), overrides=o,
                        label=_contact_label(KINDS["hinf"].label + " with exact nominal model", contact, damping),
                        tags={"contact": contact, "figures": None, "exact_model": True}))
    return out


def _contact_label(label: str, contact: str, damping: float) -> str:
    return label + (f", damped contact {damping:g} N·s/m" if contact == "damped" else "")


#: Overrides the study cannot honour: it sets these itself in every run (key -> why).
STUDY_KEYS = {
    "controller.kind": "the study runs FL-like, H∞-only and adaptive H∞ NN itself",
    "plant.contact.damping": f"the study runs the paper's undamped contact and a damped one ({DAMPED:g} N·s/m)",
    "controller.network_f.preset": "the study runs both F_f centre presets (paper-likely, paper-printed)",
    "controller.network_f.centre_start": "the study sets F_f's centres through its two presets",
    "controller.network_f.centre_step": "the study sets F_f's centres through its two presets",
    "controller.network_f.centre_count": "the study sets F_f's centres through its two presets",
}

#: Overrides the "Beyond the paper" comparison cannot honour: it sets these in its runs.
BEYOND_KEYS = {
    "plant.contact.stiffness": "the Beyond-the-paper comparison runs the contact at 1e4, 1e5 and 1e6 N/m",
    "plant.engine": "the Beyond-the-paper comparison runs the built-in plant (and MuJoCo beside it)",
    "simulation.control": "the Beyond-the-paper comparison runs continuous and 1 kHz sampled control",
    "simulation.control_period": "the Beyond-the-paper comparison runs continuous and 1 kHz sampled control",
}


def check_overrides(base: Scenario, beyond: bool = False) -> None:
    """Reject (ConfigError naming the key) an override of ``base`` the study would silently
    replace in its runs (:data:`STUDY_KEYS`; with ``beyond``, also :data:`BEYOND_KEYS`)."""
    from ..errors import ConfigError

    for key, _ in base.overrides:
        if key in STUDY_KEYS:
            raise ConfigError(f"cannot be overridden for `hinfnn reproduce`: {STUDY_KEYS[key]}; use `hinfnn run` "
                              "to run other controllers or contacts", key=key)
        if beyond and key in BEYOND_KEYS:
            raise ConfigError(f"cannot be overridden for `hinfnn reproduce`: {BEYOND_KEYS[key]}; add --paper-only "
                              "to run only the paper's study with it, or use `hinfnn run` / `hinfnn compare`",
                              key=key)


def memory_plan(runs, log=print):
    """``save_every`` for the study's runs in memory, checked against the available memory.

    Every step is kept when it fits in half the available memory: the figures' zoom panels show
    the contact's 300 Hz chatter, which 1-ms samples would alias (trajectory.npz is decimated to
    output_interval either way). Otherwise the runs keep the output_interval samples (said in
    one line), and a study that does not fit even so is refused (ResourceError)."""
    from .. import resources

    every = resources.plan(runs, save_every=1, copies=1.5)
    avail = resources.available_memory()
    if avail is None or every.peak <= resources.BASE_BYTES + 0.5 * (avail - resources.BASE_BYTES):
        return 1, every
    sampled = resources.plan(runs, copies=2.0)
    resources.check(sampled, available=avail, fields_option=False)
    log(f"hinfnn: warning: keeping every step of the study in memory would need {resources.size(every.peak)} "
        f"({resources.size(avail)} available): its figures are drawn from the stored samples, every "
        f"{sampled.interval:g} s (zoom panels may alias the contact's chatter)")
    return None, sampled


def reproduce(out: Path | None = None, *, base: Scenario | None = None, force: bool = False, progress=None,
              log=print, command: str = "hinfnn reproduce", beyond: bool = True) -> Path:
    """Run the study (and, with ``beyond``, the "Beyond the paper" comparison) and write ``out``
    (default ``results/paper``) atomically. Returns the folder actually written. Overrides of
    ``base`` the study cannot honour are rejected (:func:`check_overrides`) before anything
    runs; the output folder is reserved as for every command (:func:`hinfnn.io.reserve_output`);
    a study that would not fit in memory is refused (:func:`memory_plan`)."""
    base = base or Scenario.load("paper")
    check_overrides(base, beyond=beyond)
    cases = study_cases(base)
    with result_folder(out, command="reproduce", name=base.name, kind="study", force=force, log=log,
                       command_line=command) as written:
        runs = [c.run() for c in cases]
        save_every, plan = memory_plan(runs, log=log)
        if plan.seconds > 60:
            log(f"hinfnn: {plan.summary()}")
        _write_study(written.path, base, cases, runs, save_every, progress, command, beyond)
    return written.path


def _write_study(root: Path, base: Scenario, cases, runs, save_every, progress, command: str, beyond: bool) -> None:
    from ..io import atomic_write_bytes, atomic_write_text, dumps_json, trajectory_npz_bytes
    from ..report import paper_figures
    from .paper_report import study_report

    outcome, doc = run_cases(cases, root, base, command=command, runs=runs, progress=progress, save_every=save_every,
                             memory=False, npz="trajectory.npz", scenario_file=False)  # memory: memory_plan's
    t0 = time.perf_counter()
    figures = []
    for suffix, contact, _ in CONTACTS:
        figures += paper_figures(outcome.select(contact=contact), root, suffix=suffix)
    fig_seconds = time.perf_counter() - t0
    timings = {"simulation (compile + run, all runs)": outcome.seconds, "figures": fig_seconds}
    del outcome  # the study's every-step trajectories: written; free them before the comparison runs
    if beyond:
        from ..report.figures import beyond_figures

        b_out, b_modes = run_beyond(base, progress=progress)
        doc["beyond"] = beyond_document(base, b_out, b_modes)
        t0 = time.perf_counter()
        figures += beyond_figures(b_out.trajectories, {c.name: {**b_out.metrics[c.name], "status": r["status"]}
                                                      for c, r in zip(b_out.cases, doc["beyond"]["runs"])},
                                  doc["beyond"]["cases"], root)
        timings["beyond the paper: simulation and linearisation"] = b_out.seconds
        timings["beyond the paper: figures"] = time.perf_counter() - t0
        atomic_write_bytes(root / "beyond.npz", trajectory_npz_bytes(b_out.trajectories,
                                                                     10 * base.simulation.output_interval,
                                                                     fields=BEYOND_FIELDS))
        atomic_write_text(root / "metrics.json", dumps_json(doc))
    atomic_write_text(root / "scenario.toml", base.to_toml())
    text = study_report(base, doc, [Path(f).name for f in figures], timings=timings,
                        is_paper=base.source == "paper" and not base.overrides)
    atomic_write_text(root / "report.md", text)


# --- beyond the paper -------------------------------------------------------------------------------

#: Contact stiffnesses of the "Beyond the paper" comparison, N/m (undamped, as the paper's).
BEYOND_STIFFNESS = (1e4, 1e5, 1e6)
#: Laws compared there, each as the paper has it and stabilised (scenario ``paper-stable``).
BEYOND_KINDS = ("hinf", "hinf_nn")
#: Control modes: continuous (the paper's) and zero-order hold at 1 kHz, as a robot runs.
BEYOND_MODES = {"cont": {}, "1kHz": {"simulation.control": "sampled", "simulation.control_period": 1e-3}}
#: The contact stiffness of the MuJoCo side-by-side (N/m, undamped), when MuJoCo is installed.
MUJOCO_STIFFNESS = 1e5
#: The stabilised design under 1 kHz control: no force-rate gain stabilises 1e6 N/m at 1 kHz with
#: Theorem 1's β_λ (the design step says so), so it is designed for contacts up to 1e5 N/m.
SAMPLED_STIFFNESS_MAX = 1e5
#: How each control mode reads in labels.
MODE_WORDS = {"cont": "continuous", "1kHz": "ZOH 1 kHz", "10kHz": "ZOH 10 kHz", "mujoco": "MuJoCo plant, 10 kHz"}


def mujoco_available() -> bool:
    """Whether the optional MuJoCo extra is installed (the side-by-side needs it)."""
    try:
        from ..plant.mujoco import require_mujoco

        require_mujoco()
    except Exception:  # noqa: BLE001 - the comparison is optional: the report says it was skipped
        return False
    return True


def _beyond_case(kind: str, variant: str, mode: str, k: float, sc: Scenario, overrides: dict) -> Case:
    from ..controllers import KINDS

    name = f"{kind}_{variant}_{mode}_k{k:.0e}".replace("+0", "")
    label = (f"{KINDS[kind].label}, {'paper law' if variant == 'paper' else 'stabilised'}, {MODE_WORDS[mode]}, "
             f"k = {k:.0e} N/m".replace("+0", ""))
    return Case(name, sc.with_overrides(overrides), overrides=overrides, label=label,
                tags={"variant": variant, "mode": mode, "stiffness": float(k)})


def beyond_cases(base: Scenario, mujoco: bool = False) -> list[Case]:
    """The comparison's cases: every law × {paper, stable} × {continuous, 1 kHz} × stiffness,
    undamped contact, on top of ``base`` (the user's overrides of the paper scenario apply to both
    variants), tagged with ``variant``, ``mode`` and ``stiffness``; with ``mujoco``, the same laws
    on MuJoCo at :data:`MUJOCO_STIFFNESS` beside the built-in plant under the same 10 kHz hold."""
    user = [(k, v) for k, v in base.overrides if k != "controller.kind"]
    stable = Scenario.load("paper-stable", user)
    out = []
    for kind in BEYOND_KINDS:
        for variant, sc in (("paper", base), ("stable", stable)):
            for mode, mode_over in BEYOND_MODES.items():
                for k in BEYOND_STIFFNESS:
                    o = {**mode_over, "plant.contact.stiffness": k, "plant.contact.damping": 0.0,
                         "controller.kind": kind}
                    if variant == "stable" and mode != "cont":
                        o["controller.force_rate.stiffness_max"] = SAMPLED_STIFFNESS_MAX
                    out.append(_beyond_case(kind, variant, mode, k, sc, o))
            if mujoco:
                common = {"plant.contact.stiffness": MUJOCO_STIFFNESS, "plant.contact.damping": 0.0,
                          "controller.kind": kind}
                # MuJoCo runs the controller every step (sampled data at 1/dt); its built-in twin does too
                twin = {**common, "simulation.control": "sampled", "simulation.control_period": sc.simulation.dt}
                out.append(_beyond_case(kind, variant, "10kHz", MUJOCO_STIFFNESS, sc, twin))
                out.append(_beyond_case(kind, variant, "mujoco", MUJOCO_STIFFNESS, sc,
                                        {**common, "plant.engine": "mujoco"}))
    return out


def _peak_after(traj, m, after: float = 0.1):
    """peak |τ1| over the steps after ``after`` seconds (the start's transient excluded)."""
    t, tau = traj.t, traj.tau_abs_max
    m["peak_abs_tau1_after_0.1s"] = float(np.max(tau[t > after, 0])) if np.any(t > after) else math.nan


def run_beyond(base: Scenario, progress=None):
    """Simulate the comparison (with MuJoCo when it is installed) and linearise its laws. Returns
    (the outcome, the contact modes by (kind, variant, stiffness))."""
    from ..analysis import contact_modes
    from ..fields import METRICS_FIELDS

    t0 = time.perf_counter()
    outcome = simulate_cases(beyond_cases(base, mujoco=mujoco_available()), progress=progress, save_every=1,
                             fields=BEYOND_FIELDS + METRICS_FIELDS, extra=_peak_after)
    stable = Scenario.load("paper-stable", [(k, v) for k, v in base.overrides if k != "controller.kind"])
    modes = {}
    for kind in BEYOND_KINDS:
        for variant, sc in (("paper", base), ("stable", stable)):
            for k in BEYOND_STIFFNESS:
                modes[(kind, variant, k)] = contact_modes(sc.with_overrides({"controller.kind": kind}), kind, k)
    outcome.seconds = time.perf_counter() - t0
    return outcome, modes


def beyond_document(base: Scenario, outcome, modes) -> dict:
    """The "beyond" part of metrics.json: the cases (from their tags), their runs (metrics, design),
    the linearised contact modes, the force-rate design numbers."""
    from ..errors import DesignError

    cases = [dict(name=c.name, kind=c.kind, variant=c.tags["variant"], mode=c.tags["mode"], k=c.tags["stiffness"],
                  label=c.label) for c in outcome.cases]
    entries = outcome.entries()
    out = dict(cases=cases, runs=entries, sampled_stiffness_max=SAMPLED_STIFFNESS_MAX)
    if not any(c["mode"] == "mujoco" for c in cases):
        out["mujoco_skipped"] = "MuJoCo is not installed (pip install 'hinfnn[mujoco]')"

    def stable_design(mode):
        return next((outcome.designs[c["name"]].get("force_rate") for c in cases
                     if c["variant"] == "stable" and c["mode"] == mode and c["kind"] == "hinf"), None) or {}

    out["design"] = stable_design("cont")
    out["kappa_sampled"] = stable_design("1kHz").get("kappa")
    out["design_1kHz"] = stable_design("1kHz")
    out["design_10kHz"] = stable_design("10kHz")
    stable = Scenario.load("paper-stable", [(k, v) for k, v in base.overrides if k != "controller.kind"])
    try:
        stable.with_overrides({"controller.kind": "hinf", **BEYOND_MODES["1kHz"],
                               "controller.force_rate.stiffness_max": max(BEYOND_STIFFNESS)})
        out["sampled_1e6_error"] = None
    except DesignError as err:
        out["sampled_1e6_error"] = str(err)
    out["contact_modes"] = [dict(kind=kind, variant=variant, stiffness=k, mode=str(r["least_damped"]),
                                 s=[r["least_damped"].s.real, r["least_damped"].s.imag],
                                 omega=r["least_damped"].omega, zeta=r["least_damped"].zeta, stable=r["stable"],
                                 kappa=r["kappa"], polynomial_match=r["polynomial_match"])
                            for (kind, variant, k), r in modes.items()]
    return out


#: What trajectory files keep of the comparison's runs (enough to redraw its figures).
BEYOND_FIELDS = ("t", "u1", "u1_d", "lam", "lam_d", "e_u1", "e_lam", "tau", "penetration", "normal_force",
                 "tau_abs_max", "steps_out_of_contact")

__all__ = ["DAMPED", "STUDY", "CONTACTS", "study_cases", "check_overrides", "reproduce", "beyond_cases", "run_beyond",
           "beyond_document", "BEYOND_STIFFNESS", "BEYOND_KINDS", "BEYOND_MODES", "BEYOND_FIELDS",
           "exact_model_overrides", "memory_plan"]
