"""``hinfnn show``, ``plot`` and ``export``: a saved result's metrics, figures and table."""

from __future__ import annotations

import sys
from pathlib import Path

from ._common import zoom_option


def show(args) -> int:
    from ..io import load_metrics
    from ..report.markdown import design_text, metrics_table

    doc = load_metrics(_not_a_sweep(args.folder))
    print(metrics_table(doc, markdown=False))
    if not args.no_design:
        print()
        print(design_text(doc))
    return 0


def plot(args) -> int:
    from ..report.replot import replot

    only = [f.strip() for f in args.figures.split(",") if f.strip()] if args.figures else None
    written = replot(_not_a_sweep(args.folder), only=only, out=args.out, zoom_windows=zoom_option(args.zoom))
    for path in written:
        print(path)
    if not written:
        print(f"hinfnn: no figure drawn: the runs of {args.folder} lack the fields they need", file=sys.stderr)
        return 1
    return 0


def export(args) -> int:
    from ..errors import ConfigError
    from ..io import load
    from ..io.export import csv_text, export, export_target

    formats = [f for f, on in (("csv", args.csv), ("parquet", args.parquet)) if on]
    if not formats:
        raise ConfigError("give the format: --csv or --parquet (or both)", key="export")
    folder = _not_a_sweep(args.folder)
    if args.out == "-":
        if formats != ["csv"]:
            raise ConfigError("standard output (-) takes --csv only", key="--out")
        sys.stdout.write(csv_text(load(folder), args.run))
        return 0
    if args.out is not None and len(formats) > 1 and not Path(args.out).is_dir():
        raise ConfigError("with both --csv and --parquet, --out must be a folder", key="--out")
    targets = {fmt: export_target(folder, fmt, run=args.run, out=args.out) for fmt in formats}  # all, first
    for fmt in formats:
        print(export(folder, fmt, run=args.run, out=args.out, target=targets[fmt]))
    return 0


def _not_a_sweep(folder: Path) -> Path:
    """``folder``, unless it is a sweep's (a LoadError saying where a sweep's results are)."""
    from ..io import not_a_sweep

    return not_a_sweep(folder)
