"""Energy drift of ``"splitting"`` in float32 against float64 over long runs.

100 boxes (sides uniform in 0.3..1.5 m, unit mass), ω normal with σ = 2 rad/s
(|ω| ≈ 3.5 rad/s), torque-free; the relative kinetic-energy error of every
body against its float64 initial energy, the worst body, at 20 saved frames.
Output: benchmarks/results/float32_drift.json. About 20 s on 2 cores.

Run: python benchmarks/float32_drift.py [--quick]   (--quick: 4,000 steps at dt = 0.01, printed, not saved)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import rbjax as rb  # noqa: E402

N = 100


def errors(dtype, dt: float, steps: int) -> list[float]:
    rng = np.random.default_rng(9)
    size, w = rng.uniform(0.3, 1.5, (N, 3)), rng.normal(size=(N, 3)) * 2
    s = rb.State.create(rb.box(jnp.ones(N, dtype), jnp.asarray(size, dtype)), angular_velocity=jnp.asarray(w, dtype))
    exact = rb.State.create(rb.box(jnp.ones(N), jnp.asarray(size)), angular_velocity=jnp.asarray(w))
    traj = rb.simulate(s, None, dt, steps, "splitting", save_every=steps // 20)
    e = np.asarray(rb.kinetic_energy(traj), np.float64) / np.asarray(rb.kinetic_energy(exact)) - 1
    return [float(x) for x in np.abs(e).max(axis=1)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="4,000 steps at dt = 0.01 only, nothing saved")
    quick = ap.parse_args().quick
    out = {}
    for dt, steps in ((0.01, 4_000),) if quick else ((0.01, 400_000), (0.001, 100_000)):
        for dtype in (jnp.float32, jnp.float64):
            err = errors(dtype, dt, steps)
            out[f"{dtype.__name__} dt={dt} steps={steps}"] = err
            print(dtype.__name__, dt, steps, " ".join(f"{x:.1e}" for x in err[::4]), f"{err[-1]:.1e}")
    if quick:
        return
    path = Path(__file__).parent / "results" / "float32_drift.json"
    path.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
