"""Checks of :func:`rbjax.fit_inertia`'s data and options, before anything is traced.

Every failure is a ``TypeError``/``ValueError`` in rbjax's words, naming the
argument and the remedy.
"""

from __future__ import annotations

import jax
import jax.core
import numpy as np

from .._math import quat_tolerance
from .._rotations_np import CONJ, np_qlog, np_qmul
from ._robust import LOSSES


def _positive_finite(name: str, value, remedy: str) -> float:
    """``value`` as a float, or ``TypeError``/``ValueError`` naming ``name`` and the remedy."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        if not (isinstance(value, (np.ndarray, jax.Array)) and np.ndim(value) == 0):
            raise TypeError(f"fit_inertia: {name} must be a real number, got {type(value).__name__}; {remedy}")
    v = float(value)
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"fit_inertia: {name} must be finite and > 0, got {v!r}; {remedy}")
    return v


def _positive_int(name: str, value, remedy: str) -> int:
    """``value`` as an int ≥ 1 (not a bool), or ``TypeError``/``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"fit_inertia: {name} must be an int >= 1, got {type(value).__name__} {value!r}; {remedy}")
    if value < 1:
        raise ValueError(f"fit_inertia: {name} must be an int >= 1, got {value}; {remedy}")
    return int(value)


def check_options(
    *,
    orientation_std,
    rate_std,
    continuity_weight,
    excitation_tol,
    rtol,
    atol,
    max_steps,
    segments,
    substeps,
    loss="squared",
    loss_scale=3.0,
    acceleration_std=None,
) -> None:
    """Validate :func:`rbjax.fit_inertia`'s scalar options before anything is traced."""
    if orientation_std is not None:
        _positive_finite("orientation_std", orientation_std, "give the orientation noise std in rad, or omit it")
    if rate_std is not None:
        _positive_finite("rate_std", rate_std, "give the gyro noise std in rad/s, or omit it")
    _positive_finite("continuity_weight", continuity_weight, "the default 1000 suits most recordings")
    _positive_finite("excitation_tol", excitation_tol, "the default is 1e-3")
    _positive_finite("rtol", rtol, "the default is 1e-8")
    _positive_finite("atol", atol, "the default is 1e-8")
    _positive_int("max_steps", max_steps, "the default is 200")
    if not isinstance(loss, str) or loss not in LOSSES:
        raise ValueError(
            f"fit_inertia: loss must be 'squared', 'huber' or 'cauchy', got {loss!r}; "
            "'huber' or 'cauchy' down-weight glitches"
        )
    if acceleration_std is not None:
        _positive_finite("acceleration_std", acceleration_std, "give the accelerometer noise std in m/s², or omit it")
    _positive_finite("loss_scale", loss_scale, "it is the robust loss's threshold in noise σ; the default is 3")
    if segments is not None:
        _positive_int("segments", segments, "or omit it for the default")
    if substeps is not None:
        _positive_int("substeps", substeps, "or omit it for the default")


def gyro_frame_check(times: np.ndarray, q: np.ndarray, w: np.ndarray, k: int, ratio: float = 3.0) -> None:
    """Raise ``ValueError`` when gyro rates ``w (T, 3)`` look world-frame rather than body-frame.

    Over windows of ``k`` samples the orientations ``q (T, 4)`` give the mean
    body-frame rate ``log(q_i⁻¹ ⊗ q_{i+k}) / Δt`` and the world-frame one
    ``log(q_{i+k} ⊗ q_i⁻¹) / Δt`` (rad/s); each is compared with the gyro's
    trapezoid mean over the window. Only if the world-frame rate fits more than
    ``ratio`` times better (median residual norms) is the gyro taken for
    world-frame; where the two frames barely differ (little rotation) neither
    fits better and nothing is raised. Orientations in scalar-last order
    ``[x, y, z, w]`` are named as such when, read in that order, they fit the
    gyro ``ratio`` times better than in either frame as ``[w, x, y, z]``.
    """
    T = q.shape[0]
    if T <= k:
        return
    dt = (times[k:] - times[:-k])[:, None]
    w_body = np_qlog(np_qmul(q[:-k] * CONJ, q[k:])) / dt
    w_world = np_qlog(np_qmul(q[k:], q[:-k] * CONJ)) / dt
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * np.diff(times)[:, None] * (w[1:] + w[:-1]), 0)])
    w_mean = (cum[k:] - cum[:-k]) / dt
    r_body = np.median(np.linalg.norm(w_mean - w_body, axis=-1))
    r_world = np.median(np.linalg.norm(w_mean - w_world, axis=-1))
    # scalar-last quaternions [x, y, z, w] (scipy's, ROS's order) read as [w, x, y, z] give a motion
    # that matches the gyro in neither frame, and by chance the world frame's better; read back as
    # scalar-last they match it in the body frame
    xyzw = q[:, [3, 0, 1, 2]]
    w_xyzw = np_qlog(np_qmul(xyzw[:-k] * CONJ, xyzw[k:])) / dt
    r_xyzw = np.median(np.linalg.norm(w_mean - w_xyzw, axis=-1))
    if r_xyzw * ratio < min(r_body, r_world):
        raise ValueError(
            "fit_inertia: orientations look scalar-last, [x, y, z, w]: read so they match the gyro "
            f"(median misfit {r_xyzw:.3g} rad/s) far better than as rbjax's [w, x, y, z] ({r_body:.3g} "
            "rad/s in the body frame, "
            f"{r_world:.3g} in the world frame). Reorder them, q[..., [3, 0, 1, 2]] (scipy's "
            "Rotation.as_quat() is scalar-last), or pass check_gyro_frame=False to skip this check"
        )
    if r_body > ratio * r_world:
        raise ValueError(
            "fit_inertia: body_rates look like world-frame angular velocities: they match the rate "
            f"implied by the orientations in the world frame (median misfit {r_world:.3g} rad/s) far "
            f"better than in the body frame ({r_body:.3g} rad/s). Pass body-frame rates R(q)ᵀ ω, e.g. "
            "rb.quat_rotate(rb.quat_conjugate(q), w), or check_gyro_frame=False to skip this check"
        )


def check_arrays(**arrays) -> None:
    """``TypeError`` in rbjax's words for array arguments the fit cannot take, before any conversion.

    * a JAX tracer (``fit_inertia`` inside ``jax.jit``, ``vmap`` or ``grad``): the fit
      checks and packs its data in NumPy and compiles its own solver, so it cannot be
      traced; call it outside the transformation;
    * half precision (float16, bfloat16): ``eps ≈ 1e-3`` cannot carry the integration
      or the noise model; cast to float32 or float64;
    * complex or non-numeric data.
    """
    for name, a in arrays.items():
        if a is None:
            continue
        if isinstance(a, jax.core.Tracer):
            raise TypeError(
                f"fit_inertia is not jittable: {name} is a JAX tracer (fit_inertia was called inside "
                "jax.jit, vmap or grad). Call fit_inertia outside the transformation with concrete "
                "arrays: it validates the data in NumPy and compiles its own solver (one program per "
                "shape bucket, reused), and a batch (N, T, ...) is fitted in one call"
            )
        dtype = getattr(a, "dtype", None)
        if dtype is None:
            continue
        dtype = np.dtype(dtype)
        if dtype == np.float16 or dtype.name == "bfloat16":
            raise TypeError(
                f"fit_inertia: {name} has dtype {dtype.name}, too coarse to fit with (eps ≈ 1e-3); "
                f"cast it to float32 or float64 first, e.g. np.asarray({name}, np.float32)"
            )
        if not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)):
            raise TypeError(f"fit_inertia: {name} must be real numbers (float32 or float64), got dtype {dtype.name}")


def _series(name: str, x, T: int, k: int) -> np.ndarray:
    """``x`` as a ``(T, k)`` or ``(N, T, k)`` array; ``ValueError`` naming ``name`` otherwise."""
    a = np.asarray(x)
    if a.ndim not in (2, 3) or a.shape[-2:] != (T, k):
        raise ValueError(
            f"fit_inertia: {name} must have shape (T, {k}) or (N, T, {k}) with T = len(times) = {T}, got {a.shape}"
        )
    return a


def coarse_clock_hint(times, t: np.ndarray) -> str:
    """A hint where equal times come from a narrow float dtype (float32 Unix or uptime stamps)."""
    dtype = np.asarray(times).dtype
    if not np.issubdtype(dtype, np.floating) or dtype.itemsize >= 8 or not np.any(np.diff(t) == 0):
        return ""
    top = float(np.max(np.abs(t)))
    step = float(np.spacing(np.asarray(top, dtype)))
    return (
        f"; {dtype.name} times near {top:.4g} s are only {step:.2g} s apart, so samples merge: "
        "pass the times as float64, or subtract the first time before casting"
    )


def check_inputs(times, orientations, body_rates, torques, body_torques=None):
    """Checked NumPy copies ``(t, q, ω, τ, τ_b)``; ``q`` is None for a gyro-only recording.

    The batch shape ``(N,)`` or ``()`` comes from ``orientations``, or from
    ``body_rates`` without them; the other arrays may be ``(T, 3)`` (shared).
    """
    t = np.asarray(times, dtype=np.float64)
    if t.ndim != 1:
        hint = (
            "; the first argument is the sample times (s): pass gyro readings as body_rates= and quaternions "
            "as orientations="
            if t.ndim == 2 and t.shape[-1] in (3, 4)
            else ""
        )
        raise ValueError(f"fit_inertia: times must be 1-D (T,), got shape {t.shape}{hint}")
    if orientations is None:
        if body_rates is None:
            raise ValueError(
                "fit_inertia: give orientations, body_rates or both; a gyro-only fit needs "
                "body_rates (body frame, rad/s) with orientations=None"
            )
        if torques is not None:
            raise ValueError(
                "fit_inertia: torques= are world-frame and need orientations to be used; for a "
                "gyro-only fit pass the known torques in the body frame as body_torques="
            )
        w = _series("body_rates", body_rates, t.shape[0], 3)
        lead = w.shape[:-1]
        q = None
    else:
        q = _series("orientations", orientations, t.shape[0], 4)
        lead = q.shape[:-1]
    if torques is not None and body_torques is not None:
        raise ValueError(
            "fit_inertia: give torques= (world frame) or body_torques= (body frame), not both; "
            "add them in one frame first"
        )
    if not np.all(np.isfinite(t)):
        i = int(np.flatnonzero(~np.isfinite(t))[0])
        raise ValueError(
            f"fit_inertia: times must be finite and strictly increasing (seconds, one per sample); "
            f"times[{i}] = {t[i]}; drop the samples without a valid time"
        )
    if np.any(np.diff(t) <= 0):
        bad = np.flatnonzero(~(np.diff(t) > 0))
        raise ValueError(
            f"fit_inertia: times must be finite and strictly increasing (seconds, one per sample); "
            f"first bad interval at index {bad[0] if bad.size else '?'}; sort the samples and drop "
            f"duplicates and NaNs{coarse_clock_hint(times, t)}"
        )
    if q is not None:
        if not np.all(np.isfinite(q)):
            raise ValueError("fit_inertia: orientations contain non-finite values")
        err = np.abs(np.linalg.norm(q.astype(np.float64), axis=-1) - 1)
        tol = quat_tolerance(q.dtype)
        if np.any(err > tol):
            raise ValueError(
                f"fit_inertia: orientations must be unit quaternions [w, x, y, z]; max |‖q‖ - 1| = "
                f"{err.max():.3g} exceeds the tolerance {tol:.3g} (normalise them first)"
            )
    out = []
    for name, a in (("body_rates", body_rates), ("torques", torques), ("body_torques", body_torques)):
        if a is None:
            out.append(None)
            continue
        a = np.asarray(a)
        if a.shape not in (lead + (3,), (t.shape[0], 3)):
            raise ValueError(f"fit_inertia: {name} must have shape {lead + (3,)}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"fit_inertia: {name} contain non-finite values")
        out.append(np.broadcast_to(a, lead + (3,)))
    if out[0] is not None:
        _check_gyro_sampling(t, out[0])
    for name, a in (("torques", out[1]), ("body_torques", out[2])):
        if a is not None and not np.any(a):
            raise ValueError(
                f"fit_inertia: {name} are all zero, which cannot fix the inertia's scale (it acts like "
                f"torque-free data); omit {name}= for a shape-only fit (normalised to tr I = 1)"
            )
    return t, q, out[0], out[1], out[2]


def _check_gyro_sampling(t: np.ndarray, w: np.ndarray) -> None:
    """``ValueError`` when the gyro turns the body more than half a turn between samples (median).

    No recording samples a rotation that coarsely; it is what rates in deg/s or times in ms
    look like (57x or 1000x the angle per interval), which the fit would otherwise report as
    too little excitation or as residuals far above the noise.
    """
    speed = np.linalg.norm(np.asarray(w, np.float64), axis=-1)  # (*N, T)
    turned = float(np.median(0.5 * (speed[..., 1:] + speed[..., :-1]) * np.diff(t)))
    if turned > np.pi:
        raise ValueError(
            f"fit_inertia: the gyro turns the body a median {turned:.3g} rad between samples, more than "
            "half a turn, which no recording can follow; are the rates in rad/s (deg/s: pass "
            "np.deg2rad(body_rates)) and the times in seconds (ms: pass times / 1000)?"
        )
