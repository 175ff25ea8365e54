"""A step that turns a body by more than half a turn is named (rbjax.StepSizeWarning), not returned silently."""

from __future__ import annotations

import dataclasses
import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb
from rbjax._validate import _turn_bound

BOX = rb.box(1.0, [0.1, 0.2, 0.4])
W = np.array([0.3, 100.0, 0.3])  # |ω| ≈ 100 rad/s about the intermediate axis


def _quiet():
    """A context in which any warning is an error: the sound runs below must give none."""
    ctx = warnings.catch_warnings()
    ctx.__enter__()
    warnings.simplefilter("error")
    return ctx


def test_euler_at_dt_omega_500_is_wrong_and_says_so():
    # the case that returned a finite, unit, meaningless attitude without a word: 10 steps of
    # dt = 5 s at |ω| = 100 rad/s (dt·|ω| = 500 rad per step)
    s = rb.State.create(BOX, angular_velocity=jnp.asarray(W))
    with pytest.warns(
        rb.StepSizeWarning, match=r"^simulate: dt·\|ω\| = 500 rad at the start: .*dt < π/\|ω\| = 0\.0314 s"
    ):
        traj = rb.simulate(s, None, 5.0, 10, "euler")
    # what the warning is about: finite unit quaternions, ~a radian or more from the exact motion
    q = np.asarray(traj.orientation[-1])
    assert np.isfinite(q).all() and abs(np.linalg.norm(q) - 1) < 1e-12
    exact = rb.torque_free(s, 50.0)
    assert float(rb.quat_angle(traj.orientation[-1], exact.orientation)) > 0.5


def test_half_a_turn_is_the_limit_and_the_body_is_named():
    # 3.0 rad per step passes (NumPy's bound exceeds π here, so the exact |ω| decides); 3.3 warns,
    # naming the one fast body of a (2, 3) batch by its index
    w = np.zeros((2, 3, 3))
    w[..., 2] = 1.0
    w[1, 2] = [0.0, 0.0, 300.0]
    s = rb.State.create(BOX, angular_velocity=jnp.asarray(w))
    assert np.max(_turn_bound(s, 0.01)) > math.pi  # the exact check is what lets 3.0 through
    ctx = _quiet()
    rb.simulate(s, None, 0.01, 2, "splitting")  # dt·|ω| = 3.0
    ctx.__exit__(None, None, None)
    with pytest.warns(rb.StepSizeWarning, match=r"dt·\|ω\| = 3\.3 rad at the start \(body \(1, 2\)\)"):
        rb.simulate(s, None, 0.011, 2, "splitting")


@pytest.mark.parametrize(
    ("name", "run"),
    [
        ("simulate", lambda s, dt: rb.simulate(s, None, dt, 4, "rk4")),
        ("simulate", lambda s, dt: rb.simulate(rb.to_matrix_state(s), None, dt, 4, "rk4")),
        ("step", lambda s, dt: rb.step(s, None, dt, "rk4")),
        ("simulate_chunked", lambda s, dt: rb.simulate_chunked(s, None, dt, 4, "rk4", chunk_steps=2, progress=False)),
        ("simulate_truncated", lambda s, dt: rb.simulate_truncated(s, None, dt, 4, "rk4", truncate_every=2)),
    ],
)
def test_every_entry_point_warns_once_in_its_own_name(name, run):
    s = rb.State.create(BOX, angular_velocity=jnp.asarray(W))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run(s, 0.1)  # dt·|ω| = 10
    ours = [w for w in caught if issubclass(w.category, rb.StepSizeWarning)]
    said = [str(w.message) for w in ours]
    assert len(said) == 1 and said[0].startswith(f"{name}: dt·|ω| = 10 rad"), said
    assert ours[0].filename == __file__  # it points at the caller's line, not into rbjax
    ctx = _quiet()
    run(s, 0.01)  # dt·|ω| = 1: sound (if inaccurate for rk4: the user's call)
    ctx.__exit__(None, None, None)


def test_traced_runs_are_not_checked():
    # inside jit the state has no value: nothing to warn about (checked mode tests values at run time)
    s = rb.State.create(BOX, angular_velocity=jnp.asarray(W))
    ctx = _quiet()
    out = jax.jit(lambda s: rb.simulate(s, None, 5.0, 2, "splitting").orientation)(s)
    ctx.__exit__(None, None, None)
    assert np.isfinite(np.asarray(out)).all()


def test_the_bound_is_above_the_exact_turn():
    # |ω| ≤ |L| ‖I‖_F² / det I for boxes from rods and plates to cubes, turned at random
    rng = np.random.default_rng(0)
    a, b, c = rng.uniform(0.01, 1.0, (3, 200))
    moments = np.stack([b * b + c * c, a * a + c * c, a * a + b * b], -1) / 12
    axes = rb.quat_to_matrix(rb.quat_normalize(jnp.asarray(rng.normal(size=(200, 4)))))
    inertia = np.einsum("nij,nj,nkj->nik", np.asarray(axes), moments, np.asarray(axes))
    s = rb.State.create(
        rb.Body(jnp.ones(200), jnp.asarray(inertia)),
        orientation=rb.quat_normalize(jnp.asarray(rng.normal(size=(200, 4)))),
        angular_velocity=jnp.asarray(rng.normal(size=(200, 3))),
    )
    exact = 0.1 * np.linalg.norm(np.asarray(rb.angular_velocity(s)), axis=-1)
    bound = _turn_bound(s, 0.1)
    # the bound is a product of norms: above the exact value by far more than round-off
    assert np.all(bound >= exact * (1 - 1e-12)) and np.median(bound / exact) > 1.5


def _spun_up():
    """A unit sphere at rest, a torque of 1 N m about z: after step k of dt = 0.1 s, |ω| = 0.1 k rad/s
    (L gains τ dt a step, exactly), so dt·|ω| = 0.01 k passes π first at step 315."""
    s = rb.State.create(rb.Body(1.0, jnp.eye(3)), angular_velocity=jnp.zeros(3))
    return s, rb.Forces(torque=jnp.asarray([0.0, 0.0, 1.0]))


def test_checked_mode_sees_a_body_that_torques_spin_up():
    s, torque = _spun_up()
    ctx = _quiet()  # at rest at the start: nothing for the eager warning to see
    with pytest.raises(ValueError, match=r"at step 315 .*the body: dt·\|ω\| exceeded max_turn=3\.14 rad per step"):
        rb.simulate(s, torque, 0.1, 400, "semi_implicit_euler", checked=True)
    ctx.__exit__(None, None, None)
    # a step before it, the run passes; max_turn=None lets the whole run through
    rb.simulate(s, torque, 0.1, 314, "semi_implicit_euler", checked=True)
    traj = rb.simulate(s, torque, 0.1, 400, "semi_implicit_euler", checked=rb.Checks(max_turn=None))
    np.testing.assert_allclose(np.asarray(rb.angular_velocity(traj))[-1], [0.0, 0.0, 40.0], rtol=1e-12)


def test_checked_mode_flags_the_turn_inside_jit():
    s, torque = _spun_up()
    run = eqx.filter_jit(lambda s: rb.simulate(s, torque, 0.1, 400, "semi_implicit_euler", checked=True))
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"at step 315 .*dt·\|ω\| exceeded max_turn"):
        jax.block_until_ready(run(s))


@pytest.mark.parametrize("bad", [0.0, -1.0, float("inf"), float("nan")])
def test_max_turn_must_be_positive_and_finite(bad):
    with pytest.raises(ValueError, match="max_turn must be finite and > 0"):
        rb.Checks(max_turn=bad)


@pytest.mark.parametrize("form", ["State", "MatrixState"])
def test_rk4_at_three_radians_per_step_warns_for_its_own_reason(form):
    # dt·|ω| = 3, under π: no warning before. rk4 (order 4) errs by ~3⁵/5! = 2 rad per step on a
    # rotation (State), and the matrix form diverges beyond ~1 (stable_dt_omega): NaN within the run
    s = rb.State.create(BOX, angular_velocity=jnp.asarray(W))
    s = s if form == "State" else rb.to_matrix_state(s)
    dt = 3.0 / float(np.linalg.norm(W))
    accuracy, stability = r"errs by about \(dt·\|ω\|\)\^5/5! = 2 rad", r"beyond where 'rk4' diverges for MatrixState"
    why = accuracy if form == "State" else stability
    with pytest.warns(rb.StepSizeWarning, match=rf"^simulate: dt·\|ω\| = 3 rad at the start: .*{why}"):
        traj = rb.simulate(s, None, dt, 50, "rk4")
    exact = rb.torque_free(rb.State.create(BOX, angular_velocity=jnp.asarray(W)), 50 * dt)
    if form == "MatrixState":  # what the warning foretells: the run diverges
        assert not np.isfinite(np.asarray(traj.rotation[-1])).all()
    else:  # finite, and nothing like the motion
        assert float(rb.quat_angle(traj.orientation[-1], exact.orientation)) > 0.5
    # a step a third of that is sound (if inaccurate) for rk4 in both forms, and splitting never warns below π
    ctx = _quiet()
    rb.simulate(s, None, dt / 3, 4, "rk4")
    rb.simulate(s, None, dt, 4, "splitting")
    ctx.__exit__(None, None, None)


def test_a_concrete_state_under_a_callers_jit_is_still_checked():
    # the state's values are known while the caller's program is traced: the warning is given then
    s = rb.State.create(BOX, angular_velocity=jnp.asarray(W))
    with pytest.warns(rb.StepSizeWarning, match="more than half a turn"):
        jax.jit(lambda: rb.simulate(s, None, 5.0, 2, "splitting").orientation)()


def test_the_start_checks_follow_every_new_value():
    # the start state's reductions are kept per state object (JAX arrays are immutable); a new dt, a
    # new state and a NumPy array changed in place are each checked anew
    s = rb.State.create(rb.box(jnp.ones(3), jnp.ones((3, 3))), angular_velocity=jnp.ones((3, 3)))
    ctx = _quiet()
    for _ in range(2):
        rb.simulate(s, None, 1e-3, 2, "rk4")
    ctx.__exit__(None, None, None)
    with pytest.warns(rb.StepSizeWarning, match=r"\(body \(\d,\)\)"):
        rb.simulate(s, None, 2.0, 2, "rk4")  # the same state, a step that turns each body 3.4 rad
    with pytest.raises(ValueError, match="share one time"):
        rb.simulate(dataclasses.replace(s, time=jnp.arange(3.0)), None, 1e-3, 2, "rk4")
    host = jax.tree.map(np.array, s)  # NumPy leaves: mutable, so never kept
    rb.simulate(host, None, 1e-3, 2, "rk4")
    host.time[1] = 5.0
    with pytest.raises(ValueError, match="share one time"):
        rb.simulate(host, None, 1e-3, 2, "rk4")
