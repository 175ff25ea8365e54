"""Fitting inertia tensors to recorded rotational motion by differentiating simulations.

The model is the torque-free (or known-torque) rigid body of :func:`rbjax.step`
with inertia ``I(θ)`` from the log-Cholesky map (:mod:`rbjax._inertia_param`),
so every iterate is physically consistent. A recording is cut into segments
(multiple shooting); each segment starts from the recorded orientation at its
first sample times a fitted small rotation ``exp(δ_s)`` and from a fitted
body-frame angular velocity ``ω_s`` (nuisance parameters). The residuals are

* orientation: ``log(q_sim⁻¹ ⊗ q_meas) / σ_q`` (body-frame rotation vector, rad);
* gyro (if given): ``(ω_sim - ω_meas) / σ_ω`` (body frame, rad/s);
* continuity: the end state of segment ``s`` against the start of ``s + 1``,
  weighted ``continuity_weight`` times the data, so the segments join into one
  motion while each simulation stays short (well conditioned).

Levenberg–Marquardt (optimistix) minimises their sum of squares with Jacobians
by forward-mode differentiation through the integrator. The start is a linear
least-squares fit of the conservation law ``R_i I ω_i - L_0 = ∫τ dt`` (no
differentiated data), which also gives the identifiability check.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax import Array
from jaxtyping import Bool, Float, Int

from . import _methods
from ._body import Body, inverse_3x3
from ._inertia_param import inertia_from_params, params_from_inertia
from ._math import quat_conjugate, quat_exp, quat_log, quat_multiply, quat_rotate
from ._pytree import field, new_unchecked, pytree_dataclass, static_field
from ._simulate import step
from ._state import Forces, State, _apply, quat_tolerance
from ._typing import ArrayLike

__all__ = ["FitResult", "fit_inertia", "fit_inertia_linear"]

_ENTRIES = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


@pytree_dataclass
class FitResult:
    """Result of :func:`fit_inertia` (leading batch axis when recordings were batched).

    Attributes:
        inertia: ``(3, 3)`` fitted inertia, body frame (the frame of the
            recorded quaternions and gyro), about the centre of mass. kg m² when
            ``scale_fixed``; otherwise normalised to ``tr I = 1`` (dimensionless).
        principal_moments: ``(3,)`` ascending eigenvalues of ``inertia``.
        principal_axes: ``(3, 3)`` columns are the principal axes (body frame).
        moment_std: ``(3,)`` one-sigma uncertainty of ``principal_moments``,
            from the Gauss–Newton covariance ``s² (JᵀJ)⁻¹`` with ``s²`` the
            residual variance per degree of freedom.
        initial_angular_velocity: ``(3,)`` fitted body-frame ``ω`` at ``times[0]`` (rad/s).
        initial_orientation: ``(4,)`` fitted orientation at ``times[0]``.
        residuals: ``(n,)`` final weighted residual vector (dimensionless).
        orientation_rms: RMS orientation residual (rad).
        rate_rms: RMS gyro residual (rad/s); NaN without ``body_rates``.
        converged: whether Levenberg–Marquardt met its tolerances.
        iterations: Levenberg–Marquardt steps taken.
        scale_fixed: ``True`` when known torques fix the absolute scale;
            ``False`` for torque-free data, where only ``I / tr I`` is identifiable.
        segments: number of shooting segments used.
    """

    inertia: Float[Array, "*N 3 3"] = field(core_ndim=2)
    principal_moments: Float[Array, "*N 3"] = field(core_ndim=1)
    principal_axes: Float[Array, "*N 3 3"] = field(core_ndim=2)
    moment_std: Float[Array, "*N 3"] = field(core_ndim=1)
    initial_angular_velocity: Float[Array, "*N 3"] = field(core_ndim=1)
    initial_orientation: Float[Array, "*N 4"] = field(core_ndim=1)
    residuals: Float[Array, "*N n"] = field(core_ndim=1)
    orientation_rms: Float[Array, "*N"] = field(core_ndim=0)
    rate_rms: Float[Array, "*N"] = field(core_ndim=0)
    converged: Bool[Array, "*N"] = field(core_ndim=0)
    iterations: Int[Array, "*N"] = field(core_ndim=0)
    scale_fixed: bool = static_field(default=False)
    segments: int = static_field(default=1)


# ----------------------------------------------------------------------------------------
# NumPy preprocessing (before tracing): validation, noise levels, identifiability


# Plain NumPy quaternion helpers: eager jnp calls would compile once per new shape.


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
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        bad = np.flatnonzero(~(np.diff(t) > 0))
        raise ValueError(
            f"fit_inertia: times must be finite and strictly increasing; first bad interval at index "
            f"{bad[0] if bad.size else '?'}"
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
    return t, q, out[0], out[1]


# ----------------------------------------------------------------------------------------
# The model and its residuals (traced; one recording, vmapped for batches)


def _inertia(theta: Array, scale_fixed: bool) -> Array:
    if not scale_fixed:  # gauge: log L00 = 0 (Σ_xx = 1); reported normalised to tr I = 1
        theta = jnp.concatenate([jnp.zeros_like(theta[:1]), theta])
    return inertia_from_params(theta)


def _unpack(y: Array, n_theta: int, S: int):
    return y[:n_theta], y[n_theta : n_theta + 3 * S].reshape(S, 3), y[n_theta + 3 * S :].reshape(S, 3)


def _simulate_segment(I, q0, w0, dts, tau_a, tau_b, *, method, substeps):
    """Orientations and body rates at the ends of a segment's intervals.

    Torques (world) are linear in time between the samples ``tau_a`` → ``tau_b``.
    Padding intervals have ``dt = 0`` and leave the state unchanged.
    """
    one = jnp.ones((), I.dtype)
    body = new_unchecked(Body, mass=one, inertia=I, inverse_inertia=inverse_3x3(I))
    zero = jnp.zeros(3, I.dtype)
    s0 = new_unchecked(
        State, body=body, position=zero, velocity=zero, orientation=q0, angular_momentum=quat_rotate(q0, _apply(I, w0))
    )

    def interval(s, x):
        dt, ta, tb = x
        h = dt / substeps
        if ta is None:
            forces = None
        else:
            inv_dt = jnp.where(dt > 0, 1 / jnp.where(dt > 0, dt, 1), 0)
            forces = lambda st, t: Forces(torque=ta + (tb - ta) * (t * inv_dt))  # noqa: E731
        sub = lambda k, s: step(s, forces, h, method, t=k.astype(h.dtype) * h)  # noqa: E731
        s = jax.lax.fori_loop(0, substeps, sub, s)
        qc = quat_conjugate(s.orientation)
        w_body = _apply(s.body.inverse_inertia, quat_rotate(qc, s.angular_momentum))
        return s, (s.orientation, w_body)

    _, (q, w) = jax.lax.scan(interval, s0, (dts, tau_a, tau_b))
    return q, w


def _residuals(y, data, *, scale_fixed, method, substeps, use_rates, continuity_weight):
    S = data["q_start"].shape[0]
    n_theta = 6 if scale_fixed else 5
    theta, delta, w0 = _unpack(y, n_theta, S)
    I = _inertia(theta, scale_fixed)
    q_start = quat_multiply(data["q_start"], quat_exp(delta))
    sim = functools.partial(_simulate_segment, I, method=method, substeps=substeps)
    q, w = jax.vmap(sim)(q_start, w0, data["dt"], data["tau_a"], data["tau_b"])
    wq, ww, mask = data["wq"], data["ww"], data["mask"][..., None]
    res = [
        wq * quat_log(quat_multiply(quat_conjugate(q_start[0]), data["q0"])),
        (wq * mask * quat_log(quat_multiply(quat_conjugate(q), data["q_meas"]))).reshape(-1),
    ]
    if use_rates:
        res += [ww * (w0[0] - data["w0"]), (ww * mask * (w - data["w_meas"])).reshape(-1)]
    if S > 1:
        # last real interval of each segment (padding repeats it anyway)
        q_end, w_end = q[:-1, -1], w[:-1, -1]
        gap = quat_log(quat_multiply(quat_conjugate(q_end), q_start[1:]))
        res += [continuity_weight * wq * gap.reshape(-1), continuity_weight * data["wc"] * (w_end - w0[1:]).reshape(-1)]
    return jnp.concatenate(res)


def _normalised_moments(y, scale_fixed):
    I = _inertia(y[: 6 if scale_fixed else 5], scale_fixed)
    if not scale_fixed:
        I = I / jnp.trace(I)
    return I, jnp.linalg.eigvalsh(I)


def _jacobian_and_value(f, y, data):
    return jax.jacfwd(lambda yy: (f(yy, data),) * 2, has_aux=True)(y)


def _with_dense_jacobian(f):
    """``f(y, data)`` whose JVP in ``y`` is a dense ``J @ ẏ``, ``J`` by forward mode.

    Levenberg–Marquardt linearises, materialises and transposes the residual
    map; through the integrator's scan each of those is a separate compiled
    copy of the simulation. With the Jacobian formed once (``p`` forward
    tangents in one vmapped pass) the solver only sees a matrix: about half
    the compile time and no reverse pass through the scan. Not differentiable
    in ``data``.
    """

    @jax.custom_jvp
    def g(y, data):
        return f(y, data)

    @g.defjvp
    def g_jvp(primals, tangents):
        y, data = primals
        J, r = _jacobian_and_value(f, y, data)
        return r, J @ tangents[0]

    return g


@functools.partial(
    jax.jit,
    static_argnames=(
        "scale_fixed",
        "method",
        "substeps",
        "use_rates",
        "continuity_weight",
        "rtol",
        "atol",
        "max_steps",
        "n_data",
    ),
)
def _fit_batch(y0, data, *, scale_fixed, method, substeps, use_rates, continuity_weight, rtol, atol, max_steps, n_data):
    res_fn = _with_dense_jacobian(
        functools.partial(
            _residuals,
            scale_fixed=scale_fixed,
            method=method,
            substeps=substeps,
            use_rates=use_rates,
            continuity_weight=continuity_weight,
        )
    )
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    def one(y0, data):
        sol = optx.least_squares(res_fn, solver, y0, data, max_steps=max_steps, throw=False)
        y = sol.value
        J, r = _jacobian_and_value(res_fn, y, data)
        p = y.shape[0]
        n_res_data = (3 + data["mask"].size * 3) * (2 if use_rates else 1)  # incl. zero padding
        n_cont = r.shape[0] - n_res_data
        # continuity residuals act as constraints: they remove degrees of freedom, add no data
        s2 = jnp.sum(r[:n_res_data] ** 2) / (n_data - (p - n_cont))
        cov = s2 * jnp.linalg.pinv(J.T @ J)
        I, moments = _normalised_moments(y, scale_fixed)
        G = jax.jacfwd(lambda yy: _normalised_moments(yy, scale_fixed)[1])(y)
        std = jnp.sqrt(jnp.diagonal(G @ cov @ G.T))
        _, axes = jnp.linalg.eigh(I)
        axes = axes * jnp.sign(jnp.linalg.det(axes))
        S = data["q_start"].shape[0]
        _, delta, w0 = _unpack(y, 6 if scale_fixed else 5, S)
        nq = data["mask"].sum() * 3 + 3
        r_q = r[: 3 + data["mask"].size * 3] / data["wq"]
        q_rms = jnp.sqrt(jnp.sum(r_q**2) / nq)
        if use_rates:
            off = 3 + data["mask"].size * 3
            r_w = r[off : off + 3 + data["mask"].size * 3] / data["ww"]
            w_rms = jnp.sqrt(jnp.sum(r_w**2) / nq)
        else:
            w_rms = jnp.full((), jnp.nan, r.dtype)
        return dict(
            inertia=I,
            principal_moments=moments,
            principal_axes=axes,
            moment_std=std,
            initial_angular_velocity=w0[0],
            initial_orientation=quat_multiply(data["q_start"][0], quat_exp(delta[0])),
            residuals=r,
            orientation_rms=q_rms,
            rate_rms=w_rms,
            converged=sol.result == optx.RESULTS.successful,
            iterations=sol.stats["num_steps"],
        )

    return jax.vmap(one)(y0, data)


# ----------------------------------------------------------------------------------------
# Public entry points


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


def fit_inertia(
    times: Float[ArrayLike, " T"],
    orientations: Float[ArrayLike, "*N T 4"],
    *,
    body_rates: Float[ArrayLike, "*N T 3"] | None = None,
    torques: Float[ArrayLike, "*N T 3"] | None = None,
    initial_inertia: Float[ArrayLike, "3 3"] | None = None,
    method: str = "rk4",
    segments: int | None = None,
    substeps: int | None = None,
    orientation_std: float | None = None,
    rate_std: float | None = None,
    continuity_weight: float = 10.0,
    excitation_tol: float = 1e-3,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    max_steps: int = 100,
) -> FitResult:
    """Fit a body-frame inertia tensor to a recording of free (or known-torque) rotation.

    Model: ``d(R I ω)/dt = τ`` (Euler's law, world frame), ``q̇ = ½ q ⊗ (0, ω)``
    with ``ω`` in the body frame, integrated by :func:`rbjax.step` (``method``)
    between the samples. See the module docstring for residuals and solver.

    Args:
        times: ``(T,)`` sample times (s), strictly increasing, possibly irregular
            (each interval is its own ``dt``, split into ``substeps`` steps).
        orientations: ``(T, 4)`` unit quaternions ``[w, x, y, z]`` body to world,
            or ``(N, T, 4)`` for ``N`` recordings fitted together (one compiled
            program, ``vmap`` over recordings).
        body_rates: optional ``(T, 3)`` / ``(N, T, 3)`` gyro readings, body frame (rad/s).
        torques: optional ``(T, 3)`` / ``(N, T, 3)`` known world-frame torques
            about the centre of mass (N m), taken as linear in time between
            samples. With them the inertia is absolute (kg m²); without them only
            its shape is identifiable and the result is normalised to ``tr I = 1``
            (``FitResult.scale_fixed = False``).
        initial_inertia: optional ``(3, 3)`` starting guess (body frame); default:
            linear least squares on conservation of angular momentum.
        method: integrator (see :func:`rbjax.methods`); ``"rk4"`` recommended.
        segments: number of multiple-shooting segments; default one per ``2π``
            of recorded rotation, at least 1 and at most ``(T-1) // 8``.
        substeps: integrator steps per sample interval; default enough that no
            step turns more than 0.05 rad.
        orientation_std, rate_std: noise standard deviations (rad, rad/s) that
            weight the residuals; default estimated from second differences of
            the data (valid for smooth motion sampled finely).
        continuity_weight: weight of segment joins relative to data residuals.
        excitation_tol: relative singular value below which a direction of the
            linearised problem counts as unidentifiable (``ValueError``).
        rtol, atol, max_steps: Levenberg–Marquardt tolerances and step limit.

    Returns:
        :class:`FitResult` (with a leading ``N`` axis for batched input).

    Raises:
        ValueError: before any tracing, for non-monotonic times, non-unit
            quaternions, shape mismatches, too few samples for the parameters,
            or too little excitation (naming the unidentifiable directions).
    """
    _methods.get(method, State)
    t, q, wr, tau = _check_inputs(times, orientations, body_rates, torques)
    batched = q.ndim == 3
    if not batched:
        q = q[None]
        wr = None if wr is None else wr[None]
        tau = None if tau is None else tau[None]
    N, T = q.shape[:2]
    dtype = jnp.asarray(q).dtype
    torque_free = tau is None
    use_rates = wr is not None
    q = q.astype(np.float64)

    inc = _np_increments(q)  # (N, T-1, 3)
    angles = np.linalg.norm(inc, axis=-1)
    dts = np.diff(t)
    if substeps is None:
        substeps = max(1, int(np.ceil(angles.max() / 0.05)))
    if segments is None:
        segments = int(np.clip(np.ceil(angles.sum(-1).max() / (2 * np.pi)), 1, max(1, (T - 1) // 8)))
    S = int(segments)
    if S < 1 or (T - 1) // S < 2:
        raise ValueError(f"fit_inertia: segments={segments} needs at least 2 intervals each; T = {T}")
    n_theta = 5 if torque_free else 6
    n_params = n_theta + 6 * S
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
    if use_rates:
        rates = np.asarray(wr, np.float64)
    else:
        k = int(np.clip(np.ceil(0.1 / max(np.median(angles), 1e-12)), 1, max(1, (T - 1) // 4)))
        rates = _rate_estimate(t, q, k)

    # segment layout: S segments of K intervals (the last padded with dt = 0)
    K = int(np.ceil((T - 1) / S))
    starts = np.arange(S) * K
    idx = starts[:, None] + np.arange(K)[None, :]  # interval index
    mask = idx < T - 1
    idx_c = np.minimum(idx, T - 2)
    seg_dt = np.where(mask, dts[idx_c], 0.0)
    seg_dur = seg_dt.sum(-1).mean()

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
        theta0 = np.asarray(params_from_inertia(jnp.asarray(I0)))[(1 if torque_free else 0) :]
        w_start = rates[n][starts]
        y0s.append(np.concatenate([theta0, np.zeros(3 * S), w_start.reshape(-1)]))
        wc = (1 / sw[n]) if use_rates else seg_dur / sq[n]
        d = dict(
            q_start=q[n][starts],
            q0=q[n][0],
            q_meas=q[n][idx_c + 1],
            dt=seg_dt,
            mask=mask.astype(np.float64),
            wq=1 / sq[n],
            ww=1 / sw[n] if use_rates else 1.0,
            wc=wc,
            w0=rates[n][0],
            w_meas=rates[n][idx_c + 1],
        )
        if tau_n is not None:  # i.e. not torque_free
            d["tau_a"], d["tau_b"] = tau_n[idx_c], tau_n[idx_c + 1]
        datas.append(d)
    data = jax.tree.map(lambda *a: jnp.asarray(np.stack(a), dtype), *datas)
    if torque_free:
        data["tau_a"] = data["tau_b"] = None
    out = _fit_batch(
        jnp.asarray(np.stack(y0s), dtype),
        data,
        scale_fixed=not torque_free,
        method=method,
        substeps=int(substeps),
        use_rates=use_rates,
        continuity_weight=float(continuity_weight),
        rtol=float(rtol),
        atol=float(atol),
        max_steps=int(max_steps),
        n_data=n_data,
    )
    if not batched:
        out = jax.tree.map(lambda a: a[0], out)
    return new_unchecked(FitResult, **out, scale_fixed=not torque_free, segments=S)


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
