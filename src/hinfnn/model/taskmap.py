"""Task maps: from the end-effector frame (p, R) in the base frame to task coordinates x.

A :class:`hinfnn.model.urdf.UrdfArm` has ``h(q) = task(*chain.fk(q))``. Each map is a small
pytree dataclass with ``__call__(p, R) -> x`` (traceable, differentiable) and ``dim``; each
docstring says where the map is singular (where ∂x/∂(p, R) loses rank or x jumps).

* :class:`PlanarTaskMap`: planar arms (all joints about one axis): two in-plane coordinates and,
  optionally, the tool angle in that plane;
* :class:`PositionTaskMap`: x = p (3-DOF positioning);
* :class:`PoseTaskMap`: x = (p, r), r the rotation vector of R_refᵀ R (6-DOF arms), in a task
  frame and in any order (the constrained coordinate last);
* :class:`FittedTaskMap`: coordinates fitted to a surface (:mod:`hinfnn.model.geometry`): surface
  coordinates, the tool orientation relative to the surface's frame there, and the signed
  distance last (polar around a drum, spherical around a ball, in-plane for a plane).

Every map also says where the tool point lives for a surface (:meth:`space`, the arm's Cartesian
space: 2-D for planar maps, 3-D otherwise; ``space_rows`` are the rows of the frame Jacobian it
uses), how to get that point back from task coordinates when the coordinates contain it
(:meth:`point`, used by :class:`~hinfnn.model.surface.TaskConstraint`), the names and units of
its coordinates (:meth:`names`) and its distance from its singularities (:meth:`margin`, rad or m;
a run records it as ``task_margin``).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp

from .. import _linalg as la
from .._pytree import pytree_dataclass, static_field
from ..errors import ConfigError

_AXES = {"x": 0, "y": 1, "z": 2}


@pytree_dataclass
class PlanarTaskMap:
    """x = (p_a, p_b[, φ]) for ``plane = "ab"`` (e.g. ``"xz"``: (p_x, p_z)).

    φ is the angle of the tool axis (column ``tool_axis`` of R) in the plane, measured from
    axis a towards axis b: φ = atan2(R[b, k], R[a, k]), wrapped into (phi_ref − π, phi_ref + π].

    Singular where the tool axis is perpendicular to the plane (its projection vanishes: never
    for a planar arm whose joints all turn about the plane's normal), and φ jumps by 2π where the
    tool angle crosses phi_ref ± π (choose phi_ref near the working tool angle). The in-plane
    position coordinates are never singular (the arm's Jacobian may be).
    """

    plane: str = static_field(default="xz")
    with_angle: bool = static_field(default=False)
    tool_axis: str = static_field(default="x")
    phi_ref: float = 0.0

    def __post_init__(self):
        if (not isinstance(self.plane, str) or len(self.plane) != 2 or self.plane[0] == self.plane[1]
                or any(c not in _AXES for c in self.plane)):
            raise ConfigError(f"{self.plane!r} is not a plane; give two different axes from x, y, z "
                              "(e.g. 'xz': coordinates (p_x, p_z))", key="plane")
        if self.tool_axis not in _AXES:
            raise ConfigError(f"{self.tool_axis!r} is not an axis; allowed: 'x', 'y', 'z'", key="tool_axis")

    @property
    def dim(self) -> int:
        return 3 if self.with_angle else 2

    space_dim = 2

    @property
    def space_rows(self) -> tuple:
        return (_AXES[self.plane[0]], _AXES[self.plane[1]])

    def space(self, p):
        """The tool point in the plane's coordinates (p_a, p_b)."""
        a, b = self.space_rows
        return jnp.stack([p[a], p[b]])

    def point(self, x):
        return x[:2]

    def names(self) -> list[tuple[str, str]]:
        out = [(f"p_{self.plane[0]}", "m"), (f"p_{self.plane[1]}", "m")]
        return out + ([("phi", "rad")] if self.with_angle else [])

    def margin(self, p, R):
        """π − |φ − phi_ref| (rad): how far the tool angle is from where φ jumps; +inf without angle."""
        return self.margin_x(self(p, R))

    def margin_x(self, x):
        """:meth:`margin` from task coordinates."""
        if not self.with_angle:
            return jnp.asarray(jnp.inf)
        return jnp.pi - jnp.abs(x[2] - self.phi_ref)

    def __call__(self, p, R):
        a, b = _AXES[self.plane[0]], _AXES[self.plane[1]]
        pos = jnp.stack([p[a], p[b]])
        if not self.with_angle:
            return pos
        k = _AXES[self.tool_axis]
        u, w = R[a, k], R[b, k]
        s, c = jnp.sin(self.phi_ref), jnp.cos(self.phi_ref)
        phi = self.phi_ref + jnp.arctan2(c * w - s * u, c * u + s * w)
        return jnp.concatenate([pos, phi[None]])


@pytree_dataclass
class PositionTaskMap:
    """x = p, the tool point in the base frame (3-DOF arms). The map itself is never singular."""

    @property
    def dim(self) -> int:
        return 3

    space_dim = 3
    space_rows = (0, 1, 2)

    def space(self, p):
        return p

    def point(self, x):
        return x

    def names(self):
        return [("p_x", "m"), ("p_y", "m"), ("p_z", "m")]

    def margin(self, p, R):
        return jnp.asarray(jnp.inf)

    def margin_x(self, x):
        return jnp.asarray(jnp.inf)

    def __call__(self, p, R):
        return p


# Below this value of sin²θ the rotation-vector scale θ / sin θ is evaluated by its series.
_SMALL_S2 = 1e-4


def _log_scale_value(s2, c):
    small = (s2 < _SMALL_S2) & (c > 0)
    t2 = jnp.where(small, s2 / (c * c), 0.0)
    series = (1.0 - t2 / 3.0 + t2**2 / 5.0 - t2**3 / 7.0 + t2**4 / 9.0) / jnp.where(small, c, 1.0)
    s2_safe = jnp.where(small, 1.0, s2)
    s = jnp.sqrt(s2_safe)
    exact = jnp.arctan2(s, c) / s
    return jnp.where(small, series, exact), small, t2


@functools.cache
def _log_scale_for(kernels: la.Kernels):
    """:func:`_log_scale` whose derivative stores its values with ``kernels``
    (:meth:`hinfnn._linalg.Kernels.stored`)."""

    @jax.custom_jvp
    def _log_scale(s2, c):
        return _log_scale_value(s2, c)[0]

    @_log_scale.defjvp
    def _log_scale_jvp(primals, tangents):
        s2, c = primals
        ds2, dc = tangents
        g, small, t2 = _log_scale_value(s2, c)
        r = s2 + c * c
        series = (-1.0 / 3.0 + 2.0 * t2 / 5.0 - 3.0 * t2**2 / 7.0 + 4.0 * t2**3 / 9.0 - 5.0 * t2**4 / 11.0) \
            / jnp.where(small, c**3, 1.0)
        exact = (c / r - g) / (2.0 * jnp.where(small, 1.0, s2))
        g_s2 = jnp.where(small, series, exact)
        # g, ∂g/∂s2 and 1/r computed together, once (stored: one kernel in a compiled arm loop,
        # where each division read twice would otherwise be a kernel of its own)
        g, g_s2, r_inv = kernels.stored(jnp.stack([g, g_s2, 1.0 / r]))
        return g, g_s2 * ds2 - dc * r_inv

    return _log_scale


def _log_scale(s2, c, kernels: la.Kernels = la.DEFAULT):
    """θ / sin θ from s2 = sin²θ and c = cos θ, smooth in s2 (no square root at s2 = 0).

    For small s2 (and c > 0), θ / sin θ = atan(t)/ (c t) with t² = s2 / c²:
    (1/c)(1 − t²/3 + t⁴/5 − t⁶/7 + t⁸/9); the first dropped term is below 1e-17 there.
    Its derivatives are written out (custom JVP: fewer operations under the nested forward-mode
    derivatives of the task Jacobian and its rate): ∂g/∂c = −1/(s2 + c²) exactly, and
    ∂g/∂s2 = (c/(s2 + c²) − g)/(2 s2), by its series for small s2; g, ∂g/∂s2 and 1/(s2 + c²)
    stored with ``kernels``."""
    return _log_scale_for(kernels)(s2, c)


def so3_log(R, kernels: la.Kernels = la.DEFAULT):
    """Rotation vector r of a rotation matrix (|r| ≤ π): exp([r]×) = R.

    r = (θ / sin θ) · w with w = vee(R − Rᵀ)/2 = sin θ · axis and cos θ = (tr R − 1)/2; the
    scale is evaluated without a square root near θ = 0 (:func:`_log_scale`), so the value and
    every derivative (jacfwd, jvp, grad) are exact and finite at r = 0 (∂r = vee of the
    skew part of ∂R there). Singular at θ = π, where sin θ = 0 but θ / sin θ is unbounded.
    """
    w = (0.5 * (R[2, 1] - R[1, 2]), 0.5 * (R[0, 2] - R[2, 0]), 0.5 * (R[1, 0] - R[0, 1]))
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    g = _log_scale(w[0] * w[0] + w[1] * w[1] + w[2] * w[2], c, kernels)  # elementwise: no reduction kernel
    return jnp.stack([g * w[0], g * w[1], g * w[2]])


def so3_exp(r):
    """Rotation matrix exp([r]×) (Rodrigues), smooth at r = 0 (series for small |r|)."""
    r = jnp.asarray(r)
    t2 = jnp.sum(r * r)
    small = t2 < 1e-8
    t2s = jnp.where(small, 1.0, t2)
    t = jnp.sqrt(t2s)
    a = jnp.where(small, 1.0 - t2 / 6.0 + t2**2 / 120.0, jnp.sin(t) / t)
    b = jnp.where(small, 0.5 - t2 / 24.0 + t2**2 / 720.0, (1.0 - jnp.cos(t)) / t2s)
    K = jnp.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    return jnp.eye(3) + a * K + b * (K @ K)


@pytree_dataclass
class PoseTaskMap:
    """x = (p, r): tool position and r = log(R_refᵀ R), the rotation vector of the tool's
    orientation relative to ``R_ref`` (both in the base frame); with a task frame (``frame_rot``,
    ``frame_pos``: its axes and origin in the base frame) the position is R_fᵀ(p − o) and R_ref is
    still given in the base frame. ``order`` permutes the six coordinates (x = raw[order]), so
    that the coordinate a surface constrains can be put last, e.g. (0, 1, 3, 4, 5, 2) for a
    table: (x, y, r, z).

    r is computed by :func:`so3_log`: smooth and exact near the identity (R = R_ref), where its
    Jacobian is the identity in body-fixed angular velocity. Singular at rotation angle
    |r| = π (R_refᵀ R a half turn): r is not differentiable there and flips sign across it.
    Keep the tool within :meth:`singularity_margin` > 0 of it (choose R_ref near the working
    orientation).
    """

    R_ref: jax.Array
    frame_rot: jax.Array | None = None
    frame_pos: jax.Array | None = None
    order: tuple = static_field(default=(0, 1, 2, 3, 4, 5))
    kernels: la.Kernels = la.kernels_field()

    def __post_init__(self):
        if sorted(self.order) != list(range(6)):
            raise ConfigError(f"{self.order!r} is not a permutation of 0 … 5", key="order")

    @staticmethod
    def identity() -> "PoseTaskMap":
        return PoseTaskMap(R_ref=jnp.eye(3))

    @property
    def dim(self) -> int:
        return 6

    space_dim = 3
    space_rows = (0, 1, 2)

    def space(self, p):
        return p

    def _raw(self, p, R):
        pos = p if self.frame_pos is None else p - self.frame_pos
        k = self.kernels
        pos = pos if self.frame_rot is None else k.mm(self.frame_rot.T, pos)
        return jnp.concatenate([pos, so3_log(k.mm(self.R_ref.T, R), k)])

    def __call__(self, p, R):
        raw = self._raw(p, R)
        if tuple(self.order) == tuple(range(6)):
            return raw
        return raw[jnp.asarray(self.order)]

    def _unorder(self, x):
        inv = [self.order.index(i) for i in range(6)]
        return x[jnp.asarray(inv)] if tuple(self.order) != tuple(range(6)) else x

    def point(self, x):
        """The tool point (base frame) of task coordinates x."""
        pos = self._unorder(x)[:3]
        pos = pos if self.frame_rot is None else self.frame_rot @ pos
        return pos if self.frame_pos is None else pos + self.frame_pos

    def rotation(self, x):
        """The tool rotation R = R_ref exp([r]×) of task coordinates x."""
        return self.R_ref @ so3_exp(self._unorder(x)[3:6])

    def names(self):
        raw = [("p_x", "m"), ("p_y", "m"), ("p_z", "m"), ("r_x", "rad"), ("r_y", "rad"), ("r_z", "rad")]
        return [raw[i] for i in self.order]

    def margin(self, p, R):
        """π − |r| (rad)."""
        return self.singularity_margin(self._raw(p, R))

    def margin_x(self, x):
        return self.singularity_margin(self._unorder(x))

    @staticmethod
    def singularity_margin(x):
        """π − |r|: the distance (rad) of task coordinates x = (p, r) from the singular half turn."""
        r = x[3:6]
        t2 = jnp.sum(r * r)
        return jnp.pi - jnp.where(t2 > 0, jnp.sqrt(jnp.where(t2 > 0, t2, 1.0)), 0.0)


@pytree_dataclass
class FittedTaskMap:
    """Task coordinates fitted to a surface (a fittable :mod:`~hinfnn.model.geometry` kind):

    * 3-D (spatial arms, ``geometry.dim == 3``): x = (s1, s2, r, d), r = log((F(s) R_off)ᵀ R)
      the tool orientation relative to the surface frame F(s) (its third axis the inward
      normal) turned by ``R_off``; r = 0 holds the tool's z axis along the inward normal
      (``orientation=False``: x = (s1, s2, d) for 3-DOF positioning arms);
    * 2-D (planar arms): x = (s, φ_rel, d), φ_rel the angle from the inward normal to the tool
      axis (column ``tool_axis`` of R) in the plane ``plane`` (``orientation=False``: x = (s, d)).

    s are the surface coordinates of the tool point, d its signed distance (positive inside), so
    the constraint is θ̂(x) = d and Π = 1 everywhere (:class:`~hinfnn.model.surface.FittedConstraint`);
    λ is then the normal force in newtons. Singular where the geometry's coordinates are (poles,
    centre, axis: see its class), at r's half turn (|r| = π) and where φ_rel = ±π (the tool
    pointing out of the surface); :meth:`margin` is the smallest distance (rad) to these.
    """

    geometry: Any
    R_off: jax.Array | None = None
    plane: str = static_field(default="xz")
    tool_axis: str = static_field(default="x")
    orientation: bool = static_field(default=True)
    kernels: la.Kernels = la.kernels_field()

    @property
    def space_dim(self) -> int:
        return int(self.geometry.dim)

    @property
    def dim(self) -> int:
        if self.space_dim == 3:
            return 6 if self.orientation else 3
        return 3 if self.orientation else 2

    @property
    def space_rows(self) -> tuple:
        if self.space_dim == 3:
            return (0, 1, 2)
        return (_AXES[self.plane[0]], _AXES[self.plane[1]])

    def space(self, p):
        if self.space_dim == 3:
            return p
        a, b = self.space_rows
        return jnp.stack([p[a], p[b]])

    def _orientation(self, s, R):
        F = self.geometry.frame(s)
        if self.space_dim == 3:
            k = self.kernels
            Rd = F if self.R_off is None else k.mm(F, self.R_off)
            return so3_log(k.stored(k.mm(Rd.T, R)), k)  # read by every entry of the log: computed once
        a, b = self.space_rows
        k = _AXES[self.tool_axis]
        v = jnp.stack([R[a, k], R[b, k]])
        n = F[:, 1]
        return jnp.arctan2(n[0] * v[1] - n[1] * v[0], jnp.sum(n * v))[None]

    def __call__(self, p, R):
        s, d = self.geometry.coordinates(self.space(p))
        parts = [s] + ([self._orientation(s, R)] if self.orientation else []) + [jnp.atleast_1d(d)]
        return jnp.concatenate(parts)

    def point(self, x):
        ns = self.space_dim - 1
        return self.geometry.point(x[:ns], x[-1])

    def names(self):
        geo = self.geometry.coordinate_names()
        rot = ([("r_x", "rad"), ("r_y", "rad"), ("r_z", "rad")] if self.space_dim == 3 else [("phi_rel", "rad")])
        return geo[:-1] + (rot if self.orientation else []) + geo[-1:]

    def margin(self, p, R):
        return self.margin_x(self(p, R))

    def margin_x(self, x):
        """The smallest of the geometry's margin at the point of x and the orientation's (rad)."""
        m = self.geometry.singularity_margin(self.point(x))
        if not self.orientation:
            return m
        ns = self.space_dim - 1
        r = x[ns:-1]
        if self.space_dim == 3:
            return jnp.minimum(m, PoseTaskMap.singularity_margin(jnp.concatenate([jnp.zeros(3), r])))
        return jnp.minimum(m, jnp.pi - jnp.abs(r[0]))


# ---------------------------------------------------------------------------------------------
# Extra task coordinates of redundant arms: functions of the joint angles (not of the tool frame)
# ---------------------------------------------------------------------------------------------
# A redundant arm (n joints, a task map of n − e coordinates) gets e more motion coordinates so
# that x = h(q) is square again ((A1)): :class:`~hinfnn.model.augmented.AugmentedArm` inserts them
# before the constrained coordinate, where they are motion coordinates u1 like the others
# (tracked to a reference, with their own K_p, K_v and network output). Each has a value, its
# gradient (a row of Ĵ) and that row's time derivative (a row of J̇̂), its name and unit, and its
# distance from where it is singular or wraps.


@pytree_dataclass
class JointCoordinate:
    """x_e = q_i: one joint's angle (rad) or position (m) as a task coordinate. Its row of Ĵ is
    e_iᵀ (constant: its row of J̇̂ is 0). Never singular itself; with it, Ĵ is singular exactly
    where the task map's Jacobian without column i is (the arm with joint i locked)."""

    index: int = static_field()
    name: str = static_field(default="")
    unit: str = static_field(default="rad")

    def value(self, chain, q):
        return q[self.index]

    def jacobian(self, chain, q):
        return jnp.zeros_like(q).at[self.index].set(1.0)

    def jacobian_dot(self, chain, q, qd):
        return jnp.zeros_like(q)

    def margin(self, chain, q):
        return jnp.asarray(jnp.inf)

    def margin_x(self, value):
        return jnp.asarray(jnp.inf)


def joint_origins(chain, q, count: int):
    """The origins (base frame) of the first ``count`` joint frames of a
    :class:`~hinfnn.model.urdf.UrdfChain` at q: joint i's frame is ``placement_pos[i],
    placement_rot[i]`` in body i − 1 (a joint's own motion does not move its origin)."""
    R, p = jnp.eye(3), jnp.zeros(3)
    out = []
    for i in range(count):
        p = p + chain.kernels.mm(R, chain.placement_pos[i])
        R = chain.kernels.mm(R, chain.placement_rot[i])
        out.append(p)
        a = chain.axes[i]
        if chain.joint_types[i] == "prismatic":
            p = p + chain.kernels.mm(R, a) * q[i]
        else:
            K = jnp.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
            s, c = jnp.sin(q[i]), jnp.cos(q[i])
            R = chain.kernels.mm(R, jnp.eye(3) + s * K + (1.0 - c) * chain.kernels.mm(K, K))
    return out


@pytree_dataclass
class ArmAngle:
    """ψ, the elbow's angle ("arm angle", the swivel of the arm plane; Kreutz-Delgado, Long and
    Seraji, 1992): the angle about the shoulder–wrist axis u = (W − S)/‖W − S‖ from the reference
    half-plane (u, ``reference`` v) to the arm plane (u, elbow E):

        ψ = atan2(u · (v⊥ × e⊥), v⊥ · e⊥),   v⊥ = v − (v·u)u,   e⊥ = (E − S) − ((E − S)·u)u,

    S, E, W the origins of the joints ``shoulder``, ``elbow``, ``wrist`` (indices into the chain),
    wrapped into (psi_ref − π, psi_ref + π]. It moves the elbow about the shoulder–wrist line, the
    self-motion of a 7-DOF arm with the tool held. Its gradient and the gradient's rate are
    autodiff (forward mode). Singular where u ∥ v (v⊥ = 0: the shoulder–wrist line along the
    reference) or the arm is stretched (e⊥ = 0), and it jumps where ψ crosses psi_ref ± π:
    :meth:`margin` is the smallest of the angle from u to ±v, the angle at S between E − S and
    ±u, and π − |ψ − psi_ref| (rad)."""

    shoulder: int = static_field()
    elbow: int = static_field()
    wrist: int = static_field()
    reference: jax.Array = None
    psi_ref: jax.Array = 0.0
    name: str = static_field(default="psi")
    unit: str = static_field(default="rad")

    def _points(self, chain, q):
        origins = joint_origins(chain, q, max(self.shoulder, self.elbow, self.wrist) + 1)
        return origins[self.shoulder], origins[self.elbow], origins[self.wrist]

    def _geometry(self, chain, q):
        S, E, W = self._points(chain, q)
        d = W - S
        u = d / jnp.sqrt(jnp.sum(d * d))
        a = E - S
        e = a - jnp.sum(a * u) * u
        v = self.reference - jnp.sum(self.reference * u) * u
        return u, a, e, v

    def value(self, chain, q):
        u, _, e, v = self._geometry(chain, q)
        x, y = jnp.sum(v * e), jnp.sum(u * jnp.cross(v, e))
        s, c = jnp.sin(self.psi_ref), jnp.cos(self.psi_ref)
        return self.psi_ref + jnp.arctan2(c * y - s * x, c * x + s * y)

    def jacobian(self, chain, q):
        return jax.jacfwd(lambda qq: self.value(chain, qq))(q)

    def jacobian_dot(self, chain, q, qd):
        return jax.jvp(lambda qq: self.jacobian(chain, qq), (q,), (qd,))[1]

    def margin(self, chain, q):
        u, a, _, _ = self._geometry(chain, q)

        def off_axis(w, axis):  # angle between w and the line of the unit vector axis
            w = w / jnp.sqrt(jnp.sum(w * w))
            return jnp.arcsin(jnp.clip(jnp.sqrt(jnp.sum(jnp.cross(w, axis) ** 2)), 0.0, 1.0))

        wrap = self.margin_x(self.value(chain, q))
        return jnp.minimum(jnp.minimum(off_axis(self.reference, u), off_axis(a, u)), wrap)

    def margin_x(self, value):
        """π − |ψ − psi_ref| (rad): how far ψ is from where it jumps."""
        return jnp.pi - jnp.abs(value - self.psi_ref)
