"""Cost of ``simulate(..., checked=True)``: body-steps per second with checks on vs off.

    python benchmarks/checked_cost.py [--quick] [--bodies N] [--steps S] [--x64]

Reports, for each method, the throughput of the unchecked and checked runs
(best of a few repeats, after compilation) and their ratio. Checked mode tests
every body every step (finiteness, ‖q‖) and every saved frame (energy).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np


def _bodies(n: int, dtype):
    import rbjax as rb

    rng = np.random.default_rng(0)
    size = rng.uniform(0.5, 2.0, (n, 3))
    body = rb.box(jnp.asarray(rng.uniform(0.5, 2.0, n), dtype), jnp.asarray(size, dtype))
    w = jnp.asarray(rng.normal(size=(n, 3)), dtype)
    return rb.State.create(body, angular_velocity=w)


def _rate(fn, n_bodies: int, steps: int, repeats: int) -> float:
    jax.block_until_ready(fn())  # compile
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t)
    return n_bodies * steps / best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (< 20 s)")
    ap.add_argument("--bodies", type=int, default=None)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--save-every", type=int, default=10)
    ap.add_argument("--x64", action="store_true", help="float64 (default float32)")
    args = ap.parse_args(argv)
    if args.x64:
        jax.config.update("jax_enable_x64", True)
    import rbjax as rb

    n = args.bodies or (1_000 if args.quick else 10_000)
    steps = args.steps or (200 if args.quick else 2_000)
    repeats = 3 if args.quick else 5
    dtype = jnp.float64 if args.x64 else jnp.float32
    save_every = args.save_every
    state = _bodies(n, dtype)
    torque = rb.Forces(torque=jnp.full((n, 3), 0.01, dtype))
    dt = 1e-3
    print(f"checked-mode cost: {n} bodies x {steps} steps, save_every={args.save_every}, "
          f"{jnp.dtype(dtype).name}, {jax.devices()[0].platform}")
    print(f"{'method':8s} {'off (body-steps/s)':>20s} {'on (body-steps/s)':>20s} {'on/off':>8s}")
    for method in [m for m in ("euler", "rk4", "splitting") if m in rb.methods()]:
        rates = []
        for checked in (False, True):
            def run(method=method, checked=checked):
                return rb.simulate(state, torque, dt, steps, method, save_every=save_every, checked=checked)

            rates.append(_rate(run, n, steps, repeats))
        print(f"{method:8s} {rates[0]:20.3e} {rates[1]:20.3e} {rates[1] / rates[0]:8.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
