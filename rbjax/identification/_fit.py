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

Levenberg–Marquardt (trust region, with MINPACK's relative-reduction stop: :mod:`._solver`)
minimises their sum of squares with Jacobians by forward-mode differentiation
through the integrator (:mod:`._model`). The start is a linear
least-squares fit of the conservation law ``R_i I ω_i - L_0 = ∫τ dt`` (no
differentiated data), which also gives the identifiability check
(:mod:`._linear`).
"""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np
from jaxtyping import Float

from .._pytree import replace
from .._typing import ArrayLike
from ._joint import fit_joint
from ._members import batch_members, fit_members, is_ragged, ragged_members
from ._recording_data import Recording, to_fit_arguments
from ._result import FitResult
from ._rotor import rotor_arrays, units
from ._solve import fit_regular

__all__ = ["fit_inertia"]


def fit_inertia(
    times: Float[ArrayLike, " T"] | Recording | list[Recording],
    orientations: Float[ArrayLike, "*N T 4"] | None = None,
    *,
    body_rates: Float[ArrayLike, "*N T 3"] | None = None,
    torques: Float[ArrayLike, "*N T 3"] | None = None,
    body_torques: Float[ArrayLike, "*N T 3"] | None = None,
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
    max_steps: int = 200,
    check_gyro_frame: bool = True,
    gyro_bias: bool = False,
    gyro_rotation: bool = False,
    accelerations: Float[ArrayLike, "*N T 3"] | None = None,
    acceleration_std: float | None = None,
    loss: str = "squared",
    loss_scale: float = 3.0,
    joint: bool = False,
    drag: str | None = None,
    drag_axes: bool = False,
    gyro_scale: bool = False,
    rotor_rates: Float[ArrayLike, "*N T *k"] | None = None,
    rotor_axis: Float[ArrayLike, "*k 3"] | None = None,
    rotor_inertia: float | Float[ArrayLike, " k"] | None = None,
) -> FitResult:
    """Fit a body-frame inertia tensor to a recording of free (or known-torque) rotation.

    Model: ``d(R I ω)/dt = τ`` (Euler's law, world frame), ``q̇ = ½ q ⊗ (0, ω)``
    with ``ω`` in the body frame, integrated by :func:`rbjax.step` (``method``)
    between the samples; with rotors (``rotor_rates``) ``d(R (I ω + h))/dt = τ``.
    See the module docstring for residuals and solver.

    Args:
        times: ``(T,)`` sample times (s), strictly increasing, possibly irregular
            (each interval is its own ``dt``, split into ``substeps`` steps).
            Or a list of ``N`` such arrays of any lengths ``T_i`` (recordings of
            different lengths): then every data argument is a list of ``N``
            arrays too (``orientations[i]`` ``(T_i, 4)``, ``body_rates[i]``
            ``(T_i, 3)``, ...), each recording is fitted as if alone (those with
            the same number of segments padded to the longest, masked, and fitted
            as one batch: one compiled program), and the result has a leading
            ``N`` axis, its per-sample fields padded with NaN to the longest.
            Or a :class:`rbjax.Recording` (or a list of them): its ``orientations``,
            ``gyro`` (as ``body_rates``), ``torques``, ``body_torques`` and
            ``accelerations`` are passed on, and the data arguments must be left
            out (every recording of a list must carry the same sensors;
            ``dataclasses.replace(rec, accelerations=None)`` drops one).
        orientations: ``(T, 4)`` unit quaternions ``[w, x, y, z]`` body to world,
            or ``(N, T, 4)`` for ``N`` recordings fitted together (one compiled
            program, a work queue in which each recording stops on its own:
            :mod:`rbjax.identification._queue`). ``None`` for a gyro-only
            recording (then ``body_rates`` is required and sets the batch
            shape): the torque-free Euler equations ``I ω̇ + ω × I ω = 0``
            fix the shape of ``I`` from body rates alone, ``body_torques``
            also its scale; the body frame at ``times[0]`` is taken as the
            world frame (``initial_orientation`` is the identity, and
            ``orientation_rms`` is NaN).
        body_rates: optional ``(T, 3)`` / ``(N, T, 3)`` gyro readings, body frame (rad/s).
        torques: optional ``(T, 3)`` / ``(N, T, 3)`` known world-frame torques
            about the centre of mass (N m), taken as linear in time between
            samples. With them the inertia is absolute (kg m²); without them only
            its shape is identifiable and the result is normalised to ``tr I = 1``
            (``FitResult.scale_fixed = False``). Needs ``orientations`` (a
            world-frame torque means nothing without the attitude).
        body_torques: optional ``(T, 3)`` / ``(N, T, 3)`` known torques in the
            body frame (N m, e.g. a reaction wheel's), linear in time between
            samples; with or without ``orientations``, instead of ``torques``
            (not both). They fix the scale like ``torques``.
        initial_inertia: optional ``(3, 3)`` starting guess (body frame); default:
            linear least squares on conservation of angular momentum.
        method: integrator (see :func:`rbjax.methods`); ``"rk4"`` recommended.
        segments: number of multiple-shooting segments; default about one per
            512 sample intervals and per ``4π`` (two turns) of recorded rotation,
            rounded up to a power of two, at least 1 and at most ``(T-1) // 8``.
        substeps: integrator steps per sample interval; default enough that no
            step turns more than 0.05 rad at the rate's running median over 7
            intervals (a glitched sample's spike does not count), rounded up to
            a power of two; 2 becomes
            4 for recordings of at most 256 intervals (throws: so that throws of
            different speeds share one compiled program).
        orientation_std, rate_std: noise standard deviations (rad, rad/s) that
            weight the residuals; default estimated from the data: the residuals
            of local quadratics in time over five samples, on the recording's own
            (possibly jittered) clock (:mod:`rbjax.identification._noise`), at least
            ``1e-7`` of the signal (4 eps in float32: what the fit's model reaches).
        continuity_weight: weight of segment joins relative to data residuals
            (a join gap of ``σ / continuity_weight`` costs as much as one
            ``σ`` data residual). Soft joins let segments drift apart and lose
            information (larger error and σ); from about 1000 on the joins act
            as constraints and σ is calibrated, while much stiffer joins slow
            the solver: hence the default 1000 (docs/fitting.md's table of
            ``benchmarks/fit_weight.py``).
        excitation_tol: relative singular value below which a direction of the
            linearised problem counts as unidentifiable (``ValueError``).
        rtol, atol, max_steps: Levenberg–Marquardt tolerances and step limit.
            The solve stops when an accepted step is within ``atol + rtol·|y|``
            and changes the residuals by less than ``atol + rtol·|r|``, or when
            a trial step's actual and predicted reductions of the sum of
            squares are both below ``rtol`` of it (MINPACK's ``ftol`` test) or
            below ``0.02 / (n - p)`` of it (``n`` residuals, ``p`` parameters):
            what is left would move the estimate by under ~0.14 of its standard
            error, which is all short, weakly determined recordings can say.
        check_gyro_frame: with ``body_rates``, compare them over windows of
            ~0.1 rad of rotation with the mean rates the orientations imply in
            the body frame, ``log(q_i⁻¹ ⊗ q_j) / (t_j - t_i)``, and in the world
            frame, ``log(q_j ⊗ q_i⁻¹) / (t_j - t_i)``; raise ``ValueError`` if
            the world-frame one fits more than 3x better (median misfit), the
            signature of a world-frame gyro (convert with
            ``rb.quat_rotate(rb.quat_conjugate(q), w)``). ``False`` skips it.
        gyro_bias: fit a constant body-frame gyro bias ``b`` (3 nuisance
            parameters, rad/s): the gyro residuals become
            ``(ω_sim + b - ω_meas) / σ_ω``. Needs ``body_rates``. Reported as
            ``FitResult.gyro_bias`` with ``gyro_bias_std``.
        gyro_rotation: fit a fixed rotation ``R_g = exp(ρ)`` between the gyro's
            frame and the frame of the recorded orientations (3 nuisance
            parameters, rad): the predicted gyro reading is ``R_gᵀ ω_body (+ b)``.
            Needs ``body_rates`` and ``orientations`` (without them the gyro
            frame simply is the body frame). Reported as
            ``FitResult.gyro_rotation`` (quaternion, gyro→body) with
            ``gyro_rotation_std`` (rad). Start: the identity, so the rotation
            should be small (≲ 0.3 rad); the world-frame gyro check
            (``check_gyro_frame``) runs on the unrotated gyro.
        accelerations: optional ``(T, 3)`` / ``(N, T, 3)`` accelerometer readings
            (body frame, m/s²) of an IMU at ``r`` from the centre of mass, in
            free flight (gravity is not sensed; torque-free only):
            ``a = ω̇ × r + ω × (ω × r) + b_a`` with ``ω̇ = -I⁻¹ (ω × I ω)`` from
            the model. Fits the lever arm ``r`` (m) and the bias ``b_a`` (m/s²),
            reported as ``FitResult.lever_arm``, ``accelerometer_bias`` and their σ.
        acceleration_std: its noise std (m/s²); default estimated from the data, as the others.
        loss: ``"squared"`` (least squares, the default), ``"huber"`` or
            ``"cauchy"``: a robust loss on each sample's residual 3-vector per
            sensor (``|r|`` in units of that sensor's σ), minimised by
            iteratively reweighted least squares (:mod:`rbjax.identification._robust`);
            glitches get small weights instead of dragging the fit.
            ``FitResult.robust_weights`` holds the final weights and
            ``FitResult.outliers`` the samples beyond ``2 loss_scale`` σ. σ comes
            from the weighted fit, ``s² (JᵀWJ)⁻¹`` with the data count
            ``Σ 3 w``.
        loss_scale: ``c`` of the robust loss, in σ: Huber is quadratic
            within ``c``, weight ``c / |r|`` beyond; Cauchy weighs
            ``1 / (1 + (|r|/c)²)``. The default 3 leaves Gaussian residual
            3-vectors (``|r|`` mostly < 3) almost untouched.
        joint: for several recordings (a list, or a batch ``(N, T, ...)``) of one
            body, e.g. the throws of one phone: fit ONE inertia (and one gyro
            bias, gyro rotation, lever arm, accelerometer bias where enabled) to
            all of them, each recording keeping its own start states (its
            segments' ``δ_s``, ``ω_s``; the recordings are not joined to each
            other). The residuals are those of the separate fits stacked, so
            ``moment_std`` comes from the joint covariance: about ``1/√N`` of
            one recording's for ``N`` alike. The result has no batch axis; per
            recording ``member_rms``, ``member_chi2``, ``member_dof`` and
            ``member_pvalue`` say which one disagrees, and one that cannot be
            fitted (too short, non-finite, unexcited) is left out and named in
            ``member_errors``. Recordings are packed with one intervals-per-segment
            and ``substeps`` (the longest's, the largest), each with its own
            number of segments: one compiled program per bucket of the total
            number of segments (1, 2, 3, 4, 6, 8, 12, 16, ...: padded with
            blank segments) and padded length, so new throws of lengths in the
            same buckets, and 5 or 6 throws alike, reuse it.
            ``robust_weights`` and ``outliers`` run over the recordings' samples
            one after the other. ``False`` (default): each recording is fitted on its own.
        drag: air drag, opt-in: ``"linear"`` adds the body-frame damping torque
            ``τ_b = -c₁ ω`` to Euler's law, ``"quadratic"`` ``τ_b = -(c₁ + c₂ |ω|) ω``
            (``ω`` body frame, rad/s; ``c₁`` N m s, ``c₂`` N m s²), with the
            coefficients fitted (1 or 2 shared parameters, starting next to 0) and
            reported as ``FitResult.drag``, ``drag_std``. Never negative: each
            coefficient is ``tr I · (p + sqrt(p² + b²)) / 2`` of a free parameter
            ``p`` (``b = 1e-3`` in ``c / tr I``), so a fit of data without drag ends at
            ``c ≈ 0`` instead of a negative, energy-adding one that
            :class:`rbjax.QuadraticDrag` would refuse. One scalar each, the
            same about every axis: per-axis coefficients would add 3 or 6
            parameters that a 40-100 sample throw cannot separate from the
            inertia's own asymmetry. What the data can tell: (1) without
            torques only ``c / tr I`` (``I ω̇ + ω × I ω = -(c₁ + c₂|ω|) ω`` is
            unchanged by ``(I, c) → (λI, λc)``), which is what is reported; (2)
            ``c₁`` from ``c₂`` only as far as ``|ω|`` varies within a throw
            (nutation, decay): both act as one rate ``c₁ + c₂|ω|``, so on a
            near-steady spin their σ grow large and strongly correlated while the
            inertia stays determined; (3) a body spinning about a principal axis
            ``k`` shows drag only as the decay rate ``(c₁ + c₂|ω|) / I_k`` (and its
            shape is unidentifiable anyway). Without ``drag`` a real throw's loss
            of ``|L|`` (~15% in 1 s) makes the χ² test fail
            (``model_consistent = False``). Needs ``method="rk4"``; not with
            ``accelerations`` (their model is torque-free). ``FitResult.delta_bic``
            says whether the data support it (and the diagnosis ends with it).
            ``"auto"``: fit without drag and with each law and keep the fit of
            the smallest BIC (the ``delta_bic`` statistic: ``_auto_drag``), with
            ``drag_axes=True`` the per-axis forms among them; one model for all the
            recordings of a batch or list. Three to five fits' time.
        drag_axes: with ``drag``, fit its coefficients per body axis instead of one
            shared by all: ``τ_b,a = -c₁ₐ ω_a`` (``"linear"``, 3 coefficients) or
            ``τ_b,a = -(c₁ₐ + c₂ₐ |ω|) ω_a`` (``"quadratic"``, 6), ``a = x, y, z`` of the
            body frame (the gyro's), units and scale as ``drag``'s, each ``≥ 0`` through
            the same map. A flag beside ``drag`` rather than more names for it: the law
            (linear, quadratic) and its symmetry (isotropic, per axis) are separate
            choices. Reported as ``FitResult.drag_per_axis`` ``(2, 3)`` with
            ``drag_per_axis_std`` (``drag`` is then NaN); ``delta_bic`` compares it with
            no drag and with one coefficient for all axes. The isotropic force models
            (:class:`rbjax.LinearDrag`, :class:`rbjax.QuadraticDrag`) cannot represent
            it, and the plotting model of ``python -m rbjax fit --plot`` refuses one whose
            axes differ, in words. Works with lists and ``joint=True``.
        gyro_scale: fit one scale error ``s`` common to the gyro's three axes (1
            nuisance parameter, dimensionless): the predicted reading is
            ``(1 + s) R_gᵀ ω + b`` (``R_g``, ``b`` where fitted). Needs ``body_rates``.
            Identifiable from gyro-only torque-free data because the Euler equations
            are quadratic in ``ω``: a rate scaled by ``1 + s`` is a motion running
            ``1 + s`` times faster, which no inertia reproduces at the recorded
            sample times (measured: σ(s) 0.1-0.6% on a 2 s tumble at 200 Hz, 0.01 rad/s
            noise; docs/fitting.md). A scale per axis is not identifiable from
            torque-free motion (it trades against the inertia's shape) and is not
            offered. Reported as ``FitResult.gyro_scale`` with ``gyro_scale_std``.
        rotor_rates: a gyrostat (a body carrying spinning rotors, e.g. a thrown
            IMU with a flywheel): the rotors' measured rates ``Ω_k`` relative to
            the body (rad/s), at the recording's sample times: ``(T,)`` for one
            rotor (``rotor_axis`` ``(3,)``) or ``(T, k)`` for ``k`` rotors
            (``rotor_axis`` ``(k, 3)``), with a batch's leading ``N`` (or a list
            of such arrays for a list of recordings). The model's body-frame
            angular momentum is ``I ω + h`` with ``h = Σ_k J_k Ω_k a_k`` (body
            frame), so torque-free ``d(I ω + h)/dt = -ω × (I ω + h)``, i.e.
            ``I ω̇ = -ω × (I ω + h) - ḣ``; the fit integrates it as ``(q, L)``
            with world ``L = R (I ω + h)`` constant and ``ω = I⁻¹ (Rᵀ L - h)``, so
            ``ḣ`` is never needed there. ``h`` is taken as linear in time between
            samples: the integrator's steps never straddle a sample, so RK4 keeps
            its order on that interpolant, and a piecewise-linear one neither
            overshoots a quantised or noisy rate nor asks the user to filter or
            differentiate it (its error for a smooth rate is ``dt² |Ω''| / 8``:
            about 1e-6 of the peak for the 170 → 1300 rad/s spin-up of a thrown
            flywheel at 4 kHz). The accelerometer's ``ω̇`` reads ``ḣ`` as the mean
            of the interpolant's slopes on either side of each sample. A rotor
            fixes the scale: the inertia is no longer normalised to ``tr I = 1``
            (``scale_fixed``), but in kg m² with ``rotor_inertia`` given and in
            units of ``J`` without it (``FitResult.inertia_units``). The rotor's
            rate is taken as exact: its rounding error ``e`` enters the body rate
            as ``-I⁻¹ J e a``, which σ does not count (measured on issue 58's
            device, 200 throws of 2,001 samples at 4 kHz: 95.0% of moments within
            2σ with the exact rate, 91.5% with it in 5 rad/s steps; 85% at 1 kHz;
            benchmarks/results/fit_rotor_2026-12-07.md). Needs ``method="rk4"``; works with ``orientations``,
            ``gyro_bias``, ``gyro_rotation``, ``accelerations``, ``drag``, lists
            and ``joint=True``.
        rotor_axis: ``(3,)`` or ``(k, 3)`` the rotors' unit spin axes ``a_k`` in
            the body frame (the gyro's / IMU's frame, as the inertia); the sign
            says which way a positive ``Ω_k`` turns (right-handed).
        rotor_inertia: ``J`` (kg m²), a scalar or ``(k,)``: the rotors' axial
            inertias, each > 0. Default: ``J = 1`` (all rotors alike), and the
            fitted inertia is in units of ``J`` (``inertia_units = "rotor inertia
            J"``; multiply by ``J`` in kg m² for kg m²); given, the inertia is in
            kg m² (``"kg m^2"``). ``I`` is the whole device's, the rotors included
            as rigid masses.

    Returns:
        :class:`FitResult` (with a leading ``N`` axis for batched input, none with ``joint=True``);
        ``inertia_units`` says whether its inertia is in kg m², in units of the rotor's ``J`` or
        normalised to ``tr I = 1``. In a
        batch or list, a recording that cannot be fitted (the ``ValueError`` a
        single fit of it would raise: too little excitation, non-finite data,
        too few samples) does not stop the others: its fields are NaN,
        ``failed[i]`` is ``True`` and ``member_errors`` names it with the reason.
        Only when no recording can be fitted does the call raise.

    Raises:
        TypeError: before any tracing, for options of the wrong type (e.g. a
            float or bool ``max_steps``/``segments``/``substeps``), half-precision
            (float16, bfloat16) or complex data, or when called inside ``jax.jit``
            (``vmap``, ``grad``): fitting is not jittable (it validates in NumPy and
            compiles its own solver); call it outside, on concrete arrays.
        ValueError: before any tracing, for noise levels, ``continuity_weight``,
            tolerances that are not finite and > 0; ``max_steps``, ``segments``
            or ``substeps`` < 1; all-zero ``torques`` (they cannot fix the scale:
            omit ``torques=``); non-monotonic or non-finite times, non-unit
            quaternions, shape mismatches, too few samples for the parameters,
            or too little excitation (naming the unidentifiable directions), or
            ``body_rates`` that look world-frame (``check_gyro_frame``).
    """
    if isinstance(drag, str) and drag == "auto":
        call = dict(locals())
        return _auto_drag({k: v for k, v in call.items() if k in _ARGUMENTS})
    arrays = {
        "orientations": orientations,
        "body_rates": body_rates,
        "torques": torques,
        "body_torques": body_torques,
        "accelerations": accelerations,
    }
    _check_list_of_recordings(times)
    if isinstance(times, Recording) or (
        isinstance(times, (list, tuple)) and len(times) > 0 and all(isinstance(r, Recording) for r in times)
    ):
        given = [k for k, v in arrays.items() if v is not None]
        if given:
            raise TypeError(
                f"fit_inertia: the first argument is a Recording, which carries the data; do not also pass {given} "
                "(build the Recording with them instead)"
            )
        times, data = to_fit_arguments(times)
        arrays = {k: data[k] for k in arrays}
        if data["rotor_rates"] is not None:
            if rotor_rates is not None:
                raise TypeError(
                    "fit_inertia: the Recording carries rotor_rates; do not also pass rotor_rates= "
                    "(dataclasses.replace(rec, rotor_rates=...) changes them)"
                )
            if rotor_axis is None:
                # a ValueError, not the TypeError of a missing keyword: the data ask for it
                raise ValueError(
                    "fit_inertia: the Recording carries rotor_rates, so rotor_axis is needed: the rotor's spin "
                    "axis in the body (gyro) frame, e.g. rotor_axis=[0, 0, -1] (and rotor_inertia=J in kg m² for "
                    "an inertia in kg m²); a fit that ignores the rotor's momentum is wrong, but "
                    "dataclasses.replace(rec, rotor_rates=None) drops it"
                )
            rotor_rates = data["rotor_rates"]
    _refuse_empty(times)
    main = arrays["orientations"] if arrays["orientations"] is not None else arrays["body_rates"]
    h = rotor_arrays(times, main, rotor_rates, rotor_axis, rotor_inertia)
    inertia_units = units(
        rotor=h is not None,
        rotor_inertia_given=rotor_inertia is not None,
        torques=arrays["torques"] is not None or arrays["body_torques"] is not None,
    )
    if h is not None:
        arrays["rotor_momentum"] = h
    options = dict(
        initial_inertia=initial_inertia,
        method=method,
        segments=segments,
        substeps=substeps,
        orientation_std=orientation_std,
        rate_std=rate_std,
        continuity_weight=continuity_weight,
        excitation_tol=excitation_tol,
        rtol=rtol,
        atol=atol,
        max_steps=max_steps,
        check_gyro_frame=check_gyro_frame,
        gyro_bias=gyro_bias,
        gyro_rotation=gyro_rotation,
        acceleration_std=acceleration_std,
        loss=loss,
        loss_scale=loss_scale,
        drag=drag,
        drag_axes=drag_axes,
        gyro_scale=gyro_scale,
    )
    if not isinstance(joint, (bool, np.bool_)):
        raise TypeError(f"fit_inertia: joint must be True or False, got {type(joint).__name__}")
    if joint:
        members = ragged_members(times, arrays) if is_ragged(times) else batch_members(times, arrays)
        if members is None:
            raise ValueError(
                "fit_inertia: joint=True fits several recordings of one body together; pass a list of "
                "recordings (or a batch (N, T, ...)), or leave joint=False for one recording"
            )
        return _with_units(fit_joint(members, options), inertia_units)
    if is_ragged(times):
        return _with_units(fit_members(ragged_members(times, arrays), options), inertia_units)
    try:
        return _with_units(fit_regular(times, arrays, options), inertia_units)
    except ValueError:
        members = batch_members(times, arrays)
        if members is None:  # one recording, or a batch-wide problem: the message stands
            raise
        return _with_units(fit_members(members, options), inertia_units)


# fit_inertia's arguments, for drag="auto"'s refits
_ARGUMENTS = tuple(inspect.signature(fit_inertia).parameters)


def _auto_drag(call: dict) -> FitResult:
    """``fit_inertia(..., drag="auto")``: the fit, among no drag, ``"linear"`` and ``"quadratic"`` (with
    ``drag_axes=True`` also their per-axis forms), of the smallest BIC.

    ``BIC_m = χ²_m / (s² τ) + k_m ln(n / τ)``: ``χ²_m`` the candidate's whitened sum of squares (every
    candidate's rows are whitened by the same noise levels, estimated from the data or given),
    ``k_m`` its drag coefficients, ``s²`` (residual variance per degree of freedom), ``τ`` (largest
    correlation length, ≥ 1) and ``n`` (data rows) of the largest candidate: the likelihood ratio
    in that fit's variance over the effective sample size, as ``FitResult.delta_bic``. For a batch
    or list, one model for all its recordings: the sum of their BICs (those fitted in every candidate).
    """
    axes = call.pop("drag_axes")
    if not isinstance(axes, (bool, np.bool_)):
        raise TypeError(f"fit_inertia: drag_axes must be True or False, got {type(axes).__name__}")
    laws = [(None, False), ("linear", False), ("quadratic", False)]
    laws += [("linear", True), ("quadratic", True)] if axes else []
    sizes = [0, 1, 2, 3, 6][: len(laws)]
    fits = [fit_inertia(**{**call, "drag": law, "drag_axes": bool(per_axis)}) for law, per_axis in laws]
    big = fits[-1]
    chi2 = np.stack([np.asarray(f.chi2, np.float64) for f in fits])  # (m, *N)
    s2 = np.asarray(big.chi2, np.float64) / np.asarray(big.dof, np.float64)
    tau = np.maximum(np.nan_to_num(np.nanmax(np.asarray(big.correlation_length, np.float64), -1), nan=1.0), 1.0)
    n = np.asarray(big.dof, np.float64) + sizes[-1]
    bic = chi2 / (s2 * tau) + np.asarray(sizes, np.float64).reshape((-1,) + (1,) * s2.ndim) * np.log(n / tau)
    bic = bic.reshape(len(fits), -1)
    usable = np.all(np.isfinite(bic), 0)
    if not np.any(usable):
        return big
    return fits[int(np.argmin(bic[:, usable].sum(1)))]


def _with_units(res: FitResult, inertia_units: str) -> FitResult:
    """``res`` saying what its inertia's numbers are (``FitResult.inertia_units``)."""
    return replace(res, inertia_units=inertia_units)


def _refuse_empty(times: Any) -> None:
    """``ValueError`` for a recording (or a member of a list of them) with no samples."""
    members = list(times) if isinstance(times, (list, tuple)) else [times]
    for k, t in enumerate(members):
        shape = np.shape(t)
        if shape and shape[-1] == 0:
            which = f"recording {k} has" if isinstance(times, (list, tuple)) else "the recording has"
            raise ValueError(
                f"fit_inertia: {which} no samples (times of shape {shape}); a fit needs the samples of a free "
                "flight: check the file or the window it was cut to (rb.find_throws)"
            )


def _check_list_of_recordings(times: object) -> None:
    """``TypeError`` for the two lists a user of :func:`rbjax.find_throws` may pass by mistake."""
    if not isinstance(times, (list, tuple)) or not times:
        return
    remedy = "pass the recordings themselves: [rec.window(t0, t1) for t0, t1 in windows]"
    is_rec = [isinstance(r, Recording) for r in times]
    if any(is_rec) and not all(is_rec):
        bad = is_rec.index(False)
        raise TypeError(
            f"fit_inertia: times is a list that mixes Recordings with other things (item {bad} is a "
            f"{type(times[bad]).__name__}); {remedy}"
        )
    windows = all(
        isinstance(w, tuple) and len(w) == 2 and all(isinstance(x, (int, float, np.number)) for x in w) for w in times
    )
    if windows:
        raise TypeError(f"fit_inertia: times is a list of (t0, t1) pairs, as rb.find_throws returns; {remedy}")
