"""The cross-field and physics checks of a scenario, run before anything is compiled.

Each raises :class:`~hinfnn.errors.ConfigError` or :class:`~hinfnn.errors.DesignError` naming
the dotted key, the value and what is allowed.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..errors import ConfigError, HinfnnWarning

#: Weights of a controller's networks (Θ̂p and Θ̂f together) from which compiling a run takes
#: minutes (the shipped scenarios' networks have at most 360: 40 or 120 hidden units per coordinate).
SLOW_COMPILE_WEIGHTS = 5_000


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
    from .._config import require_x64

    require_x64()  # the start pose and the design are computed: float32 would fail them for the wrong reason
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
    setup = sc.build()
    plant = setup.plant
    n = int(plant.n)
    if len(d.amplitude) != n:
        raise ConfigError(f"must be a list of {n} numbers (one per joint), got {list(d.amplitude)!r}",
                          key="plant.disturbance.amplitude")
    if cartesian:
        _check_cartesian(sc, plant)
    elif isinstance(sc.initial.u1, tuple):
        raise ConfigError(f"must be a number (m = 1 for this surface), got {list(sc.initial.u1)}", key="initial.u1")
    constraint = setup.constraint
    m, k = constraint.m, constraint.k
    _check_reference_lengths(sc, m, k)
    _check_force_reference(sc, k, constraint.lambda_unit)
    q0 = setup.q0
    if not np.all(np.isfinite(q0)):
        if cartesian:
            _start_outside_limits(sc, plant)
            raise ConfigError(f"u1(0) = {_fmt(sc.initial.u1)} on the true surface: the start pose was not found from "
                              f"initial.q_guess = {list(sc.initial.q_guess) or 'zeros'} (out of reach, or give joint "
                              "angles near the intended pose)", key="initial.u1")
        reach = getattr(sc.plant.arm, "reach", None)
        between = f" (|x| must be between {reach()[0]:g} and {reach()[1]:g} m)" if reach else ""
        raise ConfigError(f"u1(0) = {_fmt(sc.initial.u1)} on the true surface is out of the true arm's reach{between}",
                          key="initial.u1")
    controllers = [setup.controller(kind) for kind in sc.kinds]
    for ctrl in controllers:
        ctrl.check_start(q0)
    _warn_large_networks(sc, controllers)
    if cartesian:
        _check_path(sc, controllers[0], q0)
        _check_path_joint_limits(sc, controllers[0], plant, q0)
    if sc.controller.singularity_stop > 0:
        _check_path_against_singularity(sc, controllers[0], q0)
    _check_step_against_contact(sc, plant, q0)
    _warn_unmodelled_armature(sc, setup)


def unmodelled_armature(sc, setup) -> list[tuple[str, float]]:
    """(joint, armature in kg m^2) of each joint of a user's MJCF truth (``plant.mjcf.file``) with a
    motor armature, when the nominal arm states none (``nominal.arm.armature`` all zero); empty
    otherwise (another truth, or a nominal with an armature)."""
    if getattr(sc.plant, "engine", None) != "mujoco" or not sc.plant.mjcf.file:
        return []
    chain = getattr(setup.nominal_arm, "chain", None)
    model = getattr(setup.plant, "model", None)
    if chain is None or chain.armature is not None or model is None:
        return []
    from ..plant.mujoco.scene import joint_armature

    names = sc.plant.mjcf.joints or chain.joint_names
    return [(name, float(a)) for name, a in zip(names, joint_armature(model, names)) if a > 0]


def _warn_unmodelled_armature(sc, setup) -> None:
    """Say before the run (a :class:`~hinfnn.errors.HinfnnWarning`, one line from the command) when
    the truth is a user's MJCF whose joints have a motor armature and the nominal has none: on a
    light wrist joint the armature can be a thousand times the nominal inertia (fr3-table's r_z
    error before its nominal stated it; docs/arms-and-surfaces.md, "Motor armature")."""
    import warnings

    found = unmodelled_armature(sc, setup)
    if found:
        listed = ", ".join(f"{name} {a:g}" for name, a in found)
        values = ", ".join(f"{a:g}" for _, a in found) if len(found) == len(setup.nominal_arm.chain.joint_names) \
            else None
        hint = f" (nominal.arm.armature = [{values}])" if values else ""
        warnings.warn(f"nominal.arm.armature: the true arm's MJCF ({sc.plant.mjcf.file}) gives its joints a motor "
                      f"armature ({listed} kg m^2) that the nominal model does not have: the controller's M(q) lacks "
                      f"it; state it{hint} where the robot's motors have it (docs/arms-and-surfaces.md, "
                      "\"Motor armature\")", HinfnnWarning, stacklevel=2)


def _warn_large_networks(sc, controllers) -> None:
    """Say before the run (a :class:`~hinfnn.errors.HinfnnWarning`, one line from the command) when
    a controller's networks have more than :data:`SLOW_COMPILE_WEIGHTS` weights: XLA then compiles
    its programs (the design's, the run's) for minutes, and prints its own "Very slow compile?"
    lines meanwhile."""
    import warnings

    for kind, ctrl in zip(sc.kinds, controllers):
        arrays = ctrl.state_arrays(ctrl.init()) if hasattr(ctrl, "state_arrays") else {}
        sizes = {name: int(np.size(a)) for name, a in arrays.items() if name.startswith("theta")}
        if sum(sizes.values()) > SLOW_COMPILE_WEIGHTS:
            counts = ", ".join(f"{name} {size:,}" for name, size in sizes.items())
            warnings.warn(f"controller.network_p/network_f.centre_count: the {kind} controller's networks have "
                          f"{sum(sizes.values()):,} weights ({counts}; the shipped scenarios' at most 360): compiling "
                          "its programs takes minutes, growing with the weights, and XLA may print 'Very slow "
                          "compile?' meanwhile (expected: the command goes on)", HinfnnWarning, stacklevel=2)


def _check_reference_lengths(sc, m: int, k: int) -> None:
    """Every list of the reference has one entry per motion coordinate (m) or force coordinate
    (k): a ConfigError at the first list that does not, saying the length expected and the
    coordinates' names."""
    ref = sc.reference
    names = None
    try:
        names = sc.coordinate_names()
    except ConfigError:
        pass
    groups = getattr(ref, "U1_KEYS", ()), getattr(ref, "LAM_KEYS", ())
    e = sc.n_extra
    for keys, want, what in ((groups[0], m, "motion"), (groups[1], k, "force")):
        for key in keys:
            value = getattr(ref, key)
            if isinstance(value, tuple) and len(value) != want and not (what == "motion" and e and len(value) == m - e):
                listed = ""
                if what == "motion" and names:
                    listed = ": " + ", ".join(f"{n} [{u}]" for n, u in names[:m])
                if what == "motion" and e:
                    listed += f"; or m − e = {m - e}: the extra coordinates then hold their start values"
                raise ConfigError(f"must be a number or a list of {'m' if what == 'motion' else 'k'} = {want} numbers (one per {what} coordinate"
                                  f"{listed}), got {len(value)}: [{', '.join(f'{float(v):g}' for v in value)}]",
                                  key=f"reference.{key}")


def _check_force_reference(sc, k: int, unit: str) -> None:
    """λd ≥ 0 over its whole period: every contact hinfnn simulates can only push (λ > 0 presses
    on the surface, docs/paper-conventions.md), so a negative force reference cannot be tracked.
    λd_j = r(t)(lam_offset_j + lam_amplitude_j cos(...)) with r(t) ≥ 0 reaches
    lam_offset_j − |lam_amplitude_j|: a ConfigError naming reference.lam_offset when it is < 0."""
    ref = sc.reference
    if not hasattr(ref, "lam_offset") or not hasattr(ref, "lam_amplitude"):
        return
    offset, amplitude = (np.broadcast_to(np.atleast_1d(np.asarray(getattr(ref, key), dtype=float)), (k,))
                         for key in ("lam_offset", "lam_amplitude"))
    low = offset - np.abs(amplitude)
    for j in np.flatnonzero(low < 0)[:1]:
        which = f" (force coordinate {j + 1})" if k > 1 else ""
        raise ConfigError(f"λd = lam_offset + lam_amplitude·cos(...) reaches {low[j]:g} {unit}{which}, got lam_offset = "
                          f"{offset[j]:g} and lam_amplitude = {amplitude[j]:g}: the contact can only push (λ > 0 presses "
                          "on the surface); give lam_offset >= |lam_amplitude| (λd >= 0)", key="reference.lam_offset")


def _joint_names(plant) -> list[str]:
    chain = getattr(plant.arm, "chain", None)
    names = getattr(chain, "joint_names", ()) or ()
    return list(names) if len(names) == plant.n else [f"joint {i + 1}" for i in range(plant.n)]


def _start_outside_limits(sc, plant) -> None:
    """No start pose within the joint limits: if one exists outside them (the same solve without
    the limits), a ConfigError naming the joints outside their range, their values and ranges."""
    guess = sc.initial.q_guess or None
    q = np.asarray(plant.initial_q(sc.initial.u1, q_guess=guess, within_limits=False))
    if not np.all(np.isfinite(q)):
        return
    lo, hi = (np.asarray(v) for v in plant.joint_limits())
    names = _joint_names(plant)
    out = [f"{names[i]} = {q[i]:.4g} {_unit(plant, i)} (range [{lo[i]:.4g}, {hi[i]:.4g}])"
           for i in range(plant.n) if not lo[i] <= q[i] <= hi[i]]
    if out:
        raise ConfigError(f"u1(0) = {_fmt(sc.initial.u1)} on the true surface: no start pose within the true arm's "
                          f"joint limits was found from initial.q_guess = {list(sc.initial.q_guess) or 'zeros'}; the "
                          f"pose found without them puts {', '.join(out)}: give initial.q_guess near a pose inside the "
                          "ranges, or another u1(0)", key="initial.u1")


def _unit(plant, i) -> str:
    chain = getattr(plant.arm, "chain", None)
    return "m" if chain is not None and chain.joint_types[i] == "prismatic" else "rad"


def _check_path_joint_limits(sc, ctrl, plant, q0) -> None:
    """The reference's path must keep every joint inside the TRUE arm's limits (its URDF, or a
    user's MJCF: its joints' ranges): the
    joint angles along the path are the nominal arm's inverse kinematics of x_d(t) = (u1d(t),
    Ω(u1d(t))) on 201 samples over the run (Newton steps continued from the start pose); a
    DesignError at ``reference`` naming the joint, its value on the path, its range and the time.
    (With the nominal model, what the controller aims for; the true arm follows it to within the
    tracking error.)"""
    from ..errors import DesignError

    lo, hi = (np.asarray(v) for v in plant.joint_limits())
    if not (np.isfinite(lo).any() or np.isfinite(hi).any()):
        return
    t = np.linspace(0.0, sc.simulation.t_final, 201)
    qs, res = (np.asarray(v) for v in _path_joints(ctrl.arm, ctrl.surface, sc.build().reference, t, np.asarray(q0)))
    # the path is followed while Newton converges and the joints move continuously (where it loses
    # the path, near a singularity or out of reach, the other checks and the run speak)
    jumps = np.concatenate([[0.0], np.max(np.abs(np.diff(qs, axis=0)), axis=1)])
    lost = (res >= 1e-8) | (jumps > 0.5)
    end = int(np.argmax(lost)) if lost.any() else len(t)
    if end == 0:
        return
    margin = np.full(qs.shape, np.inf)
    margin[:end] = np.minimum(qs[:end] - lo, hi - qs[:end])
    k, i = np.unravel_index(np.argmin(margin), margin.shape)
    if margin[k, i] < 0:
        names = _joint_names(plant)
        mjcf = getattr(getattr(sc.plant, "mjcf", None), "file", "")
        source = f"the true arm's MJCF, plant.mjcf.file = {mjcf!r}" if mjcf else "the true arm's URDF"
        raise DesignError(f"the reference's path takes {names[i]} to {qs[k, i]:.4g} {_unit(plant, i)} at t = {t[k]:.3g} "
                          f"s, outside its range [{lo[i]:.4g}, {hi[i]:.4g}] ({source}; joint angles from the "
                          "nominal model's inverse kinematics along the path): move the path, or start from another "
                          "pose (initial.q_guess, or the extra coordinates' reference)", key="reference",
                          value=float(qs[k, i]), bound=float(lo[i] if qs[k, i] < lo[i] else hi[i]))


def _path_joints(arm, surf, ref, t, q0):
    """Joint angles along x_d(t) (nominal inverse kinematics, 8 Newton steps of at most 0.2 rad per
    sample, continued from the previous one) and each sample's residual ‖ĥ(q) − x_d‖∞: the compiled
    :func:`hinfnn.compiled.path_joints`, one program per scenario structure (a sweep checks every
    draw)."""
    import jax.numpy as jnp

    from ..compiled import path_joints

    return path_joints(arm, surf, ref, jnp.asarray(t), jnp.asarray(q0))


#: u1d(t) is sampled at least this often per period of its fastest cosine for the design's path ...
PATH_PER_PERIOD = 40
#: ... with at least and at most this many points over the design's span.
PATH_SAMPLES = (201, 4001)


def design_span(sc) -> tuple[float | None, str]:
    """(T, in words): the design's path is u1d(t) on [0, T], T from the reference
    (``design_span()``: its fade-in and one common period, independent of the run's horizon);
    (None, ...) for a single cosine, whose path is its span of u1; the run's horizon for a
    reference kind that declares neither."""
    ref = sc.reference
    if getattr(ref, "u1_range", None) is not None:
        lo, hi = ref.u1_range()
        return None, f"the span of u1d, {lo:g}..{hi:g}"
    if hasattr(ref, "design_span"):
        return ref.design_span()
    return sc.simulation.t_final, "the run's horizon (the reference kind declares no period)"


def design_path(sc):
    """The reference's path in the motion coordinates, where the design evaluates the NOMINAL
    model (the force-rate rule's normal masses, the singularity guard's σ_min(Ĵ)): the span
    (lo, hi) of a single cosine (m = 1, as the Sec. VI reference), else u1d(t) at evenly spaced
    instants over [0, T] of :func:`design_span` (an N × m array; N from :data:`PATH_PER_PERIOD`
    and :data:`PATH_SAMPLES`). The same design for a run of any length."""
    span, _ = design_span(sc)
    if span is None:
        lo, hi = sc.reference.u1_range()
        return (float(lo), float(hi))
    import jax.numpy as jnp

    from ..controllers.force_rate import reference_points

    periods = [p for p in np.atleast_1d(np.asarray(getattr(sc.reference, "u1_period", 1.0), dtype=float)) if p > 0]
    n = int(math.ceil(span / (min(periods) / PATH_PER_PERIOD))) + 1 if periods else PATH_SAMPLES[0]
    n = min(max(n, PATH_SAMPLES[0]), PATH_SAMPLES[1])
    return np.asarray(reference_points(sc.build().reference, jnp.linspace(0.0, span, n)))


def path_sigma_min(sc, ctrl, q0):
    """[(u1, σ_min(Ĵ))] on the NOMINAL model along the reference's path (:func:`design_path`),
    the poses solved from the start pose q0."""
    from ..controllers.force_rate import path_poses
    from ..controllers.law import nominal_sigma_min

    return [(u1, float(nominal_sigma_min(ctrl.arm, q))) for u1, q in path_poses(ctrl.arm, ctrl.surface, design_path(sc), q0)]


def _check_path_against_singularity(sc, ctrl, q0) -> None:
    """With the singularity guard on, the reference's path must keep σ_min(Ĵ) above the stop on
    the NOMINAL model (else the run would stop by design): a DesignError naming the reference."""
    from ..errors import DesignError

    worst = min(((s, u1) for u1, s in path_sigma_min(sc, ctrl, q0)), key=lambda p: p[0] if math.isfinite(p[0]) else -1.0)
    stop = sc.controller.singularity_stop
    if not worst[0] > stop:
        u1 = worst[1]
        where = f"{u1:.4g}" if isinstance(u1, float) else "[" + ", ".join(f"{float(v):.4g}" for v in u1) + "]"
        raise DesignError(f"the reference reaches u1 = {where} m, where the nominal Jacobian's smallest singular "
                          f"value is {worst[0]:.3g}, not above controller.singularity_stop = {stop:g} (or the nominal "
                          "model has no pose there): the run would stop there; move the reference away from the "
                          "singularity or lower the stop", key="reference.u1_amplitude", value=worst[0], bound=stop)


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
    e = sc.n_extra
    u1 = sc.initial.u1
    got = len(u1) if isinstance(u1, tuple) else 1
    if got != m and not (e and got == m - e):
        extra = (f", or the {m - e} before the extra coordinates (task.extra: they then start where the arm's "
                 "start pose nearest initial.q_guess puts them)") if e else ""
        raise ConfigError(f"must give the {m} motion coordinates (n − 1 for n = {plant.n} joints){extra}, got {got}",
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
    ref = sc.build().reference
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
    """The task map's margin and det Π̂ at each x_d(t) (one program per structure, as
    :func:`hinfnn.compiled.path_joints`)."""
    return _path_quantities_program()(task, surf, ref, t)


@functools.cache
def _path_quantities_program():
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

    return run


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
        # the viscous force is applied at each MuJoCo step from that step's state and held over it
        # (explicit): a damper of rate c_v / m_eff, the same rule
        if fr.viscous / m_eff * dt > 0.5:
            raise ConfigError(f"{fr.viscous:g} N s/m is too large for MuJoCo's timestep {dt:g} s (effective mass "
                              f"{m_eff:.3g} kg): the viscous force is held over each MuJoCo step, so it needs "
                              f"viscous <= {0.5 * m_eff / dt:.4g} N s/m (or a smaller plant.timestep)",
                              key="plant.friction.viscous")
    elif fr.active:
        # the smoothed Coulomb law is a damper of slope mu f_n / v_s for |v_t| << v_s: the same rule
        f_scale = _force_scale(sc)
        slope = fr.coulomb * f_scale / fr.v_smooth + fr.viscous
        if slope / m_eff * dt > 0.5:
            raise ConfigError(
                f"{fr.v_smooth:g} m/s is too small for dt = {dt:g} s: the smoothed Coulomb friction acts as a damper of "
                f"mu f_n / v_s + c_v = {slope:.4g} N s/m at the reference force {f_scale:.3g} N (effective mass "
                f"{m_eff:.3g} kg), so RK4 needs v_s >= {fr.coulomb * f_scale / max(0.5 * m_eff / dt - fr.viscous, 1e-300):.3g} "
                f"m/s or simulation.dt <= {0.5 * m_eff / slope:.3g} s (the built-in plant is integrated at simulation.dt)",
                key="plant.friction.v_smooth")


def _force_scale(sc) -> float:
    """The largest |λd| over the run (sampled), a scale for the normal force."""
    import jax.numpy as jnp

    from ..reference import lam_d_at

    t = jnp.linspace(0.0, sc.simulation.t_final, 201)
    lam = np.asarray(lam_d_at(sc.build().reference, t))
    return float(np.max(np.abs(lam))) if lam.size else 0.0


def disturbance_effect(sc, q0=None) -> list[tuple[str, str, float]]:
    """The steady effect of the joint disturbance's amplitude ω on each motion coordinate through
    the nominal closed loop, at the start pose: with the law (24)-(25) the motion error obeys
    ë + K_v ė + K_p e = M̄11⁻¹ B̄1 ω (eq. 11 with the nominal model), so a constant ω leaves

        e ≈ K_p⁻¹ M̄11⁻¹ B̄1 ω,   M̄11 = (Ĵ⁻ᵀ M̂ Ĵ⁻¹)11 (task-space inertia, S = [I; ∂Ω/∂x1]),

    large where the arm is light about that coordinate (a wrist: a few mN·m² about its axis). It
    is an estimate before the robust term (which stiffens the loop: K 400 -> about 2000 in the
    shipped design) and the networks; the square wave reaches it when its half-period is longer
    than the loop's settling time. Returns (name, unit, |e_i|) per motion coordinate."""
    import jax.numpy as jnp

    from ..model.reduced import reduced_model

    setup = sc.build()
    q = np.asarray(setup.q0 if q0 is None else q0, float)
    arm, con = setup.nominal_arm, setup.constraint
    rm = reduced_model(arm, con, jnp.asarray(q), jnp.zeros_like(jnp.asarray(q)), coriolis="matrix")
    m = con.m
    w = np.asarray(sc.plant.disturbance.amplitude, float)
    accel = np.linalg.solve(np.asarray(rm.M11), np.asarray(rm.B1) @ w)
    K_p = np.asarray(sc.controller.gains.build().K_p, float)
    kp = np.broadcast_to(np.diag(np.atleast_2d(K_p)) if K_p.ndim else K_p, (m,))
    names = setup.coordinate_names or [(f"x{i + 1}", "m") for i in range(m + 1)]
    return [(names[i][0], names[i][1], float(abs(accel[i]) / kp[i])) for i in range(m)]
