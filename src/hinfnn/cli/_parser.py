"""The ``hinfnn`` command line's parser: every subcommand, its options and examples (parsing only)."""

from __future__ import annotations

import argparse
import functools
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
  hinfnn gallery --beyond --only ur5-table    # + the paper law and the stabilised one on a bare stiff table
  hinfnn gallery --sensor --only ur5-polish   # instead: a noisy, late force sensor, paper law vs designed for it
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
EXAMPLES_ROBOT = """examples:
  hinfnn robot run ur5-polish --robot virtual                 # results/robots/ur5-polish-<UTC time>/
  hinfnn robot run ur5-polish --set simulation.t_final=2 --set safety.force_limit=60 --out results/r1
  hinfnn robot run fr3-table --robot franka --host 127.0.0.1   # a Franka, or franka-sim on this machine

The virtual robot is the scenario's MuJoCo plant (plant.engine = "mujoco") in its own process, advancing
in wall-clock real time; the loop reaches it only through the robot interface. The Franka is driven
through libfranka (pip install 'hinfnn[franka]'). See docs/robot.md.
"""
EXAMPLES_MAIN = """examples:
  hinfnn reproduce                 the paper's Sec. VI study into results/paper/
  hinfnn gallery                   the shipped arms-and-surfaces scenarios into results/gallery/
  hinfnn run paper --set controller.kind=hinf --set plant.contact.damping=200
  hinfnn keys                      every scenario key, its meaning and allowed values
  hinfnn show results/paper        the metrics and designed controllers of a saved result
  hinfnn plot DIR / export DIR     redraw the figures / write the trajectories as CSV or Parquet
  hinfnn robot run ur5-polish      the controller on a (virtual) robot: real-time loop, safety layer
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


def _cpu_arg(text: str):
    """``--cpu``: "auto", "any" (None) or a CPU number."""
    if text in ("auto", "any"):
        return None if text == "any" else text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be auto, any or a CPU number, got {text!r}") from None


@functools.cache
def _parser() -> argparse.ArgumentParser:
    """The command line's parser, built once per process: it holds only constants (parsing does
    not change it; ``--set``'s list default is copied, not appended to), and building its
    subcommands is not free, so every ``main()`` called from Python (a test, a notebook) reuses it."""
    from .. import __version__

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

    ro = sub.add_parser(
        "robot", formatter_class=fmt, epilog=EXAMPLES_ROBOT,
        help="run a scenario's controller on a robot: the real-time loop with the safety layer",
        description="Drive a robot with the scenario's one controller at its control period, through the safety "
                    "layer ([safety], docs/robot.md), and record the run as `hinfnn run` records a simulation: "
                    "OUT/metrics.json (with the loop's latency, lateness, late and rejected cycles and the safety "
                    "events), OUT/trajectory.npz, OUT/scenario.toml, OUT/robot.log and figures.")
    rsub = ro.add_subparsers(dest="robot_command", metavar="ACTION")
    rr = rsub.add_parser("run", formatter_class=fmt, epilog=EXAMPLES_ROBOT,
                         help="run SCENARIO on the robot for simulation.t_final s of robot time",
                         description="Run SCENARIO (one controller, simulation.control = \"sampled\") on the robot "
                                     "for simulation.t_final s of robot time and write the result folder.")
    rr.add_argument("scenario", help="shipped scenario name (see `hinfnn scenarios`) or path to a .toml file")
    rr.add_argument("--robot", choices=("virtual", "franka"), default="virtual",
                    help="virtual: the scenario's MuJoCo plant served in its own process in real time (default); "
                         "franka: a Franka (or franka-sim) through libfranka's pylibfranka at --host (docs/robot.md)")
    rr.add_argument("--host", default="127.0.0.1", metavar="ADDRESS",
                    help="the Franka's address for --robot franka (default: 127.0.0.1, franka-sim on this machine)")
    rr.add_argument("--scheduling", choices=("auto", "enforce", "off"), default="auto",
                    help="the loop thread's real-time scheduling (docs/robot.md): auto: SCHED_FIFO where this process "
                         "may (root, CAP_SYS_NICE or an rtprio limit), else the ordinary policy (default); enforce: "
                         "SCHED_FIFO or an error before the robot starts (libfranka's default); off: ordinary")
    rr.add_argument("--cpu", type=_cpu_arg, default="auto", metavar="N",
                    help="run the loop's thread on CPU N only while it runs; auto (default): the last CPU where there "
                         "are two or more and the loop is real-time scheduled (the virtual robot's clock on the "
                         "others); any: no pinning")
    rr.add_argument("--out", default=None, metavar="DIR",
                    help="output folder (default: results/robots/<scenario name>-<UTC time>)")
    rr.add_argument("--no-figures", dest="figures", action="store_false", help="write no figures")
    common(rr)
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
               "  hinfnn design paper --json > design.json\n"
               "  hinfnn design --tune ur5-table-uncertainty --tune-t-final 4 --out results/tuned\n")
    d.add_argument("scenario", nargs="?", default=None,
                   help="shipped scenario name or path to a .toml file (with --tune: default the spec's scenario)")
    d.add_argument("--json", action="store_true", help="print the design as JSON")
    d.add_argument("--tune", default=None, metavar="SPEC",
                   help="tune the gains over the uncertainty a sweep spec declares (its draws of the truth): a seeded "
                        "cross-entropy search maximising the share of draws that did their job, then the base and "
                        "tuned designs on held-out draws; writes OUT/scenario.toml, report.md, tune.json, design.txt")
    d.add_argument("--out", default=None, metavar="DIR", help="with --tune: output folder (default: "
                                                               "results/designs/<spec>-<UTC time>)")
    d.add_argument("--force", action="store_true", help="with --tune: replace OUT if hinfnn wrote it")
    d.add_argument("--tune-draws", type=int, default=16, metavar="N", help="with --tune: tuning draws (default 16)")
    d.add_argument("--held-out", type=int, default=64, metavar="M",
                   help="with --tune: held-out draws the base and tuned designs are compared on (default 64)")
    d.add_argument("--generations", type=int, default=4, metavar="G", help="with --tune: generations (default 4)")
    d.add_argument("--population", type=int, default=8, metavar="P",
                   help="with --tune: candidates per generation (default 8)")
    d.add_argument("--seed", type=int, default=0, help="with --tune: seed of the search (default 0)")
    d.add_argument("--tune-t-final", type=float, default=None, metavar="T",
                   help="with --tune: horizon of the tuning runs, s (default the scenario's; held-out runs use it)")
    d.add_argument("--knobs", default=None, metavar="NAMES",
                   help="with --tune: the design parameters to move, separated by commas, of "
                        "omega,q,alpha_lam,alpha_z,zeta,kappa,radius_f (default: omega,q,alpha_lam,alpha_z; zeta, or "
                        "kappa where the force-rate gain is designed for the declared sensor; radius_f where a noisy "
                        "sensor makes the networks' update laws project)")
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
    ga.add_argument("--beyond", action="store_true",
                    help="also each arm's stiff-contact comparison: the paper's law and the stabilised one on a bare "
                         "undamped contact, k = 1e4, 1e5, 1e6 N/m, continuous and 1 kHz, with the contact modes "
                         "(24 runs of 10 s per arm: tens of minutes)")
    ga.add_argument("--sensor", action="store_true",
                    help="instead: each robot arm (ur5-polish, ur5-table-stable, ur5-sphere-stable, panda-table) with "
                         "a noisy, one-sample-late force sensor (sigma = 0, 0.5, 1, 2.5, 5 N) and the URDF torque "
                         "limits at 1 kHz, the paper's law against the one designed for the sensor (3-s runs; "
                         "--set simulation.t_final=10 for the issue's)")
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
                    help="local: on this machine, batches side by side in worker processes, one per core "
                         "(default; see --workers); ray: batches as Ray tasks, one per CPU (pip install 'hinfnn[ray]')")
    sw.add_argument("--workers", type=int, default=None, metavar="N",
                    help="with the local backend: worker processes (default: one per core when the simulation "
                         "would take a minute or more in one process, else none; 1: the batches one after the "
                         "other in this process)")
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
