"""The stiff-contact comparison of every arm (``hinfnn gallery --beyond``, hinfnn.workflows.stiff):
its cases, its refusals, and the paper law's runs batched with the stabilised ones. The 10-s
numbers are the gallery's (docs/beyond-the-paper.md section 7), never a test's."""

from __future__ import annotations

import pytest

import hinfnn as H
from hinfnn.controllers import ForceRate
from hinfnn.workflows import stiff as S

pytestmark = pytest.mark.xdist_group("stiff_gallery")


@pytest.fixture(scope="module")
def drum():
    return S.stiff_cases("planar3-drum", {"simulation.t_final": 0.05})


def test_the_cases_are_the_whole_matrix_but_the_refused_designs(drum):
    cases, refused = drum
    want = {f"{kind}_{variant}_{mode}_k{k:.0e}".replace("+0", "") for kind in S.STIFF_KINDS
            for variant in ("paper", "stable") for mode in S.STIFF_MODES for k in S.STIFF_STIFFNESS}
    assert {c.name for c in cases} | set(refused) == want and not {c.name for c in cases} & set(refused)
    # a 1 kHz loop cannot hold 1e6 N/m on the drum arm: the stabilised design refuses it, naming
    # the key and what would work; the paper law (κ = 0) runs there, as it does everywhere
    assert set(refused) == {"hinf_stable_1kHz_k1e6", "hinf_nn_stable_1kHz_k1e6"}
    for why in refused.values():
        assert why.startswith("controller.force_rate.stiffness_max") and "set controller.force_rate.stiffness_max <=" in why
    for c in cases:
        sc = c.scenario
        assert sc.plant.contact.damping == 0.0 and sc.plant.contact.stiffness == c.tags["stiffness"]
        assert (sc.simulation.control == "sampled") == (c.tags["mode"] == "1kHz")
        assert (c.overrides.get("controller.force_rate.kappa") == 0.0) == (c.tags["variant"] == "paper")


def test_the_paper_law_runs_in_the_stabilised_program_with_kappa_zero(drum):
    cases, _ = drum
    runs = S.build_stiff_runs(cases)
    by = {c.name: (c, r) for c, r in zip(cases, runs)}
    for kind in S.STIFF_KINDS:
        for mode in S.STIFF_MODES:
            group = [by[n] for n in by if by[n][0].kind == kind and by[n][0].tags["mode"] == mode]
            assert len({r.group_key() for _, r in group}) == 1, (kind, mode)  # one batch, one compiled program
            for c, r in group:
                kappa = float(r.controller.term(ForceRate).kappa)
                assert (kappa == 0.0) == (c.tags["variant"] == "paper")
                # the paper runs keep their own plant (the case's stiffness)
                assert r.plant.contact.stiffness == c.tags["stiffness"]
    # κ = 0 in the stabilised controller is the paper case's own design (κ = 0 there too): the
    # same torque at a pose in contact, with a force error and a moving arm
    import jax.numpy as jnp
    import numpy as np

    c, r = by["hinf_nn_paper_cont_k1e5"]
    own = c.run()
    q0 = np.asarray(own.q0)
    meas = r.plant.measure(q0, 0.1 * jnp.ones_like(q0))
    taus = [ctrl.evaluate(0.3, ctrl.init(), meas, own.reference).tau for ctrl in (own.controller, r.controller)]
    np.testing.assert_allclose(taus[0], taus[1], rtol=1e-12, atol=1e-12)


def test_gallery_beyond_refuses_an_arm_without_a_stable_scenario():
    with pytest.raises(H.ConfigError):
        S.stiff_cases("paper-stable-does-not-exist")
