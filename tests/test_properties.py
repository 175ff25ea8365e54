"""Property tests over random valid bodies, states and steps (hypothesis).

Shapes are fixed (a batch of ``N`` bodies, ``STEPS`` steps) so that every example
reuses the compiled programs; only values vary.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import rbjax as rb

N, STEPS = 4, 20
SETTINGS = settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
finite = functools.partial(st.floats, allow_nan=False, allow_infinity=False)


def _rotation(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@st.composite
def quaternions(draw, shape=(N,)):
    q = draw(hnp.arrays(np.float64, shape + (4,), elements=finite(min_value=-1, max_value=1)))
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    # keep away from 0 so that the normalised quaternion is well defined
    q = np.where(norm < 0.1, np.array([1.0, 0, 0, 0]), q)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


@st.composite
def bodies(draw):
    """Valid bodies: principal moments a, b in [0.2, 2], c strictly inside the triangle
    range (|a - b|, a + b), the principal frame rotated by a random quaternion."""
    a = draw(hnp.arrays(np.float64, (N,), elements=finite(min_value=0.2, max_value=2.0)))
    b = draw(hnp.arrays(np.float64, (N,), elements=finite(min_value=0.2, max_value=2.0)))
    u = draw(hnp.arrays(np.float64, (N,), elements=finite(min_value=0.05, max_value=0.95)))
    c = np.abs(a - b) + u * (a + b - np.abs(a - b))
    P = np.stack([_rotation(q) for q in draw(quaternions())])
    inertia = P @ (np.stack([a, b, c], -1)[..., None] * np.eye(3)) @ np.swapaxes(P, -1, -2)
    inertia = 0.5 * (inertia + np.swapaxes(inertia, -1, -2))
    mass = draw(hnp.arrays(np.float64, (N,), elements=finite(min_value=0.1, max_value=10.0)))
    return rb.Body(mass, inertia)


@st.composite
def states(draw):
    vec = lambda lim: draw(hnp.arrays(np.float64, (N, 3), elements=finite(min_value=-lim, max_value=lim)))
    return rb.State.create(
        draw(bodies()),
        position=vec(5.0),
        velocity=vec(2.0),
        orientation=draw(quaternions()),
        angular_velocity=vec(2.0),
    )


dts = finite(min_value=1e-3, max_value=1e-2)


def _one(s: rb.State, i: int) -> rb.State:
    return jax.tree.map(lambda a: a[i], s)


@functools.partial(jax.jit, static_argnames="method")
def _step_jit(s, dt, method):
    return rb.step(s, None, dt, method)


@SETTINGS
@given(s=states(), dt=dts)
def test_batch_equals_per_body_runs_and_jit_equals_eager(s, dt):
    traj = rb.simulate(s, None, dt, STEPS, "rk4")
    for i in range(N):
        single = rb.simulate(_one(s, i), None, dt, STEPS, "rk4")
        # vmap over the batch vs one body: same arithmetic up to XLA's fusion choices;
        # 1e-12 relative allows a few ulp per step over 20 steps
        for field in ("position", "velocity", "orientation", "angular_momentum"):
            np.testing.assert_allclose(
                getattr(traj, field)[:, i], getattr(single, field), rtol=1e-12, atol=1e-13, err_msg=field
            )
    # one step compiled vs op by op: identical formulas, round-off only (FMA contraction)
    eager, jitted = rb.step(s, None, dt, "euler"), _step_jit(s, dt, "euler")
    for a, b in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-14)


@SETTINGS
@given(s=states(), dt=dts, method=st.sampled_from(["euler", "rk4"]))
def test_q_and_minus_q_give_the_same_motion(s, dt, method):
    flipped = rb._pytree.replace(s, orientation=-s.orientation)
    a = rb.simulate(s, None, dt, STEPS, method)
    b = rb.simulate(flipped, None, dt, STEPS, method)
    # q and -q are the same rotation; every formula is even in q except the linear q update,
    # so the motion matches to round-off: orientation up to sign, ω and L equal (1e-12)
    np.testing.assert_allclose(a.orientation, -b.orientation, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(rb.angular_velocity(a), rb.angular_velocity(b), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(a.angular_momentum, b.angular_momentum, rtol=1e-12, atol=1e-13)


@SETTINGS
@given(s=states(), dt=finite(min_value=1e-3, max_value=0.5))
def test_euler_keeps_torque_free_world_momentum_exactly(s, dt):
    # L += τ dt with no torque adds nothing: L is bit-for-bit constant, even at large dt
    traj = rb.simulate(s, rb.Forces(force=jnp.ones((N, 3))), dt, STEPS, "euler")
    assert np.array_equal(np.asarray(traj.angular_momentum), np.broadcast_to(s.angular_momentum, (STEPS + 1, N, 3)))


def _energy_methods():
    # "splitting" is picked up when its branch is merged
    return [m for m in ("rk4", "splitting") if m in rb.methods(rb.State)]


@pytest.mark.parametrize("method", _energy_methods())
@SETTINGS
@given(s=states(), dt=dts)
def test_energy_error_is_small_at_small_dt(method, s, dt):
    traj = rb.simulate(s, None, dt, STEPS, method)
    E = np.asarray(rb.kinetic_energy(traj))  # (STEPS + 1, N)
    # torque- and force-free: ½ m v² is exact for every method, the error is rotational
    E_rot = E[0] - 0.5 * np.asarray(s.body.mass) * np.sum(np.asarray(s.velocity) ** 2, axis=-1)
    h = np.linalg.norm(np.asarray(rb.angular_velocity(s)), axis=-1) * dt  # rotation per step (rad)
    # A method of order p errs by ~C h^(p+1) E_rot per step. C = 1 is 15x the largest value
    # measured for rk4 over these bodies (0.06, 250 bodies); a lower order (an O(h^p) bug)
    # would exceed it by 1/h ≥ 30x. 1e-13 E covers float64 round-off over 20 steps.
    order = rb.methods()[method].order
    bound = STEPS * h ** (order + 1) * E_rot + 1e-13 * E[0]
    err = np.max(np.abs(E - E[0]), axis=0)
    assert np.all(err <= bound), np.max(err / bound)


# --- invalid inputs: ValueError, never NaN ---------------------------------------------


@st.composite
def invalid_inertias(draw):
    kind = draw(st.sampled_from(["asymmetric", "not_pd", "triangle", "non_finite"]))
    a, b = draw(finite(min_value=0.2, max_value=2.0)), draw(finite(min_value=0.2, max_value=2.0))
    P = _rotation(draw(quaternions(shape=(1,)))[0])
    if kind == "triangle":
        c = a + b + draw(finite(min_value=0.05, max_value=2.0)) * (a + b)  # c > a + b
        moments = [a, b, c]
    elif kind == "not_pd":
        moments = [a, b, -draw(finite(min_value=0.0, max_value=1.0))]  # a zero or negative moment
    else:
        moments = [a, b, 0.5 * (a + b)]
    inertia = P @ np.diag(moments) @ P.T
    inertia = 0.5 * (inertia + inertia.T)
    if kind == "asymmetric":
        i, j = draw(st.sampled_from([(0, 1), (0, 2), (1, 2)]))
        inertia[i, j] += draw(finite(min_value=1e-3, max_value=1.0)) * draw(st.sampled_from([-1, 1]))
    elif kind == "non_finite":
        inertia[draw(st.integers(0, 2)), draw(st.integers(0, 2))] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    return inertia


@SETTINGS
@given(inertia=invalid_inertias())
def test_invalid_inertia_raises(inertia):
    with pytest.raises(ValueError, match="Body: (inertia|principal moments)"):
        rb.Body(1.0, inertia)


@SETTINGS
@given(mass=st.one_of(finite(max_value=0.0), st.sampled_from([np.nan, np.inf, -np.inf])))
def test_invalid_mass_raises(mass):
    with pytest.raises(ValueError, match="Body: mass"):
        rb.Body(mass, np.eye(3))
    with pytest.raises(ValueError, match="mass must be"):
        rb.ParticleState.create(np.array([1.0, mass]))


@SETTINGS
@given(q=hnp.arrays(np.float64, (4,), elements=finite(min_value=-2, max_value=2)), s=states())
def test_non_unit_quaternion_raises(q, s):
    n = np.linalg.norm(q)
    if abs(n - 1) <= 1e-5:  # a unit quaternion within tolerance is valid: scale it off the sphere
        q = q * 1.5 if n > 0.5 else np.array([0.0, 0, 0, 0])
    with pytest.raises(ValueError, match="unit quaternion"):
        rb.State.create(s.body, orientation=jnp.broadcast_to(q, (N, 4)))
    with pytest.raises(ValueError, match="unit quaternion"):
        rb.State(s.body, s.position, s.velocity, jnp.broadcast_to(q, (N, 4)), s.angular_momentum)


@SETTINGS
@given(s=states(), dt=st.one_of(finite(max_value=0.0), st.sampled_from([np.nan, np.inf, -np.inf])))
def test_non_positive_or_non_finite_dt_raises(s, dt):
    for call in (lambda: rb.step(s, None, dt), lambda: rb.simulate(s, None, dt, STEPS, "rk4")):
        with pytest.raises(ValueError, match="dt must be finite and > 0"):
            call()
