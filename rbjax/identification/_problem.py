"""Recordings packed for the solver: noise levels, segment defaults, padded segments.

NumPy only, before any tracing (eager ``jnp`` calls would compile once per new
shape): :func:`prepare` checks the inputs (:mod:`._checks`) and identifiability,
estimates noise levels (:mod:`._noise`), fits the linear start
(:mod:`._linear`), chooses substeps and segments, and cuts the recordings into
padded multiple-shooting segments for the traced model (:mod:`._model`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np

from .. import _methods
from .._body import Body
from .._pytree import replace
from .._rotations_np import np_increments, np_qmat, rate_estimate
from .._state import State
from ._checks import check_inputs, gyro_frame_check
from ._layout import Layout
from ._linear import (
    body_momentum_system,
    check_identifiability,
    initial_inertia_estimate,
    momentum_system,
    np_params_from_inertia,
    skew,
)
from ._noise import noise_dof, noise_std, orientation_noise_std, roughness_covariance
from ._rotor import gyro_attitude
from ._segments import Segments

# Default numerics (see fit_inertia's docstring for the error budget)
_MAX_STEP_ANGLE = 0.05  # rad turned per integrator step: rk4 error ~1e-9 rad per step at this size
_SEGMENT_INTERVALS = 512  # target intervals per shooting segment (scan depth)
# fast recordings of at most this many intervals get at least _SHORT_SUBSTEPS integrator steps per interval
_SHORT_INTERVALS = 256
_SHORT_SUBSTEPS = 4


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


def _glitch_free_angles(angles: np.ndarray, dts: np.ndarray) -> np.ndarray:
    """Angles turned per sample interval ``(N, T-1)``, the spikes of glitched samples taken out.

    ``angle_k / dt_k`` is the mean rate over interval ``k``, which a rigid body changes
    smoothly; a glitched orientation (a sample off by 1 rad) puts a spike of that size into
    the two intervals beside it, and would ask for 20x the integrator steps everywhere. So the
    rate is the running median over ``_MEDIAN_WINDOW`` intervals (spikes of up to 3 adjacent
    intervals are removed, a smooth rate keeps its peak to second order in the window) and
    turned back into each interval's angle with its own ``dt`` (jitter and gaps kept).
    """
    rates = angles / dts
    n = rates.shape[-1]
    if n < _MEDIAN_WINDOW:
        return angles
    half = _MEDIAN_WINDOW // 2
    padded = np.pad(rates, [(0, 0)] * (rates.ndim - 1) + [(half, half)], mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, _MEDIAN_WINDOW, axis=-1)
    return np.median(windows, axis=-1) * dts


_MEDIAN_WINDOW = 7


# median |ω| above this (rad/s) is unusual for a hand-tossed object: a hint that the gyro is in deg/s
_DEG_HINT_RATE = 50.0


def _deg_hint(rates: np.ndarray) -> str:
    med = float(np.median(np.linalg.norm(rates, axis=-1)))
    return (
        f"The gyro's median rate is {med:.3g} rad/s ({med / (2 * np.pi):.3g} turns/s), a lot for a tossed "
        "object: if body_rates are in deg/s, pass np.deg2rad(body_rates) (rad/s)"
    )


def _check_gyro_units(rates: np.ndarray, implied: np.ndarray) -> None:
    """``ValueError`` when the gyro ``(N, T, 3)`` reads ~57.3x (deg/s) the rates the orientations imply."""
    for n in range(rates.shape[0]):
        g, o = np.linalg.norm(rates[n], axis=-1), np.linalg.norm(implied[n], axis=-1)
        moving = o > 0.05 * max(float(o.max()), 1e-300)
        if not np.any(moving):
            continue
        ratio = float(np.median(g[moving] / o[moving]))
        if 0.8 * np.degrees(1.0) < ratio < 1.25 * np.degrees(1.0):
            raise ValueError(
                f"fit_inertia: body_rates{'' if rates.shape[0] == 1 else f'[{n}]'} read {ratio:.3g}x the "
                "angular rate the orientations imply, the factor between deg/s and rad/s (57.3): pass "
                "np.deg2rad(body_rates) (the gyro in rad/s)"
            )


def rotor_rate_at_samples(t: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``ḣ`` ``(T, 3)`` at the samples of the rotors' momentum ``h`` ``(T, 3)``, linear between samples.

    The interpolant's slope jumps at each sample; this is the mean of the slopes on
    either side (one-sided at the ends): the centred difference, second order in
    the sample interval for a smooth ``h``. Only the accelerometer's ``ω̇`` reads it;
    the integrator needs no ``ḣ`` (world ``L`` is the total momentum).
    """
    slope = np.diff(h, axis=0) / np.diff(t)[:, None]
    return 0.5 * (np.concatenate([slope[:1], slope]) + np.concatenate([slope, slope[-1:]]))


# methods whose fit model runs through ._flow (the rotor is modelled there only)
_FLOW_METHODS = ("rk4",)


# fitted drag coefficients per model: "linear" c₁, "quadratic" c₁ and c₂ (τ_b = -(c₁ + c₂|ω|) ω)
_DRAG_COEFFICIENTS = {None: 0, "linear": 1, "quadratic": 2}


class Problem(NamedTuple):
    """Recordings packed for the solver: start ``y0 (N, p)``, segment data (leading ``N``), static options."""

    y0: np.ndarray
    data: dict
    static: dict  # scale_fixed, method, substeps, use_rates, use_orientations, layout: fixed per compiled program
    batched: bool
    segments: int
    sample_index: np.ndarray  # (S, K+1) recording sample of each segment row
    sample_valid: np.ndarray  # (S, K+1) the row is a real sample (not padding, not a repeat)
    sensors: tuple  # the sensor blocks in row order, e.g. ("orientation", "gyro")


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
    body_torques=None,
    gyro_rotation=False,
    accelerations=None,
    acceleration_std=None,
    pad_intervals=None,
    drag=None,
    rotor_momentum=None,
    drag_axes=False,
    gyro_scale=False,
) -> Problem:
    """Validate recordings and pack them for :func:`rbjax.fit_inertia` (arguments as there).

    NumPy only, before any tracing: checks inputs and identifiability, estimates
    noise levels, fits the linear start, chooses substeps and segments, and cuts
    the recordings into padded segments (``pad_intervals``: at least that many
    intervals per segment, so recordings of different lengths share one shape).
    Without orientations (gyro only) the
    body frame at ``times[0]`` is taken as the world frame: every segment starts
    from the identity times its fitted rotation, chained by the joins.
    ``rotor_momentum``: ``(T, 3)`` / ``(N, T, 3)`` the rotors' momentum relative
    to the body, ``h = Σ J_k Ω_k a_k`` (body frame; :mod:`._rotor` makes it from
    ``fit_inertia``'s rotor arguments): it fixes the scale like a torque does.
    """
    _methods.get(method, State)  # unknown method: ValueError now, not in the solver
    t, q, wr, tau, tau_b = check_inputs(times, orientations, body_rates, torques, body_torques)
    use_q = q is not None
    given = q if q is not None else wr
    assert given is not None  # check_inputs: orientations or body_rates
    lead = given.shape[:-1]
    batched = len(lead) == 2
    add = (lambda a: a) if batched else (lambda a: None if a is None else a[None])
    q, wr, tau, tau_b = add(q), add(wr), add(tau), add(tau_b)
    main = given if batched else given[None]  # the recording that sets batch shape and dtype
    N, T = main.shape[:2]
    dtype = jax.dtypes.canonicalize_dtype(main.dtype)  # float64 input stays float32 without x64
    if not np.issubdtype(dtype, np.floating):
        dtype = jax.dtypes.canonicalize_dtype(np.float64)
    torque_free = tau is None and tau_b is None
    use_rotor = rotor_momentum is not None
    # only I's shape is identifiable: torque-free and without a rotor, whose known momentum fixes the scale
    scale_free = torque_free and not use_rotor
    if use_rotor:
        if method not in _FLOW_METHODS:
            raise ValueError(f"fit_inertia: rotor_rates= are modelled with method='rk4' only, got method={method!r}")
        hr = np.asarray(rotor_momentum, np.float64)
        if hr.shape not in (lead + (3,), (T, 3)):
            raise ValueError(f"fit_inertia: the rotors' momentum must have shape {lead + (3,)}, got {hr.shape}")
        hr = np.broadcast_to(hr, lead + (3,))
        hr = hr if batched else hr[None]
    use_rates = wr is not None
    if isinstance(gyro_bias, (bool, np.bool_)):
        gyro_bias = bool(gyro_bias)
    else:
        raise TypeError(f"fit_inertia: gyro_bias must be True or False, got {type(gyro_bias).__name__}")
    if not isinstance(gyro_rotation, (bool, np.bool_)):
        raise TypeError(f"fit_inertia: gyro_rotation must be True or False, got {type(gyro_rotation).__name__}")
    gyro_rotation = bool(gyro_rotation)
    if gyro_rotation and not (use_rates and use_q):
        raise ValueError(
            "fit_inertia: gyro_rotation=True needs body_rates and orientations: without orientations a "
            "rotated gyro frame is just another body frame (the inertia is fitted in the gyro's frame)"
        )
    use_accel = accelerations is not None
    if use_accel:
        acc = np.asarray(accelerations)
        if acc.shape not in (lead + (3,), (T, 3)):
            raise ValueError(
                f"fit_inertia: accelerations must have shape {lead + (3,)} (body frame, m/s²), got {acc.shape}"
            )
        if not np.all(np.isfinite(acc)):
            raise ValueError("fit_inertia: accelerations contain non-finite values")
        acc = np.broadcast_to(acc, lead + (3,)).astype(np.float64)
        acc = acc if batched else acc[None]
        if not torque_free:
            raise ValueError(
                "fit_inertia: accelerations= are modelled for free flight only (ω̇ from the torque-free "
                "Euler equations); omit torques=/body_torques= or accelerations="
            )
    if drag not in _DRAG_COEFFICIENTS:
        raise ValueError(
            f"fit_inertia: drag must be None, 'linear' or 'quadratic' (the body-frame damping model), or 'auto' (the "
            f"one the data support best), got {drag!r}"
        )
    if not isinstance(drag_axes, (bool, np.bool_)):
        raise TypeError(f"fit_inertia: drag_axes must be True or False, got {type(drag_axes).__name__}")
    if drag_axes and drag is None:
        raise ValueError(
            "fit_inertia: drag_axes=True fits the drag= model's coefficients per body axis; give "
            "drag='linear' or drag='quadratic' with it"
        )
    # per body axis: 3 coefficients c₁ₐ, or 6 (c₁ₐ, then c₂ₐ); the layout's size says which model
    n_drag = _DRAG_COEFFICIENTS[drag] * (3 if drag_axes else 1)
    if n_drag and method not in ("rk4",):
        raise ValueError(f"fit_inertia: drag= is modelled with method='rk4' only, got method={method!r}")
    if n_drag and use_accel:
        raise ValueError(
            "fit_inertia: accelerations= are modelled for free flight without torques (ω̇ from the "
            "torque-free Euler equations); omit drag= or accelerations="
        )
    if not isinstance(gyro_scale, (bool, np.bool_)):
        raise TypeError(f"fit_inertia: gyro_scale must be True or False, got {type(gyro_scale).__name__}")
    if gyro_scale and not use_rates:
        raise ValueError("fit_inertia: gyro_scale=True needs body_rates (there is no gyro to be scaled)")
    if gyro_bias and not use_rates:
        raise ValueError("fit_inertia: gyro_bias=True needs body_rates (there is no gyro to be biased)")

    dts = np.diff(t)
    if q is not None:
        q = q.astype(np.float64)
        inc = np_increments(q)  # (N, T-1, 3)
        angles = np.linalg.norm(inc, axis=-1)
    else:
        speed = np.linalg.norm(np.asarray(wr, np.float64), axis=-1)
        angles = 0.5 * (speed[:, 1:] + speed[:, :-1]) * dts  # rad turned per interval (trapezoid)
        q = np.broadcast_to(np.array([1.0, 0.0, 0.0, 0.0]), (N, T, 4))  # body frame at t0 = world
        if use_rotor:  # the segments' start attitudes from the gyro (see gyro_attitude)
            q = gyro_attitude(t, np.asarray(wr, np.float64))
    turned = _glitch_free_angles(angles, dts)
    if substeps is None:  # a power of two, so similar recordings share a compiled program
        substeps = _next_pow2(np.ceil(turned.max() / _MAX_STEP_ANGLE))
        if T - 1 <= _SHORT_INTERVALS and substeps > 1:
            # a throw (short and fast): 2 becomes _SHORT_SUBSTEPS, so throws of ~8-20 rad/s at 100 Hz
            # (2 or 4 by the angle alone) share one program; the extra steps cost a few ms, a new
            # program seconds. Slow recordings (1 substep) keep theirs: their solve would pay 4x
            substeps = max(substeps, _SHORT_SUBSTEPS)
    if segments is None:
        segments = _default_segments(T - 1, turned.sum(-1).max())
    S = int(segments)
    if S < 1 or (T - 1) // S < 2:
        raise ValueError(f"fit_inertia: segments={segments} needs at least 2 intervals each; T = {T}")
    layout = Layout(
        inertia=5 if scale_free else 6,
        gyro_bias=3 * gyro_bias,
        gyro_rotation=3 * gyro_rotation,
        accelerometer=6 * use_accel,
        drag=n_drag,
        gyro_scale=int(gyro_scale),
    )
    n_theta, n_params = layout.inertia, layout.size(S)
    n_data = 3 * T * (int(use_q) + int(use_rates) + int(use_accel))
    if n_data <= n_params + 1:
        raise ValueError(
            f"fit_inertia: {T} samples give {n_data} residuals, too few for {n_params} parameters "
            f"({n_theta} inertia + 6 per segment × {S} segments); record more samples or use fewer segments"
        )

    # noise levels not given: from what local quadratics in time cannot follow (._noise)
    eps = float(np.finfo(dtype).eps)
    if not use_q:
        sq = np.full(N, np.nan)
    elif orientation_std is None:
        sq = orientation_noise_std(t, q, eps)
    else:
        sq = np.full(N, float(orientation_std))
    if use_rates:
        sw = np.full(N, float(rate_std)) if rate_std is not None else noise_std(t, np.asarray(wr, np.float64), eps)
    else:
        sw = np.full(N, np.nan)

    # rates for the linear start: the gyro, or orientation differences over ~0.1 rad
    k = int(np.clip(np.ceil(0.1 / max(np.median(angles), 1e-12)), 1, max(1, (T - 1) // 4)))
    if use_rates:
        rates = np.asarray(wr, np.float64)
        if use_q:  # a gyro in deg/s reads 57.3x the rate the orientations imply
            _check_gyro_units(rates, rate_estimate(t, q, k))
        if check_gyro_frame and use_q:
            for n in range(N):
                gyro_frame_check(t, q[n], rates[n], k)
    else:
        rates = rate_estimate(t, q, k)

    K = _bucket(-(-(T - 1) // S))  # intervals per segment, padded: shapes from a coarse grid
    if pad_intervals is not None:  # padded further, to share a program with longer recordings
        K = max(K, int(pad_intervals))
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
        tau_n = None if tau is None else np.asarray(tau[n], np.float64)
        taub_n = None if tau_b is None else np.asarray(tau_b[n], np.float64)
        h_n = hr[n] if use_rotor else None
        if use_q:
            # world-frame torques for the momentum law: body ones rotated by the recorded attitude
            tau_w = tau_n if taub_n is None else np.einsum("tij,tj->ti", np_qmat(q[n]), taub_n)
            MtM, Mtb, scale = momentum_system(t, q[n], rates[n], tau_w, h_n)
        else:
            MtM, Mtb, scale = body_momentum_system(t, rates[n], taub_n, h_n)
        try:
            check_identifiability(MtM, excitation_tol, scale_free)
        except ValueError as e:
            if use_rates and np.median(np.linalg.norm(rates[n], axis=-1)) > _DEG_HINT_RATE:
                raise ValueError(f"{e} {_deg_hint(rates[n])}") from None
            raise
        if initial_inertia is None:
            I0 = initial_inertia_estimate(MtM, Mtb, scale, scale_free)
        else:
            I0 = np.asarray(initial_inertia, np.float64)
            Body(1.0, I0)  # validates a user guess
            # a flat body's guess (I1 + I2 = I3, e.g. a disk's diag(1, 1, 2)) is physical, but the
            # log-Cholesky parameters need Σ = ½ tr I - I positive definite: start a hair inside
            # (1e-3 of the way to the isotropic tensor; the solver moves from there)
            if np.linalg.eigvalsh(0.5 * np.trace(I0) * np.eye(3) - I0)[0] <= 1e-6 * np.trace(I0):
                I0 = (1 - 1e-3) * I0 + 1e-3 * np.trace(I0) / 3 * np.eye(3)
        if scale_free:  # the gauge log L00 = 0: rescale so that Σ_xx = 1, drop θ0
            I0 = I0 / (0.5 * np.trace(I0) - I0[0, 0])
        # the gyro bias, the gyro frame's rotation and the drag start at zero
        theta0 = np.zeros(layout.shared)
        theta0[layout.span("inertia")] = np_params_from_inertia(I0)[(1 if scale_free else 0) :]
        if use_accel:
            # lever arm and bias from linear least squares: a = ([ω̇]× + [ω]×²) r + b_a with the
            # start inertia's ω̇ = -I⁻¹ (ω × I ω), linear in (r, b_a)
            wn = rates[n]
            Lb = wn @ I0.T if h_n is None else wn @ I0.T + h_n
            spin_rate = 0.0 if h_n is None else rotor_rate_at_samples(t, h_n)
            wd = -np.linalg.solve(I0, (np.cross(wn, Lb) + spin_rate).T).T
            Wx = skew(wn)
            A = np.concatenate([skew(wd) + Wx @ Wx, np.broadcast_to(np.eye(3), (T, 3, 3))], -1).reshape(-1, 6)
            theta0[layout.span("accelerometer")] = np.linalg.lstsq(A, acc[n].reshape(-1), rcond=None)[0]
        w_start = rates[n][starts]
        y0s.append(np.concatenate([theta0, np.column_stack([np.zeros((S, 3)), w_start]).reshape(-1)]))
        first = (np.arange(S) == 0).astype(np.float64)
        ones = np.ones(S)
        if use_q:
            wq, wcq = ones / sq[n], ones / sq[n]
        else:
            # no orientation data: the joins' orientation gaps only chain the segments (they matter
            # with body torques); a gap g weighs like a rate error g / segment duration
            wq, wcq = ones, ones / (sw[n] * seg_dur)
        seg = Segments(
            q_start=q[n][starts],
            q_first=np.broadcast_to(q[n][0], (S, 4)),
            w_first=np.broadcast_to(rates[n][0], (S, 3)),
            first=first,
            q_meas=q[n][idx_c + 1],
            w_meas=rates[n][idx_c + 1],
            dt=seg_dt,
            t0=t[starts] - t[0],
            mask=mask.astype(np.float64),
            wq=wq,
            wcq=wcq,
            delta_free=ones if use_q else 1.0 - first,
            # robust-loss weights per sensor block and sample (1: squared loss; IRLS updates them)
            rw=np.ones((S, int(use_q) + int(use_rates) + int(use_accel), K + 1)),
            ww=ones / sw[n] if use_rates else ones,
            wc=ones * ((1 / sw[n]) if use_rates else seg_dur / sq[n]),
        )
        sa = np.nan
        if use_accel:
            sa = acceleration_std if acceleration_std is not None else float(noise_std(t, acc[n], eps))
            a_first = np.broadcast_to(acc[n][0], (S, 3))
            seg = replace(seg, a_first=a_first, a_meas=acc[n][idx_c + 1], wa=ones / float(sa))
        if tau_n is not None:
            seg = replace(seg, t_samples=t[samp] - t[0], tau=tau_n[samp])
        if taub_n is not None:
            seg = replace(seg, t_samples=t[samp] - t[0], tau_b=taub_n[samp])
        if h_n is not None:
            # the rotors' momentum at every segment's samples, linear between them; padding repeats the
            # segment's last sample (the observed rate at its end reads h there, and dt = 0 keeps the state)
            at = starts[:, None] + np.minimum(np.arange(K + 1)[None, :], n_real[:, None])
            seg = replace(seg, h=h_n[at], h_noise=np.broadcast_to(roughness_covariance(t, h_n), (len(starts), 3, 3)))
            if use_accel:
                seg = replace(seg, h_rate=rotor_rate_at_samples(t, h_n)[at])
        # without orientations segment 0's rotation δ_0 is pinned (delta_free = 0): 3 parameters
        # with a zero Jacobian column, not degrees of freedom of the fit
        n_unused = 0.0 if use_q else 3.0
        # the noise levels that whiten the residuals [orientation, gyro, accelerometer] (NaN: no such
        # sensor), and the effective degrees of freedom of each: inf when given, else ._noise's
        given = (orientation_std is not None, rate_std is not None, acceleration_std is not None)
        n_est = noise_dof(T)
        datas.append(
            dict(
                noise_std=np.array([sq[n], sw[n], sa], np.float64),
                noise_dof=np.array([np.inf if g else n_est for g in given]),
                seg=seg,
                n_data=np.float64(n_data),
                n_unused=np.float64(n_unused),
                continuity_weight=np.float64(continuity_weight),
            )
        )
    # NumPy all the way into the jitted solver: eager jnp here would compile once per shape
    data = jax.tree.map(lambda *a: np.stack(a).astype(dtype), *datas)
    return Problem(
        y0=np.stack(y0s).astype(dtype),
        data=data,
        static=dict(
            scale_fixed=not scale_free,
            method=method,
            substeps=int(substeps),
            use_rates=use_rates,
            use_orientations=use_q,
            layout=layout,
        ),
        batched=batched,
        segments=S,
        sample_index=np.concatenate([np.zeros((S, 1), int), idx_c + 1], 1),
        sample_valid=np.concatenate([(np.arange(S) == 0)[:, None], mask], 1),
        sensors=(("orientation",) if use_q else ())
        + (("gyro",) if use_rates else ())
        + (("accelerometer",) if use_accel else ()),
    )


def _pooled_levels(levels: np.ndarray, dofs: np.ndarray) -> np.ndarray:
    """Each sensor's noise level ``(k,)`` pooled over recordings ``levels, dofs (n, k)``.

    ``σ² = Σ ν_i σ_i² / Σ ν_i`` over the recordings that have the sensor, whose degrees of
    freedom are then ``Σ ν_i``; a given level (``ν = inf``) is the same in every recording.
    NaN for a sensor none has.
    """
    out = np.full(levels.shape[1], np.nan)
    for k, (s, v) in enumerate(zip(levels.T, dofs.T, strict=True)):
        ok = np.isfinite(s)
        if not ok.any():
            continue
        given = np.isinf(v[ok])
        out[k] = s[ok][0] if given.any() else np.sqrt(np.sum(v[ok] * s[ok] ** 2) / np.sum(v[ok]))
    return out


def join_problems(problems: list[Problem]) -> Problem:
    """One problem of several single recordings of one body (``fit_inertia(..., joint=True)``).

    Each recording keeps its segments and their nuisance parameters
    ``(δ_s, ω_s)``; the shared block (inertia, sensor parameters) is one. The
    segments are stacked in recording order and only the joins inside a
    recording are kept (the static ``joins``: the segments ``s`` joined to
    ``s + 1``), so the throws are independent motions of the same body. All
    must be packed alike (``segments`` each, one ``pad_intervals`` and
    ``substeps``). Start: the mean of the recordings' shared blocks. Each
    sensor's noise level pools the recordings' (one sensor, one level:
    :func:`_pooled_levels`), ``noise_dof`` their sum. Sample indices count the
    recordings' samples one after the other.
    """
    first = problems[0]
    n_shared = first.static["layout"].shared
    shared = np.mean([p.y0[0, :n_shared] for p in problems], 0)
    y0 = np.concatenate([shared] + [p.y0[0, n_shared:] for p in problems])[None]
    stack = lambda name: np.stack([p.data[name][0] for p in problems])
    noise = _pooled_levels(stack("noise_std"), stack("noise_dof"))
    use_q, use_rates = first.static["use_orientations"], first.static["use_rates"]
    segs = []
    for p in problems:
        # one sensor, one noise level: every recording weighted by the pooled level
        f_q, f_w, f_a = np.where(np.isfinite(noise), p.data["noise_std"][0] / noise, 1.0)
        seg = p.data["seg"]
        segs.append(
            replace(
                seg,
                wq=seg.wq * (f_q if use_q else 1.0),
                ww=seg.ww * (f_w if use_rates else 1.0),
                wc=seg.wc * (f_w if use_rates else f_q),  # the rate join in the gyro's (or attitude's) units
                wcq=seg.wcq * (f_q if use_q else f_w),
                wa=None if seg.wa is None else seg.wa * f_a,
            )
        )
    seg = jax.tree.map(lambda *a: np.concatenate(a, 1), *segs)
    data = dict(
        first.data,
        seg=seg,
        noise_std=noise[None],
        noise_dof=stack("noise_dof").sum(0)[None],
        n_data=stack("n_data").sum(0)[None],
        n_unused=stack("n_unused").sum(0)[None],
    )
    joins, offset, index, valid = [], 0, [], []
    sample_offset = 0
    for p in problems:
        joins += [offset + s for s in range(p.segments - 1)]
        offset += p.segments
        index.append(p.sample_index + sample_offset)
        valid.append(p.sample_valid)
        sample_offset += int(p.sample_index.max()) + 1
    return first._replace(
        y0=y0,
        data=data,
        static=dict(first.static, joins=tuple(joins)),
        segments=offset,
        sample_index=np.concatenate(index),
        sample_valid=np.concatenate(valid),
    )
