"""Results a user can trust (issue 15), through the ``hinfnn`` command: as a subprocess where the
issue says so, in this process (``cli.main`` in the test's folder) where only the folder logic is
checked. --force never destroys what hinfnn did not write, concurrent runs never overwrite each
other, paths stay where the user asked, signals at any moment (import included), default folders
that do not collide, the memory guard, reproduce's overrides, the design and stopped runs in
``show`` (which needs only metrics.json), ``plot`` and ``export`` round trips, one-line warnings.
"""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from children import interruptible

import hinfnn as H
from hinfnn import cli
from hinfnn.fields import unit
from hinfnn.io import MARKER, foreign_files, read_marker, reserve_output, safe_name

HINFNN = Path(sys.executable).parent / "hinfnn"
SRC = Path(H.__file__).resolve().parents[1]  # the hinfnn under test, also in subprocesses
SHORT = ["--set", "simulation.t_final=0.05"]


def _env(cache, **extra):
    env = {**os.environ, "PYTHONPATH": str(SRC), "HINFNN_CACHE_DIR": str(cache), "JAX_PLATFORMS": "cpu",
           "PYTHONFAULTHANDLER": "1"}
    env.update({k: str(v) for k, v in extra.items()})
    return env


def hinfnn(args, cwd, cache, timeout=300, **env) -> subprocess.CompletedProcess:
    """``hinfnn ARGS`` as a subprocess in ``cwd``."""
    return subprocess.run([str(HINFNN), *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=_env(cache, **env))


def hinfnn_here(args, cwd, monkeypatch, capsys) -> subprocess.CompletedProcess:
    """``hinfnn ARGS`` in this process (``cli.main``) with ``cwd`` as the current folder: for the
    tests of where results go, which need the command's folder logic, not a process of its own
    (a subprocess would trace and load the run's programs again, 3 s each time)."""
    capsys.readouterr()
    with monkeypatch.context() as m:
        m.chdir(cwd)
        code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, out, err)


def _popen(args, cwd, cache, **env):
    with interruptible():
        return subprocess.Popen([str(HINFNN), *map(str, args)], cwd=cwd, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=_env(cache, **env))


def _one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in text, text
    return lines[0]


def _complete(folder: Path, figures: bool = True) -> bool:
    names = {p.name for p in folder.iterdir()}
    return {"metrics.json", "trajectory.npz", "scenario.toml", MARKER, *(["u1.png"] if figures else [])} <= names


@pytest.fixture(scope="module")
def result(tmp_path_factory, cache):
    """A short paper run with three controllers, written by the command (subprocess)."""
    root = tmp_path_factory.mktemp("result")
    p = hinfnn(["run", "paper", *SHORT, "--set", 'controller.kind=["fl", "hinf", "hinf_nn"]', "--out", "r",
                "--quiet"], root, cache)
    assert p.returncode == 0, p.stderr
    return root / "r"


# --- never destroy what hinfnn did not write ---------------------------------------------------------


def test_force_onto_a_folder_with_a_foreign_file_keeps_it(tmp_path, monkeypatch, capsys):
    work = tmp_path / "mywork"
    work.mkdir()
    (work / "thesis.tex").write_text("precious")
    (work / "data").mkdir()
    p = hinfnn_here(["run", "paper", *SHORT, "--out", work, "--force"], tmp_path, monkeypatch, capsys)
    assert p.returncode == 2
    line = _one_line(p.stderr)
    assert line.startswith("hinfnn: ConfigError: --out: ") and "thesis.tex" in line and "data/" in line
    assert (work / "thesis.tex").read_text() == "precious"
    assert sorted(x.name for x in work.iterdir()) == ["data", "thesis.tex"]
    assert sorted(x.name for x in tmp_path.iterdir()) == ["mywork"]  # no lock, no partial left


def test_force_replaces_a_hinfnn_folder_but_not_one_a_user_added_to(tmp_path, result):
    out = tmp_path / "r"
    shutil.copytree(result, out)
    assert read_marker(out)["files"] and foreign_files(out) == []
    code = cli.main(["run", "paper", "--set", "simulation.t_final=0.02", "--set", "controller.kind=hinf",
                     "--out", str(out), "--force", "--quiet", "--no-figures"])
    assert code == 0
    assert H.load(out).scenario.simulation.t_final == 0.02 and set(H.load(out).trajectories) == {"hinf"}
    (out / "notes.txt").write_text("mine")
    with pytest.raises(H.ConfigError, match="notes.txt"):
        reserve_output(out, force=True)
    assert cli.main(["run", "paper", "--set", "simulation.t_final=0.02", "--out", str(out), "--force",
                     "--quiet", "--no-figures"]) == 2
    assert (out / "notes.txt").read_text() == "mine"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["r"]


def test_result_folder_written_before_markers_is_still_replaceable(tmp_path, result):
    out = tmp_path / "old"
    shutil.copytree(result, out)
    (out / MARKER).unlink()
    assert foreign_files(out) == []
    (out / "notes.txt").write_text("mine")
    assert foreign_files(out) == ["notes.txt"]


def test_two_concurrent_runs_to_one_out_never_overwrite_each_other(tmp_path, cache):
    """Two real processes started together with the same --out: two complete results, or one
    complete result and an exit 2; never one silently replacing the other."""
    args = ["run", "paper", *SHORT, "--out", "same", "--no-figures"]
    a = _popen(args + ["--set", "reference.lam_offset=50"], tmp_path, cache)
    b = _popen(args + ["--set", "reference.lam_offset=55"], tmp_path, cache)
    outs = [p.communicate(timeout=300) for p in (a, b)]
    codes = [a.returncode, b.returncode]
    folders = sorted(p.name for p in tmp_path.iterdir())
    assert all(c in (0, 2) for c in codes), outs
    if codes == [0, 0]:
        assert folders == ["same", "same-2"], folders
        offsets = {H.load(tmp_path / f).scenario.reference.lam_offset for f in folders}
        assert offsets == {50.0, 55.0}
        printed = {re.search(r"results: (\S+)/", o[0]).group(1) for o in outs}
        assert printed == {"same", "same-2"}
        assert any("being written by another hinfnn process" in o[1] or "is not empty" in o[1] for o in outs)
    else:
        assert sorted(codes) == [0, 2] and folders == ["same"]
    assert all(_complete(tmp_path / f, figures=False) for f in folders)


def test_stale_lock_of_a_killed_process_does_not_block(tmp_path):
    out = tmp_path / "r"
    lock = tmp_path / ".r.hinfnn-lock"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    lock.write_text(json.dumps({"pid": dead.pid, "host": os.uname().nodename}))
    res = reserve_output(out, force=True)
    assert res.target == out and res.note is None
    res.release()
    assert not lock.exists()
    # a live holder: the folder is taken (next name), or refused with --force
    lock.write_text(json.dumps({"pid": os.getpid(), "host": os.uname().nodename}))
    res = reserve_output(out)
    assert res.target == tmp_path / "r-2" and "being written by another hinfnn process" in res.note
    res.release()
    with pytest.raises(H.ConfigError, match="being written by another hinfnn process"):
        reserve_output(out, force=True)


# --- paths stay where the user asked ------------------------------------------------------------------


def test_safe_names():
    assert safe_name("../../escaped") == "escaped"
    assert safe_name("a/b\\c") == "a_b_c"
    assert safe_name("...") == "scenario" and safe_name("") == "scenario"
    assert len(safe_name("x" * 5000)) <= 80
    assert safe_name("Bahn führung 2") == "Bahn_führung_2"


@pytest.mark.parametrize("name", ["../../escaped", "/etc/passwd", "x" * 5000, "a\nb", ".hidden", "..", ""])
def test_hostile_scenario_name_stays_under_results(tmp_path, monkeypatch, capsys, name):
    work = tmp_path / "deep" / "work"
    work.mkdir(parents=True)
    (work / "evil.toml").write_text(f'base = "paper"\nname = {json.dumps(name)}\n')
    p = hinfnn_here(["run", "evil.toml", *SHORT, "--quiet", "--no-figures"], work, monkeypatch, capsys)
    assert p.returncode == 0, p.stderr
    made = list((work / "results" / "runs").iterdir())
    assert len(made) == 1 and _complete(made[0], figures=False)
    assert re.fullmatch(r"[\w.-]{1,80}-\d{8}T\d{6}Z", made[0].name)
    assert sorted(x.name for x in tmp_path.rglob("*") if x.is_dir() and x.parent == tmp_path) == ["deep"]
    assert sorted(x.name for x in work.iterdir()) == ["evil.toml", "results"]


@pytest.mark.parametrize("out,words", [
    ("", "is empty"),
    ("   ", "is empty"),
    (".", "is the current folder"),
    ("/proc/foo", "cannot create /proc/foo"),
    ("existing_file/sub", "existing_file is a file, not a folder"),
    ("existing_file", "exists and is not a folder"),
    ("x" * 300, "characters long"),
])
@pytest.mark.parametrize("force", [False, True], ids=["", "force"])
def test_bad_out_exits_2_with_one_line_before_any_work(tmp_path, capsys, out, words, force):
    (tmp_path / "existing_file").write_text("x")
    before = sorted(p.name for p in tmp_path.iterdir())
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        t0 = time.perf_counter()
        code = cli.main(["run", "paper", "--set", "simulation.t_final=0.05", "--out", out]
                        + (["--force"] if force else []))
        seconds = time.perf_counter() - t0
    finally:
        os.chdir(cwd)
    err = capsys.readouterr().err
    assert code == 2, err
    line = _one_line(err)
    assert line.startswith("hinfnn: ConfigError: --out: ") and words in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert seconds < 10  # refused before compiling anything


# --- signals at any moment ----------------------------------------------------------------------------


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("after", [0.5, 3.0])
def test_signal_at_start_up_gives_one_line_and_its_exit_code(tmp_path, cache, sig, code, after):
    """0.5 s: JAX is being imported; 3 s: the scenario is designed or the run compiles."""
    proc = _popen(["run", "paper", "--set", "simulation.t_final=20", "--out", "long"], tmp_path, cache)
    try:
        time.sleep(after)
        assert proc.poll() is None
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == code, err
    word = "interrupted" if sig == signal.SIGINT else "terminated"
    assert _one_line(err) == f"hinfnn: {word}; no output was written"
    assert list(tmp_path.iterdir()) == []


def test_a_signal_raised_inside_a_gc_callback_is_not_lost(capsys, tmp_path):
    """Python swallows an exception raised in a garbage-collection callback (JAX registers one) and
    prints "Exception ignored in ..."; CI once saw a Ctrl-C vanish that way and the run finish
    with exit 0. The handler remembers the signal, prints nothing there, and the command raises it
    at its next check (between chunks, and before a result is put in place)."""
    import gc

    from hinfnn import _signals

    previous = _signals.install()
    try:
        def callback(phase, info):
            if phase == "start":
                _signals.handler(signal.SIGINT, sys._getframe())

        gc.callbacks.append(callback)
        try:
            gc.collect()
        finally:
            gc.callbacks.remove(callback)
        assert "Exception ignored" not in capsys.readouterr().err
        with pytest.raises(KeyboardInterrupt):
            _signals.check()
        _signals._delivered = None  # what cli.main does when it reports the interrupt
        from hinfnn.io import OutputFolder

        with pytest.raises(KeyboardInterrupt):
            with OutputFolder(tmp_path / "r") as folder:
                (folder.path / "x.txt").write_text("x")
                _signals._delivered = signal.SIGINT  # as if swallowed while the result was computed
        assert list(tmp_path.iterdir()) == []  # no result, no partial folder
    finally:
        _signals.restore(previous)


def test_import_hinfnn_loads_no_jax():
    code = "import sys, hinfnn, hinfnn.cli; assert 'jax' not in sys.modules and 'numpy' not in sys.modules; " \
           "hinfnn.TwoLinkArm; assert 'jax' in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, env={**os.environ, "PYTHONPATH": str(SRC)})


def test_the_program_collects_garbage_less_often_and_a_library_call_changes_nothing():
    """The ``hinfnn`` program (hinfnn.cli.program_gc) sets Python's garbage-collector
    thresholds before it imports JAX; ``cli.main([...])`` called from Python leaves the caller's
    process as it was; ``HINFNN_DEFAULT_GC=1`` keeps the default."""
    from hinfnn.cli import PROGRAM_GC_THRESHOLD

    code = "\n".join([
        "import contextlib, gc, io, json, sys",
        "default = gc.get_threshold()",
        "from hinfnn.cli import main",
        "with contextlib.redirect_stdout(io.StringIO()):",
        "    assert main(['keys']) == 0",  # from Python
        "library = gc.get_threshold()",
        "import atexit",  # the program may end with os._exit, after the atexit handlers (fast_exit)
        "atexit.register(lambda: print(json.dumps([default, library, gc.get_threshold()]), file=sys.stderr))",
        "sys.argv = ['hinfnn', 'keys']",
        "with contextlib.redirect_stdout(io.StringIO()):",
        "    main()"])  # the program
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    for extra, program in (({}, list(PROGRAM_GC_THRESHOLD)), ({"HINFNN_DEFAULT_GC": "1"}, [700, 10, 10])):
        p = subprocess.run([sys.executable, "-c", code], env={**env, **extra}, capture_output=True, text=True,
                           timeout=120)
        assert p.returncode == 0, p.stderr
        assert json.loads(p.stderr.strip().splitlines()[-1]) == [[700, 10, 10], [700, 10, 10], program], extra


def test_exit_codes_are_documented(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    text = capsys.readouterr().out
    for code in ("0", "1", "2", "130", "143"):
        assert re.search(rf"^\s+{code}\s+\S", text, re.M), code
    doc = (Path(__file__).resolve().parents[1] / "docs" / "results.md").read_text()
    for code in ("130", "143"):
        assert f"| {code} |" in doc


# --- default folders ------------------------------------------------------------------------------------


def test_default_folders_do_not_collide(tmp_path, monkeypatch, capsys):
    (tmp_path / "my_arm.toml").write_text('base = "paper"\n')
    first = hinfnn_here(["run", "paper", *SHORT, "--quiet", "--no-figures"], tmp_path, monkeypatch, capsys)
    assert first.returncode == 0, first.stderr
    p = hinfnn_here(["run", "my_arm.toml", *SHORT, "--no-figures"], tmp_path, monkeypatch, capsys)
    assert p.returncode == 0, p.stderr
    runs = sorted(x.name for x in (tmp_path / "results" / "runs").iterdir())
    assert [re.sub(r"\d{8}T\d{6}Z", "T", n) for n in runs] == ["my_arm-T", "paper-T"]
    assert sorted(x.name for x in (tmp_path / "results").iterdir()) == ["runs"]  # never results/paper
    assert f"results: results/runs/{runs[0]}/" in p.stdout
    from hinfnn.io import default_output

    assert default_output("reproduce", "paper") == Path("results/paper")


# --- honest guards ----------------------------------------------------------------------------------------


def test_memory_guard_refuses_and_says_how_to_store_less(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("HINFNN_MAX_MEMORY", "1GB")
    p = hinfnn_here(["run", "paper", "--set", "simulation.t_final=1000"], tmp_path, monkeypatch, capsys)
    assert p.returncode == 2
    line = _one_line(p.stderr)
    from hinfnn import resources
    from hinfnn.scenario import Scenario

    numbers = resources.plan([Scenario.load("paper", ["simulation.t_final=1000"]).run()]).numbers
    assert numbers > 40  # q, q̇, τ, λ, u1, the network weights' summaries ... (every stored field)
    assert line.startswith("hinfnn: ResourceError: ") and f"1,000,001 samples of {numbers} numbers" in line
    assert "1.0 GB of memory is available" in line
    m = re.search(r"--set simulation.output_interval=([0-9.e-]+)", line)
    assert m and "--fields metrics" in line
    assert list(tmp_path.iterdir()) == []
    # what it suggests fits

    sc = Scenario.load("paper", ["simulation.t_final=1000", f"simulation.output_interval={m.group(1)}"])
    assert resources.plan([sc.run()]).peak <= 1e9
    assert resources.plan([Scenario.load("paper", ["simulation.t_final=1000"]).run()], fields="metrics").peak <= 1e9


def test_the_issue_s_long_run_is_refused_on_this_machine(tmp_path, monkeypatch, capsys):
    """simulation.t_final = 100000 stores 38 GB: more than this machine has (capped at 16 GB so
    that the test never starts a 4-hour run on a larger machine)."""
    monkeypatch.setenv("HINFNN_MAX_MEMORY", "16GB")
    p = hinfnn_here(["run", "paper", "--set", "simulation.t_final=100000"], tmp_path, monkeypatch, capsys)
    assert p.returncode == 2 and "ResourceError" in _one_line(p.stderr)
    assert "--set simulation.output_interval=" in p.stderr


def test_sparse_output_warns_in_one_line_without_a_source_path(tmp_path, cache):
    p = hinfnn(["run", "paper", "--set", "simulation.t_final=1", "--set", "simulation.output_interval=0.5",
                "--quiet", "--out", "o"], tmp_path, cache)
    assert p.returncode == 0, p.stderr
    line = _one_line(p.stderr)
    assert line.startswith("hinfnn: warning: the runs are stored every 0.5 s")
    assert "simulation.output_interval" in line and ".py" not in line


def test_keys_prints_no_cache_warning(tmp_path, cache):
    """An unusable cache folder (inside a file) is reported by the commands that compile, never by
    `hinfnn keys`."""
    (tmp_path / "file").write_text("")
    p = hinfnn(["keys"], tmp_path, cache, HINFNN_CACHE_DIR=tmp_path / "file" / "x")
    assert p.returncode == 0 and p.stderr == "" and "plant.contact.damping" in p.stdout


def test_warnings_are_one_line(capsys):
    import warnings

    def cmd(args):
        warnings.warn("something odd\n  over two lines", UserWarning)
        return 0

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cli, "_command", lambda name: cmd)
        assert cli.main(["scenarios"]) == 0
    assert capsys.readouterr().err == "hinfnn: warning: something odd over two lines\n"


def test_sampled_period_not_dividing_t_final_exits_2(capsys):
    code = cli.main(["run", "paper", "--set", "simulation.control=sampled", "--set",
                     "simulation.control_period=0.003", "--set", "simulation.t_final=0.05"])
    assert code == 2
    assert "simulation.control_period" in _one_line(capsys.readouterr().err)


@pytest.mark.parametrize("key", ["controller.kind=fl", "plant.contact.damping=50",
                                 "controller.network_f.preset=paper-printed"])
def test_reproduce_rejects_overrides_it_cannot_honour(tmp_path, capsys, key):
    code = cli.main(["reproduce", "--set", key, "--out", str(tmp_path / "p")])
    assert code == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"hinfnn: ConfigError: {key.split('=')[0]}: cannot be overridden")
    assert list(tmp_path.iterdir()) == []


# --- the design and stopped runs in show; show needs only metrics.json ---------------------------------------


def test_show_needs_only_metrics_json_and_prints_the_design(tmp_path, result, capsys):
    out = tmp_path / "r"
    shutil.copytree(result, out)
    for name in ("trajectory.npz", "scenario.toml"):
        (out / name).unlink()
    for png in out.glob("*.png"):
        png.unlink()
    assert cli.main(["show", str(out)]) == 0
    text = capsys.readouterr().out
    assert "RMS e_u1" in text and "hinf_nn" in text
    doc = json.loads((out / "metrics.json").read_text())
    beta = next(r["design"]["gains"]["beta_lam"] for r in doc["runs"] if r["name"] == "hinf_nn")
    assert isinstance(beta, float) and doc["scenario"]["controller"]["gains"]["beta_lam"] == "min"
    assert f"beta_lam = {beta:.4g}" in text
    for needle in ("design of hinf (run hinf)", "design of hinf_nn", "P_p", "residual", "v_p", "bound     beta_lam",
                   "margin", "network   theta_f"):
        assert needle in text, needle
    assert cli.main(["show", str(out), "--no-design"]) == 0
    assert "P_p" not in capsys.readouterr().out


def test_show_of_a_diverged_run_prints_why_and_partial_metrics(tmp_path, capsys):
    out = tmp_path / "d"
    code = cli.main(["run", "paper", "--set", "simulation.t_final=0.05", "--set", "controller.gains.gamma_2=1e6",
                     "--out", str(out), "--quiet", "--no-figures"])
    assert code == 1
    capsys.readouterr()
    assert cli.main(["show", str(out)]) == 0
    text = capsys.readouterr().out
    assert re.search(r"stopped at [0-9.e-]+ s \(partial metrics\)", text)
    assert re.search(r"hinf_nn: stopped at t = [0-9.e-]+ s: torque limit exceeded \(peak \|tau\| = .*\); its metrics "
                     r"cover 0 to [0-9.e-]+ s \(partial\)", text)
    run = json.loads((out / "metrics.json").read_text())["runs"][0]
    assert run["partial"] and run["metrics"]["rms_e_u1"] is not None


@pytest.mark.parametrize("content", ['{"runs": [{"x": 1}]}', '{"runs": "no"}', '[1]', '{"runs": [{"name": "a", '
                                     '"metrics": {"rms_e_u1": "text"}}]}'])
def test_show_on_valid_json_of_another_layout(tmp_path, capsys, content):
    (tmp_path / "metrics.json").write_text(content)
    code = cli.main(["show", str(tmp_path)])
    err = capsys.readouterr().err
    assert code in (0, 2) and "Traceback" not in err and "KeyError" not in err
    if code == 2:
        assert _one_line(err).startswith("hinfnn: LoadError: ")


# --- plot and export round trips ----------------------------------------------------------------------------


def test_plot_redraws_the_same_figures(tmp_path, result, capsys):
    out = tmp_path / "r"
    shutil.copytree(result, out)
    before = {p.name: p.read_bytes() for p in out.glob("*.png")}
    for p in out.glob("*.png"):
        p.unlink()
    assert cli.main(["plot", str(out)]) == 0
    after = {p.name: p.read_bytes() for p in out.glob("*.png")}
    assert sorted(after) == sorted(before)
    assert after == before  # the same data give the same pixels
    assert foreign_files(out) == []
    capsys.readouterr()
    # only some figures, other zoom windows, into another folder
    other = tmp_path / "figs"
    assert cli.main(["plot", str(out), "--figures", "tau,lambda", "--zoom", "0.01:0.02,0.03:0.04",
                     "--out", str(other)]) == 0
    assert sorted(p.name for p in other.iterdir()) == ["lambda.png", "tau.png"]
    assert cli.main(["plot", str(out), "--zoom", "0.02:0.01,1:2"]) == 2
    assert "--zoom: must be two time windows" in capsys.readouterr().err
    # a window outside the 0.05-s runs would draw empty panels: refused, one line, nothing drawn
    (other / "tau.png").unlink()
    assert cli.main(["plot", str(out), "--zoom", "0.01:0.02,1:2", "--out", str(other), "--figures", "tau"]) == 2
    err = capsys.readouterr().err
    assert _one_line(err) == ("hinfnn: ConfigError: --zoom: the window 1:2 s holds no stored sample of the runs "
                              "(they cover 0 to 0.05 s); give windows inside the runs")
    assert not (other / "tau.png").exists()
    assert cli.main(["plot", str(out), "--figures", "nope"]) == 2
    assert "--figures: unknown figure(s) nope" in capsys.readouterr().err
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "u1.png").write_bytes(b"my own")
    assert cli.main(["plot", str(out), "--out", str(tmp_path / "mine")]) == 2
    assert (tmp_path / "mine" / "u1.png").read_bytes() == b"my own"


def _npz(path):
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def test_export_csv_equals_the_npz_exactly(tmp_path, result, capsys):
    out = tmp_path / "r"
    shutil.copytree(result, out)
    assert cli.main(["export", str(out), "--csv"]) == 0
    path = out / "trajectory.csv"
    assert capsys.readouterr().out.strip() == str(path)
    assert foreign_files(out) == []  # recorded in the marker
    rows = list(csv.reader(path.open(encoding="utf-8")))
    head, body = rows[0], rows[1:]
    assert head[:2] == ["run", "t [s]"]
    assert {"tau_1 [N·m]", "tau_2 [N·m]", "lam [N]", "J [-]", "q_1 [rad]", "u1 [m]"} <= set(head)
    npz = _npz(out / "trajectory.npz")
    units = json.loads(str(npz["__units__"]))
    assert units["tau"] == "N·m" and units["t"] == "s" and units["lam"] == "λ units"
    names = [str(n) for n in npz["__runs__"]]
    assert [r[0] for r in body] == [n for n in names for _ in range(len(npz[f"{n}/t"]))]
    col = {h: i for i, h in enumerate(head)}
    from hinfnn.fields import component_units

    for name in names:
        mine = [r for r in body if r[0] == name]
        tags = json.loads(str(npz[f"{name}/__tags__"]))  # each component's unit as the run declares it
        for key, arr in npz.items():
            if not key.startswith(f"{name}/") or "/__" in key:
                continue
            field = key.split("/", 1)[1]
            arr = arr.reshape(len(arr), -1)
            units = component_units(field, arr.shape[1], tags) or [unit(field)] * arr.shape[1]
            for j in range(arr.shape[1]):
                header = f"{field}{'' if arr.shape[1] == 1 else f'_{j + 1}'} [{units[j]}]"
                got = np.array([float(r[col[header]]) for r in mine])
                assert np.array_equal(got, arr[:, j], equal_nan=True), header  # bit for bit
    # the same table in Python, and as Parquet
    df = H.load(out).to_pandas()
    assert list(df.columns) == head and len(df) == len(body)
    assert np.array_equal(df["tau_1 [N·m]"].to_numpy(), np.array([float(r[col["tau_1 [N·m]"]]) for r in body]))
    assert cli.main(["export", str(out), "--parquet", "--run", "hinf"]) == 0
    import pandas as pd

    back = pd.read_parquet(out / "trajectory-hinf.parquet")
    one = H.load(out).to_pandas(run="hinf")
    assert set(back["run"]) == {"hinf"}
    pd.testing.assert_frame_equal(back.reset_index(drop=True), one.reset_index(drop=True), check_dtype=False)
    assert foreign_files(out) == []


def test_export_labels_each_component_in_the_unit_its_run_declares():
    """Column labels from the run's tags (the arm's joints, the task coordinates, the constraint):
    a prismatic joint's q in m and τ in N, rotation coordinates in rad and their moments in N·m, λ
    in N (or a user's θ's unit); without the tags, the field's unit. The UR5 on its table: the tags
    describe() gives."""
    from hinfnn.fields import component_units
    from hinfnn.io.formats import field_columns
    from hinfnn.scenario.setup import describe

    tags = {"joint_units": ["rad", "m"], "coordinates": [["s", "m"], ["phi", "rad"], ["d", "m"]], "lambda_unit": "N"}
    x = np.zeros((4, 2))
    assert [c for c, _ in field_columns("q", x, tags)] == ["q_1 [rad]", "q_2 [m]"]
    assert [c for c, _ in field_columns("qd", x, tags)] == ["qd_1 [rad/s]", "qd_2 [m/s]"]
    assert [c for c, _ in field_columns("tau", x, tags)] == ["tau_1 [N·m]", "tau_2 [N]"]
    assert [c for c, _ in field_columns("tau_sq", x, tags)] == ["tau_sq_1 [(N·m)²]", "tau_sq_2 [N²]"]
    assert [c for c, _ in field_columns("e_u1", x, tags)] == ["e_u1_1 [m]", "e_u1_2 [rad]"]
    assert [c for c, _ in field_columns("f_p", x, tags)] == ["f_p_1 [m/s²]", "f_p_2 [rad/s²]"]
    assert [c for c, _ in field_columns("v_p", x, tags)] == ["v_p_1 [m/s²]", "v_p_2 [rad/s²]"]  # a term's signal
    assert [c for c, _ in field_columns("F", np.zeros((4, 3)), tags)] == ["F_1 [N]", "F_2 [N·m]", "F_3 [N]"]
    assert [c for c, _ in field_columns("lam", np.zeros(4), tags)] == ["lam [N]"]
    assert [c for c, _ in field_columns("e_lam_sq", np.zeros((4, 1)), tags)] == ["e_lam_sq [N²]"]
    assert [c for c, _ in field_columns("v_rate", np.zeros(4), {"lambda_unit": "N·m/θ"})] == ["v_rate [N·m/θ]"]
    assert [c for c, _ in field_columns("q", x, None)] == ["q_1 [rad]", "q_2 [rad]"]  # no tags: the field's unit
    assert component_units("q", 3, tags) is None  # tags for another arm: the field's unit
    ur5 = describe(H.load_scenario("ur5-table", {"controller.kind": "hinf"}, check=False))
    assert ur5["joint_units"] == ["rad"] * 6 and ur5["lambda_unit"] == "N"
    assert component_units("e_u1", 5, ur5) == ["m", "m", "rad", "rad", "rad"]
    assert component_units("F", 6, ur5) == ["N", "N", "N·m", "N·m", "N·m", "N"]


def test_export_to_stdout_and_errors(tmp_path, result, capsys):
    assert cli.main(["export", str(result), "--csv", "--run", "fl", "--out", "-"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("run,t [s],") and set(line.split(",")[0] for line in text.splitlines()[1:]) == {"fl"}
    assert cli.main(["export", str(result)]) == 2
    assert "--csv or --parquet" in capsys.readouterr().err
    assert cli.main(["export", str(result), "--csv", "--run", "nope", "--out", "-"]) == 2
    assert "no run 'nope'" in capsys.readouterr().err


def test_export_of_a_diverged_run_stops_at_t_fail(tmp_path, capsys):
    out = tmp_path / "d"
    assert cli.main(["run", "paper", "--set", "simulation.t_final=0.05", "--set", "controller.gains.gamma_2=1e6",
                     "--out", str(out), "--quiet", "--no-figures"]) == 1
    df = H.load(out).to_pandas()
    t_fail = json.loads((out / "metrics.json").read_text())["runs"][0]["t_fail"]
    assert df["t [s]"].max() <= t_fail + 1e-12 and len(df) >= 1


# --- the sampled robot loop documents and checks the tool force ------------------------------------------------


def test_sampled_loop_rejects_a_wrong_force_shape():
    from hinfnn.controllers import MeasurementError

    sc = H.load_scenario("paper", {"controller.kind": "fl"})
    loop = H.SampledController(sc.build_controller(), sc.build_reference()).loop()
    q = np.asarray(sc.initial_q())
    doc = H.SampledLoop.update.__doc__
    assert "contact force the tool" in doc and "tool point" in doc and "base frame" in doc and "(d,)" in doc
    with pytest.raises(MeasurementError) as ex:
        loop.update(0.0, 1e-3, q, np.zeros(2), np.zeros(3))
    assert ("measurement.force" in str(ex.value) and "contact force at the tool point" in str(ex.value)
            and "(2,)" in str(ex.value))
    with pytest.raises(MeasurementError):
        loop.update(0.0, 1e-3, q, np.zeros(2), 5.0)
    assert np.all(np.isfinite(loop.update(0.0, 1e-3, q, np.zeros(2), np.zeros(2))))


def test_force_replacement_without_atomic_exchange(tmp_path, result, monkeypatch):
    """Where the file system cannot swap two folders atomically, the old result is moved aside,
    the new one renamed in, the old one deleted: same outcome, no leftovers."""
    monkeypatch.setattr("hinfnn.io.folders._exchange", lambda a, b: False)
    out = tmp_path / "r"
    shutil.copytree(result, out)
    assert cli.main(["run", "paper", "--set", "simulation.t_final=0.02", "--set", "controller.kind=fl",
                     "--out", str(out), "--force", "--quiet", "--no-figures"]) == 0
    assert set(H.load(out).trajectories) == {"fl"} and foreign_files(out) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]


def test_files_added_during_a_run_are_kept(tmp_path, result, monkeypatch):
    """A file dropped into the target while the result is computed: the result goes to the next
    free name and the command says so; nothing of the user's is deleted."""
    import hinfnn.io as hio
    from hinfnn.workflows import run as runner

    out = tmp_path / "r"
    shutil.copytree(result, out)

    class Dropping(hio.OutputFolder):
        def _commit(self):
            (self.target / "late.txt").write_text("mine")
            return super()._commit()

    monkeypatch.setattr(hio, "OutputFolder", Dropping)
    res = runner.run_scenario(H.load_scenario("paper", ["simulation.t_final=0.02", "controller.kind=fl"]),
                              out=out, force=True, log=lambda m: None)
    assert res.target == tmp_path / "r-2" and "did not write appeared" in res.note
    assert (out / "late.txt").read_text() == "mine" and _complete(out) and _complete(tmp_path / "r-2")


def test_loading_a_sweep_folder_says_it_is_a_sweep(tmp_path):
    from hinfnn.sweep.store import MANIFEST

    (tmp_path / MANIFEST).write_text("{}")
    with pytest.raises(H.LoadError, match="is a sweep .* not a run's result: its table is .*results.parquet "
                                          r"\(hinfnn.load_sweep\)"):
        H.load(tmp_path)
