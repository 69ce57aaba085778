"""Task maps: from the end-effector frame (p, R) in the base frame to task coordinates x.

A :class:`hinfnn.model.urdf.UrdfArm` has ``h(q) = task(*chain.fk(q))``. Each map is a small
pytree dataclass with ``__call__(p, R) -> x`` (traceable, differentiable) and ``dim``; each
docstring says where the map is singular (where ∂x/∂(p, R) loses rank or x jumps).

* :class:`PlanarTaskMap`: planar arms (all joints about one axis): two in-plane coordinates and,
  optionally, the tool angle in that plane;
* :class:`PositionTaskMap`: x = p (3-DOF positioning);
* :class:`PoseTaskMap`: x = (p, r), r the rotation vector of R_refᵀ R (6-DOF arms).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

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

    def __call__(self, p, R):
        return p


# Below this value of sin²θ the rotation-vector scale θ / sin θ is evaluated by its series.
_SMALL_S2 = 1e-4


def _log_scale(s2, c):
    """θ / sin θ from s2 = sin²θ and c = cos θ, smooth in s2 (no square root at s2 = 0).

    For small s2 (and c > 0), θ / sin θ = atan(t)/ (c t) with t² = s2 / c²:
    (1/c)(1 − t²/3 + t⁴/5 − t⁶/7 + t⁸/9); the first dropped term is below 1e-17 there.
    """
    small = (s2 < _SMALL_S2) & (c > 0)
    t2 = jnp.where(small, s2 / (c * c), 0.0)
    series = (1.0 - t2 / 3.0 + t2**2 / 5.0 - t2**3 / 7.0 + t2**4 / 9.0) / jnp.where(small, c, 1.0)
    s2_safe = jnp.where(small, 1.0, s2)
    s = jnp.sqrt(s2_safe)
    exact = jnp.arctan2(s, c) / s
    return jnp.where(small, series, exact)


def so3_log(R):
    """Rotation vector r of a rotation matrix (|r| ≤ π): exp([r]×) = R.

    r = (θ / sin θ) · w with w = vee(R − Rᵀ)/2 = sin θ · axis and cos θ = (tr R − 1)/2; the
    scale is evaluated without a square root near θ = 0 (:func:`_log_scale`), so the value and
    every derivative (jacfwd, jvp, grad) are exact and finite at r = 0 (∂r = vee of the
    skew part of ∂R there). Singular at θ = π, where sin θ = 0 but θ / sin θ is unbounded.
    """
    w = 0.5 * jnp.stack([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    return _log_scale(jnp.sum(w * w), c) * w


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
    orientation relative to ``R_ref`` (both in the base frame).

    r is computed by :func:`so3_log`: smooth and exact near the identity (R = R_ref), where its
    Jacobian is the identity in body-fixed angular velocity. Singular at rotation angle
    |r| = π (R_refᵀ R a half turn): r is not differentiable there and flips sign across it.
    Keep the tool within :meth:`singularity_margin` > 0 of it (choose R_ref near the working
    orientation).
    """

    R_ref: jax.Array

    @staticmethod
    def identity() -> "PoseTaskMap":
        return PoseTaskMap(R_ref=jnp.eye(3))

    @property
    def dim(self) -> int:
        return 6

    def __call__(self, p, R):
        return jnp.concatenate([p, so3_log(self.R_ref.T @ R)])

    def rotation(self, x):
        """The tool rotation R = R_ref exp([r]×) of task coordinates x = (p, r)."""
        return self.R_ref @ so3_exp(x[3:6])

    @staticmethod
    def singularity_margin(x):
        """π − |r|: the distance (rad) of task coordinates x = (p, r) from the singular half turn."""
        r = x[3:6]
        t2 = jnp.sum(r * r)
        return jnp.pi - jnp.where(t2 > 0, jnp.sqrt(jnp.where(t2 > 0, t2, 1.0)), 0.0)
