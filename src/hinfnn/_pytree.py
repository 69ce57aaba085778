"""Frozen dataclasses registered as JAX pytrees (the Brax / diffrax habit).

Fields are pytree *data* (traced, batchable with ``vmap``) unless declared with
:func:`static_field`, which makes them hashable compile-time metadata (sizes, flags, kinds).
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax

T = TypeVar("T")


def static_field(**kwargs: Any) -> Any:
    """A dataclass field that is compile-time metadata, not a traced array."""
    return dataclasses.field(metadata={"static": True}, **kwargs)


def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass and register it as a pytree node."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    return jax.tree_util.register_dataclass(cls)


def replace(obj: T, **changes: Any) -> T:
    """``dataclasses.replace`` for pytree dataclasses (returns a new object)."""
    return dataclasses.replace(obj, **changes)
