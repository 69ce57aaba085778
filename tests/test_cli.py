"""The command line: files written, JSON schema, PNGs, overrides, exit codes, help texts."""

from __future__ import annotations

import json
import tomllib

import matplotlib.image
import numpy as np
import pytest

import hinfnn as H
from hinfnn import cli
import typing

from hinfnn.scenario import Matrix, Scenario
from hinfnn.scenario.schema import leaves

METRIC_KEYS = {"rms_e_u1", "max_abs_e_u1", "rms_e_u1_last2s", "rms_e_lam", "max_abs_e_lam",
               "rms_e_lam_last2s", "J_T", "peak_abs_tau", "rms_tau_last2s", "fraction_out_of_contact",
               "dissipation_lhs", "dissipation_rhs", "dissipation_holds"}
PAPER_FIGURES = ["fig3_u1_fl", "fig4_lambda_fl", "fig5_u1", "fig6_lambda", "fig7_tau1", "fig8_tau2", "fig9_J"]


def _check_metrics_json(path, names):
    doc = json.loads(path.read_text())
    assert set(doc) >= {"scenario", "runs"}
    assert [r["name"] for r in doc["runs"]] == names
    for r in doc["runs"]:
        assert set(r) >= {"name", "controller", "overrides", "metrics", "status", "t_fail"}
        assert r["controller"] in ("fl", "hinf", "hinf_nn")
        assert METRIC_KEYS <= set(r["metrics"])
        assert len(r["metrics"]["peak_abs_tau"]) == 2 and len(r["metrics"]["rms_tau_last2s"]) == 2
        assert isinstance(r["metrics"]["dissipation_holds"], bool)
    return doc


def _check_png(path):
    img = matplotlib.image.imread(path)
    assert img.ndim == 3 and img.shape[0] >= 600 and img.shape[1] >= 1000


def test_run_writes_every_file(tmp_path, capsys):
    out = tmp_path / "r"
    code = cli.main(["run", "paper", "--set", "simulation.t_final=0.2", "--set",
                     'controller.kind=["fl", "hinf", "hinf_nn"]', "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "RMS e_u1" in printed and "hinf_nn" in printed
    doc = _check_metrics_json(out / "metrics.json", ["fl", "hinf", "hinf_nn"])
    assert doc["scenario"]["simulation"]["t_final"] == 0.2
    for name in ("u1", "lambda", "tau", "J", "contact", "weights"):
        _check_png(out / f"{name}.png")
    sc = tomllib.loads((out / "scenario.toml").read_text())
    assert sc["controller"]["kind"] == ["fl", "hinf", "hinf_nn"]
    res = H.load(out)
    assert set(res.trajectories) == {"fl", "hinf", "hinf_nn"}
    tr = res.trajectories["hinf"]
    assert np.all(np.diff(tr.t) <= 1e-3 + 1e-12)  # decimated to at most 1 ms
    assert tr.t[-1] == pytest.approx(0.2)
    assert res.version == H.__version__
    assert not list(tmp_path.glob(".*"))  # no temporary folders left


def test_run_no_figures_writes_everything_but_the_pngs(tmp_path, capsys):
    """--no-figures: the same files and numbers as a run with figures, and no PNG; `hinfnn plot`
    draws the figures later from the saved result."""
    args = ["run", "paper", "--set", "simulation.t_final=0.05", "--set", 'controller.kind=["fl", "hinf_nn"]']
    assert cli.main(args + ["--out", str(tmp_path / "with")]) == 0
    assert cli.main(args + ["--out", str(tmp_path / "without"), "--no-figures"]) == 0
    printed = capsys.readouterr().out
    assert "(metrics.json, trajectory.npz, scenario.toml)" in printed
    with_files = {p.name for p in (tmp_path / "with").iterdir()}
    without_files = {p.name for p in (tmp_path / "without").iterdir()}
    assert not list((tmp_path / "without").glob("*.png"))
    assert without_files == {n for n in with_files if not n.endswith(".png")}
    a, b = H.load(tmp_path / "with"), H.load(tmp_path / "without")
    for name in ("fl", "hinf_nn"):
        ta, tb = a.trajectories[name], b.trajectories[name]
        assert ta.arrays.keys() == tb.arrays.keys()
        for k in ta.arrays:
            np.testing.assert_array_equal(ta.arrays[k], tb.arrays[k])
    da, db = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("with", "without"))
    assert da["command"] != db["command"]
    da.pop("command"), db.pop("command")
    assert da == db
    assert cli.main(["plot", str(tmp_path / "without")]) == 0
    for name in ("u1", "lambda", "tau", "J", "contact", "weights"):
        _check_png(tmp_path / "without" / f"{name}.png")


@pytest.mark.parametrize("args, code", [
    (["run", "paper", "--set", "simulation.t_final=0.01", "--no-figures"], 0),
    (["run", "paper", "--set", "simulation.dt=-1"], 2),
])
def test_program_ends_with_its_code_and_all_its_output(tmp_path, args, code):
    """The fast_exit device (hinfnn._devices): the `hinfnn` program leaves without the
    interpreter's teardown, with its exit code and everything it printed (stdout a pipe)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, JAX_PLATFORMS="cpu")  # the session's compilation cache (conftest.py)
    proc = subprocess.run([sys.executable, "-c", "import sys; from hinfnn.cli import main; sys.exit(main())",
                           *args, "--out", str(tmp_path / "out")], env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == code, proc.stderr
    if code == 0:
        assert proc.stdout.rstrip().endswith("scenario.toml)")  # the last line, flushed
        assert "RMS e_u1" in proc.stdout
    else:
        assert proc.stderr.startswith("hinfnn: ConfigError") and "simulation.dt" in proc.stderr


@pytest.mark.xdist_group("beyond")  # the reproduced fixture and the study's programs, shared with test_beyond
def test_reproduce_short_horizon_writes_every_file(reproduced, capsys):
    out, command = reproduced  # `hinfnn reproduce --set simulation.t_final=0.05` (conftest.py)
    names = ["fl", "hinf", "hinf_nn", "hinf_nn_printed", "hinf_exact"]
    _check_metrics_json(out / "metrics.json", names + [n + "_damped" for n in names])
    for stem in PAPER_FIGURES:
        _check_png(out / f"{stem}.png")
        _check_png(out / f"{stem}_damped.png")
    report = (out / "report.md").read_text()
    for needle in ("## Claims", "held", "paper-conventions.md", "fig5_u1.png", "### Summary", "10 runs, each 0.05 s",
                   f"Command: `{command}`"):
        assert needle in report
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["command"] == command
    assert (out / ".hinfnn-result").exists()
    assert (out / "scenario.toml").exists() and (out / "trajectory.npz").exists()
    # writing again without --force picks a new numbered folder and says so; --paper-only: no beyond part
    assert cli.main(["reproduce", "--paper-only", "--set", "simulation.t_final=0.02", "--out", str(out)]) == 0
    assert f"{out.name}-2" in capsys.readouterr().err
    again = out.parent / f"{out.name}-2"
    assert (again / "report.md").exists() and (again / "fig5_u1.png").exists()
    doc = json.loads((again / "metrics.json").read_text())
    assert "beyond" not in doc and not (again / "beyond.npz").exists() and not list(again.glob("beyond_*.png"))
    assert "Beyond the paper" not in (again / "report.md").read_text()


def _alternative(key, tp, meta, value):
    """A different valid-typed value for every kind of key."""
    if tp is float:
        lo = meta.get("gt") if meta.get("gt") is not None else meta.get("ge")
        hi = meta.get("lt") if meta.get("lt") is not None else meta.get("le")
        for cand in (value * 1.1, value * 0.9, value + 0.125, value - 0.125):
            if cand != value and (lo is None or cand > lo) and (hi is None or cand < hi):
                return cand
        raise AssertionError(key)
    if tp is int:
        return value + 1
    if tp is bool:
        return not value
    if typing.get_origin(tp) is typing.Literal:
        choices = typing.get_args(tp)
        return next((c for c in choices if c != value), value)
    if tp is str:
        return value + "-x"
    if tp is Matrix:
        return [[2.0, 0.0], [0.0, 2.0]] if isinstance(value, tuple) else value * 1.5
    if typing.get_origin(tp) is tuple:
        return [v + 0.5 for v in value]
    args = typing.get_args(tp)
    if float in args:  # beta_lam: a number or "min"; tau_f: a number <= 1 or "auto"
        hi = meta.get("lt") if meta.get("lt") is not None else meta.get("le")
        return 5.0 if hi is None or 5.0 < hi else hi / 2
    if int in args:  # controller.force_filter.order: an integer or "design"; controller.sensor.delay: or "declared"
        return 1 if value != 1 else 2
    if str in args:  # controller.kind: a name or a list
        return ["fl", "hinf"]
    raise AssertionError((key, tp))


def _same(got, new):
    if isinstance(got, tuple):
        return [list(r) if isinstance(r, tuple) else r for r in got] == new
    return got == new or (isinstance(new, float) and got == pytest.approx(new))


def test_every_key_can_be_overridden_and_appears_in_scenario_toml():
    base = Scenario.load("paper", check=False)
    seen = 0
    for key, tp, meta, value in leaves(base):
        if key.rsplit(".", 1)[-1] in ("model", "kind", "engine", "map") and typing.get_origin(tp) is typing.Literal:
            continue  # a registry key: another kind takes other keys (tests/test_arms.py, test_seams.py)
        new = _alternative(key, tp, meta, value)
        if new == value:
            continue
        if key.startswith("controller.network_f.centre_"):
            sc = Scenario.load("paper", {"controller.network_f.preset": "custom", key: new}, check=False)
        else:
            sc = Scenario.load("paper", {key: new}, check=False)
        back = Scenario.from_dict(tomllib.loads(sc.to_toml()), check=False)
        assert _same(back.get(key), new), key
        seen += 1
    assert seen >= 60


def test_every_key_override_through_the_cli_shows_in_scenario_toml(tmp_path):
    out = tmp_path / "o"
    code = cli.main(["run", "paper", "--set", "simulation.t_final=0.01", "--set", "controller.kind=hinf",
                     "--set", "plant.contact.damping=200", "--set", "reference.lam_offset=55",
                     "--out", str(out), "--quiet", "--no-figures"])
    assert code == 0
    sc = tomllib.loads((out / "scenario.toml").read_text())
    assert sc["plant"]["contact"]["damping"] == 200.0 and sc["reference"]["lam_offset"] == 55.0
    assert sc["controller"]["kind"] == "hinf"
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["runs"][0]["overrides"]["plant.contact.damping"] == 200


@pytest.mark.parametrize("override,key,words", [
    ("plant.contact.dampnig=3", "plant.contact.dampnig", ["unknown key", "plant.contact.damping"]),
    ("controler.kind=hinf", "controler.kind", ["unknown key", "controller.kind"]),
    ("plant.arm.m1=heavy", "plant.arm.m1", ["must be"]),
    ("plant.arm.m1=-1.2", "plant.arm.m1", ["> 0", "-1.2"]),
    ("simulation.dt=0", "simulation.dt", ["> 0"]),
    ("simulation.dt=-1e-4", "simulation.dt", ["> 0"]),
    ("controller.gains.rho=0.1", "controller.gains.rho", ["no stabilising solution", "0.4975"]),
    ("controller.gains.beta_lam=1.0", "controller.gains.beta_lam", ["below its bound", "1.7777"]),
    ("controller.kind=hinff", "controller.kind", ["hinf"]),
    ("simulation.t_final=0.00035", "simulation.t_final", ["whole number of steps"]),
    ("initial.u1=5", "initial.u1", ["reach"]),
    ("plant.arm.m1=nan", "plant.arm.m1", ["finite"]),
])
def test_bad_input_exits_2_with_one_line_naming_the_key(tmp_path, capsys, override, key, words):
    code = cli.main(["run", "paper", "--set", override, "--out", str(tmp_path / "x")])
    if code != 2:
        raise AssertionError(capsys.readouterr())
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert key in err
    for w in words:
        assert w in err
    assert not (tmp_path / "x").exists()


def test_dt_not_dividing_the_disturbance_half_period(tmp_path, capsys):
    code = cli.main(["run", "paper", "--set", "simulation.dt=3e-4", "--set", "simulation.t_final=0.3",
                     "--out", str(tmp_path / "x")])
    assert code == 2
    err = capsys.readouterr().err
    assert "simulation.dt" in err and "half-period 0.5 s" in err


def test_missing_file_and_bad_toml_exit_2(tmp_path, capsys):
    assert cli.main(["run", str(tmp_path / "nope.toml")]) == 2
    bad = tmp_path / "bad.toml"
    bad.write_text("[plant\nm1 = 1")
    assert cli.main(["run", str(bad)]) == 2
    assert "not valid TOML" in capsys.readouterr().err


def test_an_empty_base_or_name_exits_2_saying_so(tmp_path, capsys):
    empty = tmp_path / "empty.toml"
    empty.write_text('base = ""\n')
    assert cli.main(["run", str(empty), "--out", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err.strip() == \
        "hinfnn: ConfigError: base: '' is empty; give a scenario name (hinfnn scenarios) or a .toml file"
    assert cli.main(["run", "", "--out", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err.strip() == \
        "hinfnn: ConfigError: '' is empty; give a scenario name (hinfnn scenarios) or a .toml file"
    assert cli.main(["sweep", " ", "--out", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err.strip() == \
        "hinfnn: ConfigError: ' ' is empty; give a sweep spec name (hinfnn sweep --list) or a .toml file"
    assert not (tmp_path / "x").exists()


def test_a_utf8_byte_order_mark_is_skipped(tmp_path):
    from hinfnn.sweep import load_spec
    from hinfnn.workflows.run import result_name

    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + 'base = "paper"\nname = "bommed"\n[plant.arm]\nm1 = 1.25\n'.encode())
    sc = Scenario.load(str(path), check=False)
    assert (sc.name, sc.plant.arm.m1) == ("bommed", 1.25) and result_name(sc) == "bommed"
    spec = tmp_path / "spec.toml"
    spec.write_bytes(b"\xef\xbb\xbf" + f'name = "b"\nscenario = "{path.name}"\ncontrollers = ["hinf"]\n'.encode())
    assert load_spec(str(spec)).base.plant.arm.m1 == 1.25


def test_compare_writes_one_run_per_value(tmp_path, capsys):
    """`hinfnn compare`: one run per value of the one varied key, compare.md with a row each and the
    ratios against the first value; refused (exit 2, before anything runs) with two varied keys or
    a value out of range."""
    out = tmp_path / "cmp"
    assert cli.main(["compare", "paper", "--set", "plant.contact.damping=0,200", "--set", "controller.kind=hinf",
                     "--set", "simulation.t_final=0.05", "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["compare"]["key"] == "plant.contact.damping" and doc["compare"]["values"] == [0, 200]
    assert len(doc["runs"]) == 2 and doc["runs"][0]["metrics"] != doc["runs"][1]["metrics"]
    table = (out / "compare.md").read_text()
    assert table.count("\n| ") >= 3 and "×" in table
    assert (out / ".hinfnn-result").exists() and (out / "trajectory.npz").exists()
    capsys.readouterr()
    for argv, key in ((["--set", "plant.contact.damping=0,200", "--set", "plant.arm.m2=1,2"], "--set"),
                      (["--set", "plant.contact.damping=0,-5"], "plant.contact.damping")):
        assert cli.main(["compare", "paper", *argv, "--out", str(tmp_path / "no")]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and key in err
    assert not (tmp_path / "no").exists()


def test_help_texts_are_complete(capsys):
    for argv in (["--help"], ["run", "--help"], ["reproduce", "--help"], ["keys", "--help"],
                 ["scenarios", "--help"], ["show", "--help"], ["plot", "--help"], ["export", "--help"],
                 ["cache", "--help"], ["design", "--help"], ["compare", "--help"], ["sweep", "--help"]):
        with pytest.raises(SystemExit) as ex:
            cli.main(argv)
        assert ex.value.code == 0
        text = capsys.readouterr().out
        assert "example" in text, argv
    assert cli.main(["keys"]) == 0
    keys = capsys.readouterr().out
    assert "plant.contact.damping" in keys and "controller.gains.beta_lam" in keys


def test_docs_scenario_table_is_current():
    """docs/scenarios.md lists exactly the schema's keys (regenerate with hinfnn.scenario.schema_table)."""
    from pathlib import Path

    from hinfnn.scenario import schema_table

    doc = (Path(__file__).resolve().parents[1] / "docs" / "scenarios.md").read_text()
    assert schema_table() in doc


def test_progress_time_left_counts_the_pace_after_the_first_chunk(monkeypatch):
    """The progress lines of a log file: the time left is the steps left at the rate since the
    first call (which follows the first chunk's compile), none before a second call; the end is
    said once; a new part of the work (another total) measures its own rate."""
    import io
    import types

    from hinfnn.cli import _common

    clock = [0.0]
    monkeypatch.setattr(_common, "time", types.SimpleNamespace(perf_counter=lambda: clock[0]))
    out = io.StringIO()
    p = _common.Progress(False, "simulating", stream=out)
    for t, done in ((11.0, 2), (24.0, 28), (37.0, 54)):  # 11 s of compiling, then 2 steps/s
        clock[0] = t
        p(done, 100)
    clock[0] = 38.0
    p(100, 100)
    p(100, 100)  # the part's end, said once
    clock[0] = 50.0
    p(10, 40, "second part")  # a new part: its first call, no rate yet (and under 3 s: no line)
    clock[0] = 61.0
    p(20, 40)  # 10 steps in 11 s
    lines = out.getvalue().splitlines()
    assert lines == ["simulating:   2.0 %  (11 s)",
                     "simulating:  28.0 %  (24 s, about 36 s left)",
                     "simulating:  54.0 %  (37 s, about 23 s left)",
                     "simulating: 100.0 %  (38 s)",
                     "simulating:  50.0 %  (11 s, about 22 s left)"], lines
