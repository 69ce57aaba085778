"""Tanh networks of eqs. (17)–(19), their update laws (30)–(31), projection (Remark 2).

A network has j hidden units σ_i = tanh(α (φ(z_n) − c_i)) (eq. 17) with fixed centres c_i and
slope α, and adjustable output weights only: F(z, Θ) = Ξ Θ, Ξ = diag(ξᵀ, …, ξᵀ) (eqs. 18–19).
The input map is φ(a, b) = w_aᵀ a + w_bᵀ b, a scalar from the two inputs the paper uses
(F_p: a = e_u1, b = ė_u1; F_f: a = e_λ, b = z); Sec. VI has w_a = w_b = 1.

Θ stacks the per-output weight vectors: Θ = [θ_1; …; θ_n_out], so Ξᵀ s = s ⊗ ξ.

Blocks: the centres, the features ξ and (inside the simulator) the weights are kept in blocks of
at most :data:`BLOCK` units. XLA's CPU runtime runs the kernels of a compiled loop body inline,
one after the other, only when every buffer they touch is at most 512 bytes (64 float64 values);
a single larger array sends every kernel of the simulation step through a thread pool, which
costs about as much as the step's arithmetic (measured on the paper scenario: 1.0 s per 100,000
steps with F_f split 60 + 60, 2.0 s with one 120-unit array). The public methods take and return
the flat Θ; the ``*_blocks`` methods also accept Θ as a tuple of blocks (:meth:`split`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import pytree_dataclass, static_field
from .. import _linalg as la
from ..errors import DesignError

#: Largest number of hidden units kept in one array (see the module docstring).
BLOCK = 64

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
    """One network of eq. (19) with optional projection onto ‖Θ‖ ≤ radius (Remark 2).

    The centres are stored in blocks of at most :data:`BLOCK` units (``centre_blocks``);
    :attr:`centres` is the whole vector.
    """

    centre_blocks: tuple  # of (≤ BLOCK,) arrays, in increasing order
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
        blocks = tuple(jnp.asarray(c[a:b]) for a, b in _block_bounds(c.size))
        return cls(centre_blocks=blocks, slope=jnp.asarray(slope), w_a=jnp.asarray(w_a),
                   w_b=jnp.asarray(w_b), radius=jnp.asarray(np.inf if radius is None else radius),
                   n_out=int(n_out), project=radius is not None)

    @property
    def centres(self) -> jax.Array:
        """All centres c_1 … c_j (the concatenated blocks)."""
        return jnp.concatenate(self.centre_blocks, axis=-1)

    @property
    def n_units(self) -> int:
        """Number of hidden units j."""
        return sum(int(b.shape[-1]) for b in self.centre_blocks)

    @property
    def size(self) -> int:
        """Number of adjustable weights, n_out · j."""
        return self.n_out * self.n_units

    # --- flat Θ (the public form) -------------------------------------------------------------
    def features(self, a, b):
        """ξ = [σ_1 … σ_j], σ_i = tanh(α(φ − c_i)), φ = w_aᵀ a + w_bᵀ b. Implements Eq. (17)."""
        return jnp.concatenate(self.features_blocks(a, b), axis=-1)

    def output(self, xi, theta):
        """F = Ξ Θ, the kth output ξᵀ θ_k. Implements Eqs. (18)–(19)."""
        return theta.reshape(self.n_out, -1) @ xi

    def update(self, xi, s, theta, gamma):
        """Θ̇ = γ Ξᵀ s, projected onto ‖Θ‖ ≤ d when ``project`` (Remark 2).

        Implements Eqs. (30)–(31) with s = B_pᵀ P_p x_p (F_p) or s = e_λ (F_f). The projection
        removes the outward radial part when ‖Θ‖ ≥ d and sᵀ Ξ Θ > 0 (the paper's "= d",
        taken as "≥ d" so that integration round-off cannot step past it).
        """
        return self.join(self.update_blocks(self.split(xi, per_output=False), s, self.split(theta), gamma))

    # --- blocked Θ (what the simulator carries) -------------------------------------------------
    def split(self, theta, per_output: bool = True) -> tuple:
        """Flat Θ (n_out·j,) → tuple of blocks, output by output (θ_1's blocks, then θ_2's …).
        With ``per_output=False`` splits a (j,) vector such as ξ. A tuple is returned as is."""
        if isinstance(theta, tuple):
            return theta
        j = self.n_units
        bounds = _block_bounds(j)
        outs = range(self.n_out) if per_output else range(1)
        return tuple(theta[o * j + a: o * j + b] for o in outs for a, b in bounds)

    @staticmethod
    def join(blocks) -> jax.Array:
        """Tuple of blocks → flat Θ (inverse of :meth:`split`)."""
        return jnp.concatenate(blocks, axis=-1) if isinstance(blocks, tuple) else blocks

    def features_blocks(self, a, b) -> tuple:
        """ξ of eq. (17), one array per centre block."""
        phi = la.mm(jnp.broadcast_to(self.w_a, a.shape), a) + la.mm(jnp.broadcast_to(self.w_b, b.shape), b)
        return tuple(jnp.tanh(self.slope * (phi - c)) for c in self.centre_blocks)

    def output_blocks(self, xi_blocks, theta):
        """F = Ξ Θ (eqs. 18–19) from blocked ξ and flat or blocked Θ."""
        th = self.split(theta)
        nb = len(xi_blocks)
        outs = [sum(jnp.sum(th[o * nb + i] * x) for i, x in enumerate(xi_blocks)) for o in range(self.n_out)]
        return jnp.stack(outs)

    def update_blocks(self, xi_blocks, s, theta, gamma):
        """Eqs. (30)–(31) (with Remark 2's projection) on blocks; returns Θ̇ in Θ's form."""
        th = self.split(theta)
        raw = tuple(gamma * s[o] * x for o in range(self.n_out) for x in xi_blocks)
        if self.project:
            growth = la.mm(s, self.output_blocks(xi_blocks, th))  # sᵀ Ξ Θ
            active = (sq_norm(th) >= self.radius**2) & (growth > 0)
            coef = jnp.where(active, gamma * growth / self.radius**2, 0.0)
            raw = tuple(r - coef * t for r, t in zip(raw, th))
        return raw if isinstance(theta, tuple) else self.join(raw)


def _block_bounds(j: int) -> list[tuple[int, int]]:
    """[(start, stop)] of ⌈j / BLOCK⌉ blocks of near-equal size (120 → 60 + 60)."""
    n = max(1, -(-j // BLOCK))
    edges = [round(i * j / n) for i in range(n + 1)]
    return list(zip(edges[:-1], edges[1:]))


def sq_norm(theta) -> jax.Array:
    """‖Θ‖² of a flat or blocked Θ."""
    if isinstance(theta, tuple):
        return sum(jnp.sum(t * t) for t in theta) if theta else jnp.zeros(())
    return jnp.sum(theta * theta)


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
