"""The phases of a job (hinfnn.controllers.job, ``[job]``): approach from free space, contact found on the
measured force, the law handed over with λd ramped, offsets of the true part, the default start in contact
unchanged, bad keys, and the robot loop's contact-loss rule during the phases."""

import math
import types

import numpy as np
import pytest

import hinfnn as H
from hinfnn.controllers.job import APPROACH, NO_CONTACT, PROCESS, RAMP, JobController
from hinfnn.errors import ConfigError
from hinfnn.metrics import compute_metrics
from hinfnn.robot import Reading, run_loop
from hinfnn.robot.safety import SafetyLimits
from hinfnn.scenario import Scenario
from hinfnn.scenario.sections import SafetyConfig
from robot_helpers import ScriptedRobot

pytestmark = pytest.mark.xdist_group("job")

#: The paper's arm on its undamped 1e5 N/m line with the force-rate term, at 1 kHz, the disturbance off (its
#: square wave moves the tool by millimetres in free space, which would blur the contact times compared below);
#: the tool starts 2 cm above the nominal line and moves towards it at 1 cm/s. One compiled program for all runs.
JOB = ["job.start=approach", "simulation.control=sampled", "simulation.t_final=3.0",
       "controller.force_rate.stiffness_max=100000.0", "plant.disturbance.amplitude=[0.0, 0.0]"]


def job_run(*extra):
    sc = Scenario.load("paper-stable", JOB + list(extra))
    return sc, sc.simulate(raise_on_failure=False)


@pytest.fixture(scope="module")
def base():
    return job_run()


def first(mask):
    return int(np.nonzero(mask)[0][0])


def test_the_job_finds_contact_and_hands_over_to_the_law(base):
    sc, tr = base
    assert isinstance(sc.build().controller(), JobController) and int(tr.status) == 0
    ph, t = np.asarray(tr.phase), np.asarray(tr.t)
    # phases in order, each once: approach, ramp, process
    assert set(np.unique(ph)) == {APPROACH, RAMP, PROCESS} and np.all(np.diff(ph) >= 0)
    i_c, i_p = first(ph == RAMP), first(ph == PROCESS)
    assert t[i_p] - t[i_c] == pytest.approx(sc.job.ramp_time, abs=2e-3)
    # started 2 cm above the NOMINAL line (the true one is 0.5 degrees steeper, a fraction of a mm off here)
    assert -np.asarray(tr.penetration)[0] == pytest.approx(0.02, abs=1e-3)
    # contact detected on the measured force at the sample the force first reaches the threshold
    F = np.linalg.norm(np.asarray(tr.F).reshape(len(t), -1), axis=1)
    threshold = sc.job.contact_threshold(0.0)  # "auto" with an ideal sensor: 2 N
    assert threshold == 2.0 and F[i_c - 1] >= threshold and np.all(F[:i_c - 1] < threshold)
    # the law's state is frozen until contact, then runs (z of eq. (27) starts at 0 at the contact)
    z = np.asarray(tr.z).reshape(len(t), -1)
    assert np.all(z[:i_c + 1] == 0.0) and np.any(z[i_c + 2:] != 0.0)
    # λd starts at the force measured at contact, reaches the reference's (shifted to the contact) after the ramp
    lam, lam_d = np.asarray(tr.lam).reshape(-1), np.asarray(tr.lam_d).reshape(-1)
    assert np.all(lam_d[:i_c] == 0.0)
    assert lam_d[i_c] == pytest.approx(lam[i_c - 1], abs=1e-4)  # the quintic is 1e-7 into its rise there
    ref = sc.build().reference
    t_c = t[i_c - 1]  # the sample that found contact; its successor is the first the law acts at
    for i in (i_p + 10, len(t) - 1):
        assert lam_d[i] == pytest.approx(float(np.asarray(ref(t[i] - t_c).lam_d).reshape(-1)[0]), rel=1e-12)


def test_the_touch_is_bounded_and_contact_is_held_after_the_ramp(base):
    sc, tr = base
    m = compute_metrics(tr)
    job = m["job"]
    assert job["peak_touch_over_lam_d"] <= 1.5
    assert job["out_of_contact_process"] == 0.0 and m["verdict"]["contact_held"] is True
    assert job["last_phase"] == PROCESS and job["process_start"] - job["contact_time"] == pytest.approx(0.5, abs=2e-3)


@pytest.mark.parametrize("offset", [-0.01, 0.005])
def test_an_offset_part_is_found_where_it_is(base, offset):
    """The true line moved by ``offset`` in d_G: the guarded move meets it earlier or later by the change of its
    distance from the start over the set speed (the distance measured on the truth at t = 0)."""
    sc0, tr0 = base
    sc, tr = job_run(f"plant.surface.d_G={0.8 + offset}")
    assert int(tr.status) == 0

    def contact(tr):
        return float(np.asarray(tr.t)[first(np.asarray(tr.phase) == RAMP)]), -float(np.asarray(tr.penetration)[0])

    (t0, d0), (t1, d1) = contact(tr0), contact(tr)
    assert abs(d1 - d0) > 0.5 * abs(offset)  # the start is as far from the NOMINAL line; the truth moved
    assert t1 - t0 == pytest.approx((d1 - d0) / sc.job.approach_speed, abs=0.02)
    assert compute_metrics(tr)["job"]["out_of_contact_process"] == 0.0


def test_the_job_unloads_and_lifts_off():
    sc, tr = job_run("plant.surface.d_G=0.79", "job.process_time=0.5", "job.lift_time=0.2")
    assert int(tr.status) == 0
    ph, t = np.asarray(tr.phase), np.asarray(tr.t)
    assert list(np.unique(ph)) == [0, 1, 2, 3, 4] and np.all(np.diff(ph) >= 0)
    i_u, i_l = first(ph == 3), first(ph == 4)
    assert t[i_l] - t[i_u] == pytest.approx(sc.job.ramp_time, abs=2e-3)
    # λd back down to the force measured at contact by the end of the unload
    lam_d, lam = np.asarray(tr.lam_d).reshape(-1), np.asarray(tr.lam).reshape(-1)
    lam_c = lam[first(ph == RAMP) - 1]
    assert lam_d[i_l - 1] == pytest.approx(lam_c, abs=1e-3)
    # lifted lift_height off the part (0.5 degrees between the nominal normal and the true one) and in the air
    done = t >= t[i_l] + sc.job.lift_time + 0.05
    np.testing.assert_allclose(-np.asarray(tr.penetration)[done], sc.job.lift_height, atol=1e-3)
    assert np.all(np.asarray(tr.normal_force)[done] == 0.0)


def test_no_contact_within_the_travel_stops_with_a_clear_status():
    sc, tr = job_run("plant.surface.d_G=0.9", "job.approach_speed=0.05", "job.approach_margin=0.005")
    assert H.RunStatus(int(tr.status)) is H.RunStatus.CONTROLLER_FAULT
    assert np.asarray(tr.phase)[-1] == NO_CONTACT
    # the travel when the guard fired: 2.5 cm, the sample after (one period at 5 cm/s: 0.05 mm) give or take one
    assert float(tr.fail_details["fault_value"]) == pytest.approx(0.025, abs=2 * 0.05 * 1e-3)
    assert "no contact found" in H.RunStatus.CONTROLLER_FAULT.describe(tr.fail_details)
    assert float(tr.t_fail) == pytest.approx(0.025 / 0.05, abs=2e-3)


def test_the_default_start_in_contact_is_todays_run_bit_for_bit():
    plain = Scenario.load("paper", ["simulation.t_final=0.05"])
    given = Scenario.load("paper", ["simulation.t_final=0.05", "job.start=contact", "job.approach_speed=0.5"])
    assert not isinstance(given.build().controller(), JobController)
    assert given.build().start_q is given.build().q0
    a, b = plain.simulate(), given.simulate()
    for k, v in a.arrays.items():
        np.testing.assert_array_equal(np.asarray(b.arrays[k]), np.asarray(v), err_msg=k)


@pytest.mark.parametrize("keys, key", [
    (["job.start=hover"], "job.start"),
    (["job.start=approach", "job.approach_speed=-0.1"], "job.approach_speed"),
    (["job.start=approach", "job.ramp_time=-1"], "job.ramp_time"),
    (["job.start=approach"], "job.start"),  # the paper's continuous control: the phases need samples
    # a threshold in the sensor's noise: given, or "auto" from a controller told the sensor is ideal
    (["job.start=approach", "simulation.control=sampled", "plant.sensor.force_noise=1.0", "job.contact_force=5"],
     "job.contact_force"),
    (["job.start=approach", "simulation.control=sampled", "plant.sensor.force_noise=1.0", "controller.sensor.noise=0"],
     "job.contact_force"),
])
def test_bad_job_keys_are_typed_errors(keys, key):
    with pytest.raises(ConfigError) as err:
        Scenario.load("paper", keys)
    assert err.value.key == key


def test_auto_contact_threshold_clears_the_assumed_noise():
    """``job.contact_force = "auto"``: 2 N with an ideal sensor, 6√3 σ with the σ the controller
    assumes (above the 5√3 σ floor of a noisy sensor's reading in free space), a number as given."""
    sc = Scenario.load("paper", ["job.start=approach", "simulation.control=sampled", "plant.sensor.force_noise=1.0"])
    assert sc.job.contact_force == "auto"
    assert sc.job.contact_threshold(0.0) == 2.0 and sc.job.contact_threshold(0.1) == 2.0
    assert sc.job.contact_threshold(1.0) == pytest.approx(6.0 * np.sqrt(3.0))
    assert float(sc.build().controller().job.contact_force) == pytest.approx(6.0 * np.sqrt(3.0))
    given = Scenario.load("paper", ["job.start=approach", "simulation.control=sampled", "job.contact_force=3"])
    assert given.job.contact_threshold(5.0) == 3.0


# --- the robot loop -----------------------------------------------------------------------------------
class PhasedLoop:
    """A job's loop as the runner sees it: a phase per call from a script, a fixed torque."""

    def __init__(self, phases):
        self.phases, self.calls = list(phases), 0

    def phase(self):
        return self.phases[min(self.calls, len(self.phases) - 1)]

    def update(self, t, h, q, qd, force):
        self.calls += 1
        return np.array([1.0, 2.0])


def drive(phases, forces, t_final):
    L = SafetyLimits.from_config(SafetyConfig(contact_loss_after=0.0, contact_loss_time=0.003, stop_time=0.002),
                                 period=1e-3, n=2)
    loop = PhasedLoop(phases)
    bot = ScriptedRobot([Reading(t=k * 1e-3, q=np.zeros(2), qd=np.zeros(2), force=np.array([0.0, -f]))
                  for k, f in enumerate(forces)])
    return run_loop(bot, types.SimpleNamespace(loop=lambda: loop), L, t_final=t_final,
                    gravity=lambda q: np.zeros(2), point_jacobian=lambda q: np.eye(2)), loop


def test_contact_loss_is_armed_in_the_process_only():
    # no force through the approach, the ramp, the unload and the lift-off: no contact loss
    phases = [0] * 10 + [1] * 5 + [2] * 10 + [3] * 5 + [4] * 10
    forces = [0.0] * 10 + [5.0] * 20 + [0.0] * 30
    log, loop = drive(phases, forces, t_final=0.039)
    assert log.stop is None and loop.calls == 40
    # the same force lost in the process phase: the rule fires
    log, _ = drive([0] * 10 + [2] * 30, [0.0] * 10 + [5.0] * 10 + [0.0] * 20, t_final=0.039)
    assert log.stop.rule == "contact_loss" and log.stop.t == pytest.approx(0.023, abs=1e-9)


def test_a_job_without_contact_stops_the_robot():
    log, loop = drive([0] * 5 + [NO_CONTACT] * 20, [0.0] * 25, t_final=0.02)
    assert log.stop.rule == "no_contact" and log.stop.action == "stop" and loop.calls == 5
    assert math.isclose(log.stop.t, 0.005)


def test_a_job_on_the_virtual_robot_is_its_simulation(tmp_path):
    """The same job through ``hinfnn robot run`` (the virtual robot in lock-step): the contact-loss rule, armed
    from 10 ms, does not fire in the approach; the phases and the law's torques are the simulation's."""
    pytest.importorskip("mujoco")
    from hinfnn.robot import VirtualRobot, run_robot

    sc = Scenario.load("paper", [
        "plant.engine=mujoco", "simulation.control=sampled", "controller.kind=hinf_nn", "plant.contact.damping=200",
        "simulation.t_final=0.1", "safety.torque_rate_limit=1e6", "safety.contact_loss_after=0.01",
        "job.start=approach", "job.approach_height=0.005", "job.approach_speed=0.2", "job.ramp_time=0.02"])
    res = run_robot(sc, robot=VirtualRobot(sc, realtime=False), out=tmp_path / "job", figures=False,
                    log=lambda _: None)
    assert res.log.stop is None and res.doc["runs"][0]["status"] == "ok"
    traj = H.load(res.target).trajectories["hinf_nn"]
    sim = sc.simulate()
    np.testing.assert_array_equal(traj.phase, sim.phase)
    assert set(np.unique(traj.phase)) == {APPROACH, RAMP, PROCESS}
    np.testing.assert_allclose(traj.tau_law[:-1], sim.tau[:-1], rtol=0, atol=1e-9)
    job = res.doc["runs"][0]["metrics"]["job"]
    assert job["contact_time"] == pytest.approx(float(np.asarray(sim.t)[first(np.asarray(sim.phase) == RAMP)]))
