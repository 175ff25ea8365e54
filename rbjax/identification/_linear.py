"""The linear least-squares start and the identifiability check.

Conservation of angular momentum, ``R_i I ω_i - L_0 = ∫_{t0}^{t_i} τ dt``
(world frame), is linear in ``(I, L_0)`` and needs no differentiated data; its
normal matrix also tells which inertia directions the data cannot determine.
:func:`fit_inertia_linear` is the textbook baseline (differentiated gyro).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from .._body import TRIANGLE_RTOL
from .._deprecated import warn_deprecated
from .._math import quat_tolerance
from .._rotations_np import np_qmat
from .._typing import ArrayLike

F = TypeVar("F", bound=Callable[..., Any])

_ENTRIES = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


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


def momentum_system(times, q, w, tau, h=None):
    """Normal matrix ``MᵀM`` and ``Mᵀb`` of ``R_i A(ω_i) x_I - L_0 = H_i - R_i h_i`` (one recording).

    ``H_i = ∫_{t0}^{t_i} τ dt`` by the trapezoid rule (zero without torques);
    ``h_i`` ``(T, 3)`` the rotors' body-frame momentum (none: zero), part of the
    total ``L = R (I ω + h)``. The ``I`` columns are scaled by the RMS rate so both blocks are O(1).
    """
    R = np_qmat(q)
    scale = np.sqrt(np.mean(np.sum(w * w, -1))) + 1e-300
    M = np.concatenate([R @ _regressor(w) / scale, -np.broadcast_to(np.eye(3), R.shape)], -1)
    M = M.reshape(-1, 9)
    if tau is None:
        b = np.zeros(M.shape[0])
    else:
        dt = np.diff(times)[:, None]
        H = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * dt * (tau[1:] + tau[:-1]), 0)])
        b = H.reshape(-1)
    if h is not None:
        b = b - np.einsum("tij,tj->ti", R, h).reshape(-1)
    return M.T @ M, M.T @ b, scale


def skew(w: np.ndarray) -> np.ndarray:
    """``[ω]×`` ``(..., 3, 3)``: ``[ω]× v = ω × v``."""
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    z = np.zeros_like(wx)
    return np.stack([np.stack([z, -wz, wy], -1), np.stack([wz, z, -wx], -1), np.stack([-wy, wx, z], -1)], -2)


def _cumtrapz(times: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``∫_{t0}^{t_i} f dt`` by the trapezoid rule along axis 0 (zero at ``t0``)."""
    dt = np.diff(times).reshape((-1,) + (1,) * (f.ndim - 1))
    return np.concatenate([np.zeros_like(f[:1]), np.cumsum(0.5 * dt * (f[1:] + f[:-1]), 0)])


def body_momentum_system(times, w, tau_b, h=None):
    """Normal matrix and right side of the body-frame integral form (gyro only, one recording).

    Euler's equations ``I ω̇ + ω × I ω = τ_b`` integrated from ``t0``:
    ``I ω(t_i) + ∫_{t0}^{t_i} ω × I ω dt - l_0 = ∫_{t0}^{t_i} τ_b dt`` with
    ``l_0 = I ω(t0)`` a free unknown, linear in ``(I, l_0)`` and, unlike the
    differentiated form of :func:`fit_inertia_linear`, free of ``ω̇``. Rows
    ``[A(ω_i) + ∫[ω]× A(ω) dt, -1]`` (the ``I`` columns scaled by the RMS rate).
    With rotors of body-frame momentum ``h`` ``(T, 3)`` (``d(Iω + h)/dt + ω × (Iω + h) = τ_b``,
    ``l_0 = I ω(t0) + h(t0)``) the right side gains ``-h_i - ∫ ω × h dt``.
    """
    scale = np.sqrt(np.mean(np.sum(w * w, -1))) + 1e-300
    A = _regressor(w)
    C = _cumtrapz(times, skew(w) @ A)
    M = np.concatenate([(A + C) / scale, -np.broadcast_to(np.eye(3), (w.shape[0], 3, 3))], -1).reshape(-1, 9)
    b = np.zeros(M.shape[0]) if tau_b is None else _cumtrapz(times, tau_b).reshape(-1)
    if h is not None:
        b = b - (h + _cumtrapz(times, np.cross(w, h))).reshape(-1)
    return M.T @ M, M.T @ b, scale


def check_identifiability(MtM: np.ndarray, tol: float, torque_free: bool) -> None:
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
            " (one of these is the overall scale, never identifiable without torques or a rotor)"
            if torque_free
            else " (one of these may be the overall scale, fixed only by the torques or the rotor)"
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


def np_params_from_inertia(I: np.ndarray) -> np.ndarray:
    """NumPy twin of :func:`params_from_inertia` (no eager JAX compile per call)."""
    L = np.linalg.cholesky(0.5 * np.trace(I) * np.eye(3) - I)
    return np.array([np.log(L[0, 0]), np.log(L[1, 1]), np.log(L[2, 2]), L[1, 0], L[2, 0], L[2, 1]])


def initial_inertia_estimate(MtM, Mtb, scale, torque_free):
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


def _linear_inputs(times, body_rates, orientations, torques):
    """The arrays of :func:`fit_inertia_linear` as float64, or ``ValueError`` naming the argument."""
    fn = "fit_inertia_linear"
    t = np.asarray(times, np.float64)
    if t.ndim != 1 or t.size < 3:
        raise ValueError(f"{fn}: times must be a 1-D array of at least 3 sample times (s), got shape {t.shape}")
    if not np.all(np.isfinite(t)) or not np.all(np.diff(t) > 0):
        raise ValueError(f"{fn}: times must be finite and strictly increasing")
    arrays = {"body_rates": (body_rates, 3), "orientations": (orientations, 4), "torques": (torques, 3)}
    out = []
    for name, (a, width) in arrays.items():
        if a is None:
            out.append(None)
            continue
        a = np.asarray(a, np.float64)
        if a.shape != (t.size, width):
            raise ValueError(f"{fn}: {name} must have shape (T, {width}) = ({t.size}, {width}), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{fn}: {name} must be finite")
        out.append(a)
    w, q, tau = out
    if tau is not None and q is None:
        raise ValueError(f"{fn}: world-frame torques need orientations (T, 4) to turn them into the body frame")
    if q is not None and np.max(np.abs(np.linalg.norm(q, axis=-1) - 1)) > quat_tolerance(np.float64):
        raise ValueError(f"{fn}: orientations must be unit quaternions [w, x, y, z]; normalise them first")
    return t, w, q, tau


_OLD_ORDER = ("body_rates", "orientations", "torques")


def _old_argument_order(fn: F) -> F:
    """Accept, for one release, the old order ``(times, body_rates, orientations, torques)``:
    a second positional argument of body rates (last axis 3; orientations have 4) while
    ``body_rates=`` is not given is moved to ``body_rates``, with a ``DeprecationWarning``."""

    @functools.wraps(fn)
    def wrapper(times: Any, *args: Any, **kwargs: Any) -> Any:
        if args and "body_rates" not in kwargs and np.shape(args[0])[-1:] == (3,):
            warn_deprecated(
                "fit_inertia_linear: body rates as the second positional argument (the old order times, "
                "body_rates, orientations, torques) are deprecated and will be removed in the next release; "
                "call fit_inertia_linear(times, orientations, body_rates=..., torques=...), as fit_inertia",
                stacklevel=2,
            )
            if len(args) > len(_OLD_ORDER):
                raise TypeError(f"fit_inertia_linear: too many positional arguments ({1 + len(args)})")
            for name, value in zip(_OLD_ORDER, args):
                if name in kwargs:
                    raise TypeError(f"fit_inertia_linear: got multiple values for argument {name!r}")
                kwargs[name] = value
            args = ()
        return fn(times, *args, **kwargs)

    return wrapper  # type: ignore[return-value]


@_old_argument_order
def fit_inertia_linear(
    times: Float[ArrayLike, " T"],
    orientations: Float[ArrayLike, "T 4"] | None = None,
    *,
    body_rates: Float[ArrayLike, "T 3"],
    torques: Float[ArrayLike, "T 3"] | None = None,
) -> Float[Array, "3 3"]:
    """Baseline: linear least squares on Euler's equations with differentiated gyro rates.

    ``I ω̇ + ω × I ω = τ_b`` (body frame) is linear in the six entries of ``I``;
    ``ω̇`` comes from central differences of ``body_rates`` ``(T, 3)`` (rad/s).
    Arguments as in :func:`fit_inertia`: ``orientations`` ``(T, 4)`` unit
    quaternions ``[w, x, y, z]``, optional here. Without ``torques`` the system
    is homogeneous and the smallest right singular vector, normalised to
    ``tr I = 1``, is returned; with world-frame ``torques`` ``(T, 3)`` (N m,
    needs ``orientations`` to rotate them into the body frame) the absolute
    inertia (kg m²). Fast and simple, but
    differentiating noisy rates amplifies the noise by ``1/dt``: use it as a
    start or a check, :func:`fit_inertia` for accuracy (and an uncertainty).
    Returns ``(3, 3)``, body frame.

    Raises ``ValueError`` for bad shapes or values, for rates that leave
    the inertia undetermined (relative singular values of the column-scaled
    system below ``1e-3`` beyond the one null direction, the scale, of the
    torque-free problem), and for an estimate that no body has (a principal
    moment ``≤ 0`` or ``I₁ + I₂ < I₃``): least squares on differentiated
    noisy rates, rates in deg/s or in the world frame, or unmodelled torques
    can give one. An estimate that is physical is not tested against the
    data's noise (deg/s rates may still give one): :func:`fit_inertia` is.
    """
    t, w, q, tau = _linear_inputs(times, body_rates, orientations, torques)
    wd = np.gradient(w, t, axis=0)
    A = _regressor(wd) + np.cross(w[:, None, :], np.swapaxes(_regressor(w), -1, -2)).swapaxes(-1, -2)
    A = A.reshape(-1, 6)
    _check_excitation(A, torque_free=tau is None)
    if tau is None:
        x = np.linalg.svd(A, full_matrices=False)[2][-1]
        I = _entries_to_matrix(x)
        I = I / np.trace(I)
    else:
        assert q is not None  # _linear_inputs: torques come with orientations
        tau_b = np.einsum("tji,tj->ti", np_qmat(q), tau)  # Rᵀ τ
        I = _entries_to_matrix(np.linalg.lstsq(A, tau_b.reshape(-1), rcond=None)[0])
    moments = np.linalg.eigvalsh(I)  # ascending; the triangle test as Body's
    if not (moments[0] > 0 and moments[0] + moments[1] - moments[2] >= -TRIANGLE_RTOL * np.sum(moments)):
        raise ValueError(
            "fit_inertia_linear: the least-squares estimate has principal moments "
            f"{np.array2string(moments, precision=3)}, which no body has (each must be > 0 and I₁ + I₂ ≥ I₃). "
            "Differentiated noisy rates, rates in deg/s or in the world frame, or unmodelled torques give such "
            "estimates; rb.fit_inertia fits the motion itself and reports its uncertainty"
        )
    return jnp.asarray(I)


_EXCITATION_TOL = 1e-3


def _check_excitation(A: np.ndarray, torque_free: bool) -> None:
    """``ValueError`` unless ``A x = b`` determines the six entries (up to scale when torque-free)."""
    norms = np.linalg.norm(A, axis=0)
    sv = np.linalg.svd(A / np.where(norms > 0, norms, 1.0), compute_uv=False)
    rel = sv / sv[0]
    determined = rel[4 if torque_free else 5] >= _EXCITATION_TOL
    if not determined:
        raise ValueError(
            "fit_inertia_linear: too little excitation to identify the inertia: relative singular values "
            f"{np.array2string(rel, precision=2)} (threshold {_EXCITATION_TOL:g}"
            + (", beyond the scale, which torque-free data never fix)" if torque_free else ")")
            + ". Record a tumble that excites all three axes (e.g. spin near, not on, a principal axis)"
        )
