"""hinfnn benchmark suite: speed and scale of the closed loop, printed as a table and saved as JSON.

Cases (each runs in a fresh worker process so that its peak memory is its own):

1. ``single``  — the paper scenario, one 10-s run (100,000 RK4 steps at dt = 1e-4, controller at
   every stage) of each controller: compile time apart, then ``--repeats`` timed runs.
2. ``batch``   — the adaptive controller on 1, 10, 100, 1,000 parameter sets under ``vmap``:
   masses, link lengths, surface angle and contact stiffness drawn uniformly within ±20 % of the
   paper's true values (seeded; draws whose start pose is out of the arm's reach are redrawn, and
   the acceptance rate is reported). Trajectory-steps per second and peak memory.
3. ``startup`` — a new process running ``hinfnn run paper``, cold then warm (persistent
   compilation cache): time to the first simulated step (benchmarks/startup.py).
4. ``whole``   — a new process running ``hinfnn run paper`` (10 s) from launch to exit, figures
   included, cold then warm, and warm with ``--no-figures``: wall and CPU time, and where the
   time goes (benchmarks/whole.py).
5. ``latency`` — the sampled controller ``update(t, period, state, measurement)`` called from
   Python as in a 1 kHz robot loop: median and 99th percentile over 10,000 calls
   (benchmarks/latency.py).
6. ``devices`` — each loop option of ``hinfnn._loop.LoopOptions`` (and the controller's block layout)
   off in turn (fresh processes):
   the adaptive 10-s run and a 100-plant batch.
7. ``arm_devices`` — ``rolled_rk4`` on and off on the UR5 (ur5-table, H∞ + NN): the first run
   (compile-dominated, empty cache) and a 0.5-s run.
8. ``batch_devices`` — ``batch_groups`` on and off: the adaptive law at B = 1,000 (1 s, metrics);
   ``arm_batch_devices`` — ``member_minor`` on and off: the UR5 (H∞ + NN) at B = 256
   (``--arm-batch-horizon``; not in the default cases, the ``ur5_batch`` rows have it on);
   ``arm_sampled_devices`` — ``frozen_law`` on and off: the UR5 at 1 kHz sampled control
   (``ur5-table-stable``, H∞ + NN), with and without the theorems' bookkeeping, 0.5-s runs (not in the
   default cases, the ``ur5_single`` rows have it on).
9. ``program_gc`` — the ``program_gc`` device on and off: ``hinfnn run paper --no-figures`` (0.05 s
   simulated, warm cache) in fresh processes, alternating; wall and CPU time.
10. ``launch_floor`` — what XLA's CPU runtime costs per kernel launched in a loop: chains of 52–402
   small kernels, and 1,200 launches per iteration from 1,200, 600, 400 or 200 distinct kernels.
11. The UR5 (``ur5-table``, H∞ + NN), every per-step time also as a ratio to the anchor:
   ``ur5_anchor`` — the rigid-body terms of one RK4 step (plant and nominal model: M, bias, the
   tool's Jacobian and its rate, four stages) by Pinocchio called from Python;
   ``ur5_single`` — one run, continuous and at 1 kHz sampled control (``ur5-table-stable``; and the
   same with ``simulation.bookkeeping = false``, no J or supply integrated): compile, steps per
   second, kernels per step of the compiled loop, launched and distinct (benchmarks/hlo.py);
   and the floor under the sampled run: RK4 steps of the true plant alone, the torque held;
   ``ur5_latency`` — the sampled update at 1 kHz from a Python loop (``ur5_latency_sync``: with
   JAX's CPU async dispatch off, as ``latency_sync``);
   ``ur5_batch`` — B = 64, 256, 1,024, 4,096 plants (``--arm-batches``): compile and trajectory-steps/s;
   ``ur5_whole`` — ``hinfnn run ur5-table --no-figures`` as a new process, cold and warm.

Baseline: the plain-NumPy closed loop of ``tests/numpy_oracle.py`` (a Python loop over RK4 steps,
the same equations), timed in the same invocation on a 1-s horizon and scaled to 10 s.

Usage::

    python benchmarks/run.py                 # everything (make bench), ~13 min on 2 cores
    python benchmarks/run.py --cases single latency --repeats 5
    python benchmarks/run.py --quick         # smaller batches and horizons, for a smoke test

Writes ``benchmarks/results/bench-<UTC time>.json`` and ``benchmarks/results/latest.json``.
Timing lives here, never in tests/.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
DT = 1e-4
T_RUN = 10.0
KINDS = ("fl", "hinf", "hinf_nn")
#: The second speed round's targets (single runs, B = 1,000, whole process) and the earlier ones.
TARGETS = {
    "single_s_per_run": {"fl": 0.5, "hinf": 0.5, "hinf_nn": 0.8},
    "single_speedup_vs_numpy": 50.0, "single_compile_s": 10.0,
    "batch1000_traj_steps_per_s": 450_000.0, "batch1000_memory_gb": 4.0,
    "startup_warm_s": 3.0, "whole_warm_s": 3.0, "whole_cold_s": 6.0,
    "latency_median_us": 30.0, "latency_p99_us": 100.0,
    # issue 33 (UR5, ur5-table, H∞ + NN)
    "ur5_s_per_10s_run": 3.0, "ur5_sampled_s_per_10s_run": 1.5, "ur5_batch_traj_steps_per_s": 100_000.0,
    "ur5_batch_compile_s": 30.0, "ur5_latency_median_us": 50.0, "ur5_latency_p99_us": 100.0, "ur5_whole_warm_s": 6.0,
}


# --- machine -------------------------------------------------------------------------------------

def machine() -> dict:
    import jax
    import jaxlib
    import numpy as np

    import hinfnn

    cpu = platform.processor() or "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return dict(cpu=cpu, cores=os.cpu_count(), usable_cores=len(os.sched_getaffinity(0)),
                memory_gb=round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1),
                python=platform.python_version(), jax=jax.__version__, jaxlib=jaxlib.__version__,
                numpy=np.__version__, hinfnn=hinfnn.__version__, commit=commit,
                platform=jax.devices()[0].platform, xla_flags=os.environ.get("XLA_FLAGS", ""))


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux


def _stats(times):
    return dict(median=statistics.median(times), min=min(times), max=max(times), n=len(times))


# --- operations per step ---------------------------------------------------------------------------

def chunk_text(plant, ctrl, ref, q0, loop=None, sampled: bool = False) -> str:
    """The optimised HLO text of the single-run chunk program hinfnn.simulate compiles for this
    plant, controller and reference (with the loop options ``loop``)."""
    import importlib

    import jax.numpy as jnp

    from hinfnn._loop import LoopOptions

    S = importlib.import_module("hinfnn.sim.simulate")
    loop = loop or LoopOptions()
    y0 = S.initial_state(plant, ctrl, q0=q0)
    chunk, _, init = S._compiled(None, S.SINGLE_RECORDS, sampled, None, loop, plant.n, True)
    carry = init(ctrl, y0, plant.n)
    hold = 10 if sampled else 1
    args = (plant, ctrl, ref, S.Limits(), carry, jnp.zeros((), jnp.int64),
            *S.RunProgram.chunk_scalars(10, DT, hold, 10, 1))
    return chunk.jitted.lower(*args).compile().as_text()


def step_profile(plant, ctrl, ref, q0, loop=None) -> dict:
    """Kernels (and library calls) per RK4 step and transcendental operations per step, read off
    the compiled chunk's step loop (benchmarks/hlo.py)."""
    sys.path.insert(0, str(HERE))
    import hlo

    return hlo.step_kernels(chunk_text(plant, ctrl, ref, q0, loop))


# --- case 1 ------------------------------------------------------------------------------------------

def numpy_baseline(kinds, horizon) -> dict:
    sys.path.insert(0, str(ROOT / "tests"))
    import numpy as np
    import numpy_oracle

    np.seterr(all="ignore")
    out = {}
    for kind in kinds:
        t0 = time.perf_counter()
        numpy_oracle.simulate(kind, {}, t_final=horizon, dt=DT)
        wall = time.perf_counter() - t0
        out[kind] = dict(horizon_s=horizon, wall_s=wall, s_per_10s_run=wall * T_RUN / horizon,
                         steps_per_s=round(horizon / DT) / wall)
    return out


def case_single(args) -> dict:
    import hinfnn as H

    base = numpy_baseline(KINDS, args.numpy_horizon)
    rows = {}
    for kind in KINDS:
        sc = H.load_scenario("paper", {"controller.kind": kind})
        plant, ctrl, ref = sc.build_plant(), sc.build_controller(kind), sc.build_reference()
        q0 = sc.initial_q(plant)
        t0 = time.perf_counter()
        H.simulate(plant, ctrl, ref, t_final=0.01, dt=DT, q0=q0)
        compile_s = time.perf_counter() - t0
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            H.simulate(plant, ctrl, ref, t_final=args.horizon, dt=DT, q0=q0)
            times.append((time.perf_counter() - t0) * T_RUN / args.horizon)
        st = _stats(times)
        rows[kind] = dict(compile_s=compile_s, s_per_10s_run=st, steps_per_s=T_RUN / DT / st["median"],
                          speedup_vs_numpy=base[kind]["s_per_10s_run"] / st["median"],
                          numpy=base[kind], ops=step_profile(plant, ctrl, ref, q0), mode="continuous")
    for kind in KINDS:  # the sampled-data mode: controller once per 1 ms, plant RK4 every 0.1 ms
        sc = H.load_scenario("paper", {"controller.kind": kind})
        plant, ctrl, ref = sc.build_plant(), sc.build_controller(kind), sc.build_reference()
        q0 = sc.initial_q(plant)
        opts = dict(dt=DT, q0=q0, control_period=1e-3, raise_on_failure=False)
        t0 = time.perf_counter()
        H.simulate(plant, ctrl, ref, t_final=0.01, **opts)
        compile_s = time.perf_counter() - t0
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            tr = H.simulate(plant, ctrl, ref, t_final=args.horizon, **opts)
            times.append((time.perf_counter() - t0) * T_RUN / args.horizon)
        st = _stats(times)
        rows[f"{kind} 1kHz"] = dict(compile_s=compile_s, s_per_10s_run=st, steps_per_s=T_RUN / DT / st["median"],
                                    speedup_vs_numpy=base[kind]["s_per_10s_run"] / st["median"],
                                    numpy=base[kind], ops={}, mode="sampled 1 kHz",
                                    status="ok" if int(tr.status) == 0 else
                                    f"stopped at t = {float(tr.t_fail):.4g} s (status {int(tr.status)})")
    return dict(rows=rows, peak_rss_gb=peak_rss_gb())


# --- case 2 ------------------------------------------------------------------------------------------

def draw_plants(B: int, seed: int = 0, spread: float = 0.2):
    """B true plants with m1, m2, l1, l2, δ and k drawn uniformly within ±spread of the paper's
    values; draws whose start pose (u1(0) on the surface) is out of reach are redrawn."""
    import numpy as np

    import hinfnn as H

    rng = np.random.default_rng(seed)
    p0 = H.load_scenario("paper").build_plant()
    arm0, surf0, con0 = p0.arm, p0.surface, p0.contact
    plants, q0s, tried = [], [], 0
    while len(plants) < B:
        tried += 1
        f = rng.uniform(1 - spread, 1 + spread, size=6)
        arm = H.TwoLinkArm(m1=float(arm0.m1) * f[0], m2=float(arm0.m2) * f[1], l1=float(arm0.l1) * f[2],
                           l2=float(arm0.l2) * f[3], g=float(arm0.g))
        plant = H.RigidBodyPlant(arm, H.InclinedLine(delta=float(surf0.delta) * f[4], d_G=float(surf0.d_G),
                                            scaling=surf0.scaling),
                        H.PenaltyContact(float(con0.stiffness) * f[5], float(con0.damping)), p0.disturbance)
        q0 = np.asarray(plant.initial_q(1.6902))
        if np.all(np.isfinite(q0)):
            plants.append(plant)
            q0s.append(q0)
    return plants, q0s, B / tried


def case_batch(args) -> dict:
    import hinfnn as H

    sc = H.load_scenario("paper", {"controller.kind": "hinf_nn"})
    ctrl, ref = sc.build_controller("hinf_nn"), sc.build_reference()
    rows = {}
    for B in args.batches:
        plants, q0s, acc = draw_plants(B, seed=args.seed)
        rss0 = peak_rss_gb()
        t0 = time.perf_counter()
        # the same program as the timed run (what it stores is part of the program): compiled here
        H.simulate_batch(plants, ctrl, ref, t_final=0.01, dt=DT, q0=q0s, fields=args.batch_fields)
        compile_s = time.perf_counter() - t0
        horizon = args.batch_horizon
        t0 = time.perf_counter()
        tr = H.simulate_batch(plants, ctrl, ref, t_final=horizon, dt=DT, q0=q0s, fields=args.batch_fields)
        wall = time.perf_counter() - t0
        stored = sum(v.nbytes for v in tr.arrays.values())
        metrics = [H.compute_metrics(tr.member(i)) for i in range(B)]  # what the study is for
        done = [m for m in metrics if not m["partial"]]
        rows[str(B)] = dict(batch=B, horizon_s=horizon, wall_s=wall,
                            traj_steps_per_s=B * round(horizon / DT) / wall,
                            s_per_1000_runs_of_10s=1000 * T_RUN / DT / (B * round(horizon / DT) / wall),
                            compile_s=compile_s, acceptance=acc, completed=int(tr.ok.sum()),
                            fields=args.batch_fields, n_fields=len(tr.arrays),
                            median_rms_e_lam_last2s=statistics.median([m["rms_e_lam_last2s"] for m in done])
                            if done else None,
                            stored_gb=stored / 2**30, peak_rss_gb=peak_rss_gb(), peak_rss_before_gb=rss0,
                            samples_per_run=int(tr.t.shape[-1]))
        del tr
    return dict(rows=rows, peak_rss_gb=peak_rss_gb())


# --- cases 3 and 4 (helpers in their own files) ---------------------------------------------------

def case_startup(args) -> dict:
    sys.path.insert(0, str(HERE))
    import startup

    return startup.measure_startup(repeats=args.repeats)


def case_whole(args) -> dict:
    sys.path.insert(0, str(HERE))
    import whole

    return whole.measure_whole(repeats=args.repeats)


def _sync_dispatch() -> None:
    """JAX's CPU async dispatch off, a robot process's setting (before JAX's first computation in
    this worker)."""
    import jax

    jax.config.update("jax_cpu_enable_async_dispatch", False)


def case_latency(args, sync: bool = False) -> dict:
    if sync:
        _sync_dispatch()
    sys.path.insert(0, str(HERE))
    import latency

    out = {}
    for kind in KINDS:
        out[kind] = latency.measure_latency(n_calls=args.calls, kind=kind)
    return out


def case_latency_sync(args) -> dict:
    return case_latency(args, sync=True)


def case_device_run(args) -> dict:
    """The adaptive 10-s run and a 100-plant batch (1 s each), with the loop options of
    ``--disable`` turned off (``blocks``: the controller's block layout)."""
    import hinfnn as H

    sc = H.load_scenario("paper", {"controller.kind": "hinf_nn"})
    plant, ctrl, ref = sc.build_plant(), _controller(sc, "hinf_nn", args), sc.build_reference()
    q0 = sc.initial_q(plant)
    loop = _loop_options(args)
    t0 = time.perf_counter()
    H.simulate(plant, ctrl, ref, t_final=0.01, dt=DT, q0=q0, loop=loop)
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        H.simulate(plant, ctrl, ref, t_final=args.horizon, dt=DT, q0=q0, loop=loop)
        times.append((time.perf_counter() - t0) * T_RUN / args.horizon)
    return dict(disabled=list(args.disable), compile_s=compile_s, s_per_10s_run=_stats(times),
                batch100_traj_steps_per_s=_batch_1s(ctrl, ref, 100, args.seed, loop=loop)[1],
                ops=step_profile(plant, ctrl, ref, q0, loop))


#: The switches of ``--disable``: the loop options (hinfnn._loop.LoopOptions) and the controller's
#: block layout (``blocks``).
SWITCHES = ("blocks", "sincos", "small_mm", "rolled_rk4", "batch_groups", "arm_kernels", "rolled_stages",
            "fusion_emitters", "record_once", "record_blocks", "member_minor", "frozen_law")


def _loop_options(args):
    """The LoopOptions of this worker: every option on but those of ``--disable``."""
    from hinfnn._loop import LoopOptions

    import dataclasses

    off = set(args.disable)
    kw = dict(sincos="sincos" not in off, small_mm="small_mm" not in off,
              rolled_rk4=False if "rolled_rk4" in off else None,
              batch_group=0 if "batch_groups" in off else LoopOptions().batch_group)
    have = {f.name for f in dataclasses.fields(LoopOptions)}  # options of the hinfnn being measured
    extra = {"arm_kernels": ("arm_kernels", False), "rolled_stages": ("rolled_stages", 3),
             "fusion_emitters": ("fusion_emitters", True), "record_once": ("record_once", False),
             "record_blocks": ("record_blocks", False), "member_minor": ("member_minor", False),
             "frozen_law": ("frozen_law", False)}
    for switch, (name, value) in extra.items():
        if switch in off:
            if name not in have:
                raise SystemExit(f"--disable {switch}: this hinfnn has no such loop option")
            kw[name] = value
    return LoopOptions(**kw)


def _controller(sc, kind, args):
    """The scenario's controller, its state in one array per part with ``--disable blocks``."""
    import dataclasses

    ctrl = sc.build_controller(kind)
    return dataclasses.replace(ctrl, block=None) if "blocks" in args.disable else ctrl


def _batch_1s(ctrl, ref, B: int, seed: int, loop=None) -> tuple[float, float]:
    """(wall s, trajectory-steps/s) of B plants of :func:`draw_plants` under one controller for
    1 s, storing the metrics; the program is compiled first by a 0.01-s run."""
    import hinfnn as H

    plants, q0s, _ = draw_plants(B, seed=seed)
    H.simulate_batch(plants, ctrl, ref, t_final=0.01, dt=DT, q0=q0s, fields="metrics", loop=loop)
    t0 = time.perf_counter()
    H.simulate_batch(plants, ctrl, ref, t_final=1.0, dt=DT, q0=q0s, fields="metrics", loop=loop)
    wall = time.perf_counter() - t0
    return wall, B * round(1.0 / DT) / wall


def case_devices(args) -> dict:
    """Each loop option (and the controller's block layout) turned off in turn (a fresh process
    each), against all on: the benchmark line that justifies each."""
    return _each_off(args, "device_run", ("blocks", "sincos", "small_mm"))


def _each_off(args, worker: str, devices) -> dict:
    """``worker`` in fresh processes: all devices on, then each of ``devices`` off in turn."""
    out = {}
    for disabled in ((), *((d,) for d in devices)):
        sub = argparse.Namespace(**{**vars(args), "disable": list(disabled)})
        out[",".join(disabled) or "all on"] = run_worker(worker, sub)
    return out


def case_arm_run(args) -> dict:
    """The UR5 on its table (ur5-table), H∞ + NN: the first 0.05-s run (compile-dominated, empty
    cache) and a 0.5-s run once compiled, with the devices of ``--disable`` off in this worker."""
    import hinfnn as H

    sc = H.load_scenario("ur5-table", {"controller.kind": "hinf_nn", "simulation.t_final": 0.05})
    first, times, _ = _first_then_runs(sc, _loop_options(args), 0.5, args.repeats)
    return dict(disabled=list(args.disable), first_run_s=first, s_per_half_second=_stats(times))


def _first_then_runs(sc, loop, horizon, repeats, kind="hinf_nn"):
    """(seconds of the scenario's run as given: the compile-dominated first, [seconds of each of
    ``repeats`` runs of ``horizon`` s], the last run's trajectory), one law, the loop options ``loop``."""
    t0 = time.perf_counter()
    sc.simulate(kind, loop=loop)
    first = time.perf_counter() - t0
    sc = sc.with_overrides({"simulation.t_final": horizon})
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        tr = sc.simulate(kind, loop=loop, raise_on_failure=False)
        times.append(time.perf_counter() - t0)
    return first, times, tr


def case_arm_devices(args) -> dict:
    """``rolled_rk4`` on and off on a 6-joint arm (it is off for the paper's 2-joint arm): the
    benchmark line that justifies it (compile time)."""
    return _each_off(args, "arm_run", ("rolled_rk4",))


def case_arm_sampled_run(args) -> dict:
    """The UR5 at 1 kHz sampled control (ur5-table-stable, H∞ + NN), with and without the theorems'
    bookkeeping: the first 0.01-s run (compile, empty cache) and ``--repeats`` 0.5-s runs (µs per
    RK4 step of the best), with the devices of ``--disable`` off in this worker."""
    import hinfnn as H

    loop = _loop_options(args)
    out = dict(disabled=list(args.disable))
    for book in (True, False):
        sc = _ur5(name="ur5-table-stable", **{"simulation.control": "sampled", "simulation.control_period": 1e-3,
                                               "simulation.t_final": 0.01, "simulation.bookkeeping": book})
        first, times, _ = _first_then_runs(sc, loop, 0.5, args.repeats)
        out["bookkeeping" if book else "no bookkeeping"] = dict(first_run_s=first,
                                                                us_per_step=1e6 * min(times) / round(0.5 / DT))
    return out


def case_arm_sampled_devices(args) -> dict:
    """``frozen_law`` on and off on the UR5 at 1 kHz: the benchmark line that justifies it."""
    return _each_off(args, "arm_sampled_run", ("frozen_law",))


def case_batch_run(args) -> dict:
    """The adaptive law at B = 1,000 for 1 s (fields="metrics", the program compiled first), with
    the devices of ``--disable`` off in this worker."""
    import hinfnn as H

    sc = H.load_scenario("paper", {"controller.kind": "hinf_nn"})
    wall, rate = _batch_1s(sc.build_controller("hinf_nn"), sc.build_reference(), 1000, args.seed,
                           loop=_loop_options(args))
    return dict(disabled=list(args.disable), wall_s=wall, traj_steps_per_s=rate)


def case_batch_devices(args) -> dict:
    """``batch_groups`` on and off at B = 1,000: the benchmark line that justifies it."""
    return _each_off(args, "batch_run", ("batch_groups",))


def case_arm_batch_run(args) -> dict:
    """The UR5 (ur5-table, H∞ + NN) as a batch of 256 plants for ``--arm-batch-horizon`` s
    (fields="metrics", the program compiled first), with the devices of ``--disable`` off in this
    worker."""
    import hinfnn as H

    sc = _ur5()
    plant, ctrl, ref = sc.build_plant(), sc.build_controller("hinf_nn"), sc.build_reference()
    kw = dict(dt=DT, q0=[sc.initial_q(plant)] * 256, fields="metrics", loop=_loop_options(args),
              t_final=args.arm_batch_horizon)
    t0 = time.perf_counter()
    H.simulate_batch([plant] * 256, ctrl, ref, **kw)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    H.simulate_batch([plant] * 256, ctrl, ref, **kw)
    wall = time.perf_counter() - t0
    return dict(disabled=list(args.disable), compile_s=compile_s, wall_s=wall,
                traj_steps_per_s=256 * round(args.arm_batch_horizon / DT) / wall)


def case_arm_batch_devices(args) -> dict:
    """``member_minor`` on and off on a UR5 batch of 256: the benchmark line that justifies it."""
    return _each_off(args, "arm_batch_run", ("member_minor",))


def case_program_gc(args) -> dict:
    """``program_gc`` (hinfnn.cli) on and off, in alternating fresh processes: the short warm
    ``hinfnn run paper --no-figures``, where tracing and loading the programs are most of the time.
    Off: ``HINFNN_DEFAULT_GC=1``."""
    sys.path.insert(0, str(HERE))
    from startup import hinfnn_command, launch

    runs: dict = {"on": [], "off": []}
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "HINFNN_CACHE_DIR": str(Path(tmp) / "cache"), "HINFNN_TRACE_STARTUP": "1"}
        cmd = hinfnn_command() + ["run", "paper", "--set", "simulation.t_final=0.05", "--no-figures", "--quiet",
                                  "--force", "--out", str(Path(tmp) / "out")]
        launch(cmd, env)  # fills the cache
        for i in range(4 * max(args.repeats, 2)):
            name = ("on", "off", "off", "on")[i % 4]
            r = launch(cmd, {**env, "HINFNN_DEFAULT_GC": "1"} if name == "off" else env)
            runs[name].append((r["total"], r["cpu_total"]))
    return {k: {"wall_s": statistics.median(w for w, _ in v), "cpu_s": statistics.median(c for _, c in v),
                "n": len(v)} for k, v in runs.items()}


def _ur5(kind="hinf_nn", name="ur5-table", **over):
    import hinfnn as H
    from hinfnn.workflows.stiff import IDEAL_INSTRUMENTS

    # the -stable scenarios declare a robot's sensor: the timings keep the ideal one they were measured with
    ideal = IDEAL_INSTRUMENTS if name.endswith("-stable") else {}
    return H.load_scenario(name, {**ideal, "controller.kind": kind, **over})


def case_ur5_anchor(args) -> dict:
    """The rigid-body terms of one RK4 step of the UR5 run, by Pinocchio called from Python: at
    each of the four stages, for the plant and for the controller's nominal model, the joint-space
    inertia (CRBA), the bias forces (RNEA), the tool frame's Jacobian and its time derivative.
    Microseconds per RK4 step (median of ``--repeats`` + 2 rounds of 2,000 steps): the anchor every
    UR5 row is divided by. It is a floor neither way: hinfnn's step also holds the reduced-order
    model, the law and the networks, and Pinocchio's C++ pays Python's call overhead here."""
    import numpy as np
    import pinocchio as pin

    from hinfnn.model.urdf import shipped_robots

    arm = _ur5().get("plant.arm")
    text = Path(shipped_robots().get(arm.file, arm.file)).read_text(encoding="utf-8")
    models = []
    for _ in range(2):  # the plant's model and the nominal one: two models, two data
        model = pin.buildModelFromXML(text)
        parent = model.getFrameId(arm.ee_link, pin.FrameType.BODY)
        frame = model.frames[parent]
        tool = model.addFrame(pin.Frame("tcp", frame.parentJoint, parent,
                                        frame.placement * pin.SE3(np.eye(3), np.asarray(arm.tool_xyz, float)),
                                        pin.FrameType.OP_FRAME))
        models.append((model, model.createData(), tool))
    rng = np.random.default_rng(args.seed)
    n = models[0][0].nq
    qs, vs = rng.uniform(-1, 1, (64, n)), rng.uniform(-1, 1, (64, n))
    world = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

    def step(i):
        for stage in range(4):
            q, v = qs[(i + stage) % 64], vs[(i + stage) % 64]
            for model, data, tool in models:
                pin.crba(model, data, q)
                pin.nonLinearEffects(model, data, q, v)
                pin.computeJointJacobiansTimeVariation(model, data, q, v)
                pin.updateFramePlacements(model, data)
                pin.getFrameJacobian(model, data, tool, world)
                pin.getFrameJacobianTimeVariation(model, data, tool, world)

    rounds = []
    for r in range(max(args.repeats, 1) + 2):
        t0 = time.perf_counter()
        for i in range(2000):
            step(i)
        rounds.append((time.perf_counter() - t0) / 2000 * 1e6)
    rounds = rounds[2:]  # warm-up
    return dict(us_per_rk4_step=statistics.median(rounds), rounds_us=rounds, pinocchio=pin.__version__,
                robot=arm.file, n_joints=n)


def case_launch_floor(args) -> dict:
    """What XLA's CPU runtime costs per kernel it launches in a loop: a ``fori_loop`` of 20,000
    iterations whose body is a chain of K float64 6 × 6 matrix–vector products, each followed by a
    tanh (one ``dot`` kernel and one fusion per link; the kernels counted off the compiled body),
    for K = 25, 50, 100, 200 (``rows``). The slope of time per iteration against kernels per
    iteration is the launch cost of one small kernel in a loop of that size.

    That cost grows with the number of *distinct* kernels the loop holds, not with the launches
    (``footprint``): 1,200 launches per iteration made of D distinct kernels (a chain of D/2 links
    run 1,200/D times by an inner loop), D = 1,200, 600, 400, 200. Read a program's step against
    the row nearest its distinct kernels per step."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    sys.path.insert(0, str(HERE))
    import hlo

    rng = np.random.default_rng(args.seed)

    def timed(body, n_iter):
        f = jax.jit(lambda x, n: jax.lax.fori_loop(0, n, body, x))
        x0 = jnp.ones(6)
        n = jnp.asarray(n_iter)
        compiled = f.lower(x0, n).compile()
        comps, entry = hlo.computations(compiled.as_text())
        (_, loop_body, _), = hlo.whiles(comps[entry])
        compiled(x0, n).block_until_ready()
        best = float("inf")
        for _ in range(max(args.repeats, 1)):
            t0 = time.perf_counter()
            compiled(x0, n).block_until_ready()
            best = min(best, time.perf_counter() - t0)
        return hlo.kernels(comps, loop_body), hlo.distinct(comps, loop_body), best / n_iter * 1e6

    rows = []
    for K in (25, 50, 100, 200):
        A = jnp.asarray(rng.normal(size=(K, 6, 6)) / 6)

        def body(i, x, A=A, K=K):
            for j in range(K):
                x = jnp.tanh(A[j] @ x + 1e-3 * i)
            return x

        kernels, _, us = timed(body, 20_000)
        rows.append(dict(links=K, kernels=kernels, us_per_iteration=us))
    k = np.array([r["kernels"] for r in rows], float)
    us = np.array([r["us_per_iteration"] for r in rows])
    slope, intercept = np.polyfit(k, us, 1)

    footprint = []
    for D in (1200, 600, 400, 200):
        K, R = D // 2, 1200 // D
        As = tuple(jnp.asarray(a) for a in rng.normal(size=(K, 6, 6)) / 6)

        def links(r, x, As=As):
            for A in As:
                x = jnp.tanh(A @ x + 1e-3 * r)
            return x

        def body(i, x, links=links, R=R):
            return jax.lax.fori_loop(0, R, links, x) if R > 1 else links(i, x)

        kernels, distinct, us = timed(body, 2_000)
        footprint.append(dict(distinct=distinct, launches=kernels, us_per_iteration=us,
                              us_per_launch=us / kernels))
    return dict(rows=rows, us_per_kernel=float(slope), us_per_iteration_fixed=float(intercept), footprint=footprint)


def case_ur5_single(args) -> dict:
    """The UR5 on its table, H∞ + NN, one run: continuous control (ur5-table) and 1 kHz sampled
    control (ur5-table-stable: the bare table with the force-rate term designed for sampled control;
    the controller once per 1 ms with zero-order hold, the plant's RK4 every 0.1 ms), and the latter
    without the theorems' bookkeeping (``simulation.bookkeeping = false``). For each: the
    first 0.01-s run (compile, empty cache), then ``--repeats`` runs of ``--arm-horizon`` s:
    steady-state RK4 steps per second and the 10-s run's simulation time at that rate; for the
    continuous run the kernels per RK4 step of its compiled loop."""
    import numpy as np

    loop = _loop_options(args)
    out = {}
    sampled = {"simulation.control": "sampled", "simulation.control_period": 1e-3}
    for label, name, over in (("continuous", "ur5-table", {}),
                              ("sampled 1 kHz", "ur5-table-stable", sampled),
                              ("1 kHz, no bookkeeping", "ur5-table-stable",
                               {**sampled, "simulation.bookkeeping": False})):
        sc = _ur5(name=name, **{"simulation.t_final": 0.01, **over})
        first, times, tr = _first_then_runs(sc, loop, args.arm_horizon, args.repeats)
        steps = round(args.arm_horizon / DT)
        best = min(times)
        out[label] = dict(scenario=name, first_run_s=first, run_s=_stats(times), steps_per_s=steps / best,
                          us_per_step=1e6 * best / steps, s_per_10s_run=T_RUN / args.arm_horizon * best,
                          status=int(np.asarray(tr.status)))
        if label == "continuous":
            plant = sc.build_plant()
            out[label]["ops"] = step_profile(plant, sc.build_controller("hinf_nn"), sc.build_reference(),
                                             sc.initial_q(plant), loop)
    out["plant alone"] = _plant_alone(_ur5(name="ur5-table-stable"), loop, args)
    return out


def _plant_alone(sc, loop, args) -> dict:
    """The floor under a sampled run: RK4 steps of the scenario's true plant alone (sensing, contact,
    forward dynamics), the torque held constant (the UR5's gravity torque at the start pose), no
    controller, no record, no checks: a ``fori_loop`` of 10,000 steps compiled with the simulator's
    loop and XLA options. The same rows as a run (first call: compile)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from hinfnn._linalg import Kernels
    from hinfnn._loop import LoopOptions
    from hinfnn.sim.integrate import RK4

    built = sc.build_plant()
    n = built.n
    opts = (loop or LoopOptions()).for_joints(n)
    y0 = built.initial_state(jnp.asarray(sc.initial_q(built)), jnp.zeros(n))
    plant = Kernels.of(opts).hold(built)  # the plant traced with the simulator's kernels
    tau = sc.build_controller("hinf_nn").arm.G(y0.q)
    steps = 10_000

    def run(plant, y0, tau):
        w = jnp.zeros(n)

        def f(t, y):
            _, cache = plant.sense(t, y)
            return plant.derivative(t, y, tau, w, cache)[0], ()

        def body(k, y):
            return RK4.of(opts.rolled(n), opts.rolled_stages, record_once=False).step(f, k * DT, y, DT)[0]

        return jax.lax.fori_loop(0, steps, body, y0)

    program = jax.jit(run, compiler_options=opts.compiler_options(n))
    t0 = time.perf_counter()
    y = jax.block_until_ready(program(plant, y0, tau))
    first = time.perf_counter() - t0
    times = []
    for _ in range(max(1, args.repeats) + 1):
        t0 = time.perf_counter()
        y = jax.block_until_ready(program(plant, y0, tau))
        times.append(time.perf_counter() - t0)
    best = min(times)
    finite = all(bool(np.isfinite(np.asarray(a)).all()) for a in jax.tree.leaves(y))
    return dict(scenario="ur5-table-stable", first_run_s=first, run_s=_stats(times), steps_per_s=steps / best,
                us_per_step=1e6 * best / steps, s_per_10s_run=T_RUN / (steps * DT) * best, status=0 if finite else 1)


def case_ur5_latency(args, sync: bool = False) -> dict:
    """The UR5's sampled update (ur5-table-stable, H∞ + NN, 1 kHz) called from a Python loop as a
    robot's loop calls it (benchmarks/latency.py), JAX's CPU async dispatch on (the default) or,
    ``sync``, off (a robot process's setting, as in ``latency_sync``)."""
    if sync:
        _sync_dispatch()
    sys.path.insert(0, str(HERE))
    import latency

    return latency.measure_latency(n_calls=args.calls, kind="hinf_nn", scenario="ur5-table-stable")


def case_ur5_latency_sync(args) -> dict:
    return case_ur5_latency(args, sync=True)


def case_ur5_batch(args) -> dict:
    """The UR5 (ur5-table, H∞ + NN) as batches of B plants (``simulate_batch``, the same plant B
    times, stacked: every member computes the whole arithmetic), fields="metrics": for each B of
    ``--arm-batches`` a first ``--arm-batch-horizon``-s run (compile included, empty cache) and a
    second one, timed: trajectory-steps per second and the time per member-step. The first run's
    compiling is JAX's own account of it (its monitoring events: tracing, lowering to StableHLO,
    XLA's compile), summed over the programs the first run builds; the first run's time less the
    second's is kept beside it, but it carries the run's own noise (±20 % of a 35-s run at
    B = 4,096 is ±7 s)."""
    import jax.monitoring as mon
    import numpy as np

    import hinfnn as H
    from hinfnn._startup import StartupTrace

    spent = {"s": 0.0}

    def on_duration(event, seconds, **_):
        if event in StartupTrace._NAMES:  # JAX's trace, lower and compile events
            spent["s"] += seconds

    mon.register_event_duration_secs_listener(on_duration)
    loop = _loop_options(args)
    sc = _ur5()
    plant, ctrl, ref = sc.build_plant(), sc.build_controller("hinf_nn"), sc.build_reference()
    q0 = sc.initial_q(plant)
    out = {}
    for B in args.arm_batches:
        kw = dict(dt=DT, q0=[q0] * B, fields="metrics", loop=loop)
        spent["s"] = 0.0
        t0 = time.perf_counter()  # the first run of the timed horizon: compiled (a batch's chunk size follows it)
        H.simulate_batch([plant] * B, ctrl, ref, t_final=args.arm_batch_horizon, **kw)
        compile_s, jax_compile_s = time.perf_counter() - t0, spent["s"]
        t0 = time.perf_counter()
        traj = H.simulate_batch([plant] * B, ctrl, ref, t_final=args.arm_batch_horizon, **kw)
        wall = time.perf_counter() - t0
        rate = B * round(args.arm_batch_horizon / DT) / wall
        out[str(B)] = dict(compile_s=compile_s, jax_compile_s=jax_compile_s, wall_s=wall, traj_steps_per_s=rate,
                           us_per_member_step=1e6 / rate, failed=int((np.asarray(traj.status) != 0).sum()),
                           peak_rss_gb=peak_rss_gb())
        print(f"ur5_batch B={B}: {json.dumps(out[str(B)])}", file=sys.stderr, flush=True)  # kept if killed
    return out


def case_ur5_whole(args) -> dict:
    """``hinfnn run ur5-table`` (H∞ + NN, 10 s, ``--no-figures``) as a new process from launch to
    exit, cold (empty caches) then warm: wall and CPU time."""
    sys.path.insert(0, str(HERE))
    from startup import hinfnn_command, launch

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "HINFNN_CACHE_DIR": str(Path(tmp) / "cache"), "HINFNN_TRACE_STARTUP": "1"}
        cmd = hinfnn_command() + ["run", "ur5-table", "--set", "controller.kind=hinf_nn",
                                  "--set", f"simulation.t_final={args.arm_whole_horizon}", "--no-figures",
                                  "--quiet", "--force", "--out", str(Path(tmp) / "out")]
        for name in ("cold", "warm"):
            r = launch(cmd, env)
            out[name] = dict(wall_s=r["total"], cpu_s=r["cpu_total"])
    return out


CASES = {"single": case_single, "batch": case_batch, "startup": case_startup, "whole": case_whole,
         "latency": case_latency, "latency_sync": case_latency_sync, "devices": case_devices,
         "device_run": case_device_run, "arm_devices": case_arm_devices, "arm_run": case_arm_run,
         "batch_devices": case_batch_devices, "batch_run": case_batch_run, "program_gc": case_program_gc,
         "arm_batch_devices": case_arm_batch_devices, "arm_batch_run": case_arm_batch_run,
         "arm_sampled_devices": case_arm_sampled_devices, "arm_sampled_run": case_arm_sampled_run,
         "launch_floor": case_launch_floor, "ur5_anchor": case_ur5_anchor, "ur5_single": case_ur5_single, "ur5_latency": case_ur5_latency,
         "ur5_latency_sync": case_ur5_latency_sync,
         "ur5_batch": case_ur5_batch, "ur5_whole": case_ur5_whole}
DEFAULT_CASES = ["single", "batch", "startup", "whole", "latency", "latency_sync", "devices", "arm_devices",
                 "batch_devices", "program_gc", "launch_floor", "ur5_anchor", "ur5_single", "ur5_latency", "ur5_latency_sync",
                 "ur5_batch", "ur5_whole"]


# --- driver --------------------------------------------------------------------------------------

def run_worker(case: str, args) -> dict:
    """Run one case in a fresh Python process; returns its JSON result (peak memory its own)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.json"
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", case, "--worker-out", str(out),
               "--repeats", str(args.repeats), "--horizon", str(args.horizon),
               "--batch-horizon", str(args.batch_horizon), "--numpy-horizon", str(args.numpy_horizon),
               "--calls", str(args.calls), "--seed", str(args.seed), "--batch-fields", args.batch_fields,
               "--batches", *map(str, args.batches), "--arm-horizon", str(args.arm_horizon),
               "--arm-batch-horizon", str(args.arm_batch_horizon), "--arm-whole-horizon", str(args.arm_whole_horizon),
               "--arm-batches", *map(str, args.arm_batches)]
        if getattr(args, "disable", None):
            cmd += ["--disable", *args.disable]
        # compile times are cold: a fresh, empty compilation cache for every worker (case 3
        # measures the cache itself)
        env = dict(os.environ, HINFNN_CACHE_DIR=str(Path(tmp) / "jax-cache"))
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:  # its stderr: the error, and what a killed ur5_batch measured before
            sys.stderr.write(proc.stderr[-4000:])
            return dict(error=f"worker for {case!r} exited with {proc.returncode}", wall_s=wall)
        res = json.loads(out.read_text())
        res["case_wall_s"] = wall
        return res


def fmt(x, spec=",.0f"):
    return "—" if x is None else format(x, spec)


def mark(ok):
    return "met" if ok else "MISSED"


def _print_each_off(title: str, case: dict | None, cols: list) -> None:
    """The table of an :func:`_each_off` case: one row per "devices off" entry, columns
    ``(header, width, format(row))``."""
    if not case or "error" in case:
        return
    print(title)
    hdr = f"{'devices off':<14}" + "".join(f"{h:>{w}}" for h, w, _ in cols)
    print(hdr)
    print("-" * len(hdr))
    for name, r in case.items():
        if isinstance(r, dict) and "error" not in r:
            print(f"{name:<14}" + "".join(f"{show(r):>{w}}" for _, w, show in cols))


def _print_ur5(c: dict) -> None:
    """The UR5 cases (ur5_anchor, ur5_single, ur5_latency, ur5_batch, ur5_whole), when run; every
    per-step time also as a ratio to the Pinocchio anchor of the same invocation."""
    anchor = c.get("ur5_anchor", {}).get("us_per_rk4_step")
    ratio = (lambda us: f"{us / anchor:.2f}") if anchor else (lambda us: "–")
    if not any(k.startswith("ur5_") for k in c):
        return
    print("\nUR5 (ur5-table, H∞ + NN)")
    if anchor:
        a = c["ur5_anchor"]
        print(f"anchor: the rigid-body terms of one RK4 step (plant + nominal: M, bias, tool Jacobian and its rate, "
              f"4 stages) by Pinocchio {a['pinocchio']} from Python: {anchor:.1f} µs")
    rows = c.get("ur5_single", {})
    rows = {k: r for k, r in rows.items() if isinstance(r, dict) and "steps_per_s" in r}
    if rows:
        hdr = (f"{'one run':<22}{'1st run s':>10}{'steps/s':>9}{'µs/step':>9}{'× anchor':>9}{'10-s run s':>11}"
               f"{'kernels/step':>13}{'distinct':>9}{'lib calls':>10}{'status':>7}")
        print(hdr + "\n" + "-" * len(hdr))
        foot = c.get("launch_floor", {}).get("footprint") or []
        for label, r in rows.items():
            ops = r.get("ops") or {}
            print(f"{label:<22}{r['first_run_s']:>10.1f}{r['steps_per_s']:>9,.0f}{r['us_per_step']:>9.1f}"
                  f"{ratio(r['us_per_step']):>9}{r['s_per_10s_run']:>11.2f}{fmt(ops.get('kernels'), 'd'):>13}"
                  f"{fmt(ops.get('distinct_kernels'), 'd'):>9}{fmt(ops.get('custom_calls'), 'd'):>10}{r['status']:>7}")
            if foot and ops.get("kernels") and ops.get("distinct_kernels"):
                near = min(foot, key=lambda f: abs(f["distinct"] - ops["distinct_kernels"]))
                per, branch = near["us_per_launch"], ops.get("kernels_in_conditionals") or 0
                span = (f"{per * (ops['kernels'] - branch):.0f}–{per * ops['kernels']:.0f} µs" if branch
                        else f"about {per * ops['kernels']:.0f} µs")
                print(f"{'':<22}(its kernels at launch_floor's cost, a launch and a 6 × 6 product's work each: {span} "
                      f"of the {r['us_per_step']:.0f} µs per step, at {per:.3f} µs per kernel in a loop of "
                      f"{near['distinct']} distinct kernels"
                      + (f"; {branch} of the {ops['kernels']} kernels counted are in conditionals, counted as if "
                         "taken at every iteration" if branch else "") + ")")
        if "plant alone" in rows:
            print(f"{'':<22}(plant alone: RK4 of the true plant with the torque held, no controller, record or checks: "
                  "the floor under a sampled run's step)")
    if "ur5_batch" in c and "error" not in c["ur5_batch"]:
        hdr = (f"{'batch B':<16}{'1st run s':>10}{'wall s':>9}{'1st-2nd s':>10}{'compile s':>10}{'traj-steps/s':>14}"
               f"{'µs/member-step':>16}{'× anchor':>9}{'peak GB':>8}{'failed':>7}")
        print(hdr + "\n" + "-" * len(hdr))
        print("(compile s: JAX's tracing, lowering and XLA compiling in the first run, by its monitoring events; "
              "1st-2nd s: the first run's time less the second's, the same horizon, which also carries the run's noise)")
        for B, r in c["ur5_batch"].items():
            if not isinstance(r, dict):
                continue
            print(f"{B:<16}{r['compile_s']:>10.1f}{r['wall_s']:>9.2f}{r['compile_s'] - r['wall_s']:>10.1f}"
                  f"{r.get('jax_compile_s', float('nan')):>10.1f}"
                  f"{r['traj_steps_per_s']:>14,.0f}"
                  f"{r['us_per_member_step']:>16.1f}{ratio(r['us_per_member_step']):>9}"
                  f"{r.get('peak_rss_gb', float('nan')):>8.2f}{r['failed']:>7}")
    for name, label in (("ur5_latency", "async dispatch on"), ("ur5_latency_sync", "async dispatch off")):
        lat = c.get(name, {})
        if "median_us" in lat:
            print(f"sampled update (ur5-table-stable at 1 kHz, SampledLoop.update from Python, {lat['n_calls']:,} calls, "
                  f"JAX's CPU {label}): median {lat['median_us']:.1f} µs ({ratio(lat['median_us'])} × anchor), "
                  f"p99 {lat['p99_us']:.1f} µs, max {lat['max_us']:.1f} µs")
    w = c.get("ur5_whole", {})
    if "cold" in w:
        print(f"`hinfnn run ur5-table --no-figures` (10 s) process: cold {w['cold']['wall_s']:.1f} s "
              f"(CPU {w['cold']['cpu_s']:.1f}), warm {w['warm']['wall_s']:.1f} s (CPU {w['warm']['cpu_s']:.1f})")


def print_report(res: dict) -> None:
    m = res["machine"]
    print(f"\nhinfnn {m['hinfnn']} ({m['commit']}) · {m['cpu']} · {m['usable_cores']} of {m['cores']} cores · "
          f"{m['memory_gb']} GB · Python {m['python']} · JAX {m['jax']} (jaxlib {m['jaxlib']}) · {m['platform']}")
    c = res["cases"]
    lf = c.get("launch_floor", {})
    if "us_per_kernel" in lf:
        print("\nXLA's CPU runtime per kernel launched in a loop (K 6×6 products and tanh per iteration): "
              + ", ".join(f"{r['kernels']} kernels {r['us_per_iteration']:.1f} µs" for r in lf["rows"])
              + f"; slope {lf['us_per_kernel']:.3f} µs per kernel")
        if lf.get("footprint"):
            print("the same 1,200 launches per iteration from fewer distinct kernels: "
                  + ", ".join(f"{f['distinct']} distinct {f['us_per_iteration']:.1f} µs ({f['us_per_launch']:.3f} µs/launch)"
                              for f in lf["footprint"]))
    _print_ur5(c)
    if "single" in c and "rows" in c["single"]:
        print("\n1. One 10-s run of the paper scenario (100,000 RK4 steps, dt = 1e-4, controller at every stage)")
        hdr = (f"{'controller':<13}{'s/run med':>10}{'min':>7}{'max':>7}{'steps/s':>10}{'compile s':>10}"
               f"{'NumPy s/run':>12}{'× NumPy':>9}{'kernels/step':>13}{'tanh+sin+cos/step':>18}{'peak GB':>8}")
        print(hdr)
        print("-" * len(hdr))
        for kind, r in c["single"]["rows"].items():
            s = r["s_per_10s_run"]
            ops = r["ops"]
            tr = ops.get("elementwise_per_step") or {}
            trans = (tr.get("tanh", 0) + tr.get("sine", 0) + tr.get("cosine", 0)) if tr else None
            print(f"{kind:<13}{s['median']:>10.3f}{s['min']:>7.3f}{s['max']:>7.3f}{r['steps_per_s']:>10,.0f}"
                  f"{r['compile_s']:>10.1f}{r['numpy']['s_per_10s_run']:>12.1f}{r['speedup_vs_numpy']:>9.0f}"
                  f"{fmt(ops.get('kernels'), 'd'):>13}{fmt(trans, ',d'):>18}{c['single']['peak_rss_gb']:>8.2f}")
        notes = [f"{k}: {r['status']}" for k, r in c["single"]["rows"].items() if r.get("status", "ok") != "ok"]
        print("(1kHz rows: the sampled-data mode, controller once per 1 ms with zero-order hold, plant RK4 "
              "every 0.1 ms; not a target" + (f"; {'; '.join(notes)}" if notes else "") + ")")
    if "batch" in c and "rows" in c["batch"]:
        first = next(iter(c["batch"]["rows"].values()))
        print(f"\n2. Adaptive controller, B parameter sets (±20 %) under vmap, storing "
              f"{first['n_fields']} fields ({first['fields']}) every 1 ms")
        hdr = (f"{'B':>6}{'horizon s':>10}{'wall s':>9}{'traj-steps/s':>14}{'1000×10 s runs, s':>19}"
               f"{'compile s':>10}{'completed':>10}{'stored GB':>10}{'peak GB':>9}")
        print(hdr)
        print("-" * len(hdr))
        for r in c["batch"]["rows"].values():
            print(f"{r['batch']:>6}{r['horizon_s']:>10.1f}{r['wall_s']:>9.2f}{r['traj_steps_per_s']:>14,.0f}"
                  f"{r['s_per_1000_runs_of_10s']:>19,.0f}{r['compile_s']:>10.1f}{r['completed']:>10}"
                  f"{r['stored_gb']:>10.3f}{r['peak_rss_gb']:>9.2f}")
        acc = next(iter(c["batch"]["rows"].values()))["acceptance"]
        print(f"(draws with an unreachable start pose were redrawn: acceptance {acc:.0%})")
    if "startup" in c and "error" not in c["startup"]:
        s = c["startup"]
        print("\n3. New process `hinfnn run paper`: seconds from launch to the first simulated step")
        print(f"cold (empty cache) {fmt(s.get('cold_first_step_s'), '.2f')}   "
              f"warm (median) {fmt(s.get('warm_first_step_s'), '.2f')}")
    if "whole" in c and "error" not in c["whole"]:
        sys.path.insert(0, str(HERE))
        import whole

        print("\n4. New process `hinfnn run paper` (10 s, figures included): launch to exit")
        print(whole.format_table(c["whole"]))
    lat = [(name, c[name]) for name in ("latency", "latency_sync") if name in c and "error" not in c[name]]
    if lat:
        print("\n5. Sampled update from a Python loop (SampledLoop.update, τ back as NumPy), µs per call")
        hdr = f"{'controller':<10}{'JAX async dispatch':>20}{'flops':>7}{'median':>9}{'p90':>9}{'p99':>9}{'max':>10}{'calls':>8}"
        print(hdr)
        print("-" * len(hdr))
        for name, rows in lat:
            for kind, r in rows.items():
                if not isinstance(r, dict):
                    continue
                print(f"{kind:<10}{'on (default)' if name == 'latency' else 'off':>20}{fmt(r.get('flops'), ',.0f'):>7}"
                      f"{r.get('median_us', float('nan')):>9.1f}{r.get('p90_us', float('nan')):>9.1f}"
                      f"{r.get('p99_us', float('nan')):>9.1f}{r.get('max_us', float('nan')):>10.1f}"
                      f"{r.get('n_calls', 0):>8}")
    dev = c.get("devices")
    if dev and "error" not in dev:
        base = dev.get("all on", {})
        b_run = base.get("s_per_10s_run", {}).get("median")
        b_batch = base.get("batch100_traj_steps_per_s")
        print("\n6. Loop options (hinfnn._loop) and the block layout, each off in turn: adaptive 10-s run, 100-plant batch")
        hdr = f"{'devices off':<14}{'s per run':>11}{'× all on':>10}{'batch traj-steps/s':>20}{'× all on':>10}{'kernels/step':>14}"
        print(hdr)
        print("-" * len(hdr))
        for name, r in dev.items():
            if not isinstance(r, dict):
                continue
            if "error" in r:
                print(f"{name:<14}{r['error']}")
                continue
            run = r["s_per_10s_run"]["median"]
            bat = r["batch100_traj_steps_per_s"]
            print(f"{name:<14}{run:>11.3f}{(run / b_run if b_run else float('nan')):>10.2f}{bat:>20,.0f}"
                  f"{(bat / b_batch if b_batch else float('nan')):>10.2f}{fmt((r.get('ops') or {}).get('kernels'), 'd'):>14}")
    _print_each_off("\n7. rolled_rk4 on a 6-joint arm (ur5-table, H∞ + NN): compile-dominated first run, then a "
                    "0.5-s run", c.get("arm_devices"),
                    [("first run s", 12, lambda r: f"{r['first_run_s']:.2f}"),
                     ("0.5-s run s", 13, lambda r: f"{r['s_per_half_second']['median']:.3f}")])
    _print_each_off("\n8. batch_groups at B = 1,000 (adaptive law, 1 s, metrics)", c.get("batch_devices"),
                    [("wall s", 8, lambda r: f"{r['wall_s']:.2f}"),
                     ("traj-steps/s", 14, lambda r: f"{r['traj_steps_per_s']:,.0f}")])
    _print_each_off("\n8b. member_minor on a UR5 batch of 256 (H∞ + NN, metrics)", c.get("arm_batch_devices"),
                    [("compile s", 11, lambda r: f"{r['compile_s']:.1f}"),
                     ("traj-steps/s", 14, lambda r: f"{r['traj_steps_per_s']:,.0f}")])
    _print_each_off("\n8c. frozen_law on the UR5 at 1 kHz (ur5-table-stable, H∞ + NN): µs per RK4 step of a 0.5-s run",
                    c.get("arm_sampled_devices"),
                    [("1st run s", 11, lambda r: f"{r['bookkeeping']['first_run_s']:.1f}"),
                     ("bookkeeping", 13, lambda r: f"{r['bookkeeping']['us_per_step']:.1f}"),
                     ("none", 8, lambda r: f"{r['no bookkeeping']['us_per_step']:.1f}")])
    g = c.get("program_gc", {})
    if "on" in g:
        print("\n9. program_gc: `hinfnn run paper --no-figures` (0.05 s, warm), medians of fresh processes")
        for k, label in (("on", "device on"), ("off", "Python's default")):
            print(f"{label:<18} wall {g[k]['wall_s']:.2f} s   CPU {g[k]['cpu_s']:.2f} s   ({g[k]['n']} launches)")
        print(f"on / off: wall {g['on']['wall_s'] / g['off']['wall_s']:.2f}, CPU {g['on']['cpu_s'] / g['off']['cpu_s']:.2f}")
    if res.get("targets"):
        print("\nTargets")
        for name, t in res["targets"].items():
            print(f"  {name:<38}{t['measured']:>14,.3f}  target {t['op']} {t['target']:,g}  {mark(t['met'])}")
        if not all(t["met"] for t in res["targets"].values()):
            print("  (docs/performance.md, \"The limits\": what keeps each missed target missed)")
    for case, r in c.items():
        if "error" in r:
            print(f"\n{case}: {r['error']}")


def targets(c: dict) -> dict:
    out = {}

    def add(name, measured, op, target):
        if measured is None:
            return
        met = measured <= target if op == "<=" else measured >= target
        out[name] = dict(measured=measured, op=op, target=target, met=bool(met))

    if "rows" in c.get("single", {}):
        for kind, r in c["single"]["rows"].items():
            if r.get("mode", "continuous") != "continuous":
                continue
            if kind in TARGETS["single_s_per_run"]:
                add(f"case 1 {kind}: s per 10-s run", r["s_per_10s_run"]["median"], "<=",
                    TARGETS["single_s_per_run"][kind])
            add(f"case 1 {kind}: × NumPy oracle", r["speedup_vs_numpy"], ">=", TARGETS["single_speedup_vs_numpy"])
            add(f"case 1 {kind}: compile s", r["compile_s"], "<=", TARGETS["single_compile_s"])
    rows = c.get("batch", {}).get("rows", {})
    if "1000" in rows:
        add("case 2 B=1000: traj-steps/s", rows["1000"]["traj_steps_per_s"], ">=", TARGETS["batch1000_traj_steps_per_s"])
        add("case 2 B=1000: peak GB", rows["1000"]["peak_rss_gb"], "<=", TARGETS["batch1000_memory_gb"])
    s = c.get("startup", {})
    if s.get("warm_first_step_s") is not None:
        add("case 3: warm start to first step, s", s["warm_first_step_s"], "<=", TARGETS["startup_warm_s"])
    w = c.get("whole", {})
    if w.get("warm_s") is not None:
        add("case 4: whole process warm, s", w["warm_s"], "<=", TARGETS["whole_warm_s"])
        add("case 4: whole process cold, s", w["cold_s"], "<=", TARGETS["whole_cold_s"])
    u = c.get("ur5_single", {})
    if "steps_per_s" in u.get("continuous", {}):
        add("UR5 continuous: s per 10-s run", u["continuous"]["s_per_10s_run"], "<=", TARGETS["ur5_s_per_10s_run"])
    if "steps_per_s" in u.get("sampled 1 kHz", {}):
        add("UR5 1 kHz: s per 10-s run", u["sampled 1 kHz"]["s_per_10s_run"], "<=",
            TARGETS["ur5_sampled_s_per_10s_run"])
    if "steps_per_s" in u.get("1 kHz, no bookkeeping", {}):
        add("UR5 1 kHz, no bookkeeping: s per 10-s run", u["1 kHz, no bookkeeping"]["s_per_10s_run"], "<=",
            TARGETS["ur5_sampled_s_per_10s_run"])
    for B, r in c.get("ur5_batch", {}).items():
        if isinstance(r, dict) and int(B) >= 256:
            add(f"UR5 B={B}: traj-steps/s", r["traj_steps_per_s"], ">=", TARGETS["ur5_batch_traj_steps_per_s"])
            if "jax_compile_s" in r:
                add(f"UR5 B={B}: compile s (trace, lower, compile)", r["jax_compile_s"], "<=",
                    TARGETS["ur5_batch_compile_s"])
            else:  # results written before the compile was measured by JAX's own events
                add(f"UR5 B={B}: compile s (1st run - 2nd)", r["compile_s"] - r["wall_s"], "<=",
                    TARGETS["ur5_batch_compile_s"])
    if "median_us" in c.get("ur5_latency", {}):
        add("UR5 sampled update: median µs", c["ur5_latency"]["median_us"], "<=", TARGETS["ur5_latency_median_us"])
        add("UR5 sampled update: p99 µs", c["ur5_latency"]["p99_us"], "<=", TARGETS["ur5_latency_p99_us"])
    if "median_us" in c.get("ur5_latency_sync", {}):
        add("UR5 sampled update, async off: median µs", c["ur5_latency_sync"]["median_us"], "<=",
            TARGETS["ur5_latency_median_us"])
        add("UR5 sampled update, async off: p99 µs", c["ur5_latency_sync"]["p99_us"], "<=",
            TARGETS["ur5_latency_p99_us"])
    if "warm" in c.get("ur5_whole", {}):
        add("UR5 whole process warm, s", c["ur5_whole"]["warm"]["wall_s"], "<=", TARGETS["ur5_whole_warm_s"])
    for name, label in (("latency", "async on"), ("latency_sync", "async off")):
        for kind, r in c.get(name, {}).items():
            if isinstance(r, dict) and "median_us" in r:
                add(f"case 5 {kind} ({label}): median µs", r["median_us"], "<=", TARGETS["latency_median_us"])
                add(f"case 5 {kind} ({label}): p99 µs", r["p99_us"], "<=", TARGETS["latency_p99_us"])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--cases", nargs="*", default=DEFAULT_CASES, choices=list(CASES))
    ap.add_argument("--repeats", type=int, default=3, help="timed repetitions after the warm-up")
    ap.add_argument("--horizon", type=float, default=T_RUN, help="simulated seconds per timed single run")
    ap.add_argument("--batches", type=int, nargs="*", default=[1, 10, 100, 1000])
    ap.add_argument("--batch-horizon", type=float, default=T_RUN, help="simulated seconds per batch run")
    ap.add_argument("--arm-horizon", type=float, default=2.0, help="simulated seconds per timed UR5 run")
    ap.add_argument("--arm-batches", type=int, nargs="*", default=[64, 256, 1024, 4096], help="UR5 batch sizes")
    ap.add_argument("--arm-batch-horizon", type=float, default=0.05, help="simulated seconds per UR5 batch run")
    ap.add_argument("--arm-whole-horizon", type=float, default=10.0, help="simulated seconds of the UR5 process")
    ap.add_argument("--batch-fields", default="metrics", help="what batch runs store: 'metrics' or 'all'")
    ap.add_argument("--numpy-horizon", type=float, default=1.0, help="NumPy oracle horizon (scaled to 10 s)")
    ap.add_argument("--calls", type=int, default=10_000, help="update() calls in the latency case")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="1-s horizons, batches up to 100, 2,000 calls")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--worker", choices=list(CASES), help=argparse.SUPPRESS)
    ap.add_argument("--worker-out", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--disable", nargs="*", default=[], help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.quick:
        args.horizon, args.batch_horizon, args.numpy_horizon = 1.0, 1.0, 0.2
        args.batches = [b for b in args.batches if b <= 100]
        args.calls = min(args.calls, 2000)
    if args.worker:
        import numpy as np

        import hinfnn

        unknown = sorted(set(args.disable) - set(SWITCHES))
        if unknown:
            raise SystemExit(f"unknown --disable {unknown}; allowed: {', '.join(SWITCHES)}")
        hinfnn.configure()
        np.seterr(all="ignore")
        res = CASES[args.worker](args)
        args.worker_out.write_text(json.dumps(res, indent=1, default=float))
        return 0

    t_start = time.perf_counter()
    # machine info in a worker too, so this process never initialises JAX
    info = subprocess.run([sys.executable, "-c", "import json, sys; sys.path.insert(0, %r); import run; "
                           "print(json.dumps(run.machine()))" % str(HERE)], capture_output=True, text=True)
    mach = json.loads(info.stdout) if info.returncode == 0 else dict(error=info.stderr[-500:])
    res = dict(machine=mach, started=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
               argv=sys.argv[1:], cases={})
    for case in args.cases:
        print(f"[{time.perf_counter() - t_start:6.0f} s] case {case} …", file=sys.stderr, flush=True)
        res["cases"][case] = run_worker(case, args)
    res["targets"] = targets(res["cases"])
    res["total_s"] = time.perf_counter() - t_start
    args.out.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    text = json.dumps(res, indent=1, default=float)
    (args.out / f"bench-{stamp}.json").write_text(text)
    (args.out / "latest.json").write_text(text)
    print_report(res)
    print(f"\ntotal {res['total_s']:.0f} s; written {args.out / f'bench-{stamp}.json'}")
    return 0 if all("error" not in r for r in res["cases"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
