"""FitResult: the fitted inertia, its uncertainty and the diagnostics of the fit."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array
from jaxtyping import Bool, Float, Int

from .._math import quat_exp, quat_multiply
from .._pytree import field, pytree_dataclass, static_field
from ._model import _normalised_moments, _unpack


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
        converged: whether the fit can be trusted: ``solver_converged`` and
            not ``on_boundary`` and ``residual_ratio ≤ 3``. Check it (and the
            two flags for the reason) before using ``moment_std``.
        iterations: Levenberg–Marquardt steps taken.
        solver_converged: whether Levenberg–Marquardt met its tolerances
            (what ``converged`` meant before the two checks below were added).
        on_boundary: the fitted moments (ascending ``I1 ≤ I2 ≤ I3``) meet the
            triangle inequality within ``(I1 + I2 - I3) / tr I < 1e-3``, i.e.
            the smallest eigenvalue of ``Σ = ½ tr(I) 1 - I`` (the log-Cholesky
            pivot ``exp(θ)``) is below 5e-4 of ``tr Σ``: the fit ran into the edge of
            the physically consistent set, where the parametrisation flattens
            (``d I / d θ → 0``) and the Gauss–Newton covariance is meaningless,
            so ``moment_std`` is NaN there. Usual causes: gyro in the wrong
            frame, orientation glitches, wrong torques. A genuinely planar
            body (a thin plate, ``I1 + I2 = I3``) also lands here.
        residual_ratio: RMS of the weighted data residuals per degree of
            freedom, ``sqrt(Σ r² / (n - p))`` (dimensionless): ≈ 1 when the
            residuals are as large as the noise levels (given or estimated)
            predict; above 3 the model or noise model does not fit the data
            (outliers, glitches, bias, wrong noise levels) and ``converged`` is
            ``False``. ``moment_std`` already scales with it (``s² = ratio²``).
        gyro_bias: ``(3,)`` fitted constant gyro bias ``b`` (body frame, rad/s;
            gyro = ω + b) with ``fit_inertia(..., gyro_bias=True)``; zeros otherwise.
        gyro_bias_std: ``(3,)`` its one-sigma uncertainty (rad/s, same
            covariance as ``moment_std``); NaN without ``gyro_bias=True``.
        gyro_rotation: ``(4,)`` fitted quaternion ``[w, x, y, z]`` of the fixed
            rotation ``R_g`` that maps gyro-frame vectors to body-frame ones
            (the body frame being the frame of the recorded orientations;
            gyro = ``R_gᵀ ω + b``) with ``gyro_rotation=True``; the identity otherwise.
        gyro_rotation_std: ``(3,)`` one-sigma uncertainty of its rotation
            vector ``log R_g`` (rad, body frame); NaN without ``gyro_rotation=True``.
        lever_arm: ``(3,)`` fitted position ``r`` of the accelerometer from the
            centre of mass (body frame, m) with ``accelerations=``; NaN otherwise.
        lever_arm_std: ``(3,)`` its one-sigma uncertainty (m); NaN without accelerations.
        accelerometer_bias: ``(3,)`` fitted constant accelerometer bias (body
            frame, m/s²); NaN without accelerations.
        accelerometer_bias_std: ``(3,)`` its one-sigma uncertainty (m/s²).
        acceleration_rms: RMS accelerometer residual (m/s²); NaN without accelerations.
        robust_weights: ``(T, 3)`` final robust-loss weights of each sample's
            orientation (column 0), gyro (column 1) and accelerometer (column 2)
            residuals, in [0, 1];
            1 with ``loss="squared"`` and for a sensor not given.
        outliers: ``(T,)`` bool: samples whose residual is beyond ``2 loss_scale`` σ
            (robust weight below 0.5 for Huber, 0.2 for Cauchy): the glitches
            the robust loss set aside; all ``False`` with ``loss="squared"``.
            ``orientation_rms``, ``rate_rms`` and ``residual_ratio`` are taken
            over the other samples.
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
    solver_converged: Bool[Array, "*N"] = field(core_ndim=0)
    on_boundary: Bool[Array, "*N"] = field(core_ndim=0)
    residual_ratio: Float[Array, "*N"] = field(core_ndim=0)
    gyro_bias: Float[Array, "*N 3"] = field(core_ndim=1)
    gyro_bias_std: Float[Array, "*N 3"] = field(core_ndim=1)
    gyro_rotation: Float[Array, "*N 4"] = field(core_ndim=1)
    gyro_rotation_std: Float[Array, "*N 3"] = field(core_ndim=1)
    lever_arm: Float[Array, "*N 3"] = field(core_ndim=1)
    lever_arm_std: Float[Array, "*N 3"] = field(core_ndim=1)
    accelerometer_bias: Float[Array, "*N 3"] = field(core_ndim=1)
    accelerometer_bias_std: Float[Array, "*N 3"] = field(core_ndim=1)
    acceleration_rms: Float[Array, "*N"] = field(core_ndim=0)
    robust_weights: Float[Array, "*N T 3"] = field(core_ndim=2)
    outliers: Bool[Array, "*N T"] = field(core_ndim=1)
    scale_fixed: bool = static_field(default=False)
    segments: int = static_field(default=1)


_BOUNDARY_RTOL = 1e-3  # (I1 + I2 - I3) / tr I below this: on the edge of the consistent set
_RESIDUAL_RATIO_MAX = 3.0  # RMS weighted residual above this: the noise model does not fit


def summarise(
    y,
    r,
    J,
    data,
    solver_ok,
    iterations,
    *,
    scale_fixed,
    use_rates,
    gyro_bias,
    use_orientations=True,
    outlier_weight=0.0,
    gyro_rotation=False,
    use_accel=False,
):
    """FitResult fields of one recording from the solver's final ``y``, residuals ``r`` and Jacobian ``J``.

    Covariance ``s² (JᵀJ)⁺`` with ``s²`` the data residuals' variance per degree
    of freedom (the continuity rows are constraints, not data), propagated to
    the principal moments; then the honest-failure diagnostics.
    """
    seg = data["seg"]
    S, K = seg["dt"].shape
    p = y.shape[0]
    n_blocks = int(use_orientations) + int(use_rates) + int(use_accel)
    n_rows = S * (3 + 3 * K) * n_blocks  # data rows, incl. zero padding
    n_cont = r.shape[0] - n_rows
    # continuity residuals act as constraints: they remove degrees of freedom, add no data
    # residual variance from the samples the robust loss kept (all of them for squared loss):
    # a glitch's w r² = c |r| would otherwise inflate s² with what the loss set aside.
    # Data count: 3 rows per kept sample and sensor, times its robust weight
    valid = jnp.concatenate([seg["first"][:, None], seg["mask"]], 1)  # (S, K+1): real samples
    kept = jnp.where(seg["rw"] >= outlier_weight, valid[:, None, :], 0)
    n_eff = 3 * jnp.sum(seg["rw"] * kept)
    r_kept = r[:n_rows].reshape(kept.shape + (3,)) * kept[..., None]
    s2 = jnp.sum(r_kept**2) / (n_eff - (p - n_cont - data["n_unused"]))
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
    n_I = 6 if scale_fixed else 5
    n_R = n_I + (3 if gyro_bias else 0)
    n_A = n_R + (3 if gyro_rotation else 0)
    _, P = _unpack(y, n_A + (6 if use_accel else 0), S)
    if use_accel:
        a_std = jnp.sqrt(jnp.diagonal(cov)[n_A : n_A + 6])
        lever, lever_std, a_bias, a_bias_std = y[n_A : n_A + 3], a_std[:3], y[n_A + 3 : n_A + 6], a_std[3:]
    else:
        lever = lever_std = a_bias = a_bias_std = jnp.full(3, jnp.nan, y.dtype)
    nan3 = jnp.full(3, jnp.nan, y.dtype)
    if gyro_bias:
        bias, bias_std = y[n_I : n_I + 3], jnp.sqrt(jnp.diagonal(cov)[n_I : n_I + 3])
    else:
        bias, bias_std = jnp.zeros(3, y.dtype), nan3
    if gyro_rotation:
        rot, rot_std = quat_exp(y[n_R : n_R + 3]), jnp.sqrt(jnp.diagonal(cov)[n_R : n_R + 3])
    else:
        rot, rot_std = jnp.zeros(4, y.dtype).at[0].set(1), nan3
    n_kept = 3 * jnp.sum(kept, (0, 2))  # per sensor block
    rms = jnp.sqrt(jnp.sum(r_kept**2 / seg["rw"][..., None], (0, 2, 3)) / n_kept)  # undo √w: σ units
    nan = jnp.full((), jnp.nan, r.dtype)
    q_rms = rms[0] / seg["wq"][0] if use_orientations else nan
    w_rms = rms[int(use_orientations)] / seg["ww"][0] if use_rates else nan
    a_rms = rms[-1] / seg["wa"][0] if use_accel else nan
    # honest failure: the triangle margin I1 + I2 - I3 = 2 λ_min(Σ) near zero, or residuals
    # far above the noise model
    on_boundary = (moments[0] + moments[1] - moments[2]) < _BOUNDARY_RTOL * jnp.sum(moments)
    ratio = jnp.sqrt(s2)
    std = jnp.where(on_boundary, jnp.nan, std)
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
        converged=solver_ok & ~on_boundary & (ratio <= _RESIDUAL_RATIO_MAX),
        iterations=iterations,
        solver_converged=solver_ok,
        on_boundary=on_boundary,
        residual_ratio=ratio,
        gyro_bias=bias,
        gyro_bias_std=bias_std,
        gyro_rotation=rot,
        gyro_rotation_std=rot_std,
        lever_arm=lever,
        lever_arm_std=lever_std,
        accelerometer_bias=a_bias,
        accelerometer_bias_std=a_bias_std,
        acceleration_rms=a_rms,
    )
