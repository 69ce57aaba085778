"""The controllers of the paper as compositions of terms, and the one place that names them.

===========  ============================  ===========================================
kind         terms added to the CT law      theory
===========  ============================  ===========================================
``fl``       none                          Sec. VI feedback-linearization-like law
``hinf``     v_p (33), v_λ (32)/(41)       Theorem 2 (eq. 51), suboptimal H∞ only
``hinf_nn``  v_p, v_λ, F_p (30), F_f (31)  Theorem 1, adaptive H∞ NN
===========  ============================  ===========================================

:data:`KINDS` maps each kind name to its :class:`Composition` (terms, label, whether Theorem 1's
bounds apply, whether it learns). A new controller is a new composition plus one line
in :data:`KINDS` (or :func:`register` from your own code).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .._declared import design_program
from .._pytree import Note
from ..errors import DesignError
from . import terms as T
from .gains import Gains
from .law import BLOCK, ReducedOrderController
from .network import Adaptation, TanhNetwork, integral_gain, paper_network_f, paper_network_p
from .riccati import design_riccati


@dataclasses.dataclass(frozen=True)
class Composition:
    """A controller kind: which terms the law gets, and its name in words.

    ``terms(options) -> tuple[Term, ...]`` builds the terms from the design options (networks,
    ``augmented`` ...). ``robust``: Theorem 1's bounds on α_λ, β_λ are required and the Riccati
    equation must have a stabilising solution (the FL-like law uses them only as performance
    weights). ``learns``: its terms include the networks (their settings describe the run).

    A controller family not built from the paper's law gives ``build(arm, surface, gains,
    **options) -> Controller`` instead (``terms`` is then not used): any
    :class:`hinfnn.protocols.Controller`, designed from the nominal arm and surface."""

    kind: str
    label: str
    terms: Callable[[dict], tuple] = lambda options: ()
    robust: bool = True
    learns: bool = False
    doc: str = ""
    build: Callable | None = None


def _networks(opts):
    return (T.PositionNetwork(network=opts.get("network_p") or paper_network_p()),
            T.ForceNetwork(network=opts.get("network_f") or paper_network_f(opts.get("centre_preset", "paper-likely"))))


#: The robust modifications of the update laws (30)–(31) (``controller.adaptation.robust``).
ROBUST = ("none", "dead_zone", "sigma", "e_mod", "projection")

#: The position-side uncertainty a "design" projection radius lets F_p cover, per output (m/s²):
#: the acceleration of gravity, a nominal model wrong by its whole gravity load.
GRAVITY_BOUND = 9.81


@design_program
def _observation_jacobians(ctrl, q, qd, force):
    """∂(u1, u̇1, λ)/∂(q, q̇, f) of the law's observation map (:meth:`ReducedOrderController.observe`)."""
    from ..protocols import Measurement

    return jax.jacfwd(lambda a, b, c: ctrl.observe(Measurement(q=a, qd=b, force=c)), argnums=(0, 1, 2))(q, qd, force)


def drive_noise(ctrl, q, force_noise: float = 0.0, q_noise=0.0, qd_noise=0.0) -> tuple[float, float]:
    """(RMS of F_p's drive B_pᵀP_p x_p, RMS of F_f's drive e_λ) from a sensor's white noise alone,
    at the pose ``q``: joint-angle and joint-rate noise of the given standard deviations (a number
    or one per joint) move u1 = ĥ1(q) and u̇1 = (Ĵq̇)_1 by Ĵ1 δq, Ĵ1 δq̇; force noise of σ on each
    axis of the sensed tool force moves λ by L δf (L the law's map from the tool force to λ), so
    RMS(e_λ) = σ ‖L‖_F. The loop's own response to the noise (the motion the noisy torque causes)
    is not included: it is what the drive would show with the loop open."""
    q = jnp.asarray(q, dtype=float)
    n = q.shape[0]
    arm = ctrl.arm
    dim = arm.J(q).shape[0] if arm.task_is_point else arm.point_jacobian(q).shape[0]
    (du_dq, _, _), (_, dv_dqd, _), (_, _, dl_df) = _observation_jacobians(ctrl, q, jnp.zeros(n), jnp.zeros(dim))
    m = ctrl.m
    sq = np.broadcast_to(np.asarray(q_noise, float), (n,)) ** 2
    sqd = np.broadcast_to(np.asarray(qd_noise, float), (n,)) ** 2
    J1, Jv = np.asarray(du_dq), np.asarray(dv_dqd)
    cov_x = np.zeros((2 * m, 2 * m))
    cov_x[:m, :m] = (J1 * sq) @ J1.T
    cov_x[m:, m:] = (Jv * sqd) @ Jv.T
    Pl = np.asarray(ctrl.P_p, float)[m:]
    noise_p = float(np.sqrt(max(np.trace(Pl @ cov_x @ Pl.T), 0.0)))
    noise_f = float(force_noise) * float(np.linalg.norm(np.asarray(dl_df)))
    return noise_p, noise_f


def _least_norm_radius(network, bound) -> float:
    """‖Θ‖ of the least-norm weights whose outputs are ``bound`` each at zero input: Σ_o bound²/‖ξ_o(0)‖²
    (ξ_o the features of output o; Remark 2's ball must contain the ideal weights Θ*, and a Θ* that
    gives the outputs U needs ‖Θ*‖ ≥ (Σ U_o²/‖ξ_o‖²)^½)."""
    zeros = jnp.zeros(network.n_out)
    xi = np.atleast_2d(np.asarray(network.features(zeros, zeros)))
    norms = np.broadcast_to(np.sqrt(np.sum(xi * xi, axis=1)), (network.n_out,))
    return float(np.sqrt(np.sum(np.asarray(bound, float) ** 2 / np.maximum(norms, 1e-12) ** 2)))


def robust_adaptation(ctrl, *, robust: str, leak: float = 1.0, zone: float = 2.0, noise_p=None, noise_f=None,
                      radius_p=None, radius_f=None, q=None, lam_max=None, force_noise: float = 0.0, q_noise=0.0,
                      qd_noise=0.0):
    """The controller ``ctrl`` with its networks' update laws (30)–(31) made robust to measurement
    noise (not in the paper; docs/beyond-the-paper.md, section 11), by ``robust``:

    * ``"dead_zone"``: no learning while ‖s‖ ≤ ``zone`` × the drive's noise RMS (``noise_p``,
      ``noise_f``; None: :func:`drive_noise` of the declared ``force_noise``, ``q_noise``,
      ``qd_noise`` at the pose ``q``);
    * ``"sigma"``: σ-modification, leakage −``leak`` Θ̂ (1/s);
    * ``"e_mod"``: e-modification, leakage −``leak`` (‖s‖ / the drive's noise RMS) Θ̂ (none on a
      network whose drive has no noise);
    * ``"projection"``: Remark 2 on both networks, radii ``radius_p``, ``radius_f`` (None: the
      least-norm weights giving :data:`GRAVITY_BOUND` per output (F_p) and ``lam_max`` (F_f) at
      zero error, :func:`_least_norm_radius`);
    * ``"none"``: ``ctrl`` itself (eqs. 30–31).

    Raises DesignError naming the ``adaptation.*`` key."""
    if robust not in ROBUST:
        raise DesignError(f"unknown robust adaptation {robust!r}; allowed: {', '.join(map(repr, ROBUST))}",
                          key="adaptation.robust", value=robust)
    nets = [t for t in ctrl.terms if isinstance(t, T._NetworkTerm)]
    if robust == "none" or not nets:
        return ctrl
    for key, v in (("leak", leak), ("zone", zone), ("noise_p", noise_p), ("noise_f", noise_f)):
        if v is not None and not (np.isfinite(v) and v >= 0):
            raise DesignError(f"must be finite and >= 0, got {v!r}", key=f"adaptation.{key}", value=v, bound=0.0)
    for key, v in (("radius_p", radius_p), ("radius_f", radius_f)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise DesignError(f"must be finite and > 0, got {v!r}", key=f"adaptation.{key}", value=v, bound=0.0)
    if robust == "projection":
        if radius_f is None and lam_max is None:
            raise DesignError("a \"design\" radius of F_f needs the largest |lam_d| of the reference (lam_max)",
                              key="adaptation.radius_f")
        terms = []
        for t in ctrl.terms:
            if isinstance(t, T._NetworkTerm):
                pos = isinstance(t, T.PositionNetwork)
                given = radius_p if pos else radius_f
                r = given if given is not None else _least_norm_radius(t.network, GRAVITY_BOUND if pos else lam_max)
                t = dataclasses.replace(t, network=dataclasses.replace(t.network, radius=jnp.asarray(float(r)),
                                                                       project=True))
            terms.append(t)
        return dataclasses.replace(ctrl, terms=tuple(terms))
    if robust in ("dead_zone", "e_mod") and (noise_p is None or noise_f is None):
        if q is None:
            raise DesignError(f"{robust!r} needs the drives' noise: give noise_p and noise_f, or a start pose and "
                              "the sensor's noise", key="adaptation.noise_f")
        auto_p, auto_f = drive_noise(ctrl, q, force_noise, q_noise, qd_noise)
        noise_p = auto_p if noise_p is None else noise_p
        noise_f = auto_f if noise_f is None else noise_f
    if robust in ("dead_zone", "e_mod") and not (noise_p or noise_f):
        raise DesignError(f"{robust!r} is sized from the sensor's noise, and none is declared (plant.sensor.force_noise, "
                          "q_noise, qd_noise all 0): declare the sensor's noise or give controller.adaptation.noise_f",
                          key="adaptation.noise_f", value=0.0)
    terms = []
    for t in ctrl.terms:
        if isinstance(t, T._NetworkTerm):
            noise = float(noise_p if isinstance(t, T.PositionNetwork) else noise_f or 0.0) if robust != "sigma" else 0.0
            name = "adaptation"
            if robust == "dead_zone":
                a = Adaptation.make(zone=zone * noise, noise=noise, name=name)
            elif robust == "sigma":
                a = Adaptation.make(leak=leak, name=name)
            else:
                a = Adaptation.make(e_gain=leak / noise if noise > 0 else 0.0, noise=noise, name=name)
            t = dataclasses.replace(t, adaptation=a)
        terms.append(t)
    return dataclasses.replace(ctrl, terms=tuple(terms))


KINDS: dict[str, Composition] = {
    "fl": Composition("fl", "FL-like", lambda o: (), robust=False,
                      doc="Sec. VI feedback-linearization-like law (the CT part alone)"),
    "hinf": Composition("hinf", "H∞-only", lambda o: (T.RobustPosition(), T.RobustForce()),
                        doc="Theorem 2: eq. (51) with v_p (33) and v_λ (32)"),
    "hinf_nn": Composition("hinf_nn", "adaptive H∞ NN", lambda o: (T.RobustPosition(), T.RobustForce(), *_networks(o)),
                           learns=True, doc="Theorem 1: eq. (24) with v_p, v_λ and the networks F_p, F_f"),
}


def register(composition: Composition) -> None:
    """Add a controller kind (its name becomes a valid ``controller.kind``)."""
    KINDS[composition.kind] = composition


def unregister(kind: str) -> None:
    """Remove a controller kind."""
    KINDS.pop(kind, None)


def design(kind: str, arm, surface, gains: Gains | None = None, *, augmented: bool = False,
           extra_terms: tuple = (), force_rate: dict | None = None, singularity_stop: float = 0.0,
           block: int | None = BLOCK, adaptation: dict | None = None, force_filter: dict | None = None,
           **options) -> ReducedOrderController:
    """Design the controller ``kind`` from the NOMINAL arm and surface: check the gains (Theorem
    1's bounds, Remarks 1–3), solve the Riccati-like eq. (35) (or (40) with ``augmented``,
    Remark 1), build and check the terms. ``options``: ``network_p``, ``network_f``,
    ``centre_preset`` for the adaptive law. ``extra_terms`` are appended to the composition's.

    ``force_rate`` (not in the paper): the keyword arguments of
    :func:`~hinfnn.controllers.force_rate.design_force_rate` (``kappa`` "rule" or seconds,
    ``tau_f``, ``zeta``, ``stiffness_min``, ``stiffness_max``, ``u1_path``, ``q_start``,
    ``period``, ``source``: "force" or "velocity", :class:`~hinfnn.controllers.terms.ForceRate`);
    a κ of 0 leaves the law as the paper's. ``singularity_stop``: the law reports a
    fault (the simulator stops, the sampled controller returns NaN) when σ_min(Ĵ) falls below it.
    ``block``: the largest array the controller keeps in the compiled loop
    (:data:`~hinfnn.controllers.law.BLOCK`; None: arrays whole). ``adaptation`` (not in the
    paper): the keyword arguments of :func:`robust_adaptation` (the networks' update laws made
    robust to measurement noise); None: eqs. (30)–(31).

    ``force_filter`` (not in the paper; :mod:`hinfnn.controllers.sensing`): ``order`` (0: none, 1,
    2 or "design"), ``cutoff_hz`` (Hz or "design"), the sensor the design assumes (``noise``, N;
    ``delay``, samples), ``period`` (the control period: the filter is discrete) and optionally
    ``torque_rate_limit`` (N·m/s per joint, the robot's rate clamp) and ``torque_rate_share`` (the
    share of it the noise's predicted 99th percentile may use, at a noise of at least
    ``rate_noise_floor`` N). With a
    force-rate term whose κ is "rule", κ is chosen with the filter for that sensor
    (:func:`~hinfnn.controllers.sensing.design_sensing`); order 0 leaves today's law unchanged.

    Raises :class:`~hinfnn.errors.DesignError` naming the condition that failed."""
    if kind not in KINDS:
        raise DesignError(f"unknown controller kind {kind!r}; known: {', '.join(KINDS)}", key="kind", value=kind)
    comp = KINDS[kind]
    if comp.build is not None:  # a family of its own (Composition.build)
        from ..protocols import Controller

        ctrl = comp.build(arm, surface, gains, augmented=augmented, force_rate=force_rate,
                          singularity_stop=singularity_stop, **options)
        if not isinstance(ctrl, Controller):
            raise TypeError(f"the build of controller kind {kind!r} returned a {type(ctrl).__name__}, not a "
                            "hinfnn.protocols.Controller")
        return ctrl
    g = (gains or Gains.paper()).normalized(surface.m, surface.k, require_bounds=comp.robust)
    try:
        P = jnp.asarray(design_riccati(g, "40" if augmented else "35").P)
    except DesignError:
        if comp.robust:
            raise
        P = jnp.full((2 * surface.m, 2 * surface.m), jnp.nan)
    terms = tuple(comp.terms(options)) + tuple(extra_terms)
    ff = force_filter or {}
    filtering = ff.get("order", 0) not in (0, None)
    if filtering and ff.get("period") is None:
        raise DesignError("the force filter is discrete: it needs sampled control (simulation.control = "
                          "\"sampled\" or a plant that steps itself)", key="force_filter.order", value=ff["order"])
    if force_rate and force_rate.get("kappa", 0.0) not in (0, 0.0, None):
        if augmented:
            raise DesignError("the force-rate term's storage argument does not cover Remark 1's augmented "
                              "index; use one or the other", key="force_rate.kappa", value=force_rate["kappa"])
        from .force_rate import design_force_rate

        sensing = None
        velocity = force_rate.get("source", "force") == "velocity"
        sampled = force_rate.get("period") is not None
        if filtering or (sampled and (velocity or int(ff.get("delay", 0)) > 0)):  # the sampled loop's design
            force_net = next((t.network for t in terms if isinstance(t, T.ForceNetwork)), None)
            sensing = dict(order=ff.get("order", 0), cutoff_hz=ff.get("cutoff_hz", "design"),
                           noise=float(ff.get("noise", 0.0)), delay=int(ff.get("delay", 0)),
                           g_f=integral_gain(force_net, g.gamma_2))
            if ff.get("torque_rate_limit") is not None:
                sensing["torque_rate_limit"] = ff["torque_rate_limit"]
                sensing["torque_rate_share"] = float(ff.get("torque_rate_share", 1.0))
                sensing["rate_noise_floor"] = float(ff.get("rate_noise_floor", 0.0))
        d = design_force_rate(arm, surface, g, robust=comp.robust, sensing=sensing, **force_rate)
        velocity_args = dict(stiffness=jnp.asarray(float(d.stiffness_max)), source="velocity") if velocity else {}
        terms = terms + (T.ForceRate(kappa=jnp.asarray(d.kappa), tau_f=jnp.asarray(d.tau_f),
                                     design=Note(d.as_dict().items()), **velocity_args),)
        if d.sensing is not None and d.sensing["order"]:
            ff = dict(ff, order=d.sensing["order"], cutoff_hz=d.sensing["cutoff_hz"])
    elif filtering and "design" in (ff["order"], ff["cutoff_hz"]):
        raise DesignError("the force filter is designed with the force-rate term's gain: set "
                          "controller.force_rate.kappa (\"rule\") or give the filter's order and cutoff",
                          key="force_filter.cutoff_hz", value=ff["cutoff_hz"])
    force_filter_obj = None
    if filtering and ff["order"] not in (0, "design"):
        from .sensing import butterworth

        force_filter_obj = butterworth(int(ff["order"]), float(ff["cutoff_hz"]), float(ff["period"]))
    for term in terms:
        term.check(surface.m, surface.k)
    ctrl = ReducedOrderController(arm=arm, surface=surface, gains=g, P_p=P, terms=terms,
                                  sigma_stop=jnp.asarray(float(singularity_stop)), kind=kind, augmented=augmented,
                                  block=block, force_filter=force_filter_obj)
    if adaptation:
        ctrl = robust_adaptation(ctrl, **adaptation)
    return ctrl


class FeedbackLinearization:
    """Sec. VI FL-like controller: eq. (24) without v_p, v_λ and networks (``design("fl", ...)``).

    Printed error fixed (docs/paper-conventions.md): the paper prints u̇1d inside M̄11[·]; the law
    needs ü1d. P_p of eq. (35) is solved too, for the storage function used in the dissipation
    report only (NaN if ρ admits no solution: this law does not use it)."""

    @staticmethod
    def design(arm_nom, surface_nom, gains: Gains | None = None) -> ReducedOrderController:
        return design("fl", arm_nom, surface_nom, gains)


class HinfController:
    """Theorem 2, suboptimal H∞-only: eq. (51) with (27), (32), (33) and P_p of eq. (35); with
    ``augmented`` (Remark 1) eq. (40) and v_λ = −β_λ e_λ (41) (``design("hinf", ...)``)."""

    @staticmethod
    def design(arm_nom, surface_nom, gains: Gains | None = None, *, augmented: bool = False,
               extra_terms: tuple = ()) -> ReducedOrderController:
        return design("hinf", arm_nom, surface_nom, gains, augmented=augmented, extra_terms=extra_terms)


class HinfNNController:
    """Theorem 1, adaptive H∞ NN (``design("hinf_nn", ...)``) and Remarks 1–3: Remark 1 with
    ``augmented``, Remark 2 with networks built with a projection ``radius``, Remark 3 with any
    α_z > 0 (bounds checked by :meth:`~hinfnn.controllers.gains.Gains.normalized`). Without
    explicit networks the Sec. VI ones are used, F_f with ``centre_preset`` ("paper-likely":
    step 0.5, or "paper-printed": step 0.05)."""

    @staticmethod
    def design(arm_nom, surface_nom, gains: Gains | None = None, *, network_p: TanhNetwork | None = None,
               network_f: TanhNetwork | None = None, centre_preset: str = "paper-likely",
               augmented: bool = False, extra_terms: tuple = ()) -> ReducedOrderController:
        return design("hinf_nn", arm_nom, surface_nom, gains, augmented=augmented, extra_terms=extra_terms,
                      network_p=network_p, network_f=network_f, centre_preset=centre_preset)
