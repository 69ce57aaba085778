"""Classic fixed-step fourth-order Runge–Kutta on pytrees."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def _axpy(a, x, y):
    return jax.tree.map(lambda xi, yi: yi + a * xi, x, y)


def rk4_step(f, t, y, dt, *, rolled: bool = False, rolled_stages: int = 4):
    """One RK4 step of ẏ = f(t, y); ``f`` returns ``(dy, aux)``. Returns ``(y_next, aux_1)``,
    aux_1 the auxiliary output of the first stage (the state at the start of the step).

    ``rolled``: stages as a loop, so a compiled program holds ``f`` fewer times (the same
    operations in the same order, bit for bit; a loop option for arms with large dynamics,
    :class:`hinfnn._loop.LoopOptions`). ``rolled_stages`` 4: the four stages a loop of four
    iterations (``f`` once in the program; its aux computed at every stage, the first kept);
    3: stage 1 written out with its aux, stages 2–4 a loop of three iterations whose aux is
    unused and not computed (``f`` twice in the program, the record once per step)."""
    if rolled and rolled_stages == 3:
        f = jax.jit(f, inline=True)  # traced once: for stage 1 and for the loop's body
        k1, aux = f(t, y)  # stage 1 at (t, y), with the auxiliary output

        def later(i, state):  # stages 2, 3 at t + dt/2 from k1, k2; stage 4 at t + dt from k3
            acc, k = state
            c = jnp.where(i == 3, 1.0, 0.5)
            ki, _ = f(t + c * dt, jax.tree.map(lambda yi, kk: yi + c * dt * kk, y, k))
            w = jnp.where(i == 3, 1.0, 2.0)
            return jax.tree.map(lambda a, kk: a + w * kk, acc, ki), ki  # k1 + 2 k2 + 2 k3 + k4

        acc, _ = jax.lax.fori_loop(1, 4, later, (k1, k1))
        return jax.tree.map(lambda yi, a: yi + (dt / 6.0) * a, y, acc), aux
    if rolled:
        f = jax.jit(f, inline=True)  # traced once: for the shapes below and for the loop's body

        def stage(i, state):
            acc, k, aux = state
            first = i == 0
            c = jnp.where(i == 3, 1.0, 0.5)  # stage 1 at (t, y); 2, 3 at t + dt/2 from k1, k2; 4 at t + dt
            ki, aux_i = f(jnp.where(first, t, t + c * dt),
                          jax.tree.map(lambda yi, kk: jnp.where(first, yi, yi + c * dt * kk), y, k))
            w = jnp.where(i == 3, 1.0, 2.0)
            acc = jax.tree.map(lambda a, kk: jnp.where(first, kk, a + w * kk), acc, ki)  # k1 + 2 k2 + 2 k3 + k4
            return acc, ki, jax.tree.map(lambda new, old: jnp.where(first, new, old), aux_i, aux)

        k0, aux0 = jax.tree.map(jnp.zeros_like, jax.eval_shape(f, t, y))
        acc, _, aux = jax.lax.fori_loop(0, 4, stage, (k0, k0, aux0))
        return jax.tree.map(lambda yi, a: yi + (dt / 6.0) * a, y, acc), aux
    k1, aux = f(t, y)
    k2, _ = f(t + 0.5 * dt, _axpy(0.5 * dt, k1, y))
    k3, _ = f(t + 0.5 * dt, _axpy(0.5 * dt, k2, y))
    k4, _ = f(t + dt, _axpy(dt, k3, y))
    y_next = jax.tree.map(
        lambda yi, a, b, c, d: yi + (dt / 6.0) * (a + 2.0 * b + 2.0 * c + d), y, k1, k2, k3, k4)
    return y_next, aux
