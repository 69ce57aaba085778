"""A sweep spec: which scenario, which keys vary and how, which controllers, which metrics.

A spec is a TOML file (or a shipped name, ``files/*.toml``) read into typed, frozen dataclasses
with the scenario loader's own schema (:func:`hinfnn.scenario.schema.load`: the same ``param``
fields, the same one-line :class:`~hinfnn.errors.ConfigError` naming the dotted key, the value
and what is allowed)::

    name = "my-sweep"
    scenario = "paper"                   # base scenario: shipped name or TOML file
    controllers = ["hinf", "hinf_nn"]
    samples = 200                        # random draws (at every grid point)
    seed = 7

    [set]                                # fixed changes to the base scenario
    "simulation.t_final" = 5.0

    [vary]                               # one entry per scenario key
    "plant.arm.m2" = { linspace = [0.5, 2.0, 7] }                          # grid
    "plant.contact.stiffness" = { logspace = [1e4, 1e6, 5] }               # grid
    "plant.arm.m1" = { distribution = "relative", percent = 20 }           # draws
    "plant.contact.damping" = { distribution = "uniform", low = 0, high = 200 }

Grids (``values``, ``linspace``, ``logspace``) span a Cartesian product of points; the random
draws (``uniform``, ``normal``, ``log-uniform``, ``relative``) are taken ``samples`` times, and the
same draws are used at every grid point (common random numbers: two points differ only in their
grid values). See ``docs/sweeps.md`` for every key.
"""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import json
import re
import typing
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from ..errors import ConfigError, is_integer, is_real
from ..metrics import METRIC_KEYS
from ..scenario import schema
from ..scenario.schema import param, section

SHIPPED = "files"

GRIDS = ("values", "linspace", "logspace")
#: The most draws a sweep takes: grid points × samples (each count and ``samples`` alone are capped
#: too; the runs are the draws × the controllers).
MAX_DRAWS = 10_000_000
DISTRIBUTIONS = ("uniform", "normal", "log-uniform", "relative")
#: The parameters each distribution takes (required, optional).
DISTRIBUTION_PARAMS = {
    "uniform": (("low", "high"), ()),
    "log-uniform": (("low", "high"), ()),
    "normal": (("std",), ("mean", "low", "high")),
    "relative": (("percent",), ()),
}
#: Metrics with one value per joint: table columns ``NAME_1``, ``NAME_2``, ...
PER_JOINT_METRICS = ("peak_abs_tau", "peak_abs_tau_last2s", "rms_tau_last2s", "tv_rate_tau_last2s")
#: Metrics with one value per motion or force coordinate: one ``list<double>`` column each.
PER_COORDINATE_METRICS = ("rms_e_u1_each", "rms_e_u1_each_last2s", "rms_e_lam_each", "rms_e_lam_each_last2s")
#: Metrics that are true/false (the report gives their fractions).
BOOL_METRICS = ("dissipation_holds", "dissipation_holds_for_all_t")
DEFAULT_METRICS = ("rms_e_u1_last2s", "rms_e_lam_last2s", "peak_abs_tau", "fraction_out_of_contact")
#: Scenario keys a sweep cannot vary (the controllers are the spec's ``controllers``).
RESERVED = {"controller.kind": "list the controllers in the spec's `controllers` instead",
            "name": "a sweep has one base scenario", "description": "a sweep has one base scenario"}


def _metrics_allowed() -> str:
    return ("names of hinfnn.metrics.METRIC_KEYS (numbers, not " + ", ".join(BOOL_METRICS)
            + "); per-joint ones as NAME or NAME_1, NAME_2, ...")


@section
class VarySpec:
    """How one scenario key varies: a grid (exactly one of ``values``, ``linspace``,
    ``logspace``) or a seeded distribution (``distribution`` and its parameters)."""

    values: tuple[float, ...] | tuple[str, ...] = param(
        None, doc="grid: the values, in order", allowed="a list of numbers or a list of strings")
    linspace: tuple[float, ...] = param(None, doc="grid: [first, last, count] evenly spaced values")
    logspace: tuple[float, ...] = param(
        None, doc="grid: [first, last, count] geometrically spaced values (first, last > 0: values, "
                  "not exponents, like numpy.geomspace)")
    distribution: Literal["uniform", "normal", "log-uniform", "relative"] = param(
        None, doc="random draws: uniform in [low, high], normal(mean, std) optionally truncated to "
                  "[low, high], log-uniform in [low, high], relative: uniform within ±percent % of the "
                  "base value")
    low: float = param(None, doc="lower end (uniform, log-uniform; truncation of normal)")
    high: float = param(None, doc="upper end (uniform, log-uniform; truncation of normal)")
    mean: float = param(None, doc="mean of normal (default: the base value)")
    std: float = param(None, doc="standard deviation of normal", gt=0.0)
    percent: float = param(None, doc="half-width of relative, in % of the base value", gt=0.0, lt=100.0)

    @property
    def kind(self) -> str:
        """``values``, ``linspace``, ``logspace`` or the distribution's name."""
        for g in GRIDS:
            if getattr(self, g) is not None:
                return g
        return self.distribution

    @property
    def is_grid(self) -> bool:
        return self.kind in GRIDS

    def validate(self, path):
        given = [g for g in GRIDS if getattr(self, g) is not None]
        if self.distribution is not None:
            given.append("distribution")
        if not given:
            raise ConfigError("needs a grid (values, linspace or logspace) or a distribution "
                              f"({', '.join(DISTRIBUTIONS)})", key=path)
        if len(given) > 1:
            raise ConfigError(f"gives both {given[0]} and {given[1]}; one key varies one way "
                              "(grids and draws combine across keys)", key=path)
        params = ("low", "high", "mean", "std", "percent")
        if self.is_grid:
            extra = [p for p in params if getattr(self, p) is not None]
            if extra:
                raise ConfigError(f"{extra[0]} belongs to a distribution, not to a {given[0]} grid", key=f"{path}.{extra[0]}")
            if self.kind in ("linspace", "logspace"):
                seq = getattr(self, self.kind)
                key = f"{path}.{self.kind}"
                if len(seq) != 3:
                    raise ConfigError(f"must be [first, last, count], got {list(seq)!r}", key=key)
                first, last, count = seq
                if count != int(count) or not 1 <= count <= 100_000:
                    raise ConfigError(f"count must be a whole number from 1 to 100000, got {count:g}", key=key)
                if self.kind == "logspace" and (first <= 0 or last <= 0):
                    raise ConfigError(f"first and last must be > 0 (values, not exponents), got {list(seq)!r}",
                                      key=key)
            if self.values is not None and len(set(self.values)) != len(self.values):
                raise ConfigError(f"lists a value twice: {list(self.values)!r}", key=f"{path}.values")
            return
        need, optional = DISTRIBUTION_PARAMS[self.distribution]
        for p in need:
            if getattr(self, p) is None:
                raise ConfigError(f"is missing (the {self.distribution} distribution needs {' and '.join(need)})",
                                  key=f"{path}.{p}")
        for p in params:
            if getattr(self, p) is not None and p not in need + optional:
                allowed = ", ".join(need + optional)
                raise ConfigError(f"is not a parameter of the {self.distribution} distribution (it takes {allowed})",
                                  key=f"{path}.{p}")
        lo, hi = self.low, self.high
        if lo is not None and hi is not None and not lo < hi:
            raise ConfigError(f"must be below high = {hi:g}, got {lo:g}", key=f"{path}.low")
        if self.distribution == "log-uniform" and lo <= 0:
            raise ConfigError(f"must be > 0 for a log-uniform distribution, got {lo:g}", key=f"{path}.low")
        if self.distribution == "normal" and self.mean is not None:
            if (lo is not None and self.mean < lo) or (hi is not None and self.mean > hi):
                raise ConfigError(f"{self.mean:g} is outside the truncation [low, high]", key=f"{path}.mean")

    @property
    def size(self) -> int:
        """How many values the grid has (without computing them)."""
        if self.values is not None:
            return len(self.values)
        return int(getattr(self, self.kind)[2])

    def grid(self) -> list:
        """The grid's values, in order."""
        import numpy as np

        if self.values is not None:
            return list(self.values)
        first, last, count = self.linspace if self.linspace is not None else self.logspace
        fn = np.linspace if self.linspace is not None else np.geomspace
        return [float(v) for v in fn(first, last, int(count))]

    def describe(self) -> str:
        """One line for reports: ``uniform in [0, 200]``, ``7 values 0.5 ... 2``."""
        k = self.kind
        if k == "values":
            return "grid " + ", ".join(_fmt(v) for v in self.values)
        if k in ("linspace", "logspace"):
            first, last, count = getattr(self, k)
            return f"grid of {int(count)} {'evenly' if k == 'linspace' else 'geometrically'} spaced values " \
                   f"{_fmt(first)} ... {_fmt(last)}"
        if k == "uniform":
            return f"uniform in [{_fmt(self.low)}, {_fmt(self.high)}]"
        if k == "log-uniform":
            return f"log-uniform in [{_fmt(self.low)}, {_fmt(self.high)}]"
        if k == "relative":
            return f"uniform within ±{_fmt(self.percent)} % of the base value"
        trunc = ""
        if self.low is not None or self.high is not None:
            trunc = f", truncated to [{_fmt(self.low) if self.low is not None else '-inf'}, " \
                    f"{_fmt(self.high) if self.high is not None else 'inf'}]"
        mean = _fmt(self.mean) if self.mean is not None else "the base value"
        return f"normal with mean {mean} and std {_fmt(self.std)}{trunc}"


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, (int, float)) else repr(v)


@dataclasses.dataclass(frozen=True)
class Varied:
    """One varied scenario key: its dotted name, how it varies, its value in the base scenario."""

    key: str
    how: VarySpec
    base: Any
    list_valued: bool = False  # a list key (plant.disturbance.amplitude): every entry gets the value


@section
class SweepSpec:
    """A validated sweep spec. ``varied``: the varied keys in the order written; ``overrides``:
    the ``[set]`` table and the command line's ``--set``, as (key, value) pairs; ``base``: the
    resolved base scenario (every check passed for every controller)."""

    name: str = param(doc="sweep name (the default output folder is results/NAME)")
    description: str = param("", doc="one line on what the sweep asks")
    scenario: str = param("paper", doc="base scenario: a shipped name or a TOML file (relative to the spec's folder)")
    controllers: tuple[str, ...] = param(None, doc="controllers to compare (default: the base scenario's "
                                                   "controller.kind)")
    samples: int = param(1, doc="random draws (taken at every grid point); 1 when nothing is drawn", ge=1,
                         le=MAX_DRAWS)
    seed: int = param(0, doc="seed of the random draws (draw i depends only on seed, key and i)", ge=0,
                      lt=2**63, allowed="a whole number >= 0 (below 2^63)")
    metrics: tuple[str, ...] = param(DEFAULT_METRICS, doc="metrics the report shows (the table holds every "
                                                                "metric)", allowed=_metrics_allowed)
    map_metric: str = param("rms_e_lam_last2s", doc="metric of the robustness maps (two-key grids)",
                            allowed=_metrics_allowed)
    max_out_of_contact: float = param(0.01, doc="a run held contact if it stayed bounded and was out of contact "
                                                "for at most this fraction of its steps after the verdict's "
                                                "contact_after (the force's build-up is not judged)", ge=0.0, le=1.0)
    varied: tuple = dataclasses.field(default=(), compare=True)
    overrides: tuple = dataclasses.field(default=(), compare=True)
    base: Any = dataclasses.field(default=None, compare=False, repr=False)
    source: str = dataclasses.field(default="<dict>", compare=False)

    # --- reading --------------------------------------------------------------------------------
    @property
    def grid_keys(self) -> list[str]:
        return [v.key for v in self.varied if v.how.is_grid]

    @property
    def drawn_keys(self) -> list[str]:
        return [v.key for v in self.varied if not v.how.is_grid]

    @property
    def points(self) -> int:
        """Number of grid points (1 without a grid)."""
        n = 1
        for v in self.varied:
            if v.how.is_grid:
                n *= v.how.size
        return n

    @property
    def n_runs(self) -> int:
        return self.points * self.samples * len(self.controllers)

    def to_dict(self, *, resolved: bool = False) -> dict:
        """The spec as plain TOML data. ``resolved``: as the output folder's ``sweep.toml``
        stores it, ``scenario = "scenario.toml"`` (the resolved base scenario beside it, with
        ``[set]`` and ``--set`` applied) and ``--samples`` folded in, so that
        ``hinfnn sweep DIR/sweep.toml --out DIR --resume`` continues the same sweep."""
        out = schema.to_dict(self)
        out = {k: v for k, v in out.items() if v is not None}
        if resolved:
            out["scenario"] = "scenario.toml"
        elif self.overrides:
            out["set"] = {k: _plain(v) for k, v in self.overrides}
        if self.varied:
            out["vary"] = {v.key: {k: _plain(x) for k, x in schema.to_dict(v.how).items() if x is not None}
                           for v in self.varied}
        return out

    def to_toml(self, *, resolved: bool = False) -> str:
        import tomli_w

        text = tomli_w.dumps(self.to_dict(resolved=resolved))
        if resolved and self.overrides:
            changes = ", ".join(f"{k} = {v!r}" for k, v in self.overrides)
            text = (f"# The sweep as run. scenario.toml is the base scenario with these changes applied: {changes}\n"
                    + text)
        return text

    def fingerprint(self) -> str:
        """A hash of everything that decides the table's rows: the resolved base scenario, the
        controllers, the varied keys, samples, seed and the contact criterion (not the name,
        description or the metrics the report shows). A resumed sweep must have the same."""
        doc = {"scenario": self.base.to_dict() if self.base is not None else None,
               "controllers": list(self.controllers or ()), "samples": self.samples, "seed": self.seed,
               "max_out_of_contact": self.max_out_of_contact,
               "vary": self.to_dict().get("vary", {}), "order": [v.key for v in self.varied]}
        return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def _plain(v):
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


def spec_table() -> str:
    """Markdown tables of a spec's keys and of a ``[vary]`` entry's keys (``docs/sweeps.md``)."""

    def table(rows, prefix=""):
        out = ["| key | meaning | allowed | default |", "|---|---|---|---|"]
        out += [f"| `{prefix}{k}` | {doc} | {allowed} | {default} |" for k, doc, allowed, default in rows]
        return "\n".join(out)

    return (table(schema.describe(SweepSpec)) + "\n\nEach entry of `[vary]`, keyed by a scenario key:\n\n"
            + table(schema.describe(VarySpec)))


# --- loading ---------------------------------------------------------------------------------------


def spec_names() -> list[str]:
    """Names of the sweep specs shipped with hinfnn."""
    folder = resources.files("hinfnn.sweep") / SHIPPED
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def read_spec_source(name_or_path) -> tuple[str, str, Path | None]:
    """(TOML text, where it came from, its folder or None for a shipped spec)."""
    text_name = str(name_or_path)
    if not text_name.strip():
        raise ConfigError(f"{text_name!r} is empty; give a sweep spec name (hinfnn sweep --list) or a .toml file")
    path = Path(text_name)
    if path.suffix == ".toml" or path.exists() or "/" in text_name:
        if path.is_dir():
            raise ConfigError(f"{text_name} is a folder; give a sweep spec name or a .toml file")
        try:
            return path.read_text(encoding="utf-8"), str(path), path.parent
        except FileNotFoundError:
            raise ConfigError(f"no sweep spec file {text_name}") from None
        except (OSError, UnicodeDecodeError) as err:
            raise ConfigError(f"cannot read sweep spec file {text_name}: {err}") from None
    names = spec_names()
    if text_name not in names:
        close = difflib.get_close_matches(text_name, names, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ConfigError(f"no sweep spec named {text_name!r} (shipped: {', '.join(names)}){hint}")
    resource = resources.files("hinfnn.sweep") / SHIPPED / f"{text_name}.toml"
    return resource.read_text(encoding="utf-8"), text_name, None


def load_spec(name_or_path="paper-uncertainty", *, samples: int | None = None, overrides=()) -> SweepSpec:
    """Read a shipped spec by name or a TOML file and validate it: the spec's keys, the base
    scenario with ``[set]`` and then ``overrides`` (``"k=v"`` strings or pairs, as ``--set``)
    applied and checked for every controller, every varied key and every grid value against
    the scenario's schema. ``samples`` replaces the spec's count (``--samples``)."""
    from ..scenario.core import parse_toml

    text, source, folder = read_spec_source(name_or_path)
    return spec_from_dict(parse_toml(text, source), samples=samples, overrides=overrides, source=source,
                          folder=folder)


def _flatten(table: dict, prefix: str, leaf) -> list[tuple[str, Any]]:
    """Dotted (key, value) pairs of a TOML table that may nest (``[vary.plant.arm.m1]``) or use
    quoted dotted keys (``[vary."plant.arm.m1"]``); ``leaf(value)`` says where to stop."""
    out = []
    for k, v in table.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, dict) and not leaf(v):
            if not v:
                raise ConfigError("is an empty table", key=key)
            out += _flatten(v, key, leaf)
        else:
            out.append((key, v))
    return out


def spec_from_dict(raw: dict, *, samples: int | None = None, overrides=(), source: str = "<dict>",
                   folder: Path | None = None) -> SweepSpec:
    """Build and validate a spec from its TOML table (see :func:`load_spec`)."""
    from ..scenario import Scenario
    from ..scenario.core import override_items

    if not isinstance(raw, dict):
        raise ConfigError(f"a sweep spec must be a table, got {raw!r}")
    raw = dict(raw)
    set_table = raw.pop("set", {})
    vary_table = raw.pop("vary", {})
    if samples is not None:
        if not is_integer(samples) or samples < 1:
            raise ConfigError(f"must be a whole number >= 1, got {samples!r}", key="--samples")
        raw["samples"] = int(samples)
    spec = schema.load(SweepSpec, raw)
    if not isinstance(set_table, dict):
        raise ConfigError(f"must be a table of scenario keys and values, got {set_table!r}", key="set")
    if not isinstance(vary_table, dict):
        raise ConfigError(f"must be a table with one entry per scenario key, got {vary_table!r}", key="vary")

    # the base scenario: the spec's [set], then the command line's --set
    items = [(f"{k}", v) for k, v in _flatten(set_table, "", lambda v: False)]
    cli_items = override_items(overrides)
    scenario_ref = spec.scenario
    if folder is not None and (scenario_ref.endswith(".toml") or "/" in scenario_ref) \
            and not Path(scenario_ref).is_absolute():
        scenario_ref = str(folder / scenario_ref)
    try:
        base = Scenario.load(scenario_ref, items, check=False)
    except ConfigError as err:
        raise _in_section(err, "set", items) from None
    if cli_items:
        base = base.with_overrides(cli_items)
    controllers = list(spec.controllers) if spec.controllers is not None else base.kinds
    _check_controllers(controllers)
    base = base.with_overrides([("controller.kind", controllers)])
    base.check()  # every controller: bad gains, a bad horizon ... are spec errors, not rows

    # the varied keys
    leaves = {k: (tp, meta, v) for k, tp, meta, v in schema.leaves(base)}
    known_vary = {f.name for f in dataclasses.fields(VarySpec)}
    hows = []
    for key, table in _flatten(vary_table, "", lambda v: bool(set(v) & known_vary)):
        where = f"vary.{key}"
        if key in RESERVED:
            raise ConfigError(f"cannot be varied: {RESERVED[key]}", key=where)
        if key not in leaves:
            raise ConfigError(f"{_not_a_key(key, base)} (see `hinfnn keys`)", key=where)
        if not isinstance(table, dict):
            raise ConfigError(f"must be a table such as {{ values = [...] }} or {{ distribution = \"uniform\", "
                              f"low = ..., high = ... }}, got {table!r}", key=where)
        hows.append((key, schema.load(VarySpec, table, path=f"{where}.")))
    _check_size(hows, spec.samples, len(controllers), "--samples" if samples is not None else "samples")
    varied = [_check_varied(key, how, leaves[key][0], leaves[key][2], base) for key, how in hows]
    if not varied and spec.samples > 1:
        raise ConfigError(f"is {spec.samples} but nothing is drawn (no distribution in [vary]): the runs would "
                          "be identical", key="--samples" if samples is not None else "samples")
    if varied and not any(not v.how.is_grid for v in varied) and spec.samples > 1:
        raise ConfigError(f"is {spec.samples} but [vary] has only grids: nothing is drawn, the runs at a "
                          "grid point would be identical", key="--samples" if samples is not None else "samples")
    _check_metric_names(spec.metrics, "metrics")
    _check_metric_names((spec.map_metric,), "map_metric")
    return dataclasses.replace(spec, controllers=tuple(controllers), varied=tuple(varied),
                               overrides=tuple(items) + tuple(cli_items), base=base, source=source)


def _in_section(err: ConfigError, section_name: str, items) -> ConfigError:
    """An error in a [set] value names its place in the spec."""
    if err.key is not None and any(err.key == k for k, _ in items):
        return ConfigError(str(err).split(": ", 1)[1], key=f"{section_name}.{err.key}")
    return err


def _check_controllers(controllers):
    from ..controllers import KINDS

    for k in controllers:
        if k not in KINDS:
            close = difflib.get_close_matches(k, list(KINDS), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(f"unknown controller {k!r}; allowed: {', '.join(KINDS)}{hint}", key="controllers")
    if len(set(controllers)) != len(controllers):
        raise ConfigError(f"lists a controller twice: {list(controllers)}", key="controllers")


def _check_metric_names(names, key):
    per_joint = re.compile(rf"({'|'.join(PER_JOINT_METRICS)})_(\d+)\Z")
    for name in names:
        if name in BOOL_METRICS:
            raise ConfigError(f"{name!r} is true or false; the report gives the fraction where it holds", key=key)
        if name in METRIC_KEYS or per_joint.match(name):
            continue
        numeric = [m for m in METRIC_KEYS if m not in BOOL_METRICS]
        close = difflib.get_close_matches(name, numeric, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ConfigError(f"unknown metric {name!r}{hint}; allowed: {', '.join(numeric)}", key=key)


def _is_number_type(tp) -> bool:
    """float, or a union with float (``beta_lam: "min" | float``)."""
    return tp is float or (schema._is_union(tp) and float in typing.get_args(tp))


def _not_a_key(key: str, base) -> str:
    """Why ``key`` is not a key of the base scenario, in the scenario loader's words: it knows the
    kinds the base chose (``plant.arm.m1`` on a URDF arm is refused at ``plant.arm.model``), so
    the suggestion is a key this scenario takes."""
    from ..scenario import Scenario

    try:
        Scenario.from_dict(base.to_dict(), [(key, 0.0)], source=base.source, check=False)
    except ConfigError as err:
        if err.key == key:
            return f"is not a key of the base scenario: {str(err).split(': ', 1)[1]}"
        return f"is not a key of the base scenario: {err}"
    return "is not a key of the base scenario"


def _check_size(hows, samples: int, controllers: int, samples_key: str) -> None:
    """Refuse, before anything is computed, a sweep whose grid points × samples exceed
    :data:`MAX_DRAWS` (each count is capped on its own; their product is capped here), naming the
    product, the cap and the counts to lower."""
    grids = [(key, how.size) for key, how in hows if how.is_grid]
    points = 1
    for _, size in grids:
        points *= size
    draws = points * samples
    if draws <= MAX_DRAWS:
        return
    counts = " × ".join(f"{size:,} ({key})" for key, size in grids)
    product = f"{counts}{f' × {samples:,} samples' if samples > 1 else ''}" if grids else f"{samples:,} samples"
    lower = "lower a grid's count or values" + (f" or {samples_key}" if samples > 1 else "")
    raise ConfigError(f"the sweep would take {product} = {draws:,} draws ({draws * controllers:,} runs with "
                      f"{controllers} controller{'s' if controllers > 1 else ''}), above the cap of "
                      f"{MAX_DRAWS:,} draws: {lower}", key="vary")


def _check_varied(key: str, how: VarySpec, tp, base_value, base) -> Varied:
    """Check a varied key against the scenario's schema: its type suits the way it varies,
    every grid value is a valid value, a distribution's range lies inside the key's range."""
    from ..scenario import Scenario

    where = f"vary.{key}"
    list_valued = typing.get_origin(tp) is tuple and typing.get_args(tp)[0] is float
    numeric = tp is float or list_valued or _is_number_type(tp)
    if not how.is_grid:
        if tp is int:
            raise ConfigError(f"{key} is a whole number; vary it with values = [...]", key=f"{where}.distribution")
        if not numeric:
            raise ConfigError(f"{key} is not a number; vary it with values = [...]", key=f"{where}.distribution")
        if how.distribution == "relative":
            scale = max(abs(x) for x in base_value) if list_valued else base_value
            if not isinstance(scale, (int, float)) or scale == 0:
                raise ConfigError(f"the base value of {key} is {base_value!r}: ±{how.percent:g} % of it is "
                                  "always the same; use uniform low/high", key=f"{where}.percent")
    elif how.kind in ("linspace", "logspace") and not numeric:
        raise ConfigError(f"{key} is {'a whole number' if tp is int else 'not a number'}; use values = [...]",
                          key=f"{where}.{how.kind}")
    elif how.values is not None and list_valued and not all(is_real(v) for v in how.values):
        raise ConfigError(f"{key} is a list of numbers; give numbers (each sets every entry)", key=f"{where}.values")

    # values checked by the scenario's own schema (type and range)
    def probe(value, what):
        v = [value] * len(base_value) if list_valued else value
        try:
            Scenario.from_dict(base.to_dict(), [(key, v)], source=base.source, check=False)
        except ConfigError as err:
            if err.key == key or (err.key or "").startswith(key + "["):
                raise ConfigError(f"{what}: {str(err).split(': ', 1)[1]}", key=where) from None
            raise ConfigError(f"{what}: {err}", key=where) from None

    if how.is_grid:
        grid = how.grid()
        if how.kind != "values" and tp is not int:  # monotonic: the ends decide a range
            grid = [grid[0], grid[-1]]
        for v in grid:
            probe(int(v) if tp is int and isinstance(v, float) and v.is_integer() else v,
                  f"grid value {_fmt(v)}")
    elif how.distribution in ("uniform", "log-uniform") or (how.distribution == "normal" and
                                                               how.low is not None and how.high is not None):
        span = how.high - how.low
        probe(how.low + 1e-9 * span, f"the low end {how.low:g}")
        probe(how.high - 1e-9 * span, f"the high end {how.high:g}")
    elif how.distribution == "relative" and not list_valued:
        for sign in (-1, 1):
            probe(base_value * (1 + sign * (how.percent / 100) * (1 - 1e-9)),
                  f"{'-' if sign < 0 else '+'}{how.percent:g} % of {base_value:g}")
    return Varied(key=key, how=how, base=base_value, list_valued=list_valued)


__all__ = ["SweepSpec", "VarySpec", "Varied", "load_spec", "spec_from_dict", "spec_names", "spec_table", "DEFAULT_METRICS",
           "PER_JOINT_METRICS", "PER_COORDINATE_METRICS", "BOOL_METRICS", "GRIDS", "DISTRIBUTIONS"]
