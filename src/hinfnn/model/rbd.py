"""Rigid-body algorithms of a serial chain, written for XLA's CPU compiler: the forward
kinematics, the frame Jacobian and its rate, CRBA, RNEA, gravity and the Christoffel product of
:class:`~hinfnn.model.urdf.UrdfChain` (Featherstone, *Rigid Body Dynamics Algorithms*, ch. 2–6;
motion vectors (linear, angular) at the base origin, in base-frame axes, as Pinocchio's
LOCAL_WORLD_ALIGNED).

How the arithmetic is laid out, and why (``docs/architecture.md``, "Writing code the loop runs"):

* **Components first, bodies last.** A 3-vector is a Python tuple of three arrays, a rotation a
  3 × 3 tuple of tuples, a spatial vector a 6-tuple; each array holds one component for every
  body (shape (n,)) or for one body (shape ()). Every operation is elementwise: no reductions,
  no tiny matrix products, no concatenations inside the algorithms, which XLA would turn into
  kernels of their own (a UR5 right-hand side compiled into about 500 kernels, each launched one
  by one by XLA's CPU runtime). Under ``vmap`` each component becomes a vector over the batch.
* **Explicit materialisation** (:func:`keep`). XLA's fusion recomputes cheap arithmetic in every
  kernel that uses it; only "expensive" operations (a division, a reduction) are computed once
  and stored. The algorithms are cut into a few stages whose results are stored once
  (:func:`keep`: the values stacked in one buffer of at most 64 numbers and divided by a one
  XLA cannot see through): each stage is one fused kernel, and nothing is recomputed across
  stages. Buffers stay at most 512 bytes: XLA's CPU runtime runs a loop body's kernels inline
  only when every buffer they touch is that small (:data:`hinfnn._loop.SEQUENTIAL_VALUES`). In a
  batch each stored buffer is laid out with the member axis minor
  (:meth:`hinfnn._linalg.Kernels.member_minor`, the chain's ``kernels``).
* **The chain's structure is unrolled** at trace time: the Python loop over the (static) joints
  and joint types, prefix and suffix sums over the bodies written out.

The numbers equal the previous vectorised formulation to rounding (the order of the sums
differs), and Pinocchio's to 1e-10 relative (tests/test_urdf.py).

That layout is for the compiled loop, which runs its step millions of times. The programs that run
once (the start pose's and the reference path's Newton solves, the effective and normal masses,
the design's equilibria) are paid by their compile time, and there the layout is about five
times the program: :func:`placements` computes the same kinematics by 3 × 3 array products
(``UrdfChain.fk``), and :func:`frames_by_products` puts them in the layout every algorithm below
reads, with nothing stored, so that those programs trace the same algorithms on a fifth of the
program (``UrdfChain.fk``, ``frame_jacobian``, ``M`` and ``UrdfArm.J`` always; every algorithm when
the chain's kernels say so, :attr:`hinfnn._linalg.Kernels.products`, which the design's and the
setup programs of arms hold). Both are checked against Pinocchio.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._linalg import DEFAULT, Kernels

#: Largest number of float64 values in one stored buffer (512 bytes,
#: :data:`hinfnn._loop.SEQUENTIAL_VALUES`).
BUFFER = 64
#: Widest concatenation of one row in :func:`grid_stack` (XLA's CPU compiler fuses a
#: concatenation of at most 8 operands, and one along the fastest-varying axis only below 64 bytes).
ROW = 7
#: The stages are stored (:func:`keep`); False lets XLA fuse freely (for the benchmark's A/B).
STORE = True


# ---------------------------------------------------------------------------------------------
# Storing a stage
# ---------------------------------------------------------------------------------------------
def runtime_one(x):
    """1.0 as a value XLA cannot fold (1 + 0·x; NaN when x is not finite, as everything
    computed from x then is)."""
    return 1.0 + 0.0 * jnp.reshape(x, (-1,))[0]


def grid_stack(parts, width: int = ROW):
    """``jnp.stack(parts)`` (equal shapes) as rows of at most ``width`` values concatenated along
    one axis and the rows along another: XLA's simplifier merges nested concatenations along
    one axis into one, and XLA's CPU compiler does not fuse one of more than 8 operands."""
    parts = [jnp.asarray(p) for p in parts]
    if len(parts) <= width:
        return jnp.stack(parts)
    shape = parts[0].shape
    zero = jnp.zeros((1, 1) + shape, parts[0].dtype)
    rows = []
    for i in range(0, len(parts), width):
        row = [p.reshape((1, 1) + shape) for p in parts[i:i + width]]
        rows.append(jnp.concatenate(row + [zero] * (width - len(row)), axis=1))
    return jnp.concatenate(rows, axis=0).reshape((-1,) + shape)[: len(parts)]


def keep(parts, one, kernels: Kernels = DEFAULT):
    """The arrays ``parts`` (equal shapes), each computed once and stored: stacked into buffers of
    at most :data:`BUFFER` values, each divided by ``one`` (:func:`runtime_one`; exact), which XLA
    computes in one kernel and does not recompute in the kernels that read it, laid out by
    ``kernels`` (:meth:`~hinfnn._linalg.Kernels.member_minor`). Returns the parts as a tuple."""
    parts = [jnp.asarray(p) for p in parts]
    if not STORE or not parts:
        return tuple(parts)
    size = max(1, int(np.prod(parts[0].shape, dtype=int)))
    per = max(1, BUFFER // size)
    out = []
    for i in range(0, len(parts), per):
        group = parts[i:i + per]
        x = kernels.member_minor(grid_stack(group) / one)
        out.extend(x[j] for j in range(len(group)))
    return tuple(out)


def table(rows, one, kernels: Kernels = DEFAULT):
    """Per-body tuples of scalars (``rows[i][k]``: component k of body i) stored component by
    component: returns a tuple of (n,) arrays (component k over the bodies). The stacking is
    the stored kernel's output, so nothing is gathered elsewhere."""
    n, K = len(rows), len(rows[0])
    flat = [jnp.asarray(rows[i][k], dtype=float) for k in range(K) for i in range(n)]
    if not STORE:
        return tuple(jnp.stack(flat[k * n:(k + 1) * n]) for k in range(K))
    per = max(1, BUFFER // n)  # components per buffer
    out = []
    for k0 in range(0, K, per):
        group = flat[k0 * n:min(K, k0 + per) * n]
        x = kernels.member_minor(grid_stack(group) / one)
        out.extend(x[j * n:(j + 1) * n] for j in range(len(group) // n))
    return tuple(out)


def table_column(rows, k):
    """Component k over the bodies of per-body stored values (a stack of stored scalars)."""
    return jnp.stack([r[k] for r in rows])


def keep_tree(tree, one, kernels: Kernels = DEFAULT):
    """:func:`keep` of every array of a pytree of arrays with equal shapes."""
    leaves, treedef = jax.tree.flatten(tree)
    return jax.tree.unflatten(treedef, keep(leaves, one, kernels))


# ---------------------------------------------------------------------------------------------
# Component algebra (tuples of arrays, elementwise)
# ---------------------------------------------------------------------------------------------
def cross(a, b):
    """a × b."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def add(a, b):
    return tuple(x + y for x, y in zip(a, b))


def sub(a, b):
    return tuple(x - y for x, y in zip(a, b))


def scale(s, a):
    return tuple(s * x for x in a)


def matvec(R, v):
    """R v."""
    return tuple(R[i][0] * v[0] + R[i][1] * v[1] + R[i][2] * v[2] for i in range(3))


def matmul(A, B):
    """A B."""
    return tuple(tuple(A[i][0] * B[0][j] + A[i][1] * B[1][j] + A[i][2] * B[2][j] for j in range(3))
                 for i in range(3))


def crm(v, m):
    """Motion cross product v ×ₘ m (Featherstone eq. 2.31 with (linear, angular) order)."""
    return add(cross(v[3:], m[:3]), cross(v[:3], m[3:])) + cross(v[3:], m[3:])


def crf(v, f):
    """Force cross product v ×* f = −(v ×ₘ)ᵀ f (force, moment order)."""
    return cross(v[3:], f[:3]) + add(cross(v[3:], f[3:]), cross(v[:3], f[:3]))


def inertia_apply(m, h, Ib, x):
    """Spatial inertia (mass m, first moment h = m c, rotational inertia Ī about the origin, as
    its six entries xx, yy, zz, xy, xz, yz) times the motion vector x: (m x_l − h × x_w,
    h × x_l + Ī x_w)."""
    xl, xw = x[:3], x[3:]
    Iw = (Ib[0] * xw[0] + Ib[3] * xw[1] + Ib[4] * xw[2],
          Ib[3] * xw[0] + Ib[1] * xw[1] + Ib[5] * xw[2],
          Ib[4] * xw[0] + Ib[5] * xw[1] + Ib[2] * xw[2])
    return sub(scale(m, xl), cross(h, xw)) + add(cross(h, xl), Iw)


def _masked_sum(x, mask):
    """Σ_k x_k mask[:, k] (x (n,) over the bodies, mask a constant n × n 0/1 matrix): written as
    a sum of constant vectors scaled by the entries of x, all elementwise (a concatenation of
    the partial sums would be a kernel of its own). Adding exact zeros leaves the values as the
    sequential sums give them."""
    n = x.shape[-1]
    out = x[..., 0:1] * mask[:, 0]
    for k in range(1, n):
        out = out + x[..., k:k + 1] * mask[:, k]
    return out


def prefix(x):
    """Σ_{k ≤ i} x_k over the bodies (the last axis)."""
    n = x.shape[-1]
    return _masked_sum(x, np.tril(np.ones((n, n))))


def suffix(x):
    """Σ_{k ≥ i} x_k over the bodies (the composite sums of the backward passes)."""
    n = x.shape[-1]
    return _masked_sum(x, np.triu(np.ones((n, n))))


def assemble(values):
    """The (n,) array of n scalars, as a sum of scaled constant unit vectors (elementwise)."""
    n = len(values)
    eye = np.eye(n)
    out = jnp.asarray(values[0])[..., None] * eye[0]
    for i in range(1, n):
        out = out + jnp.asarray(values[i])[..., None] * eye[i]
    return out


def sdot(a, b):
    """a · b of two 6-tuples."""
    return sum((x * y for x, y in zip(a[1:], b[1:])), a[0] * b[0])


# ---------------------------------------------------------------------------------------------
# Kinematics
# ---------------------------------------------------------------------------------------------
class Frames(NamedTuple):
    """Everything position-dependent, base frame, components first (each a (n,) array over the
    bodies unless said): body rotations ``R`` (3 × 3), origins ``p`` (3), motion subspaces ``S``
    (6: S_i = (p_i × a_i, a_i) revolute, (a_i, 0) prismatic, a_i the world axis), body inertias
    about the base origin (``m``, ``h`` = m c (3), ``Ib`` (6 entries)), the tool frame ``R_tool``
    (3 × 3 scalars) and ``p_tool`` (3 scalars), ``one`` (:func:`runtime_one`) and the ``kernels``
    every algorithm below stores its stages with (:func:`keep`)."""

    R: tuple
    p: tuple
    S: tuple
    m: jax.Array
    h: tuple
    Ib: tuple
    R_tool: tuple
    p_tool: tuple
    one: jax.Array
    kernels: Kernels = DEFAULT


def _rows(a):
    """A (..., 3) array as a 3-tuple of its last-axis components."""
    return tuple(a[..., k] for k in range(3))


def _mat(a):
    """A (..., 3, 3) array as a 3 × 3 tuple of components."""
    return tuple(tuple(a[..., r, k] for k in range(3)) for r in range(3))


def frames(chain, q) -> Frames:
    """Forward pass: body placements (the static joints unrolled, one stored stage per body),
    motion subspaces, body inertias in the base frame, tool frame, in the chain's kernels
    (``chain.kernels``): :func:`frames_by_products` when they say ``products``."""
    kern = chain.kernels
    if kern.products:
        return frames_by_products(chain, q)
    one = runtime_one(q)

    s, c = keep([jnp.sin(q), jnp.cos(q)], one, kern)
    R = p = None
    per_body = []
    for i, kind in enumerate(chain.joint_types):
        a = tuple(chain.axes[i, k] for k in range(3))
        P = tuple(tuple(chain.placement_rot[i, r, k] for k in range(3)) for r in range(3))
        pp = tuple(chain.placement_pos[i, k] for k in range(3))
        if kind == "prismatic":
            X = P
        else:  # Rodrigues: c I + s [a]x + (1 − c) a aᵀ
            ci, si = c[i], s[i]
            d = 1.0 - ci
            K = ((None, -a[2], a[1]), (a[2], None, -a[0]), (-a[1], a[0], None))
            rot = tuple(tuple(ci + d * a[r] * a[k] if r == k else si * K[r][k] + d * a[r] * a[k] for k in range(3))
                        for r in range(3))
            X = matmul(P, rot)
        if R is None:
            p, R = pp, X
        else:
            p, R = add(p, matvec(R, pp)), matmul(R, X)
        if kind == "prismatic":
            p = add(p, scale(q[i], matvec(R, a)))
        vals = keep([R[r][k] for r in range(3) for k in range(3)] + list(p), one, kern)
        R, p = tuple(tuple(vals[3 * r + k] for k in range(3)) for r in range(3)), vals[9:]
        per_body.append(vals)
    # per body: world axis, motion subspace, centre of mass, inertia about the base origin
    S_b, inert_b = [], []
    for i, kind in enumerate(chain.joint_types):
        vals = per_body[i]
        R = tuple(tuple(vals[3 * r + k] for k in range(3)) for r in range(3))
        p = vals[9:]
        aw = matvec(R, tuple(chain.axes[i, k] for k in range(3)))
        S_b.append(aw + (0.0, 0.0, 0.0) if kind == "prismatic" else cross(p, aw) + aw)
        m = chain.mass[i]
        cw = add(p, matvec(R, tuple(chain.com[i, k] for k in range(3))))
        I = tuple(tuple(chain.inertia[i, r, k] for k in range(3)) for r in range(3))
        RI = matmul(R, I)
        Ic = [[dot(RI[r], R[k]) for k in range(3)] for r in range(3)]  # R I Rᵀ
        cc = dot(cw, cw)
        Ib = (Ic[0][0] + m * (cc - cw[0] * cw[0]), Ic[1][1] + m * (cc - cw[1] * cw[1]),
              Ic[2][2] + m * (cc - cw[2] * cw[2]), Ic[0][1] - m * cw[0] * cw[1],
              Ic[0][2] - m * cw[0] * cw[2], Ic[1][2] - m * cw[1] * cw[2])
        inert_b.append(scale(m, cw) + Ib)
    S = table(S_b, one, kern)
    inert = table(inert_b, one, kern)
    R_all = tuple(tuple(table_column(per_body, 3 * r + k) for k in range(3)) for r in range(3))
    p_all = tuple(table_column(per_body, 9 + k) for k in range(3))
    Rn = tuple(tuple(per_body[-1][3 * r + k] for k in range(3)) for r in range(3))
    pn = per_body[-1][9:]
    T = tuple(tuple(chain.tool_rot[r, k] for k in range(3)) for r in range(3))
    tp = tuple(chain.tool_pos[k] for k in range(3))
    tool = keep([x for row in matmul(Rn, T) for x in row] + list(add(pn, matvec(Rn, tp))), one, kern)
    R_tool = tuple(tuple(tool[3 * r + k] for k in range(3)) for r in range(3))
    return Frames(R=R_all, p=p_all, S=S, m=chain.mass, h=inert[:3], Ib=inert[3:], R_tool=R_tool, p_tool=tool[9:],
                  one=one, kernels=kern)


def skew(v):
    """[v]×, so that skew(v) @ u = v × u."""
    z = jnp.zeros_like(v[0])
    return jnp.stack([jnp.stack([z, -v[2], v[1]]), jnp.stack([v[2], z, -v[0]]), jnp.stack([-v[1], v[0], z])])


class Placements(NamedTuple):
    """The chain's placements as arrays (:func:`placements`): ``R`` (n, 3, 3) and ``p`` (n, 3) of
    the bodies, ``axes`` (n, 3) the joint axes in the base frame, the tool frame ``p_tool`` (3,)
    and ``R_tool`` (3, 3)."""

    R: jax.Array
    p: jax.Array
    axes: jax.Array
    p_tool: jax.Array
    R_tool: jax.Array


def placements(chain, q) -> Placements:
    """The forward kinematics of :func:`frames` by 3 × 3 array products, for the programs that run
    once (the start pose's and the reference path's Newton solves, the design's equilibria): their
    compile time is their cost, and the component-by-component layout of :func:`frames`, written
    for the compiled loop's speed, is about five times the program. The same placements to
    rounding (tested)."""
    Rw = jnp.eye(3, dtype=q.dtype)
    p = jnp.zeros(3, dtype=q.dtype)
    s, c = jnp.sin(q), jnp.cos(q)
    Rs, ps, aws = [], [], []
    for i, kind in enumerate(chain.joint_types):
        a = chain.axes[i]
        X = chain.placement_rot[i]
        if kind != "prismatic":  # Rodrigues: c I + s [a]x + (1 − c) a aᵀ
            K = skew(a)
            rot = c[i] * jnp.eye(3, dtype=q.dtype) + s[i] * K + (1.0 - c[i]) * jnp.outer(a, a)
            X = X @ rot
        p = p + Rw @ chain.placement_pos[i]
        Rw = Rw @ X
        aw = Rw @ a
        if kind == "prismatic":
            p = p + q[i] * aw
        Rs.append(Rw)
        ps.append(p)
        aws.append(aw)
    return Placements(R=jnp.stack(Rs), p=jnp.stack(ps), axes=jnp.stack(aws),
                      p_tool=p + Rw @ chain.tool_pos, R_tool=Rw @ chain.tool_rot)


def frames_by_products(chain, q) -> Frames:
    """:func:`frames` (the same fields, in its components-first layout, so that every algorithm
    below reads it) from :func:`placements`, by 3 × 3 array products and nothing stored: the
    design's programs (the closed loop's Jacobian, the held plant's, the rest poses), compiled once
    and run a few times, trace the rigid-body algorithms on it: their programs are about two
    thirds the size and compile faster, the same matrix. The same values to rounding (tests/test_urdf.py)."""
    pl = placements(chain, q)
    prismatic = np.array([kind == "prismatic" for kind in chain.joint_types])[:, None]
    lin = jnp.where(prismatic, pl.axes, jnp.cross(pl.p, pl.axes))  # S_i = (p_i × a_i, a_i) or (a_i, 0)
    ang = jnp.where(prismatic, 0.0, pl.axes)
    c = pl.p + jnp.einsum("nij,nj->ni", pl.R, chain.com)  # centres of mass
    Ic = pl.R @ chain.inertia @ jnp.swapaxes(pl.R, 1, 2)  # R I Rᵀ
    m = chain.mass
    cc = jnp.sum(c * c, axis=1)
    Ib = (Ic[:, 0, 0] + m * (cc - c[:, 0] * c[:, 0]), Ic[:, 1, 1] + m * (cc - c[:, 1] * c[:, 1]),
          Ic[:, 2, 2] + m * (cc - c[:, 2] * c[:, 2]), Ic[:, 0, 1] - m * c[:, 0] * c[:, 1],
          Ic[:, 0, 2] - m * c[:, 0] * c[:, 2], Ic[:, 1, 2] - m * c[:, 1] * c[:, 2])
    return Frames(R=tuple(tuple(pl.R[:, r, k] for k in range(3)) for r in range(3)),
                  p=tuple(pl.p[:, k] for k in range(3)),
                  S=tuple(lin[:, k] for k in range(3)) + tuple(ang[:, k] for k in range(3)),
                  m=m, h=tuple(m * c[:, k] for k in range(3)), Ib=Ib,
                  R_tool=tuple(tuple(pl.R_tool[r, k] for k in range(3)) for r in range(3)),
                  p_tool=tuple(pl.p_tool[k] for k in range(3)), one=runtime_one(q), kernels=chain.kernels)


def as_matrix(T):
    """A 3 × 3 tuple of scalars as a (3, 3) array."""
    return jnp.stack([jnp.stack(row) for row in T])


def frame_jacobian(fr: Frames):
    """Geometric Jacobian (6, n) of the tool frame, rows (ṗ_tool, ω), base-frame axes: column i
    is (S_i,lin + S_i,ang × p_tool, S_i,ang) = (a_i × (p_tool − p_i), a_i) for a revolute joint."""
    S = fr.S
    lin = add(S[:3], cross(S[3:], fr.p_tool))
    return jnp.stack(keep(lin + S[3:], fr.one, fr.kernels))


def prefix_sums(parts, one, kernels: Kernels = DEFAULT):
    """:func:`prefix` of each component, the components stored first (a prefix sum reads each
    entry n times: XLA would store each component in a kernel of its own)."""
    return tuple(prefix(x) for x in keep(parts, one, kernels))


def velocities(fr: Frames, qd):
    """Body spatial velocities v_i = Σ_{k ≤ i} S_k q̇_k (6 components, each (n,)), stored."""
    return keep(prefix_sums(tuple(x * qd for x in fr.S), fr.one, fr.kernels), fr.one, fr.kernels)


def frame_jacobian_dot(fr: Frames, qd, v=None):
    """d/dt of :func:`frame_jacobian` along q̇: Ṡ_i = v_i ×ₘ S_i, and the tool point's velocity
    ṗ_tool = v_n,lin + v_n,ang × p_tool in the linear rows."""
    v = velocities(fr, qd) if v is None else v
    S = fr.S
    Sd = crm(v, S)
    vn = tuple(x[..., -1] for x in v)  # the last body's
    pd = add(vn[:3], cross(vn[3:], fr.p_tool))
    lin = add(add(Sd[:3], cross(Sd[3:], fr.p_tool)), cross(S[3:], pd))
    return jnp.stack(keep(lin + Sd[3:], fr.one, fr.kernels))


# ---------------------------------------------------------------------------------------------
# Dynamics
# ---------------------------------------------------------------------------------------------
def composite(fr: Frames):
    """Composite inertias I^c_i = Σ_{k ≥ i} I_k: (m, h (3), Ib (6)), each (n,), stored."""
    vals = keep([suffix(fr.m)] + [suffix(x) for x in fr.h + fr.Ib], fr.one, fr.kernels)
    return vals[0], vals[1:4], vals[4:]


def crba(fr: Frames, comp=None):
    """Joint-space inertia matrix by the composite-rigid-body algorithm: F_j = I^c_j S_j,
    M_ij = S_min(i,j) · F_max(i,j)."""
    mc, hc, Ibc = composite(fr) if comp is None else comp
    F = keep(inertia_apply(mc, hc, Ibc, fr.S), fr.one, fr.kernels)
    n = fr.m.shape[-1]
    A = sdot(tuple(x[..., :, None] for x in fr.S), tuple(x[..., None, :] for x in F))  # A_ij = S_i · F_j
    M = jnp.where(np.triu(np.ones((n, n), dtype=bool)), A, jnp.swapaxes(A, -1, -2))
    return keep([M], fr.one, fr.kernels)[0]


def gravity(fr: Frames, a0, comp=None):
    """G_i = S_i · I^c_i a0 (RNEA at q̇ = q̈ = 0 with composite inertias), a0 = (−g, 0)."""
    mc, hc, Ibc = composite(fr) if comp is None else comp
    return keep([sdot(fr.S, inertia_apply(mc, hc, Ibc, a0))], fr.one, fr.kernels)[0]


def rnea(fr: Frames, qd, qdd, a0, v=None):
    """Recursive Newton–Euler in the base frame: v_i = Σ_{k≤i} S_k q̇_k, a_i = a0 +
    Σ_{k≤i} (S_k q̈_k + v_k ×ₘ S_k q̇_k), f_i = I_i a_i + v_i ×* I_i v_i, τ_i = S_i · Σ_{k≥i} f_k.
    ``qdd`` None: q̈ = 0 (C q̇ + G with a0 = (−g, 0))."""
    v = velocities(fr, qd) if v is None else v
    acc_rate = tuple(x * qd for x in crm(v, fr.S))
    if qdd is not None:
        acc_rate = add(acc_rate, tuple(x * qdd for x in fr.S))
    acc = tuple(x + x0 for x, x0 in zip(prefix_sums(acc_rate, fr.one, fr.kernels), a0))
    f = add(inertia_apply(fr.m, fr.h, fr.Ib, acc), crf(v, inertia_apply(fr.m, fr.h, fr.Ib, v)))
    f = keep(f, fr.one, fr.kernels)
    fs = tuple(suffix(x) for x in f)
    return keep([sdot(fr.S, fs)], fr.one, fr.kernels)[0]


def christoffel(fr: Frames, a, b, va=None):
    """The Christoffel bilinear form Γ(a, b) = C(q, a) b, symmetric in a, b: the polarization of
    c(v) = C(q, v) v (RNEA without gravity, q̈ = 0), written out. With velocities V^a, V^b of the
    two vectors, acc_i = ½ Σ_{k≤i} (V^a_k ×ₘ S_k b_k + V^b_k ×ₘ S_k a_k), f_i = I_i acc_i +
    ½ (V^a_i ×* I_i V^b_i + V^b_i ×* I_i V^a_i), Γ_i = S_i · Σ_{k≥i} f_k. ``va``: V^a when known
    (:func:`velocities`)."""
    S = fr.S
    Va = velocities(fr, a) if va is None else va
    Vb = keep(prefix_sums(tuple(x * b for x in S), fr.one, fr.kernels), fr.one, fr.kernels)
    rate = add(tuple(x * b for x in crm(Va, S)), tuple(x * a for x in crm(Vb, S)))
    acc = tuple(0.5 * x for x in prefix_sums(rate, fr.one, fr.kernels))
    IVa = inertia_apply(fr.m, fr.h, fr.Ib, Va)
    IVb = inertia_apply(fr.m, fr.h, fr.Ib, Vb)
    f = add(inertia_apply(fr.m, fr.h, fr.Ib, acc), scale(0.5, add(crf(Va, IVb), crf(Vb, IVa))))
    f = keep(f, fr.one, fr.kernels)
    fs = tuple(suffix(x) for x in f)
    return keep([sdot(S, fs)], fr.one, fr.kernels)[0]


def gravity_vector(gravity):
    """a0 = (−g, 0, 0, 0) as a 6-tuple (the base's spatial acceleration that puts gravity in)."""
    return (-gravity[0], -gravity[1], -gravity[2], 0.0, 0.0, 0.0)


def potential(fr: Frames, gravity):
    """U = −Σ_i g · h_i (zero at the base origin)."""
    return -jnp.sum(dot(fr.h, _rows(gravity)))
