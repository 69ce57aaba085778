"""Desired trajectories u1d(t) and λd(t) (paper Sec. IV objectives, Sec. VI values).

A reference is a pytree callable on t returning a :class:`RefSample` with u1d, u̇1d, ü1d and λd.
Controllers and the simulator evaluate it; both import it from here (not from each other).
"""

from __future__ import annotations

import dataclasses
import math
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np

from . import _linalg as la
from ._pytree import pytree_dataclass
from .errors import ConfigError


@pytree_dataclass
class RefSample:
    """Reference values at one instant: u1d, u̇1d, ü1d (m,) and λd (k,)."""

    u1_d: jax.Array
    u1_d_dot: jax.Array
    u1_d_ddot: jax.Array
    lam_d: jax.Array


def check_references(pairs) -> None:
    """Each reference's sizes against its controller's, before anything is traced: for
    ``(reference, m, k)`` pairs (m motion and k force coordinates), u1d, u̇1d and ü1d must have
    shape (m,) and λd shape (k,) (a scalar is broadcast), or a :class:`~hinfnn.errors.ConfigError`
    at ``reference`` names the sizes. Shapes only (``jax.eval_shape``: nothing is computed), once
    per distinct structure and shapes (the members of a batch share them)."""
    seen = set()
    for ref, m, k in pairs:
        leaves, tree = jax.tree.flatten(ref)
        key = (tree, tuple(np.shape(x) for x in leaves), m, k)
        if key in seen:
            continue
        seen.add(key)
        out = jax.eval_shape(ref, 0.0)
        names = ("u1_d", "u1_d_dot", "u1_d_ddot", "lam_d")
        if not all(hasattr(out, a) for a in names):
            raise ConfigError("must be a callable on t that returns a RefSample (u1_d, u1_d_dot, u1_d_ddot, lam_d), "
                              f"got {type(out).__name__}", key="reference")
        for name in names:
            size = k if name == "lam_d" else m
            shape = tuple(getattr(out, name).shape)
            if shape not in ((), (size,)):
                raise ConfigError(f"gives {name} of shape {shape}, but the controller has m = {m} motion and k = {k} "
                                  f"force coordinates: u1_d, u1_d_dot and u1_d_ddot must have shape ({m},), lam_d "
                                  f"shape ({k},)", key="reference")


@jax.jit
def lam_d_at(ref, t):
    """λd of reference ``ref`` at the times ``t`` (an array), as one compiled program."""
    return jax.vmap(lambda ti: ref(ti).lam_d)(t)


def smoothstep(t, duration):
    """(r, ṙ, r̈) of the quintic ramp r = 10τ³ − 15τ⁴ + 6τ⁵, τ = t / duration clipped to [0, 1]
    (r = 1 for duration 0): it starts and ends with zero slope and curvature."""
    positive = duration > 0
    T = jnp.where(positive, duration, 1.0)
    tau = jnp.clip(t / T, 0.0, 1.0)
    r = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    dr = 30.0 * tau**2 * (1.0 - tau) ** 2 / T
    ddr = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / T**2
    one, zero = jnp.ones_like(r), jnp.zeros_like(r)
    return jnp.where(positive, r, one), jnp.where(positive, dr, zero), jnp.where(positive, ddr, zero)


@pytree_dataclass
class CosineReference:
    """One cosine per coordinate, optionally faded in: for m motion and k force coordinates,

        u1d_i(t) = a_i + r_u(t) b_i cos(ω_i t + φ_i),     λd_j(t) = r_λ(t) (a_j + b_j cos(ω_j t + φ_j))

    with r the quintic ramp of :func:`smoothstep` over ``u1_ramp`` (resp. ``lam_ramp``) seconds (0,
    the default: no ramp, r = 1). Each parameter is an array of shape (m,) for u1 and (k,) for λ.
    Sec. VI: u1d = 1.5 + 0.2 cos πt and λd = 60 − 20 cos πt (:meth:`paper`). The motion ramp
    makes u̇1d(0) = ü1d(0) = 0, so a run that starts at rest on u1d(0) = a has no initial velocity
    error (e.g. a circle: two coordinates with phases 0 and −π/2); the force ramp lets the contact
    force build up from 0. u̇1d and ü1d are exact (the product rule through the ramp; without a
    ramp r = 1, ṙ = r̈ = 0 exactly, so the values are the plain cosine's to the last bit).
    """

    u1_offset: jax.Array
    u1_amplitude: jax.Array
    u1_omega: jax.Array
    u1_phase: jax.Array
    lam_offset: jax.Array
    lam_amplitude: jax.Array
    lam_omega: jax.Array
    lam_phase: jax.Array
    u1_ramp: jax.Array = 0.0
    lam_ramp: jax.Array = 0.0
    kernels: la.Kernels = la.kernels_field()  # how its sines are shared (hinfnn._linalg.Kernels)

    @classmethod
    def paper(cls) -> "CosineReference":
        return cls(
            u1_offset=jnp.array([1.5]),
            u1_amplitude=jnp.array([0.2]),
            u1_omega=jnp.array([jnp.pi]),
            u1_phase=jnp.array([0.0]),
            lam_offset=jnp.array([60.0]),
            lam_amplitude=jnp.array([-20.0]),
            lam_omega=jnp.array([jnp.pi]),
            lam_phase=jnp.array([0.0]),
        )

    def holding(self, values) -> "CosineReference":
        """This reference with more motion coordinates appended, each held at its value of
        ``values`` (offset, no cosine): the extra task coordinates a scenario does not move."""
        held = jnp.asarray(values, dtype=float).reshape(-1)

        def cat(a, fill):
            return jnp.concatenate([jnp.asarray(a, dtype=float), jnp.full(held.shape, fill) if fill is not None
                                    else held])

        return dataclasses.replace(self, u1_offset=cat(self.u1_offset, None), u1_amplitude=cat(self.u1_amplitude, 0.0),
                                   u1_omega=cat(self.u1_omega, 1.0), u1_phase=cat(self.u1_phase, 0.0))

    def __call__(self, t) -> RefSample:
        s, c = self.kernels.sincos(self.u1_omega * t + self.u1_phase)  # computed once and shared (Kernels.sincos)
        _, c_lam = self.kernels.sincos(self.lam_omega * t + self.lam_phase)
        b, w = self.u1_amplitude, self.u1_omega
        wave, dwave, ddwave = b * c, -b * w * s, -b * w**2 * c
        r, dr, ddr = smoothstep(t, self.u1_ramp)
        rl, _, _ = smoothstep(t, self.lam_ramp)
        return RefSample(
            u1_d=self.u1_offset + r * wave,
            u1_d_dot=dr * wave + r * dwave,
            u1_d_ddot=ddr * wave + 2.0 * dr * dwave + r * ddwave,
            lam_d=rl * (self.lam_offset + self.lam_amplitude * c_lam),
        )


def common_period(periods, limit: float) -> float | None:
    """The shortest T > 0 that is a whole number of each of ``periods`` (s; each read as a ratio
    of integers with a denominator up to 10⁶, and checked to 1e-9 relative), or None when there
    is none up to ``limit`` s: the period of a sum of cosines of these periods."""
    periods = [float(p) for p in periods]
    if not periods:
        return None
    ratios = [Fraction(p).limit_denominator(10**6) for p in periods]
    T = float(Fraction(math.lcm(*(r.numerator for r in ratios)), math.gcd(*(r.denominator for r in ratios))))
    if T > limit or any(abs(T / p - round(T / p)) > 1e-9 * T / p for p in periods):
        return None
    return T

