"""The sections of a scenario file, as typed dataclasses, and how each builds its objects.

Arms, surfaces and plants are *registered* sections (:mod:`hinfnn.scenario.registry`): the
``model`` / ``kind`` / ``engine`` key of the TOML table chooses the class, and the class builds
the library object (``build()``). Controllers are chosen by ``controller.kind`` from
:data:`hinfnn.controllers.KINDS`.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError, DesignError
from .registry import ARMS, PLANTS, SURFACES
from .schema import Matrix, param, section

from typing import ClassVar, Literal


# --- arms ------------------------------------------------------------------------------------------


@section
class ArmConfig:
    """An arm model (``model`` chooses the kind)."""

    __registry__ = ARMS
    model: str = param(doc="arm model")

    def build(self):
        raise NotImplementedError


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

    def build(self):
        from ..model import TwoLinkArm

        return TwoLinkArm(m1=self.m1, m2=self.m2, l1=self.l1, l2=self.l2, g=self.g)

    def reach(self) -> tuple[float, float]:
        """(innermost, outermost) distance of the tip from the base."""
        return abs(self.l1 - self.l2), self.l1 + self.l2


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

    def build(self, **context):
        """The plant object. ``context``: ``dt`` (the simulation step) and ``control_period``
        (None for continuous control), for engines that step themselves."""
        raise NotImplementedError


@PLANTS.register("hinfnn")
@section
class RigidPlantConfig(PlantConfig):
    """hinfnn's own plant: rigid-body arm, penalty contact on the true surface."""

    def build(self, **context):
        from ..plant import RigidBodyPlant

        return RigidBodyPlant(arm=self.arm.build(), surface=self.surface.build(), contact=self.contact.build(),
                              disturbance=self.disturbance.build())


@PLANTS.register("mujoco")
@section
class MujocoPlantConfig(PlantConfig):
    """MuJoCo as the true plant (optional extra ``hinfnn[mujoco]``; docs/mujoco.md): the true arm
    and surface as MJCF, the contact converted from N/m and N·s/m, stepped every simulation dt
    (MuJoCo's timestep) with the torque held over the control period (sampled-data control)."""

    discrete: ClassVar[bool] = True
    integrator: Literal["RK4", "implicit", "implicitfast", "Euler"] = param(
        "RK4", doc="MuJoCo's integrator (RK4 or implicit are accurate at the contact's frequency)")
    callback: Literal["host", "pure_callback"] = param(
        "host", doc="how the compiled loop calls MuJoCo ('pure_callback': JAX's public API, ~4x slower)")

    def build(self, *, dt=1e-4, control_period=None, **context):
        from ..plant.mujoco import MujocoPlant, require_mujoco

        require_mujoco()
        return MujocoPlant.from_models(self.arm.build(), self.surface.build(), self.contact.build(),
                                       self.disturbance.build(), control_period=dt, timestep=dt,
                                       integrator=self.integrator, callback=self.callback)


@section
class NominalConfig:
    """What the controller is told: the nominal model."""

    arm: ArmConfig = param(doc="the nominal arm")
    surface: SurfaceConfig = param(doc="the nominal surface")


# --- the controller -------------------------------------------------------------------------------


@section
class GainsConfig:
    rho: float = param(doc="attenuation level rho", gt=0.0, le=1e6)
    mu_z: float = param(doc="mu_z of eq. (27)", gt=0.0, le=1e8)
    K_p: float = param(doc="position gain K_p", gt=0.0, le=1e8)
    K_v: float = param(doc="velocity gain K_v", gt=0.0, le=1e8)
    alpha_lam: float = param(doc="force weight alpha_lam", gt=0.0, le=1e8)
    alpha_z: float = param(doc="alpha_z of eq. (27)", gt=0.0, le=1e8)
    beta_lam: Literal["min"] | float = param(doc="beta_lam of eq. (32), or \"min\" for its Theorem 1 bound",
                                             gt=0.0, le=1e8)
    gamma_1: float = param(doc="learning rate gamma_1 of eq. (30)", gt=0.0, le=1e8)
    gamma_2: float = param(doc="learning rate gamma_2 of eq. (31)", gt=0.0, le=1e8)
    Q_p: Matrix = param(doc="weight Q_p (2m x 2m, symmetric positive definite)", ge=-1e8, le=1e8)
    R_p: Matrix = param(doc="weight R_p (m x m; 1x1 for the planar arm)", ge=-1e8, le=1e8)

    def build(self):
        from ..controllers import Gains

        return Gains(K_p=self.K_p, K_v=self.K_v, rho=self.rho, mu_z=self.mu_z, alpha_z=self.alpha_z,
                     alpha_lam=self.alpha_lam, beta_lam=None if self.beta_lam == "min" else self.beta_lam,
                     gamma_1=self.gamma_1, gamma_2=self.gamma_2, Q_p=np.asarray(self.Q_p, float),
                     R_p=np.asarray(self.R_p, float))


@section
class NetworkConfig:
    centre_start: float = param(doc="first centre c_1", ge=-1e6, le=1e6)
    centre_step: float = param(doc="spacing of the centres", gt=0.0, le=1e6)
    centre_count: int = param(doc="number of hidden units", ge=1, le=5000)
    slope: float = param(doc="tanh slope alpha of eq. (17)", gt=0.0, le=1e6)
    w_a: float = param(doc="weight of the first input (e_u1 for F_p, e_lam for F_f) in the network input",
                       ge=-1e6, le=1e6)
    w_b: float = param(doc="weight of the second input (e_u1_dot for F_p, z for F_f) in the network input",
                       ge=-1e6, le=1e6)
    projection: bool = param(doc="Remark 2 projection onto ||Theta|| <= radius")
    radius: float = param(doc="projection radius d (Remark 2)", gt=0.0, le=1e12)

    def build(self, name: str, n_out: int):
        from ..controllers import TanhNetwork, centres_from

        return TanhNetwork.build(centres_from(self.centre_start, self.centre_step, self.centre_count), n_out=n_out,
                                 slope=self.slope, w_a=self.w_a, w_b=self.w_b,
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

    def validate(self, path):
        if self.stiffness_max < self.stiffness_min:
            raise ConfigError(f"must be >= stiffness_min = {self.stiffness_min:g}, got {self.stiffness_max:g}",
                              key=f"{path}.stiffness_max")


@section
class ControllerConfig:
    kind: str | tuple[str, ...] = param(doc="controller(s) to run: a name of hinfnn.controllers.KINDS or a list",
                                        allowed=_kinds_allowed)
    augmented: bool = param(doc="Remark 1 augmented performance (eq. 40, v_lam = -beta_lam e_lam)")
    gains: GainsConfig = param(doc="gains")
    network_p: NetworkConfig = param(doc="F_p network")
    network_f: NetworkFConfig = param(doc="F_f network")
    force_rate: ForceRateConfig = param(doc="force-rate term (not in the paper)")
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

    def build(self, kind: str, arm, surface, *, u1_range=None, q_start=None, period=None):
        """Design the controller ``kind`` from the NOMINAL arm and surface (``u1_range``,
        ``q_start``: the reference's span of u1 and a start pose, for the force-rate rule;
        ``period``: the control period under sampled control). Raises :class:`DesignError` with
        the dotted key of the failing gain."""
        from ..controllers import design

        fr = self.force_rate
        force_rate = None
        if fr.kappa != 0.0:
            force_rate = dict(kappa=fr.kappa, tau_f=fr.tau_f, zeta=fr.zeta, stiffness_min=fr.stiffness_min,
                              stiffness_max=fr.stiffness_max, u1_range=u1_range, q_start=q_start, period=period)
        try:
            return design(kind, arm, surface, self.gains.build(), augmented=self.augmented,
                          network_p=self.network_p.build("controller.network_p", surface.m),
                          network_f=self.network_f.build("controller.network_f", surface.k),
                          force_rate=force_rate, singularity_stop=self.singularity_stop)
        except DesignError as err:
            raise prefixed(err) from None


def prefixed(err: DesignError) -> DesignError:
    """The same DesignError with its key as a scenario key (``rho`` -> ``controller.gains.rho``)."""
    key = err.key
    if key is None:
        return err
    if key in ("rho", "mu_z", "alpha_z", "alpha_lam", "beta_lam", "gamma_1", "gamma_2", "Q_p", "R_p", "K_p", "K_v"):
        full = f"controller.gains.{key}"
    elif key.startswith(("network_", "force_rate")):
        full = f"controller.{key}"
    else:
        full = key
    message = err.args[0].split(": ", 1)[1] if err.args[0].startswith(f"{key}: ") else err.args[0]
    return DesignError(message, key=full, value=err.value, bound=err.bound)


# --- reference, start, simulation --------------------------------------------------------------------


@section
class ReferenceConfig:
    """u1d = u1_offset + u1_amplitude cos(2π t / u1_period + u1_phase), λd likewise."""

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

    def build(self):
        import jax.numpy as jnp

        from ..reference import CosineReference

        def a(v):
            return jnp.array([float(v)])

        return CosineReference(
            u1_offset=a(self.u1_offset), u1_amplitude=a(self.u1_amplitude),
            u1_omega=a(2 * math.pi / self.u1_period), u1_phase=a(self.u1_phase),
            lam_offset=a(self.lam_offset), lam_amplitude=a(self.lam_amplitude),
            lam_omega=a(2 * math.pi / self.lam_period), lam_phase=a(self.lam_phase))


@section
class InitialConfig:
    u1: float = param(doc="u1(0): true end-effector x1 on the true surface, m", ge=-100.0, le=100.0)
    elbow: Literal["up", "down"] = param(doc="inverse-kinematics branch")


@section
class SimulationConfig:
    t_final: float = param(doc="horizon, s", gt=0.0, le=1e5)
    dt: float = param(doc="RK4 step, s", gt=0.0, le=0.1)
    control: Literal["continuous", "sampled"] = param(doc="control mode")
    control_period: float = param(doc="sampling period when control = \"sampled\", s", gt=0.0, le=1.0)
    output_interval: float = param(doc="largest interval between saved samples, s", gt=0.0, le=1e3)
    torque_limit: float = param(doc="a run stops past this |tau_i|, N m", gt=0.0, le=1e12)
    penetration_limit: float = param(doc="a run stops past this penetration, m", gt=0.0, le=1e3)

    def limits(self):
        from ..sim import Limits

        return Limits(torque=self.torque_limit, penetration=self.penetration_limit)
