"""URDF arms (hinfnn.model.urdf, hinfnn.model.taskmap) against Pinocchio, the closed-form Sec. VI
arm, autodiff and finite differences; and the parser's errors.

Pinocchio is the oracle (installed by ``make test``): the same URDF is built with
``pinocchio.buildModelFromUrdf``/``buildModelFromXML`` and compared on 100 seeded random states.
Everything jitted is compiled once per module (module-scoped fixtures).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pinocchio as pin  # the oracle (a test dependency)
import pytest

import hinfnn as H
from hinfnn._linalg import Kernels
from hinfnn.model.arm import Arm, PlanarPointMassArm
from hinfnn.model.taskmap import PlanarTaskMap, PoseTaskMap, PositionTaskMap, so3_exp, so3_log
from hinfnn.model.urdf import (UrdfArm, UrdfError, UrdfWarning, _tool_frame, asset_path, load_urdf, load_urdf_string,
                               rpy_matrix)

#: one xdist worker runs this module: its tests share compiled programs and expensive fixtures
pytestmark = pytest.mark.xdist_group("urdf")

UR5 = asset_path("ur5", "ur5.urdf")
SEC6 = asset_path("planar", "sec6_two_link.urdf")
THREE = asset_path("planar", "three_link.urdf")
TOL = 1e-10  # relative, against Pinocchio
UR5_TOOL = dict(tool_xyz=(0.01, -0.02, 0.15), tool_rpy=(0.1, -0.2, 0.3))


def rel(a, b):
    """max |a − b| / max |b| over everything compared."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


# --------------------------------------------------------------------------------------------
# A synthetic URDF exercising what the shipped files do not: inertial rpy and full inertia
# tensors, fixed joints on the chain carrying mass, a prismatic joint, an unnormalised axis,
# rotated joint origins, a side branch with a fixed and a revolute joint (locked), links below
# the end-effector and a massive fixed pedestal under the first joint.
# --------------------------------------------------------------------------------------------
def _synthetic_urdf(seed=3):
    rng = np.random.default_rng(seed)

    def vec(x):
        return " ".join(f"{v:.17g}" for v in x)

    def inertial(mass):
        dims = rng.uniform(0.05, 0.4, 3)
        box = mass / 12 * np.diag([dims[1]**2 + dims[2]**2, dims[0]**2 + dims[2]**2, dims[0]**2 + dims[1]**2])
        Q = rpy_matrix(rng.uniform(-np.pi, np.pi, 3))
        I = Q @ box @ Q.T
        return (f'<inertial><origin xyz="{vec(rng.uniform(-0.2, 0.2, 3))}" rpy="{vec(rng.uniform(-1, 1, 3))}"/>'
                f'<mass value="{mass:.17g}"/><inertia ixx="{I[0,0]:.17g}" ixy="{I[0,1]:.17g}" ixz="{I[0,2]:.17g}" '
                f'iyy="{I[1,1]:.17g}" iyz="{I[1,2]:.17g}" izz="{I[2,2]:.17g}"/></inertial>')

    def joint(name, jtype, parent, child, axis=None):
        o = f'<origin xyz="{vec(rng.uniform(-0.3, 0.3, 3))}" rpy="{vec(rng.uniform(-1.5, 1.5, 3))}"/>'
        a = f'<axis xyz="{axis}"/>' if axis else ""
        moving = jtype in ("revolute", "prismatic")
        lim = '<limit lower="-3" upper="3" effort="10" velocity="5"/>' if moving else ""
        return (f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
                f'{o}{a}{lim}</joint>')

    links = {"base": 0, "pedestal": 3.0, "link1": 2.0, "link1b": 0.7, "link2": 1.5, "link3": 1.2,
             "sensor": 0.3, "finger": 0.2, "ee": 0.1, "below_ee": 0.25}
    body = "".join(f'<link name="{k}">{inertial(m) if m else ""}</link>' for k, m in links.items())
    body += joint("mount", "fixed", "base", "pedestal")
    body += joint("j1", "revolute", "pedestal", "link1", "0 0 1")
    body += joint("j1_fixed", "fixed", "link1", "link1b")
    body += joint("j2", "prismatic", "link1b", "link2", "1 2 0.5")
    body += joint("j3", "revolute", "link2", "link3", "0.3 -1 0.2")
    body += joint("sensor_mount", "fixed", "link3", "sensor")
    body += joint("finger_joint", "revolute", "link3", "finger", "1 0 0")
    body += joint("ee_joint", "fixed", "link3", "ee")
    body += joint("below", "fixed", "ee", "below_ee")
    return f'<?xml version="1.0"?><robot name="synthetic">{body}</robot>'


# --------------------------------------------------------------------------------------------
# Oracles
# --------------------------------------------------------------------------------------------
def pinocchio_terms(model, frame, q, qd):
    """M, C(q,q̇)q̇, G, tool p and R, frame Jacobian and its time variation (LOCAL_WORLD_ALIGNED),
    and J̇q̇ as the frame's classical acceleration at q̈ = 0."""
    data = model.createData()
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    M = pin.crba(model, data, q)
    G = pin.computeGeneralizedGravity(model, data, q).copy()
    out = {"M": np.triu(M) + np.triu(M, 1).T, "G": G, "Cqd": pin.nonLinearEffects(model, data, q, qd) - G}
    pin.forwardKinematics(model, data, q, qd, np.zeros_like(qd))
    pin.updateFramePlacements(model, data)
    out["p"], out["R"] = data.oMf[frame].translation.copy(), data.oMf[frame].rotation.copy()
    out["Jdqd"] = pin.getFrameClassicalAcceleration(model, data, frame, lwa).vector.copy()
    pin.computeJointJacobians(model, data, q)
    out["J"] = pin.getFrameJacobian(model, data, frame, lwa).copy()
    pin.computeJointJacobiansTimeVariation(model, data, q, qd)
    out["Jd"] = pin.getFrameJacobianTimeVariation(model, data, frame, lwa).copy()
    return out


def chain_terms(chain, q, qd):
    """The quantities :func:`pinocchio_terms` returns, from a UrdfChain (each public function
    called once: XLA compile time grows with every forward pass traced). The tool frame, its
    Jacobian and M twice: by the public ``fk``, ``frame_jacobian`` and ``M`` (3 × 3 products, the
    programs that run once) and by the compiled loop's algorithms on its kinematics
    (``_kinematics``, component by component), each against Pinocchio's (:data:`LOOP_KEYS`). The
    loop's algorithms once more on the kinematics the design's programs give them
    (the chain holding kernels with :attr:`hinfnn._linalg.Kernels.products`): M, C(q, q̇)q̇, G and J̇
    (:data:`PRODUCTS_KEYS`)."""
    p, R = chain.fk(q)
    Jd = chain.frame_jacobian_dot(q, qd)
    G = chain.G(q)
    k = chain._kinematics(q)
    p_loop, R_loop = _tool_frame(k)
    by_products = Kernels(products=True).hold(chain)
    kp = by_products._kinematics(q)
    G_products = by_products.G(q)
    products = {"M_products": by_products._crba(kp), "G_products": G_products,
                "Cqd_products": by_products.bias(q, qd) - G_products,
                "Jd_products": by_products.frame_jacobian_dot(q, qd), "p_products": kp.p_tool, "R_products": kp.R_tool}
    return {"M": chain.M(q), "Cqd": chain.bias(q, qd) - G, "G": G, "p": p, "R": R,
            "J": chain.frame_jacobian(q), "Jd": Jd, "Jdqd": Jd @ qd,
            "p_loop": p_loop, "R_loop": R_loop, "J_loop": chain._jacobian(k), "M_loop": chain._crba(k),
            **{key: jnp.asarray(v) for key, v in products.items()}}


#: The compiled loop's tool frame, Jacobian and M, checked against the same Pinocchio quantities.
LOOP_KEYS = {"p_loop": "p", "R_loop": "R", "J_loop": "J", "M_loop": "M"}
#: The loop's algorithms on the design programs' kinematics (by products), against Pinocchio.
PRODUCTS_KEYS = {"M_products": "M", "G_products": "G", "Cqd_products": "Cqd", "Jd_products": "Jd",
                 "p_products": "p", "R_products": "R"}


def identities(arm, q, qd, v, qdd):
    """Quantities whose identities the tests check (C, C_times, Ṁ, inverse/forward dynamics);
    M, G and C(q, q̇)q̇ come from :func:`chain_terms`."""
    ch = arm.chain
    C = ch.C(q, qd)
    tau = ch.inverse_dynamics(q, qd, qdd)
    bias_pm = jax.vmap(lambda w: ch.bias(q, w))(jnp.stack([qd + v, qd - v]))  # one forward pass
    return {
        "M_dot": jax.jvp(ch.M, (q,), (qd,))[1], "C": C, "Cv": C @ v, "C_times": ch.C_times(q, qd, v),
        "C_times_swapped": ch.C_times(q, v, qd), "polar": 0.25 * (bias_pm[0] - bias_pm[1]), "Cqd_matrix": C @ qd,
        "ID": tau, "round_trip": ch.forward_dynamics(q, qd, tau),
        "dU_v": jax.jvp(ch.potential, (q,), (v,))[1],
    }


def autodiff(arm, q, qd, christoffel=True):
    """Analytic task terms (and C) next to the autodiff of the Arm base class (jacfwd of h and of M)."""
    out = {"terms": arm.terms(q, qd), "bias": arm.bias(q, qd), "h_ad": arm.h(q), "J_ad": Arm.J(arm, q),
           "J_dot_ad": Arm.J_dot(arm, q, qd)}
    if christoffel:
        out["C_ad"] = Arm.C(arm, q, qd)
    return out


def add_tool_frame(model, parent_frame_name, xyz, rpy, name="tcp"):
    parent = model.frames[model.getFrameId(parent_frame_name)]
    placement = parent.placement * pin.SE3(rpy_matrix(np.asarray(rpy)), np.asarray(xyz, float))
    return model.addFrame(pin.Frame(name, parent.parentJoint, model.getFrameId(parent_frame_name), placement,
                                    pin.FrameType.OP_FRAME))


def states(n, count, seed):
    """(q, q̇, v, q̈) rows: q uniform in (−π, π), the others normal (q̇ scaled by 2)."""
    rng = np.random.default_rng(seed)
    return (rng.uniform(-np.pi, np.pi, (count, n)), 2.0 * rng.normal(size=(count, n)),
            rng.normal(size=(count, n)), rng.normal(size=(count, n)))


def stacked(fn, *arrays):
    """fn called on each row (a Python loop of single calls of one compiled program), stacked."""
    outs = [jax.device_get(fn(*row)) for row in zip(*arrays)]
    return jax.tree.map(lambda *a: np.stack(a), *outs)


class Case:
    """An arm, its Pinocchio twin, 100 seeded states and the results of both on them."""

    def __init__(self, arm, model, frame, seed, extra=None):
        self.arm, self.model, self.frame = arm, model, frame
        model.gravity.linear[:] = np.asarray(arm.chain.gravity)
        assert model.nq == model.nv == arm.n
        self.Q, self.QD, self.V, self.QDD = states(arm.n, 100, seed)

        def program(arm, q, qd, v, qdd):  # one compiled program per arm structure
            out = chain_terms(arm.chain, q, qd)
            if extra is not None:
                out.update(extra(arm, q, qd, v, qdd))
            return out

        self.compiled = jax.jit(program)
        self.program = lambda *args: self.compiled(self.arm, *args)
        self.got = stacked(self.program, self.Q, self.QD, self.V, self.QDD)
        self.ref = stacked(lambda q, qd: pinocchio_terms(model, frame, q, qd), self.Q, self.QD)


@pytest.fixture(scope="module")
def ur5_chain():
    return load_urdf(UR5, "base_link", "tool0", **UR5_TOOL)


@pytest.fixture(scope="module")
def three_chain():
    return load_urdf(THREE, "base_link", "tool")


@pytest.fixture(scope="module")
def ur5_arm(ur5_chain):
    q0 = np.array([0.3, -1.1, 1.4, -0.6, 0.9, 0.2])
    R_ref = np.asarray(ur5_chain.fk(q0)[1]) @ rpy_matrix(np.array([0.4, -0.3, 0.5]))
    return UrdfArm(ur5_chain, PoseTaskMap(R_ref=jnp.asarray(R_ref)))


@pytest.fixture(scope="module")
def three_arm(three_chain):
    return UrdfArm(three_chain, PlanarTaskMap("xz", with_angle=True, phi_ref=0.5))


@pytest.fixture(scope="module")
def synthetic_arm():
    chain = load_urdf_string(_synthetic_urdf(), "base", "ee", tool_xyz=(0.05, 0.0, 0.1), tool_rpy=(0.0, 0.3, 0.0))
    return UrdfArm(chain, PositionTaskMap())


@pytest.fixture(scope="module")
def ur5_case(ur5_arm):
    model = pin.buildModelFromUrdf(UR5)
    frame = add_tool_frame(model, "tool0", UR5_TOOL["tool_xyz"], UR5_TOOL["tool_rpy"])
    # C by the Christoffel symbols is checked on the UR5 by the identities (Ṁ = C + Cᵀ and the
    # symmetry C(q, a)b = C(q, b)a determine it), against autodiff of M on the 3-link arm
    def extra(arm, q, qd, v, qdd):
        return {**identities(arm, q, qd, v, qdd), **autodiff(arm, q, qd, False)}

    return Case(ur5_arm, model, frame, seed=0, extra=extra)


@pytest.fixture(scope="module")
def three_case(three_arm):
    model = pin.buildModelFromUrdf(THREE)
    extra = lambda arm, q, qd, v, qdd: autodiff(arm, q, qd)  # noqa: E731
    return Case(three_arm, model, model.getFrameId("tool"), seed=1, extra=extra)


@pytest.fixture(scope="module")
def synthetic_case(synthetic_arm):
    """The side-branch revolute joint is locked at zero in Pinocchio too (buildReducedModel)."""
    full = pin.buildModelFromXML(_synthetic_urdf())
    model = pin.buildReducedModel(full, [full.getJointId("finger_joint")], pin.neutral(full))
    return Case(synthetic_arm, model, add_tool_frame(model, "ee", (0.05, 0.0, 0.1), (0.0, 0.3, 0.0)), seed=2)


@pytest.mark.parametrize("name", ["ur5_case", "three_case", "synthetic_case"])
def test_against_pinocchio(request, name):
    case = request.getfixturevalue(name)
    errors = {k: rel(case.got[k], case.ref[k]) for k in case.ref}
    errors.update({k: rel(case.got[k], case.ref[ref]) for k, ref in {**LOOP_KEYS, **PRODUCTS_KEYS}.items()})
    print(name, {k: f"{v:.1e}" for k, v in errors.items()})
    assert all(v < TOL for v in errors.values()), errors


def test_parsed_structure(ur5_chain):
    """Fixed joints merged: the UR5's wrist_3 body carries ee_link and tool0 (massless); tool
    offset composed after tool0; limits kept."""
    c = ur5_chain
    assert c.n == 6 and c.joint_types == ("revolute",) * 6
    assert c.joint_names[0] == "shoulder_pan_joint" and c.body_links[-1] == ("ee_link", "tool0", "wrist_3_link")
    np.testing.assert_allclose(c.mass, [3.7, 8.393, 2.275, 1.219, 1.219, 0.1879])
    np.testing.assert_allclose(c.upper[2], 3.14159265359)
    np.testing.assert_allclose(c.velocity_limit[-1], 3.2)


# --------------------------------------------------------------------------------------------
# Identities of the dynamics (UR5, 100 states)
# --------------------------------------------------------------------------------------------
def test_dynamics_identities(ur5_case):
    out = ur5_case.got
    N = out["M_dot"] - 2 * out["C"]
    scale = np.max(np.abs(out["M_dot"]))
    assert np.max(np.abs(N + np.swapaxes(N, 1, 2))) < 1e-12 * scale  # Ṁ − 2C skew
    assert rel(out["C_times"], out["Cv"]) < 1e-12
    assert rel(out["C_times_swapped"], out["Cv"]) < 1e-12  # C(q, a) b = C(q, b) a: Christoffel
    assert rel(out["polar"], out["Cv"]) < 1e-12
    assert rel(out["Cqd_matrix"], out["Cqd"]) < 1e-12
    assert rel(out["round_trip"], ur5_case.QDD) < 1e-10
    ID_matrix = (np.einsum("nij,nj->ni", out["M"], ur5_case.QDD) + np.einsum("nij,nj->ni", out["C"], ur5_case.QD)
                 + out["G"])
    assert rel(out["ID"], ID_matrix) < 1e-12
    assert rel(out["dU_v"], np.einsum("ni,ni->n", out["G"], ur5_case.V)) < 1e-12  # G = ∂U/∂q
    # Ṁ by central differences of M along q̇ (a few states)
    eps, case = 1e-6, ur5_case
    for i in range(5):
        Mp = case.program(case.Q[i] + eps * case.QD[i], case.QD[i], case.V[i], case.QDD[i])["M"]
        Mm = case.program(case.Q[i] - eps * case.QD[i], case.QD[i], case.V[i], case.QDD[i])["M"]
        M_dot_fd = (np.asarray(Mp) - np.asarray(Mm)) / (2 * eps)
        assert rel(M_dot_fd, out["M_dot"][i]) < 1e-8
        N_fd = M_dot_fd - 2 * out["C"][i]
        assert np.max(np.abs(N_fd + N_fd.T)) < 1e-8 * scale


def test_grad_matches_finite_differences(synthetic_arm):
    """Reverse mode through CRBA and RNEA (synthetic arm: full inertias, a prismatic joint)."""
    ch = synthetic_arm.chain
    rng = np.random.default_rng(11)
    W, u, qd = rng.normal(size=(3, 3)), rng.normal(size=3), rng.normal(size=3)

    def scalar(q):
        return jnp.sum(W * ch.M(q)) + jnp.dot(u, ch.bias(q, qd))

    f = jax.jit(jax.value_and_grad(scalar))
    q = rng.uniform(-np.pi, np.pi, 3)
    eps = 1e-6
    fd = np.array([(f(q + eps * e)[0] - f(q - eps * e)[0]) / (2 * eps) for e in np.eye(3)])
    assert rel(f(q)[1], fd) < 1e-7


def test_vmap_equals_loop(three_case, three_arm):
    """vmap over 16 states equals the loop of single calls (the case's compiled program)."""
    case = three_case
    batched = jax.jit(jax.vmap(lambda q, qd: (three_arm.terms(q, qd), three_arm.bias(q, qd))))
    terms, bias = batched(case.Q[:16], case.QD[:16])
    for a, b in zip(jax.tree.leaves((terms, bias)), jax.tree.leaves((case.got["terms"], case.got["bias"]))):
        np.testing.assert_allclose(a, b[:16], rtol=1e-12, atol=1e-12)


# --------------------------------------------------------------------------------------------
# Task-space terms: analytic (frame Jacobian and task map derivative) vs autodiff of h
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["ur5_case", "three_case"])
def test_task_terms_vs_autodiff(request, name):
    """UR5 with a pose map on the 100 random states (those at least 0.2 rad from the half turn),
    the 3-link arm with the planar map with angle (and C against autodiff of M)."""
    case = request.getfixturevalue(name)
    out = case.got
    t = out["terms"]
    assert rel(t.x, out["h_ad"]) < 1e-14
    ok = np.ones(len(case.Q), dtype=bool)
    if name == "ur5_case":  # r is not differentiable at the half turn
        ok = np.pi - np.linalg.norm(t.x[:, 3:], axis=1) > 0.2
        assert ok.sum() >= 50
    assert rel(t.J[ok], out["J_ad"][ok]) < 1e-11
    assert rel(t.J_dot[ok], out["J_dot_ad"][ok]) < 1e-11
    if "C_ad" in out:
        assert rel(t.C, out["C_ad"]) < 1e-12


def test_pose_map_near_reference(ur5_case):
    """At and near R_ref (r ≈ 0) the pose map's J and J̇ are exact (the case's compiled program,
    called with another R_ref)."""
    case, arm = ur5_case, ur5_case.arm
    q0 = np.array([0.3, -1.1, 1.4, -0.6, 0.9, 0.2])
    at_ref = UrdfArm(arm.chain, PoseTaskMap(R_ref=arm.chain.fk(q0)[1]))
    for dq in (np.zeros(6), 1e-9 * case.QD[0], 1e-3 * case.QD[1]):
        out = case.compiled(at_ref, q0 + dq, case.QD[2], case.V[2], case.QDD[2])
        assert np.all(np.isfinite(out["terms"].J)) and np.all(np.isfinite(out["terms"].J_dot))
        assert rel(out["terms"].J, out["J_ad"]) < 1e-12
        assert rel(out["terms"].J_dot, out["J_dot_ad"]) < 1e-12
        if not dq.any():
            assert np.max(np.abs(out["terms"].x[3:])) < 1e-15


def test_sec6_urdf_equals_two_link_arm():
    arm = UrdfArm(load_urdf(SEC6, "base_link", "tool", gravity=(0.0, 0.0, -9.8)), PlanarTaskMap("xz"))
    ref = H.TwoLinkArm(m1=1.5, m2=1.0, l1=1.0, l2=1.0)
    Q, QD, _, _ = states(2, 100, seed=4)
    a, b = jax.jit(arm.terms), jax.jit(ref.terms)
    for q, qd in zip(Q, QD):
        ta, tb = a(q, qd), b(q, qd)
        for name in ("x", "J", "J_dot", "M", "C", "G"):
            np.testing.assert_allclose(getattr(ta, name), getattr(tb, name), rtol=0, atol=1e-12, err_msg=name)


def test_three_link_equals_planar_point_mass_arm(three_case):
    """The shipped 3-link arm is the generic point-mass arm of model/arm.py (g = 9.81)."""
    case = three_case
    ref = PlanarPointMassArm(masses=jnp.array([2.0, 1.5, 1.0]), lengths=jnp.array([0.8, 0.7, 0.5]), g=9.81, n=3)
    out = stacked(jax.jit(lambda q, qd: (ref.h(q), ref.M(q), ref.C(q, qd), ref.G(q))), case.Q[:5], case.QD[:5])
    got = case.got
    for a, b in ((got["terms"].x[:5, :2], out[0]), (got["M"][:5], out[1]), (got["terms"].C[:5], out[2]),
                 (got["G"][:5], out[3])):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_three_link_reaches_the_drum_top(three_chain):
    """Tool on top of a drum of radius 0.3 m centred at (1, 0), pressing straight down
    (closed-form elbow-up inverse kinematics of the wrist point)."""
    phi, tip = -np.pi / 2, np.array([1.0, 0.3])
    w = tip - 0.5 * np.array([np.cos(phi), np.sin(phi)])
    c2 = (w @ w - 0.8**2 - 0.7**2) / (2 * 0.8 * 0.7)
    q2 = -np.arccos(c2)
    q1 = np.arctan2(w[1], w[0]) - np.arctan2(0.7 * np.sin(q2), 0.8 + 0.7 * np.cos(q2))
    q = np.array([q1, q2, phi - q1 - q2])
    x = jax.jit(lambda q: PlanarTaskMap("xz", with_angle=True)(*three_chain.fk(q)))(q)
    np.testing.assert_allclose(x, [1.0, 0.3, phi], atol=1e-12)


# --------------------------------------------------------------------------------------------
# Rotation vector
# --------------------------------------------------------------------------------------------
def test_pose_task_map_rotation_vector():
    R_ref = np.asarray(so3_exp(jnp.array([0.2, -0.4, 0.1])))
    task = PoseTaskMap(R_ref=jnp.asarray(R_ref))

    def r_of_u(u):  # rotation vector of the tool at R = R_ref exp([u]×): u itself for |u| < π
        return task(jnp.zeros(3), task.R_ref @ so3_exp(u))[3:]

    @jax.jit
    def f(u):
        R = so3_exp(u)
        x = jnp.concatenate([jnp.zeros(3), r_of_u(u)])
        return {"R": R, "log": so3_log(R), "r": r_of_u(u), "jac": jax.jacfwd(r_of_u)(u),
                "margin": PoseTaskMap.singularity_margin(x),
                "dmargin": jax.grad(PoseTaskMap.singularity_margin)(x)}

    rng = np.random.default_rng(8)
    for _ in range(20):  # round trip exp(log) up to angles near π
        axis = rng.normal(size=3)
        u = axis / np.linalg.norm(axis) * rng.uniform(0.0, np.pi - 0.05)
        out = f(u)
        np.testing.assert_allclose(out["R"] @ out["R"].T, np.eye(3), atol=1e-14)
        np.testing.assert_allclose(out["log"], u, atol=1e-12)
        np.testing.assert_allclose(out["r"], u, atol=1e-12)  # r = log(R_refᵀ R)
        np.testing.assert_allclose(out["margin"], np.pi - np.linalg.norm(u), atol=1e-12)
    # Jacobian vs central differences, away from and at r = 0 (where it is the identity)
    for u0 in (np.array([0.5, -1.0, 0.7]), np.zeros(3)):
        eps = 1e-6
        fd = np.stack([(f(u0 + eps * e)["r"] - f(u0 - eps * e)["r"]) / (2 * eps) for e in np.eye(3)], axis=1)
        np.testing.assert_allclose(f(u0)["jac"], fd, atol=1e-8)
    at0 = f(np.zeros(3))
    np.testing.assert_array_equal(at0["r"], np.zeros(3))
    np.testing.assert_allclose(at0["jac"], np.eye(3), atol=1e-15)
    assert float(at0["margin"]) == pytest.approx(np.pi) and np.all(np.isfinite(at0["dmargin"]))
    # near the identity the series branch and the exact branch agree
    for t in (0.99e-2, 1.01e-2):
        u = np.array([t, 0.0, 0.0])
        np.testing.assert_allclose(f(u)["r"], u, rtol=1e-14, atol=1e-16)
        np.testing.assert_allclose(f(u)["jac"], np.eye(3), atol=1e-12)


def test_planar_task_map_validates_plane():
    with pytest.raises(H.ConfigError, match="plane"):
        PlanarTaskMap("xx")


# --------------------------------------------------------------------------------------------
# Model uncertainty
# --------------------------------------------------------------------------------------------
def test_perturbed_inertia_matches_edited_urdf(three_chain):
    """Mass scale, centre-of-mass shift and payload equal the same edits made in the URDF."""
    text = open(THREE).read()
    shift = np.array([0.05, 0.0, -0.02])
    edited = (text.replace('<mass value="1.5"/>', '<mass value="1.8"/>')
                  .replace('<origin xyz="0.8 0 0" rpy="0 0 0"/>\n      <mass value="2.0"/>',
                           '<origin xyz="0.85 0 -0.02" rpy="0 0 0"/>\n      <mass value="2.0"/>')
                  .replace('<link name="tool"/>', '<link name="tool"><inertial><origin xyz="0.1 0 0"/>'
                           '<mass value="0.4"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>'
                           '</inertial></link>'))
    truth = load_urdf_string(edited, "base_link", "tool")
    pert = three_chain.perturbed(mass_scale=jnp.array([1.0, 1.2, 1.0]),
                                 com_shift=jnp.stack([jnp.asarray(shift), jnp.zeros(3), jnp.zeros(3)]),
                                 payload_mass=0.4, payload_xyz=(0.1, 0.0, 0.0))
    q, qd = np.array([0.3, -0.7, 1.1]), np.array([0.5, -1.0, 0.8])
    dyn = jax.jit(lambda c: (c.M(q), c.bias(q, qd), c.G(q)))  # one program for every chain
    for a, b in zip(dyn(pert), dyn(truth)):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13)
    for a, b in zip(dyn(three_chain.perturbed()), dyn(three_chain)):
        np.testing.assert_allclose(a, b, rtol=1e-15, atol=0)
    # parameters may be traced: vmap over a batch of mass scales (2× mass: 2× M)
    Ms = jax.jit(jax.vmap(lambda s: three_chain.perturbed(mass_scale=s).M(q)))(jnp.array([1.0, 2.0]))
    np.testing.assert_allclose(Ms[1], 2 * Ms[0], rtol=1e-14)


# --------------------------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------------------------
GOOD = """<robot name="r">
  <link name="base"/>
  <joint name="j1" type="{jtype}"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/></joint>
  <link name="arm"><inertial><origin xyz="0.5 0 0"/><mass value="{mass}"/>
    <inertia ixx="{ixx}" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="j2" type="fixed"><parent link="arm"/><child link="{child}"/><origin xyz="1 0 0"/></joint>
  <link name="tool"/>
  {extra}
</robot>"""


def _write(tmp_path, text):
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    return str(path)


def _good(**kw):
    args = dict(jtype="revolute", mass="1.0", ixx="0.01", child="tool", extra="")
    args.update(kw)
    return GOOD.format(**args)


def test_good_file_loads(tmp_path):
    chain = load_urdf(_write(tmp_path, _good()), "base", "tool")
    assert chain.n == 1


@pytest.mark.parametrize("text, ee, pattern, element", [
    ("<robot><link name='a'></robot", "tool", "not an XML file", None),
    ("<model name='x'/>", "tool", "no <robot> element", None),
    (_good(child="tol"), "tool", "'tol' is not defined.*did you mean 'tool'", '<joint name="j2">'),
    (_good(), "tol", "no link named 'tol'.*did you mean 'tool'", "ee_link"),
    (_good(extra='<joint name="j3" type="fixed"><parent link="base"/><child link="tool"/></joint>'), "tool",
     "kinematic loop.*'tool' has two parents", '<joint name="j3">'),
    (_good(mass="0"), "tool", "mass 0.0 \\(allowed: > 0\\)", '<joint name="j1">'),
    (_good(mass="-1"), "tool", "link 'arm' of the body moved by this joint has negative mass", '<joint name="j1">'),
    (_good(jtype="floating"), "tool", "joint type 'floating'.*not supported", '<joint name="j1">'),
    (_good(jtype="planar"), "tool", "joint type 'planar'.*not supported", '<joint name="j1">'),
    (_good(jtype="ball"), "tool", "unknown joint type 'ball'", '<joint name="j1">'),
    (_good(ixx="-0.01"), "tool", "body moved by this joint \\(links arm, tool\\) is not positive semidefinite",
     '<joint name="j1">'),
    (_good(extra='<link name="alone"/>'), "alone", "not reachable from base link 'base'", "ee_link"),
])
def test_bad_urdf_raises(tmp_path, text, ee, pattern, element):
    path = _write(tmp_path, text)
    with pytest.raises(UrdfError, match=pattern) as info:
        load_urdf(path, "base", ee)
    assert info.value.file == path and info.value.element == element
    assert path in str(info.value)
    assert isinstance(info.value, H.ConfigError)


def test_base_below_end_effector_hint(tmp_path):
    with pytest.raises(UrdfError, match="swap them"):
        load_urdf(_write(tmp_path, _good()), "tool", "base")


def test_triangle_inequality_is_a_warning(tmp_path):
    """A lumped body whose principal moments violate I1 + I2 >= I3 (CAD exports do): loaded as
    written, as Pinocchio does, with a warning naming the joint and the links."""
    with pytest.warns(UrdfWarning, match='<joint name="j1">: the inertia tensor of the body moved by this joint '
                      r'\(links arm, tool\) is not physical .* by 96.0%'):
        chain = load_urdf(_write(tmp_path, _good(ixx="0.5")), "base", "tool")
    assert chain.n == 1


def test_links_off_the_chain_are_not_checked(tmp_path):
    """Inertias are checked for the chain that is extracted only: a link above the base, or hanging
    from the base, with a negative mass or an indefinite inertia does not stop the arm loading."""
    bad = ('<link name="antenna"><inertial><mass value="-1"/><inertia ixx="-1" ixy="0" ixz="0" iyy="0.1" iyz="0" '
           'izz="0.1"/></inertial></link><joint name="ja" type="fixed"><parent link="base"/><child link="antenna"/>'
           '</joint><link name="world"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="0" iyz="0" '
           'izz="0"/></inertial></link><joint name="jw" type="fixed"><parent link="world"/><child link="base"/></joint>')
    chain = load_urdf(_write(tmp_path, _good(extra=bad)), "base", "tool")
    assert chain.n == 1 and float(chain.mass[0]) == 1.0


def test_mimic_joint_on_the_chain_is_a_coordinate_with_a_warning(tmp_path):
    mimic = _good().replace('<axis xyz="0 0 1"/></joint>', '<axis xyz="0 0 1"/><mimic joint="jx"/></joint>')
    with pytest.warns(UrdfWarning, match="<mimic> joint on the chain .* independent coordinate"):
        chain = load_urdf(_write(tmp_path, mimic), "base", "tool")
    assert chain.n == 1
