"""Cost of ``simulate(..., checked=True)``: body-steps per second with checks on vs off.

    python benchmarks/checked_cost.py [--quick] [--bodies N] [--steps S] [--x64]

Reports, for each method, the throughput of the unchecked and checked runs
(best of a few repeats, after compilation) and their ratio. Checked mode tests
every body every step (finiteness, ‖q‖, ``dt·|ω|`` against ``max_turn``) and every
saved frame (energy); checked runs take the JAX path, so they are compared with the
unchecked JAX path, and with checks but ``max_turn=None`` (the cost of the turn test).
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


def _rates(fns, n_bodies: int, steps: int, repeats: int) -> tuple[list[float], list[float]]:
    """Body-steps per wall second and per CPU second (all threads) of each function.

    Best of ``repeats``, the functions interleaved so that a change in machine load hits them
    alike. CPU time is the steadier measure on a shared machine (waiting for a core costs wall
    time, not CPU time); wall time is what a user sees on an idle one.
    """
    for fn in fns:
        jax.block_until_ready(fn())  # compile
    wall = [np.inf] * len(fns)
    cpu = [np.inf] * len(fns)
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            t, c = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn())
            wall[i] = min(wall[i], time.perf_counter() - t)
            cpu[i] = min(cpu[i], time.process_time() - c)
    work = n_bodies * steps
    return [work / w for w in wall], [work / c for c in cpu]


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
    steps = args.steps or (500 if args.quick else 2_000)
    repeats = 5 if args.quick else 7
    dtype = jnp.float64 if args.x64 else jnp.float32
    save_every = args.save_every
    state = _bodies(n, dtype)
    torque = rb.Forces(torque=jnp.full((n, 3), 0.01, dtype))
    dt = 1e-3
    print(
        f"checked-mode cost: {n} bodies x {steps} steps, save_every={args.save_every}, "
        f"{jnp.dtype(dtype).name}, {jax.devices()[0].platform}"
    )
    # checked mode runs on JAX: it is compared with the unchecked JAX path (native=False); the
    # default unchecked run (native kernels where they apply) is shown for reference
    cols = ("off, default", "off, JAX", "on, no max_turn", "on")
    print(f"{'method':10s}" + "".join(f"{c:>17s}" for c in cols) + f"{'on/JAX':>9s}{'no-turn/JAX':>12s}")
    print("(body-steps per wall second, best of the repeats; ratios per CPU second in brackets)")
    for method in [m for m in ("euler", "rk4", "splitting") if m in rb.methods()]:

        def run(checked, native=None, method=method):
            return rb.simulate(state, torque, dt, steps, method, save_every=save_every, checked=checked, native=native)

        fns = [
            lambda: run(False),
            lambda: run(False, native=False),
            lambda: run(rb.Checks(max_turn=None)),
            lambda: run(True),
        ]
        wall, cpu = _rates(fns, n, steps, repeats)
        ratios = f"{wall[3] / wall[1]:5.2f} ({cpu[3] / cpu[1]:.2f}){wall[2] / wall[1]:6.2f} ({cpu[2] / cpu[1]:.2f})"
        print(f"{method:10s}" + "".join(f"{w:17.3e}" for w in wall) + "  " + ratios)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
