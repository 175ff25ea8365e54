"""NumPy quaternion helpers for host-side code: the identification's data side (before tracing)
and the animation.

Plain NumPy: eager ``jnp`` calls would compile once per new shape. The product, the
rotation matrix and the logarithm's scale are :mod:`rbjax._math`'s formulas (on components), stacked with NumPy.
Quaternions ``[w, x, y, z]``, body to world.
"""

from __future__ import annotations

import numpy as np

from ._math import hamilton, log_scale, rotation_rows


def np_qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``p ⊗ q`` of ``(..., 4)`` arrays (:func:`rbjax._math.hamilton`)."""
    return np.stack(hamilton(np.moveaxis(p, -1, 0), np.moveaxis(q, -1, 0)), -1)


def np_qlog(q: np.ndarray) -> np.ndarray:
    """Rotation vectors ``θ n`` ``(..., 3)``, ``θ ∈ [0, π]``, of unit quaternions ``(..., 4)`` (``quat_log``)."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    return log_scale(q[..., :1], s, np.finfo(q.dtype).eps, np) * q[..., 1:]


def np_qmat(q: np.ndarray) -> np.ndarray:
    """``R(q)`` ``(..., 3, 3)`` of unit quaternions ``(..., 4)`` (:func:`rbjax._math.rotation_rows`)."""
    return np.stack([np.stack(row, -1) for row in rotation_rows(np.moveaxis(q, -1, 0))], -2)


CONJ = np.array([1.0, -1.0, -1.0, -1.0])


def np_increments(q: np.ndarray, k: int = 1) -> np.ndarray:
    """Body-frame rotation vectors ``log(q_i⁻¹ q_{i+k})`` ``(..., T-k, 3)``."""
    return np_qlog(np_qmul(q[..., :-k, :] * CONJ, q[..., k:, :]))


def rate_estimate(times: np.ndarray, q: np.ndarray, k: int) -> np.ndarray:
    """Body rates from orientations by a centred difference over ``±k`` samples."""
    T = q.shape[-2]
    i = np.arange(T)
    lo, hi = np.clip(i - k, 0, T - 1), np.clip(i + k, 0, T - 1)
    rv = np_qlog(np_qmul(q[..., lo, :] * CONJ, q[..., hi, :]))
    return rv / (times[..., hi] - times[..., lo])[..., None]
