"""The phases of a real job around the paper's constrained law (beyond the paper: its assumption A5
puts the tool on the surface at t = 0; docs/beyond-the-paper.md, docs/robot.md "Phases of a job").

A job starts in free space, ``approach_height`` above where the NOMINAL model believes the part is,
and goes through these phases (the phase is part of the controller state; it changes only at a
sample, from that sample's measurement):

0. **approach** — a guarded move: the task coordinates x = ĥ(q) follow
   x_d(t) = x_0 + n̂ · v (t − t_0), n̂ = Âᵀ/‖Â‖ the nominal constraint's normal at the start x_0
   (into the material), v the set speed, by computed torque on the nominal model
   (:func:`free_space_torque`). Contact is detected on the MEASURED force at the tool,
   ‖f‖ ≥ ``contact_force``; a move that travels ``approach_height + approach_margin`` without it
   ends in phase 5.
1. **ramp** — the paper's law (24)–(27) takes over at the contact instant t_c with its state
   started there (z = 0, the networks' weights at their initial values, the force-rate filter
   started at e_λ(t_c)) and its reference's time origin at t_c; λd ramps from the measured
   λ_c to the reference's over ``ramp_time`` (:class:`JobReference`), so the law does not start
   with a force step. The hand-over is bumpless: the step between the free-space law's torque and
   the law's at t_c (what the free-space law's integral had learnt of the model's error, mostly)
   is added to the law's torque and faded out over the ramp (the same quintic), so the torque
   sent is continuous and a robot's torque-rate limit does not clip the law's first samples.
2. **process** — the law with the reference as given (shifted by t_c), for ``process_time`` s
   (0: to the end of the run).
3. **unload** — λd ramps back down to λ_c over ``ramp_time``.
4. **lift** — the free-space law moves the tool ``lift_height`` out along the normal over
   ``lift_time`` (a quintic), then holds; its torque's step from the law's is faded out the same
   way over ``lift_time``.
5. **no contact** — the guarded move found nothing: the tool holds where the move ended, and the
   controller's guard stops the run (:attr:`JobController.fault_name`).

The controller sees only the measurement and the nominal model. It runs under sampled control
only (the phases switch at samples); ``hinfnn.scenario`` refuses ``job.start = "approach"``
under continuous control.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from .. import _linalg as la
from .._pytree import pytree_dataclass, static_field
from ..fields import declare
from ..protocols import Controller, ControllerOutput
from ..reference import RefSample, smoothstep

APPROACH, RAMP, PROCESS, UNLOAD, LIFT, NO_CONTACT = 0, 1, 2, 3, 4, 5
#: The phases by number, as recorded in the ``phase`` field.
PHASES = ("approach", "ramp", "process", "unload", "lift", "no_contact")

declare("phase", "-", "the job's phase (hinfnn.controllers.job): 0 approach, 1 force ramp, 2 process, 3 unload, "
        "4 lift-off, 5 no contact found")


@pytree_dataclass
class JobParams:
    """The job's numbers (``[job]``, :class:`hinfnn.scenario.sections.JobConfig`): the guarded move's
    speed (m/s) and longest travel (m), the free-space law's bandwidth (rad/s), the contact
    threshold (N), the ramp's time, the process's time (inf: no lift-off), the lift's height and
    time (s, m)."""

    speed: jax.Array
    travel: jax.Array
    gain: jax.Array
    contact_force: jax.Array
    ramp_time: jax.Array
    process_time: jax.Array
    lift_height: jax.Array
    lift_time: jax.Array

    @classmethod
    def make(cls, *, speed, travel, gain, contact_force, ramp_time, process_time, lift_height, lift_time):
        a = (lambda v: jnp.asarray(v, dtype=float))
        return cls(speed=a(speed), travel=a(travel), gain=a(gain), contact_force=a(contact_force),
                   ramp_time=a(ramp_time), process_time=a(jnp.inf if not process_time else process_time),
                   lift_height=a(lift_height), lift_time=a(lift_time))


@pytree_dataclass
class JobState:
    """The job's state: ``phase`` (1,) (:data:`PHASES`), ``clock`` (3,) the times the approach, the
    contact and the lift began, ``lam_c`` (k,) the measured λ at contact, ``x0`` (n,) the task
    coordinates where the free motion (approach or lift) began, ``xi`` (n,) the free-space law's
    integral of its error (:func:`free_space_torque`), ``tau0`` (n,) the torque step at the last
    hand-over between the free-space law and the law (faded out after it: a bumpless transfer), and
    the law's own state ``law`` (frozen outside the contact phases; ``xi`` inside them)."""

    phase: jax.Array
    clock: jax.Array
    lam_c: jax.Array
    x0: jax.Array
    xi: jax.Array
    tau0: jax.Array
    law: object

    def arrays(self) -> dict:
        """{"phase", "clock", "lam_c", "x0", "xi", "tau0", then the law's arrays}."""
        return {"phase": self.phase, "clock": self.clock, "lam_c": self.lam_c, "x0": self.x0, "xi": self.xi,
                "tau0": self.tau0, **self.law.arrays()}

    def names(self) -> tuple[str, ...]:
        return tuple(self.arrays())

    def __getattr__(self, name):  # the law's arrays by name (state.theta_f ...)
        law = self.__dict__.get("law")
        if law is None or name.startswith("__"):
            raise AttributeError(name)
        return getattr(law, name)


@pytree_dataclass
class JobReference:
    """The reference the law follows from the contact on: the scenario's reference with its time
    origin at the contact t_c, and λd ramped from the measured λ_c (quintic, ``ramp_time``) and,
    from the unload's start t_u, back down to λ_c:

        λd_job(t) = λ_c + r(t − t_c) (λd(t − t_c) − λ_c),  then  λd_job + r(t − t_u) (λ_c − λd_job)

    with r the quintic ramp from 0 to 1 (:func:`hinfnn.reference.smoothstep`)."""

    base: object
    t_c: jax.Array
    lam_c: jax.Array
    ramp_time: jax.Array
    t_u: jax.Array

    def __call__(self, t) -> RefSample:
        r = self.base(t - self.t_c)
        up = smoothstep(t - self.t_c, self.ramp_time)[0]
        lam = self.lam_c + up * (r.lam_d - self.lam_c)
        down = jnp.where(t >= self.t_u, smoothstep(t - jnp.minimum(self.t_u, t), self.ramp_time)[0], 0.0)
        lam = lam + down * (self.lam_c - lam)
        return RefSample(u1_d=r.u1_d, u1_d_dot=r.u1_d_dot, u1_d_ddot=r.u1_d_ddot, lam_d=lam)


def free_space_torque(arm, q, qd, x_d, xd_d, xdd_d, xi, gain, kernels=la.DEFAULT):
    """Computed torque on the NOMINAL model in task coordinates with integral action, its three
    poles at −ω (ω = ``gain``, rad/s): τ = M̂ Ĵ⁻¹ (a − J̇̂ q̇) + Ĉ(q, q̇) q̇ + Ĝ with
    a = ẍ_d − 3ω (ẋ − ẋ_d) − 3ω² (x − x_d) − ω³ ξ, ξ = ∫ (x − x_d) dt (``xi``): the integral
    takes up what the nominal model gets wrong at rest (gravity of a light model, a payload it
    does not know), which would otherwise sag the tool by that error over ω². ``kernels``: how the
    products are written (:class:`hinfnn._linalg.Kernels`). Returns (τ, x, ẋ)."""
    at = arm.law_terms(q, qd)
    x, J = at.x, at.J
    xd = kernels.mm(J, qd)
    w = gain
    a = xdd_d - 3.0 * w * (xd - xd_d) - 3.0 * w * w * (x - x_d) - w * w * w * xi
    Jd_qd = arm.J_dot_times(at, q, qd, qd[:, None])[:, 0]
    qdd = kernels.solve(J, a - Jd_qd)
    tau = kernels.mm(at.M, qdd) + arm.C_product(at, q, qd, qd) + at.G
    return tau, x, xd


def _normal(surface, x, kernels=la.DEFAULT):
    """The nominal constraint's unit normal n̂ = Âᵀ/‖Â‖ at x (into the material: θ̂ grows along it;
    its first constraint's when k > 1)."""
    A = surface.A_hat(x)[0]
    return A / jnp.sqrt(kernels.mm(A, A))


@pytree_dataclass
class JobController(Controller):
    """The phases of a job around a designed law (:class:`~hinfnn.controllers.law.ReducedOrderController`):
    ``JobController(law, job)`` with ``job`` a :class:`JobParams`. Sampled control only. Its state is
    a :class:`JobState`; its records add ``phase``. The law's attributes (``arm``, ``gains`` ...)
    are read through it."""

    law: object
    job: JobParams
    kind: str = static_field(default="")
    kernels: la.Kernels = la.kernels_field()  # how its products are written (hinfnn._linalg.Kernels)
    fault_name: ClassVar[str] = ("the job's guard: with no contact found, the distance the guarded move travelled (m); "
                                 "else σ_min(Ĵ), below the singularity guard's stop")

    def __getattr__(self, name):  # the law's attributes (arm, surface, gains, terms ...)
        law = self.__dict__.get("law")
        if law is None or name.startswith("__"):
            raise AttributeError(name)
        return getattr(law, name)

    @property
    def n(self) -> int:
        return self.law.n

    @property
    def m(self) -> int:
        return self.law.m

    @property
    def k(self) -> int:
        return self.law.k

    # --- state ---------------------------------------------------------------------------------------
    def init(self, **given) -> JobState:
        """Phase 0 (approach), the clocks at 0, the law's state as ``law.init(**given)``."""
        return JobState(phase=jnp.zeros(1), clock=jnp.zeros(3), lam_c=jnp.zeros(self.k), x0=jnp.zeros(self.n),
                        xi=jnp.zeros(self.n), tau0=jnp.zeros(self.n), law=self.law.init(**given))

    def state_from_arrays(self, arrays: dict) -> JobState:
        return JobState(phase=arrays["phase"], clock=arrays["clock"], lam_c=arrays["lam_c"], x0=arrays["x0"],
                        xi=arrays["xi"], tau0=arrays["tau0"], law=self.law.state_from_arrays(arrays))

    def state_arrays(self, state: JobState) -> dict:
        return state.arrays()

    def constrain(self, state: JobState) -> JobState:
        return dataclasses.replace(state, law=self.law.constrain(state.law))

    @property
    def needs_start(self) -> bool:
        return True

    def start(self, t, state: JobState, meas, ref) -> JobState:
        """The approach starts where the tool is: x_0 = ĥ(q) at the first sample, t_0 = t."""
        t = jnp.asarray(t, dtype=float)
        return dataclasses.replace(state, x0=self.law.arm.h(meas.q), clock=state.clock.at[0].set(t))

    def prepared(self) -> "JobController":
        return dataclasses.replace(self, law=self.law.prepared())

    def check_start(self, q0) -> None:
        self.law.check_start(q0)

    def summary(self) -> dict:
        j = self.job
        return {**self.law.summary(), "job": {k: float(getattr(j, k)) for k in (
            "speed", "travel", "gain", "contact_force", "ramp_time", "process_time", "lift_height", "lift_time")}}

    def deferred_fields(self, deferred) -> dict:
        return self.law.deferred_fields(deferred)

    def fault_measure(self, t, state, meas, ref, value):
        law = self.law.fault_measure(t, state.law, meas, self._reference(state, ref), value)
        return jnp.where(state.phase[0] == NO_CONTACT, value, law)

    # --- the phases ------------------------------------------------------------------------------------
    def _reference(self, state: JobState, ref) -> JobReference:
        j = self.job
        t_c = state.clock[1]
        return JobReference(base=ref, t_c=t_c, lam_c=state.lam_c, ramp_time=j.ramp_time,
                            t_u=t_c + j.ramp_time + j.process_time)

    def _motion(self, t, state: JobState):
        """The free-space law's target (x_d, ẋ_d, ẍ_d) in the approach, the lift and after a
        failed approach, and the guarded move's travel so far."""
        j = self.job
        nrm = _normal(self.law.surface, state.x0, self.kernels)
        travel = j.speed * (t - state.clock[0])
        moving = travel < j.travel
        dist_a = jnp.minimum(travel, j.travel)
        r, dr, ddr = smoothstep(t - state.clock[2], j.lift_time)
        lift = state.phase[0] == LIFT
        dist = jnp.where(lift, -j.lift_height * r, dist_a)
        vel = jnp.where(lift, -j.lift_height * dr, jnp.where(moving & (state.phase[0] == APPROACH), j.speed, 0.0))
        acc = jnp.where(lift, -j.lift_height * ddr, 0.0)
        return state.x0 + nrm * dist, nrm * vel, nrm * acc, travel

    def evaluate(self, t, state: JobState, meas, ref) -> ControllerOutput:
        """τ of the phase: the law (24)–(27) with :class:`JobReference` in the ramp, the process and
        the unload (its state's rate; zero in the other phases), the free-space law
        (:func:`free_space_torque`) in the approach and the lift. ``phase`` recorded."""
        t = jnp.asarray(t, dtype=float)
        ph = state.phase[0]
        law = self.law.evaluate(t, state.law, meas, self._reference(state, ref))
        x_d, xd_d, xdd_d, travel = self._motion(t, state)
        tau_f, x, xd = free_space_torque(self.law.arm, meas.q, meas.qd, x_d, xd_d, xdd_d, state.xi, self.job.gain,
                                             self.kernels)
        contact = (ph == RAMP) | (ph == PROCESS) | (ph == UNLOAD)
        # the torque step of the last hand-over, faded out over the ramp (into contact) or the lift
        fade_c = 1.0 - smoothstep(t - state.clock[1], self.job.ramp_time)[0]
        fade_l = 1.0 - smoothstep(t - state.clock[2], self.job.lift_time)[0]
        bump = state.tau0 * jnp.where(ph == RAMP, fade_c, jnp.where(ph == LIFT, fade_l, 0.0))
        m = self.m
        sig = dict(law.signals)
        lam = sig["lam"]
        free = {"u1_d": x_d[:m], "u1_d_dot": xd_d[:m], "e_u1_dot": (xd - xd_d)[:m], "lam_d": jnp.zeros_like(lam)}
        for name, v in free.items():
            sig[name] = jnp.where(contact, sig[name], v)
        sig["phase"] = ph
        dlaw = jax.tree.map(lambda d: jnp.where(contact, d, jnp.zeros_like(d)), law.dstate)
        zero = jnp.zeros(1)
        dstate = JobState(phase=zero, clock=jnp.zeros(3), lam_c=jnp.zeros_like(state.lam_c),
                          x0=jnp.zeros_like(state.x0), xi=jnp.where(contact, 0.0, x - x_d),
                          tau0=jnp.zeros_like(state.tau0), law=dlaw)
        no_contact = ph == NO_CONTACT
        return ControllerOutput(
            tau=jnp.where(contact, law.tau, tau_f) + bump, dstate=dstate,
            e_u1=jnp.where(contact, law.e_u1, (x - x_d)[:m]), e_lam=jnp.where(contact, law.e_lam, lam),
            signals=sig, fault=law.fault | no_contact,
            fault_value=jnp.where(no_contact, travel, law.fault_value), deferred=law.deferred,
            aux={"law": law.aux, "x": x})

    def sample(self, t, period, state: JobState, meas, ref, out: ControllerOutput | None = None):
        """The zero-order-hold update (τ at the sample, the law's state by forward Euler over
        ``period``), then the phase's change from this sample's measurement: contact (‖f‖ ≥
        ``contact_force``: the law started at t_c, λ_c kept), the ramp's end, the process's end,
        the unload's end (the lift starts where the tool is), or the guarded move's end without
        contact."""
        out = self.evaluate(t, state, meas, ref) if out is None else out
        tau, new = Controller.sample(self, t, period, state, meas, ref, out=out)
        j = self.job
        t = jnp.asarray(t, dtype=float)
        ph = state.phase[0]
        f = jnp.asarray(meas.force, dtype=float)
        touched = (ph == APPROACH) & (jnp.sqrt(self.kernels.mm(f, f)) >= j.contact_force)
        missed = (ph == APPROACH) & ~touched & (j.speed * (t - state.clock[0]) >= j.travel)
        t_c = state.clock[1]
        ramped = (ph == RAMP) & (t - t_c >= j.ramp_time)
        processed = (ph == PROCESS) & (t - t_c - j.ramp_time >= j.process_time)
        unloaded = (ph == UNLOAD) & (t - t_c - 2.0 * j.ramp_time - j.process_time >= 0.0)
        phase = jnp.select([touched, missed, ramped, processed, unloaded],
                           [float(RAMP), float(NO_CONTACT), float(PROCESS), float(UNLOAD), float(LIFT)], ph)
        lam_c = jnp.where(touched, out.signals["lam"], new.lam_c)
        clock = jnp.where(touched, new.clock.at[1].set(t), new.clock)
        clock = jnp.where(unloaded, clock.at[2].set(t), clock)
        x0 = jnp.where(unloaded, out.aux["x"], new.x0)
        moved = dataclasses.replace(new, phase=jnp.reshape(phase, (1,)), clock=clock, lam_c=lam_c, x0=x0)

        def at_touch():  # the law starts here (its filters on its reference from t_c); the torque's step kept
            started = dataclasses.replace(moved, law=self.law.init())
            ref_c = self._reference(started, ref)
            law = self.law.start(t, started.law, meas, ref_c) if self.law.needs_start else started.law
            return law, tau - self.law.evaluate(t, law, meas, ref_c).tau

        def at_lift():  # the free-space law from where the tool is; the torque's step kept
            x = out.aux["x"]
            zero = jnp.zeros_like(x)
            tau_f = free_space_torque(self.law.arm, meas.q, meas.qd, x, zero, zero, moved.xi, j.gain,
                                      self.kernels)[0]
            return moved.law, tau - tau_f

        law, tau0 = jax.lax.cond(touched, at_touch, lambda: jax.lax.cond(unloaded, at_lift,
                                                                             lambda: (moved.law, moved.tau0)))
        return tau, dataclasses.replace(moved, law=law, tau0=tau0)


def approach_pose(arm, constraint, q_contact, height):
    """The joint angles with the NOMINAL tool ``height`` above the NOMINAL surface, along its normal,
    at the motion coordinates of ``q_contact`` (the start pose on the true surface): ĥ(q_contact)
    projected onto θ̂ = 0 (five Newton steps along Âᵀ), moved by −height · n̂, and solved for q by
    Newton's method from q_contact. Returns (q, the task-space residual ‖ĥ(q) − x‖∞). Plain:
    its callers compile it (:data:`hinfnn.compiled.approach_pose`)."""
    x = arm.h(q_contact)
    for _ in range(5):
        A = constraint.A_hat(x)
        x = x - la.DEFAULT.mm(A.T, jnp.linalg.solve(la.DEFAULT.mm(A, A.T), constraint.theta(x)))
    target = x - height * _normal(constraint, x)
    q = arm.inverse_kinematics(target, q_contact)
    return q, jnp.max(jnp.abs(arm.h(q) - target))


def job_params(cfg, contact_force: float) -> JobParams:
    """The :class:`JobParams` of a scenario's ``[job]`` section, with its contact threshold
    ``contact_force`` resolved (N: :meth:`hinfnn.scenario.sections.JobConfig.contact_threshold`)."""
    return JobParams.make(speed=cfg.approach_speed, travel=cfg.approach_height + cfg.approach_margin,
                          gain=cfg.approach_gain, contact_force=contact_force, ramp_time=cfg.ramp_time,
                          process_time=cfg.process_time, lift_height=cfg.lift_height, lift_time=cfg.lift_time)


__all__ = ["APPROACH", "RAMP", "PROCESS", "UNLOAD", "LIFT", "NO_CONTACT", "PHASES", "JobParams", "JobState",
           "JobReference", "JobController", "free_space_torque", "approach_pose", "job_params"]
