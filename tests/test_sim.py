"""Simulator: RK4 order, dt sensitivity, vmap batches, divergence handling, sampled control."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

import hinfnn as H
from hinfnn.metrics import METRIC_KEYS, STEP_FIELDS
from conftest import PAPER, make_plant, U1_0


def _preloaded_q0(plant, depth=5e-4):
    """Start 0.5 mm inside the surface so the contact force is positive (and smooth) throughout."""
    q0 = plant.initial_q(U1_0)
    x = plant.arm.h(q0)
    return plant.arm.inverse_kinematics_closed(x + depth * plant.surface.inward_normal(x))


@pytest.mark.parametrize("kind", ["hinf", "hinf_nn"])
def test_rk4_convergence_order_is_four(kind, true_arm, true_surface, nominal_arm, nominal_surface, reference):
    """Smooth scenario (damped contact kept closed, no disturbance): the end-state error against a
    dt = 1e-5 run falls as dt⁴."""
    plant = make_plant(true_arm, true_surface, damping=200.0, disturbance=False)
    ctrl = (H.HinfController if kind == "hinf" else H.HinfNNController).design(nominal_arm, nominal_surface)
    q0 = _preloaded_q0(plant)
    T = 0.5
    fine = H.simulate(plant, ctrl, reference, t_final=T, dt=1e-5, q0=q0, save_every=50)
    assert fine.normal_force.min() > 0  # contact never opens: the right-hand side is smooth
    dts = np.array([8e-4, 4e-4, 2e-4])
    errs = []
    for dt in dts:
        tr = H.simulate(plant, ctrl, reference, t_final=T, dt=dt, q0=q0)
        errs.append(np.abs(tr.final["q"] - fine.final["q"]).max() + np.abs(tr.final["qd"] - fine.final["qd"]).max())
    order = np.polyfit(np.log(dts), np.log(errs), 1)[0]
    assert 3.6 < order < 4.4, (errs, order)


@pytest.mark.slow
def test_halving_dt_changes_J10_of_paper_hinf_run_by_under_0_1_percent(paper_plant, nominal_arm,
                                                                         nominal_surface, reference):
    ctrl = H.HinfController.design(nominal_arm, nominal_surface)
    J = [H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=10.0, dt=dt, save_every=s).J[-1]
         for dt, s in ((1e-4, 100), (5e-5, 200))]
    assert abs(J[1] - J[0]) / J[0] < 1e-3, J


def _member_params(i):
    rng = np.random.default_rng(100 + i)
    a = PAPER.plant.arm  # the paper's true arm, perturbed
    arm = H.TwoLinkArm(m1=a.m1 * rng.uniform(0.8, 1.2), m2=a.m2 * rng.uniform(0.8, 1.2),
                       l1=a.l1 * rng.uniform(0.98, 1.02), l2=a.l2 * rng.uniform(0.98, 1.02))
    # a Python float, as the scenario loader gives it: the single runs then share the program of
    # every other paper H∞ + NN run (a NumPy scalar is another argument type, so another program)
    surface = H.InclinedLine(delta=float(np.deg2rad(45.5 + rng.uniform(-1, 1))), d_G=0.8)
    plant = H.RigidBodyPlant(arm, surface, H.PenaltyContact(1e5 * rng.uniform(0.5, 2), 200 * rng.uniform(0.5, 2)),
                    H.SquareWave(amplitude=np.full(2, rng.uniform(0, 4)), period=1.0, phase=0.0))
    gains = H.Gains(K_p=18 * rng.uniform(0.7, 1.3), K_v=9 * rng.uniform(0.7, 1.3))
    return plant, gains


def test_batch_of_8_under_vmap_equals_8_single_runs(nominal_arm, nominal_surface, reference):
    members = [_member_params(i) for i in range(8)]
    plants = [p for p, _ in members]
    ctrls = [H.HinfNNController.design(nominal_arm, nominal_surface, g) for _, g in members]
    batch = H.simulate_batch(plants, ctrls, reference, u1_0=U1_0, t_final=0.5, dt=1e-4, save_every=10)
    assert batch.batched and batch.batch_size == 8
    for i in range(8):
        single = H.simulate(plants[i], ctrls[i], reference, u1_0=U1_0, t_final=0.5, dt=1e-4, save_every=10)
        b = batch.member(i)
        for name in ("q", "qd", "tau", "lam", "z", "J", "theta_f_norm", "V", "supply"):
            np.testing.assert_allclose(b.arrays[name], single.arrays[name], rtol=1e-9, atol=1e-11,
                                       err_msg=f"member {i}: {name}")
    # and the members really differ
    assert np.ptp([batch.member(i).J[-1] for i in range(8)]) > 1e-3


def test_absurd_gain_raises_simulation_error_with_time(paper_plant, nominal_arm, nominal_surface, reference):
    ctrl = H.HinfController.design(nominal_arm, nominal_surface, H.Gains(K_p=1e7, K_v=1e3))
    with pytest.raises(H.SimulationError) as err:
        H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.5, dt=1e-4)
    assert err.value.t_fail is not None and 0 <= err.value.t_fail < 0.5
    assert "t =" in str(err.value)


def test_batch_with_one_diverging_member_finishes_and_marks_only_it(paper_plant, nominal_arm,
                                                                     nominal_surface, reference):
    gains = [H.Gains(), H.Gains(K_p=1e7, K_v=1e3), H.Gains(K_p=20.0)]
    ctrls = [H.HinfController.design(nominal_arm, nominal_surface, g) for g in gains]
    tr = H.simulate_batch(paper_plant, ctrls, reference, u1_0=U1_0, t_final=0.3, dt=1e-4, save_every=10)
    assert list(tr.status != 0) == [False, True, False]
    assert np.isfinite(tr.t_fail[1]) and np.all(np.isnan(tr.t_fail[[0, 2]]))
    ok = H.simulate(paper_plant, ctrls[0], reference, u1_0=U1_0, t_final=0.3, dt=1e-4, save_every=10)
    np.testing.assert_allclose(tr.member(0).q, ok.q, rtol=1e-9)
    assert np.all(np.isfinite(tr.member(1).q))  # frozen at its last good state


def test_a_batch_in_groups_equals_the_batch_in_one(paper_plant, nominal_arm, nominal_surface, reference,
                                                   monkeypatch):
    """The ``batch_group`` loop option (hinfnn._loop): three members in groups of two (the second
    padded with a copy of its member) give the one-group batch's numbers bit for bit, the
    diverging member's status included, and the progress runs once to the end."""
    from hinfnn._loop import LoopOptions

    gains = [H.Gains(), H.Gains(K_p=1e7, K_v=1e3), H.Gains(K_p=20.0)]
    ctrls = [H.HinfController.design(nominal_arm, nominal_surface, g) for g in gains]
    run = functools.partial(H.simulate_batch, paper_plant, ctrls, reference, u1_0=U1_0, t_final=0.3, dt=1e-4,
                            save_every=10)
    one = run()
    grouped = LoopOptions(batch_group=2)
    assert [list(g) for g in grouped.groups(3)] == [[0, 1], [2, 2]]
    assert [list(g) for g in LoopOptions(batch_group=0).groups(3)] == [[0, 1, 2]]
    # by default by the arm: groups of at most 100 for the two-link arm, 4,096 for larger arms
    assert [len(g) for g in LoopOptions().groups(1000, 2)] == [100] * 10
    assert [len(g) for g in LoopOptions().groups(1000, 6)] == [1000]
    assert [len(g) for g in LoopOptions().groups(5000, 7)] == [2500, 2500]
    assert LoopOptions().for_joints(2).batch_group == 100 and LoopOptions(batch_group=7).for_joints(6).batch_group == 7
    seen = []
    two = run(progress=lambda done, total, what: seen.append((done, total)), loop=grouped)
    assert seen[-1] == (2 * 3000, 2 * 3000) and [d for d, _ in seen] == sorted(d for d, _ in seen)
    np.testing.assert_array_equal(two.status, one.status)
    np.testing.assert_array_equal(two.t_fail, one.t_fail)
    assert set(two.arrays) == set(one.arrays) and set(two.final) == set(one.final)
    for name in one.arrays:
        np.testing.assert_array_equal(two.arrays[name], one.arrays[name], err_msg=name)
    for name in one.final:
        np.testing.assert_array_equal(two.final[name], one.final[name], err_msg=name)


def test_a_batch_starts_each_controller_object_once_and_shares_its_state(paper_plant, nominal_arm, nominal_surface,
                                                                           reference, monkeypatch):
    """``simulate_batch`` takes a controller's initial state (``init()``) once per controller
    object, not once per member (at B = 1,024 of the UR5 it was 0.8 of the 1.1 ms per member its
    setup took): members that share one object run as members with equal copies of it do, bit for
    bit when listed, to rounding when given once (the controller is then not batched)."""
    ctrl = H.HinfNNController.design(nominal_arm, nominal_surface, H.Gains())
    copies = [H.HinfNNController.design(nominal_arm, nominal_surface, H.Gains()) for _ in range(3)]
    calls = []
    init = type(ctrl).init
    monkeypatch.setattr(type(ctrl), "init", lambda self, **given: calls.append(id(self)) or init(self, **given))
    run = functools.partial(H.simulate_batch, [paper_plant] * 3, references=reference, u1_0=U1_0, t_final=0.05,
                            dt=1e-4, save_every=10)
    shared, listed = run(controllers=ctrl), run(controllers=[ctrl] * 3)
    assert calls == [id(ctrl), id(ctrl)]  # one per batch
    calls.clear()
    distinct = run(controllers=copies)
    assert sorted(calls) == sorted(id(c) for c in copies)
    for name in shared.arrays:
        np.testing.assert_array_equal(distinct.arrays[name], listed.arrays[name], err_msg=name)
        # one object given once is another program (the controller not batched): the same to rounding
        np.testing.assert_allclose(shared.arrays[name], listed.arrays[name], rtol=1e-12, atol=1e-12, err_msg=name)


def test_an_arm_batch_laid_out_member_minor_is_its_single_runs():
    """A batch of a 3-joint URDF arm with the ``member_minor`` loop option (on by default for
    batches of 16 or more members of arms of 3 or more joints: the stored values laid out with the
    member axis minor) gives each
    member's single run to rounding, over two chunks (the carry handed from one program call to the
    next); the compiled batch really is laid out so, and only with the option."""
    import re

    import jax
    import jax.numpy as jnp

    from hinfnn._linalg import Kernels
    from hinfnn._loop import LoopOptions

    # by default on for batches of 16 or more members of an arm of 3 or more joints
    assert LoopOptions().for_joints(3, members=16).member_minor
    assert not LoopOptions().for_joints(3, members=15).member_minor and not LoopOptions().for_joints(3).member_minor
    assert not LoopOptions().for_joints(2, members=100).member_minor
    assert not LoopOptions(member_minor=False).for_joints(6, members=256).member_minor
    assert LoopOptions(member_minor=True).for_joints(6, members=2).member_minor
    sc = H.load_scenario("planar3-drum", {"controller.kind": "hinf"})
    plant, ctrl, ref = sc.build_plant(), sc.build_controller("hinf"), sc.build_reference()
    q0 = np.asarray(sc.initial_q(plant))
    q0s = [q0, q0 + np.array([2e-3, -1e-3, 1e-3])]
    fields = ("q", "qd", "tau", "lam", "supply")
    run = dict(t_final=0.25, dt=1e-4, save_every=10, fields=fields)  # a batch's chunk: 2,000 steps
    batch = H.simulate_batch([plant, plant], ctrl, ref, q0=q0s, loop=LoopOptions(member_minor=True), **run)
    for i, q in enumerate(q0s):
        one = H.simulate(plant, ctrl, ref, q0=q, **run)
        for name in fields:
            np.testing.assert_allclose(batch.member(i).arrays[name], one.arrays[name], rtol=1e-9, atol=1e-12,
                                       err_msg=f"member {i}: {name}")
    assert not np.allclose(batch.member(0).arrays["tau"], batch.member(1).arrays["tau"])

    # the layout: a (5, r, …) array with the member axis minor is f64[5,r,…]{0,…} in XLA's text (XLA
    # lays out a few so of its own accord)
    Q = jnp.stack([jnp.asarray(q0s[0]) + 0.01 * i for i in range(5)])
    minor = re.compile(r"f64\[5,[2-9][0-9,]*\]\{0,")
    count = {}
    for on in (True, False):
        k = Kernels.loop(3, members=5, options=LoopOptions(member_minor=on))
        arm = k.hold(ctrl.arm)
        f = jax.vmap(lambda q, qd: k.chol(k.stored(k.mm(arm.M(q), arm.M(qd)))))  # a new trace
        program = jax.jit(f).lower(Q, 0.1 * Q).compile()
        count[on] = len(minor.findall(program.as_text()))
        np.testing.assert_allclose(program(Q, 0.1 * Q), f(Q, 0.1 * Q), rtol=1e-12)
    assert count[True] > 3 * count[False] + 20, count


def test_what_a_run_stores_is_one_option_object(paper_plant, nominal_arm, nominal_surface, reference):
    """``save=H.Save(every, interval, fields)`` is the keywords ``save_every``, ``save_interval``,
    ``fields`` as one value: the same run bit for bit; both at once is a ConfigError naming ``save``."""
    ctrl = H.HinfController.design(nominal_arm, nominal_surface)
    run = dict(u1_0=U1_0, t_final=0.02, dt=1e-4)
    a = H.simulate(paper_plant, ctrl, reference, save=H.Save(every=20, fields=("q", "tau")), **run)
    b = H.simulate(paper_plant, ctrl, reference, save_every=20, fields=("q", "tau"), **run)
    assert set(a.arrays) == set(b.arrays) and a.arrays["t"].shape == (11,)
    for name in a.arrays:
        np.testing.assert_array_equal(a.arrays[name], b.arrays[name], err_msg=name)
    with pytest.raises(H.ConfigError, match="save"):
        H.simulate(paper_plant, ctrl, reference, save=H.Save(every=20), save_every=20, **run)
    with pytest.raises(H.ConfigError, match="save"):
        H.simulate_batch([paper_plant], ctrl, reference, save={"every": 20}, **run)


def test_penetration_limit_stops_a_run(paper_plant, nominal_arm, nominal_surface, reference):
    ctrl = H.HinfController.design(nominal_arm, nominal_surface)
    tr = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.2, dt=1e-4,
                    limits=H.Limits(torque=1e5, penetration=1e-4), raise_on_failure=False)
    assert int(tr.status) == 3 and 0 < float(tr.t_fail) < 0.2


def test_a_stopped_runs_metrics_include_the_step_that_stopped_it(paper_plant, nominal_arm, nominal_surface,
                                                                  reference):
    """Stopped by the torque limit between two stored samples (every 50th step): the metrics cover
    the steps up to the stop, so peak |τ| is the one the reason names, t_end the stop; the samples
    after the stop summarise nothing more."""
    ctrl = H.HinfController.design(nominal_arm, nominal_surface)
    tr = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.2, dt=1e-4, save_every=50,
                    limits=H.Limits(torque=170.0), raise_on_failure=False)
    assert tr.run_status is H.RunStatus.TORQUE_LIMIT
    stop = round(float(tr.t_fail) / 1e-4)
    assert stop % 50 != 0  # between two samples
    m = H.compute_metrics(tr)
    bad = float(tr.fail_details["tau_peak"])
    assert bad > 170.0 and max(m["peak_abs_tau"]) == bad and f"{bad:.4g}" in tr.reason
    assert m["t_end"] == pytest.approx(float(tr.t_fail)) and m["partial"]
    assert np.max(np.abs(tr.arrays["tau"][:tr.valid_samples()])) < bad  # the stored samples alone miss it
    after = tr.arrays["tau_abs_max"][tr.valid_samples() + 1:]
    assert np.all(after == 0.0)  # nothing counted after the stop
    # the same run stored at every step: the same peak and the same RMS error over the same steps
    every = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.2, dt=1e-4, save_every=1,
                       limits=H.Limits(torque=170.0), raise_on_failure=False)
    m1 = H.compute_metrics(every)
    assert float(every.t_fail) == float(tr.t_fail) and m1["peak_abs_tau"] == m["peak_abs_tau"]
    np.testing.assert_allclose(m1["rms_e_u1"], m["rms_e_u1"], rtol=1e-12)
    np.testing.assert_allclose(m1["fraction_out_of_contact"], m["fraction_out_of_contact"], rtol=1e-12)


def test_sampled_control_at_high_rate_approaches_continuous(true_arm, true_surface, nominal_arm,
                                                          nominal_surface, reference):
    """Zero-order hold at 10 kHz (every step) vs 1 kHz vs continuous, damped contact."""
    plant = make_plant(true_arm, true_surface, damping=200.0)
    ctrl = H.HinfController.design(nominal_arm, nominal_surface)
    cont = H.simulate(plant, ctrl, reference, u1_0=U1_0, t_final=2.0, dt=1e-4, save_every=10)
    fast = H.simulate(plant, ctrl, reference, u1_0=U1_0, t_final=2.0, dt=1e-4, save_every=10, control_period=1e-4)
    slow = H.simulate(plant, ctrl, reference, u1_0=U1_0, t_final=2.0, dt=1e-4, save_every=10, control_period=1e-3)
    err_fast = np.abs(fast.e_u1 - cont.e_u1).max()
    err_slow = np.abs(slow.e_u1 - cont.e_u1).max()
    assert err_fast < 1e-3 and err_fast < err_slow
    # the held torque is piecewise constant over each 1 ms (10-step) period
    short = H.simulate(plant, ctrl, reference, u1_0=U1_0, t_final=0.05, dt=1e-4, control_period=1e-3, save_every=1)
    blocks = short.tau[:-1].reshape(-1, 10, 2)
    np.testing.assert_array_equal(blocks, np.repeat(blocks[:, :1], 10, axis=1))
    assert np.abs(np.diff(blocks[:, 0], axis=0)).max() > 0


def test_sampled_accumulators_are_integrated_at_every_rk4_stage():
    """Under a zero-order hold the accumulators (J, the supply) are integrated with the state by
    RK4, their rates evaluated at every stage. Their rates vary fast within a step when a high-gain
    law rings at the hold's rate: the stabilised adaptive law on the undamped 1e5 N/m contact,
    held at 10 kHz (every step). Halving dt under the same hold then moves the supply by 4.4e-6
    relative (0.5 s); the trapezoidal rule from one evaluation per step (tried: the plant alone at
    RK4's stages, docs/performance.md, sixth pass) was 27 % off at dt = 0.1 ms, 16 % at 0.05 ms.
    Tried again in the fifteenth pass with the integrand's left limit at every sample instant (taken
    from the update's own evaluation of the law): second order, but the supply 40 % off at
    dt = 0.1 ms, 9.9 % at 0.05 ms and 2.5 % at 0.025 ms, where RK4's stages agree to 4.4e-6; this
    test fails on it."""
    base = {"plant.contact.stiffness": 1e5, "plant.contact.damping": 0.0, "controller.kind": "hinf_nn",
            "simulation.control": "sampled", "simulation.control_period": 1e-4, "simulation.t_final": 0.5}
    out = []
    for dt in (1e-4, 5e-5):
        tr = H.load_scenario("paper-stable", {**base, "simulation.dt": dt}).simulate("hinf_nn")
        out.append(np.array([tr.final[k] for k in ("J", "supply")]))
    np.testing.assert_allclose(out[1], out[0], rtol=1e-4)


BOOKKEEPING_FIELDS = ("J", "J_aug", "supply", "V", "f_p", "f_f")


@pytest.mark.parametrize("mode", ["continuous", "sampled", "sampled, rolled"])
def test_a_run_without_the_bookkeeping_is_the_same_run_without_its_fields(mode, true_arm, true_surface, nominal_arm,
                                                                          nominal_surface, reference):
    """``bookkeeping=False`` drops the theorems' bookkeeping and nothing else: the same records to
    rounding (bit for bit where XLA compiles the rest alike), none of J, J_aug, the supply, V, f_p,
    f_f, NaN for the final accumulators, and no dissipation verdict in the metrics. Under sampled
    control the law then leaves RK4's stages: ``rolled`` runs the arms' loop (the stages a loop, the
    record cut out of the derivative, hinfnn.sim.integrate.split_aux) on the paper's arm. A damped
    contact: the paper's law does not hold the undamped 1e5 N/m one at 1 kHz."""
    plant = make_plant(true_arm, true_surface, damping=200.0)
    ctrl = H.HinfNNController.design(nominal_arm, nominal_surface)
    kw = dict(u1_0=U1_0, t_final=0.2, dt=1e-4, control_period=None if mode == "continuous" else 1e-3)
    if mode.endswith("rolled"):
        from hinfnn._loop import LoopOptions

        kw["loop"] = LoopOptions(rolled_rk4=True)
    on = H.simulate(plant, ctrl, reference, **kw)
    off = H.simulate(plant, ctrl, reference, bookkeeping=False, **kw)
    assert set(on.arrays) - set(off.arrays) == set(BOOKKEEPING_FIELDS) and set(off.arrays) < set(on.arrays)
    for k, v in off.arrays.items():
        np.testing.assert_allclose(v, on.arrays[k], rtol=1e-12, atol=1e-13, err_msg=k)
    for k in ("J", "J_aug", "supply"):
        assert np.isnan(off.final[k]) and np.isfinite(on.final[k]) and on.final[k] > 0
    m_on, m_off = H.compute_metrics(on), H.compute_metrics(off)
    assert m_on["dissipation_holds_for_all_t"] is True and m_on["J_T"] > 0
    assert m_off["dissipation_holds"] is None and m_off["dissipation_holds_for_all_t"] is None
    assert np.isnan(m_off["J_T"])
    for k in ("rms_e_u1", "rms_e_lam", "peak_abs_tau", "fraction_out_of_contact"):
        assert m_off[k] == pytest.approx(m_on[k], rel=1e-12, abs=1e-15), k


@pytest.mark.parametrize("rolled,book", [(False, True), (True, False)])
def test_a_frozen_law_between_samples_is_integrated_as_before_bit_for_bit(rolled, book, true_arm, true_surface,
                                                                          nominal_arm, nominal_surface, reference):
    """Under sampled control the law's state is frozen between samples: RK4 integrates the plant and
    the accumulators alone (``frozen_law``), the law's state passed through. It is what RK4 gave
    with the law's zero rate (y + dt/6 · 0), bit for bit, for every stored field: the two-link
    arm's written-out stages with the bookkeeping (J, the supply at RK4's stages), the arms' rolled
    loop without it."""
    from hinfnn._loop import LoopOptions

    plant = make_plant(true_arm, true_surface, damping=200.0)
    ctrl = H.HinfNNController.design(nominal_arm, nominal_surface)
    kw = dict(u1_0=U1_0, t_final=0.1, dt=1e-4, control_period=1e-3, bookkeeping=book)
    runs = [H.simulate(plant, ctrl, reference, loop=LoopOptions(rolled_rk4=rolled, frozen_law=frozen), **kw)
            for frozen in (True, False)]
    assert runs[0].arrays.keys() == runs[1].arrays.keys() and ("J" in runs[0].arrays) == book
    for k in runs[0].arrays:
        np.testing.assert_array_equal(runs[0].arrays[k], runs[1].arrays[k], err_msg=k)
    for k in runs[0].final:
        np.testing.assert_array_equal(runs[0].final[k], runs[1].final[k], err_msg=f"final {k}")
    # and the option does something: the frozen program adds nothing to the law's state at RK4's stages
    import importlib

    import jax.numpy as jnp

    S = importlib.import_module("hinfnn.sim.simulate")
    y0 = S.initial_state(plant, ctrl, u1_0=U1_0)
    adds = []
    for frozen in (True, False):
        chunk, _, init = S._compiled(None, S.SINGLE_RECORDS, True, None,
                                     LoopOptions(rolled_rk4=rolled, frozen_law=frozen), plant.n, book)
        args = (plant, ctrl, reference, S.Limits(), init(ctrl, y0, plant.n), jnp.zeros((), jnp.int64),
                *S.RunProgram.chunk_scalars(10, 1e-4, 10, 10, 1))
        adds.append(chunk.jitted.lower(*args).as_text().count("stablehlo.add"))
    assert adds[0] < adds[1], adds


def test_the_bookkeeping_is_a_scenario_setting_that_reaches_runs_and_batches():
    """``simulation.bookkeeping = false`` reaches a scenario's run (its own compiled program: the
    group key differs) and a batch of its runs."""
    over = {"controller.kind": "hinf", "simulation.t_final": 0.05}
    on, off = (H.load_scenario("paper", {**over, "simulation.bookkeeping": b}) for b in (True, False))
    assert on.simulation.bookkeeping is True and off.simulation.bookkeeping is False
    r_on, r_off = on.run("hinf"), off.run("hinf")
    assert r_off.bookkeeping is False and r_on.group_key() != r_off.group_key()
    assert "J" in on.simulate("hinf").arrays and "J" not in off.simulate("hinf").arrays
    with pytest.raises(H.ConfigError, match=r"bookkeeping: must be True or False, got 'false'"):
        H.simulate(r_off.plant, r_off.controller, r_off.reference, q0=r_off.q0, t_final=0.01, bookkeeping="false")
    runs = [dataclasses.replace(r_off, name=f"m{i}") for i in range(2)]
    out = H.simulate_many(runs, fields="metrics")
    assert all("J" not in t.arrays and np.isnan(t.final["J"]) for t in out.values())


def test_groups_simulated_at_once_equal_them_one_after_the_other():
    """``simulate_many`` compiles its groups' programs on threads and runs the groups one at a
    time: the same trajectories bit for bit as one group after the other, the progress summed over
    the groups up to the total, and an error in one group (here: its progress callback) raised to
    the caller, the others stopped after their chunk; a number of threads that is not one is a
    ConfigError naming ``workers`` (a NumPy integer is one)."""
    sc = H.load_scenario("paper", {"simulation.t_final": 0.05, "controller.kind": ["fl", "hinf", "hinf_nn"]})
    runs = [sc.run(kind, kind) for kind in ("fl", "hinf", "hinf_nn")] + [sc.run("hinf", "hinf-2")]
    assert len({r.group_key() for r in runs}) == 3  # the two hinf runs are one batch
    calls = []
    serial = H.simulate_many(runs, workers=1)
    threaded = H.simulate_many(runs, workers=3, progress=lambda d, t, what: calls.append((d, t, what)))
    assert list(threaded) == [r.name for r in runs]
    for name in serial:
        a, b = serial[name].arrays, threaded[name].arrays
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k], equal_nan=True) for k in a), name
    total = sum(r.n_steps for r in runs)
    assert all(t == total for _, t, _ in calls) and calls[-1][0] == total
    assert [d for d, _, _ in calls] == sorted(d for d, _, _ in calls)
    assert {w for _, _, what in calls for w in what.split(", ")} <= {"fl", "hinf", "hinf-2", "hinf_nn"}

    def failing(done, total, what):
        if "hinf_nn" in what:
            raise RuntimeError("the callback of hinf_nn fails")

    with pytest.raises(RuntimeError, match="the callback of hinf_nn fails"):
        H.simulate_many(runs, workers=3, progress=failing)
    from hinfnn.sim import batch as B

    assert B.default_workers(1) == 1 and 1 <= B.default_workers(100) <= B.MAX_WORKERS
    for bad in (0, -2, 1.5, "2", True, np.True_, np.float64(2.0)):
        with pytest.raises(H.ConfigError, match="workers") as err:
            H.simulate_many(runs, workers=bad)
        assert repr(bad) in str(err.value)
    # a NumPy integer is a whole number like Python's
    numpy_workers = H.simulate_many(runs, workers=np.int64(2))
    for name in numpy_workers:
        a, b = serial[name].arrays, numpy_workers[name].arrays
        assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in a), name


# --- storage: decimated records, exact step statistics, field selection ------------------------

def test_default_storage_is_one_sample_per_ms_and_size_follows_the_decimation(paper_plant, nominal_arm,
                                                                               nominal_surface, reference):
    ctrl = H.HinfNNController.design(nominal_arm, nominal_surface)
    full = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.3, dt=1e-4, save_every=1)
    dec = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.3, dt=1e-4)  # save_interval = 1 ms
    coarse = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.3, dt=1e-4, save_interval=0.05)
    assert (full.save_every, dec.save_every, coarse.save_every) == (1, 10, 500)
    assert full.t.shape == (3001,) and dec.t.shape == (301,) and coarse.t.shape == (7,)
    for name, v in dec.arrays.items():  # every stored array shrinks by the same factor
        assert v.shape[0] == 301 and v.nbytes * 10 - full.arrays[name].nbytes == 9 * v[0].nbytes, name
    # the decimated samples are the same numbers as every 10th step of the full run
    for name in ("q", "tau", "lam", "z", "J", "V", "supply", "theta_f_norm"):
        np.testing.assert_allclose(dec.arrays[name], full.arrays[name][::10], rtol=1e-12, atol=1e-13,
                                   err_msg=name)


def test_metrics_cover_every_step_whatever_the_storage(paper_plant, nominal_arm, nominal_surface, reference):
    """The step summaries (tau_abs_max, tau_variation, *_sq, *_abs_max, steps_out_of_contact)
    make every metric but the sampled dissipation margin independent of the decimation, equal to
    the metric of the every-step trajectory; Trajectory.decimated merges them the same way.

    3.05 s: neither run's records fill its last compiled chunk (30,501 and 611 records in chunks of
    2,000 and 40), so the final record (t_final) is taken after padding records; its summaries
    must still cover the steps since the record before it."""
    ctrl = H.HinfController.design(nominal_arm, nominal_surface)
    full = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=3.05, dt=1e-4, save_every=1)
    dec = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=3.05, dt=1e-4, save_every=50)
    np.testing.assert_array_equal(full.tau_abs_max, np.abs(full.tau))
    np.testing.assert_allclose(full.tau_variation[1:], np.abs(np.diff(full.tau, axis=0)), rtol=1e-12)
    np.testing.assert_allclose(full.tau_sq, full.tau**2, rtol=1e-12)
    np.testing.assert_array_equal(full.steps_out_of_contact, full.penetration < -1e-9)
    m_full, m_dec = H.compute_metrics(full), H.compute_metrics(dec)
    sampled = H.compute_metrics(dataclasses.replace(dec, arrays={k: v for k, v in dec.arrays.items()
                                                                  if k not in STEP_FIELDS}))
    for key in METRIC_KEYS:
        if key == "dissipation_min_margin":
            assert m_dec[key] >= m_full[key] - 1e-9  # a min over fewer samples
            continue
        if m_full[key] is None:  # min_task_margin: not recorded for the native coordinates
            assert m_dec[key] is None, key
            continue
        np.testing.assert_allclose(m_dec[key], m_full[key], rtol=1e-9, err_msg=key)
    # from the samples alone they would differ (the contact bounces between samples)
    assert sampled["peak_abs_tau"] != m_full["peak_abs_tau"]
    assert sampled["tv_rate_tau_last2s"] != m_full["tv_rate_tau_last2s"]
    merged = full.decimated(50 * 1e-4)
    for name in STEP_FIELDS:
        np.testing.assert_allclose(merged.arrays[name], dec.arrays[name], rtol=1e-9, atol=1e-9, err_msg=name)


def test_fields_selects_what_is_stored(paper_plant, nominal_arm, nominal_surface, reference):
    ctrl = H.HinfController.design(nominal_arm, nominal_surface)
    tr = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.1, dt=1e-4, fields=("e_u1", "tau"))
    assert set(tr.arrays) == {"t", "e_u1", "tau"}
    allf = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.1, dt=1e-4)
    # same numbers, to rounding relative to the signal's scale (XLA fuses the programs that store
    # fewer fields differently, so a value crossing zero can differ in its last bits)
    np.testing.assert_allclose(tr.tau, allf.tau, rtol=1e-14, atol=1e-14 * np.abs(allf.tau).max())
    lean = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.1, dt=1e-4, fields="metrics")
    assert len(lean.arrays) == 18  # METRICS_FIELDS the paper arm records (joint_limit_margin and task_margin: not)
    m_lean, m_all = H.compute_metrics(lean), H.compute_metrics(allf)
    for key in m_all:
        if m_all[key] is None:  # min_task_margin: not recorded for the native coordinates
            assert m_lean[key] is None, key
            continue
        if key == "verdict":  # the verdicts: the same words and booleans, the same numbers
            for k, v in m_all[key].items():
                if v is None or isinstance(v, bool) or (isinstance(v, list) and not (v and isinstance(v[0], float))):
                    assert m_lean[key][k] == v, k
                else:
                    np.testing.assert_allclose(m_lean[key][k], v, rtol=1e-12, err_msg=k)
            continue
        np.testing.assert_allclose(m_lean[key], m_all[key], rtol=1e-12, err_msg=key)
    with pytest.raises(H.ConfigError, match="unknown trajectory field.*'torque'"):
        H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.1, dt=1e-4, fields=("torque",))


def test_stack_on_the_host_equals_jnp_stack_and_still_traces():
    """simulate_batch stacks its members' pytrees with NumPy when they are values (jnp.stack of B
    operands compiles a B-operand program per leaf shape: 126 s of a B = 4,096 UR5 batch's first
    run) and with jnp.stack under a trace: the same values, dtypes and shapes either way."""
    import importlib

    import jax
    import jax.numpy as jnp

    S = importlib.import_module("hinfnn.sim.simulate")
    items = [{"a": jnp.arange(3.0) * i, "b": np.int32(i), "c": (float(i), jnp.eye(2) + i)} for i in range(5)]
    got = S.stack(items)
    want = jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *items)
    for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
        assert g.shape == w.shape and g.dtype == w.dtype
        np.testing.assert_array_equal(np.asarray(g), np.asarray(w))
    traced = jax.jit(lambda xs: S.stack(xs))(items)
    for g, w in zip(jax.tree.leaves(traced), jax.tree.leaves(want)):
        np.testing.assert_array_equal(np.asarray(g), np.asarray(w))


def test_batch_of_one_equals_a_single_run(paper_plant, nominal_arm, nominal_surface, reference):
    ctrl = H.HinfNNController.design(nominal_arm, nominal_surface)
    b = H.simulate_batch([paper_plant], ctrl, reference, u1_0=U1_0, t_final=0.2, dt=1e-4)
    s = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.2, dt=1e-4)
    assert b.batched and b.batch_size == 1 and b.status.shape == (1,)
    for k in s.arrays:
        np.testing.assert_array_equal(b.member(0).arrays[k], s.arrays[k], err_msg=k)
    for k in s.final:
        np.testing.assert_array_equal(b.member(0).final[k], s.final[k], err_msg=k)


@pytest.mark.parametrize("stages,once", [(4, True), (4, False), (3, True)])
def test_rolled_rk4_stages_equal_the_unrolled_ones(stages, once):
    """The rolled_rk4 loop option (hinfnn._loop): the stages as a loop (all four, or 2–4 after the
    first written out: ``rolled_stages``; the aux at every stage or under a branch at the first:
    ``record_once``) give the same step as the four stages written out, bit for bit, on a
    nonlinear pytree system with a time-dependent force (the stage times matter), the first
    stage's auxiliary output, and order four."""
    import jax
    import jax.numpy as jnp

    from hinfnn.sim.integrate import RK4

    def f(t, y):
        q, v = y["q"], y["v"]
        s = jnp.sin(q)  # shared by the derivative and the aux
        return {"q": v, "v": -s - 0.3 * v + jnp.cos(3.0 * t)}, jnp.sum(q) + 0.0 * jnp.sum(s)

    y0 = {"q": jnp.array([0.4, -1.2, 2.0]), "v": jnp.array([0.1, 0.0, -0.5])}

    def run(rolled, dt, n, aux=False):
        step = jax.jit(lambda t, y: RK4.of(rolled, stages, once).step(f, t, y, dt))
        y, sums = y0, []
        for k in range(n):
            y, s = step(k * dt, y)
            sums.append(float(s))
        x = np.concatenate([np.asarray(y["q"]), np.asarray(y["v"])])
        return (x, sums) if aux else x

    (a, sa), (b, sb) = run(True, 0.05, 40, aux=True), run(False, 0.05, 40, aux=True)
    np.testing.assert_array_equal(a, b)
    assert sa == sb and sa[0] == float(jnp.sum(y0["q"]))
    fine = run(False, 0.05 / 8, 320)
    err = [np.max(np.abs(run(True, dt, n) - fine)) for dt, n in ((0.1, 20), (0.05, 40))]
    assert 12.0 < err[0] / err[1] < 20.0  # 2⁴ = 16


def test_split_aux_cuts_the_aux_alone_out_of_the_derivative():
    """split_aux (the record_once loop option): the first part gives f's derivative and, from the
    residuals it returns, the second gives f's aux, both bit for bit; the first holds none of the
    operations only the aux needs (here its exp and its reduction), the second none of those the
    derivative needs alone (its cos), and the values they share (sin q) are computed once, in the
    first; f with a side effect is not cut."""
    import jax
    import jax.numpy as jnp

    from hinfnn.sim.integrate import split_aux

    c = jnp.array([1.0, 2.0, 3.0])  # a closed-over constant

    def f(t, y):
        s = jnp.sin(y * c)
        return {"y": s * jnp.cos(t * y)}, {"a": jnp.sum(jnp.exp(s)), "b": s}

    t, y = 0.3, jnp.array([0.2, -0.7, 1.1])
    first, second, aux0, _ = split_aux(f, t, y)
    dy, res = first(t, y)
    want_dy, want_aux = f(t, y)
    np.testing.assert_array_equal(dy["y"], want_dy["y"])
    aux = second(res)
    np.testing.assert_array_equal(aux["a"], want_aux["a"])
    np.testing.assert_array_equal(aux["b"], want_aux["b"])
    assert aux0["a"].shape == () and aux0["b"].shape == (3,) and float(jnp.sum(aux0["b"])) == 0.0
    prims = lambda fn, *a: [e.primitive.name for e in jax.make_jaxpr(fn)(*a).jaxpr.eqns]  # noqa: E731
    p1, p2 = prims(lambda t, y: first(t, y), t, y), prims(second, res)
    assert "exp" not in p1 and "reduce_sum" not in p1 and p1.count("sin") == 1 and "cos" in p1
    assert "exp" in p2 and "reduce_sum" in p2 and "sin" not in p2 and "cos" not in p2

    def g(t, y):
        jax.debug.callback(lambda v: None, y)
        return f(t, y)

    assert split_aux(g, t, y) is None

    # the partial cut (a step that takes no record): the entries named in `every` computed, bit
    # for bit, the others left as they were, and none of the operations only the others need
    *_, partial = split_aux(f, t, y, every=("b",))
    old = {"a": jnp.asarray(7.0), "b": jnp.zeros(3)}
    got = partial(res, old)
    assert float(got["a"]) == 7.0
    np.testing.assert_array_equal(got["b"], want_aux["b"])
    p3 = prims(lambda r: partial(r, old), res)
    assert "exp" not in p3 and "reduce_sum" not in p3


def test_rk4_step_takes_the_whole_aux_only_when_asked():
    """RK4.step's ``take`` (rolled stages, record_once): the state is the same whether the step
    takes its aux or not, the entries in ``every`` are the first stage's either way, the others
    zeros when not taken."""
    import jax
    import jax.numpy as jnp

    from hinfnn.sim.integrate import RK4

    def f(t, y):
        return {"y": -y["y"] + jnp.sin(t)}, {"every": 2.0 * y["y"], "rest": jnp.exp(y["y"])}

    y0 = {"y": jnp.array([0.3, -1.0])}
    step = jax.jit(lambda y, take: RK4("rolled").step(f, 0.1, y, 0.01, take=take, every=("every",)))
    (ya, aux_a), (yb, aux_b) = step(y0, True), step(y0, False)
    np.testing.assert_array_equal(ya["y"], yb["y"])
    np.testing.assert_array_equal(aux_a["every"], 2.0 * y0["y"])
    np.testing.assert_array_equal(aux_b["every"], aux_a["every"])
    np.testing.assert_allclose(aux_a["rest"], np.exp(y0["y"]), rtol=1e-15)  # XLA's exp and NumPy's: 1 ulp
    assert not np.any(np.asarray(aux_b["rest"]))


@pytest.fixture
def sim_module():
    """hinfnn.sim.simulate itself (the package re-exports its ``simulate`` function by that name)."""
    import importlib

    return importlib.import_module("hinfnn.sim.simulate")


@pytest.fixture
def rhs_traces(sim_module, monkeypatch):
    """A list that grows by one each time plant and controller (``rhs``) are traced."""
    calls = []
    rhs = sim_module.rhs
    monkeypatch.setattr(sim_module, "rhs", lambda *a: calls.append(1) or rhs(*a))
    return calls


@pytest.mark.parametrize("rolled", [False, True])
def test_a_chunk_traces_the_dynamics_once_per_written_stage(rolled, paper_plant, nominal_arm, nominal_surface,
                                                            reference, monkeypatch, sim_module, rhs_traces):
    """Tracing cost (paid by every process, cached program or not): a chunk program traces plant
    and controller (``rhs``) once per RK4 stage written out, 4 times, or once when the stages
    are rolled (rolled_rk4). The record's shapes and the rolled stages' shapes come from those
    same traces (jax.jit's trace cache), not from second ones: 8 and 4 before."""
    import jax.numpy as jnp

    from hinfnn._loop import LoopOptions

    S = sim_module
    ctrl = H.HinfNNController.design(nominal_arm, nominal_surface, H.Gains())
    carry = S._init_carry(ctrl, S.initial_state(paper_plant, ctrl, u1_0=U1_0), 2)
    # a fresh jit (no trace cached), the paper's 2-joint arm with the stages rolled or written out
    chunk = S._compiled.__wrapped__(None, 3, False, S.select(None), LoopOptions(rolled_rk4=rolled))[0]
    chunk.jitted.trace(paper_plant, ctrl, reference, S.Limits(), carry, jnp.asarray(0), jnp.asarray(6),
                jnp.asarray(1e-4), jnp.asarray(1), jnp.asarray(2), jnp.asarray(3))
    assert len(rhs_traces) == (1 if rolled else 4)


def test_output_intervals_and_fields_share_one_compiled_program(paper_plant, nominal_arm, nominal_surface,
                                                                reference, sim_module, rhs_traces):
    """The steps between stored samples and the samples a chunk takes are arguments of the chunk
    program, not constants of it: single runs storing every step, every 2nd, 5th, 10th or 30th
    step, with every field or only some, reuse one program (nothing traced again), in chunks of
    several sizes (the every-step run is 4 chunks of 200 samples; the 30-step run is one chunk,
    21 of its 67 samples), and each stores what it should. A batch keeps one program per chunk
    size (records_per_chunk)."""
    from hinfnn.sim.plan import StepPlan, records_per_chunk

    records = [records_per_chunk(e) for e in (1, 2, 10, 11, 100, 101, 10_000)]
    assert records == [2000, 200, 200, 20, 20, 20, 20]
    single = [StepPlan(n_steps=10_000 * e, dt=1e-4, save_every=e).chunk(batched=False)
              for e in (1, 2, 10, 11, 100, 1999, 2000, 10_000)]
    assert single == [(200, 200), (200, 200), (200, 200), (200, 182), (200, 20), (200, 2), (200, 1), (200, 1)]
    ctrl = H.HinfController.design(nominal_arm, nominal_surface, H.Gains())
    runs = {10: H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.06, save_every=10)}
    traced = len(rhs_traces)  # 4, or 0 when an earlier test of this process compiled the structure
    for e in (5, 2, 1, 30):
        runs[e] = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.06, save_every=e)
    some = H.simulate(paper_plant, ctrl, reference, u1_0=U1_0, t_final=0.06, save_every=1, fields=("lam", "tau"))
    assert len(rhs_traces) == traced
    assert list(some.arrays) == ["t", "lam", "tau"]
    for e, traj in runs.items():
        np.testing.assert_allclose(traj.t, np.arange(0, 601, e) * 1e-4, rtol=1e-14, atol=1e-17)
        for name in ("q", "tau", "lam"):
            np.testing.assert_array_equal(traj.arrays[name], runs[1].arrays[name][::e], err_msg=f"{name} {e}")
    for name in ("lam", "tau"):
        np.testing.assert_array_equal(some.arrays[name], runs[1].arrays[name], err_msg=name)


def test_record_shapes_are_what_a_run_stores_and_are_traced_once_per_structure(paper_plant, nominal_arm,
                                                                                 nominal_surface, reference,
                                                                                 monkeypatch, sim_module, rhs_traces):
    """resources.plan's per-sample sizes (record_shapes) equal the arrays a run stores, for all
    fields and for ``"metrics"``; asking again for the same structure traces nothing."""
    S = sim_module
    monkeypatch.setattr(S, "_RECORD_SHAPES", {})
    ctrl = H.HinfController.design(nominal_arm, nominal_surface, H.Gains())
    q0 = paper_plant.initial_q(U1_0)
    shapes = S.RunProgram.record_shapes(paper_plant, ctrl, reference, q0=q0)
    traj = H.simulate(paper_plant, ctrl, reference, q0=q0, t_final=0.002)
    assert shapes == {k: (v.shape[1:], v.dtype) for k, v in traj.arrays.items()}
    n = len(rhs_traces)
    assert S.RunProgram.record_shapes(paper_plant, ctrl, reference, q0=q0) == shapes and len(rhs_traces) == n
    metrics = S.RunProgram.record_shapes(paper_plant, ctrl, reference, q0=q0, fields="metrics")  # its own structure
    assert len(rhs_traces) == n + 1 and metrics == {k: v for k, v in shapes.items() if k in S.select("metrics")} != shapes


def test_a_single_run_s_memory_plan_is_the_trace_its_run_uses(paper_plant, nominal_arm, nominal_surface,
                                                               reference, monkeypatch, sim_module, rhs_traces):
    """record_shapes(single=True) traces the single-run chunk program itself (four RK4 stages
    written out), and the run that follows traces nothing: jax.jit keeps the trace. The shapes are
    the stored arrays', and another choice of fields is read off the same trace. (Fresh jit
    objects for this test, and no program kept on disk by an earlier test or process: the
    exported-program cache is off here, so that the trace this test counts happens.)"""
    import functools

    from hinfnn import _programs as programs

    S = sim_module
    monkeypatch.setattr(programs.ExportedProgram, "_path", lambda self, key: None)
    monkeypatch.setattr(S, "_RECORD_SHAPES", {})
    monkeypatch.setattr(S, "_compiled", functools.lru_cache(maxsize=8)(S._compiled.__wrapped__))
    ctrl = H.HinfController.design(nominal_arm, nominal_surface, H.Gains())
    q0 = paper_plant.initial_q(U1_0)
    shapes = S.RunProgram.record_shapes(paper_plant, ctrl, reference, q0=q0, single=True)
    assert len(rhs_traces) == 4
    traj = H.simulate(paper_plant, ctrl, reference, q0=q0, t_final=0.002)
    assert len(rhs_traces) == 4
    assert shapes == {k: (v.shape[1:], v.dtype) for k, v in traj.arrays.items()}
    metrics = S.RunProgram.record_shapes(paper_plant, ctrl, reference, q0=q0, fields="metrics", single=True)
    assert len(rhs_traces) == 4 and metrics == {k: v for k, v in shapes.items() if k in S.select("metrics")}


_DEFAULT_EMITTERS_RUN = """
import sys, numpy as np, hinfnn as H
H.configure()
traj = H.load_scenario("paper", {"simulation.t_final": 0.3}).simulate("hinf_nn")
np.savez(sys.argv[1], **traj.arrays)
"""


def test_the_default_xla_emitters_give_the_tested_numbers(tmp_path):
    """The suite compiles with XLA's older CPU emitters (conftest.py, for compile time); users run
    XLA's default. The adaptive law (every term of the law) on the paper plant, 0.3 s, in a process
    with XLA's default options: every stored sample of every field equal to 1e-10 of its scale."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from conftest import TEST_XLA_FLAG

    assert TEST_XLA_FLAG in os.environ["XLA_FLAGS"]
    env = {**os.environ, "XLA_FLAGS": os.environ["XLA_FLAGS"].replace(TEST_XLA_FLAG, "").strip(),
           "PYTHONPATH": str(Path(H.__file__).resolve().parents[1])}
    subprocess.run([sys.executable, "-c", _DEFAULT_EMITTERS_RUN, str(tmp_path / "default.npz")], env=env,
                   check=True, timeout=600)
    ours = H.load_scenario("paper", {"simulation.t_final": 0.3}).simulate("hinf_nn").arrays
    with np.load(tmp_path / "default.npz") as default:
        assert set(default.files) == set(ours)
        for name in default.files:
            a, b = np.asarray(ours[name]), default[name]
            assert a.shape == b.shape, name
            scale = max(1.0, float(np.max(np.abs(b)))) if b.size else 1.0
            assert np.max(np.abs(a - b), initial=0.0) <= 1e-10 * scale, name


def test_release_programs_then_the_same_run_gives_the_same_numbers():
    """release_programs drops every compiled program of the process (a workflow over many arms
    calls it between them); the next run compiles or loads its program again and gives the same
    numbers bit for bit."""
    sc = H.load_scenario("paper", {"simulation.t_final": 0.005, "controller.kind": "hinf_nn"})
    before = sc.simulate()
    H.sim.release_programs()
    after = sc.simulate()
    for key, value in before.arrays.items():
        np.testing.assert_array_equal(value, after.arrays[key], err_msg=key)


def _whiles(jaxpr):
    """The while loops of a jaxpr, outermost first, through the jaxprs its equations hold."""
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "while":
            yield eqn
        for p in eqn.params.values():
            for x in (p if isinstance(p, (tuple, list)) else (p,)):
                sub = x.jaxpr if hasattr(x, "jaxpr") and hasattr(x.jaxpr, "eqns") else x
                if hasattr(sub, "eqns"):
                    yield from _whiles(sub)


@pytest.mark.parametrize("case", ["paper", "paper-unprepared", "ur5-table"])
def test_the_step_loop_reads_no_array_larger_than_a_block(case, paper_plant, nominal_arm, nominal_surface,
                                                          reference, sim_module, monkeypatch):
    """XLA's CPU runtime runs a loop body's kernels one after the other only when none touches
    more than 512 bytes; otherwise every kernel of every step goes through its scheduler (the
    paper's adaptive run 2.5 times slower). The controller's constants are cut into the blocks
    the law reads before the loop (``prepared``, the ``Prepared`` capability): no input of the step loop (the while
    loop inside the scan over records) holds more than 64 values, on the paper's arm and on the
    UR5 (P_p 10 × 10, F_p's centres 5 × 40). Without it F_f's 120 centres enter the loop whole
    (the check can fail)."""
    import math

    import jax.numpy as jnp

    from hinfnn._loop import LoopOptions
    from hinfnn.controllers.law import BLOCK, ReducedOrderController

    S = sim_module
    if case == "ur5-table":
        sc = H.load_scenario("ur5-table", {"controller.kind": "hinf_nn"})
        plant, ctrl, ref = sc.build_plant(), sc.build_controller("hinf_nn"), sc.build_reference()
        y0 = S.initial_state(plant, ctrl, q0=sc.initial_q(plant))
    else:
        if case == "paper-unprepared":
            monkeypatch.setattr(ReducedOrderController, "prepared", lambda self: self)
        plant, ref = paper_plant, reference
        ctrl = H.HinfNNController.design(nominal_arm, nominal_surface, H.Gains())
        y0 = S.initial_state(plant, ctrl, u1_0=U1_0)
    carry = S._init_carry(ctrl, y0, plant.n)
    chunk = S._compiled.__wrapped__(None, 3, False, S.select(None), LoopOptions(), plant.n)[0]
    traced = chunk.jitted.trace(plant, ctrl, ref, S.Limits(), carry, jnp.asarray(0), jnp.asarray(6),
                                jnp.asarray(1e-4), jnp.asarray(1), jnp.asarray(2), jnp.asarray(3))
    scan = next(e for e in traced.jaxpr.jaxpr.eqns if e.primitive.name == "scan")
    step_loop = next(_whiles(scan.params["jaxpr"].jaxpr))
    sizes = sorted(math.prod(v.aval.shape) for v in step_loop.params["body_jaxpr"].jaxpr.invars)
    assert (sizes[-1] <= BLOCK) == (case != "paper-unprepared"), sizes[-5:]


def test_records_are_taken_in_blocks_whose_stacks_the_runtime_runs_inline(paper_plant, nominal_arm,
                                                                          nominal_surface, reference, sim_module):
    """``record_blocks``: a single run's 200 record slots are taken as 8 blocks of an inner scan of
    25 (the paper's arm records at most 2 values per field), so no array the inner scan stacks
    holds more than 64 values and XLA runs its body inline (a stacked 200-sample record sent it
    through the runtime's scheduler once per sample: 10 µs per sample on the paper's arm, 70 on
    the UR5). The same run with one scan over the samples gives the same numbers."""
    import math

    import jax.numpy as jnp

    from hinfnn._loop import SEQUENTIAL_VALUES, LoopOptions

    S = sim_module
    ctrl = H.HinfNNController.design(nominal_arm, nominal_surface, H.Gains())
    y0 = S.initial_state(paper_plant, ctrl, u1_0=U1_0)
    carry = S._init_carry(ctrl, y0, paper_plant.n)
    chunk = S._compiled.__wrapped__(None, S.SINGLE_RECORDS, False, S.select(None), LoopOptions(), paper_plant.n)[0]
    traced = chunk.jitted.trace(paper_plant, ctrl, reference, S.Limits(), carry, jnp.asarray(0), jnp.asarray(6),
                                jnp.asarray(1e-4), jnp.asarray(1), jnp.asarray(2), jnp.asarray(3))
    blocks = next(e for e in traced.jaxpr.jaxpr.eqns if e.primitive.name == "scan")
    inner = next(e for e in blocks.params["jaxpr"].jaxpr.eqns if e.primitive.name == "scan")
    assert blocks.params["length"] * inner.params["length"] == S.SINGLE_RECORDS
    n_carry = inner.params["num_carry"]
    stacked = [math.prod(v.aval.shape) for v in inner.outvars[n_carry:]]  # (length, *field)
    assert inner.params["length"] > 1 and max(stacked) <= SEQUENTIAL_VALUES, stacked

    kw = dict(u1_0=U1_0, t_final=0.05, dt=1e-4, save_every=1)
    one = H.simulate(paper_plant, ctrl, reference, loop=LoopOptions(record_blocks=False), **kw)
    blocked = H.simulate(paper_plant, ctrl, reference, **kw)
    assert one.arrays.keys() == blocked.arrays.keys()
    for k in one.arrays:
        np.testing.assert_allclose(blocked.arrays[k], one.arrays[k], rtol=1e-12, atol=1e-300, err_msg=k)


def test_the_metrics_table_says_why_a_run_has_no_dissipation_verdict():
    """A run without the bookkeeping prints n/a for J(T) and the verdict, and a line that says why
    (its own overrides first, else the document's scenario)."""
    from hinfnn.report.markdown import metrics_table

    doc = {"scenario": {"simulation": {"bookkeeping": True}},
           "runs": [{"name": "off", "controller": "hinf", "metrics": {}, "overrides": {"simulation.bookkeeping": False}},
                    {"name": "on", "controller": "hinf", "metrics": {}, "overrides": {}}]}
    text = metrics_table(doc, markdown=False)
    assert "off: J(T) and the dissipation verdict n/a" in text and "on: J(T)" not in text
    doc["scenario"]["simulation"]["bookkeeping"] = False
    assert "off, on: J(T) and the dissipation verdict n/a" in metrics_table(doc, markdown=False)


def test_a_start_pose_of_the_wrong_size_or_type_and_an_empty_batch_are_refused(paper_plant, nominal_arm,
                                                                               nominal_surface, reference):
    ctrl = H.HinfController.design(nominal_arm, nominal_surface)
    for key, kw, words in (("q0", {"q0": np.zeros(3)}, "must be 2 real numbers (the arm has n = 2 joints), got float64 "
                                                        "values of shape (3,)"),
                           ("q0", {"q0": np.array([0.5, 0.5]) + 1e-3j}, "got complex128 values of shape (2,)"),
                           ("qd0", {"u1_0": U1_0, "qd0": [0.0]}, "got float64 values of shape (1,)")):
        with pytest.raises(H.ConfigError) as err:
            H.simulate(paper_plant, ctrl, reference, t_final=0.01, **kw)
        assert err.value.key == key and words in str(err.value)
    with pytest.raises(H.ConfigError) as err:
        H.simulate_batch([paper_plant] * 2, ctrl, reference, t_final=0.01, q0=[np.zeros(2), np.zeros(3)])
    assert err.value.key == "q0"
    with pytest.raises(H.ConfigError, match="at least one member: the lists .* are empty"):
        H.simulate_batch([], ctrl, reference, t_final=0.01)
