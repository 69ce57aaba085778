"""The user's own arm: real URDFs (the shipped Panda, UR10, Kinova Jaco 2 and UR5 from
example-robot-data) against Pinocchio, how a ``file`` value is resolved and refused, redundant
arms through extra task coordinates, joint limits, and the run's verdicts.

Pinocchio is the oracle: the same file is built with ``pinocchio.buildModelFromXML`` and its
whole model (grippers and fingers at their neutral positions, at rest) is restricted to the
chain's joints, which is what hinfnn's merging of side branches with their joints at zero means.
"""

from __future__ import annotations

import os
import shutil
import xml.etree.ElementTree as ET

import jax
import numpy as np
import pinocchio as pin  # the oracle (a test dependency)
import pytest

import hinfnn as H
from hinfnn import cli
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
    (lambda d: str(d / "missing.urdf"), r"no such file; .*shipped with hinfnn: 'kinova', 'panda', 'planar/sec6_two_link'"),
    (lambda d: "pandaa", r"is neither a file nor a robot shipped with hinfnn \(.*'ur5'\); did you mean 'panda'\?"),
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
    assert sc.build_arm("plant").n == 6


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
