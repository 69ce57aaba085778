"""Every quantity a run can record, with its unit, in one table.

The simulator's recorder (:mod:`hinfnn.sim.recorder`) stores what the plant, the controller and
the theorem bookkeeping produce under these names; files (``trajectory.npz``, exports) and
figures take the units from here. The core fields are listed below; a controller term declares
its own signals when its class is defined (:class:`hinfnn.controllers.terms.Term`, ``fields``),
through :func:`declare`, so a new term adds rows here without editing this module.
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Field:
    name: str
    unit: str
    doc: str
    summary: str | None = None  # how two sampling intervals merge ("max" or "sum"), for step summaries
    #: (space, template): the field's components are one per item of ``space`` (:data:`SPACES`),
    #: each in the item's unit put in the template ("{}/s": a rate); None: ``unit`` for all
    per: tuple[str, str] | None = None


#: λ's unit depends on the nominal constraint (the constraint's ``lambda_unit``: N when θ̂ is a length).
LAMBDA = "λ units"

#: The spaces a field's components live in, and the run's tag (``hinfnn.scenario.describe``) that
#: gives each component's unit: a joint's position (rad, a prismatic joint's m), a joint's effort
#: (N·m, N), a motion coordinate's, a task coordinate's (motion coordinates, then the constrained
#: ones) and its effort (the force or moment conjugate to it), λ's.
SPACES = ("joint", "effort", "motion", "task", "task_effort", "lambda")
#: The effort conjugate to a coordinate in each unit.
EFFORT = {"rad": "N·m", "m": "N"}

_CORE = [
    ("t", "s", "time"),
    # the truth (plant)
    ("q", "rad", "joint angles", None, ("joint", "{}")),
    ("qd", "rad/s", "joint rates", None, ("joint", "{}/s")),
    ("F", "N", "task-space force the end-effector exerts on the surface (measured)", None, ("task_effort", "{}")),
    ("normal_force", "N", "normal contact force of the true surface"),
    ("penetration", "m", "penetration of the true surface (< 0: distance above it)"),
    ("disturbance", "N·m", "joint disturbance torque ω_l", None, ("effort", "{}")),
    ("x_true", "m", "true task coordinates h(q)", None, ("task", "{}")),
    ("F_contact", "N", "contact force at the tool point, Cartesian (the arm's space; Cartesian surfaces)"),
    ("friction_force", "N", "magnitude of the friction force along the surface"),
    ("task_margin", "rad", "distance of the true pose's task coordinates from their singularities (rad or m)"),
    ("joint_limit_margin", "rad or m", "each joint's distance from its nearer limit (the true arm's URDF; < 0: past it, "
     "the run stops)", None, ("joint", "{}")),
    # the controller (what it measures and computes)
    ("u1", "m", "motion coordinate u1 = ĥ1(q) (nominal kinematics)", None, ("motion", "{}")),
    ("u1_dot", "m/s", "u̇1", None, ("motion", "{}/s")),
    ("lam", LAMBDA, "force multiplier λ = (ÂÂᵀ)⁻¹ÂF"),
    ("u1_d", "m", "reference u1d", None, ("motion", "{}")),
    ("u1_d_dot", "m/s", "reference u̇1d", None, ("motion", "{}/s")),
    ("lam_d", LAMBDA, "reference λd"),
    ("e_u1", "m", "e_u1 = u1 − u1d", None, ("motion", "{}")),
    ("e_u1_dot", "m/s", "ė_u1", None, ("motion", "{}/s")),
    ("e_lam", LAMBDA, "e_λ = λ − λd"),
    ("z", LAMBDA, "z-filter state, eq. (27)"),
    ("tau", "N·m", "joint torque τ the controller commands, eq. (24) (applied as is by ideal motors)", None,
     ("effort", "{}")),
    ("tau_applied", "N·m", "joint torque the plant's motors apply: τ saturated and rate-limited (plant.actuator)",
     None, ("effort", "{}")),
    ("torque_saturated", "-", "1 when a joint's applied torque is at its limit, else 0 (plant.actuator)"),
    ("sigma_min_J", "-", "smallest singular value of the nominal Jacobian Ĵ (the singularity guard's measure)"),
    # the theorem bookkeeping
    ("J", "-", "H∞ performance index J(t), eq. (34)"),
    ("J_aug", "-", "J(t) plus Remark 1's terms (augmented designs; else J)"),
    ("supply", "-", "ρ²∫(‖f_p‖² + ‖f_f‖²) dt"),
    ("V", "-", "storage function V, eqs. (36)/(55)"),
    ("f_p", "m/s²", "position residual f_p of eq. (28)/(52)", None, ("motion", "{}/s²")),
    ("f_f", LAMBDA, "force residual f_f of eq. (29)/(53)"),
    # a robot run's loop (hinfnn.robot.loop)
    ("force_measured", "N", "the robot's force reading: the contact force at the tool point, base frame"),
    ("tau_law", "N·m", "the torque the control law asked for, before the safety layer's clamps"),
    ("t_reading", "s", "the time the robot gave the reading (t: the latest time seen)"),
    ("cycle_latency", "s", "from the robot's reading to the torque written, in the loop"),
    ("cycle_lateness", "s", "the torque written against the robot's next tick (> 0: late, the previous one held again)"),
    ("missed_ticks", "-", "control periods in a row the robot held a stale torque, up to the reading"),
    ("control_h", "s", "the time since the previous reading the controller integrated over (NaN: not called)"),
    ("accepted", "-", "1 when the reading reached the controller, 0 when the safety layer rejected it"),
    ("safety_mode", "-", "0 control, 1 hold after a stop, 2 retract after a contact loss"),
]
_SUMMARIES = [
    ("tau_abs_max", "N·m", "max |τ_i| over the steps since the previous sample", "max", ("effort", "{}")),
    ("tau_variation", "N·m", "Σ|τ_i(t_k) − τ_i(t_k−1)| over the steps since the previous sample", "sum",
     ("effort", "{}")),
    ("tau_sq", "(N·m)²", "Σ τ_i² over the steps since the previous sample, this one included", "sum",
     ("effort", "({})²")),
    ("e_u1_sq", "m²", "Σ e_u1² (per coordinate) over the steps since the previous sample, this one included", "sum",
     ("motion", "({})²")),
    ("e_lam_sq", "(λ units)²", "Σ e_λ² (per coordinate) over the steps since the previous sample, this one included", "sum"),
    ("steps_out_of_contact", "-", "steps with the end-effector off the true surface (more than 1 nm above it) since "
     "the previous sample, this one included",
     "sum"),
    ("e_u1_abs_max", "m", "max ‖e_u1‖ over the steps since the previous sample, this one included", "max"),
    ("e_lam_abs_max", LAMBDA, "max ‖e_λ‖ over the steps since the previous sample, this one included", "max"),
]

FIELDS: dict[str, Field] = {}


def declare(name: str, unit: str, doc: str, summary: str | None = None, per: tuple[str, str] | None = None) -> Field:
    """Add a field (or confirm an identical one). Two different definitions of a name are an
    error: a field means one thing everywhere. ``per``: :attr:`Field.per`; a field in λ units
    has one component per constraint, in λ's unit."""
    if per is None and LAMBDA in unit:
        per = ("lambda", unit.replace(LAMBDA, "{}"))
    f = Field(name, unit, doc, summary, per)
    old = FIELDS.get(name)
    if old is not None and (old.unit, old.summary) != (unit, summary):
        raise ValueError(f"field {name!r} is already declared with unit {old.unit!r}")
    FIELDS.setdefault(name, f)
    return FIELDS[name]


for _row in _CORE:
    declare(*_row)
for _row in _SUMMARIES:
    declare(*_row)

#: Fields that summarise the steps since the previous sample (and how two intervals merge).
SUMMARY_FIELDS = {f.name: f.summary for f in FIELDS.values() if f.summary}

#: What :func:`hinfnn.compute_metrics` needs: ``fields="metrics"`` stores only these.
METRICS_FIELDS = ("t", "e_u1", "e_lam", "tau", "normal_force", "J", "J_aug", "V", "supply", "task_margin",
                  "joint_limit_margin", "lam_d", "torque_saturated", *SUMMARY_FIELDS)


def component_units(name: str, count: int, tags: dict | None) -> list[str] | None:
    """The unit of each of the ``count`` components of field ``name`` in a run described by
    ``tags`` (:func:`hinfnn.scenario.describe`: ``joint_units``, ``coordinates``, ``lambda_unit``,
    from the arm's joints, the task map's coordinates and the constraint), or None where the field
    has one unit or the tags do not say (its declared :func:`unit` then)."""
    f = FIELDS.get(name)
    if f is None or f.per is None or not tags:
        return None
    space, template = f.per
    joints, coords, lam = tags.get("joint_units"), tags.get("coordinates"), tags.get("lambda_unit")
    bases = {"joint": joints, "effort": joints and [EFFORT.get(u) for u in joints],
             "motion": coords and [c[1] for c in coords][:count], "task": coords and [c[1] for c in coords],
             "task_effort": coords and [EFFORT.get(c[1]) for c in coords],
             "lambda": lam and [lam] * count}[space]
    if not bases or len(bases) != count or not all(bases):
        return None
    return [template.format(b) if not template.startswith("({})") or any(c in b for c in "·/ ")
            else template.replace("({})", b, 1) for b in bases]


def unit(name: str) -> str:
    """The unit of a field ("-" for an undeclared name)."""
    f = FIELDS.get(name)
    return f.unit if f else "-"
