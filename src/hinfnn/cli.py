"""The ``hinfnn`` command: argument parsing and printing only; the work is in the library.

Exit codes: 0 success; 2 user error (bad scenario, bad override, infeasible design, bad or busy
output folder, not enough memory, unreadable result) with a one-line message; 1 anything else
(including a run that diverged); 130 interrupted (Ctrl-C, SIGINT); 143 terminated (SIGTERM).
``--debug`` shows tracebacks. Python warnings are printed as one line ``hinfnn: warning: ...``.

Nothing heavy is imported at module level: :func:`main` installs the signal handlers first, so
Ctrl-C or SIGTERM while JAX loads ends the command like at any other moment.
"""

from __future__ import annotations

from . import _signals  # noqa: I001  (first: nothing else to import before the handlers)

import argparse
import functools
import os
import sys
import time
from pathlib import Path

EXAMPLES_RUN = """examples:
  hinfnn run paper                   # writes results/runs/paper-<UTC time>/
  hinfnn run paper --set controller.kind=hinf --set plant.contact.damping=200
  hinfnn run paper --set 'controller.kind=["fl", "hinf", "hinf_nn"]' --out results/three
  hinfnn run my_scenario.toml --set simulation.t_final=2 --out results/mine --force
  hinfnn run paper --set simulation.t_final=1000 --fields metrics   # long: store only what the metrics need
  hinfnn run paper --no-figures --out results/fast   # scripted use: no PNG (`hinfnn plot DIR` draws them later)

--force replaces OUT only if hinfnn wrote it (it holds .hinfnn-result and nothing else);
without it, a non-empty OUT is kept and the result goes to OUT-2, OUT-3, ...
"""
EXAMPLES_REPRODUCE = """examples:
  hinfnn reproduce                       # writes results/paper/ (report.md, figures, metrics.json)
  hinfnn reproduce --out /tmp/study --force
  hinfnn reproduce --set simulation.t_final=2   # a quick look (claims are judged on whatever ran)
"""
EXAMPLES_GALLERY = """examples:
  hinfnn gallery                         # results/gallery/report.md: planar3-drum, ur5-table, ur5-sphere
  hinfnn gallery --only ur5-table --out /tmp/table
  hinfnn gallery --set simulation.t_final=2   # a quick look (the checks are judged on what ran)
"""
EXAMPLES_CACHE = """examples:
  hinfnn cache                     where the compilation cache is, its number of files and size
  hinfnn cache --clear             empty it (the next run compiles again, 4-7 s)
  du -sh "$(hinfnn cache --path)"  the folder alone, for scripts (prints nothing when it is off)

The folder is $HINFNN_CACHE_DIR, else $XDG_CACHE_HOME/hinfnn/jax, else ~/.cache/hinfnn/jax;
HINFNN_CACHE_DIR=off disables the cache. Deleting the folder at any time is safe.
"""
EXAMPLES_PLOT = """examples:
  hinfnn plot results/runs/paper-20261129T170102Z            redraw every figure in place
  hinfnn plot results/three --figures tau,lambda --zoom 1:1.1,9:9.1
  hinfnn plot results/paper --out /tmp/figs                  the study's Figs. 3-9 elsewhere
"""
EXAMPLES_EXPORT = """examples:
  hinfnn export results/three --csv                 results/three/trajectory.csv (every run)
  hinfnn export results/three --parquet --run hinf  results/three/trajectory-hinf.parquet
  hinfnn export results/three --csv --out - | head  to standard output

Columns: run, t [s], then one per component with its unit: tau_1 [N·m], tau_2 [N·m], lam [λ units] ...
In Python: hinfnn.load("results/three").to_pandas() (the same table).
"""
EXAMPLES_SWEEP = """examples:
  hinfnn sweep paper-uncertainty                       # 1,000 draws x 3 controllers into results/paper-uncertainty/
  hinfnn sweep paper-uncertainty --samples 8 --set simulation.t_final=0.5   # a quick trial
  hinfnn sweep paper-map --backend ray                 # batches as Ray tasks on a local Ray instance
  hinfnn sweep my_sweep.toml --backend ray --address auto   # on the Ray cluster this machine belongs to
  hinfnn sweep paper-uncertainty --out results/pu --resume  # continue an interrupted sweep
  hinfnn sweep --list                                  # the shipped specs

The table is OUT/results.parquet (hinfnn.load_sweep(OUT) gives a pandas DataFrame); OUT/report.md
states the fractions that stayed bounded and held contact; see docs/sweeps.md for the spec format.
"""
EXAMPLES_MAIN = """examples:
  hinfnn reproduce                 the paper's Sec. VI study into results/paper/
  hinfnn gallery                   the shipped arms-and-surfaces scenarios into results/gallery/
  hinfnn run paper --set controller.kind=hinf --set plant.contact.damping=200
  hinfnn keys                      every scenario key, its meaning and allowed values
  hinfnn show results/paper        the metrics and designed controllers of a saved result
  hinfnn plot DIR / export DIR     redraw the figures / write the trajectories as CSV or Parquet
  hinfnn sweep paper-uncertainty   a robustness sweep: 1,000 seeded draws of the true plant, 3 controllers
  hinfnn cache                     the compilation cache that makes later starts fast

exit codes:
  0    ok
  1    a run diverged (its metrics up to then are kept, marked partial), or another failure
  2    bad input: scenario, override, infeasible gains, output folder, not enough memory,
       unreadable result (one line naming the key or file)
  130  interrupted (Ctrl-C / SIGINT); nothing half-written is left behind
  143  terminated (SIGTERM); nothing half-written is left behind
"""


@functools.cache
def _parser() -> argparse.ArgumentParser:
    """The command line's parser, built once per process: it holds only constants (parsing does
    not change it; ``--set``'s list default is copied, not appended to), and building its 13
    subcommands takes about 5 ms, which every ``main()`` called from Python (a test, a notebook)
    paid again."""
    from . import __version__

    fmt = argparse.RawDescriptionHelpFormatter
    p = argparse.ArgumentParser(
        prog="hinfnn", formatter_class=fmt, epilog=EXAMPLES_MAIN,
        description="Robust position/force learning control of constrained manipulators "
                    "(Hwang & Hu: nonlinear H-infinity control with online neural networks).")
    p.add_argument("--version", action="version", version=f"hinfnn {__version__}")
    p.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    def common(sp):
        sp.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scenario value (repeatable); VALUE is read as TOML, bare words "
                             "as strings; see `hinfnn keys`")
        sp.add_argument("--force", action="store_true",
                        help="replace a non-empty output folder (default: write to OUT-2, OUT-3, ...)")
        sp.add_argument("--quiet", action="store_true", help="no progress or tables, only errors")
        sp.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show full tracebacks on errors")

    r = sub.add_parser(
        "run", formatter_class=fmt, epilog=EXAMPLES_RUN,
        help="simulate one scenario (one run per listed controller)",
        description="Simulate SCENARIO (a shipped name such as 'paper', or a .toml file) and write "
                    "OUT/metrics.json, OUT/trajectory.npz, OUT/scenario.toml and figures. Several "
                    "controllers (controller.kind = [...]) give one run each.")
    r.add_argument("scenario", help="shipped scenario name (see `hinfnn scenarios`) or path to a .toml file")
    r.add_argument("--out", default=None, metavar="DIR",
                   help="output folder (default: results/runs/<scenario name>-<UTC time>)")
    r.add_argument("--fields", default="all", metavar="WHAT",
                   help="what the runs store: all (default), metrics (only what the metrics need: less memory "
                        "for long runs), or field names separated by commas")
    r.add_argument("--no-figures", dest="figures", action="store_false",
                   help="write no figures (2.5-3 s less); `hinfnn plot DIR` draws them later from the saved result")
    common(r)

    rp = sub.add_parser(
        "reproduce", formatter_class=fmt, epilog=EXAMPLES_REPRODUCE,
        help="reproduce the paper's Sec. VI study: figures, metrics, claims, report",
        description="Run FL-like, H-infinity-only and adaptive H-infinity NN (both F_f centre presets) "
                    "on the paper scenario, with the paper's undamped contact and with a damped one, "
                    "then (unless --paper-only) the paper's laws against the stabilised ones (scenario "
                    "paper-stable) at three contact stiffnesses, continuous and at 1 kHz; write "
                    "OUT/report.md, fig3..fig9 and beyond_*.png, metrics.json, trajectory.npz, beyond.npz, "
                    "scenario.toml.")
    rp.add_argument("--out", default=None, metavar="DIR", help="output folder (default: results/paper)")
    rp.add_argument("--scenario", default="paper", help="base scenario (default: paper)")
    rp.add_argument("--paper-only", action="store_true",
                    help="only the paper's Sec. VI study, without the Beyond-the-paper comparison (24 more runs)")
    common(rp)

    d = sub.add_parser(
        "design", formatter_class=fmt,
        help="print the designed controller: Riccati solution, gains, v_p gains, Theorem 1's bounds, contact mode",
        description="Design the scenario's controller(s) from the nominal model, as a run would, and print the "
                    "design: the resolved gains (beta_lam too), P_p of the Riccati-like equation with its residual "
                    "and closed-loop eigenvalues, v_p's gains, Theorem 1's bounds with their margins, the networks, "
                    "the force-rate term's design, and the linearised contact mode (frequency, damping ratio) at the "
                    "scenario's contact stiffness with and without the force-rate term.",
        epilog="examples:\n  hinfnn design paper\n  hinfnn design paper-stable --set controller.kind=hinf\n"
               "  hinfnn design paper --json > design.json\n")
    d.add_argument("scenario", help="shipped scenario name or path to a .toml file")
    d.add_argument("--json", action="store_true", help="print the design as JSON")
    d.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario value (repeatable)")
    d.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)

    cp = sub.add_parser(
        "compare", formatter_class=fmt,
        help="run a scenario with one key at several values side by side (e.g. the built-in plant vs MuJoCo)",
        description="Run SCENARIO once per value of one key (given as --set KEY=V1,V2,...), with the same "
                    "controller(s), and write metrics.json (metrics and ratios to the first value also in "
                    "compare.md), trajectory.npz, scenario.toml and figures overlaying lambda(t), u1(t), tau(t) "
                    "and the contact of every run.",
        epilog="examples:\n  hinfnn compare paper --set plant.engine=hinfnn,mujoco --set plant.contact.damping=200 "
               "--set controller.kind=hinf\n  hinfnn compare paper --set plant.contact.stiffness=1e4,1e5,1e6\n")
    cp.add_argument("scenario", help="shipped scenario name or path to a .toml file")
    cp.add_argument("--out", type=Path, default=None, help="output folder (default: results/compares/<name>-<UTC time>)")
    common(cp)
    ga = sub.add_parser(
        "gallery", formatter_class=fmt, epilog=EXAMPLES_GALLERY,
        help="run the shipped arms-and-surfaces scenarios into one report",
        description="Run planar3-drum, ur5-table and ur5-sphere (each with the controllers it lists) and write "
                    "OUT/report.md with their setups, designs, metrics, the issue's checks and figures, and one "
                    "folder per scenario as `hinfnn run` writes it. `hinfnn reproduce` is the paper's study.")
    ga.add_argument("--out", type=Path, default=None,
                    help="output folder (default: results/gallery; if it holds a result, results/gallery-2 ...)")
    ga.add_argument("--only", action="append", default=[], metavar="NAME",
                    help="run only this gallery scenario (repeatable)")
    common(ga)

    k = sub.add_parser("keys", formatter_class=fmt, help="list every scenario key with its meaning and range",
                       description="Every key a scenario file or --set accepts.",
                       epilog="example:\n  hinfnn keys | grep contact\n")
    k.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    s = sub.add_parser("scenarios", formatter_class=fmt, help="list the shipped scenarios",
                       description="The scenarios shipped with hinfnn (usable by name).",
                       epilog="example:\n  hinfnn scenarios\n")
    s.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    sh = sub.add_parser("show", formatter_class=fmt, help="print the metrics and designed controllers of a saved result",
                        description="Read DIR/metrics.json (nothing else is needed) of a result written by "
                                    "`hinfnn run` or `reproduce` and print its metrics table, why any run stopped "
                                    "early, and the designed controllers (gains with the resolved beta_lam, "
                                    "Theorem 1's bounds and margins, P_p and the Riccati residual, v_p's gains, "
                                    "the networks).",
                        epilog="examples:\n  hinfnn show results/paper\n  hinfnn show results/three --no-design\n")
    sh.add_argument("folder", type=Path, metavar="DIR")
    sh.add_argument("--no-design", action="store_true", help="only the metrics table")
    sh.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    pl = sub.add_parser("plot", formatter_class=fmt, epilog=EXAMPLES_PLOT,
                        help="redraw the figures of a saved result from its trajectory.npz",
                        description="Draw the figures of a result folder again from DIR/trajectory.npz: a run's "
                                    "u1, lambda, tau, J, contact and weights figures, or the paper study's "
                                    "Figs. 3-9 for both contacts. They replace the folder's figures unless --out "
                                    "is given.")
    pl.add_argument("folder", type=Path, metavar="DIR")
    pl.add_argument("--figures", default=None, metavar="NAMES",
                    help="only these figures, separated by commas (run: u1, lambda, tau, J, contact, weights; "
                         "study: fig3_u1_fl ... fig9_J)")
    pl.add_argument("--zoom", default=None, metavar="A0:A1,B0:B1",
                    help="the time windows (s) of the two zoom panels (default: 6-7 %% and 96-98 %% of the run)")
    pl.add_argument("--out", default=None, metavar="FOLDER", help="write the figures there instead of into DIR")
    pl.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    ex = sub.add_parser("export", formatter_class=fmt, epilog=EXAMPLES_EXPORT,
                        help="write the trajectories of a saved result as a CSV or Parquet table",
                        description="Write DIR/trajectory.npz as a table: one row per stored sample, a column "
                                    "'run', then one column per field component with its unit in the name. "
                                    "A run that stopped early is exported up to t_fail. CSV numbers are exact "
                                    "(they read back to the same float64).")
    ex.add_argument("folder", type=Path, metavar="DIR")
    ex.add_argument("--csv", action="store_true", help="write DIR/trajectory[-RUN].csv")
    ex.add_argument("--parquet", action="store_true", help="write DIR/trajectory[-RUN].parquet (needs pyarrow)")
    ex.add_argument("--run", default=None, metavar="NAME", help="only this run (default: every run, stacked)")
    ex.add_argument("--out", default=None, metavar="FILE",
                    help="write here instead (a file, an existing folder, or - for standard output with --csv)")
    ex.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    sw = sub.add_parser(
        "sweep", formatter_class=fmt, epilog=EXAMPLES_SWEEP,
        help="robustness sweep: vary scenario keys (grids, seeded draws), run every controller, map where it holds",
        description="Run the sweep SPEC (a shipped name such as 'paper-uncertainty', or a .toml file): the base "
                    "scenario with the varied keys drawn or gridded, every listed controller on every draw, in "
                    "vmap batches grouped by compiled program. Writes OUT/results.parquet (one row per run: "
                    "varied values, controller, status, every metric), written in parts as batches finish, and "
                    "OUT/report.md with the robustness maps and distributions. A killed sweep loses at most the "
                    "batches in flight: --resume continues it.")
    sw.add_argument("spec", nargs="?", help="shipped sweep spec name (see --list) or path to a .toml file")
    sw.add_argument("--out", type=Path, default=None, help="output folder (default: results/<spec name>)")
    sw.add_argument("--backend", choices=("local", "ray"), default="local",
                    help="local: batches one after the other in this process (default); ray: batches as Ray "
                         "tasks, one per CPU (pip install 'hinfnn[ray]')")
    sw.add_argument("--address", default=None, metavar="ADDR",
                    help="with --backend ray: the cluster to join, 'auto' (the cluster this machine belongs to) or "
                         "'ray://HEAD:10001' (default: start a local Ray instance)")
    sw.add_argument("--resume", action="store_true",
                    help="continue the sweep in OUT (same spec and options): finished batches are kept")
    sw.add_argument("--samples", type=int, default=None, metavar="N",
                    help="number of random draws instead of the spec's (quick trials)")
    sw.add_argument("--batch-size", type=int, default=None, metavar="B",
                    help="largest vmap batch (default 256, fewer if memory is short)")
    sw.add_argument("--list", action="store_true", help="list the shipped sweep specs and exit")
    common(sw)
    ca = sub.add_parser(
        "cache", formatter_class=fmt, epilog=EXAMPLES_CACHE,
        help="show or clear the compilation cache (compiled simulator programs reused across runs)",
        description="The persistent compilation cache: XLA programs compiled by earlier hinfnn "
                    "processes, so that a new process skips most of the 4-7 s of compilation. "
                    "Without options: its folder, number of files and size.")
    what = ca.add_mutually_exclusive_group()
    what.add_argument("--clear", action="store_true", help="delete every cache entry and say how much was removed")
    what.add_argument("--path", action="store_true",
                      help="print only the cache folder (nothing when the cache is off), for scripts")
    ca.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    return p


# --- printing -----------------------------------------------------------------------------------


class Progress:
    """Progress on stderr with an ETA, never with ``--quiet``. On a terminal: a tqdm bar (steps
    done, rate, time left) once a run has lasted 3 s; otherwise (a log file, a pipe) one line
    every 10 s, ``LABEL: 12.0 % (10 s, about 73 s left)``. ``names``: the runs of the chunk
    being simulated."""

    def __init__(self, quiet: bool, label: str, stream=None):
        self.quiet = quiet
        self.label = label
        self.stream = stream or sys.stderr
        self.bar = None
        self.t0 = time.perf_counter()
        self.last = 0.0
        try:
            self.tty = self.stream.isatty()
        except (AttributeError, ValueError):
            self.tty = False

    def __call__(self, done: int, total: int, names=None):
        _signals.check()  # between chunks: a signal swallowed inside a callback ends the command here
        if self.quiet:
            return
        if self.tty:
            self._bar(done, total, names)
            return
        now = time.perf_counter()
        elapsed = now - self.t0
        if elapsed < 3.0 or (now - self.last < 10.0 and done < total):
            return
        self.last = now
        frac = done / max(total, 1)
        left = elapsed * (1 - frac) / frac if frac > 0 else float("nan")
        eta = f", about {_duration(left)} left" if frac > 0 and done < total else ""
        msg = f"{self.label}: {100 * frac:5.1f} %  ({_duration(elapsed)}{eta})"
        if names:
            msg += f"  [{', '.join(names)}]"
        print(msg, file=self.stream, flush=True)

    def _bar(self, done, total, names):
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=self.label, unit="step", unit_scale=True, delay=3.0,
                            file=self.stream, leave=False, dynamic_ncols=True, mininterval=0.5)
        if names:
            self.bar.set_postfix_str(", ".join(names)[:40], refresh=False)
        self.bar.update(done - self.bar.n)

    def done(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def stage(self, label: str):
        """A new part of the work with its own steps (its own bar, rate and time left)."""
        self.done()
        self.label = label
        self.t0 = time.perf_counter()
        self.last = 0.0


def _duration(seconds: float) -> str:
    from .resources import duration

    return duration(seconds)


# --- commands -----------------------------------------------------------------------------------


def _fields(text: str):
    """``--fields``: all -> None, metrics -> "metrics", else the names."""
    text = text.strip()
    if text in ("all", ""):
        return None
    if text == "metrics":
        return "metrics"
    return [f.strip() for f in text.split(",") if f.strip()]


def cmd_run(args) -> int:
    from .runner import run_scenario
    from .scenario import Scenario

    trace = getattr(args, "startup_trace", None)
    if trace:
        trace.mark("imports_done")
    sc = Scenario.load(args.scenario, args.overrides)
    if trace:
        trace.mark("scenario_loaded")
    fields = _fields(args.fields)
    if fields is not None:
        from .errors import ConfigError
        from .sim.recorder import select

        try:
            select(fields)  # unknown names: before anything runs
        except ConfigError as err:
            raise ConfigError(str(err).removeprefix("fields: "), key="--fields") from None
    kinds = sc.kinds
    progress = Progress(args.quiet, f"simulating {', '.join(kinds)}")
    log = (lambda m: print(m, file=sys.stderr))  # even with --quiet: where the result goes matters
    res = run_scenario(sc, out=args.out, force=args.force, fields=fields,
                       progress=trace.wrap(progress) if trace else progress, command=command_line(args), log=log,
                       figures=getattr(args, "figures", True))
    progress.done()
    if trace:
        trace.done()
    if res.note:
        log(f"hinfnn: {res.note}")
    doc, target = res.doc, res.target
    if not args.quiet:
        from .report.markdown import metrics_table

        print(metrics_table(doc, markdown=False))
        pngs = ", *.png" if getattr(args, "figures", True) else ""
        print(f"results: {target}/ (metrics.json, trajectory.npz, scenario.toml{pngs})")
    failed = [r for r in doc["runs"] if r["status"] != "ok"]
    for r in failed:
        print(f"hinfnn: run {r['name']!r} stopped at t = {r['t_fail']:.6g} s ({r['reason']}); "
              f"its metrics up to then are in {target}/metrics.json (marked partial)", file=sys.stderr)
    return 1 if failed else 0


def cmd_reproduce(args) -> int:
    from .scenario import Scenario
    from .study import reproduce

    base = Scenario.load(args.scenario, args.overrides)
    progress = Progress(args.quiet, "reproducing the paper study")
    t0 = time.perf_counter()
    target = reproduce(args.out, base=base, force=args.force, progress=progress,
                       log=lambda m: print(m, file=sys.stderr), command=command_line(args),
                       beyond=not args.paper_only)
    progress.done()
    if not args.quiet:
        from .io import load_metrics
        from .report.markdown import metrics_table

        print(metrics_table(load_metrics(target), markdown=False))
        print(f"report: {target}/report.md  ({time.perf_counter() - t0:.0f} s)")
    return 0


def cmd_design(args) -> int:
    from .analysis import design_report, format_design_report
    from .io import dumps_json
    from .scenario import Scenario

    report = design_report(Scenario.load(args.scenario, args.overrides))
    if args.json:
        print(dumps_json(report), end="")
    else:
        print(format_design_report(report))
    return 0


def cmd_compare(args) -> int:
    from .compare import compare, split_values
    from .errors import ConfigError
    from .report.markdown import metrics_table
    from .scenario import Scenario, parse_override

    fixed, varied = [], []
    for item in args.overrides:
        key, sep, raw = item.partition("=")
        parts = split_values(raw) if sep else []
        if len(parts) > 1:
            varied.append((key.strip(), [parse_override(f"{key}={p}")[1] for p in parts]))
        else:
            fixed.append(item)
    if len(varied) != 1:
        raise ConfigError(f"give exactly one key with several values (--set KEY=V1,V2), got {len(varied)}"
                          + (f": {', '.join(k for k, _ in varied)}" if varied else ""), key="--set")
    key, values = varied[0]
    sc = Scenario.load(args.scenario, fixed)
    for v in values:  # every value is checked before anything runs
        sc.with_overrides([(key, v)])
    progress = Progress(args.quiet, f"comparing {key}")
    target, doc = compare(sc, key, values, args.out, force=args.force,
                          progress=progress, log=lambda m: print(m, file=sys.stderr), command=command_line(args))
    progress.done()
    if not args.quiet:
        print(metrics_table(doc, markdown=False))
        print(f"results: {target}/ (compare.md, metrics.json, trajectory.npz, scenario.toml, *.png)")
    return 1 if any(r["status"] != "ok" for r in doc["runs"]) else 0


def cmd_gallery(args) -> int:
    from .gallery import gallery_scenarios, run_gallery

    gallery_scenarios(args.overrides, args.only)  # every check before anything runs
    progress = Progress(args.quiet, "gallery")
    t0 = time.perf_counter()
    target = run_gallery(args.out, overrides=args.overrides, only=args.only, force=args.force, progress=progress,
                         log=(lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr)),
                         command=command_line(args))
    progress.done()
    if not args.quiet:
        import json

        from .report.markdown import metrics_table

        for sub in sorted(p for p in target.iterdir() if p.is_dir()):
            print(f"{sub.name}:")
            print(metrics_table(json.loads((sub / "metrics.json").read_text()), markdown=False))
        print(f"report: {target}/report.md  ({time.perf_counter() - t0:.0f} s)")
    return 0


def cmd_keys(args) -> int:
    from .scenario import keys

    for key, doc, allowed, default in keys():
        print(f"{key:<40} {doc}  [{allowed}; default {default}]")
    return 0


def cmd_scenarios(args) -> int:
    from .scenario import Scenario, scenario_names

    for name in scenario_names():
        sc = Scenario.load(name, check=False)
        print(f"{name:<20} {sc.description}")
    return 0


def cmd_show(args) -> int:
    from .io import load_metrics
    from .report.markdown import design_text, metrics_table

    doc = load_metrics(args.folder)
    print(metrics_table(doc, markdown=False))
    if not args.no_design:
        print()
        print(design_text(doc))
    return 0


def _zoom(text: str | None):
    """``--zoom A0:A1,B0:B1`` -> [(A0, A1), (B0, B1)]."""
    if text is None:
        return None
    from .errors import ConfigError

    try:
        windows = [tuple(float(x) for x in part.split(":")) for part in text.split(",")]
    except ValueError:
        windows = []
    if len(windows) != 2 or any(len(w) != 2 or not w[0] < w[1] for w in windows):
        raise ConfigError(f"must be two time windows START:END,START:END with START < END, got {text!r}",
                          key="--zoom")
    return windows


def cmd_plot(args) -> int:
    from .report.replot import replot

    only = [f.strip() for f in args.figures.split(",") if f.strip()] if args.figures else None
    written = replot(args.folder, only=only, out=args.out, zoom_windows=_zoom(args.zoom))
    for path in written:
        print(path)
    if not written:
        print(f"hinfnn: no figure drawn: the runs of {args.folder} lack the fields they need", file=sys.stderr)
        return 1
    return 0


def cmd_export(args) -> int:
    from .errors import ConfigError
    from .export import csv_text, export
    from .io import load

    formats = [f for f, on in (("csv", args.csv), ("parquet", args.parquet)) if on]
    if not formats:
        raise ConfigError("give the format: --csv or --parquet (or both)", key="export")
    if args.out == "-":
        if formats != ["csv"]:
            raise ConfigError("standard output (-) takes --csv only", key="--out")
        sys.stdout.write(csv_text(load(args.folder), args.run))
        return 0
    if args.out is not None and len(formats) > 1 and not Path(args.out).is_dir():
        raise ConfigError("with both --csv and --parquet, --out must be a folder", key="--out")
    for fmt in formats:
        print(export(args.folder, fmt, run=args.run, out=args.out))
    return 0


def _size(n: int) -> str:
    """Bytes for people: ``512 B``, ``473.5 kB``, ``1.2 MB``."""
    if n < 1000:
        return f"{n} B"
    for unit in ("kB", "MB", "GB"):
        n /= 1000
        if n < 1000 or unit == "GB":
            return f"{n:.1f} {unit}"


def cmd_cache(args) -> int:
    """Show (default), clear (``--clear``) or locate (``--path``) the compilation cache."""
    from . import _cache

    folder = _cache.cache_dir()
    if args.path:
        if folder is not None:
            print(folder)
        return 0
    if folder is None:
        print(f"compilation cache: off ({_cache.cache_disabled_reason()})"
              + ("; nothing to clear" if args.clear else ""))
        return 0
    if args.clear:
        n, _ = _cache.cache_size()
        removed = _cache.clear_cache()
        print(f"removed {n} files ({_size(removed)}) from {folder}")
        return 0
    n, size = _cache.cache_size()
    print(f"compilation cache: {folder}\nfiles: {n}\nsize:  {_size(size)}")
    return 0


COMMANDS = {"run": cmd_run, "reproduce": cmd_reproduce, "design": cmd_design, "compare": cmd_compare,
            "keys": cmd_keys, "scenarios": cmd_scenarios, "show": cmd_show, "plot": cmd_plot,
            "export": cmd_export, "cache": cmd_cache}


def cmd_sweep(args) -> int:
    """Run or resume a sweep; print the outcome per controller."""
    import shutil

    from .errors import ConfigError
    from .sweep import load_spec, spec_names

    if args.list:
        from .scenario.core import parse_toml
        from .sweep.spec import read_spec_source

        for name in spec_names():
            text, _, _ = read_spec_source(name)
            print(f"{name:<20} {parse_toml(text, name).get('description', '')}")
        return 0
    if args.spec is None:
        raise ConfigError("give a sweep spec: a shipped name (hinfnn sweep --list) or a .toml file", key="SPEC")
    if args.batch_size is not None and args.batch_size < 1:
        raise ConfigError(f"must be a whole number >= 1, got {args.batch_size}", key="--batch-size")
    if args.resume and args.force:
        raise ConfigError("--resume continues the sweep in OUT, --force replaces it: give one", key="--force")
    if args.address is not None and args.backend != "ray":
        raise ConfigError("--address is for --backend ray", key="--address")
    from .sweep import run_sweep
    from .sweep.store import is_sweep_folder

    spec = load_spec(args.spec, samples=args.samples, overrides=args.overrides)
    out = args.out or Path("results") / spec.name
    if str(out).strip() in ("", ".") or Path(os.path.abspath(out)) in (Path.cwd(), *Path.cwd().parents):
        raise ConfigError(f"{str(out)!r} is the current folder or one that contains it; give a new folder's name",
                          key="--out")
    target = out
    if out.exists() and not out.is_dir():
        raise ConfigError(f"output path {out} exists and is not a folder", key="--out")
    if not args.resume and out.exists() and any(p.name != ".lock" for p in out.iterdir()):
        if args.force:
            from .sweep.store import foreign_files

            foreign = foreign_files(out) if is_sweep_folder(out) else sorted(p.name for p in out.iterdir())
            if foreign:
                shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
                raise ConfigError(f"{out} holds files a sweep did not write ({shown}); --force replaces only a "
                                  "sweep's folder: choose another --out, or move those files away", key="--out")
            shutil.rmtree(out)
        else:
            i = 2
            while Path(f"{out}-{i}").exists():
                i += 1
            target = Path(f"{out}-{i}")
            hint = " or --resume to continue the sweep in it" if is_sweep_folder(out) else ""
            print(f"{out} is not empty; writing to {target} instead (use --force to replace it{hint})",
                  file=sys.stderr)
    bars: dict = {}
    tty = sys.stderr.isatty()
    state = {"t0": time.perf_counter(), "last": 0.0}

    def progress(phase, done, total):
        if args.quiet:
            return
        if tty:
            if phase not in bars:
                from tqdm import tqdm

                for b in bars.values():
                    b.close()
                unit = "draw" if phase == "check" else "run"
                desc = "checking draws" if phase == "check" else "simulating"
                bars[phase] = tqdm(total=total, initial=done, desc=desc, unit=unit, file=sys.stderr, leave=False,
                                   dynamic_ncols=True, mininterval=0.5, smoothing=0.1,
                                   bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total} {unit}s "
                                              "[{elapsed}<{remaining}, {rate_fmt}]")
                state["t0"] = time.perf_counter()
            bar = bars[phase]
            bar.update(done - bar.n)
        elif phase == "run" and total and (time.perf_counter() - state["last"] > 30 or done >= total):
            if state.get("phase") != phase:  # a resumed sweep starts with the runs done before
                state.update(phase=phase, t0=time.perf_counter(), base=done)
            state["last"] = time.perf_counter()
            el = time.perf_counter() - state["t0"]
            rate = (done - state["base"]) / el if el > 0 else 0.0
            eta = f", ETA {(total - done) / rate / 60:.1f} min" if rate > 0 and done < total else ""
            print(f"hinfnn sweep: {done:.0f}/{total} runs, {el:.0f} s, {rate:.2f} runs/s{eta}", file=sys.stderr,
                  flush=True)

    def log(message):
        if not args.quiet:
            print(f"hinfnn sweep: {message}", file=sys.stderr, flush=True)

    try:
        res = run_sweep(spec, target, backend=args.backend, address=args.address, resume=args.resume,
                        max_batch=args.batch_size, progress=progress, log=log, command=command_line(args))
    except BaseException as err:
        for b in bars.values():
            b.close()
        if isinstance(err, (KeyboardInterrupt, _signals.Terminated)):
            import json
            import shlex

            try:
                done = len(json.loads((target / "manifest.json").read_text())["done"])
                saved = f"{done} finished batch(es) are saved in {target}/parts"
            except (OSError, ValueError, KeyError):
                saved = f"finished batches are saved in {target}/parts"
            again = ["sweep", args.spec, "--out", str(target), "--resume", *[a for o in args.overrides for a in ("--set", o)]]
            again += ["--samples", str(args.samples)] if args.samples else []
            again += ["--backend", args.backend] if args.backend != "local" else []
            # main() prints it and leaves as for every interrupt (exit 130 / 143)
            err.hinfnn_note = f"{saved}; continue with: hinfnn {' '.join(shlex.quote(a) for a in again)}"
        raise
    for b in bars.values():
        b.close()
    if not args.quiet:
        from .controllers import KINDS

        print(f"{'controller':<16} {'runs':>6} {'invalid':>8} {'simulated':>10} {'bounded':>9} {'held contact':>13}")
        for kind, c in res.counts.items():
            n = c["simulated"]
            pct = (lambda k: f"{100 * k / n:.1f} %") if n else (lambda k: "-")
            print(f"{KINDS[kind].label if kind in KINDS else kind:<16} {c['runs']:>6} {c['invalid']:>8} {n:>10} "
                  f"{pct(c['bounded']):>9} {pct(c['held_contact']):>13}")
        if res.simulated_now:
            print(f"{res.simulated_now} runs simulated in {res.run_wall_s:.1f} s ({res.runs_per_s:.2f} runs/s, "
                  f"{res.backend} backend, compilation included)"
                  + (f"; {res.already_done} were done before" if res.already_done else ""))
        print(f"results: {target}/ (results.parquet, report.md, *.png)")
    return 0


COMMANDS["sweep"] = cmd_sweep
COMMANDS["gallery"] = cmd_gallery


def _interrupted_exit(code: int, argv) -> int:
    """An interrupt that arrives while XLA compiles leaves its compiler threads running, and
    interpreter finalisation then crashes (SIGSEGV). The output is already cleaned up: a program
    run (argv None) leaves at once; an in-process call returns the code."""
    if argv is None:
        import os

        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def command_line(args) -> str:
    """The command as the user typed it (for the files that record how they were made)."""
    import shlex

    return "hinfnn " + " ".join(shlex.quote(a) for a in getattr(args, "argv", []))


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    """``warnings.showwarning`` of the command: ``hinfnn: warning: TEXT`` on one line, without the
    source file and line a user cannot act on."""
    text = " ".join(str(message).split())
    text = text.removeprefix("hinfnn: ").removeprefix("warning: ")
    try:
        print(f"hinfnn: warning: {text}", file=file or sys.stderr)
    except (OSError, ValueError):
        pass


def main(argv=None) -> int:
    # First: Ctrl-C / SIGTERM from here on, JAX's import included, end the command cleanly.
    previous = _signals.install()
    import warnings

    saved_showwarning = warnings.showwarning
    warnings.showwarning = _one_line_warning
    if argv is None:  # a program: a signal held too long during an import ends it at once
        _signals.on_hard_exit = _hard_exit
        from . import _devices

        _devices.program_gc()
    box: dict = {}
    try:
        code = _main(argv, box)
    except KeyboardInterrupt as err:
        _signals.ignore()  # a second Ctrl-C while leaving changes nothing
        print(f"hinfnn: interrupted; {getattr(err, 'hinfnn_note', 'no output was written')}", file=sys.stderr)
        return _interrupted_exit(_signals.EXIT_INTERRUPTED, argv)
    except _signals.Terminated as err:
        _signals.ignore()
        print(f"hinfnn: terminated; {getattr(err, 'hinfnn_note', 'no output was written')}", file=sys.stderr)
        return _interrupted_exit(_signals.EXIT_TERMINATED, argv)
    finally:
        trace = getattr(box.get("args"), "startup_trace", None)
        if trace is not None:
            trace.close()
        warnings.showwarning = saved_showwarning
        _signals.on_hard_exit = None
        _signals.restore(previous)
    if argv is None and "jax" in sys.modules:  # a program that loaded JAX: skip the interpreter's teardown
        from . import _devices

        _devices.fast_exit(code if isinstance(code, int) else 1)
    return code


def _hard_exit(signum: int) -> None:
    import os
    import signal

    _signals.ignore()
    word = "interrupted" if signum == signal.SIGINT else "terminated"
    print(f"hinfnn: {word}; no output was written", file=sys.stderr)
    sys.stderr.flush()
    os._exit(_signals.EXIT_INTERRUPTED if signum == signal.SIGINT else _signals.EXIT_TERMINATED)


def _main(argv, box: dict) -> int:
    parser = _parser()
    args = box["args"] = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        if args.command not in ("keys", "scenarios", "show", "plot", "export"):
            from ._config import configure

            configure()
        if args.command == "run":
            from ._startup import StartupTrace

            args.startup_trace = StartupTrace.from_env()
        return COMMANDS[args.command](args)
    except (KeyboardInterrupt, _signals.Terminated):
        raise
    except BrokenPipeError:  # `hinfnn export DIR --csv --out - | head`: the reader has left
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # no second error when Python flushes stdout at exit
        return 1
    except BaseException as err:  # noqa: BLE001 - the CLI's last line of defence
        if isinstance(err, SystemExit):
            raise
        from .errors import ConfigError, DesignError, LoadError

        if getattr(args, "debug", False):
            raise
        if isinstance(err, (ConfigError, DesignError, LoadError)):
            kind = type(err).__name__
            text = "\\n".join(str(err).splitlines())
            print(f"hinfnn: {kind}: {text}", file=sys.stderr)
            return 2
        text = " ".join(str(err).split())
        print(f"hinfnn: error: {type(err).__name__}: {text} (run with --debug for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
