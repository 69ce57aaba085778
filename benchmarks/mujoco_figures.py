"""MuJoCo against the built-in plant, one figure per arm: λ(t) (and its difference) and the largest
|e_u1| coordinate over time for the same scenario, controller and zero-order hold on both plants.

Arms: the paper's two-link arm (10 kHz, damped contact), the planar 3-link arm on its drum
(1 kHz, friction off), the UR5 on the table (1 kHz, friction off), the UR5e of ur5e-polish with its
URDF as the truth (1 kHz). Writes benchmarks/results/mujoco_vs_builtin_<arm>.png and prints the
largest differences.

Usage: python benchmarks/mujoco_figures.py [t_final]   (default 4 s)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "results"

UR5E = {"plant.arm.file": "ur5e", "nominal.arm.file": "ur5e", "plant.arm.payload_mass": 0.0,
        "plant.disturbance.amplitude": [2.0, 2.0, 2.0, 0.05, 0.05, 0.05],
        "initial.q_guess": [3.14159, -1.0, 1.6, -2.17, -1.57, -1.57]}
SAMPLED = {"simulation.control": "sampled", "simulation.control_period": 1e-3}
CASES = {
    "two_link": ("paper", "hinf_nn", {"plant.contact.damping": 200.0, "simulation.control": "sampled",
                                      "simulation.control_period": 1e-4}, {}, {}),
    "planar3": ("planar3-drum", "hinf_nn", {**SAMPLED, "plant.friction.coulomb": 0.0, "plant.friction.viscous": 0.0},
                {"simulation.dt": 1e-3}, {}),
    "ur5": ("ur5-table", "hinf_nn", {**SAMPLED, "plant.friction.coulomb": 0.0, "plant.friction.viscous": 0.0},
            {"simulation.dt": 1e-3}, {}),
    "ur5e": ("ur5-polish", "hinf_nn", {**UR5E}, {}, {"simulation.dt": 1e-4}),
}


def main(t_final=4.0):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import hinfnn as H

    H.configure()
    OUT.mkdir(exist_ok=True)
    for arm, (name, kind, common, mj, builtin) in CASES.items():
        over = {**common, "controller.kind": kind, "simulation.t_final": t_final}
        runs = {}
        for engine, extra in (("mujoco", mj), ("hinfnn", builtin)):
            sc = H.load_scenario(name, {**over, "plant.engine": engine, **extra})
            runs[engine] = sc.simulate(raise_on_failure=False).arrays
        a, b = runs["mujoco"], runs["hinfnn"]
        n = min(len(a["t"]), len(b["t"]))
        ta, tb = a["t"], b["t"]
        lam_b = np.interp(ta, tb, b["lam"][:, 0])
        d_lam = a["lam"][:, 0] - lam_b
        e_a = np.max(np.abs(a["e_u1"]), axis=1)
        e_b = np.max(np.abs(b["e_u1"]), axis=1)
        fig, ax = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
        ax[0].plot(tb, b["lam"][:, 0], label="built-in", lw=2.5, alpha=0.6)
        ax[0].plot(ta, a["lam"][:, 0], label="MuJoCo", lw=1)
        ax[0].plot(ta, a["lam_d"][:, 0], "k--", lw=0.8, label="λd")
        ax[0].set_ylabel("λ")
        ax[0].legend(loc="lower right")
        ax[1].plot(ta, d_lam)
        ax[1].set_ylabel("λ MuJoCo − built-in")
        ax[2].semilogy(tb, e_b, label="built-in", lw=2.5, alpha=0.6)
        ax[2].semilogy(ta, e_a, label="MuJoCo", lw=1)
        ax[2].set_ylabel("max |e_u1|")
        ax[2].set_xlabel("t (s)")
        ax[2].legend(loc="lower right")
        fig.suptitle(f"{name} ({arm}), {kind}: MuJoCo against the built-in plant")
        fig.tight_layout()
        path = OUT / f"mujoco_vs_builtin_{arm}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        print(f"{arm}: max |Δλ| = {np.max(np.abs(d_lam)):.4g} (λ up to {np.max(np.abs(b['lam'])):.4g}), "
              f"RMS e_u1 {np.sqrt(np.mean(a['e_u1'] ** 2)):.5g} vs {np.sqrt(np.mean(b['e_u1'][:n] ** 2)):.5g} -> {path}",
              flush=True)


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 4.0)
