"""The force measurement path designed for the sensor (hinfnn.controllers.sensing, the noise gains
of hinfnn.analysis): the discrete filter against its transfer function, the loop model with
delay, filter and network, the design's choice and refusal, the filter inside the law, and the
linearised sampled loop with a delayed, noisy sensor against simulations."""

from __future__ import annotations

import dataclasses
import inspect
import math

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
    noisy = dataclasses.replace(plant, sensor=Sensor.make(3, force_noise=sigma))
    tr = H.simulate(noisy, ctrl, ref, q0=jnp.asarray(q_eq), t_final=3.0, dt=1e-4, control_period=1e-3,
                    save_interval=1e-3)
    a = tr.arrays
    keep = np.asarray(a["t"]) > 0.5
    tau_std = np.std(np.asarray(a["tau"])[keep], axis=0) / sigma
    assert tau_std == pytest.approx(np.asarray(nr["tau_per_n"]), rel=0.2)
    # the true λ: the normal force in the paper's scaling (λ = f_n / ‖Â‖, Â = [tan δ, −1])
    scale = float(lam_d[0]) / float(np.mean(np.asarray(a["normal_force"])[keep]))
    lam_std = np.std(np.asarray(a["normal_force"])[keep]) * scale / sigma
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
    paper = H.load_scenario("ur5-polish", {**over, "controller.force_rate.source": "force"})
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
    noise gains per N and the largest noise within the torque limits."""
    from hinfnn import cli

    assert cli.main(["design", "paper-stable", "--set", "controller.kind=hinf", "--set", "simulation.control=sampled",
                     "--set", "controller.force_rate.stiffness_max=1e5", "--set", "plant.sensor.force_noise=0.1",
                     "--set", "plant.actuator.torque_limit=500", "--set", "controller.force_filter.order=design"]) == 0
    out = capsys.readouterr().out
    assert "designed for the sensor (noise 0.1 N, delay 0 sample(s))" in out
    assert "noise gains with 0 sample(s) of delay at 100000 N/m: RMS torque per N of sensor noise" in out
    assert "3 sigma of torque within the limits up to sensor noise" in out and "declared noise 0.1 N" in out
