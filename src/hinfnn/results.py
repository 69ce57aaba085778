"""The result documents hinfnn writes (``metrics.json``): runs, their metrics with units, the
designed controllers, how each run ended."""

from __future__ import annotations

import math

from .metrics import UNITS, compute_metrics
from .sim.simulate import failure_reason
from .sim.trajectory import STATUS

FORMAT = "hinfnn-metrics-2"


def run_entry(name: str, traj, *, overrides=None, design=None, metrics=None, label: str | None = None) -> dict:
    """One run of ``metrics.json``: name, controller, status, metrics (partial up to t_fail for a
    run that stopped), the resolved design."""
    status = int(traj.status)
    m = metrics if metrics is not None else compute_metrics(traj)
    info = traj.info
    details = {k: float(v) for k, v in traj.fail_details.items()}
    if status == 5 and getattr(traj, "scenario", None) is not None:
        try:  # the joint past its limit by name
            details["joint_name"] = traj.scenario.joint_names()[int(details.get("joint", -1))]
        except Exception:  # noqa: BLE001 - the index is in the reason anyway
            pass
    entry = {
        "name": name,
        "controller": info.kind,
        "label": label or info.label or info.kind,
        "overrides": dict(overrides or {}),
        "status": "ok" if status == 0 else "diverged",
        "t_fail": None if status == 0 else float(traj.t_fail),
        "reason": None if status == 0 else failure_reason(status, details),
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


def short_status(run: dict) -> str:
    if run.get("status", "ok") == "ok":
        return "ok"
    t = run.get("t_fail")
    return f"stopped t={t:.3g}" if isinstance(t, (int, float)) and math.isfinite(t) else "stopped"


__all__ = ["FORMAT", "run_entry", "metrics_document", "STATUS"]
