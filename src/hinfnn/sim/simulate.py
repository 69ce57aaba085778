"""Closed-loop simulation: plant and controller state integrated together in ``lax.scan``.

A run is a jit-compiled ``lax.scan`` over a chunk of :data:`CHUNK_STEPS` steps, called from a
Python loop over chunks (never over steps): the compiled program is the same for every horizon
and dt, progress is reported and Ctrl-C is honoured between chunks.

The state y = (q, q̇, controller state, accumulators) is advanced by fixed-step RK4
(:func:`~hinfnn.sim.integrate.rk4_step`) with the controller evaluated at every stage from that
stage's measurements (continuous-time control, the paper's setting), or held by a zero-order
hold between samples (``control_period``, the sampled-data adapter: torque computed at each
sample instant, controller state advanced by forward Euler over the period).

The disturbance is held over each step at its value at the step's midpoint; steps land on its
switching instants when dt divides them (checked by the scenario loader).

Accumulated along the run as states (eq. 34 and the dissipation check of Theorems 1–2):
``J`` = ∫ integrand of (34), ``J_aug`` = J + Remark 1's extra terms (augmented designs),
``supply`` = ρ² ∫ (‖f_p‖² + ‖f_f‖²) dt with f_p, f_f the actual residuals of (28)–(29)/(52)–(53).

One run and a batch are the same program: :func:`simulate_batch` is :func:`jax.vmap` of it over
stacked parameter pytrees.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import pytree_dataclass
from ..errors import ConfigError, DesignError, SimulationError
from ..measurement import Measurement
from .integrate import rk4_step
from .trajectory import STATUS, Trajectory


@pytree_dataclass
class Accumulators:
    J: jax.Array
    J_aug: jax.Array
    supply: jax.Array


@pytree_dataclass
class SimState:
    q: jax.Array
    qd: jax.Array
    xc: object  # ControllerState
    acc: Accumulators


#: Bits of ``fail_details["nonfinite_parts"]``: which part of the state became non-finite.
NONFINITE_PARTS = ("joint angles/rates q, q̇", "controller state z, Θ̂", "accumulated J, V-supply")


@pytree_dataclass
class Limits:
    """A run stops (status ≠ 0) when |τ_i| or the penetration passes these."""

    torque: jax.Array = 1e5
    penetration: jax.Array = 0.05


def _rhs(plant, ctrl, ref, t, y: SimState, w, held_tau):
    F, f_n, p = plant.contact_state(y.q, y.qd)  # once: the sensor reading and the dynamics share it
    meas = Measurement(q=y.q, qd=y.qd, F=F)
    tau_c, dxc, sig = ctrl.step_terms(t, y.xc, meas, ref)
    if held_tau is None:
        tau = tau_c
    else:
        tau = held_tau
        dxc = jax.tree.map(jnp.zeros_like, dxc)
    qdd = plant.acceleration(y.q, y.qd, tau, w, F=F)
    j, j_extra = ctrl.performance_rate(y.xc, sig)
    f_p, f_f = ctrl.supply_residuals(t, y.xc, sig, ctrl.u1_ddot(y.q, y.qd, qdd), ref)
    supply = ctrl.gains.rho**2 * (f_p @ f_p + f_f @ f_f)
    dy = SimState(q=y.qd, qd=qdd, xc=dxc, acc=Accumulators(J=j, J_aug=j + j_extra, supply=supply))
    r = ref(t)
    aux = dict(
        t=jnp.asarray(t, dtype=float), q=y.q, qd=y.qd, u1=sig.u1, u1_dot=sig.u1_dot, lam=sig.lam,
        u1_d=r.u1_d, u1_d_dot=r.u1_d_dot, lam_d=r.lam_d,
        e_u1=sig.e_u1, e_u1_dot=sig.e_u1_dot, e_lam=sig.e_lam, z=y.xc.z,
        v_p=sig.v_p, v_lam=sig.v_lam, nn_p=sig.nn_p, nn_f=sig.nn_f,
        tau=tau, F=F, normal_force=f_n, penetration=p, disturbance=w, x_true=plant.arm.h(y.q),
        theta_p_norm=jnp.linalg.norm(y.xc.theta_p), theta_f_norm=jnp.linalg.norm(y.xc.theta_f),
        J=y.acc.J, J_aug=y.acc.J_aug, supply=y.acc.supply, V=ctrl.storage(y.xc, sig),
        f_p=f_p, f_f=f_f,
    )
    return dy, aux


def _all_finite(tree):
    leaves = [jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree)]
    return functools.reduce(jnp.logical_and, leaves)


#: Steps per compiled chunk: a run is a Python loop over chunks of one jit-compiled ``lax.scan``
#: (progress, Ctrl-C and one compilation for every horizon), never a loop over time steps.
CHUNK_STEPS = 2000


def _step_fn(plant, ctrl, ref, limits, n_steps, dt, n_hold, sampled):
    """One RK4 step k -> k + 1 with failure detection; a no-op for k ≥ n_steps (padding)."""

    def f(t, y, w, held):
        return _rhs(plant, ctrl, ref, t, y, w, held)

    def step(carry, k):
        y, held, status, t_fail, bad_tau, bad_pen, bad_parts = carry
        active = k < n_steps
        t = k * dt
        y_in = y
        if sampled:
            meas = plant.measure(y.q, y.qd)
            tau_s, dxc_s, _ = ctrl.step_terms(t, y.xc, meas, ref)
            is_sample = (jnp.mod(k, n_hold) == 0) & active & (status == 0)
            held = jnp.where(is_sample, tau_s, held)
            xc = jax.tree.map(lambda a, d: jnp.where(is_sample, a + (n_hold * dt) * d, a), y.xc, dxc_s)
            xc = ctrl.constrain(xc)
            y = SimState(q=y.q, qd=y.qd, xc=xc, acc=y.acc)
        w = plant.disturbance(t + 0.5 * dt)
        y_new, aux = rk4_step(lambda tt, yy: f(tt, yy, w, held if sampled else None), t, y, dt)
        y_new = SimState(q=y_new.q, qd=y_new.qd, xc=ctrl.constrain(y_new.xc), acc=y_new.acc)
        tau_peak = jnp.max(jnp.abs(aux["tau"]))
        pen = aux["penetration"]
        finite_parts = (_all_finite((y_new.q, y_new.qd)), _all_finite(y_new.xc), _all_finite(y_new.acc))
        parts = sum(jnp.where(ok, 0, 1 << i) for i, ok in enumerate(finite_parts)).astype(jnp.int32)
        code = jnp.where(parts != 0, 1,
                         jnp.where(tau_peak > limits.torque, 2,
                                   jnp.where(pen > limits.penetration, 3, 0)))
        code = jnp.where(active, code, 0)
        first = (status == 0) & (code != 0)
        t_fail = jnp.where(first, jnp.where(code == 1, t + dt, t), t_fail)
        bad_tau = jnp.where(first, tau_peak, bad_tau)
        bad_pen = jnp.where(first, pen, bad_pen)
        bad_parts = jnp.where(first, parts, bad_parts)
        status = jnp.where(status == 0, code, status)
        keep_old = (status != 0) | ~active
        y_next = jax.tree.map(lambda a, b: jnp.where(keep_old, a, b), y_in, y_new)
        return (y_next, held, status, t_fail, bad_tau, bad_pen, bad_parts), aux

    return f, step


def _chunk(plant, ctrl, ref, limits, carry, k0, n_steps, dt, n_hold, *, n_records, save_every, sampled):
    """``n_records · save_every`` steps from step ``k0``, keeping every ``save_every``-th record.

    One scan over steps (one copy of the step in the compiled program), then the records are
    subsampled: cheaper to compile than a nested loop, and a chunk's records are small."""
    _, step = _step_fn(plant, ctrl, ref, limits, n_steps, dt, n_hold, sampled)
    carry, rec = jax.lax.scan(step, carry, k0 + jnp.arange(n_records * save_every))
    if save_every > 1:
        rec = jax.tree.map(lambda a: a[::save_every], rec)
    return carry, rec


def _finish(plant, ctrl, ref, limits, carry, n_steps, dt, n_hold, *, sampled):
    """The record at t_final and the full final state."""
    f, _ = _step_fn(plant, ctrl, ref, limits, n_steps, dt, n_hold, sampled)
    y_end, held, status, t_fail, bad_tau, bad_pen, bad_parts = carry
    t_end = n_steps * dt
    _, aux_end = f(t_end, y_end, plant.disturbance(t_end - 0.5 * dt), held if sampled else None)
    final = dict(q=y_end.q, qd=y_end.qd, z=y_end.xc.z, theta_p=y_end.xc.theta_p,
                 theta_f=y_end.xc.theta_f, J=y_end.acc.J, J_aug=y_end.acc.J_aug, supply=y_end.acc.supply)
    return aux_end, status, t_fail, dict(tau_peak=bad_tau, penetration=bad_pen,
                                         nonfinite_parts=bad_parts), final


def _init_carry(y0, n):
    """(state, held torque, status, t_fail, τ, penetration and non-finite parts at failure),
    strongly typed so that the carry a chunk returns has the same types (no second compile)."""
    f64 = jnp.float64
    zero = jnp.zeros((), f64)
    return (y0, jnp.zeros(n, f64), jnp.zeros((), jnp.int32), jnp.array(jnp.nan, dtype=f64), zero, zero,
            jnp.zeros((), jnp.int32))


@functools.lru_cache(maxsize=128)
def _compiled(in_axes, n_records, save_every, sampled):
    """(chunk, finish, init) compiled for one structure; in_axes=None for a single run.

    Horizon, dt and the hold period are traced arguments, so a new t_final or dt reuses the
    compiled program."""
    chunk = functools.partial(_chunk, n_records=n_records, save_every=save_every, sampled=sampled)
    finish = functools.partial(_finish, sampled=sampled)
    init = _init_carry
    if in_axes is not None:
        p, c, r, lim = in_axes
        chunk = jax.vmap(chunk, in_axes=(p, c, r, lim, 0, None, None, None, None))
        finish = jax.vmap(finish, in_axes=(p, c, r, lim, 0, None, None, None))
        init = jax.vmap(_init_carry, in_axes=(0, None))
    return jax.jit(chunk), jax.jit(finish), jax.jit(init, static_argnums=1)


def _drive(plant, ctrl, ref, limits, y0, in_axes, *, n_steps, save_every, n_hold, dt, n_joints,
           progress=None):
    """Run the chunks from Python; returns the outputs of :func:`_finish` plus all records."""
    n_records = n_steps // save_every
    per_chunk = max(1, CHUNK_STEPS // save_every)  # independent of the horizon: one compilation
    chunk, finish, init = _compiled(in_axes, per_chunk, save_every, n_hold > 0)
    carry = init(y0, n_joints)
    dt_a = jnp.asarray(dt, dtype=float)
    n_steps_a = jnp.asarray(n_steps, dtype=jnp.int64)
    hold_a = jnp.asarray(max(n_hold, 1), dtype=jnp.int64)
    pieces = []
    n_chunks = -(-n_records // per_chunk)
    for c in range(n_chunks):
        k0 = jnp.asarray(c * per_chunk * save_every, dtype=jnp.int64)
        carry, rec = chunk(plant, ctrl, ref, limits, carry, k0, n_steps_a, dt_a, hold_a)
        pieces.append(rec)
        if progress is not None:
            jax.block_until_ready(rec)
            progress(min((c + 1) * per_chunk, n_records) * save_every, n_steps)
    axis = 0 if in_axes is None else 1
    rec = {k: np.concatenate([np.asarray(p[k]) for p in pieces], axis=axis) for k in pieces[0]}
    rec = {k: (v[:n_records] if axis == 0 else v[:, :n_records]) for k, v in rec.items()}
    aux_end, status, t_fail, details, final = finish(plant, ctrl, ref, limits, carry, n_steps_a, dt_a, hold_a)
    rec = {k: np.concatenate([v, np.expand_dims(np.asarray(aux_end[k]), axis)], axis=axis)
           for k, v in rec.items()}
    return rec, status, t_fail, details, final


def _steps(t_final, dt, save_every, control_period):
    for name, v in (("t_final", t_final), ("dt", dt)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ConfigError(f"must be a finite number > 0, got {v!r}", key=f"simulation.{name}")
    n_steps = round(t_final / dt)
    if abs(n_steps * dt - t_final) > 1e-9 * max(1.0, t_final):
        raise ConfigError(f"t_final = {t_final:g} is not a whole number of steps dt = {dt:g}",
                          key="simulation.t_final")
    if not (isinstance(save_every, int) and save_every >= 1 and n_steps % save_every == 0):
        raise ConfigError(f"must be a positive integer dividing the {n_steps} steps, got {save_every!r}",
                          key="simulation.save_every")
    n_hold = 0
    if control_period is not None:
        n_hold = round(control_period / dt)
        if n_hold < 1 or abs(n_hold * dt - control_period) > 1e-9 * control_period:
            raise ConfigError(f"control period {control_period:g} must be a whole multiple of dt = {dt:g}",
                              key="simulation.control_period")
    return n_steps, n_hold


def initial_state(plant, ctrl, *, u1_0=1.6902, q0=None, qd0=None, xc0=None) -> SimState:
    """Sec. VI initial state: q0 with the TRUE end-effector at u1(0) on the TRUE surface,
    q̇ = 0, controller state ``ctrl.init()`` (z = 0, weights 0), accumulators 0."""
    q0 = plant.initial_q(u1_0) if q0 is None else jnp.asarray(q0, float)
    qd0 = jnp.zeros_like(q0) if qd0 is None else jnp.asarray(qd0, float)
    zero = jnp.zeros(())
    return SimState(q=q0, qd=qd0, xc=ctrl.init() if xc0 is None else xc0,
                    acc=Accumulators(J=zero, J_aug=zero, supply=zero))


def check_start(controller, y0: SimState, min_abs_det: float = 1e-6):
    """The start pose must be finite and the nominal Jacobian Ĵ(q0) nonsingular (A1)."""
    q0 = np.asarray(y0.q)
    if not np.all(np.isfinite(q0)):
        raise DesignError(f"the start pose is unreachable: q0 = {q0.tolist()} (u1(0) is out of the "
                          "true arm's reach on the true surface)", key="initial.u1")
    det = float(jnp.linalg.det(controller.arm.J(y0.q)))
    if not abs(det) >= min_abs_det:
        raise DesignError(f"the nominal Jacobian is singular at the start pose q0 = {q0.tolist()} "
                          f"(|det J| = {abs(det):.3g} < {min_abs_det:g})", key="initial.u1")


def _to_numpy(rec, status, t_fail, details, final, *, config, dt, save_every) -> Trajectory:
    arrays = {k: np.asarray(v) for k, v in rec.items()}
    return Trajectory(arrays=arrays, status=np.asarray(status), t_fail=np.asarray(t_fail),
                      fail_details={k: np.asarray(v) for k, v in details.items()},
                      config=config or {}, dt=float(dt), save_every=int(save_every),
                      final={k: np.asarray(v) for k, v in final.items()})


def simulate(plant, controller, reference, *, t_final: float = 10.0, dt: float = 1e-4,
             u1_0: float = 1.6902, q0=None, qd0=None, xc0=None, save_every: int = 1,
             control_period: float | None = None, limits: Limits | None = None,
             config: dict | None = None, raise_on_failure: bool = True, progress=None) -> Trajectory:
    """Simulate one closed-loop run; returns a :class:`Trajectory` sampled every ``save_every``
    steps (t = 0, …, t_final).

    Raises :class:`~hinfnn.errors.SimulationError` with the time and the offending quantities
    if the state becomes non-finite or a limit is passed (unless ``raise_on_failure=False``;
    the trajectory is then frozen at its last good state from the failing step on).
    ``progress(steps_done, steps_total)``, if given, is called after each compiled chunk of
    :data:`CHUNK_STEPS` steps.
    """
    n_steps, n_hold = _steps(t_final, dt, save_every, control_period)
    y0 = initial_state(plant, controller, u1_0=u1_0, q0=q0, qd0=qd0, xc0=xc0)
    check_start(controller, y0)
    out = _drive(plant, controller, reference, limits or Limits(), y0, None, n_steps=n_steps,
                 save_every=save_every, n_hold=n_hold, dt=float(dt), n_joints=plant.arm.n,
                 progress=progress)
    traj = _to_numpy(*out, config=config, dt=dt, save_every=save_every)
    if raise_on_failure and int(traj.status) != 0:
        raise failure_error(traj)
    return traj


def failure_error(traj: Trajectory) -> SimulationError:
    """A :class:`SimulationError` describing why a (single) run stopped."""
    code = int(traj.status)
    t = float(traj.t_fail)
    details = {k: float(v) for k, v in traj.fail_details.items()}
    what = STATUS.get(code, f"status {code}")
    msg = f"run stopped at t = {t:.6g} s: {what}"
    if code == 1:
        parts = int(details.get("nonfinite_parts", 0))
        names = [n for i, n in enumerate(NONFINITE_PARTS) if parts & (1 << i)]
        msg += f" ({', '.join(names) or 'state'}; peak |tau| at the step before = {details['tau_peak']:.4g} N·m)"
    elif code == 2:
        msg += f" (peak |tau| = {details['tau_peak']:.4g} N·m)"
    elif code == 3:
        msg += f" (penetration = {details['penetration']:.4g} m)"
    return SimulationError(msg, t_fail=t, details=details)


def stack(items):
    """Stack a list of pytrees of identical structure into one with a leading batch axis."""
    treedefs = {jax.tree.structure(x) for x in items}
    if len(treedefs) != 1:
        raise ConfigError("batch members differ in structure (controller kind, network sizes or "
                          "model types); run them as separate batches")
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *items)


def simulate_batch(plants, controllers, references, *, t_final: float = 10.0, dt: float = 1e-4,
                   u1_0=1.6902, q0=None, save_every: int = 1, control_period: float | None = None,
                   limits=None, configs: list | None = None, progress=None) -> Trajectory:
    """Simulate B runs as ONE program (``jax.vmap`` of :func:`simulate`'s run).

    ``plants``, ``controllers``, ``references`` (and ``limits``): each either a list of B objects
    (stacked along a new axis) or a single object shared by every member. ``u1_0``/``q0`` may be
    lists too. Members that fail are marked in ``status``/``t_fail`` and do not stop the others;
    nothing is raised for them. ``progress`` as for :func:`simulate`.
    """
    listed = [x for x in (plants, controllers, references, limits) if isinstance(x, (list, tuple))]
    if not listed:
        raise ConfigError("simulate_batch needs at least one list of plants, controllers or references")
    sizes = {len(x) for x in listed}
    if len(sizes) != 1:
        raise ConfigError(f"batch lists have different lengths {sorted(sizes)}")
    (B,) = sizes

    def member(x, i):
        return x[i] if isinstance(x, (list, tuple)) else x

    u1s = u1_0 if isinstance(u1_0, (list, tuple, np.ndarray)) else [u1_0] * B
    q0s = q0 if isinstance(q0, (list, tuple)) else [q0] * B
    y0s = [initial_state(member(plants, i), member(controllers, i), u1_0=u1s[i], q0=q0s[i])
           for i in range(B)]
    for i in range(B):
        check_start(member(controllers, i), y0s[i])
    n_steps, n_hold = _steps(t_final, dt, save_every, control_period)
    args, axes = [], []
    for x in (plants, controllers, references, limits or Limits()):
        if isinstance(x, (list, tuple)):
            args.append(stack(list(x)))
            axes.append(0)
        else:
            args.append(x)
            axes.append(None)
    out = _drive(*args, stack(y0s), tuple(axes), n_steps=n_steps, save_every=save_every, n_hold=n_hold,
                 dt=float(dt), n_joints=member(plants, 0).arm.n, progress=progress)
    return _to_numpy(*out, config={"members": list(configs)} if configs else {}, dt=dt,
                     save_every=save_every)
