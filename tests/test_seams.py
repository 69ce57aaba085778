"""The seams: a new controller term, a new surface and a new plant are additions, not edits.

Everything new here is defined in this file and plugged in through the registries
(``hinfnn.controllers.register``, ``hinfnn.scenario.SURFACES`` / ``PLANTS``); it then runs through
``hinfnn.simulate`` and through the command line's scenario loader, with no module of ``src/``
changed. The import rules of DESIGN are checked on the module graph (from the source's import
statements, parsed with ``ast``).
"""

from __future__ import annotations

import ast
import json
from pathlib import Path
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hinfnn as H
from conftest import U1_0
from hinfnn import cli
from hinfnn._pytree import pytree_dataclass
from hinfnn.controllers import Composition, RobustForce, RobustPosition, Term, register, unregister
from hinfnn.model import Surface
from hinfnn.protocols import ContinuousPlant, Measurement
from hinfnn.scenario import PLANTS, SURFACES, SurfaceConfig, param, section
from hinfnn.scenario.sections import RigidPlantConfig
from hinfnn._pytree import static_field

# --- a toy controller term: a constant bias b added to v_λ --------------------------------------


@pytree_dataclass
class ForceBias(Term):
    """b added inside Πᵀ[·] of eq. (26): a known signal, so f_f = e_λ − z − v_λ − b and the
    dissipation inequality keeps holding."""

    b: jax.Array
    side: ClassVar[str] = "force"
    fields: ClassVar[dict] = {"bias_lam": ("λ units", "toy: a constant bias on v_λ")}

    def evaluate(self, ctx, parts):
        v = jnp.full_like(ctx.e_lam, self.b)
        return v, {}, {"bias_lam": v}


# --- a toy surface: the paper's line raised by h ------------------------------------------------


@pytree_dataclass
class RaisedLine(Surface):
    """x2 = (x1 − d_G) tan δ + h, material below (θ > 0 inside)."""

    delta: jax.Array
    d_G: jax.Array
    h: jax.Array
    m: int = static_field(default=1)
    k: int = static_field(default=1)

    def theta(self, x):
        return jnp.atleast_1d((x[0] - self.d_G) * jnp.tan(self.delta) + self.h - x[1])


@section
class RaisedLineConfig(SurfaceConfig):
    delta_deg: float = param(doc="slope, degrees", ge=-89.0, le=89.0)
    d_G: float = param(doc="offset along x1, m", ge=-10.0, le=10.0)
    h: float = param(0.0, doc="raise along x2, m", ge=-1.0, le=1.0)

    def build(self):
        return RaisedLine(delta=jnp.deg2rad(self.delta_deg), d_G=jnp.asarray(self.d_G), h=jnp.asarray(self.h))


# --- a toy plant: the built-in one seen through a force sensor with an offset ----------------------


@pytree_dataclass
class OffsetSensorPlant(ContinuousPlant):
    """The built-in plant whose force sensor reads F + offset (a protocol implementation that
    delegates the physics)."""

    inner: H.RigidBodyPlant
    offset: jax.Array

    @property
    def n(self):
        return self.inner.n

    def initial_state(self, q0, qd0=None):
        return self.inner.initial_state(q0, qd0)

    def joints(self, state):
        return self.inner.joints(state)

    def step_input(self, t, dt):
        return self.inner.step_input(t, dt)

    def sense(self, t, state):
        meas, cache = self.inner.sense(t, state)
        return Measurement(q=meas.q, qd=meas.qd, force=meas.force + self.offset), cache

    def derivative(self, t, state, tau, w, cache):
        return self.inner.derivative(t, state, tau, w, cache)

    def record(self, state, w, cache):
        return self.inner.record(state, w, cache)

    def initial_q(self, u1_0, elbow_up=True):
        return self.inner.initial_q(u1_0, elbow_up)


@section
class OffsetSensorPlantConfig(RigidPlantConfig):
    sensor_offset: tuple[float, ...] = param((0.0, 0.0), doc="force sensor offset, N", ge=-1e3, le=1e3)

    def build(self, **context):
        return OffsetSensorPlant(inner=super().build(**context), offset=jnp.asarray(self.sensor_offset))


@pytest.fixture
def toys():
    """Register the toys for one test, and remove them afterwards (the registries are global)."""
    register(Composition("hinf_bias", "H∞-only + bias",
                         lambda o: (RobustPosition(), RobustForce(), ForceBias(b=jnp.asarray(2.0)))))
    SURFACES.register("raised_line", RaisedLineConfig)
    PLANTS.register("offset_sensor", OffsetSensorPlantConfig)
    yield
    unregister("hinf_bias")
    SURFACES.unregister("raised_line")
    PLANTS.unregister("offset_sensor")


TOY_SCENARIO = """
base = "paper"
name = "toys"
[plant]
engine = "offset_sensor"
sensor_offset = [0.5, -0.5]
[plant.surface]
kind = "raised_line"
delta_deg = 45.5
d_G = 0.8
h = 0.01
[nominal.surface]
kind = "raised_line"
delta_deg = 45.0
d_G = 0.8
h = 0.01
[controller]
kind = "hinf_bias"
[simulation]
t_final = 0.05
"""


def test_toy_term_surface_and_plant_run_through_simulate(toys, nominal_arm, true_arm):
    surface_true = RaisedLine(delta=jnp.deg2rad(45.5), d_G=jnp.asarray(0.8), h=jnp.asarray(0.01))
    surface_nom = RaisedLine(delta=jnp.deg2rad(45.0), d_G=jnp.asarray(0.8), h=jnp.asarray(0.01))
    plant = OffsetSensorPlant(inner=H.RigidBodyPlant(true_arm, surface_true, H.PenaltyContact(1e5, 200.0),
                                                     H.SquareWave.paper()), offset=jnp.array([0.5, -0.5]))
    ctrl = H.controllers.design("hinf_bias", nominal_arm, surface_nom)
    tr = H.simulate(plant, ctrl, H.CosineReference.paper(), u1_0=U1_0, t_final=0.05, dt=1e-4)
    assert int(tr.status) == 0
    np.testing.assert_array_equal(tr.bias_lam, 2.0)  # the term's declared signal is recorded ...
    assert tr.units["bias_lam"] == "λ units"  # ... with its unit
    # the storage bookkeeping follows the composition: the inequality holds along the run
    assert np.all(tr.J_aug + tr.V - tr.V[0] <= tr.supply)
    # the start pose is on the raised surface
    assert abs(float(tr.penetration[0])) < 1e-12
    # and the bias acts: the same run without it differs
    plain = H.simulate(plant, H.HinfController.design(nominal_arm, surface_nom), H.CosineReference.paper(),
                       u1_0=U1_0, t_final=0.05, dt=1e-4)
    assert np.abs(plain.tau - tr.tau).max() > 1e-3


def test_toys_run_through_the_scenario_loader_and_the_cli(toys, tmp_path, capsys):
    path = tmp_path / "toys.toml"
    path.write_text(TOY_SCENARIO)
    sc = H.load_scenario(path)
    assert type(sc.plant).__name__ == "OffsetSensorPlantConfig" and sc.plant.sensor_offset == (0.5, -0.5)
    assert sc.nominal.surface.h == 0.01 and sc.kinds == ["hinf_bias"]
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["runs"][0]["controller"] == "hinf_bias" and doc["runs"][0]["status"] == "ok"
    assert doc["runs"][0]["design"]["terms"] == ["RobustPosition", "RobustForce", "ForceBias"]
    res = H.load(out)
    assert res.scenario.plant.engine == "offset_sensor"  # scenario.toml round-trips the new kinds
    np.testing.assert_array_equal(res.trajectory.bias_lam, 2.0)
    # the new keys are listed and validated like every other
    assert cli.main(["keys"]) == 0
    listed = capsys.readouterr().out
    assert "plant.sensor_offset" in listed and "plant.surface.h" in listed
    assert cli.main(["run", str(path), "--set", "plant.surface.h=5", "--out", str(tmp_path / "x")]) == 2
    assert "plant.surface.h: must be a number >= -1 and <= 1, got 5" in capsys.readouterr().err


# --- the import rules, on the module graph ----------------------------------------------------------

SRC = Path(H.__file__).parent


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _graph() -> dict[str, set[str]]:
    """module -> the hinfnn modules it imports (anywhere in the file, function bodies included)."""
    modules = {_module_name(p): p for p in SRC.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[: len(base) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                # `from pkg import sub` imports the module pkg.sub; `from pkg import name` uses pkg
                candidates = [f"{target}.{a.name}" if f"{target}.{a.name}" in modules else target
                              for a in node.names]
            elif isinstance(node, ast.Import):
                candidates = [a.name for a in node.names]
            else:
                continue
            for c in candidates:
                if c in modules:
                    deps.add(c)
                elif c.startswith("hinfnn"):
                    head = c
                    while head and head not in modules:
                        head = head.rpartition(".")[0]
                    if head:
                        deps.add(head)
        graph[name] = deps - {name}
    return graph


def _reach(graph, start) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for d in graph[todo.pop()]:
            if d not in seen:
                seen.add(d)
                todo.append(d)
    return seen


#: The layers of src/hinfnn, lowest first: a module imports modules of its own layer and of the
#: layers below, never above (the package root, which names everything lazily, excepted).
LAYERS = [
    ("hinfnn._pytree", "hinfnn._config", "hinfnn._cache", "hinfnn._programs", "hinfnn._signals", "hinfnn._startup",
     "hinfnn._loop", "hinfnn._linalg", "hinfnn._declared", "hinfnn.errors", "hinfnn.status", "hinfnn.fields", "hinfnn.protocols", "hinfnn.reference"),
    ("hinfnn.model",),
    ("hinfnn.controllers",),
    ("hinfnn.plant",),
    ("hinfnn.compiled",),
    ("hinfnn.sim",),
    ("hinfnn.metrics", "hinfnn.results", "hinfnn.resources"),
    ("hinfnn.scenario",),
    ("hinfnn.analysis",),
    ("hinfnn.io",),
    ("hinfnn.report",),
    ("hinfnn.experiment",),
    ("hinfnn.workflows",),
    ("hinfnn.sweep",),
    ("hinfnn.robot",),
    ("hinfnn.cli",),
]
#: Besides the layers: (importer prefix, imported prefixes it must never reach, directly or not,
#: or import directly, and why).
RULES = [
    ("hinfnn.model", ("hinfnn.plant", "hinfnn.sim", "hinfnn.scenario"), "reach", "a controller never sees the truth"),
    ("hinfnn.controllers", ("hinfnn.plant", "hinfnn.sim", "hinfnn.scenario"), "reach",
     "a controller never sees the truth"),
    ("hinfnn.sim", ("hinfnn.model", "hinfnn.controllers", "hinfnn.plant"), "reach",
     "the simulator knows plants and controllers only through the protocols"),
    ("hinfnn.report", ("hinfnn.controllers", "hinfnn.plant", "hinfnn.scenario"), "import",
     "reports read tags and results documents, never a controller, a plant or a scenario"),
]


def _layer(mod: str) -> int | None:
    for i, layer in enumerate(LAYERS):
        if any(mod == p or mod.startswith(p + ".") for p in layer):
            return i
    return None


def test_the_import_rules_hold_on_the_module_graph():
    """One check of every import rule (docs/architecture.md): no circle, no arrow from a lower layer
    to a higher one, and the rules of the one rule, the simulator and the reports."""
    graph = _graph()
    unplaced = sorted(m for m in graph if m != "hinfnn" and _layer(m) is None)
    assert not unplaced, f"modules in no layer (add them to LAYERS): {unplaced}"
    upward = sorted((m, d) for m, deps in graph.items() if m != "hinfnn" for d in deps
                    if d != "hinfnn" and _layer(d) > _layer(m))
    assert not upward, f"imports from a lower layer to a higher one: {upward}"
    circles = sorted(m for m in graph if m in _reach(graph, m))
    assert not circles, f"modules on an import circle: {circles}"
    for importer, forbidden, how, why in RULES:
        for mod in graph:
            if mod == importer or mod.startswith(importer + "."):
                seen = _reach(graph, mod) if how == "reach" else graph[mod]
                bad = sorted(d for d in seen if d.startswith(forbidden))
                assert not bad, f"{mod} {'reaches' if how == 'reach' else 'imports'} {bad}: {why}"


def test_the_graph_is_read_correctly():
    """A check that can fail: known edges are found (relative, absolute and in-function imports)."""
    graph = _graph()
    assert "hinfnn.model.reduced" in graph["hinfnn.controllers.law"]
    assert "hinfnn.controllers" in graph["hinfnn.scenario.sections"] or \
        any(d.startswith("hinfnn.controllers") for d in graph["hinfnn.scenario.sections"])
    assert "hinfnn.plant" in _reach(graph, "hinfnn.scenario.sections") or \
        any(d.startswith("hinfnn.plant") for d in _reach(graph, "hinfnn.scenario.sections"))


#: The compile machinery (docs/architecture.md, "Writing code the loop runs", rule 8): the callers
#: apply it (``sim/``, ``analysis.py``, ``experiment/``, ``workflows/``, :mod:`hinfnn.compiled`),
#: never the modules that define the functions it compiles.
COMPILE_MACHINERY = ("hinfnn._loop", "hinfnn._programs", "hinfnn._cache")
BELOW_THE_CALLERS = ("hinfnn.model", "hinfnn.controllers", "hinfnn.plant", "hinfnn.scenario")


def test_no_compile_machinery_below_the_callers():
    """No module under model/, controllers/, plant/ or scenario/ imports the compile machinery
    (``_loop``, ``_programs``, ``_cache``; anywhere in the file, function bodies included): the
    programs they call themselves are declared (:mod:`hinfnn._declared`) and compiled by
    :mod:`hinfnn.compiled`. The scan sees such imports where they are (the simulator's, the
    compiled entries')."""
    graph = _graph()
    found = {m: sorted(d for d in deps if d in COMPILE_MACHINERY) for m, deps in graph.items()
             if m.startswith(BELOW_THE_CALLERS)}
    assert {m: d for m, d in found.items() if d} == {}
    assert "hinfnn._programs" in graph["hinfnn.sim.simulate"] and "hinfnn._programs" in graph["hinfnn.compiled"]
    assert "hinfnn._declared" in graph["hinfnn.plant.rigid"] and "hinfnn._declared" in graph["hinfnn.controllers.sampled"]
    assert not graph["hinfnn._declared"], "the declarations import nothing of hinfnn (the caller layer by name, lazily)"


def test_declared_programs_are_compiled_by_the_callers_as_their_kind_says():
    """Every program declared below the callers (:mod:`hinfnn._declared`) is compiled by
    :func:`hinfnn.compiled.compile_declared` into what the decorator of its kind makes: a setup
    program a pair of ``KeptFunction`` under its name (the arm's compiled with the loop's XLA
    options), a design program ``jit_by_joints``'s pair (the arm's at LLVM -O0); once per process;
    and a declared program computes what its plain function computes."""
    from hinfnn import compiled
    from hinfnn._declared import DeclaredProgram, design_program, setup_program
    from hinfnn._loop import ROLL_FROM_JOINTS, LoopOptions
    from hinfnn._programs import ANALYSIS_OPTIONS, KeptFunction
    from hinfnn.controllers import force_rate, kinds, law
    from hinfnn.plant import rigid

    loop = LoopOptions().compiler_options(ROLL_FROM_JOINTS)
    declared = {"effective_mass": rigid._effective_mass, "initial_q_cartesian": rigid._initial_q_cartesian,
                "nominal_jacobian_det": law._nominal_jacobian_det}
    for name, program in declared.items():
        assert isinstance(program, DeclaredProgram) and program.kind == "setup" and program.name == name
        made = program.compiled
        assert made is program.compiled  # once per process
        assert isinstance(made.plain, KeptFunction) and isinstance(made.arm, KeptFunction)
        assert made.plain.name == made.arm.name == name
        assert made.plain.compiler_options is None and made.arm.compiler_options == loop
    for program in (force_rate.pose_measures, force_rate._newton_path, kinds._observation_jacobians):
        assert isinstance(program, DeclaredProgram) and program.kind == "design"
        made = program.compiled
        assert made.__wrapped__ is program.fn and made is program.compiled
        assert callable(made.plain) and callable(made.arm) and made.plain is not made.arm
    two = H.TwoLinkArm(m1=1.5, m2=1.0, l1=1.0, l2=1.0)
    q = jnp.asarray([0.3, -1.2])
    np.testing.assert_array_equal(law._nominal_jacobian_det(two, q), jax.jit(law._nominal_jacobian_det.fn)(two, q))
    with pytest.raises(ValueError, match="kind"):
        DeclaredProgram(lambda a: a, "loop")
    assert setup_program("x")(lambda a: a).kind == "setup" and design_program(lambda a: a).kind == "design"
    assert ANALYSIS_OPTIONS and compiled.loop_jit(lambda a: a, 2)(1.0) == 1.0


def test_the_loop_formulation_is_a_value_the_objects_hold():
    """The kernels (hinfnn._linalg.Kernels) are a value: ``hold`` sets them on every object of a
    tree (dataclass fields, tuples, lists, dicts and the children of other pytree nodes), rebuilds
    only what changed, and the formulation follows the object, not a context: a URDF chain holding
    ``products`` gives the products' kinematics, the same M to rounding. No module of hinfnn keeps a
    context variable (which code read at trace time)."""
    from hinfnn._linalg import DEFAULT, Kernels
    from hinfnn.model import rbd
    from hinfnn.model.taskmap import PlanarTaskMap
    from hinfnn.model.urdf import UrdfArm, planar_chain

    arm = UrdfArm(planar_chain([1.0, 1.0, 0.5], [1.0, 0.8, 0.5]), PlanarTaskMap(plane="xy", with_angle=True))
    assert arm.kernels == DEFAULT and arm.chain.kernels == DEFAULT

    class Node:  # a pytree node of its own (as the MuJoCo plant), holding an arm
        def __init__(self, inner, tag):
            self.inner, self.tag = inner, tag

    jax.tree_util.register_pytree_node(Node, lambda n: ((n.inner,), n.tag), lambda tag, ch: Node(ch[0], tag))
    loop = Kernels.loop(3, members=16)
    assert loop.arm and loop.minor and not loop.products and Kernels.design(3).products
    assert not Kernels.loop(2).arm and not Kernels.design(2).products
    tree = {"a": (arm, 1.0), "b": [Node(arm, "x")], "c": np.zeros(3)}
    held = loop.hold(tree)
    assert held["a"][0].kernels == loop and held["a"][0].chain.kernels == loop
    assert held["b"][0].inner.chain.kernels == loop and held["b"][0].tag == "x"
    assert held["c"] is tree["c"] and tree["a"][0].kernels == DEFAULT  # the originals untouched
    assert loop.hold(held) is held  # nothing changed: nothing rebuilt
    q = jnp.array([0.3, -0.4, 0.2])
    by_products = Kernels(products=True).hold(arm.chain)
    assert isinstance(by_products._kinematics(q).m, jax.Array)
    np.testing.assert_allclose(by_products._crba(by_products._kinematics(q)), arm.chain._crba(arm.chain._kinematics(q)),
                               rtol=1e-12, atol=1e-12)
    assert rbd.frames(by_products, q).kernels.products and not rbd.frames(arm.chain, q).kernels.products
    src = Path(H.__file__).parent
    readers = [str(p.relative_to(src)) for p in src.rglob("*.py") if "ContextVar(" in p.read_text(encoding="utf-8")]
    assert readers == [], readers
