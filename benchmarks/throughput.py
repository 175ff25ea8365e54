"""Throughput of ``simulate`` against a NumPy structure-of-arrays step, side by side.

For each N (bodies), dtype and method: body-steps per second of a compiled
``rbjax.simulate`` (lax.scan, only the final state saved), the first-call
compile time, and the same explicit-Euler step written in NumPy on
structure-of-arrays data ((3, N) arrays, in-place-free vector ops). Prints a
markdown table and writes JSON.

    python benchmarks/throughput.py            # full: N up to 1e6
    python benchmarks/throughput.py --quick    # < 1 minute, checks it runs
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)  # allow float64 rows; float32 rows ask for it

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
import rbjax as rb  # noqa: E402


def make_state(n: int, dtype) -> rb.State:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    body = rb.box(rng.uniform(0.5, 2, n).astype(dtype), rng.uniform(0.1, 1, (n, 3)).astype(dtype))
    return rb.State.create(body, orientation=q.astype(dtype), angular_velocity=rng.normal(size=(n, 3)).astype(dtype),
                           velocity=rng.normal(size=(n, 3)).astype(dtype))


def time_rbjax(state, method: str, steps: int, dt: float, repeats: int = 3):
    f = jax.jit(lambda s: rb.simulate(s, None, dt, steps, method, save_every=steps))
    t0 = time.perf_counter()
    compiled = f.lower(state).compile()
    t_compile = time.perf_counter() - t0
    jax.block_until_ready(compiled(state))
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(state))
        best = min(best, time.perf_counter() - t0)
    return best, t_compile


def numpy_euler_soa(x, v, q, L, Iinv, dt, steps):
    """The same explicit Euler (L-form, torque-free) in NumPy, components along axis 0."""
    def rot(qw, qv, a):
        t = 2 * np.cross(qv, a, axis=0)
        return a + qw * t + np.cross(qv, t, axis=0)

    for _ in range(steps):
        qw, qv = q[0], q[1:]
        lb = rot(qw, -qv, L)
        wb = np.einsum("ijn,jn->in", Iinv, lb)
        w = rot(qw, qv, wb)
        dq = np.empty_like(q)
        dq[0] = -np.sum(w * qv, axis=0)
        dq[1:] = qw * w + np.cross(w, qv, axis=0)
        x = x + v * dt
        q = q + 0.5 * dt * dq
        q = q / np.sqrt(np.sum(q * q, axis=0))
    return x, v, q, L


def time_numpy(state, steps, dt, repeats=2):
    arrs = [np.asarray(a).T.copy() for a in (state.position, state.velocity, state.orientation, state.angular_momentum)]
    Iinv = np.moveaxis(np.asarray(state.body.inverse_inertia), 0, -1).copy()
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        numpy_euler_soa(*arrs, Iinv, arrs[0].dtype.type(dt), steps)
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small sizes, < 1 minute")
    p.add_argument("--methods", default="euler", help="comma-separated methods (default euler; 'all')")
    p.add_argument("--json", default="benchmarks/results/throughput.json")
    args = p.parse_args(argv)
    sizes = [1, 100, 10_000] if args.quick else [1, 100, 10_000, 100_000, 1_000_000]
    methods = list(rb.methods(rb.State)) if args.methods == "all" else args.methods.split(",")
    dtypes = [np.float32, np.float64]
    budget = 2e6 if args.quick else 3e7  # body-steps per timed run
    rows = []
    for dtype in dtypes:
        for n in sizes:
            steps = int(max(10, min(2000, budget // n)))
            state = make_state(n, dtype)
            t_np = time_numpy(state, min(steps, 200), 1e-3) * steps / min(steps, 200)
            for method in methods:
                t, tc = time_rbjax(state, method, steps, 1e-3)
                row = dict(method=method, dtype=np.dtype(dtype).name, bodies=n, steps=steps,
                           body_steps_per_s=n * steps / t, compile_s=tc,
                           numpy_body_steps_per_s=n * steps / t_np if method == "euler" else None)
                row["ratio_vs_numpy"] = row["body_steps_per_s"] / row["numpy_body_steps_per_s"] if row["numpy_body_steps_per_s"] else None
                rows.append(row)
                print(f"{method:>20} {row['dtype']:>8} N={n:>8} {row['body_steps_per_s']:.3e} body-steps/s "
                      f"(numpy {row['numpy_body_steps_per_s'] or float('nan'):.3e}, x{row['ratio_vs_numpy'] or float('nan'):.1f}) "
                      f"compile {tc:.2f} s", flush=True)
    machine = dict(platform=platform.platform(), processor=platform.processor() or platform.machine(),
                   cpus=os.cpu_count(), jax=jax.__version__, device=str(jax.devices()[0]))
    print("\n| method | dtype | N | body-steps/s | NumPy SoA | ratio | compile (s) |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for r in rows:
        np_s = f"{r['numpy_body_steps_per_s']:.2e}" if r["numpy_body_steps_per_s"] else "–"
        ratio = f"{r['ratio_vs_numpy']:.1f}x" if r["ratio_vs_numpy"] else "–"
        print(f"| {r['method']} | {r['dtype']} | {r['bodies']:,} | {r['body_steps_per_s']:.2e} | {np_s} | {ratio} | {r['compile_s']:.2f} |")
    print(f"\nmachine: {machine}")
    if args.json:
        os.makedirs(os.path.dirname(args.json), exist_ok=True)
        with open(args.json, "w") as f:
            json.dump(dict(machine=machine, rows=rows, quick=args.quick), f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
