"""What rotors cost a step: the same batch of torque-free bodies with and without three shared
rotors (reaction wheels along the body axes), side by side in one run, JAX path (a gyrostat
always runs there).

Issue 58's goal: with rotors, at least 0.7x the same method's rotor-free rate. The rotor-free
runs here use ``native=False`` too, so the ratio compares like with like.

    python benchmarks/rotor_cost.py [--sizes 10000,100000] [--methods euler,rk4,splitting] [--quick]
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import rbjax as rb  # noqa: E402


def rate(n: int, method: str, dtype, rotors: bool, steps: int) -> float:
    """Best body-steps per second of 5 runs of ``steps`` steps (only the last state saved)."""
    rng = np.random.default_rng(0)
    body = rb.box(jnp.asarray(rng.uniform(0.5, 2, n), dtype), jnp.asarray(rng.uniform(0.1, 1, (n, 3)), dtype))
    w = jnp.asarray(rng.normal(size=(n, 3)), dtype)
    extra = {}
    if rotors:
        wheels = rb.Rotors(axes=np.eye(3), inertia=np.full(3, 1e-3))
        extra = dict(rotors=wheels, rotor_rates=jnp.asarray(rng.normal(0, 50, (n, 3)), dtype))
    s = rb.State.create(body, angular_velocity=w, **extra)
    run = jax.jit(lambda s: rb.simulate(s, None, 1e-3, steps, method, save_every=steps, native=False))
    jax.block_until_ready(run(s))
    best = float("inf")
    for _ in range(5):
        t = time.perf_counter()
        jax.block_until_ready(run(s))
        best = min(best, time.perf_counter() - t)
    return n * steps / best


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="10000,100000")
    ap.add_argument("--methods", default="euler,rk4,splitting")
    ap.add_argument("--dtypes", default="float32,float64")
    ap.add_argument("--quick", action="store_true", help="N = 1000, euler, float64 (a smoke run)")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    if args.quick:
        args.sizes, args.methods, args.dtypes = "1000", "euler", "float64"
    rows = []
    for dtype in args.dtypes.split(","):
        for method in args.methods.split(","):
            for n in (int(x) for x in args.sizes.split(",")):
                steps = max(10, int(2e6 // n))
                plain = rate(n, method, getattr(jnp, dtype), False, steps)
                gyro = rate(n, method, getattr(jnp, dtype), True, steps)
                rows.append(dict(method=method, dtype=dtype, n=n, plain=plain, rotors=gyro, ratio=gyro / plain))
                print(f"{method:>10} {dtype} N={n:>7}: {plain:.3e} / {gyro:.3e} body-steps/s, ratio {gyro / plain:.2f}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
