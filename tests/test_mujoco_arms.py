"""MuJoCo as the truth for any arm (hinfnn.plant.mujoco, docs/mujoco.md).

* the MJCF generated from a parsed chain IS the built-in arm: M(q) (mj_fullM), the bias forces
  (qfrc_bias) and the tool pose at seeded random states, on the true UR5 (masses, centres of mass
  and a payload perturbed), a 7-DOF chain (full inertia tensors in turned frames, a prismatic
  joint, a locked joint, fixed joints and a side branch) and the planar 3-link arm; no MuJoCo
  default adds to the dynamics;
* a compiled model reads back into the same chain, and a chain written as URDF loads back;
  the shipped Menagerie UR5e loads without meshes and its URDF is its rigid-body part;
* each surface geom gives MuJoCo the tool point's exact signed distance; the contact on a plane,
  a sphere and a cylinder is the requested spring-damper: static penetration, frequency and
  damping ratio within 1 % of the requested k, c; MuJoCo's Coulomb friction is the regularised law
  docs/mujoco.md states (slope below the cone, μ f_n on it, the soft cone's normal-force gain);
* the batch path (mujoco.batch) and the one-row path give the same numbers;
* MuJoCo's viscous tool friction is the built-in plant's law at the tool point (terminal sliding
  speed, the sensed tangential force at every instant), on both row paths;
* a user's MJCF: wrong joint names, a missing tool site, a surface MuJoCo cannot model and a
  negative viscous friction are ConfigErrors naming the key (exit 2 from the CLI; a viscous
  friction too stiff for MuJoCo's step too).

Everything here steps MuJoCo from NumPy (no compiled JAX program): the closed loops are in
tests/test_mujoco.py.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import hinfnn as H
from hinfnn import cli
from hinfnn.errors import ConfigError
from hinfnn.model.geometry import Circle, Cylinder, Line, Plane, SineProfile, Sphere
from hinfnn.model.taskmap import PlanarTaskMap, PositionTaskMap
from hinfnn.model.urdf import UrdfArm, asset_path, load_urdf, load_urdf_string, planar_chain, rpy_matrix
from hinfnn.plant import Friction, PenaltyContact, SquareWave
from hinfnn.plant.mujoco import (IMPEDANCE, IMPRATIO, MujocoPlant, build_scene, chain_from_model, chain_urdf,
                                 chain_xml)
from mujoco_helpers import fit_oscillation

pytestmark = pytest.mark.xdist_group("mujoco_arms")

UR5 = asset_path("ur5", "ur5.urdf")
UR5E_XML = asset_path("ur5e", "ur5e.xml")
UR5E_URDF = asset_path("ur5e", "ur5e.urdf")
UR5E_JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
               "wrist_3_joint")
Q_UR5 = np.array([0.0, -1.0, 1.6, -2.17, -1.57, -1.57])


def _seven_dof_urdf(seed=5) -> str:
    """A 7-DOF arm: 7 revolute joints about turned axes and 1 prismatic (one revolute locked),
    full inertia tensors with turned inertial frames, fixed joints, a side branch and a link below
    the end-effector (all lumped into the chain's bodies)."""
    rng = np.random.default_rng(seed)

    def vec(x):
        return " ".join(f"{v:.17g}" for v in x)

    def inertial(mass):
        dims = rng.uniform(0.05, 0.3, 3)
        box = mass / 12 * np.diag([dims[1]**2 + dims[2]**2, dims[0]**2 + dims[2]**2, dims[0]**2 + dims[1]**2])
        Q = rpy_matrix(rng.uniform(-np.pi, np.pi, 3))
        I = Q @ box @ Q.T
        return (f'<inertial><origin xyz="{vec(rng.uniform(-0.1, 0.1, 3))}" rpy="{vec(rng.uniform(-1, 1, 3))}"/>'
                f'<mass value="{mass:.17g}"/><inertia ixx="{I[0,0]:.17g}" ixy="{I[0,1]:.17g}" ixz="{I[0,2]:.17g}" '
                f'iyy="{I[1,1]:.17g}" iyz="{I[1,2]:.17g}" izz="{I[2,2]:.17g}"/></inertial>')

    def joint(name, jtype, parent, child, axis=None):
        o = f'<origin xyz="{vec(rng.uniform(-0.2, 0.2, 3))}" rpy="{vec(rng.uniform(-1.5, 1.5, 3))}"/>'
        a = f'<axis xyz="{axis}"/>' if axis else ""
        lim = '<limit lower="-3" upper="3" effort="10" velocity="5"/>' if jtype != "fixed" else ""
        return f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>{o}{a}{lim}</joint>'

    masses = {"base": 0, "l1": 4.0, "l2": 3.5, "l3": 3.0, "l3b": 0.4, "l4": 2.5, "l5": 2.0, "l6": 1.5, "l7": 1.0,
              "l8": 0.8, "sensor": 0.3, "flange": 0.2, "tool": 0.0}
    body = "".join(f'<link name="{k}">{inertial(m) if m else ""}</link>' for k, m in masses.items())
    axes = ["0 0 1", "0 1 0", "0.3 -1 0.2", "1 0 0", "0 0 1", "0.5 0.5 1", "0 1 0"]
    chain = ["base", "l1", "l2", "l3", "l4", "l5", "l6", "l7", "l8"]
    for i in range(8):
        kind = "prismatic" if i == 3 else "revolute"
        body += joint(f"j{i + 1}", kind, chain[i], chain[i + 1], axes[i % 7] if i != 3 else "1 2 0.5")
    body += joint("l3_fixed", "fixed", "l3", "l3b")
    body += joint("sensor_mount", "fixed", "l6", "sensor")
    body += joint("flange_joint", "fixed", "l8", "flange")
    body += joint("tool_joint", "fixed", "flange", "tool")
    return f'<?xml version="1.0"?><robot name="seven">{body}</robot>'


def _true_ur5():
    chain = load_urdf(UR5, "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1))
    rng = np.random.default_rng(11)
    return chain.perturbed(mass_scale=jnp.asarray(rng.uniform(0.8, 1.2, 6)),
                           com_shift=jnp.asarray(rng.uniform(-0.02, 0.02, (6, 3))), payload_mass=0.7,
                           payload_xyz=(0.01, -0.02, 0.03))


CHAINS = {
    "ur5-true": _true_ur5,
    "seven": lambda: load_urdf_string(_seven_dof_urdf(), "base", "tool", tool_xyz=(0.02, 0.0, 0.08),
                                      tool_rpy=(0.1, 0.2, 0.3), locked={"j6": 0.4}),
    "planar3": lambda: planar_chain([2.0, 1.5, 1.0], [0.8, 0.7, 0.5]),
    # the motors' armature, written as each joint's MuJoCo armature: MuJoCo's M is the chain's
    "ur5-armature": lambda: _true_ur5().with_armature([0.3, 0.25, 0.2, 0.1, 0.05, 0.02]),
}


def _model(chain):
    return mujoco.MjModel.from_xml_string(chain_xml(chain))


@jax.jit
def _terms(chain, Q, QD):
    """M, C q̇ + G, G and the tool frame of a chain at a batch of states (one program per chain
    structure)."""
    return jax.vmap(lambda q, qd: (chain.M(q), chain.bias(q, qd), chain.G(q), *chain.fk(q)))(Q, QD)


@jax.jit
def _distances(surface, P):
    return jax.vmap(surface.signed_distance)(P), jax.vmap(surface.normal)(P)


def _rel(a, b):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(np.asarray(b)))


@pytest.mark.parametrize("name", list(CHAINS))
def test_generated_model_is_the_builtin_arm(name):
    """M(q), C(q, q̇)q̇ + G(q) and the tool frame of MuJoCo's model against the chain's CRBA,
    RNEA and forward kinematics at 20 seeded random states (q ∈ [−π, π], q̇ ∈ [−3, 3])."""
    chain = CHAINS[name]()
    m = _model(chain)
    n = chain.n
    assert (m.nq, m.nv, m.nu) == (n, n, 0)
    # nothing MuJoCo adds by default to the rigid-body dynamics; the armature is the chain's
    for field in ("dof_damping", "dof_frictionloss", "jnt_stiffness", "jnt_limited"):
        assert not np.any(getattr(m, field)), field
    np.testing.assert_array_equal(m.dof_armature, np.zeros(n) if chain.armature is None else np.asarray(chain.armature))
    np.testing.assert_array_equal(m.opt.gravity, np.asarray(chain.gravity))
    np.testing.assert_allclose(m.body_mass[1:], np.asarray(chain.mass), rtol=1e-15)
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tool")
    rng = np.random.default_rng(3)
    Q, QD = rng.uniform(-np.pi, np.pi, (20, n)), rng.uniform(-3.0, 3.0, (20, n))
    Ms, biases, Gs, ps, Rs = map(np.asarray, _terms(chain, jnp.asarray(Q), jnp.asarray(QD)))
    worst = dict(M=0.0, bias=0.0, G=0.0, p=0.0, R=0.0)
    M = np.zeros((n, n))
    for i in range(20):
        d.qpos[:], d.qvel[:] = Q[i], QD[i]
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M)
        worst["M"] = max(worst["M"], _rel(M, Ms[i]))
        worst["bias"] = max(worst["bias"], _rel(d.qfrc_bias, biases[i]))
        worst["p"] = max(worst["p"], float(np.max(np.abs(d.site_xpos[site] - ps[i]))))
        worst["R"] = max(worst["R"], float(np.max(np.abs(d.site_xmat[site].reshape(3, 3) - Rs[i]))))
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        worst["G"] = max(worst["G"], _rel(d.qfrc_bias, Gs[i]))
    print(name, {k: f"{v:.1e}" for k, v in worst.items()})
    # the planar arm's point masses carry m (1e-5 m)^2 of rotational inertia: 2e-10 of M
    assert all(v < 1e-9 for v in worst.values()), worst


def test_model_reads_back_into_the_chain_and_the_chain_writes_as_urdf():
    """chain_from_model(MJCF of the chain) and load_urdf(chain_urdf(chain)) are the same chain:
    M, bias and tool frame at 10 random states to 1e-12."""
    chain = CHAINS["seven"]()
    m = _model(chain)
    back = chain_from_model(m, chain.joint_names, "tool")
    urdf = load_urdf_string(chain_urdf(chain, "seven", links=[f"b{i}" for i in range(chain.n)]), "base_link", "tool0")
    assert back.joint_types == chain.joint_types == urdf.joint_types
    rng = np.random.default_rng(4)
    Q, QD = jnp.asarray(rng.uniform(-2, 2, (10, chain.n))), jnp.asarray(rng.uniform(-2, 2, (10, chain.n)))
    want = _terms(chain, Q, QD)
    for other in (back, urdf):
        got = _terms(other, Q, QD)
        for a, b in zip(got[:3], want[:3]):
            assert max(_rel(x, y) for x, y in zip(np.asarray(a), np.asarray(b))) < 1e-12
        for a, b in zip(got[3:], want[3:]):
            assert np.max(np.abs(np.asarray(a) - np.asarray(b))) < 1e-12


def test_menagerie_ur5e_loads_without_meshes_and_its_urdf_is_its_rigid_body_part():
    m = mujoco.MjModel.from_xml_path(UR5E_XML)
    assert m.nmesh == 0 and m.nv == 6 and m.nu == 6
    urdf = load_urdf(UR5E_URDF, "base_link", "tool0")
    assert urdf.joint_names == UR5E_JOINTS
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "attachment_site")
    rng = np.random.default_rng(5)
    Q = rng.uniform(-np.pi, np.pi, (10, 6))
    Ms, _, Gs, ps, Rs = map(np.asarray, _terms(urdf, jnp.asarray(Q), jnp.zeros((10, 6))))
    M = np.zeros((6, 6))
    for i in range(10):
        d.qpos[:], d.qvel[:] = Q[i], 0.0
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M)
        # the MJCF's joint armature (0.1 kg m^2 each) is the only difference in M; gravity equal
        np.testing.assert_allclose(M - Ms[i], 0.1 * np.eye(6), atol=1e-12)
        np.testing.assert_allclose(d.qfrc_bias, Gs[i], atol=1e-12)
        np.testing.assert_allclose(d.site_xpos[site], ps[i], atol=1e-12)
        np.testing.assert_allclose(d.site_xmat[site].reshape(3, 3), Rs[i], atol=1e-12)


# --------------------------------------------------------------------------------------------
# Surfaces and the calibrated contact
# --------------------------------------------------------------------------------------------
def _ur5_scene(surface, contact, *, gravity=True, friction=0.0, friction_damping=1000.0, integrator="RK4"):
    chain = load_urdf(UR5, "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1))
    if not gravity:
        chain = chain.with_gravity(jnp.zeros(3))
    return chain, build_scene(surface, contact, arm_xml=chain_xml(chain), friction=friction,
                              friction_damping=friction_damping, timestep=1e-4, integrator=integrator)


SURFACES_3D = {
    "plane": lambda: Plane.build((0.5, 0.1, 0.05), (0.05, 0.03, 1.0)),
    "sphere": lambda: Sphere.build((0.5, 0.1, -0.25), 0.3),
    "cylinder": lambda: Cylinder.build((0.5, 0.1, -0.25), (0.1, 1.0, 0.0), 0.3),
}


@pytest.mark.parametrize("kind", list(SURFACES_3D))
def test_surface_geom_distance_is_the_exact_signed_distance(kind):
    """MuJoCo's sphere–surface distance is minus the tool point's signed distance to the true
    surface, and the contact sensor's normal is the outward normal, at 200 poses about the top."""
    surface = SURFACES_3D[kind]()
    _, scene = _ur5_scene(surface, PenaltyContact(1e5, 0.0))
    m = scene.model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(6)
    pts, dist, sensors = [], [], []
    for _ in range(200):
        d.qpos[:] = Q_UR5 + rng.normal(0.0, 0.1, 6)
        mujoco.mj_forward(m, d)
        pts.append(d.site_xpos[scene.site].copy())
        dist.append(d.contact.dist[0] if d.ncon else np.nan)
        sensors.append(d.sensordata[scene.sensor_adr:scene.sensor_adr + 11].copy())
    sd, normal = map(np.asarray, _distances(surface, jnp.asarray(np.array(pts))))
    inside = np.isfinite(dist)
    assert inside.sum() > 20
    assert np.all(sd[~inside] < 0.0)  # MuJoCo finds a contact exactly when the tool point is inside
    np.testing.assert_allclose(-np.array(dist)[inside], sd[inside], rtol=0, atol=1e-12)
    sensors = np.array(sensors)[inside]
    assert np.all(sensors[:, 0] == 1.0)
    np.testing.assert_allclose(sensors[:, 4], np.array(dist)[inside], atol=1e-15)
    np.testing.assert_allclose(sensors[:, 5:8], -normal[inside], atol=1e-12)  # surface -> tool


@pytest.mark.parametrize("kind,rows", [("line", (0, 1)), ("circle", (0, 1))])
def test_planar_surface_geoms(kind, rows):
    """A line and a disc of a planar arm's plane: a MuJoCo plane and a cylinder along the plane's
    normal; the same exact distance at the 3-link arm's tool point."""
    chain = planar_chain([2.0, 1.5, 1.0], [0.8, 0.7, 0.5])
    surface = Line.build((1.0, -0.3), (0.1, 1.0)) if kind == "line" else Circle.build((1.0, -0.6), 0.3)
    scene = build_scene(surface, PenaltyContact(1e5, 0.0), rows=rows, arm_xml=chain_xml(chain), timestep=1e-4)
    d = mujoco.MjData(scene.model)
    rng = np.random.default_rng(7)
    pts, dist = [], []
    for _ in range(200):
        d.qpos[:] = np.array([0.1, -0.9, -0.8]) + rng.normal(0.0, 0.3, 3)
        mujoco.mj_forward(scene.model, d)
        pts.append(d.site_xpos[scene.site][list(rows)].copy())
        dist.append(d.contact.dist[0] if d.ncon else np.nan)
    sd = np.asarray(_distances(surface, jnp.asarray(np.array(pts)))[0])
    inside = np.isfinite(dist)
    assert inside.sum() > 10 and np.all(sd[~inside] < 0.0)
    np.testing.assert_allclose(-np.array(dist)[inside], sd[inside], rtol=0, atol=1e-12)


def _press(scene, chain, q0, force, n_steps):
    """Hold τ = J_pᵀ force (a constant Cartesian force at the tool point, gravity off) from rest at
    q0 and step MuJoCo; returns the tool point and the contact sensor after every step."""
    m = scene.model
    d = mujoco.MjData(m)
    d.qpos[:] = q0
    mujoco.mj_forward(m, d)
    jacp = np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jacp, None, scene.site)
    tau = jacp.T @ force
    pts, sensors = [d.site_xpos[scene.site].copy()], [d.sensordata[scene.sensor_adr:scene.sensor_adr + 11].copy()]
    for _ in range(n_steps):
        d.qfrc_applied[:] = tau
        mujoco.mj_step(m, d)
        mujoco.mj_forward(m, d)
        pts.append(d.site_xpos[scene.site].copy())
        sensors.append(d.sensordata[scene.sensor_adr:scene.sensor_adr + 11].copy())
    return np.array(pts), np.array(sensors), d


def _normal_mode(chain, q0):
    """(unit direction, effective mass) of the tool point's most mobile direction at q0: a force
    along it accelerates the tool point along it only (an eigenvector of J_p M⁻¹ J_pᵀ)."""
    Jp = np.asarray(chain.frame_jacobian(jnp.asarray(q0)))[:3]
    A = Jp @ np.linalg.solve(np.asarray(chain.M(jnp.asarray(q0))), Jp.T)
    w, V = np.linalg.eigh(A)
    return V[:, -1] * np.sign(V[2, -1] or 1.0), 1.0 / w[-1]


def _surface_through(kind, p0, n_in, depth, R=0.3):
    """A true surface whose inward normal at p0 is n_in and which p0 penetrates by ``depth``."""
    if kind == "plane":
        return Plane.build(p0 - depth * n_in, -n_in)
    if kind == "sphere":
        return Sphere.build(p0 + (R - depth) * n_in, R)
    axis = np.cross(n_in, [1.0, 0.0, 0.0])
    return Cylinder.build(p0 + (R - depth) * n_in, axis / np.linalg.norm(axis), R)


CALIBRATION = [("plane", 1e5, 200.0), ("sphere", 1e5, 200.0), ("cylinder", 1e5, 200.0), ("plane", 1e5, 0.0),
               ("sphere", 1e6, 500.0)]


@pytest.mark.parametrize("kind,k,c", CALIBRATION)
def test_contact_calibration_per_surface(kind, k, c):
    """The UR5 (gravity off) pressed with P = 50 N along the surface's inward normal, which is
    the tool point's most mobile direction (so the tool moves along the normal only), released at
    rest from 1.5 P/k. The penetration rings about P/k at √(k/m_eff) with damping ratio
    c/(2√(k m_eff)): each within 1 % (docs/mujoco.md, "Calibration"; the residue is the added
    mass 1e-4/W)."""
    P = 50.0
    chain = load_urdf(UR5, "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1)).with_gravity(jnp.zeros(3))
    n_in, m_eff = _normal_mode(chain, Q_UR5)
    p0 = np.asarray(chain.fk(jnp.asarray(Q_UR5))[0])
    surface = _surface_through(kind, p0, n_in, 1.5 * P / k)
    scene = build_scene(surface, PenaltyContact(k, c), arm_xml=chain_xml(chain), timestep=1e-4)
    n_steps = int(6 * 2 * np.pi / np.sqrt(k / m_eff) / 1e-4)  # six periods
    pts, sensors, _ = _press(scene, chain, Q_UR5, P * n_in, n_steps)
    pen = np.asarray(_distances(surface, jnp.asarray(pts))[0])
    t = 1e-4 * np.arange(n_steps + 1)
    assert pen[0] == pytest.approx(1.5 * P / k, rel=1e-9) and np.all(pen > 0.2 * P / k)
    p_eq, wn, zeta, residual = fit_oscillation(t, pen)
    wn_req, zeta_req = np.sqrt(k / m_eff), c / (2.0 * np.sqrt(k * m_eff))
    print(f"{kind} k={k:g} c={c:g}: p_eq/(P/k) = {p_eq / (P / k):.5f}, ω_n/√(k/m_eff) = {wn / wn_req:.5f}, "
          f"ζ = {zeta:.5f} (requested {zeta_req:.5f}), m_eff = {m_eff:.3f} kg, W = {scene.diag_approx:.4f} 1/kg")
    assert residual < 2e-3 * P / k  # a linear damped oscillation
    assert p_eq == pytest.approx(P / k, rel=0.01)
    assert wn == pytest.approx(wn_req, rel=0.01)
    if c > 0:
        assert zeta == pytest.approx(zeta_req, rel=0.01)
    else:
        assert abs(zeta) < 1e-3
    # the sensed normal force is MuJoCo's constraint force: f_n = k p + c ṗ + m_add p̈ (docs/mujoco.md)
    f_n = sensors[:, 1]
    p_dot = np.gradient(pen, t)
    p_ddot = np.gradient(p_dot, t)
    m_add = IMPEDANCE / ((1 - IMPEDANCE) * scene.diag_approx)
    resid = f_n[2:-2] - (k * pen + c * p_dot + m_add * p_ddot)[2:-2]
    assert np.max(np.abs(resid)) < 2e-3 * P


def _slip(scene, d):
    """The tool sphere's velocity at the contact point (where MuJoCo's friction acts), world."""
    res = np.zeros(6)
    mujoco.mj_objectVelocity(scene.model, d, mujoco.mjtObj.mjOBJ_SITE, scene.site, res, 0)
    return res[3:] + np.cross(res[:3], d.contact.pos[0] - d.site_xpos[scene.site])


def test_friction_is_mujocos_regularised_coulomb():
    """The UR5 (gravity off) pressed on a plane with P = 20 N along its normal and pushed along it
    with T. Below the cone (T = 0.5 μP) the friction force opposes the slip at the contact point
    with the slope c_t = plant.friction_damping (to 2 %: the rows' A_t/R_t and a0_t/R_t terms);
    above it (T = 2 μP) it is μ f_n, and MuJoCo's soft cone raises the normal force above the
    spring-damper's by (μ/IMPRATIO)(c_t v − μ f_n)/(1 + μ²/IMPRATIO) (docs/mujoco.md, eq. (6);
    to 3 %)."""
    P, k, c, mu, c_t = 20.0, 1e5, 200.0, 0.3, 300.0
    chain = load_urdf(UR5, "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1)).with_gravity(jnp.zeros(3))
    n_in, _ = _normal_mode(chain, Q_UR5)
    p0 = np.asarray(chain.fk(jnp.asarray(Q_UR5))[0])
    surface = _surface_through("plane", p0, n_in, P / k)
    scene = build_scene(surface, PenaltyContact(k, c), arm_xml=chain_xml(chain), friction=mu, friction_damping=c_t,
                        timestep=1e-4)
    t_dir = np.cross(n_in, [0.0, 1.0, 0.0])
    t_dir /= np.linalg.norm(t_dir)
    for ratio in (0.5, 2.0):
        T = ratio * mu * P
        pts, sensors, d = _press(scene, chain, Q_UR5, P * n_in + T * t_dir, 3000)
        f, nrm, tan = sensors[-1, 1:4], sensors[-1, 5:8], sensors[-1, 8:11]
        on_tool = f[0] * nrm + f[1] * tan + f[2] * np.cross(nrm, tan)
        f_n, f_t = f[0], on_tool - (on_tool @ nrm) * nrm
        slip = _slip(scene, d)
        slip -= (slip @ nrm) * nrm
        speed = np.linalg.norm(slip)
        pen = float(surface.signed_distance(jnp.asarray(pts[-1])))
        pen_dot = (pen - float(surface.signed_distance(jnp.asarray(pts[-2])))) / 1e-4
        spring = k * pen + c * pen_dot
        gain = (mu / IMPRATIO) * (c_t * speed - mu * f_n) / (1 + mu**2 / IMPRATIO)
        print(f"T = {ratio} μP: slip {speed:.5f} m/s, |f_t| = {np.linalg.norm(f_t):.4f} N (c_t v = {c_t * speed:.4f}), "
              f"f_n = {f_n:.4f} N, μ f_n = {mu * f_n:.4f} N, f_n − (k p + c ṗ) = {f_n - spring:.4f}, gain {gain:.4f}")
        np.testing.assert_allclose(f_t / np.linalg.norm(f_t), -slip / speed, atol=1e-3)  # opposes the slip
        if ratio < 1:  # below the cone: a damper of slope c_t, the normal force the spring-damper's
            assert np.linalg.norm(f_t) == pytest.approx(c_t * speed, rel=0.02)
            assert np.linalg.norm(f_t) < mu * f_n and f_n == pytest.approx(spring, abs=1e-3 * P)
        else:  # sliding on the cone, the normal force raised by the soft cone
            assert np.linalg.norm(f_t) == pytest.approx(mu * f_n, rel=1e-9)
            assert gain > 0.005 * P and f_n - spring == pytest.approx(gain, rel=0.03)


def test_viscous_friction_acts_at_the_tool_point_while_the_contact_pushes():
    """The UR5 (gravity off) pressed on a plane with P = 20 N along its normal and pushed along it
    with T = 5 N (constant joint torques J_pᵀ(P n + T t) at the start pose), μ = 0 and viscous
    friction c_v = 500 N·s/m: the tool point slides at the terminal speed T / c_v along t (to 1 %
    after 0.1 s, 15 time constants m_t / c_v), and at every control instant the sensed force's
    tangential part is c_v v_t of that state (v_t the tool point's velocity J_p q̇ less its normal
    part; to 1e-9 relative), the normal part MuJoCo's contact force. Rows stepped by mujoco.batch
    (with a frictionless member and an out-of-contact row) and one at a time give the same
    numbers bit for bit; c_v = 0 is the frictionless member (docs/mujoco.md, "Friction", eq. (7))."""
    P, T, k, c, c_v = 20.0, 5.0, 1e5, 200.0, 500.0
    chain = load_urdf(UR5, "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1)).with_gravity(jnp.zeros(3))
    n_in, _ = _normal_mode(chain, Q_UR5)
    p0 = np.asarray(chain.fk(jnp.asarray(Q_UR5))[0])
    surface = _surface_through("plane", p0, n_in, P / k)
    t_dir = np.cross(n_in, [0.0, 1.0, 0.0])
    t_dir /= np.linalg.norm(t_dir)
    plants = [MujocoPlant.from_models(UrdfArm(chain, PositionTaskMap()), surface, PenaltyContact(k, c),
                                      SquareWave.none(6), control_period=1e-3, timestep=1e-4,
                                      friction=Friction(coulomb=0.0, viscous=cv)) for cv in (c_v, 0.0)]
    fam, n = plants[0]._family, 6
    assert plants[1]._family is fam and fam.viscous == {int(plants[0].member): c_v}
    Jp = np.asarray(chain.frame_jacobian(jnp.asarray(Q_UR5)))[:3]
    tau = Jp.T @ (P * n_in + T * t_dir)
    jp, sens = 4 * n + 12, 10 * n + 12  # the output row: q, q̇, warm start, q̈, p, R, jacp, jacr, sensor

    def row(member, t, y):
        return np.concatenate([[member, 1e-3, t], y[:3 * n], tau])

    y = np.concatenate([Q_UR5, np.zeros(2 * n)])
    rows = []
    for i in range(100):
        y = fam._one(row(float(plants[0].member), 1e-3 * i, y), "step")
        rows.append(row(float(plants[0].member), 1e-3 * (i + 1), y))
        qd, J, s = y[n:2 * n], y[jp:jp + 3 * n].reshape(3, n), y[sens:]
        f, nrm, tan = s[1:4], s[5:8], s[8:11]
        on_tool = f[0] * nrm + f[1] * tan + f[2] * np.cross(nrm, tan)
        v = J @ qd
        v_t = v - (v @ nrm) * nrm
        assert s[0] > 0 and f[0] > 0  # in contact, pushing
        np.testing.assert_allclose(on_tool - f[0] * nrm, -c_v * v_t, rtol=1e-9, atol=1e-12)
    speed = v_t @ t_dir
    print(f"tangential speed {speed:.6f} m/s (T / c_v = {T / c_v:.6f}), across {np.linalg.norm(v_t - speed * t_dir):.2e}")
    assert speed == pytest.approx(T / c_v, rel=0.01)
    # the batch path: the viscous member's rows, the same state on the frictionless member, one out of contact
    free = rows[50].copy()
    free[0] = float(plants[1].member)
    lifted = rows[60].copy()
    lifted[3:3 + n] = Q_UR5 + 0.05 * np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    x = np.array([rows[10], free, rows[40], lifted, rows[99]])
    single = np.array([fam._one(r, "step") for r in x])
    np.testing.assert_array_equal(fam.run(x, "step"), single)
    assert single[3, sens] == 0 and single[1, sens] > 0  # out of contact; in contact without friction
    np.testing.assert_array_equal(single[1, sens + 2:sens + 4], 0.0)


def test_batch_and_single_row_paths_agree():
    """Rows stepped by mujoco.batch (several members, several models) and one at a time on an
    MjData: the same numbers, bit for bit."""
    chain = load_urdf(UR5, "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1))
    task = PositionTaskMap()
    plants = [MujocoPlant.from_models(UrdfArm(chain.perturbed(mass_scale=s), task), Sphere.build((0.5, 0.1, -0.25), 0.3),
                                      PenaltyContact(kk, 100.0), SquareWave.none(6), control_period=1e-3,
                                      timestep=2.5e-4, friction=Friction(coulomb=0.2)) for s, kk in ((1.0, 1e5), (1.2, 3e5))]
    fam = plants[0]._family
    assert plants[1]._family is fam and int(plants[0].member) != int(plants[1].member)
    rng = np.random.default_rng(8)
    rows = []
    for i in range(5):
        p = plants[i % 2]
        q = Q_UR5 + rng.normal(0, 0.02, 6)
        rows.append(np.concatenate([[float(p.member), 1e-3, 0.01 * i], q, rng.normal(0, 0.1, 6), np.zeros(6),
                                    rng.normal(0, 5.0, 6)]))
    rows.append(np.full_like(rows[0], np.nan))  # a poisoned row stays NaN and does not stop the others
    x = np.array(rows)
    batched = fam.run(x, "step")
    single = np.array([fam._one(r, "step") for r in x])
    np.testing.assert_array_equal(batched, single)
    assert np.all(np.isnan(batched[-1])) and np.all(np.isfinite(batched[:-1]))
    with pytest.raises(RuntimeError, match="not known in this process"):
        fam.run(np.concatenate([[123.0], x[0, 1:]])[None], "step")


def test_sensing_and_record_are_the_builtin_plants():
    """The UR5 (gravity off) at rest with its tool point 0.1 mm inside a sphere (k = 1e5 N/m,
    c = 100 N·s/m): MuJoCo's Measurement carries the force the tool exerts on the surface at the
    tool point in base axes (3 components), the built-in plant's k p n up to MuJoCo's constraint
    impedance: frictionless, f = k p / (1 + d A / ((1 − d) W)) (docs/mujoco.md eq. (3) at rest
    with no load, A = nᵀ J_p M⁻¹ J_pᵀ n), to 1e-9 relative; with μ = 0.2 the normal part to 1e-5
    and a tangential part within the cone (MuJoCo's soft friction rows answer the tangential
    acceleration the normal force causes: 0.09 N here, where the built-in plant's friction is 0 at
    rest). The PlantRecord has the built-in plant's signal names and values (q, qd, x_true,
    F_contact, task_margin, the joint limit margins); with the elbow's upper limit moved below its
    angle it is the same fault as the built-in plant's (joint 3, elbow_joint), and the start pose
    solver gives the built-in plant's pose, within the limits or not."""
    from hinfnn.model.taskmap import PositionTaskMap
    from hinfnn._pytree import replace

    chain = load_urdf(UR5, "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1)).with_gravity(jnp.zeros(3))
    q = jnp.asarray(Q_UR5)
    p = np.asarray(chain.fk(q)[0])
    depth, R = 1e-4, 0.3
    surface = Sphere.build(tuple(p - (R - depth) * np.array([0.0, 0.0, 1.0])), R)
    contact = PenaltyContact(1e5, 100.0)
    kw = dict(surface=surface, contact=contact, disturbance=SquareWave.none(6))
    for upper_elbow, friction in ((None, None), (float(Q_UR5[2]) - 0.01, Friction(coulomb=0.2))):
        c = chain if upper_elbow is None else replace(chain, upper=chain.upper.at[2].set(upper_elbow))
        arm = UrdfArm(c, PositionTaskMap())
        mj = MujocoPlant.from_models(arm, control_period=1e-3, timestep=1e-4, friction=friction, **kw)
        rigid = H.RigidBodyPlant(arm=arm, friction=friction, **kw)
        s_mj, s_rb = mj.initial_state(q), rigid.initial_state(q)
        (m_mj, c_mj), (m_rb, c_rb) = mj.sense(0.0, s_mj), rigid.sense(0.0, s_rb)
        assert m_mj.force.shape == m_rb.force.shape == (3,)
        n_in = np.asarray(surface.normal(jnp.asarray(p)))
        J_p = np.asarray(c_rb.terms.J_p)
        A = n_in @ J_p @ np.linalg.solve(np.asarray(c_rb.terms.M), J_p.T @ n_in)
        W, d = mj.scene.diag_approx, IMPEDANCE
        want = np.asarray(m_rb.force) / (1.0 + d * A / ((1.0 - d) * W))
        np.testing.assert_allclose(np.asarray(m_rb.force), 1e5 * depth * n_in, rtol=1e-9)
        f = np.asarray(m_mj.force)
        f_n = f @ n_in
        f_t = np.linalg.norm(f - f_n * n_in)
        if friction is None:
            np.testing.assert_allclose(f, want, rtol=1e-9, atol=1e-9)
        else:
            assert f_n == pytest.approx(want @ n_in, rel=1e-5) and f_t < 0.2 * f_n
            print(f"μ = 0.2 at rest: f_n = {f_n:.6f} N (built-in {want @ n_in:.6f}), |F_t| = {f_t:.3g} N")
        w = jnp.zeros(6)
        r_mj, r_rb = mj.record(s_mj, w, c_mj), rigid.record(s_rb, w, c_rb)
        assert set(r_mj.signals) == set(r_rb.signals), (set(r_mj.signals) ^ set(r_rb.signals))
        for name in ("q", "qd", "x_true", "task_margin", "joint_limit_margin", "disturbance"):
            np.testing.assert_allclose(np.asarray(r_mj.signals[name]), np.asarray(r_rb.signals[name]), atol=1e-12,
                                       err_msg=name)
        np.testing.assert_array_equal(np.asarray(r_mj.signals["F_contact"]), f)
        assert float(r_mj.signals["friction_force"]) == pytest.approx(f_t, rel=1e-9, abs=1e-15)
        assert float(r_mj.penetration) == pytest.approx(depth, rel=1e-9)
        for name in ("fault", "fault_index"):
            assert int(getattr(r_mj, name)) == int(getattr(r_rb, name)), name
        assert float(r_mj.fault_value) == pytest.approx(float(r_rb.fault_value), abs=1e-12)
        if upper_elbow is None:
            assert not bool(r_mj.fault)
        else:
            assert bool(r_mj.fault) and int(r_mj.fault_index) == 2
            assert mj.fault_item(2) == rigid.fault_item(2) == "joint 3 (elbow_joint)"
            np.testing.assert_array_equal(np.asarray(mj.joint_limits()[1]), np.asarray(c.upper))
        # the start pose on the true surface, within the limits or not, as the built-in plant finds it
        for within in (True, False):
            q_mj = np.asarray(mj.initial_q(jnp.asarray(p[:2]), q_guess=Q_UR5, within_limits=within))
            q_rb = np.asarray(rigid.initial_q(jnp.asarray(p[:2]), q_guess=Q_UR5, within_limits=within))
            np.testing.assert_array_equal(q_mj, q_rb)


# --------------------------------------------------------------------------------------------
# A user's MJCF
# --------------------------------------------------------------------------------------------
def _user(**kw):
    args = dict(joints=UR5E_JOINTS, tool_site="attachment_site", task=PositionTaskMap(),
                surface=Sphere.build((0.5, 0.1, -0.25), 0.3), contact=PenaltyContact(1e5, 0.0),
                disturbance=SquareWave.none(6), control_period=1e-3, timestep=1e-4)
    args.update(kw)
    return MujocoPlant.from_mjcf(UR5E_XML, **args)


def test_user_mjcf_keeps_its_dynamics_and_switches_its_actuators_off():
    plant = _user(tool_xyz=(0.0, 0.0, 0.1), surface=Sphere.build((5.0, 5.0, 5.0), 0.3))
    m = plant.model
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_ACTUATION
    np.testing.assert_array_equal(m.dof_armature, 0.1)
    urdf = load_urdf(UR5E_URDF, "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1))
    q = jnp.asarray(Q_UR5)
    np.testing.assert_allclose(np.asarray(plant.arm.chain.fk(q)[0]), np.asarray(urdf.fk(q)[0]), atol=1e-12)
    assert _rel(plant.arm.chain.M(q), urdf.M(q)) < 1e-12  # the nominal's rigid-body part, without armature
    # a held torque equal to gravity keeps the arm at rest: no actuator force, no hidden spring
    d = mujoco.MjData(m)
    d.qpos[:] = Q_UR5
    mujoco.mj_forward(m, d)
    d.qfrc_applied[:] = d.qfrc_bias
    for _ in range(100):
        mujoco.mj_step(m, d)
    assert d.ncon == 0 and np.max(np.abs(d.qpos - Q_UR5)) < 1e-9


@pytest.mark.parametrize("kw,key,words", [
    (dict(joints=("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist1_joint", "wrist_2_joint",
                  "wrist_3_joint")), "plant.mjcf.joints", ["wrist1_joint", "wrist_1_joint"]),
    (dict(joints=UR5E_JOINTS[:5]), "plant.mjcf.joints", ["6 degrees of freedom", "wrist_3_joint"]),
    (dict(joints=UR5E_JOINTS[::-1]), "plant.mjcf.joints", ["from the base to the tool"]),
    (dict(tool_site="flange"), "plant.mjcf.tool_site", ["no site named 'flange'", "attachment_site"]),
    (dict(surface=SineProfile(amplitude=jnp.asarray(0.05), wavelength=jnp.asarray(0.6), phase=jnp.asarray(0.0),
                              offset=jnp.asarray(0.1))), "plant.surface.kind", ["'sine'", "'cylinder'"]),
    (dict(friction=Friction(coulomb=0.2, viscous=-2.0)), "plant.friction.viscous", ["finite number >= 0", "-2.0"]),
    (dict(surface=Sphere.build((0.5, 0.1, -0.25), 0.0015)), "plant.surface.radius", ["too small"]),
])
def test_user_mjcf_errors_name_the_key(kw, key, words):
    with pytest.raises(ConfigError) as err:
        _user(**kw)
    assert err.value.key == key, err.value
    for w in words:
        assert w in str(err.value), str(err.value)


def test_missing_mjcf_file_and_a_model_that_is_not_an_arm(tmp_path):
    common = dict(task=PositionTaskMap(), surface=Sphere.build((0.5, 0.1, -0.25), 0.3), contact=PenaltyContact(),
                  disturbance=SquareWave.none(6), control_period=1e-3)
    with pytest.raises(ConfigError) as err:
        MujocoPlant.from_mjcf(tmp_path / "nope.xml", joints=UR5E_JOINTS, tool_site="attachment_site", **common)
    assert err.value.key == "plant.mjcf.file"
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body><freejoint/><inertial mass='1' pos='0 0 0' diaginertia='1 1 1'/>"
                   "<site name='s'/></body></worldbody></mujoco>")
    with pytest.raises(ConfigError) as err:
        MujocoPlant.from_mjcf(bad, joints=("j",), tool_site="s", **common)
    assert err.value.key == "plant.mjcf.joints" and "no joint named 'j'" in str(err.value)


@pytest.mark.parametrize("overrides,key", [
    (["plant.mjcf.file=ur5e", "plant.mjcf.tool_site=attachment_site",
      'plant.mjcf.joints=["a","b","c","d","e","f"]'], "plant.mjcf.joints"),
    (["plant.mjcf.file=ur5e", "plant.mjcf.tool_site=tool0"], "plant.mjcf.tool_site"),
    (["plant.mjcf.file=ur5e"], "plant.mjcf.tool_site"),
    (["plant.mjcf.file=ur5e", "plant.mjcf.tool_site=attachment_site", "plant.arm.com_shift=[0.0,0.0,0.01]"],
     "plant.arm.com_shift"),
    (["plant.mjcf.tool_site=attachment_site"], "plant.mjcf.tool_site"),  # the MJCF is generated: it would be ignored
    (['plant.mjcf.locked_joints=["elbow_joint"]'], "plant.mjcf.locked_joints"),
    (["plant.mjcf.file=ur5f", "plant.mjcf.tool_site=attachment_site"], "plant.mjcf.file"),
    (["plant.friction.viscous=1e5"], "plant.friction.viscous"),  # held over a 0.1-ms MuJoCo step: too stiff
    (["plant.timestep=3e-4"], "plant.timestep"),
])
def test_cli_exits_2_naming_the_key(overrides, key, capsys):
    """`hinfnn design` loads and checks the scenario as `hinfnn run` does: a bad MuJoCo setting
    is one line naming the key, exit 2."""
    base = ["design", "ur5-polish", "--set", "nominal.arm.file=ur5e", "--set", "plant.arm.file=ur5e",
            "--set", "plant.arm.payload_mass=0.0"]
    argv = base + [a for o in overrides for a in ("--set", o)]
    code = cli.main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and key in err, err


def test_cli_sine_surface_on_mujoco_exits_2(capsys):
    code = cli.main(["design", "planar3-drum", "--set", "plant.engine=mujoco", "--set",
                     'plant.surface={kind="sine", amplitude=0.05, wavelength=0.6}'])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "plant.surface.kind" in err, err


@pytest.mark.parametrize("name", ["ur5-polish", "ur5e-polish"])
def test_shipped_mujoco_scenarios_check_and_design(name):
    """The shipped MuJoCo scenarios load, pass every check (start pose on the true drum, the step
    against the contact, the design) and build their MuJoCo plant: the generated UR5 with its payload,
    and Menagerie's UR5e MJCF."""
    sc = H.load_scenario(name)
    plant = sc.build_plant()
    assert isinstance(plant, MujocoPlant) and plant.timestep == pytest.approx(1e-4)
    assert sc.control_period == 1e-3 and sc.simulation.dt == 1e-3
    q0 = np.asarray(sc.initial_q(plant))
    s0 = plant.initial_state(q0)
    assert abs(float(s0.penetration)) < 1e-12 and np.max(np.abs(np.asarray(s0.x_true))) < 1e-12
    if name == "ur5e-polish":
        np.testing.assert_array_equal(plant.model.dof_armature, 0.1)
    else:  # the payload is in the true arm's last body
        assert plant.model.body_mass[-1] == pytest.approx(0.1879 + 0.5)


# --------------------------------------------------------------------------------------------
# A user's MJCF adapted from the scenario (MjSpec): locked joints, masses, payload, torque limits
# --------------------------------------------------------------------------------------------
def _dynamics(chain, q):
    q = jnp.asarray(q)
    return np.asarray(chain.M(q)), np.asarray(chain.G(q)), np.asarray(chain.fk(q)[0]), np.asarray(chain.fk(q)[1])


def test_user_mjcf_locked_joint_is_the_urdf_chain_with_that_joint_locked():
    """plant.mjcf.locked_joints welds the joint's body at the position: the model's rigid-body part
    is the URDF's chain with the same joint locked there (its keyframe and actuator go with it)."""
    joints = UR5E_JOINTS[:2] + UR5E_JOINTS[3:]
    plant = _user(joints=joints, locked=(("elbow_joint", 1.3),), surface=Sphere.build((5.0, 5.0, 5.0), 0.3))
    m = plant.model
    assert m.nq == m.nv == 5 and m.nkey == 0 and m.nu == 5
    urdf = load_urdf(UR5E_URDF, "base_link", "tool0", locked={"elbow_joint": 1.3})
    q = np.array([0.3, -1.0, -2.0, -1.5, 0.4])
    for a, b in zip(_dynamics(plant.arm.chain, q), _dynamics(urdf, q)):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)
    with pytest.raises(ConfigError) as err:
        _user(joints=joints, locked=(("elbow", 1.3),))
    assert err.value.key == "plant.mjcf.locked_joints" and "'elbow_joint'" in str(err.value)
    with pytest.raises(ConfigError) as err:  # a joint neither listed nor locked: the message says how to lock it
        _user(joints=joints)
    assert err.value.key == "plant.mjcf.joints" and "plant.mjcf.locked_joints" in str(err.value)


def test_user_mjcf_mass_scale_and_payload_are_the_perturbed_urdf():
    """plant.arm.mass_scale and payload_* on a user's MJCF: the compiled model's rigid-body part
    is the URDF's chain perturbed the same way (UrdfChain.perturbed)."""
    scale = np.array([1.2, 0.8, 1.1, 0.9, 1.3, 0.7])
    plant = _user(mass_scale=scale, payload_mass=0.7, payload_xyz=(0.01, -0.02, 0.03), tool_xyz=(0.0, 0.0, 0.1),
                  surface=Sphere.build((5.0, 5.0, 5.0), 0.3))
    urdf = load_urdf(UR5E_URDF, "base_link", "tool0", tool_xyz=(0.0, 0.0, 0.1)).perturbed(
        mass_scale=jnp.asarray(scale), payload_mass=0.7, payload_xyz=(0.01, -0.02, 0.03))
    for a, b in zip(_dynamics(plant.arm.chain, Q_UR5), _dynamics(urdf, Q_UR5)):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)
    assert plant.model.body("hinfnn_payload").mass[0] == 0.7
    with pytest.raises(ConfigError) as err:
        _user(mass_scale=[1.0, 2.0])
    assert err.value.key == "plant.arm.mass_scale" and "6" in str(err.value)


def test_torque_limits_of_a_user_mjcf_fall_back_to_the_given_ones():
    """The effort limits of a user's MJCF are what the file states (its joints' actuatorfrcrange,
    its actuators' force ranges times their gear); a joint without one takes the nominal URDF's
    (``effort_limit``)."""
    urdf = load_urdf(UR5E_URDF, "base_link", "tool0")
    plant = _user(surface=Sphere.build((5.0, 5.0, 5.0), 0.3))
    np.testing.assert_array_equal(np.asarray(plant.arm.chain.effort_limit), [150, 150, 150, 28, 28, 28])
    model = mujoco.MjModel.from_xml_string(chain_xml(urdf))  # no actuators
    site = "tool"
    assert np.all(np.isinf(np.asarray(chain_from_model(model, UR5E_JOINTS, site).effort_limit)))
    given = chain_from_model(model, UR5E_JOINTS, site, effort_limit=urdf.effort_limit)
    np.testing.assert_array_equal(np.asarray(given.effort_limit), np.asarray(urdf.effort_limit))
    # a joint's actuatorfrcrange, an actuator's force range times its gear (summed over the joint's
    # actuators), the smaller of the two; an actuator without a force range states nothing
    xml = chain_xml(urdf)
    for joint, limit in (("shoulder_pan_joint", 40), ("elbow_joint", 20)):
        xml = xml.replace(f'<joint name="{joint}" ', f'<joint name="{joint}" actuatorfrcrange="-{limit} {limit}" ')
    xml = xml.replace("</mujoco>", '<actuator><motor joint="shoulder_lift_joint" gear="50" forcerange="-2 2"/>'
                      '<motor joint="elbow_joint" gear="-10" forcerange="-3 3"/>'
                      '<motor joint="wrist_1_joint" forcerange="-5 5"/><motor joint="wrist_1_joint" gear="2" '
                      'forcerange="-1 1"/><motor joint="wrist_2_joint" gear="3"/></actuator></mujoco>')
    stated = chain_from_model(mujoco.MjModel.from_xml_string(xml), UR5E_JOINTS, site, effort_limit=urdf.effort_limit)
    np.testing.assert_array_equal(np.asarray(stated.effort_limit), [40, 100, 20, 7, 28, 28])


def test_design_refuses_what_run_refuses(monkeypatch, capsys):
    """`hinfnn design` runs the checks a run makes before it compiles (the plant's state at the
    start pose, the start pose for the controller): what the run refuses, design refuses with the
    same one-line message, exit 2."""
    def refuse(self, q0, qd0=None):
        raise ConfigError("MuJoCo cannot start from this pose", key="plant.mjcf.file")

    sc = H.load_scenario("ur5-polish", ["simulation.t_final=0.01"])  # its sensor's check reads the start state
    monkeypatch.setattr(MujocoPlant, "initial_state", refuse)
    with pytest.raises(ConfigError) as run_err:
        sc.simulate()
    code = cli.main(["design", "ur5-polish"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == f"hinfnn: ConfigError: {run_err.value}", err


def test_mjcf_file_is_a_path_or_a_shipped_name(tmp_path, monkeypatch, capsys):
    """plant.mjcf.file: a file of that name (any extension) is the user's, relative to the
    scenario file in a file; with --set relative to the working directory, else to the scenario
    file (a name in both places that are different files is refused); else a shipped model; an
    unknown name lists the shipped ones."""
    from hinfnn.scenario.sections import mjcf_path

    mine = tmp_path / "mj-copy.mjcf"
    mine.write_text(open(UR5E_XML, encoding="utf-8").read(), encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    assert mjcf_path("mj-copy.mjcf") == "mj-copy.mjcf" and mjcf_path("ur5e") == UR5E_XML
    with pytest.raises(ConfigError) as err:
        mjcf_path("ur5f")
    assert err.value.key == "plant.mjcf.file" and "'ur5e'" in str(err.value) and "shipped" in str(err.value)
    with pytest.raises(ConfigError) as err:
        mjcf_path("nope/mine.xml")
    assert "no such file" in str(err.value)
    # a scenario file beside the MJCF names it relative to itself, from any working directory
    folder = tmp_path / "study"
    folder.mkdir()
    (folder / "arm.xml").write_text(mine.read_text(encoding="utf-8"), encoding="utf-8")
    (folder / "s.toml").write_text('base = "ur5e-polish"\n[plant.mjcf]\nfile = "arm.xml"\n', encoding="utf-8")
    monkeypatch.chdir(folder.parent.parent)
    sc = H.load_scenario(str(folder / "s.toml"), check=False)
    assert sc.plant.mjcf.file == str((folder / "arm.xml").resolve())
    # --set: a file in the working directory as typed, else the one beside the scenario file
    scenario = str(folder / "s.toml")
    sc = H.load_scenario(scenario, ["plant.mjcf.file=arm.xml"], check=False)  # cwd: tmp_path's parent
    assert sc.plant.mjcf.file == str((folder / "arm.xml").resolve())
    assert dict(sc.overrides)["plant.mjcf.file"] == sc.plant.mjcf.file  # re-applied from anywhere
    with pytest.raises(ConfigError) as err:  # in neither place: both named
        H.load_scenario(scenario, ["plant.mjcf.file=other.xml"], check=False)
    assert err.value.key == "plant.mjcf.file" and str((folder / "other.xml").resolve()) in str(err.value)
    assert str((tmp_path.parent / "other.xml").resolve()) in str(err.value) and "'ur5e'" in str(err.value)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "arm.xml").write_text(mine.read_text(encoding="utf-8"), encoding="utf-8")
    with pytest.raises(ConfigError) as err:  # two different files of that name: which one is not guessed
        H.load_scenario(scenario, ["plant.mjcf.file=arm.xml"], check=False)
    assert err.value.key == "plant.mjcf.file" and "absolute path" in str(err.value)
    for path in (folder / "arm.xml", tmp_path / "arm.xml"):
        assert str(path.resolve()) in str(err.value)
    plant = H.load_scenario("ur5e-polish", ["plant.mjcf.file=mj-copy.mjcf"]).build_plant()  # --set: the cwd
    assert plant.scene.source == "mj-copy.mjcf" and plant.model.nq == 6


def test_path_past_a_limit_of_the_users_mjcf_names_the_mjcf(tmp_path):
    """The reference's path leaves a joint range written in the user's MJCF: the DesignError says
    the range is the MJCF's (plant.mjcf.file), not a URDF's."""
    from hinfnn.errors import DesignError

    text = open(UR5E_XML, encoding="utf-8").read().replace(
        '<joint name="shoulder_pan_joint" class="size3" axis="0 0 1"/>',
        '<joint name="shoulder_pan_joint" class="size3" axis="0 0 1" range="3.07 3.076"/>')
    assert 'range="3.07 3.076"' in text
    path = tmp_path / "narrow.xml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(DesignError) as err:
        H.load_scenario("ur5e-polish", [f"plant.mjcf.file={path}"])
    assert err.value.key == "reference" and "shoulder_pan_joint" in str(err.value), err.value
    assert f"the true arm's MJCF, plant.mjcf.file = '{path}'" in str(err.value) and "URDF" not in str(err.value)


def test_an_mjcf_armature_the_nominal_lacks_is_named_in_one_warning():
    """fr3-table's truth (fr3.xml) has a motor armature on every joint: with the nominal told none,
    the scenario's checks warn (HinfnnWarning) naming the joints and values; the shipped fr3-table
    (its nominal states them) and a generated MJCF (the truth is plant.arm) do not."""
    from hinfnn.errors import HinfnnWarning
    from hinfnn.scenario import Scenario
    from hinfnn.scenario.checks import _warn_unmodelled_armature, unmodelled_armature

    bare = Scenario.load("fr3-table", {"nominal.arm.armature": 0.0}, check=False)
    setup = bare.build()
    expected = [(f"joint{i + 1}", a) for i, a in enumerate((0.2, 0.2, 0.2, 0.2, 0.1, 0.1, 0.1))]
    assert unmodelled_armature(bare, setup) == expected
    with pytest.warns(HinfnnWarning, match=r"nominal.arm.armature: the true arm's MJCF \(fr3\) gives its joints a motor "
                      r"armature \(joint1 0.2, joint2 0.2, .*joint7 0.1 kg m\^2\).*nominal.arm.armature = "
                      r"\[0.2, 0.2, 0.2, 0.2, 0.1, 0.1, 0.1\]"):
        _warn_unmodelled_armature(bare, setup)
    shipped = Scenario.load("fr3-table", check=False)
    assert unmodelled_armature(shipped, shipped.build()) == []
    generated = Scenario.load("panda-table", {"plant.engine": "mujoco"}, check=False)
    assert unmodelled_armature(generated, generated.build()) == []
