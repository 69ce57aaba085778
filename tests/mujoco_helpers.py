"""Helpers of the MuJoCo tests (tests/test_mujoco*.py)."""

from __future__ import annotations

import numpy as np


def fit_oscillation(t, p):
    """p(t) = p_eq + e^{−σt}(a cos ω_d t + b sin ω_d t) by least squares, guessed from the data
    (mean of the second half, zero crossings). Returns p_eq, ω_n, ζ and the worst residual."""
    from scipy.optimize import least_squares

    p_eq0 = p[len(p) // 2:].mean()
    s = np.sign(p - p_eq0)
    crossings = t[1:][s[1:] != s[:-1]]
    wd0 = np.pi / np.median(np.diff(crossings))

    def res(th):
        p_eq, sig, wd, a, b = th
        return p_eq + np.exp(-sig * t) * (a * np.cos(wd * t) + b * np.sin(wd * t)) - p

    fit = least_squares(res, [p_eq0, 0.0, wd0, p[0] - p_eq0, 0.0], x_scale="jac")
    p_eq, sig, wd, _, _ = fit.x
    wn = float(np.hypot(wd, sig))
    return float(p_eq), wn, float(sig / wn), float(np.abs(fit.fun).max())
