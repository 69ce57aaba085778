"""Serial-arm interface: M(q), C(q, q̇), G(q), forward kinematics h(q), J(q), J̇(q, q̇).

Paper eq. (1): ``M(q) q̈ + C(q, q̇) q̇ + G(q) + Jᵀ(q) F = τ + ω``.

:class:`Arm` derives everything a subclass does not write in closed form:

* ``J = ∂h/∂q`` by ``jax.jacfwd`` of :meth:`Arm.h`, ``J̇ = d/dt J`` by ``jax.jvp`` along q̇;
* ``C`` from the Christoffel symbols of ``M`` (autodiff of :meth:`Arm.M`), the choice that makes
  ``Ṁ − 2C`` skew-symmetric;
* ``G = ∂U/∂q`` from the potential energy :meth:`Arm.potential`.

:class:`PlanarPointMassArm` is the generic n-link planar arm with a point mass at the tip of each
link, written only through ``h``-like position maps and energies; the Sec. VI arm is its n = 2
case and :class:`hinfnn.model.planar.TwoLinkArm` is the closed form tested against it.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp

from .._pytree import pytree_dataclass, static_field
from .. import _linalg as la


@pytree_dataclass
class ArmTerms:
    """Everything the dynamics and the reduced model need at one (q, q̇), computed together
    (:meth:`Arm.terms`): x = h(q), J, J̇, M, C, G.

    The lighter sets leave out what their user does not need (``None``): :meth:`Arm.law_terms`
    (the control law: no C, only products C(q, q̇)v through :meth:`Arm.C_product`, with ``aux``
    the arm's cache for them) and :meth:`Arm.plant_terms` (the true plant: ``bias`` = C q̇ + G,
    the tool point ``p`` in the arm's Cartesian space and its Jacobian ``J_p``; no J̇, no C)."""

    x: jax.Array
    J: jax.Array
    J_dot: jax.Array
    M: jax.Array
    C: jax.Array
    G: jax.Array
    bias: jax.Array | None = None
    p: jax.Array | None = None
    J_p: jax.Array | None = None
    aux: object = None


class Arm:
    """Base class of serial arms. Subclasses are pytree dataclasses with the parameters as data.

    Must define ``n`` (number of joints), :meth:`h`, :meth:`M`; and either :meth:`potential`
    or :meth:`G`. May override :meth:`J`, :meth:`J_dot`, :meth:`C` with closed forms.
    """

    n: int
    #: How the arm's small linear algebra is written (:class:`hinfnn._linalg.Kernels`): a static
    #: field of every arm written here, set by the program that traces it (:meth:`~hinfnn._linalg.Kernels.hold`);
    #: an arm without the field computes with the default kernels.
    kernels: ClassVar[la.Kernels] = la.DEFAULT
    #: The control law forms the Coriolis matrix (cheap closed forms: the Sec. VI arm) instead of
    #: using products C(q, q̇)v (:meth:`C_product`), which is what every other arm does.
    coriolis_matrix_in_law: ClassVar[bool] = False

    # --- kinematics -------------------------------------------------------------------------
    def h(self, q):
        """Forward kinematics x = h(q) of the end-effector (assumption A1)."""
        raise NotImplementedError

    def J(self, q):
        """Jacobian ∂h/∂q (autodiff of :meth:`h`)."""
        return jax.jacfwd(self.h)(q)

    def J_dot(self, q, qd):
        """Time derivative of J along q̇: J̇ = Σ_i (∂J/∂q_i) q̇_i (forward-mode autodiff)."""
        return jax.jvp(self.J, (q,), (qd,))[1]

    # --- dynamics ---------------------------------------------------------------------------
    def M(self, q):
        """Inertia matrix M(q), symmetric positive definite."""
        raise NotImplementedError

    def potential(self, q):
        """Potential energy U(q); G = ∂U/∂q."""
        raise NotImplementedError

    def G(self, q):
        """Gravity torque G(q) = ∂U/∂q."""
        return jax.grad(self.potential)(q)

    def C(self, q, qd):
        """Coriolis/centrifugal matrix from the Christoffel symbols of M.

        C_kj = Σ_i ½ (∂M_kj/∂q_i + ∂M_ki/∂q_j − ∂M_ij/∂q_k) q̇_i, so that Ṁ − 2C is skew.
        """
        dM = jax.jacfwd(self.M)(q)  # dM[k, j, i] = ∂M_kj / ∂q_i
        term1 = dM @ qd  # Σ_i ∂M_kj/∂q_i q̇_i
        term2 = jnp.einsum("kij,i->kj", dM, qd)  # Σ_i ∂M_ki/∂q_j q̇_i
        term3 = jnp.einsum("ijk,i->kj", dM, qd)  # Σ_i ∂M_ij/∂q_k q̇_i
        return 0.5 * (term1 + term2 - term3)

    def C_times(self, q, qd, v):
        """C(q, q̇) v without forming C: ½ [Ṁ(q̇) v + Ṁ(v) q̇ − ∂(q̇ᵀ M v)/∂q] (the Christoffel
        form, by forward- and reverse-mode autodiff of M)."""
        Md_qd = jax.jvp(self.M, (q,), (qd,))[1]
        Md_v = jax.jvp(self.M, (q,), (v,))[1]
        grad = jax.grad(lambda qq: qd @ self.M(qq) @ v)(q)
        return 0.5 * (Md_qd @ v + Md_v @ qd - grad)

    def C_product(self, terms: ArmTerms, q, qd, v):
        """C(q, q̇) v reusing what :meth:`law_terms` computed (``terms.aux``)."""
        if terms.C is not None:
            return self.kernels.mm(terms.C, v)
        return self.C_times(q, qd, v)

    def J_dot_times(self, terms: ArmTerms, q, qd, v):
        """J̇(q, q̇) v (from ``terms.J_dot`` when formed, else by forward-mode autodiff of J v)."""
        if terms.J_dot is not None:
            return self.kernels.mm(terms.J_dot, v)
        return jax.jvp(lambda qq: self.kernels.mm(self.J(qq), v), (q,), (qd,))[1]

    # --- contact point --------------------------------------------------------------------------
    @property
    def task_is_point(self) -> bool:
        """Whether the task coordinates are the tool point's Cartesian coordinates (x = point(q)):
        then a force at the tool point is the task-space force itself (the Sec. VI arm)."""
        return False

    def point(self, q):
        """The tool point in the arm's Cartesian space (where surfaces live): h(q) by default
        (the Sec. VI arm: task coordinates = tip position)."""
        return self.h(q)

    def point_jacobian(self, q):
        """∂point/∂q (autodiff)."""
        return jax.jacfwd(self.point)(q)

    @property
    def space_dim(self) -> int:
        """Dimension of the arm's Cartesian space (2 for planar arms, 3 for spatial ones)."""
        return int(jax.eval_shape(self.point, jnp.zeros(self.n)).shape[0])

    def task_margin(self, q):
        """Distance of the task coordinates from their singularities at q (+inf: none)."""
        task = getattr(self, "task", None)
        if task is None or not hasattr(self, "fk"):
            return jnp.asarray(jnp.inf)
        return task.margin(*self.fk(q))

    # --- lighter sets of terms --------------------------------------------------------------------
    def law_terms(self, q, qd) -> ArmTerms:
        """x, J, J̇, M, G for the control law, and the tool point's Jacobian J_p unless the task
        coordinates are the tool point (:attr:`task_is_point`); C not formed (None) unless
        :attr:`coriolis_matrix_in_law` (then :meth:`terms`)."""
        if self.coriolis_matrix_in_law:
            return self.terms(q, qd)
        return ArmTerms(x=self.h(q), J=self.J(q), J_dot=None, M=self.M(q), C=None, G=self.G(q),
                        J_p=None if self.task_is_point else self.point_jacobian(q))

    def plant_terms(self, q, qd) -> ArmTerms:
        """x, J, M, bias = C q̇ + G, tool point and its Jacobian, for the true plant."""
        return ArmTerms(x=self.h(q), J=self.J(q), J_dot=None, M=self.M(q), C=None, G=None,
                        bias=self.C_times(q, qd, qd) + self.G(q), p=self.point(q), J_p=self.point_jacobian(q))

    def M_dot(self, q, qd):
        """Ṁ along q̇ (autodiff), used to check the skew-symmetry of Ṁ − 2C."""
        return jax.jvp(self.M, (q,), (qd,))[1]

    def terms(self, q, qd) -> ArmTerms:
        """h, J, J̇, M, C, G at (q, q̇) in one call (closed-form arms share their trigonometry)."""
        return ArmTerms(x=self.h(q), J=self.J(q), J_dot=self.J_dot(q, qd), M=self.M(q), C=self.C(q, qd),
                        G=self.G(q))

    def forward_dynamics(self, q, qd, tau_total, terms: ArmTerms | None = None):
        """q̈ = M⁻¹ (τ_total − C q̇ − G); τ_total already includes −JᵀF and disturbances."""
        t = terms if terms is not None else self.terms(q, qd)
        if t.bias is not None:
            return self.kernels.spd_solve(t.M, tau_total - t.bias)
        return self.kernels.solve(t.M, tau_total - self.kernels.mm(t.C, qd) - t.G)

    def inverse_kinematics(self, x, q_guess, iterations: int = 50):
        """Solve h(q) = x by Newton's method from ``q_guess`` (square arms, n = dim x)."""

        def body(_, q):
            return q - jnp.linalg.solve(self.J(q), self.h(q) - x)

        return jax.lax.fori_loop(0, iterations, body, jnp.asarray(q_guess, dtype=float))


@pytree_dataclass
class PlanarPointMassArm(Arm):
    """Generic n-link planar arm, point mass m_i at the tip of link i, gravity along −x2.

    Everything is derived by autodiff from the mass positions:
    M = Σ_i m_i J_iᵀ J_i (J_i the Jacobian of mass i), U = Σ_i m_i g y_i.
    For n = 2 this is exactly the arm of the paper's Sec. VI.

    Without a ``task`` map the task coordinates are the tip position (x1, x2); with one
    (:mod:`hinfnn.model.taskmap`, plane ``"xy"``), h(q) = task(p, R) with the tool frame of
    :meth:`fk`: tip (x1, x2, 0) and the rotation by the tool angle φ = q1 + … + qn about the
    plane's normal (the tool axis is the last link, axis ``"x"``).
    """

    masses: jax.Array
    lengths: jax.Array
    g: float = 9.8
    n: int = static_field(default=2)
    task: object = None
    kernels: la.Kernels = la.kernels_field()

    def _mass_positions(self, q):
        angles = jnp.cumsum(q)
        dx = self.lengths * jnp.cos(angles)
        dy = self.lengths * jnp.sin(angles)
        return jnp.stack([jnp.cumsum(dx), jnp.cumsum(dy)], axis=-1)  # (n, 2)

    def fk(self, q):
        """Tool frame: position (x1, x2, 0) and rotation about the third axis by Σ q."""
        tip = self._mass_positions(q)[-1]
        phi = jnp.sum(q)
        c, s = jnp.cos(phi), jnp.sin(phi)
        R = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return jnp.concatenate([tip, jnp.zeros(1)]), R

    def h(self, q):
        if self.task is None:
            return self._mass_positions(q)[-1]
        return self.task(*self.fk(q))

    @property
    def task_is_point(self) -> bool:
        """Without a task map the task coordinates are the tip position."""
        return self.task is None

    def point(self, q):
        """The tip (x1, x2)."""
        return self._mass_positions(q)[-1]

    def M(self, q):
        Js = jax.jacfwd(self._mass_positions)(q)  # (n, 2, n)
        return jnp.einsum("i,iak,ial->kl", self.masses, Js, Js)

    def potential(self, q):
        return self.g * jnp.sum(self.masses * self._mass_positions(q)[:, 1])
