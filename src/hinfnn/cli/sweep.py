"""``hinfnn sweep``: run or resume a robustness sweep; print the outcome per controller."""

from __future__ import annotations

import sys
import time

from .. import _signals
from ._common import command_line


def main(args) -> int:
    from ..errors import ConfigError
    from ..sweep import load_spec, spec_names

    if args.list:
        from ..scenario.core import parse_toml
        from ..sweep.spec import read_spec_source

        for name in spec_names():
            text, _, _ = read_spec_source(name)
            print(f"{name:<20} {parse_toml(text, name).get('description', '')}")
        return 0
    if args.spec is None:
        raise ConfigError("give a sweep spec: a shipped name (hinfnn sweep --list) or a .toml file", key="SPEC")
    if args.batch_size is not None and args.batch_size < 1:
        raise ConfigError(f"must be a whole number >= 1, got {args.batch_size}", key="--batch-size")
    from ..sweep.backends import check_options
    from ..sweep.run import prepare_output, run_sweep

    check_options(args.backend, args.address, args.workers)

    spec = load_spec(args.spec, samples=args.samples, overrides=args.overrides)
    output = prepare_output(args.out, spec, resume=args.resume, force=args.force)
    if output.note:
        print(output.note, file=sys.stderr)
    progress = _Progress(args.quiet)

    def log(message):
        if not args.quiet:
            print(f"hinfnn sweep: {message}", file=sys.stderr, flush=True)

    if not args.resume:
        from ..sweep.tune import range_notes

        for note in range_notes(spec):  # before anything runs: plants the design was not made for
            print(f"hinfnn sweep: warning: {note}", file=sys.stderr, flush=True)
    log(f"{spec.n_runs:,} runs: {spec.points:,} grid point(s) × {spec.samples:,} sample(s) × "
        f"{len(spec.controllers)} controller(s)")

    try:
        res = run_sweep(spec, output.work, backend=args.backend, address=args.address, resume=output.resume,
                        max_batch=args.batch_size, progress=progress, log=log, command=command_line(args),
                        replaces=output.target if output.replacing else None, workers=args.workers)
    except BaseException as err:
        progress.close()
        if isinstance(err, (KeyboardInterrupt, _signals.Terminated)):
            err.hinfnn_note = _resume_note(args, output)  # main() prints it and leaves (exit 130 / 143)
        raise
    progress.close()
    if not args.quiet:
        from ..controllers import KINDS

        print(f"{'controller':<16} {'runs':>6} {'invalid':>8} {'simulated':>10} {'bounded':>9} {'held contact':>13} "
              f"{'did its job':>12}")
        for kind, c in res.counts.items():
            n = c["simulated"]
            pct = (lambda k: f"{100 * k / n:.1f} %") if n else (lambda k: "-")
            print(f"{KINDS[kind].label if kind in KINDS else kind:<16} {c['runs']:>6} {c['invalid']:>8} {n:>10} "
                  f"{pct(c['bounded']):>9} {pct(c['held_contact']):>13} {pct(c.get('did_its_job', 0)):>12}")
            if c.get("not_judged"):
                print(f"{'':<16} contact not judged in {c['not_judged']} bounded run(s): they end before "
                      "verdict.contact_after")
        if res.simulated_now:
            print(f"{res.simulated_now} runs simulated in {res.run_wall_s:.1f} s ({res.runs_per_s:.2f} runs/s, "
                  f"{res.backend} backend, compilation included)"
                  + (f"; {res.already_done} were done before" if res.already_done else ""))
        print(f"results: {res.folder}/ (results.parquet, report.md, *.png)")
    return 0


def _resume_note(args, output) -> str:
    """What an interrupted sweep kept and the command that continues it."""
    import json
    import shlex

    try:
        done = len(json.loads((output.work / "manifest.json").read_text())["done"])
        saved = f"{done} finished batch(es) are saved in {output.work}/parts"
    except (OSError, ValueError, KeyError):
        saved = f"finished batches are saved in {output.work}/parts"
    again = ["sweep", args.spec, "--out", str(output.target)]
    again += ["--force"] if output.replacing else ["--resume"]
    again += [a for o in args.overrides for a in ("--set", o)]
    again += ["--samples", str(args.samples)] if args.samples else []
    again += ["--backend", args.backend] if args.backend != "local" else []
    again += ["--workers", str(args.workers)] if args.workers is not None else []
    kept = f"; {output.target} is as it was" if output.replacing else ""
    return f"{saved}{kept}; continue with: hinfnn {' '.join(shlex.quote(a) for a in again)}"


class _Progress:
    """The sweep's progress on stderr: a tqdm bar per phase on a terminal, else a line every 30 s
    while simulating. The callback of :func:`hinfnn.sweep.run.run_sweep`: ``(done, total, what)``."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.bars: dict = {}
        self.tty = sys.stderr.isatty()
        self.state = {"t0": time.perf_counter(), "last": 0.0}

    def __call__(self, done, total, what=""):
        from ..sweep.run import CHECKING, SIMULATING

        if self.quiet:
            return
        if self.tty:
            if what not in self.bars:
                from tqdm import tqdm

                self.close()
                unit = "draw" if what == CHECKING else "run"
                self.bars[what] = tqdm(total=total, initial=done, desc=what, unit=unit, file=sys.stderr, leave=False,
                                       dynamic_ncols=True, mininterval=0.5, smoothing=0.1,
                                       bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total} {unit}s "
                                                  "[{elapsed}<{remaining}, {rate_fmt}]")
                self.state["t0"] = time.perf_counter()
            bar = self.bars[what]
            bar.update(done - bar.n)
        elif what == SIMULATING and total and (time.perf_counter() - self.state["last"] > 30 or done >= total):
            if self.state.get("phase") != what:  # a resumed sweep starts with the runs done before
                self.state.update(phase=what, t0=time.perf_counter(), base=done)
            self.state["last"] = time.perf_counter()
            el = time.perf_counter() - self.state["t0"]
            rate = (done - self.state["base"]) / el if el > 0 else 0.0
            eta = f", ETA {(total - done) / rate / 60:.1f} min" if rate > 0 and done < total else ""
            print(f"hinfnn sweep: {done:.0f}/{total} runs, {el:.0f} s, {rate:.2f} runs/s{eta}", file=sys.stderr,
                  flush=True)

    def close(self):
        for bar in self.bars.values():
            bar.close()
        self.bars = {}
