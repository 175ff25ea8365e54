"""A day of throws of one body: 82 gyro-only throws of 41-102 samples at 100 Hz, fitted jointly
(``joint=True``, with and without ``drag="linear"``) and separately (a list), first and second call.

The second call fits new throws of the same lengths (the same compiled programs). Issue 57's
goals: joint ≤ 10 s first call and ≤ 3 s second, separate ≤ 15 s and ≤ 5 s, on a quiet 2-core
machine. Each line also says how far the joint moments are from the truth in units of their σ.

    python benchmarks/joint_day.py [--throws 82] [--out results/joint_day.json] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from fit_speed import throw_set  # noqa: E402

import rbjax as rb  # noqa: E402

GOALS = {"joint": (10.0, 3.0), "joint_drag": (10.0, 3.0), "separate": (15.0, 5.0)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--throws", type=int, default=82)
    ap.add_argument("--out", default=None)
    ap.add_argument("--quick", action="store_true", help="6 throws (a smoke run)")
    args = ap.parse_args()
    if args.quick:
        args.throws = 6
    rng = np.random.default_rng(0)
    lengths = rng.integers(41, 103, args.throws)
    out = {"throws": args.throws, "lengths": [int(n) for n in lengths]}
    for case, kw in (("joint", dict(joint=True)), ("joint_drag", dict(joint=True, drag="linear")), ("separate", {})):
        times = []
        for _ in range(2):
            truth, ts, ws = throw_set(rng, lengths)
            t0 = time.perf_counter()
            res = rb.fit_inertia(ts, body_rates=ws, **kw)
            jax.block_until_ready(res.principal_moments)
            times.append(time.perf_counter() - t0)
        m, s = np.asarray(res.principal_moments), np.asarray(res.moment_std)
        z = np.abs(m - np.sort(np.diag(truth))) / s
        goal = GOALS[case]
        out[case] = dict(
            first_call_s=times[0],
            second_call_s=times[1],
            first_over_goal=times[0] / goal[0],
            second_over_goal=times[1] / goal[1],
            converged=float(np.mean(np.asarray(res.converged))),
            iterations=int(np.max(np.asarray(res.iterations))),
            max_error_in_sigma=float(np.max(z)),
        )
        print(case, json.dumps(out[case]), flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
