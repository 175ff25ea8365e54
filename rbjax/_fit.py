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

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax import Array
from jaxtyping import Bool, Float, Int

from . import _methods
from ._body import Body, inverse_3x3
from ._inertia_param import inertia_from_params
from ._math import quat_conjugate, quat_exp, quat_log, quat_multiply, quat_rotate
from ._pytree import field, new_unchecked, pytree_dataclass, static_field
from ._shooting import _scan_segment
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
#
# Layout: S segments of K sample intervals (padding intervals have dt = 0 and
# mask 0). Segment s has local parameters p_s = (δ_s, ω_s) (6) and shares the
# inertia parameters θ (5 or 6). Its data residuals depend on (θ, p_s) only and
# a join's continuity residuals on (θ, p_s, p_{s+1}) only, so the Jacobian is
# formed from (n_θ + 6) forward tangents per segment, vmapped over segments,
# and scattered into the dense matrix: the cost no longer grows with S.


def _inertia(theta: Array, scale_fixed: bool) -> Array:
    if not scale_fixed:  # gauge: log L00 = 0 (Σ_xx = 1); reported normalised to tr I = 1
        theta = jnp.concatenate([jnp.zeros_like(theta[:1]), theta])
    return inertia_from_params(theta)


def _unpack(y: Array, n_theta: int, S: int):
    return y[:n_theta], y[n_theta:].reshape(S, 6)


def _segment(theta, p, d, *, scale_fixed, method, substeps, use_rates):
    """Data residuals of one segment and its end ``(q, ω_body)`` (7,).

    ``d`` holds the segment's slice of the recording. Torques (world) are linear
    in time between samples. Residuals: ``[first-sample orientation (3),
    orientations (K, 3)]`` and, with rates, ``[first-sample rate (3), rates (K, 3)]``,
    each weighted by its inverse noise; the first-sample terms are non-zero in
    segment 0 only.
    """
    I = _inertia(theta, scale_fixed)
    delta, w0 = p[:3], p[3:]
    q0 = quat_multiply(d["q_start"], quat_exp(delta))
    one = jnp.ones((), I.dtype)
    body = new_unchecked(Body, mass=one, inertia=I, inverse_inertia=inverse_3x3(I))
    zero = jnp.zeros(3, I.dtype)
    s0 = new_unchecked(
        State, body=body, position=zero, velocity=zero, orientation=q0, angular_momentum=quat_rotate(q0, _apply(I, w0))
    )
    if "tau" in d:
        ts, tau = d["t_samples"], d["tau"]
        force_fn = lambda st, t: Forces(  # noqa: E731
            torque=jnp.stack([jnp.interp(t, ts, tau[:, i]) for i in range(3)])
        )
    else:
        force_fn = lambda st, t: Forces()  # noqa: E731
    K = d["dt"].shape[0]
    dts = jnp.broadcast_to((d["dt"] / substeps)[:, None], (K, substeps))
    traj = _scan_segment(s0, force_fn, dts, d["t0"], _methods.get(method, State))
    q = traj.orientation[1:]
    w = jax.vmap(lambda qq, L: _apply(body.inverse_inertia, quat_rotate(quat_conjugate(qq), L)))(
        q, traj.angular_momentum[1:]
    )
    wq, m = d["wq"], d["mask"][:, None]
    res = [
        wq * d["first"] * quat_log(quat_multiply(quat_conjugate(q0), d["q_first"])),
        (wq * m * quat_log(quat_multiply(quat_conjugate(q), d["q_meas"]))).reshape(-1),
    ]
    if use_rates:
        ww = d["ww"]
        res += [ww * d["first"] * (w0 - d["w_first"]), (ww * m * (w - d["w_meas"])).reshape(-1)]
    return jnp.concatenate(res), jnp.concatenate([q[-1], w[-1]])  # padding keeps the end


def _continuity(end, p_next, d_next, continuity_weight):
    """Join residuals (6,): orientation gap (rad) and rate gap, weighted."""
    q_next = quat_multiply(d_next["q_start"], quat_exp(p_next[:3]))
    gap = quat_log(quat_multiply(quat_conjugate(end[:4]), q_next))
    return continuity_weight * jnp.concatenate([d_next["wq"] * gap, d_next["wc"] * (end[4:] - p_next[3:])])


def _model(y, data, *, scale_fixed, method, substeps, use_rates, jacobian):
    """Residual vector ``r`` (segments' data rows, then join rows) and, if asked, dense ``∂r/∂y``."""
    seg = data["seg"]
    S = seg["dt"].shape[0]
    n_theta = 6 if scale_fixed else 5
    theta, P = _unpack(y, n_theta, S)
    f = functools.partial(_segment, scale_fixed=scale_fixed, method=method, substeps=substeps, use_rates=use_rates)
    c = functools.partial(_continuity, continuity_weight=data["continuity_weight"])  # traced: no recompile
    nxt = jax.tree.map(lambda a: a[1:], seg)
    if not jacobian:
        r_seg, ends = jax.vmap(f, in_axes=(None, 0, 0))(theta, P, seg)
        r_c = jax.vmap(c)(ends[:-1], P[1:], nxt)
        return jnp.concatenate([r_seg.reshape(-1), r_c.reshape(-1)])

    def local(x, d):  # x = (θ, p_s): n_θ + 6 tangents, not n_θ + 6 S
        out = f(x[:n_theta], x[n_theta:], d)
        return out, out

    X = jnp.concatenate([jnp.broadcast_to(theta, (S, n_theta)), P], -1)
    (J_seg, J_end), (r_seg, ends) = jax.vmap(jax.jacfwd(local, has_aux=True))(X, seg)
    m = r_seg.shape[1]
    if S == 1:  # single shooting: no joins
        return r_seg.reshape(-1), J_seg.reshape(m, -1)
    cj = jax.jacfwd(lambda e, pn, dn: (c(e, pn, dn),) * 2, argnums=(0, 1), has_aux=True)
    (Dc_end, Dc_p), r_c = jax.vmap(cj)(ends[:-1], P[1:], nxt)
    eye = jnp.eye(S, dtype=y.dtype)
    blocks = lambda B, E: jnp.einsum("sra,st->srta", B, E).reshape(B.shape[0] * B.shape[1], -1)  # noqa: E731
    J_top = jnp.concatenate([J_seg[..., :n_theta].reshape(S * m, n_theta), blocks(J_seg[..., n_theta:], eye)], -1)
    Je = J_end[:-1]  # chain rule through the end state of segment s
    Jc_theta = jnp.einsum("sre,sea->sra", Dc_end, Je[..., :n_theta]).reshape(-1, n_theta)
    Jc_p = blocks(jnp.einsum("sre,sea->sra", Dc_end, Je[..., n_theta:]), eye[:-1]) + blocks(Dc_p, eye[1:])
    J = jnp.concatenate([J_top, jnp.concatenate([Jc_theta, Jc_p], -1)], 0)
    return jnp.concatenate([r_seg.reshape(-1), r_c.reshape(-1)]), J


def _normalised_moments(y, scale_fixed):
    I = _inertia(y[: 6 if scale_fixed else 5], scale_fixed)
    if not scale_fixed:
        I = I / jnp.trace(I)
    return I, jnp.linalg.eigvalsh(I)


class _TrustRegion(optx.ClassicalTrustRegion):
    """optimistix's trust-region search with its step size in the parameters' dtype.

    The stock ``init`` starts from ``jnp.array(1.0)``, which is float64 whenever x64
    is enabled; the damping ``1/step_size`` then promotes the float32 Jacobian's
    damped operator to float64 and lineax rejects the mixed system.
    """

    def init(self, y, f_info_struct):
        state = super().init(y, f_info_struct)
        return eqx.tree_at(lambda s: s.step_size, state, jnp.ones((), jnp.result_type(*jax.tree.leaves(y))))


def _levenberg_marquardt(rtol: float, atol: float) -> optx.LevenbergMarquardt:
    return eqx.tree_at(lambda s: s.search, optx.LevenbergMarquardt(rtol=rtol, atol=atol), _TrustRegion())


def _with_dense_jacobian(model):
    """``r(y, data)`` whose JVP in ``y`` is ``J @ ẏ`` with ``J`` from :func:`_model`.

    Levenberg–Marquardt linearises, materialises and transposes the residual
    map; through the integrator's scan each of those would be a separate
    compiled copy of the simulation. Handing it a matrix formed by the
    segment-local forward pass means one copy, no reverse pass through the
    scan. Not differentiable in ``data``.
    """

    # optimistix traces the residual and its linearisation several times (shape
    # inference, init, step); inside ``jit`` each is traced once and then reused
    residual = jax.jit(functools.partial(model, jacobian=False))
    residual_and_jacobian = jax.jit(functools.partial(model, jacobian=True))

    @jax.custom_jvp
    def g(y, data):
        return residual(y, data)

    @g.defjvp
    def g_jvp(primals, tangents):
        y, data = primals
        r, J = residual_and_jacobian(y, data)
        return r, J @ tangents[0]

    return g


@functools.cache
def _fit_batch_jit(backend: str):
    """The jitted solver for ``backend``; made on first use, so importing rbjax starts no backend.

    On CPU it is compiled with XLA's classic loop emitters instead of the MLIR
    fusion emitters: for the 4 s @ 1 kHz fit that halved the compile (10.6 → 5.1
    CPU-s) and made the solve faster too (3.1 → 2.0 CPU-s), same result.
    """
    options = {"xla_cpu_use_fusion_emitters": False} if backend == "cpu" else None
    static = ("scale_fixed", "method", "substeps", "use_rates", "rtol", "atol", "max_steps", "unbatch")
    return jax.jit(_fit_batch, static_argnames=static, compiler_options=options)


def _fit_batch(y0, data, *, scale_fixed, method, substeps, use_rates, rtol, atol, max_steps, unbatch):
    model = functools.partial(_model, scale_fixed=scale_fixed, method=method, substeps=substeps, use_rates=use_rates)
    res_fn = _with_dense_jacobian(model)
    solver = _levenberg_marquardt(rtol, atol)

    def one(y0, data):
        sol = optx.least_squares(res_fn, solver, y0, data, max_steps=max_steps, throw=False)
        y = sol.value
        # residual and Jacobian at the accepted point, as the solver last linearised them:
        # reusing them keeps a second copy of the simulation out of the compiled program
        f_info = sol.state.f_info
        r, J = f_info.residual, lx.materialise(f_info.jac).as_matrix()
        seg = data["seg"]
        S, K = seg["dt"].shape
        p = y.shape[0]
        n_rows = S * (3 + 3 * K) * (2 if use_rates else 1)  # data rows, incl. zero padding
        n_cont = r.shape[0] - n_rows
        # continuity residuals act as constraints: they remove degrees of freedom, add no data
        s2 = jnp.sum(r[:n_rows] ** 2) / (data["n_data"] - (p - n_cont))
        # (JᵀJ)⁺ from the SVD of J, not pinv(JᵀJ): forming JᵀJ squares the condition number
        # (~1e4 from the continuity weight alone), which float32 cannot hold; cut only
        # directions at rounding level
        _, sv, Vt = jnp.linalg.svd(J, full_matrices=False)
        inv_s2 = jnp.where(sv > 10 * p * jnp.finfo(J.dtype).eps * sv[0], 1 / sv**2, 0)
        cov = s2 * (Vt.T * inv_s2) @ Vt
        I, moments = _normalised_moments(y, scale_fixed)
        G = jax.jacfwd(lambda yy: _normalised_moments(yy, scale_fixed)[1])(y)
        std = jnp.sqrt(jnp.diagonal(G @ cov @ G.T))
        _, axes = jnp.linalg.eigh(I)
        axes = axes * jnp.sign(jnp.linalg.det(axes))
        _, P = _unpack(y, 6 if scale_fixed else 5, S)
        r_seg = r[:n_rows].reshape(S, 2 if use_rates else 1, 3 + 3 * K)
        nq = seg["mask"].sum() * 3 + 3
        q_rms = jnp.sqrt(jnp.sum(r_seg[:, 0] ** 2) / nq) / seg["wq"][0]
        if use_rates:
            w_rms = jnp.sqrt(jnp.sum(r_seg[:, 1] ** 2) / nq) / seg["ww"][0]
        else:
            w_rms = jnp.full((), jnp.nan, r.dtype)
        return dict(
            inertia=I,
            principal_moments=moments,
            principal_axes=axes,
            moment_std=std,
            initial_angular_velocity=P[0, 3:],
            initial_orientation=quat_multiply(seg["q_start"][0], quat_exp(P[0, :3])),
            residuals=r,
            orientation_rms=q_rms,
            rate_rms=w_rms,
            converged=sol.result == optx.RESULTS.successful,
            iterations=sol.stats["num_steps"],
        )

    if unbatch:  # one recording: no vmap, whose batching of the solver's loops doubles tracing
        return one(y0[0], jax.tree.map(lambda a: a[0], data))
    return jax.vmap(one)(y0, data)


# ----------------------------------------------------------------------------------------
# Public entry points


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
    continuity_weight: float = 1000.0,
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
        continuity_weight: weight of segment joins relative to data residuals
            (a join gap of ``σ / continuity_weight`` costs as much as one
            ``σ`` data residual). Soft joins let segments drift apart and lose
            information; measured on 4 s @ 1 kHz with 1e-3 rad + 0.01 rad/s noise
            (5 draws): mean error 1.7e-4 / 5.4e-5 / 4.5e-5 at weights 10 / 100 /
            1000, 14-29 Levenberg–Marquardt steps at 100 but 5 at 1000, 35-40 at
            10 000 (stiff); hence the default 1000.
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
    dtype = jax.dtypes.canonicalize_dtype(q.dtype)  # float64 input stays float32 without x64
    torque_free = tau is None
    use_rates = wr is not None
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
    out = _fit_batch_jit(jax.default_backend())(
        np.stack(y0s).astype(dtype),
        data,
        scale_fixed=not torque_free,
        method=method,
        substeps=int(substeps),
        use_rates=use_rates,
        rtol=float(rtol),
        atol=float(atol),
        max_steps=int(max_steps),
        unbatch=not batched,
    )
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
