"""How often short noisy fits converge, and whether their σ is calibrated.

Random 1 s @ 200 Hz tumbles made by scipy DOP853 (tests/reference.py): a random
body (principal moments uniform in [1, 3] meeting the triangle inequality,
random principal axes), a random initial rate of 3 rad/s in a random direction,
orientation noise 1e-3 rad and gyro noise 0.01 rad/s. Fitted as one batch
(``(N, T, 4)``) with orientations + gyro, and gyro only. Reports the fraction
``converged``, the fraction of principal moments within 3σ of the truth (over
the converged fits), the reasons for non-convergence, the iteration counts and
the errors of the unit-trace inertia.

    python benchmarks/fit_convergence.py [--quick] [--draws 100] [--seed 0] [--json out.json]

``--quick``: 20 draws.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from reference import imu_noise, reference_rotation, to_body  # noqa: E402

import rbjax as rb  # noqa: E402
from rbjax.identification import _problem  # noqa: E402

jax.config.update("jax_enable_x64", True)


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def random_body(rng):
    while True:
        d = np.sort(rng.uniform(1.0, 3.0, 3))
        if d[0] + d[1] > d[2] * 1.05 and d[1] - d[0] > 0.1 and d[2] - d[1] > 0.1:  # asymmetric, not planar
            R = random_rotation(rng)
            return R @ np.diag(d) @ R.T


def tumble(rng, times, I, speed=3.0):
    w0 = rng.normal(size=3)
    w0 *= speed / np.linalg.norm(w0)
    q, w = reference_rotation(I, np.array([1.0, 0, 0, 0]), w0, times, rtol=1e-11, atol=1e-11)
    return q, to_body(q, w)


def refused(times, q, w):
    """The ValueError message when ``fit_inertia`` refuses the recording (NumPy checks only), else None."""
    try:
        _problem.prepare(
            times, q, w, None, initial_inertia=None, method="rk4", segments=None, substeps=None,
            orientation_std=None, rate_std=None, continuity_weight=1000.0, excitation_tol=1e-3,
        )  # fmt: skip
    except ValueError as e:
        return str(e)
    return None


def study(times, Is, qs, ws, gyro_only, **kw):
    # a batch is refused as a whole when one member is: screen them (the checks are NumPy, cheap)
    keep = np.array([refused(times, None if gyro_only else q, w) is None for q, w in zip(qs, ws, strict=True)])
    n_refused = int((~keep).sum())
    Is, qs, ws = Is[keep], qs[keep], ws[keep]
    t0 = time.perf_counter()
    res = rb.fit_inertia(times, None if gyro_only else qs, body_rates=ws, **kw)
    jax.block_until_ready(res.inertia)
    wall = time.perf_counter() - t0  # incl. compile on the first call
    truth = np.stack([np.linalg.eigvalsh(I / np.trace(I)) for I in Is])
    conv = np.asarray(res.converged)
    z = np.abs(np.asarray(res.principal_moments) - truth) / np.asarray(res.moment_std)
    err = np.linalg.norm(np.asarray(res.inertia) - Is / np.trace(Is, axis1=1, axis2=2)[:, None, None], axis=(1, 2))
    err /= np.linalg.norm(Is / np.trace(Is, axis1=1, axis2=2)[:, None, None], axis=(1, 2))
    return dict(
        gyro_only=gyro_only,
        refused_too_little_excitation=n_refused,
        fitted=int(keep.sum()),
        wall_s=wall,
        converged=float(conv.mean()),
        within_3sigma=float(np.mean(z[conv] < 3)) if conv.any() else float("nan"),
        within_2sigma=float(np.mean(z[conv] < 2)) if conv.any() else float("nan"),
        not_solver_converged=int(np.sum(~np.asarray(res.solver_converged))),
        on_boundary=int(np.sum(np.asarray(res.on_boundary))),
        ratio_above_3=int(np.sum(np.asarray(res.residual_ratio) > 3)),
        iterations_median=float(np.median(res.iterations)),
        iterations_max=int(np.max(res.iterations)),
        median_error=float(np.median(err)),
        max_error_converged=float(np.max(err[conv])) if conv.any() else float("nan"),
        failed=[int(i) for i in np.flatnonzero(~conv)],
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--draws", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default="fit_convergence.json")
    args = ap.parse_args()
    n = 20 if args.quick else args.draws
    rng = np.random.default_rng(args.seed)
    times = np.linspace(0.0, 1.0, 201)
    Is, qs, ws = [], [], []
    for _ in range(n):
        I = random_body(rng)
        q, wb = tumble(rng, times, I)
        qn, wn = imu_noise(q, wb, rng)
        Is.append(I)
        qs.append(qn)
        ws.append(wn)
    Is, qs, ws = np.stack(Is), np.stack(qs), np.stack(ws)
    out = dict(draws=n, seed=args.seed, duration_s=1.0, rate_hz=200)
    for gyro_only in (False, True):
        out["gyro_only" if gyro_only else "orientations_and_gyro"] = study(times, Is, qs, ws, gyro_only)
    print(json.dumps(out, indent=1))
    with open(args.json, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
