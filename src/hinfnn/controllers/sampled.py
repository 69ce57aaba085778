"""Fixed-rate, zero-order-hold use of a designed controller, as a robot loop calls it.

The paper's controllers are continuous-time: τ(t) of eq. (24) (with Λp, Λf of eqs. (25)–(26))
acts at every instant and the controller state x_c (z and the terms' states, e.g. Θ̂p, Θ̂f)
flows by

    ż   = −μ_z z − α_z e_λ                          (27)
    Θ̂̇p = γ1 Ξpᵀ B_pᵀ P_p x_p   (projected, Remark 2)   (30)
    Θ̂̇f = γ2 Ξfᵀ e_λ           (projected, Remark 2)   (31)

A robot runs the law at a fixed period h (1 kHz: h = 1 ms), ros2_control style: at each sample
instant t_k it reads the sensors, calls ``update(t_k, h, state, measurement)``, applies the
returned τ_k until the next sample (zero-order hold) and keeps the returned state. The update is

    τ_k      = τ(t_k, x_c,k, y_k)                                   eq. (24) at the sample
    x_c,k+1  = constrain(x_c,k + h · f(t_k, x_c,k, y_k))             forward Euler over h

with f the right-hand side of (27), (30), (31) evaluated from the same measurement y_k, and
``constrain`` the controller's radial clip onto ‖Θ̂‖ ≤ d (Remark 2; identity without projection).
This update is written once, as the controller's ``sample`` method
(:meth:`~hinfnn.controllers.law.ReducedOrderController.sample`), and the simulator's
sampled-data mode calls the same method.
Forward Euler is the first-order discretisation of the continuous law: over a horizon T the
sampled state differs from the continuous one by O(h), and as h → 0 with the plant integrated
finely the sampled closed loop tends to the paper's continuous one (``tests/test_sim.py`` checks
the trend). The Euler step follows the projected flow, which is tangent to the sphere ‖Θ̂‖ = d,
so one step can leave the ball by O(h²); the clip puts it back, so ‖Θ̂‖ ≤ d holds after every
update exactly as Remark 2 requires.

This is exactly the simulator's sampled-data mode (``hinfnn.simulate(..., control_period=h)``):
the same method on the same numbers, so replaying a simulated run's measurements through
the wrapper reproduces its held torques and final controller state (``tests/test_sampled.py``).
The wrapper holds the controller and its reference only: it never sees a plant
(docs/architecture.md, "the one rule").

Two entry points:

* :meth:`SampledController.step` — the law as a pure, traceable function ``(τ_k, x_c,k+1)`` of
  (t, period, state, measurement), for use inside your own ``jit``/``vmap``/``scan``.
* :meth:`SampledController.loop` — a :class:`SampledLoop`, the controller in a robot loop:
  ``tau = loop.update(t, h, q, q̇, force)`` (NumPy τ), the state kept inside, compiled once per
  wrapper. On arms of 3 joints or more it runs the law on the packed sample and the state's
  leaves (blocks of at most 64 values, kept on the device, their buffers donated to the
  outputs); on the paper's 2-joint arm on one packed buffer ``[t, h, q, q̇, force, state...]``.

Everything else is private: the compiled programs behind the loop, and the pytree update, the
start and the signals at one instant that hinfnn's robot layer replays a run's record with
(:func:`hinfnn.robot.loop.trajectory`).

The measurement's ``force`` is the contact force the tool exerts on the surface, at the tool point,
in the base frame's Cartesian axes (:class:`~hinfnn.protocols.Measurement`): what a force/torque
sensor at the tool gives, moved to the tool point and turned into the base frame; shape (d,), d
the arm's Cartesian dimension (:attr:`SampledController.force_size`: 2 for a planar arm, in the
plane's coordinates, 3 for a spatial one). The controller maps it into its task coordinates with
its nominal kinematics. q and q̇ have shape (n,).

Non-finite inputs. A NaN or ±inf anywhere in t, h or the measurement, a negative h, or a
non-finite torque from finite inputs (e.g. overflow at an absurd q̇) never produces a usable
torque: both entry points return τ = [NaN, …, NaN], so one ``np.isfinite(tau).all()``
(:meth:`SampledController.is_valid`) tells the robot's driver to go to its safe stop. The state
``step`` returns with a NaN τ is to be discarded (it may hold NaN): ``step`` never modifies the
state passed in, so keep that one (the bad sample is then simply dropped) or re-initialise;
:class:`SampledLoop` does exactly this by itself. A NaN state kept by mistake makes every later τ
NaN too (a latched fault, never a silently wrong torque). A wrong shape, complex numbers or
strings are refused before the compiled call: :class:`MeasurementError` names the input
(:meth:`SampledController.check_sample`).

Why the compiled guard covers τ only (the state is not also selected in the program): with JAX's
CPU async dispatch on (the default), XLA's CPU client runs a program inline on the calling
thread only when its cost estimate is below 1000 flops, and hands it to a worker thread
otherwise (a thread switch per call: tens of µs, more on a loaded machine). Selecting the state
costs about one flop per weight, which is enough to push the adaptive law over that line.
``benchmarks/latency.py`` prints each program's estimate beside its latency; a robot process
can avoid the handoff altogether with ``jax.config.update("jax_cpu_enable_async_dispatch",
False)`` at start-up (process-wide, before JAX's first computation).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._declared import loop_jit
from .._linalg import Kernels
from .._pytree import all_finite, pytree_dataclass
from ..errors import HinfnnError
from ..protocols import Measurement, needs_start
from ..reference import check_references
from .law import ControllerState, ReducedOrderController

__all__ = ["SampledController", "SampledLoop", "MeasurementError"]

_F8 = np.dtype(float)
#: The dtype kinds a sample's numbers may have: floats and integers (not complex, not strings).
_REAL_KINDS = "fiu"
#: Python types a t or period would be converted from silently (NumPy's complex scalars are complex).
_NOT_REAL = (complex, str, bytes)


class MeasurementError(HinfnnError, ValueError):
    """A sample given to :meth:`SampledLoop.update` (or :meth:`SampledController.check_sample`) is
    unusable.

    ``key`` names the offending input (``measurement.force``, ``t``, ``period``, ``state.z``,
    ``tau`` …), ``value`` is what was given and ``t`` the sample time.
    """

    def __init__(self, message: str, key: str | None = None, value=None, t=None):
        self.key = key
        self.value = value
        self.t = t
        super().__init__(f"{key}: {message}" if key else message)


def _plain(n_shape: tuple, d_shape: tuple, q, qd, force) -> bool:
    """True when q, q̇ have shape ``n_shape`` = (n,), force ``d_shape`` = (d,) and all three a real
    dtype (a list counts as float: its entries are checked where it is converted): the cheap test
    each update makes in Python, with no device round trip, before its compiled call (on arrays,
    attribute reads only); ``check_sample`` names what is wrong otherwise."""
    try:
        return (q.shape == n_shape and qd.shape == n_shape and force.shape == d_shape and q.dtype.kind in _REAL_KINDS
                and qd.dtype.kind in _REAL_KINDS and force.dtype.kind in _REAL_KINDS)
    except AttributeError:  # lists, tuples, numbers
        return (np.shape(q) == n_shape and np.shape(qd) == n_shape and np.shape(force) == d_shape
                and getattr(q, "dtype", _F8).kind in _REAL_KINDS and getattr(qd, "dtype", _F8).kind in _REAL_KINDS
                and getattr(force, "dtype", _F8).kind in _REAL_KINDS)


def _as_meas(measurement) -> Measurement:
    return Measurement(q=jnp.asarray(measurement.q, dtype=float), qd=jnp.asarray(measurement.qd, dtype=float),
                       force=jnp.asarray(measurement.force, dtype=float))


@pytree_dataclass
class SampledController:
    """A designed controller and its reference, run at a fixed rate with zero-order hold.

    ``SampledController(controller, reference)`` with ``controller`` a designed
    :class:`~hinfnn.controllers.law.ReducedOrderController` (``hinfnn.HinfNNController.design(...)``
    …) and ``reference`` any reference pytree callable on t (:class:`~hinfnn.CosineReference`).
    Both are pytree data of this wrapper, so a batch of wrappers can be ``vmap``-ed through
    :meth:`step`; the programs of :meth:`loop` close over them as compile-time constants (twice as
    fast to call as passing them as arguments, see ``benchmarks/latency.py``) and are built once
    per wrapper, on first use.

    The state is the controller's :class:`~hinfnn.controllers.law.ControllerState` (its arrays
    flat by name: :meth:`~hinfnn.controllers.law.ControllerState.arrays`). The loop's packed
    layouts (n joints, d = :attr:`force_size`; ``state_size`` = the total length of the state's
    arrays):

    * packed input (``packed_size``): ``[t, period, q (n), q̇ (n), force (d), state...]``
    * packed output (``n + state_size``): ``[τ (n), state...]`` (the new state)
    """

    controller: ReducedOrderController
    reference: object

    # --- sizes and packing (Python side, cheap) ----------------------------------------------------
    @property
    def n_joints(self) -> int:
        return int(self.controller.arm.n)

    @functools.cached_property
    def force_size(self) -> int:
        """Length d of the measured tool force: the arm's Cartesian dimension (2 planar, 3 spatial);
        found once (the arm's ``space_dim`` traces its tool point)."""
        return int(self.controller.arm.space_dim)

    @functools.cached_property
    def _layout(self) -> tuple[tuple[str, int], ...]:
        return tuple((k, int(v.shape[0])) for k, v in self.controller.init().arrays().items())

    @property
    def state_size(self) -> int:
        """Total length of the state's arrays (z, then the terms' arrays)."""
        return sum(size for _, size in self._layout)

    @property
    def sample_size(self) -> int:
        """Length of the sample part ``[t, period, q, q̇, force]`` of the packed input: 2 + 2n + d."""
        return 2 + 2 * self.n_joints + self.force_size

    @property
    def packed_size(self) -> int:
        """Length of the packed input vector of the 2-joint arm's loop program."""
        return self.sample_size + self.state_size

    def _pack(self, t, period, measurement: Measurement, state: ControllerState,
             out: np.ndarray | None = None) -> np.ndarray:
        """(t, period, measurement, state) → the packed input of the 2-joint arm's loop program (NumPy).

        ``out``: a float64 array of ``packed_size`` to fill in place.
        """
        n = self.n_joints
        x = np.empty(self.packed_size) if out is None else out
        x[0] = t
        x[1] = period
        x[2:2 + n] = measurement.q
        x[2 + n:2 + 2 * n] = measurement.qd
        x[2 + 2 * n:self.sample_size] = measurement.force
        x[self.sample_size:] = self.state_vector(state)
        return x

    def state_vector(self, state: ControllerState) -> np.ndarray:
        """ControllerState → its arrays concatenated in the packed order, as one NumPy vector."""
        arrays = state.arrays()
        return np.concatenate([np.asarray(arrays[name], dtype=float).reshape(-1) for name, _ in self._layout])

    def state_from_vector(self, vec) -> ControllerState:
        """Packed state vector → ControllerState (NumPy or traced, any leading batch axes)."""
        arrays, i = {}, 0
        for name, size in self._layout:
            arrays[name] = vec[..., i:i + size]
            i += size
        return self.controller.state_from_arrays(arrays)

    def _unpack(self, out) -> tuple:
        """Packed output → ``(τ, new state)``."""
        n = self.n_joints
        return out[..., :n], self.state_from_vector(out[..., n:])

    # --- the law -----------------------------------------------------------------------------------
    def init(self, **given) -> ControllerState:
        """Initial controller state (Sec. VI: z = 0, weights 0 unless given by name, e.g.
        ``init(theta_f=...)``; ``controller.init``)."""
        self._check_parts()
        return self.controller.init(**given)

    def step(self, t, period, state: ControllerState, measurement: Measurement):
        """One sample: ``(τ_k, x_c,k+1)``. Pure and traceable (use it inside jit/vmap/scan).

        τ_k is eq. (24) at time t from ``measurement``; x_c,k+1 = constrain(x_c,k + period · ẋ_c)
        with ẋ_c of eqs. (27), (30), (31) at the same instant (the controller's ``sample``).
        Non-finite t, period or measurement, period < 0, or a non-finite τ: τ = [NaN, …] and the
        returned state is to be discarded (keep the one passed in; see the module docstring).
        """
        t = jnp.asarray(t, dtype=float)
        period = jnp.asarray(period, dtype=float)
        meas = _as_meas(measurement)
        ctrl = self.controller
        out = ctrl.evaluate(t, state, meas, self.reference)
        tau, new = ctrl.sample(t, period, state, meas, self.reference, out=out)
        ok = all_finite((t, period, meas.q, meas.qd, meas.force, tau)) & (period >= 0.0) & ~out.fault
        return jnp.where(ok, tau, jnp.nan), new

    def _start_fn(self, t, state: ControllerState, measurement: Measurement) -> ControllerState:
        """The state at the first sample from the first measurement (the controller's ``start``:
        e.g. the force-rate filter starts at e_λ(0)). Pure; identity for the paper's laws."""
        return self.controller.start(jnp.asarray(t, dtype=float), state, _as_meas(measurement), self.reference)

    def _step_packed(self, x):
        """:meth:`step` on the packed layouts: ``[t, h, q, q̇, force, state...] → [τ, state...]``."""
        n, ns = self.n_joints, self.sample_size
        meas = Measurement(q=x[2:2 + n], qd=x[2 + n:2 + 2 * n], force=x[2 + 2 * n:ns])
        tau, new = self.step(x[0], x[1], self.state_from_vector(x[ns:]), meas)
        arrays = new.arrays()
        return jnp.concatenate([tau, *(arrays[name] for name, _ in self._layout)])

    @functools.cached_property
    def _treedef(self):
        return jax.tree.structure(self.controller.init())

    def _step_leaves(self, x, *leaves):
        """:meth:`step` on the sample packed (``x = [t, period, q, q̇, force]``, :attr:`sample_size`)
        and the state as its leaves (``jax.tree.leaves(state)``): ``(τ, *new leaves)``. What
        :class:`SampledLoop` calls: the state's leaves are the controller's blocks (at most 64 values
        each), so no buffer of the program is larger than a block and XLA's CPU runtime runs its
        kernels one after the other on the calling thread (one packed state of 339 values sends
        every kernel of the UR5's update through its thread pool: docs/performance.md)."""
        n, ns = self.n_joints, self.sample_size
        meas = Measurement(q=x[2:2 + n], qd=x[2 + n:2 + 2 * n], force=x[2 + 2 * n:ns])
        tau, new = self.step(x[0], x[1], jax.tree.unflatten(self._treedef, leaves), meas)
        return (tau, *jax.tree.leaves(new))

    def _step_leaves_kept(self, x, *leaves):
        """:meth:`_step_leaves` with the state kept: ``(τ, *leaves)`` where τ is all NaN (the sample
        unusable), ``(τ, *new leaves)`` otherwise. What :class:`SampledLoop` calls on arms, with the
        state's buffers donated: the outputs are written into the inputs' buffers, and the state
        the loop holds is always the program's output (no buffer of a rejected sample to keep)."""
        tau, *new = self._step_leaves(x, *leaves)
        ok = tau[0] == tau[0]
        return (tau, *(jnp.where(ok, a, b) for a, b in zip(new, leaves)))

    def _signals_fn(self, t, state: ControllerState, measurement: Measurement):
        """Traceable ``(τ, signals)`` at one instant (eqs. (24)–(33)); no state update."""
        out = self.controller.evaluate(jnp.asarray(t, dtype=float), state, _as_meas(measurement), self.reference)
        return out.tau, {**out.signals, "e_u1": out.e_u1, "e_lam": out.e_lam, "tau": out.tau}

    # --- compiled entry points (built once per wrapper, on first use) --------------------------
    def _check_parts(self):
        if not isinstance(self.controller, ReducedOrderController) and not hasattr(self.controller, "law"):
            raise TypeError("SampledController.controller must be a designed controller "
                            "(e.g. hinfnn.HinfNNController.design(...)), got "
                            f"{type(self.controller).__name__}")
        if not callable(self.reference):
            raise TypeError("SampledController.reference must be a reference callable on t "
                            f"(e.g. hinfnn.CosineReference), got {type(self.reference).__name__}")
        self._reference_fits

    @functools.cached_property
    def _reference_fits(self) -> bool:
        """The reference's sizes checked against the controller's m and k, once per wrapper."""
        check_references([(self.reference, self.controller.m, self.controller.k)])
        return True

    @property
    def kernels(self) -> Kernels:
        """The kernels the compiled entry points are traced with: the simulator's for a single run
        of this arm (:meth:`hinfnn._linalg.Kernels.loop`: on arms of 3 or more joints the
        written-out factorisations and the products computed once)."""
        return Kernels.loop(self.n_joints)

    def _jit(self, fn, **jit_kwargs):
        """``jax.jit(fn)`` (a method of this wrapper) on this wrapper with its controller and
        reference holding :attr:`kernels` (:meth:`hinfnn._linalg.Kernels.hold`), compiled by the
        compiled layer with the simulator's compile options (:func:`hinfnn._declared.loop_jit`:
        XLA's older loop emitters on arms, as the simulator's programs); the paper's arm is traced
        and compiled as before."""
        self._check_parts()
        wrapper = self.kernels.hold(self)
        for name in ("_layout", "_treedef"):  # the state's layout, the same with any kernels: made once
            wrapper.__dict__[name] = getattr(self, name)
        held = getattr(wrapper, fn.__name__)

        @functools.wraps(fn)
        def traced(*args):
            return held(*args)
        return loop_jit(traced, self.n_joints, **jit_kwargs)

    @functools.cached_property
    def _jit_update(self):
        return self._jit(self.step)

    @functools.cached_property
    def _jit_packed(self):
        return self._jit(self._step_packed)

    @functools.cached_property
    def _jit_kept(self):
        return self._jit(self._step_leaves_kept, donate_argnums=tuple(range(1, 1 + self._treedef.num_leaves)))

    @functools.cached_property
    def _jit_start(self):
        return self._jit(self._start_fn)

    def _start(self, t, state: ControllerState, measurement: Measurement) -> ControllerState:
        """The state at the first sample (:meth:`_start_fn`, compiled) when the controller has
        filter states (``controller.needs_start``; :class:`SampledLoop` does it by itself)."""
        return self._jit_start(t, state, measurement) if needs_start(self.controller) else state

    @functools.cached_property
    def _jit_signals(self):
        return self._jit(self._signals_fn)

    def _update(self, t, period, state: ControllerState, measurement: Measurement):
        """``(τ, new_state)`` of one sample (:meth:`step`), jit-compiled once per wrapper.

        τ of eq. (24) at time ``t`` (s) from ``measurement`` (q, q̇, force), to be held for
        ``period`` (s); new_state = constrain(state + period · ẋ_c), ẋ_c of eqs. (27), (30),
        (31): forward Euler over the period. Pass t and period as floats and the measurement as
        float64 arrays (another dtype compiles a second program). Works under ``jax.vmap``. τ is
        all-NaN when a sample is unusable: check with :meth:`is_valid` (then keep your previous
        state) or use :meth:`_update_checked`. t and period must be numbers, q, q̇ and force real
        vectors of shapes (n,), (n,), (d,): anything else raises :class:`MeasurementError`
        naming the input (a cheap test in Python before the compiled call).
        """
        m = measurement
        if not (np.ndim(t) == 0 and np.ndim(period) == 0 and not isinstance(t, _NOT_REAL)
                and not isinstance(period, _NOT_REAL)
                and _plain((self.n_joints,), (self.force_size,), m.q, m.qd, m.force)):
            self.check_sample(t, period, m.q, m.qd, m.force)  # raises, naming the input
        try:
            return self._jit_update(t, period, state, measurement)
        except (TypeError, ValueError):  # a list of strings ...: named, when the sample is at fault
            self.check_sample(t, period, m.q, m.qd, m.force)
            raise

    def _update_packed(self, x):
        """One sample on the packed layouts (:meth:`_step_packed`), jit-compiled once.

        ``x = [t, period, q, q̇, force, state...]`` (:meth:`_pack`) → ``[τ, state...]``
        (:meth:`_unpack`). Same law and numbers as :meth:`_update`; one buffer in and one out,
        the cheapest call from Python: :class:`SampledLoop`'s program for the paper's 2-joint arm
        (:meth:`_step_leaves_kept` for larger arms).
        """
        return self._jit_packed(x)

    def loop(self, state: ControllerState | None = None) -> "SampledLoop":
        """The controller in a robot loop: a :class:`SampledLoop` starting from ``state`` (default:
        :meth:`init`, then the controller's ``start`` at the first sample); ``tau =
        loop.update(t, h, q, q̇, force)``."""
        return SampledLoop(self, self.init() if state is None else state, start=state is None)

    def check_sample(self, t, period, q, qd, force) -> None:
        """Raise :class:`MeasurementError` naming the input when t or period is not a finite
        number, period ≤ 0, q or q̇ is not n finite numbers, or force is not d finite numbers
        (complex numbers and strings are refused, not converted)."""
        n = self.n_joints
        for key, v in (("t", t), ("period", period)):
            try:
                a = np.asarray(v)
                if a.dtype.kind not in _REAL_KINDS:
                    raise TypeError(a.dtype)
                a = a.astype(float)
            except (TypeError, ValueError):
                raise MeasurementError(f"must be a finite number, got {v!r}", key=key, value=v, t=t) from None
            if a.shape != () or not np.isfinite(a):
                raise MeasurementError(f"must be a finite number, got {v!r}", key=key, value=v, t=t)
        if not float(period) > 0.0:
            raise MeasurementError(f"must be > 0, got {period!r}", key="period", value=period, t=t)
        d = self.force_size
        for name, v, size in (("q", q, n), ("qd", qd, n), ("force", force, d)):
            try:
                a = np.asarray(v)
                if a.dtype.kind not in _REAL_KINDS:
                    raise TypeError(a.dtype)
                v = a.astype(float)
            except (TypeError, ValueError):
                raise MeasurementError(f"must be {size} real numbers, got {v!r:.80}", key=f"measurement.{name}",
                                       value=v, t=t) from None
            if v.shape != (size,):
                what = (" (the contact force at the tool point, in the base frame's Cartesian axes)"
                        if name == "force" else "")
                raise MeasurementError(f"must have shape ({size},){what}, got {v.shape}", key=f"measurement.{name}",
                                       value=v, t=t)
            if not np.all(np.isfinite(v)):
                raise MeasurementError(f"is not finite: {v.tolist()}", key=f"measurement.{name}", value=v, t=t)

    def _update_checked(self, t, period, state: ControllerState, measurement: Measurement):
        """:meth:`_update` with its inputs validated in Python first (a few µs more per call).

        Raises :class:`MeasurementError` naming the input when t, period or a measurement
        field is not finite, has the wrong shape, or period ≤ 0; and when the law itself
        returns a non-finite torque. Returns ``(τ as NumPy, new_state)``.
        """
        self.check_sample(t, period, measurement.q, measurement.qd, measurement.force)
        arrays = state.arrays()
        for name, size in self._layout:
            part = arrays.get(name)
            try:
                v = np.asarray(part, dtype=float)
                ok = v.shape == (size,)
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise MeasurementError(f"must be a vector of {size} values, got {part!r:.80}", key=f"state.{name}",
                                       value=part, t=t)
            if not np.all(np.isfinite(v)):
                raise MeasurementError("is not finite", key=f"state.{name}", value=v, t=t)
        tau, new = self._update(float(t), float(period), state, measurement)
        tau = np.asarray(tau)
        if not np.all(np.isfinite(tau)):
            raise MeasurementError("the control law returned a non-finite torque from finite inputs "
                                   "(singular decoupling matrix or overflow at this sample?)",
                                   key="tau", value=tau, t=t)
        return tau, new

    def _torque_and_signals(self, t, state: ControllerState, measurement: Measurement):
        """``(τ, signals)`` at time t (jit-compiled once): u1, u̇1, λ, errors, v_p, v_λ, network
        outputs Ξp Θ̂p, Ξf Θ̂f and τ of eqs. (24)–(33), for logging. No state update, no NaN
        guard (a non-finite measurement gives non-finite signals)."""
        return self._jit_signals(t, state, measurement)

    @staticmethod
    def is_valid(tau) -> bool:
        """True when every entry of τ is finite (False after an unusable sample)."""
        return bool(np.all(np.isfinite(np.asarray(tau))))


class SampledLoop:
    """The controller in a robot loop, ros2_control style: ``tau = loop.update(t, h, q, q̇, force)``.

    A thin stateful shell (at the edge, like I/O) around a pure compiled update: it keeps the
    sample buffer ``[t, h, q, q̇, force]``, fills it in place, calls the update and returns τ as a
    NumPy array. Arms traced with the arm's kernels (:attr:`SampledController.kernels`, 3 joints or more) call
    the law on the packed sample (``SampledController._step_leaves_kept``) with the controller state's leaves, kept on the
    device between calls, their
    buffers donated to the outputs and the program compiled as the simulator's; the
    paper's 2-joint arm calls it on one packed buffer (``SampledController._step_packed``) with the state in the same
    packed buffer (one buffer in and one out: faster than the leaves for its small state). q, q̇
    are NumPy-convertible vectors of shape (n,), force of shape (d,): the contact force the tool
    exerts on the surface at the tool point, in the base frame's Cartesian axes (for the paper's
    planar arm: in N, in the plane's coordinates). A wrong shape, complex numbers or strings raise
    :class:`MeasurementError` (the state is not touched). The state is advanced only when τ is finite: after an unusable
    sample (NaN or inf in t, h, q, q̇, force; h < 0; non-finite τ) ``update`` returns
    τ = [NaN, …], the state stays as it was, and ``rejected`` counts it. The same law as
    :meth:`SampledController.step` (to rounding: the arms' program is compiled as the simulator's).

    In a robot process, turn JAX's CPU async dispatch off at start-up
    (``hinfnn.configure(async_dispatch=False)``, before the first computation): each call then
    runs on the calling thread instead of being handed to a worker thread and back.

    ::

        loop = sampled.loop()
        while running:                         # 1 kHz
            tau = loop.update(t, 1e-3, q, qd, force)
            if not tau[0] == tau[0]:           # NaN: unusable sample
                ...                            # safe stop
            send(tau)
    """

    __slots__ = ("controller", "_buf", "_leaves", "_packed", "_fn", "_n", "_d", "_ns", "_i_q", "_i_qd", "_i_F",
                 "rejected", "_pending_start", "_shape_q", "_shape_F", "phased")

    def __init__(self, controller: SampledController, state: ControllerState, start: bool = False):
        self.controller = controller
        self._n = n = controller.n_joints
        self._d = controller.force_size
        self._shape_q, self._shape_F = (n,), (self._d,)
        self._ns = controller.sample_size
        self._i_q, self._i_qd, self._i_F = slice(2, 2 + n), slice(2 + n, 2 + 2 * n), slice(2 + 2 * n, self._ns)
        self._packed = not controller.kernels.arm
        self._buf = np.zeros(controller.packed_size if self._packed else self._ns)
        self._leaves = ()
        self._set_state(state)
        self._fn = controller._jit_packed if self._packed else controller._jit_kept
        self.rejected = 0
        self._pending_start = start and needs_start(controller.controller)
        #: Whether the controller is a job's (:class:`hinfnn.controllers.job.JobController`): its
        #: state's first array is the phase (:meth:`phase`).
        self.phased = hasattr(controller.controller, "job")

    def phase(self) -> int | None:
        """The job's phase (:data:`hinfnn.controllers.job.PHASES`) the next update starts from, read
        from the state's first value without copying the rest; None for a controller without phases."""
        if not self.phased:
            return None
        return int(self._buf[self._ns] if self._packed else np.asarray(self._leaves[0])[0])

    def _set_state(self, state: ControllerState) -> None:
        if self._packed:
            self._buf[self._ns:] = self.controller.state_vector(state)
        else:  # the loop's own buffers: the update donates them (its outputs take their place)
            self._leaves = tuple(jnp.array(leaf, dtype=float, copy=True) for leaf in jax.tree.leaves(state))

    def update(self, t, period, q, qd, force) -> np.ndarray:
        """τ (NumPy, shape (n,), N·m) of eq. (24) for this sample; the state advances by forward
        Euler over ``period`` (eqs. (27), (30), (31)) unless the sample was unusable (τ all NaN).

        ``t``, ``period``: the sample time and the time until the next sample, s. ``q``, ``qd``:
        joint angles (rad) and rates (rad/s), shape (n,). ``force``: the contact force the tool
        exerts on the surface at the tool point, in the base frame's Cartesian axes, shape (d,)
        (for the paper's planar arm: in N along the plane's x and y axes, as a force/torque sensor
        gives it after the transform to the base frame); the controller turns it into λ itself. A
        wrong shape, complex numbers or strings (in any input; a t or period that is not one number)
        raise :class:`MeasurementError` naming the input (the state is not touched)."""
        n = self._n
        if (not _plain(self._shape_q, self._shape_F, q, qd, force) or (type(t) is not float and isinstance(t, _NOT_REAL))
                or (type(period) is not float and isinstance(period, _NOT_REAL))):
            self.controller.check_sample(t, period, q, qd, force)  # raises, naming the input
        b = self._buf
        try:
            b[self._i_q] = q
            b[self._i_qd] = qd
            b[self._i_F] = force
            b[0] = t
            b[1] = period
        except (TypeError, ValueError):  # a t of one element, a list of strings ...
            self.controller.check_sample(t, period, q, qd, force)  # raises, naming the input
            raise
        if self._pending_start:  # the controller's filters start at the first measurement
            meas = Measurement(q=b[self._i_q].copy(), qd=b[self._i_qd].copy(), force=b[self._i_F].copy())
            if np.all(np.isfinite(meas.q)) and np.all(np.isfinite(meas.qd)) and np.all(np.isfinite(meas.force)):
                self._set_state(self.controller._start(float(b[0]), self.state, meas))
                self._pending_start = False
        if self._packed:
            out = np.asarray(self._fn(b))
            tau = out[:n]
            if tau[0] == tau[0]:  # the compiled guard makes τ all-NaN or all-finite
                b[self._ns:] = out[n:]
            else:
                self.rejected += 1
            return tau
        out = self._fn(b, *self._leaves)  # the state kept by the program itself when τ is NaN
        self._leaves = out[1:]
        tau = np.asarray(out[0])
        if tau[0] != tau[0]:
            self.rejected += 1
        return tau

    @property
    def state(self) -> ControllerState:
        """The current controller state (NumPy copies)."""
        if self._packed:
            return self.controller.state_from_vector(self._buf[self._ns:].copy())
        return jax.tree.unflatten(self.controller._treedef, [np.array(leaf) for leaf in self._leaves])

    def reset(self, state: ControllerState | None = None) -> None:
        """Restart from ``state`` (default: :meth:`SampledController.init`)."""
        self._set_state(self.controller.init() if state is None else state)
        self.rejected = 0
        self._pending_start = state is None and needs_start(self.controller.controller)
