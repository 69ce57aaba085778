"""Classic fixed-step fourth-order Runge–Kutta on pytrees."""

from __future__ import annotations

import jax


def _axpy(a, x, y):
    return jax.tree.map(lambda xi, yi: yi + a * xi, x, y)


def rk4_step(f, t, y, dt):
    """One RK4 step of ẏ = f(t, y); ``f`` returns ``(dy, aux)``. Returns ``(y_next, aux_1)``,
    aux_1 the auxiliary output of the first stage (the state at the start of the step)."""
    k1, aux = f(t, y)
    k2, _ = f(t + 0.5 * dt, _axpy(0.5 * dt, k1, y))
    k3, _ = f(t + 0.5 * dt, _axpy(0.5 * dt, k2, y))
    k4, _ = f(t + dt, _axpy(dt, k3, y))
    y_next = jax.tree.map(
        lambda yi, a, b, c, d: yi + (dt / 6.0) * (a + 2.0 * b + 2.0 * c + d), y, k1, k2, k3, k4)
    return y_next, aux
