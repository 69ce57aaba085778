"""What a designed controller is, as plain numbers: for reports, ``metrics.json`` and
``hinfnn show`` / ``hinfnn design``."""

from __future__ import annotations

import numpy as np

from ..errors import DesignError
from .gains import theorem1_bounds
from .riccati import design_riccati
from . import terms as T


def _f(x):
    a = np.asarray(x, dtype=float)
    return a.tolist() if a.ndim else float(a)


def design_summary(ctrl) -> dict:
    """The resolved design of a controller: kind and terms, every gain (β_λ resolved), P_p and
    the Riccati residual, v_p's gains R_p⁻¹B_pᵀP_p, Theorem 1's bounds with their margins, the
    networks' layout. JSON-ready."""
    g = ctrl.gains
    m = ctrl.m
    rho, alpha_z, alpha_lam, beta = float(g.rho), float(g.alpha_z), float(g.alpha_lam), float(g.beta_lam)
    P = np.asarray(ctrl.P_p, dtype=float)
    out = {
        "kind": ctrl.kind,
        "terms": [type(t).__name__ for t in ctrl.terms],
        "augmented": bool(ctrl.augmented),
        "gains": {"K_p": _f(g.K_p), "K_v": _f(g.K_v), "rho": rho, "mu_z": float(g.mu_z), "alpha_z": alpha_z,
                  "alpha_lam": alpha_lam, "beta_lam": beta, "gamma_1": float(g.gamma_1),
                  "gamma_2": float(g.gamma_2), "Q_p": _f(g.Q_p), "R_p": _f(g.R_p)},
        "P_p": P.tolist(),
    }
    alpha_bound, beta_bound = theorem1_bounds(rho, alpha_z, alpha_lam)
    out["bounds"] = {
        "alpha_lam": {"value": alpha_lam, "bound": alpha_bound, "margin": alpha_lam - alpha_bound,
                      "rule": "alpha_lam > 2 rho^2 / alpha_z (Theorem 1; Remark 3)"},
        "beta_lam": {"value": beta, "bound": beta_bound, "margin": beta - beta_bound,
                     "rule": "beta_lam >= alpha_lam alpha_z / (2 rho^2) - 1 > 0 (Theorem 1; Remark 3)"},
    }
    if np.all(np.isfinite(P)):
        s_p = P[m:]  # B_pᵀ P_p: the drive of v_p and of F_p's update, per unit x_p
        R = np.atleast_2d(np.asarray(g.R_p, dtype=float))
        out["v_p_gains"] = np.linalg.solve(R, s_p).tolist()  # v_p = −v_p_gains · x_p
        out["s_p_gains"] = s_p.tolist()
        try:
            sol = design_riccati(g, "40" if ctrl.augmented else "35")
            out["riccati"] = {"equation": sol.equation, "residual": sol.residual, "min_eig_P": sol.min_eig_P,
                              "closed_loop_eigs": [[float(e.real), float(e.imag)] for e in sol.closed_loop_eigs],
                              "remark4_holds": sol.remark4_holds}
        except DesignError as err:
            out["riccati"] = {"error": str(err)}
    else:
        out["riccati"] = {"error": "no stabilising solution for these gains (not used by this law)"}
    nets = {}
    for t in ctrl.terms:
        if isinstance(t, (T.PositionNetwork, T.ForceNetwork)):
            c = np.asarray(t.network.centres)
            if c.ndim == 1:  # one hidden layer shared by the outputs (TanhNetwork)
                nets[t.key] = {"units": int(c.size), "outputs": t.network.n_out, "first_centre": float(c[0]),
                               "last_centre": float(c[-1]),
                               "step": float(c[1] - c[0]) if c.size > 1 else None,
                               "slope": float(t.network.slope), "w_a": _f(t.network.w_a), "w_b": _f(t.network.w_b),
                               "radius": float(t.network.radius) if t.network.project else None}
            else:  # one hidden layer per coordinate (CoordinateNetwork): per-coordinate lists
                nets[t.key] = {"units": int(c.shape[1]), "outputs": t.network.n_out, "per_coordinate": True,
                               "first_centre": c[:, 0].tolist(), "last_centre": c[:, -1].tolist(),
                               "step": (c[:, 1] - c[:, 0]).tolist() if c.shape[1] > 1 else None,
                               "slope": _f(t.network.slope), "w_a": _f(t.network.w_a), "w_b": _f(t.network.w_b),
                               "radius": float(t.network.radius) if t.network.project else None}
    for t in ctrl.terms:
        if isinstance(t, (T.PositionNetwork, T.ForceNetwork)) and t.adaptation is not None:
            a = t.adaptation
            nets[t.key]["adaptation"] = {"dead_zone": float(a.zone), "leak": float(a.leak), "e_gain": float(a.e_gain),
                                         "drive_noise_rms": float(a.noise)}
    if nets:
        out["networks"] = nets
    for t in ctrl.terms:
        if isinstance(t, T.ForceRate):
            out["force_rate"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in t.design}
            out["force_rate"].update(kappa=float(t.kappa), tau_f=float(t.tau_f))
    out["singularity_stop"] = float(ctrl.sigma_stop)
    return out
