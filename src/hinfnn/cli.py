"""The ``hinfnn`` command: argument parsing and printing only; the work is in the library.

Exit codes: 0 success; 2 user error (bad scenario, bad override, infeasible design, unreadable
result) with a one-line message; 1 anything else (including a run that diverged); 130 when
interrupted. ``--debug`` shows tracebacks.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

EXAMPLES_RUN = """examples:
  hinfnn run paper
  hinfnn run paper --set controller.kind=hinf --set plant.contact.damping=200
  hinfnn run paper --set 'controller.kind=["fl", "hinf", "hinf_nn"]' --out results/three
  hinfnn run my_scenario.toml --set simulation.t_final=2 --force
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
EXAMPLES_MAIN = """examples:
  hinfnn reproduce                 the paper's Sec. VI study into results/paper/
  hinfnn gallery                   the shipped arms-and-surfaces scenarios into results/gallery/
  hinfnn run paper --set controller.kind=hinf --set plant.contact.damping=200
  hinfnn keys                      every scenario key, its meaning and allowed values
  hinfnn show results/paper        the metrics of a saved result
  hinfnn cache                     the compilation cache that makes later starts fast

Exit codes: 0 ok, 2 bad input (scenario, override, infeasible gains), 1 other failures, 130 interrupted.
"""


def _parser() -> argparse.ArgumentParser:
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
    r.add_argument("--out", type=Path, default=None, help="output folder (default: results/<scenario name>)")
    common(r)

    rp = sub.add_parser(
        "reproduce", formatter_class=fmt, epilog=EXAMPLES_REPRODUCE,
        help="reproduce the paper's Sec. VI study: figures, metrics, claims, report",
        description="Run FL-like, H-infinity-only and adaptive H-infinity NN (both F_f centre presets) "
                    "on the paper scenario, with the paper's undamped contact and with a damped one, "
                    "and write OUT/report.md, fig3..fig9 PNGs, metrics.json, trajectory.npz, scenario.toml.")
    rp.add_argument("--out", type=Path, default=Path("results/paper"), help="output folder (default: results/paper)")
    rp.add_argument("--scenario", default="paper", help="base scenario (default: paper)")
    common(rp)

    ga = sub.add_parser(
        "gallery", formatter_class=fmt, epilog=EXAMPLES_GALLERY,
        help="run the shipped arms-and-surfaces scenarios into one report",
        description="Run planar3-drum, ur5-table and ur5-sphere (each with the controllers it lists) and write "
                    "OUT/report.md with their setups, designs, metrics, the issue's checks and figures, and one "
                    "folder per scenario as `hinfnn run` writes it. `hinfnn reproduce` is the paper's study.")
    ga.add_argument("--out", type=Path, default=Path("results/gallery"),
                    help="output folder (default: results/gallery)")
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
    sh = sub.add_parser("show", formatter_class=fmt, help="print the metrics table of a saved result",
                        description="Load a result folder written by `hinfnn run` or `reproduce` and print "
                                    "its metrics.", epilog="example:\n  hinfnn show results/paper\n")
    sh.add_argument("folder", type=Path)
    sh.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
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
    """Progress on stderr (tqdm: steps done, rate, ETA), shown only for runs longer than a few
    seconds and never with ``--quiet``; ``names`` are the runs of the chunk being simulated."""

    def __init__(self, quiet: bool, label: str):
        self.quiet = quiet
        self.label = label
        self.bar = None

    def __call__(self, done: int, total: int, names=None):
        if self.quiet:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=self.label, unit="step", unit_scale=True, delay=3.0,
                            file=sys.stderr, leave=False, dynamic_ncols=True, mininterval=0.5,
                            disable=None)  # None: only on a terminal
        if names:
            self.bar.set_postfix_str(", ".join(names)[:40], refresh=False)
        self.bar.update(done - self.bar.n)

    def done(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


# --- commands -----------------------------------------------------------------------------------


def cmd_run(args) -> int:
    from .controllers import design_summary
    from .io import OutputFolder, atomic_write_bytes, atomic_write_text, choose_output, dumps_json, \
        trajectory_npz_bytes
    from .report.markdown import metrics_table
    from .results import metrics_document, run_entry
    from .scenario import Scenario
    from .sim import simulate_many

    trace = getattr(args, "startup_trace", None)
    if trace:
        trace.mark("imports_done")
    sc = Scenario.load(args.scenario, args.overrides)
    if trace:
        trace.mark("scenario_loaded")
    out = args.out or Path("results") / sc.name
    target, note = choose_output(out, args.force)
    if note:  # even with --quiet: the result is not where the user asked
        print(note, file=sys.stderr)
    kinds = sc.kinds
    progress = Progress(args.quiet, f"simulating {', '.join(kinds)}")
    with OutputFolder(target) as folder:
        runs = [sc.run(kind) for kind in kinds]
        trajs = simulate_many(runs, progress=trace.wrap(progress) if trace else progress)
        progress.done()
        if trace:
            trace.done()
        entries = [run_entry(r.name, trajs[r.name], overrides=dict(sc.overrides), design=design_summary(r.controller))
                   for r in runs]
        doc = metrics_document(sc, entries, command=command_line(args))
        atomic_write_text(folder.path / "metrics.json", dumps_json(doc))
        atomic_write_bytes(folder.path / "trajectory.npz", trajectory_npz_bytes(trajs, sc.simulation.output_interval))
        atomic_write_text(folder.path / "scenario.toml", sc.to_toml())
        from .report import run_figures  # matplotlib (0.5 s): imported once the simulation is done

        run_figures(trajs, folder.path)
    if not args.quiet:
        print(metrics_table(doc, markdown=False))
        print(f"results: {target}/ (metrics.json, trajectory.npz, scenario.toml, *.png)")
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
                       log=lambda m: print(m, file=sys.stderr), command=command_line(args))
    progress.done()
    if not args.quiet:
        import json

        from .report.markdown import metrics_table

        doc = json.loads((target / "metrics.json").read_text())
        print(metrics_table(doc, markdown=False))
        print(f"report: {target}/report.md  ({time.perf_counter() - t0:.0f} s)")
    return 0


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
        print(f"{name:<16} {sc.description}")
    return 0


def cmd_show(args) -> int:
    from .io import load

    res = load(args.folder)
    if res.metrics is None:
        print(f"{args.folder}: no metrics.json", file=sys.stderr)
        return 2
    from .report.markdown import metrics_table

    print(metrics_table(res.metrics, markdown=False))
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


COMMANDS = {"run": cmd_run, "reproduce": cmd_reproduce, "keys": cmd_keys, "scenarios": cmd_scenarios,
            "show": cmd_show, "cache": cmd_cache, "gallery": cmd_gallery}


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


def main(argv=None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.print_help()
        return 2
    if args.command not in ("keys", "scenarios"):
        from ._config import configure

        configure()
    if args.command == "run":
        from ._startup import StartupTrace

        args.startup_trace = StartupTrace.from_env()
    from .errors import ConfigError, DesignError
    from .io import LoadError

    try:
        return COMMANDS[args.command](args)
    except (ConfigError, DesignError, LoadError) as err:
        if getattr(args, "debug", False):
            raise
        kind = type(err).__name__
        text = "\\n".join(str(err).splitlines())
        print(f"hinfnn: {kind}: {text}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hinfnn: interrupted; no output was written", file=sys.stderr)
        return _interrupted_exit(130, argv)
    except BaseException as err:  # noqa: BLE001 - the CLI's last line of defence
        if isinstance(err, SystemExit):
            raise
        if getattr(args, "debug", False) or type(err).__name__ == "_Interrupted":
            if type(err).__name__ == "_Interrupted":
                print("hinfnn: terminated; no output was written", file=sys.stderr)
                return _interrupted_exit(143, argv)
            raise
        print(f"hinfnn: error: {type(err).__name__}: {err} (run with --debug for the traceback)",
              file=sys.stderr)
        return 1
    finally:
        if getattr(args, "startup_trace", None) is not None:
            args.startup_trace.close()


if __name__ == "__main__":
    sys.exit(main())
