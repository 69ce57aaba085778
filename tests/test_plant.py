"""Plant: contact, disturbance, initial pose (docs/paper-conventions.md conventions)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import hinfnn as H
from conftest import U1_0


def test_initial_pose_puts_both_end_effectors_on_their_surfaces(paper_plant, nominal_arm, nominal_surface):
    """docs/paper-conventions.md: u1(0) = 1.6902, true end-effector on the true surface, elbow up: q ≈ (π/4, −0.60127),
    and the nominal end-effector then lies on the nominal surface too."""
    q0 = np.asarray(paper_plant.initial_q(U1_0))
    np.testing.assert_allclose(q0, [np.pi / 4, -0.60127], atol=2e-5)
    x_true = paper_plant.arm.h(q0)
    assert abs(float(paper_plant.surface.signed_distance(x_true))) < 1e-12
    assert float(x_true[0]) == pytest.approx(U1_0, abs=1e-12)
    x_nom = nominal_arm.h(q0)
    assert abs(float(nominal_surface.theta(x_nom)[0])) < 1e-5
    assert float(x_nom[0]) == pytest.approx(U1_0, abs=1e-5)
    F, f_n, p = paper_plant.contact_state(q0, jnp.zeros(2))
    assert float(f_n) == 0.0


def test_lambda_positive_when_pushed_1mm_into_the_surface(paper_plant, nominal_arm, nominal_surface):
    ctrl = H.HinfController.design(nominal_arm, nominal_surface)
    x = paper_plant.arm.h(paper_plant.initial_q(U1_0))
    n = paper_plant.surface.inward_normal(x)
    q1 = paper_plant.arm.inverse_kinematics_closed(x + 1e-3 * n)
    F, f_n, p = paper_plant.contact_state(q1, jnp.zeros(2))
    assert float(p) == pytest.approx(1e-3, rel=1e-9)
    assert float(f_n) == pytest.approx(100.0, rel=1e-9)  # k p = 1e5 · 1e-3
    _, _, lam = ctrl.observe(H.Measurement(q=q1, qd=jnp.zeros(2), force=F))
    assert float(lam[0]) > 0
    # with the paper's scaling λ = Â F/(ÂÂᵀ) is the normal force times cos δ̂ (up to the 0.5° tilt)
    assert float(lam[0]) == pytest.approx(100.0 * np.cos(np.pi / 4), rel=1e-2)


def test_contact_is_unilateral_and_damping_never_pulls():
    c = H.PenaltyContact(stiffness=1e5, damping=200.0)
    assert float(c.normal_force(-1e-3, 0.0)) == 0.0
    assert float(c.normal_force(1e-4, -1.0)) == 0.0  # k p + c ṗ = 10 − 200 < 0: clipped
    assert float(c.normal_force(1e-3, 0.1)) == pytest.approx(120.0)


def test_square_wave_phase_and_values():
    d = H.SquareWave(amplitude=jnp.array([3.0, 3.0]), period=1.0, phase=0.0)
    np.testing.assert_allclose(d(0.25), [3, 3])
    np.testing.assert_allclose(d(0.75), [-3, -3])
    np.testing.assert_allclose(d(1.25), [3, 3])
    d2 = H.SquareWave(amplitude=jnp.array([3.0, -1.0]), period=2.0, phase=0.5)
    np.testing.assert_allclose(d2(0.25), [-3, 1])  # before the phase: the previous half-period
    np.testing.assert_allclose(d2(0.75), [3, -1])
