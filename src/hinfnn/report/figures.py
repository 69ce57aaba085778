"""Figures of a run (``hinfnn run``) and of the paper's Sec. VI study (Figs. 3–9).

Everything here consumes :class:`~hinfnn.sim.Trajectory` objects (plain NumPy arrays plus the
resolved scenario); nothing imports a controller or the plant. Figures are built with
matplotlib's object API (:class:`matplotlib.figure.Figure`, Agg), never pyplot, and every file
is written atomically with :func:`hinfnn.io.atomic_write`.

How dense signals are drawn
---------------------------
A 10 s run sampled every 0.1 ms has 100 001 samples, and the undamped contact makes λ and τ
oscillate at tens to hundreds of Hz. Drawing such a line sample by sample either aliases the
oscillation away (decimation) or paints a solid blob that hides the other controllers. A main
(whole-run) panel with more than three samples per pixel column therefore splits its time axis
into one bin per pixel column and draws, for every run,

* a translucent **band** from the minimum to the maximum of all samples in each column, so
  every excursion, however short, is visible at its true amplitude, and
* an opaque **line**: the mean of the samples in each column, or, for the signals that chatter
  (λ, τ, contact force, penetration), their mean over a sliding window of 1 % of the run
  (0.1 s of 10 s), i.e. the slow picture under the chatter.

Bands are stacked widest first (by median column width) and all lines are drawn above all
bands, so a quiet controller stays visible on top of a chattering one; lower lines are drawn
wider, so two runs that coincide show as a thin line inside a wider one. The chattering signals
get two zoom panels (windows A, early, and B, late, shaded on the main panel) in which every
sample is drawn, so the oscillation itself — frequency, shape, loss of contact — can be read;
they are left out when the main panel already draws every sample. Figs. 7–8 add a y-detail copy
of the main panel, limited to the quietest run's full range, when another run's range is more
than five times larger. Runs that diverged (``status != 0``) are drawn up to ``t_fail``, marked
with a cross there and labelled with the time and the reason.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.legend_handler import HandlerTuple
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
from matplotlib.transforms import blended_transform_factory

from ..io import atomic_write
from ..sim.trajectory import Trajectory
from ..status import status_of

__all__ = ["paper_figures", "run_figures", "sparse_note", "RUN_FIGURES", "PAPER_FIGURES", "DPI", "SIZE",
           "SIZE_TALL"]

#: Resolution of every figure (dots per inch); sizes below are in pixels at this resolution.
DPI = 160
#: Size (width, height) in pixels of figures with one signal.
SIZE = (1600, 1000)
#: Size in pixels of the taller figures: fig7_tau1, fig8_tau2, tau.png, contact.png.
SIZE_TALL = (1600, 1600)

_MIN_SAMPLES_PER_COLUMN = 3  # above this, a panel is drawn as band + mean line
_BAND_ALPHA = 0.3
_DETAIL_RATIO = 5.0  # y-detail panel when the widest run's range exceeds the quietest's by this
_SMOOTH = 0.01  # sliding-mean window of chattering signals, as a fraction of the time span
_FONT = {"title": 13, "subtitle": 10, "panel": 10.5, "label": 10, "tick": 9, "legend": 9,
         "note": 9}

# Colours come from the run (the controller registry's colour for its kind); a second run with
# the colour of an earlier one gets the next free colour of the palette.
_PALETTE = ["#1f5fbf", "#d62728", "#1a9641", "#7b3294", "#e66101", "#8c564b", "#17becf",
            "#bcbd22", "#7f7f7f"]
_REF_STYLE = dict(color="black", linestyle=(0, (5, 3)), linewidth=1.0)


# --- reading a Trajectory ------------------------------------------------------------------


def _kind(traj: Trajectory) -> str | None:
    return traj.info.kind or None


def _tag(traj: Trajectory, name: str, default=None):
    """A tag of the run (what it stands for and the facts reports show: hinfnn.experiment)."""
    return traj.info.tags.get(name, default)


def _status(traj: Trajectory) -> int:
    return int(np.asarray(traj.status).reshape(()))


def _t_fail(traj: Trajectory) -> float:
    return float(np.asarray(traj.t_fail).reshape(()))


def _describe(traj: Trajectory) -> str:
    text = traj.info.label or _kind(traj) or "controller"
    if _tag(traj, "networks") and _tag(traj, "f_f_preset") and "centres" not in text and "(" not in text:
        text += f", $F_f$ centres {_tag(traj, 'f_f_preset')}"
    if _tag(traj, "augmented") and "augmented" not in text:
        text += ", augmented"
    return text


def _failure(traj: Trajectory) -> str:
    if _status(traj) == 0:
        return ""
    tf = _t_fail(traj)
    when = f"t = {tf:.3g} s" if math.isfinite(tf) else "unknown time"
    reason = status_of(_status(traj)).message
    return f" (diverged at {when}: {reason})"


def _damping(traj: Trajectory) -> float | None:
    return _tag(traj, "contact_damping")


def _stiffness(traj: Trajectory) -> float | None:
    return _tag(traj, "contact_stiffness")


def _scaling(traj: Trajectory) -> str | None:
    return _tag(traj, "lambda_scaling")


def _coordinates(runs) -> list[tuple[str, str]] | None:
    """Names and units of the task coordinates (x = (u1, x2)) of the first run whose tags say,
    or None (the native coordinates of the Sec. VI arm)."""
    for r in runs:
        coords = _tag(r.traj, "coordinates")
        if coords:
            return [tuple(c) for c in coords]
    return None


_GREEK = {"phi": r"\phi", "phi_rel": r"\phi_{rel}", "r_x": "r_x", "r_y": "r_y", "r_z": "r_z", "s": "s",
          "s1": "s_1", "s2": "s_2", "s_lon": r"s_{lon}", "s_lat": r"s_{lat}", "s_axial": r"s_{ax}",
          "s_arc": r"s_{arc}", "d": "d"}


def _math(name: str) -> str:
    """A coordinate's name as mathtext (p_x -> $p_x$, phi_rel -> $\\phi_{rel}$)."""
    if name in _GREEK:
        return f"${_GREEK[name]}$"
    head, _, tail = name.partition("_")
    return f"${head}_{{{tail}}}$" if tail else f"${head}$"


def _tall(n_panels: int, zoom: bool) -> tuple[int, int]:
    """Figure size for n stacked panels (with a zoom row each when ``zoom``)."""
    per = 620 if zoom else 380
    return SIZE[0], max(SIZE[1], 430 + per * n_panels)


@dataclasses.dataclass(frozen=True)
class _Run:
    name: str
    traj: Trajectory
    label: str
    color: str

    def signal(self, field: str, column: int | None = None, scale: float = 1.0):
        """(t, y) of a field up to the last valid sample, or None if the run lacks it."""
        arrays = self.traj.arrays
        if field not in arrays or "t" not in arrays:
            return None
        n = self.traj.valid_samples()
        t = np.asarray(arrays["t"], dtype=float)[:n]
        y = np.asarray(arrays[field], dtype=float)[:n]
        if y.ndim == 2:
            y = y[:, 0 if column is None else column]
        return t, y * scale


def _prepare(named: Sequence[tuple[str, Trajectory]], labels: Callable[[str, Trajectory], str]):
    used: set[str] = set()
    out = []
    for name, traj in named:
        if traj.batched:
            raise ValueError(f"run {name!r} is a batch of {traj.batch_size}; figures take single "
                             "runs (use traj.member(i))")
        color = traj.info.color or None
        if color is None or color in used:
            color = next((c for c in _PALETTE if c not in used), _PALETTE[len(out) % len(_PALETTE)])
        used.add(color)
        out.append(_Run(name, traj, labels(name, traj) + _failure(traj), color))
    return out


# --- dense drawing ---------------------------------------------------------------------------


def _dense(t: np.ndarray, x0: float, x1: float, n: int) -> bool:
    """More than ``_MIN_SAMPLES_PER_COLUMN`` samples per pixel column over the columns the
    samples span (a run that stopped early spans fewer columns)."""
    if len(t) < 2:
        return False
    covered = max(n * (min(t[-1], x1) - max(t[0], x0)) / (x1 - x0), 1.0)
    return len(t) > _MIN_SAMPLES_PER_COLUMN * covered


def _columns(t: np.ndarray, y: np.ndarray, x0: float, x1: float, n: int, smooth: float = 0.0):
    """Per pixel column of [x0, x1] (n columns): mean time, min and max of y, and the line.

    The line is the mean of y over the column, or, if ``smooth`` > 0, over a sliding window of
    that length (s) centred on the column. Returns None when there are at most
    ``_MIN_SAMPLES_PER_COLUMN`` samples per column over the span the samples cover (a run that
    stopped early covers fewer columns); the caller then draws every sample."""
    i0 = int(np.searchsorted(t, x0, side="left"))
    i1 = int(np.searchsorted(t, x1, side="right"))
    t, y = t[i0:i1], y[i0:i1]
    if not _dense(t, x0, x1, n):
        return None
    b = np.clip(((t - x0) / (x1 - x0) * n).astype(np.int64), 0, n - 1)
    starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
    counts = np.diff(np.r_[starts, len(t)])
    finite = np.isfinite(y)
    yz = np.where(finite, y, 0.0)
    lo = np.fmin.reduceat(y, starts)
    hi = np.fmax.reduceat(y, starts)
    tm = np.add.reduceat(t, starts) / counts
    if smooth > 0:
        cs = np.r_[0.0, np.cumsum(yz)]
        cn = np.r_[0, np.cumsum(finite)]
        a = np.searchsorted(t, tm - smooth / 2, side="left")
        z = np.searchsorted(t, tm + smooth / 2, side="right")
        num, den = cs[z] - cs[a], cn[z] - cn[a]
    else:
        num = np.add.reduceat(yz, starts)
        den = np.add.reduceat(finite.astype(np.int64), starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        line = np.where(den > 0, num / np.maximum(den, 1), np.nan)
    return tm, lo, hi, line


def _axes_px(ax) -> int:
    fig = ax.get_figure()
    return max(50, int(round(ax.get_position().width * fig.bbox.width)))


def _draw_runs(ax, series, x0: float, x1: float, *, zoom: bool = False,
               smooth: float = 0.0) -> bool:
    """Draw [(run, t, y)] on ax over [x0, x1]. Returns True if any run was drawn as band+line.

    Layering: the run whose typical (median) column spread is largest goes at the bottom, so a
    quiet run is never buried under a chattering one; lower lines are drawn wider, so that two
    runs that coincide show as a thin line inside a wider one of another colour."""
    n = _axes_px(ax)
    layers = []
    for run, t, y in series:
        if zoom:  # one sample either side, so lines reach the frame
            i0 = max(0, int(np.searchsorted(t, x0, side="left")) - 1)
            i1 = min(len(t), int(np.searchsorted(t, x1, side="right")) + 1)
            t, y = t[i0:i1], y[i0:i1]
            if len(t) == 0 or t[-1] < x0:
                continue
        cols = None if zoom else _columns(t, y, x0, x1, n, smooth)  # zooms: every sample
        if cols is None:
            fin = y[np.isfinite(y)]
            spread = float(np.median(np.abs(np.diff(fin)))) if len(fin) > 1 else 0.0
            layers.append((spread, run, ("line", t, y)))
        else:
            tm, lo, hi, line = cols
            w = hi - lo
            spread = float(np.nanmedian(w)) if np.isfinite(w).any() else 0.0
            layers.append((spread, run, ("band", tm, lo, hi, line)))
    layers.sort(key=lambda item: -item[0])
    dense = False
    widths = np.linspace(3.4, 1.3, len(layers)) if len(layers) > 1 else [1.7]
    for k, (_, run, data) in enumerate(layers):
        lw = widths[k] * (0.6 if zoom else 1.0)
        if data[0] == "band":
            dense = True
            _, tm, lo, hi, line = data
            ax.fill_between(tm, lo, hi, color=run.color, alpha=_BAND_ALPHA, linewidth=0,
                            zorder=1 + 0.01 * k)
            ax.plot(tm, line, color=run.color, linewidth=lw, zorder=3 + 0.01 * k)
        else:
            _, t, y = data
            marker = "." if zoom and len(t) <= 150 else None
            ax.plot(t, y, color=run.color, linewidth=lw, marker=marker, markersize=3,
                    zorder=3 + 0.01 * k)
    return dense


def _draw_reference(ax, ref, x0, x1):
    if ref is None:
        return
    t, y = ref
    i0 = max(0, int(np.searchsorted(t, x0)) - 1)
    i1 = min(len(t), int(np.searchsorted(t, x1, side="right")) + 1)
    t, y = t[i0:i1], y[i0:i1]
    step = max(1, len(t) // 4000)  # a smooth reference: a few thousand points are exact to the eye
    idx = np.r_[np.arange(0, len(t), step), len(t) - 1] if len(t) else np.arange(0)
    ax.plot(t[idx], y[idx], zorder=5, **_REF_STYLE)


# --- figure layout -------------------------------------------------------------------------


@dataclasses.dataclass
class _Panel:
    ylabel: str
    series: list  # [(run, t, y)]
    reference: tuple | None = None
    zoom: bool = False
    title: str | None = None
    log: bool = False
    detail: bool = False  # add a y-detail copy when one run's range dwarfs another's
    smooth: bool | None = None  # main-panel line as a sliding mean; default: same as zoom

    @property
    def smoothing(self) -> bool:
        return self.zoom if self.smooth is None else self.smooth


def _style_axes(ax, ylabel=None, xlabel="t (s)"):
    ax.grid(True, color="0.85", linewidth=0.6, zorder=0)
    ax.tick_params(labelsize=_FONT["tick"])
    ax.yaxis.get_offset_text().set_fontsize(_FONT["tick"])
    if xlabel:
        ax.set_xlabel(xlabel, fontsize=_FONT["label"])
    if ylabel:
        ax.set_ylabel(ylabel, fontsize=_FONT["label"])


def _zoom_windows(t_end: float, windows=None):
    if windows is not None:
        return [(float(a), float(b)) for a, b in windows]
    # A (1 % of the run): early, while the adaptive controller is still learning and chattering
    # at hundreds of Hz. B (2 %): near the end, long enough to hold several contact bounces.
    # With the paper's 10 s both avoid the disturbance's switches (multiples of 0.5 s).
    return [(0.06 * t_end, 0.07 * t_end), (0.96 * t_end, 0.98 * t_end)]


def _contact_note(runs: list[_Run]) -> str:
    damp = {}
    for r in runs:
        damp.setdefault(_damping(r.traj), []).append(r.name)

    def fmt(d):
        if d is None:
            return "contact damping not recorded"
        paper = " (as in the paper)" if d == 0 else " (not in the paper)"
        return f"contact damping {d:g} N·s/m{paper}"

    if len(damp) == 1:
        text = fmt(next(iter(damp)))
    else:
        text = "; ".join(f"{', '.join(names)}: {fmt(d)}" for d, names in damp.items())
    stiff = {_stiffness(r.traj) for r in runs}
    if len(stiff) == 1 and None not in stiff:
        text = f"contact stiffness {next(iter(stiff)):.3g} N/m, " + text
    return text


def _sample_note(runs: list[_Run]) -> str:
    dts = sorted({r.traj.dt * r.traj.save_every for r in runs})
    return "samples every " + ", ".join(f"{d * 1e3:g} ms" for d in dts)


def _lambda_label(runs: list[_Run]) -> str:
    scalings = {_scaling(r.traj) for r in runs}
    if scalings == {"paper"}:
        return r"$\lambda$ (paper scaling: N·cos$\,\hat\delta$)"
    if scalings == {"unit"}:
        return r"$\lambda$ (N)"
    return r"$\lambda$ (units differ between runs: see the scenario)"


def _draw_main(ax, p: "_Panel", t_end: float, window: float, zoom_windows, letters=True) -> bool:
    """A whole-run panel: bands and lines, reference, diverged markers, shaded zoom windows."""
    if p.log:
        ax.set_yscale("log")
    ax.set_xlim(0.0, t_end)
    dense = _draw_runs(ax, p.series, 0.0, t_end, smooth=window)
    _draw_reference(ax, p.reference, 0.0, t_end)
    for run, t, y in p.series:  # where a diverged run stopped
        if _status(run.traj) != 0 and len(t):
            ax.plot([t[-1]], [y[-1]], marker="X", markersize=9, color=run.color,
                    markeredgecolor="black", linestyle="none", zorder=6)
    _style_axes(ax, p.ylabel)
    if p.log:
        _log_limits(ax, p.series, t_end)
    for run, t, y in p.series:  # a job's phase changes (hinfnn.controllers.job), as dotted lines
        for tc in _phase_changes(run.traj):
            ax.axvline(tc, color=run.color, linestyle=":", linewidth=0.9, alpha=0.8, zorder=0.6)
    trans = blended_transform_factory(ax.transData, ax.transAxes)
    for letter, (a, b) in zip("AB", zoom_windows):
        ax.axvspan(a, b, color="0.55", alpha=0.22, linewidth=0, zorder=0.5)
        if letters:
            ax.text((a + b) / 2, 1.01, letter, transform=trans, ha="center", va="bottom",
                    fontsize=_FONT["panel"], fontweight="bold")
    return dense


def _phase_changes(traj: Trajectory) -> np.ndarray:
    """The times a job's recorded ``phase`` changes (none for a run without phases)."""
    if "phase" not in traj.arrays:
        return np.zeros(0)
    end = traj.valid_samples()
    ph = np.asarray(traj.arrays["phase"], dtype=float).reshape(-1)[:end]
    t = np.asarray(traj.arrays["t"], dtype=float)[:end]
    return t[1:][np.diff(ph) != 0]


def _detail_range(p: "_Panel"):
    """(label, lo, hi) of the quietest run if a y-detail panel is asked for and needed: when the
    widest run's full range is more than ``_DETAIL_RATIO`` times the quietest one's."""
    if not p.detail or len(p.series) < 2:
        return None
    ranges = []
    for run, t, y in p.series:
        fin = y[np.isfinite(y)]
        if len(fin):
            ranges.append((float(fin.max() - fin.min()), run, float(fin.min()), float(fin.max())))
    if len(ranges) < 2:
        return None
    ranges.sort(key=lambda r: r[0])
    quiet, loud = ranges[0], ranges[-1]
    if quiet[0] <= 0 or loud[0] < _DETAIL_RATIO * quiet[0]:
        return None
    name = quiet[1].label.split(" (diverged")[0]
    return name, quiet[2], quiet[3]


def _build(title: str, subtitle: str, panels: list[_Panel], size: tuple[int, int],
           t_end: float, windows, extra_note: str = "") -> Figure:
    w_in, h_in = size[0] / DPI, size[1] / DPI
    fig = Figure(figsize=(w_in, h_in), dpi=DPI, facecolor="white")
    runs = []
    for p in panels:
        for run, _, _ in p.series:
            if run not in runs:
                runs.append(run)

    # Zoom panels only where the main panel aggregates samples (else it already shows them all).
    left, right = 0.085, 0.975
    columns = int((right - left) * size[0])
    dense = [any(_dense(t, 0.0, t_end, columns) for _, t, _ in p.series) for p in panels]
    panels = [dataclasses.replace(p, zoom=p.zoom and d) for p, d in zip(panels, dense)]

    # legend entries: one per run (band + line, or line), then the reference
    handles, labels = [], []
    for run in runs:
        line = Line2D([], [], color=run.color, linewidth=1.6)
        handles.append((Patch(facecolor=run.color, alpha=_BAND_ALPHA, linewidth=0), line)
                       if any(dense) else line)
        labels.append(run.label)
    if any(p.reference is not None for p in panels):
        handles.append(Line2D([], [], **_REF_STYLE))
        labels.append("reference (desired)")
    if len(labels) == 1:
        ncol = 1
    else:
        ncol = 2 if (len(labels) > 3 or max(map(len, labels)) > 45) else len(labels)
    legend_rows = math.ceil(len(labels) / ncol)

    header_in = 1.02 + 0.21 * legend_rows + (0.2 if panels[0].title else 0.0)
    footer_in = 0.42 + 0.17 * (extra_note.count("\n") + 1 if extra_note else 0)
    top, bottom = 1 - header_in / h_in, (footer_in + 0.56) / h_in
    details = [_detail_range(p) for p in panels]
    ratios = []
    for p, d in zip(panels, details):
        ratios += [1.45] + ([1.45] if d else []) + ([1.0] if p.zoom else [])
    n, gap = len(ratios), 0.78  # inches between rows (x label of one, title of the next)
    hspace = gap * n / max((top - bottom) * h_in - gap * (n - 1), 0.5) if n > 1 else 0.0
    gs = fig.add_gridspec(n, 2, left=left, right=right, top=top, bottom=bottom,
                          height_ratios=ratios, hspace=hspace, wspace=0.14)

    dense_panels = []
    row = 0
    for p, detail in zip(panels, details):
        ax = fig.add_subplot(gs[row, :])
        row += 1
        window = _SMOOTH * t_end if p.smoothing else 0.0
        if _draw_main(ax, p, t_end, window, windows if p.zoom else ()):
            dense_panels.append(window)
        if p.title:
            ax.set_title(p.title, fontsize=_FONT["panel"], loc="left")
        if detail:
            who, lo, hi = detail
            dx = fig.add_subplot(gs[row, :], sharex=ax)
            row += 1
            _draw_main(dx, p, t_end, window, windows if p.zoom else (), letters=False)
            pad = 0.08 * (hi - lo)
            dx.set_ylim(lo - pad, hi + pad)
            dx.set_title(f"Same, y-range limited to the {who} run's full range: bands of the other "
                         "runs are cut at the frame", fontsize=_FONT["panel"], loc="left")
        if not p.zoom:
            continue
        for col, (letter, (a, b)) in enumerate(zip("AB", windows)):
            zx = fig.add_subplot(gs[row, col])
            zx.set_xlim(a, b)
            drawn = [(run, t, y) for run, t, y in p.series if len(t) and t[0] <= b and t[-1] >= a]
            _draw_runs(zx, drawn, a, b, zoom=True)
            _draw_reference(zx, p.reference, a, b)
            _style_axes(zx, p.ylabel if col == 0 else None)
            zx.xaxis.set_major_locator(MaxNLocator(5))
            zx.yaxis.set_major_locator(MaxNLocator(5))
            which = "early" if (a + b) / 2 < t_end / 2 else "late"
            zx.set_title(f"{letter}: zoom {a:.3g}–{b:.3g} s ({which}), every sample",
                         fontsize=_FONT["panel"], loc="left")
            if not drawn:
                zx.text(0.5, 0.5, "no run reaches this window", transform=zx.transAxes,
                        ha="center", va="center", fontsize=_FONT["note"], color="0.4")
        row += 1

    fig.suptitle(title, x=0.5, y=1 - 0.12 / h_in, ha="center", va="top", fontsize=_FONT["title"],
                 fontweight="bold")
    fig.text(0.5, 1 - 0.47 / h_in, subtitle, ha="center", va="top", fontsize=_FONT["subtitle"])
    fig.legend(handles, labels, handler_map={tuple: HandlerTuple(ndivide=None, pad=0)},
               loc="upper center", bbox_to_anchor=(0.5, 1 - 0.74 / h_in), ncol=ncol,
               fontsize=_FONT["legend"], frameon=False, handlelength=2.6, columnspacing=1.8)

    notes = []
    zooms = any(p.zoom for p in panels)
    if dense_panels:
        col_ms = t_end / _axes_px(fig.axes[0]) * 1e3
        line = ("mean over a sliding window of " + _fmt_time(max(dense_panels))
                if max(dense_panels) > 0 else "their mean")
        whole = len(panels) + sum(1 for d in details if d)
        notes.append(f"Main panel{'s' if whole > 1 else ''}: translucent band = min–max of "
                     f"all samples in each pixel column (≈{col_ms:.2g} ms); line = {line}.")
    second = []
    if zooms:
        second.append("Zoom panels A, B (shaded on the main panel) draw every sample")
    second.append(_sample_note(runs))
    if any(_status(r.traj) != 0 for r in runs):
        second.append("× marks where a diverged run stopped")
    text = "; ".join(second) + "."
    notes.append(text[0].upper() + text[1:])
    if extra_note:
        notes.append(extra_note)
    fig.text(0.01, 0.012, "\n".join(notes), ha="left", va="bottom", fontsize=_FONT["note"],
             color="0.25", linespacing=1.35)
    return fig


def _fmt_time(seconds: float) -> str:
    return f"{seconds:.3g} s" if seconds >= 1 else f"{seconds * 1e3:.3g} ms"


def _log_limits(ax, series, t_end: float):
    """Log scale for J(t): J(0) = 0, so start the axis one decade below the smallest value any
    run has reached after 1 % of the span, where every run is visible."""
    early, tops = [], []
    for _, t, y in series:
        ok = np.isfinite(y) & (y > 0)
        if not ok.any():
            continue
        tops.append(y[ok].max())
        late = ok & (t >= 0.01 * t_end)
        early.append(y[late][0] if late.any() else y[ok][-1])
    if not tops:
        return
    lo = 10 ** (math.floor(math.log10(min(early))) - 1)
    hi = 10 ** math.ceil(math.log10(max(tops) * 1.5))
    ax.set_ylim(lo, hi)


#: ``savefig`` keywords of every PNG hinfnn writes: zlib level 1 instead of matplotlib's 6, the same
#: pixels in somewhat larger files, encoded in about half the time.
PNG_OPTIONS = {"pil_kwargs": {"compress_level": 1}}


def save_png(fig: Figure, path: Path, dpi: int = DPI) -> Path:
    """Write ``fig`` to ``path`` atomically as a PNG (:data:`PNG_OPTIONS`)."""
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=dpi, facecolor="white", **PNG_OPTIONS))
    return path


def _save(fig: Figure, path: Path) -> Path:
    return save_png(fig, path)


def _series(runs: list[_Run], field: str, column: int | None = None, scale: float = 1.0):
    out = []
    for r in runs:
        s = r.signal(field, column, scale)
        if s is not None:
            out.append((r, *s))
    return out


def _reference(runs: list[_Run], field: str, column: int | None = None):
    """The reference from the run that covers the longest time (references agree across runs)."""
    best = None
    for r in runs:
        s = r.signal(field, column)
        if s is not None and (best is None or s[0][-1] > best[0][-1]):
            best = s
    return best


def _t_end(runs: list[_Run]) -> float:
    ends = [float(np.asarray(r.traj.arrays["t"])[-1]) for r in runs]
    return max(ends) if ends and max(ends) > 0 else 1.0


#: Fewer stored samples than this per period of the reference make a figure meaningless.
MIN_SAMPLES_PER_PERIOD = 50

#: Names of the figures each function can draw (``only=``).
RUN_FIGURES = ("u1", "errors", "lambda", "tau", "J", "contact", "weights", "phases")
PAPER_FIGURES = ("fig3_u1_fl", "fig4_lambda_fl", "fig5_u1", "fig6_lambda", "fig7_tau1", "fig8_tau2", "fig9_J")


def sparse_note(runs: dict[str, Trajectory]) -> str | None:
    """A sentence when the stored samples are too far apart to draw the reference (fewer than
    :data:`MIN_SAMPLES_PER_PERIOD` per period of the cosine reference), else None."""
    worst = None
    for traj in runs.values():
        t = np.asarray(traj.arrays.get("t", ()))
        if t.ndim != 1 or len(t) < 2:
            continue
        interval = float(t[1] - t[0])
        periods = _tag(traj, "reference_periods") or []
        if not periods:
            continue
        period = min(periods)  # the cosine references: one period, or one per coordinate
        per = period / interval if interval > 0 else math.inf
        if per < MIN_SAMPLES_PER_PERIOD and (worst is None or per < worst[0]):
            worst = (per, interval, period, len(t))
    if worst is None:
        return None
    per, interval, period, n = worst
    return (f"the runs are stored every {interval:g} s ({n} samples, {per:.2g} per period of the {period:g}-s "
            f"reference): the figures cannot show the reference or the response; store at most "
            f"{period / MIN_SAMPLES_PER_PERIOD:g} s apart (simulation.output_interval)")


def warn_sparse(runs: dict[str, Trajectory]) -> None:
    """Warn (:class:`hinfnn.errors.HinfnnWarning`) when :func:`sparse_note` has something to say."""
    note = sparse_note(runs)
    if note:
        import warnings

        from ..errors import HinfnnWarning

        warnings.warn(note, HinfnnWarning, stacklevel=3)


# --- the paper's figures -------------------------------------------------------------------


def _paper_label(name: str, traj: Trajectory) -> str:
    return _describe(traj)


def paper_figures(runs: dict[str, Trajectory], out_dir, *, suffix: str = "",
                  zoom_windows: Sequence[tuple[float, float]] | None = None,
                  only: Sequence[str] | None = None) -> list[Path]:
    """Write the paper's Figs. 3–9 (Sec. VI) as PNG files in ``out_dir``; return their paths.

    ``runs`` holds one contact model's runs of the study, in the study's order; each run's tag
    ``figures`` says which figures it appears in: "figs3-4" (the FL-like law: Figs. 3–4, and 9)
    or "figs5-9" (H∞-only and adaptive: Figs. 5–9); runs without it are not drawn.
    ``suffix`` is appended to every file name (``fig5_u1_damped.png``). A figure none of whose
    runs is present is not written. ``zoom_windows``: the two (start, end) times of the zoom
    panels A and B (default 6–7 % and 96–98 % of the run's length).

    Files: ``fig3_u1_fl``, ``fig4_lambda_fl`` (FL-like), ``fig5_u1``, ``fig6_lambda``,
    ``fig7_tau1``, ``fig8_tau2`` (H∞-only vs adaptive), ``fig9_J`` (all, log scale); ``only``:
    draw just these (names without suffix and ``.png``).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    drawn = {name: traj for name, traj in runs.items() if _tag(traj, "figures") in ("figs3-4", "figs5-9")}
    warn_sparse(drawn)

    def pick(groups):
        return _prepare([(n, t) for n, t in drawn.items() if _tag(t, "figures") in groups], _paper_label)

    fl = pick(("figs3-4",))
    main = pick(("figs5-9",))
    every = pick(("figs3-4", "figs5-9"))
    # one colour per controller across all the figures of the set
    colors = {r.name: r.color for r in every}
    fl = [dataclasses.replace(r, color=colors[r.name]) for r in fl]
    main = [dataclasses.replace(r, color=colors[r.name]) for r in main]

    written = []

    def emit(name, title, group, panels_fn, size=SIZE, extra=""):
        if not group or (only is not None and name not in only):
            return
        panels = panels_fn(group)
        if not any(p.series for p in panels):
            return
        t_end = _t_end(group)
        fig = _build(title, _contact_note(group), panels, size, t_end,
                     _zoom_windows(t_end, zoom_windows), extra)
        written.append(_save(fig, out_dir / f"{name}{suffix}.png"))

    u1_label = r"$u_1$ (m)"
    emit("fig3_u1_fl", r"Fig. 3 — motion $u_1(t)$ under the FL-like controller", fl,
         lambda g: [_Panel(u1_label, _series(g, "u1"), _reference(g, "u1_d"))])
    emit("fig4_lambda_fl", r"Fig. 4 — force $\lambda(t)$ under the FL-like controller", fl,
         lambda g: [_Panel(_lambda_label(g), _series(g, "lam"), _reference(g, "lam_d"), zoom=True)])
    emit("fig5_u1", r"Fig. 5 — motion $u_1(t)$: H∞-only vs adaptive H∞ NN", main,
         lambda g: [_Panel(u1_label, _series(g, "u1"), _reference(g, "u1_d"))])
    emit("fig6_lambda", r"Fig. 6 — force $\lambda(t)$: H∞-only vs adaptive H∞ NN", main,
         lambda g: [_Panel(_lambda_label(g), _series(g, "lam"), _reference(g, "lam_d"), zoom=True)])
    emit("fig7_tau1", r"Fig. 7 — applied torque $\tau_1(t)$: H∞-only vs adaptive H∞ NN", main,
         lambda g: [_Panel(r"$\tau_1$ (N·m)", _series(g, "tau", 0), zoom=True, detail=True)],
         size=SIZE_TALL)
    emit("fig8_tau2", r"Fig. 8 — applied torque $\tau_2(t)$: H∞-only vs adaptive H∞ NN", main,
         lambda g: [_Panel(r"$\tau_2$ (N·m)", _series(g, "tau", 1), zoom=True, detail=True)],
         size=SIZE_TALL)
    emit("fig9_J", r"Fig. 9 — H∞ tracking performance index $J(t)$, eq. (34)",
         _with_final(every, "J"),
         lambda g: [_Panel(r"$J(t)$ (log scale)", _series(g, "J"), log=True, title=_J_TITLE)])
    return written


_J_TITLE = (r"$J(t) = \int_0^t\,(\|x_p\|^2_{Q_p} + \alpha_\lambda e_\lambda^2 + "
            r"\alpha_\lambda\mu_z/(1+\beta_\lambda)\,z^2)\,ds$"
            " — same weights for every controller")


def _with_final(runs: list[_Run], field: str) -> list[_Run]:
    """The runs with the last valid value of ``field`` appended to their labels."""
    out = []
    for r in runs:
        s = r.signal(field)
        if s is not None and len(s[1]):
            r = dataclasses.replace(r, label=f"{r.label}: J({s[0][-1]:.3g} s) = {s[1][-1]:.4g}")
        out.append(r)
    return out


_COORD_DOC = {"s": "arc length along the surface", "s1": "first in-plane coordinate", "s2": "second in-plane coordinate",
              "s_lon": "longitude (arc length)", "s_lat": "latitude (arc length)", "s_axial": "along the axis",
              "s_arc": "arc length about the axis", "phi_rel": "tool angle from the surface normal",
              "phi": "tool angle", "r_x": "tool rotation vector, x", "r_y": "tool rotation vector, y",
              "r_z": "tool rotation vector, z (about the normal for fitted coordinates)"}


def _width(runs, field: str) -> int:
    """Number of columns of a field (1 for a scalar field)."""
    for r in runs:
        a = r.traj.arrays.get(field)
        if a is not None:
            a = np.asarray(a)
            return 1 if a.ndim == 1 else int(a.shape[1])
    return 1


def _joint_title(runs, i: int) -> str:
    for r in runs:
        js = _tag(r.traj, "joints")
        if js:
            return f"joint {i + 1}: {js[i]}" if i < len(js) else f"joint {i + 1}"
    return f"joint {i + 1}"


_CONTACT_NOTE = ("Penetration of the true surface: > 0 in contact (normal force = max(0, stiffness "
                 "× penetration + damping × its rate)), < 0 the distance above it (no force).")


# --- a run's figures -----------------------------------------------------------------------


def _run_label(name: str, traj: Trajectory) -> str:
    desc = _describe(traj)
    if name == _kind(traj):
        return desc
    return name.replace("$", r"\$") + f" ({desc})"  # a name is text, not mathtext


def run_figures(runs: dict[str, Trajectory], out_dir, *,
                zoom_windows: Sequence[tuple[float, float]] | None = None,
                only: Sequence[str] | None = None) -> list[Path]:
    """Write the figures of ``hinfnn run`` for one or several named runs; return the paths.

    ``u1.png`` (u1 and u1d), ``errors.png`` (e_u1 per coordinate and e_λ; arms other than the
    paper's), ``lambda.png`` (λ, λd, with zooms), ``tau.png`` (τ1, τ2, with
    zooms), ``J.png`` (eq. (34), log scale), ``contact.png`` (normal force in N, penetration
    in mm, with zooms), ``weights.png`` (‖Θ̂p‖, ‖Θ̂f‖) when some run has nonzero
    weights and ``phases.png`` when some run is a job's (:mod:`hinfnn.controllers.job`; its phase
    changes also dotted on every panel) (:data:`RUN_FIGURES`, the names ``hinfnn plot --figures``
    takes). Run names other
    than the controller kind are shown beside its description.
    ``only``: draw just these (names without ``.png``, e.g. ``["u1", "tau"]``).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    warn_sparse(runs)
    group = _prepare(list(runs.items()), _run_label)
    if not group:
        return []
    t_end = _t_end(group)
    windows = _zoom_windows(t_end, zoom_windows)
    sub = _contact_note(group)
    written = []

    def emit(name, title, panels, size=SIZE, extra=""):
        if only is not None and name[:-len(".png")] not in only:
            return
        if not any(p.series for p in panels):
            return
        panels = [p for p in panels if p.series]
        fig = _build(title, sub, panels, size, t_end, windows, extra)
        written.append(_save(fig, out_dir / name))

    names = _coordinates(group)
    m = _width(group, "u1")
    k = _width(group, "lam")
    n = _width(group, "tau")
    if names is None or (m == 1 and k == 1 and n == 2):  # the Sec. VI arm: the paper's layout
        emit("u1.png", r"Motion $u_1(t)$ and its reference $u_{1d}(t)$",
             [_Panel(r"$u_1$ (m)", _series(group, "u1"), _reference(group, "u1_d"))])
        emit("lambda.png", r"Force $\lambda(t)$ and its reference $\lambda_d(t)$",
             [_Panel(_lambda_label(group), _series(group, "lam"), _reference(group, "lam_d"),
                     zoom=True)])
        emit("tau.png", r"Applied torques $\tau_1(t)$, $\tau_2(t)$",
             [_Panel(r"$\tau_1$ (N·m)", _series(group, "tau", 0), zoom=True),
              _Panel(r"$\tau_2$ (N·m)", _series(group, "tau", 1), zoom=True)],
             size=SIZE_TALL)
    else:
        motion = names[:m]
        emit("u1.png", f"Motion coordinates $u_1$ ({m}) and their references",
             [_Panel(f"{_math(nm)} ({unit})", _series(group, "u1", i), _reference(group, "u1_d", i),
                     title=f"{nm}: {_COORD_DOC.get(nm, 'task coordinate')}")
              for i, (nm, unit) in enumerate(motion)], size=_tall(m, False))
        emit("errors.png", r"Tracking errors $e_{u1} = u_1 - u_{1d}$ (the controller's view) and $e_\lambda$",
             [_Panel(f"$e$ {_math(nm)} ({unit})", _series(group, "e_u1", i), title=f"error of {nm}")
              for i, (nm, unit) in enumerate(motion)]
             + [_Panel(r"$e_\lambda$" + (f" {j + 1}" if k > 1 else "") + " (N)", _series(group, "e_lam", j),
                       zoom=True, title="force error") for j in range(k)],
             size=_tall(m + k, False))
        emit("lambda.png", r"Force $\lambda(t)$ (the normal force) and its reference $\lambda_d(t)$",
             [_Panel(_lambda_label(group) if k == 1 else f"$\\lambda_{j + 1}$", _series(group, "lam", j),
                     _reference(group, "lam_d", j), zoom=True) for j in range(k)],
             size=SIZE if k == 1 else _tall(k, True))
        emit("tau.png", f"Applied joint torques $\\tau_1 \\ldots \\tau_{{{n}}}$",
             [_Panel(f"$\\tau_{i + 1}$ (N·m)", _series(group, "tau", i), title=_joint_title(group, i))
              for i in range(n)], size=_tall(n, False))
    emit("J.png", r"H∞ tracking performance index $J(t)$, eq. (34)",
         [_Panel(r"$J(t)$ (log scale)", _series(_with_final(group, "J"), "J"), log=True,
                 title=_J_TITLE)])
    contact = [_Panel("normal force (N)", _series(group, "normal_force"), zoom=True),
               _Panel("penetration (mm)", _series(group, "penetration", scale=1e3), zoom=True)]
    if any(np.any(np.asarray(r.traj.arrays.get("friction_force", [0.0])) != 0) for r in group):
        contact.append(_Panel("friction force (N)", _series(group, "friction_force"), zoom=True,
                              title="tangential (friction) force of the tool on the surface"))
    emit("contact.png", "Contact: normal force and penetration of the true surface", contact,
         size=SIZE_TALL if len(contact) == 2 else _tall(3, True), extra=_CONTACT_NOTE)

    phased = [r for r in group if "phase" in r.traj.arrays]
    if phased:
        emit("phases.png", "The job's phases (dotted lines on every figure)",
             [_Panel("phase", _series(phased, "phase"),
                     title="0 approach, 1 force ramp, 2 process, 3 unload, 4 lift-off, 5 no contact found")])

    learners = [r for r in group if any(
        f in r.traj.arrays and np.any(np.asarray(r.traj.arrays[f])[: r.traj.valid_samples()] != 0)
        for f in ("theta_p_norm", "theta_f_norm"))]
    if learners:
        emit("weights.png", r"Network weights $\|\hat\Theta_p\|$, $\|\hat\Theta_f\|$",
             [_Panel(r"$\|\hat\Theta_p\|$", _series(learners, "theta_p_norm"),
                     title=r"$F_p$ (motion) weights"),
              _Panel(r"$\|\hat\Theta_f\|$", _series(learners, "theta_f_norm"),
                     title=r"$F_f$ (force) weights")])
    return written


# --- beyond the paper ---------------------------------------------------------------------------------


def beyond_figures(runs: dict[str, Trajectory], metrics: dict[str, dict], cases: list[dict], out_dir,
                   *, stiffness: float = 1e5) -> list[Path]:
    """The "Beyond the paper" figures of ``hinfnn reproduce``.

    ``beyond_lambda_u1.png``: λ(t) and u1(t) of the paper's and the stabilised laws at
    ``stiffness``, continuous control. ``beyond_bars.png``: RMS e_λ, RMS e_u1 and the time out of
    contact of every case, paper law beside stabilised, a run that stopped marked with the time
    it stopped. ``cases``: [{"name", "kind", "variant", "mode", "k", "label"}] in plot order.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    pick = [c for c in cases if c["mode"] == "cont" and c["k"] == stiffness]
    group = _prepare([(c["name"], runs[c["name"]]) for c in pick if c["name"] in runs],
                     lambda name, traj: next(c["label"] for c in pick if c["name"] == name))
    if group:
        t_end = _t_end(group)
        fig = _build(f"Beyond the paper: force and motion on the undamped {stiffness:.0e} N/m contact",
                     _contact_note(group),
                     [_Panel(_lambda_label(group), _series(group, "lam"), _reference(group, "lam_d"), zoom=True),
                      _Panel(r"$u_1$ (m)", _series(group, "u1"), _reference(group, "u1_d"))],
                     SIZE_TALL, t_end, _zoom_windows(t_end))
        written.append(_save(fig, out_dir / "beyond_lambda_u1.png"))
    horizon = max((float(np.asarray(t.arrays["t"])[-1]) for t in runs.values()), default=0.0)
    written.append(_beyond_bars(metrics, cases, out_dir / "beyond_bars.png", horizon))
    return written


def _beyond_bars(metrics: dict, cases: list[dict], path: Path, horizon: float) -> Path:
    keys = []  # (kind, mode, k) in order
    names = {c["kind"]: c["label"].split(",")[0] for c in cases}  # the law's label ("H∞-only, paper law, ...")
    for c in cases:
        key = (c["kind"], c["mode"], c["k"])
        if key not in keys:
            keys.append(key)
    fig = Figure(figsize=(SIZE_TALL[0] / DPI, SIZE_TALL[1] / DPI), dpi=DPI, facecolor="white")
    gs = fig.add_gridspec(3, 1, left=0.09, right=0.985, top=0.88, bottom=0.15, hspace=0.3)
    panels = [("rms_e_lam", r"RMS $e_\lambda$ (log)", True, 1.0), ("rms_e_u1", r"RMS $e_{u1}$ (m)", False, 1.0),
              ("fraction_out_of_contact", "out of contact (%)", False, 100.0)]
    x = np.arange(len(keys))
    width = 0.38
    colors = {"paper": "#9e9e9e", "stable": "#1a9641"}
    for row, (metric, ylabel, log, scale) in enumerate(panels):
        ax = fig.add_subplot(gs[row])
        for j, variant in enumerate(("paper", "stable")):
            values, stopped = [], []
            for kind, mode, k in keys:
                c = next((c for c in cases if (c["kind"], c["mode"], c["k"], c["variant"]) == (kind, mode, k, variant)),
                         None)
                m = metrics.get(c["name"]) if c else None
                v = m.get(metric) if m else None
                values.append(scale * v if v is not None and math.isfinite(v) else np.nan)
                stopped.append(m is not None and m.get("status") != "ok")
            xs = x + (j - 0.5) * width
            bars = ax.bar(xs, np.nan_to_num(values, nan=0.0), width, color=colors[variant],
                          label="paper law" if variant == "paper" else "stabilised (force rate, Q_p, guard)",
                          edgecolor="black", linewidth=0.4, zorder=2)
            for b, s in zip(bars, stopped):
                if s:
                    b.set_hatch("///")
        if log:
            ax.set_yscale("log")
        _style_axes(ax, ylabel, xlabel=None)
        ax.set_xticks(x)
        how = {"cont": "cont.", "1kHz": "1 kHz", "10kHz": "10 kHz", "mujoco": "MuJoCo"}
        ax.set_xticklabels([f"{how.get(mode, mode)}\n{k:.0e}" for kind, mode, k in keys] if row == 2
                           else [""] * len(keys), fontsize=_FONT["tick"])
        kinds = list(dict.fromkeys(kind for kind, _, _ in keys))
        for i, kind in enumerate(kinds):  # the laws side by side, a line between them, named below
            at = [n for n, key in enumerate(keys) if key[0] == kind]
            if i:
                ax.axvline(at[0] - 0.5, color="0.35", linewidth=1.0, zorder=1)
            if row == 2:
                ax.text((at[0] + at[-1]) / 2, -0.3, names[kind], transform=ax.get_xaxis_transform(),
                        ha="center", va="top", fontsize=_FONT["legend"], fontweight="bold")
        if row == 0:
            handles, labels = ax.get_legend_handles_labels()
    fig.suptitle("Beyond the paper: the paper's laws and the stabilised ones on an undamped contact",
                 fontsize=_FONT["title"], fontweight="bold", y=0.975)
    handles.append(Patch(facecolor="white", edgecolor="black", hatch="///", linewidth=0.4))
    labels.append("the run stopped (metrics up to then)")
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.945), ncol=3, frameon=False,
               fontsize=_FONT["legend"])
    fig.text(0.01, 0.012, f"Each pair: the same law, control mode and contact stiffness (N/m), {horizon:.3g} s runs. "
             "cont.: continuous control; 1 kHz, 10 kHz: zero-order hold;\nMuJoCo: MuJoCo as the plant, 10 kHz hold. "
             "Out of contact: the end-effector more than 1 nm above the surface.",
             fontsize=_FONT["note"], color="0.25", linespacing=1.35)
    return _save(fig, path)
