"""The paper's Sec. VI study end to end: the runs, their metrics, figures, claims and report.

:func:`paper_study_runs` lists the runs: FL-like, H∞-only and adaptive H∞ NN with both F_f
centre presets on the paper scenario, each with the paper's undamped contact and with a damped
contact (200 N·s/m) as a sensitivity study, plus a diagnostic H∞-only run with an exact nominal
model (to separate model mismatch from disturbance in the position error). :func:`reproduce`
runs them (batched under ``vmap`` by controller structure) and writes the result folder.
"""

from __future__ import annotations

import time
from pathlib import Path

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


def check_overrides(base: Scenario) -> None:
    """Reject (ConfigError naming the key) an override of ``base`` the study would silently
    replace in its runs (:data:`STUDY_KEYS`)."""
    from .errors import ConfigError

    for key, _ in base.overrides:
        if key in STUDY_KEYS:
            raise ConfigError(f"cannot be overridden for `hinfnn reproduce`: {STUDY_KEYS[key]}; use `hinfnn run` "
                              "to run other controllers or contacts", key=key)


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


def run_study(base: Scenario, progress=None, *, prepared=None, save_every: int | None = 1):
    """Simulate the study (``prepared``: :func:`study_specs` of ``base`` when already built;
    ``save_every``: 1 keeps every step in memory, None the output_interval samples). Returns
    (runs, trajectories, metrics, designs, seconds)."""
    from .metrics import compute_metrics
    from .sim import simulate_many

    runs, specs, designs = prepared or study_specs(base)
    t0 = time.perf_counter()
    trajs = simulate_many(specs, progress=progress, save_every=save_every)
    seconds = time.perf_counter() - t0
    metrics = {}
    for name, traj in trajs.items():
        m = compute_metrics(traj)
        m["status"] = "ok" if int(traj.status) == 0 else "diverged"
        metrics[name] = m
    return runs, trajs, metrics, designs, seconds


def reproduce(out: Path | None = None, *, base: Scenario | None = None, force: bool = False, progress=None,
              log=print, command: str = "hinfnn reproduce") -> Path:
    """Run the study and write ``out`` (default ``results/paper``) atomically. Returns the
    folder actually written. Overrides of ``base`` the study cannot honour are rejected
    (:func:`check_overrides`) before anything runs; the output folder is reserved as for every
    command (:func:`hinfnn.io.reserve_output`); a study that would not fit in memory is refused
    (:func:`memory_plan`)."""
    from .io import OutputFolder, reserve_output

    base = base or Scenario.load("paper")
    check_overrides(base)
    reservation = reserve_output(out, command="reproduce", name=base.name, force=force)
    with reservation:
        specs = study_specs(base)
        save_every, plan = memory_plan(specs[1], log=log)
        if reservation.note:
            log(f"hinfnn: {reservation.note}")
        if plan.seconds > 60:
            log(f"hinfnn: {plan.summary()}")
        with OutputFolder(reservation, kind="study", command=command) as folder:
            _write_study(folder.path, base, specs, save_every, progress, command)
    return Path(folder.moved_to or reservation.target)


def _write_study(root: Path, base: Scenario, specs, save_every, progress, command: str) -> None:
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
    atomic_write_text(root / "metrics.json", dumps_json(doc))
    atomic_write_bytes(root / "trajectory.npz", trajectory_npz_bytes(trajs, base.simulation.output_interval))
    atomic_write_text(root / "scenario.toml", base.to_toml())
    text = study_report(base, doc, [Path(f).name for f in figures],
                        timings={"simulation (compile + run, all runs)": sim_seconds, "figures": fig_seconds},
                        is_paper=base.source == "paper" and not base.overrides)
    atomic_write_text(root / "report.md", text)
