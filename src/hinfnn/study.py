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


def run_study(base: Scenario, progress=None):
    """Simulate the study. Returns (runs, trajectories, metrics, designs, seconds)."""
    from .controllers import design_summary
    from .metrics import compute_metrics
    from .sim import simulate_many

    runs = paper_study_runs(base)
    t0 = time.perf_counter()
    specs, designs = [], {}
    for name, sc, kind, _ in runs:
        spec = sc.run(kind, name)
        specs.append(spec)
        designs[name] = design_summary(spec.controller)
    # every step in memory: the figures' zoom panels show the contact's 300 Hz chatter, which
    # 1-ms samples would alias (trajectory.npz is still decimated to output_interval)
    trajs = simulate_many(specs, progress=progress, save_every=1)
    seconds = time.perf_counter() - t0
    metrics = {}
    for name, traj in trajs.items():
        m = compute_metrics(traj)
        m["status"] = "ok" if int(traj.status) == 0 else "diverged"
        metrics[name] = m
    return runs, trajs, metrics, designs, seconds


def reproduce(out: Path, *, base: Scenario | None = None, force: bool = False, progress=None, log=print,
              command: str = "hinfnn reproduce") -> Path:
    """Run the study and write ``out`` atomically. Returns the folder actually written."""
    from .io import OutputFolder, atomic_write_bytes, atomic_write_text, choose_output, dumps_json, trajectory_npz_bytes
    from .report import paper_figures
    from .report.markdown import study_report
    from .results import metrics_document, run_entry

    base = base or Scenario.load("paper")
    target, note = choose_output(Path(out), force)
    if note:
        log(note)
    with OutputFolder(target) as folder:
        runs, trajs, metrics, designs, sim_seconds = run_study(base, progress=progress)
        t0 = time.perf_counter()
        root = folder.path
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
    return target
