"""The sections of a scenario file, as typed dataclasses, and how each builds its objects.

Arms, surfaces, plants, task coordinates and references are *registered* sections
(:mod:`hinfnn.scenario.registry`): the ``model`` / ``kind`` / ``engine`` / ``map`` key of the TOML
table chooses the class, and the class builds the library object (``build()``). Controllers are
chosen by ``controller.kind`` from :data:`hinfnn.controllers.KINDS`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np

from ..errors import ConfigError, DesignError
from .registry import ARMS, PLANTS, REFERENCES, SURFACES, TASKS
from .schema import Matrix, param, section

from typing import ClassVar, Literal

#: A number (the same for every coordinate or joint) or a list of numbers (one each).
Numbers = float | tuple[float, ...]


def _length(path: str, name: str, value, sizes, what: str = "numbers") -> None:
    """A list key must have one of ``sizes`` entries (ConfigError at ``path.name``)."""
    if isinstance(value, tuple) and len(value) not in sizes:
        want = " or ".join(str(n) for n in sizes)
        raise ConfigError(f"must be a list of {want} {what}, got {len(value)}: {list(value)}", key=f"{path}.{name}")


def _shown(values) -> str:
    """A list of numbers as the user wrote it ([0.1, 0.1, 0.0])."""
    return "[" + ", ".join(f"{float(v):g}" for v in values) + "]"


def per_item(value, n: int, key: str, what: str) -> np.ndarray:
    """A number broadcast to n items, or a list of exactly n (ConfigError at ``key``)."""
    a = np.atleast_1d(np.asarray(value, dtype=float))
    if a.size == 1:
        return np.full(n, float(a[0]))
    if a.size != n:
        raise ConfigError(f"must be a number or a list of {n} ({what}), got {len(a)}: {a.tolist()}", key=key)
    return a


# --- arms ------------------------------------------------------------------------------------------


def _extra_joints(c) -> tuple:
    """The chain indices an extra task coordinate uses."""
    if hasattr(c, "index"):
        return (c.index,)
    return (c.shoulder, c.elbow, c.wrist)


def _check_locked(path, joints, positions):
    """``locked_joints`` (no joint twice) and ``locked_positions`` (one per joint, or none) of the
    section at ``path``."""
    if positions and len(positions) != len(joints):
        raise ConfigError(f"must give one position per locked joint ({len(joints)}), got {len(positions)}",
                          key=f"{path}.locked_positions")
    if len(set(joints)) != len(joints):
        raise ConfigError(f"lists a joint twice: {list(joints)}", key=f"{path}.locked_joints")


def _locked_pairs(joints, positions) -> tuple:
    """(joint name, position) of each locked joint (position 0 where none is given)."""
    return tuple(zip(joints, positions or (0.0,) * len(joints)))


_ARMATURE_DOC = ("the motors' reflected inertia (armature) per joint, kg m^2 (kg for a prismatic joint): one number for "
                 "every joint or one per moving joint; added to M(q)'s diagonal (not in the paper; "
                 "docs/arms-and-surfaces.md, \"Motor armature\"); the truth's applies to the built-in plant and "
                 "to the MJCF generated from plant.arm; a user's MJCF has its own, which a nonzero plant.arm.armature "
                 "must equal")


def _with_armature(chain, armature, key: str):
    """``chain`` with the motors' armature of the section at ``key`` (nothing added when all zero)."""
    a = np.atleast_1d(np.asarray(armature, dtype=float))
    if not np.any(a):
        return chain
    return chain.with_armature(per_item(armature, chain.n, f"{key}.armature", f"one per moving joint, n = {chain.n}"),
                               key=f"{key}.armature")


@section
class ArmConfig:
    """An arm model (``model`` chooses the kind). ``build(task, key)`` returns the arm with the
    task coordinates ``task`` (a task map of :mod:`hinfnn.model.taskmap`, or None for the arm's
    native coordinates); ``key`` (``plant.arm`` or ``nominal.arm``) names the section in errors."""

    __registry__ = ARMS
    model: str = param(doc="arm model")

    #: the plane of a planar arm's Cartesian space in its tool frame (None: a spatial arm)
    plane = None
    #: task.map may choose its coordinates (False: only the native ones, the two_link arm)
    task_maps = True

    def build(self, task=None, key: str = "arm"):
        raise NotImplementedError

    def native_task(self, key: str = "task.map"):
        """The task map of ``task.map = "native"`` (None: h(q) is the arm's own)."""
        return None

    def joint_chain(self, key: str = "arm"):
        """The arm's :class:`~hinfnn.model.urdf.UrdfChain` (joint names, limits, frames), or None
        for an arm that is not a chain (the two_link arm's closed form)."""
        return None

    def _chain_arm(self, chain, task, key):
        """A chain arm with the task coordinates ``task`` (a task map, or an
        :class:`~hinfnn.model.augmented.AugmentedTask` whose extra coordinates were resolved on the
        nominal chain: the same joints must be there)."""
        from ..model.augmented import AugmentedTask, chain_arm

        for c in (task.extra if isinstance(task, AugmentedTask) else ()):
            for i in _extra_joints(c):
                if i >= chain.n or (getattr(c, "name", "") in chain.joint_names and chain.joint_names[i] != c.name):
                    raise ConfigError(f"the extra coordinate {c.name!r} uses joint {i + 1} of the nominal chain, which "
                                      f"this chain ({', '.join(chain.joint_names)}) does not have in that place",
                                      key="task.extra")
        return chain_arm(chain, task)


@ARMS.register("two_link")
@section
class TwoLinkArmConfig(ArmConfig):
    """The paper's Sec. VI arm: point masses at the tips of two links in a vertical plane."""

    m1: float = param(doc="link-1 tip mass, kg", gt=0.0, le=1e4)
    m2: float = param(doc="link-2 tip mass, kg", gt=0.0, le=1e4)
    l1: float = param(doc="link-1 length, m", gt=0.0, le=100.0)
    l2: float = param(doc="link-2 length, m", gt=0.0, le=100.0)
    g: float = param(doc="gravity, m/s^2", ge=0.0, le=100.0)

    n = 2
    task_maps = False

    def build(self, task=None, key: str = "arm"):
        from ..model import TwoLinkArm

        if task is not None:
            raise ConfigError("the two_link arm has only its native task coordinates, the tip position "
                              "(x1, x2); use model = \"planar\" (or a URDF) for other coordinates", key="task.map")
        return TwoLinkArm(m1=self.m1, m2=self.m2, l1=self.l1, l2=self.l2, g=self.g)

    def reach(self) -> tuple[float, float]:
        """(innermost, outermost) distance of the tip from the base."""
        return abs(self.l1 - self.l2), self.l1 + self.l2


@ARMS.register("planar")
@section
class PlanarArmConfig(ArmConfig):
    """An n-link planar arm with a point mass at the tip of each link (like Sec. VI), in the
    vertical x–y plane of its base (gravity along −y, joint 1 turns from the x axis towards y).
    Native task coordinates: the tip (x, y) for n = 2, (x, y, φ) with the tool angle φ = Σq for
    n = 3. Built as a chain (:func:`hinfnn.model.urdf.planar_chain`: CRBA and RNEA, tested equal to
    the autodiff :class:`~hinfnn.model.arm.PlanarPointMassArm`)."""

    masses: tuple[float, ...] = param(doc="tip mass of each link, kg", gt=0.0, le=1e4)
    lengths: tuple[float, ...] = param(doc="length of each link, m", gt=0.0, le=100.0)
    g: float = param(9.81, doc="gravity, m/s^2", ge=0.0, le=100.0)
    armature: Numbers = param(0.0, doc=_ARMATURE_DOC, ge=0.0, le=1e4)

    plane = "xy"

    def validate(self, path):
        if len(self.masses) != len(self.lengths):
            raise ConfigError(f"must list one length per mass ({len(self.masses)} masses, {len(self.lengths)} "
                              "lengths)", key=f"{path}.lengths")
        if len(self.masses) < 2:
            raise ConfigError("a planar arm needs at least 2 links", key=f"{path}.masses")

    @property
    def n(self) -> int:
        return len(self.masses)

    def native_task(self, key: str = "task.map"):
        from ..model import PlanarTaskMap

        if self.n in (2, 3):
            return PlanarTaskMap("xy", with_angle=self.n == 3)
        raise ConfigError(f"a planar arm with {self.n} joints has no native task coordinates (3 at most: x, y, φ); "
                          "lock joints or use fewer links", key=key)

    def build(self, task=None, key: str = "arm"):
        task = task if task is not None else self.native_task()
        if task.dim != self.n:
            raise ConfigError(f"the planar arm has n = {self.n} joints but the task coordinates have {task.dim}: the "
                              "paper's reduced model needs a square Jacobian"
                              + ("; add extra coordinates with task.extra (a joint's name, or 'arm_angle')"
                                 if task.dim < self.n else ""), key="task.map")
        return self._chain_arm(self.joint_chain(key), task, key)

    def joint_chain(self, key: str = "arm"):
        from ..model.urdf import planar_chain

        return _with_armature(planar_chain(self.masses, self.lengths, self.g), self.armature, key)

    def reach(self) -> tuple[float, float]:
        L = sorted(self.lengths)
        return max(0.0, L[-1] - sum(L[:-1])), float(sum(L))


def urdf_path(value: str, key: str = "arm.file") -> str:
    """A ``file`` value: a file when one of that name exists (any extension), else a shipped
    robot (``"ur5"``, ``"panda"``, ``"planar/three_link"``: :func:`hinfnn.model.urdf.shipped_robots`).
    A folder, a xacro file or a name that is neither: ConfigError at ``key``."""
    from ..model.urdf import UrdfError, robot_file

    try:
        return robot_file(value)
    except UrdfError as err:
        raise ConfigError(f"{value}: {err.problem}", key=key) from None


@functools.lru_cache(maxsize=32)
def _load_chain(path, mtime, base_link, ee_link, tool_xyz, tool_rpy, gravity, locked):
    from ..model.urdf import load_urdf

    return load_urdf(path, base_link, ee_link, tool_xyz=tool_xyz, tool_rpy=tool_rpy, gravity=gravity,
                     locked=dict(locked))


@ARMS.register("urdf")
@section
class UrdfArmConfig(ArmConfig):
    """A serial arm read from a URDF file (:mod:`hinfnn.model.urdf`): the chain from ``base_link``
    to ``ee_link`` with a tool offset, full rigid-body inertias. The true arm (``plant.arm``) may
    perturb the file's inertial parameters: ``mass_scale``, ``com_shift``, ``payload_*``; the
    nominal arm is usually the file as written."""

    file: str = param(doc="URDF: a path to a URDF file (any extension; relative to the scenario file, or on the "
                          "command line to the working directory, else to the scenario file), or a robot "
                          "shipped with hinfnn when no such file exists ('ur5', 'panda', 'ur10', 'kinova', "
                          "'planar/three_link', 'planar/sec6_two_link'); xacro files must be expanded first")
    base_link: str = param(doc="link the chain starts from (fixed)")
    ee_link: str = param(doc="end-effector link")
    tool_xyz: tuple[float, ...] = param((0.0, 0.0, 0.0), doc="tool point in the end-effector link's frame, m",
                                        ge=-10.0, le=10.0)
    tool_rpy_deg: tuple[float, ...] = param((0.0, 0.0, 0.0), doc="tool frame's roll, pitch, yaw in the "
                                            "end-effector link's frame, degrees", ge=-360.0, le=360.0)
    gravity: tuple[float, ...] = param((0.0, 0.0, -9.81), doc="gravitational acceleration in the base frame, m/s^2",
                                       ge=-100.0, le=100.0)
    locked_joints: tuple[str, ...] = param((), doc="joints held fixed (e.g. one of a 7-DOF arm, so that the number "
                                           "of moving joints equals the task coordinates')")
    locked_positions: tuple[float, ...] = param((), doc="their positions (rad or m; default 0 each)",
                                                ge=-100.0, le=100.0)
    mass_scale: Numbers = param(1.0, doc="scale of each body's mass and rotational inertia (one number, or one per "
                                         "moving joint's body)", gt=0.0, le=100.0)
    com_shift: tuple[float, ...] = param((0.0, 0.0, 0.0), doc="shift of each body's centre of mass in its frame, m "
                                         "(3 numbers for every body, or 3 per body)", ge=-10.0, le=10.0)
    payload_mass: float = param(0.0, doc="a point mass at the tool, kg", ge=0.0, le=1e4)
    payload_xyz: tuple[float, ...] = param((0.0, 0.0, 0.0), doc="its position in the tool frame, m",
                                           ge=-10.0, le=10.0)
    armature: Numbers = param(0.0, doc=_ARMATURE_DOC, ge=0.0, le=1e4)

    plane = "xz"

    def validate(self, path):
        for name in ("tool_xyz", "tool_rpy_deg", "gravity", "payload_xyz"):
            _length(path, name, getattr(self, name), (3,))
        _check_locked(path, self.locked_joints, self.locked_positions)
        if len(self.com_shift) % 3:
            raise ConfigError(f"must be 3 numbers, or 3 per body, got {len(self.com_shift)}", key=f"{path}.com_shift")

    def chain(self, key: str = "arm"):
        """The (perturbed) chain; URDF problems as ConfigError at ``key.file`` (or the key named)."""
        from ..model.urdf import UrdfError

        path = urdf_path(self.file, f"{key}.file")
        try:
            mtime = Path(path).stat().st_mtime_ns
        except OSError:
            mtime = None
        locked = _locked_pairs(self.locked_joints, self.locked_positions)
        try:
            chain = _load_chain(path, mtime, self.base_link, self.ee_link, tuple(self.tool_xyz),
                                tuple(math.radians(v) for v in self.tool_rpy_deg), tuple(self.gravity), locked)
        except UrdfError as err:
            where = err.element if err.element in ("base_link", "ee_link", "locked_joints") else "file"
            element = "" if where != "file" or not err.element else f"{err.element}: "
            raise ConfigError(f"{err.file}: {element}{err.problem}", key=f"{key}.{where}") from None
        n = chain.n
        scale = per_item(self.mass_scale, n, f"{key}.mass_scale", f"one per body, n = {n}")
        shift = np.asarray(self.com_shift, float)
        if shift.size not in (3, 3 * n):
            raise ConfigError(f"must be 3 numbers, or 3 per body ({3 * n}), got {shift.size}", key=f"{key}.com_shift")
        shift = np.broadcast_to(shift.reshape(-1, 3), (n, 3))
        if np.any(scale != 1.0) or np.any(shift != 0.0) or self.payload_mass != 0.0:
            import jax.numpy as jnp

            chain = chain.perturbed(mass_scale=jnp.asarray(scale), com_shift=jnp.asarray(shift),
                                    payload_mass=self.payload_mass, payload_xyz=tuple(self.payload_xyz))
        return _with_armature(chain, self.armature, key)

    def native_task(self, key: str = "task.map"):
        raise ConfigError("a URDF arm has no native task coordinates: choose task.map = \"fitted\" (fitted to the "
                          "nominal surface), \"pose\" or \"planar\"", key=key)

    def joint_chain(self, key: str = "arm"):
        return self.chain(key)

    def build(self, task=None, key: str = "arm"):
        chain = self.chain(key)
        if task is None:
            self.native_task()
        if chain.n != task.dim:
            names = ", ".join(chain.joint_names)
            e = chain.n - task.dim
            hint = (f"add {e} extra task coordinate{'s' if e > 1 else ''} with task.extra (a joint's name, e.g. "
                    f"{chain.joint_names[min(2, chain.n - 1)]!r}, or 'arm_angle': the redundancy stays) or lock {e} "
                    f"joint{'s' if e > 1 else ''} with {key}.locked_joints" if e > 0
                    else "use task coordinates with fewer entries, fewer task.extra, or a longer chain")
            raise ConfigError(f"the chain from {self.base_link!r} to {self.ee_link!r} has n = {chain.n} moving joints "
                              f"({names}) but the task coordinates have {task.dim}: the paper's reduced model needs a "
                              f"square Jacobian; {hint}", key="task.extra" if e > 0 else "task.map")
        return self._chain_arm(chain, task, key)


# --- surfaces ------------------------------------------------------------------------------------


@section
class SurfaceConfig:
    """A constraint surface θ(x) = 0 (``kind`` chooses it). ``scaling`` is the NOMINAL
    constraint's (what λ means to the controller); the true surface has no scaling key."""

    __registry__ = SURFACES
    kind: str = param(doc="surface kind")
    scaling: Literal["paper", "unit"] = param("paper", doc="constraint scaling: 'paper' (θ = (x1 − d_G) tan δ − x2: "
                                              "λ = normal force · cos δ) or 'unit' (λ is the normal force in N)")

    def build(self):
        raise NotImplementedError


@SURFACES.register("inclined_line")
@section
class InclinedLineConfig(SurfaceConfig):
    """The surface S1 of Sec. VI: the line x2 = (x1 − d_G) tan δ in the vertical plane."""

    delta_deg: float = param(doc="slope delta, degrees", ge=-89.0, le=89.0)
    d_G: float = param(doc="horizontal offset d_G of the line, m", ge=-100.0, le=100.0)

    def build(self):
        from ..model import InclinedLine

        return InclinedLine(delta=math.radians(self.delta_deg), d_G=self.d_G, scaling=self.scaling)


_UNIT = dict(doc="constraint scaling: 'unit' (θ is the signed distance: λ is the normal force in N)")


@section
class GeometryConfig(SurfaceConfig):
    """A Cartesian surface (:mod:`hinfnn.model.geometry`): the true one is contacted at the tool
    point with its exact signed distance; the nominal one is the controller's constraint in the
    task coordinates (or what ``task.map = "fitted"`` fits them to)."""

    scaling: Literal["unit"] = param("unit", **_UNIT)
    dim = 3
    vectors = ()

    def validate(self, path):
        for name in self.vectors:
            _length(path, name, getattr(self, name), (self.dim,))


@SURFACES.register("plane")
@section
class PlaneConfig(GeometryConfig):
    """A plane in 3-D, any pose; material on the side opposite to ``normal``."""

    point: tuple[float, ...] = param(doc="a point of the plane (base frame), m", ge=-100.0, le=100.0)
    normal: tuple[float, ...] = param(doc="outward normal: out of the material (e.g. up for a table top)",
                                      ge=-1e6, le=1e6)
    tangent: tuple[float, ...] = param((1.0, 0.0, 0.0), doc="direction of the first in-plane coordinate "
                                       "(fitted coordinates; projected onto the plane)", ge=-1e6, le=1e6)
    vectors = ("point", "normal", "tangent")

    def validate(self, path):
        super().validate(path)
        n, t = np.asarray(self.normal), np.asarray(self.tangent)
        if not np.linalg.norm(n) > 0:
            raise ConfigError("must not be zero", key=f"{path}.normal")
        if not np.linalg.norm(t - (t @ n) / (n @ n) * n) > 1e-9 * np.linalg.norm(t):
            raise ConfigError("must not be parallel to the normal", key=f"{path}.tangent")

    def build(self):
        from ..model.geometry import Plane

        return Plane.build(self.point, self.normal, self.tangent)


@SURFACES.register("sphere")
@section
class SphereConfig(GeometryConfig):
    """A ball (material inside). Fitted coordinates: longitude and latitude (as arc lengths) about
    ``pole`` from ``meridian``; singular at the poles."""

    centre: tuple[float, ...] = param(doc="centre (base frame), m", ge=-100.0, le=100.0)
    radius: float = param(doc="radius, m", gt=0.0, le=100.0)
    pole: tuple[float, ...] = param((0.0, 1.0, 0.0), doc="polar axis of the fitted coordinates (keep the path "
                                    "away from it)", ge=-1e6, le=1e6)
    meridian: tuple[float, ...] = param((0.0, 0.0, 1.0), doc="direction of zero longitude and latitude (s = 0)",
                                        ge=-1e6, le=1e6)
    vectors = ("centre", "pole", "meridian")

    def validate(self, path):
        super().validate(path)
        _not_parallel(path, "meridian", self.meridian, self.pole, other="pole")

    def build(self):
        from ..model.geometry import Sphere

        return Sphere.build(self.centre, self.radius, self.pole, self.meridian)


def _not_parallel(path, name, a, b, other="axis"):
    """``name`` (vector a) must be nonzero and not parallel to the key ``other`` (vector b)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if not np.linalg.norm(b) > 0:
        raise ConfigError("must not be zero", key=f"{path}.{other}")
    if not np.linalg.norm(a) > 0:
        raise ConfigError("must not be zero", key=f"{path}.{name}")
    if np.linalg.norm(np.cross(a, b)) <= 1e-9 * np.linalg.norm(a) * np.linalg.norm(b):
        raise ConfigError(f"{_shown(a)} must not be parallel to the {other} {_shown(b)} ({path}.{other})",
                          key=f"{path}.{name}")


@SURFACES.register("cylinder")
@section
class CylinderConfig(GeometryConfig):
    """A solid cylinder (material inside). Fitted coordinates: axial position and arc length about
    the axis from ``reference``."""

    point: tuple[float, ...] = param(doc="a point of the axis (base frame), m", ge=-100.0, le=100.0)
    axis: tuple[float, ...] = param(doc="axis direction", ge=-1e6, le=1e6)
    radius: float = param(doc="radius, m", gt=0.0, le=100.0)
    reference: tuple[float, ...] = param((0.0, 0.0, 1.0), doc="direction of zero angle (fitted coordinates)",
                                         ge=-1e6, le=1e6)
    vectors = ("point", "axis", "reference")

    def validate(self, path):
        super().validate(path)
        _not_parallel(path, "reference", self.reference, self.axis)

    def build(self):
        from ..model.geometry import Cylinder

        return Cylinder.build(self.point, self.axis, self.radius, self.reference)


@SURFACES.register("circle")
@section
class CircleConfig(GeometryConfig):
    """A disc in a planar arm's plane (a drum seen end-on; material inside). Fitted (polar)
    coordinates: arc length from the plane's first axis; they jump opposite ``angle_ref_deg``."""

    centre: tuple[float, ...] = param(doc="centre in the arm's plane, m", ge=-100.0, le=100.0)
    radius: float = param(doc="radius, m", gt=0.0, le=100.0)
    angle_ref_deg: float = param(0.0, doc="polar angle at the middle of the working range, degrees (the "
                                 "fitted coordinate jumps 180 degrees away)", ge=-360.0, le=360.0)
    dim = 2
    vectors = ("centre",)

    def build(self):
        from ..model.geometry import Circle

        return Circle.build(self.centre, self.radius, math.radians(self.angle_ref_deg))


@SURFACES.register("line")
@section
class LineConfig(GeometryConfig):
    """A straight line in a planar arm's plane; material on the side opposite to ``normal``."""

    point: tuple[float, ...] = param(doc="a point of the line, m", ge=-100.0, le=100.0)
    normal: tuple[float, ...] = param(doc="outward normal (out of the material)", ge=-1e6, le=1e6)
    dim = 2
    vectors = ("point", "normal")

    def validate(self, path):
        super().validate(path)
        if not np.linalg.norm(self.normal) > 0:
            raise ConfigError("must not be zero", key=f"{path}.normal")

    def build(self):
        from ..model.geometry import Line

        return Line.build(self.point, self.normal)


@SURFACES.register("sine")
@section
class SineConfig(GeometryConfig):
    """A wavy floor b = offset + amplitude sin(2π a / wavelength + phase) in a planar arm's plane
    (coordinates (a, b)), material below. Not fittable: use task.map = "planar"."""

    amplitude: float = param(doc="amplitude, m", ge=-10.0, le=10.0)
    wavelength: float = param(doc="wavelength, m", gt=0.0, le=1e3)
    phase_deg: float = param(0.0, doc="phase, degrees", ge=-360.0, le=360.0)
    offset: float = param(0.0, doc="mean height, m", ge=-100.0, le=100.0)
    dim = 2

    def build(self):
        import jax.numpy as jnp

        from ..model.geometry import SineProfile

        return SineProfile(amplitude=jnp.asarray(self.amplitude), wavelength=jnp.asarray(self.wavelength),
                           phase=jnp.asarray(math.radians(self.phase_deg)), offset=jnp.asarray(self.offset))


@SURFACES.register("python")
@section
class PythonSurfaceConfig(GeometryConfig):
    """θ(p, params) from your own Python: ``function = "package.module:name"`` (positive inside
    the material, smooth). The plant's penetration is the exact distance to {θ = 0}."""

    scaling: Literal["user"] = param("user", doc="constraint scaling: 'user' (λ in the units of θ's gradient)")
    function: str = param(doc="'module:name' of a function theta(p, params) -> scalar (importable)")
    params: tuple[float, ...] = param((0.0,), doc="its parameters", ge=-1e6, le=1e6)
    space: int = param(3, doc="dimension of p: 3 (spatial arms) or 2 (a planar arm's plane)", ge=2, le=3)

    @property
    def dim(self):  # type: ignore[override]
        return self.space

    def function_object(self, key="surface"):
        import importlib

        module, _, name = self.function.partition(":")
        if not module or not name:
            raise ConfigError(f"must look like 'module:name', got {self.function!r}", key=f"{key}.function")
        try:
            fn = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError) as err:
            raise ConfigError(f"cannot import {self.function!r}: {err}", key=f"{key}.function") from None
        if not callable(fn):
            raise ConfigError(f"{self.function!r} is not a function", key=f"{key}.function")
        return fn

    def build(self):
        import jax.numpy as jnp

        from ..model.geometry import UserSurface

        return UserSurface(params=jnp.asarray(self.params, float), theta_fn=self.function_object(), dim=self.space)


# --- the true plant ---------------------------------------------------------------------------------


@section
class ContactConfig:
    stiffness: float = param(doc="contact stiffness k, N/m", gt=0.0, le=1e10)
    damping: float = param(doc="contact damping c, N s/m", ge=0.0, le=1e8)

    def build(self):
        from ..plant import PenaltyContact

        return PenaltyContact(stiffness=self.stiffness, damping=self.damping)


@section
class DisturbanceConfig:
    amplitude: tuple[float, ...] = param(doc="square-wave amplitude per joint, N m", ge=-1e6, le=1e6)
    period: float = param(doc="square-wave period, s", gt=0.0, le=1e6)
    phase: float = param(doc="square-wave phase (time of the first + edge), s", ge=-1e6, le=1e6)

    def build(self):
        import jax.numpy as jnp

        from ..plant import SquareWave

        return SquareWave(amplitude=jnp.asarray(self.amplitude, float), period=self.period, phase=self.phase)


@section
class FrictionConfig:
    """Coulomb + viscous friction of the tool along the true surface (the controller does not model
    it); off by default."""

    coulomb: float = param(0.0, doc="Coulomb friction coefficient mu (tangential force mu f_n, smoothed)",
                           ge=0.0, le=10.0)
    viscous: float = param(0.0, doc="viscous friction while in contact, N s/m", ge=0.0, le=1e6)
    v_smooth: float = param(1e-3, doc="Coulomb smoothing speed v_s: mu f_n tanh(sliding speed / v_s), m/s", gt=0.0, le=10.0)

    @property
    def active(self) -> bool:
        return self.coulomb > 0 or self.viscous > 0

    def build(self):
        from ..plant import Friction

        return Friction(coulomb=self.coulomb, viscous=self.viscous, v_smooth=self.v_smooth) if self.active else None


@section
class SensorConfig:
    """The robot's sensor between the truth and the controller (:mod:`hinfnn.plant.instruments`):
    white noise, a bias, the sensor's own low-pass and a transport delay, once per control sample.
    Off by default: an ideal sensor (the paper's)."""

    force_noise: float = param(0.0, doc="standard deviation of the white noise on each axis of the sensed tool force, "
                               "one draw per control sample, N", ge=0.0, le=1e6)
    force_bias: tuple[float, ...] = param((), doc="constant bias of the sensed tool force in the base frame, N: 3 "
                                          "values (2 for a planar arm, in its plane); empty: none", ge=-1e6, le=1e6)
    delay: int = param(0, doc="transport delay of the joint angles, rates and force, whole control samples", ge=0,
                       le=1000)
    bandwidth: Literal["none"] | float = param("none", doc="the force sensor's own bandwidth: a first-order low-pass "
                                               "at this cutoff, Hz; \"none\": ideal", gt=0.0, le=1e9)
    q_noise: Numbers = param(0.0, doc="standard deviation of the white noise on each joint angle, rad (m for a "
                             "prismatic joint): a number or one per joint", ge=0.0, le=10.0)
    qd_noise: Numbers = param(0.0, doc="standard deviation of the white noise on each joint rate, rad/s: a number or "
                              "one per joint", ge=0.0, le=1e3)
    seed: int = param(0, doc="seed of the noise (the same seed: the same noise; a batch member or a sweep's draw "
                      "folds in its own index)", ge=0, le=2**31 - 1)

    @property
    def ideal(self) -> bool:
        return (self.force_noise == 0 and not any(self.force_bias) and self.delay == 0 and self.bandwidth == "none"
                and not np.any(self.q_noise) and not np.any(self.qd_noise))

    def validate(self, path):
        _length(path, "force_bias", self.force_bias, (0, 2, 3))

    def build(self, n: int, force_dim: int, path: str = "plant.sensor"):
        """The :class:`~hinfnn.plant.instruments.Sensor` of a plant of n joints whose force has
        ``force_dim`` components (None: ideal)."""
        if self.ideal:
            return None
        from ..plant.instruments import Sensor

        bias = np.zeros(force_dim)
        if self.force_bias:
            if len(self.force_bias) != force_dim:
                raise ConfigError(f"must be a list of {force_dim} numbers (the force of this arm has {force_dim} "
                                  f"components, base frame), got {len(self.force_bias)}: {_shown(self.force_bias)}",
                                  key=f"{path}.force_bias")
            bias = np.asarray(self.force_bias, dtype=float)
        return Sensor.make(self.seed, force_noise=self.force_noise, force_bias=bias,
                           q_noise=per_item(self.q_noise, n, f"{path}.q_noise", "one per joint"),
                           qd_noise=per_item(self.qd_noise, n, f"{path}.qd_noise", "one per joint"),
                           bandwidth=math.inf if self.bandwidth == "none" else self.bandwidth, delay=self.delay)


@section
class ActuatorConfig:
    """The robot's motors (:mod:`hinfnn.plant.instruments`): torque limits, a torque rate limit, and
    joint friction the controller does not know. Off by default: ideal motors (the paper's)."""

    torque_limit: Literal["none", "urdf"] | Numbers = param("none", doc="the commanded torque saturates at this |tau_i|, "
                                                            "N m: \"urdf\" (the arm's URDF effort limits), a number, "
                                                            "one per joint, or \"none\"", gt=0.0, le=1e9)
    torque_rate_limit: Literal["none"] | Numbers = param("none", doc="largest change of the applied torque, N m/s (from "
                                                         "one control sample to the next): a number, one per joint, or "
                                                         "\"none\"", gt=0.0, le=1e12)
    friction_viscous: Numbers = param(0.0, doc="viscous joint friction b_v (unknown to the controller), N m s/rad: a "
                                      "number or one per joint", ge=0.0, le=1e6)
    friction_coulomb: Numbers = param(0.0, doc="Coulomb joint friction f_c (unknown to the controller), N m: a number "
                                      "or one per joint", ge=0.0, le=1e6)
    friction_v_smooth: float = param(0.01, doc="Coulomb smoothing speed: f_c tanh(joint rate / this), rad/s", gt=0.0,
                                     le=100.0)

    @property
    def ideal(self) -> bool:
        return (self.torque_limit == "none" and self.torque_rate_limit == "none" and not np.any(self.friction_viscous)
                and not np.any(self.friction_coulomb))

    def build(self, arm, n: int, path: str = "plant.actuator"):
        """The :class:`~hinfnn.plant.instruments.Actuator` of the true ``arm`` of n joints (None:
        ideal)."""
        if self.ideal:
            return None
        from ..plant.instruments import Actuator

        if self.torque_limit == "urdf":
            chain = getattr(arm, "chain", None)
            limit = None if chain is None else np.asarray(chain.effort_limit, dtype=float)
            if limit is None or not np.all(np.isfinite(limit) & (limit > 0)):
                raise ConfigError("\"urdf\" needs the arm's effort limits on every joint, and this arm has "
                                  f"{'none (not a URDF chain)' if limit is None else _shown(limit)}: give the limits "
                                  "as numbers", key=f"{path}.torque_limit")
        elif self.torque_limit == "none":
            limit = np.full(n, np.inf)
        else:
            limit = per_item(self.torque_limit, n, f"{path}.torque_limit", "one per joint")
        rate = (np.full(n, np.inf) if self.torque_rate_limit == "none" else
                per_item(self.torque_rate_limit, n, f"{path}.torque_rate_limit", "one per joint"))
        return Actuator(torque_limit=limit, rate_limit=rate,
                        viscous=per_item(self.friction_viscous, n, f"{path}.friction_viscous", "one per joint"),
                        coulomb=per_item(self.friction_coulomb, n, f"{path}.friction_coulomb", "one per joint"),
                        v_smooth=np.asarray(self.friction_v_smooth, dtype=float))


@section
class PlantConfig:
    """The truth: what the simulated arm and surface really are (``engine`` chooses the physics)."""

    __registry__ = PLANTS
    #: An engine that steps itself (MuJoCo) runs the controller at its own step at least: the
    #: controller is then designed for sampled control (``Scenario.control_period``).
    discrete: ClassVar[bool] = False
    engine: str = param(doc="physics engine of the true plant")
    arm: ArmConfig = param(doc="the true arm")
    surface: SurfaceConfig = param(doc="the true surface", exclude=("scaling",))
    contact: ContactConfig = param(doc="contact law")
    disturbance: DisturbanceConfig = param(doc="joint disturbance")
    friction: FrictionConfig = param(doc="friction of the tool along the surface")
    sensor: SensorConfig = param(SensorConfig(), doc="the robot's sensor (noise, bias, delay, bandwidth)")
    actuator: ActuatorConfig = param(ActuatorConfig(), doc="the robot's motors (torque limits, joint friction)")

    def build(self, task=None, **context):
        """The plant object. ``task``: the task map the arm is built with (None: the arm's own
        coordinates); ``context``: ``dt`` (the simulation step) and ``control_period`` (None for
        continuous control), for engines that step themselves."""
        raise NotImplementedError

    def instruments(self, plant) -> dict:
        """``{"sensor": ..., "actuator": ...}`` of ``plant`` (the true arm's joints, the size of its
        sensed force) as this section declares them (None: ideal)."""
        import jax
        import jax.numpy as jnp

        n = int(plant.n)
        sensor = None
        if not self.sensor.ideal:
            force = jax.eval_shape(lambda q: plant.sense(0.0, plant.initial_state(q))[0].force,
                                   jax.ShapeDtypeStruct((n,), jnp.float64))
            sensor = self.sensor.build(n, int(force.shape[-1]))
        return {"sensor": sensor, "actuator": self.actuator.build(plant.arm, n)}


@PLANTS.register("hinfnn")
@section
class RigidPlantConfig(PlantConfig):
    """hinfnn's own plant: rigid-body arm, penalty contact on the true surface."""

    def build(self, task=None, **context):
        from ..plant import RigidBodyPlant

        plant = RigidBodyPlant(arm=self.arm.build(task, key="plant.arm"), surface=self.surface.build(),
                               contact=self.contact.build(), disturbance=self.disturbance.build(),
                               friction=self.friction.build())
        if self.sensor.ideal and self.actuator.ideal:
            return plant
        return dataclasses.replace(plant, **self.instruments(plant))


def mjcf_path(value: str, key: str = "plant.mjcf.file") -> str:
    """A ``plant.mjcf.file`` value: a file when one of that name exists (any extension), else an
    MJCF shipped with hinfnn (``"ur5e"``: :func:`hinfnn.model.urdf.shipped_robots` with suffix
    ``.xml``); a folder or a name that is neither: ConfigError at ``key`` listing the shipped ones."""
    from ..model.urdf import UrdfError, robot_file

    try:
        return robot_file(value, ".xml")
    except UrdfError as err:
        raise ConfigError(f"{value}: {err.problem}", key=key) from None


@section
class MjcfConfig:
    """A user's MJCF as the true arm (``file`` empty: the MJCF is generated from ``plant.arm``)."""

    file: str = param("", doc="MJCF of the true arm: a path to an MJCF file (any extension; relative to the scenario "
                              "file, or on the command line to the working directory, else to the scenario file), "
                              "or a model shipped with hinfnn when no such file exists ('ur5e': MuJoCo Menagerie's "
                              "UR5e, 'fr3'); empty: generated from plant.arm")
    joints: tuple[str, ...] = param((), doc="the arm's joints in the MJCF, from the base to the tool (all of its degrees "
                                            "of freedom; default: the joint names of plant.arm)")
    tool_site: str = param("", doc="the MJCF site the tool hangs from (e.g. the flange)")
    tool_xyz: tuple[float, ...] = param((0.0, 0.0, 0.0), doc="the tool point in the site's frame, m", ge=-10.0,
                                        le=10.0)
    tool_rpy_deg: tuple[float, ...] = param((0.0, 0.0, 0.0), doc="the tool frame's roll, pitch, yaw in the site's "
                                            "frame, degrees", ge=-360.0, le=360.0)
    locked_joints: tuple[str, ...] = param((), doc="joints of the MJCF held fixed (removed from the model, each body "
                                                   "welded at its position), e.g. one of a 7-DOF arm")
    locked_positions: tuple[float, ...] = param((), doc="their positions (rad or m, the MJCF's joint values; default 0 "
                                                        "each)", ge=-100.0, le=100.0)

    def validate(self, path):
        for name in ("tool_xyz", "tool_rpy_deg"):
            _length(path, name, getattr(self, name), (3,))
        if not self.file:  # generated from plant.arm: a key of the user's file would be ignored
            default = MjcfConfig()
            for name in ("joints", "tool_site", "tool_xyz", "tool_rpy_deg", "locked_joints", "locked_positions"):
                if tuple(np.atleast_1d(getattr(self, name))) != tuple(np.atleast_1d(getattr(default, name))):
                    raise ConfigError(f"applies to a user's MJCF only, got {getattr(self, name)!r} with {path}.file "
                                      "empty (the MJCF is generated from plant.arm: its tool is plant.arm.tool_xyz, "
                                      f"its joints plant.arm's); set {path}.file or leave the key at its default",
                                      key=f"{path}.{name}")
            return
        if not self.tool_site:
            raise ConfigError("name the MJCF site the tool hangs from", key=f"{path}.tool_site")
        _check_locked(path, self.locked_joints, self.locked_positions)
        both = sorted(set(self.locked_joints) & set(self.joints))
        if both:
            raise ConfigError(f"{both[0]!r} is both locked and listed in {path}.joints; a joint is one or the other",
                              key=f"{path}.locked_joints")

    @property
    def locked(self) -> tuple:
        """(joint name, position) of each locked joint."""
        return _locked_pairs(self.locked_joints, self.locked_positions)


@PLANTS.register("mujoco")
@section
class MujocoPlantConfig(PlantConfig):
    """MuJoCo as the true plant (optional extra ``hinfnn[mujoco]``; docs/mujoco.md): the true arm
    (generated from ``plant.arm``, or a user's MJCF: ``plant.mjcf``) and surface as a MuJoCo model,
    the contact converted from N/m and N·s/m, MuJoCo's Coulomb friction and hinfnn's viscous
    friction at the tool point; one plant step (one call into MuJoCo) per simulation dt, in MuJoCo
    timesteps, with the torque held (sampled-data control)."""

    discrete: ClassVar[bool] = True
    integrator: Literal["RK4", "implicit", "implicitfast", "Euler"] = param(
        "RK4", doc="MuJoCo's integrator (RK4 or implicit are accurate at the contact's frequency)")
    callback: Literal["host", "pure_callback"] = param(
        "host", doc="how the compiled loop calls MuJoCo ('pure_callback': JAX's public API, ~4x slower)")
    timestep: Literal["auto", "dt"] | float = param("auto", doc="MuJoCo's timestep, s: it must divide simulation.dt, "
                                                    "the plant's step (one call into MuJoCo); \"auto\": the largest that "
                                                    "divides dt and is at most 0.1 ms; \"dt\": one MuJoCo step per "
                                                    "simulation step", gt=0.0, le=0.1)
    friction_damping: float = param(1000.0, doc="MuJoCo's friction below the Coulomb cone: the tangential force is "
                                                "this damping times the sliding speed, up to mu f_n, N s/m (the built-in "
                                                "plant's mu f_n / v_smooth)", gt=0.0, le=1e7)
    mjcf: MjcfConfig = param(MjcfConfig(), doc="a user's MJCF as the true arm")

    def validate(self, path):
        from ..plant.mujoco.scene import SUPPORTED_SURFACES

        kind = self.surface.kind
        if kind not in SUPPORTED_SURFACES:
            raise ConfigError(f"MuJoCo has no primitive for a {kind!r} surface; the MuJoCo plant models "
                              f"{', '.join(repr(k) for k in SUPPORTED_SURFACES)} (use plant.engine = \"hinfnn\" for "
                              f"{kind!r})", key=f"{path}.surface.kind")
        two_link = self.arm.model == "two_link"
        if two_link != (kind == "inclined_line"):
            what = ("the two_link arm's MuJoCo model has the inclined_line only (its task space is the tip position)"
                    if two_link else "the inclined_line is the two_link arm's (task space); use a plane or a line")
            raise ConfigError(f"{what}, got a {self.arm.model!r} arm on a {kind!r}", key=f"{path}.surface.kind")
        if two_link and self.friction.active:
            raise ConfigError("the two_link arm's MuJoCo model is frictionless; set plant.friction's coefficients to 0 "
                              "or use plant.engine = \"hinfnn\"", key=f"{path}.friction.coulomb")
        if self.mjcf.file:
            if self.arm.model not in ("urdf",):
                raise ConfigError(f"a user's MJCF needs task coordinates of a spatial arm: give plant.arm as the "
                                  f"nominal's urdf arm (got {self.arm.model!r})", key=f"{path}.arm.model")
            if any(c != 0.0 for c in self.arm.com_shift):
                raise ConfigError(f"has no effect on a user's MJCF (plant.mjcf.file = {self.mjcf.file!r}): its bodies' "
                                  "centres of mass are the file's (mass_scale, payload_mass and payload_xyz apply to "
                                  "it); edit the file, or leave the key at its default", key=f"{path}.arm.com_shift")

    def _same_armature(self, model, joints) -> None:
        """A user's MJCF simulates its own joints' armature: a nonzero ``plant.arm.armature`` beside it
        states the same truth for the built-in engine (``plant.engine = "hinfnn"``, which reads
        ``plant.arm``) and must equal the compiled ``model``'s, joint by joint over the plant's
        ``joints`` (ConfigError otherwise)."""
        from ..plant.mujoco.scene import joint_armature

        ours = np.atleast_1d(np.asarray(self.arm.armature, dtype=float))
        if not np.any(ours):
            return
        theirs = joint_armature(model, joints)
        if ours.size not in (1, theirs.size) or not np.allclose(np.broadcast_to(ours, theirs.shape), theirs,
                                                                rtol=1e-12, atol=0.0):
            raise ConfigError(f"must equal the armature of the MJCF's own joints (plant.mjcf.file = {self.mjcf.file!r}: "
                              f"{', '.join(f'{n} {a:g}' for n, a in zip(joints, theirs))} kg m^2), got "
                              f"{self.arm.armature!r}: MuJoCo simulates the file's, and this key states the same truth "
                              "for the built-in engine (plant.engine = \"hinfnn\"); edit the file, or leave the key "
                              "at its default (0)", key="plant.arm.armature")

    #: The longest MuJoCo step ``timestep = "auto"`` takes, s (RK4 resolves a 1e6 N/m contact on a
    #: 1 kg effective mass at it: ω h = 0.1).
    AUTO_TIMESTEP = 1e-4

    def mujoco_timestep(self, dt: float) -> float:
        """MuJoCo's timestep for the simulation step dt (``timestep``: a number, "dt", or "auto": dt
        divided into the fewest equal steps of at most :data:`AUTO_TIMESTEP`)."""
        if self.timestep == "dt":
            return float(dt)
        if self.timestep == "auto":
            return float(dt) / max(1, math.ceil(float(dt) / self.AUTO_TIMESTEP * (1 - 1e-9)))
        return float(self.timestep)

    def build(self, task=None, *, dt=1e-4, control_period=None, **context):
        from ..plant.mujoco import MujocoPlant, require_mujoco

        require_mujoco()
        ts = self.mujoco_timestep(dt)
        common = dict(surface=self.surface.build(), contact=self.contact.build(), disturbance=self.disturbance.build(),
                      control_period=dt, timestep=ts, integrator=self.integrator, callback=self.callback,
                      friction=self.friction.build(), friction_damping=self.friction_damping)
        if self.mjcf.file:
            nominal = self.arm.chain("plant.arm")  # the user's URDF of the arm: joint names, torque limits
            joints = self.mjcf.joints or tuple(nominal.joint_names)
            effort = np.asarray(nominal.effort_limit) if nominal.n == len(joints) else None
            a = self.arm
            plant = MujocoPlant.from_mjcf(mjcf_path(self.mjcf.file), joints=joints, tool_site=self.mjcf.tool_site,
                                          tool_xyz=self.mjcf.tool_xyz, tool_rot=_rpy(self.mjcf.tool_rpy_deg),
                                          task=task, locked=self.mjcf.locked, mass_scale=a.mass_scale,
                                          payload_mass=a.payload_mass, payload_xyz=a.payload_xyz, effort_limit=effort,
                                          **common)
            self._same_armature(plant.model, joints)
        else:
            plant = MujocoPlant.from_models(self.arm.build(task, key="plant.arm"), **common)
        if self.sensor.ideal and self.actuator.ideal:
            return plant
        return plant.replace(**self.instruments(plant))


@section
class NominalConfig:
    """What the controller is told: the nominal model."""

    arm: ArmConfig = param(doc="the nominal arm")
    surface: SurfaceConfig = param(doc="the nominal surface")


# --- task coordinates ----------------------------------------------------------------------------

_PLANES = Literal["auto", "xy", "xz", "yz", "yx", "zx", "zy"]
_AXIS = Literal["x", "y", "z"]


def _rpy(deg):
    from ..model.urdf import rpy_matrix

    return rpy_matrix(np.radians(np.asarray(deg, float)))


@section
class TaskConfig:
    """The task coordinates x = h(q) (``map`` chooses them). The controller works in them, the
    reference is given in them and the force sensor's F is expressed in them; the last one is the
    coordinate the surface constrains (k = 1), the first n − 1 are the motion coordinates u1.
    ``build(arm, geometry)`` returns the task map for the arm section and the nominal surface."""

    __registry__ = TASKS
    map: str = param(doc="task coordinates")
    extra: tuple[str, ...] = param((), doc="extra motion coordinates for a redundant arm (more joints than task "
                                   "coordinates), put before the constrained one: a joint's name (its angle, rad, or "
                                   "position, m) or 'arm_angle' (the elbow's swivel angle psi about the shoulder-wrist "
                                   "line); they hold their start values unless the reference lists them "
                                   "(docs/arms-and-surfaces.md)")
    arm_angle_joints: tuple[str, ...] = param((), doc="shoulder, elbow and wrist joints whose origins define "
                                              "'arm_angle' (default: the 2nd, 4th and 6th joint of the chain)")
    arm_angle_reference: tuple[float, ...] = param((0.0, 0.0, 1.0), doc="direction (base frame) of the half-plane "
                                                   "where the arm angle is 0 (default: up)", ge=-1e6, le=1e6)
    arm_angle_ref_deg: float = param(0.0, doc="arm angle at the middle of the working range, degrees (it jumps "
                                     "180 degrees away)", ge=-360.0, le=360.0)

    fitted = False

    def build(self, arm, geometry):
        raise NotImplementedError

    def validate(self, path):
        _length(path, "arm_angle_reference", self.arm_angle_reference, (3,))
        if not np.linalg.norm(self.arm_angle_reference) > 0:
            raise ConfigError("must not be zero", key=f"{path}.arm_angle_reference")
        if len(set(self.extra)) != len(self.extra):
            raise ConfigError(f"lists a coordinate twice: {list(self.extra)}", key=f"{path}.extra")
        if self.arm_angle_joints and len(self.arm_angle_joints) != 3:
            raise ConfigError(f"must name 3 joints (shoulder, elbow, wrist), got {list(self.arm_angle_joints)}",
                              key=f"{path}.arm_angle_joints")

    def extra_coordinates(self, chain) -> tuple:
        """The extra coordinates (:class:`~hinfnn.model.taskmap.JointCoordinate`,
        :class:`~hinfnn.model.taskmap.ArmAngle`) resolved on ``chain`` (the nominal arm's)."""
        import jax.numpy as jnp

        from ..model.taskmap import ArmAngle, JointCoordinate

        if not self.extra:
            return ()
        if chain is None:
            raise ConfigError("the two_link arm has no extra coordinates (n = 2 = its task coordinates); remove "
                              "task.extra", key="task.extra")
        names = list(chain.joint_names)

        def index(name, key):
            if name not in names:
                import difflib

                close = difflib.get_close_matches(name, names, n=1)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                raise ConfigError(f"{name!r} is not a moving joint of the chain (joints: {', '.join(names)}; or "
                                  f"'arm_angle'){hint}", key=key)
            return names.index(name)

        out = []
        for item in self.extra:
            if item == "arm_angle":
                if self.arm_angle_joints:
                    idx = [index(n, "task.arm_angle_joints") for n in self.arm_angle_joints]
                elif chain.n >= 6:
                    idx = [1, 3, 5]
                else:
                    raise ConfigError(f"'arm_angle' needs shoulder, elbow and wrist joints: name them with "
                                      f"task.arm_angle_joints (the chain has {chain.n} joints)", key="task.extra")
                if not idx[0] < idx[1] < idx[2]:
                    raise ConfigError(f"must be in chain order (shoulder, elbow, wrist), got "
                                      f"{[names[i] for i in idx]}", key="task.arm_angle_joints")
                out.append(ArmAngle(shoulder=idx[0], elbow=idx[1], wrist=idx[2],
                                    reference=jnp.asarray(self.arm_angle_reference, float)
                                    / float(np.linalg.norm(self.arm_angle_reference)),
                                    psi_ref=jnp.asarray(math.radians(self.arm_angle_ref_deg))))
            else:
                i = index(item, "task.extra")
                out.append(JointCoordinate(index=i, name=item, unit="m" if chain.joint_types[i] == "prismatic"
                                           else "rad"))
        return tuple(out)

    def _plane(self, arm, plane):
        if plane != "auto":
            return plane
        if arm.plane is None:
            raise ConfigError(f"the {arm.model!r} arm is not planar; use task.map = \"pose\" or \"fitted\"",
                              key="task.plane")
        return arm.plane


@TASKS.register("native")
@section
class NativeTaskConfig(TaskConfig):
    """The arm's own coordinates: the tip position of the two_link arm (Sec. VI) and of a 2-link
    planar arm, (x, y, φ) of a 3-link planar arm; a URDF arm has none."""

    def build(self, arm, geometry):
        return arm.native_task()


@TASKS.register("planar")
@section
class PlanarTaskConfig(TaskConfig):
    """Cartesian coordinates in a planar arm's plane: (a, b[, φ]), φ the tool axis's angle from
    the plane's first axis (jumps by 2π opposite phi_ref_deg)."""

    plane: _PLANES = param("auto", doc="the arm's plane as two axes of its base frame, e.g. 'xz' ('auto': 'xy' "
                                       "for a planar arm, 'xz' for a URDF)")
    with_angle: bool = param(True, doc="add the tool angle phi as the third coordinate (x = (a, b, phi))")
    tool_axis: _AXIS = param("x", doc="the tool frame's axis whose angle is phi")
    phi_ref_deg: float = param(0.0, doc="tool angle at the middle of the working range, degrees", ge=-360.0,
                               le=360.0)

    def build(self, arm, geometry):
        from ..model import PlanarTaskMap

        return PlanarTaskMap(self._plane(arm, self.plane), with_angle=self.with_angle, tool_axis=self.tool_axis,
                             phi_ref=math.radians(self.phi_ref_deg))


@TASKS.register("pose")
@section
class PoseTaskConfig(TaskConfig):
    """Tool position in a task frame and the rotation vector of R_refᵀR (6-DOF arms), with the
    position coordinate ``constrained`` moved last: x = (the other two, r_x, r_y, r_z, that one).
    Singular where R_refᵀR is a half turn."""

    frame_xyz: tuple[float, ...] = param((0.0, 0.0, 0.0), doc="task frame origin (base frame), m", ge=-100.0,
                                         le=100.0)
    frame_rpy_deg: tuple[float, ...] = param((0.0, 0.0, 0.0), doc="task frame's roll, pitch, yaw, degrees",
                                             ge=-360.0, le=360.0)
    ref_rpy_deg: tuple[float, ...] = param((180.0, 0.0, 0.0), doc="reference orientation R_ref (roll, pitch, yaw "
                                           "in the base frame, degrees): r = 0 there (default: tool z down)",
                                           ge=-360.0, le=360.0)
    constrained: _AXIS = param("z", doc="task-frame axis of the position coordinate put last (the one the surface "
                                        "constrains)")

    def validate(self, path):
        super().validate(path)
        for name in ("frame_xyz", "frame_rpy_deg", "ref_rpy_deg"):
            _length(path, name, getattr(self, name), (3,))

    def build(self, arm, geometry):
        import jax.numpy as jnp

        from ..model import PoseTaskMap

        c = "xyz".index(self.constrained)
        order = tuple(i for i in range(3) if i != c) + (3, 4, 5, c)
        return PoseTaskMap(R_ref=jnp.asarray(_rpy(self.ref_rpy_deg)), frame_rot=jnp.asarray(_rpy(self.frame_rpy_deg)),
                           frame_pos=jnp.asarray(self.frame_xyz, float), order=order)


@TASKS.register("fitted")
@section
class FittedTaskConfig(TaskConfig):
    """Coordinates fitted to the NOMINAL surface (plane, sphere, cylinder; circle, line): surface
    coordinates (arc lengths, m), the tool orientation relative to the surface frame there (3-D:
    rotation vector, r = 0 with the tool z axis along the inward normal, turned by tool_rpy_deg;
    2-D: the angle phi_rel from the inward normal to the tool axis), and the signed distance d last.
    The constraint is then θ̂ = d with Π = 1 everywhere, and λ is the normal force in N."""

    tool_rpy_deg: tuple[float, ...] = param((0.0, 0.0, 0.0), doc="3-D: the tool orientation at r = 0 relative to "
                                            "the surface frame (roll, pitch, yaw, degrees)", ge=-360.0, le=360.0)
    orientation: bool = param(True, doc="include the tool orientation (false: x = (s, d) for arms with n = dim)")
    plane: _PLANES = param("auto", doc="2-D: the arm's plane ('auto': 'xy' for a planar arm, 'xz' for a URDF)")
    tool_axis: _AXIS = param("x", doc="2-D: the tool frame's axis pressed along the normal (phi_rel = 0)")

    fitted = True

    def validate(self, path):
        super().validate(path)
        _length(path, "tool_rpy_deg", self.tool_rpy_deg, (3,))

    def build(self, arm, geometry):
        import jax.numpy as jnp

        from ..model.geometry import Geometry
        from ..model.taskmap import FittedTaskMap

        if not isinstance(geometry, Geometry) or not getattr(geometry, "fittable", False):
            kind = type(geometry).__name__
            raise ConfigError(f"fitted coordinates need a nominal surface of kind plane, sphere, cylinder, circle or "
                              f"line (got {kind}); use task.map = \"planar\" or \"pose\"", key="task.map")
        if geometry.dim == 2:
            return FittedTaskMap(geometry=geometry, plane=self._plane(arm, self.plane), tool_axis=self.tool_axis,
                                 orientation=self.orientation)
        R_off = None if not any(self.tool_rpy_deg) else jnp.asarray(_rpy(self.tool_rpy_deg))
        return FittedTaskMap(geometry=geometry, R_off=R_off, orientation=self.orientation)


# --- the controller -------------------------------------------------------------------------------


@section
class GainsConfig:
    rho: float = param(doc="attenuation level rho", gt=0.0, le=1e6)
    mu_z: float = param(doc="mu_z of eq. (27)", gt=0.0, le=1e8)
    K_p: Numbers = param(doc="position gain K_p (a number, or one per motion coordinate)", gt=0.0, le=1e8)
    K_v: Numbers = param(doc="velocity gain K_v (a number, or one per motion coordinate)", gt=0.0, le=1e8)
    alpha_lam: float = param(doc="force weight alpha_lam", gt=0.0, le=1e8)
    alpha_z: float = param(doc="alpha_z of eq. (27)", gt=0.0, le=1e8)
    beta_lam: Literal["min"] | float = param(doc="beta_lam of eq. (32), or \"min\" for its Theorem 1 bound",
                                             gt=0.0, le=1e8)
    gamma_1: float = param(doc="learning rate gamma_1 of eq. (30)", gt=0.0, le=1e8)
    gamma_2: float = param(doc="learning rate gamma_2 of eq. (31)", gt=0.0, le=1e8)
    Q_p: Matrix = param(doc="weight Q_p (2m x 2m, symmetric positive definite; a number: times the identity)",
                        ge=-1e8, le=1e8)
    R_p: Matrix = param(doc="weight R_p (m x m; 1x1 for the planar arm; a number: times the identity)",
                        ge=-1e8, le=1e8)

    def build(self):
        from ..controllers import Gains

        def diag(v):
            return np.diag(np.asarray(v, float)) if isinstance(v, tuple) else v

        def matrix(v):
            a = np.asarray(v, float)
            return np.diag(a) if a.ndim == 1 else a

        return Gains(K_p=diag(self.K_p), K_v=diag(self.K_v), rho=self.rho, mu_z=self.mu_z, alpha_z=self.alpha_z,
                     alpha_lam=self.alpha_lam, beta_lam=None if self.beta_lam == "min" else self.beta_lam,
                     gamma_1=self.gamma_1, gamma_2=self.gamma_2, Q_p=matrix(self.Q_p), R_p=matrix(self.R_p))


@section
class NetworkConfig:
    """A network of eqs. (17)–(19). With one output (m = 1, k = 1) and plain numbers: the paper's
    network; with several outputs, one hidden layer per coordinate on that coordinate's inputs
    (:class:`~hinfnn.controllers.network.CoordinateNetwork`), and the centre, slope and weight
    keys may be lists (one per coordinate)."""

    centre_start: Numbers = param(doc="first centre c_1 (or one per coordinate)", ge=-1e6, le=1e6)
    centre_step: Numbers = param(doc="spacing of the centres (or one per coordinate)", gt=0.0, le=1e6)
    centre_count: int = param(doc="number of hidden units (per coordinate)", ge=1, le=5000)
    slope: Numbers = param(doc="tanh slope alpha of eq. (17) (or one per coordinate)", gt=0.0, le=1e6)
    w_a: Numbers = param(doc="weight of the first input (e_u1 for F_p, e_lam for F_f) in the network input",
                         ge=-1e6, le=1e6)
    w_b: Numbers = param(doc="weight of the second input (e_u1_dot for F_p, z for F_f) in the network input",
                         ge=-1e6, le=1e6)
    projection: bool = param(doc="Remark 2 projection onto ||Theta|| <= radius")
    radius: float = param(doc="projection radius d (Remark 2)", gt=0.0, le=1e12)

    def build(self, name: str, n_out: int):
        from ..controllers import CoordinateNetwork, TanhNetwork, centres_from

        lists = [k for k in ("centre_start", "centre_step", "slope", "w_a", "w_b") if isinstance(getattr(self, k), tuple)]
        if n_out == 1 and not lists:
            return TanhNetwork.build(centres_from(self.centre_start, self.centre_step, self.centre_count), n_out=n_out,
                                     slope=self.slope, w_a=self.w_a, w_b=self.w_b,
                                     radius=self.radius if self.projection else None, name=name)

        def each(key):
            try:
                return per_item(getattr(self, key), n_out, f"{name}.{key}", f"one per coordinate, {n_out}")
            except ConfigError as err:
                raise DesignError(str(err).split(": ", 1)[1], key=err.key) from None

        starts, steps = each("centre_start"), each("centre_step")
        centres = np.stack([centres_from(a, b, self.centre_count) for a, b in zip(starts, steps)])
        return CoordinateNetwork.build(centres, slope=each("slope"), w_a=each("w_a"), w_b=each("w_b"),
                                       radius=self.radius if self.projection else None, name=name)


@section
class NetworkFConfig(NetworkConfig):
    preset: Literal["paper-likely", "paper-printed", "custom"] = param(
        doc="F_f centre preset ('custom': the centre_* keys)")


def _kinds_allowed() -> str:
    from ..controllers import KINDS

    return f"one of {', '.join(repr(k) for k in KINDS)} or a list of them"


@section
class ForceRateConfig:
    """The force-rate term of v_λ (not in the paper; docs/beyond-the-paper.md)."""

    kappa: Literal["rule"] | float = param(0.0, doc="gain kappa of v_lam = -(beta_lam/2) e_lam - kappa ds/dt, s; "
                                                     "0: off (the paper's law); \"rule\": from the stiffness range",
                                           ge=0.0, le=10.0)
    tau_f: Literal["auto"] | float = param("auto", doc="time constant of the filter s of e_lam, s; \"auto\": 1 ms, "
                                                       "or the control period under sampled control (MuJoCo: its step)", gt=0.0,
                                         le=1.0)
    zeta: float = param(0.7, doc="damping ratio the rule gives the contact mode at the softest contact",
                        gt=0.0, le=10.0)
    stiffness_min: float = param(1e4, doc="softest contact the design expects, N/m (the rule's)", gt=0.0, le=1e10)
    stiffness_max: float = param(1e6, doc="stiffest contact the design expects, N/m (sampled control: kappa must "
                                          "stabilise it)", gt=0.0, le=1e10)
    source: Literal["auto", "force", "velocity"] = param(
        "auto", doc="what ds/dt is: \"force\" (the filtered difference of the measured e_lam), \"velocity\" (the "
                    "contact force's rate from the measured joint rates on the nominal constraint, scaled by "
                    "stiffness_max), \"auto\" (\"velocity\" when controller.sensor assumes force noise or a "
                    "delay, else \"force\")")

    def resolved(self, noise: float, delay: int = 0) -> str:
        """The source run: ``source``, with "auto" resolved by the sensor the design assumes (``noise``,
        N, and ``delay``, samples: :meth:`SensorAssumptionConfig.resolved`): "velocity" when either is
        not 0 (the differenced force of a late sensor holds a narrower range of contacts than the joint
        rates, which the encoders give without the force sensor's noise)."""
        if self.source == "auto":
            return "velocity" if noise > 0.0 or delay > 0 else "force"
        return self.source

    def validate(self, path):
        if self.stiffness_max < self.stiffness_min:
            raise ConfigError(f"must be >= stiffness_min = {self.stiffness_min:g}, got {self.stiffness_max:g}",
                              key=f"{path}.stiffness_max")


@section
class AdaptationConfig:
    """Robustness of the networks' update laws (30)–(31) against measurement noise (not in the
    paper; docs/beyond-the-paper.md, section 11). ``robust = "none"``: the paper's law."""

    robust: Literal["auto", "none", "dead_zone", "sigma", "e_mod", "projection"] = param(
        "auto", doc="the update laws' modification: \"auto\" (\"projection\" when plant.sensor declares noise, else "
                    "\"none\"), \"none\" (eqs. (30)-(31)), \"dead_zone\" (no learning while "
                    "the drive is within zone x its noise RMS), \"sigma\" (leakage -leak Theta), \"e_mod\" (leakage "
                    "-leak (norm of the drive / its noise RMS) Theta), \"projection\" (Remark 2, radii radius_p, radius_f)")
    leak: float = param(1.0, doc="leakage rate of \"sigma\" (and of \"e_mod\" at the drive's noise level), 1/s",
                        ge=0.0, le=1e6)
    zone: float = param(2.0, doc="dead zone width of \"dead_zone\", in RMS values of the drive's noise", ge=0.0,
                        le=1e3)
    noise_p: Literal["sensor"] | float = param("sensor", doc="RMS of F_p's drive B_p^T P_p x_p from the sensor's noise "
                                               "alone; \"sensor\": from plant.sensor's q_noise, qd_noise at the "
                                               "start pose", ge=0.0, le=1e9)
    noise_f: Literal["sensor"] | float = param("sensor", doc="RMS of F_f's drive e_lam from the sensor's noise alone, "
                                               "lam units; \"sensor\": from plant.sensor.force_noise at the start "
                                               "pose", ge=0.0, le=1e9)
    radius_p: Literal["design"] | float = param("design", doc="projection radius of F_p for \"projection\"; "
                                                "\"design\": the least-norm weights giving 9.81 per output at "
                                                "zero error", gt=0.0, le=1e12)
    radius_f: Literal["design"] | float = param("design", doc="projection radius of F_f for \"projection\"; "
                                                "\"design\": the least-norm weights giving the largest abs(lam_d) at "
                                                "zero error", gt=0.0, le=1e12)

    #: What ``robust = "auto"`` is with a noisy sensor (chosen by measurement, docs/beyond-the-paper.md
    #: section 11); with an ideal one it is "none", the paper's law.
    AUTO: ClassVar[str] = "projection"

    def resolved(self, noisy: bool) -> str:
        """The modification run: ``robust``, with "auto" resolved by whether the declared sensor
        has noise (``noisy``)."""
        if self.robust == "auto":
            return self.AUTO if noisy else "none"
        return self.robust

    def options(self, noisy: bool) -> dict:
        """The keyword arguments of :func:`hinfnn.controllers.kinds.robust_adaptation` but the
        design inputs."""
        return dict(robust=self.resolved(noisy), leak=self.leak, zone=self.zone,
                    noise_p=None if self.noise_p == "sensor" else self.noise_p,
                    noise_f=None if self.noise_f == "sensor" else self.noise_f,
                    radius_p=None if self.radius_p == "design" else self.radius_p,
                    radius_f=None if self.radius_f == "design" else self.radius_f)


@section
class ForceFilterConfig:
    """The sampled controller's low-pass on the measured force (not in the paper;
    docs/beyond-the-paper.md, section 12): a discrete Butterworth filter on e_lam, in front of
    everything the law does with it (z, v_lam, F_f and the force-rate term)."""

    order: Literal["design"] | int = param(0, doc="order of the Butterworth low-pass on the measured e_lam: 0 (none: "
                                                  "the paper's law), 1, 2, or \"design\" (chosen with kappa for the "
                                                  "sensor of controller.sensor)", ge=0, le=2)
    cutoff_hz: Literal["design"] | float = param("design", doc="its cutoff frequency, Hz (below half the control "
                                                               "rate), or \"design\"", gt=0.0, le=1e6)


@section
class SensorAssumptionConfig:
    """The sensor the controller's design assumes (the controller never reads the plant: by
    default the scenario's declared plant.sensor, copied when the scenario is built)."""

    noise: Literal["declared"] | float = param("declared", doc="standard deviation of the force sensor's noise per "
                                                               "axis the design assumes, N; \"declared\": "
                                                               "plant.sensor.force_noise", ge=0.0, le=1e6)
    delay: Literal["declared"] | int = param("declared", doc="transport delay of the measurements the design assumes, "
                                                             "whole control samples; \"declared\": "
                                                             "plant.sensor.delay", ge=0, le=1000)
    disturbance: float = param(0.0, doc="RMS of the force disturbance the contact loop meets, N (a first-order "
                                        "Gauss-Markov force held with the command), for the least force error any "
                                        "law holds that `hinfnn design` prints; 0: none declared, no bound",
                               ge=0.0, le=1e6)
    disturbance_hz: float = param(1.0, doc="corner frequency of that disturbance, Hz", gt=0.0, le=1e6)

    def resolved(self, declared: tuple[float, int]) -> tuple[float, int]:
        """(noise σ, N; delay, samples) the design assumes, "declared" taken from ``declared``
        (the scenario's plant.sensor: :attr:`hinfnn.scenario.setup.Setup.declared_sensor`)."""
        noise = declared[0] if self.noise == "declared" else self.noise
        delay = declared[1] if self.delay == "declared" else self.delay
        return float(noise), int(delay)


#: The share of the torque-rate limit the sensor noise may use by default (docs/beyond-the-paper.md,
#: section 12): on ur5-polish-sensor the drum's contact alone, with no noise, drives the shoulder's
#: commanded 99th percentile of |Δτ|/h to 290 N·m/s with ideal motors and 780–970 N·m/s behind the
#: 1,000 N·m/s clamp, and with the whole limit for the noise the design's choice at σ = 0.5 N (its
#: noise predicted at 0.66 of the limit) lost contact at the start.
TORQUE_RATE_SHARE = 0.5

#: The least noise the torque-rate criterion assumes by default, N (section 12): with no noise the
#: drum's contact alone makes the first-order filters above 50 Hz that a small declared noise
#: admits stop behind the 1,000 N·m/s clamp (σ = 0.25 N: at 1.12 s), while the choice at 1 N holds
#: from σ = 0 to 1 N.
RATE_NOISE_FLOOR = 1.0


@section
class ActuatorAssumptionConfig:
    """The motors the controller's design assumes (the controller never reads the plant: by default
    the scenario's declared plant.actuator, copied when the scenario is built)."""

    torque_rate_limit: Literal["declared", "none"] | Numbers = param(
        "declared", doc="largest change of each joint's torque the design keeps the force path's noise within, N m/s "
        "(a number or one per joint; \"declared\": plant.actuator.torque_rate_limit; \"none\": no constraint)",
        gt=0.0, le=1e12)
    torque_rate_share: float = param(
        TORQUE_RATE_SHARE, doc="share of the torque-rate limit the design lets the sensor noise's predicted 99th "
        "percentile of |dtau|/h use (the rest is the motion's and the contact's own torque changes)", gt=0.0, le=1.0)
    rate_noise_floor: float = param(
        RATE_NOISE_FLOOR, doc="least force noise the torque-rate criterion assumes, N (the contact's own force "
        "changes pass the same path as the sensor's noise; the declared noise where larger)", ge=0.0, le=1e6)

    def resolved(self, declared, n: int, path: str = "controller.actuator"):
        """The torque-rate limit per joint (N·m/s, an (n,) array) the design keeps within, or None:
        "declared" is ``declared`` (the scenario's plant.actuator.torque_rate_limit,
        :attr:`hinfnn.scenario.setup.Setup.declared_torque_rate`; None there: none)."""
        value = declared if self.torque_rate_limit == "declared" else self.torque_rate_limit
        if value is None or (isinstance(value, str) and value == "none"):
            return None
        key = (f"{path}.torque_rate_limit" if self.torque_rate_limit != "declared"
               else "plant.actuator.torque_rate_limit")
        return per_item(value, n, key, "one per joint")


@section
class ControllerConfig:
    kind: str | tuple[str, ...] = param(doc="controller(s) to run: a name of hinfnn.controllers.KINDS or a list",
                                        allowed=_kinds_allowed)
    augmented: bool = param(doc="Remark 1 augmented performance (eq. 40, v_lam = -beta_lam e_lam)")
    gains: GainsConfig = param(doc="gains")
    network_p: NetworkConfig = param(doc="F_p network")
    network_f: NetworkFConfig = param(doc="F_f network")
    force_rate: ForceRateConfig = param(doc="force-rate term (not in the paper)")
    adaptation: AdaptationConfig = param(doc="the networks' update laws made robust to measurement noise (not in the "
                                              "paper)")
    force_filter: ForceFilterConfig = param(ForceFilterConfig(), doc="low-pass on the measured force (not in the "
                                            "paper)")
    sensor: SensorAssumptionConfig = param(SensorAssumptionConfig(), doc="the sensor the design assumes")
    actuator: ActuatorAssumptionConfig = param(ActuatorAssumptionConfig(), doc="the motors the design assumes")
    singularity_stop: float = param(0.0, doc="stop (simulator) or return NaN (sampled controller) when the smallest "
                                             "singular value of the nominal Jacobian falls below this; 0: off",
                                    ge=0.0, le=100.0)

    @property
    def kinds(self) -> list[str]:
        return [self.kind] if isinstance(self.kind, str) else list(self.kind)

    def validate(self, path):
        from ..controllers import KINDS

        key = f"{path}.kind"
        for v in self.kinds:
            if v not in KINDS:
                import difflib

                close = difflib.get_close_matches(v, list(KINDS), n=1)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                raise ConfigError(f"unknown controller {v!r}; allowed: {', '.join(KINDS)}{hint}", key=key)
        if len(set(self.kinds)) != len(self.kinds):
            raise ConfigError(f"lists a controller twice: {list(self.kinds)}", key=key)

    def build(self, kind: str, arm, surface, *, u1_path=None, q_start=None, period=None, adaptation=None,
              declared=(0.0, 0), declared_rate=None):
        """Design the controller ``kind`` from the NOMINAL arm and surface (``u1_path``,
        ``q_start``: the reference's path in u1 and a start pose, for the force-rate rule;
        ``period``: the control period under sampled control; ``adaptation``: the design inputs of
        the robust update laws, :func:`hinfnn.controllers.kinds.robust_adaptation`'s ``q``,
        ``lam_max``, ``force_noise``, ``q_noise``, ``qd_noise``; ``declared``: the scenario's declared
        sensor (force noise, delay), what ``controller.sensor`` defaults to; ``declared_rate``: the
        scenario's declared torque-rate limit, N·m/s per joint or None, what
        ``controller.actuator.torque_rate_limit`` defaults to). Raises
        :class:`DesignError` with the dotted key of the failing gain, :class:`ConfigError` for a
        force filter under continuous control."""
        from ..controllers import design

        fr = self.force_rate
        force_rate = None
        noise, delay = self.sensor.resolved(declared)
        source = fr.resolved(noise, delay)
        if fr.kappa != 0.0:
            force_rate = dict(kappa=fr.kappa, tau_f=fr.tau_f, zeta=fr.zeta, stiffness_min=fr.stiffness_min,
                              stiffness_max=fr.stiffness_max, u1_path=u1_path, q_start=q_start, period=period,
                              **({"source": source} if source != "force" else {}))
        ff = self.force_filter
        force_filter = None
        if ff.order != 0:
            if period is None:
                raise ConfigError("the force filter is discrete, designed at the control period: it needs sampled "
                                  "control (simulation.control = \"sampled\", or a plant that steps itself)",
                                  key="controller.force_filter.order")
            force_filter = dict(order=ff.order, cutoff_hz=ff.cutoff_hz, noise=noise, delay=delay, period=period)
        elif force_rate is not None and period is not None and (source == "velocity" or delay > 0):
            # designed for the sensor: the sampled loop with its delay (a late sensor is never given the ideal
            # sensor's rule)
            force_filter = dict(order=0, cutoff_hz="design", noise=noise, delay=delay, period=period)
        rate_limit = self.actuator.resolved(declared_rate, int(arm.n))
        if rate_limit is not None and force_filter is not None:  # the design keeps within the motors' rate
            force_filter["torque_rate_limit"] = tuple(float(v) for v in rate_limit)
            force_filter["torque_rate_share"] = float(self.actuator.torque_rate_share)
            force_filter["rate_noise_floor"] = float(self.actuator.rate_noise_floor)
        try:
            return design(kind, arm, surface, self.gains.build(), augmented=self.augmented,
                          network_p=self.network_p.build("controller.network_p", surface.m),
                          network_f=self.network_f.build("controller.network_f", surface.k),
                          force_rate=force_rate, singularity_stop=self.singularity_stop,
                          adaptation=self._adaptation(adaptation),
                          **({"force_filter": force_filter} if force_filter else {}))
        except DesignError as err:
            raise prefixed(err) from None

    def _adaptation(self, inputs: dict | None) -> dict | None:
        """:func:`~hinfnn.controllers.kinds.robust_adaptation`'s keyword arguments (None: the
        paper's update laws), from ``controller.adaptation`` and the design ``inputs`` (the
        declared sensor's noise, the start pose, the largest λd; None: an ideal sensor)."""
        noisy = inputs is not None and bool(inputs.get("force_noise") or np.any(inputs.get("q_noise", 0))
                                            or np.any(inputs.get("qd_noise", 0)))
        robust = self.adaptation.resolved(noisy)
        if robust == "none":
            return None
        return {**self.adaptation.options(noisy), **(inputs or {})}


def prefixed(err: DesignError) -> DesignError:
    """The same DesignError with its key as a scenario key (``rho`` -> ``controller.gains.rho``)."""
    key = err.key
    if key is None:
        return err
    if key in ("rho", "mu_z", "alpha_z", "alpha_lam", "beta_lam", "gamma_1", "gamma_2", "Q_p", "R_p", "K_p", "K_v"):
        full = f"controller.gains.{key}"
    elif key.startswith(("network_", "force_rate", "adaptation", "force_filter", "sensor.")):
        full = f"controller.{key}"
    else:
        full = key
    message = err.args[0].split(": ", 1)[1] if err.args[0].startswith(f"{key}: ") else err.args[0]
    return DesignError(message, key=full, value=err.value, bound=err.bound)


# --- reference, start, simulation --------------------------------------------------------------------


@section
class ReferenceConfig:
    """The desired motion u1d(t) (m coordinates) and force λd(t) (k) (``kind`` chooses the form)."""

    __registry__ = REFERENCES
    kind: str = param(doc="reference kind")

    def build(self, m: int | None = None, k: int | None = None):
        """The reference object for m motion and k force coordinates (None: as the section gives)."""
        raise NotImplementedError

    def sizes(self) -> tuple[int | None, int | None]:
        """(m, k) the reference is for (None: any)."""
        return None, None


@REFERENCES.register("cosine")
@section
class CosineConfig(ReferenceConfig):
    """u1d = u1_offset + u1_amplitude cos(2π t / u1_period + u1_phase), λd likewise (m = k = 1)."""

    u1_offset: float = param(doc="u1d offset, m", ge=-100.0, le=100.0)
    u1_amplitude: float = param(doc="u1d cosine amplitude, m", ge=-100.0, le=100.0)
    u1_period: float = param(doc="u1d period, s", gt=0.0, le=1e6)
    u1_phase: float = param(doc="u1d phase, rad", ge=-1e3, le=1e3)
    lam_offset: float = param(doc="lam_d offset", ge=-1e7, le=1e7)
    lam_amplitude: float = param(doc="lam_d cosine amplitude", ge=-1e7, le=1e7)
    lam_period: float = param(doc="lam_d period, s", gt=0.0, le=1e6)
    lam_phase: float = param(doc="lam_d phase, rad", ge=-1e3, le=1e3)

    def u1_range(self) -> tuple[float, float]:
        """The span of u1d(t)."""
        return self.u1_offset - abs(self.u1_amplitude), self.u1_offset + abs(self.u1_amplitude)

    def build(self, m: int | None = None, k: int | None = None):
        import jax.numpy as jnp

        from ..reference import CosineReference

        def a(v):
            return jnp.array([float(v)])

        return CosineReference(
            u1_offset=a(self.u1_offset), u1_amplitude=a(self.u1_amplitude),
            u1_omega=a(2 * math.pi / self.u1_period), u1_phase=a(self.u1_phase),
            lam_offset=a(self.lam_offset), lam_amplitude=a(self.lam_amplitude),
            lam_omega=a(2 * math.pi / self.lam_period), lam_phase=a(self.lam_phase))

    def sizes(self):
        return 1, 1


@REFERENCES.register("cosines")
@section
class CosinesConfig(ReferenceConfig):
    """One cosine per coordinate, faded in: u1d_i = u1_offset_i + r_u(t) u1_amplitude_i cos(2π t /
    u1_period_i + u1_phase_i) and λd_j = r_λ(t) (lam_offset_j + lam_amplitude_j cos(...)), r the
    quintic ramp from 0 to 1 over u1_ramp (lam_ramp) seconds (0: none). Each key is a number (the
    same for every coordinate) or a list (one per coordinate: m for u1_*, k for lam_*). A circle of
    radius a in two coordinates: amplitudes [a, a], phases [0, -pi/2] (radians)."""

    u1_offset: Numbers = param(doc="u1d offsets (m or rad, per coordinate)", ge=-100.0, le=100.0)
    u1_amplitude: Numbers = param(0.0, doc="u1d cosine amplitudes", ge=-100.0, le=100.0)
    u1_period: Numbers = param(1.0, doc="u1d periods, s", gt=0.0, le=1e6)
    u1_phase: Numbers = param(0.0, doc="u1d phases, rad", ge=-1e3, le=1e3)
    u1_ramp: float = param(0.0, doc="fade-in time of the u1d cosines (u1d, its rate and acceleration start at the "
                                    "offsets and 0), s", ge=0.0, le=1e6)
    lam_offset: Numbers = param(doc="lam_d offsets", ge=-1e7, le=1e7)
    lam_amplitude: Numbers = param(0.0, doc="lam_d cosine amplitudes", ge=-1e7, le=1e7)
    lam_period: Numbers = param(1.0, doc="lam_d periods, s", gt=0.0, le=1e6)
    lam_phase: Numbers = param(0.0, doc="lam_d phases, rad", ge=-1e3, le=1e3)
    lam_ramp: float = param(0.0, doc="fade-in time of lam_d from 0, s", ge=0.0, le=1e6)

    U1_KEYS = ("u1_offset", "u1_amplitude", "u1_period", "u1_phase")
    LAM_KEYS = ("lam_offset", "lam_amplitude", "lam_period", "lam_phase")
    #: Without a common period of the cosines up to this many of the longest, the design's span is as many.
    SPAN_PERIODS = 100

    def design_span(self) -> tuple[float, str]:
        """(T, in words): u1d(t) on [0, T] passes every point of its path, whatever the run's
        horizon: the fade-in and one common period of the moving coordinates' cosines (or
        :data:`SPAN_PERIODS` of the longest when they have none that short). The design evaluates
        the nominal model there (:func:`hinfnn.scenario.checks.design_path`)."""
        from ..reference import common_period

        m, _ = self.sizes()
        m = m if m and m > 0 else 1
        amps = per_item(self.u1_amplitude, m, "reference.u1_amplitude", "one per coordinate")
        periods = [p for p, a in zip(per_item(self.u1_period, m, "reference.u1_period", "one per coordinate"), amps)
                   if a != 0.0]
        if not periods:
            return self.u1_ramp, f"u1d constant after its {self.u1_ramp:g}-s fade-in"
        limit = self.SPAN_PERIODS * max(periods)
        period = common_period(periods, limit)
        ramp = f"the {self.u1_ramp:g}-s fade-in and " if self.u1_ramp else ""
        if period is None:
            return self.u1_ramp + limit, (f"{ramp}{self.SPAN_PERIODS} periods of its slowest cosine "
                                          f"(its cosines have no common period up to {limit:g} s)")
        return self.u1_ramp + period, f"{ramp}one {period:g}-s period of u1d"

    def sizes(self):
        def n(keys):
            lens = {len(getattr(self, k)) for k in keys if isinstance(getattr(self, k), tuple)}
            return lens.pop() if len(lens) == 1 else (None if not lens else -1)

        return n(self.U1_KEYS), n(self.LAM_KEYS)

    def validate(self, path):
        for group, what in ((self.U1_KEYS, "motion"), (self.LAM_KEYS, "force")):
            lists = [(k, getattr(self, k)) for k in group if isinstance(getattr(self, k), tuple)]
            for k, v in lists[1:]:
                first, ref = lists[0]
                if len(v) != len(ref):
                    raise ConfigError(f"must be a number or a list of {len(ref)} numbers, as {path}.{first} (one per "
                                      f"{what} coordinate), got {len(v)}: {_shown(v)}", key=f"{path}.{k}")

    def build(self, m: int | None = None, k: int | None = None):
        import jax.numpy as jnp

        from ..reference import CosineReference

        m0, k0 = self.sizes()
        m = m or m0 or 1
        k = k or k0 or 1

        def v(key, n, f=lambda x: x):
            return jnp.asarray(f(per_item(getattr(self, key), n, f"reference.{key}", "one per coordinate")))

        return CosineReference(
            u1_offset=v("u1_offset", m), u1_amplitude=v("u1_amplitude", m),
            u1_omega=v("u1_period", m, lambda p: 2 * math.pi / p), u1_phase=v("u1_phase", m),
            lam_offset=v("lam_offset", k), lam_amplitude=v("lam_amplitude", k),
            lam_omega=v("lam_period", k, lambda p: 2 * math.pi / p), lam_phase=v("lam_phase", k),
            u1_ramp=jnp.asarray(self.u1_ramp), lam_ramp=jnp.asarray(self.lam_ramp))


@section
class InitialConfig:
    u1: Numbers = param(doc="u1(0): the true end-effector's motion coordinates on the true surface (m, rad; a "
                            "list of m for m > 1)", ge=-100.0, le=100.0)
    elbow: Literal["up", "down"] = param("up", doc="inverse-kinematics branch (two_link arm)")
    q_guess: tuple[float, ...] = param((), doc="joint angles near the start pose, rad (the start pose is solved by "
                                       "Newton's method from them; default all 0)", ge=-100.0, le=100.0)


@section
class VerdictConfig:
    """When a run did its job (:func:`hinfnn.metrics.verdicts`): contact held, and tracking within
    tolerance over the last 2 s, judged next to the status in the run summary and metrics.json."""

    position_tolerance: float = param(0.005, doc="largest RMS error over the last 2 s of each motion coordinate in m", gt=0.0,
                                      le=1e3)
    angle_tolerance: float = param(0.02, doc="largest RMS error over the last 2 s of each motion coordinate in rad",
                                   gt=0.0, le=10.0)
    force_tolerance: float = param(0.1, doc="largest RMS force error e_lam over the last 2 s, as a fraction of the mean "
                                   "magnitude of lam_d there", gt=0.0, le=100.0)
    contact_after: float = param(0.5, doc="contact is judged from this time on (the force builds up before), s", ge=0.0,
                                 le=1e5)
    out_of_contact: float = param(0.0, doc="largest fraction of the steps after contact_after with the tool off the "
                                  "true surface", ge=0.0, le=1.0)

    def tolerances(self) -> dict:
        return {"position_tolerance": self.position_tolerance, "angle_tolerance": self.angle_tolerance,
                "force_tolerance": self.force_tolerance, "contact_after": self.contact_after,
                "out_of_contact": self.out_of_contact}


@section
class SafetyConfig:
    """The safety layer of a robot loop (:mod:`hinfnn.robot.safety`, ``hinfnn robot run``; docs/robot.md):
    what is clamped, what is rejected before it reaches the controller and what stops the robot.
    A simulation does not read it."""

    torque_limit: tuple[float, ...] = param((), doc="largest magnitude of the torque sent to each joint, N m (clamped); empty: the "
                                            "nominal arm's URDF effort limits (an arm without them: "
                                            "simulation.torque_limit)", gt=0.0, le=1e6)
    torque_rate_limit: float = param(1000.0, doc="largest change of each joint's torque per second, N m/s (clamped; "
                                     "libfranka's limit)", gt=0.0, le=1e9)
    force_limit: float = param(200.0, doc="the robot stops when the measured contact force exceeds this, N (the "
                               "force ceiling)", gt=0.0, le=1e6)
    force_range: float = param(2000.0, doc="a force reading above this is outside the sensor's range: rejected, "
                               "never given to the controller, N", gt=0.0, le=1e9)
    velocity_limit: float = param(3.0, doc="the robot stops when a joint moves faster than this, rad/s or m/s",
                                  gt=0.0, le=1e3)
    velocity_range: float = param(50.0, doc="a joint-rate reading above this is outside the sensor's range: "
                                  "rejected, rad/s or m/s", gt=0.0, le=1e6)
    joint_limit_margin: float = param(0.05, doc="the robot stops when a joint comes this close to its limit "
                                      "(the nominal arm's URDF limits), rad or m", ge=0.0, le=10.0)
    contact_loss_force: float = param(1.0, doc="contact is lost when the measured force stays below this, N",
                                      ge=0.0, le=1e6)
    contact_loss_time: float = param(0.02, doc="contact is lost when the force stays below contact_loss_force this "
                                     "long, s: the robot then holds its position and retracts", gt=0.0, le=100.0)
    contact_loss_after: float = param(0.5, doc="the contact-loss rule is armed from this time on (the force "
                                      "builds up before), s", ge=0.0, le=1e5)
    retract_distance: float = param(0.02, doc="how far the tool backs away from the surface after a contact "
                                    "loss (against the last measured force), m", ge=0.0, le=1.0)
    retract_time: float = param(0.5, doc="the retraction takes this long, s", gt=0.0, le=100.0)
    hold_stiffness: float = param(200.0, doc="joint stiffness of the hold after a stop, N m/rad",
                                  gt=0.0, le=1e6)
    hold_damping: float = param(20.0, doc="joint damping of the hold after a stop, N m s/rad", ge=0.0,
                                le=1e6)
    stop_time: float = param(0.2, doc="how long the robot holds after a stop before the loop ends, s", ge=0.0,
                             le=100.0)
    max_period_ratio: float = param(5.0, doc="a reading more than this many control periods after the previous "
                                    "one is rejected (the law is designed for its period)", gt=1.0, le=1e3)
    max_rejected: int = param(10, doc="the robot stops after this many readings rejected in a row", ge=1,
                              le=100000)
    watchdog_misses: int = param(20, doc="the robot stops after this many control periods in a row without a "
                                 "fresh torque (libfranka stops after 20 lost packets)", ge=1, le=100000)


@section
class JobConfig:
    """The phases of a real job (:mod:`hinfnn.controllers.job`, docs/robot.md "Phases of a job"):
    where the tool starts and what it does before and after the paper's constrained law. ``start
    = "contact"`` (the default) is the paper's assumption A5: the tool starts on the true surface
    and the law runs from t = 0, as without this section. ``start = "approach"``: the tool starts
    ``approach_height`` above the NOMINAL surface (along its normal), moves towards it at
    ``approach_speed`` until the measured force reaches ``contact_force``, then the law takes over
    with λd ramped from the force at contact over ``ramp_time``; after ``process_time`` s of the
    process it unloads and lifts off. Sampled control only (the phases switch at samples)."""

    start: Literal["contact", "approach"] = param("contact", doc="where the job starts: \"contact\" (the paper's A5: "
                                                   "on the true surface, the law from t = 0) or \"approach\" (above the "
                                                   "nominal surface: approach, touch, force ramp, process, lift-off)")
    approach_height: float = param(0.02, doc="start height above the NOMINAL surface along its normal (start = "
                                   "\"approach\"), m", gt=0.0, le=1.0)
    approach_speed: float = param(0.01, doc="speed of the guarded move towards the surface, m/s", gt=0.0, le=1.0)
    approach_margin: float = param(0.02, doc="how far past the nominal surface the guarded move goes before it gives "
                                   "up (the run stops: no contact found), m", ge=0.0, le=1.0)
    approach_gain: float = param(20.0, doc="bandwidth of the free-space motion law (computed torque on the nominal "
                                 "model with integral action, its three poles at -approach_gain), rad/s", gt=0.0,
                                 le=1e3)
    contact_force: Literal["auto"] | float = param("auto", doc="contact is detected when the MEASURED force at the tool "
                                                   "reaches this, N (above the sensor's noise and bias); \"auto\": "
                                                   "2 N, or 6 sqrt(3) times the noise controller.sensor assumes where "
                                                   "that is more", gt=0.0, le=1e6)
    ramp_time: float = param(0.5, doc="lam_d ramps from the force at contact to the reference's over this time, s "
                             "(the reference's time origin is the contact)", ge=0.0, le=100.0)
    process_time: float = param(0.0, doc="time in the process phase after the ramp before the unload and lift-off, s; "
                                "0: the process runs to the end of the run (no lift-off)", ge=0.0, le=1e5)
    lift_height: float = param(0.02, doc="how far the tool lifts off the surface at the end, m", gt=0.0, le=1.0)
    lift_time: float = param(1.0, doc="the lift-off takes this long, s", gt=0.0, le=100.0)

    @property
    def approach(self) -> bool:
        return self.start == "approach"

    #: ``contact_force = "auto"``: at least this, N (an ideal sensor's threshold) ...
    CONTACT_FORCE_MIN: ClassVar[float] = 2.0
    #: ... and this many times the noise σ the controller assumes (per axis: the noise's norm has
    #: standard deviation about √3 σ; 6√3 σ clears 5√3 σ, the floor :meth:`check_sensor` demands).
    CONTACT_FORCE_SIGMAS: ClassVar[float] = 6.0 * math.sqrt(3.0)

    def contact_threshold(self, noise: float) -> float:
        """The contact-detection threshold, N: ``contact_force``, or with "auto" the larger of
        :attr:`CONTACT_FORCE_MIN` and :attr:`CONTACT_FORCE_SIGMAS` × ``noise`` (the σ the controller
        assumes, controller.sensor)."""
        if self.contact_force == "auto":
            return max(self.CONTACT_FORCE_MIN, self.CONTACT_FORCE_SIGMAS * float(noise))
        return float(self.contact_force)

    def check_sensor(self, sensor, noise: float, path: str = "job") -> None:
        """The threshold (:meth:`contact_threshold`, ``noise`` the σ the controller assumes) must
        exceed what the declared sensor reads with no contact: its bias plus 5 standard deviations
        of the noise's norm (ConfigError at ``job.contact_force``)."""
        if not self.approach:
            return
        floor = float(np.linalg.norm(sensor.force_bias)) if sensor.force_bias else 0.0
        floor += 5.0 * math.sqrt(3.0) * float(sensor.force_noise)
        value = self.contact_threshold(noise)
        if not value > floor:
            how = f"got {value:g} N" if self.contact_force != "auto" else (
                f"\"auto\" gives {value:g} N from the noise controller.sensor assumes ({float(noise):g} N): set a "
                "number, or declare the sensor's noise in controller.sensor.noise")
            raise ConfigError(f"must exceed the force the sensor reads with no contact, |plant.sensor.force_bias| + "
                              f"5 sqrt(3) plant.sensor.force_noise = {floor:.4g} N, {how} (a threshold in the noise "
                              "detects contact in free space)", key=f"{path}.contact_force")


@section
class SimulationConfig:
    t_final: float = param(doc="horizon, s", gt=0.0, le=1e5)
    dt: float = param(doc="RK4 step, s", gt=0.0, le=0.1)
    control: Literal["continuous", "sampled"] = param(doc="control mode")
    control_period: float = param(doc="sampling period when control = \"sampled\", s", gt=0.0, le=1.0)
    output_interval: float = param(doc="largest interval between saved samples, s", gt=0.0, le=1e3)
    torque_limit: float = param(doc="a run stops past this |tau_i|, N m", gt=0.0, le=1e12)
    penetration_limit: float = param(doc="a run stops past this penetration, m", gt=0.0, le=1e3)
    bookkeeping: bool = param(True, doc="integrate the theorems' bookkeeping along the run (J, J_aug, the supply; "
                              "V, f_p, f_f recorded) and check the dissipation inequality; false: none of it "
                              "(a 1 kHz sampled arm run in less than half the time)")

    def limits(self):
        from ..sim import Limits

        return Limits(torque=self.torque_limit, penetration=self.penetration_limit)
