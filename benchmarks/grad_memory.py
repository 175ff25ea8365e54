"""Peak memory and time of reverse mode through ``simulate`` vs horizon, with and without ``checkpoint=``.

Memory is XLA's compiled temporary allocation for the gradient program
(``jit(grad).lower().compile().memory_analysis()``), which is what must fit in
RAM; the largest cases are only compiled, not run. Time is one gradient
evaluation after compilation. Loss: sum of the final angular momenta of N
bodies (``save_every = steps``), rk4, float64.

    python benchmarks/grad_memory.py [--quick] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import time

import jax
import jax.numpy as jnp

import rbjax as rb

jax.config.update("jax_enable_x64", True)


def _loss(w, steps, bodies, ck):
    body = rb.box(1.0, jnp.array([1.0, 2.0, 3.0]))
    s = rb.State.create(body, angular_velocity=jnp.broadcast_to(w, (bodies, 3)))
    tr = rb.simulate(s, None, 1e-4, steps, "rk4", save_every=steps, checkpoint=ck)
    return jnp.sum(tr.orientation[-1] * jnp.arange(4.0))  # torque-free L is constant


def _segment(steps):
    """Divisor of ``steps`` nearest √steps (memory-optimal single-level checkpointing)."""
    r = math.isqrt(steps)
    return min((d for d in range(1, steps + 1) if steps % d == 0), key=lambda d: abs(d - r))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", default="grad_memory.json")
    args = ap.parse_args()
    cases = (
        [(1000, 100, True), (4096, 100, True)]
        if args.quick
        else [(1000, 1000, True), (10000, 1000, True), (100000, 1000, False)]
    )
    w = jnp.array([0.1, 2.0, 0.1])
    rows = []
    print(f"{'steps':>8} {'bodies':>7} {'checkpoint':>10} {'temp MB':>10} {'grad s':>8} {'fwd s':>8}")
    fwd = jax.jit(_loss, static_argnums=(1, 2, 3))
    for steps, bodies, run in cases:
        for ck in (None, _segment(steps)):
            g = jax.jit(jax.grad(_loss), static_argnums=(1, 2, 3))
            c = g.lower(w, steps, bodies, ck).compile()
            mb = c.memory_analysis().temp_size_in_bytes / 1e6
            tg = tf = float("nan")
            if run:
                c(w).block_until_ready()
                t = time.perf_counter()
                c(w).block_until_ready()
                tg = time.perf_counter() - t
                fwd(w, steps, bodies, ck).block_until_ready()
                t = time.perf_counter()
                fwd(w, steps, bodies, ck).block_until_ready()
                tf = time.perf_counter() - t
            rows.append(dict(steps=steps, bodies=bodies, checkpoint=ck, temp_mb=mb, grad_s=tg, forward_s=tf))
            print(f"{steps:>8} {bodies:>7} {str(ck):>10} {mb:>10.1f} {tg:>8.3f} {tf:>8.3f}")
    with open(args.json, "w") as f:
        json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
