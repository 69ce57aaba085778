"""The robot's sensor and motors as part of the truth: what a real arm measures and applies.

A controller sees the plant only through a :class:`~hinfnn.protocols.Measurement`; a real
force/torque sensor and real encoders give it late, low-passed and noisy, and real motors apply
the torque asked for only up to their limits. Both are the plant's (``plant.sensor``,
``plant.actuator``: :class:`hinfnn.protocols.Plant`), so every plant has them the same way, and
the simulator applies them at the seam (:mod:`hinfnn.sim.simulate`):

* :class:`Sensor`: at each control sample k (period T), the true measurement (q, q̇, F) is
  acquired as

      F_s(k) = F_lp(k) + b + σ_F ν_F(k),   q_s(k) = q(k) + σ_q ν_q(k),   q̇_s(k) = q̇(k) + σ_q̇ ν_q̇(k),

  F_lp the sensor's own first-order low-pass (bandwidth f_c, Hz; none: F_lp = F), discretised
  exactly for a sample-and-hold input, F_lp(k) = F_lp(k−1) + (1 − e^{−2π f_c T})(F(k) − F_lp(k−1)),
  started at the force of t = 0; b a constant bias in the base frame; ν independent standard
  normal draws, white from sample to sample (one draw per sample: ``jax.random`` with the key of
  the sensor's seed and stream, folded with the sample index k, so a run is reproducible and a
  batch member or a sweep's draw with its own stream has its own noise). The controller gets the
  acquisition of sample k − d (``delay`` d whole samples of transport delay on all three; the
  samples before the first are the acquisition of t = 0, as a sensor reading the arm at rest).
* :class:`Actuator`: the commanded torque τ_c is saturated at the joints' limits τ_max, with its
  change from one sample to the next at most r T (``rate_limit`` r, N·m/s; the first sample is
  not rate-limited: the motors hold the arm at the start), and the joints have friction the
  controller does not know, τ_f = b_v q̇ + f_c tanh(q̇ / v_s) (viscous and Coulomb, the sign of q̇
  smoothed over |q̇| ≲ v_s, as the tool's friction along the surface is): the plant is driven by
  τ_a − τ_f, τ_a the applied (saturated) torque.

None of this is the paper's (its sensor is ideal and its motors unlimited): an ideal sensor and
actuator are ``None``, and a plant without them runs the same program as before they existed.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from .._pytree import pytree_dataclass, static_field
from ..protocols import Measurement


@pytree_dataclass
class SensorState:
    """What a :class:`Sensor` carries from sample to sample: the last ``delay + 1`` acquisitions
    (oldest first), the low-pass filter's state and the measurement the controller was last given."""

    buffer: Measurement
    filtered: jax.Array
    out: Measurement


@pytree_dataclass
class Sensor:
    """A robot's joint encoders and tool force/torque sensor (module docstring).

    ``key``: the PRNG key data of the noise stream (``jax.random.key_data``; :meth:`make` from a
    seed, :meth:`stream` for a batch member's or a sweep draw's own stream); ``force_noise``
    σ_F (N, per axis), ``force_bias`` b (N, base frame, as the force), ``q_noise`` and
    ``qd_noise`` (rad or m, and per s), ``bandwidth`` f_c (Hz; inf: none); ``delay`` d (whole
    samples, static: the buffer's size)."""

    key: jax.Array
    force_noise: jax.Array
    force_bias: jax.Array
    q_noise: jax.Array
    qd_noise: jax.Array
    bandwidth: jax.Array
    delay: int = static_field(default=0)

    @classmethod
    def make(cls, seed: int, *, force_noise=0.0, force_bias=0.0, q_noise=0.0, qd_noise=0.0, bandwidth=math.inf,
             delay: int = 0) -> "Sensor":
        """The sensor of stream 0 of ``seed``."""
        f64 = jnp.float64
        return cls(key=jax.random.key_data(jax.random.PRNGKey(int(seed))), force_noise=jnp.asarray(force_noise, f64),
                   force_bias=jnp.asarray(force_bias, f64), q_noise=jnp.asarray(q_noise, f64),
                   qd_noise=jnp.asarray(qd_noise, f64), bandwidth=jnp.asarray(bandwidth, f64), delay=int(delay))

    def stream(self, *indices) -> "Sensor":
        """The same sensor with its own noise stream: the key folded with each of ``indices`` (a
        batch member's index, a sweep's grid point and draw)."""
        key = jax.random.wrap_key_data(jnp.asarray(self.key, dtype=jnp.uint32))
        for i in indices:
            key = jax.random.fold_in(key, int(i))
        return Sensor(key=jax.random.key_data(key), force_noise=self.force_noise, force_bias=self.force_bias,
                      q_noise=self.q_noise, qd_noise=self.qd_noise, bandwidth=self.bandwidth, delay=self.delay)

    def start(self, meas: Measurement) -> SensorState:
        """The state before the first sample: every slot of the buffer and the filter at the
        measurement of t = 0."""
        buffer = jax.tree.map(lambda x: jnp.broadcast_to(x, (self.delay + 1, *jnp.shape(x))), meas)
        return SensorState(buffer=buffer, filtered=jnp.asarray(meas.force), out=meas)

    def noise(self, k, shapes):
        """The standard normal draws of sample ``k`` (ν_q, ν_q̇, ν_F), of ``shapes``."""
        key = jax.random.fold_in(jax.random.wrap_key_data(jnp.asarray(self.key, dtype=jnp.uint32)), k)
        return tuple(jax.random.normal(sub, shape, dtype=jnp.float64)
                     for sub, shape in zip(jax.random.split(key, 3), shapes))

    def read(self, k, period, meas: Measurement, state: SensorState):
        """(what the controller measures at sample ``k``, the state after it) from the true
        measurement ``meas`` at the sample instant; ``period``: the sampling period T, s."""
        a = 1.0 - jnp.exp(-2.0 * jnp.pi * self.bandwidth * period)
        filtered = jnp.where(jnp.isinf(self.bandwidth), meas.force, state.filtered + a * (meas.force - state.filtered))
        nu_q, nu_qd, nu_f = self.noise(k, (jnp.shape(meas.q), jnp.shape(meas.qd), jnp.shape(meas.force)))
        acquired = Measurement(q=meas.q + self.q_noise * nu_q, qd=meas.qd + self.qd_noise * nu_qd,
                               force=filtered + self.force_bias + self.force_noise * nu_f)
        buffer = jax.tree.map(lambda b, x: jnp.concatenate([b[1:], x[None]], axis=0), state.buffer, acquired)
        out = jax.tree.map(lambda b: b[0], buffer)
        return out, SensorState(buffer=buffer, filtered=filtered, out=out)

    def upcoming(self, state: SensorState) -> Measurement:
        """What :meth:`read` will give at the next sample, known from ``state`` before that sample is
        acquired when the delay d is one sample or more (the buffer's second-oldest acquisition): a
        robot publishes it at the sample's instant and acquires the sample afterwards
        (:mod:`hinfnn.robot.virtual`). With d = 0 the next reading is the next acquisition itself."""
        if self.delay < 1:
            raise ValueError("a sensor without delay gives its next reading only once it is acquired")
        return jax.tree.map(lambda b: b[1], state.buffer)


@pytree_dataclass
class Actuator:
    """A robot's motors (module docstring): ``torque_limit`` τ_max per joint (N·m; inf: none),
    ``rate_limit`` r per joint (N·m/s; inf: none), joint friction ``viscous`` b_v (N·m·s/rad) and
    ``coulomb`` f_c (N·m) per joint, smoothed over |q̇| ≲ ``v_smooth`` (rad/s)."""

    torque_limit: jax.Array
    rate_limit: jax.Array
    viscous: jax.Array
    coulomb: jax.Array
    v_smooth: jax.Array

    @property
    def rate_limited(self) -> bool:
        """Whether the torque rate is limited (a fact of the values: checked once, on the host)."""
        return bool(jnp.any(jnp.isfinite(jnp.asarray(self.rate_limit))))

    def saturate(self, tau):
        """τ clipped at ±τ_max."""
        return jnp.clip(tau, -self.torque_limit, self.torque_limit)

    def apply(self, tau, previous, period, first):
        """The torque applied over the sample of period T from the commanded τ, the torque applied
        over the previous one (``previous``) and whether this is the first sample (``first``: no
        rate limit)."""
        step = self.rate_limit * period
        limited = jnp.where(first, tau, previous + jnp.clip(tau - previous, -step, step))
        return self.saturate(limited)

    def friction(self, qd):
        """The joints' friction torque τ_f = b_v q̇ + f_c tanh(q̇ / v_s) (it opposes the motion)."""
        return self.viscous * qd + self.coulomb * jnp.tanh(qd / self.v_smooth)

    def saturated(self, tau_applied):
        """1.0 when a joint is at its torque limit, else 0.0."""
        return jnp.where(jnp.any(jnp.abs(tau_applied) >= self.torque_limit), 1.0, 0.0)


__all__ = ["Sensor", "SensorState", "Actuator"]
