"""MuJoCo as the true plant (optional extra ``hinfnn[mujoco]``; docs/mujoco.md).

The controller is designed from the paper's closed-form model; here the truth is a different
physics engine: MuJoCo's recursive rigid-body dynamics, its collision detection and its soft
constraint solver, stepped in discrete time. MuJoCo is driven through the sampled-data path:
at each control instant the controller computes τ from a :class:`~hinfnn.Measurement`, τ is held
(zero-order hold) while MuJoCo advances by the control period in whole MuJoCo timesteps.

Pieces:

* :func:`mjcf_two_link` — the MJCF of the TRUE arm (point masses at the link tips, hinges about
  the axis normal to the motion plane) and the TRUE inclined surface (a plane), with a
  frictionless (``condim=1``) contact pair between a small sphere at the tip and the plane
  whose ``solref``/``solimp`` make it a spring-damper of the requested k (N/m) and c (N·s/m)
  (:func:`contact_solref`).
* :class:`MujocoPlant` — the plant protocol (``n``, ``discrete``, ``initial_state``, ``sense``,
  ``step``) with ``step`` one host call per control period into MuJoCo's C step (a primitive
  lowered to XLA's Python host callback, or :func:`jax.pure_callback`), so a whole closed loop
  (controller and plant) is one compiled ``lax.scan``; ``sense`` is pure JAX on the state.

Frames: task space (x1, x2) of the paper is MuJoCo's world (x, z); y is the hinge axis' line.
A positive joint angle turns the link from +x towards +z, so the hinge axes are (0, −1, 0).

``import hinfnn`` never imports ``mujoco``: it is imported on first use, and a missing package
raises :class:`~hinfnn.errors.ConfigError` (key ``plant.engine``).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import pytree_dataclass
from ..errors import ConfigError
from ..protocols import DiscretePlant, Measurement, PlantRecord

__all__ = ["MujocoPlant", "MujocoState", "mjcf_two_link", "contact_solref", "require_mujoco",
           "INTEGRATORS", "CALLBACKS", "IMPEDANCE", "POINT_MASS_GYRATION_RADIUS", "TIP_RADIUS"]

#: MuJoCo's integrators, as spelled in MJCF.
INTEGRATORS = ("Euler", "RK4", "implicit", "implicitfast")

#: Constant constraint impedance d of the contact (MuJoCo's smallest, mjMINIMP). With d → 0 the
#: soft constraint is a penalty spring-damper; what remains of MuJoCo's constraint behaviour is
#: an added normal mass of d / ((1 − d) W) ≈ 1e-4 / W kg (docs/mujoco.md, "Contact").
IMPEDANCE = 1e-4

#: Radius of gyration (m) of the tiny rotational inertia given to each point mass: MuJoCo needs a
#: positive inertia; I = m r² ≈ 1e-10 kg·m² changes M(q) by < 1e-9 relative.
POINT_MASS_GYRATION_RADIUS = 1e-5

#: Radius (m) of the contact sphere at the tip. The plane sits TIP_RADIUS inside the true surface
#: so the sphere–plane distance equals the tip point's signed distance to the true surface.
TIP_RADIUS = 0.01

_MISSING = ("plant.engine = \"mujoco\" needs the optional extra: pip install 'hinfnn[mujoco]'")


def require_mujoco():
    """Import and return the ``mujoco`` module, or raise :class:`ConfigError` (``plant.engine``)."""
    try:
        import mujoco
    except ImportError as err:
        raise ConfigError(_MISSING, key="plant.engine") from err
    return mujoco


# --------------------------------------------------------------------------------------------
# MJCF
# --------------------------------------------------------------------------------------------
def _num(x) -> str:
    """A float written so that MuJoCo parses back the same double."""
    return repr(float(x))


def _check_models(arm, surface, contact):
    from ..model.planar import TwoLinkArm
    from ..model.surface import InclinedLine

    if not isinstance(arm, TwoLinkArm):
        raise ConfigError(f"the MuJoCo plant supports the planar two-link arm (TwoLinkArm), got "
                          f"{type(arm).__name__}", key="plant.arm.model")
    if not isinstance(surface, InclinedLine):
        raise ConfigError(f"the MuJoCo plant supports the inclined line (InclinedLine), got "
                          f"{type(surface).__name__}", key="plant.surface.kind")
    for key, v in (("plant.arm.m1", arm.m1), ("plant.arm.m2", arm.m2), ("plant.arm.l1", arm.l1),
                   ("plant.arm.l2", arm.l2)):
        if not np.ndim(v) == 0 or not float(v) > 0.0:
            raise ConfigError(f"must be a number > 0, got {v!r}", key=key)
    for key, v in (("plant.contact.stiffness", contact.stiffness),
                   ("plant.contact.damping", contact.damping)):
        if not np.ndim(v) == 0 or not math.isfinite(float(v)) or float(v) < 0.0:
            raise ConfigError(f"must be a finite number >= 0, got {v!r}", key=key)


def _mjcf(arm, surface, *, timestep, integrator, solref, solimp) -> str:
    m1, m2, l1, l2, g = (float(arm.m1), float(arm.m2), float(arm.l1), float(arm.l2), float(arm.g))
    delta, d_G = float(surface.delta), float(surface.d_G)
    r = POINT_MASS_GYRATION_RADIUS
    I1, I2 = m1 * r * r, m2 * r * r
    # Plane: outward normal n_out = (−sin δ, cos δ) in (x1, x2), its local z axis; it passes
    # TIP_RADIUS inside the true line x2 = (x1 − d_G) tan δ (through (d_G, 0)).
    s, c = math.sin(delta), math.cos(delta)
    zaxis = f"{_num(-s)} 0 {_num(c)}"
    ppos = f"{_num(d_G + TIP_RADIUS * s)} 0 {_num(-TIP_RADIUS * c)}"
    return f"""<mujoco model="hinfnn_two_link">
  <!-- Generated by hinfnn.plant.mujoco.mjcf_two_link: the TRUE arm and surface of a scenario.
       Task space (x1, x2) = world (x, z); positive joint angles turn +x towards +z.
       Point masses at the link tips (rotational inertia m*(1e-5 m)^2 each, MuJoCo needs > 0);
       no joint damping, armature, limits or friction. Frictionless contact (condim 1) between
       the tip sphere and the plane, solref/solimp converted from k = stiffness N/m and
       c = damping N s/m (docs/mujoco.md): valid for THIS model only (they depend on the
       tip body's invweight0). -->
  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>
  <option timestep="{_num(timestep)}" integrator="{integrator}" gravity="0 0 {_num(-g)}"
          solver="Newton" iterations="50" tolerance="1e-12" ls_iterations="50">
    <flag autoreset="disable" warmstart="enable" frictionloss="disable"/>
  </option>
  <worldbody>
    <geom name="surface" type="plane" pos="{ppos}" zaxis="{zaxis}" size="0 0 0.05"
          contype="0" conaffinity="0" rgba="0.6 0.6 0.6 1"/>
    <body name="link1" pos="0 0 0">
      <joint name="q1" type="hinge" axis="0 -1 0" pos="0 0 0" limited="false" damping="0" armature="0"/>
      <inertial pos="{_num(l1)} 0 0" mass="{_num(m1)}" diaginertia="{_num(I1)} {_num(I1)} {_num(I1)}"/>
      <body name="link2" pos="{_num(l1)} 0 0">
        <joint name="q2" type="hinge" axis="0 -1 0" pos="0 0 0" limited="false" damping="0" armature="0"/>
        <inertial pos="{_num(l2)} 0 0" mass="{_num(m2)}" diaginertia="{_num(I2)} {_num(I2)} {_num(I2)}"/>
        <geom name="tip" type="sphere" pos="{_num(l2)} 0 0" size="{_num(TIP_RADIUS)}"
              contype="0" conaffinity="0" rgba="0.8 0.2 0.2 1"/>
        <site name="tip" pos="{_num(l2)} 0 0" size="0.005"/>
      </body>
    </body>
  </worldbody>
  <contact>
    <pair name="tip_surface" geom1="surface" geom2="tip" condim="1" margin="0" gap="0"
          solref="{_num(solref[0])} {_num(solref[1])}"
          solimp="{_num(solimp[0])} {_num(solimp[1])} {_num(solimp[2])} {_num(solimp[3])} {_num(solimp[4])}"/>
  </contact>
</mujoco>
"""


def contact_solref(stiffness, damping, diag_approx, impedance: float = IMPEDANCE):
    """MuJoCo ``(solref, solimp)`` making a frictionless contact the spring-damper (k, c).

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
    added mass (1e-4 / W kg for d = 1e-4). Returns ``((−k̃, −c̃), (d, d, 0.001, 0.5, 2))``.
    """
    d = float(impedance)
    scale = (1.0 - d) * float(diag_approx)
    solref = (-scale * float(stiffness), -scale * float(damping))
    solimp = (d, d, 0.001, 0.5, 2.0)
    return solref, solimp


def _tip_diag_approx(mujoco, xml: str) -> float:
    """W = efc_diagA of the tip–plane contact row: body_invweight0 of the tip's body (the plane's
    body, the world, has 0), computed by MuJoCo's compiler at qpos0."""
    model = mujoco.MjModel.from_xml_string(xml)
    b = model.geom_bodyid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "tip")]
    return float(model.body_invweight0[b, 0] + model.body_invweight0[0, 0])


def mjcf_two_link(arm, surface, contact, *, timestep: float, integrator: str = "RK4") -> str:
    """MJCF XML of the TRUE two-link arm and inclined surface with a calibrated contact.

    ``arm``: :class:`~hinfnn.TwoLinkArm` (point masses m1, m2 at the tips of links l1, l2,
    gravity g); ``surface``: :class:`~hinfnn.InclinedLine` (x2 = (x1 − d_G) tan δ, material
    below); ``contact``: :class:`~hinfnn.PenaltyContact` (stiffness N/m, damping N·s/m).
    The contact's ``solref``/``solimp`` come from :func:`contact_solref` with W read from a
    first compilation of the same model (W does not depend on solref). Needs ``mujoco``.
    """
    mujoco = require_mujoco()
    _check_models(arm, surface, contact)
    if integrator not in INTEGRATORS:
        raise ConfigError(f"must be one of {INTEGRATORS}, got {integrator!r}", key="plant.integrator")
    if not (isinstance(timestep, (int, float)) and math.isfinite(timestep) and timestep > 0):
        raise ConfigError(f"must be a number > 0 (s), got {timestep!r}", key="plant.timestep")
    draft = _mjcf(arm, surface, timestep=timestep, integrator=integrator, solref=(-1.0, 0.0),
                  solimp=(IMPEDANCE, IMPEDANCE, 0.001, 0.5, 2.0))
    W = _tip_diag_approx(mujoco, draft)
    solref, solimp = contact_solref(contact.stiffness, contact.damping, W)
    return _mjcf(arm, surface, timestep=timestep, integrator=integrator, solref=solref, solimp=solimp)


# --------------------------------------------------------------------------------------------
# The plant
# --------------------------------------------------------------------------------------------
@pytree_dataclass
class MujocoState:
    """The MuJoCo plant's state: everything a step is a pure function of, plus what the sensors
    read at this state (computed by MuJoCo at the end of the step that produced it).

    q, qd, qacc_warmstart (n,): MuJoCo's qpos, qvel and solver warm start; F (2,): force the
    tip exerts on the surface (from ``efc_force``); normal_force, penetration: scalars; x_true
    (2,): tip site position.
    """

    q: jax.Array
    qd: jax.Array
    qacc_warmstart: jax.Array
    F: jax.Array
    normal_force: jax.Array
    penetration: jax.Array
    x_true: jax.Array


class _Engine:
    """The host side: an MjModel, a pool of reusable MjData and the packed layouts.

    Packed input row (one per call and batch element), MuJoCo's own state layout after dt:
    ``[dt, time, qpos (n), qvel (nv), qacc_warmstart (nv), qfrc_applied (nv)]`` (the
    ``mjSTATE_TIME | QPOS | QVEL | WARMSTART | QFRC_APPLIED`` state, set with one
    ``mj_setState``); a NaN dt marks an unusable row (the program sets it when any input is not
    finite). Packed output row: ``[qpos, qvel, qacc_warmstart, qacc (nv), F (2), f_n, p, x (2)]``.
    """

    def __init__(self, mujoco, xml: str, arm, surface, contact):
        self.mujoco = mujoco
        self.xml = xml
        self.arm, self.surface, self.contact = arm, surface, contact
        self.model = m = mujoco.MjModel.from_xml_string(xml)
        self.timestep = float(m.opt.timestep)
        self.nq, self.nv = n, nv = int(m.nq), int(m.nv)
        self.tip_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "tip")
        self.plane_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "surface")
        self.tip_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tip")
        self.tip_radius = float(m.geom_size[self.tip_geom, 0])
        S = mujoco.mjtState
        self.spec_in = int(S.mjSTATE_TIME | S.mjSTATE_QPOS | S.mjSTATE_QVEL | S.mjSTATE_WARMSTART
                           | S.mjSTATE_QFRC_APPLIED)
        self.spec_out = int(S.mjSTATE_QPOS | S.mjSTATE_QVEL | S.mjSTATE_WARMSTART)
        assert mujoco.mj_stateSize(m, self.spec_in) == 1 + n + 3 * nv
        self.size_in = 2 + n + 3 * nv
        self.size_out = n + 3 * nv + 6
        self._o = n + 3 * nv  # where F, f_n, p, x start in the output row
        self._nsub_cache = (None, 0)
        # The plane is static: its outward normal and a point on it, once, from MuJoCo's data.
        d = mujoco.MjData(m)
        mujoco.mj_kinematics(m, d)
        nrm = d.geom_xmat[self.plane_geom].reshape(3, 3)[:, 2]
        self._n_out = (float(nrm[0]), float(nrm[2]))
        self._plane_pt = (float(d.geom_xpos[self.plane_geom, 0]), float(d.geom_xpos[self.plane_geom, 2]))
        # The only constraint rows the model can have are this contact's (no limits, equalities,
        # friction loss; condim 1): then efc_force[0] is the contact's normal force.
        self._one_row = (m.npair == 1 and m.neq == 0 and not m.jnt_limited.any()
                         and not m.dof_frictionloss.any() and int(m.pair_dim[0]) == 1)
        # A pool of MjData: a callback takes one, uses it and puts it back (list.pop/append are
        # atomic). Not threading.local: XLA runs callbacks on its own threads, whose Python
        # thread state is created and torn down around each call, and an MjData freed in that
        # teardown crashes the process (seen with jax 0.10.2 / mujoco 4.0.0).
        self._pool = [self._new_views()]

    def __repr__(self):  # appears in jaxprs as a primitive parameter
        return f"<MuJoCo two-link engine {id(self):#x}>"

    def _new_views(self):
        d = self.mujoco.MjData(self.model)
        return d, d.qacc, d.site_xpos

    def _acquire(self):
        try:
            return self._pool.pop()
        except IndexError:  # another thread holds the others: one more MjData
            return self._new_views()

    def _nsub(self, dt: float) -> int:
        last_dt, nsub = self._nsub_cache
        if dt == last_dt:
            return nsub
        if not (math.isfinite(dt) and dt > 0):
            return 0  # the row is unusable (NaN dt) or dt is absurd
        nsub = round(dt / self.timestep)
        if nsub < 1 or abs(nsub * self.timestep - dt) > 1e-9 * dt:
            nsub = 0  # not a whole number of MuJoCo timesteps (checked at trace time too)
        self._nsub_cache = (dt, nsub)
        return nsub

    def _sense(self, d, site_xpos, out):
        """Fill out[o:o+6] with F (2), f_n, p, x (2) at the state in d (after a forward pass):
        MuJoCo's constraint force and kinematics."""
        o = self._o
        x = site_xpos[self.tip_site]
        x1, x2 = float(x[0]), float(x[2])
        nx, nz = self._n_out
        # signed distance of the tip to MuJoCo's plane (which lies TIP_RADIUS inside the true
        # surface): the penetration of the tip point into the true surface, > 0 inside
        p = self.tip_radius - (nx * (x1 - self._plane_pt[0]) + nz * (x2 - self._plane_pt[1]))
        nefc = d.nefc
        if nefc == 0:
            F1 = F2 = fn = 0.0
        elif nefc == 1 and self._one_row:
            # the contact's normal force (>= 0); the tip presses on the surface along −n_out
            fn = float(d.efc_force[0])
            F1, F2 = -fn * nx, -fn * nz
        else:  # pragma: no cover - not with the generated model
            F1, F2, fn = self._sense_general(d)
        out[o] = F1
        out[o + 1] = F2
        out[o + 2] = fn
        out[o + 3] = p
        out[o + 4] = x1
        out[o + 5] = x2

    def _sense_general(self, d):
        """Sum over the contacts of mj_contactForce in their frames (any model)."""
        F1 = F2 = fn = 0.0
        buf = np.zeros(6)
        for i in range(d.ncon):
            con = d.contact[i]
            if con.efc_address < 0:
                continue
            self.mujoco.mj_contactForce(self.model, d, i, buf)
            fw = con.frame.reshape(3, 3).T @ buf[:3]  # on geom2, along the normal geom1 → geom2
            sgn = -1.0 if con.geom[1] == self.tip_geom else 1.0
            F1 += sgn * fw[0]
            F2 += sgn * fw[2]
            fn += buf[0]
        return F1, F2, fn

    def step_row(self, xin, out):
        """One plant step from one packed input row into one packed output row."""
        mujoco, m = self.mujoco, self.model
        nsub = self._nsub(xin[0])  # NaN dt (unusable row) gives 0 too
        if nsub == 0:
            out[:] = np.nan
            return
        v = self._acquire()
        try:
            d, qacc, site_xpos = v
            mujoco.mj_setState(m, d, xin[1:], self.spec_in)
            for _ in range(nsub):
                mujoco.mj_step(m, d)
            k = self._o - self.nv
            mujoco.mj_getState(m, d, out[:k], self.spec_out)
            out[k:self._o] = qacc  # of the last substep, before the sensing pass
            mujoco.mj_forward(m, d)  # the sensors at the new state (this step's τ still applied)
            self._sense(d, site_xpos, out)
        finally:
            self._pool.append(v)

    def init_row(self, xin, out):
        """Packed output row of the state (q, qd), zero warm start, no applied torque."""
        mujoco, m = self.mujoco, self.model
        n, nv = self.nq, self.nv
        if not math.isfinite(float(np.sum(xin))):
            out[:] = np.nan
            return
        v = self._acquire()
        try:
            d, qacc, site_xpos = v
            state = np.zeros(1 + n + 3 * nv)
            state[1:1 + n + nv] = xin[:n + nv]
            mujoco.mj_setState(m, d, state, self.spec_in)
            mujoco.mj_forward(m, d)
            k = self._o - nv
            mujoco.mj_getState(m, d, out[:k], self.spec_out)
            out[k:self._o] = qacc
            self._sense(d, site_xpos, out)
        finally:
            self._pool.append(v)

    # host functions: any leading batch shape (rows stepped in turn)
    def _batched(self, row_fn, x):
        x = np.asarray(x, dtype=np.float64)
        lead = x.shape[:-1]
        rows = x.reshape(-1, x.shape[-1])
        out = np.empty((rows.shape[0], self.size_out), dtype=np.float64)
        for i in range(rows.shape[0]):
            row_fn(np.ascontiguousarray(rows[i]), out[i])
        return out.reshape(lead + (self.size_out,))

    def host_step(self, x):
        if type(x) is not np.ndarray:  # jax.pure_callback hands over JAX arrays
            x = np.asarray(x, dtype=np.float64)
        if x.ndim == 1:  # the common, unbatched case; XLA's buffers are contiguous float64
            out = np.empty(self.size_out, dtype=np.float64)
            self.step_row(x, out)
            return out
        return self._batched(self.step_row, x)

    def host_init(self, x):
        return self._batched(self.init_row, x)


def _check_divides(timestep: float, period: float, key: str, what: str):
    nsub = round(period / timestep)
    if nsub < 1 or abs(nsub * timestep - period) > 1e-9 * period:
        raise ConfigError(f"the MuJoCo timestep {timestep:g} s must divide the {what} {period:g} s "
                          f"(a whole number of MuJoCo steps per control period)", key=key)
    return nsub


#: How the compiled program calls MuJoCo (:meth:`MujocoPlant.from_models`, ``callback``).
CALLBACKS = ("host", "pure_callback")

_PRIMITIVES: dict = {}


def _host_primitive(kind: str):
    """A JAX primitive whose CPU lowering calls ``engine.host_step``/``host_init`` on the raw
    NumPy buffers XLA hands to its Python-callback custom call (what :func:`jax.pure_callback`
    does, without the ``device_put`` of every argument and the default-device context it adds
    per call: 9 µs instead of 70–130 µs per call on this machine, docs/mujoco.md). Uses JAX
    internals (``jax._src.callback.emit_python_callback``, pinned jax 0.10.2); returns None when
    they are missing, and the plant then uses :func:`jax.pure_callback`."""
    if kind in _PRIMITIVES:
        return _PRIMITIVES[kind]
    prim = None
    try:
        from jax._src.callback import emit_python_callback
        from jax.extend.core import Primitive
        from jax.interpreters import batching, mlir
    except ImportError:  # pragma: no cover - another JAX
        _PRIMITIVES[kind] = None
        return None
    prim = Primitive(f"hinfnn_mujoco_{kind}")

    def host_fn(engine):
        return engine.host_step if kind == "step" else engine.host_init

    def impl(x, *, engine):
        return jnp.asarray(host_fn(engine)(np.asarray(x, dtype=np.float64)))

    def abstract(x, *, engine):
        return jax.core.ShapedArray(x.shape[:-1] + (engine.size_out,), np.dtype(np.float64))

    def lower(ctx, x, *, engine):
        fn = host_fn(engine)
        res, _, _ = emit_python_callback(ctx, lambda a: (fn(a),), None, [x], ctx.avals_in,
                                         ctx.avals_out, has_side_effect=False, returns_token=False)
        return res

    def batch(args, dims, *, engine):
        # the host function takes any leading batch shape and steps the rows in turn
        (x,), (bd,) = args, dims
        return prim.bind(jnp.moveaxis(x, bd, 0), engine=engine), 0

    prim.def_impl(impl)
    prim.def_abstract_eval(abstract)
    mlir.register_lowering(prim, lower, cacheable=False)
    batching.primitive_batchers[prim] = batch
    _PRIMITIVES[kind] = prim
    return prim


def _call_host(engine, kind: str, x, callback: str):
    """engine.host_<kind>(x) from inside a traced program: one host call for any batch."""
    if callback == "host":
        prim = _host_primitive(kind)
        if prim is not None:
            return prim.bind(x, engine=engine)
    fn = engine.host_step if kind == "step" else engine.host_init
    return jax.pure_callback(fn, jax.ShapeDtypeStruct(x.shape[:-1] + (engine.size_out,), jnp.float64),
                             x, vmap_method="broadcast_all")


class MujocoPlant(DiscretePlant):
    """MuJoCo as the true plant, driven at the control rate (sampled data, zero-order hold).

    Protocol (what hinfnn's simulator uses)::

        plant.n, plant.discrete (True)
        plant.initial_state(q0, qd0=None) -> MujocoState
        plant.sense(t, state) -> (Measurement(q, qd, F), diagnostics)
        plant.step(t, state, tau, dt) -> (new_state, qdd)

    ``step`` and ``initial_state`` are one host call into MuJoCo each (whatever the number of
    substeps), usable inside ``jit``, ``lax.scan`` and ``vmap`` (batch rows are stepped one
    after the other in the same call); ``sense`` is pure JAX on the state, whose sensor fields
    MuJoCo filled at the end of the step that produced it. Build it with :meth:`from_models`.
    The MuJoCo model is a compile-time constant of every program that uses the plant (the plant
    is a pytree whose only data leaf is the disturbance; its engine is static, hashed by
    identity). Not differentiable (no JVP rule).
    """

    def __init__(self, engine: _Engine, disturbance, control_period: float, callback: str = "host"):
        self._engine = engine
        self.callback = callback
        self.arm = engine.arm
        self.surface = engine.surface
        self.contact = engine.contact
        self.disturbance = disturbance
        self.control_period = float(control_period)
        self.n = engine.nv

    # --- construction -------------------------------------------------------------------------
    @classmethod
    def from_models(cls, arm, surface, contact, disturbance, *, control_period: float,
                    timestep: float | None = None, integrator: str = "RK4",
                    callback: str = "host") -> "MujocoPlant":
        """The MuJoCo plant of a TRUE arm (:class:`~hinfnn.TwoLinkArm`), surface
        (:class:`~hinfnn.InclinedLine`), contact (:class:`~hinfnn.PenaltyContact`, N/m and
        N·s/m) and joint disturbance (:class:`~hinfnn.SquareWave`).

        ``timestep`` (MuJoCo's, s) defaults to ``control_period`` and must divide it;
        ``integrator``: one of :data:`INTEGRATORS`. ``callback``: how compiled programs call
        MuJoCo, ``"host"`` (default: a primitive lowered to XLA's Python host callback, the
        fastest measured) or ``"pure_callback"`` (:func:`jax.pure_callback`, public API, about
        10x the per-call overhead). Raises :class:`ConfigError` naming the field.
        """
        mujoco = require_mujoco()
        if callback not in CALLBACKS:
            raise ConfigError(f"must be one of {CALLBACKS}, got {callback!r}", key="plant.callback")
        if not (isinstance(control_period, (int, float)) and math.isfinite(control_period)
                and control_period > 0):
            raise ConfigError(f"must be a number > 0 (s), got {control_period!r}",
                              key="simulation.control_period")
        control_period = float(control_period)
        ts = control_period if timestep is None else timestep
        if not (isinstance(ts, (int, float)) and math.isfinite(ts) and ts > 0):
            raise ConfigError(f"must be a number > 0 (s), got {timestep!r}", key="plant.timestep")
        _check_divides(float(ts), control_period, "plant.timestep", "control period")
        xml = mjcf_two_link(arm, surface, contact, timestep=float(ts), integrator=integrator)
        return cls(_Engine(mujoco, xml, arm, surface, contact), disturbance, control_period, callback)

    # --- read-only facts ----------------------------------------------------------------------
    @property
    def xml(self) -> str:
        """The MJCF of the model being simulated."""
        return self._engine.xml

    @property
    def model(self):
        """The compiled ``mujoco.MjModel`` (do not modify it while a run uses the plant)."""
        return self._engine.model

    @property
    def timestep(self) -> float:
        return self._engine.timestep

    def _rigid(self):
        from .rigid import RigidBodyPlant

        return RigidBodyPlant(self.arm, self.surface, self.contact, self.disturbance)

    def initial_q(self, u1_0, elbow_up: bool = True):
        """Joint angles with the tip at x1 = u1_0 on the true surface (as
        :meth:`hinfnn.RigidBodyPlant.initial_q`)."""
        return self._rigid().initial_q(u1_0, elbow_up)

    def effective_mass(self, q):
        """The true arm's effective mass along the surface's normal at q (for the step-size check)."""
        return self._rigid().effective_mass(q)

    # --- protocol -----------------------------------------------------------------------------
    def _unpack(self, y):
        n, nv = self._engine.nq, self._engine.nv
        o = n + 3 * nv
        state = MujocoState(q=y[..., 0:n], qd=y[..., n:n + nv], qacc_warmstart=y[..., n + nv:n + 2 * nv],
                            F=y[..., o:o + 2], normal_force=y[..., o + 2], penetration=y[..., o + 3],
                            x_true=y[..., o + 4:o + 6])
        return state, y[..., n + 2 * nv:o]

    def initial_state(self, q0, qd0=None) -> MujocoState:
        """The state at joint angles q0 and rates qd0 (default 0), at rest warm start; the
        sensor fields are MuJoCo's at that state with no applied torque."""
        q0 = jnp.asarray(q0, dtype=jnp.float64)
        qd0 = jnp.zeros_like(q0) if qd0 is None else jnp.asarray(qd0, dtype=jnp.float64)
        x = jnp.concatenate([q0, qd0], axis=-1)
        return self._unpack(_call_host(self._engine, "init", x, self.callback))[0]

    def sense(self, t, state: MujocoState):
        """``(Measurement(q, q̇, F), diagnostics)`` at this state. Pure JAX (no callback).

        F: the task-space force the tip exerts on the surface, from MuJoCo's constraint force
        (same convention as :class:`hinfnn.Plant`: the arm feels −Jᵀ F). diagnostics:
        ``normal_force`` (N, ≥ 0), ``penetration`` (m, > 0 inside, minus the height above the
        surface outside), ``F``, ``x_true`` (tip position), ``disturbance`` (the joint torque
        the step from t over one control period applies: d(t + control_period/2)).
        """
        t = jnp.asarray(t, dtype=jnp.float64)
        meas = Measurement(q=state.q, qd=state.qd, force=state.F)
        diag = {"normal_force": state.normal_force, "penetration": state.penetration, "F": state.F,
                "x_true": state.x_true, "disturbance": self.disturbance(t + 0.5 * self.control_period)}
        return meas, diag

    def joints(self, state: MujocoState):
        return state.q, state.qd

    def step_input(self, t, dt):
        """The joint disturbance of the step [t, t + dt): d(t + dt/2) (what :meth:`step` applies)."""
        return self.disturbance(t + 0.5 * dt)

    def record(self, state: MujocoState, w, cache) -> PlantRecord:
        return PlantRecord(penetration=state.penetration,
                           signals={"q": state.q, "qd": state.qd, "normal_force": state.normal_force,
                                    "disturbance": w, "x_true": state.x_true})

    def step(self, t, state: MujocoState, tau, dt):
        """Advance by ``dt`` (a whole number of MuJoCo timesteps) with τ and the disturbance
        d(t + dt/2) held as joint torques. Returns ``(new_state, qdd)``, qdd = MuJoCo's
        ``data.qacc`` after the last substep (RK4: its 4th stage; Euler and implicit*: at the
        start of the last substep). A non-finite input or a dt that is not a whole number of
        timesteps gives an all-NaN state (MuJoCo is not called)."""
        if isinstance(dt, (int, float, np.integer, np.floating)):
            _check_divides(self.timestep, float(dt), "plant.timestep", "step dt")
        t = jnp.asarray(t, dtype=jnp.float64)
        dt = jnp.asarray(dt, dtype=jnp.float64)
        tau = jnp.asarray(tau, dtype=jnp.float64)
        w = self.disturbance(t + 0.5 * dt)
        x = jnp.concatenate([dt[..., None], t[..., None], state.q, state.qd, state.qacc_warmstart,
                             tau + w], axis=-1)
        # one NaN dt tells the host the row is unusable (any non-finite input): MuJoCo is not called
        ok = jnp.all(jnp.isfinite(x), axis=-1, keepdims=True)
        x = jnp.where(ok, x, jnp.nan)
        return self._unpack(_call_host(self._engine, "step", x, self.callback))


def _flatten(plant: MujocoPlant):
    # the engine (model, MjData, true models) is static and hashed by identity; the disturbance
    # is data (batchable: it is evaluated in JAX and passed to MuJoCo as a joint torque)
    return (plant.disturbance,), (plant._engine, plant.control_period, plant.callback)


def _unflatten(aux, children):
    engine, period, callback = aux
    return MujocoPlant(engine, children[0], period, callback)


jax.tree_util.register_pytree_node(MujocoPlant, _flatten, _unflatten)
