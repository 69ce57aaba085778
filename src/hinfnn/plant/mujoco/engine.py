"""The MuJoCo plant: MuJoCo's C step inside hinfnn's compiled loop (docs/mujoco.md).

* :class:`MujocoPlant` — the plant protocol (``n``, ``discrete``, ``initial_state``, ``sense``,
  ``step``). ``step`` is ONE host call per control period, whatever the number of MuJoCo substeps
  and whatever the batch: the compiled program hands the host a block of packed rows (one per
  batch member), the host steps them with :class:`mujoco.batch.Batch` (MuJoCo's own thread pool,
  each member on its own model) and hands back one block. ``sense`` is pure JAX on the state.
* :class:`MujocoState` — joint state, MuJoCo's solver warm start, and what the sensors read at
  that state (computed in JAX from MuJoCo's tool-site pose, its Jacobian and its contact force).

Batches. Plants whose MuJoCo models have the same data layout (every size of ``MjData``: the
same arm structure with other masses, payloads, surface poses or contact parameters) share a
*family* (:class:`_Family`); a plant is a pytree whose leaves are its index in the family
(``member``), the joint disturbance and the sensing data (true surface, task map), so any number
of them stack into one ``vmap`` batch and one compiled program serves them all.
"""

from __future__ import annotations

import math
import os
import threading
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ... import _linalg as la
from ..._pytree import pytree_dataclass
from ...errors import ConfigError, is_real
from ...protocols import DiscretePlant, Measurement, PlantRecord
from ..limits import limit_record
from . import scene as S

#: How the compiled program calls MuJoCo (:meth:`MujocoPlant.from_models`, ``callback``).
CALLBACKS = ("host", "pure_callback")


# --------------------------------------------------------------------------------------------
# Host side
# --------------------------------------------------------------------------------------------
class _Family:
    """MuJoCo models sharing one data layout, and the host functions that step them.

    Packed input row: ``[member, dt, time, qpos (nq), qvel (nv), qacc_warmstart (nv),
    qfrc_applied (nv)]``; a row with any non-finite entry (or a dt that is not a whole number of
    the member's timesteps) is not stepped and gives an all-NaN output row. Packed output row:
    ``[qpos, qvel, qacc_warmstart, qacc, tool position (3), tool rotation (9, row-major),
    jacp (3 n, row-major), jacr (3 n), contact sensor (found, force (3, contact frame, on the
    tool), dist, normal (3, surface → tool), tangent (3))]`` at the END of the step: after the
    substeps, MuJoCo's forward pass at the new state with the step's applied force still applied
    (what a sensor reads just before the next torque arrives).

    A member with viscous tool friction (c_v > 0, :attr:`viscous`) is stepped one MuJoCo step at
    a time with the viscous force applied at the tool point (:meth:`_step_viscous`), and that force
    is added to the contact sensor's tangential force in the output row.
    """

    def __init__(self, mujoco, scene: S.Scene, signature):
        self.mujoco = mujoco
        self.signature = signature
        m = scene.model
        self.n, self.nq, self.nv = scene.n, int(m.nq), int(m.nv)
        self.site, self.site_body, self.sensor_adr = scene.site, scene.site_body, scene.sensor_adr
        self.size_in = 3 + self.nq + 3 * self.nv
        self.size_out = self.nq + 3 * self.nv + 12 + 6 * self.n + S.SENSOR_SIZE
        self.scenes: dict[int, S.Scene] = {}
        self.meta: dict[int, object] = {}
        #: viscous tool friction c_v (N·s/m) of each member (absent: 0)
        self.viscous: dict[int, float] = {}
        self._first = scene
        self._free: dict[int, list] = {}
        self._lock = threading.Lock()
        self.nthread = max(1, min(4, os.cpu_count() or 1))
        st = mujoco.mjtState
        self._spec = int(st.mjSTATE_TIME | st.mjSTATE_QPOS | st.mjSTATE_QVEL | st.mjSTATE_WARMSTART
                         | st.mjSTATE_QFRC_APPLIED)
        self._spec_out = int(st.mjSTATE_QPOS | st.mjSTATE_QVEL | st.mjSTATE_WARMSTART)
        assert self.nv == self.n  # every degree of freedom is an arm joint (checked when the scene is built)
        a = self.nq + 2 * self.nv
        self._offsets = np.cumsum([a, self.nv, 3, 9, 3 * self.n, 3 * self.n]).tolist()
        self._slots: dict = {}
        #: step single rows with mujoco.batch too (tests compare the two paths)
        self.always_batch = False

    def add(self, scene: S.Scene, meta, key: int) -> int:
        """Register a model under its content key (the same key: the same model, kept once)."""
        with self._lock:
            if key not in self.scenes:
                self.scenes[key] = scene
                self.meta[key] = meta
                c_v = _viscous_of(getattr(meta, "friction", None))
                if c_v > 0.0:
                    self.viscous[key] = c_v
            _MEMBERS[key] = self
            return key

    def _scene(self, key: int) -> S.Scene:
        try:
            return self.scenes[key]
        except KeyError:
            raise RuntimeError(f"MuJoCo model {key} is not known in this process (process {os.getpid()}): a MuJoCo "
                               "plant's models live in the process that built it; build the plant here "
                               "(e.g. from its scenario) instead of passing its leaves from another process") from None

    # one Batch per concurrent call and batch size (XLA may call from several threads)
    def _acquire(self, rows: int):
        with self._lock:
            free = self._free.setdefault(rows, [])
            if free:
                return free.pop()
        from mujoco import batch as mjbatch

        b = mjbatch.Batch(self._first.model, nsim=rows, nthread=min(rows, self.nthread))
        views = {k: b.bind(k) for k in ("time", "qpos", "qvel", "qacc_warmstart", "qfrc_applied", "qacc",
                                        "site_xpos", "site_xmat", "sensordata")}
        return [b, views, None]

    def _release(self, rows: int, item):
        with self._lock:
            self._free[rows].append(item)

    def _one(self, x, kind: str, out=None):
        """One row, on a pooled MjData (the unbatched case, without the batch's array bookkeeping:
        a run's every control period), written into ``out``. The same numbers as the batch path
        (tested). Every MuJoCo output is written in place: the state by ``mj_getState``, the
        Jacobians by ``mj_jacSite`` into the output row itself."""
        if out is None:
            out = np.empty(self.size_out)
        if not math.isfinite(x.sum()):
            out.fill(np.nan)
            return out
        slot = self._slots.get(int(x[0]))
        if slot is None:
            slot = self._slot(int(x[0]))
        m, ts, pool, c_v = slot
        nsub = 0
        if kind == "step":
            nsub = round(x[1] / ts)
            if nsub < 1 or abs(nsub * ts - x[1]) > 1e-9 * x[1]:
                out.fill(np.nan)
                return out
        d = pool.pop() if pool else self.mujoco.MjData(m)  # list.pop/append: atomic under the GIL
        try:
            mj = self.mujoco
            mj.mj_setState(m, d, x[2:], self._spec)
            try:
                if c_v > 0.0:
                    f_v = self._step_viscous(m, d, nsub, c_v, x[-self.nv:], 0.5 * ts)
                else:
                    for _ in range(nsub):
                        mj.mj_step(m, d)
                    mj.mj_forward(m, d)
            except Exception:  # MuJoCo raised (mju_error): this row is unusable
                out.fill(np.nan)
                return out
            o = self._offsets
            mj.mj_getState(m, d, out[:o[0]], self._spec_out)
            out[o[0]:o[1]] = d.qacc
            out[o[1]:o[2]] = d.site_xpos[self.site]
            out[o[2]:o[3]] = d.site_xmat[self.site]
            mj.mj_jacSite(m, d, out[o[3]:o[4]].reshape(3, self.nv), out[o[4]:o[5]].reshape(3, self.nv), self.site)
            out[o[5]:] = d.sensordata[self.sensor_adr:self.sensor_adr + S.SENSOR_SIZE]
            if c_v > 0.0:
                _add_to_sensor(out[o[5]:], f_v)
            return out
        finally:
            pool.append(d)

    def _slot(self, key: int):
        scene = self._scene(key)
        slot = (scene.model, scene.timestep, [], self.viscous.get(key, 0.0))
        self._slots[key] = slot
        return slot

    # --- viscous tool friction ------------------------------------------------------------------
    def _step_viscous(self, m, d, nsub: int, c_v: float, base, half: float):
        """``nsub`` MuJoCo steps of d (its state set, ``qfrc_applied`` = ``base``) with the viscous
        tool friction: before each step, after a forward pass at that step's state, the force F_v
        (:func:`_viscous_force`) at the step's midpoint velocity q̇ + ``half`` q̈ (``half`` = half
        the timestep; q̈ of that forward pass) is applied as ``qfrc_applied`` = base − J_pᵀ F_v and
        held over the step (``mj_step``); at the end state the forward pass with the force at
        that state's velocity (what the sensor reads). Returns that force (zeros out of contact).
        :meth:`_run_viscous` does the same on a batch, with the same numbers."""
        mj = self.mujoco
        jacp = np.empty((3, self.nv))
        adr, site = self.sensor_adr, self.site
        zero = np.zeros(3)
        applied = False  # d.qfrc_applied holds a viscous force (else: base)
        mj.mj_forward(m, d)
        for k in range(nsub + 1):
            sensor = d.sensordata[adr:adr + S.SENSOR_SIZE]
            f = zero
            if sensor[0] > 0.0 and sensor[1] > 0.0:  # in contact, pushing
                mj.mj_jacSite(m, d, jacp, None, site)
                f = _viscous_force(jacp, d.qvel if k == nsub else d.qvel + half * d.qacc, sensor, c_v)
                d.qfrc_applied[:] = base - f @ jacp
                applied = True
            elif applied:
                d.qfrc_applied[:] = base
                applied = False
            if k == nsub:
                mj.mj_forward(m, d)
                return f
            mj.mj_step(m, d)
            mj.mj_forward(m, d)

    def run(self, x, kind: str):
        """Step (``kind`` "step") or initialise ("init") every row of x (rows, size_in)."""
        mujoco = self.mujoco
        x = np.asarray(x, dtype=np.float64)
        rows = x.shape[0]
        if rows == 1 and not self.always_batch:
            return self._one(np.ascontiguousarray(x[0]), kind)[None]
        out = np.full((rows, self.size_out), np.nan)
        member = np.where(np.isfinite(x[:, 0]), x[:, 0], -1).astype(np.int64)
        for key in set(member[np.isfinite(x[:, 0])].tolist()):
            self._scene(key)  # an unknown model is an error, not a NaN
        ok = np.all(np.isfinite(x), axis=1)
        nsub = np.zeros(rows, dtype=np.int64)
        if kind == "step":
            for i in np.nonzero(ok)[0]:
                ts = self.scenes[member[i]].timestep
                k = round(x[i, 1] / ts)
                if k >= 1 and abs(k * ts - x[i, 1]) <= 1e-9 * x[i, 1]:
                    nsub[i] = k
                else:
                    ok[i] = False
        idx = np.nonzero(ok)[0]
        if idx.size == 0:
            return out
        item = self._acquire(rows)
        try:
            b, v, models = item
            want = tuple(int(member[i]) if ok[i] else int(member[idx[0]]) for i in range(rows))
            if want != models:
                b.set_models([self.scenes[i].model for i in want])
                item[2] = want
            nq, nv = self.nq, self.nv
            o = 2
            v["time"][idx] = x[idx, o]
            v["qpos"][idx] = x[idx, o + 1:o + 1 + nq]
            v["qvel"][idx] = x[idx, o + 1 + nq:o + 1 + nq + nv]
            v["qacc_warmstart"][idx] = x[idx, o + 1 + nq + nv:o + 1 + nq + 2 * nv]
            v["qfrc_applied"][idx] = x[idx, o + 1 + nq + 2 * nv:o + 1 + nq + 3 * nv]
            failed = []
            c_v = np.array([self.viscous.get(int(member[i]), 0.0) for i in idx])
            vidx, plain = idx[c_v > 0.0], idx[c_v == 0.0]
            try:
                if kind == "step":
                    for k in np.unique(nsub[plain]):
                        b.step(ids=plain[nsub[plain] == k], nstep=int(k), stage=mujoco.mjtStage.mjSTAGE_ACC)
                elif plain.size:
                    b.forward(ids=plain)
            except Exception as err:  # mujoco.batch.SimulationError: those members keep their old state
                failed = list(getattr(err, "ids", plain))
            if vidx.size:
                half = np.array([0.5 * self.scenes[int(member[i])].timestep for i in vidx])
                f_v, vfailed = self._run_viscous(b, v, vidx, nsub[vidx], c_v[c_v > 0.0], half,
                                                 x[vidx, o + 1 + nq + 2 * nv:o + 1 + nq + 3 * nv])
                failed += vfailed
            good = np.setdiff1d(idx, np.asarray(failed, dtype=np.int64))
            if good.size == 0:
                return out
            site = self.site
            jacp, jacr = b.jac(np.full(good.size, self.site_body), v["site_xpos"][good, site], ids=good)
            c = 0
            for arr in (v["qpos"][good], v["qvel"][good], v["qacc_warmstart"][good], v["qacc"][good],
                        v["site_xpos"][good, site], v["site_xmat"][good, site],
                        jacp[:, :, :self.n].reshape(good.size, -1), jacr[:, :, :self.n].reshape(good.size, -1),
                        v["sensordata"][good, self.sensor_adr:self.sensor_adr + S.SENSOR_SIZE]):
                w = arr.shape[1]
                out[good, c:c + w] = arr
                c += w
            for j, i in enumerate(vidx):
                if i in good:
                    _add_to_sensor(out[i, c - S.SENSOR_SIZE:c], f_v[j])
        finally:
            self._release(rows, item)
        return out

    def _run_viscous(self, b, v, ids, nsub, c_v, half, base):
        """:meth:`_step_viscous` on the batch rows ``ids`` (their state and ``qfrc_applied`` =
        ``base`` in the batch's arrays ``v``), ``nsub`` MuJoCo steps each, one step at a time for
        all of them. Returns (F_v at each row's end state, the rows MuJoCo failed on: they are
        dropped)."""
        acc = int(self.mujoco.mjtStage.mjSTAGE_ACC)
        f_v = np.zeros((ids.size, 3))
        alive = np.ones(ids.size, dtype=bool)
        failed: list = []

        def call(fn, rows, **kw):
            try:
                fn(ids=ids[rows], **kw)
            except Exception as err:  # mujoco.batch.SimulationError: those rows are dropped
                bad = {int(i) for i in getattr(err, "ids", ids[rows])}
                failed.extend(bad)
                alive[[int(i) in bad for i in ids]] = False

        call(b.forward, alive.copy())
        adr = self.sensor_adr
        for k in range(int(nsub.max(initial=0)) + 1):
            rows = alive & (nsub >= k)
            if not rows.any():
                break
            sensor = v["sensordata"][:, adr:adr + S.SENSOR_SIZE]
            pushing = np.nonzero(rows & (sensor[ids, 0] > 0.0) & (sensor[ids, 1] > 0.0))[0]
            f_v[rows] = 0.0
            v["qfrc_applied"][ids[rows]] = base[rows]
            if pushing.size:
                sel = ids[pushing]
                jacp, _ = b.jac(np.full(sel.size, self.site_body), v["site_xpos"][sel, self.site], ids=sel)
                for j, i, J in zip(pushing, sel, jacp[:, :, :self.n]):
                    J = np.ascontiguousarray(J)
                    qd = v["qvel"][i] if nsub[j] == k else v["qvel"][i] + half[j] * v["qacc"][i]
                    f_v[j] = _viscous_force(J, qd, sensor[i], c_v[j])
                    v["qfrc_applied"][i] = base[j] - f_v[j] @ J
            if (rows & (nsub == k)).any():
                call(b.forward, rows & (nsub == k))
            if (rows & (nsub > k)).any():
                call(b.step, rows & (nsub > k), nstep=1, stage=acc)
        return f_v, failed

    def host_step(self, x):
        x = np.asarray(x, dtype=np.float64)
        lead = x.shape[:-1]
        return self.run(x.reshape(-1, x.shape[-1]), "step").reshape(lead + (self.size_out,))

    def host_init(self, x):
        x = np.asarray(x, dtype=np.float64)
        lead = x.shape[:-1]
        return self.run(x.reshape(-1, x.shape[-1]), "init").reshape(lead + (self.size_out,))


def _viscous_of(friction) -> float:
    """c_v (N·s/m) of a :class:`~hinfnn.plant.contact.Friction` (0 for None)."""
    return 0.0 if friction is None else float(friction.viscous)


def _viscous_force(jacp, qvel, sensor, c_v: float):
    """F_v = c_v v_t, the viscous force the tool exerts on the surface (world axes), v_t the tool
    point's velocity J_p q̇ less its part along the contact normal n (the surface's at the tool
    point): ``jacp`` (3, n) the tool point's Jacobian, ``qvel`` (n,), ``sensor`` the contact
    sensor's row after a forward pass at that state, taken while the contact pushes (its normal
    force > 0; out of it the force is 0). Implements docs/mujoco.md eq. (7), the built-in plant's
    viscous term (:meth:`hinfnn.plant.contact.Friction.force`)."""
    vel = jacp @ qvel
    n = sensor[5:8]
    return c_v * (vel - (n @ vel) * n)


def _add_to_sensor(sensor, f_v) -> None:
    """Add the viscous force F_v (the tool's on the surface, world) to a contact sensor row's
    force (on the tool, contact frame: normal, tangent t, n × t), in place: its tangential
    components gain −F_v·t and −F_v·(n × t) (F_v is tangential)."""
    n, t = sensor[5:8], sensor[8:11]
    sensor[2] -= f_v @ t
    sensor[3] -= f_v @ np.cross(n, t)


_FAMILIES: dict = {}
_FAMILIES_LOCK = threading.Lock()


def _family_of(scene: S.Scene, kind: str) -> _Family:
    """The family of models with this scene's data layout (created on first use)."""
    key = (kind,) + scene.signature()
    with _FAMILIES_LOCK:
        fam = _FAMILIES.get(key)
        if fam is None:
            fam = _FAMILIES[key] = _Family(S.require_mujoco(), scene, key)
        return fam


#: Every member key this process knows, and its family (the FFI handler finds a row's model here).
_MEMBERS: dict = {}


def _dispatch(kind: str, x, out) -> None:
    """The FFI handler's work (:mod:`.ffi`): step (or initialise) every row of x into out."""
    if x.ndim == 1 or x.shape[0] == 1 and x.ndim == 2:  # one row: the common case, straight through
        row, res = x.reshape(-1), out.reshape(-1)
        key = row[0]
        if not math.isfinite(key):
            res.fill(np.nan)
            return
        family = _MEMBERS.get(int(key))
        if family is not None and not family.always_batch:
            family._one(row, kind, res)
            return
    rows = x.reshape(-1, x.shape[-1])
    res = out.reshape(-1, out.shape[-1])
    keys = rows[:, 0][np.isfinite(rows[:, 0])]
    if keys.size == 0:
        res[...] = np.nan
        return
    key = int(keys[0])
    family = _MEMBERS.get(key)
    if family is None:
        raise RuntimeError(f"MuJoCo model {key} is not known in this process (process {os.getpid()}): a MuJoCo "
                           "plant's models live in the process that built it; build the plant here (e.g. from its "
                           "scenario) instead of passing its leaves from another process")
    res[...] = family.run(rows, kind)


def _call_host(family, kind: str, x, callback: str):
    """family.host_<kind>(x) from inside a traced program: one call for any batch.

    ``"host"``: the FFI custom call of :mod:`.ffi` (a compiled program that steps MuJoCo is cached
    like any other); ``"pure_callback"``: :func:`jax.pure_callback` (never cached: JAX does not
    write programs with Python callbacks to its persistent cache)."""
    if callback == "host":
        from . import ffi

        ffi.register(_dispatch)
        return ffi.call(kind, x, family.size_out)
    fn = family.host_step if kind == "step" else family.host_init
    return jax.pure_callback(fn, jax.ShapeDtypeStruct(x.shape[:-1] + (family.size_out,), jnp.float64),
                             x, vmap_method="broadcast_all")


# --------------------------------------------------------------------------------------------
# Sensing (JAX, from what MuJoCo computed at the end of the step)
# --------------------------------------------------------------------------------------------
def _contact_force(sensor):
    """(force the SURFACE exerts on the tool, world axes (3,), normal force f_n): from the contact
    sensor's force in the contact frame (normal from the surface to the tool, first tangent;
    second tangent = normal × tangent). Zero out of contact (the sensor reports zeros)."""
    f, n, t = sensor[..., 1:4], sensor[..., 5:8], sensor[..., 8:11]
    on_tool = f[..., 0:1] * n + f[..., 1:2] * t + f[..., 2:3] * jnp.cross(n, t)
    return on_tool, f[..., 0]


@pytree_dataclass
class LineSensing:
    """The paper's two-link arm on the inclined line: the arm's plane is the world's (x, z), its
    Cartesian coordinates (x1, x2) = (x, z) are also its task coordinates; the sensed force is
    the force the tip exerts on the surface in those coordinates."""

    surface: object

    @property
    def cartesian(self) -> bool:
        return False

    def __call__(self, p, R, Jf, sensor, q):
        on_tool, f_n = _contact_force(sensor)
        x = jnp.stack([p[0], p[2]])
        force = -jnp.stack([on_tool[0], on_tool[2]])
        return dict(x_true=x, force=force, normal_force=f_n, penetration=self.surface.signed_distance(x))


@pytree_dataclass
class CartesianSensing:
    """An arm with a task map (URDF, planar, a user's MJCF) on a Cartesian surface, as the
    built-in plant senses it (:meth:`hinfnn.RigidBodyPlant._sense_cartesian`), with MuJoCo's tool
    pose and contact force instead of hinfnn's: x_true = task(p, R), the penetration is the true
    surface's exact signed distance at the tool point, ``force`` the Cartesian force the tool
    exerts on the surface at the tool point, in the base frame's axes of the arm's space (2-D for
    planar arms: the plane's coordinates), what :class:`~hinfnn.protocols.Measurement` carries
    (the controller maps it into task coordinates with its nominal kinematics).

    A redundant arm's task (an :class:`~hinfnn.model.augmented.AugmentedTask`: extra coordinates
    such as the arm angle, functions of the joint angles) also needs ``chain``, the true arm's
    chain: its extra coordinates and their margins are computed from it at MuJoCo's joint angles."""

    task: object
    surface: object
    chain: object = None
    kernels: la.Kernels = la.kernels_field()  # how its products are written (hinfnn._linalg.Kernels)

    @property
    def cartesian(self) -> bool:
        return True

    def __call__(self, p, R, Jf, sensor, q):
        on_tool, f_n = _contact_force(sensor)
        rows = tuple(self.task.space_rows)
        point = self.task.space(p)
        F_c = -jnp.stack([on_tool[i] for i in rows])
        n_in = self.surface.normal(point)
        F_t = F_c - self.kernels.mm(n_in, F_c) * n_in
        if self.chain is None:
            x, margin = self.task(p, R), self.task.margin(p, R)
        else:
            x, margin = self.task.of_pose(self.chain, p, R, q), self.task.margin_pose(self.chain, p, R, q)
        return dict(x_true=x, force=F_c, normal_force=f_n, penetration=self.surface.signed_distance(point),
                    friction_force=jnp.sqrt(jnp.sum(F_t * F_t)), task_margin=margin)


@pytree_dataclass
class MujocoState:
    """The MuJoCo plant's state: everything a step is a pure function of, plus what the sensors
    read at this state (computed from MuJoCo at the end of the step that produced it).

    q, qd, qacc_warmstart (n,): MuJoCo's qpos, qvel and solver warm start; force (2 or 3,): the
    force the tool exerts on the surface at the tool point, in the base frame's axes of the arm's
    space (what the force sensor reads, :class:`~hinfnn.protocols.Measurement`); normal_force,
    penetration: scalars; x_true: the true task coordinates. Cartesian surfaces also:
    friction_force (the tangential magnitude of ``force``), task_margin."""

    q: jax.Array
    qd: jax.Array
    qacc_warmstart: jax.Array
    force: jax.Array
    normal_force: jax.Array
    penetration: jax.Array
    x_true: jax.Array
    friction_force: jax.Array | None = None
    task_margin: jax.Array | None = None


class _Meta:
    """What a plant's construction knew, for the eager queries (start pose, effective mass)."""

    def __init__(self, arm, surface, contact, friction, scene, friction_damping):
        self.arm, self.surface, self.contact, self.friction = arm, surface, contact, friction
        self.scene = scene
        self.friction_damping = friction_damping


def _content_key(scene: S.Scene, sensing, disturbance, viscous: float = 0.0) -> int:
    """A plant's member key: a 48-bit hash of its MuJoCo model (the MJCF at full precision), of
    its sensing data (task map, true surface) and of its viscous tool friction (not in the MJCF),
    exact in float64, the same in every process."""
    import hashlib

    from ..._pytree import value_key

    h = hashlib.sha256(scene.xml.encode())
    h.update(repr(value_key(sensing)).encode())
    h.update(repr((scene.source, scene.timestep)).encode())
    if viscous:
        h.update(repr(("viscous", float(viscous))).encode())
    return int.from_bytes(h.digest()[:6], "little")


def _check_divides(timestep: float, period: float, key: str, what: str):
    nsub = round(period / timestep)
    if nsub < 1 or abs(nsub * timestep - period) > 1e-9 * period:
        raise ConfigError(f"the MuJoCo timestep {timestep:g} s must divide the {what} {period:g} s "
                          f"(a whole number of MuJoCo steps per control period)", key=key)
    return nsub


class MujocoPlant(DiscretePlant):
    """MuJoCo as the true plant, driven at the control rate (sampled data, zero-order hold).

    A :class:`hinfnn.protocols.DiscretePlant`::

        plant.n
        plant.initial_state(q0, qd0=None) -> MujocoState
        plant.initial_q(u1_0, ...) -> the start pose on the true surface
        plant.sense(t, state) -> (Measurement(q, qd, force), None)
        plant.record(state, w, cache) -> PlantRecord (a joint past its limit: a fault)
        plant.step(t, state, tau, dt) -> (new_state, qdd)

    ``step`` and ``initial_state`` are one host call into MuJoCo each (whatever the number of
    substeps), usable inside ``jit``, ``lax.scan`` and ``vmap`` (a batch's rows are stepped in the
    same call by MuJoCo's thread pool); ``sense`` is pure JAX on the state. Build it with
    :meth:`from_models` (hinfnn's arms) or :meth:`from_mjcf` (a user's MJCF). The plant is a
    pytree whose leaves are its member index in its model family, the disturbance and the sensing
    data; the family (the MuJoCo models) is static, hashed by identity. Not differentiable.

    Joint limits are those of the true arm as hinfnn reads it (a URDF chain's; a user's MJCF:
    its joints' ``range``): like :class:`hinfnn.RigidBodyPlant`, the plant does not enforce them
    (the generated MJCF has none; a user's MJCF keeps its own), it records the margin and a joint
    past its limit stops the run (:attr:`~hinfnn.status.RunStatus.PLANT_FAULT`).
    """

    fault_name: ClassVar[str] = "joint limit margin (rad or m, < 0: past the true arm's limit)"

    def __init__(self, family: _Family, member, disturbance, sensing, control_period: float,
                 callback: str = "host", limits=None, sensor=None, actuator=None):
        self._family = family
        self.member = member
        self.disturbance = disturbance
        self.sensing = sensing
        self.control_period = float(control_period)
        self.callback = callback
        #: (lower, upper) joint limits of the true arm's chain (data: a batch stacks them), None
        #: for an arm without a chain (the two-link arm)
        self.limits = limits
        #: the robot's sensor and motors (None: ideal; :mod:`hinfnn.plant.instruments`)
        self.sensor = sensor
        self.actuator = actuator
        self.n = family.n

    # --- construction -------------------------------------------------------------------------
    @classmethod
    def _build(cls, scene, meta, sensing, disturbance, control_period, callback):
        if callback not in CALLBACKS:
            raise ConfigError(f"must be one of {CALLBACKS}, got {callback!r}", key="plant.callback")
        kind = type(sensing).__name__
        family = _family_of(scene, kind)
        member = family.add(scene, meta, _content_key(scene, sensing, disturbance, _viscous_of(meta.friction)))
        chain = getattr(meta.arm, "chain", None)
        limits = None if chain is None else (jnp.asarray(chain.lower, dtype=jnp.float64),
                                             jnp.asarray(chain.upper, dtype=jnp.float64))
        return cls(family, jnp.asarray(member, dtype=jnp.int64), disturbance, sensing, control_period, callback,
                   limits)

    @staticmethod
    def _periods(control_period, timestep):
        if not (is_real(control_period) and math.isfinite(control_period) and control_period > 0):
            raise ConfigError(f"must be a number > 0 (s), got {control_period!r}", key="simulation.control_period")
        ts = control_period if timestep is None else timestep
        if not (is_real(ts) and math.isfinite(ts) and ts > 0):
            raise ConfigError(f"must be a number > 0 (s), got {timestep!r}", key="plant.timestep")
        _check_divides(float(ts), float(control_period), "plant.timestep", "control period")
        return float(control_period), float(ts)

    @classmethod
    def from_models(cls, arm, surface, contact, disturbance, *, control_period: float,
                    timestep: float | None = None, integrator: str = "RK4", callback: str = "host",
                    friction=None, friction_damping: float = S.FRICTION_DAMPING) -> "MujocoPlant":
        """The MuJoCo plant of a TRUE arm, surface, contact (:class:`~hinfnn.PenaltyContact`, N/m
        and N·s/m), joint disturbance (:class:`~hinfnn.SquareWave`) and tool friction
        (:class:`~hinfnn.plant.contact.Friction`: its Coulomb μ is MuJoCo's friction cone, its
        viscous c_v a force hinfnn applies at the tool point at every MuJoCo step while the contact
        pushes; docs/mujoco.md, "Friction").

        ``arm``: :class:`~hinfnn.TwoLinkArm` (surface: :class:`~hinfnn.InclinedLine`) or a
        :class:`~hinfnn.model.urdf.UrdfArm` (URDF or planar chain; surface: a plane, sphere,
        cylinder, or a line or circle of a planar arm's plane). ``timestep`` (MuJoCo's, s) defaults
        to ``control_period`` and must divide it; ``integrator``: one of ``INTEGRATORS``;
        ``callback``: ``"host"`` (default, the fastest) or ``"pure_callback"``. Raises
        :class:`ConfigError` naming the scenario key."""
        from ...model.planar import TwoLinkArm

        S.require_mujoco()
        control_period, ts = cls._periods(control_period, timestep)
        mu, c_v = _friction_values(friction)
        if isinstance(arm, TwoLinkArm):
            S._check_two_link(arm, surface)
            if mu > 0 or c_v > 0:
                raise ConfigError("the two_link arm's MuJoCo model is frictionless",
                                  key="plant.friction.coulomb" if mu > 0 else "plant.friction.viscous")
            scene = S.build_scene(surface, contact, rows=(0, 2), arm_xml=S.two_link_xml(arm), timestep=ts,
                                  integrator=integrator)
            sensing = LineSensing(surface=surface)
        else:
            task, rows = _task_of(arm, surface)
            scene = S.build_scene(surface, contact, rows=rows, arm_xml=S.chain_xml(arm.chain), friction=mu,
                                  friction_damping=friction_damping, timestep=ts, integrator=integrator)
            sensing = _cartesian_sensing(task, surface, arm.chain)
        meta = _Meta(arm, surface, contact, friction, scene, friction_damping)
        return cls._build(scene, meta, sensing, disturbance, control_period, callback)

    @classmethod
    def from_mjcf(cls, path, *, joints, tool_site: str, task, surface, contact, disturbance,
                  control_period: float, tool_xyz=(0.0, 0.0, 0.0), tool_rot=None, timestep: float | None = None,
                  integrator: str = "RK4", callback: str = "host", friction=None,
                  friction_damping: float = S.FRICTION_DAMPING, locked=(), mass_scale=1.0,
                  payload_mass: float = 0.0, payload_xyz=(0.0, 0.0, 0.0), effort_limit=None) -> "MujocoPlant":
        """The MuJoCo plant of a user's MJCF arm: ``joints`` its joint names from the base to the
        tool (all its degrees of freedom once the joints ``locked`` ((name, position) pairs) are
        welded), ``tool_site`` the site the tool hangs from, the tool point at ``tool_xyz``
        (rotation ``tool_rot``) in that site's frame; ``task`` the task map the controller's
        coordinates use (x_true and the task-space F are formed with it from MuJoCo's tool pose and
        Jacobian; an :class:`~hinfnn.model.augmented.AugmentedTask`'s extra coordinates from the
        joint angles). The model keeps what it has (armature, damping, friction loss, springs); its
        actuators are switched off. ``mass_scale``, ``payload_mass``, ``payload_xyz``: the true
        arm's perturbation, applied to the file (:func:`~hinfnn.plant.mujoco.scene.build_scene`);
        ``effort_limit``: the joints' torque limits where the file states none (a joint's
        ``actuatorfrcrange`` or its actuators' force ranges)
        (e.g. the nominal URDF's). The rest as :meth:`from_models`."""
        from ...model.augmented import chain_arm

        S.require_mujoco()
        control_period, ts = cls._periods(control_period, timestep)
        mu, _ = _friction_values(friction)
        _, rows = _task_of(None, surface, task)
        scene = S.build_scene(surface, contact, rows=rows, arm_file=os.fspath(path), joints=tuple(joints),
                              tool_site=tool_site, tool_xyz=tool_xyz, tool_rot=tool_rot, friction=mu,
                              friction_damping=friction_damping, timestep=ts, integrator=integrator,
                              locked=tuple(locked), mass_scale=mass_scale, payload_mass=payload_mass,
                              payload_xyz=payload_xyz)
        arm = chain_arm(S.chain_from_model(scene.model, joints, scene.site, effort_limit), task)
        meta = _Meta(arm, surface, contact, friction, scene, friction_damping)
        return cls._build(scene, meta, _cartesian_sensing(task, surface, arm.chain), disturbance, control_period,
                          callback)

    def replace(self, **changes) -> "MujocoPlant":
        """The same plant with other ``disturbance``, ``sensing``, ``control_period``,
        ``callback``, ``sensor`` or ``actuator`` (the MuJoCo model stays)."""
        kw = dict(disturbance=self.disturbance, sensing=self.sensing, control_period=self.control_period,
                  callback=self.callback, sensor=self.sensor, actuator=self.actuator)
        unknown = set(changes) - set(kw)
        if unknown:
            raise TypeError(f"cannot replace {sorted(unknown)}")
        kw.update(changes)
        if kw["callback"] not in CALLBACKS:
            raise ConfigError(f"must be one of {CALLBACKS}, got {kw['callback']!r}", key="plant.callback")
        return MujocoPlant(self._family, self.member, limits=self.limits, **kw)

    def with_sensor(self, sensor) -> "MujocoPlant":
        """The same plant with another ``sensor`` (:meth:`hinfnn.protocols.Plant.with_sensor`)."""
        return self.replace(sensor=sensor)

    # --- read-only facts ----------------------------------------------------------------------
    def _meta(self) -> _Meta:
        try:
            i = int(np.asarray(self.member))
        except TypeError:
            raise TypeError("this MuJoCo plant is a batch (or traced): take one member first") from None
        return self._family.meta[i]

    @property
    def scene(self) -> S.Scene:
        return self._meta().scene

    @property
    def xml(self) -> str:
        """The MJCF of the model being simulated (MuJoCo's writer: 6 significant digits; the
        compiled :attr:`model` is the exact one)."""
        return self.scene.xml

    @property
    def model(self):
        """The compiled ``mujoco.MjModel`` (do not modify it while a run uses the plant)."""
        return self.scene.model

    @property
    def timestep(self) -> float:
        return self.scene.timestep

    @property
    def arm(self):
        """The true arm as hinfnn reads it (for a user's MJCF: its rigid-body part,
        :func:`~hinfnn.plant.mujoco.scene.chain_from_model`)."""
        return self._meta().arm

    @property
    def surface(self):
        return self._meta().surface

    @property
    def contact(self):
        return self._meta().contact

    @property
    def cartesian(self) -> bool:
        return bool(self.sensing.cartesian)

    def _rigid(self):
        from ..rigid import RigidBodyPlant

        meta = self._meta()
        return RigidBodyPlant(meta.arm, meta.surface, meta.contact, self.disturbance)

    def initial_q(self, u1_0, elbow_up: bool = True, q_guess=None, within_limits: bool = True):
        """Joint angles with the tool on the true surface at u1 = u1_0 (as
        :meth:`hinfnn.RigidBodyPlant.initial_q`, on the true arm's rigid-body model: from
        ``q_guess``, kept within :meth:`joint_limits` unless ``within_limits`` is False)."""
        rigid = self._rigid()
        if rigid.cartesian:
            return rigid.initial_q(u1_0, elbow_up, q_guess=q_guess, within_limits=within_limits)
        return rigid.initial_q(u1_0, elbow_up)

    def joint_limits(self):
        """(lower, upper) of the TRUE arm's joints (rad or m, ±inf where none): its URDF's, or for
        a user's MJCF its joints' ``range`` (:func:`~hinfnn.plant.mujoco.scene.chain_from_model`)."""
        if self.limits is None:
            return jnp.full(self.n, -jnp.inf), jnp.full(self.n, jnp.inf)
        return self.limits

    def fault_item(self, index: int) -> str:
        """The joint ``index`` by its name (the URDF's or the MJCF's)."""
        names = getattr(getattr(self.arm, "chain", None), "joint_names", ()) or ()
        return f"joint {index + 1} ({names[index]})" if 0 <= index < len(names) else f"joint {index + 1}"

    def effective_mass(self, q):
        """The true arm's effective mass along the surface's normal at q (rigid-body part; a
        user's armature is not in it)."""
        return self._rigid().effective_mass(q)

    # --- protocol -----------------------------------------------------------------------------
    def _unpack(self, y):
        fam = self._family
        n, nq, nv = fam.n, fam.nq, fam.nv
        o = 0

        def take(k):
            nonlocal o
            out = y[..., o:o + k]
            o += k
            return out

        qpos, qvel, warm, qacc = take(nq), take(nv), take(nv), take(nv)
        p, R = take(3), take(9)
        jacp, jacr = take(3 * n), take(3 * n)
        sensor = take(S.SENSOR_SIZE)
        lead = y.shape[:-1]
        R = R.reshape(lead + (3, 3))
        Jf = jnp.concatenate([jacp.reshape(lead + (3, n)), jacr.reshape(lead + (3, n))], axis=-2)
        sense = self.sensing
        for _ in lead:
            sense = jax.vmap(sense)
        sensed = sense(p, R, Jf, sensor, qpos)
        return MujocoState(q=qpos, qd=qvel, qacc_warmstart=warm, **sensed), qacc

    def _row(self, parts):
        lead = parts[-1].shape[:-1]
        member = jnp.broadcast_to(jnp.asarray(self.member, dtype=jnp.float64), lead)
        x = jnp.concatenate([member[..., None]] + [jnp.broadcast_to(a, lead + a.shape[-1:]) for a in parts],
                            axis=-1)
        ok = jnp.all(jnp.isfinite(x), axis=-1, keepdims=True)
        return jnp.where(ok, x, jnp.nan)  # the host skips a row with a NaN (MuJoCo is not called)

    def initial_state(self, q0, qd0=None) -> MujocoState:
        """The state at joint angles q0 and rates qd0 (default 0), zero warm start; the sensor
        fields are MuJoCo's at that state with no applied force."""
        q0 = jnp.asarray(q0, dtype=jnp.float64)
        qd0 = jnp.zeros_like(q0) if qd0 is None else jnp.asarray(qd0, dtype=jnp.float64)
        z = jnp.zeros(q0.shape[:-1] + (1,))
        zn = jnp.zeros_like(qd0)
        x = self._row([z, z, q0, qd0, zn, zn])
        return self._unpack(_call_host(self._family, "init", x, self.callback))[0]

    def sense(self, t, state: MujocoState):
        """``(Measurement(q, q̇, force), None)`` at this state. Pure JAX (no callback): MuJoCo
        filled the sensor fields at the end of the step that produced the state.

        ``force``: the force the tool exerts on the surface at the tool point, from MuJoCo's
        contact force, in the base frame's axes of the arm's space (3 components; 2 for a planar
        arm, in its plane's coordinates), as :class:`hinfnn.RigidBodyPlant` senses it."""
        return Measurement(q=state.q, qd=state.qd, force=state.force), None

    def joints(self, state: MujocoState):
        return state.q, state.qd

    def step_input(self, t, dt):
        """The joint disturbance of the step [t, t + dt): d(t + dt/2) (what :meth:`step` applies)."""
        return self.disturbance(t + 0.5 * dt)

    def record(self, state: MujocoState, w, cache=None) -> PlantRecord:
        """What is recorded of the truth at this state, with the signal names of
        :meth:`hinfnn.RigidBodyPlant.record`: q, qd, normal_force, disturbance (``w``), x_true;
        on a Cartesian surface F_contact (the sensed force), friction_force, task_margin; for a
        chain's joints joint_limit_margin, and a fault when a joint is past its limit."""
        out = {"q": state.q, "qd": state.qd, "normal_force": state.normal_force, "disturbance": w,
               "x_true": state.x_true}
        if state.friction_force is not None:
            out.update(F_contact=state.force, friction_force=state.friction_force, task_margin=state.task_margin)
        if self.limits is not None:  # a chain's joints: the run stops past a limit
            lo, hi = self.limits
            return limit_record(state.penetration, out, state.q, lo, hi)
        return PlantRecord(penetration=state.penetration, signals=out)

    def diagnostics(self, state: MujocoState, w, cache=None) -> dict:
        """The recorded signals with the penetration, as one dict (:meth:`record`)."""
        r = self.record(state, w, cache)
        return {**r.signals, "penetration": r.penetration}

    def step(self, t, state: MujocoState, tau, dt):
        """Advance by ``dt`` (a whole number of MuJoCo timesteps) with τ and the disturbance
        d(t + dt/2) held as joint forces (``qfrc_applied``). Returns ``(new_state, qdd)``, qdd =
        MuJoCo's ``qacc`` at the new state (the forward pass the sensors come from). A non-finite
        input or a dt that is not a whole number of timesteps gives an all-NaN state (MuJoCo is not
        called for that member)."""
        if isinstance(dt, (int, float, np.integer, np.floating)) and not isinstance(self.member, jax.core.Tracer) \
                and np.ndim(self.member) == 0:
            _check_divides(self.timestep, float(dt), "plant.timestep", "step dt")
        t = jnp.asarray(t, dtype=jnp.float64)
        dt = jnp.asarray(dt, dtype=jnp.float64)
        tau = jnp.asarray(tau, dtype=jnp.float64)
        w = self.disturbance(t + 0.5 * dt)
        x = self._row([dt[..., None], t[..., None], state.q, state.qd, state.qacc_warmstart, tau + w])
        return self._unpack(_call_host(self._family, "step", x, self.callback))


def _friction_values(friction):
    """(μ, c_v) of a :class:`~hinfnn.plant.contact.Friction` (zeros for None): μ is MuJoCo's
    Coulomb cone, c_v the viscous force hinfnn applies at the tool point."""
    if friction is None:
        return 0.0, 0.0
    S._check_number("plant.friction.viscous", friction.viscous)
    return float(friction.coulomb), float(friction.viscous)


def _cartesian_sensing(task, surface, chain) -> CartesianSensing:
    """The sensing of a chain arm with the task map ``task``: with the true ``chain`` where the
    task has extra coordinates of the joint angles (a redundant arm's arm angle)."""
    from ...model.augmented import AugmentedTask

    return CartesianSensing(task=task, surface=surface, chain=chain if isinstance(task, AugmentedTask) else None)


def _task_of(arm, surface, task=None):
    """(task map, base rows of the arm's plane) for a Cartesian surface."""
    from ...model.geometry import Geometry

    task = task if task is not None else getattr(arm, "task", None)
    kind = S.surface_kind(surface)
    if kind not in S.SUPPORTED_SURFACES:
        raise S.unsupported_surface(kind)
    if not isinstance(surface, Geometry):
        raise ConfigError(f"a {S.surface_kind(surface)!r} surface is the two_link arm's (task space); this arm needs a "
                          "Cartesian surface", key="plant.surface.kind")
    if task is None:
        raise ConfigError("the MuJoCo plant needs the arm's task map", key="task.map")
    rows = tuple(task.space_rows)
    dim = len(rows)
    if int(surface.dim) != dim:
        raise ConfigError(f"a {surface.dim}-D surface for a tool that moves in {dim}-D", key="plant.surface.kind")
    S.surface_geom(surface, rows if dim == 2 else (0, 1))  # refuses the kinds MuJoCo has no primitive for
    return task, rows if dim == 2 else (0, 1)


def _flatten(plant: MujocoPlant):
    # the family (MuJoCo models, Batches) is static and hashed by identity; the member index, the
    # disturbance and the sensing data are leaves (a batch of plants is a stack of them)
    return ((plant.member, plant.disturbance, plant.sensing, plant.limits, plant.sensor, plant.actuator),
            (plant._family, plant.control_period, plant.callback))


def _unflatten(aux, children):
    family, period, callback = aux
    return MujocoPlant(family, children[0], children[1], children[2], period, callback, children[3], children[4],
                       children[5])


jax.tree_util.register_pytree_node(MujocoPlant, _flatten, _unflatten)
