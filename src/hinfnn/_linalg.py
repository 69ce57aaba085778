"""Closed-form inverses of the tiny matrices of a 2–3 DOF arm.

On the CPU, ``jnp.linalg.solve``/``inv`` call LAPACK through a custom call whose fixed cost
dominates a 2 × 2 solve; the cofactor formulas below are plain arithmetic that XLA fuses with
the rest of the step. Larger matrices fall back to ``jnp.linalg``. Shapes are static, so the
choice is made at trace time.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def mm(a, b):
    """``a @ b`` for vectors and matrices. For contractions over at most :data:`SMALL` terms it
    is written as multiply-and-sum, which XLA fuses with the neighbouring arithmetic; a ``dot``
    of 2 × 2 operands is a kernel of its own (measured on the paper's adaptive run: 1.9 s vs
    2.5 s per 100,000 steps). An unrolled sum of slices was slower still (many slice kernels)."""
    if a.ndim > 2 or b.ndim > 2 or a.shape[-1] != b.shape[0] or a.shape[-1] > SMALL:
        return a @ b
    if a.ndim == 1 and b.ndim == 1:
        return jnp.sum(a * b)
    if a.ndim == 2 and b.ndim == 1:
        return jnp.sum(a * b[None, :], axis=1)
    if a.ndim == 1:
        return jnp.sum(a[:, None] * b, axis=0)
    return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)


#: Longest contraction :func:`mm` writes as multiply-and-sum.
SMALL = 4


def sincos(x):
    """(sin x, cos x) of a vector of angles, computed once and shared.

    XLA counts real sine and cosine as cheap and recomputes them inside every kernel that uses
    them (the paper's RK4 step made about 240 libm calls for its 24 distinct sines and cosines).
    A reduction is never recomputed, so the values pass through a sum with 0·v (exact: v + 0·v
    = v for the finite values sine and cosine take; NaN stays NaN). Simpler barriers are undone
    by XLA before fusion: ``optimization_barrier`` is removed, max(v, v) folded, a complex
    exponential expanded into cosines and sines."""
    both = jnp.stack([jnp.sin(x), jnp.cos(x)])
    both = jnp.sum(jnp.stack([both, 0.0 * both]), axis=0)
    return both[0], both[1]


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
