"""`hinfnn sweep`: the spec parser, seeded draws, the table against single runs, divergence and
invalid draws isolated, resume (in-process and after SIGKILL), the Ray backend, figures, CLI.

Every simulation here is the H∞-only controller in batches of 2 (``max_batch=2``), so the module
compiles one batched program (the horizons differ: t_final is a traced argument).
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import hinfnn as H
from hinfnn import cli
from hinfnn.errors import ConfigError
from hinfnn.sweep import load_spec, run_sweep, spec_from_dict, spec_names
from hinfnn.sweep.worker import batch_cap, plan_batches, scenario_of
from hinfnn.sweep.sampling import draw_values, grid_points, runs, uniforms
from hinfnn.sweep.spec import PER_COORDINATE_METRICS
from hinfnn.sweep.store import metric_columns

SRC = Path(H.__file__).resolve().parent.parent

SPEC = """
name = "small"
scenario = "paper"
controllers = ["hinf"]
samples = 4
seed = 3
[set]
"simulation.t_final" = 0.05
[vary]
"plant.arm.m1" = { distribution = "relative", percent = 10 }
"plant.contact.damping" = { distribution = "uniform", low = 0.0, high = 200.0 }
"""


def write(tmp_path, text, name="spec.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def spec_of(text, **kw):
    import tomllib

    return spec_from_dict(tomllib.loads(textwrap.dedent(text)), **kw)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A small sweep run once with the local backend: (spec, folder, table)."""
    spec = spec_of(SPEC)
    folder = tmp_path_factory.mktemp("sweep") / "small"
    res = run_sweep(spec, folder, max_batch=2)
    assert res.counts["hinf"]["simulated"] == 4
    return spec, folder, H.load_sweep(folder)


# --- the spec and the draws -------------------------------------------------------------------


def test_grids_and_draws_combine_in_table_order():
    spec = spec_of("""
        name = "g"
        controllers = ["fl", "hinf"]
        samples = 3
        [vary]
        "plant.contact.stiffness" = { logspace = [1e4, 1e6, 3] }
        "plant.arm.m2" = { linspace = [0.8, 1.2, 2] }
        "initial.elbow" = { values = ["up"] }
        "plant.arm.m1" = { distribution = "uniform", low = 1.0, high = 1.4 }
        """)
    assert spec.points == 6 and spec.n_runs == 6 * 3 * 2
    pts = grid_points(spec)
    assert [p["plant.contact.stiffness"] for p in pts[::2]] == pytest.approx([1e4, 1e5, 1e6])
    assert [p["plant.arm.m2"] for p in pts[:2]] == pytest.approx([0.8, 1.2])
    rs = runs(spec)
    assert [r.run for r in rs] == list(range(36))
    assert (rs[7].point, rs[7].sample, rs[7].controller) == (1, 0, "hinf")
    # the same draws at every grid point, for every controller
    m1 = {(r.point, r.sample): r.values["plant.arm.m1"] for r in rs}
    assert all(m1[(p, s)] == m1[(0, s)] for p in range(6) for s in range(3))
    assert list(rs[0].values) == ["plant.contact.stiffness", "plant.arm.m2", "initial.elbow", "plant.arm.m1"]


def test_draws_are_seeded_by_seed_key_and_index():
    base = """
        name = "d"
        controllers = ["hinf"]
        seed = {seed}
        samples = {n}
        [vary]
        "plant.arm.m1" = {{ distribution = "relative", percent = 20 }}
        "plant.contact.stiffness" = {{ distribution = "log-uniform", low = 1e4, high = 1e6 }}
        "plant.contact.damping" = {{ distribution = "normal", mean = 100, std = 80, low = 0, high = 200 }}
        "plant.arm.m2" = {{ distribution = "uniform", low = 0.9, high = 1.3 }}
        """
    a = draw_values(spec_of(base.format(seed=5, n=3000)), range(3000))
    b = draw_values(spec_of(base.format(seed=5, n=10)), range(10))
    c = draw_values(spec_of(base.format(seed=6, n=10)), range(10))
    for k in a:
        assert a[k][:10] == b[k]  # a longer sweep draws the same first values
        assert a[k][:10] != c[k]
    m1 = np.array(a["plant.arm.m1"])
    assert np.all((m1 > 0.96) & (m1 < 1.44)) and abs(m1.mean() - 1.2) < 0.01
    k = np.log10(a["plant.contact.stiffness"])
    assert np.all((k > 4) & (k < 6)) and abs(k.mean() - 5) < 0.05
    d = np.array(a["plant.contact.damping"])
    assert np.all((d >= 0) & (d <= 200)) and abs(np.median(d) - 100) < 8
    # another key added later does not change the draws of the others
    more = spec_of(base.format(seed=5, n=10) + '"plant.arm.l1" = { distribution = "relative", percent = 5 }\n')
    assert draw_values(more, range(10))["plant.arm.m1"] == b["plant.arm.m1"]
    # draw i from (seed, key, i) alone, across generator blocks
    assert uniforms(5, "x", [1500])[0] == uniforms(5, "x", np.arange(2000))[1500]


def test_nested_and_quoted_vary_tables_are_the_same_spec():
    a = spec_of("""
        name = "a"
        controllers = ["hinf"]
        [vary."plant.arm.m1"]
        values = [1.0, 1.2]
        """)
    b = spec_of("""
        name = "a"
        controllers = ["hinf"]
        [vary.plant.arm.m1]
        values = [1.0, 1.2]
        """)
    assert a.varied == b.varied and a.fingerprint() == b.fingerprint()


def test_list_valued_keys_get_the_value_in_every_entry():
    spec = spec_of("""
        name = "l"
        controllers = ["hinf"]
        samples = 2
        [vary]
        "plant.disturbance.amplitude" = { distribution = "relative", percent = 50 }
        """)
    v = draw_values(spec, range(2))["plant.disturbance.amplitude"]
    assert len(v[0]) == 2 and v[0][0] == v[0][1] and 1.5 < v[0][0] < 4.5


def test_shipped_specs_load_by_name():
    assert {"paper-uncertainty", "paper-map"} <= set(spec_names())
    pu = load_spec("paper-uncertainty")
    assert pu.samples == 1000 and pu.controllers == ("fl", "hinf", "hinf_nn") and pu.n_runs == 3000
    assert {v.key for v in pu.varied} >= {"plant.arm.m1", "plant.arm.l2", "plant.surface.delta_deg",
                                           "plant.contact.stiffness", "plant.contact.damping"}
    pm = load_spec("paper-map")
    assert pm.grid_keys == ["plant.contact.stiffness", "plant.arm.m2"] and pm.controllers == ("hinf", "hinf_nn")
    quick = load_spec("paper-uncertainty", samples=8, overrides=["simulation.t_final=0.5"])
    assert quick.n_runs == 24 and quick.base.simulation.t_final == 0.5
    # counts and overrides as NumPy gives them are Python's
    from hinfnn.sweep.backends import check_workers

    numpy_given = load_spec("paper-uncertainty", samples=np.int64(8), overrides={"simulation.t_final": np.float64(0.5)})
    assert numpy_given.n_runs == 24 and type(numpy_given.samples) is int and numpy_given.base == quick.base
    assert check_workers(np.int64(2)) == 2 and type(check_workers(np.int64(2))) is int
    for bad in (np.True_, 0, 1.0):
        with pytest.raises(ConfigError, match="--workers"):
            check_workers(bad)


BAD = [  # (spec body after the header, key named, words)
    ('[vary]\n"plant.arm.mm1" = { values = [1.0] }', "vary.plant.arm.mm1", "did you mean 'plant.arm.m1'"),
    ('[vary]\n"plant.arm.m1" = { distribution = "uniform", low = 1.0 }', "vary.plant.arm.m1.high", "is missing"),
    ('[vary]\n"plant.arm.m1" = { distribution = "uniform", low = 2.0, high = 1.0 }', "vary.plant.arm.m1.low",
     "below high"),
    ('[vary]\n"plant.arm.m1" = { distribution = "gaussian", std = 1 }', "vary.plant.arm.m1.distribution",
     "one of"),
    ('[vary]\n"plant.arm.m1" = { values = [1.0], distribution = "uniform", low = 1, high = 2 }',
     "vary.plant.arm.m1", "both"),
    ('[vary]\n"plant.arm.m1" = { linspace = [1.0, 2.0, 2.5] }', "vary.plant.arm.m1.linspace", "whole number"),
    ('[vary]\n"plant.contact.stiffness" = { logspace = [4, -6, 3] }', "vary.plant.contact.stiffness.logspace",
     "not exponents"),
    ('[vary]\n"plant.arm.m1" = { values = [1.0, -1.0] }', "vary.plant.arm.m1", "grid value -1"),
    ('[vary]\n"plant.arm.m1" = { distribution = "uniform", low = -1.0, high = 2.0 }', "vary.plant.arm.m1",
     "low end"),
    ('[vary]\n"plant.contact.damping" = { distribution = "relative", percent = 10 }',
     "vary.plant.contact.damping.percent", "base value"),
    ('[vary]\n"initial.elbow" = { distribution = "uniform", low = 0, high = 1 }',
     "vary.initial.elbow.distribution", "not a number"),
    ('[vary]\n"controller.kind" = { values = ["fl"] }', "vary.controller.kind", "controllers"),
    ('[vary]\n"plant.arm.m1" = { distribution = "normal", std = 0.1, mean = 1.0, scale = 2 }',
     "vary.plant.arm.m1.scale", "unknown key"),
    ('samples = 5\n[vary]\n"plant.arm.m1" = { values = [1.0, 1.2] }', "samples", "nothing is drawn"),
    ('metrics = ["rms_e_u"]', "metrics", "did you mean"),
    ('map_metric = "dissipation_holds"', "map_metric", "fraction"),
    ('seeed = 3', "seeed", "did you mean"),
    ('[set]\n"plant.arm.m1" = -2', "set.plant.arm.m1", "> 0"),
    ('[set]\n"simulation.dt" = 0.005\n"simulation.output_interval" = 0.01', "simulation.dt", "too large"),
    ('[vary]\n"plant.arm.m1" = { linspace = [2.0, -1.0, 4] }', "vary.plant.arm.m1", "grid value -1"),
    ('[vary]\n"plant.arm.m1" = { linspace = [1.0, 2.0, 100000] }\n"plant.arm.m2" = { linspace = [1.0, 2.0, 100000] }',
     "vary", "= 10,000,000,000 draws (10,000,000,000 runs with 1 controller), above the cap of 10,000,000 draws"),
    ('samples = 1000\n[vary]\n"plant.arm.m1" = { linspace = [1.0, 2.0, 100000] }\n'
     '"plant.arm.m2" = { distribution = "relative", percent = 10 }', "vary",
     "100,000 (plant.arm.m1) × 1,000 samples = 100,000,000 draws"),
    ('scenario = "ur5-table"\n[vary]\n"plant.arm.m1" = { values = [1.0, 2.0] }', "vary.plant.arm.m1",
     "not a key of the base scenario: plant.arm.model: model = 'urdf' does not take the key 'm1'"),
    ('[vary]\n"plant.arm.mm1" = { values = [1.0, 2.0] }', "vary.plant.arm.mm1", "did you mean 'plant.arm.m1'"),
]


@pytest.mark.parametrize("body,key,words", BAD)
def test_bad_specs_exit_2_naming_the_key(tmp_path, capsys, body, key, words):
    path = write(tmp_path, 'name = "bad"\ncontrollers = ["hinf"]\n' + body + "\n")
    assert cli.main(["sweep", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hinfnn: ConfigError: ") and "\n" not in err
    assert f" {key}: " in err or f" {key} " in err or f"{key}:" in err, err
    assert words in err, err
    assert not (tmp_path / "o").exists()


def test_cli_options_are_checked(tmp_path, capsys):
    path = write(tmp_path, SPEC)
    assert cli.main(["sweep", str(path), "--samples", "0"]) == 2
    assert "--samples" in capsys.readouterr().err
    assert cli.main(["sweep", str(path), "--resume", "--force"]) == 2
    assert cli.main(["sweep", str(path), "--address", "auto"]) == 2
    assert "--address" in capsys.readouterr().err
    for bad in (["--workers", "0"], ["--workers", "2", "--backend", "ray"]):
        assert cli.main(["sweep", str(path), *bad]) == 2
        assert "--workers" in capsys.readouterr().err
    assert cli.main(["sweep", "paper-uncertanty"]) == 2
    assert "did you mean 'paper-uncertainty'" in capsys.readouterr().err
    assert cli.main(["sweep", "--list"]) == 0
    assert "paper-map" in capsys.readouterr().out
    with pytest.raises(SystemExit) as ex:
        cli.main(["sweep", "--help"])
    assert ex.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text and "--resume" in text and "--address" in text and "docs/sweeps.md" in text
    assert "--workers" in text
    (tmp_path / "afile").write_text("x")
    assert cli.main(["sweep", str(path), "--out", str(tmp_path / "afile")]) == 2
    assert "not a folder" in capsys.readouterr().err


def test_a_grid_within_the_cap_is_counted_without_computing_it():
    spec = spec_of('name = "g"\ncontrollers = ["hinf"]\n[vary]\n"plant.arm.m1" = { linspace = [1.0, 2.0, 100000] }\n'
                   '"plant.arm.m2" = { logspace = [0.5, 2.0, 100] }\n')
    assert spec.points == 10_000_000 and spec.n_runs == 10_000_000
    assert [v.how.size for v in spec.varied] == [100_000, 100]


def test_the_sweep_says_how_many_runs_before_it_starts(tmp_path, capsys, monkeypatch):
    from hinfnn.sweep import run as sweep_run

    def stop(*args, **kwargs):
        raise ConfigError("stopped here", key="--test")

    monkeypatch.setattr(sweep_run, "run_sweep", stop)
    assert cli.main(["sweep", str(write(tmp_path, SPEC)), "--out", str(tmp_path / "o")]) == 2
    assert "hinfnn sweep: 4 runs: 1 grid point(s) × 4 sample(s) × 1 controller(s)" in capsys.readouterr().err


@pytest.mark.parametrize("address,words", [
    ("localhost:notaport", "must be 'auto' (the cluster this machine belongs to), HOST:PORT"),
    ("10.0.0.5", "HOST:PORT"),
    ("ray://10.0.0.5", "ray://HOST:PORT"),
    ("10.0.0.5:70000", "HOST:PORT"),
    ("ray://10.0.0.5:10001", "Ray Client, which needs pip install 'ray[client]'"),
])
def test_ray_addresses_are_checked_before_any_work(tmp_path, capsys, monkeypatch, address, words):
    import importlib.util

    real = importlib.util.find_spec
    # Ray present, Ray Client's grpc absent, whatever this machine has
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "grpc" else (object() if name == "ray" else real(name, *a)))
    path = write(tmp_path, SPEC)
    assert cli.main(["sweep", str(path), "--backend", "ray", "--address", address, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hinfnn: ConfigError: --address: ") and "\n" not in err, err
    assert repr(address) in err and words in err, err
    assert not (tmp_path / "o").exists()


def test_the_ray_backend_without_ray_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a))
    path = write(tmp_path, SPEC)
    assert cli.main(["sweep", str(path), "--backend", "ray", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "hinfnn: ConfigError: --backend: the ray backend needs Ray: pip install 'hinfnn[ray]'"
    assert not (tmp_path / "o").exists()


def test_batches_have_equal_sizes_per_group_and_fit_memory():
    checked = [{"run": i, "ok": i % 5 != 0, "group": "a" if i < 30 else "b", "samples": 10_001, "n_joints": 2,
                "reason": "x"} for i in range(40)]
    plan = plan_batches(checked, max_batch=10)
    assert [b.group for b in plan] == ["a"] * 3 + ["b"]
    assert {b.size for b in plan if b.group == "a"} == {8} and sum(len(b.runs) for b in plan) == 32
    assert all(len(b.runs) <= b.size for b in plan)
    assert batch_cap(10_001, 2, max_batch=1000, memory=2 * 2**30) < 500  # 3.4 MB a member: memory decides
    assert batch_cap(10_001, 2, max_batch=64, memory=64 * 2**30) == 64


# --- running ------------------------------------------------------------------------------------------


def test_table_has_one_row_per_run_with_every_metric(small):
    spec, folder, df = small
    assert len(df) == 4 and list(df["run"]) == [0, 1, 2, 3]
    assert df.attrs["complete"] and (df["status"] == "ok").all()
    for col in ["plant.arm.m1", "plant.contact.damping", "controller", "status", "reason", "t_fail",
                *metric_columns(2), "bounded", "held_contact", "out_of_contact_after", "tracked", "did_its_job"]:
        assert col in df.columns, col
    assert df["dissipation_holds"].dtype == "boolean"
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "complete" and manifest["n_batches"] == 2
    for name in ("results.parquet", "report.md", "outcomes.png", "distributions.png", "failures_by_parameter.png",
                 "sweep.toml", "scenario.toml", "plan.json"):
        assert (folder / name).exists(), name


def test_table_equals_individual_simulate_runs(small):
    spec, folder, df = small
    base = spec.base.to_dict()
    for i in (0, 3):
        row = df.iloc[i]
        values = {k: row[k] for k in ("plant.arm.m1", "plant.contact.damping")}
        sc = scenario_of(base, spec.base.source, values, "hinf")
        m = H.compute_metrics(sc.simulate("hinf"))
        for k, v in m.items():
            if k == "verdict":  # the verdicts are not columns of a sweep's table yet
                continue
            if k in PER_COORDINATE_METRICS:  # one list column
                assert list(row[k]) == pytest.approx(v, rel=1e-9, abs=1e-12), k
            elif isinstance(v, list):
                for j, x in enumerate(v):
                    assert row[f"{k}_{j + 1}"] == pytest.approx(x, rel=1e-9, abs=1e-12), k
            elif isinstance(v, bool) or v is None:
                assert (row[k] if not pd.isna(row[k]) else None) == v, k
            else:
                assert row[k] == pytest.approx(v, rel=1e-9, abs=1e-12, nan_ok=True), k


def test_resume_after_an_interruption_gives_the_same_table(small, tmp_path):
    spec, _, whole = small
    folder = tmp_path / "cut"

    def stop(batch):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, folder, max_batch=2, on_part=stop)
    partial = H.load_sweep(folder)
    assert not partial.attrs["complete"] and len(partial) == 2
    with pytest.raises(ConfigError, match="--resume"):
        run_sweep(spec, folder, max_batch=2)
    other = dataclasses.replace(spec, seed=4)
    with pytest.raises(ConfigError, match="different sweep"):
        run_sweep(other, folder, resume=True)
    # a sweep written in the older table format (held_contact over the whole run) is read, never resumed
    manifest_path = folder / "manifest.json"
    manifest = json.loads(manifest_path.read_text())
    manifest_path.write_text(json.dumps({**manifest, "format": "hinfnn-sweep-1"}))
    assert len(H.load_sweep(folder)) == 2
    with pytest.raises(ConfigError, match="older format 'hinfnn-sweep-1'"):
        run_sweep(spec, folder, resume=True)
    manifest_path.write_text(json.dumps(manifest))
    res = run_sweep(spec, folder, resume=True, report=False)
    assert res.simulated_now == 2 and res.already_done == 2
    pd.testing.assert_frame_equal(H.load_sweep(folder), whole, check_exact=True)
    assert len(json.loads((folder / "manifest.json").read_text())["sessions"]) == 2


def test_diverged_and_invalid_members_are_rows_not_crashes(tmp_path):
    spec = spec_of("""
        name = "grid"
        controllers = ["hinf"]
        [set]
        "simulation.t_final" = 0.05
        [vary]
        "plant.disturbance.amplitude" = { values = [3.0, 30000.0] }
        "initial.u1" = { values = [1.6902, 5.0] }
        """)
    res = run_sweep(spec, tmp_path / "g", max_batch=2)
    df = H.load_sweep(tmp_path / "g")
    assert list(df["status"]) == ["ok", "invalid", "diverged", "invalid"]
    bad = df.iloc[2]
    assert 0 < bad["t_fail"] < 0.05 and ("penetration" in bad["reason"] or "torque" in bad["reason"]
                                         or "non-finite" in bad["reason"])
    assert bad["partial"] and np.isfinite(bad["rms_e_u1"]) and not bad["bounded"]
    inv = df.iloc[1]
    assert inv["error_key"] == "initial.u1" and "reach" in inv["reason"] and pd.isna(inv["rms_e_u1"])
    assert pd.isna(inv["bounded"])
    assert list(df["plant.disturbance.amplitude"].iloc[2]) == [30000.0, 30000.0]
    c = res.counts["hinf"]
    assert (c["runs"], c["invalid"], c["simulated"], c["bounded"], c["diverged"]) == (4, 2, 2, 1, 1)
    ok = df.iloc[0]
    # contact is judged after the verdict's contact_after (0.5 s): a 0.05-s run is not judged
    assert pd.isna(ok["held_contact"]) and pd.isna(ok["did_its_job"]) and np.isnan(ok["out_of_contact_after"])
    report = (tmp_path / "g" / "report.md").read_text()
    assert "| H∞-only | 4 | 2 | 2 | 50.0 %" in report and "`initial.u1` 2" in report
    import matplotlib.image

    for name in ("map_rms_e_lam_last2s.png", "map_held_contact.png", "outcomes.png"):
        img = matplotlib.image.imread(tmp_path / "g" / name)
        assert img.shape[0] > 400 and img.shape[1] > 800


def test_cli_sweep_writes_everything_and_refuses_to_overwrite(tmp_path, capsys):
    path = write(tmp_path, SPEC)
    out = tmp_path / "o"
    assert cli.main(["sweep", str(path), "--out", str(out), "--samples", "2", "--batch-size", "2", "--quiet"]) == 0
    assert (out / "results.parquet").exists() and capsys.readouterr().out == ""
    assert cli.main(["sweep", str(path), "--out", str(out), "--samples", "2", "--batch-size", "2"]) == 0
    captured = capsys.readouterr()
    assert "--resume to continue" in captured.err and (tmp_path / "o-2" / "results.parquet").exists()
    assert "H∞-only" in captured.out and "results:" in captured.out
    # the folder's own sweep.toml resumes it (complete: nothing to do)
    assert cli.main(["sweep", str(out / "sweep.toml"), "--out", str(out), "--resume", "--quiet"]) == 0


def test_import_hinfnn_imports_neither_pandas_pyarrow_nor_ray():
    code = ("import sys, hinfnn, hinfnn.sweep; assert callable(hinfnn.load_sweep); "
            "bad = [m for m in ('pandas', 'pyarrow', 'ray') if m in sys.modules]; assert not bad, bad")
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    subprocess.run([sys.executable, "-c", code], check=True, env=env, timeout=120)


# --- kill and resume ---------------------------------------------------------------------------------

KILL_SPEC = SPEC.replace("samples = 4", "samples = 12").replace('"simulation.t_final" = 0.05',
                                                                 '"simulation.t_final" = 0.5')


def test_killed_sweep_resumes_to_the_same_table(tmp_path, cache):
    """A sweep killed with SIGKILL after its first part, then resumed by a new process, equals an
    uninterrupted run bit for bit."""
    path = write(tmp_path, KILL_SPEC)
    whole = tmp_path / "whole"
    run_sweep(spec_of(KILL_SPEC), whole, max_batch=2, report=False)
    out = tmp_path / "killed"
    env = {**os.environ, "PYTHONPATH": str(SRC), "HINFNN_CACHE_DIR": str(cache)}
    cmd = [sys.executable, "-m", "hinfnn.cli", "sweep", str(path), "--out", str(out), "--batch-size", "2", "--quiet"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    parts = out / "parts"
    deadline = time.monotonic() + 300
    try:
        while not list(parts.glob("batch-*.parquet")):
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    n_done = len(list(parts.glob("batch-*.parquet")))
    assert 1 <= n_done < 6, n_done  # killed in the middle
    assert not (out / "results.parquet").exists()
    done = subprocess.run(cmd + ["--resume"], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert not list(out.glob(".*.part")) and not list(parts.glob(".*.part"))
    pd.testing.assert_frame_equal(H.load_sweep(out), H.load_sweep(whole), check_exact=True)


# --- the local backend's worker processes ------------------------------------------------------------------


def test_local_worker_processes_give_the_same_table(small, tmp_path, monkeypatch, cache):
    """``workers=2``: the checks and the batches run in two spawned worker processes (not this one),
    the table equals the in-process sweep's bit for bit, and the progress never passes the total
    and ends at it."""
    spec, _, whole = small
    monkeypatch.setenv("HINFNN_CACHE_DIR", str(cache))  # the workers' compilation cache
    seen = []
    res = run_sweep(spec, tmp_path / "w2", max_batch=2, workers=2, report=False,
                    progress=lambda done, total, what="": seen.append((what, done, total)))
    assert res.simulated_now == 4
    pd.testing.assert_frame_equal(H.load_sweep(tmp_path / "w2"), whole, check_exact=True)
    manifest = json.loads((tmp_path / "w2" / "manifest.json").read_text())
    assert "2 worker processes" in manifest["sessions"][0]["backend"]
    assert os.getpid() not in {d["pid"] for d in manifest["done"].values()}
    sim = [(d, t) for what, d, t in seen if what == "simulating"]
    assert all(d <= t + 1e-9 for d, t in sim) and sim[-1][0] == sim[-1][1] == 4


def test_a_worker_that_dies_stops_the_sweep_and_resume_finishes_it(small, tmp_path, monkeypatch, cache):
    """A worker process killed in the middle of a batch (here it kills itself: the fault injection
    the Ray test uses) stops the sweep with an error that says so, instead of waiting for it
    forever; ``--resume`` then gives the uninterrupted table."""
    spec, _, whole = small
    marker = tmp_path / "fault-once"
    monkeypatch.setenv("HINFNN_SWEEP_FAULT_ONCE", str(marker))
    monkeypatch.setenv("HINFNN_CACHE_DIR", str(cache))
    with pytest.raises(RuntimeError, match="worker process of the local backend died"):
        run_sweep(spec, tmp_path / "died", max_batch=2, workers=2, report=False)
    assert marker.exists()
    res = run_sweep(spec, tmp_path / "died", max_batch=2, workers=2, resume=True, report=False)
    assert res.simulated_now + res.already_done == 4
    pd.testing.assert_frame_equal(H.load_sweep(tmp_path / "died"), whole, check_exact=True)


def test_worker_processes_are_started_only_when_worth_their_start(monkeypatch):
    """The local backend left to choose starts one worker per core when one process would simulate
    for a minute or more (a 1,000-draw UR5 sweep of 10-s runs), not for a quick trial; a plan for
    batches side by side gives each a share of the memory and cuts a group into at least as many
    batches while each keeps 8 runs; --workers is checked."""
    from hinfnn.sweep import backends

    monkeypatch.setattr(backends, "available_cores", lambda: 4)
    assert backends.auto_workers(1000, 100_000, 6) == 4
    assert backends.auto_workers(48, 2_000, 2) == 1
    assert backends.auto_workers(1000, 100_000, 2) == 4  # 250 s of the paper's arm
    monkeypatch.setattr(backends, "available_cores", lambda: 1)
    assert backends.auto_workers(1000, 100_000, 6) == 1
    checked = [{"run": i, "ok": True, "group": "a", "samples": 101, "n_joints": 2} for i in range(40)]
    assert [len(b.runs) for b in plan_batches(checked, max_batch=256, memory=2**34, parallel=2)] == [20, 20]
    assert [len(b.runs) for b in plan_batches(checked[:12], max_batch=256, memory=2**34, parallel=2)] == [12]
    assert [len(b.runs) for b in plan_batches(checked, max_batch=256, memory=2**34)] == [40]
    from hinfnn.sweep.worker import MEMORY_FRACTION, bytes_per_member

    memory = int(20 * bytes_per_member(101, 2) / MEMORY_FRACTION) + 1  # 20 members' records fit
    assert [len(b.runs) for b in plan_batches(checked, max_batch=256, memory=memory)] == [20, 20]
    assert [len(b.runs) for b in plan_batches(checked, max_batch=256, memory=memory, parallel=2)] == [10] * 4
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ConfigError, match="--workers"):
            backends.LocalBackend(bad)
    with pytest.raises(ConfigError, match="--workers"):
        backends.make_backend("ray", workers=2)


# --- Ray ---------------------------------------------------------------------------------------------------


def test_ray_backend_gives_the_same_table_and_retries_a_lost_worker(small, tmp_path, monkeypatch, cache):
    ray = pytest.importorskip("ray")
    spec, _, whole = small
    marker = tmp_path / "fault-once"
    monkeypatch.setenv("HINFNN_SWEEP_FAULT_ONCE", str(marker))  # the first task kills its worker
    monkeypatch.setenv("HINFNN_CACHE_DIR", str(cache))  # the workers' compilation cache
    import warnings

    with warnings.catch_warnings():  # Ray's fork + exec of its processes, which JAX's fork hook flags
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
        # one CPU: one task at a time, so two worker processes in all (the one the fault kills and
        # its replacement) instead of three; each imports hinfnn and traces the batch's program
        # before loading it from the cache. The test kept the machine busy for 20-22 core-seconds
        # instead of 28, which the other pytest-xdist worker needs; the retry and the table do not
        # depend on tasks running side by side.
        ray.init(num_cpus=1, include_dashboard=False, logging_level="error")
    try:
        res = run_sweep(spec, tmp_path / "ray", backend="ray", max_batch=2)
    finally:
        ray.shutdown()
    assert marker.exists()  # a worker died and its task was retried
    assert res.backend == "ray" and res.simulated_now == 4
    pd.testing.assert_frame_equal(H.load_sweep(tmp_path / "ray"), whole, check_exact=True)
    manifest = json.loads((tmp_path / "ray" / "manifest.json").read_text())
    assert "ray" in manifest["sessions"][0]["backend"]
    assert {d["pid"] for d in manifest["done"].values()} != {os.getpid()}


def test_docs_spec_tables_are_current():
    """docs/sweeps.md lists exactly the spec's keys (regenerate with hinfnn.sweep.spec.spec_table)."""
    from hinfnn.sweep.spec import spec_table

    doc = (Path(__file__).resolve().parents[1] / "docs" / "sweeps.md").read_text()
    assert spec_table() in doc


def test_a_folder_in_use_by_another_sweep_is_refused(small, tmp_path):
    """The folder's lock (hinfnn.io.FolderLock, the same as every result folder's) held by a live
    process: the sweep stops before anything runs; once released, the sweep runs there."""
    from hinfnn.io import FolderLock

    spec, _, _ = small
    folder = tmp_path / "busy"
    folder.mkdir()
    other = FolderLock(folder)
    assert other.acquire() is None  # another process holds the folder (this one's pid: alive)
    try:
        with pytest.raises(ConfigError, match="in use by another hinfnn process"):
            run_sweep(spec, folder, resume=True)
    finally:
        other.release()
    assert list(folder.iterdir()) == []
    res = run_sweep(spec, folder, max_batch=2, report=False)
    assert res.simulated_now == 4


def test_cli_interrupt_names_the_saved_batches_and_the_resume_command(tmp_path, monkeypatch, capsys):
    """Ctrl-C (or SIGTERM) during a sweep: exit 130 (143), and the one line says what is saved and
    the exact command that continues, not "no output was written"."""
    import hinfnn.sweep.run as sweep_run
    from hinfnn import _signals, cli

    for exc, code in ((KeyboardInterrupt(), 130), (_signals.Terminated(), 143)):
        def stop(*a, exc=exc, **k):
            raise exc

        monkeypatch.setattr(sweep_run, "run_sweep", stop)
        out = tmp_path / "sw"
        assert cli.main(["sweep", "paper-uncertainty", "--out", str(out), "--samples", "4", "--quiet"]) == code
        err = capsys.readouterr().err
        assert "no output was written" not in err
        assert f"continue with: hinfnn sweep paper-uncertainty --out {out} --resume --samples 4" in err


def test_force_replaces_only_a_sweep_folder(tmp_path, capsys):
    """--force on a folder holding files a sweep did not write is refused (exit 2, before anything
    runs) and the files are untouched; so is the current folder as --out."""
    mine = tmp_path / "mywork"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    assert cli.main(["sweep", "paper-uncertainty", "--out", str(mine), "--force", "--samples", "2", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "thesis.tex" in err and "--out" in err and len(err.strip().splitlines()) == 1
    assert (mine / "thesis.tex").read_text() == "years of work"
    (mine / "manifest.json").write_text("{}")  # looks like a sweep folder, still holds thesis.tex
    assert cli.main(["sweep", "paper-uncertainty", "--out", str(mine), "--force", "--samples", "2", "--quiet"]) == 2
    assert (mine / "thesis.tex").exists()
    assert cli.main(["sweep", "paper-uncertainty", "--out", ".", "--samples", "2", "--quiet"]) == 2


def test_checking_draws_of_an_arm_traces_its_path_programs_once():
    """A sweep checks every draw (``Scenario.check``), and the check solves the nominal inverse
    kinematics along the path: one traced program per scenario structure, whatever the drawn values
    (it was defined inside the check and traced again for each draw, 1.3 s per UR5 draw)."""
    from hinfnn import compiled

    base = H.load_scenario("ur5-table")
    program = compiled.path_joints.arm  # the KeptFunction of arms: one entry per argument structure
    before = len(program._entries)
    for i, m in enumerate((0.85, 1.05, 1.15)):
        base.with_overrides({"plant.arm.mass_scale": m, "plant.contact.stiffness": 4e4 + 3e4 * i})
    assert len(program._entries) == max(before, 1) and program.jitted._cache_size() <= 1
