"""The user's own arm: real URDFs (the shipped Panda, UR10, Kinova Jaco 2 and UR5 from
example-robot-data) against Pinocchio, how a ``file`` value is resolved and refused, redundant
arms through extra task coordinates, joint limits, and the run's verdicts.

Pinocchio is the oracle: the same file is built with ``pinocchio.buildModelFromXML`` and its
whole model (grippers and fingers at their neutral positions, at rest) is restricted to the
chain's joints, which is what hinfnn's merging of side branches with their joints at zero means.
"""

from __future__ import annotations

import os
import re
import shutil
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import numpy as np
import pinocchio as pin  # the oracle (a test dependency)
import pytest

import hinfnn as H
from hinfnn import cli
from hinfnn.controllers.law import measured_force
from hinfnn.model.urdf import UrdfError, load_urdf, robot_file, shipped_robots
from hinfnn.scenario import Scenario

#: one xdist worker: the tests share compiled programs
pytestmark = pytest.mark.xdist_group("user_arms")

#: (shipped name, base link, end-effector link, tool xyz): the arm chains of the shipped files
ARMS = [
    ("panda", "panda_link0", "panda_link8", (0.0, 0.0, 0.1)),
    ("ur10", "base_link", "tool0", (0.0, 0.0, 0.1)),
    ("kinova", "base", "j2s6s200_end_effector", (0.0, 0.0, 0.0)),
    ("ur5", "base_link", "tool0", (0.0, 0.0, 0.1)),
]


def pinocchio_chain_terms(text, chain, base, ee, tool_xyz, q, qd):
    """M, C q̇ + G and the tool frame's Jacobian (base-frame axes) of Pinocchio's whole model of
    ``text`` restricted to the chain's joints (the others neutral and at rest)."""
    model = pin.buildModelFromXML(text)
    data = model.createData()
    joints = [model.joints[model.getJointId(name)] for name in chain.joint_names]
    iv = [jm.idx_v for jm in joints]
    qp, vp = pin.neutral(model), np.zeros(model.nv)
    for k, jm in enumerate(joints):
        if jm.nq == 2:  # continuous: (cos, sin)
            qp[jm.idx_q:jm.idx_q + 2] = (np.cos(q[k]), np.sin(q[k]))
        else:
            qp[jm.idx_q] = q[k]
        vp[jm.idx_v] = qd[k]
    fe = model.getFrameId(ee, pin.FrameType.BODY)
    frame = model.frames[fe]
    tool = model.addFrame(pin.Frame("tcp", frame.parentJoint, fe, frame.placement * pin.SE3(np.eye(3), np.asarray(
        tool_xyz, float)), pin.FrameType.OP_FRAME))
    data = model.createData()
    pin.framesForwardKinematics(model, data, qp)
    Rb = data.oMf[model.getFrameId(base, pin.FrameType.BODY)].rotation.copy()
    M = np.asarray(pin.crba(model, data, qp))
    M = (np.triu(M) + np.triu(M, 1).T)[np.ix_(iv, iv)]
    bias = np.asarray(pin.nonLinearEffects(model, data, qp, vp))[iv]
    pin.computeJointJacobians(model, data, qp)
    pin.updateFramePlacements(model, data)
    J = np.asarray(pin.getFrameJacobian(model, data, tool, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED))[:, iv]
    return M, bias, np.vstack([Rb.T @ J[:3], Rb.T @ J[3:]]), Rb.T @ model.gravity.linear


@pytest.mark.parametrize("name, base, ee, tool", ARMS, ids=[a[0] for a in ARMS])
def test_shipped_arms_against_pinocchio(name, base, ee, tool):
    """M, C q̇ + G and J of every shipped real arm equal Pinocchio's to 1e-12 (relative to the
    largest entry, at least 1) on 10 seeded random states, every joint inside and outside its range."""
    path = shipped_robots()[name]
    text = open(path, encoding="utf-8").read()
    chain = load_urdf(name, base, ee, tool_xyz=tool)
    program = jax.jit(lambda c, q, qd: (c.M(q), c.bias(q, qd), c.frame_jacobian(q)))
    rng = np.random.default_rng(31)
    worst = 0.0
    for _ in range(10):
        q, qd = rng.uniform(-3.0, 3.0, chain.n), rng.normal(size=chain.n)
        M_ref, b_ref, J_ref, g = pinocchio_chain_terms(text, chain, base, ee, tool, q, qd)
        got = program(chain.with_gravity(g), q, qd)
        for a, b in zip(got, (M_ref, b_ref, J_ref)):
            worst = max(worst, float(np.max(np.abs(np.asarray(a) - b)) / max(1.0, np.max(np.abs(b)))))
    assert worst < 1e-12, worst


def test_shipped_files_are_complete():
    """Every shipped robot has its licence and a README beside it, and the packaged names."""
    names = shipped_robots()
    assert {"ur5", "ur10", "panda", "kinova", "planar/three_link", "planar/sec6_two_link"} <= set(names)
    for name in ("ur5", "ur10", "panda", "kinova"):
        folder = os.path.dirname(names[name])
        for f in ("LICENSE", "README.md"):
            assert os.path.getsize(os.path.join(folder, f)) > 300, (name, f)
        text = open(names[name], encoding="utf-8").read()
        tags = {el.tag for el in ET.fromstring(text).iter()}
        assert not tags & {"visual", "collision", "gazebo", "transmission"} and "example-robot-data" in text


def test_panda_chain_structure():
    chain = load_urdf("panda", "panda_link0", "panda_link8")
    assert chain.n == 7 and chain.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    np.testing.assert_allclose(np.asarray(chain.lower)[[1, 3]], [-1.7628, -3.0718])
    np.testing.assert_allclose(np.asarray(chain.upper)[[1, 3]], [1.7628, -0.0698])
    # the hand and its fingers (0.73 + 2 x 0.015 kg) are merged into the last body
    assert abs(float(chain.mass[-1]) - (0.735522 + 0.73 + 0.03)) < 1e-12


# --------------------------------------------------------------------------------------------
# What a `file` value names
# --------------------------------------------------------------------------------------------
def test_any_file_name_is_a_file(tmp_path):
    """A URDF named panda.xml, or without an extension, is read as a file (not taken for a shipped
    name), and a shipped name is a shipped robot."""
    for fname in ("panda.xml", "robot"):
        dst = tmp_path / fname
        shutil.copy(shipped_robots()["panda"], dst)
        assert robot_file(str(dst)) == str(dst)
        assert load_urdf(str(dst), "panda_link0", "panda_link8").n == 7
    assert robot_file("ur10") == shipped_robots()["ur10"]


@pytest.mark.parametrize("make, pattern", [
    (lambda d: str(d / "arm.urdf.xacro"), r"is a xacro file: expand it with xacro first"),
    (lambda d: str(d), r"is a folder, not a URDF file.*\(it holds a.urdf\)"),
    (lambda d: str(d / "missing.urdf"), r"no such file; .*shipped with hinfnn: 'fr3', 'kinova', 'panda'"),
    (lambda d: "pandaa", r"is neither a file nor a robot shipped with hinfnn \(.*'ur5'.*\); did you mean 'panda'\?"),
])
def test_file_values_refused(tmp_path, make, pattern):
    (tmp_path / "a.urdf").write_text("<robot name='x'/>")
    (tmp_path / "arm.urdf.xacro").write_text("<robot/>")
    with pytest.raises(UrdfError, match=pattern):
        load_urdf(make(tmp_path), "a", "b")


@pytest.mark.parametrize("text, pattern", [
    ('<robot name="r" xmlns:xacro="http://wiki.ros.org/xacro"><xacro:property name="l" value="1"/></robot>',
     "contains xacro macros or properties: expand it with xacro first"),
    ('<robot name="r"><link name="a"><inertial><mass value="${m}"/></inertial></link></robot>',
     "contains xacro macros or properties"),
    ('<mujoco model="m"/>', r"root element is <mujoco> \(an MJCF file: hinfnn reads URDF\)"),
])
def test_xacro_and_mjcf_content_refused(tmp_path, text, pattern):
    path = tmp_path / "robot.urdf"
    path.write_text(text)
    with pytest.raises(UrdfError, match=pattern):
        load_urdf(str(path), "a", "b")


def _scenario_with_file(tmp_path, value):
    sc = tmp_path / "s.toml"
    sc.write_text(f'base = "ur5-table"\n[plant.arm]\nfile = "{value}"\n[nominal.arm]\nfile = "{value}"\n')
    return str(sc)


def test_scenario_file_relative_to_the_scenario(tmp_path):
    """``plant.arm.file = "ur5.xml"`` beside the scenario file is that file."""
    shutil.copy(shipped_robots()["ur5"], tmp_path / "ur5.xml")
    sc = Scenario.load(_scenario_with_file(tmp_path, "ur5.xml"), check=False)
    assert sc.plant.arm.file == str(tmp_path / "ur5.xml")
    assert sc.build().plant.arm.n == 6


def test_set_file_not_in_the_working_directory_is_beside_the_scenario(tmp_path, monkeypatch):
    """``--set nominal.arm.file=ur5b.xml`` from another folder: no such file in the working
    directory, so the one beside the scenario file, made absolute."""
    shutil.copy(shipped_robots()["ur5"], tmp_path / "ur5.xml")
    shutil.copy(shipped_robots()["ur5"], tmp_path / "ur5b.xml")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    sc = Scenario.load(_scenario_with_file(tmp_path, "ur5.xml"), ["nominal.arm.file=ur5b.xml"], check=False)
    assert sc.nominal.arm.file == str((tmp_path / "ur5b.xml").resolve())


@pytest.mark.parametrize("value, pattern", [
    ("arm.urdf.xacro", "is a xacro file: expand it with xacro first"),
    ("folder", "is a folder, not a URDF file"),
    ("nothere.xml", "no such file; give the path of a URDF file"),
    ("ur55", "is neither a file nor a robot shipped with hinfnn .*did you mean 'ur5'"),
])
def test_scenario_file_errors_exit_2(tmp_path, capsys, value, pattern):
    """Each refusal is one line naming plant.arm.file and what is allowed, exit code 2, and nothing
    is written."""
    (tmp_path / "folder").mkdir()
    (tmp_path / "arm.urdf.xacro").write_text("<robot/>")
    with pytest.raises(H.ConfigError, match=pattern) as info:
        Scenario.load(_scenario_with_file(tmp_path, value))
    assert info.value.key == "plant.arm.file"
    before = sorted(os.listdir(tmp_path))
    out = tmp_path / "out"
    assert cli.main(["run", _scenario_with_file(tmp_path, value), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "plant.arm.file" in err[0], err
    assert sorted(os.listdir(tmp_path)) == before and not out.exists()


# --------------------------------------------------------------------------------------------
# Redundant arms: extra task coordinates
# --------------------------------------------------------------------------------------------
def _panda_arms():
    """The Panda of panda-table with the arm angle, and with panda_joint3's angle, as extra
    coordinates (nominal arms), and the start pose."""
    sc = Scenario.load("panda-table", check=False)
    q0 = np.asarray(sc.initial_q())
    joint = Scenario.load("panda-table", {"task.extra": ["panda_joint3"]}, check=False)
    return sc, q0, {"arm_angle": sc.build().nominal_arm, "panda_joint3": joint.build().nominal_arm}


@pytest.fixture(scope="module")
def panda():
    return _panda_arms()


def test_augmented_terms_match_autodiff(panda):
    """x, Ĵ, J̇̂ of the augmented Panda (both kinds of extra coordinate): Ĵ = ∂h/∂q and J̇̂ = dĴ/dt by
    forward-mode autodiff of h, on 5 seeded states; every set of terms (terms, law_terms with the
    product J̇̂v, plant_terms) gives the same rows, the extra one before the constrained one."""
    from hinfnn.model.arm import Arm

    _, q0, arms = panda
    rng = np.random.default_rng(7)

    def program(arm, q, qd, v):
        t, lt, pt = arm.terms(q, qd), arm.law_terms(q, qd), arm.plant_terms(q, qd)
        return dict(x=t.x, J=t.J, Jd=t.J_dot, J_ad=Arm.J(arm, q), Jd_ad=Arm.J_dot(arm, q, qd), lx=lt.x, lJ=lt.J,
                    lJdv=arm.J_dot_times(lt, q, qd, v), px=pt.x, pJ=pt.J, h=arm.h(q), base=arm.arm.h(q))

    run = jax.jit(program)
    for name, arm in arms.items():
        for _ in range(5):
            q, qd, v = q0 + 0.2 * rng.normal(size=7), rng.normal(size=7), rng.normal(size=7)
            r = {k: np.asarray(x) for k, x in run(arm, q, qd, v).items()}
            np.testing.assert_allclose(r["J"], r["J_ad"], atol=1e-12, err_msg=name)
            np.testing.assert_allclose(r["Jd"], r["Jd_ad"], atol=1e-11, err_msg=name)
            np.testing.assert_allclose(r["lJdv"], r["Jd"] @ v, atol=1e-11, err_msg=name)
            for k in ("lx", "px", "h"):
                np.testing.assert_allclose(r[k], r["x"], atol=1e-15)
            for k in ("lJ", "pJ"):
                np.testing.assert_allclose(r[k], r["J"], atol=1e-15)
            np.testing.assert_allclose(r["x"][[0, 1, 2, 3, 4, 6]], r["base"], atol=0)
            if name == "panda_joint3":
                assert r["x"][5] == q[2] and np.all(r["J"][5] == np.eye(7)[2])


def test_arm_angle_against_pinocchio_joint_placements(panda):
    """ψ from the shoulder, elbow and wrist joint origins of Pinocchio's model (an independent
    forward kinematics) equals the ArmAngle coordinate to 1e-12 on 10 seeded poses."""
    _, q0, arms = panda
    arm = arms["arm_angle"]
    model = pin.buildModelFromXML(open(shipped_robots()["panda"], encoding="utf-8").read())
    data = model.createData()
    ids = [model.getJointId(f"panda_joint{i}") for i in (2, 4, 6)]
    value = jax.jit(lambda a, q: a.h(q)[5])
    rng = np.random.default_rng(11)
    for _ in range(10):
        q = q0 + 0.3 * rng.normal(size=7)
        qp = pin.neutral(model)
        qp[:7] = q
        pin.forwardKinematics(model, data, qp)
        S, E, W = (data.oMi[i].translation for i in ids)
        u = (W - S) / np.linalg.norm(W - S)
        e = (E - S) - ((E - S) @ u) * u
        v = np.array([0.0, 0.0, 1.0]) - u[2] * u
        psi = np.arctan2(u @ np.cross(v, e), v @ e)
        assert abs(float(value(arm, q)) - psi) < 1e-12


def test_force_is_the_normal_force_with_extra_coordinates(panda):
    """The sensor's force in augmented task coordinates (Ĵᵀ F = J_pᵀ f = τ_c): its last entry, λ for fitted
    coordinates, is the normal force (the true table as the nominal one here; tilted by 3°, it is
    f cos 3°), whatever the extra coordinate is."""
    sc = panda[0]
    for extra in (["arm_angle"], ["panda_joint3"]):
        one = Scenario.load("panda-table", {"task.extra": extra, "plant.friction.coulomb": 0.0,
                                            "plant.friction.viscous": 0.0, "plant.surface.normal": [0, 0, 1],
                                            "plant.surface.point": [0.5, 0, 0]}, check=False)
        plant = one.build_plant()
        q = np.asarray(one.initial_q(plant))
        x = np.array(plant.arm.h(q))
        x[-1] += 1e-4  # 0.1 mm deeper (d > 0 inside): into the true table
        q_in = np.asarray(plant.arm.inverse_kinematics(x, q))
        meas, cache = plant.sense(0.0, plant.initial_state(q_in))
        assert float(cache.normal_force) > 1.0
        # the force the controller works with: the sensor's tool-point force mapped by the arm's
        # Jacobians (here the true arm's, as nominal = true kinematics)
        F = measured_force(plant.arm.J(q_in), plant.arm.point_jacobian(q_in), meas.force)
        np.testing.assert_allclose(float(F[-1]), float(cache.normal_force), rtol=1e-9)
    del sc


def test_panda_table_without_locking(panda):
    """panda-table: 7 moving joints, m = 6 motion coordinates (ψ the sixth), the reference of ψ
    holds its start value, networks and gains per motion coordinate, Q_p 12 x 12."""
    sc, q0, arms = panda
    assert not sc.plant.arm.locked_joints and sc.build_plant().n == 7
    assert [n for n, _ in sc.coordinate_names()] == ["s1", "s2", "r_x", "r_y", "r_z", "psi", "d"]
    ref = sc.build_reference()
    psi0 = float(np.asarray(arms["arm_angle"].h(q0))[5])
    for t in (0.0, 3.7, 10.0):
        r = ref(t)
        assert r.u1_d.shape == (6,) and abs(float(r.u1_d[5]) - psi0) < 1e-12 and float(r.u1_d_dot[5]) == 0.0
    ctrl = sc.build_controller("hinf_nn")
    assert (ctrl.m, ctrl.k) == (6, 1) and np.asarray(ctrl.P_p).shape == (12, 12)
    # the reference may also give psi its own (6 entries): then it is used as given
    six = Scenario.load("panda-table", {"reference.u1_offset": [0, 0, 0, 0, 0, 0.1],
                                        "reference.u1_amplitude": [0.08, 0.08, 0, 0, 0, 0],
                                        "reference.u1_period": 4.0, "reference.u1_phase": 0.0}, check=False)
    assert float(six.build_reference()(5.0).u1_d[5]) == 0.1


def test_panda_runs_without_a_locked_joint(tmp_path):
    """A short adaptive run of panda-table: status ok, in contact, every joint inside its range,
    the arm angle and the joint limit margins recorded."""
    sc = Scenario.load("panda-table", {"controller.kind": "hinf_nn", "simulation.t_final": 0.02})
    tr = sc.simulate()
    assert int(tr.status) == 0
    assert tr.e_u1.shape[1] == 6 and tr.joint_limit_margin.shape[1] == 7
    assert np.min(tr.joint_limit_margin) > 0.3
    m = H.compute_metrics(tr)
    assert m["verdict"]["within_joint_limits"] is True and m["verdict"]["min_joint_limit_margin"] > 0.3


@pytest.mark.parametrize("overrides, key, pattern", [
    ({"task.extra": ["panda_joint9"]}, "task.extra", r"'panda_joint9' is not a moving joint.*did you mean"),
    ({"task.extra": []}, "task.extra", r"n = 7 moving joints .* have 6.*add 1 extra task coordinate with task.extra"),
    ({"task.extra": ["arm_angle", "panda_joint3"]}, "task.map", r"n = 7 moving joints .* have 8"),
    ({"task.arm_angle_joints": ["panda_joint4", "panda_joint2", "panda_joint6"]}, "task.arm_angle_joints",
     "chain order"),
    ({"task.arm_angle_reference": [0, 0, 0]}, "task.arm_angle_reference", "must not be zero"),
    ({"reference.u1_amplitude": [0.08, 0.08, 0, 0]}, "reference.u1_amplitude",
     r"a list of 5 numbers, as reference.u1_offset"),
])
def test_extra_coordinate_errors(overrides, key, pattern):
    with pytest.raises(H.ConfigError, match=pattern) as info:
        Scenario.load("panda-table", overrides).build_plant()
    assert info.value.key == key


def test_two_link_arm_has_no_extra_coordinates():
    with pytest.raises(H.ConfigError, match="two_link arm has no extra coordinates") as info:
        Scenario.load("paper", {"task.extra": ["arm_angle"]}, check=False).task_map()
    assert info.value.key == "task.extra"


# --------------------------------------------------------------------------------------------
# Joint limits
# --------------------------------------------------------------------------------------------
def test_start_guess_outside_the_limits_gives_a_pose_within(panda):
    """The UR5's start guess for the Panda (joint 2 at -1, joint 4 at -2.17 ... the 7th at 0, and
    the issue's Newton ended with joint 2 at -3.74 rad from such a guess): a pose within every range."""
    sc = Scenario.load("panda-table", {"initial.q_guess": [0.0, -1.0, 1.6, -2.17, -1.57, -1.57, 0.0]})
    plant = sc.build_plant()
    q = np.asarray(sc.initial_q(plant))
    lo, hi = (np.asarray(v) for v in plant.joint_limits())
    assert np.all(np.isfinite(q)) and np.all(q >= lo) and np.all(q <= hi)
    x = np.asarray(plant.arm.h(q))
    np.testing.assert_allclose(x[:5], 0.0, atol=1e-10)


def test_no_start_pose_within_the_limits_names_the_joint(tmp_path, capsys):
    """u1(0) 5 cm in front of the base is reachable only with the elbow past its range: exit 2,
    one line naming initial.u1, the joint, its value and its range; nothing written."""
    sets = ["initial.u1=[-0.45, 0, 0, 0, 0]", "reference.u1_offset=[-0.45, 0, 0, 0, 0]"]
    with pytest.raises(H.ConfigError, match=r"no start pose within the true arm's joint limits.*panda_joint4 = "
                       r"-3.8\d* rad \(range \[-3.072, -0.0698\]\)") as info:
        Scenario.load("panda-table", sets)
    assert info.value.key == "initial.u1"
    out = tmp_path / "out"
    assert cli.main(["run", "panda-table", *[a for s in sets for a in ("--set", s)], "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "initial.u1" in err[0] and "panda_joint4" in err[0] and not out.exists()


def test_reference_path_past_a_limit_is_a_design_error():
    """The path's joint limit is named (without the force-rate term, whose design over the path's poses
    would refuse the path first, as out of the arm's reach: also a DesignError)."""
    with pytest.raises(H.DesignError, match=r"takes panda_joint4 to -3.1\d* rad at t = 2 s, outside its range "
                       r"\[-3.072, -0.0698\]") as info:
        Scenario.load("panda-table", {"initial.u1": [-0.2, 0, 0, 0, 0], "reference.u1_offset": [-0.2, 0, 0, 0, 0],
                                      "controller.force_rate.kappa": 0.0})
    assert info.value.key == "reference"
    with pytest.raises(H.DesignError, match="move the reference into the arm's reach"):
        Scenario.load("panda-table", {"initial.u1": [-0.2, 0, 0, 0, 0], "reference.u1_offset": [-0.2, 0, 0, 0, 0]})


def test_run_stops_at_a_joint_limit():
    """The true arm's limits 1 mrad around the start pose of joint 2 (a URDF with a narrow
    range): the run stops (the plant's guard), names the joint, its metrics partial, the verdicts say
    so; the nominal model keeps the file's limits (the check is the plant's)."""
    from hinfnn.results import run_entry

    sc = Scenario.load("planar3-drum", {"controller.kind": "hinf", "simulation.t_final": 0.3})
    run = sc.run()
    chain = run.plant.arm.chain
    lo = np.asarray(chain.lower).copy()
    hi = np.asarray(chain.upper).copy()
    lo[1], hi[1] = run.q0[1] - 1e-3, run.q0[1] + 1e-3
    arm = dataclasses_replace(run.plant.arm, chain=dataclasses_replace(chain, lower=jax.numpy.asarray(lo),
                                                                        upper=jax.numpy.asarray(hi)))
    plant = dataclasses_replace(run.plant, arm=arm)
    tr = H.simulate(plant, run.controller, run.reference, q0=run.q0, info=run.info, raise_on_failure=False,
                    **sc.sim_options())
    assert tr.run_status is H.RunStatus.PLANT_FAULT and 0 < float(tr.t_fail) < 0.3
    assert tr.fail_details["fault_item"] == "joint 2 (joint2)" and float(tr.fail_details["fault_value"]) < 0
    entry = run_entry("hinf", tr)
    assert re.search(r"stopped by the plant's guard \(joint limit margin .* = -\d.*e-0\d at joint 2 \(joint2\)\)",
                     entry["reason"]), entry["reason"]
    assert entry["partial"] and entry["verdict"]["within_joint_limits"] is False
    assert entry["verdict"]["tracking_within_tolerance"] is False
    with pytest.raises(H.SimulationError, match="joint limit margin"):
        H.simulate(plant, run.controller, run.reference, q0=run.q0, **sc.sim_options())


def dataclasses_replace(obj, **kw):
    import dataclasses

    return dataclasses.replace(obj, **kw)


# --------------------------------------------------------------------------------------------
# Verdicts and the disturbance's effect
# --------------------------------------------------------------------------------------------
def _fake_run(e_u1, e_lam, lam_d, penetration, dt=1e-3, status=0):
    """A Trajectory of given samples (no step summaries: the metrics use the samples)."""
    from hinfnn.sim import Trajectory

    n = len(penetration)
    t = np.arange(n) * dt
    arrays = {"t": t, "e_u1": np.asarray(e_u1, float), "e_lam": np.asarray(e_lam, float).reshape(n, 1),
              "tau": np.zeros((n, 2)), "lam_d": np.asarray(lam_d, float).reshape(n, 1),
              "penetration": np.asarray(penetration, float), "normal_force": np.ones(n)}
    return Trajectory(arrays=arrays, status=np.asarray(status), t_fail=np.asarray(np.nan if status == 0 else t[-1]),
                      fail_details={}, dt=dt, save_every=1)


def test_a_network_held_on_its_projection_ball_is_named_in_the_notes_of_a_run_that_missed():
    """F_f's weights at the radius for 60 % of the last 2 s (the iiwa 14's base design: its design ball
    of 15 N against 16-34 N of force-side uncertainty) give one line naming the network, the radius and
    the key; 40 % gives none, nor does a network that does not project; a run that did its job keeps
    its notes as they are."""
    from types import SimpleNamespace

    from hinfnn.controllers import terms as T
    from hinfnn.experiment.result import explain
    from hinfnn.metrics import projection_notes

    n = 3001
    tr = _fake_run(np.zeros((n, 1)), np.zeros(n), np.full(n, 15.0), np.zeros(n))
    norm = np.full(n, 0.5)
    norm[-1200:] = 1.39  # the last 1.2 s of the last 2 s: 60 %
    tr.arrays["theta_f_norm"] = norm
    tr.arrays["theta_p_norm"] = np.full(n, 7.0)
    ball = SimpleNamespace(project=True, radius=np.asarray(1.39))
    law = SimpleNamespace(terms=(SimpleNamespace(network=ball, key=T.ForceNetwork.key),
                                 SimpleNamespace(network=SimpleNamespace(project=True, radius=np.asarray(7.78)),
                                                 key=T.PositionNetwork.key)))
    (note,) = projection_notes(law, tr)
    assert note.startswith("F_f's weights sat on their projection ball (radius 1.39, controller.adaptation.radius_f) "
                           "for 60% of the last 2 s") and "radius_f knob" in note
    tr.arrays["theta_f_norm"] = np.where(np.arange(n) >= n - 800, 1.39, 0.5)  # 40 %
    assert projection_notes(law, tr) == []
    tr.arrays["theta_f_norm"] = norm
    free = SimpleNamespace(terms=(SimpleNamespace(network=SimpleNamespace(project=False, radius=np.asarray(1.39)),
                                                  key=T.ForceNetwork.key),))
    assert projection_notes(free, tr) == []
    missed = {"verdict": {"contact_held": True, "tracking_within_tolerance": False, "notes": ["force: ..."]}}
    explain(missed, law, tr)
    assert missed["verdict"]["notes"] == ["force: ...", note]
    done = {"verdict": {"contact_held": True, "tracking_within_tolerance": True, "notes": []}}
    explain(done, law, tr)
    assert done["verdict"]["notes"] == []


def test_verdicts_judge_each_coordinate_in_its_unit():
    """3 s of samples: a position coordinate 3 mm off and an angle 0.03 rad off over the last 2 s,
    a force error of 5 % of λd = 20 N, contact lost once at 0.2 s (before contact_after) and once
    at 2.5 s. The verdicts and their notes follow the tolerances given, in each coordinate's unit."""
    n = 3001
    e_u1 = np.column_stack([np.full(n, 0.003), np.full(n, 0.03)])
    pen = np.zeros(n)
    pen[200] = pen[2500] = -1e-3
    tr = _fake_run(e_u1, np.full(n, 1.0), np.full(n, 20.0), pen)
    coords = [("s", "m"), ("phi", "rad")]
    m = H.compute_metrics(tr, coordinates=coords)["verdict"]  # the defaults: 5 mm, 0.02 rad, 10 %, after 0.5 s
    assert m["tracking_within_tolerance"] is False and m["contact_held"] is False
    assert m["force_error_ratio_last2s"] == pytest.approx(0.05)
    assert m["out_of_contact_after"] == pytest.approx(1 / 2500)
    assert m["notes"] == ["off the surface for 0.04% of the steps after 0.5 s (allowed: 0.00%)",
                                  "phi: RMS error 0.03 rad over the last 2 s (allowed: 0.02 rad)"]
    loose = H.compute_metrics(tr, coordinates=coords,
                              tolerances={"angle_tolerance": 0.05, "out_of_contact": 0.001})["verdict"]
    assert loose["tracking_within_tolerance"] is True and loose["contact_held"] is True and not loose["notes"]
    tight = H.compute_metrics(tr, coordinates=coords, tolerances={"position_tolerance": 0.001, "force_tolerance": 0.01,
                                                                   "angle_tolerance": 0.05, "contact_after": 3.0})
    tight = tight["verdict"]
    assert tight["contact_held"] is None and tight["out_of_contact_after"] is None  # no step after 3 s: not judged
    assert tight["notes"] == ["contact not judged: no step after 3 s (verdict.contact_after)",
                              "s: RMS error 0.003 m over the last 2 s (allowed: 0.001 m)",
                                      "force: RMS error over the last 2 s 5.0% of the mean |λd| (allowed: 1%)"]
    stopped = H.compute_metrics(_fake_run(e_u1 * 0, np.zeros(n), np.full(n, 20.0), np.zeros(n), status=2))
    assert stopped["verdict"]["tracking_within_tolerance"] is False and stopped["partial"]


def test_contact_is_not_judged_without_a_step_after_contact_after():
    """A 0.2-s run 99.5 % of its samples off the surface: no step after contact_after (0.5 s), so
    contact_held is None (null in metrics.json), with a note; the run summary says so. One step
    after it is judged."""
    from hinfnn.report.markdown import job_done

    n = 201
    pen = np.full(n, -1e-3)
    pen[0] = 0.0
    short = H.compute_metrics(_fake_run(np.zeros((n, 1)), np.zeros(n), np.full(n, 20.0), pen))["verdict"]
    assert short["contact_held"] is None and short["out_of_contact_after"] is None
    assert short["notes"][0] == "contact not judged: no step after 0.5 s (verdict.contact_after)"
    assert job_done({"verdict": short}) == "yes (contact not judged)"
    judged = H.compute_metrics(_fake_run(np.zeros((n, 1)), np.zeros(n), np.full(n, 20.0), pen),
                               tolerances={"contact_after": 0.199})["verdict"]
    assert judged["contact_held"] is False and judged["out_of_contact_after"] == 1.0
    assert job_done({"verdict": judged}) == "no: contact lost"


def test_verdict_section_and_metrics_json(tmp_path):
    """[verdict] tolerances reach the run's metrics; metrics.json has the verdicts next to the
    status, and the run summary a "did its job" column."""
    from hinfnn.results import run_entry

    sc = Scenario.load("paper", {"controller.kind": "hinf", "simulation.t_final": 0.5,
                                 "verdict.position_tolerance": 1e-9})
    tr = sc.simulate()
    e = run_entry("hinf", tr)
    assert e["verdict"]["tracking_within_tolerance"] is False
    # t_final = contact_after = 0.5 s: contact not judged (null), said in the first note
    assert e["verdict"]["contact_held"] is None and e["verdict"]["notes"][0].startswith("contact not judged")
    assert e["verdict"]["notes"][1].startswith("u1: RMS error") and "(allowed: 1e-09 m)" in e["verdict"]["notes"][1]
    assert e["verdict"]["within_joint_limits"] is None  # the two_link arm records no limits
    out = tmp_path / "run"
    assert cli.main(["run", "paper", "--set", "controller.kind=hinf", "--set", "simulation.t_final=0.2",
                     "--set", "verdict.position_tolerance=1", "--set", "verdict.force_tolerance=100",
                     "--out", str(out), "--no-figures"]) == 0
    import json

    doc = json.loads((out / "metrics.json").read_text())
    (run,) = doc["runs"]
    assert list(run)[:8] == ["name", "controller", "label", "overrides", "tags", "status", "t_fail", "reason"]
    v = run["verdict"]
    # 0.2 s: no step after verdict.contact_after (0.5 s), contact not judged (null)
    assert (v["contact_held"], v["tracking_within_tolerance"], v["within_joint_limits"], v["notes"]) == (
        None, True, None, ["contact not judged: no step after 0.5 s (verdict.contact_after)"])
    assert "verdict" not in run["metrics"] and v["min_joint_limit_margin"] is None
    from hinfnn.report.markdown import metrics_table

    assert "did its job" in metrics_table(doc, markdown=False) and "| yes (contact not judged) |" in metrics_table(doc)


def test_disturbance_effect_is_the_constrained_acceleration_over_K_p():
    """Scenario.disturbance_effect() = K_p⁻¹ M̄11⁻¹ B̄1 ω equals the acceleration of the motion
    coordinates with the contact holding the constrained one (a second method: ẍ = Ĵ M̂⁻¹(ω − Ĵᵀ e_k f)
    with ẍ_last = 0), divided by K_p; and the UR10 with the UR5's torques gets 20-40 times the UR5's."""
    ur5 = Scenario.load("ur5-table", check=False)
    q = np.asarray(ur5.initial_q())
    arm = ur5.build().nominal_arm
    J, M = np.asarray(arm.J(q)), np.asarray(arm.M(q))
    w = np.asarray(ur5.plant.disturbance.amplitude)
    A = J @ np.linalg.solve(M, J.T)
    free = J @ np.linalg.solve(M, w)
    acc = free[:-1] - A[:-1, -1] * free[-1] / A[-1, -1]
    got = np.array([v for _, _, v in ur5.disturbance_effect()])
    np.testing.assert_allclose(got, np.abs(acc) / 400.0, rtol=1e-9)
    ur10 = Scenario.load("ur5-table", {"plant.arm.file": "ur10", "nominal.arm.file": "ur10"}, check=False)
    big = np.array([v for _, _, v in ur10.disturbance_effect()])
    assert 20 < big[4] / got[4] < 40 and big[4] > 1.0  # r_z: 2.4 rad against 0.073


# --------------------------------------------------------------------------------------------
# The smaller defects of the scenario layer (issue 31), each with what it now says
# --------------------------------------------------------------------------------------------
def test_numbers_lists_are_not_called_names():
    from hinfnn.scenario import keys

    rows = keys()
    assert not [k for k, _, allowed, _ in rows if "list of names" in allowed]
    allowed = dict((k, a) for k, _, a, _ in rows)
    assert allowed["controller.gains.K_p"] == "a number > 0 and <= 1e+08 or a list of numbers > 0 and <= 1e+08"


def test_keys_lists_each_plant_key_once():
    """`hinfnn keys`: the plant.* keys every engine has are listed once, untagged; MuJoCo's own keys
    carry [engine = 'mujoco']."""
    from hinfnn.scenario import keys

    rows = keys()
    plant = [k for k, *_ in rows if k.startswith("plant.arm.") or k.startswith("plant.contact.")]
    assert plant.count("plant.contact.stiffness") == 1 and plant.count("plant.arm.m1") == 1
    assert len(rows) == len(set((k, d) for k, d, *_ in rows))
    docs = {k: d for k, d, *_ in rows}
    assert docs["plant.integrator"].endswith("[engine = 'mujoco']")
    assert "[engine" not in docs["plant.contact.stiffness"]


@pytest.mark.parametrize("scenario, override, key, message", [
    ("ur5-sphere", "plant.surface.meridian=[0, 2, 0]", "plant.surface.meridian",
     "[0, 2, 0] must not be parallel to the pole [0, 1, 0] (plant.surface.pole)"),
    ("ur5-table", "reference.u1_amplitude=[0.1, 0.1, 0, 0]", "reference.u1_amplitude",
     "must be a number or a list of 5 numbers, as reference.u1_offset (one per motion coordinate), got 4: "
     "[0.1, 0.1, 0, 0]"),
    ("paper", "plant.arm.mass2=1.0", "plant.arm.mass2", "unknown key; did you mean 'plant.arm.m2'?"),
])
def test_smaller_defects_one_line_exit_2(tmp_path, capsys, scenario, override, key, message):
    with pytest.raises(H.ConfigError) as info:
        Scenario.load(scenario, [override])
    assert info.value.key == key and str(info.value) == f"{key}: {message}"
    out = tmp_path / "out"
    assert cli.main(["run", scenario, "--set", override, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and key in err[0] and message in err[0], err
    assert not out.exists()


def test_reference_lists_of_the_wrong_length_say_the_length_expected():
    with pytest.raises(H.ConfigError) as info:
        Scenario.load("ur5-table", {f"reference.u1_{k}": [0.0] * 4 for k in ("offset", "amplitude", "period", "phase")}
                      | {"reference.u1_period": [4.0] * 4})
    assert info.value.key == "reference.u1_offset"
    assert "a list of m = 5 numbers (one per motion coordinate: s1 [m], s2 [m], r_x [rad], r_y [rad], r_z [rad])" \
        in str(info.value)


def test_docs_give_the_reference_the_code_computes():
    """docs/arms-and-surfaces.md: u1d = offset + r(t)·amplitude·cos(...) (the offset not faded), λd
    faded whole; the code computes that."""
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "arms-and-surfaces.md").read_text()
    assert "u1d = offset + r_u(t)·amplitude·cos(2πt/period + phase)" in doc and "r(t)·(offset" not in doc
    sc = Scenario.load("ur5-table", {"reference.u1_offset": [0.01, 0.02, 0.0, 0.0, 0.0]}, check=False)
    ref = sc.build_reference()
    np.testing.assert_allclose(np.asarray(ref(0.0).u1_d), [0.01, 0.02, 0, 0, 0], atol=1e-15)  # r_u(0) = 0
    t = 3.0  # after the 1-s ramp: r = 1
    want = np.array([0.01, 0.02, 0, 0, 0]) + np.array([0.1, 0.1, 0, 0, 0]) * np.cos(
        2 * np.pi * t / 4.0 + np.array([0.0, -np.pi / 2, 0, 0, 0]))
    np.testing.assert_allclose(np.asarray(ref(t).u1_d), want, atol=1e-15)
    assert float(ref(0.0).lam_d[0]) == 0.0 and float(ref(t).lam_d[0]) == 20.0  # λd faded whole, offset included


def test_scenario_load_without_float64_says_so(tmp_path):
    """From Python without hinfnn.configure(): the float64 error, not "start pose not found"."""
    import subprocess
    import sys

    code = ("import hinfnn\nfrom hinfnn.scenario import Scenario\ntry:\n    Scenario.load('ur5-table')\n"
            "except hinfnn.ConfigError as e:\n    print(e)\n")
    env = {**os.environ, "JAX_ENABLE_X64": "0"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert "hinfnn computes in float64: call hinfnn.configure()" in out.stdout, out.stdout + out.stderr


# --------------------------------------------------------------------------------------------
# Motor armature (not in the paper; docs/arms-and-surfaces.md, "Motor armature")
# --------------------------------------------------------------------------------------------
#: the FR3's motor armature as assets/fr3/fr3.xml states it (kg m^2, joints 1-7)
FR3_ARMATURE = (0.2, 0.2, 0.2, 0.2, 0.1, 0.1, 0.1)


@jax.jit
def _armature_terms(chain, Q, QD, QDD, TAU):
    """M by 3 x 3 products (``M``), M of the compiled loop's kinematics (``_crba``), inverse and
    forward dynamics, at a batch of states: one program per chain structure."""
    def one(q, qd, qdd, tau):
        return (chain.M(q), chain._crba(chain._kinematics(q)), chain.inverse_dynamics(q, qd, qdd),
                chain.forward_dynamics(q, qd, tau))

    return jax.vmap(one)(Q, QD, QDD, TAU)


def test_armature_against_pinocchio():
    """Pinocchio's model.armature is the oracle: M(q) (both of hinfnn's forms), inverse dynamics
    (RNEA + armature q̈) and forward dynamics (ABA) of the FR3 URDF with per-joint armatures, at 8
    seeded random states."""
    a = np.array(FR3_ARMATURE) * np.linspace(1.0, 1.6, 7)  # distinct on every joint
    chain = load_urdf("fr3", "link0", "link8", tool_xyz=(0.0, 0.0, 0.1)).with_armature(a)
    model = pin.buildModelFromUrdf(robot_file("fr3"))
    model.armature = a
    data = model.createData()
    rng = np.random.default_rng(56)
    Q, QD, QDD, TAU = (rng.uniform(-2.0, 2.0, (8, 7)) for _ in range(4))
    got = [np.asarray(x) for x in _armature_terms(chain, Q, QD, QDD, TAU)]
    worst = dict(M=0.0, M_loop=0.0, tau=0.0, qdd=0.0)
    for i in range(8):
        M = pin.crba(model, data, Q[i])
        M = np.triu(M) + np.triu(M, 1).T
        tau = pin.rnea(model, data, Q[i], QD[i], QDD[i])
        qdd = pin.aba(model, data, Q[i], QD[i], TAU[i])
        for key, g, ref in (("M", got[0][i], M), ("M_loop", got[1][i], M), ("tau", got[2][i], tau),
                            ("qdd", got[3][i], qdd)):
            worst[key] = max(worst[key], float(np.max(np.abs(g - ref)) / np.max(np.abs(ref))))
    print({k: f"{v:.1e}" for k, v in worst.items()})
    assert all(v < 1e-10 for v in worst.values()), worst
    # the armature matters here: joint 7's rigid inertia is a thousandth of it
    assert float(load_urdf("fr3", "link0", "link8").M(Q[0])[6, 6]) < 1e-3 * a[6]


def test_armature_is_diag_added_and_zero_is_no_armature():
    """M gains exactly diag(a), inverse dynamics exactly a q̈; zero (or None) is the chain without an
    armature, whose programs are those of a chain that never had one; copies keep it."""
    base = load_urdf("fr3", "link0", "link8", tool_xyz=(0.0, 0.0, 0.1))
    a = np.array(FR3_ARMATURE)
    chain = base.with_armature(a)
    rng = np.random.default_rng(5)
    q, qd, qdd = (jnp.asarray(rng.uniform(-1.0, 1.0, 7)) for _ in range(3))
    np.testing.assert_array_equal(np.asarray(chain.M(q)), np.asarray(base.M(q)) + np.diag(a))
    np.testing.assert_array_equal(np.asarray(chain.inverse_dynamics(q, qd, qdd)),
                                  np.asarray(base.inverse_dynamics(q, qd, qdd)) + a * np.asarray(qdd))
    np.testing.assert_array_equal(np.asarray(chain.bias(q, qd)), np.asarray(base.bias(q, qd)))  # C, G unchanged
    assert base.with_armature(0.0).armature is None and base.with_armature([0.0] * 7).armature is None
    assert chain.with_armature(None).armature is None
    for zero in (base.with_armature(0.0), chain.with_armature(0.0)):
        assert jax.tree.structure(zero) == jax.tree.structure(base)
        assert str(jax.make_jaxpr(zero.M)(q)) == str(jax.make_jaxpr(base.M)(q))
    np.testing.assert_array_equal(np.asarray(base.with_armature(0.3).armature), np.full(7, 0.3))
    for copy in (chain.perturbed(mass_scale=1.1, payload_mass=0.2), chain.with_gravity((0.0, 0.0, -9.0))):
        np.testing.assert_array_equal(np.asarray(copy.armature), a)
    # every place an arm forms M: the full terms, the law's, the plant's, forward dynamics
    from hinfnn.model.taskmap import PositionTaskMap
    from hinfnn.model.urdf import UrdfArm

    arm = UrdfArm(chain, PositionTaskMap())
    tau = jnp.asarray(rng.uniform(-5.0, 5.0, 7))
    Ms = jax.jit(lambda q, qd: (arm.terms(q, qd).M, arm.law_terms(q, qd).M, arm.plant_terms(q, qd).M))(q, qd)
    for M in Ms:
        np.testing.assert_allclose(np.asarray(M), np.asarray(chain.M(q)), rtol=0, atol=1e-13)
    qdd = arm.forward_dynamics(q, qd, tau, arm.plant_terms(q, qd))
    np.testing.assert_allclose(np.asarray(chain.inverse_dynamics(q, qd, qdd)), np.asarray(tau), rtol=0, atol=1e-11)


@pytest.mark.parametrize("value, words", [
    ([0.1, 0.2], "got [0.1, 0.2]"),
    (-0.1, "got -0.1"),
    ([0.1] * 6 + [float("nan")], "nan"),
    ([[0.1] * 7], "got [[0.1"),
    ("heavy", "got 'heavy'"),
])
def test_armature_bad_input_is_a_config_error(value, words):
    chain = load_urdf("fr3", "link0", "link8")
    with pytest.raises(H.ConfigError) as info:
        chain.with_armature(value, key="nominal.arm.armature")
    assert info.value.key == "nominal.arm.armature"
    assert "a number or a list of 7 (one per joint: joint1" in str(info.value) and ">= 0" in str(info.value)
    assert words in str(info.value)


@pytest.mark.parametrize("scenario, overrides, key, words", [
    ("fr3-table", {"nominal.arm.armature": [0.1, 0.1]}, "nominal.arm.armature",
     "must be a number or a list of 7 (one per moving joint, n = 7), got 2: [0.1, 0.1]"),
    ("fr3-table", {"nominal.arm.armature": -0.1}, "nominal.arm.armature", ">= 0"),
    ("fr3-table", {"nominal.arm.armature": float("nan")}, "nominal.arm.armature", "must be finite"),
    ("fr3-table", {"plant.arm.armature": 0.1}, "plant.arm.armature",
     "must equal the armature of the MJCF's own joints (plant.mjcf.file = 'fr3': joint1 0.2, joint2 0.2, joint3 0.2, "
     "joint4 0.2, joint5 0.1, joint6 0.1, joint7 0.1 kg m^2), got 0.1"),
    ("paper", {"plant.arm.armature": 0.1}, "plant.arm.model",  # the closed-form arm: the planar one takes it
     "model = 'two_link' does not take the key 'armature' (model = 'planar')"),
    ("planar3-drum", {"plant.arm.armature": [0.1, 0.1]}, "plant.arm.armature", "got 2: [0.1, 0.1]"),
])
def test_armature_scenario_keys_refuse_bad_input(scenario, overrides, key, words):
    with pytest.raises(H.ConfigError) as info:
        Scenario.load(scenario, overrides).build_plant()
    assert info.value.key == key and words in str(info.value), str(info.value)


def test_fr3_table_nominal_has_its_truths_armature():
    """fr3-table's nominal states the FR3's motor armature as its truth's MJCF does (fr3.xml's
    dof_armature); the built-in plant takes plant.arm.armature, the planar arm's too."""
    mujoco = pytest.importorskip("mujoco")
    from hinfnn.scenario.sections import mjcf_path

    sc = Scenario.load("fr3-table")
    nominal = sc.nominal.arm.chain("nominal.arm")
    truth = mujoco.MjModel.from_xml_path(mjcf_path("fr3"))
    np.testing.assert_array_equal(np.asarray(nominal.armature), truth.dof_armature)
    np.testing.assert_array_equal(np.asarray(nominal.armature), FR3_ARMATURE)
    # the built-in engine's truth is the same arm: plant.arm states the file's armature
    np.testing.assert_array_equal(np.asarray(sc.plant.arm.chain("plant.arm").armature), truth.dof_armature)
    builtin = Scenario.load("fr3-table", {"plant.engine": "hinfnn"})
    np.testing.assert_array_equal(np.asarray(builtin.build_plant().arm.chain.armature), FR3_ARMATURE)
    planar = Scenario.load("planar3-drum", {"plant.arm.armature": [0.1, 0.2, 0.3]})
    np.testing.assert_array_equal(np.asarray(planar.plant.arm.joint_chain("plant.arm").armature), [0.1, 0.2, 0.3])
    assert Scenario.load("planar3-drum").plant.arm.joint_chain("plant.arm").armature is None
