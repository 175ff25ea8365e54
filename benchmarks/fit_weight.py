"""How the segment-join weight of ``rb.fit_inertia`` trades error, calibration and solver steps.

The ``continuity_weight`` table of docs/fitting.md. Body ``I = [[1, .1, -.05], [.1, 2, .08], [-.05, .08, 2.6]]``,
``ω₀ = (0.3, 3, 0.4)`` rad/s, 4 s at 1 kHz, 8 segments, recordings made by scipy DOP853
(tests/reference.py), never by rbjax. For each weight:

* clean orientations: relative Frobenius error of the unit-trace inertia;
* ``--draws`` noisy recordings (1e-3 rad orientation noise, 0.01 rad/s gyro noise): mean and max
  error, z = (fitted − true principal moment) / reported σ (max |z| and rms over all moments and
  draws), mean σ, Levenberg–Marquardt steps;
* ``--draws`` noisy recordings with known torques (same noise): max error of the
  absolute inertia.

The weight is traced data, so every fit of one kind reuses one compiled solver.

    python benchmarks/fit_weight.py [--quick] [--weights 10,30,100,1000,10000] [--draws 5] [--json out.json]

``--quick``: 1 s at 200 Hz, 2 segments, weights 100 and 1000, one draw (checks that it runs).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import jax
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from reference import imu_noise, reference_rotation, to_body  # noqa: E402

import rbjax as rb  # noqa: E402

jax.config.update("jax_enable_x64", True)

I_TRUE = np.array([[1.0, 0.1, -0.05], [0.1, 2.0, 0.08], [-0.05, 0.08, 2.6]])
W0 = np.array([0.3, 3.0, 0.4])


def torque(t, q, w):
    return np.array([0.3 * np.sin(3 * t), 0.2 * np.cos(2 * t), 0.25 * np.sin(t + 0.5)])


def record(times, with_torque):
    q, w = reference_rotation(I_TRUE, np.array([1.0, 0, 0, 0]), W0, times, torque_world=torque if with_torque else None)
    return q, to_body(q, w)


def rel(a, b):
    return float(np.linalg.norm(np.asarray(a) - b) / np.linalg.norm(b))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--weights", default="10,30,100,1000,10000")
    ap.add_argument("--draws", type=int, default=5)
    ap.add_argument("--json", default="fit_weight.json")
    args = ap.parse_args()
    weights, draws = ([100.0, 1000.0], 1) if args.quick else ([float(x) for x in args.weights.split(",")], args.draws)
    times = np.linspace(0.0, 1.0, 201) if args.quick else np.linspace(0.0, 4.0, 4001)
    segments = 2 if args.quick else 8
    i_bar = I_TRUE / np.trace(I_TRUE)
    moments = np.linalg.eigvalsh(i_bar)
    q, wb = record(times, False)
    qt, wbt = record(times, True)
    tau = np.stack([torque(t, None, None) for t in times])
    fit = lambda w, *a, **k: rb.fit_inertia(times, *a, segments=segments, continuity_weight=w, **k)
    rows = []
    for w in weights:
        clean = rel(fit(w, q).inertia, i_bar)
        errs, zs, sds, steps, conv, terrs = [], [], [], [], [], []
        for d in range(draws):
            qn, wn = imu_noise(q, wb, np.random.default_rng(d))
            res = fit(w, qn, body_rates=wn)
            errs.append(rel(res.inertia, i_bar))
            zs.extend((np.asarray(res.principal_moments) - moments) / np.asarray(res.moment_std))
            sds.append(float(np.mean(res.moment_std)))
            steps.append(int(res.iterations))
            conv.append(bool(res.converged))
            qn, wn = imu_noise(qt, wbt, np.random.default_rng(100 + d))
            terrs.append(rel(fit(w, qn, body_rates=wn, torques=tau).inertia, I_TRUE))
        zs = np.asarray(zs)
        rows.append(
            dict(
                weight=w,
                clean_error=clean,
                noisy_mean_error=float(np.mean(errs)),
                noisy_max_error=float(np.max(errs)),
                max_abs_z=float(np.max(np.abs(zs))),
                rms_z=float(np.sqrt(np.mean(zs**2))),
                mean_sigma=float(np.mean(sds)),
                torques_max_error=float(np.max(terrs)),
                lm_steps=steps,
                converged=conv,
            )
        )
        print(json.dumps(rows[-1]), flush=True)
    print("| weight | clean error | noisy mean / max error | max |z| / rms z | mean σ | torques max error | LM steps |")
    for r in rows:
        print(
            f"| {r['weight']:g} | {r['clean_error']:.1e} | {r['noisy_mean_error']:.1e} / {r['noisy_max_error']:.1e} "
            f"| {r['max_abs_z']:.1f} / {r['rms_z']:.2f} | {r['mean_sigma']:.1e} | {r['torques_max_error']:.1e} "
            f"| {min(r['lm_steps'])}-{max(r['lm_steps'])} |"
        )
    with open(args.json, "w") as f:
        json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
