"""simulate_chunked: same trajectory as one simulate call, one compilation, chunks on disk."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb
from rbjax._simulate import _simulate


def _state(n=3, dtype=jnp.float64):
    rng = np.random.default_rng(7)
    body = rb.box(jnp.asarray(rng.uniform(0.5, 2, n), dtype), jnp.asarray(rng.uniform(0.3, 1.5, (n, 3)), dtype))
    return rb.State.create(
        body,
        velocity=jnp.asarray(rng.normal(size=(n, 3)), dtype),
        angular_velocity=jnp.asarray(rng.normal(size=(n, 3)) * 2, dtype),
    )


def _max_diff(a, b) -> float:
    return max(float(jnp.max(jnp.abs(x - y))) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def test_matches_one_simulate_with_time_dependent_forces():
    s = _state()
    calls = []

    def forces(state, t):  # depends on absolute t: a wrong t0 per chunk would show
        calls.append(1)  # runs only while tracing
        tau = jnp.stack([jnp.sin(3 * t), jnp.cos(2 * t), 0.5 * t])
        return rb.Forces(force=jnp.broadcast_to(tau, state.position.shape), torque=jnp.broadcast_to(tau, (3, 3)))

    dt, steps = 0.01, 120
    whole = rb.simulate(s, forces, dt, steps, "euler", save_every=4, t0=0.25)
    size0 = _simulate._cache_size()
    chunked = rb.simulate_chunked(s, forces, dt, steps, "euler", save_every=4, chunk_steps=24, t0=0.25, progress=False)
    # five chunks of 24 steps reuse one compiled scan: one new cache entry, and the force
    # function is traced (called) for the first chunk only
    assert _simulate._cache_size() == size0 + 1
    traced_once = len(calls)
    rb.simulate_chunked(s, forces, dt, steps, "euler", save_every=4, chunk_steps=24, t0=0.25, progress=False)
    assert len(calls) == traced_once and _simulate._cache_size() == size0 + 1
    assert chunked.position.shape == whole.position.shape == (31, 3, 3)
    assert chunked.body.mass.shape == (31, 3)  # every leaf has the time axis
    # each chunk's step k runs at t0 + (steps done + k) dt, as in one run: the same bits,
    # times and forces included
    assert _max_diff(chunked, whole) == 0.0


def test_time_series_forces_uneven_last_chunk_and_final_state_only():
    s = _state()
    steps, dt = 50, 0.02
    rng = np.random.default_rng(3)
    series = rb.Forces(torque=jnp.asarray(rng.normal(size=(steps, 3, 3))))
    whole = rb.simulate(s, series, dt, steps, "euler", save_every=5)
    # 20 + 20 + 10: the last chunk is shorter; constant per-step inputs make every step the
    # same arithmetic as in one scan, so the result is bitwise equal
    chunked = rb.simulate_chunked(s, series, dt, steps, "euler", save_every=5, chunk_steps=20, progress=True)
    assert _max_diff(chunked, whole) == 0.0
    final = rb.simulate_chunked(s, series, dt, steps, "euler", save_every=5, chunk_steps=20, progress=False, keep=False)
    assert _max_diff(final, rb._chunked._frames(whole, -1)) == 0.0
    assert final.position.shape == (3, 3)


def test_writer_round_trip_and_float32(tmp_path):
    s = _state(dtype=jnp.float32)
    torque = rb.Forces(torque=jnp.full((3, 3), 0.1, jnp.float32))
    w = rb.ChunkWriter(tmp_path / "run")
    traj = rb.simulate_chunked(s, torque, 0.01, 40, "euler", save_every=2, chunk_steps=10, writer=w, progress=False)
    assert w.count == 4
    back = rb.load(tmp_path / "run", expect=rb.State)
    assert back.position.dtype == jnp.float32
    assert _max_diff(back, traj) == 0.0  # stored exactly
    meta = rb.read_metadata(tmp_path / "run")
    assert (meta["method"], meta["dt"], meta["save_every"], meta["chunks"]) == ("euler", 0.01, 2, 4)
    # float32 chunked vs one scan: same per-step arithmetic, bitwise
    assert _max_diff(traj, rb.simulate(s, torque, 0.01, 40, "euler", save_every=2)) == 0.0


def test_bad_arguments():
    s = _state()
    with pytest.raises(ValueError, match="chunk_steps must be a positive multiple of save_every=4"):
        rb.simulate_chunked(s, None, 0.01, 40, save_every=4, chunk_steps=10, progress=False)
    with pytest.raises(ValueError, match="save_every must be a positive int dividing steps"):
        rb.simulate_chunked(s, None, 0.01, 42, save_every=4, progress=False)
    with pytest.raises(ValueError, match="dt must be finite and > 0"):
        rb.simulate_chunked(s, None, -0.01, 40, progress=False)
