"""The planar two-link arm of the paper's Sec. VI in closed form.

Printed error fixed (docs/paper-conventions.md, "Printed errors"): entry (2,1) of the Coriolis matrix is
``+q̇1`` (the paper prints ``−q̇1``); with the printed sign Ṁ − 2C is not skew-symmetric.
The closed forms are tested against the autodiff path of
:class:`hinfnn.model.arm.PlanarPointMassArm`.
"""

from __future__ import annotations

import jax.numpy as jnp

from .. import _linalg as la

from .._pytree import pytree_dataclass, static_field
from .arm import Arm, PlanarPointMassArm


@pytree_dataclass
class TwoLinkArm(Arm):
    """Sec. VI arm: point masses m1, m2 at the link tips, link lengths l1, l2, gravity g."""

    m1: float
    m2: float
    l1: float
    l2: float
    g: float = 9.8
    n: int = static_field(default=2)
    kernels: la.Kernels = la.kernels_field()
    coriolis_matrix_in_law = True  # the law forms C (closed form, cheaper than products)
    task_is_point = True  # the task coordinates are the tip position

    # Each closed form is written once, on the sines and cosines of q1, q2, q1 + q2 (one
    # vectorised sine and cosine of three angles); terms() evaluates them once for all six.
    def _trig(self, q):
        s, c = self.kernels.sincos(jnp.stack([q[0], q[1], q[0] + q[1]]))
        return s[0], c[0], s[1], c[1], s[2], c[2]

    def _h(self, tr):
        s1, c1, _, _, s12, c12 = tr
        return jnp.stack([self.l1 * c1 + self.l2 * c12, self.l1 * s1 + self.l2 * s12])

    def _J(self, tr):
        s1, c1, _, _, s12, c12 = tr
        return jnp.array([[-self.l1 * s1 - self.l2 * s12, -self.l2 * s12],
                          [self.l1 * c1 + self.l2 * c12, self.l2 * c12]])

    def _J_dot(self, tr, qd):
        s1, c1, _, _, s12, c12 = tr
        w1, w12 = qd[0], qd[0] + qd[1]
        return jnp.array([[-self.l1 * c1 * w1 - self.l2 * c12 * w12, -self.l2 * c12 * w12],
                          [-self.l1 * s1 * w1 - self.l2 * s12 * w12, -self.l2 * s12 * w12]])

    def _M(self, tr):
        m1, m2, l1, l2 = self.m1, self.m2, self.l1, self.l2
        c2 = tr[3]
        m11 = (m1 + m2) * l1**2 + m2 * l2**2 + 2 * m2 * l1 * l2 * c2
        m12 = m2 * l2**2 + m2 * l1 * l2 * c2
        m22 = m2 * l2**2
        return jnp.array([[m11, m12], [m12, m22]])

    def _C(self, tr, qd):
        hs = self.m2 * self.l1 * self.l2 * tr[2]
        return hs * jnp.array([[-qd[1], -(qd[0] + qd[1])], [qd[0], 0.0 * qd[0]]])

    def _G(self, tr):
        c1, c12 = tr[1], tr[5]
        return self.g * jnp.stack([(self.m1 + self.m2) * self.l1 * c1 + self.m2 * self.l2 * c12,
                                   self.m2 * self.l2 * c12])

    def h(self, q):
        """Forward kinematics x = (l1 c1 + l2 c12, l1 s1 + l2 s12)."""
        return self._h(self._trig(q))

    def J(self, q):
        """Sec. VI Jacobian J = [[−l1 s1 − l2 s12, −l2 s12], [l1 c1 + l2 c12, l2 c12]]."""
        return self._J(self._trig(q))

    def J_dot(self, q, qd):
        """Closed-form time derivative of the Sec. VI Jacobian."""
        return self._J_dot(self._trig(q), qd)

    def M(self, q):
        """Sec. VI inertia matrix."""
        return self._M(self._trig(q))

    def C(self, q, qd):
        """Sec. VI Coriolis matrix, m2 l1 l2 s2 [[−q̇2, −(q̇1+q̇2)], [+q̇1, 0]] (sign fixed)."""
        return self._C(self._trig(q), qd)

    def G(self, q):
        """Sec. VI gravity vector g [(m1+m2) l1 c1 + m2 l2 c12, m2 l2 c12]."""
        return self._G(self._trig(q))

    def terms(self, q, qd):
        """h, J, J̇, M, C, G from one set of sines and cosines."""
        from .arm import ArmTerms

        tr = self._trig(q)
        return ArmTerms(x=self._h(tr), J=self._J(tr), J_dot=self._J_dot(tr, qd), M=self._M(tr),
                        C=self._C(tr, qd), G=self._G(tr))

    def potential(self, q):
        y1 = self.l1 * jnp.sin(q[0])
        y2 = y1 + self.l2 * jnp.sin(q[0] + q[1])
        return self.g * (self.m1 * y1 + self.m2 * y2)

    def inverse_kinematics_closed(self, x, elbow_up: bool = True):
        """Closed-form inverse kinematics; elbow up means q2 < 0 (docs/paper-conventions.md, Initial state).

        Returns NaN where x is out of reach (|cos q2| > 1); callers validate.
        """
        c2 = (x[0] ** 2 + x[1] ** 2 - self.l1**2 - self.l2**2) / (2 * self.l1 * self.l2)
        q2 = jnp.arccos(c2)
        q2 = jnp.where(elbow_up, -q2, q2)
        q1 = jnp.arctan2(x[1], x[0]) - jnp.arctan2(self.l2 * jnp.sin(q2), self.l1 + self.l2 * jnp.cos(q2))
        return jnp.stack([q1, q2])

    def to_generic(self) -> PlanarPointMassArm:
        """The same arm as a :class:`PlanarPointMassArm` (the autodiff oracle)."""
        return PlanarPointMassArm(
            masses=jnp.stack([jnp.asarray(self.m1, float), jnp.asarray(self.m2, float)]),
            lengths=jnp.stack([jnp.asarray(self.l1, float), jnp.asarray(self.l2, float)]),
            g=self.g,
            n=2,
        )

