"""Controllers: the FL-like law on an exact model, networks and projection, the variants of
Remarks 1–3, and the one rule (controllers never import the plant)."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hinfnn as H
from hinfnn._pytree import pytree_dataclass
from hinfnn.controllers import TanhNetwork, centres_from, paper_network_f
from hinfnn.reference import RefSample
from conftest import make_plant, U1_0

SRC = Path(H.__file__).parent


def test_controllers_and_model_never_import_the_plant():
    """docs/architecture.md, the one rule: controllers/ and model/ import nothing from plant/ or sim/."""
    for folder in ("controllers", "model"):
        for path in (SRC / folder).glob("*.py"):
            tree = ast.parse(path.read_text())
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom):
                    mod = ("." * node.level) + (node.module or "")
                    assert "plant" not in mod and "sim" not in mod.split("."), f"{path.name}: {mod}"
                if isinstance(node, ast.Import):
                    for alias in node.names:
                        assert "hinfnn.plant" not in alias.name and "hinfnn.sim" not in alias.name


def test_report_never_imports_controllers():
    for path in (SRC / "report").glob("*.py"):
        text = path.read_text()
        assert "controllers" not in "".join(
            line for line in text.splitlines() if line.lstrip().startswith(("import", "from")))


@pytree_dataclass
class PrintedFLReference:
    """The paper's printed FL-like law uses u̇1d where ü1d belongs: feed u̇1d in its place."""

    inner: H.CosineReference

    def __call__(self, t):
        r = self.inner(t)
        return RefSample(u1_d=r.u1_d, u1_d_dot=r.u1_d_dot, u1_d_ddot=r.u1_d_dot, lam_d=r.lam_d)


@pytest.fixture(scope="module")
def exact_runs(true_arm, true_surface, reference):
    """Exact nominal model, no disturbance, damped contact (docs/paper-conventions.md: then FL-like → e → 0)."""
    plant = make_plant(true_arm, true_surface, damping=200.0, disturbance=False)
    ctrl = H.FeedbackLinearization.design(true_arm, true_surface)
    good = H.simulate(plant, ctrl, reference, u1_0=U1_0, t_final=4.0, dt=1e-4, save_every=10)
    printed = H.simulate(plant, ctrl, PrintedFLReference(reference), u1_0=U1_0, t_final=4.0, dt=1e-4, save_every=10)
    return good, printed


def test_fl_like_exact_model_tracks(exact_runs):
    good, _ = exact_runs
    last = good.t >= 2.0
    assert np.abs(good.e_u1[last]).max() < 2e-4  # m, against a 0.2 m amplitude
    assert np.abs(good.e_lam[last]).max() < 0.02  # against a 20 amplitude
    assert np.abs(good.e_u1[good.t >= 3.5]).max() < np.abs(good.e_u1[good.t < 0.5]).max() / 50


def test_printed_fl_law_with_u1d_dot_does_not_track(exact_runs):
    """docs/paper-conventions.md erratum: with u̇1d inside M̄11[·] the position error does not vanish."""
    good, printed = exact_runs
    last = printed.t >= 2.0
    assert np.abs(printed.e_u1[last]).max() > 100 * np.abs(good.e_u1[last]).max()


# --- networks ---------------------------------------------------------------------------------

def test_network_features_output_and_update():
    net = TanhNetwork.build(centres_from(-1.0, 0.5, 5), n_out=2, slope=2.0, w_a=[1.0, 0.0], w_b=[0.0, 3.0])
    a, b = jnp.array([0.3, 9.0]), jnp.array([7.0, 0.1])
    xi = np.asarray(net.features(a, b))
    phi = 0.3 + 0.3
    np.testing.assert_allclose(xi, np.tanh(2.0 * (phi - np.array([-1, -0.5, 0, 0.5, 1.0]))), rtol=1e-14)
    theta = jnp.arange(10.0)
    np.testing.assert_allclose(net.output(xi, theta), [xi @ np.arange(5.0), xi @ np.arange(5.0, 10.0)])
    s = jnp.array([0.5, -2.0])
    np.testing.assert_allclose(net.update(xi, s, theta, 3.0), 3.0 * np.concatenate([0.5 * xi, -2.0 * xi]))


def test_printed_centre_preset_saturates_every_unit():
    """docs/paper-conventions.md: with step 0.05 the F_f centres span −30 … −24.05, so ordinary inputs saturate all."""
    net = paper_network_f("paper-printed")
    c = np.asarray(net.centres)
    assert c[0] == -30.0 and c[-1] == pytest.approx(-24.05)
    xi = np.asarray(net.features(jnp.array([5.0]), jnp.array([0.0])))
    assert np.all(xi > 0.999999)


def test_projection_removes_the_outward_part_on_the_ball():
    net = TanhNetwork.build(centres_from(-1.0, 0.5, 4), radius=2.0)
    xi = net.features(jnp.array([0.2]), jnp.array([0.0]))
    theta = 2.0 * xi / jnp.linalg.norm(xi)  # on the sphere, pointing where the update pushes
    d = net.update(xi, jnp.array([1.0]), theta, 1.0)
    assert abs(float(jnp.dot(theta, d))) < 1e-12  # tangent: the norm stops growing
    d_in = net.update(xi, jnp.array([-1.0]), theta, 1.0)  # pointing inward: untouched
    np.testing.assert_allclose(d_in, -xi)


@pytest.mark.parametrize("bad", [dict(centres=[0.0, 0.0]), dict(centres=[1.0, np.nan]), dict(centres=[]),
                                 dict(centres=[0.0, 1.0], slope=0.0), dict(centres=[0.0, 1.0], radius=-1.0)])
def test_network_validation(bad):
    with pytest.raises(H.DesignError):
        TanhNetwork.build(**bad)


# --- variants along simulated runs ------------------------------------------------------------

VARIANTS = {
    "remark1_augmented": dict(augmented=True),
    "remark2_projection": dict(network_p=TanhNetwork.build(centres_from(-1, 0.05, 40), radius=0.05),
                               network_f=TanhNetwork.build(centres_from(-30, 0.5, 120), radius=5.0)),
    "remark3_alpha_z_4": dict(gains=H.Gains(alpha_z=4.0)),
}


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_variant_runs_satisfy_their_dissipation_inequality(variant, paper_plant, nominal_arm,
                                                           nominal_surface, reference):
    kw = dict(VARIANTS[variant])
    gains = kw.pop("gains", H.Gains())
    ctrl = H.HinfNNController.design(nominal_arm, nominal_surface, gains, **kw)
    tr = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=2.0, dt=1e-4, save_every=10)
    lhs = tr.J_aug + tr.V - tr.V[0]
    assert np.all(lhs <= tr.supply)
    if variant == "remark1_augmented":
        assert tr.J_aug[-1] > tr.J[-1]  # the augmented index adds ‖v_p‖²_R and the v_λ term
        np.testing.assert_allclose(tr.v_lam, -ctrl.gains.beta_lam * tr.e_lam, rtol=1e-12, atol=1e-12)
    if variant == "remark2_projection":
        assert tr.theta_p_norm.max() <= 0.05 * (1 + 1e-12)
        assert tr.theta_f_norm.max() <= 5.0 * (1 + 1e-12)
        assert tr.theta_f_norm.max() > 4.9  # the ball is reached, so the projection was active


def test_controller_is_a_pytree_that_vmaps(nominal_arm, nominal_surface, reference, paper_plant):
    """Controllers with different gains stack and evaluate under vmap like single ones."""
    ctrls = [H.HinfNNController.design(nominal_arm, nominal_surface, H.Gains(K_p=k)) for k in (10.0, 18.0)]
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *ctrls)
    q = paper_plant.initial_q(U1_0)
    meas = paper_plant.measure(q, jnp.array([0.1, -0.2]))
    xc = ctrls[0].init()
    taus = jax.vmap(lambda c: c.torque(0.3, xc, meas, reference))(stacked)
    for i, c in enumerate(ctrls):
        np.testing.assert_allclose(taus[i], c.torque(0.3, xc, meas, reference), rtol=1e-13)
    assert dataclasses.is_dataclass(ctrls[0])
