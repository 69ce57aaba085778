"""Classic fixed-step fourth-order Runge–Kutta on pytrees."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def _axpy(a, x, y):
    return jax.tree.map(lambda xi, yi: yi + a * xi, x, y)


def rk4_step(f, t, y, dt, *, rolled: bool = False):
    """One RK4 step of ẏ = f(t, y); ``f`` returns ``(dy, aux)``. Returns ``(y_next, aux_1)``,
    aux_1 the auxiliary output of the first stage (the state at the start of the step).

    ``rolled``: stages 2–4 as a loop of three iterations, so a compiled program holds ``f``
    twice instead of four times (the same operations in the same order; a device for arms with
    large dynamics, :func:`hinfnn._devices.rolled_rk4`)."""
    k1, aux = f(t, y)
    if rolled:
        def stage(i, state):
            acc, k = state
            c = jnp.where(i == 3, 1.0, 0.5)  # stages 2, 3 at t + dt/2 from k1, k2; stage 4 at t + dt
            ki, _ = f(t + c * dt, _axpy(c * dt, k, y))
            return jax.tree.map(lambda a, kk: a + jnp.where(i == 3, 1.0, 2.0) * kk, acc, ki), ki

        acc, _ = jax.lax.fori_loop(1, 4, stage, (k1, k1))  # acc = k1 + 2 k2 + 2 k3 + k4
        return jax.tree.map(lambda yi, a: yi + (dt / 6.0) * a, y, acc), aux
    k2, _ = f(t + 0.5 * dt, _axpy(0.5 * dt, k1, y))
    k3, _ = f(t + 0.5 * dt, _axpy(0.5 * dt, k2, y))
    k4, _ = f(t + dt, _axpy(dt, k3, y))
    y_next = jax.tree.map(
        lambda yi, a, b, c, d: yi + (dt / 6.0) * (a + 2.0 * b + 2.0 * c + d), y, k1, k2, k3, k4)
    return y_next, aux
