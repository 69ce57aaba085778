"""Paper-regression: the Sec. VI study's metrics at 10 s (dt = 1e-4, RK4, float64) must equal the
recorded ones (``tests/fixtures/paper_study.json``, full precision, regenerated only by
``tests/fixtures/regenerate_paper_study.py`` when a change is meant to move them) to 1e-9 relative
on the pinned stack for the runs on the damped contact, and to 1e-5 for those on the paper's
undamped contact, whose impacts amplify rounding (:data:`RTOL_IMPACTS` says by how much), so that a
change that moves them, by 0.5 % or by 1e-6, is seen.

``hinf_nn_printed`` (F_f centre step 0.05, undamped contact) is left out of that comparison: it is
chaotic, its metrics move by ~3 % when u1(0) moves by 1e-9 m (docs/paper-conventions.md on the
0.05 preset), so a rounding difference of another CPU's vector code moves them too. It is checked
for its status and its dissipation inequality. The other runs move by < 1e-4 under the same
perturbation.

The same study is checked against the theorems: the dissipation inequality (34)/(54) along every
H∞-only and adaptive run, at every saved instant.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import hinfnn as H
from hinfnn.metrics import VERDICT_KEYS
from hinfnn.experiment import simulate_cases
from hinfnn.workflows.paper import study_cases
from hinfnn.workflows.paper_report import evaluate

#: the worker that runs test_beyond.py's `hinfnn reproduce` runs this module too: the study's batched
#: programs are compiled once, for both
pytestmark = pytest.mark.xdist_group("beyond")

#: The study's metrics at full precision (tests/fixtures/paper_study.json, written by
#: tests/fixtures/regenerate_paper_study.py on the pinned stack with the suite's XLA flags).
FIXTURE = Path(__file__).parent / "fixtures" / "paper_study.json"
RECORDED = json.loads(FIXTURE.read_text())["runs"]
#: Runs whose metrics are not reproducible across machines: chaotic (see the docstring).
CHAOTIC = ("hinf_nn_printed",)
#: Relative tolerance of the comparison: the numbers of a deterministic program on the pinned stack,
#: for the runs on the damped contact (a smooth closed loop) ...
RTOL = 1e-9
#: ... and for the runs on the paper's undamped contact, which opens and closes hundreds of times a
#: second: a rounding difference decides a step in or out of contact and grows. Measured when the
#: fixture was recorded: a change of the compiled program that moved the damped runs by at most
#: 7e-12 (relative) moved these by at most 1.8e-7 (XLA fuses another program differently, as
#: another CPU's vector code would); 1e-5 keeps a 50-fold margin and still sees a 0.01 % change.
RTOL_IMPACTS = 1e-5


#: Verdicts of the claims table (report.md) for this study, by (claim, contact, subject).
VERDICTS = {
    (1, "undamped (paper)", "FL-like"): True,
    (1, "damped 200 N·s/m", "FL-like"): False,
    (2, "undamped (paper)", "adaptive (paper-likely) vs H∞-only"): True,
    (2, "damped 200 N·s/m", "adaptive (paper-likely) vs H∞-only"): True,
    (3, "undamped (paper)", "adaptive (paper-likely) vs H∞-only"): False,
    (3, "damped 200 N·s/m", "adaptive (paper-likely) vs H∞-only"): False,
    (4, "undamped (paper)", "adaptive (paper-likely) vs H∞-only"): True,
    (4, "damped 200 N·s/m", "adaptive (paper-likely) vs H∞-only"): True,
    (5, "undamped (paper)", "H∞-only"): True,
    (5, "undamped (paper)", "adaptive (paper-likely)"): True,
    (5, "damped 200 N·s/m", "H∞-only"): True,
    (5, "damped 200 N·s/m", "adaptive (paper-likely)"): True,
}


@pytest.fixture(scope="session")
def study():
    outcome = simulate_cases(study_cases(H.load_scenario("paper")), save_every=1)
    metrics = {c.name: {**outcome.metrics[c.name], "status": outcome.trajectories[c.name].run_status.outcome}
               for c in outcome.cases}
    return outcome.trajectories, metrics


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in RECORDED if n not in CHAOTIC])
def test_metrics_equal_the_recorded_study(study, name):
    _, metrics = study
    got, want = metrics[name], RECORDED[name]
    rtol = RTOL if name.endswith("_damped") else RTOL_IMPACTS
    assert got["status"] == want["status"] == "ok"
    # the verdict ("did its job") is derived from these numbers and the scenario's tolerances
    # (tests/test_sim.py); the fixture records the numbers
    verdict = got.pop("verdict")
    assert set(verdict) == set(VERDICT_KEYS) and verdict["within_joint_limits"] is None, verdict
    # contact held exactly when the fixture's share out of contact is 0 (no run of the study tracks
    # u1 to the default 5 mm over its last 2 s: see the fixture's rms_e_u1_last2s, 2-14 cm)
    assert verdict["contact_held"] is (want["fraction_out_of_contact"] == 0.0), verdict["notes"]
    assert set(got) == set(want), set(got) ^ set(want)
    for key, value in want.items():
        if isinstance(value, (bool, str)) or value is None:
            assert got[key] == value, f"{name}: {key}"
        else:
            np.testing.assert_allclose(got[key], value, rtol=rtol, atol=0.0, err_msg=f"{name}: {key}")


def test_the_fixture_is_the_whole_study():
    """Every run of the study is recorded (the chaotic one too, for its record)."""
    from hinfnn.workflows.paper import study_cases

    assert set(RECORDED) == {c.name for c in study_cases(H.load_scenario("paper", check=False))}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["hinf", "hinf_nn", "hinf_nn_printed", "hinf_exact", "hinf_damped",
                                  "hinf_nn_damped", "hinf_nn_printed_damped", "hinf_exact_damped"])
def test_dissipation_inequality_holds_along_hinf_and_adaptive_runs(study, name):
    """Theorems 1–2: J(t) + V(t) − V(0) ≤ ρ²∫₀ᵗ(‖f_p‖² + ‖f_f‖²) for every t (here every 0.1 ms)."""
    trajs, metrics = study
    tr = trajs[name]
    lhs = tr.J_aug + tr.V - tr.V[0]
    assert np.all(lhs <= tr.supply), f"violated at t = {tr.t[np.argmax(lhs - tr.supply)]}"
    assert metrics[name]["dissipation_holds_for_all_t"] is True


@pytest.mark.slow
def test_fl_like_controller_violates_the_inequality_it_does_not_claim(study):
    """A check that can fail: the FL-like law has no v_p, v_λ, and its runs break the inequality."""
    _, metrics = study
    assert metrics["fl"]["dissipation_holds"] is False
    assert metrics["fl_damped"]["dissipation_holds"] is False


@pytest.mark.slow
def test_claims_verdicts_as_recorded(study):
    _, metrics = study
    results = {(r.claim, r.contact, r.subject): r.held for r in evaluate(metrics, 0.2, -20.0)}
    for key, held in VERDICTS.items():
        assert results[key] is held, key
