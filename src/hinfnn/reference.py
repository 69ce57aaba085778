"""Desired trajectories u1d(t) and λd(t) (paper Sec. IV objectives, Sec. VI values).

A reference is a pytree callable on t returning a :class:`RefSample` with u1d, u̇1d, ü1d and λd.
Controllers and the simulator evaluate it; both import it from here (not from each other).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from . import _linalg as la
from ._pytree import pytree_dataclass


@pytree_dataclass
class RefSample:
    """Reference values at one instant: u1d, u̇1d, ü1d (m,) and λd (k,)."""

    u1_d: jax.Array
    u1_d_dot: jax.Array
    u1_d_ddot: jax.Array
    lam_d: jax.Array


@pytree_dataclass
class CosineReference:
    """u1d(t) = a_u + b_u cos(ω_u t + φ_u),  λd(t) = a_λ + b_λ cos(ω_λ t + φ_λ).

    Sec. VI: u1d = 1.5 + 0.2 cos πt and λd = 60 − 20 cos πt (:meth:`paper`).
    Each parameter is an array of shape (m,) for u1 and (k,) for λ (scalars for the planar case).
    """

    u1_offset: jax.Array
    u1_amplitude: jax.Array
    u1_omega: jax.Array
    u1_phase: jax.Array
    lam_offset: jax.Array
    lam_amplitude: jax.Array
    lam_omega: jax.Array
    lam_phase: jax.Array

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

    def __call__(self, t) -> RefSample:
        arg = self.u1_omega * t + self.u1_phase
        s, c = la.sincos(arg)  # computed once and shared, see hinfnn._linalg.sincos
        _, c_lam = la.sincos(self.lam_omega * t + self.lam_phase)
        return RefSample(
            u1_d=self.u1_offset + self.u1_amplitude * c,
            u1_d_dot=-self.u1_amplitude * self.u1_omega * s,
            u1_d_ddot=-self.u1_amplitude * self.u1_omega**2 * c,
            lam_d=self.lam_offset + self.lam_amplitude * c_lam,
        )
