"""Frozen dataclasses registered as JAX pytrees (the Brax / diffrax habit).

Fields are pytree *data* (traced, batchable with ``vmap``) unless declared with
:func:`static_field`, which makes them hashable compile-time metadata (sizes, flags, kinds).
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax
import jax.numpy as jnp

T = TypeVar("T")


class Note(tuple):
    """A record carried beside a pytree's arrays that no computation reads (a design step's numbers,
    for reports), in a :func:`static_field`. A static field is part of the pytree's structure, and
    a program is traced and compiled per structure; every Note compares equal and hashes and prints
    alike, so objects that differ only in their notes share their programs (a force-rate design of
    another horizon is another record, the same dynamics). It reads as the tuple it holds."""

    __slots__ = ()

    def __eq__(self, other):
        return isinstance(other, Note)

    def __ne__(self, other):
        return not self.__eq__(other)

    def __hash__(self):
        return hash(Note)

    def __repr__(self):
        return "Note(...)"


def static_field(**kwargs: Any) -> Any:
    """A dataclass field that is compile-time metadata, not a traced array."""
    return dataclasses.field(metadata={"static": True}, **kwargs)


def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass and register it as a pytree node."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    return jax.tree_util.register_dataclass(cls)


def all_finite(tree) -> jax.Array:
    """True iff every entry of every array leaf of ``tree`` is finite (a traced boolean)."""
    ok = jnp.array(True)
    for leaf in jax.tree.leaves(tree):
        ok = ok & jnp.all(jnp.isfinite(leaf))
    return ok


def structure_key(tree) -> tuple:
    """What decides a compiled program's inputs: the pytree structure (as text, so always
    hashable) and every leaf's shape and dtype (two networks of different sizes have the same
    structure but not the same program)."""
    import numpy as np

    leaves, treedef = jax.tree.flatten(tree)
    return str(treedef), tuple((tuple(np.shape(x)), str(getattr(x, "dtype", type(x).__name__))) for x in leaves)


def value_key(tree) -> tuple:
    """:func:`structure_key` with every leaf's values too: two trees with equal keys hold the same
    numbers (for results kept per process by value)."""
    import numpy as np

    leaves, treedef = jax.tree.flatten(tree)
    return str(treedef), tuple((a.dtype.str, a.shape, a.tobytes()) for a in map(np.asarray, leaves))


def replace(obj: T, **changes: Any) -> T:
    """``dataclasses.replace`` for pytree dataclasses (returns a new object)."""
    return dataclasses.replace(obj, **changes)
