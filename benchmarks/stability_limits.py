"""Measured stability limits of the explicit methods: the largest dt·|ω| at which 1000 steps stay bounded.

For each method and state form, torque-free, float64: 24 bodies (four shapes:
the box 0.1x0.2x0.4 of the stability tests, a 1:2:3 ellipsoid, a cylinder (axisymmetric) and a
Dzhanibekov T-handle I = diag(1, 2, 2.8)), six random ω directions each, |ω| = 1,
and dt on a geometric grid (ratio 10^(1/8) ≈ 1.33) from 0.01 to 1000. A run is
bounded when every state stays finite, the orientation stays a unit quaternion /
rotation (checked mode's test, quat_tol 1e-6) -- the ``finite`` limit, beyond
which the method diverges -- and, for ``energy_within_2x``, the kinetic energy
also stays within a factor 2 of its initial value. A limit is the last grid
value before the first failing one (``None``: none failed up to 1000).
Output: benchmarks/results/stability_limits.json; the figures are copied into
the registered methods (``Method.stable_dt_omega``).

Run: python benchmarks/stability_limits.py (about 15 s on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import rbjax as rb  # noqa: E402

# steps of up to 1000 rad are this benchmark's subject: rbjax's warning about them is known here
warnings.simplefilter("ignore", rb.StepSizeWarning)

METHODS = ("euler", "semi_implicit_euler", "rk4", "rk8")
GRID = 10.0 ** (np.arange(-16, 25) / 8)  # 0.01 .. 1000
STEPS = 1000


def bodies() -> rb.Body:
    shapes = [
        rb.box(1.0, [0.1, 0.2, 0.4]),
        rb.Body(1.0, jnp.diag(jnp.array([1.0, 2.0, 3.0]))),
        rb.cylinder(1.0, 0.2, 1.0),
        rb.Body(1.0, jnp.diag(jnp.array([1.0, 2.0, 2.8]))),
    ]
    mass = jnp.stack([b.mass for b in shapes for _ in range(6)])
    inertia = jnp.stack([b.inertia for b in shapes for _ in range(6)])
    return rb.Body(mass, inertia)


def omegas(n: int) -> jnp.ndarray:
    w = np.random.default_rng(17).normal(size=(n, 3))
    return jnp.asarray(w / np.linalg.norm(w, axis=1, keepdims=True))


def bounded(state, method: str, dt: float, energy: bool) -> bool:
    traj = rb.simulate(state, None, dt, STEPS, method, save_every=STEPS // 10)
    leaves = [np.asarray(a) for a in jax.tree.leaves(traj)]
    if not all(np.isfinite(a).all() for a in leaves):
        return False
    tol = 1e-6
    if isinstance(state, rb.State):
        off = np.abs(np.linalg.norm(np.asarray(traj.orientation), axis=-1) - 1).max()
    else:
        R = np.asarray(traj.rotation)
        off = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max()
    e = np.asarray(rb.kinetic_energy(traj))
    if not energy:
        return bool(off < tol)
    return bool(off < tol and np.all(e < 2 * e[0]) and np.all(e > 0.5 * e[0]))


def limit(method: str, form: str, energy: bool) -> float | None:
    body = bodies()
    s = rb.State.create(body, angular_velocity=omegas(body.mass.shape[0]))
    state = s if form == "State" else rb.to_matrix_state(s)
    last = None
    for g in GRID:
        if not bounded(state, method, float(g), energy):
            return last
        last = float(g)
    return None  # bounded on the whole grid


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="euler and rk4 on State only, printed, not saved")
    quick = ap.parse_args().quick
    out = {}
    for m in ("euler", "rk4") if quick else METHODS:
        for form in ("State",) if quick else ("State", "MatrixState"):
            lim = {"finite": limit(m, form, False), "energy_within_2x": limit(m, form, True)}
            out[f"{m}/{form}"] = lim
            print(f"{m:22s} {form:12s} {lim}")
    if quick:
        return
    path = Path(__file__).parent / "results" / "stability_limits.json"
    path.write_text(json.dumps({"steps": STEPS, "grid_ratio": 10 ** (1 / 8), "limits": out}, indent=1) + "\n")


if __name__ == "__main__":
    main()
