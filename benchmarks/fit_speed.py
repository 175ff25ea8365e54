"""Time to fit one recording and a batch of recordings with ``rb.fit_inertia``.

Recordings: torque-free tumbles made by scipy DOP853 (tests/reference.py),
orientation noise 1e-3 rad and gyro noise 0.01 rad/s. Reports compile time
(first call) and fit time (second call, same shapes) and the error of the
unit-trace inertia.

    python benchmarks/fit_speed.py [--quick] [--json out.json]

``--quick``: a 1 s recording at 200 Hz and a batch of 8 (< 30 s on an idle
2-core machine); default: 4 s at 1 kHz and a batch of 1000.
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
from reference import qrot, reference_rotation  # noqa: E402

import rbjax as rb  # noqa: E402

jax.config.update("jax_enable_x64", True)


def recording(rng, times):
    d = rng.uniform(1.0, 3.0, 3)
    I = np.diag(d)
    if d.min() + np.sort(d)[1] <= d.max():
        I = np.diag([1.0, 2.0, 2.6])
    w0 = rng.normal(0, 1, 3) + np.array([0, 3.0, 0])
    q, w = reference_rotation(I, np.array([1.0, 0, 0, 0]), w0, times, rtol=1e-10, atol=1e-10)
    wb = np.stack([qrot(qi * np.array([1, -1, -1, -1]), wi) for qi, wi in zip(q, w, strict=True)])
    rv = rng.normal(0, 1e-3, wb.shape)
    qn = np.asarray(rb.quat_multiply(q, rb.quat_exp(rv)))
    return I / np.trace(I), qn, wb + rng.normal(0, 0.01, wb.shape)


def timed(fn):
    t = time.perf_counter()
    out = fn()
    jax.block_until_ready(out.inertia)
    return out, time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", default="fit_speed.json")
    args = ap.parse_args()
    dur, rate, n_batch = (1.0, 200, 8) if args.quick else (4.0, 1000, 1000)
    times = np.linspace(0, dur, int(dur * rate) + 1)
    rng = np.random.default_rng(0)
    recs = [recording(rng, times) for _ in range(n_batch)]
    Ib, q, w = recs[0]
    fit = lambda q, w: rb.fit_inertia(times, q, body_rates=w, segments=2)  # noqa: E731
    _, t_first = timed(lambda: fit(q, w))
    res, t_fit = timed(lambda: fit(q, w))
    err = np.linalg.norm(res.inertia - Ib) / np.linalg.norm(Ib)
    qs, ws = np.stack([r[1] for r in recs]), np.stack([r[2] for r in recs])
    _, tb_first = timed(lambda: fit(qs, ws))
    resb, tb_fit = timed(lambda: fit(qs, ws))
    errs = [np.linalg.norm(resb.inertia[k] - r[0]) / np.linalg.norm(r[0]) for k, r in enumerate(recs)]
    out = dict(
        duration_s=dur,
        rate_hz=rate,
        single_first_call_s=t_first,
        single_fit_s=t_fit,
        single_error=float(err),
        single_iterations=int(res.iterations),
        batch=n_batch,
        batch_first_call_s=tb_first,
        batch_fit_s=tb_fit,
        batch_median_error=float(np.median(errs)),
        batch_converged=float(np.mean(resb.converged)),
    )
    for k, v in out.items():
        print(f"{k:>22}: {v:.4g}" if isinstance(v, float) else f"{k:>22}: {v}")
    with open(args.json, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
