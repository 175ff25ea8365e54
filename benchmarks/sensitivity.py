"""How sensitive a long trajectory is to its initial angular velocity.

Prints ``‖∂R(T)/∂ω₀‖_F`` (rotation matrix at time T w.r.t. the initial world
angular velocity, forward mode through rk4, dt = 1 ms) for a body with moments
(1, 2, 3) spun at 2 rad/s near its major axis (stable), and near its
intermediate axis (the separatrix: the Dzhanibekov flip).

    python benchmarks/sensitivity.py [--quick] [--json out.json]   (--quick: T = 1 s only, not saved)
"""

import argparse
import json

import jax
import jax.numpy as jnp

import rbjax as rb

jax.config.update("jax_enable_x64", True)
I = jnp.diag(jnp.array([1.0, 2.0, 3.0]))
DT = 1e-3


def sensitivity(w0, T):
    steps = int(round(T / DT))

    def final_R(w):
        s = rb.State.create(rb.Body(1.0, I), angular_velocity=w)
        return rb.rotation_matrix(rb.simulate(s, None, DT, steps, "rk4", save_every=steps))[-1]

    return float(jnp.linalg.norm(jax.jacfwd(final_R)(w0)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", default=None, help="default sensitivity.json (none with --quick)")
    ap.add_argument("--quick", action="store_true", help="T = 1 s only")
    args = ap.parse_args()
    horizons = (1,) if args.quick else (1, 5, 10, 20)
    path = args.json or (None if args.quick else "sensitivity.json")
    cases = {
        "major axis (stable)": jnp.array([0.01, 0.01, 2.0]),
        "intermediate axis (separatrix)": jnp.array([0.01, 2.0, 0.01]),
    }
    out = {}
    print(f"{'initial spin':>32} " + " ".join(f"T={T:>4}s" for T in horizons))
    for name, w0 in cases.items():
        vals = [sensitivity(w0, T) for T in horizons]
        out[name] = vals
        print(f"{name:>32} " + " ".join(f"{v:>8.3g}" for v in vals))
    if path:
        with open(path, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
