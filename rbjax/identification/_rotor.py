"""``fit_inertia``'s rotor arguments: checked in NumPy and turned into the rotors' momentum.

A gyrostat's rotors spin at measured rates ``Ω_k(t)`` (rad/s, relative to the
body) about fixed unit axes ``a_k`` (body frame) with axial inertias ``J_k``;
the fit's model needs only their summed momentum relative to the body,
``h(t) = Σ_k J_k Ω_k(t) a_k`` (body frame), at the samples
(:mod:`._model`, :mod:`._flow`). Every check here runs before anything is traced
and names the argument and the remedy.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["UNITS", "gyro_attitude", "rotor_arrays", "units"]

#: ``FitResult.inertia_units``: what the fitted inertia's numbers are
UNITS = ("trace-normalised", "rotor inertia J", "kg m^2")

# |a| may differ from 1 by this much (a unit axis written with 6 decimals passes)
_AXIS_TOL = 1e-5


def units(*, rotor: bool, rotor_inertia_given: bool, torques: bool) -> str:
    """``"kg m^2"`` (known torques or a known ``J``), ``"rotor inertia J"`` (a rotor of unknown ``J``, taken
    as 1) or ``"trace-normalised"`` (neither: only the ratios are identifiable)."""
    if torques or (rotor and rotor_inertia_given):
        return "kg m^2"
    return "rotor inertia J" if rotor else "trace-normalised"


def _axes(rotor_axis: Any) -> tuple[np.ndarray, bool]:
    """Unit axes ``(k, 3)`` and whether one axis was given as ``(3,)``."""
    if rotor_axis is None:
        raise TypeError(
            "fit_inertia: rotor_rates needs rotor_axis, the rotor's spin axis in the body (IMU) frame: "
            "a unit vector (3,), e.g. rotor_axis=[0, 0, -1], or one per rotor (k, 3)"
        )
    _refuse_nonnumeric("rotor_axis", rotor_axis)
    a = np.asarray(rotor_axis, np.float64)
    single = a.ndim == 1
    if a.shape != (3,) and not (a.ndim == 2 and a.shape[1] == 3 and a.shape[0] >= 1):
        raise ValueError(
            f"fit_inertia: rotor_axis must have shape (3,) (one rotor) or (k, 3) (k rotors), body frame, got {a.shape}"
        )
    a = a.reshape(-1, 3)
    if not np.all(np.isfinite(a)):
        raise ValueError("fit_inertia: rotor_axis contains non-finite values; give unit vectors in the body frame")
    norm = np.linalg.norm(a, axis=-1)
    if np.any(norm == 0):
        raise ValueError("fit_inertia: rotor_axis has a zero axis; give each rotor's spin axis as a unit vector")
    if np.any(np.abs(norm - 1) > _AXIS_TOL):
        raise ValueError(
            f"fit_inertia: rotor_axis must be unit vectors (|a| = {np.array2string(norm, precision=6)}); "
            "normalise it first: a / np.linalg.norm(a, axis=-1, keepdims=True)"
        )
    return a, single


def _inertias(rotor_inertia: Any, k: int) -> np.ndarray:
    _refuse_nonnumeric("rotor_inertia", rotor_inertia)
    J = np.asarray(rotor_inertia, np.float64)
    if J.shape not in ((), (k,)):
        raise ValueError(
            f"fit_inertia: rotor_inertia must be a scalar or one per rotor ({k},) (kg m²), got shape {J.shape}"
        )
    if not np.all(np.isfinite(J)) or np.any(J <= 0):
        raise ValueError(
            f"fit_inertia: rotor_inertia must be finite and > 0 (the rotor's axial inertia in kg m²), got {J}; "
            "leave it out (J = 1) to fit the inertia in units of J"
        )
    return np.broadcast_to(J, (k,))


def _refuse_nonnumeric(name: str, x: Any) -> None:
    try:
        a = np.asarray(x)
    except Exception as e:  # ragged nested lists and the like
        raise TypeError(f"fit_inertia: {name} must be an array of real numbers: {e}") from None
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)) or a.dtype == np.float16:
        raise TypeError(f"fit_inertia: {name} must be real numbers (float32 or float64), got dtype {a.dtype.name}")


def _momentum(rates: Any, lead: tuple, axes: np.ndarray, J: np.ndarray, single: bool, where: str) -> np.ndarray:
    """``h = Σ_k J_k Ω_k a_k`` ``(*lead, 3)`` of one recording's (or a batch's) rates ``lead`` or ``(*lead, k)``."""
    _refuse_nonnumeric("rotor_rates", rates)
    w = np.asarray(rates)
    k = axes.shape[0]
    want = lead if single else lead + (k,)
    if w.shape != want:
        T = lead[-1]
        shape = "(T,)" if single else f"(T, {k})"
        raise ValueError(
            f"fit_inertia: rotor_rates{where} must have shape {want} ({shape} with T = {T} samples, rad/s "
            f"relative to the body{'' if single else ', one column per rotor of rotor_axis'}), got {w.shape}: "
            "resample the rotor's rate onto the gyro's sample times (np.interp)"
        )
    w = w.astype(np.float64)
    if not np.all(np.isfinite(w)):
        raise ValueError(
            f"fit_inertia: rotor_rates{where} contain non-finite values; interpolate over the gaps "
            "(np.interp on the valid samples) or cut the recording"
        )
    w = w[..., None] if single else w
    return np.einsum("...k,k,kc->...c", w, J, axes)


def rotor_arrays(times: Any, main: Any, rotor_rates: Any, rotor_axis: Any, rotor_inertia: Any) -> Any:
    """The rotors' momentum ``h`` matching the data: ``(T, 3)``, ``(N, T, 3)`` or a list of ``(T_i, 3)``.

    ``main``: the orientations or, without them, the body rates, as given (an
    array or a list of arrays); they set the shape ``rotor_rates`` must have
    (``(T,)`` or ``(T, k)``, with the batch's or list's leading axes). ``None``
    when no rotor is given; ``rotor_axis``/``rotor_inertia`` without
    ``rotor_rates`` are refused.
    """
    if rotor_rates is None:
        given = [n for n, v in (("rotor_axis", rotor_axis), ("rotor_inertia", rotor_inertia)) if v is not None]
        if given:
            raise TypeError(
                f"fit_inertia: {' and '.join(given)} given without rotor_rates; pass the rotor's measured rate "
                "rotor_rates=(T,) rad/s relative to the body (or leave the rotor arguments out)"
            )
        return None
    axes, single = _axes(rotor_axis)
    J = _inertias(1.0 if rotor_inertia is None else rotor_inertia, axes.shape[0])
    if main is None:
        return None  # no data: fit_inertia's own checks say so
    if isinstance(main, (list, tuple)):
        if not (isinstance(rotor_rates, (list, tuple)) and len(rotor_rates) == len(main)):
            raise ValueError(
                f"fit_inertia: the recordings are a list of {len(main)}, so rotor_rates must be a list of "
                f"{len(main)} arrays too (each (T_i,) or (T_i, k)), got {type(rotor_rates).__name__}"
            )
        return [
            _momentum(r, np.shape(m)[:-1], axes, J, single, f"[{i}]")
            for i, (m, r) in enumerate(zip(main, rotor_rates, strict=True))
        ]
    return _momentum(rotor_rates, np.shape(main)[:-1], axes, J, single, "")


def gyro_attitude(t: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Orientations ``(N, T, 4)`` (body to the body frame at ``t[0]``) dead-reckoned from gyro rates ``(N, T, 3)``.

    ``q_{i+1} = q_i ⊗ exp(½ (ω_i + ω_{i+1}) dt_i)``: only a start for the segments of a fit
    without orientations, so that each segment starts near where the one before it ends
    (its fitted rotation ``δ_s`` then is small, not the ~1-3 rad a fast throw turns per
    segment, across which the joins' ``log`` may take the other way round).
    """
    rv = 0.5 * (w[:, 1:] + w[:, :-1]) * np.diff(t)[None, :, None]  # (N, T-1, 3) rotation per interval
    angle = np.linalg.norm(rv, axis=-1, keepdims=True)
    half = 0.5 * angle
    sinc = np.where(angle > 0, np.sin(half) / np.where(angle > 0, angle, 1), 0.5)
    inc = np.concatenate([np.cos(half), sinc * rv], -1)
    q = np.empty(w.shape[:-1] + (4,))
    q[:, 0] = (1.0, 0.0, 0.0, 0.0)
    for i in range(rv.shape[1]):
        a, b = q[:, i], inc[:, i]
        q[:, i + 1, 0] = a[:, 0] * b[:, 0] - np.sum(a[:, 1:] * b[:, 1:], -1)
        q[:, i + 1, 1:] = a[:, :1] * b[:, 1:] + b[:, :1] * a[:, 1:] + np.cross(a[:, 1:], b[:, 1:])
        q[:, i + 1] /= np.linalg.norm(q[:, i + 1], axis=-1, keepdims=True)
    return q
