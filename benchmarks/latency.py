"""Latency of the sampled controller step as a 1 kHz robot loop calls it from Python.

For each controller of the paper scenario (FL-like, H∞-only, adaptive H∞ NN with the 120-unit
F_f network and with a 60-unit variant), a :class:`hinfnn.SampledController` is called
``n_calls`` times from a Python loop, after a warm-up, with a changing, realistic measurement:
the q, q̇, F of a 1 s closed-loop simulation of the paper scenario sampled at 1 kHz, replayed in
order (cycled), t advancing by the period at each call. The timed region (``perf_counter_ns``)
is what a robot loop does per sample: hand the sensor arrays over, run the compiled update, and
get τ back as a NumPy array (waiting for the result). The garbage collector is off during the
timed loop (as in a real-time loop). Reported: median, p90, p99 and max latency in µs, and XLA's
cost estimate of the compiled program. No assertions: speed is measured here, never in tests/.

Entry points timed (``--variants`` also times the alternatives that were tried, interleaved,
see :func:`compare_variants`):

* ``loop``: ``tau = loop.update(t, period, q, qd, force)`` of a :class:`hinfnn.controllers.SampledLoop`
  (τ returned as NumPy): the fast path. For the paper's 2-joint arm its program on one packed
  buffer (``SampledController._step_packed``); for arms of 3 joints or more ``_step_leaves_kept`` on the packed
  sample and the state's blocks kept on the device (no buffer above 512 bytes);
* ``pytree``: ``tau, state = sc._update(t, period, state, Measurement(q, qd, force))`` (the compiled
  pytree update the robot layer replays a run with: ``step`` under ``jax.jit``) followed by
  ``np.asarray(tau)``.

Two properties of XLA's CPU runtime decide much of the cost (JAX 0.10.2):

* with JAX's CPU async dispatch on (the default), the PJRT CPU client runs a program inline on
  the calling thread only when its cost estimate is below 1000 flops, and otherwise hands it to
  a worker thread (one thread switch per call). The 120-unit adaptive law is ~1350 flops;
* a program whose buffers are all ≤ 512 bytes runs its kernels inline; otherwise its kernels go
  through a thread pool.

``--sync`` turns JAX's CPU async dispatch off for this process
(``jax.config.update("jax_cpu_enable_async_dispatch", False)``, which must happen before JAX
creates its CPU client: a robot process would do it at start-up). Every program then runs inline.

Usage: python benchmarks/latency.py [--calls 10000] [--kinds fl hinf hinf_nn hinf_nn60]
                                    [--paths loop pytree] [--variants] [--sync] [--json FILE]
"""

from __future__ import annotations

import sys

if __name__ == "__main__" and "--sync" in sys.argv:  # before anything creates the CPU client
    import jax

    jax.config.update("jax_cpu_enable_async_dispatch", False)

import argparse  # noqa: E402
import functools  # noqa: E402
import gc  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import hinfnn as H  # noqa: E402
from hinfnn._loop import ROLL_FROM_JOINTS  # noqa: E402
from hinfnn.protocols import Measurement  # noqa: E402

H.configure()

PERIOD = 1e-3
#: Table rows: label -> (controller kind, F_f units or None for the scenario's 120).
KINDS = {
    "fl": ("fl", None),
    "hinf": ("hinf", None),
    "hinf_nn": ("hinf_nn", None),
    "hinf_nn60": ("hinf_nn", 60),
}
PATHS = ("loop", "pytree")


def _overrides(kind: str, units: int | None) -> dict:
    ov = {"controller.kind": kind}
    if units is not None:  # F_f: `units` centres from −30 by 0.5 (60 units span −30 … −0.5)
        ov.update({"controller.network_f.preset": "custom", "controller.network_f.centre_start": -30.0,
                   "controller.network_f.centre_step": 0.5, "controller.network_f.centre_count": int(units)})
    return ov


def build(kind: str = "hinf_nn", units: int | None = None, scenario: str = "paper") -> H.SampledController:
    """The controller ``kind`` (F_f with ``units`` units) and reference of ``scenario`` (the
    paper's, or an arm's designed for 1 kHz sampled control: its controller is built for that
    period), wrapped."""
    if kind in KINDS and units is None:
        kind, units = KINDS[kind]
    sc = H.load_scenario(scenario, _overrides(kind, units) if scenario == "paper" else {"controller.kind": kind})
    sc = _sampled(sc)
    return H.SampledController(sc.build_controller(kind), sc.build_reference())


def _sampled(sc):
    """An arm's scenario at 1 kHz sampled control (the paper's as it is: its laws run at any rate)."""
    if sc.name == "paper":
        return sc
    return sc.with_overrides({"simulation.control": "sampled", "simulation.control_period": PERIOD})


@functools.lru_cache(maxsize=4)
def measurements(t_final: float = 1.0, scenario: str = "paper") -> dict:
    """q, q̇, F at 1 kHz from a closed-loop run of ``scenario`` (adaptive controller, dt = 0.1 ms;
    the paper's with continuous control, an arm's at 1 kHz): realistic, changing sensor values to
    replay."""
    sc = _sampled(H.load_scenario(scenario, {"controller.kind": "hinf_nn"}))
    plant = sc.build_plant()
    traj = H.simulate(plant, sc.build_controller("hinf_nn"), sc.build_reference(),
                      t_final=t_final, dt=1e-4, q0=sc.initial_q(plant), save_every=10,
                      control_period=sc.control_period)
    a = dict(traj.arrays)
    if "F_contact" in a:  # an arm's measured force: Cartesian, at the tool point (its "F" is the task-space one)
        a["F"] = a["F_contact"]
    return {k: np.ascontiguousarray(a[k][:-1]) for k in ("q", "qd", "F")}


def _stats(ns: np.ndarray) -> dict:
    us = ns / 1e3
    return dict(median_us=float(np.median(us)), p90_us=float(np.percentile(us, 90)),
                p99_us=float(np.percentile(us, 99)), max_us=float(np.max(us)))


def _time_loop(call, n_calls: int, warmup: int, gc_off: bool) -> np.ndarray:
    for i in range(warmup):
        call(i)
    ns = np.empty(n_calls, dtype=np.int64)
    clock = time.perf_counter_ns
    was_enabled = gc.isenabled()
    if gc_off:
        gc.collect()
        gc.disable()
    try:
        for i in range(n_calls):
            t0 = clock()
            call(warmup + i)
            ns[i] = clock() - t0
    finally:
        if gc_off and was_enabled:
            gc.enable()
    return ns


def _caller(sc, path: str, meas: dict):
    """``call(i)`` doing sample i the way ``path`` does it; returns (call, counter of NaN τ)."""
    Q, QD, F = meas["q"], meas["qd"], meas["F"]
    m = len(Q)
    bad = [0]
    if path == "loop":
        loop = sc.loop(sc.init())
        update = loop.update

        def call(i):
            j = i % m
            tau = update(i * PERIOD, PERIOD, Q[j], QD[j], F[j])
            if not (tau[0] == tau[0]):
                bad[0] += 1
            return tau
    elif path == "pytree":
        box = [sc.init()]
        update = sc._update

        def call(i):
            j = i % m
            tau, box[0] = update(i * PERIOD, PERIOD, box[0], Measurement(q=Q[j], qd=QD[j], force=F[j]))
            tau = np.asarray(tau)
            if not (tau[0] == tau[0]):
                bad[0] += 1
            return tau
    else:
        raise ValueError(f"path must be one of {PATHS}, got {path!r}")
    return call, bad


def program_flops(sc, path: str = "loop") -> float:
    """XLA's cost estimate (flops) of the compiled update. With async dispatch on, XLA's CPU
    client runs a program inline on the calling thread only below 1000 flops."""
    if path == "loop" and sc.n_joints >= ROLL_FROM_JOINTS:  # the programs SampledController compiles
        lowered = sc._jit_kept.lower(np.zeros(sc.sample_size), *jax.tree.leaves(sc.init()))
    elif path == "loop":
        lowered = sc._jit_packed.lower(np.zeros(sc.packed_size))
    else:
        n = sc.n_joints
        m = Measurement(q=np.zeros(n), qd=np.zeros(n), force=np.zeros(sc.force_size))
        lowered = sc._jit_update.lower(0.0, PERIOD, sc.init(), m)
    cost = lowered.compile().cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return float(cost.get("flops", float("nan")))


def measure_latency(n_calls: int = 10_000, kind: str = "hinf_nn", *, units: int | None = None,
                    path: str = "loop", warmup: int = 1000,
                    gc_off: bool = True, scenario: str = "paper") -> dict:
    """Latency of one sampled update called from a Python loop, τ back as NumPy, in µs.

    ``kind``: ``"fl"``, ``"hinf"``, ``"hinf_nn"`` (or ``"hinf_nn60"``, the same with 60 F_f
    units; ``units`` sets any count). ``path``: ``"loop"`` (:class:`SampledLoop`, the fast
    path) or ``"pytree"`` (``SampledController._update``). Returns median/p90/p99/max in µs, the
    number of calls, how many returned a NaN τ (none expected), the first call's compile time,
    XLA's flop estimate of the program, whether JAX's CPU async dispatch was on and the load
    average when done. ``scenario``: the paper's (default) or an arm's (``"ur5-table-stable"``).
    """
    sc = build(kind, units, scenario)
    meas = measurements(scenario=scenario)
    call, bad = _caller(sc, path, meas)
    t0 = time.perf_counter()
    call(0)  # compile
    compile_s = time.perf_counter() - t0
    ns = _time_loop(call, n_calls, warmup, gc_off)
    n_units = sc.controller.network_f.size if sc.controller.network_f is not None else None
    return dict(scenario=scenario, kind=sc.controller.kind, units=n_units, path=path, n_calls=n_calls,
                nan_taus=bad[0], compile_s=compile_s, flops=program_flops(sc, path),
                async_dispatch=bool(jax.config.values["jax_cpu_enable_async_dispatch"]),
                load_avg=os.getloadavg()[0], **_stats(ns))


# --- the alternatives that were tried ----------------------------------------------------------------
def compare_variants(kind: str = "hinf_nn", units: int | None = None, *, n_calls: int = 5000,
                     rounds: int = 10) -> dict:
    """Time the ways one could call the same sampled law, interleaved in ``rounds`` blocks so
    that a change of machine load hits every variant alike. Returns {variant: stats}.

    Every variant computes the same numbers (checked on the first sample before timing).
    """
    sc = build(kind, units)
    meas = measurements()
    Q, QD, F = meas["q"], meas["qd"], meas["F"]
    m, n, ns = len(Q), sc.n_joints, sc.sample_size
    xf = sc.init()
    xb = xf
    variants = {}

    def variant(name):
        def deco(make):
            variants[name] = make
            return make
        return deco

    def fill(i, y):
        j = i % m
        y[0] = i * PERIOD
        y[1] = PERIOD
        y[2:2 + n] = Q[j]
        y[2 + n:2 + 2 * n] = QD[j]
        y[2 + 2 * n:ns] = F[j]
        return y

    def meas_args(i):
        j = i % m
        return i * PERIOD, PERIOD, Measurement(q=Q[j], qd=QD[j], force=F[j])

    def pytree_caller(fn, state, get=np.asarray):
        box = [state]

        def call(i):
            tau, box[0] = fn(box[0], *meas_args(i))
            return get(tau)
        return call

    @variant("SampledLoop.update (fast path)")
    def _():
        loop = sc.loop()
        return lambda i: loop.update(i * PERIOD, PERIOD, Q[i % m], QD[i % m], F[i % m])

    def packed_caller(fn, get=np.asarray):
        x = sc._pack(0.0, PERIOD, Measurement(q=Q[0], qd=QD[0], force=F[0]), xf)

        def call(i):
            out = get(fn(fill(i, x)))
            x[ns:] = out[n:]
            return out[:n]
        return call

    @variant("update_packed, buffer by hand")
    def _():
        return packed_caller(sc._update_packed)

    @variant("update_packed, jax.device_get")
    def _():
        return packed_caller(sc._update_packed, get=jax.device_get)

    aot = jax.jit(sc._step_packed).lower(np.zeros(sc.packed_size)).compile()

    @variant("update_packed, AOT .lower().compile()")
    def _():
        return packed_caller(aot)

    @variant("update: pytree, flat state (default)")
    def _():
        return pytree_caller(lambda s, t, p, mm: sc._update(t, p, s, mm), xf)

    with_args = jax.jit(lambda c, r, t, p, s, mm: H.SampledController(c, r).step(t, p, s, mm))

    @variant("update: controller+reference as jit args")
    def _():
        return pytree_caller(lambda s, t, p, mm: with_args(sc.controller, sc.reference, t, p, s, mm), xf)

    @variant("update: t, period as np.float64")
    def _():
        return pytree_caller(lambda s, t, p, mm: sc._update(np.float64(t), np.float64(p), s, mm), xf)

    @variant("update: jax.device_get(tau)")
    def _():
        return pytree_caller(lambda s, t, p, mm: sc._update(t, p, s, mm), xf, get=jax.device_get)

    def state_y_step(state, y):
        meas_ = Measurement(q=y[2:2 + n], qd=y[2 + n:2 + 2 * n], force=y[2 + 2 * n:ns])
        return sc.step(y[0], y[1], state, meas_)
    state_y = jax.jit(state_y_step)
    state_y_donated = jax.jit(state_y_step, donate_argnums=0)

    def state_y_caller(fn, state):
        box, y = [state], np.empty(ns)

        def call(i):
            tau, box[0] = fn(box[0], fill(i, y))
            return np.asarray(tau)
        return call

    @variant("(device state pytree, packed sample)")
    def _():
        return state_y_caller(state_y, xb)

    @variant("  same, donate_argnums=state")
    def _():
        return state_y_caller(state_y_donated, jax.tree.map(jnp.array, xb))

    treedef = jax.tree.structure(xb)
    leaves_fn = jax.jit(lambda leaves, y: jax.tree.map(
        lambda v: v, (lambda tau_new: (tau_new[0], tuple(jax.tree.leaves(tau_new[1]))))(
            state_y_step(jax.tree.unflatten(treedef, leaves), y))))

    @variant("  same, state as a tuple of leaves")
    def _():
        return state_y_caller(leaves_fn, tuple(jax.tree.leaves(xb)))

    calls = {name: make() for name, make in variants.items()}
    firsts = {name: np.asarray(call(0)) for name, call in calls.items()}  # compiles too
    first = next(iter(firsts.values()))
    for name, got in firsts.items():
        assert np.allclose(got, first, rtol=1e-12, atol=1e-12), (name, got, first)
    for call in calls.values():  # warm-up
        for i in range(1, 500):
            call(i)
    per_round = max(1, n_calls // rounds)
    times = {name: [] for name in calls}
    gc.collect()
    gc.disable()
    try:
        clock = time.perf_counter_ns
        for r in range(rounds):
            for name, call in calls.items():
                buf = np.empty(per_round, dtype=np.int64)
                base = 500 + r * per_round
                for i in range(per_round):
                    t0 = clock()
                    call(base + i)
                    buf[i] = clock() - t0
                times[name].append(buf)
    finally:
        gc.enable()
    return {name: _stats(np.concatenate(ts)) for name, ts in times.items()}


def _row(label, r):
    flops = f"{r['flops']:7.0f}" if "flops" in r else ""
    return (f"{label:<44s} {r['median_us']:8.1f} {r['p90_us']:8.1f} {r['p99_us']:8.1f} "
            f"{r['max_us']:9.1f} {flops}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=10_000)
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=list(KINDS))
    ap.add_argument("--paths", nargs="+", default=list(PATHS), choices=list(PATHS))
    ap.add_argument("--variants", action="store_true", help="also time the alternatives tried")
    ap.add_argument("--sync", action="store_true", help="JAX CPU async dispatch off (process-wide)")
    ap.add_argument("--json", help="write the numbers to this file")
    args = ap.parse_args(argv)

    mode = "on" if jax.config.values["jax_cpu_enable_async_dispatch"] else "off"
    print(f"sampled update latency, {args.calls} calls each, 1 kHz replay; JAX {jax.__version__}, "
          f"{os.cpu_count()} CPUs, async dispatch {mode}, load average {os.getloadavg()[0]:.2f}")
    print("target: median ≤ 30 µs, p99 ≤ 100 µs (from Python, τ back as NumPy); times in µs;")
    print("flops: XLA's estimate for the program (with async dispatch on, inline only below 1000)\n")
    header = f"{'controller / entry point':<44s} {'median':>8s} {'p90':>8s} {'p99':>8s} {'max':>9s} {'flops':>7s}"
    print(header)
    print("-" * len(header))
    out = {"async_dispatch": mode == "on", "rows": []}
    for label in args.kinds:
        for path in args.paths:
            r = measure_latency(args.calls, label, path=path)
            out["rows"].append({"label": label, **r})
            note = f"  [{r['nan_taus']} NaN τ]" if r["nan_taus"] else ""
            units = f"{r['units']} F_f units" if r["units"] else "no networks"
            print(_row(f"{label} ({units}), {path}", r) + note, flush=True)
    if args.variants:
        out["variants"] = {}
        for label in args.kinds:
            print(f"\nvariants, {label} (interleaved rounds, {args.calls} calls each)")
            print(header)
            print("-" * len(header))
            res = compare_variants(label, n_calls=args.calls)
            out["variants"][label] = res
            for name, r in res.items():
                print(_row(name, r), flush=True)
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return out


if __name__ == "__main__":
    main()
