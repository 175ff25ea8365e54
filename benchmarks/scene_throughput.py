"""Scene throughput: body-steps per second by body kind and force structure (float32).

Compares, at N = 1e4 and 1e5 bodies (``--quick``: 1e4, fewer steps, < 30 s):
particles vs spheres (rotation skipped), spheres vs general bodies (isotropic
kernel vs full ``R I⁻¹ Rᵀ``), the same spheres forced onto the general kernel,
and bodies with and without torques. Prints a table and writes JSON.

    python benchmarks/scene_throughput.py [--quick] [--method rk4] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

import rbjax as rb


def _cases(n: int, dtype):
    rng = np.random.default_rng(0)
    m = jnp.asarray(rng.uniform(0.5, 2.0, n), dtype)
    v = jnp.asarray(rng.normal(size=(n, 3)), dtype)
    w = jnp.asarray(rng.normal(size=(n, 3)), dtype)
    q = rng.normal(size=(n, 4))
    q = jnp.asarray(q / np.linalg.norm(q, axis=-1, keepdims=True), dtype)
    spheres = rb.State.create(rb.sphere(m, jnp.asarray(0.3, dtype)), velocity=v, angular_velocity=w, orientation=q)
    boxes = rb.State.create(
        rb.box(m, jnp.asarray(rng.uniform(0.2, 1.0, (n, 3)), dtype)),
        velocity=v,
        angular_velocity=w,
        orientation=q,
    )
    cyl = rb.State.create(
        rb.cylinder(m, jnp.asarray(0.2, dtype), jnp.asarray(1.0, dtype)),
        velocity=v,
        angular_velocity=w,
        orientation=q,
    )
    particles = rb.ParticleState.create(m, velocity=v)
    grav = rb.Gravity()
    torqued = rb.Gravity() + rb.LinearDrag(0.1, angular=0.05)
    return [
        ("particles, gravity", particles, grav, None),
        ("spheres, gravity (torque-free)", spheres, grav, None),
        ("spheres, gravity, forced general", spheres, grav, "general"),
        ("cylinders, gravity", cyl, grav, None),
        ("boxes, gravity (torque-free)", boxes, grav, None),
        ("spheres, gravity + drag torque", spheres, torqued, None),
        ("boxes, gravity + drag torque", boxes, torqued, None),
        ("boxes, no forces", boxes, None, None),
    ]


def _time(fn, repeats: int) -> float:
    jax.block_until_ready(fn())  # compile
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="N = 1e4 only, few steps (< 30 s)")
    ap.add_argument("--method", default="rk4")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "scene_throughput.json"))
    args = ap.parse_args()
    sizes = [10_000] if args.quick else [10_000, 100_000]
    steps = 20 if args.quick else 100
    repeats = 2 if args.quick else 3
    rows = []
    print(f"method={args.method} float32 steps={steps} device={jax.devices()[0].device_kind}")
    print(f"{'case':36s} {'N':>8s} {'kind':>13s} {'torque':>6s} {'Mbody-steps/s':>14s} {'vs boxes+torque':>16s}")
    for n in sizes:
        results = []
        for name, state, forces, kind in _cases(n, jnp.float32):
            scene = rb.Scene.build(state, forces, args.method, kind=kind)
            sec = _time(lambda s=state, sc=scene: sc.simulate(s, 1e-3, steps, save_every=steps), repeats)
            results.append(
                dict(
                    case=name,
                    n=n,
                    kind=scene.kind,
                    torque_free=scene.torque_free,
                    seconds=sec,
                    body_steps_per_s=n * steps / sec,
                )
            )
        base = next(r for r in results if r["case"] == "boxes, gravity + drag torque")["body_steps_per_s"]
        for r in results:
            r["ratio_vs_general_torqued"] = r["body_steps_per_s"] / base
            print(
                f"{r['case']:36s} {n:8d} {r['kind']:>13s} {str(not r['torque_free']):>6s} "
                f"{r['body_steps_per_s'] / 1e6:14.1f} {r['ratio_vs_general_torqued']:15.2f}x"
            )
        rows.extend(results)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(
            dict(
                method=args.method,
                dtype="float32",
                steps=steps,
                machine=platform.machine(),
                cpus=os.cpu_count(),
                device=jax.devices()[0].device_kind,
                rows=rows,
            ),
            f,
            indent=1,
        )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
