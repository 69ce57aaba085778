"""The Riccati-like equations (35) and (40), solved once at design time (NumPy/SciPy).

Both have the form  A_pᵀP + P A_p − P B_p W B_pᵀ P + Q_p = 0  with

* eq. (35) (Theorems 1–2):  W = 2 R_p⁻¹ − I/ρ²
* eq. (40) (Remark 1):      W = R_p⁻¹ − I/ρ²

W may be indefinite (eq. 40 with the paper's numbers), so the equation is solved through the
stable invariant subspace of the Hamiltonian H = [[A, −B W Bᵀ], [−Q, −Aᵀ]] (ordered real Schur
form), not by a CARE solver that assumes W ≻ 0. docs/paper-conventions.md: Remark 4's "if and only if
2ρ²I > R_p" is only sufficient, so every solution is checked instead: residual, P ≻ 0,
A_p − B_p W B_pᵀ P Hurwitz (stabilising solution) and A_p − B_p R_p⁻¹ B_pᵀ P Hurwitz
(the nominal closed loop under v_p of eq. 33).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg

from ..errors import DesignError

RESIDUAL_TOL = 1e-10
IMAG_AXIS_TOL = 1e-9


@dataclasses.dataclass(frozen=True)
class RiccatiSolution:
    """P_p and the checks that accepted it."""

    P: np.ndarray
    equation: str  # "35" or "40"
    W: np.ndarray
    residual: float  # ‖A'P + PA − PBWB'P + Q‖_F relative to the sum of the terms' norms
    min_eig_P: float
    hamiltonian_eigs: np.ndarray
    closed_loop_eigs: np.ndarray  # eig(A_p − B_p R_p⁻¹ B_pᵀ P)
    remark4_holds: bool  # 2ρ²I > R_p (eq. 35) or ρ²I > R_p (eq. 40): sufficient only


def riccati_weight(R_p, rho, equation: str = "35") -> np.ndarray:
    """W of eq. (35) (2R_p⁻¹ − I/ρ²) or eq. (40) (R_p⁻¹ − I/ρ²)."""
    R_inv = np.linalg.inv(np.atleast_2d(R_p))
    scale = {"35": 2.0, "40": 1.0}[equation]
    return scale * R_inv - np.eye(R_inv.shape[0]) / rho**2


def riccati_residual(A, B, Q, W, P) -> np.ndarray:
    """A'P + PA − P B W B' P + Q."""
    return A.T @ P + P @ A - P @ B @ W @ B.T @ P + Q


def solve_riccati_like(A, B, Q, W) -> np.ndarray:
    """Stabilising solution of A'P + PA − P B W B' P + Q = 0 via the Hamiltonian's stable subspace.

    Raises :class:`DesignError` when there is none (eigenvalues on the imaginary axis, or the
    stable subspace is not a graph).
    """
    A, B, Q, W = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (A, B, Q, W))
    n = A.shape[0]
    H = np.block([[A, -B @ W @ B.T], [-Q, -A.T]])
    eigs = np.linalg.eigvals(H)
    scale = max(1.0, float(np.max(np.abs(eigs))))
    if np.min(np.abs(eigs.real)) <= IMAG_AXIS_TOL * scale:
        raise DesignError(
            "no stabilising solution: the Hamiltonian has eigenvalues on the imaginary axis "
            f"(min |Re| = {np.min(np.abs(eigs.real)):.3g})", value=float(np.min(np.abs(eigs.real))))
    T, Z, sdim = scipy.linalg.schur(H, output="real", sort="lhp")
    if sdim != n:
        raise DesignError(f"no stabilising solution: stable subspace has dimension {sdim}, need {n}")
    X1, X2 = Z[:n, :n], Z[n:, :n]
    cond = np.linalg.cond(X1)
    if not np.isfinite(cond) or cond > 1e12:
        raise DesignError(f"no stabilising solution: the stable subspace is not a graph (cond {cond:.3g})")
    P = np.linalg.solve(X1.T, X2.T).T  # X2 X1⁻¹
    P = 0.5 * (P + P.T)
    return _newton_refine(A, B, Q, W, P)


def _newton_refine(A, B, Q, W, P, steps: int = 6):
    """Newton (Kleinman) steps on the Riccati residual: (A − BWBᵀP)ᵀΔ + Δ(A − BWBᵀP) = −Res(P).

    The Schur solution loses digits when P's entries span many decades (large gains); a few
    Newton steps restore the residual to round-off. Stops when the residual stops decreasing.
    """
    best, best_norm = P, np.linalg.norm(riccati_residual(A, B, Q, W, P))
    for _ in range(steps):
        Ac = A - B @ W @ B.T @ best
        try:
            delta = scipy.linalg.solve_continuous_lyapunov(Ac.T, -riccati_residual(A, B, Q, W, best))
        except (np.linalg.LinAlgError, ValueError):
            break
        cand = best + 0.5 * (delta + delta.T)
        norm = np.linalg.norm(riccati_residual(A, B, Q, W, cand))
        if not norm < best_norm:
            break
        best, best_norm = cand, norm
    return best


def design_riccati(gains, equation: str = "35") -> RiccatiSolution:
    """Solve eq. (35) or (40) for normalized :class:`~hinfnn.controllers.gains.Gains` and check it.

    Raises :class:`DesignError` naming ρ and the condition that failed, with its numbers.
    """
    rho = float(gains.rho)
    R_p = np.atleast_2d(np.asarray(gains.R_p, dtype=float))
    A, B, Q = gains.A_p(), gains.B_p(), np.asarray(gains.Q_p, dtype=float)
    W = riccati_weight(R_p, rho, equation)
    if not np.all(np.isfinite(W)):
        bad_R = not np.all(np.isfinite(np.linalg.inv(R_p)))
        raise DesignError(f"the weight W of eq. ({equation}) is not finite for rho = {rho:g}, R_p = "
                          f"{R_p.tolist()}: {'R_p is numerically singular' if bad_R else 'rho is too small'}",
                          key="R_p" if bad_R else "rho", value=R_p.tolist() if bad_R else rho)
    factor = 2.0 if equation == "35" else 1.0
    remark4 = bool(np.linalg.eigvalsh(factor * rho**2 * np.eye(R_p.shape[0]) - R_p).min() > 0)
    rho_suff = float(np.sqrt(np.linalg.eigvalsh(R_p).max() / factor))
    where = f"eq. ({equation}) with rho = {rho:g}, R_p = {R_p.tolist()}"
    try:
        P = solve_riccati_like(A, B, Q, W)
    except DesignError as err:
        raise DesignError(
            f"{err.args[0]} for {where}; Remark 4's sufficient condition rho > {rho_suff:.4g} "
            f"{'holds' if remark4 else 'fails'}: increase rho or R_p", key="rho", value=rho,
            bound=rho_suff) from None
    res = riccati_residual(A, B, Q, W, P)
    scale = 2 * np.linalg.norm(A.T @ P) + np.linalg.norm(P @ B @ W @ B.T @ P) + np.linalg.norm(Q)
    residual = float(np.linalg.norm(res) / scale)
    if not residual < RESIDUAL_TOL:
        raise DesignError(f"Riccati residual {residual:.3g} above {RESIDUAL_TOL:g} for {where}",
                          key="rho", value=rho)
    min_eig = float(np.linalg.eigvalsh(P).min())
    if not min_eig > 0:
        raise DesignError(f"P_p is not positive definite (smallest eigenvalue {min_eig:.3g}) for {where}",
                          key="rho", value=rho)
    stab = np.linalg.eigvals(A - B @ W @ B.T @ P)
    if not np.max(stab.real) < 0:
        raise DesignError(f"A_p - B_p W B_p' P is not Hurwitz (max Re {np.max(stab.real):.3g}) for {where}",
                          key="rho", value=rho)
    cl = np.linalg.eigvals(A - B @ np.linalg.solve(R_p, B.T @ P))
    if not np.max(cl.real) < 0:
        raise DesignError(
            f"the closed loop A_p - B_p R_p^-1 B_p' P is not Hurwitz (max Re {np.max(cl.real):.3g}) "
            f"for {where}", key="R_p", value=R_p.tolist())
    H_eigs = np.linalg.eigvals(np.block([[A, -B @ W @ B.T], [-Q, -A.T]]))
    return RiccatiSolution(P=P, equation=equation, W=W, residual=residual, min_eig_P=min_eig,
                           hamiltonian_eigs=H_eigs, closed_loop_eigs=cl, remark4_holds=remark4)
