"""Riccati-like equations (35) and (40) and the design checks (Theorem 1, Remarks 1, 3, 4)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

import hinfnn as H
from hinfnn.controllers.riccati import design_riccati, riccati_residual, riccati_weight


def paper_gains(**kw):
    return H.Gains(**kw).normalized(1, 1)


def test_eq35_paper_numbers():
    sol = design_riccati(paper_gains(), "35")
    np.testing.assert_allclose(sol.P, [[1.30300, 0.02775], [0.02775, 0.05840]], atol=5e-6)
    assert sol.residual < 1e-10
    assert sol.min_eig_P > 0
    assert np.all(sol.closed_loop_eigs.real < 0)


def test_eq35_agrees_with_scipy_care():
    """Second method: with m = 1, eq. (35) is a standard CARE with R_eff = (2/R_p − 1/ρ²)⁻¹."""
    g = paper_gains()
    R_eff = 1.0 / (2.0 / 0.495 - 1.0 / 0.36)
    P = scipy.linalg.solve_continuous_are(g.A_p(), g.B_p(), np.eye(2), np.array([[R_eff]]))
    np.testing.assert_allclose(design_riccati(g, "35").P, P, rtol=1e-12, atol=1e-14)


def test_eq40_indefinite_weight_still_solvable():
    """docs/paper-conventions.md: (40) has an indefinite quadratic term for the paper's numbers and still a
    stabilising P ≻ 0, found through the Hamiltonian's stable subspace."""
    g = paper_gains()
    W = riccati_weight(g.R_p, g.rho, "40")
    assert W[0, 0] < 0
    sol = design_riccati(g, "40")
    assert sol.min_eig_P > 0 and sol.residual < 1e-10
    res = riccati_residual(g.A_p(), g.B_p(), np.asarray(g.Q_p), W, sol.P)
    assert np.abs(res).max() < 1e-10
    assert np.all(np.linalg.eigvals(g.A_p() - g.B_p() @ W @ g.B_p().T @ sol.P).real < 0)


def test_rho_with_no_stabilising_solution_is_a_design_error():
    """ρ = 0.1 is below the H∞ norm of Q^½(sI − A_p)⁻¹B_p (≈ 0.115): no stabilising P."""
    with pytest.raises(H.DesignError) as err:
        H.HinfController.design(H.TwoLinkArm(1.5, 1.0, 1.0, 1.0), H.InclinedLine(np.pi / 4),
                                H.Gains(rho=0.1))
    assert err.value.key == "rho"
    assert "no stabilising solution" in str(err.value)
    assert "0.4975" in str(err.value)  # Remark 4's sufficient bound sqrt(R_p/2)


def test_remark4_condition_is_only_sufficient():
    """docs/paper-conventions.md erratum: 2ρ²I > R_p is not necessary. ρ = 0.45 violates it, yet (35) has a
    stabilising P ≻ 0 (A_p is Hurwitz)."""
    g = paper_gains(rho=0.45, beta_lam=1.0 / 0.45**2)
    assert 2 * 0.45**2 < 0.495
    sol = design_riccati(g, "35")
    assert not sol.remark4_holds
    assert sol.min_eig_P > 0 and sol.residual < 1e-10


def test_beta_lam_below_bound():
    bound = 1.0 / 0.36 - 1.0
    with pytest.raises(H.DesignError) as err:
        paper_gains(beta_lam=1.5)
    assert err.value.key == "beta_lam"
    assert err.value.bound == pytest.approx(bound)
    assert f"{bound:g}" in str(err.value)
    assert paper_gains().beta_lam == pytest.approx(bound)  # default: the minimum


def test_remark3_bounds_for_other_alpha_z():
    """Remark 3: α_λ > 2ρ²/α_z and β_λ ≥ α_λ α_z/(2ρ²) − 1."""
    g = paper_gains(alpha_z=4.0)
    assert g.beta_lam == pytest.approx(4.0 / (2 * 0.36) - 1)
    with pytest.raises(H.DesignError) as err:
        paper_gains(alpha_z=0.5)  # needs alpha_lam > 1.44
    assert err.value.key == "alpha_lam"


def test_alpha_lam_not_above_rho_squared():
    with pytest.raises(H.DesignError) as err:
        paper_gains(alpha_lam=0.3)
    assert err.value.key == "alpha_lam" and err.value.bound == pytest.approx(0.36)


def test_R_p_printed_as_2x2_is_rejected_with_the_erratum():
    with pytest.raises(H.DesignError) as err:
        paper_gains(R_p=np.diag([0.495, 0.495]))
    assert err.value.key == "R_p"
    assert "misprint" in str(err.value)


@pytest.mark.parametrize("name,value", [("rho", -0.6), ("mu_z", 0.0), ("K_p", -1.0),
                                        ("K_v", np.nan), ("gamma_1", np.inf), ("Q_p", -np.eye(2)),
                                        ("R_p", -0.1), ("alpha_z", 0.0)])
def test_invalid_gains(name, value):
    with pytest.raises(H.DesignError) as err:
        paper_gains(**{name: value})
    assert err.value.key == name
