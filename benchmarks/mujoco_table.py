"""MuJoCo as the truth for any arm: the measurements of issue 32, printed as Markdown tables.

Sections (run all, or name some on the command line):

* ``compare``     ur5-table and ur5-sphere, H∞-only and adaptive, damped contact (the scenarios'
                  200 N·s/m), tool friction off in both, controller at 1 kHz with zero-order hold:
                  MuJoCo (RK4, 10 steps of 0.1 ms per control period) against the built-in plant
                  (RK4, dt = 0.1 ms): RMS e_u1, RMS e_λ (whole run, last 2 s), status, wall time of
                  the simulation (compilation apart);
* ``calibration`` the contact on a plane, a sphere and a cylinder (UR5, gravity off, P = 50 N
                  along the tool point's most mobile direction, released from 1.5 P/k): static
                  penetration, frequency and damping ratio against the requested k, c;
* ``polish``      ur5-polish, 10 s on MuJoCo: as shipped (bare contact, the force-rate term's κ by
                  the design rule), with a 200 N·s/m pad and no term, bare without the term, and at
                  500 Hz with κ = 0.02 s;
* ``menagerie``   the ur5e-polish scenario (nominal from ur5e.urdf, masses 20 % low): MuJoCo
                  Menagerie's UR5e MJCF as the truth, beside the same arm's URDF on MuJoCo and on
                  the built-in plant;
* ``walltime``    whole ``hinfnn run ur5-table`` processes (10 s at 1 kHz, --no-figures) on MuJoCo
                  and on the built-in plant, alternating, twice each.

* ``paper``       the paper's arm at 10 kHz: µs per control update through the FFI call and through
                  jax.pure_callback, and its 10-s runs beside the built-in plant.

Usage: python benchmarks/mujoco_table.py [compare] [calibration] [polish] [menagerie] [walltime] [paper]
The machine is shared: wall times vary by ±20 % or more with the other sessions' load; the load
average is printed beside them.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def load() -> str:
    return "load %.1f" % os.getloadavg()[0]


def metrics_of(traj) -> dict:
    from hinfnn.metrics import compute_metrics

    m = compute_metrics(traj)
    a = traj.arrays
    t = a["t"]
    late = t > 0.2
    return dict(status="ok" if int(traj.status) == 0 else f"stopped {float(traj.t_fail):.3g} s",
                rms_e_u1=m["rms_e_u1"], rms_e_lam=m["rms_e_lam"], rms_e_lam_2s=m["rms_e_lam_last2s"],
                out=m["fraction_out_of_contact"], out_after=float(np.mean(a["penetration"][late] < -1e-9)))


def timed_simulate(sc, controller=None):
    """(trajectory, compile s, run s): a 2-ms run first (it compiles), then the full horizon."""
    import hinfnn as H

    r = sc.run()
    ctrl = controller or r.controller
    opts = sc.sim_options()
    t0 = time.perf_counter()
    H.simulate(r.plant, ctrl, r.reference, q0=r.q0, **{**opts, "t_final": 2 * opts["dt"] if opts["dt"] >= 1e-3 else 2e-3},
               raise_on_failure=False)
    t1 = time.perf_counter()
    traj = H.simulate(r.plant, ctrl, r.reference, q0=r.q0, **opts, raise_on_failure=False)
    t2 = time.perf_counter()
    return traj, t1 - t0, t2 - t1


# ---------------------------------------------------------------------------------------------
def compare(t_final=10.0):
    import hinfnn as H

    print("\n## MuJoCo against the built-in plant (1 kHz, zero-order hold, damped contact, friction off)\n")
    print("| scenario | controller | plant | status | RMS e_u1 (m) | RMS e_λ (N) | RMS e_λ last 2 s (N) | "
          "out of contact | compile s | run s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for name in ("ur5-table", "ur5-sphere"):
        for kind in ("hinf", "hinf_nn"):
            common = {"controller.kind": kind, "plant.friction.coulomb": 0.0, "plant.friction.viscous": 0.0,
                      "simulation.control": "sampled", "simulation.control_period": 1e-3,
                      "simulation.t_final": t_final}
            res = {}
            for plant in ("mujoco", "hinfnn"):
                over = dict(common)
                if plant == "mujoco":
                    over.update({"plant.engine": "mujoco", "simulation.dt": 1e-3, "plant.timestep": 1e-4})
                sc = H.load_scenario(name, over)
                traj, tc, tr = timed_simulate(sc)
                m = metrics_of(traj)
                res[plant] = m
                print(f"| {name} | {kind} | {plant} | {m['status']} | {m['rms_e_u1']:.5g} | {m['rms_e_lam']:.4g} | "
                      f"{m['rms_e_lam_2s']:.4g} | {100 * m['out']:.2f} % | {tc:.0f} | {tr:.1f} ({load()}) |", flush=True)
            a, b = res["mujoco"], res["hinfnn"]
            rows.append((name, kind, a["rms_e_u1"] / b["rms_e_u1"], a["rms_e_lam"] / b["rms_e_lam"],
                         a["rms_e_lam_2s"] / b["rms_e_lam_2s"], a["status"], b["status"]))
    print("\n| scenario | controller | RMS e_u1 MuJoCo/built-in | RMS e_λ MuJoCo/built-in | last 2 s | statuses |")
    print("|---|---|---|---|---|---|")
    for name, kind, r1, r2, r3, s1, s2 in rows:
        print(f"| {name} | {kind} | {r1:.4f} | {r2:.4f} | {r3:.4f} | {s1}, {s2} |")


# ---------------------------------------------------------------------------------------------
def calibration():
    import jax.numpy as jnp
    import mujoco

    import hinfnn as H
    from hinfnn.model.geometry import Cylinder, Plane, Sphere
    from hinfnn.model.urdf import asset_path, load_urdf
    from hinfnn.plant import PenaltyContact
    from hinfnn.plant.mujoco import build_scene, chain_xml

    sys.path.insert(0, str(ROOT / "tests"))
    from mujoco_helpers import fit_oscillation

    H.configure()
    q0 = np.array([0.0, -1.0, 1.6, -2.17, -1.57, -1.57])
    chain = load_urdf(asset_path("ur5", "ur5.urdf"), "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1)).with_gravity(
        jnp.zeros(3))
    Jp = np.asarray(chain.frame_jacobian(jnp.asarray(q0)))[:3]
    A = Jp @ np.linalg.solve(np.asarray(chain.M(jnp.asarray(q0))), Jp.T)
    w, V = np.linalg.eigh(A)
    n_in, m_eff = V[:, -1] * np.sign(V[2, -1]), 1.0 / w[-1]
    p0 = np.asarray(chain.fk(jnp.asarray(q0))[0])
    P = 50.0
    print(f"\n## Contact calibration (UR5, gravity off, m_eff = {m_eff:.3f} kg along the normal, RK4 0.1 ms)\n")
    print("| surface | k (N/m) | c (N·s/m) | p_eq / (P/k) | ω_n / √(k/m_eff) | ζ measured | ζ requested |")
    print("|---|---|---|---|---|---|---|")
    for kind in ("plane", "sphere", "cylinder"):
        for k, c in ((1e5, 0.0), (1e5, 200.0), (1e6, 0.0), (1e6, 200.0)):
            d0 = 1.5 * P / k
            if kind == "plane":
                surf = Plane.build(p0 - d0 * n_in, -n_in)
            elif kind == "sphere":
                surf = Sphere.build(p0 + (0.3 - d0) * n_in, 0.3)
            else:
                axis = np.cross(n_in, [1.0, 0.0, 0.0])
                surf = Cylinder.build(p0 + (0.3 - d0) * n_in, axis / np.linalg.norm(axis), 0.3)
            scene = build_scene(surf, PenaltyContact(k, c), arm_xml=chain_xml(chain), timestep=1e-4)
            m, d = scene.model, mujoco.MjData(scene.model)
            d.qpos[:] = q0
            mujoco.mj_forward(m, d)
            jacp = np.zeros((3, 6))
            mujoco.mj_jacSite(m, d, jacp, None, scene.site)
            n_steps = int(6 * 2 * np.pi / np.sqrt(k / m_eff) / 1e-4)
            pen = [float(surf.signed_distance(jnp.asarray(d.site_xpos[scene.site])))]
            for _ in range(n_steps):
                d.qfrc_applied[:] = jacp.T @ (P * n_in)
                mujoco.mj_step(m, d)
                mujoco.mj_kinematics(m, d)
                pen.append(float(surf.signed_distance(jnp.asarray(d.site_xpos[scene.site]))))
            p_eq, wn, zeta, _ = fit_oscillation(1e-4 * np.arange(n_steps + 1), np.array(pen))
            print(f"| {kind} | {k:.0e} | {c:g} | {p_eq / (P / k):.5f} | {wn / np.sqrt(k / m_eff):.5f} | {zeta:.5f} | "
                  f"{c / (2 * np.sqrt(k * m_eff)):.5f} |", flush=True)


# ---------------------------------------------------------------------------------------------
def polish(t_final=10.0):
    """ur5-polish as shipped (bare contact, the force-rate term's κ by the design rule) and its
    variants, each designed by the scenario layer (a κ outside the sampled window is refused)."""
    import hinfnn as H

    print("\n## ur5-polish on MuJoCo (adaptive law, 10 s)\n")
    print("| variant | status | out of contact after 0.2 s | RMS e_λ last 2 s (N) | RMS e_u1 | compile s | run s |")
    print("|---|---|---|---|---|---|---|")
    hz500 = {"simulation.dt": 2e-3, "simulation.control_period": 2e-3, "simulation.output_interval": 2e-3}
    cases = [("as shipped: bare contact, κ by the rule, 1 kHz", {}),
             ("200 N·s/m pad, no force-rate term, 1 kHz", {"plant.contact.damping": 200.0,
                                                          "controller.force_rate.kappa": 0.0}),
             ("bare contact, no force-rate term, 1 kHz", {"controller.force_rate.kappa": 0.0}),
             ("bare contact, κ = 0.02 s, 500 Hz", {**hz500, "controller.force_rate.kappa": 0.02})]
    for label, over in cases:
        try:
            sc = H.load_scenario("ur5-polish", {**over, "simulation.t_final": t_final})
        except H.DesignError as err:
            print(f"| {label} | refused by the design: {err} | | | | | |", flush=True)
            continue
        traj, tc, tr = timed_simulate(sc)
        m = metrics_of(traj)
        print(f"| {label} | {m['status']} | {100 * m['out_after']:.2f} % | {m['rms_e_lam_2s']:.4g} | {m['rms_e_u1']:.4g} | "
              f"{tc:.0f} | {tr:.1f} ({load()}) |", flush=True)


# ---------------------------------------------------------------------------------------------
def menagerie(t_final=10.0):
    import hinfnn as H

    print("\n## MuJoCo Menagerie's UR5e as the truth (ur5e-polish: nominal ur5e.urdf, masses 20 % low)\n")
    print("| truth | status | out of contact after 0.2 s | RMS e_u1 (m) | RMS e_λ (N) | RMS e_λ last 2 s (N) | run s |")
    print("|---|---|---|---|---|---|---|")
    # the same scenario without a user's MJCF: ur5-polish with the UR5e's URDF as truth and nominal
    urdf = {"plant.arm.file": "ur5e", "nominal.arm.file": "ur5e", "plant.arm.payload_mass": 0.0,
            "plant.disturbance.amplitude": [2.0, 2.0, 2.0, 0.05, 0.05, 0.05],
            "initial.q_guess": [3.14159, -1.0, 1.6, -2.17, -1.57, -1.57]}
    cases = [("Menagerie ur5e.xml on MuJoCo (armature 0.1 kg m²)", "ur5e-polish", {}),
             ("ur5e.urdf on MuJoCo (generated MJCF, no armature)", "ur5-polish", urdf),
             ("ur5e.urdf on the built-in plant (RK4, dt 0.1 ms)", "ur5-polish",
              {**urdf, "plant.engine": "hinfnn", "simulation.dt": 1e-4})]
    for label, name, over in cases:
        sc = H.load_scenario(name, {**over, "simulation.t_final": t_final})
        traj, _, tr = timed_simulate(sc)
        m = metrics_of(traj)
        print(f"| {label} | {m['status']} | {100 * m['out_after']:.2f} % | {m['rms_e_u1']:.5g} | {m['rms_e_lam']:.4g} | "
              f"{m['rms_e_lam_2s']:.4g} | {tr:.1f} ({load()}) |", flush=True)


# ---------------------------------------------------------------------------------------------
def walltime(rounds=2):
    hinfnn = Path(sys.executable).parent / "hinfnn"
    common = ["--set", "controller.kind=hinf_nn", "--set", "plant.friction.coulomb=0", "--set",
              "plant.friction.viscous=0", "--set", "simulation.control=sampled", "--set",
              "simulation.control_period=0.001", "--no-figures", "--quiet", "--force"]
    variants = {"MuJoCo (RK4, 10 x 0.1 ms per period)": ["--set", "plant.engine=mujoco", "--set", "simulation.dt=0.001",
                                                        "--set", "plant.timestep=0.0001"],
                "built-in (RK4, dt 0.1 ms)": []}
    print("\n## Whole process: `hinfnn run ur5-table` adaptive, 10 s at 1 kHz, --no-figures (warm cache)\n")
    print("| plant | round | wall s | CPU s | load |")
    print("|---|---|---|---|---|")
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            for label, extra in variants.items():
                out = Path(tmp) / "out"
                t0 = time.perf_counter()
                p = subprocess.Popen([str(hinfnn), "run", "ur5-table", "--out", str(out), *common, *extra], env=env)
                _, status, usage = os.wait4(p.pid, 0)
                wall = time.perf_counter() - t0
                cpu = usage.ru_utime + usage.ru_stime
                print(f"| {label} | {r + 1} | {wall:.1f} | {cpu:.1f} | {load()} |" + ("" if status == 0 else " FAILED"),
                      flush=True)


def paper(rounds=3, t_short=2.0):
    """The paper's arm at 10 kHz on MuJoCo: µs per control update with the FFI call ("host") and
    with jax.pure_callback, interleaved; then the 10-s H∞-only and adaptive runs beside the built-in
    plant (damped contact 200 N·s/m)."""
    import hinfnn as H

    print("\n## The paper's arm on MuJoCo, 10 kHz control (one MuJoCo RK4 step per update)\n")
    print("| call | round | µs per update | load |")
    print("|---|---|---|---|")
    runs = {}
    for cb in ("host", "pure_callback"):
        sc = H.load_scenario("paper", {"plant.engine": "mujoco", "plant.callback": cb, "plant.contact.damping": 200.0,
                                       "controller.kind": "hinf", "simulation.t_final": t_short})
        r = sc.run()
        H.simulate(r.plant, r.controller, r.reference, q0=r.q0, **{**sc.sim_options(), "t_final": 0.01})
        runs[cb] = (sc, r)
    for i in range(rounds):
        for cb, (sc, r) in runs.items():
            t0 = time.perf_counter()
            H.simulate(r.plant, r.controller, r.reference, q0=r.q0, **sc.sim_options())
            us = (time.perf_counter() - t0) / (t_short / 1e-4) * 1e6
            print(f"| {cb} | {i + 1} | {us:.1f} | {load()} |", flush=True)
    print("\n| controller | plant | RMS e_u1 (m) | RMS e_λ | RMS e_λ last 2 s | J(T) | run s |")
    print("|---|---|---|---|---|---|---|")
    for kind in ("hinf", "hinf_nn"):
        for engine in ("hinfnn", "mujoco"):
            sc = H.load_scenario("paper", {"plant.engine": engine, "plant.contact.damping": 200.0, "controller.kind": kind})
            traj, _, tr = timed_simulate(sc)
            m = metrics_of(traj)
            from hinfnn.metrics import compute_metrics

            J = compute_metrics(traj).get("J_T", float("nan"))
            print(f"| {kind} | {engine} | {m['rms_e_u1']:.5g} | {m['rms_e_lam']:.4g} | {m['rms_e_lam_2s']:.4g} | {J:.4g} | "
                  f"{tr:.1f} ({load()}) |", flush=True)


SECTIONS = {"paper": paper, "compare": compare, "calibration": calibration, "polish": polish, "menagerie": menagerie,
            "walltime": walltime}

if __name__ == "__main__":
    import hinfnn as H

    H.configure()
    names = sys.argv[1:] or list(SECTIONS)
    for name in names:
        SECTIONS[name]()
