"""Surfaces as Cartesian shapes: exact signed distance for the plant, θ(p) for the controller,
and surface-fitted coordinates.

A *geometry* lives in the arm's Cartesian space: 3-D (the base frame of a spatial arm) or 2-D
(the plane of a planar arm, coordinates (a, b), e.g. (x, z) of a planar URDF arm with
``plane = "xz"``). Every geometry has

* :meth:`~Geometry.signed_distance` ``d(p)``: the EXACT signed distance to the surface, positive
  inside the material. The true plant's penetration is this, at the tool point; its gradient
  :meth:`~Geometry.normal` is the unit normal pointing into the material (where the contact
  force pushes the tool out). For the plane, sphere, cylinder, circle and line it is a closed
  form; for the sinusoidal profile and a user's θ it is computed from the foot point (the
  closest point of the surface, found by Newton's method) and is exact to round-off wherever the
  foot point is unique (closer to the surface than its smallest radius of curvature).
* :meth:`~Geometry.theta` ``θ(p)``: the constraint function the controller uses when the task
  coordinates contain the tool point (:class:`~hinfnn.model.surface.TaskConstraint`): the signed
  distance for the closed-form kinds, ``(f(a) − b)/√(1 + f'(a)²)`` for the profile (exact on the
  surface, unit gradient there, so λ is the normal force), the user's function otherwise.

The closed-form kinds also define *fitted coordinates* (``fittable``): surface coordinates
``s`` (dim − 1 numbers, metres: arc lengths on the reference radius) with the signed distance
``d`` as the last coordinate, the inverse map :meth:`point` ``(s, d) -> p`` and a frame
:meth:`frame` at ``s`` whose last axis is the inward normal. The task map
:class:`~hinfnn.model.taskmap.FittedTaskMap` builds the task coordinates (s, tool orientation
relative to the frame, d) from them: the constraint is then ``θ̂(x) = d``, with Π = 1 everywhere
the coordinates are defined (see each class for where they are singular).
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

from .. import _linalg as la
from .._pytree import pytree_dataclass, static_field


def _dot(a, b):
    return jnp.sum(a * b)


def _unit(v):
    return v / jnp.sqrt(jnp.sum(v * v))


def _norm(v):
    return jnp.sqrt(jnp.sum(v * v))


def _wrap(angle):
    """An angle wrapped into (−π, π] (smooth away from ±π)."""
    return jnp.arctan2(jnp.sin(angle), jnp.cos(angle))


class Geometry:
    """Base class. Subclasses define ``dim`` (2 or 3), :meth:`theta` and, unless θ is the exact
    signed distance, :meth:`signed_distance`."""

    dim: int
    fittable: bool = False
    #: True when θ is the exact signed distance (every kind but the profile and a user's θ)
    exact_theta: bool = True
    #: λ's unit when θ is the constraint (hinfnn.model.surface.Surface.lambda_unit): θ is a length
    lambda_unit = "N"
    #: How the small linear algebra is written (:class:`hinfnn._linalg.Kernels`; a subclass whose
    #: code uses it has a static ``kernels`` field, set by the program that traces it)
    kernels = la.DEFAULT

    def theta(self, p):
        raise NotImplementedError

    def signed_distance(self, p):
        """Exact signed distance (m), positive inside the material."""
        return self.theta(p)

    def normal(self, p):
        """Unit normal pointing into the material: the gradient of the signed distance."""
        return jax.grad(self.signed_distance)(p)

    def singularity_margin(self, p):
        """Distance (m or rad, see the class) of p from where the fitted coordinates are
        undefined; +inf where they are defined everywhere."""
        return jnp.inf

    # fitted coordinates (fittable kinds) ----------------------------------------------------
    def coordinates(self, p):
        """(s, d): surface coordinates (dim − 1,) and signed distance of the point p."""
        raise NotImplementedError

    def point(self, s, d):
        """The point with surface coordinates s at signed distance d (inverse of :meth:`coordinates`)."""
        raise NotImplementedError

    def frame(self, s):
        """Rotation (dim × dim) at surface coordinates s: columns (tangents…, inward normal),
        right-handed. In 2-D: [[t_a, n_a], [t_b, n_b]] with t = the normal turned by −90°."""
        raise NotImplementedError

    def coordinate_names(self) -> list[tuple[str, str]]:
        """Names and units of (s…, d)."""
        raise NotImplementedError


# --- 3-D ------------------------------------------------------------------------------------


@pytree_dataclass
class Plane(Geometry):
    """A plane through ``point`` with outward normal ``normal`` (out of the material, e.g. up for
    a table top; need not be unit). Material on the side opposite to ``normal``.

    Fitted coordinates: s = coordinates of the tool point in the plane along t1 (``tangent``
    projected onto the plane) and t2 = n_in × t1, origin at ``point``; d = depth below the plane.
    Frame (t1, t2, n_in). Never singular."""

    point_: jax.Array
    normal_out: jax.Array
    tangent: jax.Array
    dim: int = static_field(default=3)
    kernels: la.Kernels = la.kernels_field()
    fittable = True

    @classmethod
    def build(cls, point, normal, tangent=(1.0, 0.0, 0.0)) -> "Plane":
        n = jnp.asarray(normal, float)
        n = n / jnp.linalg.norm(n)
        t = jnp.asarray(tangent, float)
        t = t - _dot(t, n) * n
        return cls(point_=jnp.asarray(point, float), normal_out=n, tangent=t / jnp.linalg.norm(t))

    def _frame(self):
        n_in = -self.normal_out
        t1 = self.tangent
        return jnp.stack([t1, jnp.cross(n_in, t1), n_in], axis=1)

    def theta(self, p):
        return -jnp.sum(self.normal_out * (p - self.point_))

    def normal(self, p):
        return -self.normal_out + 0.0 * p

    def coordinates(self, p):
        local = self.kernels.mm(self._frame().T, p - self.point_)
        return local[:2], local[2]

    def point(self, s, d):
        return self.point_ + self.kernels.mm(self._frame(), jnp.concatenate([s, jnp.atleast_1d(d)]))

    def frame(self, s):
        return self._frame() + 0.0 * s[0]

    def coordinate_names(self):
        return [("s1", "m"), ("s2", "m"), ("d", "m")]


def _basis(pole, meridian):
    """Orthonormal (b1, b2, b3): b3 along ``pole``, b1 along ``meridian`` made orthogonal to it."""
    b3 = _unit(pole)
    b1 = _unit(meridian - _dot(meridian, b3) * b3)
    return b1, jnp.cross(b3, b1), b3


@pytree_dataclass
class Sphere(Geometry):
    """A ball of ``radius`` centred at ``centre`` (material inside).

    Fitted coordinates: spherical angles of the outward direction u = (p − c)/|p − c| with polar
    axis ``pole`` and zero longitude along ``meridian``: longitude α (about the pole, from the
    meridian) and latitude β (from the equator towards the pole); s = (r_s α, r_s β) with r_s the
    radius (arc lengths on the sphere, m); d = radius − |p − c|. With the pole horizontal and
    the meridian up, the top of the ball is s = 0 and s1, s2 point along the two horizontal
    directions. Frame (e_α, −e_β, −u): at the top with pole y and meridian z it is
    diag(1, −1, −1), a tool pointing down.

    Singular at the poles (|β| = 90°, where α is undefined) and at the centre;
    :meth:`singularity_margin` is the angle (rad) from the nearer pole. α jumps by 2π at the
    meridian's antipode."""

    centre: jax.Array
    radius: jax.Array
    pole: jax.Array
    meridian: jax.Array
    dim: int = static_field(default=3)
    fittable = True

    @classmethod
    def build(cls, centre, radius, pole=(0.0, 1.0, 0.0), meridian=(0.0, 0.0, 1.0)) -> "Sphere":
        return cls(centre=jnp.asarray(centre, float), radius=jnp.asarray(radius, float),
                   pole=jnp.asarray(pole, float), meridian=jnp.asarray(meridian, float))

    def theta(self, p):
        return self.radius - _norm(p - self.centre)

    def _angles(self, p):
        b1, b2, b3 = _basis(self.pole, self.meridian)
        v = p - self.centre
        x, y, z = _dot(v, b1), _dot(v, b2), _dot(v, b3)
        alpha = jnp.arctan2(y, x)
        beta = jnp.arctan2(z, jnp.sqrt(x * x + y * y))
        return alpha, beta

    def coordinates(self, p):
        alpha, beta = self._angles(p)
        return self.radius * jnp.stack([alpha, beta]), self.theta(p)

    def _vectors(self, s):
        b1, b2, b3 = _basis(self.pole, self.meridian)
        alpha, beta = s[0] / self.radius, s[1] / self.radius
        ca, sa, cb, sb = jnp.cos(alpha), jnp.sin(alpha), jnp.cos(beta), jnp.sin(beta)
        u = cb * (ca * b1 + sa * b2) + sb * b3
        e_alpha = -sa * b1 + ca * b2
        e_beta = -sb * (ca * b1 + sa * b2) + cb * b3
        return u, e_alpha, e_beta

    def point(self, s, d):
        u, _, _ = self._vectors(s)
        return self.centre + (self.radius - d) * u

    def frame(self, s):
        u, e_alpha, e_beta = self._vectors(s)
        return jnp.stack([e_alpha, -e_beta, -u], axis=1)

    def singularity_margin(self, p):
        _, beta = self._angles(p)
        return 0.5 * jnp.pi - jnp.abs(beta)

    def coordinate_names(self):
        return [("s_lon", "m"), ("s_lat", "m"), ("d", "m")]


@pytree_dataclass
class Cylinder(Geometry):
    """A solid cylinder of ``radius`` about the line through ``point`` along ``axis`` (material
    inside).

    Fitted coordinates: s = (axial position along the axis from ``point``, r_s ψ) with ψ the
    angle about the axis from ``reference`` (made orthogonal to the axis), d = radius − distance
    from the axis. Frame (axis, n_in × axis, n_in). Singular on the axis; ψ jumps by 2π opposite
    the reference direction (:meth:`singularity_margin`: the angle from there, rad)."""

    point_: jax.Array
    axis: jax.Array
    radius: jax.Array
    reference: jax.Array
    dim: int = static_field(default=3)
    fittable = True

    @classmethod
    def build(cls, point, axis, radius, reference=(0.0, 0.0, 1.0)) -> "Cylinder":
        return cls(point_=jnp.asarray(point, float), axis=jnp.asarray(axis, float),
                   radius=jnp.asarray(radius, float), reference=jnp.asarray(reference, float))

    def _radial(self, p):
        a = _unit(self.axis)
        v = p - self.point_
        return a, v - _dot(v, a) * a

    def theta(self, p):
        _, r = self._radial(p)
        return self.radius - _norm(r)

    def coordinates(self, p):
        b1, b2, a = _basis(self.axis, self.reference)
        v = p - self.point_
        psi = jnp.arctan2(_dot(v, b2), _dot(v, b1))
        return jnp.stack([_dot(v, a), self.radius * psi]), self.theta(p)

    def _u(self, s):
        b1, b2, a = _basis(self.axis, self.reference)
        psi = s[1] / self.radius
        return a, jnp.cos(psi) * b1 + jnp.sin(psi) * b2

    def point(self, s, d):
        a, u = self._u(s)
        return self.point_ + s[0] * a + (self.radius - d) * u

    def frame(self, s):
        a, u = self._u(s)
        n_in = -u
        return jnp.stack([a, jnp.cross(n_in, a), n_in], axis=1)

    def singularity_margin(self, p):
        b1, b2, _ = _basis(self.axis, self.reference)
        v = p - self.point_
        psi = jnp.arctan2(_dot(v, b2), _dot(v, b1))
        return jnp.pi - jnp.abs(psi)

    def coordinate_names(self):
        return [("s_axial", "m"), ("s_arc", "m"), ("d", "m")]


# --- 2-D (the plane of a planar arm, coordinates (a, b)) --------------------------------------


def _frame2(n_in):
    """2-D frame (t, n_in) with t = n_in turned by −90° (so that det = 1)."""
    t = jnp.stack([n_in[1], -n_in[0]])
    return jnp.stack([t, n_in], axis=1)


@pytree_dataclass
class Circle(Geometry):
    """A disc (a drum seen end-on) of ``radius`` centred at ``centre`` in the arm's plane
    (material inside).

    Fitted (polar) coordinates: s = r_s (ψ − ψ_ref wrapped into (−π, π]) + r_s ψ_ref, with ψ the
    polar angle of p − c from the plane's first axis and ψ_ref = ``angle_ref``; d = radius −
    |p − c|. Frame (t, n_in), n_in = −u pointing to the centre. Singular at the centre; s jumps
    by 2π r_s opposite ψ_ref (:meth:`singularity_margin`: angle from there, rad)."""

    centre: jax.Array
    radius: jax.Array
    angle_ref: jax.Array
    dim: int = static_field(default=2)
    fittable = True

    @classmethod
    def build(cls, centre, radius, angle_ref=0.0) -> "Circle":
        return cls(centre=jnp.asarray(centre, float), radius=jnp.asarray(radius, float),
                   angle_ref=jnp.asarray(angle_ref, float))

    def theta(self, p):
        return self.radius - _norm(p - self.centre)

    def _psi(self, p):
        v = p - self.centre
        return self.angle_ref + _wrap(jnp.arctan2(v[1], v[0]) - self.angle_ref)

    def coordinates(self, p):
        return self.radius * self._psi(p)[None], self.theta(p)

    def point(self, s, d):
        psi = s[0] / self.radius
        return self.centre + (self.radius - d) * jnp.stack([jnp.cos(psi), jnp.sin(psi)])

    def frame(self, s):
        psi = s[0] / self.radius
        return _frame2(-jnp.stack([jnp.cos(psi), jnp.sin(psi)]))

    def singularity_margin(self, p):
        return jnp.pi - jnp.abs(self._psi(p) - self.angle_ref)

    def coordinate_names(self):
        return [("s", "m"), ("d", "m")]


@pytree_dataclass
class Line(Geometry):
    """A straight line in the arm's plane through ``point`` with outward normal ``normal``
    (material on the other side). Fitted coordinates: s along t = n_in turned by −90° from
    ``point``, d the depth. Never singular."""

    point_: jax.Array
    normal_out: jax.Array
    dim: int = static_field(default=2)
    kernels: la.Kernels = la.kernels_field()
    fittable = True

    @classmethod
    def build(cls, point, normal) -> "Line":
        n = jnp.asarray(normal, float)
        return cls(point_=jnp.asarray(point, float), normal_out=n / jnp.linalg.norm(n))

    def theta(self, p):
        return -jnp.sum(self.normal_out * (p - self.point_))

    def normal(self, p):
        return -self.normal_out + 0.0 * p

    def coordinates(self, p):
        local = self.kernels.mm(_frame2(-self.normal_out).T, p - self.point_)
        return local[:1], local[1]

    def point(self, s, d):
        return self.point_ + self.kernels.mm(_frame2(-self.normal_out), jnp.stack([s[0], d]))

    def frame(self, s):
        return _frame2(-self.normal_out) + 0.0 * s[0]

    def coordinate_names(self):
        return [("s", "m"), ("d", "m")]


@pytree_dataclass
class SineProfile(Geometry):
    """A wavy surface b = f(a) = offset + amplitude · sin(2π a / wavelength + phase) in the arm's
    plane, material below (b < f(a)).

    θ(p) = (f(a) − b)/√(1 + f'(a)²) (exact on the surface, unit gradient there); the signed
    distance is exact, from the foot point s* that minimises |p − (s, f(s))| (Newton's method from
    s = a; unique while p is closer to the curve than its smallest radius of curvature,
    wavelength² / (4π² amplitude)). Not fittable: use Cartesian task coordinates (Π = −1/√(1 +
    f'²) never vanishes)."""

    amplitude: jax.Array
    wavelength: jax.Array
    phase: jax.Array
    offset: jax.Array
    iterations: int = static_field(default=12)
    dim: int = static_field(default=2)
    exact_theta = False

    def f(self, a):
        k = 2 * jnp.pi / self.wavelength
        return self.offset + self.amplitude * jnp.sin(k * a + self.phase)

    def _df(self, a):
        k = 2 * jnp.pi / self.wavelength
        return self.amplitude * k * jnp.cos(k * a + self.phase), -self.amplitude * k * k * jnp.sin(k * a + self.phase)

    def theta(self, p):
        d1, _ = self._df(p[0])
        return (self.f(p[0]) - p[1]) / jnp.sqrt(1.0 + d1 * d1)

    def foot(self, p):
        """The foot point parameter s* (Newton on (s − a) + (f(s) − b) f'(s) = 0)."""
        def body(_, s):
            d1, d2 = self._df(s)
            r = self.f(s) - p[1]
            g = (s - p[0]) + r * d1
            dg = 1.0 + d1 * d1 + r * d2
            return s - g / dg

        return jax.lax.fori_loop(0, self.iterations, body, p[0])

    def signed_distance(self, p):
        s = jax.lax.stop_gradient(self.foot(p))
        d1, _ = self._df(s)
        n_in = jnp.stack([d1, -1.0]) / jnp.sqrt(1.0 + d1 * d1)
        # (p − c(s*))·n(s*): exact at the foot point, gradient n(s*) (envelope theorem)
        return jnp.sum((p - jnp.stack([s, self.f(s)])) * n_in)


@pytree_dataclass
class UserSurface(Geometry):
    """A surface given by the user's ``theta_fn(p, params) -> scalar`` (positive inside, a
    module-level function), in 2-D or 3-D.

    The controller uses θ as given (λ is in the units of θ's gradient). The plant's signed
    distance is exact: from the closest point y* of {θ = 0} (projection iterations from p: y ←
    y − θ(y)∇θ/|∇θ|², then y ← p − ((p − y)·n)n, repeated), d = (p − y*)·n(y*)."""

    params: jax.Array
    theta_fn: Callable = static_field()
    dim: int = static_field(default=3)
    iterations: int = static_field(default=20)
    exact_theta = False
    lambda_unit = "N·m/θ"  # θ's unit is the user's

    def theta(self, p):
        return jnp.reshape(self.theta_fn(p, self.params), ())

    def _n(self, y):
        g = jax.grad(self.theta)(y)
        return g / _norm(g), g

    def foot(self, p):
        def project(y):
            _, g = self._n(y)
            return y - self.theta(y) * g / jnp.sum(g * g)

        def body(_, y):
            y = project(y)
            n, _ = self._n(y)
            return project(p - jnp.sum((p - y) * n) * n)

        return jax.lax.fori_loop(0, self.iterations, body, project(p))

    def signed_distance(self, p):
        y = jax.lax.stop_gradient(self.foot(p))
        n, _ = self._n(y)
        return jnp.sum((p - y) * jax.lax.stop_gradient(n))


__all__ = ["Geometry", "Plane", "Sphere", "Cylinder", "Circle", "Line", "SineProfile", "UserSurface"]
