"""The paper's Sec. VI study end to end: the runs, their metrics, figures, claims and report.

:func:`paper_study_runs` lists the runs: FL-like, H∞-only and adaptive H∞ NN with both F_f
centre presets on the paper scenario, each with the paper's undamped contact and with a damped
contact (200 N·s/m) as a sensitivity study, plus a diagnostic H∞-only run with an exact nominal
model (to separate model mismatch from disturbance in the position error). :func:`reproduce`
runs them (batched under ``vmap`` by controller structure) and writes the result folder.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from .scenario import Scenario

DAMPED = 200.0  # N·s/m, the sensitivity study's contact damping

#: (run name, controller kind, overrides); "" / "_damped" suffixes are added per contact model.
STUDY = [
    ("fl", "fl", {}),
    ("hinf", "hinf", {}),
    ("hinf_nn", "hinf_nn", {"controller.network_f.preset": "paper-likely"}),
    ("hinf_nn_printed", "hinf_nn", {"controller.network_f.preset": "paper-printed"}),
]
CONTACT_SUFFIXES = {"": 0.0, "_damped": DAMPED}


def exact_model_overrides(sc: Scenario) -> dict:
    """Overrides that give the controller the TRUE arm and surface as its nominal model."""
    arm = sc.plant.arm
    out = {f"nominal.arm.{k}": getattr(arm, k) for k in ("m1", "m2", "l1", "l2", "g")}
    out["nominal.surface.delta_deg"] = sc.plant.surface.delta_deg
    out["nominal.surface.d_G"] = sc.plant.surface.d_G
    return out


def paper_study_runs(base: Scenario) -> list[tuple[str, Scenario, str, dict]]:
    """[(name, scenario, kind, overrides)] of the study, on top of ``base``."""
    runs = []
    for suffix, damping in CONTACT_SUFFIXES.items():
        for name, kind, over in STUDY:
            o = {**over, "plant.contact.damping": damping, "controller.kind": kind}
            runs.append((name + suffix, base.with_overrides(o), kind, o))
        o = {**exact_model_overrides(base), "plant.contact.damping": damping, "controller.kind": "hinf"}
        runs.append(("hinf_exact" + suffix, base.with_overrides(o), "hinf", o))
    return runs


def run_label(name: str, scenario: Scenario, kind: str) -> str:
    from .controllers import KINDS

    label = KINDS[kind].label
    if kind == "hinf_nn":
        label += f" ({scenario.controller.network_f.preset})"
    if name.startswith("hinf_exact"):
        label += " with exact nominal model"
    if name.endswith("_damped"):
        label += f", damped contact {scenario.plant.contact.damping:g} N·s/m"
    return label


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
    from .errors import ConfigError

    for key, _ in base.overrides:
        if key in STUDY_KEYS:
            raise ConfigError(f"cannot be overridden for `hinfnn reproduce`: {STUDY_KEYS[key]}; use `hinfnn run` "
                              "to run other controllers or contacts", key=key)
        if beyond and key in BEYOND_KEYS:
            raise ConfigError(f"cannot be overridden for `hinfnn reproduce`: {BEYOND_KEYS[key]}; add --paper-only "
                              "to run only the paper's study with it, or use `hinfnn run` / `hinfnn compare`",
                              key=key)


def study_specs(base: Scenario):
    """(runs, Run specs, designs) of the study on ``base``."""
    from .controllers import design_summary

    runs = paper_study_runs(base)
    specs, designs = [], {}
    for name, sc, kind, _ in runs:
        spec = sc.run(kind, name)
        specs.append(spec)
        designs[name] = design_summary(spec.controller)
    return runs, specs, designs


def memory_plan(specs, log=print):
    """``save_every`` for the study's runs in memory, checked against the available memory.

    Every step is kept when it fits in half the available memory: the figures' zoom panels show
    the contact's 300 Hz chatter, which 1-ms samples would alias (trajectory.npz is decimated to
    output_interval either way). Otherwise the runs keep the output_interval samples (said in
    one line), and a study that does not fit even so is refused (ResourceError)."""
    from . import resources

    every = resources.plan(specs, save_every=1, copies=1.5)
    avail = resources.available_memory()
    if avail is None or every.peak <= resources.BASE_BYTES + 0.5 * (avail - resources.BASE_BYTES):
        return 1, every
    sampled = resources.plan(specs, copies=2.0)
    resources.check(sampled, available=avail, fields_option=False)
    log(f"hinfnn: warning: keeping every step of the study in memory would need {resources.size(every.peak)} "
        f"({resources.size(avail)} available): its figures are drawn from the stored samples, every "
        f"{sampled.interval:g} s (zoom panels may alias the contact's chatter)")
    return None, sampled


def simulate_named(runs, *, progress=None, fields=None, extra=None, save_every: int | None = 1, prepared=None):
    """Simulate [(name, scenario, kind, overrides)] (batched by structure; ``save_every`` 1 keeps
    every step in memory, None the output_interval samples; ``prepared``: the (Run specs,
    designs) of ``runs`` when already built).

    Returns (trajectories, metrics with a "status" key, design summaries, seconds). ``extra(traj,
    metrics)`` may add metrics of its own."""
    from .controllers import design_summary
    from .metrics import compute_metrics
    from .sim import simulate_many

    if prepared is None:
        specs, designs = [], {}
        for name, sc, kind, _ in runs:
            spec = sc.run(kind, name)
            specs.append(spec)
            designs[name] = design_summary(spec.controller)
    else:
        specs, designs = prepared
    t0 = time.perf_counter()
    trajs = simulate_many(specs, progress=progress, save_every=save_every, fields=fields)
    seconds = time.perf_counter() - t0
    metrics = {}
    for name, traj in trajs.items():
        m = compute_metrics(traj)
        if extra is not None:
            extra(traj, m)
        m["status"] = "ok" if int(traj.status) == 0 else "diverged"
        metrics[name] = m
    return trajs, metrics, designs, seconds


def run_study(base: Scenario, progress=None, *, prepared=None, save_every: int | None = 1):
    """Simulate the study (``prepared``: :func:`study_specs` of ``base`` when already built;
    ``save_every``: 1 keeps every step in memory, None the output_interval samples). Returns
    (runs, trajectories, metrics, designs, seconds)."""
    runs, specs, designs = prepared or study_specs(base)
    trajs, metrics, designs, seconds = simulate_named(runs, progress=progress, save_every=save_every,
                                                      prepared=(specs, designs))
    return runs, trajs, metrics, designs, seconds


def reproduce(out: Path | None = None, *, base: Scenario | None = None, force: bool = False, progress=None,
              log=print, command: str = "hinfnn reproduce", beyond: bool = True) -> Path:
    """Run the study (and, with ``beyond``, the "Beyond the paper" comparison) and write ``out``
    (default ``results/paper``) atomically. Returns the folder actually written. Overrides of
    ``base`` the study cannot honour are rejected (:func:`check_overrides`) before anything
    runs; the output folder is reserved as for every command (:func:`hinfnn.io.reserve_output`);
    a study that would not fit in memory is refused (:func:`memory_plan`)."""
    from .io import OutputFolder, reserve_output

    base = base or Scenario.load("paper")
    check_overrides(base, beyond=beyond)
    reservation = reserve_output(out, command="reproduce", name=base.name, force=force)
    with reservation:
        specs = study_specs(base)
        save_every, plan = memory_plan(specs[1], log=log)
        if reservation.note:
            log(f"hinfnn: {reservation.note}")
        if plan.seconds > 60:
            log(f"hinfnn: {plan.summary()}")
        with OutputFolder(reservation, kind="study", command=command) as folder:
            _write_study(folder.path, base, specs, save_every, progress, command, beyond)
    return Path(folder.moved_to or reservation.target)


def _write_study(root: Path, base: Scenario, specs, save_every, progress, command: str, beyond: bool) -> None:
    from .io import atomic_write_bytes, atomic_write_text, dumps_json, trajectory_npz_bytes
    from .report import paper_figures
    from .report.markdown import study_report
    from .results import metrics_document, run_entry

    runs, trajs, metrics, designs, sim_seconds = run_study(base, progress=progress, prepared=specs,
                                                           save_every=save_every)
    t0 = time.perf_counter()
    paper = {n: t for n, t in trajs.items() if not n.startswith("hinf_exact")}
    figures = paper_figures(paper, root) + paper_figures(paper, root, suffix="_damped")
    fig_seconds = time.perf_counter() - t0
    entries = [run_entry(n, trajs[n], overrides=o, design=designs[n], metrics=metrics[n],
                         label=run_label(n, sc, k)) for n, sc, k, o in runs]
    doc = metrics_document(base, entries, command=command)
    timings = {"simulation (compile + run, all runs)": sim_seconds, "figures": fig_seconds}
    atomic_write_bytes(root / "trajectory.npz", trajectory_npz_bytes(trajs, base.simulation.output_interval))
    del trajs, paper  # the study's every-step trajectories: written; free them before the comparison runs
    if beyond:
        from .report.figures import beyond_figures

        if hasattr(progress, "stage"):  # the command's progress display: the comparison has its own bar
            progress.stage("Beyond the paper")
        b_runs, b_trajs, b_metrics, b_designs, b_modes, b_seconds = run_beyond(base, progress=progress)
        doc["beyond"] = beyond_document(base, b_runs, b_trajs, b_metrics, b_designs, b_modes)
        t0 = time.perf_counter()
        figures += beyond_figures(b_trajs, b_metrics, doc["beyond"]["cases"], root)
        timings["beyond the paper: simulation and linearisation"] = b_seconds
        timings["beyond the paper: figures"] = time.perf_counter() - t0
        atomic_write_bytes(root / "beyond.npz", trajectory_npz_bytes(b_trajs, 10 * base.simulation.output_interval,
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


def beyond_name(kind: str, variant: str, mode: str, k: float) -> str:
    return f"{kind}_{variant}_{mode}_k{k:.0e}".replace("+0", "")


def mujoco_available() -> bool:
    """Whether the optional MuJoCo extra is installed (the side-by-side needs it)."""
    try:
        from .plant.mujoco import require_mujoco

        require_mujoco()
    except Exception:  # noqa: BLE001 - the comparison is optional: the report says it was skipped
        return False
    return True


def beyond_runs(base: Scenario, mujoco: bool = False) -> list[tuple[str, Scenario, str, dict]]:
    """[(name, scenario, kind, overrides)] of the comparison: every law × {paper, stable} ×
    {continuous, 1 kHz} × stiffness, undamped contact, on top of ``base`` (the user's overrides of
    the paper scenario apply to both variants); with ``mujoco``, the same laws on MuJoCo at
    :data:`MUJOCO_STIFFNESS` beside the built-in plant under the same 10 kHz hold."""
    user = [(k, v) for k, v in base.overrides if k != "controller.kind"]
    stable = Scenario.load("paper-stable", user)
    runs = []
    for kind in BEYOND_KINDS:
        for variant, sc in (("paper", base), ("stable", stable)):
            for mode, mode_over in BEYOND_MODES.items():
                for k in BEYOND_STIFFNESS:
                    o = {**mode_over, "plant.contact.stiffness": k, "plant.contact.damping": 0.0,
                         "controller.kind": kind}
                    if variant == "stable" and mode != "cont":
                        o["controller.force_rate.stiffness_max"] = SAMPLED_STIFFNESS_MAX
                    runs.append((beyond_name(kind, variant, mode, k), sc.with_overrides(o), kind, o))
            if mujoco:
                common = {"plant.contact.stiffness": MUJOCO_STIFFNESS, "plant.contact.damping": 0.0,
                          "controller.kind": kind}
                # MuJoCo runs the controller every step (sampled data at 1/dt); its built-in twin does too
                twin = {**common, "simulation.control": "sampled", "simulation.control_period": sc.simulation.dt}
                runs.append((beyond_name(kind, variant, "10kHz", MUJOCO_STIFFNESS), sc.with_overrides(twin), kind, twin))
                o = {**common, "plant.engine": "mujoco"}
                runs.append((beyond_name(kind, variant, "mujoco", MUJOCO_STIFFNESS), sc.with_overrides(o), kind, o))
    return runs


def beyond_label(name: str, kind: str) -> str:
    from .controllers import KINDS

    _, variant, mode, k = name.rsplit("_", 3)
    how = {"cont": "continuous", "1kHz": "ZOH 1 kHz", "10kHz": "ZOH 10 kHz", "mujoco": "MuJoCo plant, 10 kHz"}[mode]
    return f"{KINDS[kind].label}, {'paper law' if variant == 'paper' else 'stabilised'}, {how}, k = {k[1:]} N/m"


def _peak_after(traj, m, after: float = 0.1):
    """peak |τ1| over the steps after ``after`` seconds (the start's transient excluded)."""
    t, tau = traj.t, traj.tau_abs_max
    m["peak_abs_tau1_after_0.1s"] = float(np.max(tau[t > after, 0])) if np.any(t > after) else math.nan


def run_beyond(base: Scenario, progress=None):
    """Simulate the comparison (with MuJoCo when it is installed) and linearise its laws. Returns
    (runs, trajectories, metrics, designs, contact modes, seconds)."""
    from .analysis import contact_modes
    from .fields import METRICS_FIELDS

    runs = beyond_runs(base, mujoco=mujoco_available())
    trajs, metrics, designs, seconds = simulate_named(runs, progress=progress, fields=BEYOND_FIELDS + METRICS_FIELDS,
                                                      extra=_peak_after)
    stable = Scenario.load("paper-stable", [(k, v) for k, v in base.overrides if k != "controller.kind"])
    modes = {}
    for kind in BEYOND_KINDS:
        for variant, sc in (("paper", base), ("stable", stable)):
            for k in BEYOND_STIFFNESS:
                modes[(kind, variant, k)] = contact_modes(sc.with_overrides({"controller.kind": kind}), kind, k)
    return runs, trajs, metrics, designs, modes, seconds


def beyond_document(base: Scenario, runs, trajs, metrics, designs, modes) -> dict:
    """The "beyond" part of metrics.json: the cases, their runs (metrics, design), the
    linearised contact modes, the force-rate design numbers."""
    from .errors import DesignError
    from .results import run_entry

    cases = []
    for name, sc, kind, o in runs:
        _, variant, mode, _ = name.rsplit("_", 3)
        cases.append(dict(name=name, kind=kind, variant=variant, mode=mode, k=float(o["plant.contact.stiffness"]),
                          label=beyond_label(name, kind)))
    entries = [run_entry(n, trajs[n], overrides=o, design=designs[n], metrics=metrics[n], label=beyond_label(n, k))
               for n, _, k, o in runs]
    out = dict(cases=cases, runs=entries, sampled_stiffness_max=SAMPLED_STIFFNESS_MAX)
    if not any(c["mode"] == "mujoco" for c in cases):
        out["mujoco_skipped"] = "MuJoCo is not installed (pip install 'hinfnn[mujoco]')"
    cont = next((designs[c["name"]].get("force_rate") for c in cases
                 if c["variant"] == "stable" and c["mode"] == "cont" and c["kind"] == "hinf"), None)
    def stable_design(mode):
        return next((designs[c["name"]].get("force_rate") for c in cases
                     if c["variant"] == "stable" and c["mode"] == mode and c["kind"] == "hinf"), None) or {}

    out["design"] = cont or {}
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
