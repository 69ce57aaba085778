"""Small dense linear algebra written for the compiled loop: products of small matrices as
multiply-and-sum, shared sines and cosines, closed-form inverses of 1 × 1 and 2 × 2 matrices and a
written-out Cholesky factorisation of the small SPD matrices of a 6-DOF arm.

On the CPU, ``jnp.linalg.solve``/``inv`` call LAPACK through a custom call whose fixed cost
dominates a 2 × 2 solve, and a ``dot`` of small operands is a kernel of its own; the forms below
are plain arithmetic that XLA fuses with the rest of the step. Shapes are static, so the choice is
made at trace time; :mod:`hinfnn._loop` says which of these the traced program uses (its
``small_mm`` and ``sincos`` options).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import custom_batching, lax
from jax.experimental.layout import Layout, with_layout_constraint

from . import _loop

#: Longest contraction :func:`mm` writes as multiply-and-sum (the 6 × 6 matrices of a 6-DOF arm
#: included: a ``dot`` is a kernel of its own, multiply-and-sum fuses with its neighbours).
SMALL_MM = 8


def mm(a, b):
    """``a @ b`` for vectors and matrices; contractions over at most :data:`SMALL_MM` terms are
    written as multiply-and-sum (the ``small_mm`` loop option, :mod:`hinfnn._loop`). With the
    ``arm_kernels`` option (arms of 3 or more joints), contractions of 3 to :data:`SMALL_MM` terms
    are a sum of products term by term, all elementwise: a reduction is a kernel of its own in
    XLA's CPU compiler, the elementwise sum fuses with the arithmetic around it."""
    opts = _loop.current()
    K = a.shape[-1] if a.ndim else 0
    if (opts.small_mm and opts.arm_kernels and 3 <= K <= SMALL_MM and 1 <= a.ndim <= 2 and 1 <= b.ndim <= 2
            and b.shape[0] == K):
        if a.ndim == 2 and b.ndim == 2:
            terms = [a[:, k:k + 1] * b[k:k + 1, :] for k in range(K)]
        elif a.ndim == 2:
            terms = [a[:, k] * b[k] for k in range(K)]
        elif b.ndim == 2:
            terms = [a[k] * b[k, :] for k in range(K)]
        else:
            terms = [a[k] * b[k] for k in range(K)]
        out = terms[0]
        for t in terms[1:]:
            out = out + t
        return out
    if (not opts.small_mm or a.ndim > 2 or b.ndim > 2 or a.shape[-1] != b.shape[0]
            or a.shape[-1] > SMALL_MM):
        return a @ b
    if a.ndim == 1 and b.ndim == 1:
        return jnp.sum(a * b)
    if a.ndim == 2 and b.ndim == 1:
        return jnp.sum(a * b[None, :], axis=1)
    if a.ndim == 1:
        return jnp.sum(a[:, None] * b, axis=0)
    return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)


def sincos(x):
    """(sin x, cos x) of a vector of angles, computed once and shared (the ``sincos`` loop option,
    :mod:`hinfnn._loop`): the values pass through a sum with 0·v, which XLA never recomputes inside
    the kernels that use them (exact for finite values; NaN stays NaN)."""
    s, c = jnp.sin(x), jnp.cos(x)
    if not _loop.current().sincos:
        return s, c
    both = jnp.stack([s, c])
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


#: Largest symmetric positive definite matrix factored by the written-out Cholesky below (a 6-DOF
#: arm's M, task-space inertia and their blocks): plain arithmetic that XLA fuses into a few
#: kernels (LAPACK's factorisation is a custom call of its own, and an LU solve also runs a small
#: loop over the pivots, about 50 extra kernels per solve inside the time loop).
SMALL_SPD = 8


def runtime_one(x):
    """1.0 as a value XLA cannot fold (1 + 0·x₀, x any array; NaN when x₀ is not finite, as
    everything computed from x then is)."""
    return 1.0 + 0.0 * jnp.reshape(x, (-1,))[0]


@custom_batching.custom_vmap
def _member_minor(x):
    return x


@_member_minor.def_vmap
def _member_minor_vmap(axis_size, in_batched, x):
    # vmap puts the member axis first (major); the layout puts it last (minor) in memory
    if not in_batched[0] or x.ndim < 2:
        return x, in_batched[0]
    return with_layout_constraint(x, Layout(major_to_minor=tuple(range(1, x.ndim)) + (0,))), True


@custom_batching.custom_vmap
def _member_major(x):
    return x


@_member_major.def_vmap
def _member_major_vmap(axis_size, in_batched, x):
    if not in_batched[0] or x.ndim < 2:
        return x, in_batched[0]
    return with_layout_constraint(x, Layout(major_to_minor=tuple(range(x.ndim)))), True


def member_minor(x):
    """x as it is, laid out in memory with a batch's member axis minor (the ``member_minor`` loop
    option, under ``jax.vmap``; else x untouched). For a stored value (:func:`store`,
    :func:`stored`, :func:`hinfnn.model.rbd.keep`): ``vmap`` puts the member axis first, so a
    member's 6 × 6 matrix is 36 adjacent values and the kernels that read it vectorise over a
    row of 6; member-minor, each entry is a contiguous vector over the members and every kernel
    around it runs on whole SIMD registers. A constraint on every value would cut XLA's fusions
    (tried: slower); on the stored values, which are written to memory anyway, XLA's layout
    assignment carries the layout to the kernels around them."""
    if not _loop.current().member_minor:
        return x
    return _member_minor(x)


def default_layout(tree):
    """Every array of ``tree`` in the default (row-major) layout (the ``member_minor`` loop option,
    under ``jax.vmap``; else the tree untouched): a compiled program's outputs, which JAX assumes
    laid out so."""
    if not _loop.current().member_minor:
        return tree
    return jax.tree.map(lambda x: _member_major(x) if isinstance(x, jax.Array) or hasattr(x, "aval") else x, tree)


def store(x, one):
    """x computed once and kept: divided by ``one`` (:func:`runtime_one`, exact). XLA's CPU
    compiler recomputes cheap arithmetic in every kernel that uses it, and a division is not cheap
    in its book, so the value is computed in one kernel and read by the others. Keep what is
    stored at most 64 values (512 bytes: XLA's CPU runtime runs a loop body's kernels inline only
    when every buffer is that small). XLA may rewrite the division by the broadcast scalar into a
    product with its reciprocal, which it then copies into the readers like any product (a 6 × 6
    product read by six kernels was computed six times): for such a value use :func:`stored`.
    (Making this function :func:`stored` was measured and is slower: more kernels per UR5 step.)
    Laid out by :func:`member_minor`."""
    return member_minor(x / one)


def stored(x):
    """x computed in one kernel and read from memory by every kernel that uses it, with the
    ``arm_kernels`` loop option; else x. For a product read by several others: a 6 × 6 product
    feeding the six column kernels of :func:`chol` was recomputed in each of them (about 800
    operations apiece). Written x / (1 + 0·x), exact (NaN stays NaN): XLA does not copy a division
    into several consumers, and it turns a division by a broadcast scalar (:func:`store`) into a
    product that it does copy. Its derivative is the tangent stored the same way. Laid out by
    :func:`member_minor`."""
    if not _loop.current().arm_kernels:
        return x
    return _stored(x)


@jax.custom_jvp
def _stored(x):
    return member_minor(x / (1.0 + 0.0 * x))


@_stored.defjvp
def _stored_jvp(primals, tangents):
    (x,), (t,) = primals, tangents
    return _stored(x), _stored(t)


def chol(A):
    """Lower Cholesky factor L (A = L Lᵀ) of a symmetric positive definite A (NaN if it is not),
    column by column as whole-vector operations: L_:j = v / √v_j with v = A_:j − Σ_{k<j} L_:k L_jk.
    With the ``arm_kernels`` loop option each column is one stored kernel (:func:`store`), written
    v · rsqrt(v_j) with the pivot taken in every entry (a scalar broadcast is a kernel of its own)."""
    n = A.shape[-1]
    if n > SMALL_SPD or A.ndim != 2:
        return jnp.linalg.cholesky(A)
    if _loop.current().arm_kernels:
        return jnp.stack(_stored_columns(A)[0], axis=1)
    rows = np.arange(n)
    cols = []
    for j in range(n):
        v = A[:, j]
        for k in range(j):
            v = v - cols[k] * cols[k][j]
        cols.append(jnp.where(rows >= j, v / jnp.sqrt(v[j]), 0.0))
    return jnp.stack(cols, axis=1)


def _stored_columns(A, guard: bool = False):
    """(the columns of A's lower Cholesky factor, whether every pivot is positive), each column one
    stored kernel (:func:`store`), written v · rsqrt(v_j) with the pivot v_j in every entry (a
    scalar broadcast is a kernel of its own). ``guard``: a pivot ≤ 0 is taken as 1 (the columns
    stay finite; the answer is in the flag), else the column is NaN as √ of it is."""
    n = A.shape[-1]
    one = runtime_one(A)
    A = stored(A)  # read by every column's kernel: computed once
    rows = np.arange(n)
    ok = jnp.array(True)
    cols = []
    for j in range(n):
        v = A[:, j]
        for k in range(j):
            v = v - cols[k] * cols[k][j]
        ok = ok & (v[j] > 0.0)
        pivot = (jnp.where(v[j] > 0.0, v[j], 1.0) if guard else v[j]) + 0.0 * v  # v_j in every entry (exact)
        cols.append(store(jnp.where(rows >= j, v * lax.rsqrt(pivot), 0.0), one))
    return cols, ok


def chol_solve(L, B):
    """A⁻¹ B from A's Cholesky factor L (B a vector or a matrix): forward and back substitution
    written out, row by row. With the ``arm_kernels`` loop option the reciprocals of L's diagonal
    are computed once and the solution is one stored kernel (:func:`store`)."""
    n = L.shape[-1]
    if n > SMALL_SPD:
        import jax.scipy.linalg as jsl

        return jsl.cho_solve((L, True), B)
    kept = _loop.current().arm_kernels
    if kept:
        one = runtime_one(L)
        d = store(1.0 / jnp.diagonal(L), one)

        def div(x, i):
            return x * d[i]
    else:
        def div(x, i):
            return x / L[i, i]
    y = []
    for i in range(n):
        acc = B[i]
        for k in range(i):
            acc = acc - L[i, k] * y[k]
        y.append(div(acc, i))
    x = [None] * n
    for i in reversed(range(n)):
        acc = y[i]
        for k in range(i + 1, n):
            acc = acc - L[k, i] * x[k]
        x[i] = div(acc, i)
    out = jnp.stack(x)
    return store(out, one) if kept else out


def positive_definite(A):
    """Whether the symmetric A (n ≤ :data:`SMALL_SPD`) is positive definite: every pivot of its
    Cholesky factorisation (written out as in :func:`chol`) is positive (a traced boolean). Exact
    up to the rounding of the pivots: for A = J Jᵀ − s² I it says σ_min(J) > s without a singular
    value decomposition."""
    return _stored_columns(A, guard=True)[1]


def spd_solve(A, B):
    """A⁻¹ B for a symmetric positive definite A (Cholesky)."""
    if A.shape[-1] <= 2:
        return solve(A, B)
    return chol_solve(chol(A), B)
