"""Stiff contact on every arm (docs/beyond-the-paper.md, section 7): the force-rate design, the
linearised contact modes, the sampled-loop window and ``hinfnn design`` for any arm and surface.

Oracles: today's two-link numbers (the general formulas must reduce to them bit for bit, and the
general route must agree with the closed form); Pinocchio's inverse inertia for the UR5's normal
mass; a brute-force eigenvalue scan of the simulator's linearised sampled loop for the Jury
window; the closed-form modal damping of the k > 1 derivation; short runs of the simulator.
"""

from __future__ import annotations

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

import hinfnn as H
from hinfnn import analysis as A
from hinfnn import cli
from hinfnn.controllers import force_rate as fr
from hinfnn.scenario import scenario_names

#: one xdist worker runs this module: its tests share compiled programs (the UR5's path, its
#: linearised loops) and fixtures
pytestmark = pytest.mark.xdist_group("stiff_arms")


#: the paper's ideal sensor and motors (the -stable scenarios declare a robot's): the rule's design
IDEAL = {"plant.sensor.force_noise": 0.0, "plant.sensor.delay": 0, "plant.actuator.torque_limit": "none",
         "controller.force_filter.order": 0}


def _design(name, **over):
    sc = H.load_scenario(name, over)
    return sc.build_controller().summary()["force_rate"]


# --------------------------------------------------------------------------------------------
# The κ rule: the two-link numbers, the general route, k > 1
# --------------------------------------------------------------------------------------------
#: The force-rate design of paper-stable before the rule was made general (full precision).
TWO_LINK = {
    ("hinf", "cont"): dict(kappa=0.02803039919428774, m_n_max=2.1222477523769934, m_n_min=1.3338318387831591),
    ("fl", "cont"): dict(kappa=0.020395111165813502),
    ("hinf", "1kHz"): dict(kappa=0.019936593955052297, window=(0.00047874318410111587, 0.02492074244381537)),
    ("fl", "1kHz"): dict(kappa=0.020395111165813502, window=(0.0, 0.025843930072360927)),
}


@pytest.mark.parametrize("kind, mode", list(TWO_LINK))
def test_two_link_rule_gives_the_numbers_it_gave_before(kind, mode):
    over = {"controller.kind": kind}
    if mode == "1kHz":
        over.update({"simulation.control": "sampled", "controller.force_rate.stiffness_max": 1e5})
    d = _design("paper-stable", **over)
    for key, want in TWO_LINK[(kind, mode)].items():
        assert (tuple(d[key]) if key == "window" else d[key]) == want, key


def test_general_route_reduces_to_the_two_link_closed_form():
    """On the Sec. VI arm the general path solver (damped Newton along the path) finds the closed
    form's poses, the general normal-mass matrix (k × k, unit normals) is m_n, and the rule's κ from
    them is the same to rounding."""
    sc = H.load_scenario("paper-stable", {"controller.kind": "hinf"})
    ctrl = sc.build_controller()
    arm, surface = ctrl.arm, ctrl.surface
    q0 = np.asarray(sc.initial_q())
    closed = fr.path_poses(arm, surface, sc.reference.u1_range(), q0)
    points = jnp.asarray([[u] for u, _ in closed])
    general = np.asarray(fr._newton_path(arm, surface, points, jnp.asarray(q0)))
    np.testing.assert_allclose(general, np.stack([np.asarray(q) for _, q in closed]), atol=1e-12)
    m_n = np.array([float(fr.normal_mass(arm, surface, jnp.asarray(q))) for q in general])
    m_N = np.array([float(fr.normal_mass_matrix(arm, surface, jnp.asarray(q))[0, 0]) for q in general])
    np.testing.assert_allclose(m_N, m_n, rtol=1e-13)
    d = ctrl.summary()["force_rate"]
    kappa = 2 * 0.7 * math.sqrt(d["K_prime"] * m_N.max() / 1e4)
    assert kappa == pytest.approx(d["kappa"], rel=1e-12)


def test_matrix_rule_for_several_constraints():
    """k = 2 (a 3-link planar arm whose tip height and tool angle are both constrained): M_N along
    the unit normals from the arm's own M and J (NumPy), and the modal claim behind the rule: with
    one stiffness k on every normal, M_N p̈ + κk ṗ + K'k p = 0 has the damping ratios
    (κ/2)√(k/(μ_i K')), μ_i the eigenvalues of M_N, so κ = 2ζ√(K' μ_max/k_min) puts ζ on the
    slowest mode."""
    from hinfnn.model.arm import PlanarPointMassArm
    from hinfnn.model.surface import ImplicitSurface
    from hinfnn.model.taskmap import PlanarTaskMap

    arm = PlanarPointMassArm(masses=jnp.array([2.0, 1.5, 1.0]), lengths=jnp.array([0.8, 0.7, 0.5]), g=9.81, n=3,
                             task=PlanarTaskMap("xy", with_angle=True))
    surface = ImplicitSurface(params=jnp.array([0.4, -1.2]), theta_fn=_height_and_angle, m=1, k=2)
    gains = H.controllers.Gains.paper().normalized(1, 2)
    q_start = arm.inverse_kinematics(jnp.array([1.0, 0.4, -1.2]), jnp.array([0.3, -0.6, -0.9]))
    d = fr.design_force_rate(arm, surface, gains, robust=True, u1_path=(0.9, 1.1), q_start=q_start)
    assert d.constraints == 2 and d.path_points == 41
    mus = []
    for _, q in fr.path_poses(arm, surface, (0.9, 1.1), q_start):
        J, M = np.asarray(arm.J(q)), np.asarray(arm.M(q))
        Ahat = np.asarray(surface.A_hat(arm.h(q)))
        N = Ahat / np.linalg.norm(Ahat, axis=1, keepdims=True)
        mus.append(np.linalg.eigvalsh(np.linalg.inv(N @ J @ np.linalg.solve(M, J.T) @ N.T)))
    mus = np.array(mus)
    assert d.m_n_max == pytest.approx(mus.max(), rel=1e-10) and d.m_n_min == pytest.approx(mus.min(), rel=1e-10)
    assert d.kappa == pytest.approx(2 * 0.7 * math.sqrt(d.K_prime * d.m_n_max / 1e4), rel=1e-14)
    # the modal damping of the second-order loop, at the heaviest pose and the softest contact
    MN = np.linalg.inv(N @ J @ np.linalg.solve(M, J.T) @ N.T)
    k = 1e4
    system = np.block([[np.zeros((2, 2)), np.eye(2)],
                       [-np.linalg.solve(MN, d.K_prime * k * np.eye(2)), -np.linalg.solve(MN, d.kappa * k * np.eye(2))]])
    s = np.sort_complex(np.linalg.eigvals(system))
    mu = np.linalg.eigvalsh(MN)
    modal = np.sort_complex(np.concatenate([np.roots([m, d.kappa * k, d.K_prime * k]) for m in mu]))
    np.testing.assert_allclose(s, modal, rtol=1e-9)
    zeta = 0.5 * d.kappa * np.sqrt(k / (mu * d.K_prime))  # each mode's damping ratio
    assert zeta.min() == pytest.approx(0.7 * math.sqrt(mu.max() / d.m_n_max)) and zeta.min() <= 0.7 + 1e-12


def _height_and_angle(x, p):
    return jnp.stack([p[0] - x[1], p[1] - x[2]])


# --------------------------------------------------------------------------------------------
# The normal mass of a URDF arm against Pinocchio
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["ur5-table", "ur5-sphere"])
def test_normal_mass_of_the_ur5_against_pinocchio(name):
    """m_n = ÂÂᵀ/(ÂĴM̂⁻¹ĴᵀÂᵀ) in the fitted coordinates equals 1/(nᵀ J_p M⁻¹ J_pᵀ n) with Pinocchio's
    M⁻¹ (computeMinverse) and tool-point Jacobian, n the surface normal at the tool point, at 12
    seeded poses around the start pose."""
    pin = pytest.importorskip("pinocchio")
    from hinfnn.model.urdf import asset_path

    sc = H.load_scenario(name, check=False)
    arm, surface = sc.build().nominal_arm, sc.build().constraint
    geometry = sc.nominal.surface.build()
    model = pin.buildModelFromUrdf(asset_path("ur5", "ur5.urdf"))
    parent = model.frames[model.getFrameId("tool0")]
    frame = model.addFrame(pin.Frame("tcp", parent.parentJoint, model.getFrameId("tool0"),
                                     parent.placement * pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.1])),
                                     pin.FrameType.OP_FRAME))
    data = model.createData()
    rng = np.random.default_rng(30)
    q0 = np.array(sc.initial.q_guess)
    for _ in range(12):
        q = q0 + rng.uniform(-0.3, 0.3, 6)
        Minv = pin.computeMinverse(model, data, q)
        Minv = np.triu(Minv) + np.triu(Minv, 1).T
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        Jp = pin.getFrameJacobian(model, data, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
        p = data.oMf[frame].translation
        n = np.asarray(geometry.normal(jnp.asarray(p)))
        want = 1.0 / (n @ Jp @ Minv @ Jp.T @ n)
        got = float(fr.normal_mass(arm, surface, jnp.asarray(q)))
        assert got == pytest.approx(want, rel=1e-10)


# --------------------------------------------------------------------------------------------
# The sampled loop: the Jury window against the simulator's linearised sampled loop
# --------------------------------------------------------------------------------------------
def _edge(radius, inside, outside, steps=8):
    """The κ between ``inside`` (stable) and ``outside`` (unstable) where the radius crosses 1."""
    for _ in range(steps):
        mid = math.sqrt(inside * outside)
        inside, outside = (mid, outside) if radius(mid) < 1.0 else (inside, mid)
    return math.sqrt(inside * outside)


def test_jury_window_against_the_linearised_sampled_loop_on_a_ur5_pose():
    """At the circle's centre on the UR5 table (H∞-only law, 1 kHz hold, undamped 1e6 N/m contact),
    the κ window where the spectral radius of the simulator's one-period map is below 1 is the Jury
    window of the contact mode ω0 = √(k/m_n) with the pose's m_n (the upper edge, set by the hold,
    to 3 %; the lower edge, where the z-filter and the position loop the Jury model leaves out
    matter, to 15 %)."""
    sc = H.load_scenario("ur5-table-stable", {"controller.kind": "hinf", "simulation.control": "sampled", **IDEAL})
    ctrl = sc.build_controller()
    plant, ref, q_eq, _, _ = A.operating_point(sc, 1e6, ctrl=ctrl)
    m_n = float(fr.normal_mass(ctrl.arm, ctrl.surface, jnp.asarray(q_eq)))
    K_prime = 1.0 + 0.5 * float(ctrl.gains.beta_lam)
    lo, hi = fr.jury_window(math.sqrt(1e6 / m_n) * 1e-3, K_prime - 1.0, 1e-3)

    def radius(kappa):
        return A.sampled_modes(plant, A.with_kappa(ctrl, kappa), ref, q_eq, 1e-3, sc.simulation.dt)["radius"]

    middle = math.sqrt(lo * hi)
    assert radius(middle) < 1.0 and radius(0.5 * lo) > 1.0 and radius(1.5 * hi) > 1.0
    assert _edge(radius, middle, 1.5 * hi) == pytest.approx(hi, rel=0.03)
    assert _edge(radius, middle, 0.5 * lo) == pytest.approx(lo, rel=0.15)


def test_sampled_map_composed_equals_the_simulators_sampled_step_differentiated():
    """The one-period map of the sampled loop composed from the continuous loop's Jacobian and the
    held plant's (the RK4 polynomial of the linear plant) equals ``jacfwd`` of the simulator's
    sampled step (sample update, ten RK4 steps with the torque held) on the paper's arm, adaptive
    law at 1 kHz, 1e5 N/m."""
    sc = H.load_scenario("paper-stable", {"controller.kind": "hinf_nn", "simulation.control": "sampled",
                                          "controller.force_rate.stiffness_max": 1e5})
    ctrl = sc.build_controller()
    plant, ref, q_eq, _, _ = A.operating_point(sc, 1e5, ctrl=ctrl)
    composed = A.sampled_map_jacobian(plant, ctrl, ref, q_eq, 1e-3, 1e-4)
    direct, y1 = A.sampled_map_direct(plant, ctrl, ref, jnp.asarray(A.rest_state(ctrl, q_eq)), 1e-3, 10)
    direct = np.asarray(direct)
    assert np.max(np.abs(composed - direct)) < 1e-12 * np.max(np.abs(direct))
    assert np.max(np.abs(np.asarray(y1) - A.rest_state(ctrl, q_eq))) < 1e-9  # a fixed point of the map


def test_design_refuses_what_the_sampled_loop_cannot_hold_and_says_what_would():
    """1e6 N/m at 1 kHz on the drum: a DesignError on controller.force_rate.stiffness_max whose
    bound is the stiffest contact the period holds, which the design then accepts (just below)."""
    over = {"controller.kind": "hinf", "simulation.control": "sampled", **IDEAL}
    with pytest.raises(H.DesignError) as err:
        H.load_scenario("planar3-drum-stable", {**over, "controller.force_rate.stiffness_max": 1e6})
    e = err.value
    assert e.key == "controller.force_rate.stiffness_max" and e.value == 1e6
    assert "stiffness_max <=" in str(e) and "control_period <=" in str(e)
    limit = float(e.bound)
    assert 1e5 < limit < 1e6
    d = _design("planar3-drum-stable", **over, **{"controller.force_rate.stiffness_max": 0.999 * limit})
    assert d["window"][0] < d["kappa"] < d["window"][1]
    with pytest.raises(H.DesignError):
        H.load_scenario("planar3-drum-stable", {**over, "controller.force_rate.stiffness_max": 1.001 * limit})


def test_singularity_guard_checks_the_path_of_any_arm():
    with pytest.raises(H.DesignError) as err:
        H.load_scenario("ur5-table-stable", {"controller.singularity_stop": 50.0})
    assert err.value.key == "reference.u1_amplitude" and "singular value" in str(err.value)


def test_the_design_does_not_depend_on_the_runs_horizon():
    """ur5-table-stable's path (a 1-s fade-in and a 4-s circle) is designed over 0..5 s, whatever
    simulation.t_final: a 0.3-s smoke test and a 10-s run get the same κ, continuous and at 1 kHz,
    and `hinfnn design` says what span it covered."""
    from hinfnn.scenario.checks import design_span

    for over in ({}, {"simulation.control": "sampled"}):
        kappas = {t: _design("ur5-table-stable", **{"controller.kind": "hinf", "simulation.t_final": t, **over})["kappa"]
                  for t in (0.3, 10.0)}
        assert kappas[0.3] == kappas[10.0], (over, kappas)
    sc = H.load_scenario("ur5-table-stable", {"simulation.t_final": 0.3})
    assert design_span(sc) == (5.0, "the 1-s fade-in and one 4-s period of u1d")
    rep = A.design_report(sc.single("hinf"))
    assert "u1d(t) on 0..5 s: the 1-s fade-in and one 4-s period of u1d" in A.format_design_report(rep)
    # cosines of periods 2 and 3 s repeat every 6 s; of 1 and √2 s never: 100 periods of the slowest
    two = sc.with_overrides({"reference.u1_period": [2.0, 3.0, 4.0, 4.0, 4.0]})
    assert design_span(two)[0] == 7.0
    odd = sc.with_overrides({"reference.u1_period": [1.0, math.sqrt(2), 4.0, 4.0, 4.0]})
    assert design_span(odd) == (1.0 + 100 * math.sqrt(2), "the 1-s fade-in and 100 periods of its slowest cosine "
                                "(its cosines have no common period up to 141.421 s)")


# --------------------------------------------------------------------------------------------
# `hinfnn design` on every shipped scenario
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", scenario_names())
def test_design_command_on_every_shipped_scenario(name, capsys):
    """Text and --json (one controller kind per scenario: the H∞-only law): the design, the
    contact modes before and after the force-rate term at the design's stiffnesses (the force
    loop's eigenvalues are the polynomial's roots, the force loop does not depend on the position
    loop), the path and the start pose."""
    over = ["--set", "controller.kind=hinf"]
    assert cli.main(["design", name, *over, "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    # the text is format_design_report of the same report (cli/design.py), read back from its JSON
    # (the report is computed once per scenario: its linearisations are this file's largest cost)
    from hinfnn.analysis import format_design_report

    text = format_design_report(rep)
    if name == "paper":  # and the command's text path itself, once
        assert cli.main(["design", name, *over]) == 0
        assert capsys.readouterr().out.strip() == text.strip()
    assert "contact mode at 100000 N/m" in text and "start pose" in text and "path:" in text
    d = rep["kinds"]["hinf"]
    variants = d["contact_modes"]["variants"]
    assert len(variants) == 2
    for label, entries in variants.items():
        paper = "paper" in label
        for k, m in entries.items():
            if k == "sampled":  # a sampled scenario (ur5-polish): the one-period map's spectral radius
                assert m["stable"] is (m["radius"] < 1.0) is (not paper), (label, k, m["radius"])
                continue
            if k == "noise":  # the sampled loop with the declared sensor's delay: its gains per N of noise
                assert m["stable"] is (m["radius"] < 1.0), (label, k, m["radius"])
                assert not m["stable"] or (m["lam_per_n"] > 0 and min(m["tau_per_n"]) >= 0), (label, m)
                continue
            assert m["polynomial_match"] < 1e-8 and m["coupling"] < 1e-12 and m["residual"] < 1e-6, (label, k)
            assert m["stable"] is (not paper), (label, k, m["mode"])
    assert rep["path"]["found"] == rep["path"]["points"] and rep["path"]["sigma_min"] > 0
    if name.endswith("stable") and d["force_rate"].get("sensing"):  # designed for the declared sensor (section 12)
        # with the joint rates the damping is least at the stiffest contact: more than the rule's at the softest
        assert d["force_rate"]["sensing"]["noise"] == 1.0 and d["force_rate"]["zeta_softest"] > 0.7
    elif name.endswith("stable"):
        assert d["force_rate"]["rule"] and d["force_rate"]["zeta_softest"] == pytest.approx(0.7)


# --------------------------------------------------------------------------------------------
# Runs: the stabilised law holds contact where the paper's law bounces
# --------------------------------------------------------------------------------------------
def test_stabilised_ur5_holds_contact_where_the_paper_law_bounces():
    """ur5-table on the bare table (undamped 1e5 N/m), adaptive law, 0.5 s: the paper's law
    (κ = 0, the same compiled program) leaves the table after 0.2 s, the stabilised one never does,
    and its dissipation inequality holds at every sample."""
    sc = H.load_scenario("ur5-table-stable", {"controller.kind": "hinf_nn", "simulation.t_final": 0.5})
    run = sc.run()
    import dataclasses

    runs = [run, dataclasses.replace(run, name="paper", controller=A.with_kappa(run.controller, 0.0))]
    trajs = H.simulate_many(runs, fields="metrics")
    out = {}
    for r in runs:
        tr = trajs[r.name]
        after = np.asarray(tr.t) > 0.2
        out[r.name] = (int(tr.status), float(np.sum(np.asarray(tr.steps_out_of_contact)[after])),
                       H.compute_metrics(tr)["dissipation_holds_for_all_t"])
    assert out[run.name] == (0, 0.0, True)
    assert out["paper"][1] > 0 or out["paper"][0] != 0, out
