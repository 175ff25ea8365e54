"""One process of tests/test_multiprocess.py: a 2-process ``jax.distributed`` run, or its reference.

    python _multiprocess_worker.py ID PORT OUT.npz   # process ID of 2 on localhost:PORT
    python _multiprocess_worker.py ref OUT.npz        # one process, nothing sharded

Every process computes the same three things; the reference computes them in
one process without sharding, and the test compares the files:

* ``free``: a batch of bodies split over the 4 devices of both processes
  (``rb.batch_sharding``; each process builds only its own half with
  ``jax.make_array_from_process_local_data``), under gravity, by RK4;
* ``spring``: the same batch with a ``Spring`` between body 0 (process 0) and
  the last body (process 1): the coupled pair crosses processes;
* ``fit``: ``rb.fit_inertia`` of recordings sharded over processes at the
  process level: each process fits its own recordings, the results are
  gathered with ``process_allgather``.

The caller sets ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` and
``JAX_PLATFORMS=cpu`` before this starts.
"""

from __future__ import annotations

import dataclasses
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU collectives across processes

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from reference import reference_rotation  # noqa: E402

import rbjax as rb  # noqa: E402

N = 2048  # bodies: a multiple of the 4 devices
STEPS, SAVE = 200, 100
DT = 1e-3
RECORDINGS = 4  # fits: 2 per process
TIMES = np.linspace(0.0, 1.0, 101)  # 1 s at 100 Hz


def global_bodies() -> tuple[np.ndarray, ...]:
    """The whole batch as NumPy arrays (every process derives its slice from the same seed)."""
    rng = np.random.default_rng(19)
    q = rng.normal(size=(N, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return (
        rng.uniform(0.5, 2.0, N),
        rng.uniform(0.1, 0.5, (N, 3)),
        rng.normal(size=(N, 3)),
        rng.normal(size=(N, 3)),
        q,
        rng.normal(size=(N, 3)),
    )


def make_state(lo: int, hi: int) -> rb.State:
    m, sides, x, v, q, w = (a[lo:hi] for a in global_bodies())
    s = rb.State.create(rb.box(m, sides), position=x, velocity=v, orientation=q, angular_velocity=w)
    return jax.tree.map(np.asarray, s)


def spring() -> rb.Spring:
    # points off the centres of mass: forces and torques on both ends
    return rb.Spring.between(
        [0], [N - 1], 50.0, point_a=[[0.1, 0.0, 0.05]], point_b=[[0.0, -0.1, 0.0]], rest_length=0.5, damping=0.2
    )


def recordings() -> tuple[np.ndarray, list[np.ndarray]]:
    """Inertia tensors and their free-rotation recordings (scipy DOP853), one per fit."""
    rng = np.random.default_rng(7)
    base = np.array([[1.0, 0.1, -0.05], [0.1, 2.0, 0.08], [-0.05, 0.08, 2.6]])  # as tests/test_fit.py
    inertia, qs = [], []
    for _ in range(RECORDINGS):
        I = base * rng.uniform(0.8, 1.25) + np.diag(rng.uniform(-0.1, 0.1, 3))
        w0 = np.array([0.6, 6.0, 0.8]) + rng.normal(0, 0.2, 3)  # near the intermediate axis: a tumble in 1 s
        q, _ = reference_rotation(I, np.array([1.0, 0, 0, 0]), w0, TIMES)
        inertia.append(I)
        qs.append(q)
    return np.stack(inertia), qs


def fit(qs: list[np.ndarray]) -> np.ndarray:
    """Principal moments ``(n, 3)`` of a batched fit of the recordings ``qs``."""
    res = rb.fit_inertia(TIMES, np.stack(qs), segments=2)
    return np.asarray(res.principal_moments)


def simulate_all(state: rb.State) -> dict[str, rb.State]:
    free = rb.Scene.build(state, rb.Gravity(), "rk4").simulate(state, DT, STEPS, save_every=SAVE)
    coupled = rb.Scene.build(state, rb.Gravity() + spring(), "rk4").simulate(state, DT, STEPS, save_every=SAVE)
    return {"free": free, "spring": coupled}


def reference(out: str) -> None:
    trajs = simulate_all(make_state(0, N))
    _, qs = recordings()
    arrays = {f"{k}_{f}": np.asarray(getattr(t, f)) for k, t in trajs.items() for f in ("position", "orientation")}
    np.savez(out, fit=fit(qs), **arrays)


def distributed(pid: int, port: int, out: str) -> None:
    from jax.experimental import multihost_utils

    jax.distributed.initialize(coordinator_address=f"localhost:{port}", num_processes=2, process_id=pid)
    assert jax.process_count() == 2 and jax.device_count() == 4 and jax.local_device_count() == 2
    mesh = jax.make_mesh((jax.device_count(),), ("bodies",))
    n_local = N // jax.process_count()
    local = make_state(pid * n_local, (pid + 1) * n_local)
    state = jax.tree.map(jax.make_array_from_process_local_data, rb.batch_sharding(local, mesh), local)
    assert not state.position.is_fully_addressable  # a global batch: half of it lives in the other process
    # a batch on two clocks (each process's half at its own time) is refused, as in one process
    times = jax.make_array_from_process_local_data(rb.batch_sharding(local, mesh).time, local.time + pid)
    try:
        rb.simulate(dataclasses.replace(state, time=times), None, DT, 1)
    except ValueError as e:
        assert "share one time" in str(e), e
    else:
        raise AssertionError("a batch on two clocks was simulated")
    trajs = simulate_all(state)
    arrays = {}
    for k, t in trajs.items():
        for f in ("position", "orientation"):
            a = getattr(t, f)
            assert a.sharding.spec[1] == "bodies", a.sharding  # the trajectory stays split on its bodies
            arrays[f"{k}_{f}"] = np.asarray(multihost_utils.process_allgather(a, tiled=True))
    # fits sharded over recordings at the process level: each fits its own, then gather
    _, qs = recordings()
    per = RECORDINGS // jax.process_count()
    mine = fit(qs[pid * per : (pid + 1) * per])
    moments = np.asarray(multihost_utils.process_allgather(mine))  # (processes, per, 3)
    if pid == 0:
        np.savez(out, fit=moments.reshape(RECORDINGS, 3), **arrays)
    multihost_utils.sync_global_devices("written")  # neither process exits while the other still needs it


if __name__ == "__main__":
    if sys.argv[1] == "ref":
        reference(sys.argv[2])
    else:
        distributed(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3])
