"""Closed-loop simulation: plant, controller and bookkeeping integrated together in ``lax.scan``.

The simulator knows the plant and the controller only through :mod:`hinfnn.protocols` (checked
once, by :func:`hinfnn.protocols.check`, before anything is traced):

* a *continuous* plant (:class:`~hinfnn.protocols.ContinuousPlant`) is integrated with the controller state and
  the accumulators by fixed-step RK4 (:class:`~hinfnn.sim.integrate.RK4`), the controller
  evaluated at every stage from that stage's measurement (the paper's continuous-time control),
  or held by a zero-order hold between samples (``control_period``: τ computed at each sample
  instant by the controller's ``sample`` method, its state advanced by forward Euler over the
  period);
* a *discrete* plant (:class:`~hinfnn.protocols.DiscretePlant`, a physics engine) advances itself by
  ``plant.step`` every ``dt`` with the held torque; it always runs in the sampled-data mode, and
  the accumulators advance by the rectangle rule.

The steps, the controller's period and the stored samples are a :class:`~hinfnn.sim.plan.StepPlan`.
A run is a jit-compiled program over a chunk of stored samples (about
:data:`~hinfnn.sim.plan.CHUNK_STEPS` steps, :meth:`~hinfnn.sim.plan.StepPlan.chunk`), called from
a Python loop over chunks (never over steps): a single
run's compiled program is the same for every horizon, dt, output interval and choice of stored
fields (a batch's, within one of three sizes of chunk), progress is reported and Ctrl-C is
honoured between chunks.
Inside a chunk, an outer scan takes one stored sample every ``save_every`` steps and an inner
loop runs the steps between them, keeping the record of the first (the RK4 step's first stage is
the evaluation at the sample instant, so the dynamics appear in the program once per RK4 stage,
not again for the samples); how the program is written for XLA's CPU runtime is a
:class:`~hinfnn._loop.LoopOptions` value, part of the program's key. The same program takes the last
sample (t_final) in the chunk that reaches it, so a run structure compiles one large program (the
final state is read from the last carry by a small one). What a sample holds is the recorder's
business (:mod:`hinfnn.sim.recorder`); how a run ended is a :class:`~hinfnn.status.RunStatus`.

The plant's held input (the joint disturbance) is evaluated at each step's midpoint; steps land
on its switching instants when dt divides them (checked by the scenario loader).

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

from .. import _linalg as la
from .._loop import SEQUENTIAL_VALUES, LoopOptions
from .._programs import ExportedProgram, KeptFunction
from .._pytree import all_finite, pytree_dataclass, structure_key
from ..errors import ConfigError, SimulationError
from .. import protocols
from ..protocols import check as check_protocols
from ..reference import check_references
from ..status import RunStatus, status_of
from .integrate import RK4
from .plan import SINGLE_RECORDS, StepPlan
from .recorder import STEP_MAXES, STEP_SUMS, Accumulators, bookkeeping, pick, select
from .trajectory import RunInfo, Trajectory


@pytree_dataclass
class SimState:
    """The integrated state: the plant's, the controller's (opaque) and the accumulators."""

    plant: object
    xc: object
    acc: Accumulators


@pytree_dataclass
class Limits:
    """A run stops (status ≠ 0) when |τ_i| or the penetration passes these."""

    torque: jax.Array = 1e5
    penetration: jax.Array = 0.05


@dataclasses.dataclass(frozen=True)
class Save:
    """What a run stores (``simulate(..., save=Save(...))``, as diffrax's ``SaveAt``): a sample
    every ``every`` steps, or every ``interval`` seconds (the largest divisor of the step count with
    ``every · dt ≤ interval``; default 1 ms), of the ``fields`` (names of
    :data:`hinfnn.fields.FIELDS` or ``"metrics"``; None: everything the run produces; ``t``
    always). :class:`~hinfnn.sim.plan.StepPlan` makes the steps of it. The same as the keywords
    ``save_every``, ``save_interval`` and ``fields``, which :func:`simulate` and
    :func:`simulate_batch` still accept (one or the other, not both)."""

    every: int | None = None
    interval: float | None = None
    fields: object = None

    @staticmethod
    def of(save: "Save | None", save_every, save_interval, fields) -> "Save":
        """``save``, or the keywords as a :class:`Save` (a ConfigError naming ``save`` when both
        are given)."""
        if save is None:
            return Save(save_every, save_interval, fields)
        if not isinstance(save, Save):
            raise ConfigError(f"must be a hinfnn.sim.Save, got {type(save).__name__}", key="save")
        if (save_every, save_interval, fields) != (None, None, None):
            raise ConfigError("give what to store once: save=Save(...) or the keywords save_every, save_interval "
                              f"and fields, not both (save={save!r})", key="save")
        return save


def _evaluate(plant, ctrl, ref, t, y: SimState, w, held, sampled, applied=None, sensed=None):
    """Measurement, controller output, the torque that drives the plant, and the record's plant and
    controller parts (keys starting with "_" are the simulator's own: the fault flags and
    measures). ``sensed``: what the plant's sensor last gave the controller (sampled control with
    a sensor: the law is evaluated on it; the true measurement is returned, for the bookkeeping);
    ``applied``: the torque the plant's actuator applies over the sample (sampled control with an
    actuator), see :func:`_actuated`."""
    meas, cache = plant.sense(t, y.plant)
    out = ctrl.evaluate(t, y.xc, meas if sensed is None else sensed, ref)
    tau = held if sampled else out.tau
    pr = plant.record(y.plant, w, cache)
    record = {"t": jnp.asarray(t, dtype=float), **pr.signals, "penetration": pr.penetration, **out.signals,
              "tau": tau, "e_u1": out.e_u1, "e_lam": out.e_lam,
              "_cfault": jnp.asarray(out.fault), "_cfault_value": jnp.asarray(out.fault_value, dtype=float),
              "_pfault": jnp.asarray(pr.fault), "_pfault_value": jnp.asarray(pr.fault_value, dtype=float),
              "_pfault_index": jnp.asarray(pr.fault_index, dtype=jnp.int32)}
    if out.deferred is not None:  # the controller's fields computed per stored sample (_derived)
        record["_deferred"] = out.deferred
    return meas, cache, out, _actuated(plant, y.plant, tau, applied, record), record


def _actuated(plant, y_plant, tau, applied, record):
    """The torque that drives the plant: the commanded ``tau`` itself for ideal motors; with the
    plant's actuator (:attr:`hinfnn.protocols.Plant.actuator`) the ``applied`` torque (sampled
    control; under continuous control τ saturated) less the joints' friction, the applied torque
    and whether a joint is at its limit recorded (``tau_applied``, ``torque_saturated``)."""
    act = plant.actuator
    if act is None:
        return tau
    applied = act.saturate(tau) if applied is None else applied
    record.update(tau_applied=applied, torque_saturated=act.saturated(applied))
    return applied - act.friction(plant.joints(y_plant)[1])


def plant_rhs(plant, t, y_plant, tau, w, cache=None):
    """The plant's part of :func:`rhs`: (d y_plant/dt, q̈) under the torque τ and the disturbance
    input w; ``cache``: the plant's sensing at (t, y_plant) (:meth:`sense`'s second result), sensed
    here when None. :mod:`hinfnn.analysis` linearises it alone for the sampled loop, where τ is
    held and the controller's output is not applied."""
    if cache is None:
        _, cache = plant.sense(t, y_plant)
    return plant.derivative(t, y_plant, tau, w, cache)


def rhs(plant, ctrl, ref, t, y: SimState, w, held=None, sampled: bool = False, book: bool = True, applied=None,
        sensed=None):
    """Time derivative of the whole closed-loop state of a continuous plant (plant, controller,
    accumulators) at (t, y) under the held input w, and the record there. The function the
    simulator integrates, and that :mod:`hinfnn.analysis` linearises. ``held``/``sampled``: the
    torque held by the sampled-data path (the controller state is then frozen between samples).
    ``book``: the theorems' bookkeeping (:func:`~hinfnn.sim.recorder.bookkeeping`); False: the
    accumulators' rates are zero and the record has none of its fields. ``applied``, ``sensed``:
    the plant's actuator and sensor under sampled control (:func:`_evaluate`)."""
    meas, cache, out, tau, record = _evaluate(plant, ctrl, ref, t, y, w, held, sampled, applied, sensed)
    dplant, qdd = plant_rhs(plant, t, y.plant, tau, w, cache)
    rates, kept = bookkeeping(ctrl, y.xc, out, meas.qd, qdd, y.acc, enabled=book)
    dxc = jax.tree.map(jnp.zeros_like, out.dstate) if sampled else out.dstate
    return SimState(plant=dplant, xc=dxc, acc=rates), {**record, **kept}


@pytree_dataclass
class Carry:
    """What the compiled loop carries from step to step.

    ``tau_peak``/``tau_tv``/``tau_prev``: max |τ_i| and Σ|τ_i(t_k) − τ_i(t_{k−1})| over the steps
    since the last record, and τ at the previous step (NaN before the first); ``sums``/``maxes``:
    the recorder's step summaries over those steps. Records taken every ``save_every`` steps thus
    still give the exact peak, total variation and RMS values over every step. A run that stops
    counts the step that stopped it and none after it: the first record after the stop summarises
    the steps from the previous record up to the stop (its other entries are the frozen state, the
    state at the start of that step), so the metrics of a partial run cover every step it ran.
    """

    y: SimState
    held: jax.Array  # the zero-order-held torque (sampled mode)
    #: sampled mode: the controller state the next sample's law reads (the update of the last
    #: sample); ``y.xc`` holds the state the held torque was computed from, which the records and
    #: the bookkeeping between samples read. None in continuous mode.
    xc_next: object
    status: jax.Array  # a RunStatus value
    t_fail: jax.Array
    bad_tau: jax.Array
    bad_pen: jax.Array
    bad_parts: jax.Array
    bad_fault: jax.Array  # the fault measure of the controller or the plant that stopped the run
    bad_fault_index: jax.Array  # which item (a joint) the plant's fault measure is of, -1: none
    tau_peak: jax.Array
    tau_tv: jax.Array
    tau_prev: jax.Array
    sums: dict
    maxes: dict
    sensor: object = None  # the plant's sensor's state (hinfnn.protocols.Plant.sensor; None: ideal)
    applied: object = None  # the torque the plant's actuator applies (sampled control; None: ideal)


#: The record's entries a step reads at every step (its checks and the step summaries); the others
#: are computed only at the steps that take a record.
EVERY_STEP = ("tau", "penetration", "e_u1", "e_lam", "_cfault", "_cfault_value", "_pfault", "_pfault_value",
              "_pfault_index")


def _step_fn(plant, ctrl, ref, limits, n_steps, dt, n_hold, sampled, fields, rolled=None, book: bool = True,
             loop: LoopOptions = LoopOptions()):
    """(sample, step): the sampled-mode controller update at step k, and one step k -> k + 1
    with failure detection (a no-op for k ≥ n_steps) that also returns the record at step k.
    ``rolled``: RK4's stages as a loop (default: the loop options' choice); ``book``: the
    theorems' bookkeeping integrated (:func:`rhs`); ``loop``: the loop options the step is written
    with (:meth:`~hinfnn._loop.LoopOptions.for_joints` of the plant)."""
    discrete = plant.discrete
    rolled = loop.rolled(plant.n) if rolled is None else rolled

    def sample(c: Carry, k, skip=False):
        """At a sample instant: τ held from now on, computed from the state of the previous
        sample's update (``c.xc_next``), which is now the state the law acts with (``y.xc``: what
        the records and the bookkeeping read until the next sample, as it acted); the controller's
        zero-order-hold update from it is kept for the next sample. The update runs only at sample
        instants (a ``lax.cond`` on the step index, which every member of a batch shares, so it
        stays a branch under ``vmap``); a stopped run (its own status) keeps what it held."""
        if not sampled:
            return c
        due = (jnp.mod(k, n_hold) == 0) & (k < n_steps) & ~jnp.asarray(skip)

        def update(c):
            t = k * dt
            y = c.y
            meas, _ = plant.sense(t, y.plant)
            running = c.status == 0

            def keep(new, old):
                return jax.tree.map(lambda a, b: jnp.where(running, a, b), new, old)

            extra = {}
            if plant.sensor is not None:  # what the robot's sensor gives at sample k // n_hold
                meas, state = plant.sensor.read(k // n_hold, n_hold * dt, meas, c.sensor)
                extra["sensor"] = keep(state, c.sensor)
            tau_s, xc_s = ctrl.sample(t, n_hold * dt, c.xc_next, meas, ref)
            if plant.actuator is not None:  # what the robot's motors apply over the sample
                extra["applied"] = jnp.where(running, plant.actuator.apply(tau_s, c.applied, n_hold * dt, k == 0),
                                             c.applied)
            return dataclasses.replace(c, y=SimState(plant=y.plant, xc=keep(c.xc_next, y.xc), acc=y.acc),
                                       held=jnp.where(running, tau_s, c.held), xc_next=keep(xc_s, c.xc_next), **extra)

        return jax.lax.cond(due, update, lambda c: c, c)

    def advance(t, y, w, held, take=None, applied=None, sensed=None):
        """(state after one step, the record at the step's start; with ``take`` False, only its
        entries every step reads: :data:`EVERY_STEP`). ``applied``, ``sensed``: the plant's
        actuator's torque and its sensor's last measurement (:func:`_evaluate`)."""
        if discrete:
            meas, cache, out, tau, record = _evaluate(plant, ctrl, ref, t, y, w, held, True, applied, sensed)
            new_plant, qdd = plant.step(t, y.plant, tau, dt)
            rates, kept = bookkeeping(ctrl, y.xc, out, meas.qd, qdd, y.acc, enabled=book)
            acc = jax.tree.map(lambda a, r: a + dt * r, y.acc, rates)
            return SimState(plant=new_plant, xc=y.xc, acc=acc), {**record, **kept}
        rk4 = RK4.of(rolled, loop.rolled_stages, loop.record_once)
        opts = dict(take=take, every=EVERY_STEP)
        if sampled and loop.frozen_law:
            # the law's state is frozen between samples (its rate is zero): RK4 integrates the
            # plant and the accumulators, the law's state passes through unchanged (as it would
            # with its zero rate: y + dt/6 · 0, exactly)
            def f(tt, part):
                d, aux = rhs(plant, ctrl, ref, tt, SimState(plant=part[0], xc=y.xc, acc=part[1]), w, held, True, book,
                             applied, sensed)
                return (d.plant, d.acc), aux

            (p_new, acc_new), aux = rk4.step(f, t, (y.plant, y.acc), dt, **opts)
            return SimState(plant=p_new, xc=protocols.constrain(ctrl, y.xc), acc=acc_new), aux
        y_new, aux = rk4.step(lambda tt, yy: rhs(plant, ctrl, ref, tt, yy, w, held, sampled, book, applied, sensed),
                              t, y, dt, **opts)
        return SimState(plant=y_new.plant, xc=protocols.constrain(ctrl, y_new.xc), acc=y_new.acc), aux

    def step(c: Carry, k, first):
        """Step k, and the record at step k (its start). ``first``: a record is taken at step k
        (its sample update is already done): the record's τ statistics cover the steps since the
        previous record, and they restart. At k = n_steps (t_final) the step is a no-op that
        gives the last record, with the last step's held input."""
        active = k < n_steps
        t = k * dt
        c = sample(c, k, skip=first)
        y_in = c.y
        y_new, aux = advance(t, y_in, plant.step_input(jnp.minimum(k, n_steps - 1) * dt, dt), c.held, take=first,
                             applied=c.applied if sampled else None, sensed=None if c.sensor is None else c.sensor.out)
        tau = aux["tau"]
        running = c.status == 0

        def own(new, old):  # a stopped run's steps (its frozen state) add nothing to the summaries
            return jnp.where(running, new, old)

        rec = dict(aux, tau_abs_max=own(jnp.maximum(c.tau_peak, jnp.abs(tau)), c.tau_peak),
                   tau_variation=own(c.tau_tv + jnp.where(jnp.isnan(c.tau_prev), 0.0, jnp.abs(tau - c.tau_prev)),
                                     c.tau_tv),
                   **{name: own(c.sums[name] + fn(aux), c.sums[name]) for name, fn in STEP_SUMS.items()},
                   **{name: own(jnp.maximum(c.maxes[name], fn(aux)), c.maxes[name]) for name, fn in STEP_MAXES.items()})
        tau_peak = jnp.max(jnp.abs(tau))
        pen = aux["penetration"]
        finite_parts = (all_finite(y_new.plant), all_finite(y_new.xc), all_finite(y_new.acc))
        parts = sum(jnp.where(ok, 0, 1 << i) for i, ok in enumerate(finite_parts)).astype(jnp.int32)
        code = jnp.select([parts != 0, tau_peak > limits.torque, pen > limits.penetration, aux["_cfault"],
                           aux["_pfault"]],
                          [int(RunStatus.NONFINITE), int(RunStatus.TORQUE_LIMIT), int(RunStatus.PENETRATION_LIMIT),
                           int(RunStatus.CONTROLLER_FAULT), int(RunStatus.PLANT_FAULT)], int(RunStatus.OK))
        code = jnp.where(active, code, int(RunStatus.OK))
        status = c.status
        first_fail = (status == 0) & (code != 0)
        status = jnp.where(status == 0, code, status)
        keep_old = (status != 0) | ~active
        count = active & ~first & running  # the step that stops the run is counted, none after it

        def stat(new, old):  # restart at a record, else accumulate over the counted steps
            return jnp.where(first, jnp.zeros_like(old), jnp.where(count, new, old))

        return Carry(
            y=jax.tree.map(lambda a, b: jnp.where(keep_old, a, b), y_in, y_new), held=c.held, xc_next=c.xc_next,
            status=status,
            t_fail=jnp.where(first_fail, jnp.where(code == 1, t + dt, t), c.t_fail),
            bad_tau=jnp.where(first_fail, tau_peak, c.bad_tau),
            bad_pen=jnp.where(first_fail, pen, c.bad_pen),
            bad_parts=jnp.where(first_fail, parts, c.bad_parts),
            bad_fault=jnp.where(first_fail, jnp.where(code == int(RunStatus.PLANT_FAULT), aux["_pfault_value"],
                                                      aux["_cfault_value"]), c.bad_fault),
            bad_fault_index=jnp.where(first_fail & (code == int(RunStatus.PLANT_FAULT)), aux["_pfault_index"],
                                      c.bad_fault_index),
            tau_peak=stat(rec["tau_abs_max"], c.tau_peak),
            tau_tv=stat(c.tau_tv + jnp.abs(tau - c.tau_prev), c.tau_tv),
            tau_prev=jnp.where(count | first, tau, c.tau_prev),
            sums={name: stat(rec[name], c.sums[name]) for name in STEP_SUMS},
            maxes={name: stat(rec[name], c.maxes[name]) for name in STEP_MAXES}, sensor=c.sensor,
            applied=c.applied), _stored(rec, fields)

    return sample, step


def _stored(rec, fields):
    """The stored part of a step's record, and what the controller's deferred fields are computed
    from (:meth:`~hinfnn.protocols.PerSample.deferred_fields`), kept until the sample is taken."""
    out = pick(rec, fields)
    if "_deferred" in rec:
        out["_deferred"] = rec["_deferred"]
    return out


def _derived(ctrl, rec, fields):
    """A stored sample with the controller's deferred fields computed from it, once per stored
    sample rather than at every RK4 stage of every step (σ_min(Ĵ) of a 6-DOF arm: an SVD), those
    asked for kept."""
    if "_deferred" not in rec:
        return rec
    rec = dict(rec)
    extra = protocols.deferred_fields(ctrl, rec.pop("_deferred"))
    return {**rec, **pick(extra, None if fields is None else tuple(f for f in fields if f in extra))}


def _chunk(plant, ctrl, ref, limits, carry, k0, n_steps, dt, n_hold, save_every, n_take, *, n_records, sampled,
           fields, book=True, loop: LoopOptions = LoopOptions(), kernels: la.Kernels = la.DEFAULT):
    """Records ``r = 0 … n_records − 1`` of a chunk starting at step ``k0``: record r is taken at
    step k = k0 + r · save_every, as the first of the ``save_every`` steps after it. Only the
    first ``n_take`` (traced) are taken; the other slots run no step and hold zeros.

    An outer scan over records, an inner loop over the steps between them that keeps the first
    step's record (every buffer it touches is small, so XLA runs its kernels inline). The
    record at k = n_steps (t_final) is the last one, given by one no-op step; records past it
    are padding and run no step. So one program takes every record, the final one included,
    with the dynamics in it once per RK4 stage and not again for the records, and the final
    state is the carry after the last chunk.

    The step is traced once: the record buffer's shapes (``jax.eval_shape``) and the loop body
    share that trace through ``jax.jit``'s trace cache (``inline=True`` puts the same operations
    in the program as a plain call would). Its arguments must then have the same types in both
    places (hence the strongly typed ``first``); if they did not, the step would be traced twice,
    with the same result (a test counts the traces), in about twice the time.

    ``loop``: the loop options made for the plant (and the batch); ``kernels``: the kernels the
    plant, the controller and the reference hold (:meth:`hinfnn._linalg.Kernels.hold`), which lay
    out the chunk's outputs."""
    ctrl = protocols.prepared(ctrl)  # its constants by the blocks the loop reads, cut once here
    sample, step = _step_fn(plant, ctrl, ref, limits, n_steps, dt, n_hold, sampled, fields, book=book, loop=loop)
    step = jax.jit(step, inline=True)

    def one_record(c, r):
        k = k0 + r * save_every
        taken = r < n_take
        c = sample(c, k, skip=~taken)
        rec0 = jax.tree.map(jnp.zeros_like, jax.eval_shape(step, c, k, jnp.asarray(True))[1])
        n_inner = jnp.where(taken & (k <= n_steps), jnp.clip(n_steps - k, 1, save_every), 0)

        def body(i, state):
            cc, rec = state
            cc, new = step(cc, k + i, jnp.asarray(i == 0, dtype=bool))
            # the step's record kept at the first step only (a branch: no select per field at the others)
            return cc, jax.lax.cond(i == 0, lambda a, b: a, lambda a, b: b, new, rec)

        c, rec = jax.lax.fori_loop(0, n_inner, body, (c, rec0))
        return c, _derived(ctrl, rec, fields)

    return kernels.default_layout(_record_scan(one_record, carry, n_records, loop.record_blocks))


def _record_scan(one_record, carry, n_records, blocks: bool = True):
    """``lax.scan(one_record, carry, arange(n_records))``, by blocks when ``blocks`` (the loop
    option ``record_blocks``): a scan over blocks of an inner scan over b samples, b the largest divisor
    of ``n_records`` whose b samples of the largest recorded array (one member's, under ``vmap``)
    hold at most :data:`hinfnn._loop.SEQUENTIAL_VALUES` values. The inner loop's body then touches
    no larger buffer, and XLA runs its kernels inline; only the block loop writes the chunk's
    stacked records. The same samples, in the same order."""
    shapes = jax.eval_shape(one_record, carry, jnp.zeros((), jnp.int64))[1]
    per = max([math.prod(x.shape) for x in jax.tree.leaves(shapes)] + [1])
    fits = [b for b in range(2, n_records + 1) if n_records % b == 0 and b * per <= SEQUENTIAL_VALUES]
    if not (blocks and fits):
        return jax.lax.scan(one_record, carry, jnp.arange(n_records))
    b = max(fits)

    def block(c, i):
        return jax.lax.scan(one_record, c, i * b + jnp.arange(b))

    carry, recs = jax.lax.scan(block, carry, jnp.arange(n_records // b))
    return carry, jax.tree.map(lambda x: x.reshape(n_records, *x.shape[2:]), recs)


def _final(plant, ctrl, ref, carry, kernels: la.Kernels = la.DEFAULT):
    """The full final state (the controller's arrays by name) and why the run stopped, from the
    carry after the last chunk. A controller fault's measure is the controller's
    (:meth:`~hinfnn.protocols.PerSample.fault_measure`), at the frozen state: the state at the
    start of the step that stopped the run, where the loop evaluated the fault."""
    y_end = carry.y
    q, qd = plant.joints(y_end.plant)
    xc_end = y_end.xc if carry.xc_next is None else carry.xc_next  # sampled: the last sample's update
    final = dict(q=q, qd=qd, **ctrl.state_arrays(xc_end), J=y_end.acc.J, J_aug=y_end.acc.J_aug,
                 supply=y_end.acc.supply)
    fault_value = carry.bad_fault
    if isinstance(ctrl, protocols.PerSample):
        meas, _ = plant.sense(carry.t_fail, y_end.plant)
        measure = protocols.fault_measure(ctrl, carry.t_fail, y_end.xc, meas, ref, fault_value)
        fault_value = jnp.where(carry.status == int(RunStatus.CONTROLLER_FAULT), measure, fault_value)
    details = dict(tau_peak=carry.bad_tau, penetration=carry.bad_pen, nonfinite_parts=carry.bad_parts,
                   fault_value=fault_value, fault_index=carry.bad_fault_index)
    return kernels.default_layout((carry.status, carry.t_fail, details, final))


def _init_carry(ctrl, y0, n, plant=None, sampled: bool = False):
    """The first carry, strongly typed so that the carry a chunk returns has the same types (no
    second compile); with the ``plant``'s sensor's state at the measurement of t = 0 and its
    actuator's applied torque (zero: the first sample is not rate-limited); ``sampled``: the
    sampled-data mode's (the controller state carried twice: :attr:`Carry.xc_next`)."""
    f64 = jnp.float64
    zero = jnp.zeros((), f64)
    sensor = applied = None
    if plant is not None and plant.sensor is not None:
        sensor = plant.sensor.start(plant.sense(jnp.zeros((), f64), y0.plant)[0])
    if plant is not None and plant.actuator is not None:
        applied = jnp.zeros(n, f64)
    # per-coordinate sums: e_u1 has the controller's m entries, e_λ its k
    sizes = {"tau_sq": n, "e_u1_sq": ctrl.m, "e_lam_sq": ctrl.k}
    return Carry(y=y0, held=jnp.zeros(n, f64), xc_next=y0.xc if sampled else None, status=jnp.zeros((), jnp.int32),
                 t_fail=jnp.array(jnp.nan, dtype=f64), bad_tau=zero, bad_pen=zero,
                 bad_parts=jnp.zeros((), jnp.int32), bad_fault=jnp.array(jnp.nan, dtype=f64),
                 bad_fault_index=jnp.full((), -1, jnp.int32),
                 tau_peak=jnp.zeros(n, f64), tau_tv=jnp.zeros(n, f64),
                 tau_prev=jnp.full(n, jnp.nan, f64),
                 sums={k: jnp.zeros(sizes.get(k, ()), f64) for k in STEP_SUMS},
                 maxes={k: jnp.zeros((), f64) for k in STEP_MAXES}, sensor=sensor, applied=applied)


def _with_options(make, loop: LoopOptions, members=None, n_joints: int = 2, name: str = "program"):
    """The program ``make(options, kernels)(*args)`` under the name ``name`` (the compiled
    program's name, e.g. ``jit__chunk``): the loop options ``loop`` (made for the plant,
    :meth:`~hinfnn._loop.LoopOptions.for_joints`), their kernels
    (:meth:`hinfnn._linalg.Kernels.of`) held by every object of the arguments
    (:meth:`~hinfnn._linalg.Kernels.hold`), both chosen once, here, as the program is traced.
    ``members``: a batch's size from the arguments, for the options a batch decides
    (``member_minor``)."""

    def traced(*args):
        opts = loop if members is None else loop.for_joints(n_joints, members(*args))
        kernels = la.Kernels.of(opts)
        return make(opts, kernels)(*kernels.hold(args))

    traced.__name__ = traced.__qualname__ = name
    return traced


@functools.lru_cache(maxsize=128)
def _compiled(in_axes, n_records, sampled, fields, loop: LoopOptions = LoopOptions(), n_joints: int = 2,
              book: bool = True):
    """(chunk, final, init) compiled for one structure; in_axes=None for a single run; ``book``: the
    theorems' bookkeeping integrated (part of the key, as the structure); traced with
    the loop options ``loop`` as they are for a plant of ``n_joints`` joints
    (:meth:`~hinfnn._loop.LoopOptions.for_joints`, part of the key), compiled with their XLA options
    (:meth:`~hinfnn._loop.LoopOptions.compiler_options`).

    Horizon, dt, the hold period, the steps between samples and the samples a chunk takes are
    traced arguments, so a new t_final, dt or output interval reuses the compiled program (see
    :meth:`~hinfnn.sim.plan.StepPlan.chunk`). The chunk program is also kept traced and lowered
    between processes (:class:`~hinfnn._programs.ExportedProgram`)."""
    options = loop.compiler_options(n_joints)
    loop = loop.for_joints(n_joints)

    def chunk(opts, kernels):
        fn = functools.partial(_chunk, n_records=n_records, sampled=sampled, fields=fields, book=book, loop=opts,
                               kernels=kernels)
        if in_axes is None:
            return fn
        p, c, r, lim = in_axes
        return jax.vmap(fn, in_axes=(p, c, r, lim, 0, None, None, None, None, None, None))

    def final(opts, kernels):
        fn = functools.partial(_final, kernels=kernels)
        return fn if in_axes is None else jax.vmap(fn, in_axes=(in_axes[0], in_axes[1], in_axes[2], 0))

    def init(opts, kernels):
        fn = functools.partial(_init_carry, sampled=sampled)
        return fn if in_axes is None else jax.vmap(fn, in_axes=(in_axes[1], 0, None, in_axes[0]))

    members = {"chunk": None, "final": None}
    if in_axes is not None:
        # the batch's own options (member_minor) by its size: the leading axis of the carry
        members = {"chunk": lambda *a: jax.tree.leaves(a[4])[0].shape[0],
                   "final": lambda *a: jax.tree.leaves(a[3])[0].shape[0]}
    chunk = ExportedProgram(_with_options(chunk, loop, members["chunk"], n_joints, "_chunk"), "chunk",
                            (in_axes, n_records, sampled, fields, loop, book), carry_arg=4,
                            compiler_options=options)  # kept lowered on disk (hinfnn._programs)
    final = KeptFunction(_with_options(final, loop, members["final"], n_joints, "_final"), "final", (in_axes, loop),
                         compiler_options=options)
    return chunk, final, jax.jit(_with_options(init, loop, name="_init_carry"), static_argnums=2)


def release_programs() -> None:
    """Drop every compiled program this process holds (hinfnn's and JAX's in-memory caches; the
    persistent compilation cache on disk is kept, so a program needed again is loaded, not
    compiled). A workflow that runs many different arms in one process calls it between them:
    XLA's CPU backend keeps each program's machine code in one region of memory, and a process that
    compiled some forty large arm programs (``hinfnn gallery --beyond``: three arms, each with its
    runs, batches and linearisations) failed there with "LLVM ERROR: Unable to allocate section
    memory"."""
    import gc

    _compiled.cache_clear()
    jax.clear_caches()
    gc.collect()


@dataclasses.dataclass(frozen=True)
class RunProgram:
    """The compiled programs of one run structure, built once and used by every caller: a single
    run (:func:`simulate`) and a batch (:func:`simulate_batch`), the two public entry points of a
    run, through :meth:`run`; the compile-ahead of :func:`~hinfnn.sim.simulate_many`
    (:meth:`lower_ahead`, :meth:`lower_ahead_batch`, through :meth:`lower`) and the memory plan of
    :mod:`hinfnn.resources` (:meth:`record_shapes`, through :meth:`shapes`). The chunk's traced
    scalars are :meth:`chunk_scalars`.

    The structure: ``in_axes`` (None for a single run; else, for the plant, the controller, the
    reference and the limits, 0 when stacked along a batch axis and None when shared), the
    chunk's record ``slots`` (:meth:`hinfnn.sim.plan.StepPlan.chunk`), sampled or continuous
    control, the stored ``fields`` (None: a single run's program stores every field), the loop
    options, the plant's joints and the theorems' bookkeeping. Its programs (chunk, final state,
    first carry) are :func:`_compiled` for that key, traced once per process (and kept lowered on
    disk between processes). Horizon, dt and output interval are the chunk's traced scalars
    (:meth:`scalars`), not part of the structure."""

    in_axes: tuple | None
    slots: int
    sampled: bool
    fields: tuple | None
    loop: LoopOptions
    n_joints: int
    book: bool = True

    @classmethod
    def of(cls, plan: StepPlan, in_axes, fields, loop: LoopOptions, n_joints: int, book: bool = True) -> "RunProgram":
        """The program of a run of ``plan`` (a single run when ``in_axes`` is None, whose program
        stores every field, the driver keeping those asked for: one program; its record slots are
        independent of the horizon)."""
        slots, _ = plan.chunk(batched=in_axes is not None)
        return cls(in_axes, slots, plan.sampled, fields if in_axes is not None else None, loop, n_joints, book)

    @classmethod
    def single(cls, n_joints: int, sampled: bool, loop: LoopOptions, book: bool = True) -> "RunProgram":
        """The program of every single run of a plant of ``n_joints`` joints (any horizon, dt,
        output interval and stored fields)."""
        return cls(None, SINGLE_RECORDS, sampled, None, loop, n_joints, book)

    @property
    def programs(self) -> tuple:
        """(chunk, final, init): the compiled programs (:func:`_compiled`, one per structure)."""
        return _compiled(self.in_axes, self.slots, self.sampled, self.fields, self.loop, self.n_joints, self.book)

    def scalars(self, plan: StepPlan) -> tuple:
        """(samples per chunk, the chunk's traced scalars) of a run of ``plan``."""
        _, per_chunk = plan.chunk(batched=self.in_axes is not None)
        return per_chunk, RunProgram.chunk_scalars(plan.n_steps, plan.dt, plan.n_hold, plan.save_every, per_chunk)

    def _args(self, plant, ctrl, ref, limits, y0, plan: StepPlan | None, dt: float):
        """(chunk, the arguments a chunk call gets, the carry as its type): their values do not
        matter to :meth:`lower` and :meth:`shapes` (a plan of one step of ``dt`` without ``plan``)."""
        chunk, _, init = self.programs
        carry = init.eval_shape(ctrl, y0, self.n_joints, plant)
        scalars = RunProgram.chunk_scalars(1, dt, 1, 1, 1) if plan is None else self.scalars(plan)[1]
        return chunk, (plant, ctrl, ref, limits, carry, jnp.zeros((), jnp.int64), *scalars)

    def lower(self, plant, ctrl, ref, limits, y0, *, plan: StepPlan | None = None, dt: float = 1e-4):
        """The chunk program lowered for these arguments' types, or None when it is not kept
        between processes (:meth:`hinfnn._programs.KeptFunction.lower_ahead`); nothing is compiled
        or run."""
        chunk, args = self._args(plant, ctrl, ref, limits, y0, plan, dt)
        return chunk.lower_ahead(*args)

    def shapes(self, plant, ctrl, ref, limits, y0, *, dt: float = 1e-4) -> dict:
        """``{field: ShapeDtypeStruct}`` of one stored sample of every field the chunk records,
        from the chunk program itself (``eval_shape``: traced once, and ``jax.jit`` keeps that
        trace for the run's first chunk)."""
        chunk, args = self._args(plant, ctrl, ref, limits, y0, None, dt)
        records = chunk.eval_shape(*args)[1]
        axis = 1 if self.in_axes is not None else 0
        return {k: jax.ShapeDtypeStruct(v.shape[:axis] + v.shape[axis + 1:], v.dtype) for k, v in records.items()}

    def run(self, plant, ctrl, ref, limits, y0, plan: StepPlan, *, fields, progress=None, what: str = ""):
        """Run the chunks of ``plan`` from Python; returns (records, status, t_fail, details, final).

        The n_records + 1 records (t = 0, …, t_final) are copied chunk by chunk into arrays
        allocated once, so memory is what is stored, never proportional to the steps. ``fields``:
        those kept (a single run's program records them all)."""
        n_total, n_steps, save_every = plan.samples, plan.n_steps, plan.save_every
        chunk, final, init = self.programs
        per_chunk, scalars = self.scalars(plan)
        carry = init(ctrl, y0, self.n_joints, plant)
        axis = 0 if self.in_axes is None else 1  # the time axis of the records
        out: dict[str, np.ndarray] = {}
        n_chunks = -(-n_total // per_chunk)

        def store(c, rec):
            start = c * per_chunk
            stop = min(start + per_chunk, n_total)
            for k, v in pick(rec, fields).items():  # the fields asked for (a single run's program has all)
                v = np.asarray(v)
                if k not in out:
                    shape = v.shape[:axis] + (n_total,) + v.shape[axis + 1:]
                    out[k] = np.empty(shape, v.dtype)
                if axis == 0:
                    out[k][start:stop] = v[:stop - start]
                else:
                    out[k][:, start:stop] = v[:, :stop - start]
            if progress is not None:
                progress(min(stop * save_every, n_steps), n_steps, what)

        pending = None  # the previous chunk's records, copied while the next chunk runs
        for c in range(n_chunks):
            k0 = jnp.asarray(c * per_chunk * save_every, dtype=jnp.int64)  # typed as chunk_scalars
            carry, rec = chunk(plant, ctrl, ref, limits, carry, k0, *scalars)
            if pending is not None:
                store(*pending)
            pending = (c, rec)
        store(*pending)  # n_chunks >= 1
        del pending
        return (out, *final(plant, ctrl, ref, carry))

    @staticmethod
    def chunk_scalars(n_steps, dt, n_hold, save_every, per_chunk):
        """The chunk program's traced scalars as :meth:`run` passes them (their types are part of
        the program's signature: :meth:`RunProgram.shapes` traces the same one)."""
        i64 = functools.partial(jnp.asarray, dtype=jnp.int64)
        return (i64(n_steps), jnp.asarray(dt, dtype=jnp.float64), i64(max(n_hold, 1)), i64(save_every),
                i64(per_chunk))

    @classmethod
    def lower_ahead(cls, plant, controller, reference, *, q0, dt: float = 1e-4, control_period: float | None = None,
                    limits: Limits | None = None, loop: LoopOptions | None = None, bookkeeping: bool = True):
        """The chunk program a single run of these objects calls (:func:`simulate`; a group of one in
        :func:`~hinfnn.sim.simulate_many`) lowered for its arguments' types, or None when the program
        is not kept between processes (:meth:`hinfnn._programs.KeptFunction.lower_ahead`). Nothing is
        compiled or run; its ``.compile()`` (XLA's work, without Python's lock) done before the run
        leaves the run's first chunk nothing to compile: :func:`~hinfnn.sim.simulate_many` compiles its
        groups' programs so, at once."""
        sampled = control_period is not None or plant.discrete
        y0 = initial_state(plant, controller, q0=q0)
        program = cls.single(plant.n, sampled, loop or LoopOptions(), _flag(bookkeeping, "bookkeeping"))
        return program.lower(plant, controller, reference, limits or Limits(), y0, dt=dt)

    @classmethod
    def lower_ahead_batch(cls, plants: list, controllers: list, references: list, *, q0: list, limits: list,
                          t_final: float, dt: float = 1e-4, control_period: float | None = None,
                          save_interval: float | None = None, save_every: int | None = None, fields=None,
                          loop: LoopOptions | None = None, bookkeeping: bool = True):
        """:meth:`lower_ahead` for :func:`simulate_batch` of these lists of B members (q0 and limits
        one per member: a group of :func:`~hinfnn.sim.simulate_many`): the batch's chunk program
        lowered for its first group of members, or None when it is not kept. The members are stacked
        as the run stacks them (their start, which changes values and not types, is not run); nothing
        is compiled or run."""
        loop = loop or LoopOptions()
        B, plant0 = len(plants), plants[0]
        if B == 1:  # simulate_batch runs one member unbatched
            return cls.lower_ahead(plant0, controllers[0], references[0], q0=q0[0], dt=dt,
                                   control_period=control_period, limits=limits[0], loop=loop, bookkeeping=bookkeeping)
        plan = StepPlan.make(t_final, dt, control_period=control_period, save_interval=save_interval,
                             save_every=save_every, discrete=plant0.discrete)
        program = cls.of(plan, (0, 0, 0, 0), select(fields), loop, plant0.n, _flag(bookkeeping, "bookkeeping"))
        idx = loop.groups(B, plant0.n)[0]
        take = functools.partial(_take, idx=idx) if idx.size != B else (lambda x: x)
        args = [take(stack(list(x))) for x in (plants, controllers, references, limits)]
        y0 = take(stack([initial_state(p, c, q0=q) for p, c, q in zip(plants, controllers, q0)]))
        return program.lower(*args, y0, plan=plan)

    @classmethod
    def record_shapes(cls, plant, controller, reference, *, q0, dt: float = 1e-4, control_period: float | None = None,
                      fields=None, limits: Limits | None = None, single: bool = False,
                      loop: LoopOptions | None = None, bookkeeping: bool = True) -> dict:
        """``{field: (shape, dtype)}`` of one stored sample of a run, found by tracing (``eval_shape``:
        nothing is compiled or run). What a run stores is this times its number of samples;
        :mod:`hinfnn.resources` uses it to estimate memory before a run.

        ``single``: the run is simulated alone (:func:`simulate`, or a group of one in
        :func:`~hinfnn.sim.simulate_many`), and its own chunk program is what is traced: ``jax.jit``
        keeps that trace, so the run's first chunk does not trace it again (the memory plan costs no
        trace of its own). Otherwise
        (members of a batch, whose program is another) it is one step with RK4's stages rolled (plant
        and controller traced once, not four times: the shapes are the same). Either way the result is
        kept for the process's later runs of the same structure (the same pytree structure and array
        types)."""
        fields = select(fields)
        loop = loop or LoopOptions()
        sampled = control_period is not None or plant.discrete
        y0 = initial_state(plant, controller, q0=q0)
        args = (plant, controller, reference, limits or Limits(), y0)
        book = _flag(bookkeeping, "bookkeeping")
        key = (*structure_key(args), float(dt), sampled, fields, loop, book)
        if key in _RECORD_SHAPES:
            return dict(_RECORD_SHAPES[key])

        def one(opts, kernels):
            def run(plant, ctrl, ref, lim, y0):
                carry = _init_carry(ctrl, y0, plant.n, plant, sampled)
                _, step = _step_fn(plant, ctrl, ref, lim, 1, dt, 1, sampled, fields, rolled=True, book=book, loop=opts)
                return _derived(ctrl, step(carry, jnp.zeros((), jnp.int64), True)[1], fields)

            return run

        if single:  # the single-run program as a run calls it
            out = pick(cls.single(plant.n, sampled, loop, book).shapes(*args, dt=dt), fields)
        else:
            out = jax.eval_shape(_with_options(one, loop.for_joints(plant.n), name="one"), *args)
        shapes = {k: (tuple(v.shape), np.dtype(v.dtype)) for k, v in out.items()}
        if len(_RECORD_SHAPES) < 256:
            _RECORD_SHAPES[key] = shapes
        return dict(shapes)


def _drive(plant, ctrl, ref, limits, y0, in_axes, *, plan: StepPlan, n_joints, fields, loop: LoopOptions,
           book: bool = True, progress=None, what: str = ""):
    """:meth:`RunProgram.run` of the program of this structure."""
    program = RunProgram.of(plan, in_axes, fields, loop, n_joints, book)
    return program.run(plant, ctrl, ref, limits, y0, plan, fields=fields, progress=progress, what=what)


def initial_state(plant, ctrl, *, q0=None, u1_0=None, qd0=None, xc0=None) -> SimState:
    """The state at t = 0: the plant at q0 (or, from ``u1_0``, the start pose with the TRUE
    end-effector at x1 = u1_0 on the TRUE surface, ``plant.initial_q``), q̇ = qd0 (default 0),
    controller state ``ctrl.init()`` (z = 0, weights 0) unless given, accumulators 0."""
    if q0 is None:
        if u1_0 is None:
            raise ConfigError("give the start pose: q0 (joint angles) or u1_0 (the motion coordinate of the "
                              "end-effector on the true surface)", key="initial")
        q0 = plant.initial_q(u1_0)
    for key, v in (("q0", q0), ("qd0", qd0)):
        if v is None:
            continue
        dtype = v.dtype if hasattr(v, "dtype") else np.asarray(v).dtype
        if np.shape(v) != (plant.n,) or dtype.kind not in "fiu":
            raise ConfigError(f"must be {plant.n} real numbers (the arm has n = {plant.n} joints), got "
                              f"{dtype} values of shape {np.shape(v)}", key=key)
    return SimState(plant=plant.initial_state(jnp.asarray(q0, dtype=float), qd0),
                    xc=ctrl.init() if xc0 is None else xc0, acc=Accumulators.zero())


@jax.jit
def _started(plant, ctrl, ref, y0: SimState) -> SimState:
    """The state at t = 0 with the controller's ``start`` applied to the first measurement."""
    meas, _ = plant.sense(0.0, y0.plant)
    return SimState(plant=y0.plant, xc=ctrl.start(0.0, y0.xc, meas, ref), acc=y0.acc)


def start(plant, ctrl, ref, y0: SimState) -> SimState:
    """:func:`_started` when the controller needs it (one compiled program), else ``y0``."""
    return _started(plant, ctrl, ref, y0) if protocols.needs_start(ctrl) else y0


def _to_numpy(rec, status, t_fail, details, final, *, info, plan: StepPlan, plant, ctrl,
              book: bool = True) -> Trajectory:
    arrays = {k: np.asarray(v) for k, v in rec.items()}
    final = {k: np.asarray(v) for k, v in final.items()}
    if not book:  # the accumulators were not integrated: their final values are not known
        final.update({k: np.full_like(final[k], np.nan) for k in ("J", "J_aug", "supply")})
    details = {k: np.asarray(v) for k, v in details.items()}
    details.update(controller_fault=ctrl.fault_name, plant_fault=plant.fault_name)
    index = details.pop("fault_index")
    items = [plant.fault_item(int(i)) if i >= 0 else "" for i in np.ravel(index)]
    details["fault_item"] = np.asarray(items).reshape(np.shape(index)) if np.ndim(index) else items[0]
    return Trajectory(arrays=arrays, status=np.asarray(status), t_fail=np.asarray(t_fail), fail_details=details,
                      dt=plan.dt, save_every=plan.save_every, final=final, info=info)


def simulate(plant, controller, reference, *, t_final: float = 10.0, dt: float = 1e-4,
             q0=None, u1_0=None, qd0=None, xc0=None, save: Save | None = None,
             control_period: float | None = None, limits: Limits | None = None,
             info: RunInfo | None = None, raise_on_failure: bool = True, progress=None,
             loop: LoopOptions | None = None, bookkeeping: bool = True, save_every: int | None = None,
             save_interval: float | None = None, fields=None) -> Trajectory:
    """Simulate one closed-loop run; returns a :class:`Trajectory` sampled every ``save_every``
    steps (t = 0, …, t_final).

    Start: ``q0`` (joint angles), or ``u1_0`` (the end-effector's motion coordinate on the true
    surface; the plant's ``initial_q`` finds the pose). Storage (``save``, a :class:`Save`; or the
    keywords ``save_every``, ``save_interval``, ``fields`` of the same meaning): a sample every
    ``save_every`` steps; by default the largest divisor of the step count with ``save_every · dt ≤
    save_interval`` (default 1 ms: every 10th step at dt = 1e-4; :class:`~hinfnn.sim.plan.StepPlan`).
    The step summaries (``tau_abs_max``,
    ``tau_variation``, ``tau_sq``, ``e_u1_sq``, ...) still cover every step, so
    :func:`~hinfnn.compute_metrics` does not depend on the decimation. ``fields``: what to store,
    names of :data:`hinfnn.fields.FIELDS` or ``"metrics"`` (default: everything the run
    produces; ``t`` always); memory is what is stored. ``control_period``: sampled-data control
    with zero-order hold at that period (a discrete plant always runs this way, default: every
    step).

    Raises :class:`~hinfnn.errors.SimulationError` with the time and the offending quantities
    if the state becomes non-finite or a limit is passed (unless ``raise_on_failure=False``;
    the trajectory is then frozen at its last good state from the failing step on).
    ``progress(steps_done, steps_total, what)``, if given, is called after each compiled chunk (about
    :data:`~hinfnn.sim.plan.CHUNK_STEPS` steps; 200 when every step is stored). ``loop``: how the
    compiled program is written (:class:`~hinfnn._loop.LoopOptions`; default: all options on).
    ``bookkeeping``: integrate the theorems' bookkeeping of a dissipative controller (J, J_aug and
    the supply along the run; V, f_p, f_f recorded). False (``simulation.bookkeeping = false``):
    none of it is computed or recorded, the final J, J_aug and supply are NaN, and the metrics of
    the dissipation inequality are not reported; everything else is the same run (to rounding).
    Under sampled control it is most of what a step costs besides the plant (the law evaluated at
    RK4's four stages between samples; docs/performance.md, "The limits").
    """
    from .._config import require_x64

    require_x64()
    save = Save.of(save, save_every, save_interval, fields)
    save_every, save_interval, fields = save.every, save.interval, save.fields
    check_protocols(plant, controller)
    check_references([(reference, controller.m, controller.k)])
    plan = StepPlan.make(t_final, dt, control_period=control_period, save_interval=save_interval,
                         save_every=save_every, discrete=plant.discrete)
    check_instruments(plant, plan.sampled)
    fields = select(fields)
    y0 = initial_state(plant, controller, q0=q0, u1_0=u1_0, qd0=qd0, xc0=xc0)
    controller.check_start(plant.joints(y0.plant)[0])
    if xc0 is None:
        y0 = start(plant, controller, reference, y0)
    book = _flag(bookkeeping, "bookkeeping")
    out = _drive(plant, controller, reference, limits or Limits(), y0, None, plan=plan, n_joints=plant.n,
                 fields=fields, loop=loop or LoopOptions(), book=book, progress=progress,
                 what=info.name if info else "")
    traj = _to_numpy(*out, info=info or RunInfo(kind=controller.kind), plan=plan, plant=plant, ctrl=controller,
                     book=book)
    if raise_on_failure and int(traj.status) != 0:
        raise failure_error(traj)
    return traj


def check_instruments(plant, sampled: bool) -> None:
    """Refuse what the plant's sensor and motors cannot do under continuous control (a
    :class:`ConfigError` naming the key): a sensor's noise is drawn, its delay counted and its
    filter stepped once per control sample, and a torque rate is a change from one sample to the
    next; the continuous law has no samples. Saturation and joint friction need none."""
    if sampled:
        return
    if plant.sensor is not None:
        raise ConfigError("a sensor model (noise, bias, delay or bandwidth) acts once per control sample; continuous "
                          "control has none: set simulation.control = \"sampled\" with a simulation.control_period, "
                          "or leave plant.sensor ideal", key="plant.sensor")
    if plant.actuator is not None and plant.actuator.rate_limited:
        raise ConfigError("a torque rate limit acts from one control sample to the next; continuous control has none: "
                          "set simulation.control = \"sampled\", or leave it \"none\"",
                          key="plant.actuator.torque_rate_limit")


def _flag(value, name: str) -> bool:
    """A yes/no option of a run, given as a bool (a string such as "false" would be true)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"must be True or False, got {value!r}", key=name)
    return bool(value)


def failure_error(traj: Trajectory) -> SimulationError:
    """A :class:`SimulationError` describing why a (single) run stopped."""
    t = float(traj.t_fail)
    msg = f"run stopped at t = {t:.6g} s: {traj.reason}"
    return SimulationError(msg, t_fail=t, details=traj.details())


def stack(items):
    """Stack a list of pytrees of identical structure into one with a leading batch axis."""
    treedefs = {jax.tree.structure(x) for x in items}
    if len(treedefs) != 1:
        raise ConfigError("batch members differ in structure (controller kind, network sizes or "
                          "model types); run them as separate batches")
    return jax.tree.map(_stack_leaves, *items)


def _stack_leaves(*xs):
    """One leaf of :func:`stack`: by NumPy on the host when every member's leaf is a value (one
    copy to the device), else by ``jnp.stack``. ``jnp.stack`` of B values compiles a program of B
    operands for each leaf shape, which took most of a large UR5 batch's first run."""
    if any(isinstance(x, jax.core.Tracer) for x in xs):
        return jnp.stack([jnp.asarray(x) for x in xs])
    return jnp.asarray(np.stack([np.asarray(x) for x in xs]))


def simulate_batch(plants, controllers, references, *, t_final: float = 10.0, dt: float = 1e-4,
                   q0=None, u1_0=None, save: Save | None = None,
                   control_period: float | None = None, limits=None, infos: list | None = None,
                   progress=None, loop: LoopOptions | None = None, bookkeeping: bool = True,
                   save_every: int | None = None, save_interval: float | None = None, fields=None) -> Trajectory:
    """Simulate B runs as ONE program (``jax.vmap`` of :func:`simulate`'s run).

    ``plants``, ``controllers``, ``references`` (and ``limits``): each either a list of B objects
    (stacked along a new axis) or a single object shared by every member (a shared plant with a
    sensor gives member i the noise stream ``sensor.stream(i)``: independent members; a list keeps
    each plant's own). ``q0``/``u1_0`` may be
    lists too. Members that fail are marked in ``status``/``t_fail`` and do not stop the others;
    nothing is raised for them. ``save`` (or ``save_every``, ``save_interval``, ``fields``),
    ``progress`` and ``bookkeeping`` as for :func:`simulate`; a batch of B runs stores B times what one run stores.
    More than ``loop.batch_group`` members (by default 100 for the two-link arm, 4,096 for larger arms) run
    as equal groups, one after the other, through the same compiled program
    (:class:`~hinfnn._loop.LoopOptions`: faster; the numbers to rounding, as any other batch size).
    """
    from .._config import require_x64

    require_x64()
    save = Save.of(save, save_every, save_interval, fields)
    save_every, save_interval, fields = save.every, save.interval, save.fields
    loop = loop or LoopOptions()
    listed = [x for x in (plants, controllers, references, limits) if isinstance(x, (list, tuple))]
    if not listed:
        raise ConfigError("simulate_batch needs at least one list of plants, controllers or references")
    sizes = {len(x) for x in listed}
    if len(sizes) != 1:
        raise ConfigError(f"batch lists have different lengths {sorted(sizes)}")
    (B,) = sizes
    if B == 0:
        raise ConfigError("simulate_batch needs at least one member: the lists of plants, controllers or "
                          "references are empty")

    def member(x, i):
        return x[i] if isinstance(x, (list, tuple)) else x

    if not isinstance(plants, (list, tuple)) and plants.sensor is not None:  # each member its own noise stream
        plants = [plants.with_sensor(plants.sensor.stream(i)) for i in range(B)]
    for i in range(B):
        check_protocols(member(plants, i), member(controllers, i))
    check_references((member(references, i), member(controllers, i).m, member(controllers, i).k) for i in range(B))
    q0s = q0 if isinstance(q0, (list, tuple)) else [q0] * B
    u1s = u1_0 if isinstance(u1_0, (list, tuple, np.ndarray)) else [u1_0] * B
    inits: dict = {}  # a controller's initial state once per object, not once per member that shares it
    y0s = []
    for i in range(B):
        c = member(controllers, i)
        if id(c) not in inits:
            inits[id(c)] = c.init()
        y0s.append(initial_state(member(plants, i), c, q0=q0s[i], u1_0=u1s[i], xc0=inits[id(c)]))
    for i in range(B):
        member(controllers, i).check_start(member(plants, i).joints(y0s[i].plant)[0])
        y0s[i] = start(member(plants, i), member(controllers, i), member(references, i), y0s[i])
    plant0, ctrl0 = member(plants, 0), member(controllers, 0)
    plan = StepPlan.make(t_final, dt, control_period=control_period, save_interval=save_interval,
                         save_every=save_every, discrete=plant0.discrete)
    for i in range(B if isinstance(plants, (list, tuple)) else 1):
        check_instruments(member(plants, i), plan.sampled)
    fields = select(fields)
    info = tuple(infos) if infos else tuple(RunInfo(kind=member(controllers, i).kind) for i in range(B))
    limits = limits if limits is not None else Limits()
    if B == 1:  # the unbatched program (a vmap over one member runs slower), then a batch axis
        args, y0, axes = (member(plants, 0), member(controllers, 0), member(references, 0), member(limits, 0)), y0s[0], None
    else:
        args, axes = [], []
        for x in (plants, controllers, references, limits):
            if isinstance(x, (list, tuple)):
                args.append(stack(list(x)))
                axes.append(0)
            else:
                args.append(x)
                axes.append(None)
        y0, axes = stack(y0s), tuple(axes)
    book = _flag(bookkeeping, "bookkeeping")
    opts = dict(plan=plan, n_joints=plant0.n, fields=fields, loop=loop, book=book)
    groups = loop.groups(B, plant0.n)
    if len(groups) == 1:
        out = _drive(*args, y0, axes, progress=progress, **opts)
    else:  # a large batch as equal groups run one after the other (one program; hinfnn._loop)
        parts = []
        for i, idx in enumerate(groups):
            take = functools.partial(_take, idx=idx)
            sub_args = [x if ax is None else take(x) for x, ax in zip(args, axes)]
            report = None if progress is None else functools.partial(_group_progress, progress, i, len(groups))
            parts.append(_drive(*sub_args, take(y0), axes, progress=report, **opts))
        out = jax.tree.map(lambda *xs: np.concatenate([np.asarray(x) for x in xs])[:B], *parts)
    if B == 1:
        out = jax.tree.map(lambda a: np.expand_dims(np.asarray(a), 0), out)
    return _to_numpy(*out, info=info, plan=plan, plant=plant0, ctrl=ctrl0, book=book)


def _take(tree, idx):
    """Members ``idx`` of a stacked pytree."""
    return jax.tree.map(lambda a: jnp.asarray(a)[idx], tree)


def _group_progress(progress, i, n_groups, done, total, what=""):
    progress(i * total + done, n_groups * total, what)


#: RunProgram.record_shapes' results by run structure (this process).
_RECORD_SHAPES: dict = {}
