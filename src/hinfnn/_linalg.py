"""Small dense linear algebra written for the compiled loop: products of small matrices as
multiply-and-sum, shared sines and cosines, closed-form inverses of 1 × 1 and 2 × 2 matrices and a
written-out Cholesky factorisation of the small SPD matrices of a 6-DOF arm.

On the CPU, ``jnp.linalg.solve``/``inv`` call LAPACK through a custom call whose fixed cost
dominates a 2 × 2 solve, and a ``dot`` of small operands is a kernel of its own; the forms below
are plain arithmetic that XLA fuses with the rest of the step. Shapes are static, so the choice is
made at trace time, by a value: :class:`Kernels`, the formulation one program is written with (small
products, sines and cosines, Cholesky, stores, the layout of a batch, a URDF chain's kinematics). It
is chosen once per program (:meth:`Kernels.loop` for the simulator's programs, :meth:`Kernels.design`
for the programs that run once) and held by the objects that use it: every model, plant, controller
and reference whose code the loop runs has a static ``kernels`` field, set for a whole tree of
objects by :meth:`Kernels.hold`, and calls ``self.kernels.mm(a, b)`` and the like. Nothing here
reads a context: what a function computes is decided by its arguments.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax import custom_batching, lax
from jax.experimental.layout import Layout, with_layout_constraint


#: Longest contraction :meth:`Kernels.mm` writes as multiply-and-sum (the 6 × 6 matrices of a 6-DOF arm
#: included: a ``dot`` is a kernel of its own, multiply-and-sum fuses with its neighbours).
SMALL_MM = 8


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


def _stored_fn(minor: bool):
    """The custom-derivative store of :meth:`Kernels.stored`, laid out member-minor or not."""

    @jax.custom_jvp
    def _stored(x):
        y = x / (1.0 + 0.0 * x)
        return _member_minor(y) if minor else y

    @_stored.defjvp
    def _stored_jvp(primals, tangents):
        (x,), (t,) = primals, tangents
        return _stored(x), _stored(t)

    return _stored


_STORED = {False: _stored_fn(False), True: _stored_fn(True)}


@dataclasses.dataclass(frozen=True)
class Kernels:
    """How the small linear algebra of one program is written: a frozen, hashable value, static in
    every pytree that holds it (a ``kernels`` field), so a program traced with some kernels is never
    reused with others. Each field changes how XLA executes the program, never what it computes
    (the numbers agree to rounding, most of them bit for bit; docs/architecture.md, "Writing code
    the loop runs").

    ``shared_sincos``
        :meth:`sincos` shares one computation of the sines and cosines (the loop option ``sincos``).
    ``small_mm``
        :meth:`mm` writes contractions of at most :data:`SMALL_MM` terms as multiply-and-sum.
    ``arm``
        The arm's kernels (the ``arm_kernels`` loop option: arms of 3 joints or more): products of 3
        to :data:`SMALL_MM` terms as sums of products term by term, the written-out Cholesky with
        its columns stored, :meth:`stored` products.
    ``minor``
        Stored values laid out with a batch's member axis minor (:meth:`member_minor`; the loop
        option ``member_minor``).
    ``products``
        A URDF chain's kinematics by 3 × 3 products (:func:`hinfnn.model.rbd.frames_by_products`)
        in every algorithm of the chain, as the programs that run once trace it; False: component
        by component with stored stages (:func:`hinfnn.model.rbd.frames`), the loop's layout.

    The default (``Kernels()``) is what eager code and the plain ``jax.jit`` programs trace."""

    shared_sincos: bool = True
    small_mm: bool = True
    arm: bool = False
    minor: bool = False
    products: bool = False

    @classmethod
    def loop(cls, n_joints: int, members: int | None = None, options=None) -> "Kernels":
        """The kernels the simulator traces a plant of ``n_joints`` joints with, for a batch of
        ``members`` (None: a single run), under the loop options ``options``
        (:class:`hinfnn._loop.LoopOptions`, default all on; :meth:`~hinfnn._loop.LoopOptions.for_joints`)."""
        from ._loop import LoopOptions

        return cls.of((options or LoopOptions()).for_joints(n_joints, members))

    @classmethod
    def of(cls, options) -> "Kernels":
        """The kernels of loop options already made for an arm (:meth:`hinfnn._loop.LoopOptions.for_joints`)."""
        return cls(shared_sincos=bool(options.sincos), small_mm=bool(options.small_mm), arm=bool(options.arm_kernels),
                   minor=bool(options.member_minor))

    @classmethod
    def design(cls, n_joints: int) -> "Kernels":
        """The kernels of a program that runs once (the start pose, the checks, the design): the
        default ones, with a URDF chain's kinematics by products on arms of 3 joints or more
        (:data:`hinfnn._loop.ROLL_FROM_JOINTS`), where they make a program a fraction of the size."""
        from ._loop import ROLL_FROM_JOINTS

        return cls(products=n_joints >= ROLL_FROM_JOINTS)

    def replace(self, **changes) -> "Kernels":
        """These kernels with ``changes``."""
        return dataclasses.replace(self, **changes)

    def hold(self, tree):
        """``tree`` (any nesting of dataclasses, tuples, lists and dicts: a plant, a controller, a
        reference, the arguments of a program) with the ``kernels`` field of every object in it set
        to these kernels: the objects it holds are rebuilt, nothing else changes (what a program
        calls before it traces its objects' code)."""
        return hold(tree, self)

    # --- the linear algebra ------------------------------------------------------------------------
    def mm(self, a, b):
        """``a @ b`` for vectors and matrices; contractions over at most :data:`SMALL_MM` terms are
        written as multiply-and-sum (``small_mm``). With ``arm``, contractions of 3 to
        :data:`SMALL_MM` terms are a sum of products term by term, all elementwise: a reduction is a
        kernel of its own in XLA's CPU compiler, the elementwise sum fuses with the arithmetic
        around it."""
        K = a.shape[-1] if a.ndim else 0
        if (self.small_mm and self.arm and 3 <= K <= SMALL_MM and 1 <= a.ndim <= 2 and 1 <= b.ndim <= 2
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
        if (not self.small_mm or a.ndim > 2 or b.ndim > 2 or a.shape[-1] != b.shape[0]
                or a.shape[-1] > SMALL_MM):
            return a @ b
        if a.ndim == 1 and b.ndim == 1:
            return jnp.sum(a * b)
        if a.ndim == 2 and b.ndim == 1:
            return jnp.sum(a * b[None, :], axis=1)
        if a.ndim == 1:
            return jnp.sum(a[:, None] * b, axis=0)
        return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)

    def sincos(self, x):
        """(sin x, cos x) of a vector of angles, computed once and shared (``shared_sincos``): the values
        pass through a sum with 0·v, which XLA never recomputes inside the kernels that use them
        (exact for finite values; NaN stays NaN)."""
        s, c = jnp.sin(x), jnp.cos(x)
        if not self.shared_sincos:
            return s, c
        both = jnp.stack([s, c])
        both = jnp.sum(jnp.stack([both, 0.0 * both]), axis=0)
        return both[0], both[1]

    def solve(self, A, b):
        """A⁻¹ b for a vector or matrix right-hand side (the cofactor inverse for n ≤ 2)."""
        if A.shape[-1] <= 2:
            return self.mm(inv(A), b)
        return jnp.linalg.solve(A, b)

    def member_minor(self, x):
        """x as it is, laid out in memory with a batch's member axis minor (``minor``, under
        ``jax.vmap``; else x untouched). For a stored value (:meth:`store`, :meth:`stored`,
        :func:`hinfnn.model.rbd.keep`): ``vmap`` puts the member axis first, so a member's 6 × 6
        matrix is 36 adjacent values and the kernels that read it vectorise over a row of 6;
        member-minor, each entry is a contiguous vector over the members and every kernel around it
        runs on whole SIMD registers. A constraint on every value would cut XLA's fusions (tried:
        slower); on the stored values, which are written to memory anyway, XLA's layout assignment
        carries the layout to the kernels around them."""
        if not self.minor:
            return x
        return _member_minor(x)

    def default_layout(self, tree):
        """Every array of ``tree`` in the default (row-major) layout (``minor``, under
        ``jax.vmap``; else the tree untouched): a compiled program's outputs, which JAX assumes
        laid out so."""
        if not self.minor:
            return tree
        return jax.tree.map(lambda x: _member_major(x) if isinstance(x, jax.Array) or hasattr(x, "aval") else x, tree)

    def store(self, x, one):
        """x computed once and kept: divided by ``one`` (:func:`runtime_one`, exact). XLA's CPU
        compiler recomputes cheap arithmetic in every kernel that uses it, and a division is not
        cheap in its book, so the value is computed in one kernel and read by the others. Keep what
        is stored at most 64 values (512 bytes: XLA's CPU runtime runs a loop body's kernels inline
        only when every buffer is that small). XLA may rewrite the division by the broadcast scalar
        into a product with its reciprocal, which it then copies into the readers like any product
        (a 6 × 6 product read by six kernels was computed six times): for such a value use
        :meth:`stored`. Laid out by :meth:`member_minor`."""
        return self.member_minor(x / one)

    def stored(self, x):
        """x computed in one kernel and read from memory by every kernel that uses it, with
        ``arm``; else x. For a product read by several others: a 6 × 6 product feeding the six
        column kernels of :meth:`chol` was recomputed in each of them. Written x / (1 + 0·x), exact
        (NaN stays NaN): XLA does not copy a division into several consumers, and it turns a
        division by a broadcast scalar (:meth:`store`) into a product that it does copy. Its
        derivative is the tangent stored the same way. Laid out by :meth:`member_minor`."""
        if not self.arm:
            return x
        return _STORED[self.minor](x)

    def chol(self, A):
        """Lower Cholesky factor L (A = L Lᵀ) of a symmetric positive definite A (NaN if it is
        not), column by column as whole-vector operations: L_:j = v / √v_j with v = A_:j − Σ_{k<j}
        L_:k L_jk. With ``arm`` each column is one stored kernel (:meth:`store`), written
        v · rsqrt(v_j) with the pivot taken in every entry (a scalar broadcast is a kernel of its own)."""
        n = A.shape[-1]
        if n > SMALL_SPD or A.ndim != 2:
            return jnp.linalg.cholesky(A)
        if self.arm:
            return jnp.stack(self._stored_columns(A)[0], axis=1)
        rows = np.arange(n)
        cols = []
        for j in range(n):
            v = A[:, j]
            for k in range(j):
                v = v - cols[k] * cols[k][j]
            cols.append(jnp.where(rows >= j, v / jnp.sqrt(v[j]), 0.0))
        return jnp.stack(cols, axis=1)

    def _stored_columns(self, A, guard: bool = False):
        """(the columns of A's lower Cholesky factor, whether every pivot is positive), each column
        one stored kernel (:meth:`store`), written v · rsqrt(v_j) with the pivot v_j in every entry
        (a scalar broadcast is a kernel of its own). ``guard``: a pivot ≤ 0 is taken as 1 (the
        columns stay finite; the answer is in the flag), else the column is NaN as √ of it is."""
        n = A.shape[-1]
        one = runtime_one(A)
        A = self.stored(A)  # read by every column's kernel: computed once
        rows = np.arange(n)
        ok = jnp.array(True)
        cols = []
        for j in range(n):
            v = A[:, j]
            for k in range(j):
                v = v - cols[k] * cols[k][j]
            ok = ok & (v[j] > 0.0)
            pivot = (jnp.where(v[j] > 0.0, v[j], 1.0) if guard else v[j]) + 0.0 * v  # v_j in every entry (exact)
            cols.append(self.store(jnp.where(rows >= j, v * lax.rsqrt(pivot), 0.0), one))
        return cols, ok

    def chol_solve(self, L, B):
        """A⁻¹ B from A's Cholesky factor L (B a vector or a matrix): forward and back substitution
        written out, row by row. With ``arm`` the reciprocals of L's diagonal are computed once and
        the solution is one stored kernel (:meth:`store`)."""
        n = L.shape[-1]
        if n > SMALL_SPD:
            import jax.scipy.linalg as jsl

            return jsl.cho_solve((L, True), B)
        kept = self.arm
        if kept:
            one = runtime_one(L)
            d = self.store(1.0 / jnp.diagonal(L), one)

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
        return self.store(out, one) if kept else out

    def positive_definite(self, A):
        """Whether the symmetric A (n ≤ :data:`SMALL_SPD`) is positive definite: every pivot of
        its Cholesky factorisation (written out as in :meth:`chol`) is positive (a traced boolean).
        Exact up to the rounding of the pivots: for A = J Jᵀ − s² I it says σ_min(J) > s without a
        singular value decomposition."""
        return self._stored_columns(A, guard=True)[1]

    def spd_solve(self, A, B):
        """A⁻¹ B for a symmetric positive definite A (Cholesky)."""
        if A.shape[-1] <= 2:
            return self.solve(A, B)
        return self.chol_solve(self.chol(A), B)


jax.tree_util.register_static(Kernels)

#: The default kernels (eager code, plain ``jax.jit`` programs): what every object holds until a
#: program's kernels are set on it (:meth:`Kernels.hold`).
DEFAULT = Kernels()


def kernels_field():
    """The ``kernels`` field of an object whose code the loop runs: static (part of the pytree's
    structure, so of a program's key), keyword-only, :data:`DEFAULT` until a program holds the
    object with its own (:meth:`Kernels.hold`)."""
    return dataclasses.field(default=DEFAULT, kw_only=True, metadata={"static": True})


def hold(tree, kernels):
    """``tree`` with the ``kernels`` field of every dataclass in it set to ``kernels`` (a
    :class:`Kernels`, or a function of an object's present kernels that returns its new ones),
    through dataclass fields, tuples, lists, dicts and the children of other pytree nodes. Dataclasses
    are rebuilt without running their ``__init__`` (their arrays may be tracers), other nodes by
    their unflatten, and only where something changed."""
    if dataclasses.is_dataclass(tree) and not isinstance(tree, type):
        if isinstance(tree, Kernels):
            return tree
        changed = {}
        for f in dataclasses.fields(tree):
            value = getattr(tree, f.name)
            if f.name == "kernels" and isinstance(value, Kernels):
                new = kernels(value) if callable(kernels) and not isinstance(kernels, Kernels) else kernels
            else:
                new = hold(value, kernels)
            if new is not value:
                changed[f.name] = new
        if not changed:
            return tree
        out = object.__new__(type(tree))
        for f in dataclasses.fields(tree):
            object.__setattr__(out, f.name, changed.get(f.name, getattr(tree, f.name)))
        return out
    if isinstance(tree, (list, tuple)) and type(tree).__name__ != "Note":
        items = [hold(x, kernels) for x in tree]
        if all(a is b for a, b in zip(items, tree)):
            return tree
        if isinstance(tree, list):
            return items
        return type(tree)._make(items) if hasattr(tree, "_make") else type(tree)(items)
    if isinstance(tree, dict):
        items = {k: hold(v, kernels) for k, v in tree.items()}
        if all(items[k] is tree[k] for k in tree):
            return tree
        return type(tree)(items) if type(tree) is dict else {**items}
    if tree is None or isinstance(tree, (jax.Array, np.ndarray, np.generic, int, float, complex, str, bytes)):
        return tree
    # another pytree node (a plant registered with its own flatten, e.g. MuJoCo's): its children
    children, treedef = jax.tree_util.tree_flatten(tree, is_leaf=lambda x: x is not tree)
    if len(children) == 1 and children[0] is tree:  # a leaf
        return tree
    new = [hold(c, kernels) for c in children]
    if all(a is b for a, b in zip(new, children)):
        return tree
    return jax.tree_util.tree_unflatten(treedef, new)
