"""Noise levels from the data: what a local quadratic in time cannot follow.

A sensor's white noise ``σ`` shows in the part of its samples that no smooth curve
follows. Over each window of five consecutive samples a quadratic in time is fitted
by least squares at the samples' *own* times; the residual at the centre sample is

    r_c = y_c - ŷ_c = Σ_j a_j y_j,    a = e_c - H[c, :],    var(r_c) = σ² Σ_j a_j² = σ² (1 - h_cc)

(``H`` the window's hat matrix), whatever the spacing. ``σ`` is the MAD of the
standardised residuals, ``1.4826 median |r_c| / sqrt(1 - h_cc)``, so a glitch or a
catch does not move it. For a motion smooth on the scale of five samples the
residual is of the order of its fourth derivative times the spacing to the fourth
(on a symmetric window the quadratic is exact for cubics at the centre). Plain second
differences would also keep ``ω̇ (Δt_{i+1} - Δt_i)`` from a jittered clock and
``ω̈ Δt²`` from a fast tumble: on a phone's 100 Hz gyro (1 ms jitter, 10-20 rad/s)
several times the noise itself.

Orientations: ``y_j = log(q_c⁻¹ q_j)`` (body frame, relative to the window's centre),
whose noise is ``n_j - n_c`` to first order; the quadratic's constant and linear
terms absorb ``-n_c`` and its rotation with the window, so the same residual holds.

A level is never below what the fit's own model reaches: ``max(FLOOR_EPS eps,
MODEL_FLOOR)`` times the signal's RMS (1 rad for orientations), ``eps`` the fit dtype's
round-off. Clean data carry only their rounding (or their generator's error), while
the fit's residuals also carry its integration's: rk4 steps of at most 0.05 rad err
~1e-9 rad each, hundreds of them per segment, and float32 rounds at 1.2e-7. A level
below that would call a clean fit inconsistent.

The estimate's effective degrees of freedom (for the consistency test's ``F``
distribution) were measured by simulating white noise: :data:`DOF_PER_RESIDUAL`.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .._rotations_np import CONJ, np_qlog, np_qmul

__all__ = [
    "noise_std",
    "roughness_covariance",
    "orientation_noise_std",
    "noise_dof",
    "DOF_PER_RESIDUAL",
    "FLOOR_EPS",
    "MODEL_FLOOR",
]

_HALF = 2  # five-sample windows: a quadratic keeps two residual degrees of freedom in each
#: The lowest level: in units of the fit dtype's epsilon, and relative (see above); times the signal's RMS.
FLOOR_EPS = 4.0
MODEL_FLOOR = 1e-7

#: Effective degrees of freedom of the squared estimate per standardised residual component,
#: ``ν = 2 E[σ̂²]² / var(σ̂²)`` over ``3 (T - 4)`` residuals, for white noise:
#: 0.18-0.22 for T = 20-1000, regular or jittered clocks (overlapping windows correlate the
#: residuals; the MAD costs too). The lower end: an overstated ν would flag clean fits.
DOF_PER_RESIDUAL = 0.18


def _centre_weights(t: np.ndarray) -> np.ndarray:
    """``(W, 5)`` weights ``a / ‖a‖`` of each window's centre residual (``W = T - 4``), unit noise gain."""
    win = sliding_window_view(np.asarray(t, np.float64), 2 * _HALF + 1)
    tt = win - win[:, _HALF : _HALF + 1]
    tt = tt / np.max(np.abs(tt), axis=1, keepdims=True)  # scaled: a well-conditioned Vandermonde
    V = tt[..., None] ** np.arange(3)  # (W, 5, 3)
    a = -np.einsum("wk,wkj->wj", V[:, _HALF], np.linalg.pinv(V))  # -H[c, :] = -V_c (VᵀV)⁻¹ Vᵀ
    a[:, _HALF] += 1.0
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def _mad(r: np.ndarray, eps: float, scale: np.ndarray | float) -> np.ndarray:
    """``1.4826 median |r|`` over the last two axes, at least the floor for a signal of RMS ``scale``."""
    floor = max(FLOOR_EPS * eps, MODEL_FLOOR) * np.maximum(scale, np.finfo(np.float64).tiny)
    return np.maximum(1.4826 * np.median(np.abs(r), axis=(-2, -1)), floor)


def noise_std(times: np.ndarray, y: np.ndarray, eps: float) -> np.ndarray:
    """White-noise std ``(*N,)`` of samples ``y`` ``(*N, T, 3)`` at ``times`` ``(T,)`` (y's units).

    ``T ≥ 5``; ``eps``: the fit dtype's machine epsilon (sets the floor).
    """
    y = np.asarray(y, np.float64)
    a = _centre_weights(times)
    win = sliding_window_view(y, 2 * _HALF + 1, axis=-2)  # (*N, W, 3, 5)
    return _mad(np.einsum("...wdk,wk->...wd", win, a), eps, np.sqrt(np.mean(y**2, axis=(-2, -1))))


def roughness_covariance(times: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``(3, 3)``: the covariance of what a local quadratic cannot follow in ``y`` ``(T, 3)`` (y's units squared).

    The mean of ``r_c r_cᵀ`` over the five-sample windows (``r_c`` the centre
    residual at unit noise gain, as in :func:`noise_std`): for white errors of
    covariance ``Σ`` it is ``Σ``. A mean, not a MAD: a quantised series (a motor's
    logged rate in whole steps) sits on one step over some windows and crosses
    steps in others, and its error's variance is the mean over both (``step²/12``
    for a steady ramp). Zeros for fewer than five samples.
    """
    y = np.asarray(y, np.float64)
    if y.shape[0] < 2 * _HALF + 1:
        return np.zeros((3, 3))
    r = np.einsum("wdk,wk->wd", sliding_window_view(y, 2 * _HALF + 1, axis=0), _centre_weights(times))
    return r.T @ r / r.shape[0]


def orientation_noise_std(times: np.ndarray, q: np.ndarray, eps: float) -> np.ndarray:
    """Orientation noise std ``(*N,)`` (rad, body frame, per axis) of unit quaternions ``q`` ``(*N, T, 4)``."""
    a = _centre_weights(times)
    win = np.moveaxis(sliding_window_view(np.asarray(q, np.float64), 2 * _HALF + 1, axis=-2), -1, -2)
    rel = np_qlog(np_qmul((win[..., _HALF : _HALF + 1, :] * CONJ), win))  # (*N, W, 5, 3): log(q_c⁻¹ q_j)
    return _mad(np.einsum("...wkd,wk->...wd", rel, a), eps, 1.0)


def noise_dof(samples: int) -> float:
    """Effective degrees of freedom of one estimated level from ``samples`` samples (3 components each)."""
    return DOF_PER_RESIDUAL * 3 * max(samples - 2 * _HALF, 1)
