"""Closed-loop simulation: plant and controller state integrated together in ``lax.scan``.

A run is a jit-compiled ``lax.scan`` over a chunk of :data:`CHUNK_STEPS` steps, called from a
Python loop over chunks (never over steps): the compiled program is the same for every horizon
and dt, progress is reported and Ctrl-C is honoured between chunks. Inside a chunk, an outer scan
takes one stored sample every ``save_every`` steps and an inner loop runs the steps between them
with no output, so that every buffer it touches is small (at most 512 bytes: the networks' weights
travel in blocks of 64 units) and XLA runs its kernels inline instead of through its thread pool.
Each sample also summarises the steps since the previous one (:data:`STEP_SUMS`,
:data:`STEP_MAXES`, peak and total variation of τ), so metrics cover every step whatever the
storage.

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

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import all_finite, pytree_dataclass
from ..errors import ConfigError, DesignError, SimulationError
from .. import _linalg as la
from ..controllers.network import sq_norm
from ..measurement import Measurement
from .integrate import rk4_step
from .trajectory import FIELD_SETS, FIELDS, STATUS, Trajectory


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
    at = plant.arm.terms(y.q, y.qd)  # the true arm's kinematics and dynamics, once per stage
    F, f_n, p = plant.contact_state(y.q, y.qd, at)  # the sensor reading and the dynamics share it
    meas = Measurement(q=y.q, qd=y.qd, F=F)
    tau_c, dxc, sig = ctrl.step_terms(t, y.xc, meas, ref)
    if held_tau is None:
        tau = tau_c
    else:
        tau = held_tau
        dxc = jax.tree.map(jnp.zeros_like, dxc)
    qdd = plant.acceleration(y.q, y.qd, tau, w, F=F, terms=at)
    j, j_extra = ctrl.performance_rate(y.xc, sig)
    f_p, f_f = ctrl.supply_residuals(t, y.xc, sig, ctrl.u1_ddot(y.q, y.qd, qdd), ref)
    supply = ctrl.gains.rho**2 * (la.mm(f_p, f_p) + la.mm(f_f, f_f))
    dy = SimState(q=y.qd, qd=qdd, xc=dxc, acc=Accumulators(J=j, J_aug=j + j_extra, supply=supply))
    r = ref(t)
    aux = dict(
        t=jnp.asarray(t, dtype=float), q=y.q, qd=y.qd, u1=sig.u1, u1_dot=sig.u1_dot, lam=sig.lam,
        u1_d=r.u1_d, u1_d_dot=r.u1_d_dot, lam_d=r.lam_d,
        e_u1=sig.e_u1, e_u1_dot=sig.e_u1_dot, e_lam=sig.e_lam, z=y.xc.z,
        v_p=sig.v_p, v_lam=sig.v_lam, nn_p=sig.nn_p, nn_f=sig.nn_f,
        tau=tau, F=F, normal_force=f_n, penetration=p, disturbance=w, x_true=at.x,
        theta_p_norm=jnp.sqrt(sq_norm(y.xc.theta_p)), theta_f_norm=jnp.sqrt(sq_norm(y.xc.theta_f)),
        J=y.acc.J, J_aug=y.acc.J_aug, supply=y.acc.supply, V=ctrl.storage(y.xc, sig),
        f_p=f_p, f_f=f_f,
    )
    return dy, aux


#: Steps per compiled chunk: a run is a Python loop over chunks of one jit-compiled ``lax.scan``
#: (progress, Ctrl-C and one compilation for every horizon), never a loop over time steps.
CHUNK_STEPS = 2000


@pytree_dataclass
class Carry:
    """What the compiled loop carries from step to step.

    ``tau_peak``/``tau_tv``/``tau_prev``: max |τ_i| and Σ|τ_i(t_k) − τ_i(t_{k−1})| over the steps
    since the last record, and τ at the previous step (NaN before the first); ``sums``: the
    :data:`STEP_SUMS` over those steps. Records taken every ``save_every`` steps thus still give
    the exact peak, total variation and RMS values over every step.
    """

    y: SimState
    held: jax.Array  # the zero-order-held torque (sampled mode)
    status: jax.Array
    t_fail: jax.Array
    bad_tau: jax.Array
    bad_pen: jax.Array
    bad_parts: jax.Array
    tau_peak: jax.Array
    tau_tv: jax.Array
    tau_prev: jax.Array
    sums: dict
    maxes: dict


#: Per-step quantities summed between records (``Trajectory`` fields of the same names): the
#: metrics' RMS values and contact fraction then cover every step, whatever the storage.
STEP_SUMS = {
    "e_u1_sq": lambda a: jnp.sum(a["e_u1"] ** 2),
    "e_lam_sq": lambda a: jnp.sum(a["e_lam"] ** 2),
    "tau_sq": lambda a: a["tau"] ** 2,
    "steps_out_of_contact": lambda a: jnp.where(a["normal_force"] <= 0.0, 1.0, 0.0),
}
#: Per-step quantities whose maximum between records is kept.
STEP_MAXES = {
    "e_u1_abs_max": lambda a: jnp.sqrt(jnp.sum(a["e_u1"] ** 2)),
    "e_lam_abs_max": lambda a: jnp.sqrt(jnp.sum(a["e_lam"] ** 2)),
}


def _step_fn(plant, ctrl, ref, limits, n_steps, dt, n_hold, sampled):
    """(f, sample, step): the right-hand side, the sampled-mode controller update at step k, and
    one RK4 step k -> k + 1 with failure detection (a no-op for k ≥ n_steps: padding)."""

    def f(t, y, w, held):
        return _rhs(plant, ctrl, ref, t, y, w, held if sampled else None)

    def sample(c: Carry, k, skip=False):
        """At a sample instant: τ held from now on, controller state advanced by Euler."""
        if not sampled:
            return c
        t = k * dt
        y = c.y
        tau_s, dxc_s, _ = ctrl.step_terms(t, y.xc, plant.measure(y.q, y.qd), ref)
        is_sample = (jnp.mod(k, n_hold) == 0) & (k < n_steps) & (c.status == 0) & ~skip
        held = jnp.where(is_sample, tau_s, c.held)
        xc = jax.tree.map(lambda a, d: jnp.where(is_sample, a + (n_hold * dt) * d, a), y.xc, dxc_s)
        xc = ctrl.constrain(xc)
        return dataclasses.replace(c, y=SimState(q=y.q, qd=y.qd, xc=xc, acc=y.acc), held=held)

    def step(c: Carry, k, first):
        """Step k; ``first``: the record of step k was just taken (its sample update and its τ
        statistics are already done)."""
        active = k < n_steps
        t = k * dt
        c = sample(c, k, skip=first)
        y_in = c.y
        w = plant.disturbance(t + 0.5 * dt)
        y_new, aux = rk4_step(lambda tt, yy: f(tt, yy, w, c.held), t, y_in, dt)
        y_new = SimState(q=y_new.q, qd=y_new.qd, xc=ctrl.constrain(y_new.xc), acc=y_new.acc)
        tau = aux["tau"]
        tau_peak = jnp.max(jnp.abs(tau))
        pen = aux["penetration"]
        finite_parts = (all_finite((y_new.q, y_new.qd)), all_finite(y_new.xc), all_finite(y_new.acc))
        parts = sum(jnp.where(ok, 0, 1 << i) for i, ok in enumerate(finite_parts)).astype(jnp.int32)
        code = jnp.where(parts != 0, 1,
                         jnp.where(tau_peak > limits.torque, 2,
                                   jnp.where(pen > limits.penetration, 3, 0)))
        code = jnp.where(active, code, 0)
        status = c.status
        first_fail = (status == 0) & (code != 0)
        status = jnp.where(status == 0, code, status)
        keep_old = (status != 0) | ~active
        count = active & ~first
        return Carry(
            y=jax.tree.map(lambda a, b: jnp.where(keep_old, a, b), y_in, y_new), held=c.held,
            status=status,
            t_fail=jnp.where(first_fail, jnp.where(code == 1, t + dt, t), c.t_fail),
            bad_tau=jnp.where(first_fail, tau_peak, c.bad_tau),
            bad_pen=jnp.where(first_fail, pen, c.bad_pen),
            bad_parts=jnp.where(first_fail, parts, c.bad_parts),
            tau_peak=jnp.where(count, jnp.maximum(c.tau_peak, jnp.abs(tau)), c.tau_peak),
            tau_tv=jnp.where(count, c.tau_tv + jnp.abs(tau - c.tau_prev), c.tau_tv),
            tau_prev=jnp.where(count | first, tau, c.tau_prev),
            sums={k: jnp.where(count, c.sums[k] + fn(aux), c.sums[k]) for k, fn in STEP_SUMS.items()},
            maxes={k: jnp.where(count, jnp.maximum(c.maxes[k], fn(aux)), c.maxes[k])
                   for k, fn in STEP_MAXES.items()})

    return f, sample, step


def _record(f, c: Carry, t, w, fields):
    """The record at t (the state at the start of step k) and the carry with the τ statistics
    restarted; ``tau_abs_max``/``tau_variation`` cover the steps since the previous record."""
    _, aux = f(t, c.y, w, c.held)
    tau = aux["tau"]
    aux["tau_abs_max"] = jnp.maximum(c.tau_peak, jnp.abs(tau))
    aux["tau_variation"] = c.tau_tv + jnp.where(jnp.isnan(c.tau_prev), 0.0, jnp.abs(tau - c.tau_prev))
    for k, fn in STEP_SUMS.items():
        aux[k] = c.sums[k] + fn(aux)
    for k, fn in STEP_MAXES.items():
        aux[k] = jnp.maximum(c.maxes[k], fn(aux))
    c = dataclasses.replace(c, tau_peak=jnp.zeros_like(c.tau_peak), tau_tv=jnp.zeros_like(c.tau_tv),
                            tau_prev=tau, sums=jax.tree.map(jnp.zeros_like, c.sums),
                            maxes=jax.tree.map(jnp.zeros_like, c.maxes))
    return c, {k: aux[k] for k in fields}


def _chunk(plant, ctrl, ref, limits, carry, k0, n_steps, dt, n_hold, *, n_records, save_every, sampled,
           fields):
    """``n_records · save_every`` steps from step ``k0``; a record every ``save_every`` steps.

    An outer scan over records, an inner loop over the steps between them with no output: the
    inner loop body touches only small buffers, so XLA runs its kernels inline (see
    :mod:`hinfnn.controllers.network`, BLOCK)."""
    f, sample, step = _step_fn(plant, ctrl, ref, limits, n_steps, dt, n_hold, sampled)

    def one_record(c, r):
        k = k0 + r * save_every
        c = sample(c, k)
        c, rec = _record(f, c, k * dt, plant.disturbance(k * dt + 0.5 * dt), fields)
        c = jax.lax.fori_loop(0, save_every, lambda i, cc: step(cc, k + i, i == 0), c)
        return c, rec

    return jax.lax.scan(one_record, carry, jnp.arange(n_records))


def _finish(plant, ctrl, ref, limits, carry, n_steps, dt, n_hold, *, sampled, fields):
    """The record at t_final and the full final state (controller state flat again)."""
    f, _, _ = _step_fn(plant, ctrl, ref, limits, n_steps, dt, n_hold, sampled)
    t_end = n_steps * dt
    _, rec = _record(f, carry, t_end, plant.disturbance(t_end - 0.5 * dt), fields)
    y_end = carry.y
    xc = ctrl.flat(y_end.xc)
    final = dict(q=y_end.q, qd=y_end.qd, z=xc.z, theta_p=xc.theta_p,
                 theta_f=xc.theta_f, J=y_end.acc.J, J_aug=y_end.acc.J_aug, supply=y_end.acc.supply)
    details = dict(tau_peak=carry.bad_tau, penetration=carry.bad_pen, nonfinite_parts=carry.bad_parts)
    return rec, carry.status, carry.t_fail, details, final


def _init_carry(ctrl, y0, n):
    """The first carry, with the controller state in blocks, strongly typed so that the carry a
    chunk returns has the same types (no second compile)."""
    f64 = jnp.float64
    zero = jnp.zeros((), f64)
    y0 = SimState(q=y0.q, qd=y0.qd, xc=ctrl.blocked(y0.xc), acc=y0.acc)
    return Carry(y=y0, held=jnp.zeros(n, f64), status=jnp.zeros((), jnp.int32),
                 t_fail=jnp.array(jnp.nan, dtype=f64), bad_tau=zero, bad_pen=zero,
                 bad_parts=jnp.zeros((), jnp.int32), tau_peak=jnp.zeros(n, f64), tau_tv=jnp.zeros(n, f64),
                 tau_prev=jnp.full(n, jnp.nan, f64),
                 sums={k: jnp.zeros(n if k == "tau_sq" else (), f64) for k in STEP_SUMS},
                 maxes={k: jnp.zeros((), f64) for k in STEP_MAXES})


@functools.lru_cache(maxsize=128)
def _compiled(in_axes, n_records, save_every, sampled, fields):
    """(chunk, finish, init) compiled for one structure; in_axes=None for a single run.

    Horizon, dt and the hold period are traced arguments, so a new t_final or dt reuses the
    compiled program."""
    chunk = functools.partial(_chunk, n_records=n_records, save_every=save_every, sampled=sampled,
                              fields=fields)
    finish = functools.partial(_finish, sampled=sampled, fields=fields)
    init = _init_carry
    if in_axes is not None:
        p, c, r, lim = in_axes
        chunk = jax.vmap(chunk, in_axes=(p, c, r, lim, 0, None, None, None, None))
        finish = jax.vmap(finish, in_axes=(p, c, r, lim, 0, None, None, None))
        init = jax.vmap(_init_carry, in_axes=(c, 0, None))
    return jax.jit(chunk), jax.jit(finish), jax.jit(init, static_argnums=2)


def _drive(plant, ctrl, ref, limits, y0, in_axes, *, n_steps, save_every, n_hold, dt, n_joints,
           fields, progress=None):
    """Run the chunks from Python; returns the outputs of :func:`_finish` with all records.

    The records are copied chunk by chunk into arrays allocated once (n_records + 1 samples),
    so memory is what is stored, never proportional to the steps."""
    n_records = n_steps // save_every
    per_chunk = max(1, CHUNK_STEPS // save_every)  # independent of the horizon: one compilation
    chunk, finish, init = _compiled(in_axes, per_chunk, save_every, n_hold > 0, fields)
    carry = init(ctrl, y0, n_joints)
    dt_a = jnp.asarray(dt, dtype=float)
    n_steps_a = jnp.asarray(n_steps, dtype=jnp.int64)
    hold_a = jnp.asarray(max(n_hold, 1), dtype=jnp.int64)
    axis = 0 if in_axes is None else 1
    out = {}

    def store(c, rec):
        lo = c * per_chunk
        n = min(per_chunk, n_records - lo)
        for k, v in rec.items():
            v = np.asarray(v)  # waits for that chunk
            if k not in out:
                out[k] = np.empty(v.shape[:axis] + (n_records + 1,) + v.shape[axis + 1:], v.dtype)
            if axis == 0:
                out[k][lo:lo + n] = v[:n]
            else:
                out[k][:, lo:lo + n] = v[:, :n]
        if progress is not None:
            progress(min((c + 1) * per_chunk, n_records) * save_every, n_steps)

    pending = None  # the previous chunk's records, copied while the next chunk runs
    for c in range(-(-n_records // per_chunk)):
        k0 = jnp.asarray(c * per_chunk * save_every, dtype=jnp.int64)
        carry, rec = chunk(plant, ctrl, ref, limits, carry, k0, n_steps_a, dt_a, hold_a)
        if pending is not None:
            store(*pending)
        pending = (c, rec)
    if pending is not None:
        store(*pending)
    del pending
    rec_end, status, t_fail, details, final = finish(plant, ctrl, ref, limits, carry, n_steps_a, dt_a, hold_a)
    for k, v in rec_end.items():
        if k not in out:  # no chunk (n_records = 0 cannot happen, n_steps >= 1)
            out[k] = np.empty(np.shape(v)[:axis] + (n_records + 1,) + np.shape(v)[axis:], np.asarray(v).dtype)
        if axis == 0:
            out[k][n_records] = np.asarray(v)
        else:
            out[k][:, n_records] = np.asarray(v)
    return out, status, t_fail, details, final


def _steps(t_final, dt, save_every, control_period, save_interval=None):
    for name, v in (("t_final", t_final), ("dt", dt)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ConfigError(f"must be a finite number > 0, got {v!r}", key=f"simulation.{name}")
    n_steps = round(t_final / dt)
    if abs(n_steps * dt - t_final) > 1e-9 * max(1.0, t_final):
        raise ConfigError(f"t_final = {t_final:g} is not a whole number of steps dt = {dt:g}",
                          key="simulation.t_final")
    if save_every is None:
        save_every = save_every_for(n_steps, dt, DEFAULT_SAVE_INTERVAL if save_interval is None else save_interval)
    if not (isinstance(save_every, int) and save_every >= 1 and n_steps % save_every == 0):
        raise ConfigError(f"must be a positive integer dividing the {n_steps} steps, got {save_every!r}",
                          key="simulation.save_every")
    n_hold = 0
    if control_period is not None:
        n_hold = round(control_period / dt)
        if n_hold < 1 or abs(n_hold * dt - control_period) > 1e-9 * control_period:
            raise ConfigError(f"control period {control_period:g} must be a whole multiple of dt = {dt:g}",
                              key="simulation.control_period")
    return n_steps, n_hold, save_every


#: Default interval between stored samples, s (``save_interval``).
DEFAULT_SAVE_INTERVAL = 1e-3


def save_every_for(n_steps: int, dt: float, save_interval: float) -> int:
    """The largest divisor s of ``n_steps`` with s·dt ≤ ``save_interval`` (at least 1): samples
    stay uniform and the last one falls on t_final."""
    if not (isinstance(save_interval, (int, float)) and math.isfinite(save_interval) and save_interval > 0):
        raise ConfigError(f"must be a finite number > 0, got {save_interval!r}", key="simulation.output_interval")
    limit = max(1, min(n_steps, int(math.floor(save_interval / dt * (1 + 1e-9)))))
    return max(s for s in range(1, limit + 1) if n_steps % s == 0)


def _fields(fields) -> tuple:
    """The record fields to store: all of :data:`FIELDS` (``None``), a named set of
    :data:`FIELD_SETS` (``"all"``, ``"metrics"``) or the names given; ``t`` always."""
    if fields is None:
        return tuple(FIELDS)
    if isinstance(fields, str) and fields in FIELD_SETS:
        return tuple(n for n in FIELDS if n in FIELD_SETS[fields])
    names = [fields] if isinstance(fields, str) else list(fields)
    unknown = [n for n in names if n not in FIELDS]
    if unknown:
        raise ConfigError(f"unknown trajectory field(s) {unknown}; allowed: {', '.join(FIELDS)}, or one of "
                          f"the sets {sorted(FIELD_SETS)}", key="fields")
    return tuple(n for n in FIELDS if n == "t" or n in names)


def initial_state(plant, ctrl, *, u1_0=1.6902, q0=None, qd0=None, xc0=None) -> SimState:
    """Sec. VI initial state: q0 with the TRUE end-effector at u1(0) on the TRUE surface,
    q̇ = 0, controller state ``ctrl.init()`` (z = 0, weights 0), accumulators 0."""
    q0 = plant.initial_q(u1_0) if q0 is None else jnp.asarray(q0, float)
    qd0 = jnp.zeros_like(q0) if qd0 is None else jnp.asarray(qd0, float)
    zero = jnp.zeros(())
    return SimState(q=q0, qd=qd0, xc=ctrl.init() if xc0 is None else xc0,
                    acc=Accumulators(J=zero, J_aug=zero, supply=zero))


@jax.jit
def nominal_jacobian_det(arm, q):
    """det Ĵ(q) as one compiled program (a new process lowers each eager operation separately)."""
    return jnp.linalg.det(arm.J(q))


def check_start(controller, y0: SimState, min_abs_det: float = 1e-6):
    """The start pose must be finite and the nominal Jacobian Ĵ(q0) nonsingular (A1)."""
    q0 = np.asarray(y0.q)
    if not np.all(np.isfinite(q0)):
        raise DesignError(f"the start pose is unreachable: q0 = {q0.tolist()} (u1(0) is out of the "
                          "true arm's reach on the true surface)", key="initial.u1")
    det = float(nominal_jacobian_det(controller.arm, y0.q))
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
             u1_0: float = 1.6902, q0=None, qd0=None, xc0=None, save_every: int | None = None,
             save_interval: float = DEFAULT_SAVE_INTERVAL, fields=None,
             control_period: float | None = None, limits: Limits | None = None,
             config: dict | None = None, raise_on_failure: bool = True, progress=None) -> Trajectory:
    """Simulate one closed-loop run; returns a :class:`Trajectory` sampled every ``save_every``
    steps (t = 0, …, t_final).

    Storage: a sample every ``save_every`` steps; by default the largest divisor of the step
    count with ``save_every · dt ≤ save_interval`` (1 ms: every 10th step at dt = 1e-4).
    The step summaries (``tau_abs_max``, ``tau_variation``, ``tau_sq``, ``e_u1_sq``, ...) still
    cover every step, so :func:`~hinfnn.compute_metrics` does not depend on the decimation.
    ``fields``: the trajectory fields to store, names or ``"metrics"`` (default all of
    :data:`~hinfnn.sim.trajectory.FIELDS`; ``t`` always); memory is what is stored.

    Raises :class:`~hinfnn.errors.SimulationError` with the time and the offending quantities
    if the state becomes non-finite or a limit is passed (unless ``raise_on_failure=False``;
    the trajectory is then frozen at its last good state from the failing step on).
    ``progress(steps_done, steps_total)``, if given, is called after each compiled chunk of
    :data:`CHUNK_STEPS` steps.
    """
    n_steps, n_hold, save_every = _steps(t_final, dt, save_every, control_period, save_interval)
    fields = _fields(fields)
    y0 = initial_state(plant, controller, u1_0=u1_0, q0=q0, qd0=qd0, xc0=xc0)
    check_start(controller, y0)
    out = _drive(plant, controller, reference, limits or Limits(), y0, None, n_steps=n_steps,
                 save_every=save_every, n_hold=n_hold, dt=float(dt), n_joints=plant.arm.n,
                 fields=fields, progress=progress)
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
                   u1_0=1.6902, q0=None, save_every: int | None = None,
                   save_interval: float = DEFAULT_SAVE_INTERVAL, fields=None,
                   control_period: float | None = None, limits=None, configs: list | None = None,
                   progress=None) -> Trajectory:
    """Simulate B runs as ONE program (``jax.vmap`` of :func:`simulate`'s run).

    ``plants``, ``controllers``, ``references`` (and ``limits``): each either a list of B objects
    (stacked along a new axis) or a single object shared by every member. ``u1_0``/``q0`` may be
    lists too. Members that fail are marked in ``status``/``t_fail`` and do not stop the others;
    nothing is raised for them. ``save_every``, ``save_interval``, ``fields`` and ``progress``
    as for :func:`simulate`; a batch of B runs stores B times what one run stores.
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
    n_steps, n_hold, save_every = _steps(t_final, dt, save_every, control_period, save_interval)
    fields = _fields(fields)
    if B == 1:  # the unbatched program (a vmap over one member runs about 6x slower), then a batch axis
        out = _drive(member(plants, 0), member(controllers, 0), member(references, 0),
                     member(limits, 0) if limits is not None else Limits(), y0s[0], None, n_steps=n_steps,
                     save_every=save_every, n_hold=n_hold, dt=float(dt), n_joints=member(plants, 0).arm.n,
                     fields=fields, progress=progress)
        out = jax.tree.map(lambda a: np.expand_dims(np.asarray(a), 0), out)
        return _to_numpy(*out, config={"members": list(configs)} if configs else {}, dt=dt,
                         save_every=save_every)
    args, axes = [], []
    for x in (plants, controllers, references, limits or Limits()):
        if isinstance(x, (list, tuple)):
            args.append(stack(list(x)))
            axes.append(0)
        else:
            args.append(x)
            axes.append(None)
    out = _drive(*args, stack(y0s), tuple(axes), n_steps=n_steps, save_every=save_every, n_hold=n_hold,
                 dt=float(dt), n_joints=member(plants, 0).arm.n, fields=fields, progress=progress)
    return _to_numpy(*out, config={"members": list(configs)} if configs else {}, dt=dt,
                     save_every=save_every)
