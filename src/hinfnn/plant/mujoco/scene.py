"""MuJoCo models of hinfnn's true plants: the arm, the surface as a geom, the calibrated contact.

Three ways an arm becomes MJCF (docs/mujoco.md, "How an arm becomes a MuJoCo model"):

* :func:`two_link_xml` — the paper's two-link arm (point masses at the link tips, hinges about the
  world's y line, task space (x1, x2) = world (x, z));
* :func:`chain_xml` — any :class:`~hinfnn.model.urdf.UrdfChain` (URDF arms after ``mass_scale``,
  ``com_shift``, payload and locked joints; the planar arms of :func:`~hinfnn.model.urdf.planar_chain`):
  one body per moving joint with the chain's placement, axis, mass, centre of mass and full
  rotational inertia, the tool frame as a site, no geoms and no meshes;
* a user's MJCF file, read as it is (:func:`build_scene` with ``arm_file``).

:func:`build_scene` then adds what hinfnn needs to any of them, with :class:`mujoco.MjSpec`: a
site at the tool point (the user's site composed with a tool offset), a small sphere there
(``TIP_RADIUS``), the true surface as a geom placed ``TIP_RADIUS`` inside it (:func:`surface_geom`:
MuJoCo's sphere–surface distance is then exactly the tool point's signed distance), ONE contact
pair between them whose ``solref``/``solimp`` make the contact the requested spring-damper
(:func:`contact_solref`), MuJoCo's Coulomb friction (``condim`` 3, elliptic cone,
:func:`friction_solref`), and a contact sensor reading that pair.

:func:`chain_from_model` reads a compiled model back into a :class:`~hinfnn.model.urdf.UrdfChain`
(the rigid-body part: armature, damping and friction loss are not in it) and :func:`chain_urdf`
writes a chain as URDF text (how the nominal UR5e of the shipped Menagerie model was made).

Every function here needs ``mujoco`` (imported on first use, :func:`require_mujoco`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import threading

import numpy as np

from ...errors import ConfigError, is_real

#: Constant constraint impedance d of the contact (MuJoCo's smallest, mjMINIMP). With d → 0 the
#: soft constraint is a penalty spring-damper; what remains of MuJoCo's constraint behaviour is
#: an added normal mass of d / ((1 − d) W) ≈ 1e-4 / W kg (docs/mujoco.md, "Contact").
IMPEDANCE = 1e-4

#: Radius of gyration (m) of the tiny rotational inertia given to a point mass (MuJoCo needs a
#: positive inertia for a moving body): I = m r² ≈ 1e-10 kg·m² changes M(q) by < 1e-9 relative.
POINT_MASS_GYRATION_RADIUS = 1e-5

#: Radius (m) of the contact sphere at the tool point. The surface geom sits TIP_RADIUS inside the
#: true surface, so the sphere–surface distance equals the tool point's signed distance. MuJoCo's
#: friction acts where the sphere touches, TIP_RADIUS from the tool point: its slip velocity there
#: includes ω × (TIP_RADIUS n) and its moment about the tool point is TIP_RADIUS |F_t| (the built-in
#: plant's friction acts at the point itself); 1 mm keeps both small (docs/mujoco.md, "Friction").
TIP_RADIUS = 0.001

#: MuJoCo's ratio of frictional to normal constraint impedance (``impratio``) for the tool's
#: friction: the friction rows' added mass is IMPRATIO times the normal row's, and the normal force
#: a sliding tool gains from MuJoCo's soft cone is 1/IMPRATIO of what it would be at 1
#: (docs/mujoco.md, "Friction").
IMPRATIO = 100.0

#: Default slope (N·s/m) of MuJoCo's regularised Coulomb friction below the cone (the tangential
#: force is −c v_t up to μ f_n): μ f_n / v_s of the built-in plant's smoothed law at 20 N, μ = 0.15
#: and v_s = 3 mm/s.
FRICTION_DAMPING = 1000.0

#: Half-length (m) of the MuJoCo cylinder standing for hinfnn's infinite cylinder (and circle).
CYLINDER_HALF_LENGTH = 10.0

#: The surface kinds MuJoCo models (``plant.surface.kind``), and MuJoCo's primitive for each.
SUPPORTED_SURFACES = {"inclined_line": "plane", "plane": "plane", "sphere": "sphere", "cylinder": "cylinder",
                      "line": "plane (2-D: a line of the arm's plane)",
                      "circle": "cylinder (2-D: a disc of the arm's plane)"}

#: Names of what hinfnn adds to a model (prefixed so that a user's MJCF keeps its own names).
TOOL_SITE = "hinfnn_tool"
TIP_GEOM = "hinfnn_tip"
SURFACE_GEOM = "hinfnn_surface"
PAIR = "hinfnn_contact"
SENSOR = "hinfnn_contact"

#: Layout of the contact sensor's data: found, force (contact frame, on the tool), dist, normal
#: (world, from the surface to the tool), first tangent (world).
SENSOR_DATA = "found force dist normal tangent"
SENSOR_SIZE = 11

INTEGRATORS = ("Euler", "RK4", "implicit", "implicitfast")

_MISSING = ("plant.engine = \"mujoco\" needs the optional extra: pip install 'hinfnn[mujoco]'")


def require_mujoco():
    """Import and return the ``mujoco`` module, or raise :class:`ConfigError` (``plant.engine``)."""
    try:
        import mujoco
    except ImportError as err:
        raise ConfigError(_MISSING, key="plant.engine") from err
    return mujoco


def joint_armature(model, names) -> np.ndarray:
    """The armature MuJoCo's ``model`` gives each joint of ``names`` (its degree of freedom's
    ``dof_armature``: kg·m² for a hinge, kg for a slide; NaN for a name the model has no joint of)."""
    mujoco = require_mujoco()
    out = []
    for name in names:
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        out.append(float(model.dof_armature[model.jnt_dofadr[j]]) if j >= 0 else math.nan)
    return np.array(out)


# --------------------------------------------------------------------------------------------
# Calibration
# --------------------------------------------------------------------------------------------
def contact_solref(stiffness, damping, diag_approx, impedance: float = IMPEDANCE):
    """MuJoCo ``(solref, solimp)`` making a contact's normal row the spring-damper (k, c).

    MuJoCo's force on one active contact row is f = (a_ref − a0) / (A + R) with
    a_ref = −B v − K d r (r the distance, negative inside; v = ṙ), R = (1 − d)/d · W,
    W = ``efc_diagA`` (the approximate inverse mass from ``body_invweight0``, a constant of the
    compiled model), A = J M⁻¹ Jᵀ (the configuration's exact inverse effective mass) and a0 the
    unconstrained normal acceleration. With the direct form ``solref = (−k̃, −c̃)``
    (K = k̃/d², B = c̃/d) and a constant impedance d (``solimp = (d, d, ·, ·, ·)``):

        f = (k̃ p + c̃ ṗ − d a0) / (d A + (1 − d) W),          p = −r the penetration.

    Choosing k̃ = (1 − d) W k and c̃ = (1 − d) W c, the normal motion is exactly
    (m_eff + m_add) p̈ = P − k p − c ṗ (P the applied normal load, m_eff = 1/A) with an added mass
    m_add = d / ((1 − d) W): the requested spring-damper, at any configuration, up to that
    added mass (1e-4 / W kg for d = 1e-4). Implements docs/mujoco.md eq. (3).
    Returns ``((−k̃, −c̃), (d, d, 0.001, 0.5, 2))``.
    """
    d = float(impedance)
    scale = (1.0 - d) * float(diag_approx)
    solref = (-scale * float(stiffness), -scale * float(damping))
    solimp = (d, d, 0.001, 0.5, 2.0)
    return solref, solimp


def friction_solref(friction_damping, diag_approx, impedance: float = IMPEDANCE, impratio: float = IMPRATIO):
    """MuJoCo ``solreffriction`` giving the friction rows of an elliptic-cone contact the
    tangential damping c_t (N·s/m) below the cone.

    A friction row has K = 0, B = b̃/d (direct form ``solreffriction = (0, −b̃)``) and the
    regulariser R_t = R/impratio = (1 − d) W / (d · impratio). Its force below the cone is
    −(B v_t + a0_t)/(A_t + R_t): with b̃ = (1 − d) W c_t / impratio the tangential motion is
    (m_t + impratio · m_add) v̇_t = P_t − c_t v_t, saturated by MuJoCo at the cone μ f_n
    (docs/mujoco.md, "Friction", eq. (5)). Returns ``(0, −b̃)``.
    """
    d = float(impedance)
    return (0.0, -(1.0 - d) * float(diag_approx) * float(friction_damping) / float(impratio))


# --------------------------------------------------------------------------------------------
# MJCF text of hinfnn's own arms
# --------------------------------------------------------------------------------------------
def _num(x) -> str:
    """A float written so that MuJoCo parses back the same double."""
    return repr(float(x))


def _vec(v) -> str:
    return " ".join(_num(a) for a in np.asarray(v, dtype=float).ravel())


def _quat(R) -> np.ndarray:
    """(w, x, y, z) of a rotation matrix (MuJoCo's convention)."""
    mujoco = require_mujoco()
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(np.asarray(R, dtype=float)).ravel())
    return q


_HEADER = """  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>
  <option gravity="{gravity}"/>"""


def two_link_xml(arm) -> str:
    """MJCF of the paper's two-link arm (:class:`~hinfnn.TwoLinkArm`), arm only: task space
    (x1, x2) = world (x, z), gravity 0 0 −g, hinges about (0, −1, 0) so that a positive angle
    turns a link from +x towards +z (q1 from the x1 axis, q2 relative); a point mass m_i at the tip
    of link i with rotational inertia m_i (1e-5 m)² (MuJoCo needs it > 0); the site ``tool`` at the
    tip of link 2. No joint damping, armature, limits or friction loss."""
    m1, m2, l1, l2, g = (float(arm.m1), float(arm.m2), float(arm.l1), float(arm.l2), float(arm.g))
    r = POINT_MASS_GYRATION_RADIUS
    I1, I2 = m1 * r * r, m2 * r * r
    return f"""<mujoco model="hinfnn_two_link">
  <!-- Generated by hinfnn.plant.mujoco.two_link_xml: the TRUE two-link arm of a scenario. -->
{_HEADER.format(gravity=f"0 0 {_num(-g)}")}
  <worldbody>
    <body name="link1" pos="0 0 0">
      <joint name="q1" type="hinge" axis="0 -1 0" pos="0 0 0" limited="false" damping="0" armature="0"/>
      <inertial pos="{_num(l1)} 0 0" mass="{_num(m1)}" diaginertia="{_num(I1)} {_num(I1)} {_num(I1)}"/>
      <body name="link2" pos="{_num(l1)} 0 0">
        <joint name="q2" type="hinge" axis="0 -1 0" pos="0 0 0" limited="false" damping="0" armature="0"/>
        <inertial pos="{_num(l2)} 0 0" mass="{_num(m2)}" diaginertia="{_num(I2)} {_num(I2)} {_num(I2)}"/>
        <site name="tool" pos="{_num(l2)} 0 0" size="0.005"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _body_inertia(mass: float, inertia) -> np.ndarray:
    """The rotational inertia written for a body: the chain's, plus m r² I (r =
    POINT_MASS_GYRATION_RADIUS) when its smallest principal moment is below m r² (point masses:
    MuJoCo refuses a moving body without rotational inertia)."""
    inertia = np.asarray(inertia, dtype=float)
    floor = mass * POINT_MASS_GYRATION_RADIUS**2
    if np.linalg.eigvalsh(inertia)[0] < floor:
        inertia = inertia + floor * np.eye(3)
    return inertia


def chain_xml(chain, name: str = "hinfnn_chain") -> str:
    """MJCF of a :class:`~hinfnn.model.urdf.UrdfChain`, arm only (no geoms, no meshes).

    Body i (named after its URDF links) sits at ``placement_rot[i], placement_pos[i]`` in body
    i − 1 (the world is the chain's base), with a hinge (revolute) or slide (prismatic) joint named
    as in the URDF about ``axes[i]`` at its origin; its ``<inertial>`` is the chain's mass, centre
    of mass and full rotational inertia (``fullinertia``; MuJoCo diagonalises it). The site
    ``tool`` is the tool frame in the last body. Gravity is the chain's. Everything MuJoCo would
    add to the rigid-body dynamics is off: ``inertiafromgeom="false"``, no damping, friction loss,
    springs or limits (hinfnn keeps joint limits, it does not enforce them); each joint's
    ``armature`` is the chain's motor armature (:meth:`~hinfnn.model.urdf.UrdfChain.with_armature`;
    0 without one), so that MuJoCo's M(q) is the chain's.
    Point masses (zero rotational inertia) get m (1e-5 m)² (:func:`_body_inertia`)."""
    n = int(chain.n)
    lines = []
    armature = np.zeros(n) if getattr(chain, "armature", None) is None else np.asarray(chain.armature, dtype=float)
    for i in range(n):
        ind = "  " * (i + 2)
        R = np.asarray(chain.placement_rot[i])
        p = np.asarray(chain.placement_pos[i])
        m = float(chain.mass[i])
        I = _body_inertia(m, chain.inertia[i])
        kind = "slide" if chain.joint_types[i] == "prismatic" else "hinge"
        links = chain.body_links[i] if i < len(chain.body_links) else ()
        body_name = "+".join(links) if links else f"body{i + 1}"
        joint = chain.joint_names[i] if i < len(chain.joint_names) else f"joint{i + 1}"
        lines.append(f'{ind}<body name="{body_name}" pos="{_vec(p)}" quat="{_vec(_quat(R))}">')
        lines.append(f'{ind}  <joint name="{joint}" type="{kind}" axis="{_vec(chain.axes[i])}" pos="0 0 0" '
                     f'limited="false" damping="0" armature="{_num(armature[i]) if armature[i] else 0}" frictionloss="0" stiffness="0"/>')
        lines.append(f'{ind}  <inertial pos="{_vec(chain.com[i])}" mass="{_num(m)}" fullinertia="'
                     f'{_num(I[0, 0])} {_num(I[1, 1])} {_num(I[2, 2])} {_num(I[0, 1])} {_num(I[0, 2])} {_num(I[1, 2])}"/>')
    ind = "  " * (n + 2)
    lines.append(f'{ind}<site name="tool" pos="{_vec(chain.tool_pos)}" quat="{_vec(_quat(chain.tool_rot))}" '
                 'size="0.005"/>')
    for i in reversed(range(n)):
        lines.append("  " * (i + 2) + "</body>")
    body = "\n".join(lines)
    return f"""<mujoco model="{name}">
  <!-- Generated by hinfnn.plant.mujoco.chain_xml from hinfnn's parsed chain (the TRUE arm). -->
{_HEADER.format(gravity=_vec(chain.gravity))}
  <worldbody>
{body}
  </worldbody>
</mujoco>
"""


# --------------------------------------------------------------------------------------------
# Surfaces as geoms
# --------------------------------------------------------------------------------------------
def _embed(v2, rows) -> np.ndarray:
    """A 2-D vector of an arm's plane (coordinates along base axes ``rows``) in 3-D."""
    out = np.zeros(3)
    out[rows[0]], out[rows[1]] = float(v2[0]), float(v2[1])
    return out


def _quat_z_to(v) -> np.ndarray:
    """Quaternion turning the z axis onto the unit vector v (the geom's local z)."""
    mujoco = require_mujoco()
    q = np.zeros(4)
    mujoco.mju_quatZ2Vec(q, np.asarray(v, dtype=float) / np.linalg.norm(v))
    return q


def surface_kind(surface) -> str:
    """The scenario kind of a true surface object (for messages)."""
    names = {"InclinedLine": "inclined_line", "Plane": "plane", "Sphere": "sphere", "Cylinder": "cylinder",
             "Line": "line", "Circle": "circle", "SineProfile": "sine", "UserSurface": "python"}
    return names.get(type(surface).__name__, type(surface).__name__)


def unsupported_surface(kind: str) -> ConfigError:
    return ConfigError(f"MuJoCo has no primitive for a {kind!r} surface; the MuJoCo plant models "
                       f"{', '.join(repr(k) for k in SUPPORTED_SURFACES)} (use plant.engine = \"hinfnn\" for "
                       f"{kind!r})", key="plant.surface.kind")


def surface_geom(surface, rows=(0, 1)) -> dict:
    """MuJoCo geom attributes (type, size, pos, quat) for a true surface, placed ``TIP_RADIUS``
    inside it so that the distance MuJoCo computes between it and the tool's sphere is the tool
    point's signed distance to the true surface (minus when inside):

    * plane (and the paper's inclined line, and a 2-D line): a MuJoCo plane (local z the outward
      normal, material below), shifted TIP_RADIUS along the inward normal;
    * sphere: a sphere of radius R − TIP_RADIUS at the centre;
    * cylinder (and a 2-D circle, a cylinder along the plane's normal): a cylinder of radius
      R − TIP_RADIUS and half-length ``CYLINDER_HALF_LENGTH`` about the axis (MuJoCo's cylinder is
      finite; its ends are 10 m from the axis point, out of an arm's reach).

    ``rows``: for 2-D surfaces, the base axes of the arm's plane (e.g. (0, 2) for "xz"; the
    paper's two-link arm: (x1, x2) = (x, z)). Other kinds raise :class:`ConfigError`
    (``plant.surface.kind``). The distances are exact for plane–sphere, sphere–sphere and
    sphere–cylinder (MuJoCo's analytic collision functions; tested)."""
    import jax.numpy as jnp  # noqa: F401  (surfaces hold JAX arrays)

    kind = surface_kind(surface)
    r = TIP_RADIUS
    if kind == "inclined_line":
        s, c = math.sin(float(surface.delta)), math.cos(float(surface.delta))
        n_out = np.array([-s, 0.0, c])
        point = np.array([float(surface.d_G), 0.0, 0.0])
        return dict(type="plane", size=[0.0, 0.0, 0.05], pos=point - r * n_out, quat=_quat_z_to(n_out))
    if kind == "plane":
        n_out = np.asarray(surface.normal_out, dtype=float)
        return dict(type="plane", size=[0.0, 0.0, 0.05], pos=np.asarray(surface.point_, dtype=float) - r * n_out,
                    quat=_quat_z_to(n_out))
    if kind == "line":
        n_out = _embed(surface.normal_out, rows)
        return dict(type="plane", size=[0.0, 0.0, 0.05], pos=_embed(surface.point_, rows) - r * n_out,
                    quat=_quat_z_to(n_out))
    if kind in ("sphere", "cylinder", "circle"):
        R = float(surface.radius)
        if not R > 2.0 * r:
            raise ConfigError(f"radius {R:g} m is too small for the MuJoCo plant: the tool's contact sphere has radius "
                              f"{r:g} m and the surface geom sits that far inside the surface (allowed: > {2 * r:g} m)",
                              key="plant.surface.radius")
        if kind == "sphere":
            return dict(type="sphere", size=[R - r, 0.0, 0.0], pos=np.asarray(surface.centre, dtype=float),
                        quat=np.array([1.0, 0.0, 0.0, 0.0]))
        if kind == "cylinder":
            axis = np.asarray(surface.axis, dtype=float)
            return dict(type="cylinder", size=[R - r, CYLINDER_HALF_LENGTH, 0.0],
                        pos=np.asarray(surface.point_, dtype=float), quat=_quat_z_to(axis))
        normal = np.zeros(3)
        normal[3 - rows[0] - rows[1]] = 1.0
        return dict(type="cylinder", size=[R - r, CYLINDER_HALF_LENGTH, 0.0], pos=_embed(surface.centre, rows),
                    quat=_quat_z_to(normal))
    raise unsupported_surface(kind)


# --------------------------------------------------------------------------------------------
# The scene: arm + tool sphere + surface + calibrated pair + sensor
# --------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """A compiled MuJoCo model of a true plant and what hinfnn needs to read it.

    ``model``: the MjModel; ``xml``: its MJCF (MuJoCo's own writer); ``diag_approx``: W of the
    contact rows; ``n``: arm joints (= nq = nv); ``site``, ``site_body``, ``tip_geom``,
    ``surface_geom``, ``sensor_adr``: ids and the sensor's address in ``sensordata``;
    ``timestep``; ``source``: what it was built from (text)."""

    model: object
    xml: str
    diag_approx: float
    n: int
    site: int
    site_body: int
    tip_geom: int
    surface_geom: int
    sensor_adr: int
    timestep: float
    source: str

    def signature(self) -> tuple:
        """What two scenes must share to be stepped in one MuJoCo batch: every size of MjData,
        and the ids hinfnn reads."""
        m = self.model
        sizes = tuple((a, getattr(m, a)) for a in sorted(dir(m))
                      if a.startswith("n") and not a.startswith("names") and isinstance(getattr(m, a), int))
        return sizes + (("site", self.site), ("site_body", self.site_body), ("tip", self.tip_geom),
                        ("surface", self.surface_geom), ("sensor", self.sensor_adr), ("n", self.n))


def _check_number(key, v, *, positive=False):
    if not (np.ndim(v) == 0 and math.isfinite(float(v)) and (float(v) > 0 if positive else float(v) >= 0)):
        raise ConfigError(f"must be a finite number {'> 0' if positive else '>= 0'}, got {v!r}", key=key)


def _load_spec(mujoco, arm_xml: str | None, arm_file: str | None):
    if arm_file is None:
        return mujoco.MjSpec.from_string(arm_xml), "hinfnn"
    path = os.fspath(arm_file)
    if not os.path.isfile(path):
        raise ConfigError(f"no MJCF file {path}", key="plant.mjcf.file")
    try:
        if path.lower().endswith(".xml"):
            return mujoco.MjSpec.from_file(path), path
        # MuJoCo picks its reader by the extension: another one (a user's "arm.mjcf") is read as
        # text, its assets (meshes) still found beside it
        with open(path, encoding="utf-8") as f:
            spec = mujoco.MjSpec.from_string(f.read())
        spec.modelfiledir = os.path.dirname(os.path.abspath(path))
        return spec, path
    except Exception as err:  # MuJoCo's parser error: a ValueError with its message
        raise ConfigError(f"{path}: MuJoCo cannot read it: {err}", key="plant.mjcf.file") from None


def _compile_user(spec, source, key):
    try:
        return spec.compile()
    except Exception as err:  # MuJoCo's compiler error: a ValueError with its message
        raise ConfigError(f"{source}: MuJoCo cannot compile it: {err}", key=key) from None


def _hint(name, names) -> str:
    import difflib

    close = difflib.get_close_matches(name, names, n=2, cutoff=0.5)
    if close:
        return "; did you mean " + " or ".join(repr(c) for c in close) + "?"
    return f"; the file has: {', '.join(repr(x) for x in names[:30])}" if names else "; the file has none"


def _check_user_model(mujoco, model, joints, site_name, source):
    """The user's MJCF: the named joints exist, are hinges or slides without ``ref``, are ALL the
    model's degrees of freedom, listed from the base to the tool, and each moves the tool site."""
    names = [model.joint(j).name for j in range(model.njnt)]
    if not joints:
        raise ConfigError(f"{source}: name the arm's joints, from the base to the tool (the file has "
                          f"{', '.join(repr(x) for x in names)})", key="plant.mjcf.joints")
    ids = []
    for j in joints:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)
        if jid < 0:
            raise ConfigError(f"{source}: no joint named {j!r}{_hint(j, names)}", key="plant.mjcf.joints")
        if int(model.jnt_type[jid]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise ConfigError(f"{source}: joint {j!r} is not a hinge or a slide (allowed: hinge, slide)",
                              key="plant.mjcf.joints")
        if model.qpos0[model.jnt_qposadr[jid]] != 0.0:
            raise ConfigError(f"{source}: joint {j!r} has ref = {model.qpos0[model.jnt_qposadr[jid]]:g} (allowed: 0, "
                              "hinfnn's joint angles are measured from the model's pose)", key="plant.mjcf.joints")
        ids.append(jid)
    if len(set(ids)) != len(ids):
        raise ConfigError(f"lists a joint twice: {list(joints)}", key="plant.mjcf.joints")
    if model.nv != len(ids) or model.nq != len(ids):
        others = [x for x in names if x not in joints]
        raise ConfigError(f"{source}: the model has {model.nv} degrees of freedom but {len(ids)} joints are listed; "
                          f"hinfnn drives every degree of freedom of the model (list, or lock with "
                          f"plant.mjcf.locked_joints: {', '.join(repr(x) for x in others) or 'free/ball joints'})",
                          key="plant.mjcf.joints")
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site_name)
    sites = [model.site(s).name for s in range(model.nsite)]
    if sid < 0:
        raise ConfigError(f"{source}: no site named {site_name!r}{_hint(site_name, sites)}",
                          key="plant.mjcf.tool_site")
    # serial chain: joint k's body is an ancestor of joint k+1's body and of the site's body
    chain = []
    b = int(model.site_bodyid[sid])
    while b > 0:
        chain.append(b)
        b = int(model.body_parentid[b])
    chain.reverse()
    order = [chain.index(int(model.jnt_bodyid[j])) if int(model.jnt_bodyid[j]) in chain else -1 for j in ids]
    for j, o in zip(joints, order):
        if o < 0:
            raise ConfigError(f"{source}: joint {j!r} does not move the tool site {site_name!r} (not on the path from "
                              "the world to the site's body)", key="plant.mjcf.joints")
    if order != sorted(order) or [model.jnt_qposadr[j] for j in ids] != list(range(len(ids))):
        raise ConfigError(f"{source}: list the joints from the base to the tool, in the model's order "
                          f"({', '.join(repr(names[j]) for j in sorted(ids))})", key="plant.mjcf.joints")


def build_scene(surface, contact, *, rows=(0, 1), arm_xml: str | None = None, arm_file: str | None = None,
                joints=(), tool_site: str = "tool", tool_xyz=(0.0, 0.0, 0.0), tool_rot=None,
                friction: float = 0.0, friction_damping: float = FRICTION_DAMPING, timestep: float = 1e-4,
                integrator: str = "RK4", locked=(), mass_scale=1.0, payload_mass: float = 0.0,
                payload_xyz=(0.0, 0.0, 0.0)) -> Scene:
    """The compiled MuJoCo model of a true plant (module docstring).

    ``arm_xml`` (hinfnn's own arm: :func:`chain_xml`, :func:`two_link_xml`) or ``arm_file`` (a
    user's MJCF, with ``joints`` the arm's joint names from the base to the tool and ``tool_site``
    the site the tool hangs from); the tool point is ``tool_site`` moved by ``tool_xyz`` (and
    turned by ``tool_rot``) in the site's frame. ``surface``: the true surface (model object),
    ``rows``: base axes of a planar arm's plane; ``contact``: k (N/m), c (N·s/m);
    ``friction``: Coulomb μ (0: frictionless, ``condim`` 1); ``friction_damping``: MuJoCo's
    tangential damping below the cone (N·s/m); ``timestep``, ``integrator``: MuJoCo's.

    A user's MJCF is adapted with MuJoCo's model editing (``MjSpec``) before it is compiled with the
    surface: ``locked`` ((joint name, position) pairs) removes those joints, each body welded at
    the position (:func:`_lock_joints`); ``mass_scale`` (one number, or one per listed joint)
    scales the mass and rotational inertia of each arm body (:func:`_scale_masses`);
    ``payload_mass`` (kg) adds a point mass at ``payload_xyz`` in the tool frame, welded to the
    tool site's body (the true arm's ``plant.arm.mass_scale``, ``payload_mass``, ``payload_xyz``,
    as the built-in arm's :meth:`~hinfnn.model.urdf.UrdfChain.perturbed` applies them).

    Options set on every model: ``solver = Newton``, ``tolerance = 1e-12`` (a contact solved to
    round-off, in one or two iterations), ``cone = elliptic``, ``impratio = IMPRATIO``, autoreset
    off (a NaN must poison the state, not restart the arm), warm start on. A user's model keeps its
    gravity, joint armature, damping, friction loss, springs and limits (the truth the nominal URDF
    cannot express); its actuators are switched off (``actuation`` flag: hinfnn's torque is applied
    as ``qfrc_applied``). Raises :class:`ConfigError` naming the scenario key.
    """
    mujoco = require_mujoco()
    if integrator not in INTEGRATORS:
        raise ConfigError(f"must be one of {INTEGRATORS}, got {integrator!r}", key="plant.integrator")
    if not (is_real(timestep) and math.isfinite(timestep) and timestep > 0):
        raise ConfigError(f"must be a number > 0 (s), got {timestep!r}", key="plant.timestep")
    _check_number("plant.contact.stiffness", contact.stiffness)
    _check_number("plant.contact.damping", contact.damping)
    _check_number("plant.friction.coulomb", friction)
    _check_number("plant.friction_damping", friction_damping)
    geom = surface_geom(surface, rows)
    user = arm_file is not None
    spec, source = _load_spec(mujoco, arm_xml, arm_file)
    if user:  # check the names on a compiled copy of the user's model as it is (its locked joints removed)
        plain = _compile_user(spec.copy(), source, "plant.mjcf.file")
        if locked:
            _lock_joints(mujoco, spec, plain, tuple(locked), source)
            plain = _compile_user(spec.copy(), source, "plant.mjcf.locked_joints")
        _check_user_model(mujoco, plain, list(joints), tool_site, source)
        scale = np.asarray(mass_scale, dtype=float).reshape(-1)
        if scale.size not in (1, len(joints)):
            raise ConfigError(f"must be a number or a list of {len(joints)} (one per joint of plant.mjcf.joints), got "
                              f"{scale.size}: {scale.tolist()}", key="plant.arm.mass_scale")
        if np.any(scale != 1.0):
            _scale_masses(mujoco, spec, _compile_user(spec, source, "plant.mjcf.file"), list(joints),
                          np.broadcast_to(scale, (len(joints),)))
    elif locked or payload_mass or np.any(np.asarray(mass_scale) != 1.0):  # pragma: no cover - the chain has them
        raise ValueError("locked, mass_scale and payload apply to a user's MJCF; hinfnn's arms carry them in the chain")
    site = spec.site(tool_site)
    if site is None:
        raise ConfigError(f"{source}: no site named {tool_site!r}", key="plant.mjcf.tool_site")
    body = site.parent
    # the tool point: the site's pose composed with the offset, in the site's body
    R_site = np.zeros(9)
    q_site = np.asarray(site.quat, dtype=float)
    mujoco.mju_quat2Mat(R_site, q_site / np.linalg.norm(q_site))
    R_site = R_site.reshape(3, 3)
    R_off = np.eye(3) if tool_rot is None else np.asarray(tool_rot, dtype=float)
    pos = np.asarray(site.pos, dtype=float) + R_site @ np.asarray(tool_xyz, dtype=float)
    tool = body.add_site(name=TOOL_SITE, pos=pos, quat=_quat(R_site @ R_off), size=[0.005, 0.0, 0.0])
    del tool
    if payload_mass:
        _check_number("plant.arm.payload_mass", payload_mass)
        m = float(payload_mass)
        r2 = m * POINT_MASS_GYRATION_RADIUS**2
        load = body.add_body(name="hinfnn_payload")
        load.pos = pos + R_site @ R_off @ np.asarray(payload_xyz, dtype=float)
        load.explicitinertial, load.mass, load.inertia, load.ipos = True, m, [r2, r2, r2], [0.0, 0.0, 0.0]
    body.add_geom(name=TIP_GEOM, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[TIP_RADIUS, 0.0, 0.0], pos=pos,
                  contype=0, conaffinity=0, density=0.0, mass=0.0, group=3, rgba=[0.8, 0.2, 0.2, 1.0])
    gtype = {"plane": mujoco.mjtGeom.mjGEOM_PLANE, "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
             "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER}[geom["type"]]
    spec.worldbody.add_geom(name=SURFACE_GEOM, type=gtype, size=geom["size"], pos=geom["pos"], quat=geom["quat"],
                            contype=0, conaffinity=0, density=0.0, mass=0.0, rgba=[0.6, 0.6, 0.6, 0.5])
    mu = float(friction)
    pair = spec.add_pair(name=PAIR, geomname1=SURFACE_GEOM, geomname2=TIP_GEOM, condim=3 if mu > 0 else 1,
                         friction=[mu, mu, 0.005, 0.0001, 0.0001], margin=0.0, gap=0.0)
    sensor = spec.add_sensor(name=SENSOR, type=mujoco.mjtSensor.mjSENS_CONTACT)
    sensor.objtype, sensor.objname = mujoco.mjtObj.mjOBJ_GEOM, SURFACE_GEOM
    sensor.reftype, sensor.refname = mujoco.mjtObj.mjOBJ_GEOM, TIP_GEOM
    con = mujoco.mjtConDataField if hasattr(mujoco, "mjtConDataField") else None
    bits = [0, 1, 3, 5, 6] if con is None else [int(con.mjCONDATA_FOUND), int(con.mjCONDATA_FORCE),
                                                int(con.mjCONDATA_DIST), int(con.mjCONDATA_NORMAL),
                                                int(con.mjCONDATA_TANGENT)]
    sensor.intprm = [sum(1 << b for b in bits), 0, 1]  # data, reduce = none, num = 1
    opt = spec.option
    opt.timestep = float(timestep)
    opt.integrator = {"Euler": mujoco.mjtIntegrator.mjINT_EULER, "RK4": mujoco.mjtIntegrator.mjINT_RK4,
                      "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
                      "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST}[integrator]
    opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    opt.iterations = 100
    opt.ls_iterations = 50
    opt.tolerance = 1e-12
    opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    opt.impratio = IMPRATIO
    dsbl = mujoco.mjtDisableBit
    opt.disableflags = int(opt.disableflags) | int(dsbl.mjDSBL_AUTORESET)
    opt.disableflags = int(opt.disableflags) & ~int(dsbl.mjDSBL_WARMSTART) & ~int(dsbl.mjDSBL_CONTACT) \
        & ~int(dsbl.mjDSBL_CONSTRAINT)
    if user:
        opt.disableflags = int(opt.disableflags) | int(dsbl.mjDSBL_ACTUATION)
    else:
        opt.disableflags = int(opt.disableflags) | int(dsbl.mjDSBL_FRICTIONLOSS)
    try:
        model = spec.compile()
    except Exception as err:
        raise ConfigError(f"{source}: MuJoCo cannot compile the scene: {err}", key="plant.mjcf.file"
                          if user else "plant.arm") from None
    tip = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, TIP_GEOM)
    # W: efc_diagA of the contact rows = body_invweight0 (translation) of the tool's body (the
    # surface's body, the world, has 0); a constant of the compiled model, independent of solref
    W = float(model.body_invweight0[model.geom_bodyid[tip], 0] + model.body_invweight0[0, 0])
    solref, solimp = contact_solref(contact.stiffness, contact.damping, W)
    fref = friction_solref(friction_damping, W)
    pair.solref, pair.solimp, pair.solreffriction = list(solref), list(solimp), list(fref)
    pid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_PAIR, PAIR)
    model.pair_solref[pid], model.pair_solimp[pid], model.pair_solreffriction[pid] = solref, solimp, fref
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, TOOL_SITE)
    sens = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, SENSOR)
    n = int(model.nv)
    if not user and (model.nq != n):  # pragma: no cover - hinfnn's arms have hinges and slides only
        raise ConfigError("the generated model has joints other than hinges and slides", key="plant.arm")
    return Scene(model=model, xml=_to_xml(mujoco, spec), diag_approx=W, n=n, site=sid, site_body=int(model.site_bodyid[sid]),
                 tip_geom=tip, surface_geom=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, SURFACE_GEOM),
                 sensor_adr=int(model.sensor_adr[sens]), timestep=float(timestep), source=source)


_XML_LOCK = threading.Lock()


def _to_xml(mujoco, spec) -> str:
    """MuJoCo's MJCF of a spec, with 17 significant digits (every double round-trips) through the
    writer's precision setting ``_mjPRIVATE__set_xml_precision`` of libmujoco (a private symbol;
    without it, MuJoCo's default 6 digits)."""
    import ctypes

    try:
        lib = ctypes.CDLL(os.path.join(os.path.dirname(mujoco.__file__), f"libmujoco.so.{mujoco.__version__}"))
        setp, getp = lib._mjPRIVATE__set_xml_precision, lib._mjPRIVATE__get_xml_precision
    except (OSError, AttributeError):  # pragma: no cover - another build of MuJoCo
        return spec.to_xml()
    with _XML_LOCK:
        old = getp()
        setp(17)
        try:
            return spec.to_xml()
        finally:
            setp(old)


def mjcf_two_link(arm, surface, contact, *, timestep: float, integrator: str = "RK4") -> str:
    """MJCF XML of the TRUE two-link arm and inclined surface with a calibrated frictionless
    contact (:func:`two_link_xml` + :func:`build_scene`). Needs ``mujoco``."""
    _check_two_link(arm, surface)
    return build_scene(surface, contact, rows=(0, 2), arm_xml=two_link_xml(arm), timestep=timestep,
                       integrator=integrator).xml


def _check_two_link(arm, surface):
    from ...model.surface import InclinedLine

    for key, v in (("plant.arm.m1", arm.m1), ("plant.arm.m2", arm.m2), ("plant.arm.l1", arm.l1),
                   ("plant.arm.l2", arm.l2)):
        if not np.ndim(v) == 0 or not float(v) > 0.0:
            raise ConfigError(f"must be a number > 0, got {v!r}", key=key)
    if not isinstance(surface, InclinedLine):
        raise ConfigError(f"the two_link arm's MuJoCo model has the inclined line only (its task space is the tip "
                          f"position), got a {surface_kind(surface)!r}", key="plant.surface.kind")


# --------------------------------------------------------------------------------------------
# Back to hinfnn: a compiled model as a chain, a chain as URDF
# --------------------------------------------------------------------------------------------
def _owners(model, jids):
    """owner(body id) -> the index (into ``jids``) of the nearest listed joint at or above the
    body, -1 for a body above the first one (the base): the arm's body i is every MuJoCo body
    whose owner is i."""
    jbody = {int(model.jnt_bodyid[j]): i for i, j in enumerate(jids)}

    def owner(b):
        while b > 0:
            if b in jbody:
                return jbody[b]
            b = int(model.body_parentid[b])
        return -1

    return owner


def _lock_joints(mujoco, spec, model, locked, source):
    """A user's MJCF with the joints ``locked`` ((name, position) pairs) removed: each joint's body
    is turned (hinge) or moved (slide) to the position (rad or m, MuJoCo's joint value: ``ref`` is
    the body as written) about the joint's axis through its anchor and welded to its parent
    there; actuators and sensors on the joint and the file's keyframes go with it. ``model``: the
    file compiled as it is (the body's pose in its parent, the joint's axis and anchor)."""
    key = "plant.mjcf.locked_joints"
    names = [model.joint(j).name for j in range(model.njnt)]
    for name, value in locked:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            raise ConfigError(f"{source}: no joint named {name!r}{_hint(name, names)}", key=key)
        jtype = int(model.jnt_type[jid])
        if jtype not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise ConfigError(f"{source}: joint {name!r} is not a hinge or a slide (allowed: hinge, slide)", key=key)
        b = int(model.jnt_bodyid[jid])
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, model.body_quat[b])
        R = R.reshape(3, 3)
        axis = model.jnt_axis[jid] / np.linalg.norm(model.jnt_axis[jid])
        delta = float(value) - float(model.qpos0[model.jnt_qposadr[jid]])
        anchor = np.asarray(model.jnt_pos[jid], dtype=float)
        if jtype == int(mujoco.mjtJoint.mjJNT_SLIDE):
            turn, shift = np.eye(3), axis * delta
        else:  # Rodrigues: the body turned by delta about the axis through the anchor
            K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
            turn = np.eye(3) + math.sin(delta) * K + (1.0 - math.cos(delta)) * (K @ K)
            shift = anchor - turn @ anchor
        body = spec.joint(name).parent
        body.pos = model.body_pos[b] + R @ shift
        body.quat = _quat(R @ turn)
        body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
        for el in list(spec.actuators) + list(spec.sensors):
            if getattr(el, "target", getattr(el, "objname", None)) == name or getattr(el, "objname", None) == name:
                spec.delete(el)
        spec.delete(spec.joint(name))
    if locked:
        for k in list(spec.keys):
            spec.delete(k)


def _scale_masses(mujoco, spec, model, joints, mass_scale):
    """Each arm body's mass and rotational inertia times its joint's ``mass_scale`` entry (the
    MuJoCo bodies of arm body i, as :func:`chain_from_model` lumps them): every body's inertial
    written explicitly from the compiled ``model`` (so inferred ones keep their values), scaled."""
    jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in joints]
    owner = _owners(model, jids)
    by_id = {int(b.id): b for b in spec.bodies}
    for b in range(1, model.nbody):
        sb = by_id.get(b)
        if sb is None:
            continue
        i = owner(b)
        k = float(mass_scale[i]) if i >= 0 else 1.0
        sb.explicitinertial = True
        sb.mass = float(model.body_mass[b]) * k
        sb.inertia = np.asarray(model.body_inertia[b], dtype=float) * k
        sb.fullinertia = [np.nan] + [0.0] * 5
        sb.ipos = model.body_ipos[b]
        sb.iquat = model.body_iquat[b]
        sb.ialt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE


def _effort_limits(mujoco, model, jids, given):
    """Each listed joint's torque (or force) limit as the file states it: the joint's own
    ``actuatorfrcrange`` and the actuators on it (each force range times its gear, summed over the
    joint's actuators when every one of them has a force range), the smaller where both are
    given; a joint with neither takes ``given``'s entry (infinite without it)."""
    n = len(jids)
    effort = np.full(n, np.inf) if given is None else np.array(given, dtype=float).reshape(n)
    for i, j in enumerate(jids):
        acts = [a for a in range(model.nu) if int(model.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
                and int(model.actuator_trnid[a, 0]) == j]
        stated = []
        if acts and all(model.actuator_forcelimited[a] for a in acts):
            stated.append(sum(abs(float(model.actuator_gear[a, 0]))
                              * float(np.max(np.abs(model.actuator_forcerange[a]))) for a in acts))
        if model.jnt_actfrclimited[j]:
            stated.append(float(np.max(np.abs(model.jnt_actfrcrange[j]))))
        if stated:
            effort[i] = min(stated)
    return effort


def chain_from_model(model, joints, site: str | int, effort_limit=None):
    """The :class:`~hinfnn.model.urdf.UrdfChain` of a compiled MuJoCo arm: its rigid-body part.

    ``joints``: the arm's joint names from the base to the tool (hinges and slides, the model's
    only degrees of freedom, ``ref`` 0); ``site``: the tool site (name or id). Read at the
    model's reference pose (q = 0): joint i's frame is its body's frame moved to the joint's
    anchor; body i is every MuJoCo body whose nearest listed joint above it (itself included) is
    joint i, lumped (parallel-axis theorem) in that frame; bodies above the first joint are the
    base. Not in the chain: armature, damping, friction loss, springs, limits' forces, actuators
    (what the nominal of a user's MJCF does not know); its effort limits are the joints'
    ``actuatorfrcrange`` and the force ranges of the actuators on them times their gear, where a
    joint has neither ``effort_limit``'s entry (e.g. the nominal URDF's; infinite without it)."""
    import jax.numpy as jnp

    from ...model.urdf import UrdfChain

    mujoco = require_mujoco()
    d = mujoco.MjData(model)
    d.qpos[:] = model.qpos0
    mujoco.mj_kinematics(model, d)
    jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in joints]
    sid = site if isinstance(site, (int, np.integer)) else mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site)
    frames = []
    for j in jids:
        b = int(model.jnt_bodyid[j])
        frames.append((d.xmat[b].reshape(3, 3).copy(), d.xanchor[j].copy()))
    owner = _owners(model, jids)
    n = len(jids)
    parts = [[] for _ in range(n)]
    for b in range(1, model.nbody):
        i = owner(b)
        if i >= 0 and model.body_mass[b] > 0:
            R = d.ximat[b].reshape(3, 3)
            parts[i].append((float(model.body_mass[b]), d.xipos[b].copy(), R @ np.diag(model.body_inertia[b]) @ R.T))
    place_R, place_p, mass, com, inertia = [], [], [], [], []
    prev = (np.eye(3), np.zeros(3))
    for i in range(n):
        R, p = frames[i]
        place_R.append(prev[0].T @ R)
        place_p.append(prev[0].T @ (p - prev[1]))
        m = sum(x[0] for x in parts[i])
        c = sum(x[0] * x[1] for x in parts[i]) / m
        I = np.zeros((3, 3))
        for mi, ci, Ii in parts[i]:
            dv = ci - c
            I += Ii + mi * (dv @ dv * np.eye(3) - np.outer(dv, dv))
        mass.append(m)
        com.append(R.T @ (c - p))
        inertia.append(R.T @ I @ R)
        prev = (R, p)
    Rs = d.site_xmat[sid].reshape(3, 3)
    R_n, p_n = frames[-1]
    lower = [model.jnt_range[j, 0] if model.jnt_limited[j] else -np.inf for j in jids]
    upper = [model.jnt_range[j, 1] if model.jnt_limited[j] else np.inf for j in jids]
    names = [[model.body(b).name for b in range(1, model.nbody) if owner(b) == i] for i in range(n)]
    effort = _effort_limits(mujoco, model, jids, effort_limit)
    f = lambda x: jnp.asarray(np.asarray(x, dtype=float))  # noqa: E731
    return UrdfChain(
        placement_rot=f(place_R), placement_pos=f(place_p),
        axes=f([model.jnt_axis[j] / np.linalg.norm(model.jnt_axis[j]) for j in jids]), mass=f(mass), com=f(com),
        inertia=f(inertia), tool_rot=f(R_n.T @ Rs), tool_pos=f(R_n.T @ (d.site_xpos[sid] - p_n)),
        gravity=f(model.opt.gravity), lower=f(lower), upper=f(upper), effort_limit=f(effort),
        velocity_limit=f(np.full(n, np.inf)), n=n,
        joint_types=tuple("prismatic" if int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_SLIDE) else "revolute"
                          for j in jids),
        joint_names=tuple(joints), body_links=tuple(tuple(x) for x in names))


def _rpy(R) -> np.ndarray:
    """URDF roll-pitch-yaw of R = Rz(yaw) Ry(pitch) Rx(roll) (the inverse of
    :func:`hinfnn.model.urdf.rpy_matrix` away from pitch = ±90°)."""
    R = np.asarray(R, dtype=float)
    pitch = math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0]))
    return np.array([math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])])


def chain_urdf(chain, name: str, base_link: str = "base_link", tool_link: str = "tool0", links=None) -> str:
    """URDF text of a chain: ``base_link`` → one link per moving joint (named ``links[i]`` or
    link1 …) → the fixed ``tool_link`` at the tool frame. Joint origins and inertials are written
    with Python's shortest round-trip floats, so :func:`~hinfnn.model.urdf.load_urdf` reads back
    the same chain to round-off (tested). Infinite effort or velocity limits are written 1e9."""
    n = int(chain.n)
    links = list(links) if links is not None else [f"link{i + 1}" for i in range(n)]
    out = [f'<?xml version="1.0"?>', f'<robot name="{name}">', f'  <link name="{base_link}"/>']
    parent = base_link
    for i in range(n):
        I = np.asarray(chain.inertia[i], dtype=float)
        kind = "prismatic" if chain.joint_types[i] == "prismatic" else "revolute"
        lo, hi = float(chain.lower[i]), float(chain.upper[i])
        if not (math.isfinite(lo) and math.isfinite(hi)):
            kind = "continuous" if kind == "revolute" else kind
        out += [f'  <link name="{links[i]}">', "    <inertial>",
                f'      <origin xyz="{_vec(chain.com[i])}" rpy="0 0 0"/>', f'      <mass value="{_num(chain.mass[i])}"/>',
                f'      <inertia ixx="{_num(I[0, 0])}" ixy="{_num(I[0, 1])}" ixz="{_num(I[0, 2])}" iyy="{_num(I[1, 1])}" '
                f'iyz="{_num(I[1, 2])}" izz="{_num(I[2, 2])}"/>', "    </inertial>", "  </link>",
                f'  <joint name="{chain.joint_names[i]}" type="{kind}">', f'    <parent link="{parent}"/>',
                f'    <child link="{links[i]}"/>',
                f'    <origin xyz="{_vec(chain.placement_pos[i])}" rpy="{_vec(_rpy(chain.placement_rot[i]))}"/>',
                f'    <axis xyz="{_vec(chain.axes[i])}"/>']
        if kind != "continuous":
            eff, vel = float(chain.effort_limit[i]), float(chain.velocity_limit[i])
            eff, vel = (_num(v) if math.isfinite(v) else "1e9" for v in (eff, vel))
            out.append(f'    <limit lower="{_num(lo)}" upper="{_num(hi)}" effort="{eff}" velocity="{vel}"/>')
        out.append("  </joint>")
        parent = links[i]
    out += [f'  <link name="{tool_link}"/>', f'  <joint name="{tool_link}_fixed_joint" type="fixed">',
            f'    <parent link="{parent}"/>', f'    <child link="{tool_link}"/>',
            f'    <origin xyz="{_vec(chain.tool_pos)}" rpy="{_vec(_rpy(chain.tool_rot))}"/>', "  </joint>", "</robot>", ""]
    return "\n".join(out)
