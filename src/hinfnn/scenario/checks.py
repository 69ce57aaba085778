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
    from ..model.geometry import Geometry

    geo = [isinstance(getattr(sc, who).surface.build(), Geometry) for who in ("plant", "nominal")]
    if geo[0] != geo[1]:
        raise ConfigError(f"the true and nominal surfaces must both be task-space constraints (inclined_line) or both "
                          f"Cartesian shapes (true: {sc.plant.surface.kind!r}, nominal: {sc.nominal.surface.kind!r})",
                          key="nominal.surface.kind")
    cartesian = geo[0]
    plant = sc.build_plant()
    n = int(plant.n)
    if len(d.amplitude) != n:
        raise ConfigError(f"must be a list of {n} numbers (one per joint), got {list(d.amplitude)!r}",
                          key="plant.disturbance.amplitude")
    if cartesian:
        _check_cartesian(sc, plant)
    elif isinstance(sc.initial.u1, tuple):
        raise ConfigError(f"must be a number (m = 1 for this surface), got {list(sc.initial.u1)}", key="initial.u1")
    constraint = sc.build_constraint() if cartesian else sc.nominal.surface.build()
    m, k = constraint.m, constraint.k
    rm, rk = sc.reference.sizes()
    for name, got, want in (("u1_offset", rm, m), ("lam_offset", rk, k)):
        if got is not None and got != want:
            what = "motion" if name.startswith("u1") else "force"
            raise ConfigError(f"gives {got if got != -1 else 'lists of different lengths of'} {what} coordinates, the "
                              f"task coordinates have {want} (m = {m}, k = {k})", key=f"reference.{name}")
    q0 = np.asarray(sc.initial_q(plant))
    if not np.all(np.isfinite(q0)):
        if cartesian:
            raise ConfigError(f"u1(0) = {_fmt(sc.initial.u1)} on the true surface: the start pose was not found from "
                              f"initial.q_guess = {list(sc.initial.q_guess) or 'zeros'} (out of reach, or give joint "
                              "angles near the intended pose)", key="initial.u1")
        reach = getattr(sc.plant.arm, "reach", None)
        between = f" (|x| must be between {reach()[0]:g} and {reach()[1]:g} m)" if reach else ""
        raise ConfigError(f"u1(0) = {_fmt(sc.initial.u1)} on the true surface is out of the true arm's reach{between}",
                          key="initial.u1")
    controllers = [sc.build_controller(kind) for kind in sc.kinds]
    for ctrl in controllers:
        ctrl.check_start(q0)
    if cartesian:
        _check_path(sc, controllers[0], q0)
    elif sc.controller.singularity_stop > 0:
        _check_path_against_singularity(sc, q0)
    _check_step_against_contact(sc, plant, q0)


def _check_path_against_singularity(sc, q0) -> None:
    """With the singularity guard on, the reference's path must keep σ_min(Ĵ) above the stop on
    the NOMINAL model (else the run would stop by design): a DesignError naming the reference."""
    from ..controllers.force_rate import path_poses
    from ..controllers.law import nominal_sigma_min
    from ..errors import DesignError

    arm, surface = sc.nominal.arm.build(), sc.nominal.surface.build()
    lo, hi = sc.reference.u1_range()
    worst = min(((float(nominal_sigma_min(arm, q)), u1) for u1, q in path_poses(arm, surface, (lo, hi), q0)), key=lambda p: p[0])
    stop = sc.controller.singularity_stop
    if not worst[0] > stop:
        raise DesignError(f"the reference reaches u1 = {worst[1]:.4g} m, where the nominal Jacobian's smallest singular "
                          f"value is {worst[0]:.3g}, not above controller.singularity_stop = {stop:g}: the run would "
                          "stop there; move the reference away from the singularity or lower the stop",
                          key="reference.u1_amplitude", value=worst[0], bound=stop)


def _fmt(v):
    return f"{v:g}" if isinstance(v, float) else str([float(x) for x in v])


def _check_cartesian(sc, plant) -> None:
    """Dimensions of the Cartesian case: the arm's space vs the surfaces, m = n − 1 for u1(0)."""
    arm = plant.arm
    dim = int(arm.space_dim)
    for who in ("plant", "nominal"):
        g = getattr(sc, who).surface.build()
        if int(g.dim) != dim:
            space = "a plane (2-D)" if dim == 2 else "3-D space"
            raise ConfigError(f"a {g.dim}-D surface ({getattr(sc, who).surface.kind!r}) for an arm whose tool moves in "
                              f"{space}", key=f"{who}.surface.kind")
    m = plant.n - 1
    u1 = sc.initial.u1
    got = len(u1) if isinstance(u1, tuple) else 1
    if got != m:
        raise ConfigError(f"must give the {m} motion coordinates (n − 1 for n = {plant.n} joints), got {got}",
                          key="initial.u1")
    if sc.initial.q_guess and len(sc.initial.q_guess) != plant.n:
        raise ConfigError(f"must list {plant.n} joint angles, got {len(sc.initial.q_guess)}", key="initial.q_guess")


#: Closest approach of the desired path to a singularity of the task coordinates (rad or m).
MIN_MARGIN = 0.05


def _check_path(sc, ctrl, q0) -> None:
    """The desired path (u1d on the nominal surface, sampled over the run) must stay clear of the
    task coordinates' singularities and, for Cartesian constraints, of Π = 0 ((A3))."""
    import jax
    import jax.numpy as jnp

    task = getattr(ctrl.arm, "task", None)
    ref = sc.build_reference()
    t = jnp.linspace(0.0, sc.simulation.t_final, 201)
    surf = ctrl.surface
    margin, pi = _path_quantities(task, surf, ref, t)
    margin, pi = np.asarray(margin), np.asarray(pi)
    if task is not None and np.min(margin) < MIN_MARGIN:
        i = int(np.argmin(margin))
        raise ConfigError(f"the desired path comes within {margin[i]:.3g} (rad or m) of a singularity of the task "
                          f"coordinates at t = {float(t[i]):.3g} s (poles, centre or axis of fitted coordinates, a half "
                          "turn of the rotation vector, or where an angle wraps): move the path or the coordinates' "
                          "reference (pole, angle_ref_deg, ref_rpy_deg)", key="reference")
    bad = ~np.isfinite(pi) | (np.abs(pi) < 1e-3)
    if bad.any():
        i = int(np.argmax(bad))
        raise ConfigError(f"at t = {float(t[i]):.3g} s the desired path reaches a point where the nominal surface cannot "
                          f"be written x2 = Ω(x1) in these task coordinates (|Π| = {abs(pi[i]):.3g}: assumption (A3) "
                          "fails); put another coordinate last (task.constrained) or use task.map = \"fitted\"",
                          key="reference")
    del jax


def _path_quantities(task, surf, ref, t):
    import jax
    import jax.numpy as jnp

    @jax.jit
    def run(task, surf, ref, t):
        def one(ti):
            u1 = ref(ti).u1_d
            x = jnp.concatenate([u1, surf.Omega(u1)])
            marg = task.margin_x(x) if task is not None else jnp.asarray(jnp.inf)
            Pi = surf.Pi(x)
            return marg, jnp.linalg.det(Pi)

        return jax.vmap(one)(t)

    return run(task, surf, ref, t)


def _check_step_against_contact(sc, plant, q0) -> None:
    """RK4 resolves the contact oscillation only if ω dt is small: ω = √(k/m_eff), m_eff the
    true arm's effective mass along the surface normal at the start pose."""
    effective_mass = getattr(plant, "effective_mass", None)
    if effective_mass is None:
        return
    m_eff = float(effective_mass(np.asarray(q0, dtype=float)))
    # the integration step: MuJoCo's timestep for a plant that steps itself (substeps of dt)
    step_key = "plant.timestep" if getattr(plant, "discrete", False) else "simulation.dt"
    k, c, dt = sc.plant.contact.stiffness, sc.plant.contact.damping, float(getattr(plant, "timestep", sc.simulation.dt))
    omega = math.sqrt(k / m_eff)
    rate = max(omega, c / m_eff)  # the damping rate c/m_eff matters too
    if rate * dt > 0.5:
        raise ConfigError(
            f"dt = {dt:g} s is too large for the contact: its natural frequency is {omega:.4g} rad/s "
            f"(stiffness {k:g} N/m, effective mass {m_eff:.3g} kg) and its damping rate "
            f"{c / m_eff:.4g} 1/s, so RK4 needs dt <= {0.5 / rate:.3g} s", key=step_key)
    fr = sc.plant.friction
    slope = getattr(sc.plant, "friction_damping", None)  # MuJoCo's regularised Coulomb friction
    if fr.active and slope is not None:
        if slope / m_eff * dt > 0.5:
            raise ConfigError(f"{slope:g} N s/m is too large for MuJoCo's timestep {dt:g} s (effective mass {m_eff:.3g} kg): "
                              f"it needs friction_damping <= {0.5 * m_eff / dt:.4g} N s/m (or a smaller timestep)",
                              key="plant.friction_damping")
    elif fr.active:
        # the smoothed Coulomb law is a damper of slope mu f_n / v_s for |v_t| << v_s: the same rule
        f_scale = _force_scale(sc)
        slope = fr.coulomb * f_scale / fr.v_smooth + fr.viscous
        if slope / m_eff * dt > 0.5:
            raise ConfigError(
                f"{fr.v_smooth:g} m/s is too small for dt = {dt:g} s: the smoothed Coulomb friction acts as a damper of "
                f"mu f_n / v_s + c_v = {slope:.4g} N s/m at the reference force {f_scale:.3g} N (effective mass "
                f"{m_eff:.3g} kg), so RK4 needs v_s >= {fr.coulomb * f_scale / max(0.5 * m_eff / dt - fr.viscous, 1e-300):.3g} "
                "m/s (or a smaller dt)", key="plant.friction.v_smooth")


def _force_scale(sc) -> float:
    """The largest |λd| over the run (sampled), a scale for the normal force."""
    import jax.numpy as jnp

    from ..reference import lam_d_at

    t = jnp.linspace(0.0, sc.simulation.t_final, 201)
    lam = np.asarray(lam_d_at(sc.build_reference(), t))
    return float(np.max(np.abs(lam))) if lam.size else 0.0
