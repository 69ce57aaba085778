"""Simulation speed: steps per second of the JAX closed loop against the plain NumPy oracle.

Prints a table (no assertions; speed is measured here, never in tests/):

* NumPy oracle (tests/numpy_oracle.py): the same closed loop with a Python loop over RK4 steps;
  the baseline, run in the same process.
* JAX, one run: ``hinfnn.simulate`` after compilation (compile time reported separately).
* JAX, batch of B runs under ``vmap``: run-steps per second (B · steps / wall time).

Usage: python benchmarks/bench_sim.py [--horizon 2.0] [--batches 8 32]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import hinfnn as H  # noqa: E402
import numpy_oracle  # noqa: E402

DT = 1e-4
KINDS = ("fl", "hinf", "hinf_nn")


def setup(kind, damping=0.0, scale=1.0):
    sc = H.load_scenario("paper", {"controller.kind": kind, "plant.contact.damping": damping,
                                    "plant.arm.m1": 1.2 * scale})
    return sc.build_plant(), sc.build_controller(kind), sc.build_reference(), sc.initial_q()


def bench_numpy(kind, horizon=0.05):
    t0 = time.perf_counter()
    numpy_oracle.simulate(kind, {}, t_final=horizon, dt=DT)
    return round(horizon / DT) / (time.perf_counter() - t0)


def bench_single(kind, horizon):
    plant, ctrl, ref, q0 = setup(kind)
    t0 = time.perf_counter()
    H.simulate(plant, ctrl, ref, t_final=0.01, dt=DT, q0=q0)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    H.simulate(plant, ctrl, ref, t_final=horizon, dt=DT, q0=q0)
    return round(horizon / DT) / (time.perf_counter() - t0), compile_s


def bench_batch(kind, horizon, B):
    members = [setup(kind, damping=200.0, scale=1.0 + 0.01 * i) for i in range(B)]
    plants = [m[0] for m in members]
    ctrls = [m[1] for m in members]
    ref, q0 = members[0][2], [m[3] for m in members]
    H.simulate_batch(plants, ctrls, ref, t_final=0.01, dt=DT, q0=q0)
    t0 = time.perf_counter()
    H.simulate_batch(plants, ctrls, ref, t_final=horizon, dt=DT, q0=q0)
    return B * round(horizon / DT) / (time.perf_counter() - t0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--horizon", type=float, default=2.0, help="simulated seconds per timed JAX run")
    ap.add_argument("--batches", type=int, nargs="*", default=[8, 32])
    args = ap.parse_args()
    import jax

    print(f"hinfnn {H.__version__}, jax {jax.__version__}, dt = {DT:g} s, horizon {args.horizon:g} s, "
          f"device {jax.devices()[0].platform}")
    header = f"{'controller':<12}{'mode':<22}{'steps/s':>14}{'µs/step':>10}{'× NumPy':>10}{'compile s':>11}"
    print(header)
    print("-" * len(header))
    for kind in KINDS:
        base = bench_numpy(kind)
        print(f"{kind:<12}{'NumPy oracle (loop)':<22}{base:>14,.0f}{1e6 / base:>10.1f}{1.0:>10.1f}{'':>11}")
        rate, comp = bench_single(kind, args.horizon)
        print(f"{kind:<12}{'JAX, 1 run':<22}{rate:>14,.0f}{1e6 / rate:>10.2f}{rate / base:>10.1f}{comp:>11.1f}")
        for B in args.batches:
            rate_b = bench_batch(kind, args.horizon, B)
            print(f"{kind:<12}{f'JAX, vmap batch {B}':<22}{rate_b:>14,.0f}{1e6 / rate_b:>10.2f}"
                  f"{rate_b / base:>10.1f}{'':>11}")
    print("\nsteps/s for batches counts run-steps (B runs × steps) per wall-clock second.")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
