"""What a scene's forces cost: ``simulate`` with no forces, ``Gravity() + QuadraticDrag``, the same law
as a callable, and the law plus springs on ten bodies, on the JAX path and the default path (the native
kernel where it applies; a sum with springs runs on JAX), side by side.

Each figure is a share of the same path's force-free rate, measured in one process: N boxes with
per-body masses, float32, ``steps`` steps per call with only the last state saved, blocking on the
whole final state (blocking on one field lets XLA drop the rotation from a force-free run). Every
case is compiled first (that first call, compile included, is reported); then ``--rounds`` rounds
each time every case once, in an order that rotates from round to round, so that a slow spell of a
shared machine falls on all cases alike. A share is taken within each round (the case against its
force-free twin of the same round) and reported as the median with the lowest and highest round;
so is each method's force-free rate against euler's (``vs euler``, default path), issue 29's second
ratio.

    python benchmarks/forces_throughput.py [--methods euler,rk4,rk4_body,splitting] [--n 100000]
        [--forces "none,gravity+quadratic drag"] [--rounds 7] [--json results/forces.json]
        [--md results/forces.md] [--quick]   (--quick: N = 1000, euler and rk4, 2 rounds)
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np
from _common import machine

import rbjax as rb

PATHS = {"jax": False, "default": None}
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


def compiled(state, method: str, name: str, native, steps: int):
    """``(run, seconds of its first call)``: ``run(state)`` is ``steps`` steps, the final state saved."""
    f = forces(name)
    run = jax.jit(lambda s: rb.simulate(s, f, 1e-3, steps, method, save_every=steps, native=native))
    t = time.perf_counter()
    jax.block_until_ready(run(state))
    return run, time.perf_counter() - t


def seconds(run, state) -> float:
    t = time.perf_counter()
    jax.block_until_ready(run(state))
    return time.perf_counter() - t


def spread(values) -> dict:
    v = np.asarray(values, float)
    return dict(median=float(np.median(v)), low=float(v.min()), high=float(v.max()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", default="euler,rk4,rk4_body,splitting")
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--forces", default=",".join(FORCES), help="comma-separated, of: " + ", ".join(FORCES))
    ap.add_argument("--rounds", type=int, default=7, help="timed calls of every case, interleaved")
    ap.add_argument("--json", default=None)
    ap.add_argument("--md", default=None)
    ap.add_argument("--quick", action="store_true", help="N = 1000, euler and rk4, with and without forces, 2 rounds")
    args = ap.parse_args()
    if args.quick:
        args.n, args.methods, args.forces, args.rounds = 1000, "euler,rk4", "none,gravity+quadratic drag", 2
    n = args.n
    names = args.forces.split(",")
    if "none" not in names or any(name not in FORCES for name in names):
        ap.error(f"--forces: 'none' (the reference) and names among {FORCES}")
    body = rb.box(mass=jnp.ones(n), size=jnp.tile(jnp.array([0.1, 0.2, 0.4]), (n, 1)))
    w = jax.random.normal(jax.random.PRNGKey(0), (n, 3))
    state = rb.State.create(body, angular_velocity=w, velocity=jnp.zeros((n, 3)))
    cases = [(m, name, path) for m in args.methods.split(",") for name in names for path in ("jax", "default")]
    runs, first = {}, {}
    for case in cases:
        runs[case], first[case] = compiled(state, case[0], case[1], PATHS[case[2]], args.steps)
    rates: dict = {case: [] for case in cases}
    for r in range(args.rounds):
        for case in cases[r % len(cases) :] + cases[: r % len(cases)]:
            rates[case].append(n * args.steps / seconds(runs[case], state))
    rows = []
    for case in cases:
        m, name, path = case
        row = dict(method=m, forces=name, path=path, first=first[case], rates=rates[case])
        row["rate"] = float(np.median(rates[case]))
        row["share"] = spread(np.divide(rates[case], rates[(m, "none", path)]))
        if (("euler", "none", path)) in rates:
            row["vs_euler"] = spread(np.divide(rates[case], rates[("euler", "none", path)]))
        rows.append(row)
        share = row["share"]
        print(
            f"{m:>12} {name:>24} {path:>8} {row['rate']:9.2e} share {share['median']:.2f}x "
            f"({share['low']:.2f}-{share['high']:.2f}) first {row['first']:5.2f} s",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as fh:
            meta = dict(n=n, steps=args.steps, rounds=args.rounds, native=str(rb.native_status()), machine=machine())
            json.dump(dict(meta, rows=rows), fh, indent=1)
    if args.md:
        r = {(x["method"], x["forces"], x["path"]): x for x in rows}

        def cell(x, key):
            v = x.get(key)
            return "-" if v is None else f"{v['median']:.2f}x ({v['low']:.2f}-{v['high']:.2f})"

        out = [
            f"N = {n}, float32, {args.steps} steps per call, {args.rounds} rounds; rates: the median; "
            "shares: the median (lowest-highest) of the rounds' ratios.",
            "",
            "| method | forces | JAX path | share of its force-free | default path | share of its force-free "
            "| default vs euler | first call JAX / default (s) |",
            "|---|---|---:|---:|---:|---:|---:|---:|",
        ]
        for case in cases:
            if case[2] != "jax":
                continue
            j, d = r[case], r[(case[0], case[1], "default")]
            out.append(
                f"| {case[0]} | {case[1]} | {j['rate']:.2e} | {cell(j, 'share')} | {d['rate']:.2e} "
                f"| {cell(d, 'share')} | {cell(d, 'vs_euler')} | {j['first']:.2f} / {d['first']:.2f} |"
            )
        with open(args.md, "w") as fh:
            fh.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
