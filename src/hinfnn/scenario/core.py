"""A scenario: the typed root section, loading from TOML with ``base`` inheritance and overrides,
the cross-field checks, and the runs it describes.

A scenario has the sections ``plant`` (the truth), ``nominal`` (what the controller is told),
``task`` (the task coordinates; default: the arm's native ones), ``controller``, ``reference``,
``initial`` and ``simulation``; ``files/paper.toml`` is the paper's Sec. VI with a comment on
every value the paper does not state, ``planar3-drum``, ``ur5-table`` and ``ur5-sphere`` the
shipped arms-and-surfaces scenarios (docs/arms-and-surfaces.md). A file gives every key,
or names a ``base`` (a shipped name or a path) and gives only what differs.

Everything is checked before anything is compiled: types and ranges (the section dataclasses,
:mod:`hinfnn.scenario.schema`), then the cross-field conditions (dt dividing t_final and the
disturbance's half-period, the start pose, the RK4 step against the contact's natural
frequency) and the controller design (Theorem 1/2 bounds, Riccati) in :meth:`Scenario.check`.
Errors are :class:`~hinfnn.errors.ConfigError` or :class:`~hinfnn.errors.DesignError` naming
the dotted key.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import functools
import math
import tomllib
from collections.abc import Iterable
from importlib import resources
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from . import schema
from .schema import param, section
from .sections import (ControllerConfig, InitialConfig, JobConfig, NativeTaskConfig, NominalConfig, PlantConfig,
                       ReferenceConfig, SafetyConfig, SimulationConfig, TaskConfig, VerdictConfig)

SHIPPED = "files"


@section
class Scenario:
    """A validated scenario. Read it as typed attributes (``sc.plant.arm.m1``); ``source`` is
    where it came from and ``overrides`` the typed ``(key, value)`` pairs applied on top, in order.
    """

    name: str = param(doc="scenario name")
    description: str = param(doc="one line on what the scenario is")
    plant: PlantConfig = param(doc="the truth")
    nominal: NominalConfig = param(doc="the nominal model")
    task: TaskConfig = param(NativeTaskConfig(map="native"), doc="the task coordinates")
    controller: ControllerConfig = param(doc="the controller")
    reference: ReferenceConfig = param(doc="the desired motion and force")
    initial: InitialConfig = param(doc="the start")
    simulation: SimulationConfig = param(doc="the simulation")
    verdict: VerdictConfig = param(VerdictConfig(), doc="when a run did its job")
    safety: SafetyConfig = param(SafetyConfig(), doc="the safety layer of a robot loop (hinfnn robot run)")
    job: JobConfig = param(JobConfig(), doc="the phases of a job: start in contact (the paper) or approach from "
                           "free space")
    source: str = dataclasses.field(default="<dict>", compare=False)
    overrides: tuple = dataclasses.field(default=(), compare=False)

    # --- construction ------------------------------------------------------------------------------
    @classmethod
    def load(cls, name_or_path: str | Path = "paper", overrides=(), *, check: bool = True) -> "Scenario":
        """Read a shipped scenario by name or a TOML file, apply ``overrides`` (``"k=v"``
        strings, ``(key, value)`` pairs or a mapping of dotted keys to values) and validate."""
        raw, source = load_raw(name_or_path)
        return cls.from_dict(raw, overrides, source=source, check=check)

    @classmethod
    def from_dict(cls, raw: dict, overrides=(), *, source: str = "<dict>", check: bool = True) -> "Scenario":
        """Build from a plain dict (the TOML table), resolving ``base`` and applying overrides."""
        items = _resolve_set_paths(override_items(overrides), source)
        data = resolve_base(_resolve_paths(raw, source), source)
        if items:
            before, given = copy.deepcopy(data), {}
            for key, value in items:
                set_key(data, key, value)
                set_key(given, key, value)
            schema.drop_switched(cls, before, data, given)  # --set plant.surface.kind=sphere: as a file would
        try:
            sc = schema.load(cls, data)
        except ConfigError as err:
            raise _unknown_override(err, items) from None
        sc = _normalise_presets(sc, explicit=_preset_keys(raw, items))
        sc = dataclasses.replace(sc, source=source, overrides=tuple(items))
        if check:
            sc.check()
        return sc

    def with_overrides(self, overrides) -> "Scenario":
        """A new scenario with more overrides applied (``overrides`` lists all of them)."""
        new = Scenario.from_dict(self.to_dict(), overrides, source=self.source)
        return dataclasses.replace(new, overrides=self.overrides + new.overrides)

    def single(self, kind: str) -> "Scenario":
        """This scenario with one controller kind."""
        return dataclasses.replace(self, controller=dataclasses.replace(self.controller, kind=kind))

    # --- reading ---------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The resolved scenario as a plain nested dict (what ``scenario.toml`` holds)."""
        return schema.to_dict(self)

    def to_toml(self) -> str:
        """The resolved scenario as TOML text (loads back to the same scenario)."""
        import tomli_w

        return tomli_w.dumps(self.to_dict(), multiline_strings=False)

    def get(self, key: str):
        """The value at a dotted key (``"plant.contact.damping"``)."""
        node: Any = self
        for part in key.split("."):
            node = getattr(node, part)
        return node

    @property
    def kinds(self) -> list[str]:
        return self.controller.kinds

    # --- building the library objects ----------------------------------------------------------------
    def build(self):
        """The scenario's objects, each built once (:class:`~hinfnn.scenario.setup.Setup`): task
        map, true plant, nominal arm and constraint, reference, start pose, controllers by kind,
        simulation options, coordinate and joint names."""
        return self._setup

    @functools.cached_property
    def _setup(self):
        from .setup import Setup

        return Setup(self)

    def task_map(self):
        """The task map both arms are built with; None for the arm's native coordinates."""
        return self.build().task

    @property
    def n_extra(self) -> int:
        """The number of extra task coordinates (``task.extra``)."""
        return len(self.task.extra)

    @property
    def extra_start(self):
        """The extra coordinates' values at the start pose (:attr:`Setup.extra_start`)."""
        return self.build().extra_start

    def build_plant(self):
        """The true plant (``plant.engine`` chooses the class)."""
        return self.build().plant

    def build_constraint(self):
        """The controller's constraint θ̂(x) in task coordinates (:attr:`Setup.constraint`)."""
        return self.build().constraint

    def coordinate_names(self) -> list[tuple[str, str]] | None:
        """Names and units of the task coordinates, or None for the two_link arm's (x1, x2)."""
        return self.build().coordinate_names

    def joint_names(self) -> list[str]:
        """The moving joints' names (URDF), or joint1 … jointn."""
        return self.build().joint_names

    def build_reference(self):
        """The reference (:attr:`Setup.reference`)."""
        return self.build().reference

    @property
    def control_period(self) -> float | None:
        """The period the controller runs at (:attr:`Setup.control_period`)."""
        return self.build().control_period

    def build_controller(self, kind: str | None = None):
        """Design the controller ``kind`` (default: the scenario's only kind) from the NOMINAL
        model. Raises :class:`DesignError` with the dotted key of the failing gain."""
        return self.build().controller(kind)

    def initial_q(self, plant=None):
        """The start pose (the truth: inverse kinematics of the true arm onto the true surface,
        within the true arm's joint limits); ``plant``: another plant than the scenario's own."""
        return self.build().q0 if plant is None else self.build().start_pose(plant)

    def sim_options(self) -> dict:
        """Keyword arguments of :func:`hinfnn.simulate` for this scenario."""
        return self.build().options()

    def run(self, kind: str | None = None, name: str | None = None, *, info=None, controller=None):
        """The :class:`hinfnn.sim.Run` of one controller kind (default: the only one)."""
        return self.build().run(kind, name, info=info, controller=controller)

    def simulate(self, kind: str | None = None, **options):
        """Run one controller (default: the only kind) and return its Trajectory."""
        from ..sim import simulate

        r = self.run(kind)
        opts = {**self.sim_options(), **options}
        return simulate(r.plant, r.controller, r.reference, q0=r.q0, info=r.info, **opts)

    def disturbance_effect(self):
        """The joint disturbance's steady effect on each motion coordinate through the nominal loop,
        (name, unit, estimate): :func:`hinfnn.scenario.checks.disturbance_effect`."""
        from .checks import disturbance_effect

        return disturbance_effect(self)

    # --- the checks that need the models ---------------------------------------------------------------
    def check(self) -> None:
        """Cross-field and design checks (no compilation of a run). Raises ConfigError/DesignError."""
        from .checks import check

        check(self)


# --- files and overrides ------------------------------------------------------------------------------


def scenario_names() -> list[str]:
    """Names of the scenarios shipped with hinfnn."""
    folder = resources.files("hinfnn.scenario") / SHIPPED
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def read_source(name_or_path: str | Path) -> tuple[str, str]:
    """(TOML text, where it came from) for a shipped scenario name or a file path."""
    text_name = str(name_or_path)
    if not text_name.strip():
        raise ConfigError(f"{text_name!r} is empty; give a scenario name (hinfnn scenarios) or a .toml file")
    path = Path(text_name)
    if path.suffix == ".toml" or path.exists() or "/" in text_name:
        if path.is_dir():
            raise ConfigError(f"{text_name} is a folder; give a scenario name or a .toml file")
        try:
            return path.read_text(encoding="utf-8"), str(path)
        except FileNotFoundError:
            raise ConfigError(f"no scenario file {text_name}") from None
        except (OSError, UnicodeDecodeError) as err:
            raise ConfigError(f"cannot read scenario file {text_name}: {err}") from None
    names = scenario_names()
    if text_name not in names:
        close = difflib.get_close_matches(text_name, names, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ConfigError(f"no scenario named {text_name!r} (shipped: {', '.join(names)}){hint}")
    resource = resources.files("hinfnn.scenario") / SHIPPED / f"{text_name}.toml"
    return resource.read_text(encoding="utf-8"), text_name


def parse_toml(text: str, source: str = "<string>") -> dict:
    """The TOML table of ``text``; a leading UTF-8 byte-order mark (which some Windows editors
    write) is skipped, as TOML readers that open files as ``utf-8-sig`` do."""
    try:
        return tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{source} is not valid TOML: {err}") from None


def load_raw(name_or_path) -> tuple[dict, str]:
    text, source = read_source(name_or_path)
    return parse_toml(text, source), source


def parse_override(item: str) -> tuple[str, Any]:
    """``"a.b.c=value"`` -> ("a.b.c", value), the value read as TOML (bare words as strings)."""
    if "=" not in item:
        raise ConfigError(f"override {item!r} must look like dotted.key=value")
    key, raw = item.split("=", 1)
    key, raw = key.strip(), raw.strip()
    if not key:
        raise ConfigError(f"override {item!r} has no key before '='")
    if raw == "":
        raise ConfigError("needs a value after '='", key=key)
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        lowered = raw.lower()
        if lowered in ("nan", "+nan", "-nan", "inf", "+inf", "-inf"):
            value = float(lowered)
        else:
            value = raw  # a bare word such as hinf or paper-likely
    return key, value


def override_items(overrides) -> list[tuple[str, Any]]:
    """``(key, value)`` pairs of a dict, of ``"key=value"`` strings or of pairs, the values as TOML
    would give them (:func:`~hinfnn.scenario.schema.plain`: NumPy values as Python's)."""
    allowed = ("a dict of dotted keys to values, or a list of 'key=value' strings or (key, value) pairs, "
               "e.g. {'plant.arm.m1': 2.0} or ['plant.arm.m1=2.0']")
    if isinstance(overrides, dict):
        items = list(overrides.items())
    elif isinstance(overrides, (str, bytes)) or not isinstance(overrides, Iterable):
        raise ConfigError(f"must be {allowed}, got {overrides!r:.80}", key="overrides")
    else:
        items = []
        for o in overrides:
            if isinstance(o, str):
                items.append(parse_override(o))
                continue
            pair = tuple(o) if isinstance(o, Iterable) and not isinstance(o, (bytes, dict)) else ()
            if len(pair) != 2:
                raise ConfigError(f"must be {allowed}; {o!r:.80} is neither", key="overrides")
            items.append(pair)
    for k, _ in items:
        if not isinstance(k, str):
            raise ConfigError(f"keys must be dotted scenario keys (strings), got {k!r:.80}", key="overrides")
    return [(k, schema.plain(v)) for k, v in items]


def set_key(data: dict, key: str, value: Any) -> None:
    """Set a dotted key in nested dicts (the schema then checks that the key exists)."""
    parts = key.split(".")
    if any(p == "" for p in parts):
        raise ConfigError("is not a dotted key (an empty part)", key=key)
    node = data
    for part in parts[:-1]:
        if not isinstance(node.get(part), dict):
            if part in node:
                raise ConfigError(f"{part!r} is a value, not a section", key=key)
            node[part] = {}
        node = node[part]
    if isinstance(node.get(parts[-1]), dict) and not isinstance(value, dict):
        raise ConfigError(f"is a section, not a value; set one of its keys: {', '.join(sorted(node[parts[-1]]))}",
                          key=key)
    node[parts[-1]] = value


def deep_merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _identity(source: str) -> str:
    """A scenario's identity for cycle detection: the resolved path of a file, else its name."""
    return str(Path(source).resolve()) if Path(source).exists() else str(source)


def resolve_base(raw: dict, source: str, _chain: tuple = ()) -> dict:
    """The raw table with its ``base`` chain merged in (the file's own values win)."""
    raw = dict(raw)
    base = raw.pop("base", None)
    if base is None:
        return copy.deepcopy(raw)
    if not isinstance(base, str):
        raise ConfigError(f"must be the name or path of a scenario, got {base!r}", key="base")
    if base == source:
        raise ConfigError("a scenario cannot be its own base", key="base")
    base_path = Path(base)
    if (base_path.suffix == ".toml" or "/" in base) and not base_path.is_absolute() \
            and source != "<dict>" and Path(source).exists():
        base = str(Path(source).parent / base_path)
    chain = _chain + (_identity(source),)
    if _identity(base) in chain:
        raise ConfigError(f"{base!r} makes a cycle: {' -> '.join(chain + (_identity(base),))}", key="base")
    try:
        base_raw, base_source = load_raw(base)
    except ConfigError as err:
        if err.key is not None:
            raise
        raise ConfigError(str(err), key="base") from None
    resolved = resolve_base(_resolve_paths(base_raw, base_source), base_source, chain)
    merged = deep_merge(resolved, raw)
    schema.drop_switched(Scenario, resolved, merged, raw)  # a file that switches kind lists the new kind's keys
    return merged


def _resolve_paths(raw: dict, source: str) -> dict:
    """URDF paths (``*.arm.file``) and a user's MJCF (``plant.mjcf.file``) relative to the
    scenario file that names them, made absolute (so a scenario.toml written elsewhere still finds
    them): a value is a path when a file or folder of that name exists beside the scenario, or
    when it looks like one (a '/' or an extension) and is not the name of a shipped robot or MJCF
    model (then the error names the path tried). A value given with ``--set`` is resolved by
    :func:`_resolve_set_paths`."""
    if source == "<dict>" or not Path(source).is_file():
        return raw
    out = raw
    for who, section, suffix in _FILE_KEYS:
        part = raw.get(who, {}).get(section) if isinstance(raw.get(who), dict) else None
        f = part.get("file") if isinstance(part, dict) else None
        if not isinstance(f, str) or not f or Path(f).is_absolute():
            continue
        candidate = Path(source).parent / f
        if candidate.exists() or _names_a_file(f, suffix):
            if out is raw:
                out = copy.deepcopy(raw)
            out[who][section]["file"] = str(candidate.resolve())
    return out


def _resolve_set_paths(items, source: str) -> list:
    """The override pairs with each relative file path (``plant.arm.file``, ``nominal.arm.file``,
    ``plant.mjcf.file``) found: a file of that name in the working directory (a path typed in a
    shell) is kept as given; else one beside the scenario file (a scenario loaded from a file) is
    made absolute; a value naming a file in both places that are not the same file is refused
    (ConfigError at the key naming both: give an absolute path); a value that looks like a path (a
    '/' or an extension), is no shipped robot or model and is in neither place is refused naming
    both places tried. Anything else (a shipped name, an absolute path) is kept for the section's
    own reading of it."""
    keys = {f"{who}.{section}.file": suffix for who, section, suffix in _FILE_KEYS}
    folder = Path(source).parent if source != "<dict>" and Path(source).is_file() else None
    out = []
    for key, value in items:
        if key in keys and isinstance(value, str) and value and not Path(value).is_absolute():
            value = _set_path(key, value, folder, keys[key])
        out.append((key, value))
    return out


def _set_path(key: str, value: str, folder, suffix: str) -> str:
    from ..model.urdf import shipped_robots

    here = Path(value)
    beside = folder / value if folder is not None else None
    if beside is not None and beside.exists():
        if not here.exists():
            return str(beside.resolve())
        if here.resolve() != beside.resolve():
            raise ConfigError(f"{value!r} names two files, {here.resolve()} (from the working directory) and "
                              f"{beside.resolve()} (beside the scenario file): give an absolute path", key=key)
        return value
    if not here.exists() and _names_a_file(value, suffix):
        tried = f"{here.resolve()} (from the working directory)"
        if beside is not None:
            tried = f"neither {tried} nor {beside.resolve()} (beside the scenario file)"
        what = "a URDF" if suffix == ".urdf" else "an MJCF"
        raise ConfigError(f"{value}: no such file: {tried}; give the path of {what} file or the name of "
                          f"one shipped with hinfnn ({', '.join(repr(k) for k in shipped_robots(suffix))})", key=key)
    return value


def _names_a_file(value: str, suffix: str) -> bool:
    """Whether a file key's ``value`` is meant as a path: it looks like one (a '/' or an extension)
    and is not the name of a robot or model shipped with hinfnn (files ending in ``suffix``)."""
    from ..model.urdf import shipped_robots

    return ("/" in value or Path(value).suffix != "") and value not in shipped_robots(suffix)


#: The scenario keys that name a file: (section, subsection, the suffix of the shipped files).
_FILE_KEYS = (("plant", "arm", ".urdf"), ("nominal", "arm", ".urdf"), ("plant", "mjcf", ".xml"))


def suggest_key(key: str) -> str:
    """"; did you mean 'x.y'?" for a dotted key that is not a scenario key (or "")."""
    known = schema.all_keys(Scenario)
    close = difflib.get_close_matches(key, known, n=1, cutoff=0.5)
    if not close:
        leaf = key.rsplit(".", 1)[-1]
        close = [k for k in known if k.rsplit(".", 1)[-1] == leaf][:1]
    return f"; did you mean {close[0]!r}?" if close else ""


def _unknown_override(err: ConfigError, items) -> ConfigError:
    """An unknown-key error found at a prefix of an override's key names the whole key."""
    if err.key is None or "unknown key" not in str(err):
        return err
    for key, _ in items:
        if key == err.key:
            return err  # the schema's suggestion knows the kind chosen (plant.arm.mass2 -> m2 on a two_link arm)
        if key.startswith(err.key + "."):
            return ConfigError(f"unknown key{suggest_key(key)}", key=key)
    return err


def load_scenario(name_or_path: str | Path = "paper", overrides=(), *, check: bool = True) -> Scenario:
    """Shortcut for :meth:`Scenario.load`."""
    return Scenario.load(name_or_path, overrides, check=check)


# --- the F_f presets ------------------------------------------------------------------------------------


def _preset_keys(raw: dict, items) -> set:
    """The network_f centre keys set explicitly in the layer that last set the preset: an
    override of the preset replaces the centres of the file (or the data being re-overridden)
    unless the same overrides set centres too."""
    from_items = {key.rsplit(".", 1)[-1] for key, _ in items if key.startswith("controller.network_f.")}
    if "preset" in from_items:
        return from_items
    nf = raw.get("controller", {}).get("network_f", {}) if isinstance(raw.get("controller"), dict) else {}
    return from_items | (set(nf) if isinstance(nf, dict) else set())


def _normalise_presets(sc: Scenario, explicit: set) -> Scenario:
    """A preset fixes F_f's centres; setting a centre key with a preset other than "custom" is an
    error unless it equals the preset's value. Setting only the preset updates the centres."""
    from ..controllers import CENTRE_PRESETS_F

    nf = sc.controller.network_f
    if nf.preset == "custom":
        return sc
    values = dict(zip(("centre_start", "centre_step", "centre_count"), CENTRE_PRESETS_F[nf.preset]))
    for key, value in values.items():
        given = getattr(nf, key)
        if key in explicit and (isinstance(given, tuple)
                                or not math.isclose(given, value, rel_tol=1e-12, abs_tol=1e-12)):
            shown = list(given) if isinstance(given, tuple) else f"{given:g}"
            raise ConfigError(f"{shown} conflicts with preset {nf.preset!r} ({key} = {value:g}); "
                              "set controller.network_f.preset = \"custom\" to choose the centres",
                              key=f"controller.network_f.{key}")
    values = {k: (int(v) if k == "centre_count" else float(v)) for k, v in values.items()}
    return dataclasses.replace(sc, controller=dataclasses.replace(
        sc.controller, network_f=dataclasses.replace(nf, **values)))


def keys() -> list[tuple[str, str, str, str]]:
    """Every scenario key: (dotted key, meaning, allowed values, default)."""
    return schema.describe(Scenario)


def schema_table() -> str:
    """A Markdown table of every key, for the docs and ``hinfnn keys``."""
    rows = ["| key | meaning | allowed | default |", "|---|---|---|---|"]
    rows += [f"| `{k}` | {doc} | {allowed} | {default} |" for k, doc, allowed, default in keys()]
    return "\n".join(rows)


__all__ = ["Scenario", "load_scenario", "scenario_names", "parse_override", "keys", "schema_table"]
