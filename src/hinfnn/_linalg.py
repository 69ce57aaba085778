"""Closed-form inverses of the tiny matrices of a 2–3 DOF arm, and the products of
:mod:`hinfnn._devices`.

On the CPU, ``jnp.linalg.solve``/``inv`` call LAPACK through a custom call whose fixed cost
dominates a 2 × 2 solve; the cofactor formulas below are plain arithmetic that XLA fuses with
the rest of the step. Larger matrices fall back to ``jnp.linalg``. Shapes are static, so the
choice is made at trace time.
"""

from __future__ import annotations

import jax.numpy as jnp

from ._devices import mm, sincos  # noqa: F401  (re-exported: the model code uses la.mm, la.sincos)


def inv(A):
    """A⁻¹ (cofactor formula for n ≤ 2, LAPACK otherwise)."""
    n = A.shape[-1]
    if n == 1:
        return 1.0 / A
    if n == 2:
        a, b, c, d = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
        det = a * d - b * c
        return jnp.array([[d, -b], [-c, a]]) / det
    return jnp.linalg.inv(A)


def solve(A, b):
    """A⁻¹ b for a vector or matrix right-hand side."""
    if A.shape[-1] <= 2:
        return mm(inv(A), b)
    return jnp.linalg.solve(A, b)
