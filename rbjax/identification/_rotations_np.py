"""NumPy quaternion helpers for the identification's data side (before tracing).

Plain NumPy: eager ``jnp`` calls would compile once per new shape. Quaternions
``[w, x, y, z]``, body to world.
"""

from __future__ import annotations

import numpy as np


def np_qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
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


def np_qlog(q: np.ndarray) -> np.ndarray:
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    scale = np.where(s > 1e-12, 2 * np.arctan2(s, q[..., :1]) / np.maximum(s, 1e-300), 2 / q[..., :1])
    return scale * q[..., 1:]


def np_qmat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


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
