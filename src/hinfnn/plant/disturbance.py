"""The joint disturbance ω_l of eq. (1): Sec. VI uses a ±3 square wave of period 1 on both joints.

d(t) = +A on [φ, φ + T/2), −A on [φ + T/2, φ + T), and so on (docs/paper-conventions.md: the phase φ is not
given; it is a parameter, in seconds). The simulator holds it constant over each step, and its
steps land on the switching instants φ + iT/2 (the scenario loader checks dt divides them).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._pytree import pytree_dataclass


@pytree_dataclass
class SquareWave:
    """Per-joint amplitude A (n,), period T (s), phase φ (s)."""

    amplitude: jax.Array
    period: jax.Array = 1.0
    phase: jax.Array = 0.0

    def __call__(self, t):
        half = jnp.floor((t - self.phase) / (0.5 * self.period))
        sign = 1.0 - 2.0 * jnp.mod(half, 2.0)
        return sign * self.amplitude

    @classmethod
    def paper(cls) -> "SquareWave":
        return cls(amplitude=jnp.array([3.0, 3.0]), period=1.0, phase=0.0)

    @classmethod
    def none(cls, n: int = 2) -> "SquareWave":
        return cls(amplitude=jnp.zeros(n), period=1.0, phase=0.0)
