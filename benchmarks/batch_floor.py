"""The arithmetic floor of a UR5 batch on one core: what its compiled step computes per member,
priced at the rate XLA's CPU code reaches on each kind of operation over a member axis.

    python benchmarks/batch_floor.py [--members 256] [--horizon 0.05] [--repeats 2] [--perf]

1. The batch (``ur5-table``, H∞ + NN, ``fields="metrics"``, B members, the shipped loop options)
   is compiled with the compilation cache off and XLA's optimised HLO dumped; the step loop's
   body (``benchmarks/hlo.py``: the steps between two samples, RK4's rolled stages expanded) gives
   the elementwise operations per member-step by kind (tanh, divide, sine, cosine, sqrt, the rest:
   add, multiply, select, compare, ... counted at each instruction's full shape, so an upper bound)
   and the bytes its kernels read and write (operand and result shapes of every launched kernel).
   Its second run is timed: µs per member-step.
2. Each kind of operation is timed alone in XLA on this machine: a loop whose body is a chain of 50
   of them over an 8 × B array (the member axis minor, as a batch stores it), one fused kernel, so
   every value stays in registers: ns per value, the best XLA's CPU code does on that operation.
3. The floor is the sum of count × rate: the member-step's arithmetic at those rates, with no
   memory traffic, no copies and no kernel launches. Its inverse is the most trajectory-steps per
   second one core could give to this formulation.
4. The kernels' traffic priced at NumPy's bandwidth on one thread, within the L2 cache and from
   memory, added to the floor: the bound if reading and writing the kernels' buffers did not
   overlap their arithmetic (a batch of 256 UR5 members passes about 40 MB through its kernels per
   step, more than this machine's 32-MiB L3).
5. ``--perf``: Linux ``perf record`` attached to one more batch run; its CPU samples split between
   the compiled kernels (XLA's JIT code), XLA's runtime and libraries, libm, Python and the
   operating system. The kernels' share of the measured time is what the batch would take if
   everything but its kernels were free: a floor that does not rest on the operation count.

No assertions: speed is measured here, never in tests/.
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import hlo  # noqa: E402

KINDS = ("tanh", "divide", "sine", "cosine", "sqrt", "other")
_SHAPE = re.compile(r"\b(f64|s64|u64|f32|s32|u32|pred|u8|s8)\[([\d,]*)\]")
_BYTES = {"f64": 8, "s64": 8, "u64": 8, "f32": 4, "s32": 4, "u32": 4, "pred": 1, "u8": 1, "s8": 1}


def _ops(comps, name, seen=()) -> dict:
    """Elementwise operations by kind one execution of computation ``name`` performs (through the
    computations it calls)."""
    out = dict.fromkeys(KINDS, 0)
    for line in comps.get(name, ()):
        m = hlo.ARITH.search(line)
        if m:
            kind = m.group(2) if m.group(2) in KINDS else "other"
            out[kind] += hlo.size(m.group(1))
        for callee in hlo._CALLS.findall(line):
            if callee not in seen:
                for k, v in _ops(comps, callee, seen + (name,)).items():
                    out[k] += v
    return out


def _kernel_bytes(line: str) -> int:
    line = line.split(", metadata=")[0].split(", backend_config=")[0]
    return sum(hlo.size(dims) * _BYTES[dt] for dt, dims in _SHAPE.findall(line))


def walk(comps, name) -> tuple[dict, int]:
    """(operations by kind, bytes read and written by the launched kernels) of one execution of
    ``name``, nested loops expanded by their trip counts, a conditional by its largest branch."""
    ops, nbytes = dict.fromkeys(KINDS, 0), 0
    for line in comps.get(name, ()):
        if hlo._WHILE.search(line):
            continue
        m = hlo._COND.search(line)
        if m:
            branches = [walk(comps, b.strip().lstrip("%")) for b in m.group(1).split(",")]
            o, b = max(branches, key=lambda x: sum(x[0].values()))
            ops = {k: ops[k] + o[k] for k in KINDS}
            nbytes += b
        elif hlo._KERNEL.search(line):
            nbytes += _kernel_bytes(line)
            for callee in hlo._CALLS.findall(line):
                o = _ops(comps, callee)
                ops = {k: ops[k] + o[k] for k in KINDS}
    for cond, body, trip in hlo.whiles(comps.get(name, ())):
        for part in (body, cond):
            o, b = walk(comps, part)
            ops = {k: ops[k] + (trip or 1) * o[k] for k in KINDS}
            nbytes += (trip or 1) * b
    return ops, nbytes


def batch_step(members: int, horizon: float, repeats: int, dump: str, profile: bool = False) -> dict:
    """Compile and time the UR5 batch (in this process, XLA dumping to ``dump``)."""
    import hinfnn as H

    H.configure(cache=False)
    sc = H.load_scenario("ur5-table", {"controller.kind": "hinf_nn"})
    plant, ctrl, ref = sc.build_plant(), sc.build_controller("hinf_nn"), sc.build_reference()
    kw = dict(dt=1e-4, q0=[sc.initial_q(plant)] * members, fields="metrics", t_final=horizon)
    H.simulate_batch([plant] * members, ctrl, ref, **kw)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        H.simulate_batch([plant] * members, ctrl, ref, **kw)
        best = min(best, time.perf_counter() - t0)
    steps = round(horizon / 1e-4)
    shares = None
    if profile:
        shares = _profiled(lambda: H.simulate_batch([plant] * members, ctrl, ref, **kw))
    text = open(max(glob.glob(f"{dump}/*after_optimizations.txt"), key=os.path.getsize)).read()
    comps, entry = hlo.computations(text)
    body = hlo.step_loop(comps, entry)
    ops, nbytes = walk(comps, body)
    return dict(us_per_member_step=best / (members * steps) * 1e6, kernels=hlo.kernels(comps, body),
                ops={k: v / members for k, v in ops.items()}, bytes=nbytes / members, shares=shares)


def _profiled(run) -> dict:
    """Shares of the CPU samples (``perf record`` attached to this process while ``run()`` runs)
    by where they fall: the compiled kernels (XLA's JIT code, which has no file behind it), XLA's
    runtime and libraries (``libjax_common``: kernel launches, YNNPACK, the thread pool), libm, the
    Python interpreter, the operating system's kernel, the rest."""
    with tempfile.TemporaryDirectory() as tmp:
        data = f"{tmp}/perf.data"
        perf = subprocess.Popen(["perf", "record", "-F", "1999", "-p", str(os.getpid()), "-o", data],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(1.0)  # perf attaches
        run()
        perf.send_signal(signal.SIGINT)
        perf.wait()
        report = subprocess.run(["perf", "report", "-i", data, "--stdio", "--sort", "dso"],
                                capture_output=True, text=True, check=True).stdout
    shares = dict.fromkeys(("compiled kernels", "XLA runtime and libraries", "libm", "Python", "OS kernel",
                            "other"), 0.0)
    for line in report.splitlines():
        m = re.match(r"\s*([\d.]+)%\s+(\S.*)$", line)
        if not m:
            continue
        pct, dso = float(m.group(1)), m.group(2).strip()
        if pct >= 1.0:
            print(f"  perf: {pct:5.1f} %  {dso}", file=sys.stderr)
        if dso.startswith("[unknown]") or dso.startswith("[JIT]") or "anon" in dso:
            shares["compiled kernels"] += pct
        elif "jax" in dso or "xla" in dso:
            shares["XLA runtime and libraries"] += pct
        elif dso.startswith("libm"):
            shares["libm"] += pct
        elif "python" in dso:
            shares["Python"] += pct
        elif dso.startswith("[kernel"):
            shares["OS kernel"] += pct
        else:
            shares["other"] += pct
    return shares


def op_rates(members: int, repeats: int) -> dict:
    """ns per value of each kind of operation, a chain of 50 in one kernel over 8 × B values."""
    import jax
    import jax.numpy as jnp
    from jax import lax

    jax.config.update("jax_enable_x64", True)
    chains = {"tanh": lambda y, b, k: jnp.tanh(y + b * (1e-3 * k)),
              "divide": lambda y, b, k: b / (y + 1e-3 * k),
              "sine": lambda y, b, k: jnp.sin(y + b * (1e-3 * k)),
              "cosine": lambda y, b, k: jnp.cos(y + b * (1e-3 * k)),
              "sqrt": lambda y, b, k: jnp.sqrt(y + b * (1e-3 * k)),
              "other": lambda y, b, k: y * (1.0 - 1e-9 * k) + b}  # a multiply and an add: two operations
    per_link = {"tanh": 1, "divide": 1, "sine": 1, "cosine": 1, "sqrt": 1, "other": 2}
    out = {}
    for kind, fn in chains.items():
        def body(i, xs, fn=fn):
            a, b = xs
            y = a
            for k in range(50):
                y = fn(y, b, k)
            return y / (1.0 + 0.0 * y), a

        f = jax.jit(lambda a, b, n, body=body: lax.fori_loop(0, n, body, (a, b)))
        a, b = jnp.full((8, members), 0.3), jnp.full((8, members), 0.5)
        n = jnp.asarray(max(20, int(4e6 / members)))
        f(a, b, n)[0].block_until_ready()
        best = float("inf")
        for _ in range(max(repeats, 2)):
            t0 = time.perf_counter()
            f(a, b, n)[0].block_until_ready()
            best = min(best, time.perf_counter() - t0)
        out[kind] = best / (int(n) * 50 * per_link[kind] * 8 * members) * 1e9
    return out


def streaming_gbps(n: int) -> float:
    """NumPy's c = a + b over three arrays of n float64 on one thread: bytes moved per second
    (n = 2**24, 128 MiB each: from memory; n = 2**13, 192 KiB in all: from the core's L2 cache)."""
    import numpy as np

    a, b, c = np.ones(n), np.ones(n), np.empty(n)
    reps = max(5, 2**27 // n)
    np.add(a, b, out=c)
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(reps):
            np.add(a, b, out=c)
        best = min(best, time.perf_counter() - t0)
    return 24 * n * reps / best / 1e9


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--members", type=int, default=256)
    ap.add_argument("--horizon", type=float, default=0.05)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--perf", action="store_true",
                    help="also profile one batch run with perf record: where its CPU samples fall")
    ap.add_argument("--_dump", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.members < 2:
        ap.error(f"--members must be at least 2 (one member runs the unbatched program), got {args.members}")
    if not args.horizon > 0:
        ap.error(f"--horizon must be > 0 s, got {args.horizon}")
    if args.perf and shutil.which("perf") is None:
        ap.error("--perf needs Linux perf (the `perf` command) on PATH")
    if args._dump is None:  # XLA reads its flags once, at start: the batch runs in a child process
        with tempfile.TemporaryDirectory() as tmp:
            env = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_dump_to={tmp}".strip()}
            subprocess.run([sys.executable, __file__, *(argv if argv is not None else sys.argv[1:]), "--_dump", tmp],
                           env=env, check=True)
        return
    step = batch_step(args.members, args.horizon, args.repeats, args._dump, args.perf)
    rates = op_rates(args.members, args.repeats)
    memory, cache = streaming_gbps(2**24), streaming_gbps(2**13)
    us = step["us_per_member_step"]
    print(f"UR5 batch, B = {args.members}: {step['kernels']:,} kernels per step, "
          f"{us:.2f} µs per member-step measured ({1e6 / us:,.0f} trajectory-steps/s)")
    print(f"{'operation':10s} {'per member-step':>16s} {'ns per value':>13s} {'µs per member-step':>19s}")
    floor = 0.0
    for kind in KINDS:
        cost = step["ops"][kind] * rates[kind] * 1e-3
        floor += cost
        print(f"{kind:10s} {step['ops'][kind]:16,.0f} {rates[kind]:13.3f} {cost:19.2f}")
    print(f"{'floor':10s} {sum(step['ops'].values()):16,.0f} {'':13s} {floor:19.2f}"
          f"   -> at most {1e6 / floor:,.0f} trajectory-steps/s on one core")
    kb = step["bytes"] / 1e3
    print(f"kernels' traffic: {kb:.1f} kB per member-step, {kb / us:.1f} GB/s at the measured rate; "
          f"NumPy moves {memory:.1f} GB/s from memory, {cache:.1f} GB/s within L2, on one thread")
    for where, gbps in (("within L2", cache), ("from memory", memory)):
        total = floor + kb / gbps
        print(f"floor + traffic {where:11s}: {total:6.2f} µs per member-step -> "
              f"{1e6 / total:,.0f} trajectory-steps/s")
    print(f"measured / floor: {us / floor:.2f}; measured / (floor + traffic from memory): "
          f"{us / (floor + kb / memory):.2f}")
    if step["shares"]:
        print("perf, one batch run (share of CPU samples; µs per member-step at the measured rate):")
        for where, pct in step["shares"].items():
            print(f"  {where:28s} {pct:5.1f} %  {us * pct / 100:6.2f} µs")


if __name__ == "__main__":
    main()
