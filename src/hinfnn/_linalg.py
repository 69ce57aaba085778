"""Closed-form inverses of the tiny matrices of a 2–3 DOF arm, and the products of
:mod:`hinfnn._devices`.

On the CPU, ``jnp.linalg.solve``/``inv`` call LAPACK through a custom call whose fixed cost
dominates a 2 × 2 solve; the cofactor formulas below are plain arithmetic that XLA fuses with
the rest of the step. Larger matrices fall back to ``jnp.linalg``. Shapes are static, so the
choice is made at trace time.
"""

from __future__ import annotations

import jax.numpy as jnp

from . import _devices as _dev
from ._devices import sincos  # noqa: F401  (re-exported: the model code uses la.sincos)

#: Longest contraction :func:`mm` writes as multiply-and-sum (the ``small_mm`` device of
#: :mod:`hinfnn._devices`, extended here from 4 to the 6 × 6 matrices of a 6-DOF arm: a ``dot``
#: is a kernel of its own, multiply-and-sum fuses with its neighbours).
SMALL_MM = 8


def mm(a, b):
    """``a @ b`` for vectors and matrices (:func:`hinfnn._devices.mm`, with contractions up to
    :data:`SMALL_MM` written as multiply-and-sum)."""
    return _dev.mm(a, b, limit=SMALL_MM)


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


#: Largest symmetric positive definite matrix factored by the written-out Cholesky below (a 6-DOF
#: arm's M, task-space inertia and their blocks): plain arithmetic that XLA fuses into a few
#: kernels (LAPACK's factorisation is a custom call of its own, and an LU solve also runs a small
#: loop over the pivots, about 50 extra kernels per solve inside the time loop).
SMALL_SPD = 8


def chol(A):
    """Lower Cholesky factor L (A = L Lᵀ) of a symmetric positive definite A (NaN if it is not),
    column by column as whole-vector operations."""
    n = A.shape[-1]
    if n > SMALL_SPD or A.ndim != 2:
        return jnp.linalg.cholesky(A)
    rows = jnp.arange(n)
    cols = []
    for j in range(n):
        v = A[:, j]
        for k in range(j):
            v = v - cols[k] * cols[k][j]
        cols.append(jnp.where(rows >= j, v / jnp.sqrt(v[j]), 0.0))
    return jnp.stack(cols, axis=1)


def chol_solve(L, B):
    """A⁻¹ B from A's Cholesky factor L (B a vector or a matrix): forward and back substitution
    written out, row by row."""
    n = L.shape[-1]
    if n > SMALL_SPD:
        import jax.scipy.linalg as jsl

        return jsl.cho_solve((L, True), B)
    y = []
    for i in range(n):
        acc = B[i]
        for k in range(i):
            acc = acc - L[i, k] * y[k]
        y.append(acc / L[i, i])
    x = [None] * n
    for i in reversed(range(n)):
        acc = y[i]
        for k in range(i + 1, n):
            acc = acc - L[k, i] * x[k]
        x[i] = acc / L[i, i]
    return jnp.stack(x)


def spd_solve(A, B):
    """A⁻¹ B for a symmetric positive definite A (Cholesky)."""
    if A.shape[-1] <= 2:
        return solve(A, B)
    return chol_solve(chol(A), B)
