"""The JAX closed loop against the plain NumPy implementation (tests/numpy_oracle.py), written
independently from the paper's matrix forms, over the first 0.2 s of the paper scenario."""

from __future__ import annotations

import numpy as np
import pytest

import hinfnn as H
from conftest import PAPER_SETUP, U1_0
import numpy_oracle as oracle

T, DT = 0.2, 1e-4
KINDS = {
    "fl": lambda arm, surf, preset: H.FeedbackLinearization.design(arm, surf),
    "hinf": lambda arm, surf, preset: H.HinfController.design(arm, surf),
    "hinf_nn": lambda arm, surf, preset: H.HinfNNController.design(arm, surf, centre_preset=preset),
}


def _close(name, a, b, rtol=1e-8):
    """|a − b| ≤ rtol · max|b| per component over the run (relative to the signal's scale)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = np.maximum(np.abs(b).max(axis=0), 1e-12)
    err = np.abs(a - b).max(axis=0) / scale
    assert np.all(err < rtol), f"{name}: max relative difference {err.max():.3g}"


@pytest.mark.parametrize("kind,preset,step,scaling", [
    ("fl", "paper-likely", 0.5, "paper"),
    ("hinf", "paper-likely", 0.5, "paper"),
    ("hinf_nn", "paper-likely", 0.5, "paper"),
    ("hinf_nn", "paper-printed", 0.05, "paper"),
    ("hinf_nn", "paper-likely", 0.5, "unit"),
])
def test_jax_matches_numpy_oracle(kind, preset, step, scaling, true_arm, nominal_arm, paper_plant):
    ref = oracle.simulate(kind, {"centre_step_f": step, "scaling": scaling}, t_final=T, dt=DT)
    surf = H.InclinedLine(delta=np.pi / 4, d_G=0.8, scaling=scaling)
    ctrl = KINDS[kind](nominal_arm, surf, preset)
    tr = H.simulate(paper_plant, ctrl, H.CosineReference.paper(), u1_0=U1_0, t_final=T, dt=DT, save_every=1)
    y = ref["y"]
    np.testing.assert_allclose(tr.t, ref["t"], rtol=0, atol=1e-15)
    _close("q", tr.q, y[:, 0:2])
    _close("qd", tr.qd, y[:, 2:4])
    _close("z", tr.z[:, 0], y[:, 4])
    _close("J", tr.J, y[:, -1])
    _close("tau", tr.tau, ref["tau"])
    _close("lam", tr.lam[:, 0], ref["lam"])
    _close("u1", tr.u1[:, 0], ref["u1"])
    if kind == "hinf_nn":
        _close("theta_p_norm", tr.theta_p_norm, np.linalg.norm(y[:, 5:45], axis=1))
        _close("theta_f_norm", tr.theta_f_norm, np.linalg.norm(y[:, 45:165], axis=1))
        _close("theta_p(T)", tr.final["theta_p"], y[-1, 5:45])
        _close("theta_f(T)", tr.final["theta_f"], y[-1, 45:165])


def test_oracle_riccati_and_initial_pose_agree():
    np.testing.assert_allclose(oracle.design_P(oracle.PAPER), H.controllers.design_riccati(
        H.Gains.paper().normalized(1, 1)).P, rtol=1e-10)
    # the shipped scenario file's true plant against the oracle's own transcription of the paper
    np.testing.assert_allclose(PAPER_SETUP.q0, oracle.initial_q(oracle.PAPER), atol=1e-12)
