"""``hinfnn design``: the designed controller(s) of a scenario, as text or JSON
(:func:`hinfnn.analysis.design_report`, :func:`hinfnn.analysis.format_design_report`)."""

from __future__ import annotations


def main(args) -> int:
    from ..analysis import design_report, format_design_report
    from ..io import dumps_json
    from ..scenario import Scenario

    report = design_report(Scenario.load(args.scenario, args.overrides))
    if args.json:
        print(dumps_json(report), end="")
    else:
        print(format_design_report(report))
    return 0
