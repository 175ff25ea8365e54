"""rb.shoot / rb.defects / rb.simulate_truncated against scipy DOP853 and independent gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import reference_rotation

import rbjax as rb
from rbjax._pytree import replace

I_T = np.diag([1.0, 2.0, 3.0])  # a T-handle-like body: distinct moments
W_SEP = np.array([0.01, 2.0, 0.01])  # near the intermediate axis: the Dzhanibekov flip
DT = 1e-3


def _states(q, w_world, I=I_T):
    """States (batch of len(q)) from reference orientations and world rates."""
    return rb.State.create(rb.Body(1.0, I), orientation=q, angular_velocity=w_world)


def test_defects_vanish_on_dop853_trajectory():
    S, steps = 4, 250
    times = np.arange(S + 1) * steps * DT
    q, w = reference_rotation(I_T, np.array([1.0, 0, 0, 0]), W_SEP, times)
    starts = _states(q[:-1], w[:-1])
    traj, ends = rb.shoot(starts, None, DT, steps, "rk4", save_every=50)
    assert traj.orientation.shape == (steps // 50 + 1, S, 4)
    d = rb.defects(ends, starts)
    assert d.shape == (S - 1, 12)
    # rk4, |ω| h = 2e-3 over 0.25 s: global error ~ (ωh)⁴ ω t ≈ 1e-11; DOP853 at rtol 1e-13
    assert np.max(np.abs(d)) < 1e-9
    # and the defects are not trivially zero: wrong starts (shifted by one segment) give O(1)
    assert np.max(np.abs(rb.defects(ends, _states(q[1:], w[1:])))) > 0.1
    # per-step (S, steps) dt with zero padding: same ends, padding steps are no-ops
    dts = np.concatenate([np.full((S, steps), DT), np.zeros((S, 10))], axis=1)
    _, ends_pad = rb.shoot(starts, None, dts, steps + 10, "rk4")
    np.testing.assert_allclose(ends_pad.orientation, ends.orientation, atol=1e-14)


def test_shoot_time_dependent_torque_segments_tile_the_horizon():
    S, steps = 3, 200
    torque = lambda t: np.array([0.2 * np.sin(3 * t), 0.1, -0.1 * np.cos(t)])
    times = np.arange(S + 1) * steps * DT + 0.5
    q, w = reference_rotation(I_T, np.array([1.0, 0, 0, 0]), W_SEP, times, torque_world=lambda t, *_: torque(t))
    starts = _states(q[:-1], w[:-1])
    f = lambda s, t: rb.Forces(torque=jnp.stack([0.2 * jnp.sin(3 * t), 0.1 + 0 * t, -0.1 * jnp.cos(t)]))
    _, ends = rb.shoot(starts, f, DT, steps, "rk4", t0=0.5)  # scalar t0: segment s starts at 0.5 + s·0.2
    # rk4 with smooth torque, 0.2 s per segment: error ~1e-11
    assert np.max(np.abs(rb.defects(ends, starts))) < 1e-9


def _loss(traj):
    return jnp.sum(traj.orientation[-1] * jnp.array([0.3, -1.0, 0.5, 2.0], traj.orientation.dtype))


@pytest.mark.slow  # reverse mode through every segment (~20 s)
def test_truncated_gradient_is_sum_of_independent_segment_gradients():
    steps, k = 120, 40
    state = rb.State.create(rb.Body(1.0, I_T), angular_velocity=W_SEP)

    def chunk_loss(traj):  # a loss summed over the chunk ends
        ends = traj.orientation[k::k]
        return jnp.sum(ends * jnp.array([0.3, -1.0, 0.5, 2.0]))

    def run(inertia, trunc):  # initial L fixed (not a function of I), like each chunk's start
        s = replace(state, body=rb.Body(1.0, inertia))
        if trunc:
            return rb.simulate_truncated(s, None, DT, steps, "rk4", truncate_every=k)
        return rb.simulate(s, None, DT, steps, "rk4")

    # every gradient below is jitted (one compile each, not eager per-op dispatch) and
    # forward-mode (9 tangents; XLA compiles a JVP scan ~4x faster than its transpose);
    # stop_gradient cuts tangents exactly as it cuts cotangents. The trajectories come out
    # of the same programs as aux
    def loss_and_traj(I, trunc):
        traj = run(I, trunc)
        return chunk_loss(traj), traj

    grad_and_traj = jax.jit(jax.jacfwd(loss_and_traj, has_aux=True), static_argnums=1)
    g_tr, tr = grad_and_traj(jnp.asarray(I_T), True)
    g_full, full = grad_and_traj(jnp.asarray(I_T), False)
    np.testing.assert_allclose(tr.orientation, full.orientation, atol=1e-14)  # values unchanged

    # independently: each chunk from its (fixed, numeric) start, its own gradient in I
    @jax.jit
    @jax.jacfwd
    def piece_grad(I, x):
        return _loss(rb.simulate(replace(x, body=rb.Body(1.0, I)), None, DT, k, "rk4"))

    g_sum = 0.0
    for i in range(steps // k):
        x = jax.tree.map(lambda a, i=i: a[i * k], replace(full, body=None))
        g_sum = g_sum + piece_grad(jnp.asarray(I_T), x)
    np.testing.assert_allclose(g_tr, g_sum, rtol=1e-10, atol=1e-12)  # same arithmetic: round-off only
    # the untruncated gradient differs (cross-chunk terms) — the test can tell them apart
    assert np.max(np.abs(g_full - g_sum)) > 1e-3 * np.max(np.abs(g_sum))

    # d(end)/d(initial L) is exactly zero across a cut, and not within the first chunk
    def frames(L0):  # (after the last cut, at the first cut)
        s = replace(state, angular_momentum=L0)
        q = rb.simulate_truncated(s, None, DT, steps, "rk4", truncate_every=k).orientation
        return q[steps], q[k]

    J_last, J_first = jax.jit(jax.jacfwd(frames))(state.angular_momentum)
    assert np.all(np.asarray(J_last) == 0.0)
    assert np.max(np.abs(J_first)) > 1e-3


def test_multiple_shooting_bounds_the_sensitivity_single_shooting_cannot():
    # near the separatrix ‖∂q(T)/∂ω0‖ grows by orders of magnitude over a long horizon;
    # S segments of length T/S each see only a short, moderate derivative
    steps_total, S = 6000, 12

    def end_q(w0):
        s = rb.State.create(rb.Body(1.0, I_T), angular_velocity=w0)
        return rb.simulate(s, None, DT, steps_total, "rk4", save_every=steps_total).orientation[-1]

    single = np.linalg.norm(jax.jit(jax.jacfwd(end_q))(jnp.asarray(W_SEP)))
    traj = rb.simulate(rb.State.create(rb.Body(1.0, I_T), angular_velocity=W_SEP), None, DT, steps_total, "rk4")
    starts = traj[: steps_total : steps_total // S]  # every leaf, the body's too, has the time axis

    def seg_ends(L):
        _, ends = rb.shoot(replace(starts, angular_momentum=L), None, DT, steps_total // S, "rk4")
        return ends.orientation

    J = jax.jit(jax.jacfwd(seg_ends))(starts.angular_momentum)  # (S, 4, S, 3): block diagonal
    blocks = np.stack([np.linalg.norm(J[s, :, s, :]) for s in range(S)])
    off = np.max(np.abs(np.asarray(J).transpose(0, 2, 1, 3)[~np.eye(S, dtype=bool)]))
    assert off == 0.0  # segments are independent
    # measured: single ≈ 2e2-1e3, per-segment ≤ ~1 (T/S = 0.5 s): at least 50x better conditioned
    assert single > 50 * blocks.max(), (single, blocks.max())


def test_bad_input():
    starts = rb.State.create(rb.Body(1.0, I_T), angular_velocity=np.tile(W_SEP, (2, 1)))
    with pytest.raises(ValueError, match="save_every"):
        rb.shoot(starts, None, DT, 10, save_every=3)
    with pytest.raises(ValueError, match="dt must be"):
        rb.shoot(starts, None, np.ones((3, 10)) * DT, 10)
    with pytest.raises(ValueError, match="segment axis"):
        rb.shoot(rb.State.create(rb.Body(1.0, I_T)), None, DT, 10)
    with pytest.raises(ValueError, match="truncate_every"):
        rb.simulate_truncated(starts, None, DT, 10, truncate_every=3)


def test_float32_gradient_matches_float64():
    def loss(L, dtype):
        s = rb.State.create(
            rb.Body(jnp.asarray(1.0, dtype), jnp.asarray(I_T, dtype)),
            angular_velocity=jnp.asarray(L, dtype),
        )
        return _loss(rb.simulate_truncated(s, None, jnp.asarray(DT, dtype), 400, "rk4", truncate_every=200))

    L0 = W_SEP  # differentiate in the initial world rate
    grad = jax.jit(jax.jacfwd(loss), static_argnums=1)  # forward mode: 3 tangents, quicker to compile
    g64 = np.asarray(grad(jnp.asarray(L0), jnp.float64))
    g32 = np.asarray(grad(jnp.asarray(L0, jnp.float32), jnp.float32))
    assert g32.dtype == np.float32
    # float32: eps 6e-8 per op, 200 steps per chunk and ‖∂q/∂ω0‖ ~ O(1): ~1e-5 relative, 10x margin
    np.testing.assert_allclose(g32, g64, rtol=0, atol=1e-4 * np.max(np.abs(g64)))
