"""Cost per step of every integrator relative to ``"euler"`` (the ``Method.cost`` numbers).

N = 10⁴ tumbling bodies with distinct non-diagonal inertias, float32, constant
torque, ``simulate`` of 500 steps (compiled once, best of 5).
Run: ``PYTHONPATH=. python benchmarks/integrator_cost.py``.
"""

import time

import jax
import jax.numpy as jnp
import numpy as np

import rbjax as rb

N, STEPS = 10_000, 500
rng = np.random.default_rng(0)
Q = np.linalg.qr(rng.normal(size=(N, 3, 3)))[0]
d = rng.uniform(1.0, 2.0, size=(N, 3))
I = np.einsum("nij,nj,nkj->nik", Q, d, Q).astype(np.float32)
body = rb.Body(jnp.ones(N, jnp.float32), jnp.asarray(I))
state = rb.State.create(body, angular_velocity=jnp.asarray(rng.normal(size=(N, 3)), jnp.float32))
forces = rb.Forces(force=jnp.zeros(3, jnp.float32), torque=jnp.asarray([0.0, 0.0, 0.1], jnp.float32))


def time_method(name):
    run = lambda: jax.block_until_ready(rb.simulate(state, forces, 1e-3, STEPS, name, save_every=STEPS))
    run()
    best = np.inf
    for _ in range(5):
        t = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - t)
    return best / STEPS


times = {m: time_method(m) for m in rb.methods(rb.State)}
for m, t in times.items():
    print(f"{m:22s} {t * 1e6:8.1f} us/step  {t / times['euler']:5.2f}x euler")
