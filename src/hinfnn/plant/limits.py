"""Joint limits as a plant fault, the same for every plant (the built-in one and MuJoCo)."""

from __future__ import annotations

import jax.numpy as jnp

from ..protocols import PlantRecord


def limit_record(penetration, signals: dict, q, lower, upper) -> PlantRecord:
    """The record of a plant whose joints have limits ``lower`` ≤ q ≤ ``upper`` (±inf where a
    joint has none): ``signals`` plus ``joint_limit_margin`` = min(q − lower, upper − q) per joint,
    and a fault (:attr:`~hinfnn.status.RunStatus.PLANT_FAULT`) at the joint of the smallest margin
    when it is negative (``fault_index``: that joint)."""
    margin = jnp.minimum(q - lower, upper - q)
    worst = jnp.argmin(margin)
    return PlantRecord(penetration=penetration, signals={**signals, "joint_limit_margin": margin},
                       fault=margin[worst] < 0, fault_value=margin[worst], fault_index=worst.astype(jnp.int32))
