"""Side by side: one scenario with one key set to several values (``hinfnn compare``), e.g. the
built-in plant against MuJoCo (``plant.engine = hinfnn, mujoco``), with the same controller(s).

Every case is the scenario with ``key = value`` and one controller, tagged with the key and the
value; the figures overlay λ(t), u1(t), τ(t) (and the contact) of every run, and ``compare.md``
tables the metrics with their ratios to the first value's.
"""

from __future__ import annotations

from pathlib import Path

from ..experiment import Case, cases, result_folder, run_cases

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


def comparison_cases(sc, key: str, values: list) -> list[Case]:
    """Every controller kind of ``sc`` at every value (each value checked with the scenario)."""
    out = []
    for i, value in enumerate(values):
        one = sc.with_overrides([(key, value)])
        out += cases(one, suffix=f"@{value}", tags={"compared": key, "value": value, "value_index": i},
                     overrides={key: value})
    return out


def comparison_table(doc: dict, key: str, values: list) -> str:
    """compare.md: what was compared, the metrics of every run and their ratio to the run of the
    same controller at the first value (runs told apart by their tags)."""
    from ..report.markdown import _f, percent

    runs = doc["runs"]
    first = {r["controller"]: r for r in runs if r["tags"].get("value_index") == 0}
    lines = [f"# {doc['scenario']['name']}: {key} = {', '.join(str(v) for v in values)}", "",
             f"Command: `{doc['command']}`. The same scenario and controller(s), {key} changed; the figures overlay "
             "every run. Ratios are to the run of the same controller at the first value.", "",
             "| run | status | " + " | ".join(COMPARED) + " |", "|---|---|" + "---|" * len(COMPARED)]
    for r in runs:
        base = first.get(r["controller"])
        cells = []
        for m in COMPARED:
            v = r["metrics"].get(m)
            text = percent(v) if m == "fraction_out_of_contact" else _f(v)
            b = base["metrics"].get(m) if base and base is not r else None
            if b not in (None, 0) and v is not None and m != "fraction_out_of_contact":
                text += f" (×{v / b:.3g})"
            cells.append(text)
        status = r["status"] if r["status"] == "ok" else f"stopped at {_f(r['t_fail'])} s"
        lines.append(f"| {r['name']} | {status} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def compare(sc, key: str, values: list, out: Path | None = None, *, force: bool = False, progress=None,
            log=print, command: str = "hinfnn compare") -> tuple[Path, dict]:
    """Run the comparison and write ``out`` atomically (metrics.json, trajectory.npz,
    scenario.toml, compare.md, figures; default ``results/compares/<name>-<UTC time>``, reserved
    as for every command: :func:`hinfnn.io.reserve_output`). Returns the folder and the metrics
    document."""
    from ..io import atomic_write_text

    todo = comparison_cases(sc, key, values)
    with result_folder(out, command="compare", name=sc.name, kind="run", force=force, log=log,
                       command_line=command) as written:
        outcome, doc = run_cases(todo, written.path, sc, command=command, progress=progress, log=log,
                                 document=lambda o: {"compare": {"key": key, "values": list(values),
                                                                 "seconds": o.seconds}})
        atomic_write_text(written.path / "compare.md", comparison_table(doc, key, values))
        from ..report import run_figures

        run_figures(outcome.trajectories, written.path)
    return written.path, doc


__all__ = ["COMPARED", "split_values", "comparison_cases", "comparison_table", "compare"]
