"""``hinfnn run``: simulate a scenario (one run per listed controller) into a result folder."""

from __future__ import annotations

import sys

from ._common import Progress, command_line, fields_option, log_stderr


def main(args) -> int:
    from ..scenario import Scenario
    from ..workflows.run import run_scenario

    trace = getattr(args, "startup_trace", None)
    if trace:
        trace.mark("imports_done")
    sc = Scenario.load(args.scenario, args.overrides)
    if trace:
        trace.mark("scenario_loaded")
    fields = fields_option(args.fields)
    progress = Progress(args.quiet, f"simulating {', '.join(sc.kinds)}")
    res = run_scenario(sc, out=args.out, force=args.force, fields=fields,
                       progress=trace.wrap(progress) if trace else progress, command=command_line(args),
                       log=log_stderr,  # even with --quiet: where the result goes matters
                       figures=getattr(args, "figures", True))
    progress.done()
    if trace:
        trace.done()
    doc, target = res.doc, res.target
    if not args.quiet:
        from ..report.markdown import metrics_table

        print(metrics_table(doc, markdown=False))
        pngs = ", *.png" if getattr(args, "figures", True) else ""
        print(f"results: {target}/ (metrics.json, trajectory.npz, scenario.toml{pngs})")
    failed = [r for r in doc["runs"] if r["status"] != "ok"]
    for r in failed:
        print(f"hinfnn: run {r['name']!r} stopped at t = {r['t_fail']:.6g} s ({r['reason']}); "
              f"its metrics up to then are in {target}/metrics.json (marked partial)", file=sys.stderr)
    return 1 if failed else 0
