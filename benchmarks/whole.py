"""Whole process: ``hinfnn run paper`` (10 s, 100,000 RK4 steps) from launch to exit, cold and warm.

With a fresh, empty compilation cache (``HINFNN_CACHE_DIR`` = a temporary folder), launches

    hinfnn run paper --out <tmp> --force --quiet

once (cold: every program is compiled and written to the cache), then ``repeats`` more times
(warm), and ``repeats`` times with ``--no-figures`` (warm). Wall time is taken here, in the
parent, from just before ``Popen`` to the child's exit; CPU time (user + system, all threads) from
the child's resource usage (``os.wait4``): on a busy machine the wall time grows, the CPU time
hardly does. The breakdown comes from the child's ``HINFNN_TRACE_STARTUP=1`` lines
(:mod:`hinfnn._startup`):

* ``to first step``: launch to the end of the first compiled chunk, split as in
  ``benchmarks/startup.py`` (import, setup, trace, lower, compile or cache load, first chunk);
* ``simulation``: the remaining 49 chunks and the final record;
* ``files``: metrics, metrics.json, trajectory.npz, scenario.toml;
* ``figures``: the six PNGs (matplotlib's import included);
* ``exit``: from the last file to the end of the process (interpreter shutdown).

Usage: python benchmarks/whole.py [--repeats 3] [--json FILE]
Importable: ``from whole import measure_whole; measure_whole(repeats=3)`` returns a dict.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from startup import hinfnn_command, launch  # noqa: E402

#: The issue's targets for the whole process (figures included), seconds.
TARGET_WARM_S = 3.0
TARGET_COLD_S = 6.0
PARTS = ("to_first_step", "simulation", "files", "figures", "exit")


def _parts(r: dict) -> dict:
    """The whole-process breakdown of one launch (seconds); see the module docstring."""
    done = r["done"] or {}
    offset = r["first_step"] - r["first_since_main"]  # launch -> the trace's zero
    sim_end = done.get("simulated", r["first_since_main"])
    files_end = done.get("files_written", sim_end)
    fig_end = done.get("figures_written", files_end)
    return {"to_first_step": r["first_step"], "simulation": sim_end - r["first_since_main"],
            "files": files_end - sim_end, "figures": fig_end - files_end,
            "exit": r["total"] - (offset + fig_end)}


def measure_whole(repeats: int = 3, cmd: list[str] | None = None, env: dict | None = None,
                  scenario_args: tuple[str, ...] = ()) -> dict:
    """Launch ``hinfnn run paper`` cold once, warm ``repeats`` times, and warm with
    ``--no-figures`` ``repeats`` times, all with one fresh cache. Returns ``cold``, ``warm``,
    ``no_figures`` (every launch: ``wall``, ``cpu``, ``parts``, the startup phases), their
    medians (``cold_s``, ``warm_s``, ``warm_cpu_s``, ``no_figures_s``, ...), ``breakdown``
    (median part by part, cold and warm), the targets and whether they are met."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    cmd = list(cmd or hinfnn_command())
    with tempfile.TemporaryDirectory(prefix="hinfnn-whole-") as tmp:
        env = dict(env if env is not None else os.environ, HINFNN_CACHE_DIR=str(Path(tmp) / "cache"),
                   HINFNN_TRACE_STARTUP="1")
        env.setdefault("JAX_PLATFORMS", "cpu")
        args = ["run", "paper", *scenario_args, "--out", str(Path(tmp) / "out"), "--force", "--quiet"]

        def one(extra=()):
            r = launch(cmd + args + list(extra), env)
            r["parts"] = _parts(r)
            return r

        cold = one()
        warm, bare = [], []
        for _ in range(repeats):  # interleaved: a change in the machine's load hits both alike
            warm.append(one())
            bare.append(one(["--no-figures"]))

    def med(rows, key):
        return statistics.median(r[key] for r in rows)

    breakdown = {"cold": cold["parts"], "warm": {p: statistics.median(r["parts"][p] for r in warm) for p in PARTS},
                 "no_figures": {p: statistics.median(r["parts"][p] for r in bare) for p in PARTS}}
    warm_phases = {p: statistics.median(r["phases"][p] for r in warm) for p in warm[0]["phases"]}
    return dict(command=cmd + args[:2 + len(scenario_args)], repeats=repeats,
                cold_s=cold["total"], cold_cpu_s=cold["cpu_total"],
                warm_s=med(warm, "total"), warm_cpu_s=med(warm, "cpu_total"),
                warm_all_s=[r["total"] for r in warm],
                no_figures_s=med(bare, "total"), no_figures_cpu_s=med(bare, "cpu_total"),
                breakdown=breakdown, startup_phases={"cold": cold["phases"], "warm": warm_phases},
                cold=cold, warm=warm, no_figures=bare,
                target_warm_s=TARGET_WARM_S, target_cold_s=TARGET_COLD_S,
                warm_within_target=med(warm, "total") <= TARGET_WARM_S,
                cold_within_target=cold["total"] <= TARGET_COLD_S)


def format_table(res: dict) -> str:
    """The result of :func:`measure_whole` as a small text table."""
    labels = {"to_first_step": "launch -> first simulated step", "simulation": "simulation (other 49 chunks)",
              "files": "metrics, .json, .npz, .toml", "figures": "figures (6 PNG)", "exit": "interpreter exit"}
    b = res["breakdown"]
    lines = [f"{'hinfnn run paper, whole process':<34}{'cold':>9}{'warm':>9}{'no figs':>9}",
             f"{'':<34}{'':>9}{'(median)':>9}{'(median)':>9}", "-" * 61]
    for p in PARTS:
        lines.append(f"{labels[p]:<34}{b['cold'][p]:>8.2f}s{b['warm'][p]:>8.2f}s{b['no_figures'][p]:>8.2f}s")
    ph = res["startup_phases"]
    for p in ("import", "setup", "trace", "lower", "compile"):
        lines.append(f"{'  of the first: ' + p:<34}{ph['cold'][p]:>8.2f}s{ph['warm'][p]:>8.2f}s")
    lines.append("-" * 61)
    lines.append(f"{'whole process, wall':<34}{res['cold_s']:>8.2f}s{res['warm_s']:>8.2f}s{res['no_figures_s']:>8.2f}s")
    lines.append(f"{'whole process, CPU (user + sys)':<34}{res['cold_cpu_s']:>8.2f}s{res['warm_cpu_s']:>8.2f}s"
                 f"{res['no_figures_cpu_s']:>8.2f}s")
    lines.append("")
    lines.append("warm runs: " + ", ".join(f"{x:.2f} s" for x in res["warm_all_s"]))
    lines.append(f"warm <= {res['target_warm_s']:g} s: {'yes' if res['warm_within_target'] else 'NO'}; "
                 f"cold <= {res['target_cold_s']:g} s: {'yes' if res['cold_within_target'] else 'NO'}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3, help="warm runs with and without figures (default 3)")
    ap.add_argument("--json", type=Path, default=None, help="also write the numbers to this JSON file")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error("--repeats must be at least 1")
    res = measure_whole(a.repeats)
    print(f"{' '.join(res['command'])}  (cold, then {a.repeats} warm with and without figures; fresh cache)\n")
    print(format_table(res))
    if a.json:
        a.json.write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
