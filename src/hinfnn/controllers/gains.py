"""Controller gains and the bounds Theorem 1, Theorem 2 and Remarks 1–4 put on them.

Names follow the paper: K_p, K_v (eq. 25), rho (ρ), mu_z, alpha_z (eq. 27), alpha_lam,
beta_lam (eqs. 32, 34), gamma_1, gamma_2 (eqs. 30–31), Q_p, R_p (eqs. 33, 35).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import pytree_dataclass
from ..errors import DesignError


def theorem1_bounds(rho: float, alpha_z: float, alpha_lam: float) -> tuple[float, float]:
    """Theorem 1's bounds (Remark 3 for any α_z): α_λ > 2ρ²/α_z and β_λ ≥ α_λα_z/(2ρ²) − 1.
    Returns (the bound on α_λ, the bound on β_λ); the one place they are written."""
    return 2.0 * rho**2 / alpha_z, alpha_lam * alpha_z / (2.0 * rho**2) - 1.0


@pytree_dataclass
class Gains:
    """Design parameters. Scalars are accepted for the m = 1 matrices (K_p, K_v, R_p).

    ``beta_lam=None`` means "the smallest value Theorem 1 allows" (docs/paper-conventions.md: the paper does not
    give β_λ): β_λ = α_λ α_z / (2ρ²) − 1 (Remark 3; = α_λ/ρ² − 1 for α_z = 2).
    """

    K_p: jax.Array = 18.0
    K_v: jax.Array = 9.0
    rho: float = 0.6
    mu_z: float = 100.0
    alpha_z: float = 2.0
    alpha_lam: float = 1.0
    beta_lam: float | None = None
    gamma_1: float = 2.0
    gamma_2: float = 2.0
    Q_p: jax.Array | None = None
    R_p: jax.Array = 0.495

    @classmethod
    def paper(cls) -> "Gains":
        """Sec. VI gains (R_p as the scalar 0.495: docs/paper-conventions.md, the printed diag is a misprint)."""
        return cls()


    def normalized(self, m: int, k: int, *, require_bounds: bool = True) -> "Gains":
        """Check every gain and return a copy with float64 arrays of the right shapes.

        Raises :class:`DesignError` naming the gain, its value and what is allowed.
        ``require_bounds=False`` skips the H∞ bounds (α_λ, β_λ) for the FL-like controller,
        which uses them only as performance weights.
        """
        n2 = 2 * m
        rho = _positive_scalar("rho", self.rho)
        mu_z = _positive_scalar("mu_z", self.mu_z)
        alpha_z = _positive_scalar("alpha_z", self.alpha_z)
        alpha_lam = _positive_scalar("alpha_lam", self.alpha_lam)
        gamma_1 = _positive_scalar("gamma_1", self.gamma_1)
        gamma_2 = _positive_scalar("gamma_2", self.gamma_2)
        K_p = _diag_positive("K_p", self.K_p, m)
        K_v = _diag_positive("K_v", self.K_v, m)
        R_p = _spd("R_p", self.R_p, m, hint=(
            "the paper prints R_p = diag{0.495, 0.495}, a misprint: R_p is m x m and m = 1 "
            "for the planar arm on a line (docs/paper-conventions.md)" if m == 1 else None))
        Q_p = np.eye(n2) if self.Q_p is None else self.Q_p
        Q_p = _spd("Q_p", Q_p, n2)

        if not (rho**2 > 0 and math.isfinite(alpha_lam * alpha_z / (2.0 * rho**2))):
            raise DesignError(f"rho = {rho:g} is too small: alpha_lam alpha_z / (2 rho^2) (Theorem 1's bound "
                              "on beta_lam) is not a finite number", key="rho", value=rho, bound=0.0)
        alpha_bound, beta_bound = theorem1_bounds(rho, alpha_z, alpha_lam)
        if self.beta_lam is None:
            beta_lam = beta_bound
        else:
            beta_lam = _finite_scalar("beta_lam", self.beta_lam)
        if require_bounds:
            if not alpha_lam > alpha_bound:
                raise DesignError(
                    f"alpha_lam = {alpha_lam:g} must exceed 2 rho^2 / alpha_z = {alpha_bound:g} "
                    "(Theorem 1: alpha_lam > rho^2 for alpha_z = 2; Remark 3 in general)",
                    key="alpha_lam", value=alpha_lam, bound=alpha_bound)
            if not beta_lam >= beta_bound - 1e-12 * max(1.0, abs(beta_bound)):
                raise DesignError(
                    f"beta_lam = {beta_lam:g} is below its bound alpha_lam alpha_z / (2 rho^2) - 1 "
                    f"= {beta_bound:g} (Theorem 1, Remark 3); by {beta_bound - beta_lam:.4g}",
                    key="beta_lam", value=beta_lam, bound=beta_bound)
        if not beta_lam > 0:
            raise DesignError(f"beta_lam = {beta_lam:g} must be > 0 (Theorem 1)",
                              key="beta_lam", value=beta_lam, bound=0.0)
        return Gains(
            K_p=jnp.asarray(K_p), K_v=jnp.asarray(K_v), rho=rho, mu_z=mu_z, alpha_z=alpha_z,
            alpha_lam=alpha_lam, beta_lam=float(beta_lam), gamma_1=gamma_1, gamma_2=gamma_2,
            Q_p=jnp.asarray(Q_p), R_p=jnp.asarray(R_p),
        )

    # --- matrices of eq. (29) -------------------------------------------------------------------
    def A_p(self):
        """A_p = [[0, I], [−K_p, −K_v]] of eq. (29) (normalized gains only)."""
        K_p, K_v = np.asarray(self.K_p), np.asarray(self.K_v)
        m = K_p.shape[0]
        return np.block([[np.zeros((m, m)), np.eye(m)], [-K_p, -K_v]])

    def B_p(self):
        """B_p = [0; I] of eq. (29)."""
        m = np.asarray(self.K_p).shape[0]
        return np.vstack([np.zeros((m, m)), np.eye(m)])


def _finite_scalar(name, value) -> float:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise DesignError(f"must be a real number, got {value!r}", key=name, value=value) from None
    if arr.size != 1:
        raise DesignError(f"must be a scalar, got shape {arr.shape}", key=name, value=value)
    v = float(arr.reshape(()))
    if not math.isfinite(v):
        raise DesignError(f"must be finite, got {v}", key=name, value=v)
    return v


def _positive_scalar(name, value) -> float:
    v = _finite_scalar(name, value)
    if not v > 0:
        raise DesignError(f"must be > 0, got {v:g}", key=name, value=v, bound=0.0)
    return v


def _matrix(name, value, size) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise DesignError(f"must be a number or a {size}x{size} matrix, got {value!r}", key=name) from None
    if arr.ndim == 0 or (arr.ndim == 1 and arr.size == 1 and size == 1):
        arr = arr.reshape(()) * np.eye(size)
    elif arr.ndim == 1 and arr.size == size:
        arr = np.diag(arr)
    if arr.shape != (size, size):
        got = f"a list of {arr.size}" if arr.ndim == 1 else f"shape {arr.shape}"
        raise DesignError(f"must be a number, a list of {size} (the diagonal) or a {size}x{size} matrix "
                          f"({size} = the coordinates it weighs), got {got}", key=name, value=arr.tolist())
    if not np.all(np.isfinite(arr)):
        raise DesignError(f"must be finite, got {arr.tolist()}", key=name, value=arr.tolist())
    return arr


def _diag_positive(name, value, size) -> np.ndarray:
    arr = _matrix(name, value, size)
    if np.any(arr - np.diag(np.diag(arr))):
        raise DesignError("must be diagonal (Sec. IV: K_p, K_v > 0 diagonal)", key=name, value=arr.tolist())
    if not np.all(np.diag(arr) > 0):
        raise DesignError(f"must have positive diagonal, got {np.diag(arr).tolist()}", key=name,
                          value=arr.tolist(), bound=0.0)
    return arr


def _spd(name, value, size, hint=None) -> np.ndarray:
    try:
        arr = _matrix(name, value, size)
    except DesignError as err:
        if hint:
            raise DesignError(f"{err.args[0].split(': ', 1)[-1]}; {hint}", key=name, value=value) from None
        raise
    if not np.allclose(arr, arr.T, rtol=1e-12, atol=1e-12):
        raise DesignError("must be symmetric", key=name, value=arr.tolist())
    min_eig = float(np.linalg.eigvalsh(arr).min())
    if not min_eig > 0:
        raise DesignError(f"must be positive definite; smallest eigenvalue {min_eig:g}", key=name,
                          value=arr.tolist(), bound=0.0)
    return arr
