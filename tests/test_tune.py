"""`hinfnn design --tune SPEC` and the pre-run check of a spec's drawn stiffness against the design
(hinfnn.sweep.tune): the seeded search improves a toy objective, the declared range a design
cannot hold at the control period is refused before anything runs (naming the key and the largest
range), and the written scenario loads back to the tuned design.

The one simulating test tunes the paper's H∞-only law on 2 draws of 0.05 s (one compiled program,
shared with tests/test_sweep.py's H∞-only batches where the cache holds it)."""

from __future__ import annotations

import json
import textwrap
import tomllib

import numpy as np
import pytest

from hinfnn import cli
from hinfnn.errors import ConfigError, DesignError
from hinfnn.scenario import Scenario
from hinfnn.sweep import spec_from_dict
from hinfnn.sweep.tune import (_force_rate_design, _outcome, candidate_overrides, cross_entropy, declared_range,
                               default_knobs, force_radius, range_notes, require_holdable, score, sensed_design, tune)

SAMPLED = """
name = "sampled"
scenario = "paper-stable"
controllers = ["hinf_nn"]
samples = 2
seed = 5
[set]
"simulation.t_final" = 0.05
"simulation.control" = "sampled"
"controller.force_rate.stiffness_max" = 100000.0
[vary]
"plant.contact.stiffness" = { distribution = "log-uniform", low = 1e4, high = 1e7 }
"""

TINY = """
name = "tiny"
scenario = "paper"
controllers = ["hinf"]
samples = 2
seed = 3
[set]
"simulation.t_final" = 0.05
[vary]
"plant.arm.m2" = { distribution = "relative", percent = 20 }
"plant.contact.damping" = { distribution = "uniform", low = 0.0, high = 200.0 }
"""


def spec_of(text):
    return spec_from_dict(tomllib.loads(textwrap.dedent(text)))


def friction_spec(scenario):
    """A spec of ``scenario`` that draws the tool's Coulomb friction alone (2 draws)."""
    return spec_of(f"""
        name = "friction"
        scenario = "{scenario}"
        controllers = ["hinf_nn"]
        samples = 2
        [vary]
        "plant.friction.coulomb" = {{ distribution = "uniform", low = 0.0, high = 0.3 }}
        """)


def test_cross_entropy_improves_a_toy_objective_deterministically():
    target = np.array([0.8, 0.2, 0.6])

    def objective(us, g):
        return [-float(np.sum((u - target) ** 2)) for u in us]

    start = np.array([0.3, 0.7, 0.1])
    u1, s1 = cross_entropy(objective, start, generations=12, population=10, seed=4)
    u2, s2 = cross_entropy(objective, start, generations=12, population=10, seed=4)
    assert s1 == s2 and np.array_equal(u1, u2)  # seeded: the same points
    assert s1 > objective([start], 0)[0] + 0.5 and np.max(np.abs(u1 - target)) < 0.1


def test_the_first_generation_spans_the_whole_box():
    """A Latin hypercube: each knob's range cut into P − 1 strata holds one of the first generation's
    P − 1 points each (the iiwa 14's q × 10 and radius_f × 3.6 sit at 1.0 and 0.57 of their unit
    ranges, two spreads from the base design's start; a Gaussian start did not reach them). Later
    generations, and explore=False, sample around the mean."""
    seen = []

    def objective(us, g):
        seen.append(np.array(us))
        return [-float(np.sum((u - 0.9) ** 2)) for u in us]

    start = np.full(4, 0.2)
    cross_entropy(objective, start, generations=2, population=9, seed=1)
    first = seen[0]
    assert np.array_equal(first[0], start)
    for d in range(4):
        assert sorted(np.floor(first[1:, d] * 8).astype(int)) == list(range(8))
    seen.clear()
    cross_entropy(objective, start, generations=1, population=9, seed=1, explore=False)
    rng = np.random.default_rng(1)  # the Gaussian samples of the search before the hypercube
    assert np.array_equal(seen[0][1:], [np.clip(start + 0.25 * rng.standard_normal(4), 0.0, 1.0) for _ in range(8)])


def test_refused_candidates_are_never_elite():
    calls = []

    def objective(us, g):  # everything right of 0.5 is "refused by the design"
        calls.append(us)
        return [-1.0 if u[0] > 0.5 else float(u[0]) for u in us]

    u, s = cross_entropy(objective, np.array([0.45]), generations=6, population=8, seed=1)
    assert 0.4 < s <= 0.5 and u[0] <= 0.5


def test_declared_ranges():
    spec = spec_of(TINY)
    lo, hi = declared_range(spec, "plant.arm.m2")
    base = float(spec.base.plant.arm.m2)
    assert (lo, hi) == pytest.approx((0.8 * base, 1.2 * base))
    assert declared_range(spec, "plant.contact.damping") == (0.0, 200.0)
    assert declared_range(spec, "plant.contact.stiffness") is None
    # the paper law without a force-rate term: the drawn damping is the contact mode's only damping
    assert range_notes(spec) == []  # the stiffness is not drawn: nothing to compare


def test_a_range_the_design_cannot_hold_is_named_before_anything_runs(tmp_path, capsys):
    spec = spec_of(SAMPLED)
    notes = range_notes(spec)
    assert len(notes) == 1 and notes[0].startswith("plant.contact.stiffness: the spec draws [10000, 1e+07] N/m")
    assert "design is for [10000, 100000] N/m" in notes[0] and "cannot be held" in notes[0]
    assert "damps the softest contact only with ζ = " in notes[0]
    with pytest.raises(DesignError) as err:
        require_holdable(spec.base, "hinf_nn", 1e4, 1e7)
    assert err.value.key == "plant.contact.stiffness" and 1e5 < err.value.bound < 1e7
    assert f"at most [10000, {err.value.bound:.3g}] N/m" in str(err.value)
    require_holdable(spec.base, "hinf_nn", 1e4, 0.9 * err.value.bound)  # inside: accepted
    # the command refuses it with exit 2, before any run (nothing is written)
    (tmp_path / "s.toml").write_text(textwrap.dedent(SAMPLED))
    code = cli.main(["design", "--tune", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out")])
    assert code == 2 and not (tmp_path / "out").exists()
    assert "plant.contact.stiffness" in capsys.readouterr().err


def test_candidate_keeps_the_riccati_weights_structure():
    sc = Scenario.load("ur5-table", check=False)
    over = dict(candidate_overrides(sc, {"omega": 2.0, "q": 3.0, "alpha_lam": 2.0, "zeta": 0.5}, (3e4, 3e5)))
    assert over["controller.gains.K_p"] == pytest.approx(1600.0) and over["controller.gains.K_v"] == pytest.approx(80.0)
    assert over["controller.gains.Q_p"] == pytest.approx([3e4] * 5 + [75.0 / 4] * 5)  # diag(q I, q/ω_n² I)
    assert over["controller.gains.alpha_lam"] == pytest.approx(0.025) and over["controller.gains.beta_lam"] == "min"
    assert over["controller.force_rate.kappa"] == "rule" and over["controller.force_rate.stiffness_max"] == 3e5


def test_design_tune_writes_a_scenario_that_reproduces_the_tuned_design(tmp_path, capsys):
    (tmp_path / "tiny.toml").write_text(textwrap.dedent(TINY))
    out = tmp_path / "tuned"
    code = cli.main(["design", "--tune", str(tmp_path / "tiny.toml"), "--tune-draws", "2", "--held-out", "2",
                     "--generations", "1", "--population", "3", "--seed", "2", "--knobs", "omega,alpha_lam",
                     "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "held-out did its job" in printed and "results:" in printed
    record = json.loads((out / "tune.json").read_text())
    assert record["tuning_draws"] == [0, 1] and record["held_out_draws"] == [2, 3]
    assert len(record["history"]) == 1 + 3
    judged = sum(c["judged"] for c in record["history"] if c["error"] is None)  # a refused design runs nothing
    assert record["runs"] == judged + 2 * (2 if record["best"]["overrides"] else 1)
    assert all(c["judged"] == 2 for c in record["history"] if c["error"] is None)
    for name in ("scenario.toml", "report.md", "design.txt"):
        assert (out / name).stat().st_size > 0
    loaded = Scenario.load(out / "scenario.toml")
    expected = spec_of(TINY).base.with_overrides([tuple(x) for x in record["best"]["overrides"]])
    g1, g2 = loaded.build_controller("hinf").gains, expected.build_controller("hinf").gains
    for f in ("K_p", "K_v", "alpha_lam", "beta_lam", "Q_p"):
        assert np.array_equal(np.asarray(getattr(g1, f)), np.asarray(getattr(g2, f))), f


def test_the_sweep_warns_before_it_runs_plants_the_design_was_not_made_for(tmp_path, capsys, monkeypatch):
    from hinfnn.errors import ConfigError
    from hinfnn.sweep import run as sweep_run

    def stop(*args, **kwargs):
        raise ConfigError("stopped here", key="--test")

    monkeypatch.setattr(sweep_run, "run_sweep", stop)  # nothing runs: the warning comes first
    (tmp_path / "s.toml").write_text(textwrap.dedent(SAMPLED))
    assert cli.main(["sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    warning = err.index("hinfnn sweep: warning: plant.contact.stiffness: the spec draws [10000, 1e+07] N/m")
    assert warning < err.index("stopped here") and "no design at this period keeps contacts stiffer than" in err


def test_a_force_rate_gain_designed_for_the_sensor_is_tuned_by_kappa_not_zeta():
    """ur5-table-stable chose κ for its declared sensor (1 N of noise, one sample late, 1 kHz): ζ* sets
    nothing there (the dead knob the iiwa 14 search moved, docs/arms-and-surfaces.md), so the default
    knobs scale κ instead and an explicit zeta is refused; an ideal-sensor design keeps zeta."""
    sc = Scenario.load("ur5-table-stable", check=False)
    base = sensed_design(sc, "hinf_nn")
    assert base is not None and default_knobs(sc, "hinf_nn") == ("omega", "q", "alpha_lam", "alpha_z", "kappa",
                                                                 "radius_f")
    assert default_knobs(Scenario.load("ur5-table", check=False), "hinf_nn")[-1] == "zeta"
    kap = float(base["kappa"])

    def kappa_of(values):
        over = candidate_overrides(sc, values, None, kap)
        return float(_force_rate_design(sc.single("hinf_nn").with_overrides(over), "hinf_nn")["kappa"])

    assert kappa_of({"zeta": 0.2}) == kappa_of({"zeta": 1.8}) == kap  # ζ* moves nothing here
    assert kappa_of({"kappa": 1.1}) == pytest.approx(1.1 * kap, rel=1e-12)
    with pytest.raises(ConfigError) as err:  # before anything runs
        tune(friction_spec("ur5-table-stable"), knobs=("omega", "zeta"), draws=1, held_out=0, generations=0)
    assert err.value.key == "--knobs" and "kappa knob" in str(err.value)
    with pytest.raises(ConfigError, match="has no force-rate term"):
        candidate_overrides(sc, {"kappa": 1.1}, None, None)


def test_the_radius_f_knob_scales_the_force_networks_projection_radius():
    """Where a noisy sensor makes the update laws project (Remark 2), the design's radius of F_f lets the
    network give the largest |λ_d| and no more; the iiwa 14's 20 % mass error presses harder than that
    (docs/arms-and-surfaces.md), so the tuner moves the radius by a factor. The candidate's controller
    projects on exactly that factor times the design's ball; H∞-only (no network) and an ideal sensor
    (no projection) have no such knob, and asking for it is refused before anything runs."""
    from hinfnn.controllers import terms as T

    sc = Scenario.load("ur5-table-stable", check=False)
    r0 = force_radius(sc, "hinf_nn")
    built = sc.single("hinf_nn").build_controller("hinf_nn").term(T.ForceNetwork).network
    assert r0 == pytest.approx(float(built.radius), rel=0) and bool(built.project)
    over = candidate_overrides(sc, {"radius_f": 3.5}, None, None, r0)
    assert over == [("controller.adaptation.radius_f", pytest.approx(3.5 * r0, rel=1e-15))]
    net = sc.single("hinf_nn").with_overrides(over).build_controller("hinf_nn").term(T.ForceNetwork).network
    assert float(net.radius) == pytest.approx(3.5 * r0, rel=1e-15) and bool(net.project)
    pos = sc.single("hinf_nn").with_overrides(over).build_controller("hinf_nn").term(T.PositionNetwork).network
    assert float(pos.radius) == float(sc.single("hinf_nn").build_controller("hinf_nn").term(T.PositionNetwork)
                                      .network.radius)  # F_p's ball is not moved
    assert "radius_f" not in default_knobs(sc, "hinf")
    ideal = Scenario.load("ur5-table", check=False)
    assert force_radius(ideal, "hinf_nn") is None and "radius_f" not in default_knobs(ideal, "hinf_nn")
    with pytest.raises(ConfigError, match="does not project"):
        candidate_overrides(ideal, {"radius_f": 2.0}, None, None, None)
    with pytest.raises(ConfigError) as err:  # before anything runs
        tune(friction_spec("ur5-table"), knobs=("q", "radius_f"), draws=1, held_out=0, generations=0)
    assert err.value.key == "--knobs" and "does not project" in str(err.value)


def test_the_kappa_knob_scales_the_kappa_designed_for_the_declared_range(monkeypatch):
    """ur5-polish declares its sensor and is designed for [1e4, 1e5] N/m; its spec draws [1e4, 1e6].
    Every candidate sets the force-rate term's range to the declared one, where the base design's κ
    holds nothing (the design refuses it: the first tuning of this spec refused all 24 candidates), so
    the kappa knob scales the κ the design chooses for the declared range. Nothing is simulated: the
    draws are stubbed out and the candidates' keys read back."""
    from hinfnn.sweep import load_spec
    from hinfnn.sweep import tune as tune_module

    spec = load_spec("ur5-polish-uncertainty")
    sc = spec.base.single("hinf_nn")
    declared = [("controller.force_rate.stiffness_min", 1e4), ("controller.force_rate.stiffness_max", 1e6)]
    base_k = float(_force_rate_design(sc, "hinf_nn")["kappa"])
    ranged_k = float(_force_rate_design(sc.with_overrides(declared), "hinf_nn")["kappa"])
    assert ranged_k < 0.2 * base_k
    with pytest.raises(DesignError, match="does not hold even the stiffest contact"):
        sc.with_overrides(candidate_overrides(sc, {"kappa": 1.0}, (1e4, 1e6), base_k)).build_controller("hinf_nn")
    none = tune_module.Draws([], [], [], [], [], [])
    monkeypatch.setattr(tune_module, "build_draws", lambda *a, **k: none)
    lines = []
    res = tune(spec, knobs=("kappa",), draws=1, held_out=0, generations=1, population=2, seed=0, log=lines.append)
    first = dict(res.history[1].overrides)  # generation 1's mean: the factor 1
    assert res.history[1].values == {"kappa": 1.0} and first["controller.force_rate.kappa"] == ranged_k
    assert (first["controller.force_rate.stiffness_min"], first["controller.force_rate.stiffness_max"]) == (1e4, 1e6)
    sc.with_overrides(list(first.items())).build_controller("hinf_nn")  # the design takes it
    assert any(line.startswith(f"kappa knob: factors on κ = {ranged_k:.4g} s") for line in lines)


def test_an_outcome_names_the_criterion_furthest_from_its_tolerance():
    tol = dict(position_tolerance=0.005, angle_tolerance=0.02, force_tolerance=0.1, out_of_contact=0.0)
    coords = [("s1", "m"), ("r_y", "rad")]

    def outcome(e, force, status=0):
        m = dict(rms_e_u1_each_last2s=e, verdict=dict(contact_held=True, tracking_within_tolerance=False,
                                                      force_error_ratio_last2s=force, out_of_contact_after=0.0))
        return _outcome(m, status, tol, coords)

    o = outcome([0.006, 0.029], 0.05)  # the issue's trial: s1 6 mm, the tilt 29 mrad
    assert (o.worst, o.badness) == ("r_y", pytest.approx(1.45)) and not o.done
    o = outcome([0.001, 0.01], 0.18)
    assert (o.worst, o.badness) == ("force", pytest.approx(1.8))
    assert outcome([0.001, 0.01], 0.05, status=3).worst == "stopped"


def test_the_score_does_not_give_up_tracking_for_the_worst_criterion():
    """The iiwa 14 search (docs/arms-and-surfaces.md): with the force the worst criterion on every draw,
    a score of the worst criterion alone preferred a design that tracked worse (q 0.28: s1 6.4 mm,
    r_y 29 mrad) to one within tolerance (q 10: 1.5 mm, 6.6 mrad) at a slightly larger force error."""
    tol = dict(position_tolerance=0.005, angle_tolerance=0.02, force_tolerance=0.1, out_of_contact=0.0)
    coords = [("s1", "m"), ("r_y", "rad")]

    def outcome(e, force):
        m = dict(rms_e_u1_each_last2s=e, verdict=dict(contact_held=True, tracking_within_tolerance=False,
                                                      force_error_ratio_last2s=force, out_of_contact_after=0.0))
        return _outcome(m, 0, tol, coords)

    loose = outcome([0.0064, 0.029], 0.25)  # force worst (2.5), r_y and s1 beyond theirs too
    tight = outcome([0.0015, 0.0066], 0.27)  # force worst (2.7), the rest within
    assert loose.worst == tight.worst == "force" and tight.others == 0.0
    assert loose.others == pytest.approx(np.log10(1.28) + np.log10(1.45))
    assert score([tight]) > score([loose])
    # within every other tolerance, the score is the worst criterion's alone, as before
    assert score([tight]) == pytest.approx(-0.01 * np.log10(2.7))


def test_the_iiwa14_example_is_the_issues_trial_on_the_users_urdf():
    """examples/iiwa14 (docs/arms-and-surfaces.md, "Your own arm, tuned"): panda-table's task on the
    user's iiwa 14 URDF, the truth 20 % heavy with mu = 0.2, and a spec that draws the truth only."""
    from pathlib import Path

    folder = Path(__file__).resolve().parents[1] / "examples" / "iiwa14"
    sc = Scenario.load(folder / "iiwa14-table.toml", check=False)
    assert (sc.plant.arm.mass_scale, sc.plant.friction.coulomb, sc.nominal.arm.mass_scale) == (1.2, 0.2, 1.0)
    assert sc.build().nominal_arm.n == 7 and sc.task.extra == ("arm_angle",)
    spec = tomllib.loads((folder / "iiwa14-uncertainty.toml").read_text())
    assert spec["scenario"] == "iiwa14-table.toml" and set(spec["vary"]) == {
        "plant.arm.mass_scale", "plant.arm.payload_mass", "plant.friction.coulomb"}
    assert (spec["vary"]["plant.arm.mass_scale"]["low"], spec["vary"]["plant.arm.mass_scale"]["high"]) == (0.8, 1.2)
    # the tuned example: the base scenario with the four tuned keys, the design's ball scaled by its factor
    from hinfnn.controllers import terms as T

    tuned = Scenario.load(folder / "iiwa14-table-tuned.toml", check=False)
    r0 = force_radius(sc, "hinf_nn")
    law = tuned.single("hinf_nn").build_controller("hinf_nn")
    assert float(law.term(T.ForceNetwork).network.radius) == pytest.approx(4.170842255983227 * r0, rel=1e-12)
    assert tuned.controller.force_rate.kappa == pytest.approx(
        0.5449269701274813 * float(_force_rate_design(sc.single("hinf_nn"), "hinf_nn")["kappa"]), rel=1e-12)
    assert float(tuned.controller.gains.K_p) == pytest.approx(0.5295465532726283 ** 2 * float(sc.controller.gains.K_p),
                                                              rel=1e-12)
    assert (tuned.plant, tuned.nominal, tuned.task, tuned.reference) == (sc.plant, sc.nominal, sc.task, sc.reference)
