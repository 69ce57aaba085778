"""Holonomic constraint surfaces θ̂(x) = 0 and the quantities of paper eqs. (3)–(6).

For a surface in task space x = (x1, x2), x1 ∈ ℝᵐ (motion), x2 ∈ ℝᵏ (constrained):

* Â = ∂θ̂/∂x = [Σ Π]                       eq. (3), by ``jax.jacfwd`` of θ̂
* x2 = Ω(x1) on the surface                 (A4), Newton on θ̂(x1, ·) = 0 unless closed form
* Γ = ∂Ω/∂x1 = −Π⁻¹ Σ                       eq. (4)
* u = (x1, x2 − Ω(x1)), ẋ = S u̇, S = [[I, 0], [Γ, I]],  Ṡ = dS/dt along ẋ1    eq. (6)

Sign convention (docs/paper-conventions.md, Conventions): θ̂ is positive inside the material, so with
F = Âᵀλ the force the end-effector exerts on the surface, λ > 0 means pressing.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from .._pytree import pytree_dataclass, static_field
from .. import _linalg as la

SCALINGS = ("paper", "unit")


class Surface:
    """Base class: subclasses define :meth:`theta` and the static sizes ``m`` and ``k``."""

    m: int
    k: int
    #: How the small linear algebra is written (:class:`hinfnn._linalg.Kernels`; a subclass whose
    #: code uses it has a static ``kernels`` field, set by the program that traces it)
    kernels = la.DEFAULT
    #: λ's unit: F = Âᵀλ (eq. 3) makes λ the force conjugate to θ̂, in N when θ̂ is a length (the
    #: lines in either scaling, the shapes' θ, the fitted distance); a user's θ̂ of another unit
    #: gives λ in N·m per unit of θ̂
    lambda_unit = "N"

    def theta(self, x):
        """Constraint function θ̂(x) ∈ ℝᵏ, positive inside the material."""
        raise NotImplementedError

    # --- eq. (3) -----------------------------------------------------------------------------
    def A_hat(self, x):
        """Â = ∂θ̂/∂x (k × n), eq. (3)."""
        return jax.jacfwd(self.theta)(x)

    def Sigma(self, x):
        """Σ = ∂θ̂/∂x1 (k × m)."""
        return self.A_hat(x)[:, : self.m]

    def Pi(self, x):
        """Π = ∂θ̂/∂x2 (k × k), nonsingular by assumption (A3)."""
        return self.A_hat(x)[:, self.m :]

    # --- (A4), eq. (4) ---------------------------------------------------------------------------
    def Omega(self, x1, iterations: int = 30):
        """x2 = Ω(x1) on the surface, by Newton's method on θ̂(x1, x2) = 0 from x2 = 0.

        NaN where Newton has not converged (x1 outside the surface's domain): the simulator
        then stops with a SimulationError instead of using a wrong Ω.
        """

        def body(_, x2):
            x = jnp.concatenate([x1, x2])
            return x2 - self.kernels.solve(self.Pi(x), self.theta(x))

        x2 = jax.lax.fori_loop(0, iterations, body, jnp.zeros(self.k, dtype=jnp.result_type(x1)))
        residual = jnp.max(jnp.abs(self.theta(jnp.concatenate([x1, x2]))))
        return jnp.where(residual < 1e-9 * (1.0 + jnp.max(jnp.abs(x2))), x2, jnp.nan)

    def Gamma(self, x1):
        """Γ = ∂Ω/∂x1 = −Π⁻¹Σ at (x1, Ω(x1)), eq. (4)."""
        x = jnp.concatenate([x1, self.Omega(x1)])
        return -self.kernels.solve(self.Pi(x), self.Sigma(x))

    # --- eq. (6) ---------------------------------------------------------------------------------
    def S(self, x1):
        """S = ∂x/∂u = [[I_m, 0], [Γ, I_k]]."""
        m, k = self.m, self.k
        top = jnp.concatenate([jnp.eye(m), jnp.zeros((m, k))], axis=1)
        bottom = jnp.concatenate([self.Gamma(x1), jnp.eye(k)], axis=1)
        return jnp.concatenate([top, bottom], axis=0)

    def S_dot(self, x1, x1_dot):
        """Ṡ = dS/dt along ẋ1 = u̇1 (forward-mode autodiff)."""
        return jax.jvp(self.S, (x1,), (x1_dot,))[1]

    def to_u(self, x):
        """u = (x1, x2 − Ω(x1)), the coordinates of eq. (6)."""
        x1 = x[: self.m]
        return jnp.concatenate([x1, x[self.m :] - self.Omega(x1)])

    # --- for the plant's contact (k = 1) --------------------------------------------------
    def signed_distance(self, x):
        """θ(x)/‖∇θ(x)‖: the penetration depth, exact for planes and lines (k = 1)."""
        grad = self.A_hat(x)[0]
        return self.theta(x)[0] / jnp.linalg.norm(grad)

    def inward_normal(self, x):
        """Unit normal pointing into the material, ∇θ/‖∇θ‖ (k = 1)."""
        grad = self.A_hat(x)[0]
        return grad / jnp.linalg.norm(grad)


@pytree_dataclass
class InclinedLine(Surface):
    """The surface S1 of Sec. VI: the line x2 = (x1 − d_G) tan δ in the vertical plane.

    ``scaling="paper"``: θ̂ = (x1 − d_G) tan δ − x2, Â = [tan δ, −1], Π = −1 (the paper's form;
    the normal force is then λ / cos δ).
    ``scaling="unit"``: θ̂ = (x1 − d_G) sin δ − x2 cos δ, Â = [sin δ, −cos δ], Π = −cos δ
    (λ is the normal force in newtons). Both have Γ = tan δ and Ω(x1) = (x1 − d_G) tan δ.
    """

    delta: float
    d_G: float = 0.8
    scaling: str = static_field(default="paper")
    m: int = static_field(default=1)
    k: int = static_field(default=1)

    def __post_init__(self):
        if self.scaling not in SCALINGS:
            raise ValueError(f"scaling must be one of {SCALINGS}, got {self.scaling!r}")

    def theta(self, x):
        if self.scaling == "paper":
            return jnp.atleast_1d((x[0] - self.d_G) * jnp.tan(self.delta) - x[1])
        return jnp.atleast_1d((x[0] - self.d_G) * jnp.sin(self.delta) - x[1] * jnp.cos(self.delta))

    def Omega(self, x1, iterations: int = 0):
        return jnp.atleast_1d((x1[0] - self.d_G) * jnp.tan(self.delta))

    def Gamma(self, x1):
        return jnp.tan(self.delta) * jnp.ones((1, 1), dtype=jnp.result_type(x1, self.delta))


@pytree_dataclass
class ImplicitSurface(Surface):
    """Any surface given by a function ``theta_fn(x, params) -> (k,)``, positive inside.

    Ω comes from Newton's method on the implicit function, Γ and Ṡ from autodiff; ``params``
    is data (batchable), ``theta_fn`` must be a module-level function (it is hashed by jit).
    """

    params: jax.Array
    theta_fn: Callable = static_field()
    m: int = static_field(default=1)
    k: int = static_field(default=1)
    kernels: la.Kernels = la.kernels_field()
    lambda_unit = "N·m/θ"  # θ's unit is the user's

    def theta(self, x):
        return jnp.atleast_1d(self.theta_fn(x, self.params))


@pytree_dataclass
class TaskConstraint(Surface):
    """A geometry (:mod:`hinfnn.model.geometry`, Cartesian) as a constraint in task coordinates
    whose value determines the tool point: θ̂(x) = geometry.θ(task.point(x)) (Cartesian planar,
    position and pose maps). The last k coordinates are the constrained ones: choose the task
    map's order so that Π = ∂θ̂/∂x2 does not vanish along the path (e.g. (x, y, r, z) for a
    near-horizontal plane); where it does, (A3) fails (Ω, Γ are NaN and the run stops).

    Ω by Newton's method from the nominal surface's implicit function (30 iterations), Γ and Ṡ by
    autodiff (the generic :class:`Surface` machinery)."""

    geometry: object
    task: object
    m: int = static_field(default=1)
    k: int = static_field(default=1)
    kernels: la.Kernels = la.kernels_field()

    def theta(self, x):
        return jnp.atleast_1d(self.geometry.theta(self.task.point(x)))

    @property
    def lambda_unit(self) -> str:
        return self.geometry.lambda_unit


@pytree_dataclass
class FittedConstraint(Surface):
    """The constraint in coordinates fitted to the surface (:class:`~hinfnn.model.taskmap.FittedTaskMap`):
    θ̂(x) = x_n, the signed distance of the tool point. Closed forms: Â = [0 … 0 1], Σ = 0, Π = 1,
    Ω = 0, Γ = 0, S = I, Ṡ = 0; λ = F_n is the normal force (N)."""

    m: int = static_field(default=2)
    k: int = static_field(default=1)

    def theta(self, x):
        return x[self.m:]

    def A_hat(self, x):
        return jnp.concatenate([jnp.zeros((self.k, self.m)), jnp.eye(self.k)], axis=1) + 0.0 * x[0]

    def Omega(self, x1, iterations: int = 0):
        return jnp.zeros(self.k) + 0.0 * x1[0]

    def Gamma(self, x1):
        return jnp.zeros((self.k, self.m)) + 0.0 * x1[0]

    def S(self, x1):
        return jnp.eye(self.m + self.k) + 0.0 * x1[0]

    def S_dot(self, x1, x1_dot):
        return jnp.zeros((self.m + self.k, self.m + self.k)) + 0.0 * x1[0]
