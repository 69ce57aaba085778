"""A real force sensor on every arm: the paper's law against the one designed for the sensor
(``hinfnn gallery --sensor``; docs/beyond-the-paper.md, section 12).

For each arm of :data:`SENSOR_ARMS` (its shipped scenario: model errors, payload, friction,
disturbance) with a force sensor of white noise σ ∈ :data:`SENSOR_NOISE` N per axis and
:data:`SENSOR_DELAY` sample of transport delay, the URDF's torque limits on the true motors and a
1 kHz zero-order hold, each law of :data:`SENSOR_KINDS` runs twice:

* ``paper``: the scenario's controller designed for an ideal sensor (its force-rate term with κ by
  the rule of section 7 on the differenced force, no force filter, whatever sensor the scenario
  declares; none where the scenario has none);
* ``designed``: the law as the scenario ships it for its declared sensor: κ designed for the sensor
  ("rule"; section 12) with the scenario's own force filter (``"design"``: order and cutoff designed
  with κ; 0 where the scenario ships none, as `ur5-table-stable` and `panda-table` do), over the
  scenario's stated stiffness range (or, without a force-rate section, up to the plant's contact
  stiffness).

A design the sensor makes impossible is refused (the DesignError's text is reported instead of
the run). Reported per run: status, the TRUE normal force's RMS error over the last 2 s, the
share of samples out of contact after :data:`AFTER` s, the peak commanded torque after
:data:`AFTER` s and the share of samples with a joint at its torque limit
(``fraction_torque_saturated``).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..experiment import Case, simulate_cases
from ..scenario import Scenario

#: The arms compared (shipped scenarios).
SENSOR_ARMS = ("ur5-polish", "ur5-table-stable", "ur5-sphere-stable", "panda-table")
#: Sensor noise, N per axis.
SENSOR_NOISE = (0.0, 0.5, 1.0, 2.5, 5.0)
#: Transport delay, samples.
SENSOR_DELAY = 1
#: The laws compared.
SENSOR_KINDS = ("hinf", "hinf_nn")
#: The start's transient left out of "out of contact" and the torque peak, s.
AFTER = 0.2
#: The default length of each run, s (the gallery's run is kept short; the issue's targets are
#: for 10-s runs: ``--set simulation.t_final=10``).
T_FINAL = 3.0
#: What the trajectories keep.
SENSOR_FIELDS = ("t", "lam", "lam_d", "e_lam", "tau", "normal_force", "tau_abs_max", "steps_out_of_contact")


def sensor_cases(arm: str, overrides=(), noises=SENSOR_NOISE, kinds=SENSOR_KINDS,
                 t_final: float = T_FINAL) -> tuple[list[Case], dict[str, str]]:
    """The cases of one arm and the designs refused ({case name: the DesignError's text}).
    ``overrides``: the user's, applied to every case before the comparison's own."""
    from ..controllers import KINDS
    from ..errors import DesignError

    base = Scenario.load(arm, overrides)
    fr = base.controller.force_rate
    k_plant = float(base.plant.contact.stiffness)
    cases, refused = [], {}
    for kind in kinds:
        for sigma in noises:
            common = {"controller.kind": kind, "plant.sensor.force_noise": float(sigma),
                      "plant.sensor.delay": SENSOR_DELAY, "plant.actuator.torque_limit": "urdf",
                      "simulation.control": "sampled", "simulation.control_period": 1e-3,
                      "simulation.t_final": float(t_final)}
            for variant in ("paper", "designed"):
                o = dict(common)
                if variant == "paper":  # the law as designed for an ideal sensor: ṡ the differenced force, no filter
                    o["controller.force_rate.source"] = "force"
                    o["controller.force_filter.order"] = 0
                if variant == "designed":  # the scenario's own force filter, as shipped
                    if fr.kappa == 0.0:
                        o.update({"controller.force_rate.kappa": "rule",
                                  "controller.force_rate.stiffness_max": k_plant,
                                  "controller.force_rate.stiffness_min": min(fr.stiffness_min, k_plant)})
                name = f"{kind}_{variant}_s{sigma:g}"
                label = (f"{KINDS[kind].label}, {'paper law' if variant == 'paper' else 'designed for the sensor'}, "
                         f"σ = {sigma:g} N")
                try:
                    sc = base.with_overrides(o)
                    sc.build_controller(kind)
                except DesignError as err:
                    refused[name] = str(err)
                    continue
                cases.append(Case(name, sc, overrides=o, label=label,
                                  tags={"arm": arm, "variant": variant, "kind": kind, "noise": float(sigma)}))
    return cases, refused


def _after(traj, m):
    """Out-of-contact share and peak |τ| after :data:`AFTER` s."""
    t = np.asarray(traj.t)
    after = t > AFTER
    steps = np.asarray(traj.steps_out_of_contact)
    per = int(traj.save_every)
    m[f"out_of_contact_after_{AFTER:g}s"] = (float(np.sum(steps[after]) / (per * int(np.sum(after))))
                                            if np.any(after) else math.nan)
    m[f"peak_abs_tau_after_{AFTER:g}s"] = (float(np.max(np.asarray(traj.tau_abs_max)[after]))
                                          if np.any(after) else math.nan)


def run_sensor(arm: str, overrides=(), progress=None, t_final: float = T_FINAL, noises=SENSOR_NOISE,
               kinds=SENSOR_KINDS) -> dict:
    """Simulate one arm's comparison: {"arm", "outcome", "refused", "seconds"}."""
    from ..fields import METRICS_FIELDS

    t0 = time.perf_counter()
    cases, refused = sensor_cases(arm, overrides, noises=noises, kinds=kinds, t_final=t_final)
    outcome = simulate_cases(cases, progress=progress, fields=SENSOR_FIELDS + METRICS_FIELDS, extra=_after)
    return dict(arm=arm, outcome=outcome, refused=refused, seconds=time.perf_counter() - t0)


def sensor_document(result: dict) -> dict:
    """The part of metrics.json of one arm's comparison: its rows (case, status, the numbers) and
    the refusals."""
    outcome = result["outcome"]
    rows = []
    for c, r in zip(outcome.cases, outcome.entries()):
        m = r["metrics"]
        fr = (r.get("design") or {}).get("force_rate") or {}
        sd = fr.get("sensing") or {}
        rows.append(dict(name=c.name, kind=c.tags["kind"], variant=c.tags["variant"], noise=c.tags["noise"],
                         status=r["status"], t_fail=r.get("t_fail"),
                         force_error=m.get("rms_normal_force_error_last2s"),
                         out_of_contact=m.get(f"out_of_contact_after_{AFTER:g}s"),
                         peak_tau=m.get(f"peak_abs_tau_after_{AFTER:g}s"),
                         saturated=m.get("fraction_torque_saturated"), kappa=fr.get("kappa"),
                         filter_order=sd.get("order", 0), cutoff_hz=sd.get("cutoff_hz"),
                         predicted_force_error_per_n=sd.get("force_error_per_n")))
    return dict(arm=result["arm"], rows=rows, refused=result["refused"], seconds=result["seconds"])


def sensor_table(doc: dict) -> list[str]:
    """The markdown table of one arm's comparison."""
    head = ["law", "design", "σ (N)", "status", "true force RMS error, last 2 s (N)",
            f"out of contact after {AFTER:g} s",
            f"peak abs τ after {AFTER:g} s (N·m)", "time at a torque limit", "κ (s)", "filter"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def f(x, spec=".3g"):
        return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)

    for r in doc["rows"]:
        status = r["status"] if r["status"] == "ok" else f"stopped at {f(r['t_fail'])} s"
        filt = "none" if not r["filter_order"] else f"order {r['filter_order']}, {f(r['cutoff_hz'])} Hz"
        lines.append(f"| {r['kind']} | {r['variant']} | {r['noise']:g} | {status} | {f(r['force_error'])} | "
                     f"{f(r['out_of_contact'], '.1%') if r['out_of_contact'] is not None else '—'} | "
                     f"{f(r['peak_tau'])} | {f(r['saturated'], '.1%') if r['saturated'] is not None else '—'} | "
                     f"{f(r['kappa'])} | {filt if r['variant'] == 'designed' else '—'} |")
    for name, text in doc["refused"].items():
        lines.append(f"| {name} | refused | | {text[:300]} | | | | | | |")
    return lines


def sensor_figure(doc: dict, path) -> str:
    """Force error, peak torque and time at a limit against σ, paper law against the designed one,
    per law (one PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    styles = {("hinf", "paper"): ("C0", "--"), ("hinf", "designed"): ("C0", "-"),
              ("hinf_nn", "paper"): ("C3", "--"), ("hinf_nn", "designed"): ("C3", "-")}
    for (kind, variant), (color, ls) in styles.items():
        rows = [r for r in doc["rows"] if r["kind"] == kind and r["variant"] == variant]
        if not rows:
            continue
        s = [r["noise"] for r in rows]

        def v(key, ok_only=True):
            return [r[key] if (r["status"] == "ok" or not ok_only) and r[key] is not None else np.nan for r in rows]

        label = f"{kind}, {variant}"
        axes[0].plot(s, v("force_error"), color=color, ls=ls, marker="o", label=label)
        axes[1].plot(s, v("peak_tau"), color=color, ls=ls, marker="o", label=label)
        axes[2].plot(s, [100 * x for x in v("saturated", ok_only=False)], color=color, ls=ls, marker="o", label=label)
        for r in rows:
            if r["status"] != "ok":
                axes[0].plot([r["noise"]], [np.nan], "x", color=color)
    axes[0].set_ylabel("true force RMS error, last 2 s (N)")
    axes[1].set_ylabel(f"peak |τ| after {AFTER:g} s (N·m)")
    axes[2].set_ylabel("time at a torque limit (%)")
    for ax in axes:
        ax.set_xlabel("sensor noise σ (N per axis)")
        ax.grid(True, alpha=0.3)
    axes[0].set_yscale("log")
    axes[1].set_yscale("log")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{doc['arm']}: {SENSOR_DELAY} sample of delay, URDF torque limits, 1 kHz (runs that stopped "
                 "are left out of the first two panels)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)




def _t_final(base: Scenario) -> float:
    """The user's simulation.t_final when given (``--set``), else :data:`T_FINAL`."""
    given = dict(base.overrides)
    return float(given["simulation.t_final"]) if "simulation.t_final" in given else T_FINAL


def sensor_report(parts: list, command: str) -> str:
    """report.md of ``hinfnn gallery --sensor``."""
    lines = ["# A real force sensor on every arm", "",
             f"`{command}`: each arm with white force-sensor noise σ per axis, {SENSOR_DELAY} sample of transport "
             "delay, the URDF's torque limits on the true motors and a 1 kHz zero-order hold; the paper's law as "
             "shipped (κ by the rule of docs/beyond-the-paper.md section 7, designed for an ideal sensor) against the "
             "force filter and κ designed together for the declared sensor (docs/beyond-the-paper.md section 12). The force error is the TRUE "
             "normal force's (the plant's) minus λd.", ""]
    for doc, fig, t_final in parts:
        lines += [f"## {doc['arm']} ({t_final:g}-s runs, {doc['seconds']:.0f} s to simulate)", ""]
        lines += sensor_table(doc)
        if fig:
            lines += ["", f"![{doc['arm']}]({doc['arm']}/sensor.png)"]
        lines.append("")
    return "\n".join(lines)


def run_sensor_gallery(out=None, *, overrides=(), only=None, force: bool = False, progress=None, log=print,
                       command: str = "hinfnn gallery --sensor"):
    """Run the comparison for each arm (``only``: these of :data:`SENSOR_ARMS`) and write ``out``
    atomically (OUT/report.md; OUT/<arm>/metrics.json with a "sensor" part, trajectory.npz,
    scenario.toml, sensor.png). Returns the folder written."""
    from ..errors import ConfigError
    from ..experiment import result_folder, write_result
    from ..io import atomic_write_text
    from ..sim import release_programs

    arms = list(dict.fromkeys(only)) if only else list(SENSOR_ARMS)
    unknown = [a for a in arms if a not in SENSOR_ARMS]
    if unknown:
        raise ConfigError(f"{unknown} not in the sensor comparison; allowed: {', '.join(SENSOR_ARMS)}", key="only")
    bases = {arm: Scenario.load(arm, overrides) for arm in arms}  # every check before the folder is reserved
    parts = []
    with result_folder(out, command="gallery", name="gallery-sensor", kind="gallery", force=force, log=log,
                       command_line=command) as written:
        for arm in arms:
            t_final = _t_final(bases[arm])
            label = (lambda d, t, what, n=arm: progress(d, t, f"{n}, sensor: {what}")) if progress else None
            result = run_sensor(arm, overrides, progress=label, t_final=t_final)
            doc = sensor_document(result)
            sub = written.path / arm
            sub.mkdir()
            fig = None
            if result["outcome"].cases:
                write_result(sub, bases[arm], result["outcome"], command=command, fields=SENSOR_FIELDS,
                             extra={"sensor": doc})
                fig = sensor_figure(doc, sub / "sensor.png")
            parts.append((doc, fig, t_final))
            log(f"{arm}: {len(result['outcome'].cases)} runs in {result['seconds']:.0f} s, "
                f"{len(result['refused'])} designs refused")
            release_programs()
        atomic_write_text(written.path / "report.md", sensor_report(parts, command))
    return written.path


__all__ = ["SENSOR_ARMS", "SENSOR_NOISE", "SENSOR_DELAY", "SENSOR_KINDS", "AFTER", "T_FINAL", "sensor_cases",
           "run_sensor", "sensor_document", "sensor_table", "sensor_figure", "sensor_report", "run_sensor_gallery"]
