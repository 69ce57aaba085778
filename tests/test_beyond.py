"""Beyond the paper (docs/beyond-the-paper.md): the force loop's instability and its fix.

The linearised closed loop (JAX Jacobian of the simulator's right-hand side) against the
closed-form polynomial; the force-rate term's filter and storage along runs; the κ rule; the
singularity guard driven into q2 = 0; the stabilised laws' numbers on the undamped contact.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hinfnn as H
from hinfnn.status import RunStatus
from hinfnn import cli
from hinfnn.analysis import contact_modes, force_loop_polynomial, loop_constants
from hinfnn.controllers import SampledController
from hinfnn.protocols import Measurement

#: one xdist worker runs this module: its tests share compiled programs and expensive fixtures
pytestmark = pytest.mark.xdist_group("beyond")

STABLE = {"controller.force_rate.kappa": "rule", "controller.gains.Q_p": [[1e4, 0.0], [0.0, 1.0]]}


@pytest.fixture(scope="module")
def paper():
    return H.load_scenario("paper")


@pytest.fixture(scope="module")
def stable():
    return H.load_scenario("paper-stable")


@pytest.mark.parametrize("kind", ["fl", "hinf"])
def test_paper_laws_have_the_unstable_contact_pair_of_the_cubic(paper, kind):
    """The Jacobian's force-loop eigenvalues are the roots of m_s s³ + m_s μ_z s² + k_u K's +
    k_u(K'μ_z + α_z) (to 1e-6 relative), and the pair is unstable: Routh's a₂a₁ − a₃a₀ = −α_z m_s k_u."""
    r = contact_modes(paper.with_overrides({"controller.kind": kind}), kind, 1e5)
    assert r["residual"] < 1e-6  # an equilibrium indeed
    assert r["polynomial_match"] < 1e-6
    assert r["least_damped"].s.real > 0 and not r["stable"]
    c, g = r["constants"], paper.controller.gains
    K = 1.0 if kind == "fl" else 1.0 + 0.5 * (g.alpha_lam * g.alpha_z / (2 * g.rho**2) - 1.0)
    a3, a2, a1, a0 = force_loop_polynomial(c["m_s"], c["k_u"], K, g.mu_z, g.alpha_z)
    np.testing.assert_allclose(a2 * a1 - a3 * a0, -g.alpha_z * c["m_s"] * c["k_u"], rtol=1e-12)
    # its growth rate is α_z ω²/(2K'(ω² + μ_z²)) to first order (→ α_z/(2K') for a stiff contact)
    w2 = r["least_damped"].s.imag ** 2
    assert r["least_damped"].s.real == pytest.approx(g.alpha_z * w2 / (2 * K * (w2 + g.mu_z**2)), rel=0.02)


@pytest.mark.parametrize("k", [1e4, 1e5, 1e6])
def test_force_rate_term_damps_the_contact_mode(stable, k):
    r = contact_modes(stable.with_overrides({"controller.kind": "hinf"}), "hinf", k)
    assert r["polynomial_match"] < 1e-6  # the quintic with κ and τ_f
    assert r["stable"] and r["least_damped"].zeta > 0.1
    assert r["kappa"] == pytest.approx(0.0280, abs=1e-4)


def test_kappa_rule_on_two_stiffnesses(paper):
    """κ = 2ζ√(K' m_n,max / k_min): 4× the softest stiffness halves κ, and the linearised contact
    mode at that stiffness then has (about) the damping ratio asked for, whichever it is."""
    out = {}
    for k_min in (1e4, 4e4):
        sc = paper.with_overrides({**STABLE, "controller.kind": "hinf", "controller.force_rate.stiffness_min": k_min})
        r = contact_modes(sc, "hinf", k_min)
        out[k_min] = r
        assert r["stable"] and 0.6 < r["least_damped"].zeta < 1.0, r["least_damped"]
    assert out[1e4]["kappa"] / out[4e4]["kappa"] == pytest.approx(2.0, rel=1e-12)
    # m_n from the design step is the model's: the normal mass at the equilibrium pose is inside its range
    c = loop_constants(paper.nominal.arm.build(), paper.nominal.surface.build(), 1e4, np.asarray(out[1e4]["q"]))
    d = H.controllers.design_summary(paper.with_overrides({**STABLE, "controller.kind": "hinf"}).build_controller())
    assert d["force_rate"]["m_n_min"] <= c["m_n"] <= d["force_rate"]["m_n_max"]


def test_path_poses_are_solved_once_per_model_and_path(paper, monkeypatch):
    """The design's path (kept per process): the same arm, surface, range and start give the poses
    solved the first time, without solving again; another arm (a value, not the object) or
    another range is solved anew."""
    from hinfnn.controllers import force_rate as fr

    calls = []
    solve = fr._solve_path
    monkeypatch.setattr(fr, "_solve_path", lambda *a: calls.append(a) or solve(*a))
    monkeypatch.setattr(fr, "_PATHS", {})
    arm, surface = paper.nominal.arm.build(), paper.nominal.surface.build()
    q0 = np.asarray(paper.initial_q())
    first = fr.path_poses(arm, surface, (1.4, 1.6), q0)
    again = fr.path_poses(paper.nominal.arm.build(), paper.nominal.surface.build(), (1.4, 1.6), q0.copy())
    assert len(calls) == 1 and [u for u, _ in again] == [u for u, _ in first]
    assert all(a is b for (_, a), (_, b) in zip(first, again))
    longer = fr.path_poses(H.TwoLinkArm(m1=1.5, m2=1.0, l1=1.0, l2=1.01), surface, (1.4, 1.6), q0)
    fr.path_poses(arm, surface, (1.4, 1.55), q0)
    assert len(calls) == 3 and not np.array_equal(longer[-1][1], first[-1][1])


def test_sampled_design_window_and_refusal(paper):
    sc = paper.with_overrides({**STABLE, "controller.kind": "hinf", "simulation.control": "sampled",
                               "controller.force_rate.stiffness_max": 1e5})
    d = H.controllers.design_summary(sc.build_controller())["force_rate"]
    lo, hi = d["window"]
    assert lo < d["kappa"] <= 0.8 * hi + 1e-15 and d["tau_f"] == pytest.approx(1e-3)
    with pytest.raises(H.DesignError, match="stiffness_max") as err:
        paper.with_overrides({**STABLE, "controller.kind": "hinf", "simulation.control": "sampled",
                              "controller.force_rate.stiffness_max": 1e6})
    assert err.value.key == "controller.force_rate.stiffness_max"


@pytest.fixture(scope="module")
def stable_runs(stable):
    """0.5 s of the stabilised H∞-only and adaptive laws on the paper plant, every step stored."""
    out = {}
    for kind in ("hinf", "hinf_nn"):
        sc = stable.with_overrides({"controller.kind": kind, "simulation.t_final": 0.5})
        out[kind] = sc.simulate(save_every=1)
    return out


@pytest.mark.parametrize("kind", ["hinf", "hinf_nn"])
def test_storage_identity_with_the_new_term(stable_runs, kind):
    """V̇ + (integrand of 34) − supply ≤ 0 along the run: the margin ρ²∫‖f‖² − (J_aug + V − V(0)),
    J_aug carrying the filter's extra dissipation, never decreases (up to the RK4 error) and
    stays ≥ 0 at every sample."""
    tr = stable_runs[kind]
    margin = tr.supply - (tr.J_aug + tr.V - tr.V[0])
    assert np.all(margin >= 0)
    scale = np.max(np.abs(tr.supply))
    assert np.min(np.diff(margin)) > -1e-9 * scale
    assert tr.J_aug[-1] > tr.J[-1]  # the filter dissipates: its term is in J_aug


def test_filter_derivative_against_finite_differences(stable_runs):
    """The state s the simulator integrates has the derivative the term uses, (e_λ − s)/τ_f."""
    tr = stable_runs["hinf"]
    kappa = float(H.controllers.design_summary(H.load_scenario("paper-stable", {"controller.kind": "hinf"})
                                               .build_controller())["force_rate"]["kappa"])
    s_dot = -tr.v_rate[:, 0] / kappa
    fd = (tr.s_lam[2:, 0] - tr.s_lam[:-2, 0]) / (tr.t[2:] - tr.t[:-2])
    assert np.max(np.abs(fd - s_dot[1:-1])) < 2e-2 * np.max(np.abs(s_dot))
    # and the filter starts at e_λ(0): no kick at the first sample
    assert tr.s_lam[0, 0] == pytest.approx(tr.e_lam[0, 0])
    assert abs(tr.v_rate[0, 0]) < 1e-9


def test_singularity_guard_stops_a_run_driven_into_q2_zero(paper):
    """A reference past the line's reach (u1d up to 1.85 m; q2 = 0 at 1.7565 m on the nominal
    path): with the guard the run stops cleanly, status 4, before the torque blows up."""
    sc = paper.with_overrides({**STABLE, "controller.kind": "hinf", "plant.contact.damping": 200.0})
    plant = sc.build_plant()
    ref = H.CosineReference(u1_offset=jnp.array([1.7]), u1_amplitude=jnp.array([-0.15]),
                            u1_omega=jnp.array([math.pi]), u1_phase=jnp.array([0.0]),
                            lam_offset=jnp.array([60.0]), lam_amplitude=jnp.array([0.0]),
                            lam_omega=jnp.array([math.pi]), lam_phase=jnp.array([0.0]))
    arm, surf = sc.nominal.arm.build(), sc.nominal.surface.build()
    guarded = H.controllers.design("hinf", arm, surf, sc.controller.gains.build(), singularity_stop=0.1)
    tr = H.simulate(plant, guarded, ref, q0=sc.initial_q(plant), t_final=1.0, dt=1e-4, raise_on_failure=False)
    assert tr.run_status is RunStatus.CONTROLLER_FAULT, tr.reason
    t_fail = float(tr.t_fail)
    assert 0.1 < t_fail < 1.0
    assert float(tr.fail_details["fault_value"]) < 0.1 and "σ_min(Ĵ)" in tr.reason
    before = tr.t <= t_fail
    assert np.max(tr.tau_abs_max[before]) < 2e3 and np.min(tr.sigma_min_J[before][:-1]) >= 0.1 - 0.02
    with pytest.raises(H.SimulationError, match="singularity guard"):
        H.simulate(plant, guarded, ref, q0=sc.initial_q(plant), t_final=1.0, dt=1e-4)
    # the sampled controller refuses a torque there too (NaN: the robot's safe stop)
    x = jnp.array([1.755, float(surf.Omega(jnp.array([1.755]))[0])])
    q = arm.inverse_kinematics_closed(x, elbow_up=True)
    tau, _ = SampledController(guarded, ref).step(0.0, 1e-3, guarded.init(),
                                                  Measurement(q=q, qd=jnp.zeros(2), force=jnp.zeros(2)))
    assert np.all(np.isnan(np.asarray(tau)))
    loop = SampledController(guarded, ref).loop(guarded.init())
    assert np.all(np.isnan(loop.update(0.0, 1e-3, np.asarray(q), np.zeros(2), np.zeros(2)))) and loop.rejected == 1


def test_scenario_refuses_a_reference_into_the_singularity(paper):
    with pytest.raises(H.DesignError) as err:
        paper.with_overrides({"controller.singularity_stop": 0.1, "reference.u1_amplitude": 0.3})
    assert err.value.key == "reference.u1_amplitude" and "singular value" in str(err.value)


def test_design_command_prints_the_design(capsys):
    assert cli.main(["design", "paper-stable", "--set", "controller.kind=hinf"]) == 0
    out = capsys.readouterr().out
    assert "force rate: kappa 0.028" in out and "Riccati eq. (35)" in out
    assert "contact mode at 100000 N/m, as designed" in out and "without the force-rate term" in out
    assert "UNSTABLE" in out  # the paper's law, shown beside


@pytest.mark.slow
def test_stabilised_laws_meet_the_targets_on_the_undamped_paper_plant(stable):
    """10 s, k = 1e5, continuous: never out of contact, RMS e_λ ≤ 2 (H∞-only) / 1.2 (adaptive),
    RMS e_u1 ≤ 0.02 m, peak |τ1| ≤ 250 N·m after 0.1 s, dissipation at every sample."""
    runs = [stable.run(kind) for kind in ("hinf", "hinf_nn")]
    trajs = H.simulate_many(runs, fields="metrics")
    for kind, lam_max in (("hinf", 2.0), ("hinf_nn", 1.2)):
        tr = trajs[kind]
        m = H.compute_metrics(tr)
        assert int(tr.status) == 0
        assert m["fraction_out_of_contact"] == 0.0
        assert m["rms_e_lam"] <= lam_max and m["rms_e_u1"] <= 0.02
        assert np.max(tr.tau_abs_max[tr.t > 0.1, 0]) <= 250.0
        assert m["dissipation_holds_for_all_t"] is True


def test_reproduce_writes_the_beyond_part(tmp_path, reproduced):
    """`hinfnn reproduce` (short horizon, one stiffness to keep it quick: the ``reproduced``
    fixture of conftest.py): metrics.json's "beyond" part names every case with its run,
    beyond.npz holds their fields, the figures and the report's section exist, and the override
    the comparison cannot honour is refused."""
    import json

    from hinfnn.workflows import paper as study

    with pytest.raises(H.ConfigError) as err:
        study.reproduce(tmp_path / "refused", base=H.load_scenario("paper", [("plant.contact.stiffness", 2e5)]))
    assert err.value.key == "plant.contact.stiffness" and "--paper-only" in str(err.value)
    assert not (tmp_path / "refused").exists()
    out, _ = reproduced
    doc = json.loads((out / "metrics.json").read_text())
    beyond = doc["beyond"]
    names = {c["name"] for c in beyond["cases"]}
    expected = {f"{kind}_{variant}_{mode}_k1e5" for kind in ("hinf", "hinf_nn") for variant in ("paper", "stable")
                for mode in ("cont", "1kHz", "10kHz", "mujoco")}
    assert names == expected and {r["name"] for r in beyond["runs"]} == expected
    assert "mujoco_skipped" not in beyond
    assert beyond["design"]["kappa"] == pytest.approx(0.028, abs=5e-4)
    assert len(beyond["contact_modes"]) == 4
    assert all(m["polynomial_match"] is None or m["polynomial_match"] < 1e-6 for m in beyond["contact_modes"])
    with np.load(out / "beyond.npz") as z:
        assert {f"{n}/e_lam" for n in expected} <= set(z.files)
    report = (out / "report.md").read_text()
    assert "Beyond the paper" in report
    pngs = sorted(p.name for p in out.glob("beyond_*.png"))
    assert pngs and all(f"({p})" in report or p in report for p in pngs)


def test_two_designs_share_their_program_structure(paper):
    """A design's record holds its numbers (κ's rule takes the normal masses on the reference's
    path, so another horizon or another softest contact records other numbers); the record is a
    Note (every Note equal), so two designs have one pytree structure (one compiled program) while
    each keeps and reports its own numbers."""
    from hinfnn._pytree import Note

    sc = paper.with_overrides({**STABLE, "controller.kind": "hinf"})
    designs = [sc.with_overrides({"controller.force_rate.stiffness_min": k}).build_controller() for k in (1e4, 3e4)]
    records = [dict(c.term(H.controllers.terms.ForceRate).design) for c in designs]
    assert records[0]["kappa"] != records[1]["kappa"]  # another design: another record
    assert jax.tree.structure(designs[0]) == jax.tree.structure(designs[1])
    summaries = [H.controllers.design_summary(c)["force_rate"] for c in designs]
    assert [s["kappa"] for s in summaries] == [r["kappa"] for r in records]
    assert Note((("a", 1.0),)) == Note() and hash(Note((("a", 1.0),))) == hash(Note()) and Note() != ()
