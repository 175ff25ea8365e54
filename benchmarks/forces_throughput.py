"""What a scene's forces cost: ``simulate`` with no forces, ``Gravity() + QuadraticDrag``, the same law
as a callable, and the law plus springs on ten bodies, on the JAX path and the default path (the native
kernel where it applies; a sum with springs runs on JAX), side by side.

Each figure is a share of the same path's force-free rate, measured in one process: N boxes with
per-body masses, float32, ``steps`` steps per call with only the last state saved, the best of 3
timed calls after the first (whose time, compile included, is reported too), blocking on the whole
final state (blocking on one field lets XLA drop the rotation from a force-free run).

    python benchmarks/forces_throughput.py [--methods euler,rk4,rk4_body,splitting] [--n 100000]
        [--forces "none,gravity+quadratic drag"] [--json results/forces.json] [--md results/forces.md]
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp

import rbjax as rb

FORCES = ("none", "gravity+quadratic drag", "callable (same law)", "gravity+quadratic drag+springs")


def forces(name: str):
    if name == "none":
        return None
    if name == "gravity+quadratic drag":
        return rb.Gravity() + rb.QuadraticDrag(0.05, 0.01)
    if name == "gravity+quadratic drag+springs":  # ten bodies tied to anchors: a sum with a term not per body
        return (
            rb.Gravity() + rb.QuadraticDrag(0.05, 0.01) + rb.Spring.to_anchor(jnp.arange(10), jnp.zeros((10, 3)), 10.0)
        )
    g, c = jnp.array([0.0, 0.0, -9.81], jnp.float32), 0.05

    def law(s, t):  # Gravity() + QuadraticDrag(0.05) on the centre of mass (no drag torque)
        speed = jnp.linalg.norm(s.velocity, axis=-1, keepdims=True)
        return rb.Forces(force=s.body.mass[..., None] * g - c * speed * s.velocity)

    return law


def measure(state, method: str, name: str, native, steps: int) -> dict:
    f = forces(name)
    run = jax.jit(lambda s: rb.simulate(s, f, 1e-3, steps, method, save_every=steps, native=native))
    t = time.perf_counter()
    jax.block_until_ready(run(state))
    first = time.perf_counter() - t
    best = float("inf")
    for _ in range(3):
        t = time.perf_counter()
        jax.block_until_ready(run(state))
        best = min(best, time.perf_counter() - t)
    n = state.position.shape[0]
    path = "jax" if native is False else "default"
    return dict(method=method, forces=name, path=path, rate=n * steps / best, first=first)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", default="euler,rk4,rk4_body,splitting")
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--forces", default=",".join(FORCES), help="comma-separated, of: " + ", ".join(FORCES))
    ap.add_argument("--json", default=None)
    ap.add_argument("--md", default=None)
    args = ap.parse_args()
    n = args.n
    names = args.forces.split(",")
    if "none" not in names or any(name not in FORCES for name in names):
        ap.error(f"--forces: 'none' (the reference) and names among {FORCES}")
    body = rb.box(mass=jnp.ones(n), size=jnp.tile(jnp.array([0.1, 0.2, 0.4]), (n, 1)))
    w = jax.random.normal(jax.random.PRNGKey(0), (n, 3))
    state = rb.State.create(body, angular_velocity=w, velocity=jnp.zeros((n, 3)))
    rows = []
    for method in args.methods.split(","):
        for name in names:
            for native in (False, None):
                row = measure(state, method, name, native, args.steps)
                rows.append(row)
                line = f"{method:>12} {name:>24} {row['path']:>8} {row['rate']:9.2e} first {row['first']:5.2f} s"
                print(line, flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(dict(n=n, steps=args.steps, native=str(rb.native_status()), rows=rows), fh, indent=1)
    if args.md:
        r = {(x["method"], x["forces"], x["path"]): x for x in rows}
        out = [
            "| method | forces | JAX path | share of its force-free | default path | share of its force-free "
            "| first call JAX / default (s) |",
            "|---|---|---:|---:|---:|---:|---:|",
        ]
        for method in args.methods.split(","):
            for name in names:
                j, d = r[(method, name, "jax")], r[(method, name, "default")]
                j0, d0 = r[(method, "none", "jax")], r[(method, "none", "default")]
                out.append(
                    f"| {method} | {name} | {j['rate']:.2e} | {j['rate'] / j0['rate']:.2f}x | {d['rate']:.2e} "
                    f"| {d['rate'] / d0['rate']:.2f}x | {j['first']:.2f} / {d['first']:.2f} |"
                )
        with open(args.md, "w") as fh:
            fh.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
