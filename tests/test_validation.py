"""Bad arguments raise TypeError/ValueError in rbjax's words, naming the argument."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb


def _state():
    return rb.State.create(rb.box(1.0, [0.1, 0.2, 0.4]), angular_velocity=[0.3, 1.0, 0.3])


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: rb.box(1.0, [-0.1, 0.2, 0.4]), r"box: size must be finite and > 0"),
        (lambda: rb.box(1.0, [0.1, 0.2]), r"box: size must end in \(3,\)"),
        (lambda: rb.sphere(1.0, -0.5), r"sphere: radius must be finite and > 0"),
        (lambda: rb.sphere(1.0, np.nan), r"sphere: radius must be finite and > 0"),
        (lambda: rb.cylinder(1.0, 0.5, 0.0), r"cylinder: length must be finite and > 0"),
        (lambda: rb.cylinder(1.0, -0.5, 1.0), r"cylinder: radius must be finite and > 0"),
        (lambda: rb.ellipsoid(1.0, [1.0, -2.0, 3.0]), r"ellipsoid: semi_axes must be finite and > 0"),
    ],
)
def test_shape_constructors_refuse_bad_sizes(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_low_precision_floats_are_refused_by_name():
    with pytest.raises(TypeError, match="float32 or float64; got dtype float16"):
        rb.box(jnp.float16(1.0), jnp.ones(3, jnp.float16))
    with pytest.raises(TypeError, match="float32 or float64; got dtype bfloat16"):
        rb.sphere(jnp.ones((), jnp.bfloat16), 1.0)


@pytest.mark.parametrize(
    "dt, error, match",
    [
        (None, TypeError, r"dt must be a real number \(seconds\), got None"),
        ("x", TypeError, r"dt must be a real number \(seconds\), got 'x'"),
        (True, TypeError, r"dt must be a real number"),
        (1j, TypeError, r"dt must be a real number"),
        ([0.1, 0.2], ValueError, r"dt must be a scalar"),
        (-0.1, ValueError, r"dt must be finite and > 0, got -0.1"),
        (float("nan"), ValueError, r"dt must be finite and > 0"),
    ],
)
def test_bad_dt_names_dt(dt, error, match):
    s = _state()
    with pytest.raises(error, match=match):
        rb.simulate(s, None, dt, 3)
    with pytest.raises(error, match=match):
        rb.step(s, None, dt)


@pytest.mark.parametrize("steps", [True, False, -1, 2.0, "3", None])
def test_bad_steps_are_refused(steps):
    with pytest.raises(ValueError, match=r"steps must be a non-negative int, got"):
        rb.simulate(_state(), None, 0.1, steps)


def test_traced_steps_are_refused_with_the_remedy():
    # steps sets the trajectory's length: under jit it must be static, not a traced int
    run = jax.jit(lambda n: rb.simulate(_state(), None, 0.1, n))
    with pytest.raises(TypeError, match=r"steps must be a Python int, known before tracing.*static_argnames"):
        run(3)
    # the remedy the message names
    static = jax.jit(lambda s, n: rb.simulate(s, None, 0.1, n), static_argnames="n")
    np.testing.assert_array_equal(static(_state(), n=3).time, rb.simulate(_state(), None, 0.1, 3).time)


def test_bad_save_every_t0_and_state():
    s = _state()
    with pytest.raises(ValueError, match=r"save_every must be a positive int"):
        rb.simulate(s, None, 0.1, 4, save_every=True)
    with pytest.raises(ValueError, match=r"t0 must be finite, got nan"):
        rb.simulate(s, None, 0.1, 4, t0=float("nan"))
    with pytest.raises(TypeError, match=r"simulate: state must be a State, MatrixState or ParticleState, got dict"):
        rb.simulate({"position": jnp.zeros(3)}, None, 0.1, 4)


def test_force_callable_returning_a_tuple_is_named():
    with pytest.raises(TypeError) as info:
        rb.simulate(_state(), lambda s, t: (jnp.zeros(3), jnp.zeros(3)), 0.1, 3)
    msg = str(info.value)
    assert "force callable" in msg and "<lambda>" in msg and "it returned tuple" in msg
    assert "must return rbjax.Forces(force=None or (3,), torque=None or (3,))" in msg


def test_force_callable_with_a_wrong_torque_shape_is_named():
    def four_torques(state, t):
        return rb.Forces(torque=jnp.zeros((4, 3)))

    for run in (lambda: rb.simulate(_state(), four_torques, 0.1, 3), lambda: rb.step(_state(), four_torques, 0.1)):
        with pytest.raises(ValueError, match=r"four_torques': torque has shape \(4, 3\), which does not broadcast"):
            run()


def test_step_names_forces_of_another_shape_and_points_a_time_series_to_simulate():
    # a (steps, 3) series given to step had been reported as a "force callable 'as_force_fn.<locals>...'"
    series = rb.Forces(force=jnp.ones((5, 3)))
    with pytest.raises(ValueError, match=r"^step: forces.force has shape \(5, 3\).*\(3,\).*is for simulate"):
        rb.step(_state(), series, 0.1)
    # shared (3,) and per-body (N, 3) forces still step, and the same as their full broadcast
    b = rb.State.create(rb.box(jnp.ones(2), jnp.full((2, 3), 0.3)), angular_velocity=jnp.ones((2, 3)))
    shared = rb.step(b, rb.Forces(torque=jnp.asarray([0.0, 0.0, 1.0])), 0.1, "euler")
    full = rb.step(b, rb.Forces(torque=jnp.tile(jnp.asarray([0.0, 0.0, 1.0]), (2, 1))), 0.1, "euler")
    np.testing.assert_array_equal(np.asarray(shared.angular_momentum), np.asarray(full.angular_momentum))
    # Euler: L gains τ dt exactly
    np.testing.assert_allclose(
        np.asarray(shared.angular_momentum - b.angular_momentum), [[0, 0, 0.1]] * 2, rtol=0, atol=1e-15
    )


def test_force_callable_with_a_shared_force_still_works_and_matches_the_full_one():
    # a (3,) force shared by the batch is valid: broadcast once, the same run as the (N, 3) one
    body = rb.box(jnp.ones(3), jnp.full((3, 3), 0.3))
    s = rb.State.create(body, angular_velocity=jnp.eye(3))
    shared = rb.simulate(s, lambda st, t: rb.Forces(force=jnp.array([0.0, 0.0, -1.0])), 0.1, 5, "rk4")
    full = rb.simulate(s, lambda st, t: rb.Forces(force=jnp.tile(jnp.array([0.0, 0.0, -1.0]), (3, 1))), 0.1, 5, "rk4")
    assert np.array_equal(np.asarray(shared.position), np.asarray(full.position))
    # exact free fall: x(t) = -t²/2 along z (rk4 is exact on a quadratic)
    np.testing.assert_allclose(np.asarray(shared.position[-1, :, 2]), -0.5 * 0.5**2, rtol=1e-12)
