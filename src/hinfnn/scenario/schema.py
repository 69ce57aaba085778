"""Typed configuration: frozen dataclasses are the schema, this module loads them.

A scenario section is a frozen dataclass (:func:`section`) whose fields carry their type, range,
meaning and default (:func:`param`). From that one definition come the TOML loader with its
error messages (:func:`load`), the ``hinfnn keys`` listing and ``docs/scenarios.md``
(:func:`describe`), and the plain dict written back to ``scenario.toml`` (:func:`to_dict`).

Supported field types: ``float``, ``int``, ``bool``, ``str``, ``Literal[...]``,
``tuple[float, ...]``, :data:`Matrix` (a number or a square matrix), ``float | Literal[...]``,
``str | tuple[str, ...]`` (one name or a list), a nested section, and a *registered* section: a
base class with a :class:`Registry` whose subclasses are chosen by a key of the TOML table
(``plant.arm.model = "two_link"``), so that a new kind of arm, surface or plant is a new
dataclass plus one registry line.

Every error is a :class:`~hinfnn.errors.ConfigError` naming the dotted key, the value and what
is allowed.
"""

from __future__ import annotations

import dataclasses
import datetime
import difflib
import functools
import math
import types
import typing
from typing import Any, Literal, NewType, Union

from ..errors import ConfigError, is_integer, is_real

#: A number (times the identity), a flat list (the diagonal) or a square matrix given as a list of
#: equal-length rows.
Matrix = NewType("Matrix", object)

_MISSING = dataclasses.MISSING


def param(default=_MISSING, *, doc: str, gt=None, ge=None, lt=None, le=None, choices=None,
          hidden: bool = False, exclude: tuple = (), allowed=None):
    """A field of a section: its default (none: required), meaning, and bounds (gt/ge/lt/le).
    ``exclude``: for a section-valued field, keys of that section not accepted here;
    ``allowed``: the words for what it accepts, when the type alone does not say (a callable is
    called each time: e.g. the names of a registry that grows)."""
    meta = {"doc": doc, "gt": gt, "ge": ge, "lt": lt, "le": le, "choices": choices, "hidden": hidden,
            "exclude": exclude, "allowed": allowed, "empty_ok": isinstance(default, tuple) and not default}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: default, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def section(cls):
    """Make ``cls`` a frozen, keyword-only dataclass usable as a scenario section."""
    return dataclasses.dataclass(frozen=True, kw_only=True)(cls)


class Registry:
    """Maps the value of a key (``model``, ``kind``, ``engine``) to a section class.

    ``Registry("plant.arm", "model")``; :meth:`register` adds a class (usable as a decorator:
    ``@ARMS.register("two_link")``)."""

    def __init__(self, what: str, key: str, default: str | None = None):
        self.what = what
        self.key = key
        self.default = default
        self._classes: dict[str, type] = {}

    def register(self, name: str, cls: type | None = None):
        def add(c):
            self._classes[name] = c
            return c
        return add(cls) if cls is not None else add

    def unregister(self, name: str) -> None:
        """Remove a kind (tests that add toys clean up after themselves)."""
        self._classes.pop(name, None)

    def names(self) -> list[str]:
        return list(self._classes)

    def __contains__(self, name) -> bool:
        return name in self._classes

    def __getitem__(self, name: str) -> type:
        return self._classes[name]

    def lookup(self, name, key: str) -> type:
        """The class for ``name``, or a ConfigError at ``key`` listing the known names."""
        if not isinstance(name, str):
            raise ConfigError(f"must be one of {self._allowed()}, got {name!r}", key=key)
        if name not in self._classes:
            close = difflib.get_close_matches(name, self.names(), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(f"must be one of {self._allowed()}, got {name!r}{hint}", key=key)
        return self._classes[name]

    def _allowed(self) -> str:
        return ", ".join(repr(n) for n in self._classes)


def registry_of(tp) -> Registry | None:
    return getattr(tp, "__registry__", None) if isinstance(tp, type) else None


# --- introspection ---------------------------------------------------------------------------------


@functools.cache
def _hints(cls) -> dict:
    """The resolved annotations of a section class (cached: resolving them is most of a load)."""
    return typing.get_type_hints(cls)


def fields_of(cls, exclude=()) -> list[tuple[dataclasses.Field, Any]]:
    """The schema fields of a section class with their resolved types."""
    hints = _hints(cls)
    return [(f, hints[f.name]) for f in dataclasses.fields(cls)
            if f.metadata.get("doc") is not None and f.name not in exclude]


def _is_section(tp) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _args(tp):
    return typing.get_args(tp)


def _is_union(tp) -> bool:
    return typing.get_origin(tp) in (Union, types.UnionType)


def allowed(tp, meta) -> str:
    """What a field accepts, in words (``a number > 0 and <= 10000``)."""
    words = meta.get("allowed")
    if words is not None:
        return words() if callable(words) else words
    if typing.get_origin(tp) is Literal:
        return "one of " + ", ".join(repr(c) for c in _args(tp))
    if meta.get("choices"):
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    bounds = []
    for k, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
        if meta.get(k) is not None:
            bounds.append(f"{sym} {meta[k]:g}")
    tail = (" " + " and ".join(bounds)) if bounds else ""
    if tp is float:
        return "a number" + tail
    if tp is int:
        return "an integer" + tail
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    if tp is Matrix:
        return "a number, a list (the diagonal) or a square matrix" + (f" with entries{tail}" if tail else "")
    if typing.get_origin(tp) is tuple:
        inner = _args(tp)[0]
        if inner is str:
            return "a list of strings"
        return "a list of numbers" + (f"{tail}" if tail else "")
    if _is_union(tp):
        parts = []
        for a in _args(tp):
            if typing.get_origin(a) is Literal:
                parts.append(" or ".join(f'"{c}"' for c in _args(a)))
            elif a is float:
                parts.append("a number" + tail)
            elif a is int:
                parts.append("an integer" + tail)
            elif a is str:
                parts.append("a name")
            elif typing.get_origin(a) is tuple:
                parts.append("a list of names" if _args(a)[0] is str else "a list of numbers" + tail)
        return " or ".join(parts)
    return str(tp)


# --- loading -------------------------------------------------------------------------------------------


def _number(key, value, meta, tp_words, integer=False):
    if not is_real(value):
        raise ConfigError(f"must be {tp_words}, got {value!r} ({type(value).__name__})", key=key)
    if integer and not is_integer(value):
        raise ConfigError(f"must be an integer, got {value!r}", key=key)
    if not math.isfinite(value):
        raise ConfigError(f"must be finite, got {value}", key=key)
    for k, ok in (("gt", lambda b: value > b), ("ge", lambda b: value >= b), ("lt", lambda b: value < b),
                  ("le", lambda b: value <= b)):
        if meta.get(k) is not None and not ok(meta[k]):
            raise ConfigError(f"must be {tp_words}, got {value:g}", key=key)
    return int(value) if integer else float(value)


def plain(value):
    """A value given from Python as TOML would give it: NumPy (or JAX) scalars and arrays as
    Python numbers, bools and lists (``.tolist()``), tuples as lists, at any depth of lists and
    tables. Overrides are kept this way (:attr:`hinfnn.Scenario.overrides`, written to
    ``metrics.json``)."""
    if hasattr(value, "dtype") and hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    return value


def _value(key: str, value, tp, meta):
    """Check one value against its type and bounds; returns the normalised value."""
    value = plain(value)
    words = allowed(tp, meta)
    if isinstance(value, dict):
        raise ConfigError(f"must be {words}, got a section", key=key)
    if isinstance(value, (datetime.date, datetime.time, datetime.datetime)):
        raise ConfigError(f"must be {words}, got a date/time {value!r}", key=key)
    if tp is float:
        return _number(key, value, meta, words)
    if tp is int:
        return _number(key, value, meta, words, integer=True)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"must be true or false, got {value!r}", key=key)
        return value
    if tp is str or typing.get_origin(tp) is Literal:
        choices = _args(tp) if typing.get_origin(tp) is Literal else meta.get("choices")
        if not isinstance(value, str):
            raise ConfigError(f"must be {words}, got {value!r}", key=key)
        if choices and value not in choices:
            close = difflib.get_close_matches(value, [str(c) for c in choices], n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(f"must be {words}, got {value!r}{hint}", key=key)
        return value
    if tp is Matrix:
        if isinstance(value, list) and value and not any(isinstance(r, list) for r in value):
            # a flat list: the diagonal
            return tuple(_number(f"{key}[{i}]", v, meta, "a number") for i, v in enumerate(value))
        if isinstance(value, list):
            rows = value
            if not rows or not all(isinstance(r, list) and len(r) == len(rows) for r in rows):
                raise ConfigError(f"must be a number or a square matrix (list of equal-length rows), got {value!r}",
                                  key=key)
            return tuple(tuple(_number(f"{key}[{i}][{j}]", v, meta, "a number") for j, v in enumerate(r))
                         for i, r in enumerate(rows))
        return _number(key, value, meta, words)
    if typing.get_origin(tp) is tuple:
        inner = _args(tp)[0]
        if not isinstance(value, list) or not (value or meta.get("empty_ok")):  # [] where () is the default
            raise ConfigError(f"must be {words}, got {value!r}", key=key)
        if inner is str:
            if not all(isinstance(v, str) for v in value):
                raise ConfigError(f"must be {words}, got {value!r}", key=key)
            return tuple(value)
        return tuple(_number(f"{key}[{i}]", v, meta, "a number" + words.removeprefix("a list of numbers"))
                     for i, v in enumerate(value))
    if _is_union(tp):
        for a in _args(tp):
            try:
                return _value(key, value, a, {**meta, "allowed": None})
            except ConfigError as err:
                # a number out of a number branch's range: that branch's message (it names the range)
                if a is float and is_real(value):
                    raise err from None
        raise ConfigError(f"must be {words}, got {value!r}", key=key)
    raise AssertionError(f"unsupported field type {tp!r} at {key}")


def _suggest(key: str, names) -> str:
    leaf = key.rsplit(".", 1)[-1]
    close = difflib.get_close_matches(leaf, list(names), n=1, cutoff=0.5)
    if close:
        return f"; did you mean {key.rsplit('.', 1)[0] + '.' + close[0] if '.' in key else close[0]!r}?"
    return ""


def drop_switched(cls, before: dict, after: dict, given: dict) -> None:
    """Where ``given`` (a derived file's table over its base, or the overrides) switches a
    section's kind (``plant.surface.kind``, ``plant.arm.model``, ``plant.engine``, ...), drop
    from ``after`` (``before`` with ``given`` applied) the keys it kept from ``before`` that the
    new kind does not take, in place: a file that switches kind lists the new kind's keys only,
    and keys both kinds take stay. Keys ``given`` itself sets are left for :func:`load` to judge."""
    reg = registry_of(cls)
    if reg is not None and cls.__dict__.get("__registry__") is reg:
        old, new = before.get(reg.key, reg.default), after.get(reg.key, reg.default)
        if not isinstance(new, str) or new not in reg:
            return  # an unknown kind: load() names it
        cls = reg[new]
        if new != old:
            taken = {f.name for f, _ in fields_of(cls)}
            for key in [k for k in after if k not in taken and k not in given and k in before]:
                del after[key]
    for f, tp in fields_of(cls):
        sub_before, sub_after, sub_given = (d.get(f.name) for d in (before, after, given))
        if _is_section(tp) and isinstance(sub_after, dict) and isinstance(sub_given, dict):
            drop_switched(tp, sub_before if isinstance(sub_before, dict) else {}, sub_after, sub_given)


def load(cls, data, path: str = "", exclude=()):
    """Build section ``cls`` from a TOML table ``data`` (a dict), checking every key.

    Unknown keys, missing required keys, wrong types and out-of-range values raise
    :class:`~hinfnn.errors.ConfigError` with the dotted key ``path.field``. A registered section
    type dispatches on its registry's key."""
    where = path.rstrip(".")
    if not isinstance(data, dict):
        raise ConfigError(f"must be a section (table), got {data!r}", key=where or None)
    reg = registry_of(cls)
    chosen = None
    if reg is not None and cls.__dict__.get("__registry__") is reg:  # the base: choose the subclass
        chosen = data.get(reg.key, reg.default)
        if chosen is None:
            raise ConfigError("is missing", key=f"{path}{reg.key}")
        cls = reg.lookup(chosen, f"{path}{reg.key}")
    fields = fields_of(cls, exclude)
    names = [f.name for f, _ in fields]
    if chosen is not None:  # keys of another kind: the kind is what is wrong (or the keys are)
        foreign = [k for k in data if k not in names and isinstance(k, str)]
        owners = {}
        for other in reg.names():
            if other == chosen:
                continue
            theirs = {f.name for f, _ in fields_of(reg[other], exclude)}
            for k in foreign:
                if k in theirs:
                    owners.setdefault(k, other)
        if owners:
            listed = ", ".join(f"{k!r} ({reg.key} = {o!r})" for k, o in owners.items())
            raise ConfigError(f"{reg.key} = {chosen!r} does not take the key{'s' if len(owners) > 1 else ''} "
                              f"{listed}; remove {'them' if len(owners) > 1 else 'it'} or choose that "
                              f"{reg.what}", key=f"{path}{reg.key}")
    for key in data:
        if key not in names:
            if isinstance(key, str) and any(c in key for c in "\n\r"):
                shown = key.encode("unicode_escape").decode()
            else:
                shown = key
            raise ConfigError(f"unknown key{_suggest(f'{path}{shown}', names)}", key=f"{path}{shown}")
    values = {}
    for f, tp in fields:
        key = f"{path}{f.name}"
        if chosen is not None and f.name == reg.key:
            values[f.name] = chosen
            continue
        if f.name not in data:
            if f.default is not _MISSING or f.default_factory is not _MISSING:  # type: ignore[misc]
                continue
            if _is_section(tp) and all(g.default is not _MISSING or g.default_factory is not _MISSING  # type: ignore[misc]
                                       for g, _ in fields_of(tp)) and registry_of(tp) is None:
                values[f.name] = tp()
                continue
            raise ConfigError("is missing", key=key)
        value = data[f.name]
        if _is_section(tp):
            if not isinstance(value, dict):
                sub = ", ".join(g.name for g, _ in fields_of(tp)) if registry_of(tp) is None else \
                    f"{registry_of(tp).key} and the keys of that kind"
                raise ConfigError(f"must be a section with keys {sub}, got {value!r}", key=key)
            values[f.name] = load(tp, value, key + ".", exclude=f.metadata.get("exclude", ()))
        else:
            values[f.name] = _value(key, value, tp, f.metadata)
    obj = cls(**values)
    check = getattr(obj, "validate", None)
    if check is not None:
        check(where)
    return obj


def to_dict(obj, exclude=()) -> dict:
    """A section as a plain nested dict (lists for tuples), as TOML writes it."""
    out = {}
    reg = None
    for base in type(obj).__mro__:
        if "__registry__" in base.__dict__:
            reg = base.__dict__["__registry__"]
            break
    if reg is not None:
        out[reg.key] = next(n for n in reg.names() if reg[n] is type(obj))
    for f, tp in fields_of(type(obj), exclude):
        if reg is not None and f.name == reg.key:
            continue
        v = getattr(obj, f.name)
        if _is_section(type(v)):
            out[f.name] = to_dict(v, f.metadata.get("exclude", ()))
        elif isinstance(v, tuple):
            out[f.name] = [list(r) if isinstance(r, tuple) else r for r in v]
        else:
            out[f.name] = v
    return out


# --- description: ``hinfnn keys`` and docs/scenarios.md ------------------------------------------------


def _shared(reg, exclude) -> set:
    """The fields every variant of a registry has unchanged (the same field, the same type): listed
    once, without a variant tag."""
    variants = [reg[n] for n in reg.names()]
    if not variants:
        return set()
    first = {f.name: (f, tp) for f, tp in fields_of(variants[0], exclude)}
    shared = set()
    for name, (f, tp) in first.items():
        if all(any(g is f and ut == tp for g, ut in fields_of(v, exclude) if g.name == name) for v in variants[1:]):
            shared.add(name)
    return shared


def describe(cls, prefix: str = "", exclude=(), tag: str = "") -> list[tuple[str, str, str, str]]:
    """Rows (dotted key, meaning, allowed values, default) of every key of a section, with every
    registered variant's keys (marked with the variant, e.g. ``plant.arm.m1  [model = "two_link"]``).
    A key every variant has unchanged (``plant.arm`` of every engine) is listed once, untagged;
    ``tag`` marks every row (the keys inside a variant's own section)."""
    rows = []
    reg = registry_of(cls)
    variants = [(None, cls)]
    shared: set = set()
    if reg is not None and cls.__dict__.get("__registry__") is reg:
        variants = [(n, reg[n]) for n in reg.names()]
        shared = _shared(reg, exclude)
        rows.append((f"{prefix}{reg.key}", f"which {reg.what}" + tag, "one of " + ", ".join(repr(n) for n in reg.names()),
                     repr(reg.default) if reg.default else "required"))
    listed: set = set()
    for name, c in variants:
        for f, tp in fields_of(c, exclude):
            if reg is not None and f.name == reg.key:
                continue
            if f.metadata.get("hidden"):
                continue
            own = name is not None and f.name not in shared
            if not own and f.name in listed:
                continue
            listed.add(f.name)
            row_tag = tag + (f" [{reg.key} = {name!r}]" if own else "")
            key = f"{prefix}{f.name}"
            if _is_section(tp):
                rows += describe(tp, key + ".", exclude=f.metadata.get("exclude", ()), tag=row_tag)
                continue
            doc = f.metadata["doc"] + row_tag
            if f.default is not _MISSING:
                default = repr(f.default)
            elif f.default_factory is not _MISSING:  # type: ignore[misc]
                default = repr(f.default_factory())  # type: ignore[misc]
            else:
                default = "required"
            rows.append((key, doc, allowed(tp, f.metadata), default))
    return rows


def all_keys(cls) -> list[str]:
    """Every dotted key of a section class (with every registered variant)."""
    return [row[0] for row in describe(cls)]


def leaves(obj, prefix: str = ""):
    """(dotted key, type, field metadata, value) of every value of a section instance (the
    variants it actually holds), in order: for tests, tools and documentation."""
    reg = None
    for base in type(obj).__mro__:
        if "__registry__" in base.__dict__:
            reg = base.__dict__["__registry__"]
            break
    for f, tp in fields_of(type(obj)):
        key = f"{prefix}{f.name}"
        v = getattr(obj, f.name)
        if _is_section(tp):
            yield from ((k, t, m, x) for k, t, m, x in leaves(v, key + ".")
                        if k.rsplit(".", 1)[-1] not in f.metadata.get("exclude", ()))
        elif reg is not None and f.name == reg.key:
            yield key, Literal[tuple(reg.names())], f.metadata, v
        else:
            yield key, tp, f.metadata, v
