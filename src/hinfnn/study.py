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

from .scenario import KIND_LABELS, Scenario, simulate_many

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
    arm = sc.data["plant"]["arm"]
    out = {f"nominal.arm.{k}": arm[k] for k in ("m1", "m2", "l1", "l2", "g")}
    out["nominal.surface.delta_deg"] = sc.data["plant"]["surface"]["delta_deg"]
    out["nominal.surface.d_G"] = sc.data["plant"]["surface"]["d_G"]
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
    label = KIND_LABELS[kind]
    if kind == "hinf_nn":
        label += f" ({scenario.data['controller']['network_f']['preset']})"
    if name.startswith("hinf_exact"):
        label += " with exact nominal model"
    if name.endswith("_damped"):
        label += f", damped contact {scenario.data['plant']['contact']['damping']:g} N·s/m"
    return label


def design_facts(base: Scenario) -> dict:
    """Numbers of the H∞ design the report quotes: v_p's gains R_p⁻¹B_pᵀP_p, F_p's drive B_pᵀP_p."""
    import numpy as np

    ctrl = base.build_controller("hinf")
    g = ctrl.gains
    s_p = np.asarray(ctrl.P_p)[1]  # B_pᵀP_p for m = 1
    return {"s_p": s_p.tolist(), "v_p_gain": (s_p / float(np.asarray(g.R_p).reshape(-1)[0])).tolist(),
            "K_p": float(np.asarray(g.K_p).reshape(-1)[0]), "K_v": float(np.asarray(g.K_v).reshape(-1)[0]),
            "gamma_1": float(g.gamma_1), "damping_damped": DAMPED,
            "u1_amplitude": base.data["reference"]["u1_amplitude"]}


def run_study(base: Scenario, progress=None):
    """Simulate the study. Returns (runs, trajectories, metrics, seconds)."""
    from .metrics import compute_metrics

    runs = paper_study_runs(base)
    t0 = time.perf_counter()
    # every step in memory: the figures' zoom panels show the contact's 300 Hz chatter, which
    # 1-ms samples would alias (trajectory.npz is still decimated to output_interval)
    trajs = simulate_many([(n, sc, k) for n, sc, k, _ in runs], progress=progress, save_every=1)
    seconds = time.perf_counter() - t0
    metrics = {}
    for name, traj in trajs.items():
        m = compute_metrics(traj)
        m["status"] = "ok" if int(traj.status) == 0 else "diverged"
        metrics[name] = m
    return runs, trajs, metrics, seconds


def metrics_document(scenario: Scenario, entries) -> dict:
    """The metrics.json document: ``entries`` = [(name, kind, overrides, metrics, traj)]."""
    from . import __version__
    from .sim.trajectory import STATUS

    runs = []
    for name, kind, overrides, m, traj in entries:
        status = int(traj.status)
        run = {"name": name, "controller": kind, "overrides": {k: v for k, v in overrides.items()},
               "status": "ok" if status == 0 else "diverged",
               "t_fail": None if status == 0 else float(traj.t_fail),
               "reason": None if status == 0 else STATUS.get(status, str(status)),
               "metrics": {k: v for k, v in m.items() if k != "status"}}
        runs.append(run)
    return {"hinfnn_version": __version__, "scenario": scenario.data, "runs": runs}


def reproduce(out: Path, *, base: Scenario | None = None, force: bool = False, progress=None,
              log=print) -> Path:
    """Run the study and write ``out`` atomically. Returns the folder actually written."""
    from .io import OutputFolder, atomic_write_bytes, atomic_write_text, choose_output, dumps_json, \
        trajectory_npz_bytes
    from .report import paper_figures
    from .report.markdown import study_report

    base = base or Scenario.load("paper")
    target, note = choose_output(Path(out), force)
    if note:
        log(note)
    with OutputFolder(target) as folder:
        runs, trajs, metrics, sim_seconds = run_study(base, progress=progress)
        t0 = time.perf_counter()
        root = folder.path
        paper = {n: t for n, t in trajs.items() if not n.startswith("hinf_exact")}
        figures = paper_figures(paper, root) + paper_figures(paper, root, suffix="_damped")
        fig_seconds = time.perf_counter() - t0
        doc = metrics_document(base, [(n, k, o, metrics[n], trajs[n]) for n, _, k, o in runs])
        atomic_write_text(root / "metrics.json", dumps_json(doc))
        atomic_write_bytes(root / "trajectory.npz", trajectory_npz_bytes(trajs, base.data["simulation"]["output_interval"]))
        atomic_write_text(root / "scenario.toml", base.to_toml())
        labels = {n: run_label(n, sc, k) for n, sc, k, _ in runs}
        text = study_report(base, metrics, labels, [Path(f).name for f in figures],
                            timings={"simulation (compile + run, all runs)": sim_seconds,
                                     "figures": fig_seconds},
                            design=design_facts(base), is_paper=base.source == "paper" and not base.overrides)
        atomic_write_text(root / "report.md", text)
    return target
