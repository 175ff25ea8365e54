"""Does ``FitResult.converged`` ("trust this fit") hold? A Monte-Carlo study on synthetic tumbles with a known truth.

Each case draws ``--fits`` random bodies (principal moments uniform in [0.5, 3],
triangle margin ≥ 5%, moments ≥ 0.08 apart, random principal axes) and start
rates (3-8 rad/s about a random axis), integrates them with scipy's DOP853
(rtol 1e-11; never rbjax) and records the gyro alone, 2 s @ 200 Hz with 0.01
rad/s white noise (the docs' tumble; ``clean_short``: a 10 rad/s throw, 0.5 s @
100 Hz), then fits them all in one batched ``rb.fit_inertia`` with the noise level
estimated. What the fit does not model, per case:

* ``clean``: nothing (``clean_og``: orientations too, 1e-3 rad);
* ``bias``: a constant gyro bias of 0.02 rad/s in a random direction;
* ``quad_drag``: a torque ``-c |ω| ω`` with ``c |ω₀|² = 0.15 |L₀|``: ``|L|`` falls ~15%/s;
* ``aniso_drag``: ``-c ⊙ ω``, ``c ∝ (0.2, 1, 2)``, ``|c ⊙ ω₀|`` about ``0.15 |L₀|``;
* ``scale``: the gyro's x axis reads 1% high;
* ``jitter``: the samples are taken at times off the nominal clock by N(0, 2 ms);
* ``rotor``: an internal rotor of constant body-frame momentum ``h``, ``|h| = 0.02 |L₀|``
  (``ω = I⁻¹ (L - h)``, ``L̇ = L × ω``);
* ``rate_std_small``: ``rate_std`` given as half the true noise level.

(A flexing body, a small mass on a stiff spring, is not simulated here.) Per
case: the share trusted (``converged``), the share of moments within 2σ and 3σ of
the truth among the trusted, false alarms (an untrusted fit whose moments are
all within 1% of the truth), the median ``moment_std / moment_std_white``, and the
cause ``diagnosis`` names most often.

    python benchmarks/fit_verdict.py [--quick] [--fits 200] [--cases clean,bias] [--dtypes float64,float32]
        [--out FILE.md]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax
import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from reference import imu_noise, qmul  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _common import machine  # noqa: E402

import rbjax as rb  # noqa: E402

jax.config.update("jax_enable_x64", True)

CASES = (
    "clean",
    "clean_og",
    "clean_short",
    "bias",
    "quad_drag",
    "aniso_drag",
    "scale",
    "jitter",
    "rotor",
    "rate_std_small",
)
SW = 0.01  # gyro noise, rad/s
SQ = 1e-3  # orientation noise, rad
CAUSES = ("drag", "bias", "rotor", "scale")


def random_body(rng: np.random.Generator) -> np.ndarray:
    while True:
        m = np.sort(rng.uniform(0.5, 3.0, 3))
        if m[0] + m[1] > 1.05 * m[2] and m[1] - m[0] > 0.08 and m[2] - m[1] > 0.08:
            break
    A = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    return A @ np.diag(m) @ A.T


def gyrostat(I, w0, times, drag=None, h=None, with_q=False):
    """Body rates ``(T, 3)`` (and orientations ``(T, 4)``): ``L̇ = L × ω + τ(ω)``, ``ω = I⁻¹ (L - h)``, DOP853."""
    Iinv = np.linalg.inv(I)
    h = np.zeros(3) if h is None else h

    def rhs(t, y):
        L, q = y[:3], y[3:]
        w = Iinv @ (L - h)
        tau = np.zeros(3) if drag is None else drag(w)
        return np.concatenate([np.cross(L, w) + tau, 0.5 * qmul(q / np.linalg.norm(q), np.concatenate([[0.0], w]))])

    y0 = np.concatenate([I @ w0 + h, [1.0, 0, 0, 0]])
    sol = solve_ivp(rhs, (times[0], times[-1]), y0, method="DOP853", t_eval=times, rtol=1e-11, atol=1e-12)
    assert sol.success, sol.message
    w = (Iinv @ (sol.y[:3] - h[:, None])).T
    q = sol.y[3:].T / np.linalg.norm(sol.y[3:].T, axis=1, keepdims=True)
    return (w, q) if with_q else w


def _unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def make(case: str, rng: np.random.Generator):
    """``(times, gyro, orientations or None, I / tr I, rate_std or None)`` of one recording."""
    short = case == "clean_short"
    duration, hz = (0.5, 100.0) if short else (2.0, 200.0)
    I = random_body(rng)
    d = _unit(rng)
    w0 = d * (10.0 if short else rng.uniform(3.0, 8.0))
    n = int(round(duration * hz)) + 1
    t_rec = np.arange(n) / hz
    t_true = t_rec.copy()
    drag = h = None
    L0, wm = np.linalg.norm(I @ w0), np.linalg.norm(w0)
    if case == "quad_drag":
        c = 0.15 * L0 / wm**2
        drag = lambda w: -c * np.linalg.norm(w) * w  # noqa: E731
    elif case == "aniso_drag":
        c = 0.15 * L0 / wm * np.array([0.2, 1.0, 2.0])
        drag = lambda w: -c * w  # noqa: E731
    elif case == "rotor":
        h = 0.02 * L0 * _unit(rng)
    elif case == "jitter":
        t_true = np.sort(np.concatenate([[0.0], t_rec[1:] + rng.normal(0, 2e-3, n - 1)]))
    w, q = gyrostat(I, w0, t_true, drag, h, with_q=True)
    quats = None
    if case == "clean_og":
        quats, gyro = imu_noise(q, w, rng, SQ, SW)
    else:
        gyro = w + rng.normal(0, SW, w.shape)
    if case == "bias":
        gyro = gyro + 0.02 * _unit(rng)
    elif case == "scale":
        gyro[:, 0] *= 1.01
    rate_std = SW / 2 if case == "rate_std_small" else None
    return t_rec, gyro, quats, I / np.trace(I), rate_std


def named_cause(res, i) -> str:
    sig, share = np.asarray(res.cause_significant[i]), np.asarray(res.cause_share[i])
    if not sig.any():
        return "none"
    return CAUSES[int(np.argmax(np.where(sig, share, -1)))]


def run_case(case: str, fits: int, dtype: str, seed: int = 0) -> dict:
    rng = np.random.default_rng([seed, CASES.index(case)])
    recs = [make(case, rng) for _ in range(fits)]
    t = recs[0][0].astype(dtype)
    gyro = np.stack([r[1] for r in recs]).astype(dtype)
    quats = None if recs[0][2] is None else np.stack([r[2] for r in recs]).astype(dtype)
    truth = np.stack([np.linalg.eigvalsh(r[3]) for r in recs])
    t0 = time.perf_counter()
    res = rb.fit_inertia(t, quats, body_rates=gyro, rate_std=recs[0][4])
    seconds = time.perf_counter() - t0
    m, s, sw = (
        np.asarray(getattr(res, k), np.float64) for k in ("principal_moments", "moment_std", "moment_std_white")
    )
    z = np.abs(m - truth) / s
    fitted = ~np.asarray(res.failed)  # a spin that excites too little is refused (member_errors)
    trusted = np.asarray(res.converged) & fitted
    close = np.all(np.abs(m - truth) <= 0.01 * truth, axis=1)
    names = [named_cause(res, i) for i in range(fits) if fitted[i]]
    top = max(set(names), key=names.count)
    return dict(
        case=case,
        dtype=dtype,
        fits=fits,
        refused=int(np.sum(~fitted)),
        trusted=float(trusted.sum() / max(fitted.sum(), 1)),
        in2=float(np.mean(z[trusted] < 2)) if trusted.any() else float("nan"),
        in3=float(np.mean(z[trusted] < 3)) if trusted.any() else float("nan"),
        in3_all=float(np.mean(z[fitted] < 3)),
        false_alarms=int(np.sum(fitted & ~trusted & close)),
        consistent=float(np.mean(np.asarray(res.model_consistent))),
        inflation=float(np.median((s / sw)[fitted])),
        cause=f"{top} {names.count(top)}/{len(names)}",
        seconds=seconds,
    )


HEADER = (
    "| case | dtype | fits | refused | trusted (of fitted) | within 2σ (trusted) | within 3σ (trusted) "
    "| within 3σ (all) "
    "| false alarms | χ² test passed | σ / white σ (median) | cause named most | fit time |\n"
    "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|"
)


def row(r: dict) -> str:
    return (
        f"| {r['case']} | {r['dtype']} | {r['fits']} | {r['refused']} | {r['trusted']:.1%} | {r['in2']:.1%} "
        f"| {r['in3']:.1%} "
        f"| {r['in3_all']:.1%} | {r['false_alarms']} | {r['consistent']:.0%} | {r['inflation']:.2f} | {r['cause']} "
        f"| {r['seconds']:.1f} s |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fits", type=int, default=200)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--dtypes", default="float64")
    ap.add_argument("--out", default=None, help="write the table (Markdown) here too")
    ap.add_argument("--quick", action="store_true", help="4 fits of clean and bias data (a smoke run)")
    args = ap.parse_args()
    if args.quick:
        args.fits, args.cases = 4, "clean,bias"
    where = machine()
    on = f"{where['cpu']}, {where['cpus']} CPUs, jax {where['jax']}, {time.strftime('%Y-%m-%d')}"
    lines = [f"`python benchmarks/fit_verdict.py --fits {args.fits} --dtypes {args.dtypes}` ({on})", "", HEADER]
    print("\n".join(lines), flush=True)
    for dtype in args.dtypes.split(","):
        for case in args.cases.split(","):
            lines.append(row(run_case(case, args.fits, dtype)))
            print(lines[-1], flush=True)
    if args.out:
        pathlib.Path(args.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
