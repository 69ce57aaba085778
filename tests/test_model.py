"""Model layer: arm dynamics, kinematics, surfaces and the reduced-order model (eqs. 1–14)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import hinfnn as H
from conftest import PAPER_SETUP
from hinfnn.model import reduced_model


def call(obj, name, *args):
    """obj.name(*args), jit-compiled once per (type, name): hypothesis examples then run fast."""
    return np.asarray(_jitted(name)(obj, *args))


_JIT = {}


def _jitted(name):
    if name not in _JIT:
        _JIT[name] = jax.jit(lambda obj, *a: getattr(obj, name)(*a))
    return _JIT[name]

angles = st.floats(-np.pi, np.pi)
rates = st.floats(-3.0, 3.0)
state = st.tuples(angles, angles, rates, rates).map(lambda v: (np.array(v[:2]), np.array(v[2:])))
masses = st.floats(0.2, 5.0)
lengths = st.floats(0.3, 2.0)
arm_params = st.tuples(masses, masses, lengths, lengths).map(
    lambda v: H.TwoLinkArm(m1=v[0], m2=v[1], l1=v[2], l2=v[3]))


@given(arm=arm_params, s=state)
def test_M_dot_minus_2C_is_skew_by_finite_differences(arm, s):
    """docs/paper-conventions.md erratum: C(2,1) = +q̇1. Ṁ by central differences along q̇, not autodiff."""
    q, qd = s
    eps = 1e-6
    M_dot = (call(arm, "M", q + eps * qd) - call(arm, "M", q - eps * qd)) / (2 * eps)
    N = M_dot - 2 * call(arm, "C", q, qd)
    scale = 1.0 + np.abs(M_dot).max()
    np.testing.assert_allclose(N + N.T, 0.0, atol=1e-7 * scale)


def test_printed_coriolis_sign_is_not_skew(true_arm):
    """The paper's printed C (entry (2,1) = −q̇1) breaks skew-symmetry: the test above would fail."""
    q, qd = np.array([0.3, -0.9]), np.array([1.1, -0.4])
    printed = np.asarray(true_arm.C(q, qd)).copy()
    printed[1, 0] *= -1
    N = np.asarray(true_arm.M_dot(q, qd)) - 2 * printed
    assert np.abs(N + N.T).max() > 0.1


@given(arm=arm_params, s=state)
def test_M_symmetric_positive_definite(arm, s):
    M = call(arm, "M", s[0])
    np.testing.assert_allclose(M, M.T, rtol=0, atol=1e-14)
    assert np.linalg.eigvalsh(M).min() > 0


@given(arm=arm_params, s=state)
def test_closed_form_equals_generic_autodiff_arm(arm, s):
    """Sec. VI closed forms (M, C, G, h, J, J̇) = the generic point-mass arm's autodiff path."""
    q, qd = s
    gen = arm.to_generic()
    for name, args in (("M", (q,)), ("C", (q, qd)), ("G", (q,)), ("h", (q,)), ("J", (q,)),
                       ("J_dot", (q, qd))):
        a = call(arm, name, *args)
        b = call(gen, name, *args)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12, err_msg=name)
    # and the base class's autodiff J, J̇, C, G of the closed-form h, M, U
    for name, args in (("J", (q,)), ("J_dot", (q, qd)), ("C", (q, qd)), ("G", (q,))):
        np.testing.assert_allclose(call(arm, name, *args), _base_call(name, arm, *args), atol=1e-12,
                                   err_msg=name)


@jax.jit
def _base_all(arm, q, qd):
    Arm = H.model.Arm
    return dict(J=Arm.J(arm, q), J_dot=Arm.J_dot(arm, q, qd), C=Arm.C(arm, q, qd), G=Arm.G(arm, q))


def _base_call(name, arm, *args):
    q = args[0]
    qd = args[1] if len(args) > 1 else jnp.zeros_like(q)
    return np.asarray(_base_all(arm, q, qd)[name])


@given(s=state)
def test_J_dot_qd_matches_finite_difference_of_J(s):
    """J̇ q̇ from autodiff (generic arm) equals (J(q + ε q̇) − J(q − ε q̇))/(2ε) q̇."""
    q, qd = s
    arm = H.PlanarPointMassArm(masses=jnp.array([1.0, 0.7, 0.4]), lengths=jnp.array([0.8, 0.6, 0.3]),
                               n=3)
    q3 = np.array([q[0], q[1], 0.5 * q[0]])
    qd3 = np.array([qd[0], qd[1], -qd[0]])
    eps = 1e-6
    fd = (call(arm, "J", q3 + eps * qd3) - call(arm, "J", q3 - eps * qd3)) / (2 * eps)
    np.testing.assert_allclose(call(arm, "J_dot", q3, qd3) @ qd3, fd @ qd3, atol=1e-7)


def test_three_link_generic_arm_is_consistent():
    """n = 3: M SPD, Ṁ − 2C skew, G = ∂U/∂q by finite differences."""
    arm = H.PlanarPointMassArm(masses=jnp.array([1.0, 0.7, 0.4]), lengths=jnp.array([0.8, 0.6, 0.3]),
                               n=3)
    q, qd = np.array([0.2, -0.7, 0.9]), np.array([0.5, 1.2, -0.8])
    N = np.asarray(arm.M_dot(q, qd) - 2 * arm.C(q, qd))
    np.testing.assert_allclose(N + N.T, 0, atol=1e-12)
    eps = 1e-6
    G_fd = [(arm.potential(q + eps * e) - arm.potential(q - eps * e)) / (2 * eps) for e in np.eye(3)]
    np.testing.assert_allclose(arm.G(q), G_fd, atol=1e-7)


# --- surfaces ------------------------------------------------------------------------------------

@pytest.mark.parametrize("scaling", ["paper", "unit"])
def test_inclined_line_quantities(scaling):
    """docs/paper-conventions.md sign convention: Â = [tan δ, −1] (paper) or [sin δ, −cos δ] (unit), Γ = tan δ."""
    d = 0.6
    s = H.InclinedLine(delta=d, d_G=0.8, scaling=scaling)
    x = np.array([1.3, 0.2])
    A = np.asarray(s.A_hat(x))
    expected = [np.tan(d), -1.0] if scaling == "paper" else [np.sin(d), -np.cos(d)]
    np.testing.assert_allclose(A, [expected], atol=1e-15)
    np.testing.assert_allclose(s.Gamma(np.array([1.3])), [[np.tan(d)]], atol=1e-14)
    # eq. (4): Σ + Π Γ = 0
    np.testing.assert_allclose(s.Sigma(x) + s.Pi(x) @ s.Gamma(x[:1]), 0, atol=1e-14)
    # inside the material θ > 0: below the line
    assert s.theta(np.array([1.3, (1.3 - 0.8) * np.tan(d) - 0.01]))[0] > 0
    # the generic implicit-function path of the base class agrees with the closed forms
    np.testing.assert_allclose(H.model.Surface.Omega(s, x[:1]), s.Omega(x[:1]), atol=1e-13)
    np.testing.assert_allclose(H.model.Surface.Gamma(s, x[:1]), s.Gamma(x[:1]), atol=1e-13)


def _circle_theta(x, params):
    """A circular bump: positive inside the disc of radius params[2] centred at params[:2]."""
    return params[2] ** 2 - (x[0] - params[0]) ** 2 - (x[1] - params[1]) ** 2


def circle_surface():
    return H.ImplicitSurface(params=jnp.array([1.0, -1.5, 2.2]), theta_fn=_circle_theta)


def test_implicit_surface_omega_gamma_by_finite_differences():
    s = circle_surface()
    x1 = np.array([1.4])
    om = float(s.Omega(x1)[0])
    np.testing.assert_allclose(s.theta(np.array([1.4, om])), 0, atol=1e-12)
    eps = 1e-6
    fd = (float(s.Omega(x1 + eps)[0]) - float(s.Omega(x1 - eps)[0])) / (2 * eps)
    np.testing.assert_allclose(s.Gamma(x1), [[fd]], rtol=1e-7)
    # Ṡ along ẋ1 by finite differences of S
    x1d = np.array([0.7])
    fdS = (np.asarray(s.S(x1 + eps * x1d)) - np.asarray(s.S(x1 - eps * x1d))) / (2 * eps)
    np.testing.assert_allclose(s.S_dot(x1, x1d), fdS, atol=1e-7)


# --- reduced-order model ---------------------------------------------------------------------------

@jax.jit
def _reduced_identity_residual(arm, surface, q, qd, tau, lam):
    """Simulate the exact model one instant (F = Âᵀλ) and return both sides of eq. (9)."""
    x = arm.h(q)
    A = surface.A_hat(x)
    F = A.T @ lam
    qdd = arm.forward_dynamics(q, qd, tau - arm.J(q).T @ F)
    xd = arm.J(q) @ qd
    xdd = arm.J(q) @ qdd + arm.J_dot(q, qd) @ qd
    m = surface.m
    S = surface.S(x[:m])
    Sd = surface.S_dot(x[:m], xd[:m])
    ud = jnp.linalg.solve(S, xd)
    udd = jnp.linalg.solve(S, xdd - Sd @ ud)
    rm = reduced_model(arm, surface, q, qd)
    lhs = rm.M_bar @ udd + rm.C_bar @ ud + rm.G_bar + S.T @ A.T @ lam
    rhs = rm.B_bar @ tau
    return lhs, rhs, rm, S, A


@pytest.mark.parametrize("surface_kind", ["paper", "unit", "circle"])
@given(s=state, tau=st.tuples(st.floats(-50, 50), st.floats(-50, 50)), lam=st.floats(-100, 100))
def test_reduced_order_identity_on_exact_model(surface_kind, s, tau, lam):
    """Eq. (9) with docs/paper-conventions.md's corrections: M̄ü + C̄u̇ + Ḡ + SᵀÂᵀλ = B̄τ, and SᵀÂᵀ = [0; Πᵀ]."""
    q, qd = s
    arm = PAPER_SETUP.plant.arm  # the paper's true arm
    if surface_kind == "circle":
        surface = circle_surface()
    else:
        surface = H.InclinedLine(delta=0.79, d_G=0.8, scaling=surface_kind)
    if abs(np.linalg.det(call(arm, "J", q))) < 1e-2:
        return  # (A1): Ĵ nonsingular
    if surface_kind == "circle":
        # put the end-effector ON the surface (eq. 4 holds there), Π nonsingular (A3)
        x1 = call(arm, "h", q)[:1]
        x = np.concatenate([x1, call(surface, "Omega", x1)])
        if not np.all(np.isfinite(x)) or abs(call(surface, "Pi", x)[0, 0]) < 0.3:  # (A3), (A4)
            return
        q = call(arm, "inverse_kinematics_closed", x)
        if not np.all(np.isfinite(q)) or abs(np.linalg.det(call(arm, "J", q))) < 1e-2:
            return
    lhs, rhs, rm, S, A = _reduced_identity_residual(arm, surface, q, qd, jnp.array(tau), jnp.array([lam]))
    lhs, rhs = np.asarray(lhs), np.asarray(rhs)
    scale = 1.0 + np.abs(rhs).max() + np.abs(lam)
    np.testing.assert_allclose(lhs, rhs, atol=1e-9 * scale)
    StAt = np.asarray(S.T @ A.T)
    np.testing.assert_allclose(StAt[:1], 0, atol=1e-10)
    np.testing.assert_allclose(StAt[1:], np.asarray(rm.Pi).T, atol=1e-12)


def test_printed_reduced_model_fails_identity():
    """The printed M̄ = SᵀĴ⁻ᵀM̂Ĵ⁻ᵀS and Ḡ = SᵀĴ⁻¹Ĝ do not satisfy eq. (9): the test above catches them."""
    arm = PAPER_SETUP.plant.arm
    surface = H.InclinedLine(delta=0.79, d_G=0.8)
    q, qd = jnp.array([0.7, -0.9]), jnp.array([0.3, -0.2])
    tau, lam = jnp.array([10.0, -4.0]), jnp.array([30.0])
    lhs, rhs, rm, S, A = _reduced_identity_residual(arm, surface, q, qd, tau, lam)
    rhs = np.asarray(rhs)
    Ji = jnp.linalg.inv(arm.J(q))
    M_printed = S.T @ Ji.T @ arm.M(q) @ Ji.T @ S
    G_printed = S.T @ Ji @ arm.G(q)
    x = arm.h(q)
    xd = arm.J(q) @ qd
    ud = jnp.linalg.solve(S, xd)
    qdd = arm.forward_dynamics(q, qd, tau - arm.J(q).T @ (A.T @ lam))
    udd = jnp.linalg.solve(S, arm.J(q) @ qdd + arm.J_dot(q, qd) @ qd)
    bad = M_printed @ udd + rm.C_bar @ ud + G_printed + S.T @ A.T @ lam
    assert np.abs(np.asarray(bad) - rhs).max() > 1e-2
    assert x.shape == (2,)


def test_reduced_model_is_batchable(true_arm, true_surface):
    """vmap over states equals a Python loop over them."""
    qs = jnp.array([[0.7, -0.6], [0.9, -1.0], [0.5, -0.3]])
    qds = jnp.array([[0.1, 0.2], [-0.3, 0.5], [0.0, 0.0]])
    batched = jax.vmap(lambda q, qd: reduced_model(true_arm, true_surface, q, qd).M_bar)(qs, qds)
    for i in range(3):
        np.testing.assert_allclose(batched[i], reduced_model(true_arm, true_surface, qs[i], qds[i]).M_bar,
                                   rtol=1e-14)
