"""Cost per step of every integrator relative to ``"euler"``, against its FLOP share.

N = 10⁴ tumbling bodies with distinct non-diagonal inertias, float32, constant
torque, ``simulate`` of 500 steps (compiled once, best of 5), all methods side
by side in one process, every method on its JAX step (``native=False``).
Beside each time, deterministic measures of the compiled program:

* ``flops``, ``bytes``: XLA's cost analysis of one ``rbjax.step`` per body
  (``bytes`` sums every kernel's operands and outputs, so it counts the passes
  over memory a step makes; sines and cosines are counted apart by XLA as
  transcendentals, not in ``flops``);
* ``kernels``: XLA ops that run as their own loop over the batch (fusions,
  dots, copies, custom calls) in the innermost loop of the compiled ``simulate``;
* ``time/flop``: the time ratio to ``"euler"`` over the FLOP ratio to
  ``"euler"`` (the goal: at most 2).

Run: ``PYTHONPATH=. python benchmarks/integrator_cost.py [--quick] [--n N]``.
"""

import argparse
import os
import re
import time

import jax
import jax.numpy as jnp
import numpy as np

import rbjax as rb

KERNEL_OPS = ("fusion", "dot", "copy", "custom-call", "transpose", "reduce", "concatenate", "sort")


def make(n):
    rng = np.random.default_rng(0)
    Q = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    d = rng.uniform(1.0, 2.0, size=(n, 3))
    I = np.einsum("nij,nj,nkj->nik", Q, d, Q).astype(np.float32)
    body = rb.Body(jnp.ones(n, jnp.float32), jnp.asarray(I))
    state = rb.State.create(body, angular_velocity=jnp.asarray(rng.normal(size=(n, 3)), jnp.float32))
    forces = rb.Forces(force=jnp.zeros(3, jnp.float32), torque=jnp.asarray([0.0, 0.0, 0.1], jnp.float32))
    return state, forces


def loop_kernels(hlo: str) -> int:
    """Kernels in the innermost while body (the per-step loop) of optimised HLO text."""
    comps = {}
    for block in re.split(r"\n(?=\S)", hlo):
        m = re.match(r"(?:ENTRY )?%?([\w.\-]+) ", block)
        if m:
            comps[m.group(1)] = block
    bodies = [comps[b] for b in re.findall(r"body=%?([\w.\-]+)", hlo) if "while(" not in comps[b]]
    pattern = r"= \S+ (?:" + "|".join(re.escape(o) for o in KERNEL_OPS) + r")\("
    return max((len(re.findall(pattern, b)) for b in bodies), default=0)


def measure(name, state, forces, steps, repeats):
    n = state.batch_shape[0]
    step = jax.jit(lambda s: rb.step(s, forces, 1e-3, name)).lower(state).compile()
    ca = step.cost_analysis()
    ca = ca[0] if isinstance(ca, list) else ca
    # native=False: every method on its JAX step, so the ratios compare like with like (the native
    # kernels cover five methods; their rates are in benchmarks/throughput.py)
    sim = jax.jit(lambda s: rb.simulate(s, forces, 1e-3, steps, name, save_every=steps, native=False))
    kernels = loop_kernels(sim.lower(state).compile().as_text())
    jax.block_until_ready(sim(state))
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(sim(state))
        best = min(best, time.perf_counter() - t)
    return dict(
        time=best / steps,
        flops=ca.get("flops", 0.0) / n,
        transcendentals=ca.get("transcendentals", 0.0) / n,
        bytes=ca.get("bytes accessed", 0.0) / n,
        kernels=kernels,
    )


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="N = 1000, 50 steps: checks it runs")
    p.add_argument("--n", type=int, default=None)
    args = p.parse_args(argv)
    n = args.n or (1_000 if args.quick else 10_000)
    steps, repeats = (50, 2) if args.quick else (500, 5)
    state, forces = make(n)
    rows = {m: measure(m, state, forces, steps, repeats) for m in rb.methods(rb.State)}
    e = rows["euler"]
    print(f"N = {n}, float32, load {np.round(os.getloadavg(), 2).tolist()}")
    print(
        "| method | us/step | x euler | flops/body-step | transc./body-step | bytes/body-step"
        " | loop kernels | x euler flops | time/flop |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for m, r in rows.items():
        tr, fr = r["time"] / e["time"], r["flops"] / e["flops"]
        print(
            f"| {m} | {r['time'] * 1e6:.1f} | {tr:.2f} | {r['flops']:.0f} | {r['transcendentals']:.0f} | "
            f"{r['bytes']:.0f} | {r['kernels']} | {fr:.2f} | {tr / fr:.2f} |"
        )
    return rows


if __name__ == "__main__":
    main()
