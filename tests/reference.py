"""Independent reference: the Newton–Euler equations integrated by scipy's DOP853.

Written in plain NumPy, separately from rbjax, in the body-frame form
(Euler's equations ``I ω̇ = τ_b - ω × I ω``, ``q̇ = ½ q ⊗ (0, ω_b)``) rather than
rbjax's world-frame ``L``-form, so that agreement checks the physics rather
than one implementation against itself.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp


def qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    pw, pv = p[0], p[1:]
    qw, qv = q[0], q[1:]
    return np.concatenate([[pw * qw - pv @ qv], pw * qv + qw * pv + np.cross(pv, qv)])


def qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    return qmul(qmul(q, np.concatenate([[0.0], v])), q * np.array([1, -1, -1, -1]))[1:]


def reference_rotation(
    inertia: np.ndarray,
    q0: np.ndarray,
    omega_world0: np.ndarray,
    times: np.ndarray,
    torque_world: Callable[[float, np.ndarray, np.ndarray], np.ndarray] | None = None,
    rtol: float = 1e-13,
    atol: float = 1e-13,
) -> tuple[np.ndarray, np.ndarray]:
    """Orientation ``(T, 4)`` and world angular velocity ``(T, 3)`` at ``times``.

    ``torque_world(t, q, omega_world)`` gives the world-frame torque (N m).
    """
    I = np.asarray(inertia, dtype=np.float64)
    Iinv = np.linalg.inv(I)
    q0 = np.asarray(q0, dtype=np.float64)
    wb0 = qrot(q0 * np.array([1, -1, -1, -1]), np.asarray(omega_world0, dtype=np.float64))

    def rhs(t, y):
        q, wb = y[:4], y[4:]
        q = q / np.linalg.norm(q)
        tau_b = np.zeros(3)
        if torque_world is not None:
            tau_w = np.asarray(torque_world(t, q, qrot(q, wb)), dtype=np.float64)
            tau_b = qrot(q * np.array([1, -1, -1, -1]), tau_w)
        dq = 0.5 * qmul(q, np.concatenate([[0.0], wb]))
        dw = Iinv @ (tau_b - np.cross(wb, I @ wb))
        return np.concatenate([dq, dw])

    sol = solve_ivp(
        rhs,
        (times[0], times[-1]),
        np.concatenate([q0, wb0]),
        method="DOP853",
        t_eval=times,
        rtol=rtol,
        atol=atol,
    )
    assert sol.success, sol.message
    q = sol.y[:4].T
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w = np.stack([qrot(qi, wi) for qi, wi in zip(q, sol.y[4:].T)])
    return q, w


def to_body(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """World-frame vectors ``v (T, 3)`` in the body frames of ``q (T, 4)``: ``R(q)ᵀ v`` (a gyro's view of ω)."""
    conj = np.array([1, -1, -1, -1])
    return np.stack([qrot(qi * conj, vi) for qi, vi in zip(q, v, strict=True)])


def imu_noise(
    q: np.ndarray, wb: np.ndarray, rng: np.random.Generator, sq: float = 1e-3, sw: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """A noisy recording: ``q ⊗ exp(r)`` with ``r ~ N(0, sq²)`` per axis (rad), gyro ``wb + N(0, sw²)`` (rad/s)."""
    rv = rng.normal(0, sq, wb.shape)
    ang = np.linalg.norm(rv, axis=1, keepdims=True)
    dq = np.concatenate([np.cos(ang / 2), np.sin(ang / 2) * rv / ang], axis=1)
    qn = np.stack([qmul(a, b) for a, b in zip(q, dq, strict=True)])
    return qn / np.linalg.norm(qn, axis=1, keepdims=True), wb + rng.normal(0, sw, wb.shape)


def quat_angle(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rotation angle between unit quaternions (sign-insensitive), radians.

    ``2 atan2(‖vec(p* ⊗ q)‖, |scal(p* ⊗ q)|)``: accurate to round-off for small
    angles (``2 arccos |p·q|`` bottoms out at ``2 sqrt(2 eps) ≈ 3e-8`` in float64).
    """
    p, q = np.broadcast_arrays(np.asarray(p, np.float64), np.asarray(q, np.float64))
    pw, pv, qw, qv = p[..., 0], p[..., 1:], q[..., 0], q[..., 1:]
    w = pw * qw + np.sum(pv * qv, axis=-1)  # scal(p* ⊗ q)
    v = pw[..., None] * qv - qw[..., None] * pv - np.cross(pv, qv)  # vec(p* ⊗ q)
    return 2 * np.arctan2(np.linalg.norm(v, axis=-1), np.abs(w))
