"""The result documents hinfnn writes (``metrics.json``): runs, their metrics with units, the
designed controllers, how each run ended."""

from __future__ import annotations

from .metrics import UNITS, compute_metrics

FORMAT = "hinfnn-metrics-2"


def run_entry(name: str, traj, *, overrides=None, design=None, metrics=None, label: str | None = None,
              tags: dict | None = None) -> dict:
    """One run of ``metrics.json``: name, controller, label, tags, status (the
    :class:`~hinfnn.status.RunStatus` outcome and why it stopped), metrics (partial up to t_fail
    for a run that stopped), the resolved design."""
    status = int(traj.status)
    m = metrics if metrics is not None else compute_metrics(traj)
    info = traj.info
    entry = {
        "name": name,
        "controller": info.kind,
        "label": label or info.label or info.kind,
        "overrides": dict(overrides or {}),
        "tags": dict(tags if tags is not None else info.tags),
        "status": traj.run_status.outcome,
        "t_fail": None if status == 0 else float(traj.t_fail),
        "reason": traj.reason,
        "verdict": m.get("verdict"),
        "partial": bool(m.get("partial", False)),
        "metrics": {k: v for k, v in m.items() if k not in ("partial", "verdict")},
    }
    if design is not None:
        entry["design"] = design
    return entry


def metrics_document(scenario, entries: list[dict], *, command: str) -> dict:
    """The whole ``metrics.json``."""
    from . import __version__

    return {"format": FORMAT, "hinfnn_version": __version__, "command": command, "units": dict(UNITS),
            "scenario": scenario.to_dict(), "runs": entries}


__all__ = ["FORMAT", "run_entry", "metrics_document"]
