"""Figures (hinfnn.report.figures): files written atomically, readable PNGs of the stated size,
missing runs skipped, diverged runs cut at t_fail, dense signals drawn without aliasing.

The runs are synthetic Trajectories (no simulation), so the whole file takes a few seconds."""

from __future__ import annotations

import matplotlib.image as mpimg
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hinfnn.report import paper_figures, run_figures
from hinfnn.report import figures as F
from hinfnn.scenario import Scenario, describe
from hinfnn.sim.trajectory import RunInfo, Trajectory

PAPER_FILES = ["fig3_u1_fl", "fig4_lambda_fl", "fig5_u1", "fig6_lambda", "fig7_tau1",
               "fig8_tau2", "fig9_J"]
TALL = ("fig7_tau1", "fig8_tau2", "tau.png", "contact.png")


def make_run(kind="hinf", preset="paper-likely", *, t_final=1.0, dt=1e-4, chatter=0.0,
             status=0, t_fail=np.nan, damping=0.0, weights=None, scaling="paper"):
    """A Trajectory with the fields the figures use; ``chatter`` adds a 450 Hz oscillation."""
    t = np.linspace(0.0, t_final, int(round(t_final / dt)) + 1)
    u1_d = 1.5 + 0.2 * np.cos(np.pi * t)
    lam_d = 60 - 20 * np.cos(np.pi * t)
    fast = chatter * np.sin(2 * np.pi * 450 * t)
    u1 = u1_d - 0.1 * np.sin(np.pi * t)
    lam = np.maximum(lam_d + 5 * np.sin(3 * t) + fast, 0.0)
    tau = np.stack([-100 + 10 * np.sin(t) + 50 * fast, -30 + 5 * np.cos(t) + 20 * fast], axis=1)
    w = (kind == "hinf_nn") if weights is None else weights
    arrays = {
        "t": t, "u1": u1[:, None], "u1_d": u1_d[:, None], "lam": lam[:, None],
        "lam_d": lam_d[:, None], "e_u1": (u1 - u1_d)[:, None], "e_lam": (lam - lam_d)[:, None],
        "tau": tau, "J": 10.0 * t + 0.5 * t**2 * (1 + chatter),
        "normal_force": lam / np.cos(np.pi / 4), "penetration": lam / np.cos(np.pi / 4) / 1e5,
        "theta_p_norm": 0.02 * t if w else np.zeros_like(t),
        "theta_f_norm": 30.0 * t if w else np.zeros_like(t),
    }
    if status:  # arrays after t_fail are frozen at the last good state
        k = np.searchsorted(t, t_fail, side="right")
        for name, a in arrays.items():
            if name != "t":
                a[k:] = a[k - 1]
    sc = Scenario.load("paper", {"plant.contact.damping": damping, "nominal.surface.scaling": scaling,
                                 "controller.kind": kind, "controller.network_f.preset": preset}, check=False)
    tags = {**describe(sc), "contact": "damped" if damping else "undamped",
            "figures": "figs3-4" if kind == "fl" else "figs5-9"}
    info = RunInfo(name=kind, kind=kind, label=tags["label"], color=tags["color"], tags=tags, scenario=sc)
    return Trajectory(arrays=arrays, status=np.array(status), t_fail=np.array(t_fail),
                      fail_details={}, info=info, dt=dt, save_every=1)


@pytest.fixture(scope="module")
def study():
    return {
        "fl": make_run("fl", chatter=2.0),
        "hinf": make_run("hinf", chatter=2.0),  # 10x quieter torque: Figs. 7-8 get a y-detail
        "hinf_nn": make_run("hinf_nn", chatter=20.0),
        "hinf_nn_printed": make_run("hinf_nn", "paper-printed", chatter=5.0),
    }


def check_pngs(folder, paths, names):
    assert sorted(p.name for p in paths) == sorted(names)
    for p in paths:
        assert p.parent == folder and p.is_file()
        img = mpimg.imread(p)  # raises if it is not a valid PNG
        w, h = F.SIZE_TALL if p.name.startswith(TALL) else F.SIZE
        assert img.shape[:2] == (h, w), p.name
        assert img[..., :3].std() > 0.05  # not blank
    # nothing else: no temporary (.part) or hidden files left behind
    assert sorted(x.name for x in folder.iterdir()) == sorted(names)


def test_paper_figures_all_written_with_a_diverged_run(tmp_path, study):
    runs = dict(study)
    runs["hinf_nn"] = make_run("hinf_nn", chatter=20.0, status=2, t_fail=0.4)
    paths = paper_figures(runs, tmp_path)
    check_pngs(tmp_path, paths, [f"{n}.png" for n in PAPER_FILES])


def test_diverged_run_is_cut_at_t_fail_and_labelled():
    traj = make_run("hinf_nn", chatter=20.0, status=2, t_fail=0.4)
    (run,) = F._prepare([("hinf_nn", traj)], F._paper_label)
    assert "diverged at t = 0.4 s" in run.label and "torque limit" in run.label
    t, y = run.signal("tau", 0)
    assert t[-1] == pytest.approx(0.4) and len(t) == 4001
    (ok,) = F._prepare([("hinf_nn", make_run("hinf_nn"))], F._paper_label)
    assert "diverged" not in ok.label and len(ok.signal("tau", 0)[0]) == 10001


def test_suffix_and_missing_runs(tmp_path, study):
    """The runs given are one contact model's; each run's ``figures`` tag says where it is drawn
    (never its name); the suffix goes on every file; a figure none of whose runs is given is not
    written, and a run without the tag is not drawn."""
    import dataclasses

    paths = paper_figures({"any name": make_run("hinf", damping=200.0)}, tmp_path / "a", suffix="_damped")
    check_pngs(tmp_path / "a", paths, [f"{n}_damped.png" for n in PAPER_FILES[2:]])
    paths = paper_figures({"fl": make_run("fl", damping=200.0)}, tmp_path / "b", suffix="_damped")
    check_pngs(tmp_path / "b", paths, ["fig3_u1_fl_damped.png", "fig4_lambda_fl_damped.png",
                                       "fig9_J_damped.png"])
    assert paper_figures({}, tmp_path / "c") == []
    assert list((tmp_path / "c").iterdir()) == []
    hinf = study["hinf"]
    untagged = dataclasses.replace(hinf, info=dataclasses.replace(hinf.info, tags={**hinf.info.tags, "figures": None}))
    assert paper_figures({"hinf": untagged}, tmp_path / "d") == []


def test_run_figures(tmp_path, study):
    runs = dict(study)
    runs["diverged"] = make_run("hinf_nn", chatter=20.0, status=1, t_fail=0.7)
    paths = run_figures(runs, tmp_path)
    check_pngs(tmp_path, paths, ["u1.png", "lambda.png", "tau.png", "J.png", "contact.png",
                                 "weights.png"])


def test_every_run_figure_can_be_asked_for_by_name():
    """RUN_FIGURES (what ``hinfnn plot --figures`` accepts) names every figure run_figures writes:
    errors.png, an arm's, was once refused by ``--figures errors``."""
    import inspect
    import re

    written = set(re.findall(r'emit\("(\w+)\.png"', inspect.getsource(F.run_figures)))
    assert written == set(F.RUN_FIGURES), written ^ set(F.RUN_FIGURES)


def test_run_figures_without_weights_and_short_run(tmp_path):
    runs = {"hinf": make_run("hinf", t_final=0.05),
            "my $run": make_run("fl", t_final=0.05, damping=200.0, scaling="unit")}
    paths = run_figures(runs, tmp_path)
    check_pngs(tmp_path, paths, ["u1.png", "lambda.png", "tau.png", "J.png", "contact.png"])


def test_batched_trajectory_is_refused(tmp_path):
    r = make_run("hinf", t_final=0.01)
    batch = Trajectory(arrays={k: np.stack([v, v]) for k, v in r.arrays.items()},
                       status=np.zeros(2, int), t_fail=np.full(2, np.nan), fail_details={},
                       info=r.info, dt=r.dt, save_every=1)
    with pytest.raises(ValueError, match="batch"):
        run_figures({"b": batch}, tmp_path)


def test_columns_keep_the_extremes_of_fast_chatter():
    """A 455 Hz oscillation at 10 kHz, 10 s, in 1400 columns: every column spans ±1 (no
    aliasing), and the sliding mean is ~0 (the slow picture)."""
    t = np.linspace(0.0, 10.0, 100_001)
    y = np.sin(2 * np.pi * 455 * t + 0.3)
    tm, lo, hi, line = F._columns(t, y, 0.0, 10.0, 1400, smooth=0.1)
    assert len(tm) == 1400
    assert np.all(hi > 0.95) and np.all(lo < -0.95)
    assert np.max(np.abs(line[20:-20])) < 0.02
    # a single-sample spike survives
    y2 = np.zeros_like(t)
    y2[54_321] = 7.0
    _, _, hi2, _ = F._columns(t, y2, 0.0, 10.0, 1400)
    assert hi2.max() == 7.0
    # few samples per column: drawn sample by sample
    assert F._columns(t[::50], y[::50], 0.0, 10.0, 1400) is None
    # a run that stopped at 4 s is dense over the columns it spans
    assert F._columns(t[:40_001], y[:40_001], 0.0, 10.0, 1400) is not None


def test_report_does_not_import_controllers_or_plant():
    import ast
    import inspect

    tree = ast.parse(inspect.getsource(F))
    names = [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    names += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    assert not [n for n in names if "controllers" in n or "plant" in n or "pyplot" in n]


@settings(max_examples=60, deadline=None)
@given(n_samples=st.integers(10, 3000), columns=st.integers(1, 400), seed=st.integers(0, 2**32 - 1),
       uneven=st.booleans())
def test_columns_keep_min_and_max_of_every_pixel_column(n_samples, columns, seed, uneven):
    """The decimation the main panels draw: each pixel column's band spans exactly the smallest
    and largest sample in that column, so no excursion is lost, and the columns together cover
    every sample."""
    rng = np.random.default_rng(seed)
    steps = rng.uniform(0.1, 2.0, n_samples) if uneven else np.ones(n_samples)
    t = np.cumsum(steps) - steps[0]
    y = rng.standard_normal(n_samples) * rng.choice([1e-3, 1.0, 1e4])
    x0, x1 = 0.0, float(t[-1])
    cols = F._columns(t, y, x0, x1, columns)
    if cols is None:  # sparse: every sample is drawn as it is
        assert not F._dense(t, x0, x1, columns)
        return
    tm, lo, hi, _ = cols
    b = np.clip(((t - x0) / (x1 - x0) * columns).astype(np.int64), 0, columns - 1)
    used = np.unique(b)
    assert len(tm) == len(used)
    for j, col in enumerate(used):
        assert lo[j] == y[b == col].min() and hi[j] == y[b == col].max()
    assert lo.min() == y.min() and hi.max() == y.max()


def test_png_fast_writes_the_same_pixels(tmp_path, monkeypatch):
    """The PNG compression of every figure (hinfnn.report.figures.PNG_OPTIONS, zlib level 1)
    changes the file's size, not the picture."""
    from hinfnn.report import figures

    runs = {"hinf": make_run("hinf", chatter=2.0)}
    fast = run_figures(runs, tmp_path / "fast", only=["tau"])
    monkeypatch.setattr(figures, "PNG_OPTIONS", {})
    default = run_figures(runs, tmp_path / "default", only=["tau"])
    assert np.array_equal(mpimg.imread(fast[0]), mpimg.imread(default[0]))