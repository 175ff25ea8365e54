"""Accuracy of ``rb.fit_inertia`` against recording length, rate, noise, excitation and sensor model.

Each case fixes a true body and motion, records it with scipy's DOP853
(tests/reference.py, never rbjax), adds independent noise ``draws`` times and
fits all draws in one batched call. Beside the achieved error it puts

* ``sigma``: the σ the fit reports (``FitResult.moment_std``, mean over draws);
* ``crb``: the Cramér–Rao bound, ``sqrt(diag(F⁻¹))`` pushed to the principal
  moments, with ``F = JᵀJ`` the Fisher information of the whitened
  measurements at the *truth*, ``J`` by central differences of DOP853
  solutions (this file's own model, independent of rbjax's residuals);
* ``z_rms``: the RMS over draws and moments of ``(fitted - true) / crb``: about
  1 when the estimator is efficient (its error is the bound's), above 1 by the
  factor it loses;
* ``cal``: the RMS of ``(fitted - true) / sigma``: about 1 when the reported σ
  is calibrated;
* ``in2σ``: the fraction of moments within 2 reported σ of the truth (~0.95
  when σ is calibrated), over the draws that report ``converged``;
* ``cov_cal``: the inertia error's squared Mahalanobis distance under
  ``FitResult.inertia_covariance`` per degree of freedom (5 with ``tr I = 1``),
  mean over converged draws: ~1 when the 6x6 covariance is right;
* ``axes_cal``: the RMS of the principal frame's rotation error over
  ``FitResult.principal_axes_std``: ~1 when calibrated.

The ``calibration`` sweep fits gyro-only and orientation+gyro recordings, short
(0.5 s @ 100 Hz, a 10 rad/s throw) and long (2 s @ 200 Hz), in float64 and
float32 (the data cast, so the whole fit runs in float32): run it alone with
``--sweep calibration --draws 40``.

Moments are those of ``I / tr I`` unless torques fix the scale (none here:
every case is torque-free, as a thrown or tumbling body is). Errors are
relative, ``|λ_fit - λ_true| / λ_true``, the worst of the three moments, median
over draws.

    python benchmarks/fit_accuracy.py [--quick] [--draws 8] [--sweep NAME] [--json fit_accuracy.json]

The new models have their own sweeps, on a tossed phone's gyro (10 rad/s,
100 Hz, 0.005 rad/s): ``drag`` (1 s with linear drag ``c₁ / tr I = 0.1``/s,
fitted with ``drag="linear"``; also the error and calibration of ``c₁``),
``joint`` (throws of 0.4, 0.6, 0.8 and 1 s, each with its own start rate, one
``joint=True`` fit per draw, against the CRB of one inertia shared by all) and
``ragged`` (the same throws as a list fitted one by one, each against its own CRB).

``--quick`` runs two small cases and the three model sweeps with 2 draws (2.5
minutes on the 2-core machine shared with other jobs, 2026-12-02, most of it
compiling six programs); the default runs every sweep.
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys
import time

import jax
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from reference import qmul, reference_rotation, to_body  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _common import machine, write_json  # noqa: E402

import rbjax as rb  # noqa: E402

jax.config.update("jax_enable_x64", True)

# a body whose principal axes are not the recording's axes: the fit must find them too
_AXES = np.linalg.qr(np.array([[1.0, 0.3, -0.2], [0.1, 1.0, 0.4], [-0.3, 0.2, 1.0]]))[0]
INERTIA = _AXES @ np.diag([1.0, 2.0, 2.6]) @ _AXES.T


@dataclasses.dataclass(frozen=True)
class Case:
    sweep: str
    sensors: str = "orientation+gyro"  # | "gyro" | "gyro+bias" | "gyro+accel"
    duration: float = 2.0  # s
    rate: float = 200.0  # Hz
    orientation_std: float = 1e-3  # rad
    rate_std: float = 0.01  # rad/s
    acceleration_std: float = 0.05  # m/s²
    spin: float = 3.0  # |ω| (rad/s)
    excitation: str = "tumble"  # | "near-axis": spin 0.05 rad off the major axis (little information)
    bias: tuple = (0.02, -0.01, 0.015)  # rad/s, used with "+bias"
    lever_arm: tuple = (0.05, -0.02, 0.03)  # m, used with "+accel"
    accel_bias: tuple = (0.1, 0.0, -0.05)  # m/s², used with "+accel"
    dtype: str = "float64"  # the data's dtype, and so the fit's
    drag: float = 0.0  # linear drag c₁ / tr I (1/s): τ_b = -c₁ ω, fitted with drag="linear" when > 0
    # several recordings of one body: "joint" (one fit of all, joint=True) or "ragged" (a list of
    # recordings of the lengths in `throws`, fitted one by one in one call); each its own start rate
    mode: str = "batch"
    throws: tuple = ()  # durations (s) of the recordings of a "joint" or "ragged" case


def cases(quick: bool) -> list[Case]:
    throw = dict(sensors="gyro", rate=100.0, spin=10.0, rate_std=0.005)  # a tossed phone's gyro
    models = [
        Case("drag", duration=1.0, drag=0.1, **throw),
        Case("joint", mode="joint", throws=(0.4, 0.6, 0.8, 1.0), **throw),
        Case("ragged", mode="ragged", throws=(0.4, 0.6, 0.8, 1.0), **throw),
    ]
    if quick:
        return [Case("quick", duration=1.0), Case("quick", sensors="gyro", duration=1.0)] + models
    out = [Case("length", duration=d) for d in (0.5, 1.0, 2.0, 4.0, 8.0)]
    out += [Case("rate", rate=r) for r in (100.0, 400.0, 1000.0)]
    out += [Case("noise", orientation_std=1e-3 * k, rate_std=0.01 * k) for k in (0.1, 10.0)]
    out += [Case("excitation", excitation="near-axis")]
    out += [Case("sensors", sensors=s) for s in ("gyro", "gyro+bias")]
    out += [Case("sensors", sensors="gyro+accel", duration=1.0, spin=10.0)]
    out += [Case("thrown", sensors="gyro", duration=1.0, rate=400.0, spin=10.0, rate_std=2e-3)]
    for dtype in ("float64", "float32"):
        for sensors in ("gyro", "orientation+gyro"):
            out += [Case("calibration", sensors=sensors, duration=0.5, rate=100.0, spin=10.0, dtype=dtype)]
            out += [Case("calibration", sensors=sensors, duration=2.0, rate=200.0, dtype=dtype)]
    return out + models


def initial_rate(case: Case, k: int = 0) -> np.ndarray:
    """Body-frame ω at t = 0 of recording ``k`` with ``|ω| = case.spin``."""
    evals, evecs = np.linalg.eigh(INERTIA)
    if case.excitation == "near-axis":
        a = 0.05
        d = np.cos(a) * evecs[:, 2] + np.sin(a) * (evecs[:, 0] + evecs[:, 1]) / np.sqrt(2)
    else:  # a generic tumble: every axis excited; recording k's axis turned by k/2 rad about the major axis
        c, s = np.cos(0.5 * k), np.sin(0.5 * k)
        d = evecs @ np.array([0.5 * c - 0.6 * s, 0.5 * s + 0.6 * c, 0.62])
    return case.spin * d / np.linalg.norm(d)


# --- the measurement model at parameters p (this file's own; DOP853) ---


def _traceless_basis() -> np.ndarray:
    """Five symmetric traceless 3x3 matrices: the directions of ``I / tr I`` at fixed trace."""
    E = []
    for i, j in ((0, 1), (0, 2), (1, 2)):
        m = np.zeros((3, 3))
        m[i, j] = m[j, i] = 1.0
        E.append(m)
    E.append(np.diag([1.0, -1.0, 0.0]))
    E.append(np.diag([1.0, 1.0, -2.0]) / np.sqrt(3))
    return np.array(E)


def _qexp(v: np.ndarray) -> np.ndarray:
    a = np.linalg.norm(v)
    return np.concatenate([[np.cos(a / 2)], np.sinc(a / (2 * np.pi)) / 2 * v])


def _qlog(q: np.ndarray) -> np.ndarray:
    q = q * np.sign(q[..., :1] + (q[..., :1] == 0))
    n = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    return 2 * np.arctan2(n, q[..., :1]) * q[..., 1:] / np.where(n > 0, n, 1.0)


def measurements(case: Case, times: np.ndarray, p: np.ndarray, k: int = 0) -> dict[str, np.ndarray]:
    """Noise-free readings of recording ``k`` at ``p = (5 inertia, 3 orientation, 3 rate, nuisance..., drag)``."""
    I = INERTIA / np.trace(INERTIA) + np.tensordot(p[:5], _traceless_basis(), 1)
    q0 = _qexp(p[5:8])
    wb0 = initial_rate(case, k) + p[8:11]
    # linear drag τ_b = -c₁ ω: in the world frame -c₁ ω_world (I here has trace 1, so c₁ is c₁ / tr I)
    drag = (lambda t, q, w: -p[-1] * w) if case.drag else None
    q, w_world = reference_rotation(I, q0, to_body(q0[None] * [[1, -1, -1, -1]], wb0[None])[0], times, drag)
    wb = to_body(q, w_world)
    out = {"q": q}
    k = 11
    out["gyro"] = wb + (p[k : k + 3] if "bias" in case.sensors else 0.0)
    if "accel" in case.sensors:
        r, ba = p[k : k + 3], p[k + 3 : k + 6]
        wdot = np.linalg.solve(I, -np.cross(wb, wb @ I.T).T).T  # torque-free Euler, body frame
        out["accel"] = np.cross(wdot, r) + np.cross(wb, np.cross(wb, r)) + ba
    return out


def truth(case: Case) -> np.ndarray:
    nuisance = {"bias": case.bias, "accel": case.lever_arm + case.accel_bias}
    extra = [v for k, v in nuisance.items() if k in case.sensors]
    drag = [[case.drag]] if case.drag else []
    return np.concatenate([np.zeros(11), *[np.asarray(e, float) for e in extra + drag]])


def whitened(case: Case, times: np.ndarray, p: np.ndarray, q_ref: np.ndarray, k: int = 0) -> np.ndarray:
    m = measurements(case, times, p, k)
    parts = []
    if case.sensors == "orientation+gyro":
        conj = q_ref * np.array([1, -1, -1, -1])
        parts.append(np.stack([_qlog(qmul(a, b)) for a, b in zip(conj, m["q"], strict=True)]) / case.orientation_std)
    parts.append(m["gyro"] / case.rate_std)
    if "accel" in m:
        parts.append(m["accel"] / case.acceleration_std)
    return np.concatenate([x.ravel() for x in parts])


def _jacobian(case: Case, times: np.ndarray, k: int = 0) -> tuple[np.ndarray, list[int]]:
    """Whitened-measurement Jacobian of recording ``k`` at the truth (columns: the free parameters)."""
    p0 = truth(case)
    q_ref = measurements(case, times, p0, k)["q"]
    free = [i for i in range(len(p0)) if not (case.sensors != "orientation+gyro" and 5 <= i < 8)]
    h = 1e-6  # DOP853 at rtol 1e-13: central-difference error ~1e-13/h + h² ≈ 1e-7 relative
    J = np.stack(
        [
            (whitened(case, times, p0 + h * e, q_ref, k) - whitened(case, times, p0 - h * e, q_ref, k)) / (2 * h)
            for e in np.eye(len(p0))[free]
        ],
        -1,
    )
    return J, free


def _moment_sigma(cov5: np.ndarray) -> np.ndarray:
    """σ of the principal moments of ``I / tr I`` (ascending) from the covariance of the 5 shape parameters."""
    lam, V = np.linalg.eigh(INERTIA / np.trace(INERTIA))
    G = np.einsum("jk,ejl,lk->ke", V, _traceless_basis(), V)  # dλ_k / dp_e = v_kᵀ E_e v_k
    return np.sqrt(np.einsum("ke,ef,kf->k", G, cov5, G))


def cramer_rao(case: Case, times: np.ndarray) -> np.ndarray:
    """CRB σ of the principal moments of ``I / tr I`` (ascending), from ``F = JᵀJ`` at the truth."""
    J, _ = _jacobian(case, times)
    return _moment_sigma(np.linalg.inv(J.T @ J)[:5, :5])


def cramer_rao_joint(case: Case, times_list: list) -> np.ndarray:
    """CRB of the moments for one inertia shared by the recordings, each with its own start state.

    ``F`` is the sum of the recordings' Fisher information over (shared: inertia, sensor
    parameters, drag; own: start orientation and rate), the own blocks of different recordings
    apart: the recordings are independent motions of one body.
    """
    blocks = [_jacobian(case, t, k) for k, t in enumerate(times_list)]
    free = blocks[0][1]
    own = [j for j, i in enumerate(free) if 5 <= i < 11]
    shared = [j for j in range(len(free)) if j not in own]
    n_s, n_o, M = len(shared), len(own), len(blocks)
    F = np.zeros((n_s + M * n_o,) * 2)
    for k, (J, _) in enumerate(blocks):
        A = np.zeros((J.shape[0], F.shape[0]))
        A[:, :n_s] = J[:, shared]
        A[:, n_s + k * n_o : n_s + (k + 1) * n_o] = J[:, own]
        F += A.T @ A
    return _moment_sigma(np.linalg.inv(F)[:5, :5])


def recordings(
    case: Case, times: np.ndarray, draws: int, rng: np.random.Generator, k: int = 0
) -> dict[str, np.ndarray]:
    m = measurements(case, times, truth(case), k)
    T = len(times)
    out: dict[str, np.ndarray] = {}
    if case.sensors == "orientation+gyro":
        noise = rng.normal(0, case.orientation_std, (draws, T, 3))
        out["orientations"] = np.stack(
            [np.stack([qmul(a, _qexp(b)) for a, b in zip(m["q"], n, strict=True)]) for n in noise]
        )
    out["body_rates"] = m["gyro"] + rng.normal(0, case.rate_std, (draws, T, 3))
    if "accel" in m:
        out["accelerations"] = m["accel"] + rng.normal(0, case.acceleration_std, (draws, T, 3))
    return out


def fit(case: Case, times: np.ndarray, rec: dict[str, np.ndarray]):
    dt = np.dtype(case.dtype)
    kwargs = {k: v.astype(dt) for k, v in rec.items() if k != "orientations"}
    if "bias" in case.sensors:
        kwargs["gyro_bias"] = True
    if case.drag:
        kwargs["drag"] = "linear"
    q = rec.get("orientations")
    return rb.fit_inertia(times.astype(dt), None if q is None else q.astype(dt), **kwargs)


def run_several(case: Case, draws: int, rng: np.random.Generator) -> dict:
    """A "joint" or "ragged" case: ``case.throws`` recordings of one body, ``draws`` noise draws.

    Joint: one fit per draw (one compiled program for all draws), against the joint CRB.
    Ragged: per draw one call with the list of recordings (padded into one batch), each
    recording against its own CRB; the statistics run over draws and recordings.
    """
    times = [np.linspace(0.0, d, int(round(d * case.rate)) + 1) for d in case.throws]
    t0 = time.perf_counter()
    if case.mode == "joint":
        crb = cramer_rao_joint(case, times)[None]
    else:
        crb = np.stack([cramer_rao(case, t) for t in times])
    t_crb = time.perf_counter() - t0
    recs = [recordings(case, t, draws, rng, k) for k, t in enumerate(times)]
    got, sig, conv, t_fit = [], [], [], 0.0
    for d in range(draws):
        kwargs = {"body_rates": [r["body_rates"][d] for r in recs], "joint": case.mode == "joint"}
        if case.drag:
            kwargs["drag"] = "linear"
        t0 = time.perf_counter()
        res = rb.fit_inertia(times, **kwargs)
        jax.block_until_ready(res.inertia)
        t_fit += time.perf_counter() - t0
        got.append(np.asarray(res.principal_moments, np.float64).reshape(-1, 3))
        sig.append(np.asarray(res.moment_std, np.float64).reshape(-1, 3))
        conv.append(np.asarray(res.converged).reshape(-1))
    got, sig, conv = np.stack(got), np.stack(sig), np.stack(conv)  # (draws, recordings or 1, 3)
    return _statistics(case, draws, got, sig, conv, crb, t_fit / draws, t_crb)


def _statistics(case, draws, got, sig, conv, crb, t_fit, t_crb) -> dict:
    lam = np.linalg.eigvalsh(INERTIA / np.trace(INERTIA))
    err = np.max(np.abs(got - lam) / lam, axis=-1)
    return dict(
        dataclasses.asdict(case),
        draws=draws,
        converged=float(np.mean(conv)),
        error_median=float(np.median(err)),
        error_max=float(np.max(err)),
        sigma_rel=float(np.nanmean(sig / lam)),
        crb_rel=float(np.mean(crb / lam)),
        z_rms=float(np.sqrt(np.mean(((got - lam) / crb) ** 2))),
        cal=float(np.sqrt(np.nanmean(((got - lam) / sig) ** 2))),
        within_2sigma=float(np.mean(np.abs(got - lam)[conv] < 2 * sig[conv])) if conv.any() else float("nan"),
        fit_s=t_fit,
        crb_s=t_crb,
    )


def _covariance_calibration(res) -> dict:
    """``cov_cal``: the mean over converged draws of the inertia error's Mahalanobis distance²
    under ``inertia_covariance``, per degree of freedom (5 with ``tr I = 1``): ~1 when the 6x6
    covariance is right; ``axes_cal``: the RMS of the principal frame's rotation error over
    ``principal_axes_std`` (~1 when calibrated)."""
    conv = np.asarray(res.converged)
    if not conv.any():
        return dict(cov_cal=float("nan"), axes_cal=float("nan"))
    six = lambda M: np.asarray(M, np.float64)[..., [0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]
    truth = INERTIA / np.trace(INERTIA)
    C = np.asarray(res.inertia_covariance, np.float64)[conv]
    e = six(res.inertia)[conv] - six(truth)
    d2 = np.einsum("na,nab,nb->n", e, np.linalg.pinv(C, rcond=1e-6, hermitian=True), e)
    _, V_true = np.linalg.eigh(truth)
    z = []
    for V, sd in zip(np.asarray(res.principal_axes, np.float64)[conv], np.asarray(res.principal_axes_std)[conv]):
        V = V * np.sign(np.sum(V * V_true, 0))
        R = V_true.T @ V
        z.append(np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2 / sd)
    return dict(cov_cal=float(np.mean(d2) / 5), axes_cal=float(np.sqrt(np.mean(np.square(z)))))


def run(case: Case, draws: int, rng: np.random.Generator) -> dict:
    if case.mode != "batch":
        return run_several(case, draws, rng)
    times = np.linspace(0.0, case.duration, int(round(case.duration * case.rate)) + 1)
    t0 = time.perf_counter()
    crb = cramer_rao(case, times)
    t_crb = time.perf_counter() - t0
    rec = recordings(case, times, draws, rng)
    t0 = time.perf_counter()
    res = fit(case, times, rec)
    jax.block_until_ready(res.inertia)
    t_fit = time.perf_counter() - t0
    got, sig = np.asarray(res.principal_moments, np.float64), np.asarray(res.moment_std, np.float64)
    out = _statistics(case, draws, got, sig, np.asarray(res.converged), crb, t_fit, t_crb)
    out.update(_covariance_calibration(res))
    if case.drag:
        c1, c1_std = np.asarray(res.drag, np.float64)[:, 0], np.asarray(res.drag_std, np.float64)[:, 0]
        out["drag_error_median"] = float(np.median(np.abs(c1 - case.drag)))
        out["drag_z_rms"] = float(np.sqrt(np.mean(((c1 - case.drag) / c1_std) ** 2)))
    if "accel" in case.sensors and hasattr(res, "lever_arm"):
        out["lever_arm_error_mm"] = float(
            np.median(np.linalg.norm(np.asarray(res.lever_arm) - np.asarray(case.lever_arm), axis=-1)) * 1e3
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--draws", type=int, default=8)
    ap.add_argument("--json", default="fit_accuracy.json")
    ap.add_argument("--sweep", default=None, help="run only this sweep (e.g. calibration)")
    args = ap.parse_args()
    draws = 2 if args.quick else args.draws
    rng = np.random.default_rng(0)
    rows = []
    head = (
        f"{'sweep':>10} {'sensors':>17} {'T s':>4} {'Hz':>5} {'σ_q':>7} {'σ_ω':>6} {'exc':>9} "
        f"{'conv':>5} {'err med':>8} {'err max':>8} {'σ rep':>8} {'CRB':>8} {'z_rms':>6} {'cal':>5} "
        f"{'in2σ':>5} {'cov_cal':>7} {'axes_cal':>8} {'dtype':>7} {'fit s':>6}"
    )
    print(head)
    nan = float("nan")  # the model sweeps over several recordings have no covariance columns
    for case in cases(args.quick):
        if args.sweep is not None and case.sweep != args.sweep:
            continue
        r = run(case, draws, rng)
        rows.append(r)
        seconds = sum(r["throws"]) if r["throws"] else r["duration"]  # a multi-recording case: all of them
        print(
            f"{r['sweep']:>10} {r['sensors']:>17} {seconds:>4g} {r['rate']:>5g} {r['orientation_std']:>7.0e} "
            f"{r['rate_std']:>6.0e} {r['excitation']:>9} {r['converged']:>5.2f} {r['error_median']:>8.1e} "
            f"{r['error_max']:>8.1e} {r['sigma_rel']:>8.1e} {r['crb_rel']:>8.1e} {r['z_rms']:>6.2f} {r['cal']:>5.2f} "
            f"{r['within_2sigma']:>5.2f} {r.get('cov_cal', nan):>7.2f} {r.get('axes_cal', nan):>8.2f} "
            f"{r['dtype']:>7} {r['fit_s']:>6.1f}"
            + (f"  lever arm {r['lever_arm_error_mm']:.2f} mm" if "lever_arm_error_mm" in r else "")
            + (f"  drag c1/trI err {r['drag_error_median']:.1e} cal {r['drag_z_rms']:.2f}" if "drag_z_rms" in r else "")
            + (f"  {r['mode']} {len(r['throws'])} recordings {r['throws']} s" if r["mode"] != "batch" else ""),
            flush=True,
        )
    write_json(args.json, {"machine": machine(), "draws": draws, "cases": rows})


if __name__ == "__main__":
    main()
