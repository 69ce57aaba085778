"""The persistent compilation cache (hinfnn._cache, `hinfnn cache`): where it lives, that a second
process reuses what the first compiled, that it never makes a run fail. No timed assertions:
speed is measured by benchmarks/startup.py."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from hinfnn import _cache, cli

PY = sys.executable
HINFNN = [PY, "-c", "import sys; from hinfnn.cli import main; sys.exit(main())"]
SHOW_DIR = ("import hinfnn, json; hinfnn.configure(); d = hinfnn.cache_dir(); "
            "print(json.dumps(None if d is None else str(d)))")


def _env(**set_vars) -> dict:
    """The test environment without any cache setting, plus ``set_vars`` (None: remove)."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("HINFNN_CACHE_DIR", "XDG_CACHE_HOME", "HINFNN_TRACE_STARTUP")}
    env["JAX_PLATFORMS"] = "cpu"
    for k, v in set_vars.items():
        if v is None:
            env.pop(k, None)
        else:
            env[k] = v
    return env


def _entries(folder: Path) -> dict[str, int]:
    """Cache entries (JAX's ``<name>-<hash>-cache`` files and hinfnn's kept programs,
    ``hinfnn-program-<name>-<hash>-export``) with their modification times."""
    if not folder.is_dir():
        return {}
    return {p.name: p.stat().st_mtime_ns for pattern in ("*-cache", "*-export") for p in folder.glob(pattern)}


# --- where the cache lives ------------------------------------------------------------------


def test_directory_rules_in_fresh_processes(tmp_path):
    """HINFNN_CACHE_DIR, then XDG_CACHE_HOME/hinfnn/jax, then ~/.cache/hinfnn/jax; the disable
    words turn it off. Each case is a new process (the setting is read by `hinfnn.configure()`)."""
    home, home_off = tmp_path / "home", tmp_path / "home_off"
    cases = {
        "env": (dict(HINFNN_CACHE_DIR=str(tmp_path / "mine"), XDG_CACHE_HOME=str(tmp_path / "xdg")),
                tmp_path / "mine"),
        "xdg": (dict(XDG_CACHE_HOME=str(tmp_path / "xdg"), HOME=str(home)), tmp_path / "xdg" / "hinfnn" / "jax"),
        "home": (dict(HOME=str(home)), home / ".cache" / "hinfnn" / "jax"),
        "off": (dict(HINFNN_CACHE_DIR="off", HOME=str(home_off)), None),
        "empty": (dict(HINFNN_CACHE_DIR="", HOME=str(home_off)), None),
    }
    procs = {name: subprocess.Popen([PY, "-c", SHOW_DIR], env=_env(**env), stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
             for name, (env, _) in cases.items()}  # all at once: each one is an `import hinfnn`
    for name, proc in procs.items():
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, (name, err)
        got = json.loads(out.strip().splitlines()[-1])
        expected = cases[name][1]
        assert got == (None if expected is None else str(expected)), name
        assert "CacheWarning" not in err, (name, err)
        if expected is not None:
            assert expected.is_dir() and (expected.stat().st_mode & 0o777) == 0o700, name
    assert not home_off.exists()  # a disabled cache creates nothing


def test_default_cache_dir_reads_only_the_environment(tmp_path):
    """The same rules as a pure function (what `hinfnn.configure()` calls), for every disable word."""
    for word in ("off", "OFF", " Off ", "0", "none", "None", "false", "no", ""):
        assert _cache.default_cache_dir({"HINFNN_CACHE_DIR": word, "XDG_CACHE_HOME": "/x"}) is None, word
    assert _cache.default_cache_dir({"HINFNN_CACHE_DIR": "~/x"}) == Path("~/x").expanduser()
    assert _cache.default_cache_dir({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "hinfnn" / "jax"
    assert _cache.default_cache_dir({"XDG_CACHE_HOME": ""}) == Path("~/.cache/hinfnn/jax").expanduser()
    assert not (tmp_path / "hinfnn").exists()  # nothing created


# --- a second process reuses the compiled programs ------------------------------------------


# one controller kind and no figures: the test runs three processes with cold caches
RUN = ["run", "paper", "--set", "controller.kind=fl", "--set", "simulation.t_final=0.02", "--quiet", "--no-figures",
       "--out"]


def _run(out: Path, env: dict) -> subprocess.CompletedProcess:
    return subprocess.run(HINFNN + RUN + [str(out)], env=env, capture_output=True, text=True, timeout=900)


def _first_chunk(stderr: str) -> dict:
    line = next(ln for ln in stderr.splitlines() if ln.startswith("hinfnn-startup: first-chunk"))
    return json.loads(line.split(maxsplit=3)[3])


def test_second_process_reuses_programs_and_an_unusable_folder_does_not_fail(tmp_path, monkeypatch, capsys,
                                                                             cache_state):
    """Two identical `hinfnn run` processes: the first compiles and writes the cache, the second
    loads every program from it and writes nothing. Meanwhile (in parallel, to save wall time: it
    compiles everything) a run whose cache folder is blocked by a file succeeds with one warning."""
    blocker = tmp_path / "blocker"
    blocker.write_text("in the way")
    unusable = subprocess.Popen(HINFNN + RUN + [str(tmp_path / "unusable")],
                                env=_env(HINFNN_CACHE_DIR=str(blocker / "jax")),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    cache = tmp_path / "cache"
    env = _env(HINFNN_CACHE_DIR=str(cache), HINFNN_TRACE_STARTUP="1")
    try:
        cold = _run(tmp_path / "cold", env)
        assert cold.returncode == 0, cold.stderr
        written = _entries(cache)
        # the run's chunk program kept traced and lowered (hinfnn._programs), and its compiled code
        assert any(name.startswith("hinfnn-program-chunk-") and name.endswith("-export") for name in written), \
            sorted(written)
        assert any(name.startswith("jit_call-") for name in written), sorted(written)
        assert _first_chunk(cold.stderr)["programs"] > 0

        warm = _run(tmp_path / "warm", env)
        assert warm.returncode == 0, warm.stderr
        # nothing new compiled and written, nothing rewritten ...
        assert _entries(cache) == written
        # ... because every program up to the first chunk was a hit (JAX's cache-hit events), and the
        # chunk program was not traced again: the kept one was called (tracing it takes seconds)
        info = _first_chunk(warm.stderr)
        assert info["programs"] > 0 and info["cache_hits"] == info["programs"], info
        assert "chunk" in _first_chunk(cold.stderr)["traced"] and "chunk" not in info["traced"], info
        # nor were the setup programs kept the same way (hinfnn._programs.kept): the start's check
        for name in ("nominal_jacobian_det",):
            assert name in _first_chunk(cold.stderr)["traced"] and name not in info["traced"], (name, info)
        assert "CacheWarning" not in cold.stderr + warm.stderr and not list(cache.glob(".tmp-*"))
        # and the loaded programs compute exactly what the compiled ones did
        m_cold = json.loads((tmp_path / "cold" / "metrics.json").read_text())["runs"]
        m_warm = json.loads((tmp_path / "warm" / "metrics.json").read_text())["runs"]
        assert m_warm == m_cold
    finally:
        _, err = unusable.communicate(timeout=900)
    assert unusable.returncode == 0, err
    # one warning, on one line, without the source path of the code that raised it
    assert err.count("hinfnn: warning: compilation cache off") == 1 and ".py:" not in err, err
    assert (tmp_path / "unusable" / "metrics.json").exists() and blocker.read_text() == "in the way"

    # `hinfnn cache --path` in a process configured by the environment ...
    r = subprocess.run(HINFNN + ["cache", "--path"], env=_env(HINFNN_CACHE_DIR=str(cache)),
                       capture_output=True, text=True, timeout=300)
    assert (r.returncode, r.stdout) == (0, f"{cache}\n"), r.stderr
    # ... and `hinfnn cache` / `--clear` here, on the same folder (no need for new processes)
    monkeypatch.setenv("HINFNN_CACHE_DIR", str(cache))
    assert cli.main(["cache"]) == 0
    shown = capsys.readouterr().out
    assert str(cache) in shown and f"files: {len(written)}" in shown
    (cache / "notes.txt").write_text("not a cache entry")  # --clear removes cache files only
    assert cli.main(["cache", "--clear"]) == 0
    assert f"removed {len(written)} files" in capsys.readouterr().out
    assert _entries(cache) == {} and (cache / "notes.txt").exists()
    assert cli.main(["cache"]) == 0
    assert "files: 0" in capsys.readouterr().out


# --- it never makes a run fail (the run itself: above) -----------------------------------------


@pytest.fixture
def cache_state(monkeypatch):
    """Leave the test process's cache as it was (the session's, see conftest.py) whatever a test does."""
    monkeypatch.setattr(_cache, "_warned", False)
    before = _cache.cache_dir()
    yield
    _cache.enable_cache(before)


def test_enable_cache_degrades_with_one_warning(tmp_path, cache_state):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert _cache.enable_cache(blocker) is None
        assert _cache.enable_cache(blocker / "sub") is None
    assert [w.category for w in caught] == [_cache.CacheWarning]
    assert _cache.cache_dir() is None and "unusable" in _cache.cache_disabled_reason()
    with pytest.raises(TypeError):
        _cache.enable_cache(42)


def test_read_only_folder_disables_the_cache(tmp_path, cache_state):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        if os.access(folder, os.W_OK):
            pytest.skip("running as a user that can write to read-only folders (root)")
        with pytest.warns(_cache.CacheWarning):
            assert _cache.enable_cache(folder) is None
    finally:
        folder.chmod(0o700)


def test_folder_writable_by_everyone_is_refused(tmp_path, cache_state):
    """Entries are executed: a folder others can plant files in is not used."""
    folder = tmp_path / "shared"
    folder.mkdir()
    folder.chmod(0o777)
    with pytest.warns(_cache.CacheWarning, match="writable by every user"):
        assert _cache.enable_cache(folder) is None
    assert _cache.cache_dir() is None


def test_enable_and_disable_in_process(tmp_path, cache_state):
    import jax

    folder = _cache.enable_cache(tmp_path / "c")
    assert folder == tmp_path / "c" and _cache.cache_dir() == folder
    assert jax.config.jax_compilation_cache_dir == str(folder)
    assert _cache.enable_cache("off") is None and _cache.cache_dir() is None
    assert jax.config.jax_compilation_cache_dir is None


def test_a_truncated_entry_costs_a_warning_and_a_compile_not_a_wrong_result(tmp_path, cache_state):
    """JAX's own cache (hinfnn uses its public options) writes entries in place: a process killed
    mid-write leaves a truncated entry. JAX then warns and compiles again; the result is right,
    and `hinfnn cache --clear` removes the entry (docs: _cache module)."""
    import jax
    import jax.numpy as jnp

    folder = _cache.enable_cache(tmp_path / "c")
    f = jax.jit(lambda x: jnp.sin(x) * 3.0 + 0.125)
    assert float(f(jnp.float64(0.5))) == pytest.approx(3.0 * float(jnp.sin(0.5)) + 0.125)
    entries = list(folder.glob("*-cache"))
    assert entries, "the program was cached"
    for e in entries:
        e.write_bytes(e.read_bytes()[: e.stat().st_size // 2])
    _cache.enable_cache(folder)  # a new process's view: JAX reopens the folder
    g = jax.jit(lambda x: jnp.sin(x) * 3.0 + 0.125)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert float(g(jnp.float64(0.5))) == pytest.approx(3.0 * float(jnp.sin(0.5)) + 0.125)
    assert any("Error reading persistent compilation cache entry" in str(w.message) for w in caught)
    n, _ = _cache.cache_size(folder)
    assert n == len(entries) and _cache.clear_cache(folder) > 0 and _cache.cache_size(folder) == (0, 0)


def test_import_changes_no_process_wide_setting():
    """`import hinfnn` leaves JAX_PLATFORMS, x64 and the compilation cache as they were: a user
    with a GPU keeps it (DESIGN: nothing at import)."""
    code = ("import os, jax; before = (os.environ.get('JAX_PLATFORMS'), jax.config.jax_enable_x64, "
            "jax.config.jax_compilation_cache_dir); import hinfnn; "
            "after = (os.environ.get('JAX_PLATFORMS'), jax.config.jax_enable_x64, jax.config.jax_compilation_cache_dir); "
            "print(before == after, after)")
    env = _env(HINFNN_CACHE_DIR=None)
    env.pop("JAX_PLATFORMS", None)
    r = subprocess.run([PY, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.startswith("True"), (r.stdout, r.stderr)


def test_computing_without_float64_is_a_clear_error():
    code = ("import hinfnn, sys\n"
            "try:\n"
            "    hinfnn.simulate(None, None, None, t_final=1.0)\n"
            "except hinfnn.ConfigError as e:\n"
            "    print('ConfigError', e)\n")
    r = subprocess.run([PY, "-c", code], env=_env(), capture_output=True, text=True, timeout=300)
    assert "ConfigError" in r.stdout and "hinfnn.configure()" in r.stdout, (r.stdout, r.stderr)


# --- the command, in process (the test session runs with the cache off) ---------------------


def test_cache_command_when_off(capsys, monkeypatch, cache_state):
    monkeypatch.setenv("HINFNN_CACHE_DIR", "off")
    assert cli.main(["cache", "--path"]) == 0
    assert _cache.cache_dir() is None
    assert capsys.readouterr().out == ""
    assert cli.main(["cache"]) == 0
    assert "off" in capsys.readouterr().out
    assert cli.main(["cache", "--clear"]) == 0
    assert "nothing to clear" in capsys.readouterr().out


def test_cache_command_usage_errors_and_help(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["cache", "--clear", "--path"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        cli.main(["cache", "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text and "HINFNN_CACHE_DIR" in text and "--clear" in text


# --- the kept programs (hinfnn._programs) ---------------------------------------------------------


def test_a_kept_program_is_used_and_one_that_cannot_be_read_is_traced_again(tmp_path, cache_state):
    """In one process with a fresh program cache: the first run keeps its chunk program; after the
    in-memory programs are dropped, a run calls the kept one (the same numbers bit for bit); a kept
    file that is garbage (a truncated write, another tool's) is traced as usual, with the same
    numbers, and no error; with the cache off nothing is kept."""
    import importlib

    import hinfnn as H

    S = importlib.import_module("hinfnn.sim.simulate")
    sc = H.load_scenario("paper", {"controller.kind": "fl", "simulation.t_final": 0.02})
    folder = _cache.enable_cache(tmp_path / "c")
    S._compiled.cache_clear()
    first = sc.simulate("fl")
    (kept,) = folder.glob("hinfnn-program-chunk-*-export")
    S._compiled.cache_clear()
    again = sc.simulate("fl")
    kept.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json at all}")
    S._compiled.cache_clear()
    garbage = sc.simulate("fl")
    for name, a in first.arrays.items():
        np.testing.assert_array_equal(again.arrays[name], a, err_msg=name)
        np.testing.assert_array_equal(garbage.arrays[name], a, err_msg=name)
    _cache.enable_cache(None)
    S._compiled.cache_clear()
    off = sc.simulate("fl")
    np.testing.assert_array_equal(off.arrays["tau"], first.arrays["tau"])
    S._compiled.cache_clear()


def test_a_run_of_many_chunks_compiles_its_kept_program_once(tmp_path, cache_state):
    """A run of three chunks calls its kept program three times: once with the first carry (from
    the jitted initialiser) and twice with the carry the program returned, committed to its device.
    One compiled program serves all three (it compiled a second program for the committed carry,
    25 s for a UR5 chunk, until the arguments were committed before every call), and a second run
    compiles nothing more."""
    import importlib

    import hinfnn as H

    S = importlib.import_module("hinfnn.sim.simulate")
    sc = H.load_scenario("paper", {"controller.kind": "fl", "simulation.t_final": 0.5})  # 501 samples, 3 chunks
    _cache.enable_cache(tmp_path / "c")
    S._compiled.cache_clear()
    sc.simulate("fl")
    chunk = S._compiled(None, S.SINGLE_RECORDS, False, None, S.LoopOptions(), 2, True)[0]  # the program the run used
    (entry,) = chunk._entries.values()
    assert entry[0]._cache_size() == 1
    sc.simulate("fl")
    assert entry[0]._cache_size() == 1
    S._compiled.cache_clear()


def test_a_kept_function_is_traced_once_across_instances(tmp_path, cache_state):
    """hinfnn._programs.KeptFunction (the setup programs: start pose, path checks, final state):
    the first call exports the lowered program to the cache folder; another instance (what a new
    process has) loads it and calls it without tracing the Python function, with the same numbers,
    for a pytree argument and a dict result; under another trace it is an ordinary jit; with the
    cache off it traces as usual."""
    import jax
    import jax.numpy as jnp

    from hinfnn._programs import PREFIX, KeptFunction

    traces = []

    def fn(p, x):
        traces.append(1)
        return {"y": jnp.sin(p["a"] * x), "n": jnp.sum(x) + p["b"]}

    _cache.enable_cache(tmp_path / "c")
    p, x = {"a": jnp.asarray(2.0), "b": 1.5}, jnp.arange(3.0)
    first = KeptFunction(fn, "test_kept")(p, x)
    assert len(traces) == 1 and len(list((tmp_path / "c").glob(f"{PREFIX}test_kept-*"))) == 1
    again = KeptFunction(fn, "test_kept")(p, x)
    assert len(traces) == 1
    for k in ("y", "n"):
        np.testing.assert_array_equal(np.asarray(again[k]), np.asarray(first[k]))
    inside = jax.jit(lambda x: KeptFunction(fn, "test_kept")(p, x)["n"])(x)
    assert len(traces) == 2 and float(inside) == float(first["n"])
    _cache.enable_cache(None)
    KeptFunction(fn, "test_kept")(p, jnp.arange(4.0))  # a new shape: traced (JAX's own trace cache aside)
    assert len(traces) == 3 and len(list((tmp_path / "c").glob(f"{PREFIX}test_kept-*"))) == 1


@pytest.mark.parametrize("members", [1, 3])
def test_a_program_compiled_ahead_leaves_the_run_nothing_to_compile(tmp_path, cache_state, members):
    """hinfnn.sim.RunProgram.lower_ahead and lower_ahead_batch (what simulate_many compiles on its
    threads while another group runs): its ``.compile()`` is the chunk program the run then calls.
    A run (one, or a batch of three plants) after it compiles one kept program (``jit(call)``)
    fewer than the same run from nothing, the same trajectories bit for bit; with the cache off
    there is nothing kept to lower ahead (None)."""
    import importlib

    import jax
    import jax.monitoring as mon

    import hinfnn as H

    S = importlib.import_module("hinfnn.sim.simulate")
    sc = H.load_scenario("paper", {"controller.kind": "fl", "simulation.t_final": 0.02})
    runs = [sc.with_overrides({"plant.arm.m2": 1.0 + 0.1 * i}).run("fl") for i in range(members)]
    r = runs[0]
    compiled: list[str] = []

    def simulate():
        return H.simulate_many([dataclasses.replace(x, name=f"m{i}") for i, x in enumerate(runs)], workers=1)

    def on_duration(event, seconds, fun_name=None, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(str(fun_name))

    def fresh(folder):
        jax.clear_caches()
        S._compiled.cache_clear()
        _cache.enable_cache(folder)
        compiled.clear()

    mon.register_event_duration_secs_listener(on_duration)
    try:
        fresh(tmp_path / "plain")
        plain = simulate()
        from_nothing = compiled.count("jit(call)")
        fresh(tmp_path / "ahead")
        lowered = S.RunProgram.lower_ahead_batch([x.plant for x in runs], [x.controller for x in runs],
                                      [x.reference for x in runs], q0=[x.q0 for x in runs],
                                      limits=[x.limits for x in runs], t_final=r.t_final, dt=r.dt,
                                      control_period=r.control_period, save_interval=r.save_interval,
                                      bookkeeping=r.bookkeeping)
        lowered.compile()
        compiled.clear()
        ahead = simulate()
        assert from_nothing >= 1 and compiled.count("jit(call)") == from_nothing - 1, compiled
        fresh(None)
        assert S.RunProgram.lower_ahead(r.plant, r.controller, r.reference, q0=r.q0, dt=r.dt) is None
    finally:
        mon.unregister_event_duration_listener(on_duration)
        S._compiled.cache_clear()
    assert list(ahead) == list(plain)
    for run, traj in plain.items():
        for name, a in traj.arrays.items():
            np.testing.assert_array_equal(ahead[run].arrays[name], a, err_msg=f"{run} {name}")
