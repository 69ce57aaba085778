"""Arms from URDF files: a serial chain with rigid-body dynamics in pure JAX (float64).

:func:`load_urdf` parses a URDF with the standard library and extracts the serial chain from
a base link to an end-effector link into a :class:`UrdfChain`:

* revolute, continuous and prismatic joints on the path move; fixed joints on it are merged
  into the moving body they hang from (frames composed into the next joint's placement,
  inertias lumped by the parallel-axis theorem);
* everything else hanging from a moving body (side branches, links below the end-effector) is
  merged rigidly into it, its joints *locked at zero*, whatever their type: their mass counts
  for gravity and inertia;
* links above the base and the base's own rigid subtree do not move and are ignored;
* continuous joints are revolute joints without limits (one coordinate q, not Pinocchio's
  (cos q, sin q)); joint limits are kept, not enforced; <dynamics> (damping, friction) is
  ignored; floating and planar joints on the chain are errors; a <mimic> joint on the chain is
  an independent coordinate (as in Pinocchio's default), with a :class:`UrdfWarning`.

Inertias follow URDF: <inertial>/<origin> places the centre of mass and the axes of the
<inertia> tensor (about the centre of mass); a link without <inertial> is massless. Only the
chain that is extracted is checked, after merging (as Pinocchio, which loads a file whatever
the inertias of the links a chain does not use: an antenna on a mobile base, a gripper's
fingers): every moving body must have mass > 0, no link in it a negative mass, and its lumped
rotational inertia (zero allowed: point masses) must be positive semidefinite; it should be
physical (triangle inequality; a violation, frequent in CAD exports, is a :class:`UrdfWarning`: the
dynamics stay well defined, M(q) positive definite). A xacro file, an MJCF or SDF file and a
folder are refused, each with what to do instead.

:class:`UrdfChain` computes, with 6-D spatial algebra in the base frame (Featherstone,
*Rigid Body Dynamics Algorithms*, ch. 2–6; motion vectors (linear, angular) at the base origin,
as in Pinocchio): the tool frame (:meth:`~UrdfChain.fk`), its geometric Jacobian and that
Jacobian's time derivative, M(q) by the composite-rigid-body algorithm, C(q, q̇)q̇ + G(q) by
recursive Newton–Euler, the Christoffel-symbol Coriolis matrix and its product with a vector.
Every function works under ``jit``, ``vmap`` and ``grad``; the loop over joints is a Python
loop over the (static) chain.

:class:`UrdfArm` is an :class:`~hinfnn.model.arm.Arm` made of a chain and a task map
(:mod:`hinfnn.model.taskmap`): ``h(q) = task(*chain.fk(q))``.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib.resources
import math
import os
import warnings
import xml.etree.ElementTree as ET
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import _linalg as la
from .._pytree import pytree_dataclass, replace, static_field
from ..errors import ConfigError
from . import rbd
from .arm import Arm, ArmTerms

MOVING_TYPES = ("revolute", "continuous", "prismatic")


def _is_xacro(el) -> bool:
    """An element of the xacro namespace (``<xacro:macro>``, any of its URLs) or an attribute with
    a xacro property or substitution (``${...}``, ``$(find ...)``)."""
    tag = el.tag if isinstance(el.tag, str) else ""
    if tag.startswith("{") and "xacro" in tag[1:tag.find("}")]:
        return True
    return any("${" in v or "$(" in v for v in el.attrib.values())
JOINT_TYPES = MOVING_TYPES + ("fixed", "floating", "planar")


class UrdfError(ConfigError):
    """A URDF file cannot be turned into a serial chain. ``file`` and ``element`` (e.g.
    ``<joint name="elbow">``) say where; the message says what is wrong and what is allowed."""

    def __init__(self, problem: str, file: str | None = None, element: str | None = None):
        self.file = file
        self.element = element
        self.problem = problem
        key = ", ".join(s for s in (file, element) if s) or None
        super().__init__(problem, key=key)


class UrdfWarning(UserWarning):
    """Something in a URDF that hinfnn loads but a user should know: a lumped body whose inertia
    violates the triangle inequality (not realisable by a mass distribution, though the dynamics
    stay well defined), a <mimic> joint on the chain taken as an independent coordinate."""


def asset_path(*parts: str) -> str:
    """Path of a robot file shipped with hinfnn, e.g. ``asset_path("ur5", "ur5.urdf")``."""
    return str(importlib.resources.files("hinfnn").joinpath("assets", *parts))


def shipped_robots(suffix: str = ".urdf") -> dict[str, str]:
    """The robots shipped with hinfnn by name (``"ur5"``, ``"panda"``, ``"planar/three_link"``):
    ``assets/NAME/NAME.urdf`` is ``NAME``, any other ``assets/DIR/FILE.urdf`` is ``DIR/FILE``.
    ``suffix`` ``".xml"``: the shipped MJCF models (``"ur5e"``: MuJoCo Menagerie's UR5e)."""
    root = importlib.resources.files("hinfnn").joinpath("assets")
    out = {}
    for folder in sorted((d for d in root.iterdir() if d.is_dir()), key=lambda d: d.name):
        for f in sorted((f for f in folder.iterdir() if f.name.endswith(suffix)), key=lambda f: f.name):
            stem = f.name[:-len(suffix)]
            out[folder.name if stem == folder.name else f"{folder.name}/{stem}"] = str(f)
    return out


def robot_file(value: str, suffix: str = ".urdf") -> str:
    """The URDF a ``file`` value names: a file when a file of that name exists (any extension:
    ``.urdf``, ``.xml``, none), else a shipped robot (:func:`shipped_robots`). A folder, a xacro
    file (``.xacro``) and a name that is neither raise :class:`UrdfError` saying what is allowed.
    ``suffix`` ``".xml"``: the same for an MJCF (a file of that name, else a shipped MJCF model)."""
    value = os.fspath(value)
    what = "URDF" if suffix == ".urdf" else "MJCF"
    if suffix == ".urdf" and value.endswith(".xacro"):
        raise UrdfError("is a xacro file: expand it with xacro first (`xacro FILE.urdf.xacro > robot.urdf`, in a "
                        "ROS environment) and give the .urdf it writes", value)
    if os.path.isdir(value):
        raise UrdfError(f"is a folder, not a {what} file; give the path of the {suffix} file in it"
                        + (_urdf_in_folder(value) if suffix == ".urdf" else ""), value)
    if os.path.isfile(value):
        return value
    shipped = shipped_robots(suffix)
    if value in shipped:
        return shipped[value]
    looks_like_path = os.sep in value or "/" in value or os.path.splitext(value)[1] != ""
    names = ", ".join(repr(k) for k in shipped)
    article, kind = ("a", "robot") if suffix == ".urdf" else ("an", "model")
    close = difflib.get_close_matches(value, list(shipped), n=1, cutoff=0.6)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    if looks_like_path:
        raise UrdfError(f"no such file; give the path of {article} {what} file (in a scenario file relative to that file, "
                        f"on the command line to the working directory) or a {kind} shipped with hinfnn: {names}{hint}",
                        value)
    raise UrdfError(f"is neither a file nor a {'robot' if suffix == '.urdf' else 'model'} shipped with hinfnn "
                    f"({names}){hint}", value)


def _urdf_in_folder(folder) -> str:
    try:
        found = sorted(f for f in os.listdir(folder) if f.endswith(".urdf"))
    except OSError:
        return ""
    return f" (it holds {', '.join(found[:5])}{', ...' if len(found) > 5 else ''})" if found else ""


# ---------------------------------------------------------------------------------------------
# Parse-time geometry (NumPy, float64)
# ---------------------------------------------------------------------------------------------
def rpy_matrix(rpy) -> np.ndarray:
    """URDF roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll) (fixed axes x, y, z)."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _compose(T1, T2):
    """(R1, p1) ∘ (R2, p2): the placement of frame 2 given in frame 1, frame 1 given in 0."""
    return T1[0] @ T2[0], T1[0] @ T2[1] + T1[1]


def _lump(parts):
    """Mass, centre of mass and rotational inertia about it of rigidly joined (m, c, I_c) parts
    given in one frame (parallel-axis theorem)."""
    m = sum(p[0] for p in parts)
    if m <= 0:
        return m, np.zeros(3), np.zeros((3, 3))
    c = sum(p[0] * p[1] for p in parts) / m
    inertia = np.zeros((3, 3))
    for mi, ci, Ii in parts:
        d = ci - c
        inertia += Ii + mi * (d @ d * np.eye(3) - np.outer(d, d))
    return m, c, inertia


@dataclasses.dataclass
class _Link:
    name: str
    mass: float
    com: np.ndarray  # centre of mass in the link frame
    inertia: np.ndarray  # about the centre of mass, link-frame axes


@dataclasses.dataclass
class _Joint:
    name: str
    type: str
    parent: str
    child: str
    origin: tuple  # (R, p) of the joint frame in the parent link frame
    axis: np.ndarray
    limits: tuple  # lower, upper, effort, velocity
    mimic: bool = False


class _Parser:
    """Reads links and joints; every error names the file and the element."""

    def __init__(self, text: str, source: str):
        self.source = source
        try:
            root = ET.fromstring(text)
        except ET.ParseError as e:
            raise UrdfError(f"not an XML file ({e})", source) from None
        if root.tag != "robot":
            hint = {"mujoco": " (an MJCF file: hinfnn reads URDF)", "sdf": " (an SDF file: hinfnn reads URDF)"}
            raise UrdfError(f"no <robot> element: the root element is <{root.tag}>{hint.get(root.tag, '')}", source)
        if any(_is_xacro(el) for el in root.iter()):
            raise UrdfError("contains xacro macros or properties: expand it with xacro first (`xacro FILE > "
                            "robot.urdf`, in a ROS environment) and give the .urdf it writes", source)
        self.robot_name = root.get("name", "")
        self.links: dict[str, _Link] = {}
        self.joints: list[_Joint] = []
        for el in root.findall("link"):
            link = self._link(el)
            if link.name in self.links:
                raise UrdfError("two links have this name", source, f'<link name="{link.name}">')
            self.links[link.name] = link
        names = set()
        for el in root.findall("joint"):
            joint = self._joint(el)
            if joint.name in names:
                raise UrdfError("two joints have this name", source, f'<joint name="{joint.name}">')
            names.add(joint.name)
            self.joints.append(joint)

    def _err(self, problem, element):
        return UrdfError(problem, self.source, element)

    def _floats(self, el, attr, count, where, default=None):
        text = el.get(attr) if el is not None else None
        if text is None:
            if default is None:
                raise self._err(f"attribute {attr!r} is missing", where)
            return np.array(default, dtype=float)
        try:
            vals = [float(v) for v in text.split()]
        except ValueError:
            vals = []
        if len(vals) != count or not all(math.isfinite(v) for v in vals):
            raise self._err(f'{attr}="{text}" is not {count} finite number(s)', where)
        return np.array(vals)

    def _origin(self, el, where):
        o = el.find("origin")
        xyz = self._floats(o, "xyz", 3, where + "/<origin>", (0.0, 0.0, 0.0))
        rpy = self._floats(o, "rpy", 3, where + "/<origin>", (0.0, 0.0, 0.0))
        return rpy_matrix(rpy), xyz

    def _link(self, el):
        name = el.get("name")
        if not name:
            raise self._err("a <link> has no name", "<link>")
        where = f'<link name="{name}">'
        inertial = el.find("inertial")
        if inertial is None:
            return _Link(name, 0.0, np.zeros(3), np.zeros((3, 3)))
        w = where + "/<inertial>"
        mass_el = inertial.find("mass")
        if mass_el is None:
            raise self._err("<inertial> without <mass>", w)
        mass = float(self._floats(mass_el, "value", 1, w + "/<mass>")[0])
        R, com = self._origin(inertial, w)
        iel = inertial.find("inertia")
        if iel is None:
            raise self._err("<inertial> without <inertia>", w)
        v = {k: float(self._floats(iel, k, 1, w + "/<inertia>")[0])
             for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
        I_in = np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]],
                         [v["ixz"], v["iyz"], v["izz"]]])
        # mass and inertia are checked only for the links of the chain that is extracted (after
        # merging: _extract_chain), as Pinocchio loads a file whatever its unused links hold
        return _Link(name, mass, com, R @ I_in @ R.T)

    def _joint(self, el):
        name = el.get("name")
        if not name:
            raise self._err("a <joint> has no name", "<joint>")
        where = f'<joint name="{name}">'
        jtype = el.get("type")
        if jtype not in JOINT_TYPES:
            raise self._err(f"unknown joint type {jtype!r} (allowed: {', '.join(JOINT_TYPES)})", where)
        ends = []
        for tag in ("parent", "child"):
            e = el.find(tag)
            if e is None or not e.get("link"):
                raise self._err(f'no <{tag} link="...">', where)
            ends.append(e.get("link"))
        axis = self._floats(el.find("axis"), "xyz", 3, where + "/<axis>", (1.0, 0.0, 0.0))
        if jtype in MOVING_TYPES:
            norm = np.linalg.norm(axis)
            if norm < 1e-12:
                raise self._err("zero axis (allowed: a nonzero vector)", where + "/<axis>")
            axis = axis / norm
        lim = el.find("limit")
        limits = [-np.inf, np.inf, np.inf, np.inf]
        if lim is not None and jtype != "continuous":
            for i, k in enumerate(("lower", "upper", "effort", "velocity")):
                if lim.get(k) is not None:
                    limits[i] = float(self._floats(lim, k, 1, where + "/<limit>")[0])
        return _Joint(name, jtype, ends[0], ends[1], self._origin(el, where), axis, tuple(limits),
                      mimic=el.find("mimic") is not None)


def _check_inertia(I, source, where, what="inertia tensor"):
    """Rotational inertia about the centre of mass: symmetric positive semidefinite (else
    :class:`UrdfError`: M(q) could lose definiteness) and physically consistent (principal moments
    satisfy the triangle inequality; else a :class:`UrdfWarning`, as Pinocchio loads such files).
    Zero is allowed (point mass)."""
    lam = np.linalg.eigvalsh(I)
    tol = 1e-12 * max(1.0, float(np.abs(lam).max()))
    if lam[0] < -tol:
        raise UrdfError(f"{what} not positive semidefinite (principal moments {lam.tolist()}; "
                        "allowed: all ≥ 0)", source, where)
    if lam[0] + lam[1] < lam[2] - tol:
        warnings.warn(f"{source}: {where}: {what} not physical (principal moments {lam.tolist()} violate the "
                      "triangle inequality I1 + I2 ≥ I3 by "
                      f"{(lam[2] - lam[0] - lam[1]) / lam[2]:.1%}); loaded as written (the dynamics stay well "
                      "defined)", UrdfWarning, stacklevel=4)


def _did_you_mean(name, names):
    close = difflib.get_close_matches(name, names, n=3, cutoff=0.5)
    if close:
        return "; did you mean " + " or ".join(repr(c) for c in close) + "?"
    return f"; links in the file: {', '.join(sorted(names)[:20])}"


def _lock(parsed: _Parser, locked: dict):
    """Turn the joints named in ``locked`` into fixed joints at the given position (rad or m):
    the joint's origin composed with its motion there."""
    src = parsed.source
    by_name = {j.name: j for j in parsed.joints}
    movable = [j.name for j in parsed.joints if j.type in MOVING_TYPES]
    for name, value in locked.items():
        if name not in by_name:
            raise UrdfError(f"cannot lock joint {name!r}: no joint of that name in the file"
                            + _did_you_mean(name, movable).replace("links in the file", "moving joints"), src,
                            "locked_joints")
        j = by_name[name]
        if j.type not in MOVING_TYPES:
            raise UrdfError(f"cannot lock joint {name!r}: it is {j.type} (allowed: {', '.join(MOVING_TYPES)})", src,
                            "locked_joints")
        value = float(value)
        if not math.isfinite(value):
            raise UrdfError(f"cannot lock joint {name!r} at {value} (allowed: a finite position)", src,
                            "locked_joints")
        a = j.axis
        if j.type == "prismatic":
            motion = (np.eye(3), a * value)
        else:
            K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            motion = (np.eye(3) + math.sin(value) * K + (1 - math.cos(value)) * K @ K, np.zeros(3))
        locked_joint = dataclasses.replace(j, type="fixed", origin=_compose(j.origin, motion))
        parsed.joints[parsed.joints.index(j)] = locked_joint


def _extract_chain(parsed: _Parser, base_link, ee_link, tool_T):
    """Serial chain base → ee: placements, axes, lumped inertias, tool placement (NumPy)."""
    src, links = parsed.source, parsed.links
    for role, name in (("base_link", base_link), ("ee_link", ee_link)):
        if name not in links:
            raise UrdfError(f"no link named {name!r} in the file" + _did_you_mean(name, list(links)),
                            src, role)
    parent_joint, children = {}, {name: [] for name in links}
    for j in parsed.joints:
        for end in (j.parent, j.child):
            if end not in links:
                raise UrdfError(f"link {end!r} is not defined in the file"
                                + _did_you_mean(end, list(links)), src, f'<joint name="{j.name}">')
        if j.child in parent_joint:
            raise UrdfError(f"kinematic loop: link {j.child!r} has two parents (joints "
                            f"{parent_joint[j.child].name!r} and {j.name!r}); a URDF must be a tree",
                            src, f'<joint name="{j.name}">')
        parent_joint[j.child] = j
        children[j.parent].append(j)

    path, link, seen = [], ee_link, set()
    while link != base_link:
        if link in seen:
            raise UrdfError(f"kinematic loop through link {link!r}", src, f'<link name="{link}">')
        seen.add(link)
        if link not in parent_joint:
            hint = " (the base is below the end-effector: swap them?)" if ee_link in _ancestors(
                base_link, parent_joint) else ""
            raise UrdfError(f"end-effector link {ee_link!r} is not reachable from base link "
                            f"{base_link!r}: going up from it ends at root link {link!r}{hint}",
                            src, "ee_link")
        path.append(parent_joint[link])
        link = parent_joint[link].parent
    path.reverse()
    for j in path:
        if j.type in ("floating", "planar"):
            raise UrdfError(f"joint type {j.type!r} on the chain from {base_link!r} to {ee_link!r} is "
                            f"not supported (allowed: {', '.join(MOVING_TYPES)}, fixed)",
                            src, f'<joint name="{j.name}">')
        if j.mimic and j.type in MOVING_TYPES:
            warnings.warn(f"{src}: <joint name=\"{j.name}\">: a <mimic> joint on the chain from {base_link!r} to "
                          f"{ee_link!r}: taken as an independent coordinate (as Pinocchio does by default); lock "
                          "it (locked_joints) to hold it", UrdfWarning, stacklevel=3)
    moving = [j for j in path if j.type in MOVING_TYPES]
    if not moving:
        raise UrdfError(f"no moving joint between {base_link!r} and {ee_link!r}", src, "ee_link")
    moving_names = {j.name for j in moving}

    def rigid(root):
        """Links rigidly attached to ``root`` (placements in root's frame) and the next chain
        joint's placement in that frame."""
        members, nxt, stack = {}, None, [(root, (np.eye(3), np.zeros(3)))]
        while stack:
            name, T = stack.pop()
            members[name] = T
            for j in children[name]:
                if j.name in moving_names:
                    nxt = (j, _compose(T, j.origin))
                else:
                    stack.append((j.child, _compose(T, j.origin)))
        return members, nxt

    _, nxt = rigid(base_link)
    placements, bodies, tool = [], [], None
    for i, j in enumerate(moving):
        assert nxt is not None and nxt[0] is j
        placements.append(nxt[1])
        members, nxt = rigid(j.child)
        parts = []
        where = f'<joint name="{j.name}">'
        for name, (R, p) in members.items():
            L = links[name]
            if L.mass < 0:
                raise UrdfError(f"link {name!r} of the body moved by this joint has negative mass {L.mass} "
                                "(allowed: mass ≥ 0)", src, where)
            parts.append((L.mass, R @ L.com + p, R @ L.inertia @ R.T))
        m, c, inertia = _lump(parts)
        body = f"links {', '.join(sorted(members))}"
        if m <= 0:
            raise UrdfError(f"the body moved by this joint ({body}) has "
                            f"mass {m} (allowed: > 0)", src, where)
        _check_inertia(inertia, src, where, what=f"the inertia tensor of the body moved by this joint ({body}) is")
        bodies.append((m, c, inertia, sorted(members)))
        if i == len(moving) - 1:
            tool = _compose(members[ee_link], tool_T)
    return moving, placements, bodies, tool


def _ancestors(link, parent_joint):
    out, seen = set(), set()
    while link in parent_joint and link not in seen:
        seen.add(link)
        link = parent_joint[link].parent
        out.add(link)
    return out


# ---------------------------------------------------------------------------------------------
# Spatial algebra (the rigid-body algorithms themselves are in hinfnn.model.rbd)
# ---------------------------------------------------------------------------------------------
skew = rbd.skew  # [v]×, so that skew(v) @ u = v × u


@pytree_dataclass
class UrdfChain:
    """A serial chain of n revolute/prismatic joints with lumped rigid bodies.

    Data (base-frame conventions of URDF): joint i's frame sits at ``placement_rot[i],
    placement_pos[i]`` in body i−1's frame (body 0 = the base) and turns about (or slides
    along) the unit ``axes[i]`` of that frame; body i (the frame after the joint motion) has
    ``mass[i]``, centre of mass ``com[i]`` and rotational inertia ``inertia[i]`` about it (body
    axes); the tool frame is ``tool_rot, tool_pos`` in body n's frame; ``gravity`` is the
    gravitational acceleration in the base frame. Joint limits are kept, not enforced.
    ``armature`` (None, or (n,) kg·m² / kg): the motors' reflected inertia per joint, which a URDF
    cannot state (Pinocchio's ``model.armature``, MuJoCo's joint ``armature``): M(q) =
    M_rigid(q) + diag(armature), and inverse dynamics gains armature · q̈ (:meth:`with_armature`;
    None, the default, adds nothing to any program).

    Two formulations of the forward kinematics (:mod:`hinfnn.model.rbd`), and each public method
    says which it uses: :meth:`fk`, :meth:`frame_jacobian` and :meth:`M` always by 3 × 3 products
    (:func:`~hinfnn.model.rbd.placements`, for the programs that run once); the others on
    :meth:`_kinematics`, which follows the chain's ``kernels`` (:class:`hinfnn._linalg.Kernels`):
    component by component with stored stages (:func:`~hinfnn.model.rbd.frames`, the compiled
    loop's layout) by default and in the simulator's programs, by products when the kernels say
    ``products`` (the design's and the setup programs of arms hold such kernels).
    """

    placement_rot: jax.Array
    placement_pos: jax.Array
    axes: jax.Array
    mass: jax.Array
    com: jax.Array
    inertia: jax.Array
    tool_rot: jax.Array
    tool_pos: jax.Array
    gravity: jax.Array
    lower: jax.Array
    upper: jax.Array
    effort_limit: jax.Array
    velocity_limit: jax.Array
    n: int = static_field()
    joint_types: tuple = static_field()
    joint_names: tuple = static_field(default=())
    body_links: tuple = static_field(default=())
    kernels: la.Kernels = la.kernels_field()
    armature: jax.Array | None = None

    # --- kinematics (hinfnn.model.rbd) --------------------------------------------------------
    def _kinematics(self, q) -> rbd.Frames:
        """Forward pass (:func:`hinfnn.model.rbd.frames`): body placements, motion subspaces
        S_i = (p_i × a_i, a_i) (revolute) or (a_i, 0) (prismatic), body inertias, tool frame;
        component by component, or by products when ``self.kernels.products``."""
        return rbd.frames(self, q)

    def fk(self, q):
        """Tool frame (position (3,), rotation (3,3)) in the base frame, by 3 × 3 products
        (:func:`hinfnn.model.rbd.placements`: a fifth of the program of the compiled loop's
        :meth:`_kinematics`, for the programs that run once)."""
        pl = rbd.placements(self, q)
        return pl.p_tool, pl.R_tool

    @staticmethod
    def _jacobian(k: rbd.Frames):
        return rbd.frame_jacobian(k)

    @staticmethod
    def _jacobian_dot(k: rbd.Frames, qd, v=None):
        return rbd.frame_jacobian_dot(k, qd, v)

    def frame_jacobian(self, q):
        """Geometric Jacobian (6, n) of the tool frame: rows (ṗ_tool, ω), base-frame axes
        (Pinocchio's LOCAL_WORLD_ALIGNED). Column i: (a_i × (p_tool − p_i), a_i) (revolute).
        On the kinematics by 3 × 3 products (:func:`hinfnn.model.rbd.frames_by_products`), as
        :meth:`fk`."""
        return rbd.frame_jacobian(rbd.frames_by_products(self, q))

    def frame_jacobian_dot(self, q, qd):
        """d/dt of :meth:`frame_jacobian` along q̇; J̇ q̇ is the tool's classical acceleration
        (p̈, ω̇) at q̈ = 0. On :meth:`_kinematics` (the chain's kernels)."""
        return self._jacobian_dot(self._kinematics(q), qd)

    # --- dynamics (hinfnn.model.rbd) ----------------------------------------------------------
    def _a0(self):
        """The base's spatial acceleration (−g, 0) that puts gravity into RNEA (a 6-tuple)."""
        return rbd.gravity_vector(self.gravity)

    def _crba(self, k: rbd.Frames):
        """M by the composite-rigid-body algorithm: M_ij = S_iᵀ I^c_{max(i,j)} S_j with composite
        inertias I^c_j = Σ_{k≥j} I_k, plus diag(armature) (:meth:`_with_armature`)."""
        return self._with_armature(rbd.crba(k))

    def _with_armature(self, M):
        """M + diag(armature): the motors' reflected inertia on the diagonal (not in the paper:
        docs/arms-and-surfaces.md, "Motor armature"). Without an armature M itself, the same
        program as before the field existed."""
        if self.armature is None:
            return M
        return M + jnp.diag(self.armature)

    @staticmethod
    def _rnea(k: rbd.Frames, qd, qdd, a0, v=None):
        """Recursive Newton–Euler (:func:`hinfnn.model.rbd.rnea`; ``qdd`` None: q̈ = 0)."""
        return rbd.rnea(k, qd, qdd, a0, v)

    @staticmethod
    def _christoffel(k: rbd.Frames, a, b, va=None):
        """The Christoffel bilinear form Γ(a, b) = C(q, a) b (:func:`hinfnn.model.rbd.christoffel`)."""
        return rbd.christoffel(k, a, b, va)

    def _coriolis(self, k: rbd.Frames, qd):
        va = rbd.velocities(k, qd)
        cols = jax.vmap(lambda e: self._christoffel(k, qd, e, va))(jnp.eye(self.n))
        return cols.T

    def M(self, q):
        """Joint-space inertia matrix by the composite-rigid-body algorithm (:meth:`_crba`) on the
        kinematics by 3 × 3 products (:func:`hinfnn.model.rbd.frames_by_products`), as :meth:`fk`:
        M alone is computed by the programs that run once; the compiled loop's comes from
        :meth:`_crba` on its own kinematics. With the motors' ``armature``: M_rigid + diag(armature)."""
        return self._with_armature(rbd.crba(rbd.frames_by_products(self, q)))

    def bias(self, q, qd):
        """C(q, q̇) q̇ + G(q) by recursive Newton–Euler (q̈ = 0), on :meth:`_kinematics` (the chain's kernels)."""
        return self._rnea(self._kinematics(q), qd, None, self._a0())

    def _gravity(self, k: rbd.Frames):
        """G_i = S_i · I^c_i a0: RNEA at q̇ = q̈ = 0 with composite inertias."""
        return rbd.gravity(k, self._a0())

    def G(self, q):
        """Gravity torque G(q) = ∂U/∂q (RNEA at q̇ = q̈ = 0), on :meth:`_kinematics` (the chain's kernels)."""
        return self._gravity(self._kinematics(q))

    def potential(self, q):
        """Potential energy U(q) = −Σ m_i g · c_i (zero at the base origin), on :meth:`_kinematics`."""
        return rbd.potential(self._kinematics(q), self.gravity)

    def inverse_dynamics(self, q, qd, qdd):
        """τ = M(q) q̈ + C(q, q̇) q̇ + G(q) (RNEA, plus armature · q̈ with the motors' ``armature``),
        on :meth:`_kinematics` (the chain's kernels)."""
        tau = self._rnea(self._kinematics(q), qd, qdd, self._a0())
        if self.armature is None:
            return tau
        return tau + self.armature * qdd

    def forward_dynamics(self, q, qd, tau):
        """q̈ = M(q)⁻¹ (τ − C(q, q̇) q̇ − G(q)) (CRBA and RNEA share the forward pass; M by its
        Cholesky factor), on :meth:`_kinematics` (the chain's kernels)."""
        k = self._kinematics(q)
        return self.kernels.spd_solve(self._crba(k), tau - self._rnea(k, qd, None, self._a0()))

    def C(self, q, qd):
        """Coriolis matrix from the Christoffel symbols of M (Ṁ − 2C skew-symmetric):
        column j is Γ(q̇, e_j) (:meth:`_christoffel`), on :meth:`_kinematics` (the chain's kernels)."""
        return self._coriolis(self._kinematics(q), qd)

    def C_times(self, q, qd, v):
        """C(q, q̇) v without forming C (one bilinear Newton–Euler pass), on :meth:`_kinematics`."""
        return self._christoffel(self._kinematics(q), qd, v)

    # --- model uncertainty -------------------------------------------------------------------
    def perturbed(self, *, mass_scale=1.0, com_shift=0.0, payload_mass=0.0,
                  payload_xyz=(0.0, 0.0, 0.0)) -> "UrdfChain":
        """A chain with other inertial parameters (e.g. the "true" plant of a nominal model).

        ``mass_scale`` (scalar or (n,)) scales body i's mass and rotational inertia (density
        scaled, shape kept); ``com_shift`` (scalar, (3,) or (n, 3), body axes) moves each centre
        of mass keeping the inertia about it; ``payload_mass`` adds a point mass at
        ``payload_xyz`` in the tool frame to the last body (parallel-axis theorem). All
        arguments may be traced (vmap over parameter draws).
        """
        s = jnp.broadcast_to(jnp.asarray(mass_scale, float), (self.n,))
        mass = self.mass * s
        inertia = self.inertia * s[:, None, None]
        com = self.com + jnp.broadcast_to(jnp.asarray(com_shift, float), (self.n, 3))
        mp = jnp.asarray(payload_mass, float)
        cp = self.tool_pos + self.tool_rot @ jnp.asarray(payload_xyz, float)
        m_last = mass[-1] + mp
        c_last = (mass[-1] * com[-1] + mp * cp) / m_last

        def shift(m, d):
            return m * (jnp.sum(d * d) * jnp.eye(3) - d[:, None] * d[None, :])

        I_last = inertia[-1] + shift(mass[-1], com[-1] - c_last) + shift(mp, cp - c_last)
        return replace(self, mass=mass.at[-1].set(m_last), com=com.at[-1].set(c_last),
                       inertia=inertia.at[-1].set(I_last))

    def with_gravity(self, gravity) -> "UrdfChain":
        """The same chain under another gravity vector (base frame)."""
        return replace(self, gravity=jnp.asarray(gravity, float))

    def with_armature(self, armature, key: str = "armature") -> "UrdfChain":
        """The same chain with the motors' reflected inertia ``armature`` (kg·m² for a revolute
        joint, kg for a prismatic one; a number for every joint or one per joint, finite, ≥ 0):
        M(q) gains diag(armature), inverse dynamics armature · q̈, forward dynamics follows from M.
        Not in the paper (docs/arms-and-surfaces.md, "Motor armature"). All zeros (or None) give
        the chain without one (``armature`` None: the programs of a chain that never had one).
        Bad input: :class:`~hinfnn.errors.ConfigError` at ``key`` naming the value and what is
        allowed."""
        if armature is None:
            return replace(self, armature=None)
        a = np.asarray(armature, dtype=float) if _numeric(armature) else None
        allowed = f"a number or a list of {self.n} (one per joint: {', '.join(self.joint_names) or self.n}), each finite and >= 0, kg m^2"
        if a is None or a.ndim > 1 or a.size not in (1, self.n):
            raise ConfigError(f"must be {allowed}, got {_listed(armature)}", key=key)
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ConfigError(f"must be {allowed}, got {_listed(armature)}", key=key)
        a = np.broadcast_to(a.reshape(-1), (self.n,)).astype(float)
        if not np.any(a):
            return replace(self, armature=None)
        return replace(self, armature=jnp.asarray(a))


def _numeric(value) -> bool:
    """A number or a (nested) list or array of numbers (not text, not a mapping)."""
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return not isinstance(value, (str, bytes, dict))


def _listed(value) -> str:
    """A value as a user would have written it, in an error message."""
    try:
        return repr(np.asarray(value, dtype=float).tolist())
    except (TypeError, ValueError):
        return repr(value)


def planar_chain(masses, lengths, g: float = 9.81) -> UrdfChain:
    """The n-link planar arm with a point mass at the tip of each link (the arm of Sec. VI for
    n = 2) as a chain: joints about z in the x–y plane, joint 1 at the origin turning from x
    towards y, link i of length l_i along its body's x axis, gravity along −y, the tool at the last
    tip with its x axis along the last link. With :class:`~hinfnn.model.taskmap.PlanarTaskMap`
    ``("xy", with_angle=True)`` the task coordinates are (x, y, φ = Σ q); it equals
    :class:`~hinfnn.model.arm.PlanarPointMassArm` (the autodiff oracle, tested) and runs on
    CRBA/RNEA."""
    m = np.asarray(masses, dtype=float)
    L = np.asarray(lengths, dtype=float)
    n = m.size
    f = lambda x: jnp.asarray(np.asarray(x, dtype=float))  # noqa: E731
    pos = np.zeros((n, 3))
    pos[1:, 0] = L[:-1]
    com = np.zeros((n, 3))
    com[:, 0] = L
    return UrdfChain(
        placement_rot=f(np.broadcast_to(np.eye(3), (n, 3, 3))), placement_pos=f(pos),
        axes=f(np.broadcast_to([0.0, 0.0, 1.0], (n, 3))), mass=f(m), com=f(com), inertia=f(np.zeros((n, 3, 3))),
        tool_rot=f(np.eye(3)), tool_pos=f([L[-1], 0.0, 0.0]), gravity=f([0.0, -float(g), 0.0]),
        lower=f(np.full(n, -np.inf)), upper=f(np.full(n, np.inf)), effort_limit=f(np.full(n, np.inf)),
        velocity_limit=f(np.full(n, np.inf)), n=n, joint_types=("revolute",) * n,
        joint_names=tuple(f"joint{i + 1}" for i in range(n)), body_links=tuple((f"link{i + 1}",) for i in range(n)))


def load_urdf_string(text: str, base_link: str, ee_link: str, *, tool_xyz=(0.0, 0.0, 0.0),
                     tool_rpy=(0.0, 0.0, 0.0), gravity=(0.0, 0.0, -9.81),
                     source: str = "<string>", locked: dict | None = None) -> UrdfChain:
    """:func:`load_urdf` of URDF text (``source`` names it in error messages)."""
    parsed = _Parser(text, source)
    if locked:
        _lock(parsed, dict(locked))
    tool_T = (rpy_matrix(np.asarray(tool_rpy, float)), np.asarray(tool_xyz, float))
    moving, placements, bodies, tool = _extract_chain(parsed, base_link, ee_link, tool_T)
    f = lambda x: jnp.asarray(np.asarray(x, dtype=float))  # noqa: E731
    return UrdfChain(
        placement_rot=f([T[0] for T in placements]), placement_pos=f([T[1] for T in placements]),
        axes=f([j.axis for j in moving]), mass=f([b[0] for b in bodies]),
        com=f([b[1] for b in bodies]), inertia=f([b[2] for b in bodies]),
        tool_rot=f(tool[0]), tool_pos=f(tool[1]), gravity=f(gravity),
        lower=f([j.limits[0] for j in moving]), upper=f([j.limits[1] for j in moving]),
        effort_limit=f([j.limits[2] for j in moving]), velocity_limit=f([j.limits[3] for j in moving]),
        n=len(moving), joint_types=tuple(j.type for j in moving),
        joint_names=tuple(j.name for j in moving), body_links=tuple(tuple(b[3]) for b in bodies))


def load_urdf(path, base_link: str, ee_link: str, *, tool_xyz=(0.0, 0.0, 0.0),
              tool_rpy=(0.0, 0.0, 0.0), gravity=(0.0, 0.0, -9.81), locked: dict | None = None) -> UrdfChain:
    """Serial chain from ``base_link`` to ``ee_link`` of a URDF file, with a fixed tool offset
    (xyz, rpy in the end-effector link's frame) and gravity (base frame). ``path`` is a file (any
    extension) or the name of a robot shipped with hinfnn (:func:`robot_file`). ``locked`` maps
    joint names to positions (rad or m) at which they are held fixed. Raises :class:`UrdfError`
    naming the file, the element and the problem."""
    path = robot_file(path)
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except OSError as e:
        raise UrdfError(f"cannot read the file ({e.strerror})", path) from None
    return load_urdf_string(text, base_link, ee_link, tool_xyz=tool_xyz, tool_rpy=tool_rpy,
                            gravity=gravity, source=path, locked=locked)


# ---------------------------------------------------------------------------------------------
# The arm
# ---------------------------------------------------------------------------------------------
def _tool_frame(k: rbd.Frames):
    """(p_tool (3,), R_tool (3, 3)) as arrays."""
    return jnp.stack(k.p_tool), rbd.as_matrix(k.R_tool)


def _task_derivatives(task, p, R, Jf, Jf_dot, qd, kernels: la.Kernels = la.DEFAULT):
    """Task Jacobian J = ∂x/∂q and J̇ from the frame Jacobian and the task map's derivative.

    Column j of J is the directional derivative of the task map along the frame motion of joint
    j, (ṗ, Ṙ) = (v_j, [ω_j]× R); J̇'s column is its time derivative, a second directional
    derivative along (ṗ_tool, [ω_tool]× R, v̇_j, [ω̇_j]× R + [ω_j]× [ω_tool]× R).
    """
    def column(p, R, v, W):
        return jax.jvp(task, (p, R), (v, W))[1]

    mm = kernels.mm
    vt, wt = mm(Jf[:3], qd), mm(Jf[3:], qd)
    Rd = mm(skew(wt), R)

    def both(v, w, vd, wd):
        W = mm(skew(w), R)
        Wd = mm(skew(wd), R) + mm(skew(w), Rd)
        return jax.jvp(column, (p, R, v, W), (vt, Rd, vd, Wd))

    J, Jd = jax.vmap(both, in_axes=1, out_axes=1)(Jf[:3], Jf[3:], Jf_dot[:3], Jf_dot[3:])
    return J, Jd


def _task_derivatives_times(task, p, R, Jf, Jf_dot, qd, V, kernels: la.Kernels = la.DEFAULT):
    """J̇ V for a few joint-space directions (columns of V, or a vector): the columns of
    :func:`_task_derivatives` for those directions only."""
    mm = kernels.mm

    def column(p, R, vl, W):
        return jax.jvp(task, (p, R), (vl, W))[1]

    vt, wt = mm(Jf[:3], qd), mm(Jf[3:], qd)
    Rd = mm(skew(wt), R)

    def one(v):
        w, wd = mm(Jf[3:], v), mm(Jf_dot[3:], v)
        W = mm(skew(w), R)
        Wd = mm(skew(wd), R) + mm(skew(w), Rd)
        return jax.jvp(column, (p, R, mm(Jf[:3], v), W), (vt, Rd, mm(Jf_dot[:3], v), Wd))[1]

    if V.ndim == 1:
        return one(V)
    return jax.vmap(one, in_axes=1, out_axes=1)(V)


def _task_jacobian(task, p, R, Jf, kernels: la.Kernels = la.DEFAULT):
    """J = ∂x/∂q alone (the plant needs no J̇): one directional derivative of the task map per
    joint."""
    def column(v, w):
        return jax.jvp(task, (p, R), (v, kernels.mm(skew(w), R)))[1]

    return jax.vmap(column, in_axes=1, out_axes=1)(Jf[:3], Jf[3:])


@pytree_dataclass
class UrdfArm(Arm):
    """An :class:`~hinfnn.model.arm.Arm` from a :class:`UrdfChain` and a task map
    (:mod:`hinfnn.model.taskmap`): h(q) = task(*chain.fk(q)).

    J and J̇ come from the frame Jacobian and the task map's derivative (tested against the
    autodiff of h); M by CRBA, G and C(q, q̇)q̇ by RNEA, C by the Christoffel symbols.
    """

    chain: UrdfChain
    task: Any
    kernels: la.Kernels = la.kernels_field()

    @property
    def n(self) -> int:
        return self.chain.n

    @classmethod
    def from_urdf(cls, path, base_link, ee_link, task, **load_kwargs) -> "UrdfArm":
        """``UrdfArm(load_urdf(path, base_link, ee_link, **load_kwargs), task)``."""
        return cls(load_urdf(path, base_link, ee_link, **load_kwargs), task)

    def h(self, q):
        return self.task(*self.chain.fk(q))

    def _J_Jdot(self, k, qd, v=None):
        return _task_derivatives(self.task, *_tool_frame(k), self.chain._jacobian(k),
                                 self.chain._jacobian_dot(k, qd, v), qd, self.kernels)

    def J(self, q):
        """∂h/∂q = (∂task/∂(p, R)) · frame Jacobian (the kinematics by 3 × 3 products, as
        :meth:`UrdfChain.fk`: J alone is computed by the programs that run once; the compiled
        loop's comes from :meth:`law_terms` and :meth:`plant_terms`)."""
        k = rbd.frames_by_products(self.chain, q)
        return _task_jacobian(self.task, *_tool_frame(k), rbd.frame_jacobian(k), self.kernels)

    def J_dot(self, q, qd):
        """dJ/dt along q̇ (frame Jacobian, its time derivative and the task map's derivatives)."""
        return self._J_Jdot(self.chain._kinematics(q), qd)[1]

    def M(self, q):
        return self.chain.M(q)

    def C(self, q, qd):
        return self.chain.C(q, qd)

    def C_times(self, q, qd, v):
        """C(q, q̇) v without forming C."""
        return self.chain.C_times(q, qd, v)

    def G(self, q):
        return self.chain.G(q)

    def potential(self, q):
        return self.chain.potential(q)

    def bias(self, q, qd):
        """C(q, q̇) q̇ + G(q) (RNEA)."""
        return self.chain.bias(q, qd)

    def terms(self, q, qd) -> ArmTerms:
        """h, J, J̇, M, C, G sharing one forward kinematics pass."""
        k = self.chain._kinematics(q)
        J, J_dot = self._J_Jdot(k, qd)
        return ArmTerms(x=self.task(*_tool_frame(k)), J=J, J_dot=J_dot, M=self.chain._crba(k),
                        C=self.chain._coriolis(k, qd), G=self.chain._gravity(k))

    def law_terms(self, q, qd) -> ArmTerms:
        """x, J, M, G sharing one forward pass; neither C nor J̇ formed (J_dot None): ``aux`` keeps
        the kinematics, the frame Jacobian and its derivative for :meth:`C_product` and
        :meth:`J_dot_times`."""
        k = self.chain._kinematics(q)
        v = rbd.velocities(k, qd)  # shared by J̇ and the Christoffel products along q̇
        Jf = self.chain._jacobian(k)
        Jf_dot = self.chain._jacobian_dot(k, qd, v)
        p, R = _tool_frame(k)
        J = _task_jacobian(self.task, p, R, Jf, self.kernels)
        return ArmTerms(x=self.task(p, R), J=J, J_dot=None, M=self.chain._crba(k), C=None,
                        G=self.chain._gravity(k), aux=(k, Jf, Jf_dot, v),
                        J_p=None if self.task_is_point else jnp.stack([Jf[i] for i in self.task.space_rows]))

    def C_product(self, terms: ArmTerms, q, qd, v):
        """C(q, q̇) v by one bilinear Newton–Euler pass on the kinematics of :meth:`law_terms`."""
        if terms.C is not None:
            return self.kernels.mm(terms.C, v)
        if terms.aux is None:
            return self.chain.C_times(q, qd, v)
        k, va = terms.aux[0], terms.aux[3]
        return self.chain._christoffel(k, qd, v, va)

    def J_dot_times(self, terms: ArmTerms, q, qd, v):
        """J̇(q, q̇) v: one column of :func:`_task_derivatives` (the task map's second directional
        derivative along the frame motion), not the whole J̇."""
        if terms.J_dot is not None:
            return self.kernels.mm(terms.J_dot, v)
        if terms.aux is None:
            return self.kernels.mm(self.J_dot(q, qd), v)
        k, Jf, Jf_dot, _ = terms.aux
        return _task_derivatives_times(self.task, *_tool_frame(k), Jf, Jf_dot, qd, v, self.kernels)

    @property
    def task_is_point(self) -> bool:
        """The task coordinates are the tool point (x = p) for the position task map."""
        from .taskmap import PositionTaskMap

        return isinstance(self.task, PositionTaskMap)

    def point(self, q):
        """The tool point in the task map's space (3-D, or the plane's coordinates)."""
        return self.task.space(self.chain.fk(q)[0])

    def point_jacobian(self, q):
        Jf = self.chain.frame_jacobian(q)
        return jnp.stack([Jf[i] for i in self.task.space_rows])

    @property
    def space_dim(self) -> int:
        return int(self.task.space_dim)

    def plant_terms(self, q, qd) -> ArmTerms:
        """x, J, M, bias = C q̇ + G (RNEA), tool point and its Jacobian, from one forward pass."""
        k = self.chain._kinematics(q)
        Jf = self.chain._jacobian(k)
        p, R = _tool_frame(k)
        return ArmTerms(x=self.task(p, R), J=_task_jacobian(self.task, p, R, Jf, self.kernels),
                        J_dot=None, M=self.chain._crba(k), C=None, G=None,
                        bias=self.chain._rnea(k, qd, None, self.chain._a0()),
                        p=self.task.space(p), J_p=jnp.stack([Jf[i] for i in self.task.space_rows]))

    def task_margin(self, q):
        """The task map's distance from its singularities at q (:meth:`~hinfnn.model.taskmap.PoseTaskMap.margin`).
        Recorded by the compiled loop at every stored sample: from the loop's own kinematics
        (:meth:`UrdfChain._kinematics`), which XLA shares with the plant's terms at the same q."""
        return self.task.margin(*_tool_frame(self.chain._kinematics(q)))

    def forward_dynamics(self, q, qd, tau_total, terms: ArmTerms | None = None):
        """q̈ = M⁻¹ (τ_total − C q̇ − G); without ``terms`` by CRBA + RNEA (C is not formed)."""
        if terms is None:
            return self.chain.forward_dynamics(q, qd, tau_total)
        if terms.bias is not None:
            return self.kernels.spd_solve(terms.M, tau_total - terms.bias)
        return self.kernels.solve(terms.M, tau_total - self.kernels.mm(terms.C, qd) - terms.G)
