"""What an eager ``rb.simulate`` call costs beyond the same call under ``jax.jit``.

Most users call ``simulate`` eagerly; its argument checks (the batch's one clock, the
step-size warning's turn per step, the force model's fields) then run on every call,
outside the compiled program. Side by side, per N and dtype: the median of ``--repeats``
eager calls and of the same call wrapped in ``jax.jit`` (compiled once), both blocked,
100 Euler steps on the default path (native where built), constant world forces as
arrays. Reports both times and their ratio (goal: eager ≤ 1.25x jit at N ≥ 1e4), and
a "new state" column: eager from a fresh state each call (a run continued from its last
frame), which the checks' cache cannot serve.

    python benchmarks/eager_overhead.py [--quick] [--sizes 10000,100000] [--json out.json]

Run it against another checkout with ``PYTHONPATH=that/checkout`` (the same script).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import rbjax as rb

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import machine  # noqa: E402

STEPS, DT = 100, 1e-3


def make_state(n: int, dtype) -> rb.State:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(n, 4))
    body = rb.box(jnp.asarray(rng.uniform(0.5, 2.0, n), dtype), jnp.asarray(rng.uniform(0.1, 1.0, (n, 3)), dtype))
    return rb.State.create(
        body,
        velocity=jnp.asarray(rng.normal(size=(n, 3)), dtype),
        orientation=jnp.asarray(q / np.linalg.norm(q, axis=1, keepdims=True), dtype),
        angular_velocity=jnp.asarray(rng.normal(size=(n, 3)), dtype),
    )


def interleaved_medians(fns: dict, repeats: int) -> dict:
    """Median blocked wall time of each of ``fns`` (name: call), the calls taken in turn within each
    repeat: a machine whose speed drifts (a shared VM) slows all of them alike, not one column."""
    for fn in fns.values():
        jax.block_until_ready(fn())
    times = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            times[k].append(time.perf_counter() - t0)
    return {k: float(np.median(v)) for k, v in times.items()}


def measure(n: int, dtype, repeats: int) -> dict:
    state = make_state(n, dtype)
    forces = rb.Forces(force=jnp.zeros((n, 3), dtype), torque=jnp.zeros((n, 3), dtype))
    run = lambda s, f: rb.simulate(s, f, DT, STEPS, "euler", save_every=STEPS)
    compiled = jax.jit(run)  # the state and forces as arguments: the program simulate compiles eagerly
    # a new state object each call, made outside the timing (a copy of the arrays, as a frame is)
    fresh = [jax.tree.map(jnp.copy, state) for _ in range(repeats + 1)]
    jax.block_until_ready(fresh)
    it = iter(fresh)
    t = interleaved_medians(
        dict(jit=lambda: compiled(state, forces), eager=lambda: run(state, forces), new=lambda: run(next(it), forces)),
        repeats,
    )
    return dict(
        bodies=n,
        dtype=np.dtype(dtype).name,
        steps=STEPS,
        jit_s=t["jit"],
        eager_s=t["eager"],
        eager_new_state_s=t["new"],
        eager_vs_jit=t["eager"] / t["jit"],
        new_state_vs_jit=t["new"] / t["jit"],
        native=rb.native_status().available,
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="N = 1e3 and 1e4, a few repeats")
    p.add_argument("--sizes", default=None, help="comma-separated N (default 1e4, 1e5, 1e6)")
    p.add_argument("--dtypes", default="float32,float64")
    p.add_argument("--repeats", type=int, default=None)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    sizes = [1_000, 10_000] if args.quick else [10_000, 100_000, 1_000_000]
    if args.sizes:
        sizes = [int(float(n)) for n in args.sizes.split(",")]
    repeats = args.repeats or (5 if args.quick else 30)
    rows = []
    for dname in args.dtypes.split(","):
        dtype = np.dtype(dname).type
        with jax.enable_x64(dtype == np.float64):
            for n in sizes:
                r = measure(n, dtype, repeats if n < 1_000_000 else max(5, repeats // 3))
                rows.append(r)
                print(
                    f"{r['dtype']} N={n:>8}: jit {r['jit_s'] * 1e3:8.3f} ms, eager {r['eager_s'] * 1e3:8.3f} ms "
                    f"({r['eager_vs_jit']:.2f}x), eager from a new state {r['eager_new_state_s'] * 1e3:8.3f} ms "
                    f"({r['new_state_vs_jit']:.2f}x)",
                    flush=True,
                )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(machine=machine(), rows=rows), f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
