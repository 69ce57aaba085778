"""Redundant arms without a locked joint: an augmented task space.

The paper's reduced-order model needs a square, nonsingular task Jacobian (assumption (A1):
m + k = n). A 7-DOF arm with a 6-coordinate task map (tool position and orientation, or surface
coordinates, orientation and depth) has one coordinate too few. :class:`AugmentedArm` adds e
coordinates that are functions of the joint angles (:class:`~hinfnn.model.taskmap.JointCoordinate`:
a joint's own angle; :class:`~hinfnn.model.taskmap.ArmAngle`: the elbow's swivel angle) and puts
them among the motion coordinates, before the constrained one:

    x = h(q) = (x_b,1 … x_b,m_b,  x_e,1 … x_e,e,  x_b,last),   m = m_b + e,  k = 1,

so that Ĵ = ∂h/∂q is square again and everything of the paper applies unchanged: the surface
still constrains the last coordinate only (x2 = Ω(x1) does not involve the extra coordinates,
Π and S keep their form), the extra coordinates are motion coordinates u1 tracked to their
reference (a default one holds their start value) with their own K_p, K_v, Riccati weights and
network outputs, and λ is still the constrained coordinate's force (the sensor's force in task
coordinates F = Ĵ⁻ᵀ τ_c has the same last entry whatever the other coordinates are: a virtual
displacement along d alone moves the tool along the normal only). Ĵ can be singular where the
task map's Jacobian is not (an "algorithmic" singularity: for a joint coordinate, where the arm
with that joint locked is singular): the singularity guard and the path check see it through
σ_min(Ĵ), and :meth:`AugmentedArm.task_margin` through the coordinates' own margins.

:class:`AugmentedArm` wraps a :class:`~hinfnn.model.urdf.UrdfArm` (the chain and the task map)
and uses only its public methods; :class:`AugmentedTask` is its task map's stand-in where task
coordinates are handled without q (names, margins on x, the tool point of x).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from .. import _linalg as la
from .._pytree import pytree_dataclass, replace
from .arm import Arm, ArmTerms


def _insert(base, extra):
    """(base[:-1], extra, base[-1:]) along the first axis: the extra coordinates before the
    constrained one."""
    return jnp.concatenate([base[:-1], extra, base[-1:]], axis=0)


@pytree_dataclass
class AugmentedTask:
    """The task coordinates of an :class:`AugmentedArm` where q is not at hand: ``base`` the task
    map of the tool frame (its last coordinate constrained), ``extra`` the joint-space
    coordinates inserted before that one."""

    base: Any
    extra: tuple

    @property
    def n_extra(self) -> int:
        return len(self.extra)

    @property
    def dim(self) -> int:
        return int(self.base.dim) + self.n_extra

    @property
    def space_dim(self) -> int:
        return int(self.base.space_dim)

    @property
    def space_rows(self) -> tuple:
        return self.base.space_rows

    def space(self, p):
        return self.base.space(p)

    def split(self, x):
        """(x of the base map, the extra coordinates)."""
        e = self.n_extra
        return jnp.concatenate([x[:-1 - e], x[-1:]]), x[-1 - e:-1]

    def point(self, x):
        return self.base.point(self.split(x)[0])

    def names(self) -> list[tuple[str, str]]:
        base = list(self.base.names())
        return base[:-1] + [(c.name, c.unit) for c in self.extra] + base[-1:]

    def of_pose(self, chain, p, R, q):
        """x = (x_b[:-1], x_e, x_b[-1]) of a tool at (p, R) with joint angles q: the base map's
        coordinates of the pose, the extra ones of ``chain`` at q (a plant that senses the tool's
        pose, e.g. MuJoCo's, forms the true task coordinates with it)."""
        return _insert(self.base(p, R), jnp.stack([c.value(chain, q) for c in self.extra]))

    def margin_pose(self, chain, p, R, q):
        """The smallest of the base map's margin at the pose (p, R) and the extra coordinates' at q
        (rad or m; :meth:`AugmentedArm.task_margin` from a sensed pose)."""
        out = self.base.margin(p, R)
        for c in self.extra:
            out = jnp.minimum(out, c.margin(chain, q))
        return out

    def margin_x(self, x):
        """The base map's margin at its coordinates and each extra coordinate's from its value."""
        xb, xe = self.split(x)
        out = self.base.margin_x(xb)
        for i, c in enumerate(self.extra):
            out = jnp.minimum(out, c.margin_x(xe[i]))
        return out


@pytree_dataclass
class AugmentedArm(Arm):
    """An arm with extra joint-space task coordinates (module docstring): x = (x_b[:-1], x_e, x_b[-1]).

    Dynamics, the tool point and its Jacobian are the wrapped arm's; x, Ĵ and J̇̂ get the extra
    rows (their gradients and the gradients' rates)."""

    arm: Any  # the wrapped UrdfArm (chain + tool-frame task map)
    task: AugmentedTask
    kernels: la.Kernels = la.kernels_field()

    @property
    def n(self) -> int:
        return self.arm.n

    @property
    def chain(self):
        return self.arm.chain

    # --- the extra rows ----------------------------------------------------------------------
    def _values(self, q):
        return jnp.stack([c.value(self.chain, q) for c in self.task.extra])

    def _rows(self, q):
        return jnp.stack([c.jacobian(self.chain, q) for c in self.task.extra])

    def _rows_dot(self, q, qd):
        return jnp.stack([c.jacobian_dot(self.chain, q, qd) for c in self.task.extra])

    def _augment(self, t: ArmTerms, q, qd, *, J_dot: bool) -> ArmTerms:
        changes = dict(x=_insert(t.x, self._values(q)), J=_insert(t.J, self._rows(q)))
        if J_dot and t.J_dot is not None:
            changes["J_dot"] = _insert(t.J_dot, self._rows_dot(q, qd))
        return replace(t, **changes)

    # --- kinematics ----------------------------------------------------------------------------
    def fk(self, q):
        return self.chain.fk(q)

    def h(self, q):
        return _insert(self.arm.h(q), self._values(q))

    def J(self, q):
        return _insert(self.arm.J(q), self._rows(q))

    def J_dot(self, q, qd):
        return _insert(self.arm.J_dot(q, qd), self._rows_dot(q, qd))

    def J_dot_times(self, terms: ArmTerms, q, qd, v):
        """J̇̂ v: the wrapped arm's rows (from its cache in ``terms``) and the extra rows'."""
        if terms.J_dot is not None:
            return self.kernels.mm(terms.J_dot, v)
        return _insert(self.arm.J_dot_times(terms, q, qd, v), self.kernels.mm(self._rows_dot(q, qd), v))

    def point(self, q):
        return self.arm.point(q)

    def point_jacobian(self, q):
        return self.arm.point_jacobian(q)

    @property
    def space_dim(self) -> int:
        return int(self.arm.space_dim)

    def task_margin(self, q):
        """The smallest of the wrapped task map's margin and the extra coordinates' (rad or m)."""
        out = self.arm.task_margin(q)
        for c in self.task.extra:
            out = jnp.minimum(out, c.margin(self.chain, q))
        return out

    # --- dynamics (the wrapped arm's) ----------------------------------------------------------
    def M(self, q):
        return self.arm.M(q)

    def C(self, q, qd):
        return self.arm.C(q, qd)

    def C_times(self, q, qd, v):
        return self.arm.C_times(q, qd, v)

    def C_product(self, terms: ArmTerms, q, qd, v):
        return self.arm.C_product(terms, q, qd, v)

    def G(self, q):
        return self.arm.G(q)

    def potential(self, q):
        return self.arm.potential(q)

    def bias(self, q, qd):
        return self.arm.bias(q, qd)

    def forward_dynamics(self, q, qd, tau_total, terms: ArmTerms | None = None):
        return self.arm.forward_dynamics(q, qd, tau_total, terms)

    # --- the sets of terms ---------------------------------------------------------------------
    def terms(self, q, qd) -> ArmTerms:
        return self._augment(self.arm.terms(q, qd), q, qd, J_dot=True)

    def law_terms(self, q, qd) -> ArmTerms:
        return self._augment(self.arm.law_terms(q, qd), q, qd, J_dot=True)

    def plant_terms(self, q, qd) -> ArmTerms:
        return self._augment(self.arm.plant_terms(q, qd), q, qd, J_dot=False)


def chain_arm(chain, task) -> Arm:
    """The arm of a :class:`~hinfnn.model.urdf.UrdfChain` with the task coordinates ``task``: a
    :class:`~hinfnn.model.urdf.UrdfArm`, or for an :class:`AugmentedTask` the
    :class:`AugmentedArm` around the chain's arm with the task's base map."""
    from .urdf import UrdfArm

    if isinstance(task, AugmentedTask):
        return AugmentedArm(arm=UrdfArm(chain, task.base), task=task)
    return UrdfArm(chain, task)


def augment(arm, extra) -> Arm:
    """``arm`` (a :class:`~hinfnn.model.urdf.UrdfArm`) with the extra task coordinates ``extra``
    (a tuple of :class:`~hinfnn.model.taskmap.JointCoordinate` / :class:`~hinfnn.model.taskmap.ArmAngle`);
    ``arm`` itself when there are none."""
    if not extra:
        return arm
    return AugmentedArm(arm=arm, task=AugmentedTask(base=arm.task, extra=tuple(extra)))
