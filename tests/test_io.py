"""Saving and loading: exact round trips, type and version guards, chunk directories."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb


def _bitwise_equal(a, b) -> bool:
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    # same structure and types (None fields included), same dtypes and bits
    return ta == tb and all(
        x.dtype == y.dtype and x.shape == y.shape and np.asarray(x).tobytes() == np.asarray(y).tobytes()
        for x, y in zip(la, lb, strict=True)
    )


def _state(dtype, batch=(3,)):
    rng = np.random.default_rng(1)
    size = rng.uniform(0.5, 2, batch + (3,))
    body = rb.box(jnp.asarray(rng.uniform(0.5, 2, batch), dtype), jnp.asarray(size, dtype))
    q = rng.normal(size=batch + (4,))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return rb.State.create(
        body,
        position=jnp.asarray(rng.normal(size=batch + (3,)), dtype),
        velocity=jnp.asarray(rng.normal(size=batch + (3,)), dtype),
        orientation=jnp.asarray(q, dtype),
        angular_velocity=jnp.asarray(rng.normal(size=batch + (3,)), dtype),
    )


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_round_trip_is_bitwise(tmp_path, dtype):
    s = _state(dtype)
    traj = rb.simulate(s, None, 0.01, 6, "euler", save_every=2)  # (4, 3, ...) with an unstacked (3,) body
    objects = {
        "state": s,
        "one_body": _state(dtype, batch=()),
        "traj": traj,
        "matrix": rb.to_matrix_state(s),
        "particles": rb.ParticleState.create(jnp.asarray([1.0, 2.0], dtype), position=jnp.ones((2, 3), dtype)),
        "body": s.body,
        "forces_torque_only": rb.Forces(torque=jnp.ones((3, 3), dtype)),
    }
    for name, obj in objects.items():
        path = tmp_path / f"{name}.npz"
        rb.save(path, obj, method="rk4" if name == "traj" else None, dt=0.01 if name == "traj" else None)
        back = rb.load(path)
        assert type(back) is type(obj), name
        assert _bitwise_equal(back, obj), name
    meta = rb.read_metadata(tmp_path / "traj.npz")
    assert (meta["method"], meta["dt"], meta["dtype"]) == ("rk4", 0.01, jnp.dtype(dtype).name)
    assert meta["tree"]["fields"]["body"]["type"] == "Body"
    assert rb.load(tmp_path / "forces_torque_only.npz").force is None


def test_non_finite_values_round_trip(tmp_path):
    # a blown-up run must still be saveable and loadable for post-mortem (no validation on load)
    s = _state(jnp.float64)
    bad = rb._pytree.replace(s, velocity=s.velocity.at[1, 0].set(jnp.nan).at[2, 2].set(jnp.inf))
    rb.save(tmp_path / "bad.npz", bad)
    assert _bitwise_equal(rb.load(tmp_path / "bad.npz"), bad)


def test_wrong_type_and_version_raise(tmp_path, monkeypatch):
    path = tmp_path / "s.npz"
    rb.save(path, _state(jnp.float64))
    assert isinstance(rb.load(path, expect=(rb.MatrixState, rb.State)), rb.State)
    with pytest.raises(ValueError, match="holds a State, expected MatrixState"):
        rb.load(path, expect=rb.MatrixState)
    monkeypatch.setattr(rb, "__version__", "1.0.0")
    with pytest.raises(ValueError, match="written by rbjax 0.1.0.*major version"):
        rb.load(path)
    monkeypatch.setattr(rb, "__version__", "0.9.3")  # same major: loads
    assert _bitwise_equal(rb.load(path), rb.load(path))


def test_not_an_rbjax_file(tmp_path):
    np.savez(tmp_path / "plain.npz", x=np.ones(3))
    with pytest.raises(ValueError, match="not an rbjax file"):
        rb.load(tmp_path / "plain.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="cannot read"):
        rb.load(tmp_path / "junk.npz")
    with pytest.raises(TypeError, match="can store"):
        rb.save(tmp_path / "x.npz", {"a": jnp.ones(3)})


def test_chunk_directory_concatenates_and_survives_a_crash(tmp_path):
    s = _state(jnp.float64)
    traj = rb.simulate(s, None, 0.01, 9, "euler", save_every=3)  # frames 0, 3, 6, 9
    w = rb.ChunkWriter(tmp_path / "run", method="euler", dt=0.01, save_every=3)
    take = lambda sl: rb._chunked._frames(traj, sl)
    w.write(take(slice(0, 2)))
    w.write(take(slice(2, 3)))
    # a crash while writing the third chunk leaves only its temporary file
    (tmp_path / "run" / "chunk_000002.npz.abc123.tmp").write_bytes(b"partial")
    back = rb.load(tmp_path / "run", expect=rb.State)
    assert _bitwise_equal(back, take(slice(0, 3)))
    assert rb.read_metadata(tmp_path / "run")["chunks"] == 2
    w.write(take(slice(3, 4)))
    assert _bitwise_equal(rb.load(tmp_path / "run"), traj)
    # a lost chunk in the middle is reported, not silently skipped
    os.unlink(tmp_path / "run" / "chunk_000001.npz")
    with pytest.raises(ValueError, match=r"missing chunk\(s\) \[1\]"):
        rb.load(tmp_path / "run")
    with pytest.raises(ValueError, match="already holds"):
        rb.ChunkWriter(tmp_path / "run")
    assert rb.ChunkWriter(tmp_path / "run", overwrite=True).count == 0
    assert not [n for n in os.listdir(tmp_path / "run") if n.startswith("chunk_") and n.endswith(".npz")]
