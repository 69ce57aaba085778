"""Side by side: one scenario with one key set to several values (``hinfnn compare``), e.g. the
built-in plant against MuJoCo (``plant.engine = hinfnn, mujoco``), with the same controller(s).

Every run is the scenario with ``key = value``; the figures overlay λ(t), u1(t), τ(t) (and the
contact) of every run, and ``compare.md`` tables the metrics with their ratios to the first
value's.
"""

from __future__ import annotations

import time
from pathlib import Path

from .scenario import Scenario

#: Metrics compared (and their ratios) in compare.md.
COMPARED = ("rms_e_u1", "rms_e_u1_last2s", "rms_e_lam", "rms_e_lam_last2s", "J_T", "fraction_out_of_contact")


def split_values(raw: str) -> list[str]:
    """``"hinfnn,mujoco"`` -> ["hinfnn", "mujoco"] (commas inside brackets or quotes do not split)."""
    out, depth, quote, cur = [], 0, None, ""
    for ch in raw:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
            continue
        cur += ch
    out.append(cur.strip())
    return [v for v in out if v]


def comparison_runs(sc: Scenario, key: str, values: list) -> list[tuple[str, Scenario, str, dict]]:
    """[(name, scenario, kind, overrides)]: every controller kind of ``sc`` at every value."""
    runs = []
    for value in values:
        one = sc.with_overrides([(key, value)])
        for kind in one.kinds:
            runs.append((f"{kind}@{value}", one.single(kind), kind, {key: value}))
    return runs


def comparison_table(doc: dict, key: str, values: list) -> str:
    """compare.md: what was compared, the metrics of every run and their ratio to the run of the
    same controller at the first value."""
    from .report.markdown import _f, percent

    runs = {r["name"]: r for r in doc["runs"]}
    lines = [f"# {doc['scenario']['name']}: {key} = {', '.join(str(v) for v in values)}", "",
             f"Command: `{doc['command']}`. The same scenario and controller(s), {key} changed; the figures overlay "
             "every run. Ratios are to the run of the same controller at the first value.", "",
             "| run | status | " + " | ".join(COMPARED) + " |", "|---|---|" + "---|" * len(COMPARED)]
    for name, r in runs.items():
        kind, value = name.split("@", 1)
        base = runs.get(f"{kind}@{values[0]}")
        cells = []
        for m in COMPARED:
            v = r["metrics"].get(m)
            text = percent(v) if m == "fraction_out_of_contact" else _f(v)
            b = base["metrics"].get(m) if base and base is not r else None
            if b not in (None, 0) and v is not None and m != "fraction_out_of_contact":
                text += f" (×{v / b:.3g})"
            cells.append(text)
        status = r["status"] if r["status"] == "ok" else f"stopped at {_f(r['t_fail'])} s"
        lines.append(f"| {name} | {status} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def compare(sc: Scenario, key: str, values: list, out: Path | None = None, *, force: bool = False, progress=None,
            log=print, command: str = "hinfnn compare") -> tuple[Path, dict]:
    """Run the comparison and write ``out`` atomically (metrics.json, trajectory.npz,
    scenario.toml, compare.md, figures; default ``results/compares/<name>-<UTC time>``, reserved
    as for every command: :func:`hinfnn.io.reserve_output`). Returns the folder and the metrics
    document."""
    from .controllers import design_summary
    from .io import OutputFolder, atomic_write_bytes, atomic_write_text, dumps_json, reserve_output, trajectory_npz_bytes
    from .results import metrics_document, run_entry
    from .sim import simulate_many

    runs = comparison_runs(sc, key, values)
    reservation = reserve_output(out, command="compare", name=sc.name, force=force)
    with reservation, OutputFolder(reservation, kind="run", command=command) as folder:
        if reservation.note:
            log(f"hinfnn: {reservation.note}")
        specs = [s.run(kind, name) for name, s, kind, _ in runs]
        t0 = time.perf_counter()
        trajs = simulate_many(specs, progress=progress)
        entries = [run_entry(spec.name, trajs[spec.name], overrides=o, design=design_summary(spec.controller))
                   for spec, (_, _, _, o) in zip(specs, runs)]
        doc = metrics_document(sc, entries, command=command)
        doc["compare"] = {"key": key, "values": list(values), "seconds": time.perf_counter() - t0}
        atomic_write_text(folder.path / "metrics.json", dumps_json(doc))
        atomic_write_bytes(folder.path / "trajectory.npz", trajectory_npz_bytes(trajs, sc.simulation.output_interval))
        atomic_write_text(folder.path / "scenario.toml", sc.to_toml())
        atomic_write_text(folder.path / "compare.md", comparison_table(doc, key, values))
        from .report import run_figures

        run_figures(trajs, folder.path)
    return Path(folder.moved_to or reservation.target), doc
