"""Tanh networks of eqs. (17)–(19), their update laws (30)–(31), projection (Remark 2).

A network has j hidden units σ_i = tanh(α (φ(z_n) − c_i)) (eq. 17) with fixed centres c_i and
slope α, and adjustable output weights only: F(z, Θ) = Ξ Θ, Ξ = diag(ξᵀ, …, ξᵀ) (eqs. 18–19).
The input map is φ(a, b) = w_aᵀ a + w_bᵀ b, a scalar from the two inputs the paper uses
(F_p: a = e_u1, b = ė_u1; F_f: a = e_λ, b = z); Sec. VI has w_a = w_b = 1.

Θ stacks the per-output weight vectors: Θ = [θ_1; …; θ_n_out], so Ξᵀ s = s ⊗ ξ.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import pytree_dataclass, static_field
from ..errors import DesignError

#: F_f centre presets (NOTES.md, "F_f centre step"): (first centre, step, count).
#: The printed step 0.05 spans −30 … −24.05, so for ordinary inputs every unit saturates at +1
#: and the network degenerates into a single integrator; 0.5 spans −30 … 29.5.
CENTRE_PRESETS_F = {
    "paper-printed": (-30.0, 0.05, 120),
    "paper-likely": (-30.0, 0.5, 120),
}
#: F_p centres of Sec. VI: c_1 = −1, step 0.05, 40 units (−1 … 0.95).
CENTRES_P = (-1.0, 0.05, 40)


def centres_from(start: float, step: float, count: int) -> np.ndarray:
    """c_1 = start, c_{i+1} = c_i + step, i = 1 … count − 1 (Sec. VI)."""
    return start + step * np.arange(int(count), dtype=float)


@pytree_dataclass
class TanhNetwork:
    """One network of eq. (19) with optional projection onto ‖Θ‖ ≤ radius (Remark 2)."""

    centres: jax.Array  # (j,)
    slope: jax.Array  # α of eq. (17)
    w_a: jax.Array  # (dim,) weights of the first input in φ
    w_b: jax.Array  # (dim,) weights of the second input in φ
    radius: jax.Array  # d_p or d_f of Remark 2 (used when ``project``)
    n_out: int = static_field(default=1)
    project: bool = static_field(default=False)

    @classmethod
    def build(cls, centres, *, n_out: int = 1, slope: float = 1.0, w_a=1.0, w_b=1.0,
              radius: float | None = None, name: str = "network") -> "TanhNetwork":
        """Validate and build. ``radius=None`` disables the projection."""
        c = np.asarray(centres, dtype=float).ravel()
        if c.size == 0:
            raise DesignError("needs at least one centre", key=f"{name}.centres")
        if not np.all(np.isfinite(c)):
            raise DesignError("centres must be finite", key=f"{name}.centres", value=c.tolist())
        if c.size > 1 and not np.all(np.diff(c) > 0):
            raise DesignError("centres must be strictly increasing", key=f"{name}.centres",
                              value=c.tolist())
        slope = float(slope)
        if not (np.isfinite(slope) and slope > 0):
            raise DesignError(f"slope must be finite and > 0, got {slope:g}", key=f"{name}.slope",
                              value=slope, bound=0.0)
        w_a = np.atleast_1d(np.asarray(w_a, dtype=float))
        w_b = np.atleast_1d(np.asarray(w_b, dtype=float))
        for key, w in (("w_a", w_a), ("w_b", w_b)):
            if not np.all(np.isfinite(w)):
                raise DesignError("input weights must be finite", key=f"{name}.{key}", value=w.tolist())
        if radius is not None:
            radius = float(radius)
            if not (np.isfinite(radius) and radius > 0):
                raise DesignError(f"projection radius must be finite and > 0, got {radius:g}",
                                  key=f"{name}.radius", value=radius, bound=0.0)
        return cls(centres=jnp.asarray(c), slope=jnp.asarray(slope), w_a=jnp.asarray(w_a),
                   w_b=jnp.asarray(w_b), radius=jnp.asarray(np.inf if radius is None else radius),
                   n_out=int(n_out), project=radius is not None)

    @property
    def size(self) -> int:
        """Number of adjustable weights, n_out · j."""
        return self.n_out * int(self.centres.shape[-1])

    def features(self, a, b):
        """ξ = [σ_1 … σ_j], σ_i = tanh(α(φ − c_i)), φ = w_aᵀ a + w_bᵀ b. Implements Eq. (17)."""
        phi = jnp.dot(self.w_a, a) + jnp.dot(self.w_b, b)
        return jnp.tanh(self.slope * (phi - self.centres))

    def output(self, xi, theta):
        """F = Ξ Θ, the kth output ξᵀ θ_k. Implements Eqs. (18)–(19)."""
        return theta.reshape(self.n_out, -1) @ xi

    def update(self, xi, s, theta, gamma):
        """Θ̇ = γ Ξᵀ s, projected onto ‖Θ‖ ≤ d when ``project`` (Remark 2).

        Implements Eqs. (30)–(31) with s = B_pᵀ P_p x_p (F_p) or s = e_λ (F_f). The projection
        removes the outward radial part when ‖Θ‖ ≥ d and sᵀ Ξ Θ > 0 (the paper's "= d",
        taken as "≥ d" so that integration round-off cannot step past it).
        """
        raw = gamma * jnp.kron(s, xi)
        if not self.project:
            return raw
        growth = jnp.dot(s, self.output(xi, theta))  # sᵀ Ξ Θ
        active = (jnp.dot(theta, theta) >= self.radius**2) & (growth > 0)
        return raw - jnp.where(active, gamma * growth / self.radius**2, 0.0) * theta


def paper_network_p(**overrides) -> TanhNetwork:
    """F_p of Sec. VI: tanh(e_u1 + ė_u1 − c_i), 40 centres from −1 by 0.05."""
    kwargs = dict(centres=centres_from(*CENTRES_P), name="network_p")
    kwargs.update(overrides)
    return TanhNetwork.build(**kwargs)


def paper_network_f(preset: str = "paper-likely", **overrides) -> TanhNetwork:
    """F_f of Sec. VI: tanh(e_λ + z − c_i), 120 centres from −30, step by ``preset``."""
    if preset not in CENTRE_PRESETS_F:
        raise DesignError(f"unknown centre preset {preset!r}; allowed: {sorted(CENTRE_PRESETS_F)}",
                          key="network_f.preset", value=preset)
    kwargs = dict(centres=centres_from(*CENTRE_PRESETS_F[preset]), name="network_f")
    kwargs.update(overrides)
    return TanhNetwork.build(**kwargs)
