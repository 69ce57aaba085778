"""Scenarios as TOML files: load, override, validate, build the objects, run.

A scenario has the sections ``plant`` (the truth), ``nominal`` (what the controller is told),
``controller``, ``reference``, ``initial`` and ``simulation``; ``scenarios/paper.toml`` is the
paper's Sec. VI with a comment on every value the paper does not state. :data:`SCHEMA` lists
every key with its type, range and meaning; a key that is not in it is an error that names the
closest valid one.

Everything is checked before anything is compiled: types and ranges (:func:`validate`), then
the cross-field conditions (dt dividing t_final and the disturbance's half-period, the start
pose, the RK4 step against the contact's natural frequency) and the controller design
(Theorem 1/2 bounds, Riccati) in :meth:`Scenario.check`. Errors are
:class:`~hinfnn.errors.ConfigError` or :class:`~hinfnn.errors.DesignError` naming the dotted key.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ConfigError, DesignError

KINDS = ("fl", "hinf", "hinf_nn")
KIND_LABELS = {"fl": "FL-like", "hinf": "H∞-only", "hinf_nn": "adaptive H∞ NN"}


# --- the schema ------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Field:
    """One scalar or array entry of a scenario."""

    type: str  # "float", "int", "bool", "str", "float_list", "matrix", "kinds", "float_or_min"
    doc: str
    lo: float | None = None  # lower bound
    hi: float | None = None  # upper bound
    lo_open: bool = False  # lo excluded
    hi_open: bool = False
    choices: tuple | None = None
    length: int | None = None  # for float_list

    def allowed(self) -> str:
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {self.lo:g}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {self.hi:g}")
        kind = {"float": "a number", "int": "an integer", "bool": "true or false", "str": "a string",
                "float_list": f"a list of {self.length} numbers", "matrix": "a number or a square matrix",
                "kinds": f"one of {KINDS} or a list of them",
                "float_or_min": '"min" or a number'}[self.type]
        return kind + (" " + " and ".join(parts) if parts else "")


def _pos(doc, hi=None):
    return Field("float", doc, lo=0.0, lo_open=True, hi=hi)


def _arm(who):
    return {
        "model": Field("str", "arm model", choices=("two_link",)),
        "m1": _pos(f"{who} link-1 tip mass, kg", hi=1e4),
        "m2": _pos(f"{who} link-2 tip mass, kg", hi=1e4),
        "l1": _pos(f"{who} link-1 length, m", hi=100.0),
        "l2": _pos(f"{who} link-2 length, m", hi=100.0),
        "g": Field("float", "gravity, m/s^2", lo=0.0, hi=100.0),
    }


def _surface(who):
    return {
        "kind": Field("str", "surface kind", choices=("inclined_line",)),
        "delta_deg": Field("float", f"{who} slope delta, degrees", lo=-89.0, hi=89.0),
        "d_G": Field("float", "horizontal offset d_G of the line, m", lo=-100.0, hi=100.0),
    }


def _network(which):
    return {
        "centre_start": Field("float", "first centre c_1", lo=-1e6, hi=1e6),
        "centre_step": _pos("spacing of the centres", hi=1e6),
        "centre_count": Field("int", "number of hidden units", lo=1, hi=5000),
        "slope": _pos("tanh slope alpha of eq. (17)", hi=1e6),
        "w_a": Field("float", f"weight of {which[0]} in the network input", lo=-1e6, hi=1e6),
        "w_b": Field("float", f"weight of {which[1]} in the network input", lo=-1e6, hi=1e6),
        "projection": Field("bool", "Remark 2 projection onto ||Theta|| <= radius"),
        "radius": _pos("projection radius d (Remark 2)", hi=1e12),
    }


SCHEMA: dict[str, Any] = {
    "name": Field("str", "scenario name"),
    "description": Field("str", "one line on what the scenario is"),
    "plant": {
        "arm": _arm("true"),
        "surface": _surface("true"),
        "contact": {
            "stiffness": _pos("contact stiffness k, N/m", hi=1e10),
            "damping": Field("float", "contact damping c, N s/m", lo=0.0, hi=1e8),
        },
        "disturbance": {
            "amplitude": Field("float_list", "square-wave amplitude per joint, N m", lo=-1e6, hi=1e6, length=2),
            "period": _pos("square-wave period, s", hi=1e6),
            "phase": Field("float", "square-wave phase (time of the first + edge), s", lo=-1e6, hi=1e6),
        },
    },
    "nominal": {
        "arm": _arm("nominal"),
        "surface": {**_surface("nominal"),
                    "scaling": Field("str", "constraint scaling", choices=("paper", "unit"))},
    },
    "controller": {
        "kind": Field("kinds", "controller(s) to run"),
        "augmented": Field("bool", "Remark 1 augmented performance (eq. 40, v_lam = -beta_lam e_lam)"),
        "gains": {
            "rho": _pos("attenuation level rho", hi=1e6),
            "mu_z": _pos("mu_z of eq. (27)", hi=1e8),
            "K_p": _pos("position gain K_p", hi=1e8),
            "K_v": _pos("velocity gain K_v", hi=1e8),
            "alpha_lam": _pos("force weight alpha_lam", hi=1e8),
            "alpha_z": _pos("alpha_z of eq. (27)", hi=1e8),
            "beta_lam": Field("float_or_min", "beta_lam of eq. (32), or \"min\" for its Theorem 1 bound",
                              lo=0.0, lo_open=True, hi=1e8),
            "gamma_1": _pos("learning rate gamma_1 of eq. (30)", hi=1e8),
            "gamma_2": _pos("learning rate gamma_2 of eq. (31)", hi=1e8),
            "Q_p": Field("matrix", "weight Q_p (2x2, symmetric positive definite)", lo=-1e8, hi=1e8),
            "R_p": Field("matrix", "weight R_p (1x1 for the planar arm)", lo=-1e8, hi=1e8),
        },
        "network_p": _network(("e_u1", "e_u1_dot")),
        "network_f": {
            "preset": Field("str", "F_f centre preset", choices=("paper-likely", "paper-printed", "custom")),
            **_network(("e_lam", "z")),
        },
    },
    "reference": {
        "u1_offset": Field("float", "u1d offset, m", lo=-100.0, hi=100.0),
        "u1_amplitude": Field("float", "u1d cosine amplitude, m", lo=-100.0, hi=100.0),
        "u1_period": _pos("u1d period, s", hi=1e6),
        "u1_phase": Field("float", "u1d phase, rad", lo=-1e3, hi=1e3),
        "lam_offset": Field("float", "lam_d offset", lo=-1e7, hi=1e7),
        "lam_amplitude": Field("float", "lam_d cosine amplitude", lo=-1e7, hi=1e7),
        "lam_period": _pos("lam_d period, s", hi=1e6),
        "lam_phase": Field("float", "lam_d phase, rad", lo=-1e3, hi=1e3),
    },
    "initial": {
        "u1": Field("float", "u1(0): true end-effector x1 on the true surface, m", lo=-100.0, hi=100.0),
        "elbow": Field("str", "inverse-kinematics branch", choices=("up", "down")),
    },
    "simulation": {
        "t_final": _pos("horizon, s", hi=1e5),
        "dt": _pos("RK4 step, s", hi=0.1),
        "control": Field("str", "control mode", choices=("continuous", "sampled")),
        "control_period": _pos("sampling period when control = \"sampled\", s", hi=1.0),
        "output_interval": _pos("largest interval between saved samples, s", hi=1e3),
        "torque_limit": _pos("a run stops past this |tau_i|, N m", hi=1e12),
        "penetration_limit": _pos("a run stops past this penetration, m", hi=1e3),
    },
}

#: The F_f presets as scenario values (NOTES.md "F_f centre step").
PRESETS_F = {"paper-printed": (-30.0, 0.05, 120), "paper-likely": (-30.0, 0.5, 120)}


def _walk(schema, prefix=""):
    for key, spec in schema.items():
        path = f"{prefix}{key}"
        if isinstance(spec, dict):
            yield from _walk(spec, path + ".")
        else:
            yield path, spec


def all_keys() -> list[str]:
    """Every valid dotted key."""
    return [k for k, _ in _walk(SCHEMA)]


def schema_table() -> str:
    """A Markdown table of every key, for the docs and ``hinfnn keys``."""
    rows = ["| key | meaning | allowed |", "|---|---|---|"]
    rows += [f"| `{k}` | {f.doc} | {f.allowed()} |" for k, f in _walk(SCHEMA)]
    return "\n".join(rows)


# --- loading and overrides -----------------------------------------------------------------------


def scenario_names() -> list[str]:
    """Names of the scenarios shipped with hinfnn."""
    folder = resources.files("hinfnn") / "scenarios"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def _read_source(name_or_path: str | Path) -> tuple[str, str]:
    """(TOML text, where it came from) for a shipped scenario name or a file path."""
    text_name = str(name_or_path)
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
    resource = resources.files("hinfnn") / "scenarios" / f"{text_name}.toml"
    return resource.read_text(encoding="utf-8"), text_name


def parse_toml(text: str, source: str = "<string>") -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{source} is not valid TOML: {err}") from None


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


def _suggest(key: str) -> str:
    keys = all_keys()
    close = difflib.get_close_matches(key, keys, n=1, cutoff=0.5)
    if not close:
        leaf = key.rsplit(".", 1)[-1]
        close = [k for k in keys if k.rsplit(".", 1)[-1] == leaf][:1]
    return f"; did you mean {close[0]!r}?" if close else ""


def set_key(data: dict, key: str, value: Any) -> None:
    """Set a dotted key in nested dicts, refusing keys that are not in :data:`SCHEMA`."""
    spec: Any = SCHEMA
    parts = key.split(".")
    node = data
    for i, part in enumerate(parts):
        if not isinstance(spec, dict) or part not in spec:
            raise ConfigError(f"unknown key{_suggest(key)}", key=key)
        spec = spec[part]
        if i < len(parts) - 1:
            if not isinstance(node.get(part), dict):
                node[part] = {}
            node = node[part]
    if isinstance(spec, dict):
        raise ConfigError(f"is a section, not a value; set one of its keys: "
                          f"{', '.join(sorted(spec))}", key=key)
    node[parts[-1]] = value


def _deep_merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


# --- validation of types and ranges ---------------------------------------------------------------


def _check_number(key, value, f: Field, *, integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"must be {f.allowed()}, got {value!r} ({type(value).__name__})", key=key)
    if integer and not isinstance(value, int):
        raise ConfigError(f"must be an integer, got {value!r}", key=key)
    if not math.isfinite(value):
        raise ConfigError(f"must be finite, got {value}", key=key)
    if f.lo is not None and (value < f.lo or (f.lo_open and value == f.lo)):
        raise ConfigError(f"must be {f.allowed()}, got {value:g}", key=key)
    if f.hi is not None and (value > f.hi or (f.hi_open and value == f.hi)):
        raise ConfigError(f"must be {f.allowed()}, got {value:g}", key=key)
    return int(value) if integer else float(value)


def _check_value(key: str, value: Any, f: Field):
    t = f.type
    if t == "float":
        return _check_number(key, value, f)
    if t == "int":
        return _check_number(key, value, f, integer=True)
    if t == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"must be true or false, got {value!r}", key=key)
        return value
    if t == "str":
        if not isinstance(value, str):
            raise ConfigError(f"must be a string, got {value!r}", key=key)
        if f.choices and value not in f.choices:
            close = difflib.get_close_matches(value, f.choices, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(f"must be {f.allowed()}, got {value!r}{hint}", key=key)
        return value
    if t == "float_or_min":
        if value == "min":
            return value
        return _check_number(key, value, f)
    if t == "kinds":
        values = [value] if isinstance(value, str) else value
        if not isinstance(values, list) or not values or not all(isinstance(v, str) for v in values):
            raise ConfigError(f"must be {f.allowed()}, got {value!r}", key=key)
        for v in values:
            if v not in KINDS:
                close = difflib.get_close_matches(v, KINDS, n=1)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                raise ConfigError(f"unknown controller {v!r}; allowed: {', '.join(KINDS)}{hint}", key=key)
        if len(set(values)) != len(values):
            raise ConfigError(f"lists a controller twice: {values}", key=key)
        return value
    if t == "float_list":
        if not isinstance(value, list) or len(value) != f.length:
            raise ConfigError(f"must be {f.allowed()}, got {value!r}", key=key)
        return [_check_number(f"{key}[{i}]", v, f) for i, v in enumerate(value)]
    if t == "matrix":
        if isinstance(value, list):
            rows = value
            if not rows or not all(isinstance(r, list) and len(r) == len(rows) for r in rows):
                raise ConfigError(f"must be a number or a square matrix (list of equal-length rows), "
                                  f"got {value!r}", key=key)
            return [[_check_number(f"{key}[{i}][{j}]", v, f) for j, v in enumerate(r)]
                    for i, r in enumerate(rows)]
        return _check_number(key, value, f)
    raise AssertionError(t)


def validate(data: dict, schema: dict = SCHEMA, prefix: str = "") -> dict:
    """Types, ranges, unknown and missing keys. Returns a normalised copy (ints as floats...)."""
    if not isinstance(data, dict):
        raise ConfigError(f"must be a table (section), got {data!r}", key=prefix.rstrip(".") or None)
    out = {}
    for key, value in data.items():
        path = f"{prefix}{key}"
        if key not in schema:
            raise ConfigError(f"unknown key{_suggest(path)}", key=path)
        spec = schema[key]
        if isinstance(spec, dict):
            if not isinstance(value, dict):
                raise ConfigError(f"must be a section with keys {', '.join(sorted(spec))}, got {value!r}",
                                  key=path)
            out[key] = validate(value, spec, path + ".")
        else:
            if isinstance(value, dict):
                raise ConfigError(f"must be {spec.allowed()}, got a section", key=path)
            out[key] = _check_value(path, value, spec)
    for key, spec in schema.items():
        if key not in data:
            raise ConfigError("is missing", key=f"{prefix}{key}")
    return out


# --- the Scenario ------------------------------------------------------------------------------


def _to_toml(data: dict) -> str:
    import tomli_w

    return tomli_w.dumps(data, multiline_strings=False)


@dataclasses.dataclass(frozen=True)
class Scenario:
    """A validated scenario: ``data`` holds every key of :data:`SCHEMA` (resolved values)."""

    data: dict
    source: str = "<dict>"
    overrides: tuple = ()  # ((dotted key, value), ...) applied on top of the source, in order

    # --- construction --------------------------------------------------------------------------
    @classmethod
    def load(cls, name_or_path: str | Path = "paper", overrides=(), *, check: bool = True,
             _chain: tuple = ()) -> "Scenario":
        """Read a shipped scenario by name or a TOML file, apply ``overrides`` (``"k=v"``
        strings or a mapping of dotted keys to values) and validate everything.

        A file gives every key of :data:`SCHEMA`, or names a ``base = "paper"`` (a shipped name
        or a path) and gives only what differs from it.
        """
        text, source = _read_source(name_or_path)
        raw = parse_toml(text, source)
        return cls.from_dict(raw, overrides, source=source, check=check, _chain=_chain)

    @classmethod
    def from_dict(cls, raw: dict, overrides=(), *, source: str = "<dict>", check: bool = True,
                  _chain: tuple = ()) -> "Scenario":
        items = list(overrides.items()) if isinstance(overrides, dict) else [
            parse_override(o) if isinstance(o, str) else tuple(o) for o in overrides]
        raw = dict(raw)
        base = raw.pop("base", None)
        if base is not None:
            if not isinstance(base, str):
                raise ConfigError(f"must be the name or path of a scenario, got {base!r}", key="base")
            if base == source:
                raise ConfigError("a scenario cannot be its own base", key="base")
            base_path = Path(base)
            if (base_path.suffix == ".toml" or "/" in base) and not base_path.is_absolute() \
                    and source not in ("<dict>",) and Path(source).exists():
                base = str(Path(source).parent / base_path)
            chain = _chain + (_identity(source),)
            if _identity(base) in chain:
                raise ConfigError(f"{base!r} makes a cycle: {' -> '.join(chain + (_identity(base),))}",
                                  key="base")
            try:
                base_data = Scenario.load(base, check=False, _chain=chain).data
            except ConfigError as err:
                if err.key is not None:
                    raise
                raise ConfigError(str(err), key="base") from None
            data = _deep_merge(base_data, raw)
        else:
            data = copy.deepcopy(raw)
        for key, value in items:
            set_key(data, key, value)
        data = validate(data)
        _normalise_presets(data, explicit=_preset_keys(raw, items))
        sc = cls(data=data, source=source, overrides=tuple((k, v) for k, v in items))
        if check:
            sc.check()
        return sc

    def with_overrides(self, overrides) -> "Scenario":
        """A new scenario with more overrides applied (``overrides`` lists all of them)."""
        new = Scenario.from_dict(self.data, overrides, source=self.source)
        return dataclasses.replace(new, overrides=self.overrides + new.overrides)

    def to_toml(self) -> str:
        """The resolved scenario as TOML text (loads back to the same scenario)."""
        return _to_toml(self.data)

    # --- reading ---------------------------------------------------------------------------------
    def get(self, key: str):
        node = self.data
        for part in key.split("."):
            node = node[part]
        return node

    @property
    def name(self) -> str:
        return self.data["name"]

    @property
    def kinds(self) -> list[str]:
        k = self.data["controller"]["kind"]
        return [k] if isinstance(k, str) else list(k)

    def single(self, kind: str) -> "Scenario":
        """This scenario with one controller kind."""
        return dataclasses.replace(self, data=_deep_merge(self.data, {"controller": {"kind": kind}}))

    # --- building the library objects --------------------------------------------------------------
    def build_arm(self, who: str):
        from .model import TwoLinkArm

        a = self.data[who]["arm"]
        return TwoLinkArm(m1=a["m1"], m2=a["m2"], l1=a["l1"], l2=a["l2"], g=a["g"])

    def build_surface(self, who: str):
        from .model import InclinedLine

        s = self.data[who]["surface"]
        return InclinedLine(delta=math.radians(s["delta_deg"]), d_G=s["d_G"],
                            scaling=s.get("scaling", "paper"))

    def build_plant(self):
        import jax.numpy as jnp

        from .plant import PenaltyContact, Plant, SquareWave

        p = self.data["plant"]
        d = p["disturbance"]
        return Plant(
            arm=self.build_arm("plant"), surface=self.build_surface("plant"),
            contact=PenaltyContact(stiffness=p["contact"]["stiffness"], damping=p["contact"]["damping"]),
            disturbance=SquareWave(amplitude=jnp.asarray(d["amplitude"], float), period=d["period"],
                                   phase=d["phase"]))

    def build_reference(self):
        import jax.numpy as jnp

        from .reference import CosineReference

        r = self.data["reference"]

        def a(v):
            return jnp.array([float(v)])

        return CosineReference(
            u1_offset=a(r["u1_offset"]), u1_amplitude=a(r["u1_amplitude"]),
            u1_omega=a(2 * math.pi / r["u1_period"]), u1_phase=a(r["u1_phase"]),
            lam_offset=a(r["lam_offset"]), lam_amplitude=a(r["lam_amplitude"]),
            lam_omega=a(2 * math.pi / r["lam_period"]), lam_phase=a(r["lam_phase"]))

    def build_gains(self):
        from .controllers import Gains

        g = self.data["controller"]["gains"]
        return Gains(K_p=g["K_p"], K_v=g["K_v"], rho=g["rho"], mu_z=g["mu_z"], alpha_z=g["alpha_z"],
                     alpha_lam=g["alpha_lam"], beta_lam=None if g["beta_lam"] == "min" else g["beta_lam"],
                     gamma_1=g["gamma_1"], gamma_2=g["gamma_2"], Q_p=np.asarray(g["Q_p"], float),
                     R_p=np.asarray(g["R_p"], float))

    def _network(self, which: str):
        from .controllers import TanhNetwork, centres_from

        n = self.data["controller"][which]
        return TanhNetwork.build(
            centres_from(n["centre_start"], n["centre_step"], n["centre_count"]), n_out=1,
            slope=n["slope"], w_a=n["w_a"], w_b=n["w_b"], radius=n["radius"] if n["projection"] else None,
            name=f"controller.{which}")

    def build_controller(self, kind: str | None = None):
        """Design the controller ``kind`` (default: the scenario's only kind) from the NOMINAL
        model. Raises :class:`DesignError` with the dotted key of the failing gain."""
        from .controllers import FeedbackLinearization, HinfController, HinfNNController

        kind = kind or _only(self.kinds)
        arm, surface = self.build_arm("nominal"), self.build_surface("nominal")
        gains = self.build_gains()
        augmented = self.data["controller"]["augmented"]
        try:
            if kind == "fl":
                return FeedbackLinearization.design(arm, surface, gains)
            if kind == "hinf":
                return HinfController.design(arm, surface, gains, augmented=augmented)
            return HinfNNController.design(arm, surface, gains, network_p=self._network("network_p"),
                                           network_f=self._network("network_f"), augmented=augmented)
        except DesignError as err:
            raise _prefixed(err) from None

    def sim_options(self) -> dict:
        """Keyword arguments for :func:`hinfnn.sim.simulate`."""
        from .sim import Limits

        s = self.data["simulation"]
        return dict(t_final=s["t_final"], dt=s["dt"], q0=self.initial_q(), save_interval=s["output_interval"],
                    control_period=s["control_period"] if s["control"] == "sampled" else None,
                    limits=Limits(torque=s["torque_limit"], penetration=s["penetration_limit"]))

    def initial_q(self, plant=None):
        """The start pose (truth: IK of the true arm onto the true surface)."""
        plant = plant or self.build_plant()
        return plant.initial_q(self.data["initial"]["u1"],
                                            elbow_up=self.data["initial"]["elbow"] == "up")

    # --- the checks that need the models -----------------------------------------------------------
    def check(self) -> None:
        """Cross-field and design checks (no compilation of a run). Raises ConfigError/DesignError."""
        s = self.data["simulation"]
        dt, t_final = s["dt"], s["t_final"]
        _require_multiple("simulation.t_final", t_final, dt,
                          f"{t_final:g} s is not a whole number of steps dt = {dt:g} s")
        d = self.data["plant"]["disturbance"]
        if any(a != 0.0 for a in d["amplitude"]):
            half = 0.5 * d["period"]
            _require_multiple("simulation.dt", half, dt,
                              f"{dt:g} s does not divide the disturbance's half-period {half:g} s; steps must "
                              "land on its switching instants")
            _require_multiple("plant.disturbance.phase", d["phase"] % half, dt,
                              f"{d['phase']:g} s (modulo the half-period {half:g} s) is not a multiple of "
                              f"dt = {dt:g} s; steps must land on the switching instants", allow_zero=True)
        if s["control"] == "sampled":
            _require_multiple("simulation.control_period", s["control_period"], dt,
                              f"{s['control_period']:g} s is not a whole multiple of dt = {dt:g} s")
        if s["output_interval"] < dt:
            raise ConfigError(f"must be >= dt = {dt:g}, got {s['output_interval']:g}",
                              key="simulation.output_interval")
        plant = self.build_plant()
        q0 = np.asarray(self.initial_q(plant))
        if not np.all(np.isfinite(q0)):
            arm = self.data["plant"]["arm"]
            raise ConfigError(
                f"u1(0) = {self.data['initial']['u1']:g} on the true surface is out of the true arm's "
                f"reach (|x| must be between {abs(arm['l1'] - arm['l2']):g} and {arm['l1'] + arm['l2']:g} m)",
                key="initial.u1")
        self._check_start(q0)
        self._check_step_against_contact(plant, q0)
        for kind in self.kinds:
            self.build_controller(kind)
        if self.data["plant"]["arm"]["model"] != self.data["nominal"]["arm"]["model"]:
            raise ConfigError("nominal and true arm models must have the same structure",
                              key="nominal.arm.model")

    def _check_start(self, q0) -> None:
        from .sim.simulate import nominal_jacobian_det

        det = float(nominal_jacobian_det(self.build_arm("nominal"), np.asarray(q0, dtype=float)))
        if abs(det) < 1e-6:
            raise DesignError(f"the nominal Jacobian is singular at the start pose q0 = "
                              f"{np.round(q0, 6).tolist()} (|det J| = {abs(det):.3g}): (A1) fails",
                              key="initial.u1", value=self.data["initial"]["u1"])

    def _check_step_against_contact(self, plant, q0) -> None:
        """RK4 resolves the contact oscillation only if ω dt is small: ω = √(k/m_eff), m_eff the
        true arm's effective mass along the surface normal at the start pose."""
        J, M, n = (np.asarray(a) for a in plant.contact_terms(np.asarray(q0, dtype=float)))
        inv_m = float(n @ J @ np.linalg.solve(M, J.T @ n))
        k = self.data["plant"]["contact"]["stiffness"]
        c = self.data["plant"]["contact"]["damping"]
        dt = self.data["simulation"]["dt"]
        omega = math.sqrt(k * inv_m)
        rate = max(omega, c * inv_m)  # damping rate c/m_eff matters too
        if rate * dt > 0.5:
            raise ConfigError(
                f"dt = {dt:g} s is too large for the contact: its natural frequency is {omega:.4g} rad/s "
                f"(stiffness {k:g} N/m, effective mass {1 / inv_m:.3g} kg) and its damping rate "
                f"{c * inv_m:.4g} 1/s, so RK4 needs dt <= {0.5 / rate:.3g} s", key="simulation.dt")

    # --- running ----------------------------------------------------------------------------------
    def simulate(self, kind: str | None = None, **options):
        """Run one controller (default: the only kind) and return its Trajectory."""
        from .sim import simulate

        kind = kind or _only(self.kinds)
        opts = {**self.sim_options(), **options}
        return simulate(self.build_plant(), self.build_controller(kind), self.build_reference(),
                        config=self.single(kind).data, **opts)


# --- helpers ---------------------------------------------------------------------------------------


def _only(kinds):
    if len(kinds) != 1:
        raise ConfigError(f"the scenario lists {len(kinds)} controllers {kinds}; name one",
                          key="controller.kind")
    return kinds[0]


def _identity(source: str) -> str:
    """A scenario's identity for cycle detection: the resolved path of a file, else its name."""
    return str(Path(source).resolve()) if Path(source).exists() else str(source)


def _require_multiple(key, value, step, message, allow_zero=False):
    """value must be a whole multiple (≥ 1, or 0 when allow_zero) of step."""
    ratio = value / step
    if not math.isfinite(ratio):
        raise ConfigError(message, key=key)
    n = round(ratio)
    if abs(ratio - n) > 1e-6 * max(1.0, abs(ratio)) or (n < 1 and not (allow_zero and value == 0)):
        raise ConfigError(message, key=key)


def _preset_keys(raw: dict, items) -> set:
    """The network_f centre keys set explicitly in the layer that last set the preset: an
    override of the preset replaces the centres of the file (or the data being re-overridden)
    unless the same overrides set centres too."""
    from_items = {key.rsplit(".", 1)[-1] for key, _ in items if key.startswith("controller.network_f.")}
    if "preset" in from_items:
        return from_items
    nf = raw.get("controller", {}).get("network_f", {}) if isinstance(raw.get("controller"), dict) else {}
    return from_items | (set(nf) if isinstance(nf, dict) else set())


def _normalise_presets(data: dict, explicit: set) -> None:
    """A preset fixes F_f's centres; setting a centre key with a preset other than "custom" is an
    error unless it equals the preset's value. Setting only the preset updates the centres."""
    nf = data["controller"]["network_f"]
    preset = nf["preset"]
    if preset == "custom":
        return
    values = dict(zip(("centre_start", "centre_step", "centre_count"), PRESETS_F[preset]))
    for key, value in values.items():
        if key in explicit and not math.isclose(nf[key], value, rel_tol=1e-12, abs_tol=1e-12):
            raise ConfigError(f"{nf[key]:g} conflicts with preset {preset!r} ({key} = {value:g}); "
                              "set controller.network_f.preset = \"custom\" to choose the centres",
                              key=f"controller.network_f.{key}")
        nf[key] = int(value) if key == "centre_count" else float(value)


def _prefixed(err: DesignError) -> DesignError:
    key = err.key
    if key is None:
        return err
    if key in ("rho", "mu_z", "alpha_z", "alpha_lam", "beta_lam", "gamma_1", "gamma_2", "Q_p", "R_p",
               "K_p", "K_v"):
        full = f"controller.gains.{key}"
    elif key.startswith("network_"):
        full = f"controller.{key}"
    else:
        full = key
    message = err.args[0].split(": ", 1)[1] if err.args[0].startswith(f"{key}: ") else err.args[0]
    return DesignError(message, key=full, value=err.value, bound=err.bound)


def load_scenario(name_or_path: str | Path = "paper", overrides=(), *, check: bool = True) -> Scenario:
    """Shortcut for :meth:`Scenario.load`."""
    return Scenario.load(name_or_path, overrides, check=check)


def simulate_many(runs, *, progress=None, save_every: int | None = None):
    """Simulate named runs ``[(name, scenario, kind), ...]``, batching under ``vmap`` every group
    that shares a compiled program (same controller structure and simulation settings).

    Returns ``{name: Trajectory}`` in the order given. Runs that diverge are marked in their
    Trajectory's ``status``; they never stop the others. ``progress(steps_done, steps_total,
    names)`` is called after every compiled chunk (steps summed over all runs). A group of one
    runs without ``vmap`` (faster to trace and to run: see :mod:`hinfnn.sim.simulate`).
    ``save_every`` overrides the scenarios' ``output_interval`` for what is kept in memory (files
    are decimated to ``output_interval`` when written).
    """
    import jax

    from .sim import simulate, simulate_batch

    built = []
    for name, sc, kind in runs:
        one = sc.single(kind)
        opts = one.sim_options()
        plant, ctrl, ref = one.build_plant(), one.build_controller(kind), one.build_reference()
        structure = jax.tree.structure((plant, ctrl, ref))
        key = (str(structure), opts["t_final"], opts["dt"], opts["control_period"],
               one.data["simulation"]["output_interval"])
        built.append((name, one, plant, ctrl, ref, opts, key))
    groups: dict = {}
    for item in built:
        groups.setdefault(item[-1], []).append(item)
    out = {}
    total = sum(round(i[5]["t_final"] / i[5]["dt"]) for i in built)
    finished = 0
    for items in groups.values():
        opts = items[0][5]
        names = [i[0] for i in items]
        steps = round(opts["t_final"] / opts["dt"])

        def report(done, _total, names=names, base=finished, width=len(items)):
            if progress:
                progress(base + done * width, total, names)

        if len(items) == 1:
            _, one, plant, ctrl, ref, o, _ = items[0]
            out[names[0]] = simulate(plant, ctrl, ref, t_final=o["t_final"], dt=o["dt"], q0=o["q0"],
                                     control_period=o["control_period"], save_interval=o["save_interval"],
                                     save_every=save_every, limits=o["limits"], config=one.data,
                                     raise_on_failure=False,
                                     progress=report if progress else None)
            finished += steps
            continue
        traj = simulate_batch([i[2] for i in items], [i[3] for i in items], [i[4] for i in items],
                              q0=[i[5]["q0"] for i in items], t_final=opts["t_final"], dt=opts["dt"],
                              control_period=opts["control_period"], save_interval=opts["save_interval"],
                              save_every=save_every,
                              limits=[i[5]["limits"] for i in items],
                              configs=[i[1].data for i in items], progress=report if progress else None)
        for j, item in enumerate(items):
            out[item[0]] = traj.member(j)
        finished += steps * len(items)
    return {name: out[name] for name, *_ in runs}
