"""Classic fixed-step fourth-order Runge–Kutta on pytrees, :class:`RK4`, its looping a field."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jax.extend import core as jcore


def _needed(eqns, outs):
    """The equations of ``eqns`` (in order) that the variables ``outs`` depend on."""
    live = {v for v in outs if isinstance(v, jcore.Var)}
    keep = []
    for e in reversed(eqns):
        if e.effects or any(v in live for v in e.outvars if not isinstance(v, jcore.DropVar)):
            keep.append(e)
            live.update(v for v in e.invars if isinstance(v, jcore.Var))
    return keep[::-1]


def split_aux(f, *args, every=()):
    """``f(*args) = (dy, aux)`` traced once and cut in two: ``(first, second, aux0, partial)`` with
    ``first(*args) = (dy, residuals)``, the equations ``dy`` needs, and ``second(residuals) = aux``,
    the equations only ``aux`` needs (``residuals``: the values of the first that they read);
    ``aux0`` zeros of the shapes of ``aux``. The same operations as ``f``, so a stage that does not
    keep its ``aux`` runs ``first`` alone, and XLA does not compute what no one reads.
    ``partial(residuals, old)``: ``old`` (an aux) with the entries named in ``every`` (keys of a
    dict aux) computed, by the equations those entries need alone. None when ``f`` has side
    effects (it is then not cut)."""
    closed, shapes = jax.make_jaxpr(f, return_shape=True)(*args)
    jaxpr = closed.jaxpr
    if jaxpr.effects:
        return None
    dy_tree, aux_tree = jax.tree.structure(shapes[0]), jax.tree.structure(shapes[1])
    n_dy = dy_tree.num_leaves
    dy_out, aux_out = list(jaxpr.outvars[:n_dy]), list(jaxpr.outvars[n_dy:])
    dy_eqns = _needed(jaxpr.eqns, dy_out)
    known = {*jaxpr.invars, *jaxpr.constvars, *(v for e in dy_eqns for v in e.outvars)}
    aux_eqns = [e for e in _needed(jaxpr.eqns, aux_out)
                if not all(v in known for v in e.outvars if not isinstance(v, jcore.DropVar))]
    made = {v for e in aux_eqns for v in e.outvars}
    res = list(dict.fromkeys(v for v in [*(v for e in aux_eqns for v in e.invars), *aux_out]
                             if isinstance(v, jcore.Var) and v not in made))

    def info(part, n_in, n_out):
        return jcore.DebugInfo(f"split_aux ({part})", jaxpr.debug_info.func_src_info, ("",) * n_in, ("",) * n_out)

    first = jcore.jaxpr_as_fun(jcore.ClosedJaxpr(
        jcore.Jaxpr(jaxpr.constvars, jaxpr.invars, dy_out + res, dy_eqns,
                    debug_info=info("derivative", len(jaxpr.invars), n_dy + len(res))), closed.consts))
    second = jcore.jaxpr_as_fun(jcore.ClosedJaxpr(
        jcore.Jaxpr([], res, aux_out, aux_eqns, debug_info=info("aux", len(res), len(aux_out))), []))

    def run_first(*a):
        out = first(*jax.tree.leaves(a))
        return jax.tree.unflatten(dy_tree, out[:n_dy]), tuple(out[n_dy:])

    def run_second(residuals):
        return jax.tree.unflatten(aux_tree, second(*residuals))

    paths = [p for p, _ in jax.tree_util.tree_flatten_with_path(shapes[1])[0]]
    every = set(every)
    picked = [i for i, p in enumerate(paths) if p and getattr(p[0], "key", None) in every]
    part_out = [aux_out[i] for i in picked]
    part = jcore.jaxpr_as_fun(jcore.ClosedJaxpr(
        jcore.Jaxpr([], res, part_out, _needed(aux_eqns, part_out),
                    debug_info=info("aux, every step", len(res), len(part_out))), []))

    def run_partial(residuals, old):
        leaves = list(jax.tree.leaves(old))
        for i, v in zip(picked, part(*residuals)):
            leaves[i] = v
        return jax.tree.unflatten(aux_tree, leaves)

    return run_first, run_second, jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes[1]), run_partial


def _axpy(a, x, y):
    return jax.tree.map(lambda xi, yi: yi + a * xi, x, y)


#: How :class:`RK4` loops over its four stages (:attr:`RK4.looping`).
LOOPINGS = ("written", "rolled", "rolled3")


@dataclasses.dataclass(frozen=True)
class RK4:
    """Classic fixed-step fourth-order Runge–Kutta on pytrees: :meth:`step` of ẏ = f(t, y), ``f``
    returning ``(dy, aux)``. How the four stages are looped is a field, as diffrax's
    ``AbstractRungeKutta.scan_kind`` (the same operations in the same order in every form, bit
    for bit; a loop option for arms with large dynamics, :class:`hinfnn._loop.LoopOptions`).

    ``looping``: ``"written"``, the four stages written out (``f`` four times in a compiled
    program); ``"rolled"``, the four stages a loop of four iterations (``f`` once in the program;
    its aux computed at every stage, the first kept); ``"rolled3"``, stage 1 written out with its
    aux, stages 2–4 a loop of three iterations whose aux is unused and not computed (``f`` twice
    in the program, the record once per step). ``record_once`` (with ``"rolled"``): ``f`` cut by
    :func:`split_aux`, the equations of its aux alone under a ``lax.cond`` taken at stage 1 only,
    the others at every stage (``f``'s operations once in the program, its aux once per step);
    False: the aux computed at every stage, the first kept."""

    looping: str = "written"
    record_once: bool = True

    def __post_init__(self):
        if self.looping not in LOOPINGS:
            raise ValueError(f"looping must be one of {LOOPINGS}, got {self.looping!r}")

    @classmethod
    def of(cls, rolled: bool, rolled_stages: int = 4, record_once: bool = True) -> "RK4":
        """The RK4 of the loop options ``rolled_rk4`` (made for the arm), ``rolled_stages`` and
        ``record_once`` (:class:`hinfnn._loop.LoopOptions`)."""
        return cls("rolled3" if rolled and rolled_stages == 3 else "rolled" if rolled else "written", record_once)

    def step(self, f, t, y, dt, *, take=None, every=()):
        """One step: ``(y_next, aux_1)``, aux_1 the auxiliary output of the first stage (the state
        at the start of the step). ``take`` (with ``"rolled"`` and ``record_once``; a traced bool,
        or None: always): whether the whole aux is wanted at this step; when not, only its
        entries named in ``every`` are computed and the others are zeros (a simulation records
        every few steps, but checks τ and the contact at every step)."""
        if self.looping == "rolled3":
            return _rolled3(f, t, y, dt)
        if self.looping == "rolled":
            return _rolled(f, t, y, dt, self.record_once, take, every)
        return _written(f, t, y, dt)


def _rolled3(f, t, y, dt):
    """:class:`RK4` with ``looping="rolled3"``."""
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


def _rolled(f, t, y, dt, record_once, take, every):
    """:class:`RK4` with ``looping="rolled"``."""
    cut = split_aux(f, t, y, every=every) if record_once else None
    if cut is not None:
        f_dy, f_aux, aux0, f_part = cut

        def keep(first, res, old):  # stage 1's record, computed at stage 1 only
            if take is None:
                return jax.lax.cond(first, lambda r, o: f_aux(r), lambda r, o: o, res, old)
            which = jnp.where(first, jnp.where(take, 2, 1), 0)
            return jax.lax.switch(which, (lambda r, o: o, f_part, lambda r, o: f_aux(r)), res, old)
    else:
        f_dy = jax.jit(f, inline=True)  # traced once: for the shapes below and for the loop's body
        aux0 = jax.tree.map(jnp.zeros_like, jax.eval_shape(f_dy, t, y)[1])

        def keep(first, new, old):  # every stage's aux computed, the first kept
            return jax.tree.map(lambda a, b: jnp.where(first, a, b), new, old)

    def stage(i, state):
        # ys: this stage's state (stage 1 at (t, y); 2, 3 at t + dt/2 from k1, k2; 4 at t + dt
        # from k3), made at the end of the stage before: the loop carries it, not k
        acc, ys, aux = state
        first = i == 0
        c = jnp.where(i == 3, 1.0, 0.5)
        ki, extra = f_dy(jnp.where(first, t, t + c * dt), ys)
        w = jnp.where(i == 3, 1.0, 2.0)
        acc = jax.tree.map(lambda a, kk: jnp.where(first, kk, a + w * kk), acc, ki)  # k1 + 2 k2 + 2 k3 + k4
        c_next = jnp.where(i == 2, 1.0, 0.5)
        ys = jax.tree.map(lambda yi, kk: yi + c_next * dt * kk, y, ki)
        return acc, ys, keep(first, extra, aux)

    k0 = jax.tree.map(jnp.zeros_like, jax.eval_shape(f_dy, t, y)[0])
    acc, _, aux = jax.lax.fori_loop(0, 4, stage, (k0, y, aux0))
    return jax.tree.map(lambda yi, a: yi + (dt / 6.0) * a, y, acc), aux


def _written(f, t, y, dt):
    """:class:`RK4` with ``looping="written"``."""
    k1, aux = f(t, y)
    k2, _ = f(t + 0.5 * dt, _axpy(0.5 * dt, k1, y))
    k3, _ = f(t + 0.5 * dt, _axpy(0.5 * dt, k2, y))
    k4, _ = f(t + dt, _axpy(dt, k3, y))
    y_next = jax.tree.map(
        lambda yi, a, b, c, d: yi + (dt / 6.0) * (a + 2.0 * b + 2.0 * c + d), y, k1, k2, k3, k4)
    return y_next, aux
