"""``hinfnn robot run``: a scenario's controller on a robot, through the safety layer, into a result folder."""

from __future__ import annotations

import sys

from ._common import command_line, log_stderr


def main(args) -> int:
    from ..robot import run_robot
    from ..scenario import Scenario

    if getattr(args, "robot_command", None) != "run":
        print("hinfnn robot: give an action: hinfnn robot run SCENARIO --robot virtual (see hinfnn robot run --help)",
              file=sys.stderr)
        return 2
    sc = Scenario.load(args.scenario, args.overrides)
    res = run_robot(sc, robot=args.robot, out=args.out, force=args.force, command=command_line(args), log=log_stderr,
                    figures=args.figures, host=args.host, scheduling=args.scheduling,
                    cpu=args.cpu)  # no printing inside the loop: the events are in robot.log
    doc, target, s = res.doc, res.target, res.doc["robot"]
    if not args.quiet:
        from ..report.markdown import metrics_table

        print(metrics_table(doc, markdown=False))
        lat, late = s["latency_s"], s["lateness_s"]
        print(f"loop: {s['cycles']} cycles at {1e3 * s['period']:g} ms; latency p50 {1e6 * lat['p50']:.0f} µs, "
              f"p99 {1e6 * lat['p99']:.0f} µs, max {1e6 * lat['max']:.0f} µs; late cycles {s['late_cycles']} "
              f"({s['late_fraction']:.2%}, longest run {s['longest_late_run']}); ticks the robot held the previous "
              f"torque {s['missed_ticks']} ({s['missed_tick_fraction']:.2%}); rejected readings {s['rejected']}")
        if res.log.scheduling is not None:
            print(f"loop thread: {res.log.scheduling.line()}")
        pngs = ", *.png" if args.figures else ""
        print(f"results: {target}/ (metrics.json, trajectory.npz, scenario.toml, robot.log{pngs})")
    failed = [r for r in doc["runs"] if r["status"] != "ok"]
    for r in failed:
        print(f"hinfnn: robot run {r['name']!r} stopped at t = {r['t_fail']:.6g} s ({r['reason']}); the run up to "
              f"then is in {target}/", file=sys.stderr)
    return 1 if failed else 0
