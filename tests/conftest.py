"""Shared fixtures: the paper's Sec. VI models. float64 is on (``hinfnn.configure``) and
implicit rank promotion is an error, as in diffrax's test suite."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

# A compilation cache private to this test session, never the user's ~/.cache: the programs one
# test process compiles (a pytest-xdist worker, a CLI subprocess) are loaded by the others. The
# first process (the xdist controller, or pytest alone) creates it; workers and subprocesses
# inherit HINFNN_CACHE_DIR. The tests of the cache itself set their own folders.
_SESSION_CACHE = "HINFNN_TEST_SESSION_CACHE"
if _SESSION_CACHE not in os.environ:
    os.environ[_SESSION_CACHE] = tempfile.mkdtemp(prefix="hinfnn-test-cache-")
    _OWN_CACHE = True
else:
    _OWN_CACHE = False
os.environ["HINFNN_CACHE_DIR"] = os.environ[_SESSION_CACHE]

# The suite's programs are compiled with XLA's older CPU loop emitters instead of its default
# fusion emitters: about a third less compile time (the paper's adaptive program 4.9 -> 2.5-3.0 s),
# the same run time, and results equal to 2e-13 relative (252 arrays of the paper's three laws, a
# sampled run, a failing run and a batch). The suite is mostly compiling, so it takes 10-11 min instead
# of 15-17 on this project's machines. Users run XLA's default: test_sim.py's
# test_the_default_xla_emitters_give_the_tested_numbers checks that it gives the same samples.
# Set before JAX is imported; subprocesses and Ray workers inherit it.
TEST_XLA_FLAG = "--xla_cpu_use_fusion_emitters=false"
if TEST_XLA_FLAG not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {TEST_XLA_FLAG}".strip()

# One OpenBLAS thread (NumPy's and SciPy's): hinfnn's linear algebra is design-time work on
# matrices of a few rows, and each process's idle BLAS threads cost about 0.1 s of CPU that the
# other pytest-xdist worker needs (a warm `hinfnn run paper`, 0.05 s: 2.0-2.2 s of CPU against
# 2.1-2.3 s). Subprocesses inherit it.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import gc  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

import hinfnn as H  # noqa: E402
from hinfnn.cli import PROGRAM_GC_THRESHOLD  # noqa: E402

H.configure()
# The garbage-collector thresholds of the hinfnn program (the program_gc device): the suite's
# processes trace hundreds of programs, each allocating millions of short-lived objects.
gc.set_threshold(*PROGRAM_GC_THRESHOLD)
jax.config.update("jax_numpy_rank_promotion", "raise")


# Where the suite's time goes (opt-in): HINFNN_COMPILE_REPORT=FILE appends one JSON line per test
# with the JAX programs it compiled in this process, and the seconds spent tracing, lowering and
# compiling them, and the test's wall and CPU seconds (CPU: all this process's threads; a loaded
# machine stretches the wall time, hardly the CPU time; subprocesses a test starts are not counted). Summarise with
# `python tests/compile_report.py FILE`.
_COMPILE_REPORT = os.environ.get("HINFNN_COMPILE_REPORT")
if _COMPILE_REPORT:
    import json
    import time

    import jax.monitoring as _mon

    from hinfnn._startup import StartupTrace

    _spans = StartupTrace._NAMES  # JAX's trace, lower and compile events, named as hinfnn's startup trace does
    _now: dict = {}

    def _on_duration(event, seconds, fun_name=None, **_):
        name = _spans.get(event)
        if name is not None and _now:
            _now[name] = _now.get(name, 0.0) + seconds
            if name == "compile":
                _now["programs"] = _now.get("programs", 0) + 1
            if seconds >= 0.2:  # the programs worth naming: [span, program, seconds]
                _now.setdefault("named", []).append([name, str(fun_name), round(seconds, 3)])

    def _on_event(event, **_):
        if event == "/jax/compilation_cache/cache_hits" and _now:
            _now["cache_hits"] = _now.get("cache_hits", 0) + 1

    _mon.register_event_duration_secs_listener(_on_duration)
    _mon.register_event_listener(_on_event)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        _now.clear()
        _now["t0"], _now["c0"] = time.perf_counter(), time.process_time()
        yield
        wall = time.perf_counter() - _now.pop("t0")
        cpu = time.process_time() - _now.pop("c0")
        with open(_COMPILE_REPORT, "a", encoding="utf-8") as f:
            f.write(json.dumps({"test": item.nodeid, "wall": round(wall, 3), "cpu": round(cpu, 3), "pid": os.getpid(),
                                **{k: v if k == "named" else round(v, 3) for k, v in _now.items()}}) + "\n")
        _now.clear()


#: Modules whose tests take longest, in descending total time of their ungrouped tests: collected
#: first, so that pytest-xdist hands the longest tests out first and both workers finish together.
#: The order is that of one suite run on a busy 2-core host (27 min; the seconds of its 80 slowest
#: tests, about twice an idle run's: test_instruments 250, test_arms 227, test_sim 173, test_robot
#: 100, test_readme 96, test_cache 92, test_sensing 75, test_sweep 51, test_results 48,
#: test_robustness 31). The xdist groups (``xdist_group`` marks) are scheduled before any of these
#: whatever the order (pytest-xdist's --loadscope-reorder: the scopes with most tests first); within
#: a module the order is the file's.
LONGEST_FIRST = ("test_instruments.py", "test_arms.py", "test_sim.py", "test_robot.py",
                 "test_readme.py",  # the README's arm commands: nine UR5 and 3-link programs
                 "test_cache.py", "test_sensing.py", "test_sweep.py", "test_results.py", "test_robustness.py",
                 "test_cli.py")


def _module_fixtures(item) -> list[str]:
    """The module-scoped fixtures defined in ``item``'s own module that it uses."""
    module = getattr(getattr(item, "module", None), "__name__", None)
    names = []
    for name, defs in item._fixtureinfo.name2fixturedefs.items():
        fd = defs[-1]  # the one this test gets
        if fd.scope == "module" and getattr(fd.func, "__module__", None) == module:
            names.append(name)
    return sorted(names)


class _FixtureGroups:
    """A test in a module with no xdist_group mark that uses a module-scoped fixture of its module
    joins the group ``<module>::<fixture>``: pytest-xdist would otherwise hand the fixture's tests
    to both workers, and each would build the fixture (a run, a sweep, a written result). A plugin
    of its own, so that it runs before pytest-xdist names the groups (tryfirst) while the hook
    below runs after it."""

    @pytest.hookimpl(tryfirst=True)
    def pytest_collection_modifyitems(self, config, items):
        if not config.getoption("loadgroup", default=False):
            return
        for item in items:
            if any(True for _ in item.iter_markers("xdist_group")):
                continue
            shared = _module_fixtures(item)
            if shared:
                item.add_marker(pytest.mark.xdist_group(f"{item.path.name}::{shared[0]}"))


def pytest_configure(config):
    config.pluginmanager.register(_FixtureGroups(), "hinfnn-fixture-groups")


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config, items):
    """The modules of :data:`LONGEST_FIRST` first (a stable sort: the others keep their order).

    The xdist_group marks must reach pytest-xdist's ``--dist loadgroup``: it appends the group to
    each marked test's node id, and sends the tests of one group to one worker. pytest 9.2 builds
    node ids another way, so pytest-xdist 3.8's suffix was silently lost and the groups were split
    over both workers (the paper study's 14-s fixture ran twice). If that happens again, every
    grouped test fails and says why (an error raised here would be swallowed by pytest-xdist)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
    if not config.getoption("loadgroup", default=False):
        return
    for item in items:
        if any(True for _ in item.iter_markers("xdist_group")) and "@" not in item.nodeid:
            item.add_marker(pytest.mark.xdist_group_lost)


def pytest_runtest_setup(item):
    if item.get_closest_marker("xdist_group_lost"):
        pytest.fail(f"pytest-xdist's --dist loadgroup does not see this test's xdist_group mark (pytest "
                    f"{pytest.__version__}): its group is split over the workers; pin a pytest it supports",
                    pytrace=False)


def _mappings() -> int:
    """The memory mappings this process holds (Linux; 0 where /proc is not there)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


#: Compiled programs are released when a test leaves the process with more memory mappings than
#: this (the kernel's default limit, vm.max_map_count, is 65,530).
MAPPINGS_RELEASE = 24_000
_release_above = [MAPPINGS_RELEASE]


@pytest.fixture(autouse=True)
def _release_compiled_programs():
    """Every compiled program held in memory is dropped after a test that leaves the worker with
    more than :data:`MAPPINGS_RELEASE` memory mappings (:func:`hinfnn.sim.simulate.release_programs`;
    the session's disk cache keeps them, so a later test loads what it needs again instead of
    compiling it). XLA's CPU backend maps about three regions of memory per compiled program and
    unmaps them only when the program is dropped: a worker that held the ~20,000 programs of a
    whole suite reached the kernel's 65,530 mappings per process (vm.max_map_count), its next mmap
    failed, and it died with a segmentation fault while XLA raised that error (the core of the
    crashed worker had 65,508 segments; seen in compiles and cache writes of unrelated tests)."""
    yield
    n = _mappings()
    if n > _release_above[0]:
        from hinfnn.sim.simulate import release_programs

        release_programs()
        _release_above[0] = max(MAPPINGS_RELEASE, _mappings() + MAPPINGS_RELEASE // 2)  # what is still held stays


@pytest.fixture(scope="session")
def cache():
    """The test session's compilation cache (above), for the subprocesses and Ray workers a test
    starts: they load what the suite compiled instead of compiling it again (6 s per paper run)."""
    return Path(os.environ["HINFNN_CACHE_DIR"])


@pytest.fixture(scope="session")
def reproduced(tmp_path_factory):
    """`hinfnn reproduce --set simulation.t_final=0.05 --quiet` once ("Beyond the paper" at 1e5
    N/m only, to keep it quick): (folder, command line). test_cli checks the paper study's files,
    test_beyond the comparison's; both modules run in the "beyond" xdist group, so on one worker."""
    from hinfnn import cli
    from hinfnn.workflows import paper

    out = tmp_path_factory.mktemp("reproduce") / "paper"
    argv = ["reproduce", "--set", "simulation.t_final=0.05", "--out", str(out), "--quiet"]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(paper, "BEYOND_STIFFNESS", (1e5,))
        assert cli.main(argv) == 0
    return out, "hinfnn " + " ".join(argv)


def pytest_unconfigure(config):
    if _OWN_CACHE and not hasattr(config, "workerinput"):
        shutil.rmtree(os.environ[_SESSION_CACHE], ignore_errors=True)

settings.register_profile("ci", deadline=None, derandomize=True, print_blob=True)
settings.load_profile("ci")

#: The paper's Sec. VI scenario as shipped (src/hinfnn/scenario/files/paper.toml): the tests read the
#: paper's parameters from it (the models it builds), never retype them.
PAPER = H.load_scenario("paper", check=False)
PAPER_SETUP = PAPER.build()


@pytest.fixture(scope="session")
def true_arm():
    return PAPER_SETUP.plant.arm


@pytest.fixture(scope="session")
def nominal_arm():
    return PAPER_SETUP.nominal_arm


@pytest.fixture(scope="session")
def true_surface():
    return PAPER_SETUP.plant.surface


@pytest.fixture(scope="session")
def nominal_surface():
    return PAPER_SETUP.constraint


@pytest.fixture(scope="session")
def reference():
    return PAPER_SETUP.reference


def make_plant(true_arm, true_surface, damping=0.0, disturbance=True):
    """The paper's plant with the given arm and surface, contact damping and disturbance on or off."""
    dist = PAPER_SETUP.plant.disturbance if disturbance else H.SquareWave.none()
    return H.RigidBodyPlant(true_arm, true_surface, H.PenaltyContact(PAPER.plant.contact.stiffness, damping), dist)


@pytest.fixture(scope="session")
def paper_plant(true_arm, true_surface):
    return make_plant(true_arm, true_surface)


#: The paper's start: u1(0) on the true surface (docs/paper-conventions.md, Initial state).
U1_0 = float(PAPER.initial.u1)
