"""Figures and report of a sweep: outcomes per controller, robustness maps, metric distributions.

Everything here consumes the sweep's table (a pandas DataFrame, :func:`hinfnn.load_sweep`) and
plain metadata (:func:`hinfnn.sweep.run.report_meta`); it never runs or imports a controller.
Figures use matplotlib's object API and are written atomically.

* ``outcomes.png``: per controller, the share of runs that held contact, stayed bounded but
  lost contact, stopped (by reason), or could not start (invalid).
* ``map_METRIC.png`` and ``map_held_contact.png`` (a two-key grid): per controller a heat map
  over the grid of the metric (median over the draws that stayed bounded at each point; cells
  where no draw stayed bounded are grey and crossed, the share that stopped is written in cells
  where some did, invalid cells are hatched), and of the share of draws that held contact.
* ``curve_METRIC.png`` (a one-key grid): the metric and the share that held contact along the key.
* ``distributions.png`` (random draws): per metric, the empirical distribution function of
  each controller over its runs that stayed bounded.
* ``failures_by_parameter.png`` (random draws): per drawn key, the share of runs that stayed
  bounded and held contact in ten bins of the key.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import LogLocator, MaxNLocator, NullFormatter

from ..io import atomic_write_text
from .figures import save_png

DPI = 130
_OUTCOMES = [  # (name, colour, label)
    ("held_contact", "#1a9641", "held contact"),
    ("lost_contact", "#fdae61", "bounded, lost contact"),
    ("torque", "#d7191c", "stopped: torque limit"),
    ("penetration", "#7b3294", "stopped: penetration limit"),
    ("nonfinite", "#404040", "stopped: non-finite state"),
    ("invalid", "#bdbdbd", "invalid (not simulated)"),
]


def _save(fig: Figure, path: Path) -> Path:
    return save_png(fig, path, dpi=DPI)


def _label(meta, kind):
    return meta["labels"].get(kind, kind)


def _color(meta, kind):
    return meta["colors"].get(kind) or "#1f5fbf"


def outcome_of(df):
    """A Series naming each row's outcome (see :data:`_OUTCOMES`)."""
    import pandas as pd

    out = pd.Series("invalid", index=df.index, dtype=object)
    ok = df["status"] == "ok"
    held = df["held_contact"].fillna(False).astype(bool)
    out[ok & held] = "held_contact"
    out[ok & ~held] = "lost_contact"
    reason = df["reason"].fillna("")
    div = df["status"] == "diverged"
    out[div & reason.str.contains("torque")] = "torque"
    out[div & reason.str.contains("penetration")] = "penetration"
    out[div & ~reason.str.contains("torque") & ~reason.str.contains("penetration")] = "nonfinite"
    return out


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion k/n."""
    if n == 0:
        return math.nan, math.nan
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def metric_columns(df, names) -> list[str]:
    """Table columns of metric names (a per-joint name gives its NAME_1, NAME_2 ...)."""
    cols = []
    for n in names:
        if n in df.columns:
            cols.append(n)
        else:
            cols += sorted((c for c in df.columns if c.startswith(n + "_") and c[len(n) + 1:].isdigit()),
                           key=lambda c: int(c.rsplit("_", 1)[1]))
    return cols


def _log_x(ax):
    ax.set_xscale("log")
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 3.0), numticks=12))
    ax.xaxis.set_minor_formatter(NullFormatter())


def _few_ticks(ax):
    if ax.get_xscale() == "linear":
        ax.xaxis.set_major_locator(MaxNLocator(5))
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4), useOffset=False)


def _use_log(values) -> bool:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return v.size > 1 and np.all(v > 0) and v.max() / v.min() > 100


# --- figures --------------------------------------------------------------------------------------


def outcomes_figure(df, meta, path: Path) -> Path:
    kinds = meta["controllers"]
    outcome = outcome_of(df)
    fig = Figure(figsize=(10, max(3.2, 1.4 + 0.8 * len(kinds))))
    ax = fig.add_subplot()
    for i, kind in enumerate(kinds):
        sel = outcome[df["controller"] == kind]
        n = len(sel)
        left = 0.0
        for name, color, _ in _OUTCOMES:
            frac = float((sel == name).sum()) / n if n else 0.0
            if frac > 0:
                ax.barh(i, frac, left=left, color=color, edgecolor="white", linewidth=0.5)
                if frac >= 0.04:
                    ax.text(left + frac / 2, i, f"{100 * frac:.0f} %", ha="center", va="center", fontsize=8,
                            color="white" if name not in ("lost_contact", "invalid") else "black")
            left += frac
    ax.set_yticks(range(len(kinds)), [_label(meta, k) for k in kinds])
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("share of runs")
    ax.xaxis.set_major_formatter(lambda x, _: f"{100 * x:.0f} %")
    ax.set_title(f"{meta['name']}: outcome of {len(df) // max(1, len(kinds))} runs per controller", fontsize=11)
    ax.legend(handles=[Patch(color=c, label=lab) for _, c, lab in _OUTCOMES], loc="upper center",
              bbox_to_anchor=(0.5, -0.35 if len(kinds) < 3 else -0.22), ncol=3, fontsize=8, frameon=False)
    fig.subplots_adjust(left=0.16, right=0.97, top=0.86, bottom=0.42 if len(kinds) < 3 else 0.3)
    return _save(fig, path)


def _tick(v) -> str:
    return f"{v:g}" if isinstance(v, (int, float)) else str(v)


def _grid_axes(meta):
    return [v for v in meta["varied"] if v["grid"]]


def _cell_table(df, meta, metric):
    """For a two-key grid: per controller, arrays (n_y, n_x) of the median metric over bounded
    draws, the share of simulated draws that stopped, that held contact, and whether every draw
    was invalid."""
    grid = _grid_axes(meta)
    gx, gy = grid[:2]
    xs, ys = gx["values"], gy["values"]
    rest = int(np.prod([len(g["values"]) for g in grid[2:]])) if len(grid) > 2 else 1
    out = {}
    outcome = outcome_of(df)
    point = df["point"].to_numpy(int) // rest  # further grid keys (and the draws) are pooled
    ix_all, iy_all = point // len(ys), point % len(ys)  # the first grid key varies slowest
    for kind in meta["controllers"]:
        m = (df["controller"] == kind).to_numpy()
        med = np.full((len(ys), len(xs)), np.nan)
        stopped = np.full_like(med, np.nan)
        held = np.full_like(med, np.nan)
        invalid = np.zeros_like(med, dtype=bool)
        for iy in range(len(ys)):
            for ix in range(len(xs)):
                g = df[m & (ix_all == ix) & (iy_all == iy)]
                if len(g) == 0:
                    continue
                sim = g[g["status"] != "invalid"]
                if len(sim) == 0:
                    invalid[iy, ix] = True
                    continue
                ok = sim[sim["status"] == "ok"]
                if len(ok) and metric in ok:
                    med[iy, ix] = float(np.nanmedian(ok[metric].astype(float)))
                stopped[iy, ix] = float((sim["status"] == "diverged").mean())
                held[iy, ix] = float((outcome[sim.index] == "held_contact").mean())
        out[kind] = (med, stopped, held, invalid)
    return xs, ys, out


def _edges(values, log):
    v = np.asarray(values, dtype=float)
    if len(v) == 1:
        return np.array([v[0] * 0.9, v[0] * 1.1]) if log else np.array([v[0] - 0.5, v[0] + 0.5])
    if log:
        lv = np.log10(v)
        mid = (lv[1:] + lv[:-1]) / 2
        return 10 ** np.concatenate([[lv[0] - (mid[0] - lv[0])], mid, [lv[-1] + (lv[-1] - mid[-1])]])
    mid = (v[1:] + v[:-1]) / 2
    return np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])


def map_figures(df, meta, folder: Path) -> list[Path]:
    """The robustness maps of a two-key grid (the first two grid keys; others pooled)."""
    gx, gy = _grid_axes(meta)[:2]
    # linspace/logspace grids on a real (log) axis; a list of values as equal cells labelled by value
    xs_num = gx.get("kind") in ("linspace", "logspace") and gy.get("kind") in ("linspace", "logspace")
    metric = metric_columns(df, [meta["map_metric"]])
    metric = metric[0] if metric else meta["map_metric"]
    xs, ys, cells = _cell_table(df, meta, metric)
    kinds = meta["controllers"]
    unit = meta.get("units", {}).get(metric, "")
    paths = []
    for what in ("metric", "held"):
        fig = Figure(figsize=(max(7.5, 4.6 * len(kinds) + 1.4), 4.6))
        axes = fig.subplots(1, len(kinds), squeeze=False)[0]
        if what == "metric":
            allv = np.concatenate([c[0].ravel() for c in cells.values()])
            finite = allv[np.isfinite(allv)]
            if finite.size and _use_log(finite):
                norm = LogNorm(vmin=finite.min(), vmax=finite.max())
            elif finite.size:
                lo, hi = float(finite.min()), float(finite.max())
                if hi - lo <= 1e-9 * max(abs(hi), 1e-300):  # one value: a band around it
                    pad = 0.05 * abs(hi) if hi != 0 else 1.0
                    lo, hi = lo - pad, hi + pad
                norm = Normalize(vmin=lo, vmax=hi)
            else:
                norm = Normalize(0, 1)
            cmap = "viridis"
        else:
            norm, cmap = Normalize(0, 1), "RdYlGn"
        mesh = None
        for ax, kind in zip(axes, kinds):
            med, stopped, held, invalid = cells[kind]
            data = med if what == "metric" else held
            if xs_num:
                ex, ey = _edges(xs, gx["log"]), _edges(ys, gy["log"])
                cx, cy = np.asarray(xs, float), np.asarray(ys, float)
            else:
                ex, ey = np.arange(len(xs) + 1) - 0.5, np.arange(len(ys) + 1) - 0.5
                cx, cy = np.arange(len(xs)), np.arange(len(ys))
            masked = np.ma.masked_invalid(data)
            mesh = ax.pcolormesh(ex, ey, masked, norm=norm, cmap=cmap, shading="flat")
            for iy in range(len(ys)):
                for ix in range(len(xs)):
                    x0, x1, y0, y1 = ex[ix], ex[ix + 1], ey[iy], ey[iy + 1]
                    if invalid[iy, ix]:
                        ax.fill([x0, x1, x1, x0], [y0, y0, y1, y1], facecolor="#eeeeee", hatch="///",
                                edgecolor="#9e9e9e", linewidth=0)
                    elif what == "metric" and not np.isfinite(med[iy, ix]):
                        ax.fill([x0, x1, x1, x0], [y0, y0, y1, y1], facecolor="#bdbdbd", edgecolor="none")
                        ax.plot([cx[ix]], [cy[iy]], marker="x", color="#d7191c", markersize=9, mew=2)
                    elif stopped[iy, ix] > 0:
                        mark = "#d7191c" if what == "metric" else "black"  # the held map is red where it fails
                        if meta["samples"] > 1:
                            ax.text(cx[ix], cy[iy], f"{100 * stopped[iy, ix]:.0f}%", ha="center", va="center",
                                    fontsize=7, color=mark, fontweight="bold")
                        else:
                            ax.plot([cx[ix]], [cy[iy]], marker="x", color=mark, markersize=9, mew=2)
            if xs_num and gx["log"]:
                ax.set_xscale("log")
            if xs_num and gy["log"]:
                ax.set_yscale("log")
            if not xs_num:
                ax.set_xticks(cx, [_tick(v) for v in xs], rotation=30 if len(xs) > 6 else 0)
                ax.set_yticks(cy, [_tick(v) for v in ys])
            ax.set_xlim(ex[0], ex[-1])
            ax.set_ylim(ey[0], ey[-1])
            ax.set_xlabel(gx["key"])
            ax.set_title(_label(meta, kind), fontsize=11)
        axes[0].set_ylabel(gy["key"])
        if what == "metric":
            title = f"{meta['name']}: {metric}" + (f" ({unit})" if unit and unit != "-" else "")
            title += " — median over bounded draws" if meta["samples"] > 1 else ""
            note = ("red ×: no run stayed bounded (stopped: torque, penetration or non-finite)"
                    if meta["samples"] == 1 else "red %: share of draws that stopped; ×: all stopped")
        else:
            title = f"{meta['name']}: share of draws that held contact"
            note = (f"held contact: bounded and out of contact ≤ {100 * meta['max_out_of_contact']:g} % of the steps; "
                    + ("×: stopped" if meta["samples"] == 1 else "%: share of draws that stopped"))
        note += "; hatched: invalid (start out of reach or design infeasible)"
        fig.suptitle(title, fontsize=12)
        fig.text(0.5, 0.015, note, ha="center", fontsize=8, color="#444444")
        fig.subplots_adjust(left=0.08, right=0.88, top=0.86, bottom=0.2, wspace=0.28)
        cax = fig.add_axes([0.9, 0.2, 0.015, 0.66])
        fig.colorbar(mesh, cax=cax)
        name = f"map_{metric}.png" if what == "metric" else "map_held_contact.png"
        paths.append(_save(fig, folder / name))
    return paths


def curve_figure(df, meta, folder: Path) -> Path:
    """Metric and share held along a one-key grid."""
    (g,) = _grid_axes(meta)[:1]
    metric = metric_columns(df, [meta["map_metric"]])
    metric = metric[0] if metric else meta["map_metric"]
    xs = g["values"]
    numeric = not any(isinstance(v, str) for v in xs)
    outcome = outcome_of(df)
    fig = Figure(figsize=(10, 7))
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    for kind in meta["controllers"]:
        sel = df[df["controller"] == kind]
        med, held, failed_x = [], [], []
        for p in range(len(xs)):
            g_ = sel[sel["point"] == p]
            sim = g_[g_["status"] != "invalid"]
            ok = sim[sim["status"] == "ok"]
            med.append(float(np.nanmedian(ok[metric].astype(float))) if len(ok) else np.nan)
            held.append(float((outcome[sim.index] == "held_contact").mean()) if len(sim) else np.nan)
            if len(sim) and len(ok) == 0:
                failed_x.append(p)
        x = np.asarray(xs, float) if numeric else np.arange(len(xs))
        c = _color(meta, kind)
        ax1.plot(x, med, "o-", color=c, label=_label(meta, kind), markersize=4)
        ax1.plot(x[failed_x], np.full(len(failed_x), np.nanmin(med) if np.any(np.isfinite(med)) else 0), "x",
                 color=c, markersize=9, mew=2)
        ax2.plot(x, held, "o-", color=c, markersize=4)
    if numeric and g["log"]:
        ax1.set_xscale("log")
    if _use_log(df[metric].astype(float)) if metric in df else False:
        ax1.set_yscale("log")
    ax1.set_ylabel(metric + (" (median over bounded)" if meta["samples"] > 1 else ""))
    ax1.legend(fontsize=8)
    ax2.set_ylabel("share held contact")
    ax2.set_ylim(-0.02, 1.02)
    ax2.set_xlabel(g["key"])
    if not numeric:
        ax2.set_xticks(np.arange(len(xs)), [str(v) for v in xs])
    ax1.set_title(f"{meta['name']}: along {g['key']} (×: no run stayed bounded)", fontsize=11)
    fig.tight_layout()
    return _save(fig, folder / f"curve_{metric}.png")


def distributions_figure(df, meta, path: Path) -> Path:
    cols = metric_columns(df, meta["metrics"])
    n = len(cols)
    ncol = min(3, n)
    nrow = -(-n // ncol)
    fig = Figure(figsize=(5.0 * ncol, 3.6 * nrow + 0.6))
    axes = fig.subplots(nrow, ncol, squeeze=False).ravel()
    units = meta.get("units", {})
    for ax, col in zip(axes, cols):
        drawn = 0
        for kind in meta["controllers"]:
            sel = df[(df["controller"] == kind) & (df["status"] == "ok")]
            v = np.sort(sel[col].astype(float).to_numpy())
            v = v[np.isfinite(v)]
            if v.size == 0:
                continue
            drawn += 1
            y = np.arange(1, v.size + 1) / v.size
            ax.step(v, y, where="post", color=_color(meta, kind), label=f"{_label(meta, kind)} ({v.size})")
            ax.plot([np.median(v)], [0.5], "o", color=_color(meta, kind), markersize=4)
        vals = df.loc[df["status"] == "ok", col].astype(float)
        if _use_log(vals):
            _log_x(ax)
        else:
            _few_ticks(ax)
        unit = units.get(col, "")
        ax.set_xlabel(col + (f" ({unit})" if unit and unit != "-" else ""))
        ax.set_ylabel("share of bounded runs ≤ x")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        if drawn:
            ax.legend(fontsize=7, loc="lower right")
        else:  # e.g. J_T of runs without the theorems' bookkeeping (simulation.bookkeeping = false)
            ax.text(0.5, 0.5, "no bounded run has a value", transform=ax.transAxes, ha="center", va="center",
                    fontsize=9, color="0.4")
    for ax in axes[n:]:
        ax.set_visible(False)
    fig.suptitle(f"{meta['name']}: distribution of each metric over the runs that stayed bounded (• median)",
                 fontsize=12)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    return _save(fig, path)


def _binned(sim, v, n: int = 10):
    """(values, bin edges, bin centres, bin of each row, log) of a drawn key over ``n`` equal bins
    of its range (geometric for log-uniform draws); a list-valued key by its first entry."""
    x = sim[v["key"]]
    if x.dtype == object:
        x = x.map(lambda a: float(a[0]))
    x = x.astype(float).to_numpy()
    if x.size == 0:
        return x, None, None, None, False
    log = bool(v["log"] and np.all(x > 0))
    edges = np.geomspace(x.min(), x.max(), n + 1) if log else np.linspace(x.min(), x.max(), n + 1)
    centres = np.sqrt(edges[1:] * edges[:-1]) if log else (edges[1:] + edges[:-1]) / 2
    bins = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, n - 1)
    return x, edges, centres, bins, log


def failures_figure(df, meta, path: Path) -> Path:
    drawn = [v for v in meta["varied"] if not v["grid"]]
    n = len(drawn)
    ncol = min(4, n)
    nrow = -(-n // ncol)
    fig = Figure(figsize=(4.2 * ncol, 3.3 * nrow + 0.8))
    axes = fig.subplots(nrow, ncol, squeeze=False).ravel()
    sim = df[df["status"] != "invalid"]
    outcome = outcome_of(df)
    for ax, v in zip(axes, drawn):
        key = v["key"]
        x, edges, centres, bins, log = _binned(sim, v)
        if x.size == 0:
            continue
        if log:
            _log_x(ax)
        for kind in meta["controllers"]:
            is_kind = (sim["controller"] == kind).to_numpy()
            ok = (sim["status"] == "ok").to_numpy()
            held = (outcome[sim.index] == "held_contact").to_numpy()
            b_ok, b_held = [], []
            for b in range(10):
                m = is_kind & (bins == b)
                b_ok.append(ok[m].mean() if m.any() else np.nan)
                b_held.append(held[m].mean() if m.any() else np.nan)
            c = _color(meta, kind)
            ax.plot(centres, b_ok, "o-", color=c, markersize=3, label=_label(meta, kind))
            ax.plot(centres, b_held, "s--", color=c, markersize=3, alpha=0.7)
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel(key)
        _few_ticks(ax)
        ax.grid(alpha=0.3)
    for ax in axes[::ncol]:
        ax.set_ylabel("share of runs")
    for ax in axes[n:]:
        ax.set_visible(False)
    handles = [Line2D([], [], color=_color(meta, k), label=_label(meta, k)) for k in meta["controllers"]]
    handles += [Line2D([], [], color="#444444", marker="o", label="stayed bounded"),
                Line2D([], [], color="#444444", marker="s", linestyle="--", label="held contact")]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.suptitle(f"{meta['name']}: where runs fail — share that stayed bounded / held contact in 10 bins of each "
                 "drawn key (all other keys drawn too)", fontsize=11)
    fig.tight_layout(rect=(0, 0.06, 1, 0.95))
    return _save(fig, path)


# --- the report --------------------------------------------------------------------------------------


def _pct(k, n) -> str:
    if n == 0:
        return "–"
    lo, hi = wilson(k, n)
    return f"{100 * k / n:.1f} % ({100 * lo:.1f}–{100 * hi:.1f})"


def _share(q) -> str:
    return f"{100 * q:.0f} %" if q is not None and np.isfinite(q) else "–"


def _num(x) -> str:
    if x is None or not np.isfinite(x):
        return "–"
    return f"{x:.4g}"


def summary_counts(df, meta) -> dict:
    """Per controller: runs, invalid, simulated, bounded, held_contact and each stop reason."""
    outcome = outcome_of(df)
    out = {}
    for kind in meta["controllers"]:
        m = df["controller"] == kind
        o = outcome[m]
        sim = int((df.loc[m, "status"] != "invalid").sum())
        out[kind] = dict(runs=int(m.sum()), invalid=int((o == "invalid").sum()), simulated=sim,
                         bounded=int((df.loc[m, "status"] == "ok").sum()), held_contact=int((o == "held_contact").sum()),
                         did_its_job=int(df.loc[m, "did_its_job"].fillna(False).astype(bool).sum())
                         if "did_its_job" in df else None,
                         torque=int((o == "torque").sum()), penetration=int((o == "penetration").sum()),
                         nonfinite=int((o == "nonfinite").sum()))
    return out


def sweep_markdown(df, meta, figures: list[str]) -> str:
    counts = summary_counts(df, meta)
    kinds = meta["controllers"]
    L = []
    L.append(f"# Sweep `{meta['name']}`")
    L.append("")
    if meta.get("description"):
        L.append(meta["description"])
        L.append("")
    n_draws = meta["points"] * meta["samples"]
    src = meta["scenario_source"]
    where = f" ({src})" if src and src != meta["scenario"] else ""
    L.append(f"Base scenario `{meta['scenario']}`{where}, horizon {meta['t_final']:g} s, "
             f"RK4 step {meta['dt']:g} s. Controllers: " + ", ".join(f"{_label(meta, k)} (`{k}`)" for k in kinds)
             + f". {n_draws} draw{'s' if n_draws != 1 else ''} × {len(kinds)} controllers = {len(df)} runs"
             + (f" ({meta['points']} grid points × {meta['samples']} random draws)" if meta["points"] > 1
                and meta["samples"] > 1 else "") + ".")
    L.append("")
    if meta["varied"]:
        L.append("| varied key | how |")
        L.append("|---|---|")
        for v in meta["varied"]:
            L.append(f"| `{v['key']}` | {v['how']} |")
        L.append("")
        if any(not v["grid"] for v in meta["varied"]):
            L.append(f"Random draws are seeded (seed {meta['seed']}): draw *i* of a key depends only on the seed, "
                     "the key and *i*, and every controller (and every grid point) sees the same draws.")
            L.append("")
    if meta["overrides"]:
        L.append("Changes to the base scenario: " + ", ".join(f"`{k} = {v!r}`" for k, v in meta["overrides"]) + ".")
        L.append("")

    L.append("## Outcomes")
    L.append("")
    L.append("Shares are of the simulated runs, with 95 % Wilson intervals. *Stayed bounded*: ran to the "
             "horizon without a non-finite state, |τ| above the torque limit or penetration past its limit. "
             f"*Held contact*: stayed bounded and was out of contact for at most "
             f"{100 * meta['max_out_of_contact']:g} % of its steps after the verdict's contact_after (the force's "
             "build-up is not judged). *Did its job*: held contact and tracked within the verdict's tolerances "
             "over the last 2 s. *Invalid*: the draw could not start "
             "(start pose out of the true arm's reach, singular nominal Jacobian, infeasible design, a step "
             "too large for the contact): not simulated.")
    L.append("")
    L.append("| controller | runs | invalid | simulated | stayed bounded | held contact | did its job | "
             "stopped: torque | stopped: penetration | stopped: non-finite |")
    L.append("|---|---|---|---|---|---|---|---|---|---|")
    for k in kinds:
        c = counts[k]
        job = _pct(c["did_its_job"], c["simulated"]) if c["did_its_job"] is not None else "–"
        L.append(f"| {_label(meta, k)} | {c['runs']} | {c['invalid']} | {c['simulated']} | "
                 f"{_pct(c['bounded'], c['simulated'])} | {_pct(c['held_contact'], c['simulated'])} | {job} | "
                 f"{c['torque']} | "
                 f"{c['penetration']} | {c['nonfinite']} |")
    L.append("")
    for k in kinds:
        c = counts[k]
        if c["simulated"]:
            L.append(f"- {_label(meta, k)}: of {c['simulated']} simulated runs, {c['bounded']} stayed bounded "
                     f"({100 * c['bounded'] / c['simulated']:.1f} %) and {c['held_contact']} held contact "
                     f"({100 * c['held_contact'] / c['simulated']:.1f} %).")
    L.append("")
    inv = df[df["status"] == "invalid"]
    if len(inv):
        keys = inv["error_key"].fillna("(none)").value_counts()
        L.append("Invalid runs by the key their error names: " + ", ".join(f"`{k}` {n}" for k, n in keys.items())
                 + f". Example: {inv['reason'].iloc[0]}")
        L.append("")
    if len(kinds) > 1:
        L.append("### Paired by draw")
        L.append("")
        L.append("Every controller ran the same draws, so they can be compared draw by draw (held contact; "
                 "draws simulated for both):")
        L.append("")
        L.append("| A | B | both held | only A held | only B held | neither |")
        L.append("|---|---|---|---|---|---|")
        outcome = outcome_of(df)
        held = (outcome == "held_contact")
        key = df["point"] * max(1, meta["samples"]) + df["sample"]
        for i, a in enumerate(kinds):
            for b in kinds[i + 1:]:
                ha = held[df["controller"] == a].set_axis(key[df["controller"] == a])
                hb = held[df["controller"] == b].set_axis(key[df["controller"] == b])
                sa = (df.loc[df["controller"] == a, "status"] != "invalid").set_axis(ha.index)
                sb = (df.loc[df["controller"] == b, "status"] != "invalid").set_axis(hb.index)
                common = sa.index[sa.to_numpy() & sb.reindex(sa.index, fill_value=False).to_numpy()]
                A, B = ha.reindex(common).to_numpy(bool), hb.reindex(common).to_numpy(bool)
                L.append(f"| {_label(meta, a)} | {_label(meta, b)} | {int((A & B).sum())} | {int((A & ~B).sum())} | "
                         f"{int((~A & B).sum())} | {int((~A & ~B).sum())} |")
        L.append("")

    drawn = [v for v in meta["varied"] if not v["grid"]]
    sim = df[df["status"] != "invalid"]
    if drawn and len(sim) and (sim["status"] != "ok").any() and meta["samples"] >= 20:
        rows = []
        ok = (sim["status"] == "ok").to_numpy()
        for v in drawn:
            x, edges, _, bins, _ = _binned(sim, v)
            shares = [ok[bins == b].mean() if (bins == b).any() else np.nan for b in range(10)]
            finite = [q for q in shares if np.isfinite(q)]
            if finite:
                rows.append((max(finite) - min(finite), v["key"], edges, shares))
        rows.sort(key=lambda r: -r[0])
        L.append("### Where runs stop")
        L.append("")
        L.append("The share of simulated runs (all controllers) that stayed bounded in the lowest and the "
                 "highest tenth of each drawn key's range (every other key drawn too; "
                 "`failures_by_parameter.png` shows all ten bins per controller), largest spread first:")
        L.append("")
        L.append("| drawn key | its range | bounded, lowest tenth | bounded, highest tenth | min – max over the 10 bins |")
        L.append("|---|---|---|---|---|")
        for spread, key, edges, shares in rows:
            L.append(f"| `{key}` | {_num(edges[0])} … {_num(edges[-1])} | {_share(shares[0])} | "
                     f"{_share(shares[-1])} | {_share(np.nanmin(shares))} – {_share(np.nanmax(shares))} |")
        L.append("")

    cols = metric_columns(df, meta["metrics"])
    if cols:
        L.append("## Metrics of the runs that stayed bounded")
        L.append("")
        L.append("| metric | unit | controller | runs | median | 5 % | 95 % | max |")
        L.append("|---|---|---|---|---|---|---|---|")
        units = meta.get("units", {})
        for col in cols:
            for k in kinds:
                v = df.loc[(df["controller"] == k) & (df["status"] == "ok"), col].astype(float).to_numpy()
                v = v[np.isfinite(v)]
                if v.size:
                    q = np.percentile(v, [50, 5, 95])
                    L.append(f"| `{col}` | {units.get(col, '')} | {_label(meta, k)} | {v.size} | {_num(q[0])} | "
                             f"{_num(q[1])} | {_num(q[2])} | {_num(v.max())} |")
                else:
                    L.append(f"| `{col}` | {units.get(col, '')} | {_label(meta, k)} | 0 | – | – | – | – |")
        L.append("")
        diss = df[(df["status"] == "ok") & df["dissipation_holds"].notna()]
        if len(diss):
            parts = []
            for k in kinds:
                d = diss[diss["controller"] == k]
                if len(d):
                    parts.append(f"{_label(meta, k)} {int(d['dissipation_holds'].astype(bool).sum())}/{len(d)}")
            L.append("Dissipation inequality of Theorems 1–2 at t = T, bounded runs where it holds: "
                     + ", ".join(parts) + " (claimed for the H∞-only and adaptive laws only).")
            L.append("")

    if figures:
        L.append("## Figures")
        L.append("")
        for f in figures:
            L.append(f"![{Path(f).stem}]({Path(f).name})")
            L.append("")

    L.append("## How it ran")
    L.append("")
    sessions = meta.get("sessions", [])
    for i, s in enumerate(sessions):
        rate = s["runs"] / s["wall_s"] if s.get("wall_s") else math.nan
        L.append(f"- session {i + 1}: {s['backend']}, started {s['started']}, {s['runs']} runs in "
                 f"{s['batches']} batches, {s['wall_s']:.1f} s ({rate:.2f} runs/s, compilation included)"
                 + (f": `{s['command']}`" if s.get("command") else ""))
    if len(sessions) > 1:
        L.append(f"- the sweep was interrupted and resumed {len(sessions) - 1} time(s); finished batches were "
                 "kept, the plan (batches) was the stored one.")
    L.append(f"- {meta['batches']} batches in {meta['groups']} compiled program(s); checking the draws took "
             f"{meta.get('check_wall_s') or 0:.1f} s; hinfnn {meta.get('hinfnn_version')}.")
    L.append("- the table: `results.parquet` (`hinfnn.load_sweep(folder)` returns it as a pandas DataFrame).")
    L.append("")
    return "\n".join(L)


def write_sweep_report(df, meta: dict, folder) -> list[Path]:
    """Write the figures and report.md of a sweep into ``folder``; returns the files."""
    folder = Path(folder)
    meta = dict(meta)
    meta.setdefault("units", df.attrs.get("units", {}))
    figures = [outcomes_figure(df, meta, folder / "outcomes.png")]
    grid = _grid_axes(meta)
    simulated = df[df["status"] != "invalid"]
    if len(grid) >= 2 and len(simulated):
        figures += map_figures(df, meta, folder)
    elif len(grid) == 1 and len(simulated):
        figures.append(curve_figure(df, meta, folder))
    if meta["samples"] > 1 and len(simulated):
        figures.append(distributions_figure(df, meta, folder / "distributions.png"))
        if any(not v["grid"] for v in meta["varied"]):
            figures.append(failures_figure(df, meta, folder / "failures_by_parameter.png"))
    text = sweep_markdown(df, meta, [str(f) for f in figures])
    report = atomic_write_text(folder / "report.md", text)
    return figures + [report]


__all__ = ["write_sweep_report", "sweep_markdown", "summary_counts", "outcome_of", "wilson"]
