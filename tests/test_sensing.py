"""The force measurement path designed for the sensor (hinfnn.controllers.sensing, the noise gains
of hinfnn.analysis): the discrete filter against its transfer function, the loop model with
delay, filter and network, the design's choice and refusal, the filter inside the law, and the
linearised sampled loop with a delayed, noisy sensor against simulations."""

from __future__ import annotations

import dataclasses
import inspect
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import signal

import hinfnn as H
from hinfnn import analysis as A
from hinfnn.controllers import force_rate as fr
from hinfnn.controllers import sensing as S
from hinfnn.errors import ConfigError, DesignError
from hinfnn.plant.instruments import Sensor


@pytest.mark.parametrize("order", [1, 2])
def test_force_filter_is_the_butterworth_transfer_function(order):
    """The filter stepped as the controller steps it (x + h·rate, output C x + D u) is
    ``lfilter`` of SciPy's Butterworth coefficients on a random input (to 1e-12), its gain is 1 at
    DC (the rest state) and 1/√2 at the cutoff (the Butterworth property, from the state space)."""
    h, fc = 1e-3, 60.0
    f = S.butterworth(order, fc, h)
    A_, B, C, D = f.matrices()
    u = np.random.default_rng(0).normal(size=400)
    x, y = np.zeros(order), []
    for uk in u:
        y.append(float(np.asarray(f.output(np.array([uk]), x))[0]))
        x = x + h * np.asarray(f.rate(np.array([uk]), x))
    b, a = signal.butter(order, fc, fs=1 / h)
    assert np.max(np.abs(np.array(y) - signal.lfilter(b, a, u))) < 1e-12
    rest = np.asarray(f.rest(np.array([3.0])))
    assert float(np.asarray(f.output(np.array([3.0]), rest))[0]) == pytest.approx(3.0, rel=1e-12)
    zc = np.exp(2j * np.pi * fc * h)
    H_c = C @ np.linalg.solve(zc * np.eye(order) - A_, B) + D
    assert abs(H_c) == pytest.approx(1 / math.sqrt(2), rel=1e-9)


def test_filter_above_nyquist_and_bad_order_are_refused():
    with pytest.raises(DesignError) as err:
        S.butterworth(2, 600.0, 1e-3)
    assert err.value.key == "force_filter.cutoff_hz"
    with pytest.raises(DesignError) as err:
        S.butterworth(3, 50.0, 1e-3)
    assert err.value.key == "force_filter.order"


def test_sensed_loop_without_a_sensor_is_the_ideal_loop_and_a_delay_destabilises_it():
    """No delay, filter or network: the matrix of the ideal sensor's force loop (the Jury model).
    One sample of delay at the UR5 drum's contact (1e5 N/m, 3.08 kg) turns today's rule κ unstable
    (the issue's measured divergence) while the design finds a κ that holds."""
    ideal = fr.sampled_force_loop(0.18, 2.0, 0.02, 1e-3, 100.0, 2.0)
    same, *_ = S.sensed_force_loop(0.18, 2.0, 0.02, 1e-3, 100.0, 2.0)
    assert np.array_equal(ideal, same)
    w0h = math.sqrt(1e5 / 3.08) * 1e-3
    assert S.loop_damping(S.sensed_force_loop(w0h, 2.0, 0.0469, 1e-3, 100.0, 2.0, delay=0)[0], 1e-3)[0] < 1.0
    assert S.loop_damping(S.sensed_force_loop(w0h, 2.0, 0.0469, 1e-3, 100.0, 2.0, delay=1)[0], 1e-3)[0] > 1.0
    d = S.design_sensing(h=1e-3, g_P=2.0, mu_z=100.0, alpha_z=2.0, g_f=0.0, noise=1.0, delay=1,
                         stiffness_min=1e4, stiffness_max=1e5, m_n_min=3.08, m_n_max=4.95)
    assert d.zeta >= fr.SAMPLED_ZETA_MIN and d.kappa < 0.0469
    assert inspect.signature(S.design_sensing).parameters["zeta_min"].default == fr.SAMPLED_ZETA_MIN
    for k in (1e4, 1e5):
        for m in (3.08, 4.95):
            loop = S.sensed_force_loop(math.sqrt(k / m) * 1e-3, 2.0, d.kappa, 1e-3, 100.0, 2.0, delay=1,
                                       filt=None if not d.order else S.butterworth_matrices(d.order, d.cutoff_hz,
                                                                                            1e-3))
            assert S.loop_damping(loop[0], 1e-3)[0] < 1.0


def test_noise_gains_of_the_scalar_loop_against_its_own_simulation():
    """The discrete Lyapunov equation's RMS force error and command against 20,000 samples of the
    same linear loop driven by seeded white noise (within 5 %)."""
    Phi, G, w, wn = S.sensed_force_loop(0.15, 2.0, 0.012, 1e-3, 100.0, 2.0, g_f=0.0, delay=1,
                                        filt=S.butterworth_matrices(2, 300.0, 1e-3))
    assert S.loop_damping(Phi, 1e-3)[0] < 0.999
    e_pred, w_pred = S.noise_gains(Phi, G, w, wn)
    rng = np.random.default_rng(1)
    x, es, ws = np.zeros(Phi.shape[0]), [], []
    for n in rng.normal(size=20000):
        ws.append(w @ x + wn * n)
        x = Phi @ x + G * n
        es.append(x[0])
    assert np.std(es[2000:]) == pytest.approx(e_pred, rel=0.05)
    assert np.std(ws[2000:]) == pytest.approx(w_pred, rel=0.05)


def test_design_refuses_naming_the_key_when_nothing_holds():
    """The adaptive law's network (g_f 232 1/s) with one sample of delay over 1e4..1e5 N/m."""
    with pytest.raises(DesignError) as err:
        S.design_sensing(h=1e-3, g_P=2.0, mu_z=100.0, alpha_z=2.0, g_f=232.0, noise=1.0, delay=1,
                         stiffness_min=1e4, stiffness_max=1e5, m_n_min=3.08, m_n_max=4.95)
    e = err.value
    assert e.key == "sensor.delay" and "stiffness_min >=" in str(e) and 1e4 < e.bound < 1e5
    S.design_sensing(h=1e-3, g_P=2.0, mu_z=100.0, alpha_z=2.0, g_f=232.0, noise=1.0, delay=1,  # holds there
                     stiffness_min=e.bound, stiffness_max=1e5, m_n_min=3.08, m_n_max=4.95)


def _paper(over=None):
    return H.load_scenario("paper-stable", {"controller.kind": "hinf", "simulation.control": "sampled",
                                            "controller.force_rate.stiffness_max": 1e5, **(over or {})})


def test_the_default_has_no_filter_and_continuous_control_refuses_one():
    """order 0 (the default) is today's law: no filter, no new state; a filter under continuous
    control is a ConfigError naming the key."""
    ctrl = _paper().build_controller()
    assert ctrl.force_filter is None and "lam_filter" not in ctrl.init().parts
    with pytest.raises(ConfigError) as err:
        H.load_scenario("paper-stable", {"controller.kind": "hinf", "controller.force_filter.order": 2,
                                         "controller.force_filter.cutoff_hz": 100.0}).build_controller()
    assert err.value.key == "controller.force_filter.order"


def test_the_filter_in_the_law_filters_e_lam_from_rest_at_the_first_sample():
    """With a 2nd-order filter the law's e_λ is the filter's output: at rest at the first sample,
    then lfilter of the measured e_λ sequence."""
    sc = _paper({"controller.force_filter.order": 2, "controller.force_filter.cutoff_hz": 40.0,
                 "controller.force_rate.kappa": 0.0})
    ctrl = sc.build_controller()
    assert ctrl.force_filter is not None and ctrl.force_filter.order == 2
    ref = A.constant_reference(1.0, 60.0)
    q = jnp.asarray(sc.initial_q())
    rng = np.random.default_rng(2)
    forces = [np.array([30.0, -30.0]) + rng.normal(size=2) for _ in range(30)]
    meas = [H.Measurement(q=q, qd=jnp.zeros(2), force=jnp.asarray(f)) for f in forces]
    state = ctrl.start(0.0, ctrl.init(), meas[0], ref)
    raw, seen = [], []
    for k, m in enumerate(meas):
        out = ctrl.evaluate(k * 1e-3, state, m, ref)
        raw.append(float(ctrl.observe(m)[2][0]) - 60.0)
        seen.append(float(out.e_lam[0]))
        _, state = ctrl.sample(k * 1e-3, 1e-3, state, m, ref, out=out)
    b, a = signal.butter(2, 40.0, fs=1e3)
    zi = signal.lfilter_zi(b, a) * raw[0]
    assert np.max(np.abs(np.array(seen) - signal.lfilter(b, a, raw, zi=zi)[0])) < 1e-9


def _simulated_noise(plant, ctrl, ref, q_eq, lam_d, sigma, t_final, delay=0):
    """A run at rest at the operating point with a sensor of white noise σ (and ``delay`` samples):
    (its arrays, the samples after 0.5 s, the RMS torque per joint and the RMS true λ, each per N of
    noise; λ the normal force in the paper's scaling, λ = f_n / ‖Â‖, Â = [tan δ, −1])."""
    noisy = dataclasses.replace(plant, sensor=Sensor.make(3, force_noise=sigma, delay=delay))
    tr = H.simulate(noisy, ctrl, ref, q0=jnp.asarray(q_eq), t_final=t_final, dt=1e-4, control_period=1e-3,
                    save_interval=1e-3)
    a = tr.arrays
    keep = np.asarray(a["t"]) > 0.5
    tau_std = np.std(np.asarray(a["tau"])[keep], axis=0) / sigma
    scale = float(lam_d[0]) / float(np.mean(np.asarray(a["normal_force"])[keep]))
    lam_std = np.std(np.asarray(a["normal_force"])[keep]) * scale / sigma
    return a, keep, tau_std, lam_std


def test_noise_gains_and_delay_of_the_linearised_loop_against_simulation():
    """The paper's arm, H∞-only law with the force-rate term at 1 kHz on an undamped 1e5 N/m contact
    (the exact model at rest at u1 = 1.0, λ = 60): the linearised sampled loop with white force
    noise predicts the simulated standard deviation of each joint torque and of λ within 20 %; with
    one sample of delay it predicts growth (spectral radius > 1), and the simulated force error
    grows at ln(radius)/h within 20 %. (About 30 s: the loop's Jacobians and two short runs of the
    2-joint arm.)"""
    sc = _paper()
    ctrl = sc.build_controller()
    plant, ref, q_eq, _, lam_d = A.operating_point(sc, 1e5, ctrl=ctrl)
    nr = A.noise_response(A.sensed_sampled_loop(plant, ctrl, ref, q_eq, 1e-3, 1e-4, 0))
    assert nr["stable"]
    sigma = 0.1
    _, _, tau_std, lam_std = _simulated_noise(plant, ctrl, ref, q_eq, lam_d, sigma, 3.0)
    assert tau_std == pytest.approx(np.asarray(nr["tau_per_n"]), rel=0.2)
    assert lam_std == pytest.approx(nr["lam_per_n"], rel=0.2)

    late = A.noise_response(A.sensed_sampled_loop(plant, ctrl, ref, q_eq, 1e-3, 1e-4, 1))
    assert not late["stable"] and late["radius"] > 1.05
    delayed = dataclasses.replace(plant, sensor=Sensor.make(0, delay=1))
    tr = H.simulate(delayed, ctrl, ref, q0=jnp.asarray(q_eq) + 1e-10, t_final=0.1, dt=1e-4, control_period=1e-3,
                    save_interval=1e-3, raise_on_failure=False)
    t, e = np.asarray(tr.arrays["t"]), np.abs(np.asarray(tr.arrays["e_lam"])[:, 0])
    w1, w2 = e[(t > 0.04) & (t <= 0.07)].max(), e[(t > 0.07) & (t <= 0.1)].max()
    assert math.log(w2 / w1) / 0.03 == pytest.approx(math.log(late["radius"]) / 1e-3, rel=0.2)


def test_a_noisy_late_sensor_on_the_ur5_drum_holds_within_the_torque_limits_only_with_the_design():
    """ur5-polish on MuJoCo at 1 kHz, H∞-only law, σ = 1 N and one sample of delay on the sensor, the
    UR5's torque limits: the force-rate gain of section 7's rule (designed for an ideal sensor, ṡ
    the differenced force: source "force") drives the motors into their limits a large part of the
    time, the design for the declared sensor (source "auto": the joint rates) never after the first
    0.2 s, with a smaller true force error. (One compiled MuJoCo
    program for both laws, 1.2-s runs: tens of seconds; the one test of the design on the arm and
    plant the issue measured.)"""
    pytest.importorskip("mujoco")
    from hinfnn.metrics import compute_metrics
    from hinfnn.sim import simulate_many

    over = {"controller.kind": "hinf", "simulation.t_final": 1.2, "plant.sensor.force_noise": 1.0,
            "plant.sensor.delay": 1, "plant.actuator.torque_limit": "urdf"}
    paper = H.load_scenario("ur5-polish", {**over, "controller.force_rate.source": "force",  # designed as if the
                                           "controller.force_filter.order": 0,              # sensor were ideal
                                           "controller.sensor.delay": 0, "controller.sensor.noise": 0.0})
    designed = H.load_scenario("ur5-polish", {**over, "controller.force_filter.order": "design"})
    sd = dict(designed.build_controller().terms[-1].design)["sensing"]
    assert sd["delay"] == 1 and sd["noise"] == 1.0  # the declared sensor, copied by the scenario
    runs = [paper.run(name="paper"), designed.run(name="designed")]
    trajs = simulate_many(runs)
    m = {name: compute_metrics(tr, last=0.7) for name, tr in trajs.items()}
    t = np.asarray(trajs["designed"].arrays["t"])
    tau = np.abs(np.asarray(trajs["designed"].arrays["tau"]))[t > 0.2]
    limits = np.asarray(designed.build().plant.actuator.torque_limit)
    assert trajs["designed"].ok and np.all(tau < limits)
    assert m["paper"]["fraction_torque_saturated"] > 0.25
    assert m["designed"]["rms_normal_force_error_last2s"] < 0.6 * m["paper"]["rms_normal_force_error_last2s"]


def test_design_command_prints_the_sensor_design_and_the_noise_gains(capsys):
    """`hinfnn design` with a declared sensor and the filter by design: the choice, the predicted
    noise gains per N and the largest noise within the torque limits; with a declared disturbance,
    the least force error any law holds (force_error_bound at the stiffest contact and the worst
    of the path's normal masses)."""
    import re

    from hinfnn import cli

    assert cli.main(["design", "paper-stable", "--set", "controller.kind=hinf", "--set", "simulation.control=sampled",
                     "--set", "controller.force_rate.stiffness_max=1e5", "--set", "plant.sensor.force_noise=0.1",
                     "--set", "plant.actuator.torque_limit=500", "--set", "controller.force_filter.order=design",
                     "--set", "controller.sensor.disturbance=2", "--set", "controller.sensor.disturbance_hz=3"]) == 0
    out = capsys.readouterr().out
    assert "designed for the sensor (noise 0.1 N, delay 0 sample(s))" in out
    assert "noise gains with 0 sample(s) of delay at 100000 N/m: RMS torque per N of sensor noise" in out
    assert "3 sigma of torque within the limits up to sensor noise" in out and "declared noise 0.1 N" in out
    line = next(x for x in out.splitlines() if "least force error any law holds at sensor noise 0.1 N" in x)
    printed = float(re.search(r"([0-9.e+-]+) N at 100000 N/m", line).group(1))
    lo, hi = (float(v) for v in re.search(r"m_n ([0-9.]+)\.\.([0-9.]+) kg", line).groups())
    want = max(S.force_error_bound(omega0=math.sqrt(1e5 / m), h=1e-3, noise=0.1, delay=0, disturbance=2.0,
                                   disturbance_hz=3.0) for m in (lo, hi))
    assert printed == pytest.approx(want, rel=2e-3)


# --- the force-rate term's rate from the joint rates (source "velocity") ----------------------------


@pytest.fixture(scope="module")
def velocity_run():
    """0.3 s of the H∞-only law on the paper plant (undamped 1e5 N/m contact, ideal sensor, continuous
    control), the force-rate term's ṡ from the joint rates with k_s = the plant's 1e5 N/m, every
    step stored; the nominal line and link lengths are the true ones (a slope or length error makes
    sliding read as a constraint rate, docs/beyond-the-paper.md section 12)."""
    sc = H.load_scenario("paper-stable", {"controller.kind": "hinf", "simulation.t_final": 0.3,
                                          "controller.force_rate.source": "velocity",
                                          "nominal.surface.delta_deg": 45.5, "nominal.arm.l1": 1.02724,
                                          "nominal.arm.l2": 0.98041,
                                          "controller.force_rate.stiffness_max": 1e5})
    return sc.build_controller(), sc.simulate(save_every=1)


def test_velocity_rate_is_the_measured_force_rate_on_the_paper_line(velocity_run):
    """An oracle on sign and scale (the paper's line: Â = [tan δ, −1], ÂÂᵀ = 2, λ = f_n/‖Â‖): with
    k_s the contact's stiffness and the nominal kinematics the true ones, the term's ṡ = k_s D²ÂĴq̇ is dλ/dt
    of the measured λ, here its central difference over the 0.1-ms steps (to 1 % of its RMS; the
    difference's own error is (ωh)²/6 ≈ 2e-4 at the contact mode's 330 rad/s). No s state."""
    ctrl, tr = velocity_run
    term = ctrl.term(H.controllers.ForceRate)
    assert term.source == "velocity" and float(term.stiffness) == 1e5 and "s_lam" not in ctrl.init().parts
    t = np.asarray(tr.arrays["t"])
    lam, rate = np.asarray(tr.arrays["lam"])[:, 0], np.asarray(tr.arrays["lam_rate"])[:, 0]
    diff = (lam[2:] - lam[:-2]) / (t[2:] - t[:-2])
    keep = t[1:-1] > 0.01  # after the first contact transient's first steps
    err = rate[1:-1][keep] - diff[keep]
    assert np.sqrt(np.mean(err ** 2)) < 0.01 * np.sqrt(np.mean(diff[keep] ** 2))
    assert np.sqrt(np.mean(diff[keep] ** 2)) > 10.0  # the rate is not trivially small
    v = np.asarray(tr.arrays["v_rate"])[:, 0]
    assert np.max(np.abs(v + float(term.kappa) * rate)) < 1e-12 * np.max(np.abs(v))


def test_velocity_rate_keeps_the_dissipation_inequality(velocity_run):
    """V̇ + (integrand of 34) − supply ≤ 0 along the run with the velocity source: the term's cross
    term −cα_zκ e_λᵀṡ carried as it is (positive part in J_aug, negative part in the supply), the
    margin ρ²∫‖f‖² + ... − (J_aug + V − V(0)) never decreases (up to the RK4 error) and stays ≥ 0."""
    _, tr = velocity_run
    margin = tr.supply - (tr.J_aug + tr.V - tr.V[0])
    assert np.all(margin >= 0)
    scale = np.max(np.abs(tr.supply))
    assert np.min(np.diff(margin)) > -1e-9 * scale
    assert tr.J_aug[-1] > tr.J[-1]  # the positive part of the cross term is in J_aug


def test_source_auto_follows_the_assumed_sensor_and_a_bad_source_names_the_key():
    """"auto" (the default) is "force" with an ideal assumed sensor (today's term, its s state) and
    "velocity" with a noisy one (no s state, k_s = stiffness_max, designed on the sampled loop);
    a value not allowed is a ConfigError naming the key and the allowed values."""
    from hinfnn.scenario.sections import ForceRateConfig

    assert ForceRateConfig().source == "auto"
    assert ForceRateConfig().resolved(0.0) == "force" and ForceRateConfig().resolved(0.5) == "velocity"
    assert ForceRateConfig(source="force").resolved(0.5) == "force"
    ideal = _paper().build_controller().term(H.controllers.ForceRate)
    assert ideal.source == "force" and ideal.stiffness is None
    noisy = _paper({"plant.sensor.force_noise": 0.1}).build_controller()
    term = noisy.term(H.controllers.ForceRate)
    assert term.source == "velocity" and float(term.stiffness) == 1e5 and "s_lam" not in noisy.init().parts
    assert dict(term.design)["sensing"]["source"] == "velocity"
    assumed = _paper({"plant.sensor.force_noise": 0.1, "controller.sensor.noise": 0.0}).build_controller()
    assert assumed.term(H.controllers.ForceRate).source == "force"  # the assumed sensor decides
    # a late sensor without noise: "velocity", designed on the sampled loop with its delay (it used to get the
    # ideal sensor's rule, a κ no sample of delay was checked against)
    assert ForceRateConfig().resolved(0.0, 1) == "velocity" and ForceRateConfig().resolved(0.0, 0) == "force"
    late = _paper({"plant.sensor.delay": 1}).build_controller().term(H.controllers.ForceRate)
    assert late.source == "velocity" and dict(late.design)["sensing"]["delay"] == 1
    # "force" asked for with a late sensor: designed for the delay too (here a κ of 3.6 ms, not the rule's 28 ms)
    forced = _paper({"plant.sensor.delay": 1, "controller.force_rate.source": "force"}).build_controller()
    sd = dict(forced.term(H.controllers.ForceRate).design)["sensing"]
    assert sd["delay"] == 1 and sd["source"] == "force" and sd["kappa"] < 0.01
    with pytest.raises(ConfigError) as err:
        H.load_scenario("paper-stable", {"controller.force_rate.source": "speed"})
    assert err.value.key == "controller.force_rate.source"
    assert all(w in str(err.value) for w in ("speed", "velocity", "force", "auto"))


def test_velocity_design_for_the_ur5_drum():
    """ur5-polish-sensor's parameters (1 kHz, one sample of delay, g_P = 2, μ_z = 100, α_z = 2,
    g_f = 232, k 3.5e4..1e5 N/m, m_n 3.077..4.947 kg): the velocity source's design has a worst-corner
    force error of 0.32 per N and κ 0.0234 s (the one-period loop's optimum, within 5 %), a force
    command and its rate no larger than the 132-Hz first-order filter's 1.45 per N and 1,240 N/s
    per N, and at most a fifth of the force source's force error and a fiftieth of its command
    rate. The choice is the least command rate within 10 % of the least force error."""
    kw = dict(h=1e-3, g_P=2.0, mu_z=100.0, alpha_z=2.0, g_f=232.0, noise=1.0, delay=1, stiffness_min=3.5e4,
              stiffness_max=1e5, m_n_min=3.077, m_n_max=4.947)
    v = S.design_sensing(**kw, source="velocity")
    f = S.design_sensing(**kw)
    assert v.source == "velocity" and f.source == "force"
    assert v.force_error_per_n == pytest.approx(0.32, rel=0.05) and v.kappa == pytest.approx(0.0234, rel=0.05)
    assert v.command_per_n <= 1.45 and v.command_rate_per_n <= 1240.0
    assert v.force_error_per_n < f.force_error_per_n / 5 and v.command_rate_per_n < f.command_rate_per_n / 50
    assert f.command_rate_per_n == pytest.approx(45000.0, rel=0.05)  # today's 45,000 N/s per N
    # the rule: the chosen filter keeps the force error within 10 % of the least and smooths the command
    unfiltered = S.design_sensing(**kw, source="velocity", order=0)
    assert v.force_error_per_n <= S.RATE_TOLERANCE * min(unfiltered.force_error_per_n, v.force_error_per_n) * 1.0001
    assert unfiltered.command_rate_per_n > v.command_rate_per_n


def test_velocity_noise_gains_against_simulation():
    """The paper's arm, H∞-only law at 1 kHz on an undamped 1e5 N/m contact, a sensor with white force
    noise and one sample of delay, the force-rate term from the joint rates (source "auto" with the
    noisy sensor; κ designed on the delayed loop): the whole-arm linearised loop's RMS joint torques
    and true λ per N of noise, and the one-dimensional loop's force error at the operating point's
    normal mass, against a 2-s simulation's standard deviations (20 %)."""
    sigma = 0.1
    sc = _paper({"plant.sensor.force_noise": sigma, "plant.sensor.delay": 1})
    ctrl = sc.build_controller()
    term = ctrl.term(H.controllers.ForceRate)
    assert term.source == "velocity"
    plant, ref, q_eq, _, lam_d = A.operating_point(sc, 1e5, ctrl=ctrl)
    nr = A.noise_response(A.sensed_sampled_loop(plant, ctrl, ref, q_eq, 1e-3, 1e-4, 1))
    assert nr["stable"]
    m_n = float(fr.normal_mass(ctrl.arm, ctrl.surface, jnp.asarray(q_eq)))
    g_P = float(A.k_prime(ctrl)) - 1.0
    one_d = S.noise_gains(*S.sensed_force_loop(math.sqrt(1e5 / m_n) * 1e-3, g_P, float(term.kappa), 1e-3,
                                               float(ctrl.gains.mu_z), float(ctrl.gains.alpha_z), 0.0, 1,
                                               source="velocity", rate_scale=1.0))[0]
    one_d /= float(jnp.linalg.norm(ctrl.surface.A_hat(ctrl.arm.h(jnp.asarray(q_eq)))))  # λ's noise: 1/‖Â‖ per N
    assert one_d == pytest.approx(nr["lam_per_n"], rel=0.05)
    a, keep, tau_std, lam_std = _simulated_noise(plant, ctrl, ref, q_eq, lam_d, sigma, 2.0, delay=1)
    assert tau_std == pytest.approx(np.asarray(nr["tau_per_n"]), rel=0.2)
    assert lam_std == pytest.approx(nr["lam_per_n"], rel=0.2)
    assert lam_std == pytest.approx(one_d, rel=0.2)
    tau = np.asarray(a["tau"])[keep]
    rate_std = np.std(np.diff(tau, axis=0), axis=0) / 1e-3 / sigma
    assert rate_std == pytest.approx(np.asarray(nr["tau_rate_per_n"]), rel=0.2)
    # the design's torque-rate prediction: the 1-D loop's command rate times each joint's lever
    sd = dict(term.design)["sensing"]
    filt = None if not sd["order"] else S.butterworth_matrices(sd["order"], sd["cutoff_hz"], 1e-3)
    loop = S.sensed_force_loop(math.sqrt(1e5 / m_n) * 1e-3, g_P, float(term.kappa), 1e-3, float(ctrl.gains.mu_z),
                               float(ctrl.gains.alpha_z), 0.0, 1, filt, source="velocity", rate_scale=1.0)
    lever = np.asarray(fr.normal_lever(ctrl.arm, ctrl.surface, jnp.asarray(q_eq)))
    rate_1d = S.command_rate(*loop) / 1e-3
    assert rate_1d * lever == pytest.approx(np.asarray(nr["tau_rate_per_n"]), rel=0.05)
    p99 = np.percentile(np.abs(np.diff(tau, axis=0)) / 1e-3, 99, axis=0)
    assert S.predicted_torque_rate(rate_1d, sigma, lever) == pytest.approx(p99, rel=0.2)


def _height_and_slanted_angle(x, p):
    return jnp.stack([p[0] - x[1], p[1] - x[2] - 0.5 * x[1]])  # non-orthogonal normals of unequal norms


def test_velocity_rate_per_constraint_on_two_slanted_constraints():
    """k = 2 constraints whose gradients are neither orthogonal nor of unit norm (a 3-link planar arm,
    tip height and a slanted tool angle): a penalty contact of stiffness k along each unit normal,
    F = kÂᵀD²θ̂, reads λ = (ÂÂᵀ)⁻¹ÂF = kD²θ̂, so on the surface λ̇ = kD²ÂĴq̇, the law's
    ``theta_rate`` times k (forward-mode derivative along q̇, 1e-10), and not k(ÂÂᵀ)⁻¹ÂĴq̇."""
    from hinfnn.controllers.law import force_multiplier
    from hinfnn.model.arm import PlanarPointMassArm
    from hinfnn.model.surface import ImplicitSurface
    from hinfnn.model.taskmap import PlanarTaskMap

    arm = PlanarPointMassArm(masses=jnp.array([2.0, 1.5, 1.0]), lengths=jnp.array([0.8, 0.7, 0.5]), g=9.81, n=3,
                             task=PlanarTaskMap("xy", with_angle=True))
    surface = ImplicitSurface(params=jnp.array([0.4, -1.0]), theta_fn=_height_and_slanted_angle, m=1, k=2)
    ctrl = H.controllers.design("hinf", arm, surface)
    q = arm.inverse_kinematics(jnp.array([1.0, 0.4, -1.2]), jnp.array([0.3, -0.6, -0.9]))
    x = arm.h(q)
    assert np.max(np.abs(np.asarray(surface.theta(x)))) < 1e-9  # on both constraints
    qd = jnp.array([0.3, -0.7, 0.5])
    k = 1e5

    def lam(q):
        x = arm.h(q)
        A_hat = surface.A_hat(x)
        D2 = 1.0 / jnp.sum(A_hat * A_hat, axis=1)
        return force_multiplier(A_hat, k * A_hat.T @ (D2 * surface.theta(x)))

    _, lam_dot = jax.jvp(lam, (q,), (qd,))
    out = ctrl.evaluate(0.0, ctrl.init(), H.Measurement(q=q, qd=qd, force=jnp.zeros(2)),
                        A.constant_reference(1.0, jnp.array([10.0, 10.0])))
    rate = k * np.asarray(out.aux.ctx.theta_rate)
    np.testing.assert_allclose(rate, np.asarray(lam_dot), rtol=1e-10, atol=1e-10 * float(np.max(np.abs(lam_dot))))
    A_hat = np.asarray(surface.A_hat(x))
    other = k * np.linalg.solve(A_hat @ A_hat.T, A_hat @ np.asarray(arm.J(q)) @ np.asarray(qd))
    assert np.max(np.abs(other - rate)) > 0.1 * np.max(np.abs(rate))


def test_design_within_a_torque_rate_limit():
    """ur5-polish-sensor's one-dimensional loop (the velocity source, order 1) with one joint of lever
    0.55 N·m per N: without a limit the choice is today's (the same candidate with a limit no
    candidate reaches); with 1,000 N·m/s the least-error choice predicts a 99th percentile of
    |Δτ|/h above it, so the design takes another, within it, at a larger force error; with
    100 N·m/s none is within and the least predicted rate is taken, with a warning naming the key.
    The prediction is 2.5758 σ × the largest corner's command rate × the lever, recomputed here."""
    kw = dict(h=1e-3, g_P=2.0, mu_z=100.0, alpha_z=2.0, g_f=232.0, noise=1.0, delay=1, stiffness_min=3.5e4,
              stiffness_max=1e5, m_n_min=3.077, m_n_max=4.947, source="velocity", order=1)
    lever = np.array([0.55])
    free = S.design_sensing(**kw)
    assert free.torque_rate_limit is None and free.within_rate_limit is None and free.rate_warning is None
    loose = S.design_sensing(**kw, torque_rate_limit=[1e9], lever=lever)
    assert (loose.order, loose.cutoff_hz, loose.kappa) == (free.order, free.cutoff_hz, free.kappa)
    pts = S.corners(3.5e4, 1e5, 3.077, 4.947)
    args = dict(h=1e-3, g_P=2.0, mu_z=100.0, alpha_z=2.0, g_f=232.0, delay=1, pts=pts, source="velocity",
                stiffness_max=1e5)
    free_p99 = 2.5758 * 1.0 * S.max_command_rate(free.order, free.cutoff_hz, free.kappa, **args) * 0.55
    assert free_p99 > 1000.0 and loose.torque_rate_p99[0] == pytest.approx(free_p99, rel=1e-12)
    held = S.design_sensing(**kw, torque_rate_limit=[1000.0], lever=lever)
    p99 = 2.5758 * S.max_command_rate(held.order, held.cutoff_hz, held.kappa, **args) * 0.55
    assert held.within_rate_limit and held.rate_warning is None
    assert held.torque_rate_p99[0] == pytest.approx(p99, rel=1e-12) and p99 <= 1000.0
    assert held.force_error_per_n > free.force_error_per_n and held.cutoff_hz < free.cutoff_hz
    tight = S.design_sensing(**kw, torque_rate_limit=[100.0], lever=lever)
    assert tight.within_rate_limit is False and tight.torque_rate_p99[0] > 100.0
    assert tight.torque_rate_p99[0] < p99  # the least rate: below the 1,000 N·m/s choice's
    assert "controller.actuator.torque_rate_limit" in tight.rate_warning and "100 N m/s" in tight.rate_warning
    half = S.design_sensing(**kw, torque_rate_limit=[1000.0], lever=lever, torque_rate_share=0.5)
    assert half.within_rate_limit and half.torque_rate_p99[0] <= 500.0 < held.torque_rate_p99[0]
    floor = S.design_sensing(**dict(kw, noise=0.25), torque_rate_limit=[1000.0], lever=lever, torque_rate_share=0.5,
                             rate_noise_floor=1.0)  # the rate judged at 1 N: the choice at 1 N
    assert (floor.order, floor.cutoff_hz, floor.kappa) == (half.order, half.cutoff_hz, half.kappa)
    assert floor.rate_noise == 1.0 and floor.torque_rate_p99 == half.torque_rate_p99
    with pytest.raises(DesignError) as err:
        S.design_sensing(**kw, torque_rate_limit=[1000.0], lever=lever, torque_rate_share=1.5)
    assert err.value.key == "actuator.torque_rate_share"


def test_torque_rate_limit_key_declared_number_none_and_bad_values():
    """controller.actuator.torque_rate_limit: "declared" (the default) is plant.actuator's (none
    there: no constraint), a number or one per joint is taken as given, "none" is none; a wrong
    count or a value out of range is a ConfigError naming the key; the scenario's declared limit
    reaches the design record with the joints' levers."""
    from hinfnn.scenario.sections import ActuatorAssumptionConfig

    c = ActuatorAssumptionConfig()
    assert c.torque_rate_limit == "declared" and c.resolved(None, 2) is None and c.torque_rate_share == 0.5
    assert c.rate_noise_floor == 1.0
    assert c.resolved(1000.0, 2).tolist() == [1000.0, 1000.0] and c.resolved((10.0, 20.0), 2).tolist() == [10.0, 20.0]
    assert ActuatorAssumptionConfig(torque_rate_limit=500.0).resolved(1000.0, 2).tolist() == [500.0, 500.0]
    assert ActuatorAssumptionConfig(torque_rate_limit="none").resolved(1000.0, 2) is None
    with pytest.raises(ConfigError) as err:
        ActuatorAssumptionConfig(torque_rate_limit=(1.0, 2.0, 3.0)).resolved(None, 2)
    assert err.value.key == "controller.actuator.torque_rate_limit"
    with pytest.raises(ConfigError) as err:
        c.resolved((1.0, 2.0, 3.0), 2)
    assert err.value.key == "plant.actuator.torque_rate_limit"
    for key, bad in (("torque_rate_limit", -5), ("torque_rate_limit", 0), ("torque_rate_limit", "fast"),
                     ("torque_rate_share", 1.5), ("torque_rate_share", 0), ("rate_noise_floor", -1)):
        with pytest.raises(ConfigError) as err:
            H.load_scenario("paper-stable", {f"controller.actuator.{key}": bad})
        assert err.value.key == f"controller.actuator.{key}" and str(bad) in str(err.value)
    sd = dict(_paper({"plant.sensor.force_noise": 0.1, "plant.actuator.torque_rate_limit": 2e4})
              .build_controller().term(H.controllers.ForceRate).design)["sensing"]
    assert sd["torque_rate_limit"] == (2e4, 2e4) and len(sd["lever"]) == 2 and sd["within_rate_limit"]
    assert sd["torque_rate_share"] == 0.5 and sd["rate_noise"] == 1.0  # the declared 0.1 N, at least the floor
    assert max(sd["torque_rate_p99"]) <= 1e4
    none = dict(_paper({"plant.sensor.force_noise": 0.1, "plant.actuator.torque_rate_limit": 5000.0,
                        "controller.actuator.torque_rate_limit": "none"})
                .build_controller().term(H.controllers.ForceRate).design)["sensing"]
    assert none["torque_rate_limit"] is None


# --- the least force error any law holds (force_error_bound) ---------------------------------------

def test_lqg_cost_of_a_scalar_plant_is_the_kalman_closed_form():
    """x_{k+1} = a x + u + w, y = x + n, cost E[x²] (+ a vanishing control weight): the best law
    cancels the estimate, u = −a x̂_{k|k}, so E[x²] = a² P_{k|k} + q with the Kalman filter's
    stationary variances P⁻ = a²P + q, P = P⁻r/(P⁻ + r) (a quadratic)."""
    a, q, r = 0.9, 0.3, 0.5
    cost = S.lqg_cost(np.array([[a]]), np.array([[1.0]]), np.array([[q]]), np.array([[1.0]]), np.array([[r]]),
                      np.diag([1.0, 1e-12]), np.array([[1.0], [0.0]]), np.array([[0.0], [1.0]]))
    # P⁻ solves P⁻ = a² P⁻ r/(P⁻ + r) + q: P⁻² + (r − a²r − q) P⁻ − q r = 0
    b = r - a * a * r - q
    p_pred = 0.5 * (-b + math.sqrt(b * b + 4 * q * r))
    p_filt = p_pred * r / (p_pred + r)
    assert cost == pytest.approx(a * a * p_filt + q, rel=1e-8)


def test_period_cost_is_the_integral_of_the_squared_force_error():
    """Q̄ of period_cost against the quadrature of e(t)² over one held period (the exact solution
    of the damped contact mode at 2001 points), for a random state and held force."""
    from scipy.integrate import simpson
    from scipy.linalg import expm

    w0, h, zeta = 180.0, 1e-3, 0.2
    Phi, Gam, Qbar = S.period_cost(w0, h, zeta)
    A = np.array([[0.0, w0, 0.0], [-w0, -2 * zeta * w0, w0], [0.0, 0.0, 0.0]])
    x = np.random.default_rng(1).normal(size=3)
    ts = np.linspace(0.0, h, 2001)
    e = np.array([(expm(A * t) @ x)[0] for t in ts])
    assert float(x @ Qbar @ x) == pytest.approx(simpson(e * e, x=ts), rel=1e-8)
    assert np.allclose(np.append(Phi @ x[:2] + Gam * x[2], x[2]), expm(A * h) @ x, atol=1e-13)


def test_force_error_bound_is_what_the_lqg_law_holds_in_a_simulation():
    """The bound (the LQG law on the UR5 table's contact, one sample of delay, σ = 1 N, a 2 N
    disturbance at 2 Hz) against a seeded simulation of that law on the continuous contact mode
    (20 sub-steps a period): the RMS true force error within 3 %. The bound grows with the noise
    and with the delay, and is 0 with no disturbance (a law that does nothing holds e = 0)."""
    w0, h = math.sqrt(1e5 / 4.26), 1e-3
    kw = dict(omega0=w0, h=h, delay=1, disturbance=2.0, disturbance_hz=2.0)
    bound = S.force_error_bound(noise=1.0, **kw)
    Phi, Gam, W, C, V, Qbar, Mx, Mu = S.bound_model(noise=1.0, **kw)
    K, L = S.lqg_law(Phi, Gam, W, C, V, Qbar, Mx, Mu)
    P_sub, G_sub, _ = S.period_cost(w0, h / 20)
    rng = np.random.default_rng(0)
    n = Phi.shape[0]
    x, xh = np.zeros(n), np.zeros(n)
    acc, cnt = 0.0, 0
    steps = 60_000
    wd, vn = rng.normal(size=steps) * math.sqrt(W[2, 2]), rng.normal(size=steps) * math.sqrt(V[0, 0])
    for k in range(steps):
        y = C @ x + vn[k]
        xf = xh + L @ (y - C @ xh)
        u = float(-(K @ xf)[0])
        s_ = u + x[2]
        ev = x[:2].copy()
        if k >= 2000:
            for _ in range(20):  # the true error between the samples
                acc += ev[0] ** 2
                cnt += 1
                ev = P_sub @ ev + G_sub * s_
        nxt = Phi @ x + Gam[:, 0] * u
        nxt[2] += wd[k]
        x = nxt
        xh = Phi @ xf + Gam[:, 0] * u
    assert math.sqrt(acc / cnt) == pytest.approx(bound, rel=0.03)
    assert S.force_error_bound(noise=2.0, **kw) > bound
    assert S.force_error_bound(noise=1.0, **{**kw, "delay": 2}) > bound
    assert S.force_error_bound(noise=1.0, **{**kw, "disturbance": 0.0}) == 0.0
    with pytest.raises(DesignError) as err:
        S.force_error_bound(noise=-1.0, **kw)
    assert err.value.key == "sensor.noise"
