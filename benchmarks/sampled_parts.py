"""Where a UR5 step goes, continuous and at 1 kHz sampled control: the same run with parts taken away.

    python benchmarks/sampled_parts.py [--horizon 1.0] [--repeats 3]

``ur5-table-stable`` (the bare 1e5 N/m table, adaptive law with the force-rate term), dt = 0.1 ms,
timed in one process without the compilation cache, each variant compiled first (then the best of
``--repeats`` runs of ``--horizon`` s; µs per RK4 step and the 10-s run's simulation time at that
rate):

1. ``plant alone``: RK4 of the true plant, the torque held, no controller, record or checks
   (``benchmarks/run.py``'s floor row);
2. ``hold law``: ``hinfnn.simulate`` with a controller that computes only the nominal arm's gravity
   torque and a joint PD (what the simulator itself costs: records, checks, the sampled update);
3. ``law, no bookkeeping``: the adaptive law without the theorems' bookkeeping (the J and supply
   integrands at RK4's stages, V, f_p, f_f): ``simulation.bookkeeping = false``;
4. ``law``: as shipped.

Under sampled control the law's torque is held between samples, but the bookkeeping's integrands
(the controller's kinematics, networks and residuals at each stage's state) are evaluated at the four
stages of every step, and the errors and guards the run checks at every step at its first. No
assertions: speed is measured here, never in tests/.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

#: the paper's ideal sensor and motors (hinfnn.workflows.stiff.IDEAL_INSTRUMENTS): the -stable scenarios declare a robot's
IDEAL_INSTRUMENTS = {"plant.sensor.force_noise": 0.0, "plant.sensor.delay": 0, "plant.actuator.torque_limit": "none",
                     "controller.force_filter.order": 0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--horizon", type=float, default=1.0, help="simulated seconds per timed run")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    import hinfnn as H

    H.configure(cache=False)  # no program from disk: the variants below share their programs' keys
    import jax
    import jax.numpy as jnp

    from hinfnn._pytree import pytree_dataclass, static_field
    from hinfnn.protocols import Controller, ControllerOutput
    from run import DT, T_RUN, _plant_alone

    @pytree_dataclass
    class HoldLaw(Controller):
        """τ = Ĝ(q) − K_v q̇ − K_p (q − q0): the nominal arm's gravity pass and a joint PD."""

        arm: object
        q0: jax.Array
        kind: str = static_field(default="hold")

        @property
        def n(self):
            return int(self.arm.n)

        @property
        def m(self):
            return 1

        @property
        def k(self):
            return 1

        def init(self):
            return jnp.zeros(1)

        def evaluate(self, t, state, meas, ref):
            tau = self.arm.G(meas.q) - 5.0 * meas.qd - 50.0 * (meas.q - self.q0)
            return ControllerOutput(tau=tau, dstate=jnp.zeros(1), e_u1=meas.q[:1] - self.q0[:1],
                                    e_lam=meas.qd[:1], signals={})

    S = importlib.import_module("hinfnn.sim.simulate")

    rows = []
    for label, period in (("continuous", None), ("sampled 1 kHz", 1e-3)):
        over = {**IDEAL_INSTRUMENTS, "simulation.control": "continuous", "controller.kind": "hinf_nn"}
        if period:
            over.update({"simulation.control": "sampled", "simulation.control_period": period})
        sc = H.load_scenario("ur5-table-stable", over)
        plant, ref = sc.build_plant(), sc.build_reference()
        q0 = sc.initial_q(plant)
        law = sc.build_controller("hinf_nn")
        kw = dict(dt=DT, save_every=10, fields="metrics", control_period=period, raise_on_failure=False)
        variants = (("hold law", HoldLaw(law.arm, jnp.asarray(q0)), True),
                    ("law, no bookkeeping", law, False), ("law", law, True))
        for name, ctrl, book in variants:
            S.release_programs()  # a variant's program traced anew, never another's from memory
            t0 = time.perf_counter()
            H.simulate(plant, ctrl, ref, q0=q0, t_final=0.01, bookkeeping=book, **kw)
            first = time.perf_counter() - t0
            times = []
            for _ in range(max(1, args.repeats)):
                t0 = time.perf_counter()
                tr = H.simulate(plant, ctrl, ref, q0=q0, t_final=args.horizon, bookkeeping=book, **kw)
                times.append(time.perf_counter() - t0)
            us = 1e6 * min(times) / round(args.horizon / DT)
            rows.append((label, name, first, us, int(tr.status)))
    floor = _plant_alone(H.load_scenario("ur5-table-stable", {**IDEAL_INSTRUMENTS, "controller.kind": "hinf_nn"}),
                         None, args)
    rows.insert(0, ("either", "plant alone", floor["first_run_s"], floor["us_per_step"], floor["status"]))

    hdr = f"{'control':<15}{'variant':<22}{'1st run s':>10}{'µs/step':>9}{'10-s run s':>11}{'status':>7}"
    print(hdr + "\n" + "-" * len(hdr))
    for label, name, first, us, status in rows:
        print(f"{label:<15}{name:<22}{first:>10.1f}{us:>9.1f}{us * T_RUN / DT * 1e-6:>11.2f}{status:>7}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
