"""The least force error any law holds on a noisy, late force sensor, against what a run measured
(docs/beyond-the-paper.md, section 12, "The least force error any law holds").

For a scenario's run with an ideal sensor (its sensor's delay kept, the law designed for the noisy
sensor, the networks not projected: the law the linearised loop models) the force disturbance the
arm meets is identified (:func:`hinfnn.controllers.sensing.fit_force_disturbance`: a first-order
Gauss–Markov force held with the command that, through the law's linearised loop at the true
contact, reproduces the run's TRUE force-error spectrum), and the least RMS true force error any
law holds at the sensor's noise and delay against it is computed
(:func:`hinfnn.controllers.sensing.force_error_bound`, the worst over the path's normal masses).

    PYTHONPATH=src python benchmarks/force_error_bound.py IDEAL_RUN_DIR [NOISY_RUN_DIR] \
        [--noise 1] [--delay 1] [--m-n LO HI] [--json OUT]

IDEAL_RUN_DIR: `hinfnn run SCENARIO --set plant.sensor.force_noise=0 --set controller.sensor.noise=1
--set controller.adaptation.robust=none --set controller.kind=hinf_nn ...`; NOISY_RUN_DIR (optional)
the run at the noise whose measured error is set beside the bound.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

from hinfnn.controllers import sensing as S


def _run(path, kind):
    m = json.load(open(f"{path}/metrics.json"))
    z = np.load(f"{path}/trajectory.npz")
    run = next(r for r in m["runs"] if r.get("controller") == kind or r["name"].endswith(kind))
    return m, run, z


def _g_f(net, gamma_2):
    """γ2‖ξ_f(0, 0)‖² of the tanh network the design record describes (its integral gain)."""
    c = np.arange(net["first_centre"], net["last_centre"] + 0.5 * net["step"], net["step"])
    xi = np.tanh(np.asarray(net["slope"], float).ravel()[0] * (0.0 - c))
    return float(gamma_2) * float(xi @ xi)


def identify(ideal, kind="hinf_nn", m_n=None, t_skip=2.0):
    m, run, z = _run(ideal, kind)
    d = run["design"]
    g = d["gains"]
    fr = d.get("force_rate") or {}
    sd = fr.get("sensing") or {}
    scen = m["scenario"]
    k = float(scen["plant"]["contact"]["stiffness"])
    c = float(scen["plant"]["contact"].get("damping", 0.0))
    lo, hi = (fr["m_n_min"], fr["m_n_max"]) if m_n is None else m_n
    h = float(scen["simulation"]["control_period"])
    delay = int(scen["plant"]["sensor"]["delay"])
    g_f = _g_f(d["networks"]["theta_f"], g["gamma_2"]) if "networks" in d else 0.0
    order, fc, kappa = int(sd.get("order", 0) or 0), sd.get("cutoff_hz"), float(fr.get("kappa", 0.0))
    source = fr.get("source", "force") if kappa else "force"
    filt = S.butterworth_matrices(order, fc, h) if order else None
    filt = None if filt is None else (filt[0], filt[1], filt[2], filt[3])
    m_mid = math.sqrt(lo * hi)
    w0 = math.sqrt(k / m_mid)
    zeta_c = c / (2.0 * math.sqrt(k * m_mid))
    extra = dict(source="velocity", rate_scale=float(fr["stiffness_max"]) / k) if source == "velocity" else {}
    Phi, _, _, _ = S.sensed_force_loop(w0 * h, 0.5 * float(g["beta_lam"]), kappa, h, float(g["mu_z"]),
                                       float(g["alpha_z"]), g_f, delay, filt, damping_ratio=zeta_c, **extra)
    t = z[f"{kind}/t"]
    e = (z[f"{kind}/normal_force"] - z[f"{kind}/lam_d"][:, 0])[t >= t_skip]
    D, fd = S.fit_force_disturbance(e, h, Phi, S.command_column(Phi, w0 * h, h, zeta_c))
    return dict(stiffness=k, damping=c, m_n=(lo, hi), period=h, delay=delay, kappa=kappa, order=order,
                cutoff_hz=fc, source=source, g_f=g_f, disturbance=D, disturbance_hz=fd,
                ideal_rms=float(np.sqrt(np.mean(e * e))),
                ideal_rms_last2s=run["metrics"]["rms_normal_force_error_last2s"])


def bound(ident, noise, delay=None, rate_noise=None):
    k, c, h = ident["stiffness"], ident["damping"], ident["period"]
    out = []
    for m in ident["m_n"]:
        out.append(S.force_error_bound(omega0=math.sqrt(k / m), h=h, noise=noise,
                                       delay=ident["delay"] if delay is None else delay,
                                       disturbance=ident["disturbance"], disturbance_hz=ident["disturbance_hz"],
                                       damping_ratio=c / (2.0 * math.sqrt(k * m)), rate_noise=rate_noise))
    return max(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ideal")
    ap.add_argument("noisy", nargs="?")
    ap.add_argument("--kind", default="hinf_nn")
    ap.add_argument("--noise", type=float, default=1.0)
    ap.add_argument("--m-n", type=float, nargs=2, default=None)
    ap.add_argument("--json")
    a = ap.parse_args()
    ident = identify(a.ideal, a.kind, a.m_n)
    ident["bound_sigma0"] = bound(ident, 0.0)
    ident["noise"] = a.noise
    ident["bound"] = bound(ident, a.noise)
    ident["bound_with_rate"] = bound(ident, a.noise, rate_noise=0.0)
    if a.noisy:
        ident["measured"] = _run(a.noisy, a.kind)[1]["metrics"]["rms_normal_force_error_last2s"]
    print(json.dumps(ident, indent=1))
    if a.json:
        json.dump(ident, open(a.json, "w"), indent=1)


if __name__ == "__main__":
    main()
