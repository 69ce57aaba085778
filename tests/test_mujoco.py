"""MuJoCo as the true plant (hinfnn.plant.mujoco, optional extra; docs/mujoco.md).

* the generated MJCF is the built-in arm: M(q), the bias at q̇ = 0 (= G) and at q̇ ≠ 0
  (= C q̇ + G), the tip position, at 20 random q;
* the contact is the requested spring-damper: steady penetration P/k, free oscillation
  frequency √(k/m_eff) and damping ratio c/(2√(k m_eff)), for k = 1e5, 1e6 N/m, c = 0, 200 N·s/m;
* the paper's H∞-only controller gives the same λ(t), u1(t) on MuJoCo as on the built-in plant;
* the plant is a pure function of its state (replays, vmap, the two callback paths agree);
* errors: missing extra, timestep not dividing the control period, bad integrator.
"""

from __future__ import annotations

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mujoco  # noqa: E402  (installed by `make test`: the test extra; a missing one must fail, not skip)

import hinfnn as H  # noqa: E402
from hinfnn.errors import ConfigError  # noqa: E402
from hinfnn.scenario.core import scenario_names  # noqa: E402
from hinfnn.plant import mujoco as hm  # noqa: E402
from hinfnn.plant.mujoco import MujocoPlant, mjcf_two_link  # noqa: E402
from mujoco_helpers import fit_oscillation  # noqa: E402

#: one xdist worker runs this module: its tests share compiled programs and expensive fixtures
pytestmark = pytest.mark.xdist_group("mujoco")

DELTA_TRUE = 91.0 / 360.0 * np.pi
TRUE_ARM = H.TwoLinkArm(1.2, 1.1, 1.02724, 0.98041)
TRUE_SURFACE = H.InclinedLine(DELTA_TRUE, 0.8)
N_IN = np.array([np.sin(DELTA_TRUE), -np.cos(DELTA_TRUE)])  # inward unit normal
H_CTRL = 1e-4  # 10 kHz control


def _rel(a, b):
    return np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(np.asarray(b))


@pytest.fixture(scope="module")
def q_start():
    """The paper's start pose: tip at x1 = 1.6902 on the true surface, elbow up."""
    return np.asarray(H.RigidBodyPlant(TRUE_ARM, TRUE_SURFACE, H.PenaltyContact(), H.SquareWave.none())
                      .initial_q(1.6902))


# --------------------------------------------------------------------------------------------
# MJCF
# --------------------------------------------------------------------------------------------
def test_mjcf_is_the_builtin_arm():
    xml = mjcf_two_link(TRUE_ARM, TRUE_SURFACE, H.PenaltyContact(1e5, 200.0), timestep=1e-4,
                        integrator="RK4")
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tip")
    rng = np.random.default_rng(7)
    worst = np.zeros(4)
    for _ in range(20):
        q = rng.uniform(-np.pi, np.pi, 2)
        qd = rng.uniform(-3.0, 3.0, 2)
        d.qpos[:] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        M = np.zeros((2, 2))
        mujoco.mj_fullM(m, d, M)
        bias_static = d.qfrc_bias.copy()
        x = d.site_xpos[site][[0, 2]]
        d.qvel[:] = qd
        mujoco.mj_forward(m, d)
        worst = np.maximum(worst, [
            _rel(M, TRUE_ARM.M(q)),
            _rel(bias_static, TRUE_ARM.G(q)),
            _rel(x, TRUE_ARM.h(q)),
            _rel(d.qfrc_bias, TRUE_ARM.C(q, qd) @ qd + TRUE_ARM.G(q)),
        ])
    assert np.all(worst < 1e-6), worst
    # the rotational inertia given to the point masses is what makes M differ at all
    assert worst[0] < 1e-9


def test_mjcf_contact_parameters():
    """solref is the direct (negative) form with k̃ = (1 − d) W k, c̃ = (1 − d) W c, W the
    contact row's efc_diagA; solimp is flat at d = IMPEDANCE."""
    k, c = 1e5, 200.0
    xml = mjcf_two_link(TRUE_ARM, TRUE_SURFACE, H.PenaltyContact(k, c), timestep=1e-4, integrator="RK4")
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    pen_q = np.asarray(TRUE_ARM.inverse_kinematics_closed(jnp.array([1.7, 0.9 * np.tan(DELTA_TRUE)])
                                                          + 1e-3 * N_IN))
    d.qpos[:] = pen_q
    mujoco.mj_forward(m, d)
    assert d.ncon == 1 and d.nefc == 1
    W = d.efc_diagA[0]
    tip_body = m.geom_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "tip")]
    assert W == pytest.approx(m.body_invweight0[tip_body, 0], rel=1e-12)
    dd = hm.IMPEDANCE
    np.testing.assert_allclose(m.pair_solref[0], [-(1 - dd) * W * k, -(1 - dd) * W * c], rtol=1e-12)
    np.testing.assert_allclose(m.pair_solimp[0][:2], [dd, dd])
    # the geometric distance MuJoCo sees is minus the tip's penetration into the TRUE surface
    assert -d.contact.dist[0] == pytest.approx(1e-3, rel=1e-9)
    assert d.efc_KBIP[0, 2] == pytest.approx(dd)


# --------------------------------------------------------------------------------------------
# Contact calibration
# --------------------------------------------------------------------------------------------
CALIBRATION = [(1e5, 0.0), (1e5, 200.0), (1e6, 0.0), (1e6, 200.0)]


@pytest.mark.parametrize("k,c", CALIBRATION)
def test_contact_is_the_requested_spring_damper(k, c, q_start):
    """Gravity off, a constant joint torque τ = Jᵀ(P n) pressing with P = 50 N along the inward
    normal n; released at rest from 1.5 P/k (the contact stays closed). The penetration must
    settle about P/k and ring at √(k/m_eff) with damping ratio c/(2√(k m_eff))."""
    P = 50.0
    arm = H.TwoLinkArm(1.2, 1.1, 1.02724, 0.98041, g=0.0)
    plant = MujocoPlant.from_models(arm, TRUE_SURFACE, H.PenaltyContact(k, c), H.SquareWave.none(2),
                                    control_period=H_CTRL)
    tau = jnp.asarray(np.asarray(arm.J(q_start)).T @ (P * N_IN))
    x0 = np.asarray(arm.h(q_start)) + 1.5 * P / k * N_IN
    s0 = plant.initial_state(arm.inverse_kinematics_closed(jnp.asarray(x0)))
    assert float(s0.penetration) == pytest.approx(1.5 * P / k, rel=1e-6)
    n_steps = 1000 if k == 1e5 else 400  # about 5 and 6 periods

    @jax.jit
    def run(s):
        def body(s, i):
            s1, _ = plant.step(i * H_CTRL, s, tau, H_CTRL)
            return s1, (s1.penetration, s1.normal_force, s1.force)
        return jax.lax.scan(body, s, jnp.arange(n_steps))

    s_end, (p, fn, F) = run(s0)
    p = np.concatenate([[float(s0.penetration)], np.asarray(p)])
    t = H_CTRL * np.arange(n_steps + 1)
    assert np.all(p > 0.2 * P / k)  # never left the surface
    # the sensed force is MuJoCo's normal force along the inward normal
    np.testing.assert_allclose(np.asarray(F), np.asarray(fn)[:, None] * N_IN, atol=1e-9)

    p_eq, wn, zeta, worst_residual = fit_oscillation(t, p)
    q_end = np.asarray(s_end.q)
    J, M = np.asarray(arm.J(q_end)), np.asarray(arm.M(q_end))
    m_eff = 1.0 / (N_IN @ J @ np.linalg.solve(M, J.T) @ N_IN)
    wn_req = np.sqrt(k / m_eff)
    zeta_req = c / (2.0 * np.sqrt(k * m_eff))
    print(f"k={k:g} c={c:g}: p_eq/(P/k) = {p_eq / (P / k):.5f}, ω_n/√(k/m_eff) = {wn / wn_req:.5f}, "
          f"ζ = {zeta:.5f} (requested {zeta_req:.5f}), m_eff = {m_eff:.4f} kg")
    assert worst_residual < 1e-3 * P / k  # it IS a linear damped oscillation
    assert p_eq == pytest.approx(P / k, rel=0.02)
    assert wn == pytest.approx(wn_req, rel=0.05)
    if c > 0:
        assert zeta == pytest.approx(zeta_req, rel=0.05)
        # and, once settled, the static balance: penetration P/k, normal force P
        assert p[-1] == pytest.approx(P / k, rel=0.02)
        assert float(fn[-1]) == pytest.approx(P, rel=0.02)
    else:
        assert abs(zeta) < 0.005  # undamped within the 5 % of a ζ = 0.1 resolution


def test_contact_calibration_with_substeps_and_other_integrators(q_start):
    """The same static load and frequency with 4 MuJoCo steps per control period (RK4) and
    with semi-implicit Euler (one step): the conversion does not depend on the integrator."""
    P, k, c = 50.0, 1e5, 200.0
    arm = H.TwoLinkArm(1.2, 1.1, 1.02724, 0.98041, g=0.0)
    tau = jnp.asarray(np.asarray(arm.J(q_start)).T @ (P * N_IN))
    for kw in (dict(timestep=H_CTRL / 4, integrator="RK4"), dict(integrator="Euler")):
        plant = MujocoPlant.from_models(arm, TRUE_SURFACE, H.PenaltyContact(k, c), H.SquareWave.none(2),
                                        control_period=H_CTRL, **kw)
        s0 = plant.initial_state(arm.inverse_kinematics_closed(
            jnp.asarray(np.asarray(arm.h(q_start)) + 1.5 * P / k * N_IN)))

        @jax.jit
        def run(s):
            return jax.lax.scan(lambda s, i: (plant.step(i * H_CTRL, s, tau, H_CTRL)[0],) * 2, s,
                                jnp.arange(1000))

        _, states = run(s0)
        p = np.concatenate([[float(s0.penetration)], np.asarray(states.penetration)])
        p_eq, wn, zeta, _ = fit_oscillation(H_CTRL * np.arange(1001), p)
        J, M = np.asarray(arm.J(q_start)), np.asarray(arm.M(q_start))
        m_eff = 1.0 / (N_IN @ J @ np.linalg.solve(M, J.T) @ N_IN)
        assert p_eq == pytest.approx(P / k, rel=0.02), kw
        assert wn == pytest.approx(np.sqrt(k / m_eff), rel=0.05), kw
        assert zeta == pytest.approx(c / (2 * np.sqrt(k * m_eff)), rel=0.05), kw


# --------------------------------------------------------------------------------------------
# Closed loop against the built-in plant
# --------------------------------------------------------------------------------------------
def test_hinf_closed_loop_matches_builtin_plant(q_start):
    """0.2 s of the paper's H∞-only controller at 10 kHz, damped contact (200 N·s/m), on the
    built-in plant (RK4, dt = control period) and on MuJoCo (RK4, timestep = control period).

    Both integrate M q̈ + C q̇ + G + Jᵀ F = τ + ω with the same held τ and disturbance; MuJoCo's
    contact differs from the penalty law only by its soft-constraint residue d·a0/W (d = 1e-4,
    a0 the unconstrained normal acceleration: ≈ 0.02 N at the first, violent sample, < 0.005 N
    later) and an added normal mass of 3e-4 kg (2e-4 of m_eff). Tolerance: |Δλ| ≤ 0.05 (1e-3 of
    λ's range), |Δu1| ≤ 1e-6 m; measured 0.014 and 4e-8 m."""
    ctrl = H.HinfController.design(H.TwoLinkArm(1.5, 1.0, 1.0, 1.0), H.InclinedLine(delta=np.pi / 4, d_G=0.8))
    ref = H.CosineReference.paper()
    contact = H.PenaltyContact(1e5, 200.0)
    dist = H.SquareWave.paper()
    builtin = H.RigidBodyPlant(TRUE_ARM, TRUE_SURFACE, contact, dist)
    np.testing.assert_allclose(np.asarray(builtin.initial_q(1.6902)), q_start)
    T = 0.2
    traj = H.simulate(builtin, ctrl, ref, q0=q_start, t_final=T, dt=H_CTRL, control_period=H_CTRL, save_every=1,
                      fields=("lam", "u1", "penetration", "disturbance"))  # fewer fields: faster compile

    plant = MujocoPlant.from_models(TRUE_ARM, TRUE_SURFACE, contact, dist, control_period=H_CTRL)
    n_steps = int(round(T / H_CTRL))
    # the simulator's own discrete-plant path (sampled data at every step, MuJoCo stepping the plant)
    mj = H.simulate(plant, ctrl, ref, q0=q_start, t_final=T, dt=H_CTRL, save_every=1,
                    fields=("lam", "u1", "penetration", "disturbance"))
    lam, u1, pen, w = mj.lam, mj.u1, mj.penetration, mj.disturbance
    A = traj.arrays
    assert A["lam"].shape[0] == n_steps + 1
    d_lam = np.abs(np.asarray(lam)[:, 0] - A["lam"][:, 0])
    d_u1 = np.abs(np.asarray(u1)[:, 0] - A["u1"][:, 0])
    print(f"max |Δλ| = {d_lam.max():.3g} (λ up to {np.abs(A['lam']).max():.3g}), "
          f"max |Δu1| = {d_u1.max():.3g} m, max |Δp| = {np.abs(np.asarray(pen) - A['penetration']).max():.3g} m")
    assert d_lam.max() < 0.05
    assert d_u1.max() < 1e-6
    np.testing.assert_allclose(np.asarray(pen), A["penetration"], atol=1e-6)
    np.testing.assert_array_equal(np.asarray(w), A["disturbance"])
    assert np.abs(A["lam"]).max() > 40.0  # a real pressing run, not a trivial one


# --------------------------------------------------------------------------------------------
# Purity, batching, both callback paths
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def paper_mujoco_plant():
    return MujocoPlant.from_models(TRUE_ARM, TRUE_SURFACE, H.PenaltyContact(1e5, 200.0), H.SquareWave.paper(),
                                   control_period=H_CTRL)


def _same_step(a, b):
    """Two (state, qdd) results: MuJoCo's numbers (q, q̇, warm start, q̈) bit-identical; the
    sensing computed from them in JAX (F, penetration, x_true ...) to rounding (eager and compiled
    XLA may order the floating-point operations differently)."""
    (sa, qa), (sb, qb) = a, b
    for name in ("q", "qd", "qacc_warmstart"):
        np.testing.assert_array_equal(np.asarray(getattr(sa, name)), np.asarray(getattr(sb, name)), err_msg=name)
    if qa is not None:
        np.testing.assert_array_equal(np.asarray(qa), np.asarray(qb))
    for name in ("force", "normal_force", "penetration", "x_true"):
        np.testing.assert_allclose(np.asarray(getattr(sa, name)), np.asarray(getattr(sb, name)), rtol=1e-12,
                                   atol=1e-15, err_msg=name)


def test_step_is_a_pure_function_of_the_state(paper_mujoco_plant, q_start):
    """Stepping from a state is the same as MuJoCo's own loop on one MjData (the state carries
    everything, the warm start included), whichever path and batching is used."""
    plant = paper_mujoco_plant
    tau = jnp.array([-150.0, -70.0])
    s = plant.initial_state(q_start)
    states = []
    for k in range(20):
        s, qdd = plant.step(k * H_CTRL, s, tau, H_CTRL)
        states.append(s)
    # MuJoCo's own loop
    m = plant.model
    d = mujoco.MjData(m)
    d.qpos[:] = q_start
    for k in range(20):
        d.qfrc_applied[:] = np.asarray(tau) + np.asarray(plant.disturbance((k + 0.5) * H_CTRL))
        mujoco.mj_step(m, d)
    np.testing.assert_array_equal(np.asarray(s.q), d.qpos)
    np.testing.assert_array_equal(np.asarray(s.qd), d.qvel)
    mujoco.mj_forward(m, d)  # qdd is the acceleration at the new state, the step's force still applied
    np.testing.assert_array_equal(np.asarray(qdd), d.qacc)
    assert float(s.normal_force) > 0.0
    # jit, the pure_callback path, vmap over a batch of states: the same numbers
    s10 = states[9]
    ref_next = plant.step(10 * H_CTRL, s10, tau, H_CTRL)
    jitted = jax.jit(lambda st: plant.step(10 * H_CTRL, st, tau, H_CTRL))(s10)
    pure = plant.replace(callback="pure_callback")
    via_pure = jax.jit(lambda st: pure.step(10 * H_CTRL, st, tau, H_CTRL))(s10)
    batch = jax.tree.map(lambda a, b: jnp.stack([a, b]), s10, states[4])
    batched = jax.jit(jax.vmap(lambda st: plant.step(10 * H_CTRL, st, tau, H_CTRL)))(batch)
    for other in (jitted, via_pure, jax.tree.map(lambda a: a[0], batched)):
        _same_step(ref_next, other)
    second = plant.step(10 * H_CTRL, states[4], tau, H_CTRL)
    _same_step(second, jax.tree.map(lambda a: a[1], batched))
    # the disturbance is data: a vmapped batch of plants that differ only in it
    dist = plant.disturbance
    flipped = H.SquareWave(-dist.amplitude, dist.period, dist.phase)
    plants = jax.tree.map(lambda a, b: jnp.stack([a, b]), plant, plant.replace(disturbance=flipped))
    by_plant = jax.jit(jax.vmap(lambda pl: pl.step(10 * H_CTRL, s10, tau, H_CTRL)[0].qd))(plants)
    np.testing.assert_array_equal(np.asarray(by_plant[0]), np.asarray(ref_next[0].qd))
    other = plant.replace(disturbance=flipped).step(10 * H_CTRL, s10, tau, H_CTRL)
    np.testing.assert_array_equal(np.asarray(by_plant[1]), np.asarray(other[0].qd))
    assert not np.array_equal(np.asarray(by_plant[0]), np.asarray(by_plant[1]))
    # initial_state: eager, jitted and vmapped agree
    q_pair = jnp.stack([jnp.asarray(q_start), jnp.asarray(q_start) + 0.01])
    eager = [plant.initial_state(q) for q in q_pair]
    pairs = [(eager[1], jax.jit(plant.initial_state)(q_pair[1]))]
    vmapped = jax.vmap(plant.initial_state)(q_pair)
    pairs += [(eager[i], jax.tree.map(lambda a: a[i], vmapped)) for i in range(2)]
    for want, got in pairs:
        _same_step((want, None), (got, None))


def test_sense_and_bad_inputs(paper_mujoco_plant, q_start):
    plant = paper_mujoco_plant
    assert plant.n == 2 and plant.discrete is True
    s0 = plant.initial_state(q_start)
    meas, cache = plant.sense(0.0, s0)
    w = plant.step_input(0.0, H_CTRL)
    rec = plant.record(s0, w, cache)
    diag = {**rec.signals, "penetration": rec.penetration}
    np.testing.assert_array_equal(np.asarray(meas.force), np.asarray(s0.force))
    np.testing.assert_array_equal(np.asarray(meas.q), q_start)
    np.testing.assert_array_equal(np.asarray(meas.qd), np.zeros(2))
    # at zero penetration MuJoCo's soft contact still carries d·a0/W of the load (gravity here):
    # 0.003 N, docs/mujoco.md
    assert abs(float(diag["penetration"])) < 1e-12 and 0.0 <= float(diag["normal_force"]) < 0.01
    np.testing.assert_allclose(np.asarray(diag["x_true"]), np.asarray(TRUE_ARM.h(q_start)), atol=1e-14)
    np.testing.assert_array_equal(np.asarray(diag["disturbance"]), [3.0, 3.0])
    assert set(diag) == {"q", "qd", "normal_force", "penetration", "x_true", "disturbance"}
    assert not bool(rec.fault) and int(rec.fault_index) == -1  # the two-link arm has no joint limits
    # above the surface: negative penetration = minus the height, no force
    up = plant.initial_state(np.asarray(q_start) + np.array([0.05, 0.0]))
    x = np.asarray(TRUE_ARM.h(np.asarray(q_start) + np.array([0.05, 0.0])))
    assert float(up.penetration) == pytest.approx((x[0] - 0.8) * np.sin(DELTA_TRUE) - x[1] * np.cos(DELTA_TRUE),
                                                  abs=1e-12)
    assert float(up.penetration) < 0 and float(up.normal_force) == 0.0
    # a NaN torque poisons the state instead of reaching MuJoCo
    bad, _ = plant.step(0.0, s0, jnp.array([np.nan, 0.0]), H_CTRL)
    assert np.all(np.isnan(np.asarray(bad.q)))
    ok, _ = plant.step(0.0, s0, jnp.zeros(2), H_CTRL)  # and the plant still works afterwards
    assert np.all(np.isfinite(np.asarray(ok.q)))
    with pytest.raises(ConfigError) as err:
        plant.step(0.0, s0, jnp.zeros(2), 1.5e-4)
    assert err.value.key == "plant.timestep"


# --------------------------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------------------------
def test_configuration_errors():
    args = (TRUE_ARM, TRUE_SURFACE, H.PenaltyContact(1e5, 0.0), H.SquareWave.paper())
    with pytest.raises(ConfigError) as err:
        MujocoPlant.from_models(*args, control_period=1e-3, timestep=3e-4)
    assert err.value.key == "plant.timestep" and "divide" in str(err.value)
    with pytest.raises(ConfigError) as err:
        MujocoPlant.from_models(*args, control_period=1e-3, integrator="Verlet")
    assert err.value.key == "plant.integrator"
    with pytest.raises(ConfigError) as err:
        MujocoPlant.from_models(TRUE_ARM, TRUE_SURFACE, H.PenaltyContact(-1.0, 0.0), H.SquareWave.paper(),
                                control_period=1e-3)
    assert err.value.key == "plant.contact.stiffness"
    plant = MujocoPlant.from_models(*args, control_period=1e-3, timestep=2.5e-4)
    assert plant.timestep == 2.5e-4


def test_missing_extra_is_a_config_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # `import mujoco` now raises ImportError
    with pytest.raises(ConfigError) as err:
        MujocoPlant.from_models(TRUE_ARM, TRUE_SURFACE, H.PenaltyContact(), H.SquareWave.paper(),
                                control_period=1e-4)
    assert err.value.key == "plant.engine"
    assert "plant.engine = \"mujoco\" needs the optional extra: pip install 'hinfnn[mujoco]'" in str(err.value)
    with pytest.raises(ConfigError):
        mjcf_two_link(TRUE_ARM, TRUE_SURFACE, H.PenaltyContact(), timestep=1e-4, integrator="RK4")


def test_hinfnn_imports_without_mujoco():
    code = ("import sys; sys.modules['mujoco'] = None\n"
            "import hinfnn, hinfnn.plant.mujoco\n"
            "assert 'mujoco' not in [m for m in sys.modules if sys.modules[m] is not None]\n"
            "print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**__import__("os").environ, "HINFNN_CACHE_DIR": "off", "JAX_PLATFORMS": "cpu"})
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_the_controller_is_designed_for_mujocos_step():
    """MuJoCo holds the torque over each of its steps: the controller it runs is the one designed
    for sampled control at that period (the force-rate term's κ and filter), the same as its
    built-in twin under a dt-period zero-order hold."""
    from hinfnn.controllers import design_summary

    over = {"controller.kind": "hinf"}
    on_mujoco = H.load_scenario("paper-stable", {**over, "plant.engine": "mujoco"})
    twin = H.load_scenario("paper-stable", {**over, "simulation.control": "sampled",
                                             "simulation.control_period": on_mujoco.simulation.dt})
    assert on_mujoco.control_period == twin.control_period == on_mujoco.simulation.dt
    a, b = design_summary(on_mujoco.build_controller()), design_summary(twin.build_controller())
    assert a == b and a["force_rate"]["tau_f"] == on_mujoco.simulation.dt
    assert H.load_scenario("paper-stable", over).control_period is None


# --------------------------------------------------------------------------------------------
# Batches of MuJoCo plants, and a URDF arm's closed loop
# --------------------------------------------------------------------------------------------
def test_a_batch_of_mujoco_plants_is_its_members():
    """simulate_batch over MuJoCo plants with other masses and contact stiffnesses (other MuJoCo
    models, one family: one host call per step for the batch, mujoco.batch stepping the rows) gives
    each member's single run: MuJoCo's numbers bit for bit, the controller's to rounding."""
    from hinfnn.sim import simulate_batch

    scs = [H.load_scenario("paper", {"plant.engine": "mujoco", "controller.kind": "hinf", "plant.contact.damping": 200.0,
                                     "simulation.t_final": 0.01, "plant.contact.stiffness": k, "plant.arm.m2": m2})
           for k, m2 in ((1e5, 1.1), (3e5, 1.3))]
    runs = [sc.run() for sc in scs]
    assert runs[0].plant._family is runs[1].plant._family and int(runs[0].plant.member) != int(runs[1].plant.member)
    batch = simulate_batch([r.plant for r in runs], runs[0].controller, runs[0].reference, q0=[r.q0 for r in runs],
                           t_final=0.01, dt=H_CTRL, fields=("q", "qd", "lam", "penetration"))
    for i, r in enumerate(runs):
        one = H.simulate(r.plant, r.controller, r.reference, q0=r.q0, t_final=0.01, dt=H_CTRL,
                         fields=("q", "qd", "lam", "penetration"))
        a, b = batch.member(i).arrays, one.arrays
        np.testing.assert_allclose(a["q"], b["q"], rtol=0, atol=1e-13)
        np.testing.assert_allclose(a["lam"], b["lam"], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(a["penetration"], b["penetration"], rtol=0, atol=1e-15)
    assert not np.allclose(batch.member(0).arrays["lam"], batch.member(1).arrays["lam"])


def test_ur5_closed_loop_on_mujoco_matches_the_builtin_plant():
    """ur5-table at 1 kHz (zero-order hold), damped contact, viscous tool friction 20 N·s/m and no
    Coulomb friction, 50 ms, with the FL-like law (the cheapest UR5 program to compile; the plants
    are what is compared): the built-in plant (RK4, dt = 0.1 ms) and MuJoCo (its RK4, 10 steps of
    0.1 ms per control period, one call per period, the viscous force applied at the tool point at
    each step) give the same λ, e_u1, penetration and tool force at every control instant:
    |Δλ| < 0.01 N, |Δe_u1| < 1e-7 (m and rad), as without friction, and the friction force |F_t|
    within 1e-4 N (c_v times a 5e-6 m/s difference of the tool's sliding speed; |F_t| is up to
    0.5 N here, so a missing or misplaced viscous force fails; measured 2.3e-6 N, and 8.5e-5 N with
    the force held at each MuJoCo step's start velocity instead of its midpoint's). (H∞-only over
    1 s: 1.9e-5 N, benchmarks/mujoco_friction.py; benchmarks/mujoco_table.py compares 10-s runs of
    both laws of the issue.)"""
    over = {"controller.kind": "fl", "plant.friction.coulomb": 0.0, "plant.friction.viscous": 20.0,
            "simulation.control": "sampled", "simulation.control_period": 1e-3, "simulation.t_final": 0.05,
            "simulation.output_interval": 1e-3}
    fields = ("lam", "e_u1", "penetration", "F_contact", "friction_force")
    builtin = H.load_scenario("ur5-table", over).simulate(fields=fields)
    mj = H.load_scenario("ur5-table", {**over, "plant.engine": "mujoco", "simulation.dt": 1e-3,
                                       "plant.timestep": 1e-4}).simulate(fields=fields)
    a, b = mj.arrays, builtin.arrays
    assert a["lam"].shape == b["lam"].shape == (51, 1)
    d_lam, d_u1 = np.abs(a["lam"] - b["lam"]).max(), np.abs(a["e_u1"] - b["e_u1"]).max()
    d_ft = np.abs(a["friction_force"] - b["friction_force"]).max()
    print(f"max |Δλ| = {d_lam:.3g} N (λ up to {np.abs(b['lam']).max():.3g}), max |Δe_u1| = {d_u1:.3g}, "
          f"max |ΔF_contact| = {np.abs(a['F_contact'] - b['F_contact']).max():.3g} N, max |ΔF_t| = {d_ft:.3g} N "
          f"(|F_t| up to {b['friction_force'].max():.3g} N)")
    assert np.abs(b["lam"]).max() > 1.0 and np.all(b["penetration"][5:] > 0)  # pressing, in contact
    assert b["friction_force"].max() > 0.25  # sliding: the friction is there to compare
    assert d_lam < 0.01 and d_u1 < 1e-7 and d_ft < 1e-4
    np.testing.assert_allclose(a["penetration"], b["penetration"], atol=1e-7)
    np.testing.assert_allclose(a["F_contact"], b["F_contact"], atol=0.01)


# --------------------------------------------------------------------------------------------
# Every shipped scenario on both engines
# --------------------------------------------------------------------------------------------
#: (scenario, engine) -> (key, words) of the typed error that refuses it: none now (MuJoCo applies
#: the viscous tool friction; ur5-polish's v_smooth suits the built-in plant's 1-ms step)
REFUSED: dict = {}
#: variants whose MuJoCo plant is their base's but for the contact's numbers (the MuJoCo model's
#: solref, not the compiled program): on MuJoCo they are loaded, checked and their plant built and
#: sensed at the start pose; the base's run covers the engine, the variant's run on the built-in
#: engine its controller (each run here compiles a program: this keeps the test's time)
SAME_MUJOCO_PROGRAM = {"paper-stable": "paper", "planar3-drum-stable": "planar3-drum",
                       "ur5-sphere-stable": "ur5-sphere", "ur5-table-stable": "ur5-table"}


def _short_run(name, overrides=()):
    """The scenario's first controller for ten control periods (ten steps of continuous control)."""
    sc = H.load_scenario(name, list(overrides))
    t_final = 10 * (sc.control_period or sc.simulation.dt)
    sc = sc.with_overrides([f"simulation.t_final={t_final!r}", f"controller.kind={sc.kinds[0]}"])
    traj = sc.simulate(fields="metrics")
    assert int(traj.status) == 0 and float(traj.t[-1]) == pytest.approx(t_final)
    return sc


def _scenario_group(name):
    """The xdist group of one shipped scenario's tests here: its two engines share the scenario's
    design in one process, and the scenarios spread over both workers (one group for all of them
    was the suite's longest stretch on one worker)."""
    return pytest.mark.xdist_group(f"scenario-{name}")


@pytest.mark.parametrize("engine", ["hinfnn", "mujoco"])
@pytest.mark.parametrize("name", [pytest.param(n, marks=_scenario_group(n)) for n in scenario_names()])
def test_every_shipped_scenario_runs_on_both_engines_or_says_why_not(name, engine):
    """Each shipped scenario runs briefly on the built-in plant and on MuJoCo (status ok), or the
    engine is refused with the typed error naming why (:data:`REFUSED`: none is now); the
    variants of :data:`SAME_MUJOCO_PROGRAM` are built and sensed on MuJoCo without a run. The
    scenarios with viscous tool friction run on MuJoCo with it (applied at the tool point); the
    redundant panda-table with its arm angle sensed from MuJoCo's joint angles; ur5-polish and
    ur5e-polish on the built-in plant at their 1-ms step (the smoothed Coulomb friction's slope at
    v_s = 5 mm/s is within RK4's reach there)."""
    overrides = [f"plant.engine={engine}"]
    if engine == "mujoco" and name in SAME_MUJOCO_PROGRAM:
        sc = H.load_scenario(name, overrides)
        base = H.load_scenario(SAME_MUJOCO_PROGRAM[name], overrides, check=False).to_dict()["plant"]
        mine = sc.to_dict()["plant"]
        ignored = {"contact": None, "sensor": None, "actuator": None}  # the -stable variants declare a sensor
        assert {**mine, **ignored} == {**base, **ignored}  # only the contact's numbers and the instruments differ
        plant = sc.build_plant()
        state = plant.initial_state(sc.initial_q(plant))
        assert np.isfinite(np.asarray(state.q)).all() and float(state.normal_force) >= 0.0
        return
    if (name, engine) not in REFUSED:
        sc = _short_run(name, overrides)
        assert sc.plant.engine == engine
        return
    key, words = REFUSED[(name, engine)]
    with pytest.raises(ConfigError) as err:
        H.load_scenario(name, overrides)
    assert err.value.key == key and words in str(err.value), err.value


@_scenario_group("panda-table")  # panda-table's program on MuJoCo, with the panda-table tests above
def test_a_users_seven_joint_mjcf_runs_with_no_joint_locked(tmp_path):
    """panda-table's Panda as a user's MJCF file (the generated one, written out): seven joints,
    none locked, the arm angle a task coordinate; the MuJoCo sensing forms ψ from MuJoCo's joint
    angles, the same as the generated plant's, and a short run ends ok."""
    from hinfnn.model.augmented import AugmentedArm

    base = ["plant.engine=mujoco"]
    generated = H.load_scenario("panda-table", base).build_plant()
    path = tmp_path / "my-panda.mjcf"
    path.write_text(hm.chain_xml(generated.arm.chain), encoding="utf-8")
    sc = _short_run("panda-table", base + [f"plant.mjcf.file={path}", "plant.mjcf.tool_site=tool"])
    plant = sc.build_plant()
    assert plant.n == 7 and plant.model.nq == 7 and isinstance(plant.arm, AugmentedArm)
    q0 = np.asarray(sc.initial_q())
    user, gen = plant.initial_state(q0), generated.initial_state(q0)
    assert np.asarray(user.x_true).shape == (7,)
    np.testing.assert_allclose(np.asarray(user.x_true), np.asarray(gen.x_true), rtol=0, atol=1e-12)
    np.testing.assert_allclose(float(user.task_margin), float(gen.task_margin), rtol=1e-12)
