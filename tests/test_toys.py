"""A new controller family, a new discrete-time plant and a new workflow, all defined in this file.

None is built from the paper's law or hinfnn's plant code paths they replace: a PD law on the motion
with an integral of the force error (its own state pytree, not the law's), a plant stepped by
semi-implicit Euler in discrete time (driven by the simulator's sampled-data path, as MuJoCo is),
and a workflow of two cases with a one-line report. Each goes through the protocols
(:mod:`hinfnn.protocols`), the registries (``hinfnn.controllers.register``, ``hinfnn.scenario.PLANTS``),
the scenario loader, ``hinfnn.simulate``, the command line and the result writer
(:mod:`hinfnn.experiment`) with no file of ``src/`` changed.
"""

from __future__ import annotations

import json
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hinfnn as H
from hinfnn import cli
from hinfnn._pytree import pytree_dataclass, static_field
from hinfnn.controllers import Composition, register, unregister
from hinfnn.experiment import cases, result_folder, simulate_cases, write_result
from hinfnn.io import atomic_write_text, load_metrics
from hinfnn.protocols import Controller, ControllerOutput, DiscretePlant, PlantRecord
from hinfnn.scenario import PLANTS, param, section
from hinfnn.scenario.sections import RigidPlantConfig
from hinfnn.status import RunStatus

# --- a controller family of its own: PD on the motion, integral of the force error ---------------


@pytree_dataclass
class PDState:
    """The toy's state: the integral of e_λ."""

    integral: jax.Array


@pytree_dataclass
class PDForceIntegral(Controller):
    """τ = Ĝ(q) + Ĵᵀ [f_u; 0] + Ĵᵀ Âᵀ (λd − k_i ∫e_λ), f_u = −k_p e_u1 − k_v ė_u1: a computed-gravity PD
    law along the surface and an integral force loop along its normal, from the nominal model. The
    paper's arm: task coordinates = the tip, so the measured tool force is the task-space force."""

    arm: object
    surface: object
    k_p: jax.Array
    k_v: jax.Array
    k_i: jax.Array
    kind: str = static_field(default="pd_fi")

    @property
    def n(self):
        return int(self.arm.n)

    @property
    def m(self):
        return self.surface.m

    @property
    def k(self):
        return self.surface.k

    def init(self):
        return PDState(integral=jnp.zeros(self.k))

    def evaluate(self, t, state, meas, ref):
        r = ref(t)
        x, J = self.arm.h(meas.q), self.arm.J(meas.q)
        x_dot = J @ meas.qd
        A = self.surface.A_hat(x)
        lam = jnp.linalg.solve(A @ A.T, A @ meas.force)
        e_u1, e_lam = x[:self.m] - r.u1_d, lam - r.lam_d
        f_u = -self.k_p * e_u1 - self.k_v * (x_dot[:self.m] - r.u1_d_dot)
        f = jnp.concatenate([f_u, jnp.zeros(self.k)]) + A.T @ (r.lam_d - self.k_i * state.integral)
        tau = self.arm.G(meas.q) + J.T @ f
        return ControllerOutput(tau=tau, dstate=PDState(integral=e_lam), e_u1=e_u1, e_lam=e_lam,
                                signals={"u1": x[:self.m], "lam": lam, "u1_d": r.u1_d, "lam_d": r.lam_d})

    def summary(self):
        return {"kind": self.kind, "terms": [], "gains": {"k_p": float(self.k_p), "k_v": float(self.k_v),
                                                          "k_i": float(self.k_i)}}


def _build_pd_fi(arm, surface, gains, **options):
    return PDForceIntegral(arm=arm, surface=surface, k_p=jnp.asarray(400.0), k_v=jnp.asarray(40.0),
                           k_i=jnp.asarray(5.0))


# --- a discrete-time plant: the built-in physics stepped by semi-implicit Euler -----------------


@pytree_dataclass
class EulerPlant(DiscretePlant):
    """The rigid-body arm and contact of ``inner``, advanced in discrete time: q̇ ← q̇ + dt q̈,
    q ← q + dt q̇ (the held torque over each step). What a physics engine does, in a dozen lines."""

    inner: H.RigidBodyPlant
    fault_name: ClassVar[str] = "none"

    @property
    def n(self):
        return self.inner.n

    def initial_state(self, q0, qd0=None):
        return self.inner.initial_state(q0, qd0)

    def initial_q(self, u1_0, **options):
        return self.inner.initial_q(u1_0, **options)

    def joints(self, state):
        return self.inner.joints(state)

    def step_input(self, t, dt):
        return self.inner.step_input(t, dt)

    def sense(self, t, state):
        return self.inner.sense(t, state)

    def record(self, state, w, cache):
        return PlantRecord(penetration=cache.penetration, signals={"q": state.q, "qd": state.qd})

    def step(self, t, state, tau, dt):
        w = self.inner.step_input(t, dt)
        _, cache = self.inner.sense(t, state)
        d, qdd = self.inner.derivative(t, state, tau, w, cache)
        qd = state.qd + dt * qdd
        return type(state)(q=state.q + dt * qd, qd=qd), qdd


@section
class EulerPlantConfig(RigidPlantConfig):
    discrete: ClassVar[bool] = True

    def build(self, task=None, **context):
        return EulerPlant(inner=super().build(task, **context))


@pytest.fixture
def toys():
    register(Composition("pd_fi", "PD + force integral", terms=lambda o: (), build=_build_pd_fi))
    PLANTS.register("toy_euler", EulerPlantConfig)
    yield
    unregister("pd_fi")
    PLANTS.unregister("toy_euler")


TOY = """
base = "paper"
name = "toy-family"
[plant]
engine = "toy_euler"
[plant.contact]
damping = 200.0
[controller]
kind = "pd_fi"
[simulation]
t_final = 0.05
"""


def test_the_toy_family_and_plant_run_through_simulate(toys):
    """Through the protocols alone: the family's own state pytree is carried and integrated (the
    sampled-data path's forward Euler, since the plant steps itself), its signals recorded; the run
    ends ok; no theorem bookkeeping (the family does not declare it). The seam it is written
    against: seven methods, two of them required, and none of the declared capabilities."""
    from hinfnn import protocols as P

    methods = {n for n, v in vars(P.Controller).items() if callable(v) and not n.startswith("_")}
    assert methods == {"init", "evaluate", "sample", "start", "check_start", "summary", "state_arrays"}
    assert P.Controller.__abstractmethods__ == {"init", "evaluate"}
    sc = H.load_scenario("paper", {"plant.contact.damping": 200.0, "simulation.t_final": 0.05})
    inner = sc.build_plant()
    ctrl = _build_pd_fi(sc.build().nominal_arm, sc.build_constraint(), None)
    assert not any(isinstance(ctrl, c) for c in (P.Constrained, P.Starting, P.Prepared, P.PerSample, P.Dissipative))
    plant = EulerPlant(inner=inner)
    tr = H.simulate(plant, ctrl, sc.build_reference(), q0=sc.initial_q(), t_final=0.05, dt=1e-4, save_every=1)
    assert tr.run_status is RunStatus.OK, tr.reason
    assert {"u1", "lam", "e_u1", "e_lam", "tau", "penetration", "q"} <= set(tr.arrays)
    assert "J" not in tr.arrays and "V" not in tr.arrays
    # the state is the family's: ∫e_λ over the run, by the rectangle rule of the sampled path
    # (the controller updated at every step of the plant, from the error at that step)
    np.testing.assert_allclose(tr.final["integral"], 1e-4 * np.sum(tr.e_lam[:-1], axis=0), rtol=1e-12)
    assert float(np.abs(tr.final["integral"][0])) > 0
    # the discrete plant differs from the continuous one (its own integrator), but holds contact
    assert float(np.max(tr.penetration)) > 0


def test_the_toy_family_and_plant_run_through_the_loader_and_the_cli(toys, tmp_path, capsys):
    path = tmp_path / "toy.toml"
    path.write_text(TOY)
    sc = H.load_scenario(path)
    assert type(sc.plant).__name__ == "EulerPlantConfig" and sc.kinds == ["pd_fi"]
    assert sc.control_period == sc.simulation.dt  # a plant that steps itself: sampled at its step
    out = tmp_path / "out"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "metrics.json").read_text())
    run = doc["runs"][0]
    assert run["controller"] == "pd_fi" and run["status"] == "ok" and run["design"]["gains"]["k_i"] == 5.0
    assert run["tags"]["label"] == "PD + force integral"
    res = H.load(out)
    assert res.scenario.plant.engine == "toy_euler"
    assert "integral" in res.trajectory.final
    assert cli.main(["show", str(out)]) == 0
    assert "pd_fi" in capsys.readouterr().out


def toy_workflow(out, *, log=print):
    """A workflow: two cases (the FL-like law on the paper's arm, two contact dampings, told apart by
    a tag) and a one-line report, through the one result writer."""
    base = H.load_scenario("paper", {"controller.kind": "fl", "simulation.t_final": 0.02})
    todo = (cases(base.with_overrides({"plant.contact.damping": 0.0}), suffix="_stiff", tags={"pad": "none"})
            + cases(base.with_overrides({"plant.contact.damping": 200.0}), suffix="_padded", tags={"pad": "200"}))
    with result_folder(out, command="toy", name="toy", kind="run", log=log) as written:
        outcome = simulate_cases(todo)
        doc = write_result(written.path, base, outcome, command="toy workflow")
        ok = sum(r["status"] == "ok" for r in doc["runs"])
        atomic_write_text(written.path / "report.md", f"toy: {ok} of {len(doc['runs'])} runs ok\n")
    return written.path


def test_a_toy_workflow_writes_through_the_result_writer(tmp_path):
    folder = toy_workflow(tmp_path / "toy", log=lambda m: None)
    assert (folder / "report.md").read_text() == "toy: 2 of 2 runs ok\n"
    doc = load_metrics(folder)
    assert [r["name"] for r in doc["runs"]] == ["fl_stiff", "fl_padded"]
    assert [r["tags"]["pad"] for r in doc["runs"]] == ["none", "200"]
    assert [r["tags"]["contact_damping"] for r in doc["runs"]] == [0.0, 200.0]
    saved = H.load(folder)
    assert saved.trajectories["fl_padded"].info.tags["pad"] == "200"  # the tags round-trip through the npz
    assert cli.main(["plot", str(folder), "--figures", "lambda"]) == 0
