"""Tool friction on MuJoCo against the built-in plant (issue 56, item 1): the same scenario, the
same controller, both engines, printed as a Markdown table.

For each friction case: the scenario at 1 kHz with zero-order hold on both plants (MuJoCo: RK4,
10 steps of 0.1 ms per control period; the built-in plant: RK4 at dt = 0.1 ms), the friction
force |F_t| along the path (the recorded ``friction_force``: the tangential part of the force the
tool exerts on the surface), its largest and RMS difference between the engines after the first
50 ms, and the friction's work W = ∫ F_t · v dt on each engine (v the tool point's velocity, J_p q̇
of the true arm at the recorded q, q̇; trapezoids at the 1-ms samples), with λ's RMS error.

Cases: viscous only (the shipped c_v = 2 N·s/m, and 20 N·s/m), the shipped Coulomb + viscous
(μ = 0.15, v_s = 5 mm/s; MuJoCo's regularised Coulomb with its default slope
plant.friction_damping = 1000 N·s/m, and with the built-in law's slope at 20 N, μ λ_d / v_s =
600 N·s/m).

Usage: python benchmarks/mujoco_friction.py [SCENARIO] [T_FINAL] [CONTROLLER]
(default ur5-table 1.0 hinf). The machine is shared: the wall times printed vary with its load.
"""

from __future__ import annotations

import sys
import time

import numpy as np

CASES = [
    ("viscous 2 N·s/m", {"plant.friction.coulomb": 0.0, "plant.friction.viscous": 2.0}, {}),
    ("viscous 20 N·s/m", {"plant.friction.coulomb": 0.0, "plant.friction.viscous": 20.0}, {}),
    ("μ 0.15 + viscous 2 (MuJoCo c_t 1000)", {"plant.friction.coulomb": 0.15, "plant.friction.viscous": 2.0,
                                              "plant.friction.v_smooth": 0.005}, {}),
    ("μ 0.15 + viscous 2 (MuJoCo c_t 600)", {"plant.friction.coulomb": 0.15, "plant.friction.viscous": 2.0,
                                             "plant.friction.v_smooth": 0.005}, {"plant.friction_damping": 600.0}),
]


def work(sc, traj):
    """(W, |F_t| per sample): the friction's work on the surface, J, from the recorded q, q̇ and
    F_contact, with the true arm's tool point Jacobian and the true surface's normal."""
    import jax
    import jax.numpy as jnp

    plant = sc.with_overrides(["plant.engine=hinfnn"]).build_plant() if sc.plant.engine == "mujoco" \
        else sc.build_plant()
    arm, surface = plant.arm, plant.surface
    a = traj.arrays

    @jax.jit
    def power(q, qd, F):
        v = arm.point_jacobian(q) @ qd
        n = surface.normal(arm.point(q))
        F_t = F - (F @ n) * n
        return F_t @ v

    P = np.asarray(jax.vmap(power)(jnp.asarray(a["q"]), jnp.asarray(a["qd"]), jnp.asarray(a["F_contact"])))
    return float(np.trapezoid(P, a["t"])), np.asarray(a["friction_force"])


def main(name="ur5-table", t_final=1.0, kind="hinf"):
    import hinfnn as H

    H.configure()
    fields = ("lam", "e_lam", "e_u1", "q", "qd", "F_contact", "friction_force", "normal_force", "penetration")
    print(f"\n## Tool friction, {name}, controller {kind}, {t_final:g} s at 1 kHz (zero-order hold)\n")
    print("| case | max \\|ΔF_t\\| (N) | RMS ΔF_t (N) | RMS \\|F_t\\| built-in / MuJoCo (N) | W built-in / MuJoCo (J) | "
          "RMS e_λ built-in / MuJoCo (N) | status | run s built-in / MuJoCo |")
    print("|---|---|---|---|---|---|---|---|")
    for label, over, mj_only in CASES:
        common = {"controller.kind": kind, "simulation.control": "sampled", "simulation.control_period": 1e-3,
                  "simulation.t_final": t_final, "simulation.output_interval": 1e-3, **over}
        res = {}
        for engine in ("hinfnn", "mujoco"):
            o = dict(common)
            if engine == "mujoco":
                o.update({"plant.engine": "mujoco", "simulation.dt": 1e-3, "plant.timestep": 1e-4, **mj_only})
            else:
                o.update({"plant.engine": "hinfnn", "simulation.dt": 1e-4})
            sc = H.load_scenario(name, o)
            t0 = time.perf_counter()
            traj = sc.simulate(fields=fields)
            wall = time.perf_counter() - t0
            W, Ft = work(sc, traj)
            e_lam = float(np.sqrt(np.mean(traj.arrays["e_lam"] ** 2)))
            res[engine] = dict(W=W, Ft=Ft, t=traj.arrays["t"], status=int(traj.status), wall=wall, e_lam=e_lam)
        a, b = res["hinfnn"], res["mujoco"]
        late = a["t"] > 0.05
        d = np.abs(a["Ft"][late] - b["Ft"][late])
        rms = lambda x: float(np.sqrt(np.mean(x**2)))  # noqa: E731
        print(f"| {label} | {d.max():.4g} | {rms(d):.3g} | {rms(a['Ft'][late]):.4g} / {rms(b['Ft'][late]):.4g} | "
              f"{a['W']:.4g} / {b['W']:.4g} | {a['e_lam']:.4g} / {b['e_lam']:.4g} | {a['status']}, {b['status']} | "
              f"{a['wall']:.0f} / {b['wall']:.0f} |", flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    main(args[0] if args else "ur5-table", float(args[1]) if len(args) > 1 else 1.0,
         args[2] if len(args) > 2 else "hinf")
