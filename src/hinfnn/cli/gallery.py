"""``hinfnn gallery``: the shipped arms-and-surfaces scenarios into one report."""

from __future__ import annotations

import json
import time

from ._common import Progress, command_line, log_stderr


def main(args) -> int:
    from ..report.markdown import metrics_table
    from ..workflows.gallery import gallery_scenarios, run_gallery

    if getattr(args, "sensor", False):
        from ..workflows.sensor import run_sensor_gallery

        progress = Progress(args.quiet, "gallery")
        t0 = time.perf_counter()
        target = run_sensor_gallery(args.out, overrides=args.overrides, only=args.only, force=args.force,
                                    progress=progress, log=(lambda m: None) if args.quiet else log_stderr,
                                    command=command_line(args))
        progress.done()
        if not args.quiet:
            print((target / "report.md").read_text())
            print(f"report: {target}/report.md  ({time.perf_counter() - t0:.0f} s)")
        return 0

    gallery_scenarios(args.overrides, args.only)  # every check before anything runs (run_gallery: the
    # stiff-contact designs too, before its folder is reserved)
    progress = Progress(args.quiet, "gallery")
    t0 = time.perf_counter()
    target = run_gallery(args.out, overrides=args.overrides, only=args.only, force=args.force, progress=progress,
                         beyond=args.beyond, log=(lambda m: None) if args.quiet else log_stderr, command=command_line(args))
    progress.done()
    if not args.quiet:
        for sub in sorted(p for p in target.iterdir() if (p / "metrics.json").is_file()):  # not beyond/
            print(f"{sub.name}:")
            print(metrics_table(json.loads((sub / "metrics.json").read_text()), markdown=False))
        print(f"report: {target}/report.md  ({time.perf_counter() - t0:.0f} s)")
    return 0
