"""Tanh networks of eqs. (17)–(19), their update laws (30)–(31), projection (Remark 2).

A network has j hidden units σ_i = tanh(α (φ(z_n) − c_i)) (eq. 17) with fixed centres c_i and
slope α, and adjustable output weights only: F(z, Θ) = Ξ Θ, Ξ = diag(ξᵀ, …, ξᵀ) (eqs. 18–19).
The input map is φ(a, b) = w_aᵀ a + w_bᵀ b, a scalar from the two inputs the paper uses
(F_p: a = e_u1, b = ė_u1; F_f: a = e_λ, b = z); Sec. VI has w_a = w_b = 1. Every output shares
the hidden layer ξ (eq. 19).

Θ stacks the per-output weight vectors: Θ = [θ_1; …; θ_n_out], so Ξᵀ s = s ⊗ ξ.

A network holds flat arrays (centres, slope, input weights) and its public methods
(:meth:`~TanhNetwork.features`, :meth:`~TanhNetwork.output`, :meth:`~TanhNetwork.update`) take and
return flat arrays. The controller carries Θ in blocks of at most ``block`` values inside the
compiled loop (:func:`split`; :class:`hinfnn.controllers.law.ReducedOrderController`, ``block``:
XLA's CPU runtime runs a loop body's kernels inline only when no kernel touches a buffer of more
than 512 bytes, 64 float64, and one larger buffer sends the step's kernels through its thread
pool, which cost about as much as the step's arithmetic); the ``*_blocks`` methods, used by the
network terms of :mod:`hinfnn.controllers.terms`, take Θ in that layout, cut the centres the same
way (read off Θ's blocks) and return the same layout.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .. import _linalg as la
from .._pytree import pytree_dataclass, static_field
from ..errors import DesignError

#: F_f centre presets of the paper's Sec. VI: (first centre, step, count). The printed step 0.05
#: spans −30 … −24.05, so for ordinary inputs every unit saturates at +1 and the network
#: degenerates into a single integrator; 0.5 spans −30 … 29.5 (docs/paper-conventions.md).
CENTRE_PRESETS_F = {
    "paper-printed": (-30.0, 0.05, 120),
    "paper-likely": (-30.0, 0.5, 120),
}
#: F_p centres of Sec. VI: c_1 = −1, step 0.05, 40 units (−1 … 0.95).
CENTRES_P = (-1.0, 0.05, 40)


def centres_from(start: float, step: float, count: int) -> np.ndarray:
    """c_1 = start, c_{i+1} = c_i + step, i = 1 … count − 1 (Sec. VI)."""
    return start + step * np.arange(int(count), dtype=float)


def block_bounds(j: int, block: int | None) -> list[tuple[int, int]]:
    """[(start, stop)] of ⌈j / block⌉ blocks of near-equal size (120 → 60 + 60 for block 64); one
    block when ``block`` is None or 0."""
    n = max(1, -(-j // block)) if block else 1
    edges = [round(i * j / n) for i in range(n + 1)]
    return list(zip(edges[:-1], edges[1:]))


def split(x, groups: int = 1, block: int | None = None) -> tuple:
    """A flat vector as a tuple of blocks: ``groups`` equal consecutive parts (one per network
    output), each cut by :func:`block_bounds`."""
    j = x.shape[-1] // groups
    return tuple(x[..., g * j + a: g * j + b] for g in range(groups) for a, b in block_bounds(j, block))


def join(blocks: tuple):
    """Inverse of :func:`split`."""
    return jnp.concatenate(blocks, axis=-1)


def _bounds(sizes) -> tuple:
    """[(start, stop)] of consecutive blocks of the given sizes."""
    edges = np.cumsum([0, *sizes])
    return tuple(zip(edges[:-1].tolist(), edges[1:].tolist()))


class _Network:
    """What both network forms share: their sizes, the centre blocks matching a blocked Θ, and
    Remark 2's clip (subclasses hold ``centres`` with the units on the last axis, ``n_out``,
    ``project`` and ``radius``)."""

    #: How a network's products are written (:class:`hinfnn._linalg.Kernels`; the networks here hold
    #: it as a static field, set by the program that traces them)
    kernels = la.DEFAULT

    @property
    def n_units(self) -> int:
        """Hidden units (per output), j."""
        return int(self.centres.shape[-1])

    @property
    def size(self) -> int:
        """Number of adjustable weights, n_out · j."""
        return self.n_out * self.n_units

    def with_centre_blocks(self, bounds) -> "_Network":
        """This network with its centres also held as the blocks ``bounds`` (:meth:`layout`) of
        every output: taken outside a compiled loop (:meth:`ReducedOrderController.prepared`), so
        the loop reads blocks of at most 64 values and never the whole array (XLA's CPU runtime
        runs a loop body's kernels one after the other, without its scheduler, only when no
        kernel touches more than 512 bytes)."""
        bounds = tuple((int(lo), int(hi)) for lo, hi in bounds)
        rows = self.centres.reshape((-1, self.n_units))
        blocks = tuple(rows[o, lo:hi] for o in range(rows.shape[0]) for lo, hi in bounds)
        return dataclasses.replace(self, centre_blocks=blocks, centre_bounds=bounds)

    def _centres(self, o: int, lo: int, hi: int):
        """Output o's centres lo … hi − 1 (a kept block when :meth:`with_centre_blocks` made it)."""
        if self.centre_blocks is not None and (lo, hi) in self.centre_bounds:
            return self.centre_blocks[o * len(self.centre_bounds) + self.centre_bounds.index((lo, hi))]
        return self.centres.reshape((-1, self.n_units))[o, lo:hi]

    def layout(self, theta_blocks) -> tuple:
        """[(start, stop)] of one output's centre blocks matching a blocked Θ."""
        nb = len(theta_blocks) // self.n_out
        return _bounds(int(t.shape[-1]) for t in theta_blocks[:nb])

    def clip_blocks(self, theta_blocks) -> tuple:
        """Θ put back on the ball ‖Θ‖ ≤ d if an integration step overshot it (Remark 2; the
        identity without projection). The projected flow is tangent to the sphere, but its switch
        at ‖Θ‖ = d lets a fixed step cross by O(dt); the radial clip makes ‖Θ̂(t)‖ ≤ d hold
        exactly and only shrinks the storage function."""
        if not self.project:
            return theta_blocks
        scale = jnp.minimum(1.0, self.radius / jnp.maximum(jnp.sqrt(sq_norm(theta_blocks)), 1e-300))
        return tuple(t * scale for t in theta_blocks)


@pytree_dataclass
class TanhNetwork(_Network):
    """One network of eq. (19) with optional projection onto ‖Θ‖ ≤ radius (Remark 2).

    Build it with :meth:`build`.
    """

    centres: jax.Array  # (j,), increasing
    slope: jax.Array  # α of eq. (17)
    w_a: jax.Array  # (1,) or (n_out,) weights of the first input in φ
    w_b: jax.Array  # (1,) or (n_out,) weights of the second input in φ
    radius: jax.Array  # d_p or d_f of Remark 2 (used when ``project``)
    n_out: int = static_field(default=1)
    project: bool = static_field(default=False)
    centre_blocks: tuple | None = None  # the centres by blocks, for a compiled loop (with_centre_blocks)
    centre_bounds: tuple = static_field(default=())
    kernels: la.Kernels = la.kernels_field()  # how its products are written (hinfnn._linalg.Kernels)

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

    # --- flat arrays (the public form) ------------------------------------------------------------
    def features(self, a, b):
        """ξ = [σ_1 … σ_j], σ_i = tanh(α(φ − c_i)), φ = w_aᵀ a + w_bᵀ b. Implements eq. (17)."""
        return self.features_blocks(a, b, ((0, self.n_units),))[0]

    def output(self, xi, theta):
        """F = Ξ Θ, output o = ξ_oᵀ θ_o. Implements eqs. (18)–(19)."""
        return self.output_blocks((xi,), split(theta, self.n_out))

    def update(self, xi, s, theta, gamma):
        """Θ̇ = γ Ξᵀ s, projected onto ‖Θ‖ ≤ d when ``project`` (Remark 2).

        Implements eqs. (30)–(31) with s = B_pᵀ P_p x_p (F_p) or s = e_λ (F_f). The projection
        removes the outward radial part when ‖Θ‖ ≥ d and sᵀ Ξ Θ > 0 (the paper's "= d",
        taken as "≥ d" so that integration round-off cannot step past it).
        """
        return join(self.update_blocks((xi,), s, split(theta, self.n_out), gamma))

    # --- blocks (inside the compiled loop) ---------------------------------------------------------

    def features_blocks(self, a, b, bounds) -> tuple:
        """ξ of eq. (17), one array per centre block ``bounds`` (:meth:`layout`)."""
        mm = self.kernels.mm
        phi = mm(jnp.broadcast_to(self.w_a, a.shape), a) + mm(jnp.broadcast_to(self.w_b, b.shape), b)
        return tuple(jnp.tanh(self.slope * (phi - self._centres(0, lo, hi))) for lo, hi in bounds)

    def output_blocks(self, xi_blocks, theta_blocks):
        """F = Ξ Θ (eqs. 18–19) from blocked ξ and blocked Θ."""
        nb = len(xi_blocks)
        outs = [sum(jnp.sum(theta_blocks[o * nb + i] * x) for i, x in enumerate(xi_blocks))
                for o in range(self.n_out)]
        return jnp.stack(outs)

    def update_blocks(self, xi_blocks, s, theta_blocks, gamma) -> tuple:
        """Eqs. (30)–(31) (with Remark 2's projection) on blocks; returns Θ̇ as blocks."""
        raw = tuple(gamma * s[o] * x for o in range(self.n_out) for x in xi_blocks)
        return _projected(self, raw, xi_blocks, s, theta_blocks, gamma)


def sq_norm(blocks) -> jax.Array:
    """‖Θ‖² of a blocked Θ (a tuple of arrays)."""
    return sum(jnp.sum(t * t) for t in blocks) if blocks else jnp.zeros(())


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


@pytree_dataclass
class CoordinateNetwork(_Network):
    """Networks of eqs. (17)–(19) for m, k > 1: one output per coordinate, each with its OWN
    hidden layer on its own coordinate's inputs.

    Output o: F_o = ξ_oᵀ θ_o with ξ_o,i = tanh(α_o (φ_o − c_o,i)), φ_o = w_a,o a_o + w_b,o b_o
    (F_p: a = e_u1, b = ė_u1; F_f: a = e_λ, b = z, coordinate by coordinate). Stacked, F = Ξ Θ
    with Ξ = diag(ξ_1ᵀ, …, ξ_nᵀ) and Θ = [θ_1; …; θ_n]: still linear in Θ, so the update laws
    (30)–(31) Θ̇ = γ Ξᵀ s (θ̇_o = γ s_o ξ_o) and Remark 2's projection keep Theorem 1's proof.
    (:class:`TanhNetwork` shares one hidden layer driven by the sum over coordinates, which for
    m > 1 mixes unrelated errors.) Every output has the same number of units j; centres
    (n_out, j), slopes and input weights (n_out,) are per coordinate.

    Same interface as :class:`TanhNetwork` (flat public arrays; blocks inside the loop), so the
    network terms of :mod:`hinfnn.controllers.terms` use it unchanged.
    """

    centres: jax.Array  # (n_out, j)
    slope: jax.Array  # (n_out,)
    w_a: jax.Array  # (n_out,)
    w_b: jax.Array  # (n_out,)
    radius: jax.Array
    n_out: int = static_field(default=1)
    project: bool = static_field(default=False)
    centre_blocks: tuple | None = None  # the centres by blocks, for a compiled loop (with_centre_blocks)
    centre_bounds: tuple = static_field(default=())
    kernels: la.Kernels = la.kernels_field()  # how its products are written (hinfnn._linalg.Kernels)

    @classmethod
    def build(cls, centres, *, slope=1.0, w_a=1.0, w_b=1.0, radius: float | None = None,
              name: str = "network") -> "CoordinateNetwork":
        """``centres``: (n_out, j) (each row strictly increasing); ``slope``, ``w_a``, ``w_b``:
        a number or one per output. Raises DesignError naming ``name``'s key."""
        c = np.asarray(centres, dtype=float)
        if c.ndim != 2 or c.shape[1] == 0:
            raise DesignError(f"needs a (outputs, units) array of centres, got shape {c.shape}", key=f"{name}.centres")
        n_out = c.shape[0]
        if not np.all(np.isfinite(c)):
            raise DesignError("centres must be finite", key=f"{name}.centres", value=c.tolist())
        if c.shape[1] > 1 and not np.all(np.diff(c, axis=1) > 0):
            raise DesignError("centres must be strictly increasing", key=f"{name}.centres", value=c.tolist())

        def per_output(key, v, positive):
            a = np.atleast_1d(np.asarray(v, dtype=float))
            if a.size == 1:
                a = np.full(n_out, float(a[0]))
            if a.shape != (n_out,):
                raise DesignError(f"must be a number or a list of {n_out} (one per coordinate), got {a.tolist()}",
                                  key=f"{name}.{key}", value=a.tolist())
            if not np.all(np.isfinite(a)) or (positive and not np.all(a > 0)):
                raise DesignError(f"must be finite{' and > 0' if positive else ''}, got {a.tolist()}",
                                  key=f"{name}.{key}", value=a.tolist(), bound=0.0 if positive else None)
            return jnp.asarray(a)

        slope_a = per_output("slope", slope, True)
        w_a_a, w_b_a = per_output("w_a", w_a, False), per_output("w_b", w_b, False)
        if radius is not None:
            radius = float(radius)
            if not (np.isfinite(radius) and radius > 0):
                raise DesignError(f"projection radius must be finite and > 0, got {radius:g}",
                                  key=f"{name}.radius", value=radius, bound=0.0)
        return cls(centres=jnp.asarray(c), slope=slope_a, w_a=w_a_a, w_b=w_b_a,
                   radius=jnp.asarray(np.inf if radius is None else radius), n_out=n_out,
                   project=radius is not None)

    # flat arrays -----------------------------------------------------------------------------
    def features(self, a, b):
        """Ξ's rows ξ_o (n_out, j), eq. (17) per coordinate."""
        whole = ((0, self.n_units),)
        return jnp.stack([self._xi_out(a, b, o, whole)[0] for o in range(self.n_out)])

    def output(self, xi, theta):
        """F_o = ξ_oᵀ θ_o, eq. (19)."""
        return jnp.sum(xi * theta.reshape(self.n_out, -1), axis=1)

    def update(self, xi, s, theta, gamma):
        """θ̇_o = γ s_o ξ_o, eqs. (30)–(31), with Remark 2's projection (flat Θ)."""
        return join(self.update_blocks(tuple(xi[o] for o in range(self.n_out)), s, split(theta, self.n_out), gamma))

    # blocks (inside the compiled loop) ---------------------------------------------------------
    def _xi_out(self, a, b, o, bounds):
        phi = self.w_a[o] * a[o] + self.w_b[o] * b[o]
        return tuple(jnp.tanh(self.slope[o] * (phi - self._centres(o, lo, hi))) for lo, hi in bounds)

    def features_blocks(self, a, b, bounds) -> tuple:
        """ξ_o of eq. (17), output by output, block by block (``bounds``: :meth:`layout`)."""
        return tuple(x for o in range(self.n_out) for x in self._xi_out(a, b, o, bounds))

    def output_blocks(self, xi_blocks, theta_blocks):
        nb = len(theta_blocks) // self.n_out
        return jnp.stack([sum(jnp.sum(theta_blocks[o * nb + i] * xi_blocks[o * nb + i]) for i in range(nb))
                          for o in range(self.n_out)])

    def update_blocks(self, xi_blocks, s, theta_blocks, gamma) -> tuple:
        nb = len(theta_blocks) // self.n_out
        raw = tuple(gamma * s[o] * xi_blocks[o * nb + i] for o in range(self.n_out) for i in range(nb))
        return _projected(self, raw, xi_blocks, s, theta_blocks, gamma)


def integral_gain(net, gamma_2, e_lam: float = 0.0, z: float = 0.0) -> float:
    """g_f = γ2‖ξ_f(e_λ, z)‖²: the force network F_f of eq. (31) at Θ̂_f = 0 is an integral action
    of this gain on e_λ, at the inputs (e_λ, z) (every constraint's); the largest over the outputs
    and over γ2's entries; 0 without a network (``net`` None). Design-time (NumPy)."""
    if net is None:
        return 0.0
    k = net.n_out
    xi = np.atleast_2d(np.asarray(net.features(jnp.full(k, float(e_lam)), jnp.full(k, float(z))), dtype=float))
    return float(np.max(np.asarray(gamma_2, dtype=float))) * max(float(row @ row) for row in xi)


#: Remark 2's projection acts from ‖Θ‖² ≥ (1 − this) d²: the radial clip leaves Θ on the sphere to
#: the rounding of ‖Θ‖, and a test at d² exactly would switch the projection on or off by that
#: rounding (two compiled programs of the same law, a run and a batch member, then part ways). Acting
#: this little inside the ball only removes an outward part sooner: the storage still only shrinks.
PROJECTION_BAND = 1e-9


def _projected(net, raw, xi_blocks, s, theta_blocks, gamma) -> tuple:
    """Remark 2's projection of the update Θ̇ = ``raw`` (blocks) of either network: on the ball's
    boundary ‖Θ‖ ≥ d (to :data:`PROJECTION_BAND`) with sᵀΞΘ > 0, the outward part γ (sᵀΞΘ/d²) Θ is
    removed."""
    if not net.project:
        return raw
    growth = net.kernels.mm(s, net.output_blocks(xi_blocks, theta_blocks))  # sᵀ Ξ Θ
    active = (sq_norm(theta_blocks) >= (1.0 - PROJECTION_BAND) * net.radius**2) & (growth > 0)
    coef = jnp.where(active, gamma * growth / net.radius**2, 0.0)
    return tuple(r - coef * t for r, t in zip(raw, theta_blocks))


@pytree_dataclass
class Adaptation:
    """The robust modification of a network's update law (30) or (31) against measurement noise
    (not in the paper; docs/beyond-the-paper.md, section 11):

        Θ̂̇ = γ g(s) Ξᵀ s − ℓ(s) Θ̂,   g(s) = max(0, 1 − d/‖s‖),   ℓ(s) = σ + ν ‖s‖,

    then Remark 2's projection of the first part when the network has a radius. ``zone`` is the
    dead zone's width d on ‖s‖ (the update stops while ‖s‖ ≤ d and grows continuously from its
    edge), ``leak`` is σ-modification's leakage σ (1/s) and ``e_gain`` e-modification's ν (1/s per
    unit of ‖s‖). ``noise`` is the RMS of the drive s from the sensor's noise alone, the scale the
    design sized d and ν from (a record). With every parameter 0 this is eq. (30)/(31) itself.
    Every parameter is data: the options share one compiled program."""

    zone: jax.Array
    leak: jax.Array
    e_gain: jax.Array
    noise: jax.Array
    kernels: la.Kernels = la.kernels_field()  # how its products are written (hinfnn._linalg.Kernels)

    @classmethod
    def make(cls, zone: float = 0.0, leak: float = 0.0, e_gain: float = 0.0, noise: float = 0.0,
             name: str = "controller.adaptation") -> "Adaptation":
        """Validate (finite, ≥ 0; DesignError naming the key) and build."""
        values = dict(zone=zone, leak=leak, e_gain=e_gain, noise=noise)
        for key, v in values.items():
            v = float(v)
            if not (np.isfinite(v) and v >= 0):
                raise DesignError(f"must be finite and >= 0, got {v:g}", key=f"{name}.{key}", value=v, bound=0.0)
        return cls(**{k: jnp.asarray(float(v)) for k, v in values.items()})

    def gate(self, s):
        """g(s) = max(0, 1 − d/‖s‖): 0 inside the dead zone ‖s‖ ≤ d, → 1 far outside it; 1 for d = 0."""
        ns = jnp.sqrt(self.kernels.mm(s, s))
        return jnp.where(ns > self.zone, 1.0 - self.zone / jnp.maximum(ns, 1e-300), 0.0)

    def rate(self, s):
        """ℓ(s) = σ + ν ‖s‖, the leakage rate (1/s)."""
        return self.leak + self.e_gain * jnp.sqrt(self.kernels.mm(s, s))

    def update_blocks(self, net, xi_blocks, s, theta_blocks, gamma) -> tuple:
        """Θ̂̇ of eq. (30) or (31) with the dead zone, the leakage and Remark 2's projection, on
        blocks. Implements eqs. (30)–(31) modified (docs/beyond-the-paper.md, section 11)."""
        driven = net.update_blocks(xi_blocks, self.gate(s) * s, theta_blocks, gamma)
        ell = self.rate(s)
        return tuple(d - ell * t for d, t in zip(driven, theta_blocks))

    def storage_rate(self, net, xi_blocks, s, theta_blocks, gamma, weight):
        """(D, S): what the modification does to the storage w‖Θ̂‖² (w = ``weight``) of eq. (36).
        With eq. (30)/(31), d/dt w‖Θ̂‖² = 2wγ sᵀΞΘ̂ cancels the network's cross term in V̇ (37)–(38);
        with the modification d/dt w‖Θ̂‖² = 2wγ g sᵀΞΘ̂ − 2wℓ‖Θ̂‖² (− the projection's removal), so V̇
        gains −D, D = 2wℓ‖Θ̂‖² ≥ 0 (dissipation: the stricter inequality), and the uncancelled
        2wγ(1 − g) sᵀΞΘ̂, bounded by S = 2wγ (1 − g)‖s‖ ‖ΞΘ̂‖ = 2wγ min(‖s‖, d) ‖ΞΘ̂‖ ≥ 0: a supply the
        dead zone adds (zero outside it and for d = 0)."""
        ns = jnp.sqrt(self.kernels.mm(s, s))
        out = net.output_blocks(xi_blocks, theta_blocks)
        D = 2.0 * weight * self.rate(s) * sq_norm(theta_blocks)
        S = 2.0 * weight * gamma * jnp.minimum(ns, self.zone) * jnp.sqrt(self.kernels.mm(out, out))
        return D, S
