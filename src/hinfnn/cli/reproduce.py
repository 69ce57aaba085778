"""``hinfnn reproduce``: the paper's Sec. VI study and "Beyond the paper" into one report."""

from __future__ import annotations

import time

from ._common import Progress, command_line, log_stderr


def main(args) -> int:
    from ..scenario import Scenario
    from ..workflows.paper import reproduce

    base = Scenario.load(args.scenario, args.overrides)
    progress = Progress(args.quiet, "reproducing the paper study")
    t0 = time.perf_counter()
    target = reproduce(args.out, base=base, force=args.force, progress=progress, log=log_stderr,
                       command=command_line(args), beyond=not args.paper_only)
    progress.done()
    if not args.quiet:
        from ..io import load_metrics
        from ..report.markdown import metrics_table

        print(metrics_table(load_metrics(target), markdown=False))
        print(f"report: {target}/report.md  ({time.perf_counter() - t0:.0f} s)")
    return 0
