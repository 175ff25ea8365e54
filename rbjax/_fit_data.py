"""The NumPy side of inertia fitting: before any tracing.

Input checks, noise levels from second differences, the linear least-squares
start (conservation of angular momentum) with its identifiability check, the
linear baseline :func:`fit_inertia_linear`, and the packing of recordings into
padded multiple-shooting segments for the traced model (:mod:`rbjax._fit_model`).
Plain NumPy throughout: eager ``jnp`` calls would compile once per new shape.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from . import _methods
from ._body import Body
from ._state import State, quat_tolerance
from ._typing import ArrayLike

_ENTRIES = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def _np_qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        -1,
    )


def _np_qlog(q: np.ndarray) -> np.ndarray:
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    scale = np.where(s > 1e-12, 2 * np.arctan2(s, q[..., :1]) / np.maximum(s, 1e-300), 2 / q[..., :1])
    return scale * q[..., 1:]


def _np_qmat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def _np_increments(q: np.ndarray, k: int = 1) -> np.ndarray:
    """Body-frame rotation vectors ``log(q_i⁻¹ q_{i+k})`` ``(..., T-k, 3)``."""
    return _np_qlog(_np_qmul(q[..., :-k, :] * _CONJ, q[..., k:, :]))


def _mad_sigma(x: np.ndarray) -> np.ndarray:
    """Noise std of white noise seen through a second difference (variance 6σ²), robustly."""
    return 1.4826 * np.median(np.abs(x), axis=(-2, -1)) / np.sqrt(6.0)


def _rate_estimate(times: np.ndarray, q: np.ndarray, k: int) -> np.ndarray:
    """Body rates from orientations by a centred difference over ``±k`` samples."""
    T = q.shape[-2]
    i = np.arange(T)
    lo, hi = np.clip(i - k, 0, T - 1), np.clip(i + k, 0, T - 1)
    rv = _np_qlog(_np_qmul(q[..., lo, :] * _CONJ, q[..., hi, :]))
    return rv / (times[..., hi] - times[..., lo])[..., None]


def _regressor(w: np.ndarray) -> np.ndarray:
    """``A(ω)`` ``(..., 3, 6)`` with ``I ω = A(ω) [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]``."""
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    z = np.zeros_like(wx)
    return np.stack(
        [
            np.stack([wx, z, z, wy, wz, z], -1),
            np.stack([z, wy, z, wx, z, wz], -1),
            np.stack([z, z, wz, z, wx, wy], -1),
        ],
        -2,
    )


def _entries_to_matrix(x: np.ndarray) -> np.ndarray:
    xx, yy, zz, xy, xz, yz = (x[..., i] for i in range(6))
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)


def _momentum_system(times, q, w, tau):
    """Normal matrix ``MᵀM`` and ``Mᵀb`` of ``R_i A(ω_i) x_I - L_0 = H_i`` (one recording).

    ``H_i = ∫_{t0}^{t_i} τ dt`` by the trapezoid rule (zero without torques).
    The ``I`` columns are scaled by the RMS rate so both blocks are O(1).
    """
    R = _np_qmat(q)
    scale = np.sqrt(np.mean(np.sum(w * w, -1))) + 1e-300
    M = np.concatenate([R @ _regressor(w) / scale, -np.broadcast_to(np.eye(3), R.shape)], -1)
    M = M.reshape(-1, 9)
    if tau is None:
        b = np.zeros(M.shape[0])
    else:
        dt = np.diff(times)[:, None]
        H = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * dt * (tau[1:] + tau[:-1]), 0)])
        b = H.reshape(-1)
    return M.T @ M, M.T @ b, scale


def _identifiability(MtM: np.ndarray, tol: float, torque_free: bool) -> None:
    """Raise ``ValueError`` naming the inertia directions the data cannot determine."""
    evals, evecs = np.linalg.eigh(MtM)
    sv = np.sqrt(np.maximum(evals, 0) / evals[-1])
    # torque-free the true (I, L) is an exact null vector; with torques it is only as far
    # from null as the torque impulse is large against L, so it is the scale, checked by
    # the fit's uncertainty rather than here: one weak direction is allowed either way
    allowed = 1
    weak = sv < tol
    if weak.sum() <= allowed:
        return
    null = evecs[:6, weak]  # I-parts of the (near-)null vectors
    u, s, _ = np.linalg.svd(null, full_matrices=False)
    basis = u[:, s > 1e-6 * s.max()]
    # a readable basis: reduced row echelon form of the span (entries that move together)
    terms = []
    for v in _rref_columns(basis):
        parts = [f"{c:+.2f}·{n}" for c, n in zip(v, _ENTRIES, strict=True) if abs(c) > 1e-3]
        terms.append(" ".join(parts))
    raise ValueError(
        "fit_inertia: too little excitation to identify the inertia. Relative singular values of "
        f"the linearised problem {np.array2string(sv, precision=2)} (threshold {tol:g}); the data "
        "fit any inertia (body-frame entries) in the span of: ["
        + "], [".join(terms)
        + "]"
        + (
            " (one of these is the overall scale, never identifiable without torques)"
            if torque_free
            else " (one of these may be the overall scale, fixed only by the torques)"
        )
        + ". Record a tumble that excites all three axes (e.g. spin near, not on, a principal axis)."
    )


def _rref_columns(basis: np.ndarray) -> list[np.ndarray]:
    A = basis.T.copy()
    rows, cols = A.shape
    r = 0
    for c in range(cols):
        if r == rows:
            break
        p = r + int(np.argmax(np.abs(A[r:, c])))
        if abs(A[p, c]) < 1e-8:
            continue
        A[[r, p]] = A[[p, r]]
        A[r] /= A[r, c]
        for i in range(rows):
            if i != r:
                A[i] -= A[i, c] * A[r]
        r += 1
    return list(A[:r])


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
    *, orientation_std, rate_std, continuity_weight, excitation_tol, rtol, atol, max_steps, segments, substeps
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
    _positive_int("max_steps", max_steps, "the default is 100")
    if segments is not None:
        _positive_int("segments", segments, "or omit it for the default")
    if substeps is not None:
        _positive_int("substeps", substeps, "or omit it for the default")


def _gyro_frame_check(times: np.ndarray, q: np.ndarray, w: np.ndarray, k: int, ratio: float = 3.0) -> None:
    """Raise ``ValueError`` when gyro rates ``w (T, 3)`` look world-frame rather than body-frame.

    Over windows of ``k`` samples the orientations ``q (T, 4)`` give the mean
    body-frame rate ``log(q_i⁻¹ ⊗ q_{i+k}) / Δt`` and the world-frame one
    ``log(q_{i+k} ⊗ q_i⁻¹) / Δt`` (rad/s); each is compared with the gyro's
    trapezoid mean over the window. Only if the world-frame rate fits more than
    ``ratio`` times better (median residual norms) is the gyro taken for
    world-frame; where the two frames barely differ (little rotation) neither
    fits better and nothing is raised.
    """
    T = q.shape[0]
    if T <= k:
        return
    dt = (times[k:] - times[:-k])[:, None]
    w_body = _np_qlog(_np_qmul(q[:-k] * _CONJ, q[k:])) / dt
    w_world = _np_qlog(_np_qmul(q[k:], q[:-k] * _CONJ)) / dt
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * np.diff(times)[:, None] * (w[1:] + w[:-1]), 0)])
    w_mean = (cum[k:] - cum[:-k]) / dt
    r_body = np.median(np.linalg.norm(w_mean - w_body, axis=-1))
    r_world = np.median(np.linalg.norm(w_mean - w_world, axis=-1))
    if r_body > ratio * r_world:
        raise ValueError(
            "fit_inertia: body_rates look like world-frame angular velocities: they match the rate "
            f"implied by the orientations in the world frame (median misfit {r_world:.3g} rad/s) far "
            f"better than in the body frame ({r_body:.3g} rad/s). Pass body-frame rates R(q)ᵀ ω, e.g. "
            "rb.quat_rotate(rb.quat_conjugate(q), w), or check_gyro_frame=False to skip this check"
        )


def _check_inputs(times, orientations, body_rates, torques):
    t = np.asarray(times, dtype=np.float64)
    q = np.asarray(orientations)
    if t.ndim != 1:
        raise ValueError(f"fit_inertia: times must be 1-D (T,), got shape {t.shape}")
    if q.ndim not in (2, 3) or q.shape[-2:] != (t.shape[0], 4):
        raise ValueError(
            f"fit_inertia: orientations must have shape (T, 4) or (N, T, 4) with T = len(times) = "
            f"{t.shape[0]}, got {q.shape}"
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
            "duplicates and NaNs"
        )
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
    for name, a in (("body_rates", body_rates), ("torques", torques)):
        if a is None:
            out.append(None)
            continue
        a = np.asarray(a)
        if a.shape not in (q.shape[:-1] + (3,), (t.shape[0], 3)):
            raise ValueError(f"fit_inertia: {name} must have shape {q.shape[:-1] + (3,)}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"fit_inertia: {name} contain non-finite values")
        out.append(np.broadcast_to(a, q.shape[:-1] + (3,)))
    if torques is not None and not np.any(out[1]):
        raise ValueError(
            "fit_inertia: torques are all zero, which cannot fix the inertia's scale (it acts like "
            "torque-free data); omit torques= for a shape-only fit (normalised to tr I = 1)"
        )
    return t, q, out[0], out[1]


# Default numerics (see fit_inertia's docstring for the error budget)
_MAX_STEP_ANGLE = 0.05  # rad turned per integrator step: rk4 error ~1e-9 rad per step at this size
_SEGMENT_INTERVALS = 512  # target intervals per shooting segment (scan depth)


def _next_pow2(x: float) -> int:
    return 1 << max(0, int(np.ceil(np.log2(max(float(x), 1.0)))))


def _bucket(k: int) -> int:
    """Round ``k`` up onto a grid with at most 12.5% padding (multiples of 2^(⌊log2 k⌋-3))."""
    g = 1 << max(0, int(np.floor(np.log2(max(k, 1)))) - 3)
    return int(-(-k // g) * g)


def _default_segments(n_intervals: int, total_angle: float) -> int:
    """A power of two: about one segment per 512 intervals and per two turns (4π) of rotation.

    Only the power of two depends on the data, so recordings of similar length and
    motion share a compiled program; pass ``segments=`` to pin it.
    """
    want = max(n_intervals / _SEGMENT_INTERVALS, total_angle / (4 * np.pi))
    return int(min(_next_pow2(want), max(1, n_intervals // 8)))


def _np_params_from_inertia(I: np.ndarray) -> np.ndarray:
    """NumPy twin of :func:`params_from_inertia` (no eager JAX compile per call)."""
    L = np.linalg.cholesky(0.5 * np.trace(I) * np.eye(3) - I)
    return np.array([np.log(L[0, 0]), np.log(L[1, 1]), np.log(L[2, 2]), L[1, 0], L[2, 0], L[2, 1]])


def _initial_inertia(MtM, Mtb, scale, torque_free):
    """Inertia from the momentum LLS, projected onto the physically consistent set."""
    if torque_free:
        x = np.linalg.eigh(MtM)[1][:, 0]
    else:
        x = np.linalg.lstsq(MtM, Mtb, rcond=None)[0]
    I = _entries_to_matrix(x[:6] / scale)
    if torque_free:
        I = I / np.trace(I)  # the null vector's sign is arbitrary
    sig_vals, sig_vecs = np.linalg.eigh(0.5 * np.trace(I) * np.eye(3) - I)
    # Σ must be positive definite; clip at 1% of its mean eigenvalue
    sig_vals = np.maximum(sig_vals, 0.01 * max(np.abs(sig_vals).mean(), 1e-300))
    sigma = (sig_vecs * sig_vals) @ sig_vecs.T
    return np.trace(sigma) * np.eye(3) - sigma


class Problem(NamedTuple):
    """Recordings packed for the solver: start ``y0 (N, p)``, segment data (leading ``N``), static options."""

    y0: np.ndarray
    data: dict
    static: dict  # scale_fixed, method, substeps, use_rates: fixed per compiled program
    batched: bool
    segments: int


def prepare(
    times,
    orientations,
    body_rates,
    torques,
    *,
    initial_inertia,
    method,
    segments,
    substeps,
    orientation_std,
    rate_std,
    continuity_weight,
    excitation_tol,
    check_gyro_frame=True,
    gyro_bias=False,
) -> Problem:
    """Validate recordings and pack them for :func:`rbjax.fit_inertia` (arguments as there).

    NumPy only, before any tracing: checks inputs and identifiability, estimates
    noise levels, fits the linear start, chooses substeps and segments, and cuts
    the recordings into padded segments.
    """
    _methods.get(method, State)  # unknown method: ValueError now, not in the solver
    t, q, wr, tau = _check_inputs(times, orientations, body_rates, torques)
    batched = q.ndim == 3
    if not batched:
        q = q[None]
        wr = None if wr is None else wr[None]
        tau = None if tau is None else tau[None]
    N, T = q.shape[:2]
    dtype = jax.dtypes.canonicalize_dtype(q.dtype)  # float64 input stays float32 without x64
    torque_free = tau is None
    use_rates = wr is not None
    if isinstance(gyro_bias, (bool, np.bool_)):
        gyro_bias = bool(gyro_bias)
    else:
        raise TypeError(f"fit_inertia: gyro_bias must be True or False, got {type(gyro_bias).__name__}")
    if gyro_bias and not use_rates:
        raise ValueError("fit_inertia: gyro_bias=True needs body_rates (there is no gyro to be biased)")
    q = q.astype(np.float64)

    inc = _np_increments(q)  # (N, T-1, 3)
    angles = np.linalg.norm(inc, axis=-1)
    dts = np.diff(t)
    if substeps is None:  # a power of two, so similar recordings share a compiled program
        substeps = _next_pow2(np.ceil(angles.max() / _MAX_STEP_ANGLE))
    if segments is None:
        segments = _default_segments(T - 1, angles.sum(-1).max())
    S = int(segments)
    if S < 1 or (T - 1) // S < 2:
        raise ValueError(f"fit_inertia: segments={segments} needs at least 2 intervals each; T = {T}")
    n_theta = 5 if torque_free else 6
    n_params = n_theta + (3 if gyro_bias else 0) + 6 * S
    n_data = 3 * T * (2 if use_rates else 1)
    if n_data <= n_params + 1:
        raise ValueError(
            f"fit_inertia: {T} samples give {n_data} residuals, too few for {n_params} parameters "
            f"({n_theta} inertia + 6 per segment × {S} segments); record more samples or use fewer segments"
        )

    # noise levels from second differences (robust MAD), floored so clean data stay finite
    if orientation_std is None:
        sq = _mad_sigma(np.diff(inc, axis=-2))
        sq = np.maximum(sq, 1e-12)
    else:
        sq = np.full(N, float(orientation_std))
    if use_rates:
        sw = (
            np.full(N, float(rate_std))
            if rate_std is not None
            else np.maximum(_mad_sigma(np.diff(wr, 2, axis=-2)), 1e-12)
        )
    else:
        sw = np.full(N, np.nan)

    # rates for the linear start: the gyro, or orientation differences over ~0.1 rad
    k = int(np.clip(np.ceil(0.1 / max(np.median(angles), 1e-12)), 1, max(1, (T - 1) // 4)))
    if use_rates:
        rates = np.asarray(wr, np.float64)
        if check_gyro_frame:
            for n in range(N):
                _gyro_frame_check(t, q[n], rates[n], k)
    else:
        rates = _rate_estimate(t, q, k)

    K = _bucket(-(-(T - 1) // S))  # intervals per segment, padded: shapes from a coarse grid
    n_real = np.full(S, (T - 1) // S) + (np.arange(S) < (T - 1) % S)  # spread the real intervals evenly
    starts = np.concatenate([[0], np.cumsum(n_real)[:-1]])
    local = np.arange(K)[None, :]
    mask = local < n_real[:, None]
    idx_c = np.minimum(starts[:, None] + local, T - 2)  # interval index (padding repeats the last)
    seg_dt = np.where(mask, dts[idx_c], 0.0)
    seg_dur = seg_dt.sum(-1).mean()
    samp = np.minimum(starts[:, None] + np.arange(K + 1)[None, :], T - 1)  # sample index per segment

    y0s, datas = [], []
    for n in range(N):
        tau_n = None if torque_free else np.asarray(tau[n], np.float64)
        MtM, Mtb, scale = _momentum_system(t, q[n], rates[n], tau_n)
        _identifiability(MtM, excitation_tol, torque_free)
        if initial_inertia is None:
            I0 = _initial_inertia(MtM, Mtb, scale, torque_free)
        else:
            I0 = np.asarray(initial_inertia, np.float64)
            Body(1.0, I0)  # validates a user guess
        if torque_free:  # the gauge log L00 = 0: rescale so that Σ_xx = 1, drop θ0
            I0 = I0 / (0.5 * np.trace(I0) - I0[0, 0])
        theta0 = _np_params_from_inertia(I0)[(1 if torque_free else 0) :]
        if gyro_bias:
            theta0 = np.concatenate([theta0, np.zeros(3)])  # the bias starts at zero
        w_start = rates[n][starts]
        y0s.append(np.concatenate([theta0, np.column_stack([np.zeros((S, 3)), w_start]).reshape(-1)]))
        first = (np.arange(S) == 0).astype(np.float64)
        ones = np.ones(S)
        seg = dict(
            q_start=q[n][starts],
            q_first=np.broadcast_to(q[n][0], (S, 4)),
            w_first=np.broadcast_to(rates[n][0], (S, 3)),
            first=first,
            q_meas=q[n][idx_c + 1],
            w_meas=rates[n][idx_c + 1],
            dt=seg_dt,
            t0=t[starts] - t[0],
            mask=mask.astype(np.float64),
            wq=ones / sq[n],
            ww=ones / sw[n] if use_rates else ones,
            wc=ones * ((1 / sw[n]) if use_rates else seg_dur / sq[n]),
        )
        if tau_n is not None:  # i.e. not torque_free
            seg["t_samples"], seg["tau"] = t[samp] - t[0], tau_n[samp]
        datas.append(dict(seg=seg, n_data=np.float64(n_data), continuity_weight=np.float64(continuity_weight)))
    # NumPy all the way into the jitted solver: eager jnp here would compile once per shape
    data = jax.tree.map(lambda *a: np.stack(a).astype(dtype), *datas)
    return Problem(
        y0=np.stack(y0s).astype(dtype),
        data=data,
        static=dict(
            scale_fixed=not torque_free,
            method=method,
            substeps=int(substeps),
            use_rates=use_rates,
            gyro_bias=gyro_bias,
        ),
        batched=batched,
        segments=S,
    )


def fit_inertia_linear(
    times: Float[ArrayLike, " T"],
    body_rates: Float[ArrayLike, "T 3"],
    orientations: Float[ArrayLike, "T 4"] | None = None,
    torques: Float[ArrayLike, "T 3"] | None = None,
) -> Float[Array, "3 3"]:
    """Baseline: linear least squares on Euler's equations with differentiated gyro rates.

    ``I ω̇ + ω × I ω = τ_b`` (body frame) is linear in the six entries of ``I``;
    ``ω̇`` comes from central differences of ``body_rates`` ``(T, 3)`` (rad/s).
    Without ``torques`` the system is homogeneous and the smallest right
    singular vector, normalised to ``tr I = 1``, is returned; with world-frame
    ``torques`` ``(T, 3)`` (N m, needs ``orientations`` to rotate them into the
    body frame) the absolute inertia (kg m²). Fast and simple, but
    differentiating noisy rates amplifies the noise by ``1/dt``: use it as a
    start or a check, :func:`fit_inertia` for accuracy. Not guaranteed
    physically consistent. Returns ``(3, 3)``.
    """
    t = np.asarray(times, np.float64)
    w = np.asarray(body_rates, np.float64)
    wd = np.gradient(w, t, axis=0)
    A = _regressor(wd) + np.cross(w[:, None, :], np.swapaxes(_regressor(w), -1, -2)).swapaxes(-1, -2)
    A = A.reshape(-1, 6)
    if torques is None:
        x = np.linalg.svd(A, full_matrices=False)[2][-1]
        I = _entries_to_matrix(x)
        return jnp.asarray(I / np.trace(I))
    R = _np_qmat(np.asarray(orientations, np.float64))
    tau_b = np.einsum("tji,tj->ti", R, np.asarray(torques, np.float64))  # Rᵀ τ
    x = np.linalg.lstsq(A, tau_b.reshape(-1), rcond=None)[0]
    return jnp.asarray(_entries_to_matrix(x))
