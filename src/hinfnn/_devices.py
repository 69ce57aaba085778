"""Performance devices, all in this one module: of the compiled simulation loop, and of the
``hinfnn run`` process as a whole.

Each loop device changes how XLA's CPU runtime executes the loop, never what it computes (the numbers
agree to rounding), and each has the benchmark line that justifies it: ``python
benchmarks/run.py --devices`` runs the paper's 10-s adaptive run with each device turned off in
turn, in a fresh process, and prints the ratio against all devices on. The process devices
(``png_fast``, ``program_gc``, ``fast_exit``, below the loop devices) change no number either;
their lines come from ``python benchmarks/run.py --cases whole`` (``benchmarks/whole.py``) and
``--cases program_gc``.

``blocks``
    Large controller-state arrays (the networks' weights Θ̂, 40 and 120 values) are carried
    through the loop as tuples of blocks of at most :data:`BLOCK` float64 values, and the
    networks' centres and features are computed block by block. XLA's CPU runtime runs the
    kernels of a compiled loop body inline, one after the other, only when every buffer they
    touch is at most 512 bytes (64 float64); one larger buffer sends the kernels of the step
    through its thread pool, which costs about as much as the step's arithmetic (2.0 s vs 1.0 s
    per 100,000 steps on the paper's adaptive run when this was introduced). Public state is
    always flat: the split happens at the loop boundary (:func:`split` / :func:`join`, called by
    the controller's ``to_loop`` / ``from_loop``).
``sincos``
    Sines and cosines of a vector of angles computed once and shared (:func:`sincos`). XLA
    counts them as cheap and recomputes them inside every kernel that uses them (the paper's RK4
    step made about 240 libm calls for its 24 distinct values); a reduction is never recomputed,
    so the values pass through a sum with 0·v (exact for finite values; NaN stays NaN).
``small_mm``
    Products of tiny matrices written as multiply-and-sum (:func:`mm`), which XLA fuses with the
    neighbouring arithmetic; a ``dot`` of 2 × 2 operands is a kernel of its own (1.9 s vs 2.5 s
    per 100,000 steps of the paper's adaptive run when this was introduced).
``rolled_rk4``
    For arms with at least :data:`ROLL_FROM_JOINTS` joints, RK4's four stages are a loop of four
    iterations (:func:`~hinfnn.sim.integrate.rk4_step`, ``rolled``), so the compiled step holds
    the plant and the controller once instead of four times. This one is for compile time: the
    UR5's H∞ + NN first run (0.05 s simulated, compile-dominated) takes 14.1 s instead of 24.8 s
    written out, and its 0.5-s run 1.51 s instead of 2.02 s, with the same numbers bit for bit
    (``python benchmarks/run.py --cases arm_devices``; ur5-table, ur5-sphere and planar3-drum,
    three kinds each: 417 arrays equal). Rolling only stages 2–4 (the plant and the controller
    twice) took 15.3 s and 1.86 s. The paper's 2-joint arm keeps the stages written out: rolled, its
    adaptive 10-s run took 3.0 s instead of 1.9 s and its results moved by up to 8e-9.
``batch_groups``
    A batch of more than :data:`BATCH_GROUP` members runs as equal groups of at most that many,
    one after the other, through one compiled program (the last group is padded with copies of
    its first member, whose results are dropped). Past a few hundred members the vmapped step's
    arrays no longer stay in the cache: the paper's adaptive law at B = 1,000 (1 s, metrics)
    runs 260,875 trajectory-steps/s in two groups of 500 and 179,791 in one group (``python
    benchmarks/run.py --cases batch_devices``), with the same numbers bit for bit (each member's
    run does not depend on the others).
``png_fast``
    Figures written with zlib level 1 instead of matplotlib's 6 (:func:`png_options`): the
    same pixels, files about 15 % larger; the six PNGs of ``hinfnn run paper`` encode in
    0.41 s instead of 0.81 s.
``program_gc``
    The ``hinfnn`` program (not :func:`hinfnn.cli.main` called from Python) runs Python's cyclic
    garbage collector less often (:func:`program_gc`, before JAX is imported): a
    collection of the youngest objects every 100,000 allocations instead of 700. Importing JAX
    and tracing a program allocate millions of short-lived objects, and each collection walks
    them. ``python benchmarks/run.py --cases program_gc`` (``hinfnn run paper --no-figures``, 0.05 s
    simulated, warm cache, fresh processes alternating with ``HINFNN_DEFAULT_GC=1``): 3.97 s
    instead of 4.58 s, CPU 4.02 s instead of 4.45 s (medians of 6, ``bench-20261130T103213Z.json``).
    The full 10-s run with figures: 10.0 s against 9.9 s (medians of 6), no difference within this
    machine's noise. The test suite's processes use the same thresholds (``tests/conftest.py``):
    ``test_sim.py`` with ``test_controllers.py`` took 110–119 s instead of 121–124 s.
``fast_exit``
    The ``hinfnn`` program ends with ``os._exit`` once its output is flushed and the ``atexit``
    handlers have run (:func:`fast_exit`), skipping the interpreter's teardown of JAX, XLA and
    matplotlib objects: 0.5-0.7 s of wall and CPU time per process.

:func:`disable` turns devices off (the benchmark does it in a fresh process, before anything is
compiled: the switches are read when a program is traced).
"""

from __future__ import annotations

# JAX is imported by the loop devices' functions when they are traced, not here: the ``hinfnn``
# program calls :func:`program_gc` before JAX is imported.

#: Largest number of float64 values kept in one array of the loop carry (512 bytes).
BLOCK = 64
#: Longest contraction :func:`mm` writes as multiply-and-sum.
SMALL = 4

ENABLED = {"blocks": True, "sincos": True, "small_mm": True, "rolled_rk4": True, "batch_groups": True,
           "png_fast": True, "fast_exit": True, "program_gc": True}
#: Arms with at least this many joints integrate with RK4's stages 2–4 rolled (``rolled_rk4``).
ROLL_FROM_JOINTS = 3
#: Largest group of a batch run at once (``batch_groups``).
BATCH_GROUP = 500


def disable(*names: str) -> None:
    """Turn devices off (any name of :data:`ENABLED`), for the benchmark and the tests only.

    Must run before the first program is traced; programs compiled earlier keep the devices."""
    for name in names:
        if name not in ENABLED:
            raise ValueError(f"unknown device {name!r}; devices: {', '.join(ENABLED)}")
        ENABLED[name] = False


def rolled_rk4(n_joints: int) -> bool:
    """Whether a plant with ``n_joints`` joints integrates with RK4's stages rolled."""
    return ENABLED["rolled_rk4"] and n_joints >= ROLL_FROM_JOINTS


def batch_groups(B: int) -> list:
    """Member indices of the groups a batch of B runs in (``batch_groups``): one group of all
    when B <= :data:`BATCH_GROUP` or the device is off, else equal groups (numpy index arrays,
    the last padded with its first member)."""
    import numpy as np

    if not ENABLED["batch_groups"] or B <= BATCH_GROUP:
        return [np.arange(B)]
    n = -(-B // BATCH_GROUP)
    g = -(-B // n)
    groups = []
    for i in range(n):
        idx = np.arange(i * g, min((i + 1) * g, B))
        groups.append(np.concatenate([idx, np.full(g - idx.size, idx[0])]))
    return groups


# --- blocks --------------------------------------------------------------------------------------


def block_bounds(j: int) -> list[tuple[int, int]]:
    """[(start, stop)] of ⌈j / BLOCK⌉ blocks of near-equal size (120 → 60 + 60); one block when
    the ``blocks`` device is off."""
    n = max(1, -(-j // BLOCK)) if ENABLED["blocks"] else 1
    edges = [round(i * j / n) for i in range(n + 1)]
    return list(zip(edges[:-1], edges[1:]))


def split(x, groups: int = 1) -> tuple:
    """A flat vector as a tuple of blocks: ``groups`` equal consecutive parts (one per network
    output), each cut by :func:`block_bounds`."""
    j = x.shape[-1] // groups
    return tuple(x[..., g * j + a: g * j + b] for g in range(groups) for a, b in block_bounds(j))


def join(blocks: tuple):
    """Inverse of :func:`split`."""
    import jax.numpy as jnp

    return jnp.concatenate(blocks, axis=-1)


# --- sines and cosines ---------------------------------------------------------------------------


def sincos(x):
    """(sin x, cos x) of a vector of angles, computed once and shared (see the module docstring)."""
    import jax.numpy as jnp

    s, c = jnp.sin(x), jnp.cos(x)
    if not ENABLED["sincos"]:
        return s, c
    both = jnp.stack([s, c])
    both = jnp.sum(jnp.stack([both, 0.0 * both]), axis=0)
    return both[0], both[1]


# --- products of tiny matrices -------------------------------------------------------------------


def mm(a, b, limit: int = SMALL):
    """``a @ b`` for vectors and matrices; contractions over at most ``limit`` (default
    :data:`SMALL`) terms are written as multiply-and-sum (see the module docstring)."""
    import jax.numpy as jnp

    if (not ENABLED["small_mm"] or a.ndim > 2 or b.ndim > 2 or a.shape[-1] != b.shape[0]
            or a.shape[-1] > limit):
        return a @ b
    if a.ndim == 1 and b.ndim == 1:
        return jnp.sum(a * b)
    if a.ndim == 2 and b.ndim == 1:
        return jnp.sum(a * b[None, :], axis=1)
    if a.ndim == 1:
        return jnp.sum(a[:, None] * b, axis=0)
    return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)


# --- figures -------------------------------------------------------------------------------------


def png_options() -> dict:
    """``savefig`` keywords of every PNG hinfnn writes (``png_fast``: zlib level 1)."""
    return {"pil_kwargs": {"compress_level": 1}} if ENABLED["png_fast"] else {}


# --- the process ---------------------------------------------------------------------------------

#: Python's garbage-collector thresholds in the ``hinfnn`` program (``program_gc``); the default is
#: (700, 10, 10).
PROGRAM_GC_THRESHOLD = (100_000, 50, 100)


def program_gc() -> None:
    """Set :data:`PROGRAM_GC_THRESHOLD` (``program_gc``); the ``hinfnn`` program calls it first,
    and ``HINFNN_DEFAULT_GC=1`` keeps Python's default (for the benchmark's A/B)."""
    import gc
    import os

    if ENABLED["program_gc"] and os.environ.get("HINFNN_DEFAULT_GC") != "1":
        gc.set_threshold(*PROGRAM_GC_THRESHOLD)


# --- the end of the process ----------------------------------------------------------------------


def fast_exit(code: int) -> None:
    """End the ``hinfnn`` program now with ``code``: flush stdout and stderr, run the ``atexit``
    handlers, then ``os._exit`` (no interpreter teardown). Returns (doing nothing) when the
    ``fast_exit`` device is off."""
    if not ENABLED["fast_exit"]:
        return
    import atexit
    import os
    import sys

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more can be said there
            pass
    os._exit(code)
