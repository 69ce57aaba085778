"""Robustness: validation before running, divergence, atomic results, saved runs loading back.

The issue's four requirements, tested from the outside (library API and the ``hinfnn`` CLI):

* every bad scenario value is a ConfigError/DesignError naming the key (never another
  exception), and the CLI prints it on one line and exits 2 (hypothesis, 500 mutations of
  paper.toml, in-process: nothing is simulated);
* a diverging run stops with SimulationError (single run) or is marked "diverged" in
  metrics.json while the other runs of the batch finish;
* SIGINT/SIGTERM/SIGKILL during ``hinfnn run`` never leave a partial or damaged result
  (subprocesses), a non-empty output folder is kept unless --force;
* results load back (hinfnn.load) with their scenario and version, bit-identically when a run is
  repeated from its scenario.toml; truncated, corrupted and foreign files are LoadErrors.
"""

from __future__ import annotations

import contextlib
import copy
import datetime
import io
import json
import math
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from children import interruptible
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hinfnn as H
from hinfnn import cli
from hinfnn.io import FORMAT, load_npz, trajectory_npz_bytes
import typing

from hinfnn.scenario import Scenario, keys
from hinfnn.scenario.schema import leaves

HINFNN = Path(sys.executable).parent / "hinfnn"
PAPER_TEXT = (resources.files("hinfnn.scenario") / "files" / "paper.toml").read_text(encoding="utf-8")
KEYS = [k for k, *_ in keys()]


def paper_raw() -> dict:
    return tomllib.loads(PAPER_TEXT)


SECTIONS = sorted({k.rsplit(".", i)[0] for k in KEYS for i in range(1, k.count(".") + 1)})


def simulate_many(named):
    """[(name, scenario, kind)] -> {name: Trajectory}, batched as the CLI does."""
    return H.simulate_many([sc.run(kind, name) for name, sc, kind in named])


def _run_cli(argv) -> tuple[int, str, str]:
    """``hinfnn ARGV`` in this process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def _npz_arrays(path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _assert_same_arrays(a: dict, b: dict):
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
        assert np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k


def _hidden_leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".partial-" in p.name or ".old-" in p.name
                  or p.name.endswith(".part"))


# =================================================================================================
# 1. Validation before running: mutations of paper.toml
# =================================================================================================

NAN, INF = float("nan"), float("inf")
MATRICES = [
    [[1.0]], [[0.495]], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],  # wrong shapes
    [[0.495, 0.0], [0.0, 0.495]],  # the paper's printed R_p (2x2)
    [[1.0, 2.0], [0.0, 1.0]],  # not symmetric
    [[1.0, 0.0], [0.0, -1.0]], [[0.0, 0.0], [0.0, 0.0]],  # not positive definite
    [[1.0], [1.0, 2.0]], [[1.0, 0.0]], [[]], [1.0, 1.0],  # ragged / not square / 1-D
    [[NAN, 0.0], [0.0, 1.0]], [[INF, 0.0], [0.0, 1.0]], [["a", 0.0], [0.0, 1.0]],
]
SPECIAL = [
    NAN, INF, -INF, 0, 0.0, -0.0, -1, -1.0, 1e300, -1e300, 1e12, 1e30, 5e-324, 1e-310, 1e-200, 1e-9,
    2**63 - 1, -(2**63), 40.5, True, False, "", "abc", "min", "MIN", "custom", "paper-printed",
    "hinf", "fl", "unit", "sampled", "down", "two_link", "nan", "1.0",
    [], [1.0], [1.0, 2.0], [1.0, 2.0, 3.0], [NAN, 1.0], [1.0, "x"], ["fl", "fl"], ["hinf", 3], [["fl"]],
    ["fl", "hinf", "hinf_nn"], ["fl", "HINF"], {}, {"x": 1.0}, {"m1": 1.0},
    datetime.date(2020, 1, 1), datetime.time(12, 0),
] + MATRICES
CHOICES = sorted({c for _, tp, _, _ in leaves(Scenario.load("paper", check=False))
                  for a in (typing.get_args(tp) if typing.get_origin(tp) is not typing.Literal else (tp,))
                  if typing.get_origin(a) is typing.Literal for c in typing.get_args(a)})
#: key names the property test adds (line breaks in key names are tested on their own)
PRINTABLE = st.characters(exclude_categories=("Cs", "Cc", "Zl", "Zp"))
UNKNOWN_NAMES = ["foo", "m3", "dampnig", "Kp", "", "Q_P", "centres", "m1", "t_final", "kind", "preset",
                 "plant", "gains", "a.b", "ünïcode"]


def _paths(node, prefix=()):
    for key, value in node.items():
        path = prefix + (key,)
        yield path
        if isinstance(value, dict):
            yield from _paths(value, path)
        elif isinstance(value, list):
            for i, item in enumerate(value):
                yield path + (i,)
                if isinstance(item, list):
                    for j in range(len(item)):
                        yield path + (i, j)


PATHS = list(_paths(paper_raw()))
#: paths where the interesting checks live, drawn more often than the rest
FOCUS = [p for p in PATHS if p[0] in ("controller", "simulation") or p[-1] in ("u1", "period", "phase", "l1")]


def _dotted(path) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else part)
    return out


def _get(data, path):
    node = data
    for part in path:
        node = node[part]
    return node


def _numeric_values(orig):
    if isinstance(orig, bool) or not isinstance(orig, (int, float)):
        return st.nothing()
    return st.one_of(
        st.just(-orig), st.just(float(orig)), st.just(int(orig)) if math.isfinite(orig) else st.nothing(),
        st.integers(-330, 330).map(lambda e: orig * float(f"1e{e}")),
        st.floats(-3.0, 3.0).map(lambda f: orig * f),
        st.floats(-1e-6, 1e-6).map(lambda f: orig * (1 + f)),
    )


def _values(orig):
    """Bad (and some good) replacement values for a value that was ``orig``."""
    return st.one_of(
        st.sampled_from(SPECIAL), st.sampled_from(CHOICES), _numeric_values(orig),
        st.floats(), st.integers(-(2**63), 2**63 - 1), st.text(max_size=6),
        st.lists(st.floats(), max_size=3),
    )


@st.composite
def mutation(draw):
    """One mutation: ("set", path, value), ("delete", path, None), ("add", section + (name,), value),
    ("custom_centres", network, (key, value)) or ("dt", None, value)."""
    op = draw(st.sampled_from(["set", "set", "set", "set", "delete", "add", "custom_centres", "dt"]))
    if op in ("set", "delete"):
        path = draw(st.one_of(st.sampled_from(PATHS), st.sampled_from(FOCUS)))
        if op == "delete":
            return ("delete", path, None)
        return ("set", path, draw(_values(_get(paper_raw(), path))))
    if op == "add":
        section = draw(st.sampled_from([""] + SECTIONS))
        name = draw(st.one_of(st.sampled_from(UNKNOWN_NAMES), st.text(PRINTABLE, min_size=1, max_size=5)))
        if section == "" and name in ("base", ""):
            name = "bases"  # a top-level `base` is the inheritance key (tested on its own)
        path = tuple(section.split(".")) + (name,) if section else (name,)
        return ("add", path, draw(st.one_of(st.sampled_from(SPECIAL), st.floats())))
    if op == "custom_centres":
        net = draw(st.sampled_from(["network_p", "network_f"]))
        key = draw(st.sampled_from(["centre_start", "centre_step", "centre_count"]))
        value = draw(st.sampled_from([0, 0.0, -0.5, -1, 1e-320, 1e-12, NAN, INF, -INF, 5001, 40.5, 1e300, 1e6,
                                      -1e6, 5000, 1, 2]))
        return ("custom_centres", net, (key, value))
    # dt against t_final, the disturbance's half-period, control_period, output_interval
    return ("dt", None, draw(st.sampled_from([3e-4, 7e-5, 2e-3, 0.1, 0.2, 1e-310, 5e-324, 1e-300, 0.0, -1e-4,
                                               1.5e-4, 2.5e-4, 1e-3, 5e-5])))


def apply_mutation(data: dict, mut) -> None:
    op, path, value = mut
    if op == "custom_centres":
        nets = data.get("controller")
        if isinstance(nets, dict) and isinstance(nets.get(path), dict):
            if path == "network_f":
                nets[path]["preset"] = "custom"
            nets[path][value[0]] = value[1]
        return
    if op == "dt":
        if isinstance(data.get("simulation"), dict):
            data["simulation"]["dt"] = value
        return
    try:
        parent = _get(data, path[:-1])
    except (KeyError, IndexError, TypeError):
        return  # an earlier mutation removed or replaced the parent
    last = path[-1]
    if isinstance(parent, dict) and isinstance(last, str):
        if op == "delete":
            parent.pop(last, None)
        else:
            parent[last] = copy.deepcopy(value)
    elif isinstance(parent, list) and isinstance(last, int) and last < len(parent):
        if op == "delete":
            del parent[last]
        else:
            parent[last] = copy.deepcopy(value)


def _library_error(call):
    """Run ``call``; return the ConfigError/DesignError it raised, or None. Any other exception
    propagates and fails the test."""
    try:
        call()
    except (H.ConfigError, H.DesignError) as err:
        return err
    return None


def _check_cli_line(code, err_text, err, argv):
    lines = err_text.strip().splitlines()
    assert code == 2, (argv, code, err_text)
    assert len(lines) == 1, (argv, err_text)
    assert lines[0] == f"hinfnn: {type(err).__name__}: {err}", (lines[0], str(err))
    assert "Traceback" not in err_text


def _key_is_reasonable(key: str, muts) -> bool:
    """The error names a real key or section, an index into one, a network's centres, or an
    (unknown) key a mutation added."""
    base = re.sub(r"(\[\d+\])+$", "", key)
    if base in KEYS or base in SECTIONS:
        return True
    if re.fullmatch(r"controller\.network_[pf]\.centres", base):
        return True
    # an unknown key the mutations put in (added, or inside a table they set)
    return any(op in ("add", "set") and base.startswith(_dotted(path)) for op, path, _ in muts)


def _inline_toml(value):
    """``value`` as an inline TOML value (for --set), or None."""
    if isinstance(value, dict):
        return None
    text = tomli_w.dumps({"v": value})
    if text.count("\n") != 1 or not text.startswith("v = "):
        return None
    return text[4:].strip()


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(muts=st.lists(mutation(), min_size=1, max_size=3))
def test_mutated_paper_scenario_raises_only_config_or_design_error_and_cli_exits_2(muts):
    """Random mutations of paper.toml (wrong types, missing and unknown keys, NaN/inf, negative,
    zero, tiny and huge values, wrong-length lists, wrong-shape matrices, bad centres, dt that
    does not divide t_final or the disturbance's half-period ...).

    Library: Scenario.from_dict on the mutated dict and Scenario.load on the same data written as
    TOML raise the same ConfigError/DesignError (with a key) or nothing. CLI: `hinfnn run FILE`
    exits 2 with exactly one line "hinfnn: <Error>: <key>: ..." for every invalid one (valid ones
    are not run). A single-key mutation is also given as `--set key=value` to the paper scenario.
    """
    raw = paper_raw()
    for m in muts:
        apply_mutation(raw, m)
    err = _library_error(lambda: Scenario.from_dict(copy.deepcopy(raw)))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mutated.toml"
        path.write_text(tomli_w.dumps(raw), encoding="utf-8")
        err_file = _library_error(lambda: Scenario.load(path))
        # the same verdict; the same error for one mutation (with several, the TOML writer's key
        # order may decide which one is reported first)
        assert (err_file is None) == (err is None), (err, err_file)
        if len(muts) == 1:
            assert type(err_file) is type(err) and str(err_file) == str(err), (err, err_file)
        err = err_file
        if err is not None:
            assert err.key, f"{type(err).__name__} without a key: {err}"
            assert _key_is_reasonable(err.key, muts), err
            assert err.key in str(err)
            if len(muts) == 1 and muts[0][0] in ("set", "delete", "add"):
                schema_err = _library_error(lambda: Scenario.from_dict(copy.deepcopy(raw), check=False))
                if schema_err is not None:  # a type/range/missing/unknown error: at the mutated key
                    mutated = _dotted(muts[0][1])
                    assert schema_err.key.startswith(mutated) or mutated.startswith(schema_err.key), \
                        (mutated, schema_err)
            out = Path(tmp) / "out"
            argv = ["run", path, "--out", out]
            code, _, text = _run_cli(argv)
            _check_cli_line(code, text, err, argv)
            assert not out.exists()
            assert _hidden_leftovers(Path(tmp)) == []
        # the same single change as a command-line override of the paper scenario
        if len(muts) == 1 and muts[0][0] == "set" and _dotted(muts[0][1]) in KEYS:
            inline = _inline_toml(muts[0][2])
            if inline is not None:
                item = f"{_dotted(muts[0][1])}={inline}"
                err_set = _library_error(lambda: Scenario.load("paper", [item]))
                if err_set is not None:
                    assert err_set.key, err_set
                    out = Path(tmp) / "out_set"
                    argv = ["run", "paper", "--set", item, "--out", out]
                    code, _, text = _run_cli(argv)
                    _check_cli_line(code, text, err_set, argv)
                    assert not out.exists()


# Hand-picked bad inputs through the CLI: (overrides, key named in the one-line message, words).
BAD_INPUTS = [
    (["plant.arm.m1=0"], "plant.arm.m1", ["> 0", "got 0"]),
    (["plant.arm.l2=-0.5"], "plant.arm.l2", ["-0.5"]),
    (["plant.contact.stiffness=-1e5"], "plant.contact.stiffness", ["> 0"]),
    (["plant.contact.stiffness=1e300"], "plant.contact.stiffness", ["1e+300"]),
    (["plant.contact.stiffness=1e9"], "simulation.dt", ["too large for the contact"]),
    (["plant.contact.damping=inf"], "plant.contact.damping", ["finite"]),
    (["plant.disturbance.amplitude=[3.0]"], "plant.disturbance.amplitude", ["list of 2 numbers"]),
    (["plant.disturbance.amplitude=[3.0, nan]"], "plant.disturbance.amplitude[1]", ["finite"]),
    (["plant.disturbance.period=0.0007"], "simulation.dt", ["half-period 0.00035"]),
    (["plant.disturbance.period=5e-324"], "simulation.dt", ["half-period"]),
    (["plant.disturbance.phase=0.00005"], "plant.disturbance.phase", ["multiple of dt"]),
    (["nominal.surface.scaling=units"], "nominal.surface.scaling", ["'unit'"]),
    (["controller.kind=[]"], "controller.kind", ["one of"]),
    (['controller.kind=["fl","fl"]'], "controller.kind", ["twice"]),
    (["controller.augmented=1"], "controller.augmented", ["true or false"]),
    (["controller.gains.rho=-0.6"], "controller.gains.rho", ["> 0"]),
    (["controller.gains.alpha_lam=0.3"], "controller.gains.alpha_lam", ["must exceed", "0.36"]),
    (["controller.gains.alpha_z=4", "controller.gains.beta_lam=2"], "controller.gains.beta_lam",
     ["below its bound", "4.55556"]),
    (["controller.gains.alpha_z=0.5"], "controller.gains.alpha_lam", ["must exceed", "1.44"]),
    (["controller.gains.beta_lam=max"], "controller.gains.beta_lam", ['"min" or a number']),
    (["controller.augmented=true", "controller.gains.rho=0.1"], "controller.gains.rho",
     ["eq. (40)", "rho > 0.7036"]),
    (["controller.gains.R_p=500", "controller.gains.rho=0.1"], "controller.gains.rho", ["eq. (35)", "rho > 15.81"]),
    (["controller.gains.Q_p=[[1,0,0],[0,1,0],[0,0,1]]"], "controller.gains.Q_p", ["2x2", "(3, 3)"]),
    (["controller.gains.Q_p=[[1,2],[0,1]]"], "controller.gains.Q_p", ["symmetric"]),
    (["controller.gains.Q_p=[[1,0],[0,-1]]"], "controller.gains.Q_p", ["positive definite"]),
    (["controller.gains.R_p=[[0.495,0],[0,0.495]]"], "controller.gains.R_p", ["1x1", "misprint"]),
    (["controller.gains.R_p=[[1],[1,2]]"], "controller.gains.R_p", ["square matrix"]),
    (["controller.gains.K_p=[18, 18]"], "controller.gains.K_p", ["a number"]),
    (["controller.network_p.centre_count=0"], "controller.network_p.centre_count", [">= 1"]),
    (["controller.network_p.centre_count=40.5"], "controller.network_p.centre_count", ["integer"]),
    (["controller.network_p.centre_step=-0.05"], "controller.network_p.centre_step", ["> 0"]),
    (["controller.network_p.centre_start=nan"], "controller.network_p.centre_start", ["finite"]),
    (["controller.network_f.centre_step=0.05"], "controller.network_f.centre_step",
     ["conflicts with preset", "custom"]),
    (["controller.network_f.preset=custom", "controller.network_f.centre_start=1e6",
      "controller.network_f.centre_step=1e-12"], "controller.network_f.centres", ["increasing"]),
    (["controller.network_f.preset=paper"], "controller.network_f.preset", ["paper-likely"]),
    (["controller.network_p.projection=true", "controller.network_p.radius=0"],
     "controller.network_p.radius", ["> 0"]),
    (["reference.u1_period=0"], "reference.u1_period", ["> 0"]),
    (["initial.u1=2.5"], "initial.u1", ["reach"]),
    (["nominal.arm.l2=1e-9"], "initial.u1", ["singular", "(A1)"]),
    (["initial.elbow=sideways"], "initial.elbow", ["'up'"]),
    (["simulation.t_final=-1"], "simulation.t_final", ["> 0"]),
    (["simulation.t_final=inf"], "simulation.t_final", ["finite"]),
    (["simulation.dt=0.0003"], "simulation.t_final", ["whole number of steps"]),
    (["simulation.dt=0.0003", "simulation.t_final=0.3"], "simulation.dt", ["half-period 0.5"]),
    (["simulation.dt=1e-310"], "simulation.", []),
    (["simulation.control=sampled", "simulation.control_period=0.00015"], "simulation.control_period",
     ["multiple of dt"]),
    (["simulation.output_interval=0.00001"], "simulation.output_interval", [">= dt"]),
    (["simulation.torque_limit=0"], "simulation.torque_limit", ["> 0"]),
    (["simulation.penetration_limit=-0.05"], "simulation.penetration_limit", ["> 0"]),
    (["simulation.dtt=1e-4"], "simulation.dtt", ["unknown key", "simulation.dt"]),
    (["simulation=3"], "simulation", ["section"]),
    (["plant.arm.m1"], None, ["dotted.key=value"]),
    (["plant.arm.m1="], "plant.arm.m1", ["needs a value"]),
    (["controller.gains.rho=1e-200"], "controller.gains.", []),
    (["controller.gains.R_p=1e-320"], "controller.gains.", []),
    (['controller.kind=["fl","hinf_nn"]', "controller.gains.rho=1e-160"], "controller.gains.", []),
]


@pytest.mark.parametrize("overrides,key,words", BAD_INPUTS, ids=[" ".join(o) for o, _, _ in BAD_INPUTS])
def test_hand_picked_bad_input_exits_2_with_one_line_naming_the_key(tmp_path, overrides, key, words):
    # the library must reject it (so the CLI below never starts a 10 s run)
    err = _library_error(lambda: Scenario.load("paper", overrides))
    assert err is not None, f"{overrides} is accepted"
    argv = ["run", "paper", "--out", tmp_path / "x"]
    for o in overrides:
        argv += ["--set", o]
    code, _, text = _run_cli(argv)
    lines = text.strip().splitlines()
    assert code == 2 and len(lines) == 1, (code, text)
    assert re.match(r"hinfnn: (ConfigError|DesignError): ", lines[0]), lines[0]
    if key:
        assert f": {key}" in lines[0], lines[0]
    for w in words:
        assert w in lines[0], lines[0]
    assert not (tmp_path / "x").exists()


BASE_FILES = {
    "not a string": {"s.toml": "base = 3\n"},
    "no such scenario": {"s.toml": 'base = "no_such_scenario"\n'},
    "no such file": {"s.toml": 'base = "missing.toml"\n'},
    "itself": {"s.toml": 'base = "s.toml"\n'},
    "a cycle": {"s.toml": 'base = "b.toml"\n', "b.toml": 'base = "s.toml"\n'},
}


@pytest.mark.parametrize("case", list(BASE_FILES))
def test_bad_scenario_base_is_a_config_error_naming_base(tmp_path, case):
    """`base` that is not a string, names nothing, names the file itself (relative path) or
    closes a cycle: a ConfigError on key `base` (not a RecursionError), CLI exit 2."""
    for name, text in BASE_FILES[case].items():
        (tmp_path / name).write_text(text)
    path = tmp_path / "s.toml"
    err = _library_error(lambda: Scenario.load(path))
    assert err is not None and err.key == "base", repr(err)
    code, _, text = _run_cli(["run", path, "--out", tmp_path / "out"])
    _check_cli_line(code, text, err, case)


@pytest.mark.parametrize("argv_tail", [["--set", "plant.arm.m\n1=3"], ["--set", "controller.kind=hi\nnf"]],
                         ids=["newline in the key", "newline in the value"])
def test_line_breaks_in_keys_and_values_still_give_one_line(tmp_path, argv_tail):
    """The CLI's message stays on one line even when the bad key or value of a --set holds a
    line break."""
    code, _, text = _run_cli(["run", "paper", *argv_tail, "--out", tmp_path / "x"])
    assert code == 2 and len(text.strip().splitlines()) == 1, text


def test_line_break_in_an_unknown_file_key_still_gives_one_line(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('base = "paper"\n[plant.arm]\n"m\\nx" = 1.0\n')
    assert "m\nx" in tomllib.loads(path.read_text())["plant"]["arm"]
    code, _, text = _run_cli(["run", path, "--out", tmp_path / "x"])
    assert code == 2 and len(text.strip().splitlines()) == 1, text


def test_cli_out_path_that_is_a_file_exits_2(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    code, _, text = _run_cli(["run", "paper", "--set", "simulation.t_final=0.01", "--out", f])
    assert code == 2 and text.strip().splitlines() == [f"hinfnn: ConfigError: --out: output path {f} exists "
                                                       "and is not a folder"]


# =================================================================================================
# 2. Random valid scenarios run
# =================================================================================================


def _start_on_surface(l1, l2, delta_deg, d_G, frac):
    """x1 of the point of the line x2 = (x1 - d_G) tan(delta) at distance frac (l1 + l2) from the
    base (the larger root)."""
    t = math.tan(math.radians(delta_deg))
    r = frac * (l1 + l2)
    a, b, c = 1 + t * t, -2 * d_G * t * t, d_G * d_G * t * t - r * r
    return (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)


@st.composite
def valid_scenario(draw):
    """A scenario inside the documented envelope (see the test's docstring)."""
    def f(lo, hi):
        return draw(st.floats(lo, hi))

    raw = paper_raw()
    for who in ("plant", "nominal"):
        arm = raw[who]["arm"]
        arm["m1"] *= f(0.7, 1.3)
        arm["m2"] *= f(0.7, 1.3)
        arm["l1"] *= f(0.9, 1.1)
        arm["l2"] *= f(0.9, 1.1)
        arm["g"] = f(0.0, 12.0)
        raw[who]["surface"]["delta_deg"] += f(-5.0, 5.0)
        raw[who]["surface"]["d_G"] += f(-0.1, 0.1)
    raw["nominal"]["surface"]["scaling"] = draw(st.sampled_from(["paper", "unit"]))
    raw["plant"]["contact"]["stiffness"] *= f(0.7, 1.3)
    raw["plant"]["contact"]["damping"] = f(0.0, 500.0)
    d = raw["plant"]["disturbance"]
    d["amplitude"] = [f(-4.0, 4.0), f(-4.0, 4.0)]
    d["period"] = draw(st.sampled_from([0.5, 1.0, 2.0]))
    d["phase"] = 0.05 * draw(st.integers(-20, 20))
    g = raw["controller"]["gains"]
    g["rho"] *= f(1.0, 2.0)  # rho >= 0.6 > sqrt(R_p / 2): Remark 4 holds
    g["R_p"] *= f(0.5, 1.0)
    for k in ("mu_z", "K_p", "K_v", "gamma_1", "gamma_2"):
        g[k] *= f(0.5, 2.0)
    g["alpha_z"] *= f(0.5, 2.0)
    g["alpha_lam"] = 2 * g["rho"] ** 2 / g["alpha_z"] * f(1.05, 3.0)  # above Theorem 1's bound
    bound = g["alpha_lam"] * g["alpha_z"] / (2 * g["rho"] ** 2) - 1
    g["beta_lam"] = draw(st.sampled_from(["min", bound * f(1.0, 2.0)]))
    off = f(-0.3, 0.3)
    g["Q_p"] = [[f(0.5, 2.0), off], [off, f(0.5, 2.0)]]  # positive definite: |off| < 0.5
    for net in ("network_p", "network_f"):
        n = raw["controller"][net]
        n["slope"] = f(0.5, 2.0)
        n["w_a"] = f(0.5, 2.0)
        n["w_b"] = f(0.5, 2.0)
    n = raw["controller"]["network_p"]
    n["centre_start"] += f(-0.2, 0.2)
    n["centre_step"] *= f(0.5, 2.0)
    preset = draw(st.sampled_from(["paper-likely", "paper-printed"]))
    raw["controller"]["network_f"]["preset"] = preset
    raw["controller"]["network_f"]["centre_step"] = 0.5 if preset == "paper-likely" else 0.05
    arm, surf = raw["plant"]["arm"], raw["plant"]["surface"]
    u1 = _start_on_surface(arm["l1"], arm["l2"], surf["delta_deg"], surf["d_G"], f(0.9, 0.97))
    raw["initial"]["u1"] = u1
    r = raw["reference"]
    r["u1_amplitude"] *= f(0.5, 1.5)
    r["u1_offset"] = u1 + f(-0.02, 0.02) - r["u1_amplitude"]
    r["lam_offset"] *= f(0.7, 1.3)
    r["lam_amplitude"] *= f(0.5, 1.5)
    r["u1_period"] *= f(0.7, 1.3)
    r["lam_period"] *= f(0.7, 1.3)
    s = raw["simulation"]
    s["t_final"] = 1e-4 * draw(st.integers(200, 1000))
    s["output_interval"] = draw(st.sampled_from([1e-4, 1e-3, 2e-3]))
    raw["controller"]["kind"] = draw(st.sampled_from(["fl", "hinf", "hinf_nn"]))
    return raw


@settings(max_examples=24, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(raw=valid_scenario())
def test_random_valid_scenarios_run_a_short_horizon(raw):
    """Envelope: true and nominal masses x0.7..1.3, lengths x0.9..1.1, g in 0..12, slopes
    +-5 deg, d_G +-0.1 m, scaling paper/unit; stiffness x0.7..1.3, damping 0..500 N s/m;
    disturbance amplitudes -4..4 N m, period 0.5/1/2 s, phase a multiple of 0.05 s; rho x1..2,
    R_p x0.5..1, mu_z, K_p, K_v, gamma_1, gamma_2, alpha_z x0.5..2, alpha_lam 1.05..3 times its
    bound 2 rho^2/alpha_z, beta_lam "min" or 1..2 times its bound, Q_p symmetric with diagonal
    0.5..2 and |off-diagonal| <= 0.3; network slopes and input weights 0.5..2, F_p centres
    shifted by +-0.2 with step x0.5..2, either F_f preset; u1(0) on the true surface at 0.9..0.97
    of the true reach (elbow up), u1d starting within 2 cm of it; t_final 0.02..0.1 s at
    dt = 1e-4, output interval 0.1/1/2 ms; one of fl, hinf, hinf_nn (continuous, no projection,
    not augmented: one compiled program per kind).

    Every such scenario validates, designs, and runs to t_final without diverging."""
    sc = Scenario.from_dict(raw)
    kind = sc.kinds[0]
    tr = simulate_many([(kind, sc, kind)])[kind]
    assert int(tr.status) == 0, (float(tr.t_fail), tr.fail_details)
    assert tr.t[-1] == pytest.approx(raw["simulation"]["t_final"])
    for name, arr in tr.arrays.items():
        assert np.all(np.isfinite(arr)), name


# =================================================================================================
# 3. Divergence
# =================================================================================================


def test_single_run_divergence_raises_simulation_error_with_time_and_quantities():
    """Absurd learning rate gamma_2 (used by the adaptive controller only): the torque passes the
    limit in the first steps; with the limits removed the state becomes non-finite."""
    sc = Scenario.load("paper", ["simulation.t_final=0.05", "controller.gains.gamma_2=1e6"])
    with pytest.raises(H.SimulationError) as ex:
        sc.simulate()
    err = ex.value
    assert err.t_fail is not None and 0 <= err.t_fail < 0.05
    assert err.details["tau_peak"] > 1e5
    assert "torque limit" in str(err) and f"t = {err.t_fail:.6g} s" in str(err)
    assert f"{err.details['tau_peak']:.4g}" in str(err)

    sc = Scenario.load("paper", ["simulation.t_final=0.05", "controller.gains.gamma_2=1e8"])
    with pytest.raises(H.SimulationError) as ex:
        sc.simulate(limits=H.Limits(torque=np.inf, penetration=np.inf))
    assert "non-finite" in str(ex.value) and 0 < ex.value.t_fail < 0.05
    assert "controller state" in str(ex.value) or "q, q̇" in str(ex.value)  # names the part

    sc = Scenario.load("paper", ["simulation.t_final=0.05", "simulation.penetration_limit=1e-5"])
    with pytest.raises(H.SimulationError) as ex:
        sc.simulate()
    assert "penetration" in str(ex.value) and ex.value.details["penetration"] > 1e-5


def test_cli_batch_with_one_diverging_member_finishes_the_others(tmp_path):
    """`controller.kind = ["fl", "hinf", "hinf_nn"]` with gamma_2 = 1e6 (only hinf_nn learns):
    the batch completes, exactly hinf_nn is "diverged" with its t_fail, the others are ok, every
    file is written and loads back; the CLI exits 1 and names the diverged run on stderr."""
    out = tmp_path / "batch"
    code, stdout, stderr = _run_cli(["run", "paper", "--set", "simulation.t_final=0.05", "--set",
                                     'controller.kind=["fl","hinf","hinf_nn"]', "--set",
                                     "controller.gains.gamma_2=1e6", "--out", out])
    assert code == 1, stderr
    doc = json.loads((out / "metrics.json").read_text())
    runs = {r["name"]: r for r in doc["runs"]}
    assert list(runs) == ["fl", "hinf", "hinf_nn"]
    assert [n for n, r in runs.items() if r["status"] == "diverged"] == ["hinf_nn"]
    assert runs["hinf_nn"]["t_fail"] is not None and 0 <= runs["hinf_nn"]["t_fail"] < 0.05
    assert runs["hinf_nn"]["reason"].startswith("torque limit exceeded (peak |tau| = ")
    for n in ("fl", "hinf"):
        assert runs[n]["status"] == "ok" and runs[n]["t_fail"] is None
        assert math.isfinite(runs[n]["metrics"]["rms_e_u1"])
    assert re.search(r"run 'hinf_nn' stopped at t = [0-9.e-]+ s \(torque limit exceeded", stderr)
    assert "'fl'" not in stderr and "'hinf'" not in stderr
    res = H.load(out)
    assert [int(res.trajectories[n].status) for n in ("fl", "hinf", "hinf_nn")] == [0, 0, 2]
    assert res.trajectories["fl"].t[-1] == pytest.approx(0.05)
    assert float(res.trajectories["hinf_nn"].t_fail) == pytest.approx(runs["hinf_nn"]["t_fail"])
    code, shown, _ = _run_cli(["show", out])
    assert code == 0 and "hinf_nn" in shown
    assert _hidden_leftovers(tmp_path) == []


def test_vmapped_batch_marks_only_the_member_past_its_limit():
    """One compiled vmap batch of three FL-like runs; the middle one has a 10 N m torque limit."""
    base = Scenario.load("paper", ["simulation.t_final=0.02", "controller.kind=fl"])
    tight = base.with_overrides(["simulation.torque_limit=10"])
    trajs = simulate_many([("a", base, "fl"), ("b", tight, "fl"), ("c", base, "fl")])
    assert [int(trajs[n].status) for n in "abc"] == [0, 2, 0]
    assert 0 <= float(trajs["b"].t_fail) < 0.02 and float(trajs["b"].fail_details["tau_peak"]) > 10
    _assert_same_arrays(trajs["a"].arrays, trajs["c"].arrays)
    assert np.all(np.isfinite(trajs["a"].tau))


# =================================================================================================
# 4. Atomic results: signals, kills, non-empty folders
# =================================================================================================


@pytest.fixture(scope="module")
def paper_result(tmp_path_factory):
    """A complete short paper run written by the CLI (in-process)."""
    out = tmp_path_factory.mktemp("paper") / "result"
    code, _, err = _run_cli(["run", "paper", "--set", "simulation.t_final=0.05", "--out", out, "--quiet"])
    assert code == 0, err
    return out


def _wait_for(predicate, timeout, what):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if predicate():
            return
        time.sleep(0.005)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def _partials(parent: Path, name: str) -> list[Path]:
    return [p for p in parent.iterdir() if p.name.startswith(f".{name}.partial-")]


def _popen(args, cwd):
    # a crash shows on stderr; PYTHONPATH: the hinfnn under test, whatever the subprocess's cwd
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONFAULTHANDLER": "1",
           "PYTHONPATH": str(Path(H.__file__).resolve().parents[1])}
    with interruptible():
        return subprocess.Popen([str(HINFNN), *map(str, args)], cwd=cwd, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, env=env, text=True)


class _StderrReader:
    """Collect a subprocess's stderr lines in a thread (the progress lines tell when it simulates)."""

    def __init__(self, proc):
        import threading

        self.lines: list[str] = []
        self.thread = threading.Thread(target=self._read, args=(proc.stderr,), daemon=True)
        self.thread.start()

    def _read(self, stream):
        for line in stream:
            self.lines.append(line)

    def text(self) -> str:
        self.thread.join(timeout=30)
        return "".join(self.lines)


@pytest.mark.parametrize("phase", ["compiling", "simulating"])
@pytest.mark.parametrize("sig,expected", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
def test_signal_during_run_leaves_no_output(tmp_path, sig, expected, phase):
    """`hinfnn run paper --set simulation.t_final=60` interrupted while JAX compiles the run (2 s
    after the temporary folder appears) or while it simulates (after its first progress line):
    exit 130 (SIGINT) / 143 (SIGTERM), the message says nothing was written, and the parent
    folder is left empty (no output folder, no .partial-/.old- leftovers)."""
    out = tmp_path / "long"
    # 60 s simulated: about 7 s of simulation, past the 3 s after which a pipe gets its first progress
    # line (a 20-s run, once its setup programs were kept between processes, could end before it)
    proc = _popen(["run", "paper", "--set", "simulation.t_final=60", "--out", out], tmp_path)
    reader = _StderrReader(proc)
    try:
        _wait_for(lambda: _partials(tmp_path, "long"), 60, "the temporary output folder")
        if phase == "compiling":
            time.sleep(2.0)
        else:
            _wait_for(lambda: any("simulating" in line for line in reader.lines), 90, "a progress line")
        assert proc.poll() is None
        proc.send_signal(sig)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = reader.text()
    assert proc.returncode == expected, stderr
    assert "no output was written" in stderr
    assert "Traceback" not in stderr and "Fatal Python error" not in stderr
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_kill_mid_write_leaves_previous_result_intact(tmp_path, paper_result):
    """SIGKILL while the replacing run (--force) writes its files: the previous result is
    untouched (every file, byte for byte)."""
    out = tmp_path / "result"
    shutil.copytree(paper_result, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    proc = _popen(["run", "paper", "--set", "simulation.t_final=0.05", "--set", "reference.lam_offset=50",
                   "--out", out, "--force", "--quiet"], tmp_path)
    try:
        def writing():
            try:
                return any(any(True for _ in part.iterdir()) for part in _partials(tmp_path, "result"))
            except FileNotFoundError:  # renamed into place meanwhile: too late, reported below
                return True

        _wait_for(writing, 90, "files in the temporary output folder")
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the run finished before it could be killed"
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert H.load(out).scenario.reference.lam_offset == 60.0


def test_non_empty_output_folder_needs_force(tmp_path):
    out = tmp_path / "r"
    args = ["run", "paper", "--set", "simulation.t_final=0.01", "--set", "controller.kind=hinf", "--no-figures"]
    assert _run_cli(args + ["--out", out])[0] == 0
    first = (out / "metrics.json").read_bytes()
    code, stdout, stderr = _run_cli(args + ["--set", "reference.lam_offset=50", "--out", out])
    assert code == 0
    assert f"{out} is not empty; writing to {out}-2 instead (use --force to replace it)" in stderr
    assert f"results: {out}-2/" in stdout
    assert (out / "metrics.json").read_bytes() == first
    assert H.load(Path(f"{out}-2")).scenario.reference.lam_offset == 50.0
    code, stdout, stderr = _run_cli(args + ["--set", "reference.lam_offset=55", "--out", out, "--force"])
    assert code == 0 and "not empty" not in stderr
    assert H.load(out).scenario.reference.lam_offset == 55.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r", "r-2"]
    (tmp_path / "empty").mkdir()  # an empty folder is used as is
    code, _, stderr = _run_cli(args + ["--out", tmp_path / "empty"])
    assert code == 0 and "not empty" not in stderr and (tmp_path / "empty" / "metrics.json").exists()


def test_exception_during_run_leaves_target_as_it_was(tmp_path, paper_result, monkeypatch):
    """An exception after some files are written (here: while drawing the figures) removes the
    temporary folder; the previous result in the target is untouched."""
    out = tmp_path / "result"
    shutil.copytree(paper_result, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def boom(*a, **k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr("hinfnn.report.run_figures", boom)
    code, _, stderr = _run_cli(["run", "paper", "--set", "simulation.t_final=0.05", "--out", out, "--force"])
    assert code == 1 and "disk on fire" in stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert _hidden_leftovers(tmp_path) == []


# =================================================================================================
# 5. Saved runs load back
# =================================================================================================

ALL_OPTIONS = """
base = "paper"
name = "all-options"
description = "every option away from its default"

[plant.arm]
m1 = 1.3
g = 9.81
[plant.contact]
stiffness = 120000.0
damping = 150.0
[plant.disturbance]
amplitude = [2.0, -1.5]
period = 0.8
phase = 0.1

[nominal.arm]
m2 = 0.9
l1 = 1.01
[nominal.surface]
delta_deg = 44.0
scaling = "unit"

[controller]
kind = "hinf_nn"
augmented = true
[controller.gains]
rho = 0.9
mu_z = 80.0
K_p = 20.0
K_v = 10.0
alpha_lam = 1.2
alpha_z = 3.0        # Remark 3: alpha_lam > 2 rho^2 / alpha_z = 0.54
beta_lam = 2.0       # >= alpha_lam alpha_z / (2 rho^2) - 1 = 1.2222
gamma_1 = 1.5
gamma_2 = 2.5
Q_p = [[2.0, 0.5], [0.5, 1.0]]
R_p = 0.4            # eq. (40) needs rho^2 > R_p here
[controller.network_p]
centre_start = -0.8
centre_step = 0.04
centre_count = 41
slope = 1.5
w_a = 1.2
w_b = 0.8
projection = true
radius = 0.0005
[controller.network_f]
preset = "custom"
centre_start = -20.0
centre_step = 0.4
centre_count = 101
slope = 0.8
w_a = 1.0
w_b = 0.5
projection = true
radius = 0.5

[reference]
u1_offset = 1.45
u1_amplitude = 0.25
u1_phase = 0.1
lam_offset = 50.0
lam_amplitude = -15.0
lam_period = 2.5
lam_phase = -0.2

[initial]
u1 = 1.65

[simulation]
t_final = 0.05
dt = 0.0001
control = "sampled"
control_period = 0.0005
output_interval = 0.002
torque_limit = 50000.0
penetration_limit = 0.02
"""


def test_all_options_scenario_saves_loads_and_repeats_bit_for_bit(tmp_path):
    """ALL_OPTIONS (augmented, both projections on with radii, custom F_f centres, numeric beta_lam,
    alpha_z = 3 with matching bounds, sampled control, unit scaling, damping, disturbance phase,
    base inheritance ...): run by the CLI, loaded back with its resolved scenario and version,
    repeated from the saved scenario.toml bit for bit; an undecimated Trajectory round-trips
    through trajectory.npz exactly."""
    src = tmp_path / "all.toml"
    src.write_text(ALL_OPTIONS)
    sc = Scenario.load(src)
    d = sc.to_dict()
    assert sc.controller.augmented and sc.simulation.control == "sampled"
    assert sc.controller.network_f.centre_count == 101 and sc.controller.gains.beta_lam == 2.0
    out, again = tmp_path / "one", tmp_path / "two"
    code, _, err = _run_cli(["run", src, "--out", out, "--quiet"])
    assert code == 0, err
    res = H.load(out)
    assert res.scenario.to_dict() == d
    assert res.version == H.__version__ and res.metrics["hinfnn_version"] == H.__version__
    assert res.metrics["scenario"] == d
    tr = res.trajectory
    assert tr.scenario.to_dict() == d and int(tr.status) == 0
    assert tr.t.shape == (26,) and tr.t[-1] == pytest.approx(0.05)  # decimated to 2 ms
    # both projections act (Remark 2): the weights reach their radii and stay on them
    for norm, radius in ((tr.theta_p_norm, 0.0005), (tr.theta_f_norm, 0.5)):
        assert radius * (1 - 1e-6) < norm.max() <= radius * (1 + 1e-9)
    # the saved scenario.toml is complete (no base) and resolves to the same scenario
    saved = tomllib.loads((out / "scenario.toml").read_text())
    assert "base" not in saved and Scenario.from_dict(saved).to_dict() == d
    # repeating the run from its scenario.toml gives the same numbers to the last bit
    code, _, err = _run_cli(["run", out / "scenario.toml", "--out", again, "--quiet"])
    assert code == 0, err
    a, b = _npz_arrays(out / "trajectory.npz"), _npz_arrays(again / "trajectory.npz")
    _assert_same_arrays(a, b)
    # a Trajectory saved without decimation loads back exactly
    full = simulate_many([("hinf_nn", sc, "hinf_nn")])["hinf_nn"]
    npz = tmp_path / "full.npz"
    npz.write_bytes(trajectory_npz_bytes({"x": full}, max_interval=None))
    runs, version = load_npz(npz)
    back = runs["x"]
    assert version == H.__version__
    _assert_same_arrays(back.arrays, full.arrays)
    _assert_same_arrays(back.final, full.final)
    assert back.dt == full.dt and back.save_every == full.save_every and back.scenario.to_dict() == d
    assert int(back.status) == 0 and np.isnan(back.t_fail)
    _assert_same_arrays(full.decimated(0.002).arrays, tr.arrays)


def test_repeat_from_scenario_toml_in_a_new_process_is_bit_identical(tmp_path, paper_result):
    again = tmp_path / "again"
    proc = subprocess.run([str(HINFNN), "run", str(paper_result / "scenario.toml"), "--out", str(again),
                           "--quiet", "--no-figures"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    _assert_same_arrays(_npz_arrays(paper_result / "trajectory.npz"), _npz_arrays(again / "trajectory.npz"))
    res = H.load(paper_result)
    assert res.scenario.to_dict() == Scenario.load(again / "scenario.toml").to_dict()
    assert res.scenario.simulation.t_final == 0.05
    arrays = _npz_arrays(paper_result / "trajectory.npz")
    assert str(arrays["__hinfnn_version__"]) == H.__version__ and str(arrays["__format__"]) == FORMAT
    tr = res.trajectory
    for name, arr in tr.arrays.items():
        assert np.array_equal(arr, arrays[f"hinf_nn/{name}"]), name
    assert abs(tr.penetration[0]) < 1e-12 and tr.x_true[0, 0] == pytest.approx(1.6902, abs=1e-9)  # on the surface


CORRUPT_CASES = [
    "npz cut in half", "npz cut by 10 bytes", "npz empty", "npz random bytes", "npz deflate stream corrupted",
    "npz needing an unsupported zip version", "npz without format marker", "npz of another format",
    "npz with only the format marker", "npz missing a run's arrays", "npz with an object array", "npz missing",
    "metrics.json cut short", "metrics.json not UTF-8", "metrics.json of another tool", "metrics.json a list",
    "scenario.toml not TOML", "scenario.toml of another tool", "scenario.toml missing",
]


def _corrupt_cases(folder: Path):
    npz, metrics, scen = folder / "trajectory.npz", folder / "metrics.json", folder / "scenario.toml"
    good = npz.read_bytes()
    arrays = _npz_arrays(npz)

    def savez(path, **kw):
        with open(path, "wb") as fh:
            np.savez(fh, **kw)

    def deflate_corrupted():
        """Flip bytes inside the first member's compressed data (zlib fails before the CRC)."""
        b = bytearray(good)
        assert b[:4] == b"PK\x03\x04"
        name_len, extra_len = struct.unpack("<HH", b[26:30])
        start = 30 + name_len + extra_len
        for i in range(start + 2, start + 10):
            b[i] ^= 0x5A
        return bytes(b)

    def unsupported_zip_version():
        """A central-directory entry asking for zip version 25.5."""
        b = bytearray(good)
        i = b.index(b"PK\x01\x02")
        b[i + 6] = 0xFF
        return bytes(b)

    return {
        "npz cut in half": lambda: npz.write_bytes(good[: len(good) // 2]),
        "npz cut by 10 bytes": lambda: npz.write_bytes(good[:-10]),
        "npz empty": lambda: npz.write_bytes(b""),
        "npz random bytes": lambda: npz.write_bytes(np.random.default_rng(0).bytes(5000)),
        "npz deflate stream corrupted": lambda: npz.write_bytes(deflate_corrupted()),
        "npz needing an unsupported zip version": lambda: npz.write_bytes(unsupported_zip_version()),
        "npz without format marker": lambda: savez(npz, **{k: v for k, v in arrays.items() if k != "__format__"}),
        "npz of another format": lambda: savez(npz, **{**arrays, "__format__": np.array("other-format-1")}),
        "npz with only the format marker": lambda: savez(npz, __format__=np.array(FORMAT)),
        "npz missing a run's arrays": lambda: savez(npz, **{k: v for k, v in arrays.items()
                                                           if not k.startswith("hinf_nn/__")}),
        "npz with an object array": lambda: savez(npz, __format__=np.array(FORMAT),
                                                  x=np.array([{}], dtype=object)),
        "npz missing": lambda: npz.unlink(),
        "metrics.json cut short": lambda: metrics.write_bytes(metrics.read_bytes()[:100]),
        "metrics.json not UTF-8": lambda: metrics.write_bytes(b"\xff\xfe\x00{"),
        "metrics.json of another tool": lambda: metrics.write_text('{"accuracy": 0.9}'),
        "metrics.json a list": lambda: metrics.write_text("[1, 2, 3]"),
        "scenario.toml not TOML": lambda: scen.write_text("[plant\n"),
        "scenario.toml of another tool": lambda: scen.write_text('[tool.black]\nline-length = 88\n'),
        "scenario.toml missing": lambda: scen.unlink(),
    }


@pytest.mark.parametrize("case", CORRUPT_CASES)
def test_truncated_or_foreign_result_files_are_load_errors(tmp_path, paper_result, case):
    folder = tmp_path / "r"
    shutil.copytree(paper_result, folder)
    _corrupt_cases(folder)[case]()
    with pytest.raises(H.LoadError) as ex:
        H.load(folder)
    assert str(folder) in str(ex.value)
    # `show` needs only metrics.json; `export` reads the whole folder
    if case.startswith("metrics.json"):
        code, _, text = _run_cli(["show", folder])
        assert code == 2 and text.strip().splitlines() == [f"hinfnn: LoadError: {ex.value}"], text
    else:
        code, shown, _ = _run_cli(["show", folder])
        assert code == 0 and "RMS e_u1" in shown
    code, _, text = _run_cli(["export", folder, "--csv", "--out", "-"])
    assert code == 2 and text.strip().splitlines() == [f"hinfnn: LoadError: {ex.value}"], text


def test_load_of_missing_folder_is_a_load_error(tmp_path):
    with pytest.raises(H.LoadError):
        H.load(tmp_path / "nothing")
    code, _, text = _run_cli(["show", tmp_path / "nothing"])
    assert code == 2 and text.startswith("hinfnn: LoadError: ")


def test_numpy_and_tuple_values_from_python_load_as_their_python_equal():
    """A value given from Python as NumPy computes it (``np.float64``, ``np.float32``,
    ``np.int64``, an array) or as a tuple loads as the same number or list would: the same
    scenario, its values Python floats and tuples, its overrides Python's values (JSON writes
    them). Bools stay refused for numbers, NumPy's too, and NaN inside an array is named by its
    index."""
    plain = Scenario.load("ur5-table", {"simulation.t_final": 1, "plant.arm.gravity": [0.0, 0.0, -9.81],
                                        "simulation.torque_limit": 500.0})
    for given in ({"simulation.t_final": np.int64(1), "plant.arm.gravity": np.array([0.0, 0.0, -9.81]),
                   "simulation.torque_limit": np.float64(500)},
                  {"simulation.t_final": 1.0, "plant.arm.gravity": (0.0, 0.0, -9.81),
                   "simulation.torque_limit": np.float32(500)}):
        sc = Scenario.load("ur5-table", given)
        assert sc == plain, given
        assert type(sc.get("simulation.t_final")) is float and type(sc.get("plant.arm.gravity")) is tuple
        # the overrides as kept (and written to metrics.json): Python's values
        assert json.loads(json.dumps(dict(sc.overrides))) == dict(plain.overrides), sc.overrides
    for bad, key, words in ((np.True_, "simulation.t_final", "got True (bool)"),
                            (True, "simulation.t_final", "got True (bool)"),
                            (np.array([0.1, 0.2]), "simulation.t_final", "got [0.1, 0.2] (list)")):
        with pytest.raises(H.ConfigError, match=re.escape(words)) as err:
            Scenario.load("paper", {key: bad})
        assert err.value.key == key
    with pytest.raises(H.ConfigError) as err:
        Scenario.load("ur5-table", {"plant.arm.gravity": np.array([0.0, np.nan, -9.81])})
    assert err.value.key == "plant.arm.gravity[1]" and "finite" in str(err.value)


def test_a_force_reference_that_would_pull_is_refused(tmp_path):
    """Every contact hinfnn simulates can only push (λ > 0 presses): λd below zero anywhere on its
    period is a ConfigError naming reference.lam_offset, the least λd and what is allowed; on the
    CLI one line, exit 2, nothing written. λd touching zero is accepted."""
    with pytest.raises(H.ConfigError) as err:
        H.load_scenario("paper", {"reference.lam_offset": -20.0, "reference.lam_amplitude": 0.0})
    assert err.value.key == "reference.lam_offset" and "reaches -20 N" in str(err.value)
    with pytest.raises(H.ConfigError, match=r"reaches -10 N, got lam_offset = 10 and lam_amplitude = -20"):
        H.load_scenario("paper", {"reference.lam_offset": 10.0})
    H.load_scenario("paper", {"reference.lam_offset": 20.0})  # 20 − 20 cos(πt) ≥ 0
    with pytest.raises(H.ConfigError, match=r"^reference.lam_offset: λd = .* reaches -20 N, "):  # a spatial arm's too
        H.load_scenario("ur5-table", {"reference.lam_offset": -20.0})
    code, out, stderr = _run_cli(["run", "paper", "--set", "reference.lam_offset=-20", "--set",
                                  "reference.lam_amplitude=0", "--out", tmp_path / "r", "--no-figures"])
    assert code == 2 and out == "" and not (tmp_path / "r").exists()
    assert stderr.strip().splitlines() == [
        "hinfnn: ConfigError: reference.lam_offset: λd = lam_offset + lam_amplitude·cos(...) reaches -20 N, got "
        "lam_offset = -20 and lam_amplitude = 0: the contact can only push (λ > 0 presses on the surface); give "
        "lam_offset >= |lam_amplitude| (λd >= 0)"]
