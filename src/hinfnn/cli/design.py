"""``hinfnn design``: the designed controller(s) of a scenario, as text or JSON
(:func:`hinfnn.analysis.design_report`, :func:`hinfnn.analysis.format_design_report`); with
``--tune SPEC`` the gains tuned over a sweep spec's declared uncertainty
(:func:`hinfnn.sweep.tune.tune`), written as a scenario file with a before/after report."""

from __future__ import annotations

import sys


def main(args) -> int:
    from ..analysis import design_report, format_design_report
    from ..errors import ConfigError
    from ..io import dumps_json
    from ..scenario import Scenario

    if getattr(args, "tune", None) is not None:
        return tune_main(args)
    if args.scenario is None:
        raise ConfigError("give a scenario: a shipped name or a .toml file (or --tune SPEC)", key="SCENARIO")
    report = design_report(Scenario.load(args.scenario, args.overrides))
    if args.json:
        print(dumps_json(report), end="")
    else:
        print(format_design_report(report))
    return 0


def _spec(args):
    from ..scenario.core import parse_toml
    from ..sweep.spec import read_spec_source, spec_from_dict

    text, source, folder = read_spec_source(args.tune)
    raw = parse_toml(text, source)
    if args.scenario is not None:  # tune this scenario over the spec's draws instead of the spec's own
        from pathlib import Path

        p = Path(args.scenario)
        raw["scenario"] = str(p.resolve()) if (p.suffix == ".toml" or p.exists()) else args.scenario
    return spec_from_dict(raw, overrides=args.overrides, source=source, folder=folder)


def tune_main(args) -> int:
    from ..analysis import design_report, format_design_report
    from ..errors import ConfigError
    from ..experiment.result import result_folder
    from ..io import dumps_json
    from ..sweep.tune import range_notes, tune
    from ._common import command_line

    if args.json:
        raise ConfigError("--json prints a design; --tune writes a folder (its tune.json)", key="--json")
    knobs = None if args.knobs is None else tuple(k.strip() for k in args.knobs.split(",") if k.strip())
    spec = _spec(args)
    if args.tune_t_final is not None and not 0 < args.tune_t_final <= spec.base.simulation.t_final:
        raise ConfigError(f"must be > 0 and at most the scenario's t_final {spec.base.simulation.t_final:g} s, got "
                          f"{args.tune_t_final:g}", key="--tune-t-final")

    def log(message):
        print(f"hinfnn design --tune: {message}", file=sys.stderr, flush=True)

    for note in range_notes(spec):
        log(f"note: {note}")
    with result_folder(args.out, command="design", name=spec.name, kind="tune", force=args.force, log=log,
                       command_line=command_line(args)) as out:
        res = tune(spec, knobs=knobs, draws=args.tune_draws, held_out=args.held_out, generations=args.generations,
                   population=args.population, seed=args.seed, t_final=args.tune_t_final, log=log)
        kind = res.tuned.kinds[0] if len(res.tuned.kinds) == 1 else spec.controllers[0]
        design_text = format_design_report(design_report(res.tuned.single(kind)))
        (out.path / "scenario.toml").write_text(_scenario_text(res, spec), encoding="utf-8")
        (out.path / "design.txt").write_text(design_text + "\n", encoding="utf-8")
        (out.path / "tune.json").write_text(dumps_json(tune_record(res, spec, args)), encoding="utf-8")
        (out.path / "report.md").write_text(tune_markdown(res, spec, args), encoding="utf-8")
    print(tune_summary(res))
    print(design_text)
    print(f"results: {out.path}/ (scenario.toml, report.md, tune.json, design.txt)")
    return 0


def _scenario_text(res, spec) -> str:
    head = (f"# {res.tuned.name} with its gains tuned by `hinfnn design --tune {spec.name}` over the spec's draws "
            f"(seed {spec.seed}); changed keys:\n"
            + "".join(f"#   {k} = {v!r}\n" for k, v in res.best.overrides)
            + ("#   (none: no candidate did better than the base design)\n" if not res.best.overrides else ""))
    return head + res.tuned.to_toml()


def _share(outs, attr="done"):
    from ..report.sweep import wilson

    n = len(outs)
    k = sum(bool(getattr(o, attr)) for o in outs)
    lo, hi = wilson(k, n) if n else (float("nan"), float("nan"))
    return k, n, lo, hi


def _fmt_share(outs, attr="done") -> str:
    k, n, lo, hi = _share(outs, attr)
    return f"{k}/{n} = {100 * k / n:.1f} % ({100 * lo:.1f}-{100 * hi:.1f})" if n else "-"


def tune_summary(res) -> str:
    lines = [f"tuned over {len(res.tuning_draws)} draws: {res.runs} runs in {res.wall_s:.0f} s; best "
             + (", ".join(f"{k} = {v:.3g}" for k, v in res.best.values.items()) or "the base design")]
    for label, attr in (("did its job", "done"), ("held contact", "held"), ("stayed bounded", "bounded")):
        lines.append(f"held-out {label:<15} before {_fmt_share(res.held_out_before, attr)}   after "
                     f"{_fmt_share(res.held_out_after, attr)}")
    for label, outs in (("before", res.held_out_before), ("after", res.held_out_after)):
        fails = failures_by_criterion(outs)
        if fails:
            lines.append(f"held-out missed {label}, by worst criterion: "
                         + ", ".join(f"{k} {n}" for k, n in fails.items()))
    return "\n".join(lines)


def tune_record(res, spec, args) -> dict:
    values = res.held_out_values or [{} for _ in res.held_out_draws]

    def outs(o):
        return [dict(draw=i, values=_plain_values(v), done=x.done, held=x.held, tracked=x.tracked, bounded=x.bounded,
                     badness=x.badness, worst=x.worst)
                for i, v, x in zip(res.held_out_draws, values, o)]

    return dict(spec=spec.name, seed=spec.seed, search_seed=args.seed, knobs=[k.name for k in res.knobs],
                stiffness_declared=res.stiffness, tuning_draws=res.tuning_draws, held_out_draws=res.held_out_draws,
                invalid=[dict(draw=i, reason=r) for i, r in res.invalid], runs=res.runs, wall_s=res.wall_s,
                best=dict(values=res.best.values, overrides=[[k, v] for k, v in res.best.overrides],
                          score=res.best.score, done=res.best.done, judged=res.best.judged),
                base=dict(score=res.base.score, done=res.base.done, judged=res.base.judged),
                history=[dict(generation=c.generation, values=c.values, score=c.score, done=c.done, judged=c.judged,
                              error=c.error) for c in res.history],
                held_out_before=outs(res.held_out_before), held_out_after=outs(res.held_out_after))


def _plain_values(values: dict) -> dict:
    import numpy as np

    return {k: (np.asarray(v).tolist() if not isinstance(v, str) else v) for k, v in values.items()}


def failures_by_criterion(outs) -> dict:
    """How many held-out draws missed their job, by the criterion furthest from its tolerance
    (:attr:`hinfnn.sweep.tune.Outcome.worst`)."""
    counts: dict = {}
    for o in outs:
        if not o.done:
            counts[o.worst or "?"] = counts.get(o.worst or "?", 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: -kv[1]))


def tune_markdown(res, spec, args) -> str:
    lines = [f"# `hinfnn design --tune {spec.name}`", "",
             f"Base scenario `{res.tuned.name}`; the spec's draws (seed {spec.seed}): tuning draws "
             f"{res.tuning_draws[0] if res.tuning_draws else '-'}…{res.tuning_draws[-1] if res.tuning_draws else '-'}"
             f" ({len(res.tuning_draws)}), held-out draws {len(res.held_out_draws)} others. Search: cross-entropy, "
             f"seed {args.seed}, {args.generations} generations of {args.population}, knobs "
             f"{', '.join(k.name for k in res.knobs)}; {res.runs} runs in {res.wall_s:.0f} s.", "",
             "| held-out draws | base design | tuned design |", "|---|---|---|"]
    for label, attr in (("did its job", "done"), ("held contact", "held"), ("stayed bounded", "bounded")):
        lines.append(f"| {label} | {_fmt_share(res.held_out_before, attr)} | {_fmt_share(res.held_out_after, attr)} |")
    for label, outs in (("base design", res.held_out_before), ("tuned design", res.held_out_after)):
        fails = failures_by_criterion(outs)
        if fails:
            lines.append(f"\nHeld-out draws the {label} missed, by the criterion furthest from its tolerance: "
                         + ", ".join(f"{k} {n}" for k, n in fails.items()) + " (tune.json: each draw's values).")
    lines += ["", "(95 % Wilson intervals.) Tuned keys:", ""]
    lines += [f"- `{k} = {v!r}`" for k, v in res.best.overrides] or ["- none: no candidate beat the base design"]
    lines += ["", "| generation | candidate | did its job (tuning draws) | score | refused |", "|---|---|---|---|---|"]
    for c in res.history:
        vals = ", ".join(f"{k}={v:.3g}" for k, v in c.values.items()) or "base"
        lines.append(f"| {c.generation} | {vals} | {c.done}/{c.judged} | {c.score:.4f} | {c.error or ''} |")
    if res.invalid:
        lines += ["", f"{len(res.invalid)} draws could not start (not judged)."]
    return "\n".join(lines) + "\n"
