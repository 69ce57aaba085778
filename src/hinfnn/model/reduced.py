"""Task-space reduced-order model, paper eqs. (9)–(14), with the docs/paper-conventions.md corrections.

Premultiplying eq. (5) by Sᵀ Ĵ⁻ᵀ gives eq. (9)

    M̄ ü + C̄ u̇ + Ḡ + Sᵀ Âᵀ λ = B̄ τ + B̄ ω_x,    Sᵀ Âᵀ = [0; Πᵀ]  (by eq. 4)

with (printed errors fixed, docs/paper-conventions.md "Printed errors"):

    M̄ = Sᵀ Ĵ⁻ᵀ M̂ Ĵ⁻¹ S          (printed: ... M̂ Ĵ⁻ᵀ S)
    C̄ = Sᵀ Ĵ⁻ᵀ { M̂ Ĵ⁻¹ Ṡ + [Ĉ − M̂ Ĵ⁻¹ J̇̂] Ĵ⁻¹ S }
    Ḡ = Sᵀ Ĵ⁻ᵀ Ĝ                  (printed: Sᵀ Ĵ⁻¹ Ĝ)
    B̄ = Sᵀ Ĵ⁻ᵀ

The partitions (11)–(14) use the m × m, k × m blocks M̄11, M̄21, C̄11, C̄21 and the rows B̄1, B̄2.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._pytree import pytree_dataclass, static_field
from .. import _linalg as la


@pytree_dataclass
class ReducedModel:
    """M̄, C̄, Ḡ, B̄ of eq. (9) at one (q, q̇), with the quantities they were built from."""

    M_bar: jax.Array  # (n, n)
    C_bar: jax.Array | None  # (n, n); None when only the product below is formed
    C_u1dot: jax.Array | None  # C̄ (u̇1, 0) (n,): all of C̄ the law uses (None with C_bar)
    G_bar: jax.Array  # (n,)
    B_bar: jax.Array  # (n, n)
    S: jax.Array
    S_dot: jax.Array
    A_hat: jax.Array  # (k, n)
    x: jax.Array  # nominal task-space position ĥ(q)
    x_dot: jax.Array  # Ĵ q̇
    J: jax.Array  # Ĵ(q)
    J_dot: jax.Array | None  # J̇̂(q, q̇) (None on the "product" path)
    m: int = static_field()
    Jd_qd: jax.Array | None = None  # J̇̂ q̇ (the "product" path)
    J_p: jax.Array | None = None  # the tool point's Jacobian Ĵ_p (None: the task coordinates are the tool point)
    kernels: la.Kernels = la.kernels_field()  # the arm's (hinfnn._linalg.Kernels)

    # --- partitions used by eqs. (11)-(14) ------------------------------------------------
    @property
    def M11(self):
        return self.M_bar[: self.m, : self.m]

    @property
    def M21(self):
        return self.M_bar[self.m :, : self.m]

    @property
    def C11(self):
        return self.C_bar[: self.m, : self.m]

    @property
    def C21(self):
        return self.C_bar[self.m :, : self.m]

    @property
    def G1(self):
        return self.G_bar[: self.m]

    @property
    def G2(self):
        return self.G_bar[self.m :]

    @property
    def B1(self):
        return self.B_bar[: self.m]

    @property
    def B2(self):
        return self.B_bar[self.m :]

    @property
    def Pi(self):
        """Π = ∂θ̂/∂x2 at the nominal end-effector position."""
        return self.A_hat[:, self.m :]

    def coriolis_u1dot(self):
        """C̄ (u̇1, 0) = (C̄11 u̇1, C̄21 u̇1), from C̄ or from the product formed without it."""
        if self.C_u1dot is not None:
            return self.C_u1dot
        u1_dot = self.x_dot[: self.m]
        return jnp.concatenate([self.kernels.mm(self.C11, u1_dot), self.kernels.mm(self.C21, u1_dot)])

    # --- eqs. (13)-(14) ---------------------------------------------------------------------
    def force_terms(self):
        """The (k × m) and (k,) coefficients of eq. (14):
        C̄21 − M̄21 M̄11⁻¹ C̄11 and Ḡ2 − M̄21 M̄11⁻¹ Ḡ1."""
        L = self.kernels.mm(self.M21, la.inv(self.M11))
        return self.C21 - self.kernels.mm(L, self.C11), self.G2 - self.kernels.mm(L, self.G1)

    def decoupling_matrix(self):
        """T = [B̄1; B̄2 − M̄21 M̄11⁻¹ B̄1] of eqs. (24), (51); τ = T⁻¹ [Λp; Λf]."""
        L = self.kernels.mm(self.M21, la.inv(self.M11))
        return jnp.concatenate([self.B1, self.B2 - self.kernels.mm(L, self.B1)], axis=0)


def reduced_model(arm, surface, q, qd, *, coriolis: str | None = None) -> ReducedModel:
    """Build M̄, C̄, Ḡ, B̄ of eq. (9) (corrected per docs/paper-conventions.md) from a nominal arm and surface.

    Implements Eq. (9). ``arm`` and ``surface`` are the controller's nominal models.

    ``coriolis``: ``"matrix"`` forms C and C̄ (the arm's :meth:`~hinfnn.model.arm.Arm.terms`);
    ``"product"`` forms only C̄ (u̇1, 0) = Sᵀ Ĵ⁻ᵀ {M̂ Ĵ⁻¹ Ṡ v + [Ĉ − M̂ Ĵ⁻¹ J̇̂] Ĵ⁻¹ S v},
    v = (u̇1, 0), with one product Ĉ(q, q̇) w (:meth:`~hinfnn.model.arm.Arm.C_product`): all of
    C̄ the law (25)–(26) uses (``C_bar`` is then None). Default: ``"matrix"`` for arms whose
    Coriolis matrix is a cheap closed form (``arm.coriolis_matrix_in_law``), else ``"product"``.
    Written with the arm's kernels (``arm.kernels``, :class:`hinfnn._linalg.Kernels`).
    """
    if coriolis is None:
        coriolis = "matrix" if getattr(arm, "coriolis_matrix_in_law", False) else "product"
    if coriolis not in ("matrix", "product"):
        raise ValueError(f"coriolis must be 'matrix' or 'product', got {coriolis!r}")
    if coriolis == "product":
        return _reduced_products(arm, surface, q, qd)
    kern = arm.kernels
    mm = kern.mm
    at = arm.terms(q, qd)
    x, J, J_dot, M = at.x, at.J, at.J_dot, at.M
    x_dot = mm(J, qd)
    m = surface.m
    S = surface.S(x[:m])
    S_dot = surface.S_dot(x[:m], x_dot[:m])
    J_inv = la.inv(J)
    B_bar = mm(S.T, J_inv.T)  # Sᵀ Ĵ⁻ᵀ
    MJi = mm(M, J_inv)
    JiS = mm(J_inv, S)
    M_bar = mm(B_bar, mm(M, JiS))
    C_bar = mm(B_bar, mm(MJi, S_dot) + mm(at.C - mm(MJi, J_dot), JiS))
    G_bar = mm(B_bar, at.G)
    return ReducedModel(
        M_bar=M_bar,
        C_bar=C_bar,
        C_u1dot=None,
        G_bar=G_bar,
        B_bar=B_bar,
        S=S,
        S_dot=S_dot,
        A_hat=surface.A_hat(x),
        x=x,
        x_dot=x_dot,
        J=J,
        J_dot=J_dot,
        m=m,
        J_p=None if arm.task_is_point else arm.point_jacobian(q),
        kernels=kern,
    )


def _reduced_products(arm, surface, q, qd) -> ReducedModel:
    """Eq. (9) without forming C or J̇ (n ≥ 3 arms), and with Ĵ⁻¹ = Ĵᵀ(Ĵ Ĵᵀ)⁻¹ from one
    Cholesky factorisation (no pivoting loop, plain arithmetic in the compiled step):

        M̄ = B̄ M̂ Ĵ⁻¹ S,   B̄ = Sᵀ Ĵ⁻ᵀ,   Ḡ = B̄ Ĝ,
        C̄ v = B̄ [M̂ Ĵ⁻¹ Ṡ v + Ĉ(q, q̇) w − M̂ Ĵ⁻¹ J̇̂ w],   w = Ĵ⁻¹ S v,   v = (u̇1, 0),

    which need only the products Ĉ(q, q̇) w and J̇̂ w (:meth:`~hinfnn.model.arm.Arm.C_product`,
    :meth:`~hinfnn.model.arm.Arm.J_dot_times`): all of C̄ the law (25)–(26) uses. The same
    quantities as the matrix path (tested)."""
    kern = arm.kernels
    mm = kern.mm
    at = arm.law_terms(q, qd)
    x, J, M = at.x, at.J, at.M
    x_dot = mm(J, qd)
    m = surface.m
    S = surface.S(x[:m])
    S_dot = surface.S_dot(x[:m], x_dot[:m])
    # Each product below is read by several others: computed once (kernels.stored), not again
    # inside every kernel that reads it (on a 6-DOF arm, most of a right-hand side's operations).
    st = kern.stored
    J_inv = st(mm(J.T, kern.chol_solve(kern.chol(mm(J, J.T)), jnp.eye(J.shape[0], dtype=J.dtype))))
    B_bar = st(mm(S.T, J_inv.T))  # Sᵀ Ĵ⁻ᵀ
    MJi = st(mm(M, J_inv))
    JiS = st(mm(J_inv, S))
    M_bar = mm(B_bar, st(mm(M, JiS)))
    v = jnp.concatenate([x_dot[:m], jnp.zeros(surface.k, dtype=x_dot.dtype)])
    w = mm(JiS, v)  # Ĵ⁻¹ S v
    Jd = arm.J_dot_times(at, q, qd, jnp.stack([w, qd], axis=1))  # (J̇̂ w, J̇̂ q̇) in one pass
    C_u = mm(B_bar, mm(MJi, mm(S_dot, v) - Jd[:, 0]) + arm.C_product(at, q, qd, w))
    G_bar = mm(B_bar, at.G)
    return ReducedModel(
        M_bar=M_bar,
        C_bar=None,
        C_u1dot=C_u,
        G_bar=G_bar,
        B_bar=B_bar,
        S=S,
        S_dot=S_dot,
        A_hat=surface.A_hat(x),
        x=x,
        x_dot=x_dot,
        J=J,
        J_dot=None,
        m=m,
        Jd_qd=Jd[:, 1],
        J_p=at.J_p,
        kernels=kern,
    )
