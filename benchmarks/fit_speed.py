"""Time to fit one recording and a batch of recordings with ``rb.fit_inertia``.

Recordings: torque-free tumbles made by scipy DOP853 (tests/reference.py),
orientation noise 1e-3 rad and gyro noise 0.01 rad/s. Reports the first call
(split into jax's trace, lowering and XLA compile, from jax's own stage timers,
and the rest: checks, solve, result) and the fit time (second call, same
shapes or lengths in the same buckets) and the error of the unit-trace inertia.
First: one gyro-only throw of 80 samples at 100 Hz (first call, then a 76-sample
one that must reuse the program).

    python benchmarks/fit_speed.py [--quick] [--batch 10,100,1000] [--batch-duration 1.0]
                                   [--batch-rate 200] [--throws 5] [--json out.json]

``--quick``: a 1 s recording at 200 Hz and a batch of 8 (< 30 s on an idle
2-core machine); default: one 4 s recording at 1 kHz (first call incl. compile,
then a second recording of the same shape), then batches of the given sizes of
``--batch-duration`` s at ``--batch-rate`` Hz recordings in one vmapped call
(first call incl. compile, second call). Then ``--throws`` gyro-only throws of
one body (40-100 samples at 100 Hz) as a ragged list, fitted one by one and
with ``joint=True``: first call and a second on new throws of other lengths in
the same buckets (no recompile). Wall times and process CPU times are
both reported: the CI box is shared, so wall time depends on its load.
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

jax.config.update("jax_enable_x64", True)


def recording(rng, times):
    d = rng.uniform(1.0, 3.0, 3)
    I = np.diag(d)
    if d.min() + np.sort(d)[1] <= d.max():
        I = np.diag([1.0, 2.0, 2.6])
    w0 = rng.normal(0, 1, 3) + np.array([0, 3.0, 0])
    q, w = reference_rotation(I, np.array([1.0, 0, 0, 0]), w0, times, rtol=1e-10, atol=1e-10)
    return I / np.trace(I), *imu_noise(q, to_body(q, w), rng)


# seconds spent by jax in each stage of making programs, summed over the programs of a call
_STAGES = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}
_spent: dict = {}


def _listen(event, seconds, **_):
    if event in _STAGES:
        _spent[_STAGES[event]] = _spent.get(_STAGES[event], 0.0) + seconds


jax.monitoring.register_event_duration_secs_listener(_listen)


def timed(fn, split=None):
    """``(result, wall s, CPU s)``; ``split``: a dict that receives the call's trace / lower / compile
    seconds (jax's own stage timers, summed over its programs and threads) and ``rest``, the wall time
    less those: NumPy checks, and what of the solve did not overlap the result pass's compile.
    ``rest`` is negative by as much as the stages ran side by side (the fit compiles its two programs
    at once, _compile_side_by_side in rbjax/identification/_solve.py)."""
    _spent.clear()
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    jax.block_until_ready(out.inertia)
    wall = time.perf_counter() - t
    if split is not None:
        stages = {k: _spent.get(k, 0.0) for k in ("trace", "lower", "compile")}
        split.update(stages, rest=wall - sum(stages.values()))
    return out, wall, time.process_time() - c


def throw_set(rng, lengths, rate=100.0):
    """Gyro-only phone-toss-like throws of one body: ``(truth, times list, gyro list)``, 0.005 rad/s noise."""
    I = np.diag([1.0, 3.2, 4.1])
    ts, ws = [], []
    for n in lengths:
        t = np.arange(n) / rate
        w0 = rng.normal(0, 1, 3)
        w0 = w0 / np.linalg.norm(w0) * rng.uniform(8, 12)
        q, w = reference_rotation(I, np.array([1.0, 0, 0, 0]), w0, t, rtol=1e-10, atol=1e-10)
        ts.append(t)
        ws.append(to_body(q, w) + rng.normal(0, 0.005, w.shape))
    return I / np.trace(I), ts, ws


def short_throw(rng):
    """One gyro-only throw of 80 samples at 100 Hz: first call split into stages, then a throw of
    another length in the same bucket (76 samples; must not recompile)."""
    split, again = {}, {}
    _, ts, ws = throw_set(rng, [80])
    _, t_first, _ = timed(lambda: rb.fit_inertia(ts[0], body_rates=ws[0]), split)
    truth, ts, ws = throw_set(rng, [76])
    res, t_fit, _ = timed(lambda: rb.fit_inertia(ts[0], body_rates=ws[0]), again)
    return dict(
        samples=[80, 76],
        first_call_s=t_first,
        first_call_split_s=split,
        fit_s=t_fit,
        second_call_compile_s=again["compile"],
        max_abs_error=float(np.abs(np.asarray(res.inertia) - truth).max()),
    )


def throw_lists(rng, n_throws):
    """Ragged lists of throws (40-100 samples at 100 Hz), fitted one by one and jointly.

    For each mode: the first call (compile + fit) and a second call on new throws
    whose lengths differ but fall into the same buckets (must not recompile: the
    second call is the fit alone).
    """
    lengths = np.linspace(40, 100, n_throws).astype(int)
    # the second set: a few samples shorter, the longest kept (the padded shape follows it)
    shorter = np.maximum(lengths - 2, 38)
    shorter[-1] = lengths[-1]
    out = {}
    for joint in (False, True):
        truth, ts, ws = throw_set(rng, lengths)
        fit = lambda ts, ws: rb.fit_inertia(ts, body_rates=ws, joint=joint)  # noqa: B023
        split, again = {}, {}
        _, t_first, c_first = timed(lambda: fit(ts, ws), split)  # noqa: B023
        truth, ts, ws = throw_set(rng, shorter)
        res, t_fit, c_fit = timed(lambda: fit(ts, ws), again)  # noqa: B023
        err = np.nanmax(np.abs(np.asarray(res.inertia) - truth))  # over the throws that could be fitted
        out[f"throws{n_throws}_{'joint' if joint else 'separate'}"] = dict(
            lengths=lengths.tolist(),
            first_call_s=t_first,
            first_call_cpu_s=c_first,
            first_call_split_s=split,
            fit_s=t_fit,
            fit_cpu_s=c_fit,
            second_call_compile_s=again["compile"],
            max_abs_error=float(err),
            failed=int(np.sum(np.asarray(res.failed))),
        )
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--batch", default="10,100,1000", help="comma-separated batch sizes")
    ap.add_argument("--batch-duration", type=float, default=1.0)
    ap.add_argument("--batch-rate", type=float, default=200.0)
    ap.add_argument("--throws", type=int, default=5, help="throws in the ragged-list and joint fits")
    ap.add_argument("--json", default="fit_speed.json")
    args = ap.parse_args()
    dur, rate = (1.0, 200) if args.quick else (4.0, 1000)
    sizes = [8] if args.quick else [int(b) for b in args.batch.split(",") if b]
    times = np.linspace(0, dur, int(dur * rate) + 1)
    rng = np.random.default_rng(0)
    recs = [recording(rng, times) for _ in range(2)]
    fit = lambda t, q, w: rb.fit_inertia(t, q, body_rates=w)
    out = dict(short_throw=short_throw(np.random.default_rng(1)))  # its own draws: the others' stay as they were
    split = {}
    res, t_first, c_first = timed(lambda: fit(times, recs[0][1], recs[0][2]), split)
    err_first = np.linalg.norm(res.inertia - recs[0][0]) / np.linalg.norm(recs[0][0])
    res, t_fit, c_fit = timed(lambda: fit(times, recs[1][1], recs[1][2]))  # a new recording, same shape
    err = np.linalg.norm(res.inertia - recs[1][0]) / np.linalg.norm(recs[1][0])
    out.update(
        duration_s=dur,
        rate_hz=rate,
        segments=res.segments,
        single_first_call_s=t_first,
        single_first_call_cpu_s=c_first,
        single_first_call_split_s=split,
        single_fit_s=t_fit,
        single_fit_cpu_s=c_fit,
        single_errors=[float(err_first), float(err)],
        single_iterations=int(res.iterations),
    )
    print(json.dumps(out), flush=True)  # each case as it ends: a long run leaves what it measured
    bd, br = (dur, rate) if args.quick else (args.batch_duration, args.batch_rate)
    btimes = np.linspace(0, bd, int(bd * br) + 1)
    brecs = [recording(rng, btimes) for _ in range(max(sizes, default=0))]
    for n in sizes:
        qs, ws = np.stack([r[1] for r in brecs[:n]]), np.stack([r[2] for r in brecs[:n]])
        split = {}
        _, tb_first, cb_first = timed(lambda: fit(btimes, qs, ws), split)  # noqa: B023
        resb, tb_fit, cb_fit = timed(lambda: fit(btimes, qs[::-1], ws[::-1]))  # noqa: B023
        errs = [np.linalg.norm(resb.inertia[n - 1 - k] - r[0]) / np.linalg.norm(r[0]) for k, r in enumerate(brecs[:n])]
        out[f"batch{n}"] = dict(
            duration_s=bd,
            rate_hz=br,
            first_call_s=tb_first,
            first_call_cpu_s=cb_first,
            first_call_split_s=split,
            fit_s=tb_fit,
            fit_cpu_s=cb_fit,
            median_error=float(np.median(errs)),
            max_error=float(np.max(errs)),
            converged=float(np.mean(resb.converged)),
        )
        print(json.dumps({f"batch{n}": out[f"batch{n}"]}), flush=True)  # each case as it ends
    out.update(throw_lists(rng, args.throws))
    print(json.dumps(out, indent=1))
    with open(args.json, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
