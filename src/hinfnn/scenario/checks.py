"""The cross-field and physics checks of a scenario, run before anything is compiled.

Each raises :class:`~hinfnn.errors.ConfigError` or :class:`~hinfnn.errors.DesignError` naming
the dotted key, the value and what is allowed.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError


def require_multiple(key, value, step, message, allow_zero=False):
    """value must be a whole multiple (≥ 1, or 0 when allow_zero) of step."""
    ratio = value / step
    if not math.isfinite(ratio):
        raise ConfigError(message, key=key)
    n = round(ratio)
    if abs(ratio - n) > 1e-6 * max(1.0, abs(ratio)) or (n < 1 and not (allow_zero and value == 0)):
        raise ConfigError(message, key=key)


def check(sc) -> None:
    """Every check of :meth:`hinfnn.scenario.Scenario.check`."""
    s = sc.simulation
    dt, t_final = s.dt, s.t_final
    require_multiple("simulation.t_final", t_final, dt, f"{t_final:g} s is not a whole number of steps dt = {dt:g} s")
    d = sc.plant.disturbance
    if any(a != 0.0 for a in d.amplitude):
        half = 0.5 * d.period
        require_multiple("simulation.dt", half, dt,
                         f"{dt:g} s does not divide the disturbance's half-period {half:g} s; steps must "
                         "land on its switching instants")
        require_multiple("plant.disturbance.phase", d.phase % half, dt,
                         f"{d.phase:g} s (modulo the half-period {half:g} s) is not a multiple of "
                         f"dt = {dt:g} s; steps must land on the switching instants", allow_zero=True)
    if s.control == "sampled":
        require_multiple("simulation.control_period", s.control_period, dt,
                         f"{s.control_period:g} s is not a whole multiple of dt = {dt:g} s")
        require_multiple("simulation.control_period", t_final, s.control_period,
                         f"{s.control_period:g} s does not divide t_final = {t_final:g} s: the last "
                         "control period would be cut short")
    if s.output_interval < dt:
        raise ConfigError(f"must be >= dt = {dt:g}, got {s.output_interval:g}", key="simulation.output_interval")
    if type(sc.plant.arm) is not type(sc.nominal.arm):
        raise ConfigError(f"nominal and true arm models must have the same structure (true: {sc.plant.arm.model!r}, "
                          f"nominal: {sc.nominal.arm.model!r})", key="nominal.arm.model")
    n = getattr(type(sc.plant.arm), "n", None)
    if n is not None and len(d.amplitude) != n:
        raise ConfigError(f"must be a list of {n} numbers (one per joint), got {list(d.amplitude)!r}",
                          key="plant.disturbance.amplitude")
    plant = sc.build_plant()
    q0 = np.asarray(sc.initial_q(plant))
    if not np.all(np.isfinite(q0)):
        reach = getattr(sc.plant.arm, "reach", None)
        between = f" (|x| must be between {reach()[0]:g} and {reach()[1]:g} m)" if reach else ""
        raise ConfigError(f"u1(0) = {sc.initial.u1:g} on the true surface is out of the true arm's reach{between}",
                          key="initial.u1")
    controllers = [sc.build_controller(kind) for kind in sc.kinds]
    for ctrl in controllers:
        ctrl.check_start(q0)
    if sc.controller.singularity_stop > 0:
        _check_path_against_singularity(sc, q0)
    _check_step_against_contact(sc, plant, q0)


def _check_path_against_singularity(sc, q0) -> None:
    """With the singularity guard on, the reference's path must keep σ_min(Ĵ) above the stop on
    the NOMINAL model (else the run would stop by design): a DesignError naming the reference."""
    import jax

    from ..controllers.force_rate import path_poses
    from ..controllers.law import sigma_min
    from ..errors import DesignError

    arm, surface = sc.nominal.arm.build(), sc.nominal.surface.build()
    sig = jax.jit(lambda a, q: sigma_min(a.J(q)))
    lo, hi = sc.reference.u1_range()
    worst = min(((float(sig(arm, q)), u1) for u1, q in path_poses(arm, surface, (lo, hi), q0)), key=lambda p: p[0])
    stop = sc.controller.singularity_stop
    if not worst[0] > stop:
        raise DesignError(f"the reference reaches u1 = {worst[1]:.4g} m, where the nominal Jacobian's smallest singular "
                          f"value is {worst[0]:.3g}, not above controller.singularity_stop = {stop:g}: the run would "
                          "stop there; move the reference away from the singularity or lower the stop",
                          key="reference.u1_amplitude", value=worst[0], bound=stop)


def _check_step_against_contact(sc, plant, q0) -> None:
    """RK4 resolves the contact oscillation only if ω dt is small: ω = √(k/m_eff), m_eff the
    true arm's effective mass along the surface normal at the start pose."""
    effective_mass = getattr(plant, "effective_mass", None)
    if effective_mass is None:
        return
    m_eff = float(effective_mass(np.asarray(q0, dtype=float)))
    k, c, dt = sc.plant.contact.stiffness, sc.plant.contact.damping, sc.simulation.dt
    omega = math.sqrt(k / m_eff)
    rate = max(omega, c / m_eff)  # the damping rate c/m_eff matters too
    if rate * dt > 0.5:
        raise ConfigError(
            f"dt = {dt:g} s is too large for the contact: its natural frequency is {omega:.4g} rad/s "
            f"(stiffness {k:g} N/m, effective mass {m_eff:.3g} kg) and its damping rate "
            f"{c / m_eff:.4g} 1/s, so RK4 needs dt <= {0.5 / rate:.3g} s", key="simulation.dt")
