"""``hinfnn compare``: one scenario with one key at several values, side by side."""

from __future__ import annotations

from ._common import Progress, command_line, log_stderr


def main(args) -> int:
    from ..errors import ConfigError
    from ..report.markdown import metrics_table
    from ..scenario import Scenario, parse_override
    from ..workflows.compare import compare, split_values

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
    target, doc = compare(sc, key, values, args.out, force=args.force, progress=progress, log=log_stderr,
                          command=command_line(args))
    progress.done()
    if not args.quiet:
        print(metrics_table(doc, markdown=False))
        print(f"results: {target}/ (compare.md, metrics.json, trajectory.npz, scenario.toml, *.png)")
    return 1 if any(r["status"] != "ok" for r in doc["runs"]) else 0
