"""The robot's sensor and motors as part of the truth (hinfnn.plant.instruments, plant.sensor and
plant.actuator): the noise stream's statistics and seeding, the delay, the sensor's low-pass,
saturation and the rate limit, how the simulator applies them on the built-in plant, in batches
and sweeps, and that an ideal sensor leaves every number as it was."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hinfnn as H
from hinfnn.errors import ConfigError
from hinfnn.plant.instruments import Actuator, Sensor
from hinfnn.protocols import Measurement


def _readings(sensor, true_forces, q=None):
    """What ``sensor`` gives at samples 0 … K − 1 for the true forces ``true_forces`` (K, d)
    (joints fixed), one jitted scan."""
    true_forces = jnp.asarray(true_forces, dtype=jnp.float64)
    q = jnp.zeros(2) if q is None else jnp.asarray(q, dtype=jnp.float64)
    first = Measurement(q=q, qd=jnp.zeros_like(q), force=true_forces[0])

    @jax.jit
    def run(sensor, forces):
        def body(state, kf):
            k, f = kf
            out, state = sensor.read(k, 1e-3, Measurement(q=q, qd=jnp.zeros_like(q), force=f), state)
            return state, out

        return jax.lax.scan(body, sensor.start(first), (jnp.arange(forces.shape[0]), forces))[1]

    return run(sensor, true_forces)


# --- the sensor alone -------------------------------------------------------------------------------


def test_force_noise_is_white_with_the_declared_mean_and_sigma():
    K, sigma, bias = 20_000, 1.5, np.array([0.5, -2.0, 0.0])
    out = _readings(Sensor.make(11, force_noise=sigma, force_bias=bias), np.full((K, 3), 10.0))
    e = np.asarray(out.force) - 10.0 - bias
    assert np.all(np.abs(e.mean(axis=0)) < 4 * sigma / math.sqrt(K))  # mean: the bias, no more
    assert np.allclose(e.std(axis=0), sigma, rtol=0.03)
    for i in range(3):  # white: no correlation from one sample to the next, nor between axes
        assert abs(np.corrcoef(e[1:, i], e[:-1, i])[0, 1]) < 4 / math.sqrt(K)
    assert abs(np.corrcoef(e[:, 0], e[:, 1])[0, 1]) < 4 / math.sqrt(K)
    assert np.array_equal(np.asarray(out.q), np.zeros((K, 2)))  # no joint noise declared: exact


def test_joint_noise_has_its_sigma_per_joint():
    K = 20_000
    s = Sensor.make(2, q_noise=np.array([1e-3, 2e-3]), qd_noise=np.array([0.1, 0.0]))
    out = _readings(s, np.zeros((K, 2)))
    assert np.allclose(np.asarray(out.q).std(axis=0), [1e-3, 2e-3], rtol=0.03)
    assert np.allclose(np.asarray(out.qd)[:, 0].std(), 0.1, rtol=0.03)
    assert np.array_equal(np.asarray(out.qd)[:, 1], np.zeros(K))


def test_the_same_seed_gives_the_same_noise_and_streams_are_independent():
    forces = np.zeros((4000, 3))
    a = np.asarray(_readings(Sensor.make(5, force_noise=1.0), forces).force)
    b = np.asarray(_readings(Sensor.make(5, force_noise=1.0), forces).force)
    c = np.asarray(_readings(Sensor.make(6, force_noise=1.0), forces).force)
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)
    s = Sensor.make(5, force_noise=1.0)
    m0, m1 = (np.asarray(_readings(s.stream(i), forces).force) for i in (0, 1))
    assert np.array_equal(m0, np.asarray(_readings(Sensor.make(5, force_noise=1.0).stream(0), forces).force))
    for x, y in ((m0, m1), (m0, a)):
        assert abs(np.corrcoef(x.ravel(), y.ravel())[0, 1]) < 4 / math.sqrt(x.size)


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_a_step_in_the_true_force_appears_delay_samples_later(delay):
    forces = np.zeros((12, 3))
    forces[5:, 2] = 7.0  # the step at sample 5
    out = np.asarray(_readings(Sensor.make(0, delay=delay), forces).force)
    assert np.array_equal(out[:, 2], np.where(np.arange(12) >= 5 + delay, 7.0, 0.0))


@pytest.mark.parametrize("delay", [1, 3])
def test_a_delayed_reading_is_known_before_its_sample_is_acquired(delay):
    # the virtual robot publishes Sensor.upcoming at the tick and acquires the sample afterwards: it must
    # be exactly what read gives at that sample (noise, bias and low-pass included)
    rng = np.random.default_rng(3)
    sensor = Sensor.make(4, force_noise=1.0, force_bias=[0.2, 0.0, -0.1], q_noise=1e-3, qd_noise=0.1,
                         bandwidth=80.0, delay=delay)
    q = jnp.zeros(2)
    state = sensor.start(Measurement(q=q, qd=q, force=jnp.zeros(3)))
    for k in range(8):
        meas = Measurement(q=jnp.asarray(rng.normal(size=2)), qd=jnp.asarray(rng.normal(size=2)),
                           force=jnp.asarray(rng.normal(size=3)))
        ahead = sensor.upcoming(state) if k else None
        out, state = sensor.read(k, 1e-3, meas, state)
        if ahead is not None:
            for a, b in zip(jax.tree.leaves(ahead), jax.tree.leaves(out)):
                assert np.array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="without delay"):
        Sensor.make(0).upcoming(state)


def test_the_sensor_bandwidth_is_the_first_order_low_pass():
    fc, T, K = 50.0, 1e-3, 60
    forces = np.zeros((K, 3))
    forces[1:, 0] = 1.0  # a unit step at sample 1
    out = np.asarray(_readings(Sensor.make(0, bandwidth=fc), forces).force)[:, 0]
    k = np.arange(K)
    # y(k) = 1 − e^{−2π fc T k} for a step held from sample 1 (the exact discretisation of 1/(1 + s/(2π fc)))
    assert np.allclose(out, np.where(k >= 1, 1.0 - np.exp(-2 * np.pi * fc * T * k), 0.0), rtol=0, atol=1e-14)


# --- the motors alone -------------------------------------------------------------------------------


def test_torque_saturates_at_the_limit_and_is_rate_limited():
    act = Actuator(torque_limit=jnp.array([10.0, 100.0]), rate_limit=jnp.array([1000.0, jnp.inf]),
                   viscous=jnp.zeros(2), coulomb=jnp.zeros(2), v_smooth=jnp.asarray(0.01))
    assert np.array_equal(act.saturate(jnp.array([-25.0, 50.0])), [-10.0, 50.0])
    assert np.array_equal(act.apply(jnp.array([8.0, 80.0]), jnp.zeros(2), 1e-3, True), [8.0, 80.0])  # first sample
    applied = jnp.zeros(2)
    seen = []
    for _ in range(15):
        applied = act.apply(jnp.array([50.0, 80.0]), applied, 1e-3, False)
        seen.append(np.asarray(applied))
    seen = np.array(seen)
    assert np.allclose(seen[:10, 0], np.arange(1, 11) * 1.0) and np.all(seen[10:, 0] == 10.0)  # 1 N·m a sample, then the limit
    assert np.all(seen[:, 1] == 80.0)  # no rate limit on joint 2
    assert float(act.saturated(seen[-1])) == 1.0 and float(act.saturated(jnp.array([9.0, 80.0]))) == 0.0
    f = Actuator(torque_limit=jnp.full(2, jnp.inf), rate_limit=jnp.full(2, jnp.inf), viscous=jnp.array([2.0, 0.0]),
                 coulomb=jnp.array([0.0, 3.0]), v_smooth=jnp.asarray(0.01))
    assert np.allclose(f.friction(jnp.array([0.5, 1.0])), [1.0, 3.0 * math.tanh(100.0)])


# --- in the scenario and the simulator ---------------------------------------------------------------

#: the paper's ideal sensor and motors on planar3-drum-stable (which declares a robot's): the tests' baseline
IDEAL = ["plant.sensor.force_noise=0", "plant.sensor.delay=0", "plant.actuator.torque_limit=none",
         "controller.force_filter.order=0"]
DRUM = ["controller.kind=hinf_nn", "simulation.control=sampled", "simulation.control_period=0.001", "simulation.t_final=0.05",
        *IDEAL]


def _run(sets, plant=None):
    sc = H.load_scenario("planar3-drum-stable", DRUM + list(sets))
    r = sc.build().run()
    return H.simulate(plant or r.plant, r.controller, r.reference, q0=r.q0, t_final=r.t_final, dt=r.dt,
                      control_period=r.control_period, save_interval=r.save_interval, limits=r.limits,
                      raise_on_failure=False, info=r.info), r


NOISY = ["plant.sensor.force_noise=2.0", "plant.sensor.delay=1", "plant.sensor.seed=4", "plant.actuator.torque_limit=30",
         "plant.actuator.torque_rate_limit=20000", "plant.actuator.friction_viscous=0.2",
         "controller.force_rate.source=force", "controller.sensor.delay=0"]  # the differenced force designed as if the
# sensor were ideal (the rule's κ; designed for its delay it would not be): a law that asks for more than the motors give


@pytest.fixture(scope="module")
def noisy():
    return _run(NOISY)


def test_a_noisy_run_is_reproducible_by_its_seed(noisy):
    traj, r = noisy
    again, _ = _run(NOISY)
    other, _ = _run([*NOISY[:2], "plant.sensor.seed=5", *NOISY[3:]])
    assert int(traj.status) == 0
    for k in ("tau", "q", "normal_force"):
        assert np.array_equal(traj.arrays[k], again.arrays[k]), k
    assert not np.allclose(traj.arrays["tau"], other.arrays["tau"])


def test_the_applied_torque_is_the_commanded_one_saturated_and_recorded(noisy):
    traj, r = noisy
    a = traj.arrays
    tau, applied = a["tau"], a["tau_applied"]
    assert np.all(np.abs(applied) <= 30.0)
    assert np.max(np.abs(tau)) > 30.0  # the controller asked for more than the motors give
    rate = np.abs(np.diff(applied, axis=0)) / np.diff(a["t"])[:, None]
    assert np.all(rate[1:] <= 20000.0 * (1 + 1e-9))  # rate-limited after the first sample
    at_limit = np.any(np.abs(applied) >= 30.0, axis=1)
    assert np.array_equal(a["torque_saturated"] == 1.0, at_limit)
    m = H.compute_metrics(traj)
    assert m["fraction_torque_saturated"] == pytest.approx(at_limit.mean())
    # the true force error: the plant's normal force minus λd (λ is the normal force on the drum)
    err = a["normal_force"] - a["lam_d"][:, 0]
    assert m["rms_normal_force_error"] == pytest.approx(np.sqrt(np.mean(err**2)))


def test_batch_members_of_one_plant_have_their_own_noise(noisy):
    traj, r = noisy
    batch = H.simulate_batch(r.plant, [r.controller, r.controller], r.reference, q0=r.q0, t_final=r.t_final, dt=r.dt,
                             control_period=r.control_period, save_interval=r.save_interval, limits=r.limits)
    m0, m1 = batch.member(0), batch.member(1)
    assert not np.allclose(m0.arrays["tau"], m1.arrays["tau"])
    alone, _ = _run(NOISY, plant=r.plant.with_sensor(r.plant.sensor.stream(1)))
    assert np.allclose(m1.arrays["tau"], alone.arrays["tau"], rtol=1e-9, atol=1e-9)  # member i: stream i


def test_an_ideal_sensor_is_no_sensor_and_a_zero_one_gives_the_same_run():
    """The default (an ideal sensor and motors) builds no sensor and no actuator: the plant and
    its program are today's, bit for bit (tests/test_paper_regression.py; a UR5 on both plants
    compared array by array before and after, in the commit that added them). A sensor declared
    with zero noise, bias and delay and no bandwidth gives the controller the true measurement
    exactly: the same run, to the rounding of another compiled program."""
    ideal, r = _run([])
    assert r.plant.sensor is None and r.plant.actuator is None
    zero = dataclasses.replace(r.plant, sensor=Sensor.make(3))
    declared, _ = _run([], plant=zero)
    for k in ("tau", "q", "qd", "normal_force", "e_lam"):
        assert np.allclose(ideal.arrays[k], declared.arrays[k], rtol=1e-10, atol=1e-10), k
    m = H.compute_metrics(ideal)
    assert m["fraction_torque_saturated"] == 0.0 and m["rms_normal_force_error"] is not None


@pytest.mark.parametrize("sets, key", [
    (["plant.sensor.force_noise=1"], "plant.sensor"),
    (["plant.actuator.torque_rate_limit=1000"], "plant.actuator.torque_rate_limit"),
])
def test_continuous_control_refuses_what_needs_samples(sets, key):
    with pytest.raises(ConfigError) as err:
        H.load_scenario("planar3-drum-stable", ["simulation.t_final=0.05", "simulation.control=continuous", *IDEAL,
                                                *sets]).build().plant
    assert err.value.key == key and "sampled" in str(err.value)


@pytest.mark.parametrize("scenario, sets, key, words", [
    ("paper", ["plant.actuator.torque_limit=urdf"], "plant.actuator.torque_limit", "effort limits"),
    ("planar3-drum-stable", [*DRUM, "plant.sensor.force_bias=[1.0, 2.0, 3.0]"], "plant.sensor.force_bias", "2 numbers"),
    ("planar3-drum-stable", [*DRUM, "plant.sensor.force_bias=[1.0]"], "plant.sensor.force_bias", "2 or 3"),
    ("planar3-drum-stable", [*DRUM, "plant.actuator.torque_limit=[1.0, 2.0]"], "plant.actuator.torque_limit",
     "3 (one per joint)"),
    ("planar3-drum-stable", [*DRUM, "plant.sensor.delay=-1"], "plant.sensor.delay", ">= 0"),
])
def test_bad_sensor_and_motor_keys_name_the_key(scenario, sets, key, words):
    with pytest.raises(ConfigError) as err:
        H.load_scenario(scenario, sets).build().plant
    assert err.value.key == key and words in str(err.value)


def test_urdf_torque_limits_are_the_files_efforts():
    sc = H.load_scenario("ur5-table", ["plant.actuator.torque_limit=urdf"])
    plant = sc.build().plant
    assert np.array_equal(np.asarray(plant.actuator.torque_limit), [150.0, 150.0, 150.0, 28.0, 28.0, 28.0])


# --- sweeps ---------------------------------------------------------------------------------------

SWEEP = """
name = "noise"
scenario = "planar3-drum-stable"
controllers = ["hinf_nn"]
samples = 2
seed = 1
[set]
"simulation.t_final" = 0.02
"simulation.control" = "sampled"
"simulation.control_period" = 0.001
"plant.sensor.delay" = 1
[vary]
"plant.sensor.force_noise" = { distribution = "uniform", low = 0.5, high = 2.0 }
"""


def test_a_sweep_varies_the_sensor_noise_and_each_draw_has_its_own_stream(tmp_path):
    import tomllib

    from hinfnn.sweep import run_sweep, spec_from_dict
    from hinfnn.sweep.sampling import RunSpec
    from hinfnn.sweep.worker import own_stream, scenario_of

    spec = spec_from_dict(tomllib.loads(SWEEP))
    run_sweep(spec, tmp_path / "a", max_batch=2)
    df = H.load_sweep(tmp_path / "a")
    assert list(df["status"]) == ["ok", "ok"] and df["plant.sensor.force_noise"].nunique() == 2
    assert df["rms_normal_force_error_last2s"].notna().all() and "fraction_torque_saturated" in df.columns
    # a row is its draw's run alone, its noise on the draw's own stream
    base = spec.base.to_dict()
    for i in range(2):
        values = {"plant.sensor.force_noise": df["plant.sensor.force_noise"][i]}
        r = RunSpec(run=i, point=0, sample=i, controller="hinf_nn", values=values)
        run = own_stream(scenario_of(base, spec.base.source, values, "hinf_nn").single("hinf_nn").run("hinf_nn"), r)
        traj = H.simulate(run.plant, run.controller, run.reference, q0=run.q0, t_final=run.t_final, dt=run.dt,
                          control_period=run.control_period, limits=run.limits, info=run.info)
        assert df["rms_normal_force_error"][i] == pytest.approx(H.compute_metrics(traj)["rms_normal_force_error"],
                                                                rel=1e-9)
    # the streams: a function of the draw (grid point, sample) alone
    run = scenario_of(base, spec.base.source, {}, "hinf_nn").single("hinf_nn").run("hinf_nn")
    keys = [np.asarray(own_stream(run, RunSpec(run=j, point=p, sample=s, controller="hinf_nn", values={})).plant.sensor.key)
            for j, (p, s) in enumerate([(0, 0), (0, 1), (1, 0), (0, 0)])]
    assert len({k.tobytes() for k in keys[:3]}) == 3 and np.array_equal(keys[0], keys[3])


@pytest.mark.parametrize("override, key", [
    ("plant.sensor.force_noise=1.0", "plant.sensor"),
    ("plant.actuator.torque_limit=urdf", "plant.actuator.torque_limit"),
    ("plant.sensor.bandwidth=0", "plant.sensor.bandwidth"),
])
def test_the_cli_refuses_a_bad_sensor_or_motor_in_one_line(tmp_path, capsys, override, key):
    from hinfnn import cli

    code = cli.main(["run", "paper", "--set", override, "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and key in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()


# --- on MuJoCo ------------------------------------------------------------------------------------


def test_the_sensor_and_motors_act_on_the_mujoco_plant():
    pytest.importorskip("mujoco")
    sets = ["simulation.t_final=0.03", "plant.sensor.force_noise=1.0", "plant.sensor.delay=1",
            "plant.actuator.torque_limit=[150.0, 40.0, 150.0, 28.0, 28.0, 28.0]",
            "controller.force_filter.order=0",  # no force filter and the differenced force's rate, designed as if
            "controller.force_rate.source=force", "controller.sensor.delay=0"]  # the sensor were ideal: the
    # shoulder asks for more than 40 N m
    sc = H.load_scenario("ur5-polish", sets)
    r = sc.build().run()
    assert r.plant.sensor.delay == 1 and np.asarray(r.plant.actuator.torque_limit)[1] == 40.0

    def once(plant):
        return H.simulate(plant, r.controller, r.reference, q0=r.q0, t_final=r.t_final, dt=r.dt,
                          control_period=r.control_period, limits=r.limits, info=r.info, raise_on_failure=False)

    a, b = once(r.plant), once(r.plant)
    assert np.array_equal(a.arrays["tau"], b.arrays["tau"])  # the same seed: the same run
    end = a.valid_samples()
    applied, tau = a.arrays["tau_applied"][:end], a.arrays["tau"][:end]
    limit = np.asarray(r.plant.actuator.torque_limit)
    # (the law's τ is computed once for the record and once for the motors: equal to rounding)
    assert np.allclose(applied, np.clip(tau, -limit, limit), rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(tau[:, 1])) > 40.0 and np.max(np.abs(applied[:, 1])) == 40.0
    m = H.compute_metrics(a)
    assert 0 < m["fraction_torque_saturated"] < 1 and m["rms_normal_force_error"] is not None
