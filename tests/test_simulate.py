"""``step`` and ``simulate``: the notes' explicit Euler, batching, forces, gradients."""

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from reference import qmul, reference_rotation
from scipy.spatial.transform import Rotation

import rbjax as rb

I_GENERIC = (
    Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
    @ np.diag([1.0, 2.0, 2.8])
    @ Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix().T
)
W0 = np.array([0.4, 1.5, -0.7])


def _generic_state(cls=rb.State, **kw):
    return cls.create(
        rb.Body(1.5, I_GENERIC),
        orientation=rb.quat_exp(jnp.array([0.1, 0.2, 0.3])),
        angular_velocity=W0,
        position=[1.0, 2.0, 3.0],
        velocity=[0.1, -0.2, 0.3],
        **kw,
    )


def _numpy_euler_L(x, v, q, L, m, I, F, tau, dt):
    """The notes' right column, transcribed directly (R from q, I_w = R I Rᵀ, solve)."""
    R = Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()
    w = np.linalg.solve(R @ I @ R.T, L)
    q2 = q + dt * 0.5 * qmul(np.concatenate([[0.0], w]), q)
    return x + v * dt, v + F / m * dt, q2 / np.linalg.norm(q2), L + tau * dt


def _numpy_euler_R(x, v, R, w, m, I, F, tau, dt):
    """The notes' middle column: ω̇ from Σ τ = I_w ω̇ + ω × I_w ω; R += ω̃ R dt."""
    Iw = R @ I @ R.T
    wdot = np.linalg.solve(Iw, tau - np.cross(w, Iw @ w))
    R2 = R + np.cross(w[:, None], R, axis=0) * dt  # ω̃ R column by column
    return x + v * dt, v + F / m * dt, R2, w + wdot * dt


def test_euler_state_is_the_notes_update():
    s = _generic_state()
    F, tau, dt = np.array([1.0, 0, -2.0]), np.array([0.3, 0.1, -0.2]), 0.01
    out = rb.step(s, rb.Forces(F, tau), dt, "euler")
    ref = _numpy_euler_L(
        *(np.asarray(a) for a in (s.position, s.velocity, s.orientation, s.angular_momentum)),
        1.5,
        I_GENERIC,
        F,
        tau,
        dt,
    )
    for a, b in zip((out.position, out.velocity, out.orientation, out.angular_momentum), ref):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-14)


def test_euler_matrix_state_is_the_notes_update():
    s = _generic_state(rb.MatrixState)
    F, tau, dt = np.array([1.0, 0, -2.0]), np.array([0.3, 0.1, -0.2]), 0.01
    out = rb.step(s, rb.Forces(F, tau), dt, "euler")
    x, v, R2, w = _numpy_euler_R(
        *(np.asarray(a) for a in (s.position, s.velocity, s.rotation, s.angular_velocity)),
        1.5,
        I_GENERIC,
        F,
        tau,
        dt,
    )
    for a, b in zip((out.position, out.velocity, out.angular_velocity), (x, v, w)):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-14)
    # re-orthonormalisation moves R by O(dt²|ω|²) towards its polar factor
    U, _, Vt = np.linalg.svd(R2)
    np.testing.assert_allclose(out.rotation, U @ Vt, atol=1e-12)


def test_particles_euler_has_the_discrete_closed_form():
    # x_n = x0 + n dt v0 + n(n-1)/2 dt² g exactly for explicit Euler under constant g
    p = rb.ParticleState.create(jnp.array([1.0, 2.0]), velocity=jnp.array([[1.0, 0, 5.0], [0, 1, 0]]))
    n, dt = 50, 0.02
    traj = rb.simulate(p, rb.Forces.gravity(p), dt, n, "euler")
    g = np.array([0, 0, -9.81])
    expect = p.position + n * dt * p.velocity + n * (n - 1) / 2 * dt**2 * g
    np.testing.assert_allclose(traj.position[-1], expect, rtol=1e-12, atol=1e-12)
    # every leaf has the time axis (see rbjax._trajectory): the mass is each frame's
    np.testing.assert_array_equal(traj.mass, np.broadcast_to(np.asarray(p.mass), (51, 2)))


@pytest.mark.parametrize("cls", [rb.State, rb.MatrixState])
def test_euler_is_first_order_against_dop853(cls):
    """Error at t = 1 s against DOP853 (rtol 1e-12) halves with dt: slope 1 ± 0.15."""
    s = _generic_state(cls)
    t_end = 1.0
    q_ref, w_ref = reference_rotation(
        I_GENERIC, np.asarray(rb.orientation(s)), W0, np.array([0.0, t_end]), rtol=1e-12, atol=1e-14
    )
    errs = []
    dts = [1e-2 / 2**k for k in range(4)]
    # one program for the four step sizes: 800 steps saving every 100th state, dt traced; the run
    # at dt reads its state at t_end (after t_end/dt steps), the same numbers as a run of that length
    for dt in dts:
        at_end = int(round(t_end / dt)) // 100
        traj = rb.simulate(s, None, jnp.asarray(dt), 800, "euler", save_every=100)
        errs.append(
            float(rb.quat_angle(rb.orientation(traj)[at_end], q_ref[-1]))
            + float(np.linalg.norm(rb.angular_velocity(traj)[at_end] - w_ref[-1]))
        )
    slope = np.polyfit(np.log(dts), np.log(errs), 1)[0]
    assert abs(slope - 1) < 0.15, (slope, errs)


def test_euler_keeps_world_L_exactly_and_gains_energy():
    s = _generic_state()
    traj = rb.simulate(s, None, 0.01, 2000, "euler", save_every=100)
    np.testing.assert_array_equal(
        traj.angular_momentum, np.broadcast_to(s.angular_momentum, traj.angular_momentum.shape)
    )
    E = np.asarray(rb.kinetic_energy(traj))
    # the notes' explicit Euler drifts: energy is not conserved (here it rises)
    assert E[-1] > E[0] * (1 + 1e-3)


def test_simulate_save_every_and_length():
    s = _generic_state()
    full = rb.simulate(s, None, 0.01, 12)
    sparse = rb.simulate(s, None, 0.01, 12, save_every=4)
    assert full.orientation.shape == (13, 4) and sparse.orientation.shape == (4, 4)
    # the same steps; a native kernel steps all of a frame's steps in one call and may regroup their
    # arithmetic (splitting carries q ⊗ p across them), so frames saved at other intervals agree to
    # round-off: 8 · steps · eps, the bound tests/test_native.py holds native and JAX steps to
    np.testing.assert_allclose(sparse.orientation, full.orientation[::4], rtol=0, atol=8 * 12 * np.finfo(float).eps)
    with pytest.raises(ValueError, match="save_every"):
        rb.simulate(s, None, 0.01, 10, save_every=3)


def test_time_series_and_callable_forces():
    s = rb.ParticleState.create(2.0)
    n, dt = 20, 0.1
    ts = dt * np.arange(n)
    series = rb.Forces(force=np.stack([ts, 0 * ts, 0 * ts], axis=-1))
    a = rb.simulate(s, series, dt, n, "euler")
    b = rb.simulate(s, lambda state, t: rb.Forces(force=jnp.stack([t, 0.0 * t, 0.0 * t])), dt, n, "euler")
    # Euler: v_n = Σ_k F(t_k)/m dt with t_k = k dt
    np.testing.assert_allclose(a.velocity[-1, 0], ts.sum() / 2.0 * dt, rtol=1e-13)
    np.testing.assert_allclose(b.velocity, a.velocity, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("method", ["euler", "rk4"])
def test_batch_equals_per_body_and_jit_equals_eager(method):
    rng = np.random.default_rng(0)
    sizes = rng.uniform(0.2, 2.0, size=(4, 3))
    w = rng.normal(size=(4, 3))
    batch = rb.State.create(rb.box(np.ones(4), sizes), angular_velocity=w)
    tau = rb.Forces(torque=rng.normal(size=(4, 3)))
    traj = rb.simulate(batch, tau, 0.01, 30, method=method)
    for i in range(4):
        one = rb.simulate(
            rb.State.create(rb.box(1.0, sizes[i]), angular_velocity=w[i]),
            rb.Forces(torque=tau.torque[i]),
            0.01,
            30,
            method=method,
        )
        np.testing.assert_allclose(traj.orientation[:, i], one.orientation, rtol=1e-13, atol=1e-14)
    eager = batch
    for _ in range(3):
        eager = rb.step(eager, tau, 0.01, method)
    jitted = jax.jit(lambda s: rb.step(rb.step(rb.step(s, tau, 0.01, method), tau, 0.01, method), tau, 0.01, method))(
        batch
    )
    np.testing.assert_allclose(jitted.orientation, eager.orientation, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(traj.orientation[3], eager.orientation, rtol=1e-14, atol=1e-15)


def test_two_batch_dimensions_with_a_shared_body():
    body = rb.box(1.0, [1.0, 2.0, 3.0])
    w = np.random.default_rng(1).normal(size=(2, 3, 3))
    s = rb.State.create(body, angular_velocity=w)
    traj = rb.simulate(s, None, 0.01, 5)
    assert traj.orientation.shape == (6, 2, 3, 4)
    one = rb.simulate(rb.State.create(body, angular_velocity=w[1, 2]), None, 0.01, 5)
    np.testing.assert_allclose(traj.orientation[:, 1, 2], one.orientation, rtol=1e-14)
    np.testing.assert_allclose(rb.kinetic_energy(traj)[:, 1, 2], rb.kinetic_energy(one), rtol=1e-14)


def test_simulate_compiles_once_per_shape():
    calls = []

    @chex.assert_max_traces(n=1)
    def run(s):
        calls.append(1)
        return rb.simulate(s, None, 0.01, 10)

    run_j = jax.jit(run)
    s = _generic_state()
    run_j(s)
    run_j(jax.tree.map(lambda a: a * 1.0, s))  # new values, same shapes: no retrace
    assert len(calls) == 1


def test_gradients_through_simulate():
    """check_grads: reverse and forward mode vs central finite differences (float64).

    eps = 1e-5 gives a central-difference error ~eps² ≈ 1e-10 plus round-off ~1e-16/eps ≈ 1e-11,
    well inside the 1e-6 tolerance while any wrong derivative term would be O(1e-2).
    """
    F = rb.Forces(torque=jnp.array([0.1, -0.2, 0.05]))

    def final_angle(A, w0, torque):
        # finite differences perturb every entry: symmetrise so each probe is a valid inertia
        s = rb.State.create(rb.Body(1.0, 0.5 * (A + A.T)), angular_velocity=w0)
        traj = rb.simulate(s, rb.Forces(torque=torque), 0.01, 20, save_every=20)
        return rb.orientation(traj)[-1]

    check_grads(
        jax.jit(final_angle),
        (jnp.asarray(I_GENERIC), jnp.asarray(W0), F.torque),
        order=1,
        modes=("fwd", "rev"),
        eps=1e-5,
        atol=1e-6,
        rtol=1e-6,
    )


def test_invalid_arguments_raise():
    s = _generic_state()
    with pytest.raises(ValueError, match="dt"):
        rb.step(s, None, 0.0)
    with pytest.raises(ValueError, match="dt"):
        rb.simulate(s, None, -1e-3, 10)
    with pytest.raises(ValueError, match="unknown method"):
        rb.step(s, None, 0.01, "leapfrog-ish")
    with pytest.raises(ValueError, match="broadcast"):
        rb.step(
            rb.State.create(rb.sphere(1.0, 1.0), angular_velocity=np.ones((4, 3))),
            rb.Forces(force=np.ones((5, 3))),
            0.01,
        )
    with pytest.raises(ValueError, match="time-series"):
        rb.simulate(s, rb.Forces(force=np.ones((7, 1, 3))), 0.01, 10)
    with pytest.raises(ValueError, match="steps"):
        rb.simulate(s, None, 0.01, -1)


def test_float32_run_matches_float64():
    s64 = _generic_state()
    s32 = jax.tree.map(lambda a: a.astype(jnp.float32), s64)
    t64 = rb.simulate(s64, None, 0.01, 100, method="rk4", save_every=100)
    t32 = rb.simulate(s32, None, 0.01, 100, method="rk4", save_every=100)
    assert t32.orientation.dtype == jnp.float32
    # 100 steps accumulate ~100 roundings of ε32 ≈ 1.2e-7 each
    assert float(rb.quat_angle(t32.orientation[-1].astype(jnp.float64), t64.orientation[-1])) < 100 * 1.2e-7
