"""What a run records, beside the simulator: the per-sample record, the step summaries between
samples, and the theorem bookkeeping integrated along the run.

Every recorded quantity is a named field of :data:`hinfnn.fields.FIELDS` (one table, with
units). A record is assembled from what the parts produce, never from a list in the simulator:

* the plant's :class:`~hinfnn.protocols.PlantRecord` (the penetration, and q, q̇, normal force,
  disturbance, true position ...);
* the controller's :class:`~hinfnn.protocols.ControllerOutput`: τ, e_u1, e_λ and its ``signals``
  (u1, λ, z and whatever its terms declare: v_p, v_λ, the networks' outputs and weight norms ...);
* the bookkeeping of Theorems 1–2 when the controller is :class:`~hinfnn.protocols.Dissipative`:
  J, J_aug and the supply integrated as states (:class:`Accumulators`), V, f_p, f_f;
* the step summaries (:data:`STEP_SUMS`, :data:`STEP_MAXES`, peak and total variation of τ), so
  that metrics cover every step whatever the decimation of the stored samples.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._pytree import pytree_dataclass
from ..errors import ConfigError
from ..fields import FIELDS, METRICS_FIELDS
from ..protocols import Dissipative


@pytree_dataclass
class Accumulators:
    """∫ of eq. (34)'s integrand (J), the same plus Remark 1's terms (J_aug), and the supply
    ρ²∫(‖f_p‖² + ‖f_f‖²) dt, integrated with the state."""

    J: jax.Array
    J_aug: jax.Array
    supply: jax.Array

    @classmethod
    def zero(cls) -> "Accumulators":
        z = jnp.zeros(())
        return cls(J=z, J_aug=z, supply=z)


def bookkeeping(controller, xc, out, qd, qdd, acc: Accumulators, enabled: bool = True):
    """(rates of the accumulators, recorded fields) at one instant. A controller that is not
    :class:`~hinfnn.protocols.Dissipative`, or a run that declines the bookkeeping (``enabled``
    False, ``simulation.bookkeeping = false``), gets zero rates and records nothing of it."""
    if not enabled or not isinstance(controller, Dissipative):
        zero = jnp.zeros(())
        return Accumulators(J=zero, J_aug=zero, supply=zero), {}
    d = controller.dissipation(xc, out, qd, qdd)
    rates = Accumulators(J=d.j, J_aug=d.j + d.j_extra, supply=d.supply)
    return rates, {"J": acc.J, "J_aug": acc.J_aug, "supply": acc.supply, "V": d.V, "f_p": d.f_p, "f_f": d.f_f}


#: A step is out of contact when the end-effector is more than this above the true surface (m):
#: the start pose is on the surface to rounding (|penetration| ~ 1e-16 m), which is contact.
SEPARATED = 1e-9

#: Per-step quantities summed between records (fields of the same names): the metrics' RMS values
#: and contact fraction then cover every step, whatever the storage.
STEP_SUMS = {
    "e_u1_sq": lambda a: a["e_u1"] ** 2,  # per coordinate (the overall RMS sums them)
    "e_lam_sq": lambda a: a["e_lam"] ** 2,
    "tau_sq": lambda a: a["tau"] ** 2,
    "steps_out_of_contact": lambda a: jnp.where(a["penetration"] < -SEPARATED, 1.0, 0.0),
}
#: Per-step quantities whose maximum between records is kept.
STEP_MAXES = {
    "e_u1_abs_max": lambda a: jnp.sqrt(jnp.sum(a["e_u1"] ** 2)),
    "e_lam_abs_max": lambda a: jnp.sqrt(jnp.sum(a["e_lam"] ** 2)),
}

#: Named selections for ``simulate(..., fields=...)``: ``"metrics"`` is what
#: :func:`hinfnn.compute_metrics` needs (18 fields: 22 numbers per sample for the planar arm).
FIELD_SETS = {"metrics": METRICS_FIELDS}


def select(fields) -> tuple | None:
    """The record fields to store: ``None`` (every field the run produces), a named set of
    :data:`FIELD_SETS` or the names given (``t`` always). Unknown names are a
    :class:`~hinfnn.errors.ConfigError`; known names the run does not produce are not stored."""
    if fields is None or fields == "all":
        return None
    if isinstance(fields, str) and fields in FIELD_SETS:
        return tuple(FIELD_SETS[fields])
    names = [fields] if isinstance(fields, str) else list(fields)
    unknown = [n for n in names if n not in FIELDS]
    if unknown:
        raise ConfigError(f"unknown trajectory field(s) {unknown}; allowed: {', '.join(FIELDS)}, or one of "
                          f"the sets {['all', *FIELD_SETS]}", key="fields")
    return ("t", *[n for n in names if n != "t"])


def pick(record: dict, fields: tuple | None) -> dict:
    """The stored part of a record (keys starting with "_" are the simulator's own)."""
    if fields is None:
        return {k: v for k, v in record.items() if not k.startswith("_")}
    return {k: record[k] for k in fields if k in record}
