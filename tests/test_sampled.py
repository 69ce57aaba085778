"""SampledController: the controller as a robot loop calls it (controllers/sampled.py).

(a) replaying a simulated sampled-data run through ``update`` reproduces the simulator's held
torques and final controller state, for the three controllers of the paper scenario;
(b) ``jax.vmap`` of ``update`` equals single calls; (c) a non-finite sample never yields a
torque; (d) Remark 2's projection keeps ‖Θ̂‖ ≤ d under ``update``. No timing here (see
benchmarks/latency.py).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hinfnn as H
from hinfnn.controllers import MeasurementError
from hinfnn.protocols import Measurement

#: one xdist worker runs this module: its tests share compiled programs and expensive fixtures
pytestmark = pytest.mark.xdist_group("sampled")

KINDS = ("fl", "hinf", "hinf_nn")
PERIOD = 1e-3
DT = 1e-4
HOLD = round(PERIOD / DT)
RTOL = 1e-10


def _scenario(kind, **overrides):
    return H.load_scenario("paper", {"controller.kind": kind, **overrides})


@pytest.fixture(scope="module", params=KINDS)
def replay(request):
    """(kind, SampledController, trajectory of a 0.05 s sampled run at 1 kHz, dt = 0.1 ms)."""
    kind = request.param
    sc = _scenario(kind)
    plant, ctrl, ref = sc.build_plant(), sc.build_controller(kind), sc.build_reference()
    traj = H.simulate(plant, ctrl, ref, t_final=0.05, dt=DT, q0=sc.initial_q(plant),
                      control_period=PERIOD, save_every=1)
    return kind, H.SampledController(ctrl, ref), traj


def _meas(a, k):
    return Measurement(q=a["q"][k], qd=a["qd"][k], force=a["F"][k])


def _assert_state_close(state, final, scale_floor=1e-300):
    for name in state.names():
        got = np.asarray(getattr(state, name))
        want = np.asarray(final[name])
        assert got.shape == want.shape, name
        scale = max(float(np.max(np.abs(want), initial=0.0)), scale_floor)
        np.testing.assert_allclose(got, want, rtol=0, atol=RTOL * scale, err_msg=name)


# --- (a) exactly the simulator's sampled-mode law -----------------------------------------------
def test_replay_matches_simulator(replay):
    kind, sc, traj = replay
    a = traj.arrays
    n_steps = round(0.05 / DT)
    samples = range(0, n_steps, HOLD)
    tau_scale = float(np.max(np.abs(a["tau"])))
    state = sc.init()
    for k in samples:
        tau, state = sc._update(float(a["t"][k]), PERIOD, state, _meas(a, k))
        tau = np.asarray(tau)
        # the simulator holds τ_k over the whole period: every step of it recorded the same torque
        held = a["tau"][k:k + HOLD]
        np.testing.assert_allclose(np.broadcast_to(tau, held.shape), held, rtol=RTOL,
                                   atol=RTOL * tau_scale, err_msg=f"{kind}: tau at step {k}")
    assert len(samples) == 50
    # public state is flat arrays, whatever the loop carries inside
    assert all(isinstance(v, jax.Array) and v.ndim == 1 for v in jax.tree.leaves(state))
    _assert_state_close(state, traj.final)
    if kind == "hinf_nn":  # the weights did learn: the comparison is not between zeros
        assert np.max(np.abs(traj.final["theta_f"])) > 1e-3
        assert np.max(np.abs(traj.final["theta_p"])) > 1e-6


def test_packed_loop_and_checked_paths_equal_update(replay):
    kind, sc, traj = replay
    a = traj.arrays
    s1 = s2 = s3 = sc.init()
    loop = sc.loop()
    x = np.empty(sc.packed_size)
    for k in range(0, 200, HOLD):
        t = float(a["t"][k])
        tau1, s1 = sc._update(t, PERIOD, s1, _meas(a, k))
        tau2, s2 = sc._unpack(np.asarray(sc._update_packed(sc._pack(t, PERIOD, _meas(a, k), s2, out=x))))
        tau3, s3 = sc._update_checked(t, PERIOD, s3, _meas(a, k))
        tau4 = loop.update(t, PERIOD, a["q"][k], a["qd"][k], a["F"][k])
        assert isinstance(tau4, np.ndarray) and tau4.shape == (2,)
        for tau in (tau2, tau3, tau4):
            np.testing.assert_allclose(tau, np.asarray(tau1), rtol=1e-13, atol=1e-13)
    want = sc.state_vector(s1)
    for other in (s2, s3, loop.state):
        np.testing.assert_allclose(sc.state_vector(other), want, rtol=1e-13, atol=1e-300)
    assert loop.rejected == 0


def test_update_compiles_once_and_never_sees_the_plant(replay):
    kind, sc, traj = replay
    a = traj.arrays
    state = sc.init()
    _, state = sc._update(0.0, PERIOD, state, _meas(a, 0))
    compiled = sc._jit_update._cache_size()
    for k in (10, 20, 30):
        _, state = sc._update(float(a["t"][k]), PERIOD, state, _meas(a, k))
    assert sc._jit_update is sc._jit_update  # one jitted function per wrapper ...
    assert sc._jit_update._cache_size() == compiled  # ... not compiled again for new values
    leaves, treedef = jax.tree.flatten(sc)  # a pytree: the controller and reference are its data
    assert leaves and isinstance(jax.tree.unflatten(treedef, leaves), H.SampledController)
    assert set(type(sc).__dataclass_fields__) == {"controller", "reference"}


def test_the_adapter_has_two_public_entry_points():
    """The robot-loop adapter's public surface (issue 53): the pure ``step`` (inside the user's own
    jit) and ``loop()`` (``loop().update``); the compiled programs and the pytree update, the start
    and the signals that the robot layer replays a record with are private. The rest of the public
    names are sizes, the state's layout, ``init`` and the checks, none of which runs the law."""
    public = {n for n in dir(H.SampledController) if not n.startswith("_")}
    assert public == {"step", "loop", "init", "check_sample", "is_valid", "kernels",
                      "n_joints", "force_size", "state_size", "sample_size", "packed_size", "state_vector",
                      "state_from_vector"}
    assert {n for n in dir(H.SampledLoop) if not n.startswith("_")} == {
        "update", "state", "reset", "phase", "rejected", "controller", "phased"}


def test_torque_and_signals_match_update():
    sc = _scenario("hinf_nn")
    sampled = H.SampledController(sc.build_controller("hinf_nn"), sc.build_reference())
    meas = Measurement(q=np.asarray(sc.initial_q()), qd=np.array([0.01, -0.02]), force=np.array([30.0, -30.0]))
    state = sampled.init()
    tau, sig = sampled._torque_and_signals(0.01, state, meas)
    tau_u, _ = sampled._update(0.01, PERIOD, state, meas)
    np.testing.assert_allclose(np.asarray(tau), np.asarray(tau_u), rtol=1e-13)
    np.testing.assert_allclose(np.asarray(sig["tau"]), np.asarray(tau), rtol=1e-13)
    # λ = (Â Âᵀ)⁻¹ Â F with the nominal Â = [tan 45°, −1]: (30 + 30) / 2
    np.testing.assert_allclose(np.asarray(sig["lam"]), [30.0], rtol=1e-12)


# --- (b) batching ---------------------------------------------------------------------------------
def test_vmap_update_equals_single_calls(replay):
    kind, sc, traj = replay
    a = traj.arrays
    ks = [0, 50, 120, 330]
    # B different states: the ones reached by replaying up to each k, with perturbed weights
    states, state = [], sc.init()
    for k in range(0, max(ks) + 1, HOLD):
        if k in ks:
            states.append(state)
        _, state = sc._update(float(a["t"][k]), PERIOD, state, _meas(a, k))
    ts = jnp.asarray([a["t"][k] for k in ks])
    periods = jnp.asarray([PERIOD, 2e-3, 5e-4, PERIOD])
    meas = Measurement(q=jnp.asarray(a["q"][ks]), qd=jnp.asarray(a["qd"][ks]), force=jnp.asarray(a["F"][ks]))
    batch = jax.tree.map(lambda *xs: jnp.stack(xs), *states)
    taus, news = jax.vmap(sc._update)(ts, periods, batch, meas)
    assert taus.shape == (len(ks), 2)
    for i, k in enumerate(ks):
        tau_i, new_i = sc._update(float(ts[i]), float(periods[i]), states[i], _meas(a, k))
        np.testing.assert_allclose(np.asarray(taus[i]), np.asarray(tau_i), rtol=1e-12, atol=1e-12)
        for x, z in zip(jax.tree.leaves(news), jax.tree.leaves(new_i)):
            np.testing.assert_allclose(np.asarray(x[i]), np.asarray(z), rtol=1e-12, atol=1e-300)
    if kind != "hinf_nn":
        return
    # the packed entry point batches the same way
    xs = np.stack([sc._pack(a["t"][k], p, _meas(a, k), st) for k, p, st in zip(ks, np.asarray(periods), states)])
    taus_p, news_p = sc._unpack(np.asarray(jax.vmap(sc._update_packed)(xs)))
    np.testing.assert_allclose(taus_p, np.asarray(taus), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(news_p.theta_f, np.asarray(news.theta_f), rtol=1e-12, atol=1e-300)


# --- (c) non-finite samples -------------------------------------------------------------------------
def _raw_law(sc, t, state, meas):
    """The controller's law without the wrapper's guard (compiled: faster than op by op)."""
    ctrl = sc.controller
    out = jax.jit(lambda x, m: ctrl.evaluate(t, x, m, sc.reference))(state, meas)
    return out.tau, out.dstate


@pytest.fixture(scope="module")
def sampled_fl():
    sc = _scenario("fl")
    return H.SampledController(sc.build_controller("fl"), sc.build_reference()), np.asarray(sc.initial_q())


@pytest.mark.parametrize("bad", ["q", "qd", "force", "t", "period", "inf_F", "negative_period"])
def test_nonfinite_sample_gives_nan_torque(sampled_fl, bad):
    sc, q0 = sampled_fl
    good = Measurement(q=q0, qd=np.array([0.01, -0.02]), force=np.array([30.0, -30.0]))
    state = sc.init()
    _, state = sc._update(0.0, PERIOD, state, good)  # a non-zero state to keep
    kept = jax.tree.map(np.array, state)
    t, period, meas = 0.001, PERIOD, good
    if bad in ("q", "qd", "force"):
        v = np.array(getattr(good, bad), dtype=float)
        v[1] = np.nan
        meas = Measurement(**{**good.__dict__, bad: v})
    elif bad == "inf_F":
        meas = Measurement(q=good.q, qd=good.qd, force=np.array([np.inf, -30.0]))
    elif bad == "t":
        t = float("nan")
    elif bad == "period":
        period = float("nan")
    else:
        period = -PERIOD
    tau, _ = sc._update(t, period, state, meas)
    tau = np.asarray(tau)
    assert tau.shape == (2,) and np.all(np.isnan(tau))
    assert not sc.is_valid(tau)
    for x, z in zip(jax.tree.leaves(state), jax.tree.leaves(kept)):  # the input is untouched
        np.testing.assert_array_equal(np.asarray(x), z)
    # the packed path behaves the same
    tau_p, _ = sc._unpack(np.asarray(sc._update_packed(sc._pack(t, period, meas, state))))
    assert np.all(np.isnan(tau_p))
    # the loop drops the sample: its state does not move, and it counts the rejection
    loop = sc.loop(state)
    tau_l = loop.update(t, period, meas.q, meas.qd, meas.force)
    assert np.all(np.isnan(tau_l)) and loop.rejected == 1
    np.testing.assert_array_equal(sc.state_vector(loop.state), sc.state_vector(kept))
    # the checked entry point names the culprit
    key = {"inf_F": "measurement.force", "negative_period": "period", "t": "t", "period": "period"}.get(
        bad, f"measurement.{bad}")
    with pytest.raises(MeasurementError) as err:
        sc._update_checked(t, period, state, meas)
    assert err.value.key == key
    # keeping the state passed in drops the bad sample: the next good one is unaffected
    assert sc.is_valid(sc._update(0.002, PERIOD, state, good)[0])


def test_nan_state_kept_by_mistake_latches(sampled_fl):
    """Keeping the state returned with a NaN τ never yields a finite torque afterwards."""
    sc, q0 = sampled_fl
    good = Measurement(q=q0, qd=np.zeros(2), force=np.array([30.0, -30.0]))
    tau, bad_state = sc._update(0.0, PERIOD, sc.init(), Measurement(q=q0, qd=np.zeros(2),
                                                                    force=np.array([np.nan, 0.0])))
    assert not sc.is_valid(tau)
    for k in range(1, 4):
        tau, bad_state = sc._update(k * PERIOD, PERIOD, bad_state, good)
        assert np.all(np.isnan(np.asarray(tau)))


def test_nan_force_would_otherwise_pass_silently_through_fl(sampled_fl):
    """The FL-like law's τ does not depend on λ (only ż does): without the guard a NaN force
    reading would give a finite, plausible torque and a NaN state one sample later."""
    sc, q0 = sampled_fl
    meas = Measurement(q=q0, qd=np.zeros(2), force=np.array([np.nan, np.nan]))
    raw_tau, raw_dxc = _raw_law(sc, 0.0, sc.init(), meas)
    assert np.all(np.isfinite(np.asarray(raw_tau))) and not np.all(np.isfinite(np.asarray(raw_dxc.z)))
    tau, _ = sc._update(0.0, PERIOD, sc.init(), meas)
    assert np.all(np.isnan(np.asarray(tau)))


def test_overflowing_law_gives_nan_not_inf(sampled_fl):
    """A finite but absurd measurement (q̇ = 1e200 rad/s: the Coriolis terms overflow) yields no
    usable torque either: the guard covers the law's output, not only its inputs."""
    sc, q0 = sampled_fl
    meas = Measurement(q=q0, qd=np.array([1e200, 0.0]), force=np.zeros(2))
    state = sc.init()
    raw_tau, _ = _raw_law(sc, 0.0, state, meas)
    assert not np.all(np.isfinite(np.asarray(raw_tau)))
    tau, _ = sc._update(0.0, PERIOD, state, meas)
    assert np.all(np.isnan(np.asarray(tau)))
    with pytest.raises(MeasurementError) as err:
        sc._update_checked(0.0, PERIOD, state, meas)
    assert err.value.key == "tau"


def test_checked_rejects_wrong_shapes(sampled_fl):
    sc, q0 = sampled_fl
    state = sc.init()
    with pytest.raises(MeasurementError, match="measurement.qd"):
        sc._update_checked(0.0, PERIOD, state, Measurement(q=q0, qd=np.zeros(3), force=np.zeros(2)))
    with pytest.raises(MeasurementError, match="state.z"):
        sc._update_checked(0.0, PERIOD, state.__class__(z=np.zeros(2), parts=state.parts),
                          Measurement(q=q0, qd=np.zeros(2), force=np.zeros(2)))
    # the robot loop names a wrong shape instead of broadcasting it
    loop = sc.loop()
    with pytest.raises(MeasurementError, match="measurement.force.*contact force at the tool point"):
        loop.update(0.0, PERIOD, q0, np.zeros(2), 30.0)
    with pytest.raises(MeasurementError, match="measurement.q"):
        loop.update(0.0, PERIOD, q0[:1], np.zeros(2), np.zeros(2))
    assert loop.rejected == 0 and np.all(loop.state.z == 0)
    with pytest.raises(MeasurementError, match="period"):
        sc._update_checked(0.0, 0.0, state, Measurement(q=q0, qd=np.zeros(2), force=np.zeros(2)))


@pytest.mark.parametrize("bad", ["q_strings", "q_complex", "q_list_of_strings", "t_one_element", "t_complex",
                                 "period_string"])
def test_both_updates_refuse_strings_complex_numbers_and_an_array_of_t(sampled_fl, bad):
    """Nothing is silently converted: strings and complex numbers (whose imaginary part a float
    buffer would drop) and a t that is an array are refused, naming the input; the state stays."""
    sc, q0 = sampled_fl
    args = {"t": 0.0, "period": PERIOD, "q": np.asarray(q0, dtype=float), "qd": np.zeros(2), "force": np.zeros(2)}
    name, how = bad.split("_", 1)
    args[name] = {"strings": np.array(["0.1", "0.2"]), "complex": args[name] + 1e-3j,
                  "list_of_strings": ["a", "b"], "one_element": np.array([0.0]), "string": "0.001"}[how]
    key = f"measurement.{name}" if name == "q" else name
    loop = sc.loop()
    with pytest.raises(MeasurementError) as err:
        loop.update(args["t"], args["period"], args["q"], args["qd"], args["force"])
    assert err.value.key == key
    assert loop.rejected == 0 and np.all(loop.state.z == 0)
    with pytest.raises(MeasurementError) as err:
        sc._update(args["t"], args["period"], sc.init(),
                  Measurement(q=args["q"], qd=args["qd"], force=args["force"]))
    assert err.value.key == key
    # a good sample still goes through both, to the same torque
    tau = loop.update(0.0, PERIOD, q0, np.zeros(2), np.zeros(2))
    np.testing.assert_array_equal(tau, np.asarray(sc._update(0.0, PERIOD, sc.init(),
                                                            Measurement(q=q0, qd=np.zeros(2), force=np.zeros(2)))[0]))


def test_a_reference_of_the_wrong_size_is_refused_naming_the_sizes(paper_plant):
    import dataclasses

    sc = _scenario("hinf")
    ctrl, ref = sc.build_controller("hinf"), sc.build_reference()
    two = jnp.array([1.5, 1.5])
    bad = dataclasses.replace(ref, u1_offset=two, u1_amplitude=two, u1_omega=two, u1_phase=two)
    words = "gives u1_d of shape (2,), but the controller has m = 1 motion and k = 1 force coordinates"
    for call in (lambda: H.SampledController(ctrl, bad).init(), lambda: H.SampledController(ctrl, bad).loop(),
                 lambda: H.simulate(paper_plant, ctrl, bad, t_final=0.01, q0=sc.initial_q()),
                 lambda: H.simulate_batch([paper_plant] * 2, ctrl, [ref, bad], t_final=0.01, q0=sc.initial_q())):
        with pytest.raises(H.ConfigError) as err:
            call()
        assert err.value.key == "reference" and words in str(err.value)
    lam = dataclasses.replace(ref, lam_offset=jnp.zeros(3))
    with pytest.raises(H.ConfigError, match=r"gives lam_d of shape \(3,\).*lam_d shape \(1,\)"):
        H.SampledController(ctrl, lam).init()
    # a scalar reference is broadcast as before
    scalar = dataclasses.replace(ref, u1_offset=1.5, u1_amplitude=0.2, u1_omega=jnp.pi, u1_phase=0.0)
    H.SampledController(ctrl, scalar).init()


def test_wrong_parts_are_rejected():
    sc = _scenario("fl")
    with pytest.raises(TypeError, match="controller"):
        H.SampledController(sc.build_plant(), sc.build_reference()).init()
    with pytest.raises(TypeError, match="reference"):
        H.SampledController(sc.build_controller("fl"), 3.0).init()


# --- (d) Remark 2: ‖Θ̂‖ ≤ d under update -------------------------------------------------------------
def test_projection_keeps_weights_in_ball():
    d_p, d_f = 0.02, 0.5
    sc = _scenario("hinf_nn", **{"controller.network_p.projection": True, "controller.network_p.radius": d_p,
                                 "controller.network_f.projection": True, "controller.network_f.radius": d_f})
    sampled = H.SampledController(sc.build_controller("hinf_nn"), sc.build_reference())
    q0 = np.asarray(sc.initial_q())
    # the arm off the surface (F = 0: e_λ = −λd) and away from u1d: both networks are driven
    meas = Measurement(q=q0 + np.array([0.02, -0.01]), qd=np.array([0.05, 0.0]), force=np.zeros(2))
    state = sampled.init()
    norms_p, norms_f = [], []
    for k in range(300):
        tau, state = sampled._update(k * PERIOD, PERIOD, state, meas)
        assert sampled.is_valid(tau)
        norms_p.append(float(np.linalg.norm(np.asarray(state.theta_p))))
        norms_f.append(float(np.linalg.norm(np.asarray(state.theta_f))))
    assert max(norms_p) <= d_p * (1 + 1e-12)
    assert max(norms_f) <= d_f * (1 + 1e-12)
    # the projection was active (the weights reached the sphere), so the bound was tested
    assert norms_p[-1] > 0.999 * d_p and norms_f[-1] > 0.999 * d_f
    # without it, the same samples take the weights out of the ball
    free = H.SampledController(_scenario("hinf_nn").build_controller("hinf_nn"), sampled.reference).loop()
    for k in range(300):
        free.update(k * PERIOD, PERIOD, meas.q, meas.qd, meas.force)
    assert np.linalg.norm(free.state.theta_f) > 2 * d_f


# --- (e) an arm's robot loop: the state as its blocks, on the device -----------------------------------
def test_an_arms_loop_keeps_its_state_in_blocks_and_equals_update():
    """SampledLoop on the UR5 (ur5-table-stable, H∞ + NN) calls ``step_leaves_kept`` (its state's
    buffers donated): τ and the state equal ``update``'s over a changing measurement, to rounding; a
    NaN sample is rejected and leaves the state where it was (the program keeps it); a state the
    caller hands to a loop is not consumed by the donation; ``reset`` restarts from ``init``; and
    no buffer of the compiled update holds more than a block (64 values), the reason for this path
    (XLA's CPU runtime then runs the kernels inline: median 141 → 68 µs per call, benchmarks/run.py
    ``ur5_latency_sync``). The packed
    program of the same controller, for contrast, holds about the whole packed state (338 values) in one
    array."""
    import math
    import re

    from hinfnn.controllers.law import BLOCK

    sc = H.load_scenario("ur5-table-stable", {"controller.kind": "hinf_nn"})
    plant = sc.build_plant()
    sampled = H.SampledController(sc.build_controller("hinf_nn"), sc.build_reference())
    q0 = np.asarray(sc.initial_q(plant))
    loop = sampled.loop()
    assert not loop._packed
    state = sampled.init()
    for k in range(12):
        q = q0 + 0.01 * np.sin(0.7 * k + np.arange(6))
        qd = 0.2 * np.cos(0.3 * k + np.arange(6))
        force = np.array([0.5 * k, -0.2, -20.0 + k])
        meas = Measurement(q=q, qd=qd, force=force)
        if k == 0:  # the force-rate filter starts at the first measurement (the loop does it itself)
            state = sampled._start(0.0, state, meas)
        tau, state = sampled._update(k * PERIOD, PERIOD, state, meas)
        tau_l = loop.update(k * PERIOD, PERIOD, q, qd, force)
        assert isinstance(tau_l, np.ndarray) and tau_l.shape == (6,)
        np.testing.assert_allclose(tau_l, np.asarray(tau), rtol=1e-12, atol=1e-12)
    want = sampled.state_vector(state)
    assert np.max(np.abs(want)) > 1e-6  # the weights moved: the comparison is not between zeros
    np.testing.assert_allclose(sampled.state_vector(loop.state), want, rtol=1e-12, atol=1e-300)
    tau_bad = loop.update(12 * PERIOD, PERIOD, np.full(6, np.nan), qd, force)
    assert np.all(np.isnan(tau_bad)) and loop.rejected == 1
    np.testing.assert_allclose(sampled.state_vector(loop.state), want, rtol=1e-12, atol=1e-300)
    loop.reset()
    np.testing.assert_array_equal(sampled.state_vector(loop.state), sampled.state_vector(sampled.init()))
    # the update donates the loop's state buffers: a state the caller passed in stays readable
    mine = sampled._update(0.0, PERIOD, sampled.init(), Measurement(q=q0, qd=qd, force=force))[1]
    kept = sampled.state_vector(mine)
    other = sampled.loop(mine)
    for k in range(3):
        other.update(k * PERIOD, PERIOD, q0, qd, force)
    np.testing.assert_array_equal(sampled.state_vector(mine), kept)

    def largest_buffer(compiled):  # values in the largest array an instruction of ENTRY makes
        text = compiled.as_text()
        entry = text[text.index("\nENTRY"):]
        sizes = [math.prod(int(d) for d in dims.split(",") if d)
                 for line in entry[:entry.index("\n}")].splitlines()[1:]
                 for m in [re.match(r"\s*(?:ROOT )?%\S+ = (\(.*?\)|\S+) ", line)] if m
                 for dims in re.findall(r"\w+\[([\d,]*)\]", m.group(1))]
        return max(sizes)

    leaves = jax.tree.leaves(sampled.init())
    assert largest_buffer(sampled._jit_kept.lower(np.zeros(sampled.sample_size), *leaves).compile()) <= BLOCK
    assert largest_buffer(sampled._jit_packed.lower(np.zeros(sampled.packed_size)).compile()) >= sampled.packed_size - 1


def test_configure_turns_async_dispatch_off_for_a_robot_process():
    """``hinfnn.configure(async_dispatch=False)`` (what a robot process calls at start-up, the
    SampledLoop docstring says so) turns JAX's CPU async dispatch off; by default it is left as JAX
    sets it (on). A new process each, as the setting must come before the first computation."""
    import subprocess
    import sys

    show = ("import jax, hinfnn; hinfnn.configure(cache=False{}); "
            "print(jax.config.read('jax_cpu_enable_async_dispatch'))")
    got = [subprocess.run([sys.executable, "-c", show.format(arg)], capture_output=True, text=True, timeout=300)
           for arg in ("", ", async_dispatch=False")]
    assert [g.returncode for g in got] == [0, 0], [g.stderr for g in got]
    assert [g.stdout.split()[-1] for g in got] == ["True", "False"]
    assert "async_dispatch=False" in H.SampledLoop.__doc__


def test_sampled_runs_record_the_law_as_it_acted():
    """paper-stable (force-rate term, adaptive law) at 1 kHz, stiffest contact 1e5 N/m: every
    stored row between two samples, and the sample itself, holds the signals of the state the held
    torque was computed from (v_rate, s_lam, z, nn_f, nn_p, the torque), evaluated at that row's
    measurement: recomputed by replaying the run through the robot's entry points, to 1e-10. The
    force-rate term acted (v_rate is not zero), and the last row keeps the torque that acted."""
    sc = H.load_scenario("paper-stable", {"controller.force_rate.stiffness_max": 1e5, "simulation.control": "sampled",
                                          "simulation.control_period": PERIOD})
    plant, ctrl, ref = sc.build_plant(), sc.build_controller(), sc.build_reference()
    traj = H.simulate(plant, ctrl, ref, t_final=0.05, dt=DT, q0=sc.initial_q(plant), control_period=PERIOD,
                      save_every=1)
    a = traj.arrays
    sampled = H.SampledController(ctrl, ref)
    names = ("v_rate", "s_lam", "z", "nn_f", "nn_p", "tau")
    scale = {n: max(float(np.max(np.abs(a[n]))), 1e-300) for n in names}
    assert scale["v_rate"] > 1e-3  # the term acted
    assert ctrl.needs_start  # the filter starts at the first e_λ, as the simulator starts it
    state = sampled._start(0.0, sampled.init(), _meas(a, 0))
    n_steps = round(0.05 / DT)
    for k in range(0, n_steps + 1):
        if k % HOLD == 0 and k < n_steps:
            acting = state
            tau_k, state = sampled._update(float(a["t"][k]), PERIOD, state, _meas(a, k))
        _, sig = sampled._torque_and_signals(float(a["t"][k]), acting, _meas(a, k))
        sig = dict(sig, tau=tau_k)  # the held torque, the last row's too
        for n in names:
            np.testing.assert_allclose(np.asarray(a[n][k]).ravel(), np.asarray(sig[n]).ravel(), rtol=0,
                                       atol=RTOL * scale[n], err_msg=f"{n} at step {k}")
    _assert_state_close(state, traj.final)  # the final state: the last sample's update
