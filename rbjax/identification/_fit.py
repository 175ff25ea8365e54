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

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from .._pytree import new_unchecked, replace
from .._typing import ArrayLike
from . import _robust
from ._checks import check_arrays, check_options
from ._model import model_residuals
from ._problem import join_problems, prepare
from ._queue import run_queue, stage_widths
from ._recording_data import Recording, to_fit_arguments
from ._result import FitResult, summarise
from ._solver import LMMember

__all__ = ["fit_inertia"]


@functools.cache
def _fit_batch_jit(backend: str):
    """The jitted solver for ``backend``; made on first use, so importing rbjax starts no backend.

    On CPU it is compiled with XLA's classic loop emitters instead of the MLIR
    fusion emitters: for the 4 s @ 1 kHz fit that halved the compile (10.6 → 5.1
    CPU-s) and made the solve faster too (3.1 → 2.0 CPU-s), same result.
    """
    options = {"xla_cpu_use_fusion_emitters": False} if backend == "cpu" else None
    static = ("model_opts", "loss", "rtol", "atol", "max_steps", "unbatch")
    return jax.jit(_fit_batch, static_argnames=static, compiler_options=options)


def _fit_batch(y0, data, *, model_opts, loss, rtol, atol, max_steps, unbatch):
    """Fit ``N`` recordings (leading axes of ``y0``, ``data``); ``model_opts``: sorted ``(name, value)`` pairs.

    Each recording is one Levenberg–Marquardt solve (:class:`._solver.LMMember`),
    repeated with new weights for a robust loss (IRLS, :mod:`._robust`). A batch
    runs through a work queue (:mod:`._queue`): every recording stops on its own
    instead of being stepped until the slowest one stops.
    """
    opts = dict(model_opts)
    member = lambda tree, i: jax.tree.map(lambda a: a[i], tree)
    # one recording keeps J in its slot, so the model is compiled once (see `summary`)
    lm = LMMember(functools.partial(model_residuals, **opts), rtol, atol, max_steps, keep_jacobian=unbatch)
    kw = {k: opts[k] for k in _SUMMARY_OPTS}
    outlier_weight = _robust.outlier_weight(loss)
    zero = jnp.zeros((), jnp.int32)

    def start(y, d, round=zero, total=zero):
        return dict(lm.start(y, d), round=round, total=total)

    def retire(slot):
        """``(again, next round's slot, solution)`` of a stopped solve."""
        d, y, total = slot["data"], slot["y"], slot["total"] + slot["steps"]
        rw = d["seg"]["rw"]
        out = dict(y=y, converged=lm.converged(slot), iterations=total, rw=rw)
        if lm.keep_jacobian:
            out.update(r=slot["r"], J=slot["J"])
        if loss == "squared":
            return jnp.array(False), slot, out
        rw_new = _robust.weights(slot["r"], rw, loss, d["loss_scale"])
        again = _robust.another_round(rw, rw_new, slot["round"])
        restarted = start(y, {**d, "seg": {**d["seg"], "rw": rw_new}}, slot["round"] + 1, total)
        return again, restarted, out

    def summary(sol, d):
        """FitResult fields at the solution, with its final weights.

        A batch's slots keep ``JᵀJ``, not ``J`` (:class:`._solver.LMMember`), and
        the covariance is formed from ``J``'s SVD, so there the model is
        re-evaluated at the solution. A single solve keeps its ``J``: a second
        model in the program doubled the first call's compile (4.2 → 6.5 s on
        4 s @ 1 kHz).
        """
        d = {**d, "seg": {**d["seg"], "rw": sol["rw"]}}
        r, J = (sol["r"], sol["J"]) if "J" in sol else lm.model(sol["y"], d)
        out = summarise(sol["y"], r, J, d, sol["converged"], sol["iterations"], **kw, outlier_weight=outlier_weight)
        return dict(out, robust_weights=sol["rw"])

    if not unbatch:
        sols = run_queue(
            y0.shape[0],
            lambda i: start(y0[i], member(data, i)),
            lm.advance,
            lm.running,
            retire,
            widths=stage_widths(y0.shape[0], first=_SLOTS),
            steps_per_round=_STEPS_PER_ROUND,
        )
        # in slices of the queue's width: the memory of one model evaluation per slice
        return jax.lax.map(lambda a: summary(*a), (sols, data), batch_size=min(_SLOTS, y0.shape[0]))
    # one recording: no queue (and no vmap, whose batching of the solver's loops doubles tracing)

    def body(c):
        slot = jax.lax.while_loop(lm.running, lm.advance, c[1])
        return retire(slot)

    first = start(y0[0], member(data, 0))
    out0 = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(lambda s: retire(s)[2], first))
    return summary(jax.lax.while_loop(lambda c: c[0], body, (jnp.array(True), first, out0))[2], member(data, 0))


_SUMMARY_OPTS = ("scale_fixed", "use_rates", "use_orientations", "layout")
# Levenberg–Marquardt steps per round of the queue between retiring and refilling slots
_STEPS_PER_ROUND = 4
# the queue's width: per recording, the model of 64 slots of 1 s @ 200 Hz was 1.25-1.5x cheaper
# than that of 128 (the flow's working set stays in cache), and narrower ones pay fixed costs
_SLOTS = 64


# ----------------------------------------------------------------------------------------
# Public entry point


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
) -> FitResult:
    """Fit a body-frame inertia tensor to a recording of free (or known-torque) rotation.

    Model: ``d(R I ω)/dt = τ`` (Euler's law, world frame), ``q̇ = ½ q ⊗ (0, ω)``
    with ``ω`` in the body frame, integrated by :func:`rbjax.step` (``method``)
    between the samples. See the module docstring for residuals and solver.

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
            step turns more than 0.05 rad.
        orientation_std, rate_std: noise standard deviations (rad, rad/s) that
            weight the residuals; default estimated from second differences of
            the data (valid for smooth motion sampled finely).
        continuity_weight: weight of segment joins relative to data residuals
            (a join gap of ``σ / continuity_weight`` costs as much as one
            ``σ`` data residual). Soft joins let segments drift apart and lose
            information; measured on 4 s @ 1 kHz with 1e-3 rad + 0.01 rad/s noise
            (5 draws, ``benchmarks/fit_weight.py``): mean error 1.7e-4 / 5.4e-5 /
            4.5e-5 / 4.5e-5 at weights 10 / 100 / 1000 / 10 000, reported σ
            calibrated (rms z ≈ 1) from 1000 on, 4 Levenberg–Marquardt steps
            up to 1000 and 4-8 at 10 000 (stiff); hence the default 1000.
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
        acceleration_std: its noise std (m/s²); default estimated from second differences.
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
            number of segments: one compiled program per total number of
            segments and padded length, so new throws of lengths in the same
            buckets reuse it (a different number of throws compiles anew).
            ``robust_weights`` and ``outliers`` run over the recordings' samples
            one after the other. ``False`` (default): each recording is fitted on its own.
        drag: air drag, opt-in: ``"linear"`` adds the body-frame damping torque
            ``τ_b = -c₁ ω`` to Euler's law, ``"quadratic"`` ``τ_b = -(c₁ + c₂ |ω|) ω``
            (``ω`` body frame, rad/s; ``c₁`` N m s, ``c₂`` N m s²), with the
            coefficients fitted (1 or 2 shared parameters, starting at 0) and
            reported as ``FitResult.drag``, ``drag_std``. One scalar each, the
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
            ``accelerations`` (their model is torque-free).

    Returns:
        :class:`FitResult` (with a leading ``N`` axis for batched input, none with ``joint=True``). In a
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
    arrays = dict(
        orientations=orientations,
        body_rates=body_rates,
        torques=torques,
        body_torques=body_torques,
        accelerations=accelerations,
    )
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
    )
    if not isinstance(joint, (bool, np.bool_)):
        raise TypeError(f"fit_inertia: joint must be True or False, got {type(joint).__name__}")
    if joint:
        members = _ragged_members(times, arrays) if _is_ragged(times) else _batch_members(times, arrays)
        if members is None:
            raise ValueError(
                "fit_inertia: joint=True fits several recordings of one body together; pass a list of "
                "recordings (or a batch (N, T, ...)), or leave joint=False for one recording"
            )
        return _fit_joint(members, options)
    if _is_ragged(times):
        return _fit_members(_ragged_members(times, arrays), options)
    try:
        return _fit_regular(times, arrays, options)
    except ValueError:
        members = _batch_members(times, arrays)
        if members is None:  # one recording, or a batch-wide problem: the message stands
            raise
        return _fit_members(members, options)


def _fit_regular(times, arrays, options) -> FitResult:
    """:func:`fit_inertia` on one recording or a regular batch ``(N, T, ...)``: any bad input raises."""
    stds = {k: options[k] for k in ("initial_inertia", "orientation_std", "rate_std", "acceleration_std")}
    check_arrays(times=times, **arrays, **stds)
    check_options(**{k: options[k] for k in _OPTION_NAMES})
    return _solve(_fit_regular_check(times, arrays, options), options)


_OPTION_NAMES = (
    "orientation_std",
    "rate_std",
    "continuity_weight",
    "excitation_tol",
    "rtol",
    "atol",
    "max_steps",
    "segments",
    "substeps",
    "loss",
    "loss_scale",
    "acceleration_std",
)


def _solve(prob, options, sample_weights: bool = True) -> FitResult:
    """Run the compiled solver on a packed :class:`._problem.Problem`; ``options``: loss, tolerances.

    ``sample_weights=False`` leaves ``robust_weights`` as the solver's per-segment
    rows (``(N, S, B, K+1)``) for the caller to map member by member.
    """
    loss = options["loss"]
    data = dict(prob.data, loss_scale=np.full(prob.y0.shape[0], float(options["loss_scale"]), prob.y0.dtype))
    out = _fit_batch_jit(jax.default_backend())(
        prob.y0,
        data,
        model_opts=tuple(sorted(prob.static.items())),
        loss=loss,
        rtol=float(options["rtol"]),
        atol=float(options["atol"]),
        max_steps=int(options["max_steps"]),
        unbatch=not prob.batched,
    )
    rw = np.asarray(out.pop("robust_weights"))
    if sample_weights:
        out["robust_weights"], out["outliers"] = _sample_weights(prob, rw, _robust.outlier_weight(loss))
    else:
        out["robust_weights"], out["outliers"] = jnp.asarray(rw), jnp.zeros(rw.shape[0], bool)
    out["failed"] = jnp.zeros(prob.y0.shape[0] if prob.batched else (), bool)
    return new_unchecked(
        FitResult,
        **out,
        scale_fixed=prob.static["scale_fixed"],
        segments=prob.segments,
        member_errors=(),
        **_NOT_JOINT,
    )


# the static fields of a FitResult of recordings fitted one by one (see FitResult.joint)
_NOT_JOINT = dict(joint=False, member_rms=(), member_chi2=(), member_dof=(), member_pvalue=())


def _is_ragged(times) -> bool:
    """``times`` given as a list (or tuple) of 1-D arrays: one per recording, lengths free."""
    return isinstance(times, (list, tuple)) and len(times) > 0 and all(np.ndim(t) == 1 for t in times)


_PER_MEMBER_NDIM = {"orientations": 3, "body_rates": 3, "torques": 3, "body_torques": 3, "accelerations": 3}


def _ragged_members(times, arrays):
    """Per-recording ``(times, arrays)`` of a ragged list; ``ValueError`` if the lists do not match."""
    n = len(times)
    for name, a in arrays.items():
        if a is not None and not (isinstance(a, (list, tuple)) and len(a) == n):
            raise ValueError(
                f"fit_inertia: times is a list of {n} recordings, so {name} must be a list of {n} arrays "
                f"(one per recording, each of its own length), got {type(a).__name__}"
                + (f" of length {len(a)}" if isinstance(a, (list, tuple)) else "")
            )
    return [(times[i], {k: None if a is None else a[i] for k, a in arrays.items()}) for i in range(n)]


def _batch_members(times, arrays):
    """Per-recording ``(times, arrays)`` of a regular batch ``(N, T, ...)``; ``None`` for a single recording."""
    main = arrays["orientations"] if arrays["orientations"] is not None else arrays["body_rates"]
    if main is None or np.ndim(main) != 3:
        return None
    main = np.asarray(main)
    if np.ndim(times) != 1 or main.shape[1] != np.shape(times)[0]:
        return None
    for k, a in arrays.items():  # a shape that does not match the batch: the batch-wide message stands
        if a is not None and np.ndim(a) == _PER_MEMBER_NDIM[k] and np.shape(a)[0] != main.shape[0]:
            return None
    out = []
    for i in range(main.shape[0]):
        member = {}
        for k, a in arrays.items():
            a = None if a is None else np.asarray(a)
            member[k] = a[i] if a is not None and a.ndim == _PER_MEMBER_NDIM[k] else a
        out.append((times, member))
    return out


def _fit_members(members, options) -> FitResult:
    """Fit recordings one by one (ragged) or as one batch (equal lengths), setting bad ones aside.

    Each member is checked first (:func:`._problem.prepare`, NumPy); one that raises
    ``ValueError`` (too little excitation, non-finite data, too few samples, ...) gets
    NaN results, ``failed = True`` and its reason in ``FitResult.member_errors``; the
    others are fitted. Members of equal length share one batched solve; ragged ones
    with the same number of segments are padded to the longest and fitted as one
    batch too (:func:`_fit_padded`). Arrays whose length varies (``residuals``, ``robust_weights``,
    ``outliers``) are padded with NaN (``False``) to the longest.
    """
    probs, errors, good = _check_members(members, options)
    lengths = {np.shape(members[i][0])[0] for i in good}
    results: dict[int, FitResult] = {}
    if len(lengths) == 1 and all(members[i][0] is members[good[0]][0] for i in good):
        t = members[good[0]][0]
        stacked = {k: _stack_or_share([members[i][1][k] for i in good]) for k in _PER_MEMBER_NDIM}
        batch = _fit_regular(t, stacked, options)
        for j, i in enumerate(good):
            results[i] = jax.tree.map(lambda a, j=j: a[j], batch)
    else:
        results = _fit_padded(members, probs, options)
    return _stack_results(results, len(members), errors)


def _check_members(members, options):
    """``(problems, errors, good)``: each member packed alone, or its ``ValueError``'s message.

    Raises only when no member can be fitted (one message when all share it).
    """
    check_options(**{k: options[k] for k in _OPTION_NAMES})  # an option's error is raised once
    errors: dict[int, str] = {}
    probs = {}
    for i, (t, arrays) in enumerate(members):
        try:
            probs[i] = _fit_regular_check(t, arrays, options)
        except ValueError as e:
            errors[i] = str(e)
    good = [i for i in range(len(members)) if i not in errors]
    if not good:
        reasons = list(dict.fromkeys(errors.values()))
        if len(reasons) == 1:  # the same for all (an option, a shared array): say it once
            raise ValueError(reasons[0])
        listed = list(errors.items())
        raise ValueError(
            f"fit_inertia: none of the {len(members)} recordings can be fitted: "
            + "; ".join(f"recording {i}: {msg}" for i, msg in listed[:5])
            + (f"; and {len(listed) - 5} more" if len(listed) > 5 else "")
        )
    return probs, errors, good


def _fit_joint(members, options) -> FitResult:
    """One inertia for all members (:func:`._problem.join_problems`); bad members left out and named."""
    probs, errors, good = _check_members(members, options)
    K = max(probs[i].data["seg"]["dt"].shape[-1] for i in good)
    substeps = max(probs[i].static["substeps"] for i in good)  # more steps only add accuracy
    packed = [
        _fit_regular_check(
            members[i][0], members[i][1], options, segments=probs[i].segments, substeps=substeps, pad_intervals=K
        )
        for i in good
    ]
    prob = join_problems(packed)
    res = _solve(prob, options)
    # per member: its segments' data rows (segment-major, as the model lays them out)
    seg = prob.data["seg"]
    S, K1 = seg["rw"].shape[1], seg["rw"].shape[-1]
    blocks = len(prob.sensors)
    r = np.asarray(res.residuals)[: S * blocks * K1 * 3].reshape(S, blocks, K1, 3)
    valid = np.concatenate([seg["first"][0][:, None], seg["mask"][0]], 1)  # (S, K+1)
    n_all = 3 * blocks * valid.sum()
    n_shared = prob.static["layout"].shared
    s2 = float(res.residual_ratio) ** 2
    stats = {}
    start = 0
    for i, p in zip(good, packed):
        part = slice(start, start + p.segments)
        start += p.segments
        chi2 = float(np.sum(r[part] ** 2))
        n_i = 3 * blocks * float(valid[part].sum())
        dof = n_i - (6 - float(p.data["n_unused"][0])) - n_shared * n_i / n_all
        # against the joint fit's residual level s² (not the estimated noise levels, which the
        # motion's own second differences inflate on short throws): which throw stands out
        ratio = chi2 / (dof * s2)
        pval = float(jax.scipy.special.gammaincc(dof / 2, ratio * dof / 2))
        stats[i] = (float(np.sqrt(ratio)), chi2, dof, pval)
    nan4 = (np.nan,) * 4
    per = [stats.get(i, nan4) for i in range(len(members))]
    return replace(
        res,
        member_errors=tuple(f"recording {i}: {msg}" for i, msg in sorted(errors.items())),
        joint=True,
        member_rms=tuple(x[0] for x in per),
        member_chi2=tuple(x[1] for x in per),
        member_dof=tuple(x[2] for x in per),
        member_pvalue=tuple(x[3] for x in per),
    )


def _stack_or_share(values):
    """The members' arrays as one batch array; one shared array (the same object) passed as is."""
    if values[0] is None:
        return None
    if len(values) > 1 and all(v is values[0] for v in values):
        return values[0]
    return np.stack([np.asarray(v) for v in values])


def _fit_regular_check(t, arrays, options, **fixed):
    """:func:`fit_inertia`'s checks and packing of one recording (NumPy only, nothing compiled).

    ``fixed``: ``segments``, ``substeps``, ``pad_intervals`` overriding the options.
    """
    check_arrays(times=t, **arrays)
    options = {**options, **{k: v for k, v in fixed.items() if k != "pad_intervals"}}
    return prepare(
        t,
        arrays["orientations"],
        arrays["body_rates"],
        arrays["torques"],
        initial_inertia=options["initial_inertia"],
        method=options["method"],
        segments=options["segments"],
        substeps=options["substeps"],
        orientation_std=options["orientation_std"],
        rate_std=options["rate_std"],
        continuity_weight=options["continuity_weight"],
        excitation_tol=options["excitation_tol"],
        check_gyro_frame=bool(options["check_gyro_frame"]),
        gyro_bias=options["gyro_bias"],
        body_torques=arrays["body_torques"],
        gyro_rotation=options["gyro_rotation"],
        accelerations=arrays["accelerations"],
        acceleration_std=None if options["acceleration_std"] is None else float(options["acceleration_std"]),
        pad_intervals=fixed.get("pad_intervals"),
        drag=options["drag"],
    )


def _fit_padded(members, probs, options) -> dict:
    """Fit ragged recordings in groups that share one compiled program: ``{index: FitResult}``.

    Recordings with the same number of segments (their default, or the option) are
    packed with the intervals per segment of the group's longest (the padding is
    masked: ``dt = 0``, no residuals) and the group's largest ``substeps``, stacked
    and fitted as one batch.
    """
    groups: dict = {}
    for i, prob in probs.items():
        groups.setdefault(prob.segments, []).append(i)
    out = {}
    for S, idx in groups.items():
        K = max(probs[i].data["seg"]["dt"].shape[-1] for i in idx)
        substeps = max(probs[i].static["substeps"] for i in idx)  # more steps only add accuracy
        packed = {
            i: _fit_regular_check(members[i][0], members[i][1], options, segments=S, substeps=substeps, pad_intervals=K)
            for i in idx
        }
        if len(idx) == 1:
            i = idx[0]
            out[i] = _solve(packed[i], options)
            continue
        first = packed[idx[0]]
        batch = first._replace(
            y0=np.concatenate([packed[i].y0 for i in idx]),
            data=jax.tree.map(lambda *a: np.concatenate(a), *[packed[i].data for i in idx]),
            batched=True,
        )
        res = _solve(batch, options, sample_weights=False)
        rw = np.asarray(res.robust_weights)
        for j, i in enumerate(idx):
            one = jax.tree.map(lambda a, j=j: a[j], res)
            w, o = _sample_weights(packed[i], rw[j], _robust.outlier_weight(options["loss"]))
            fields = {f.name: getattr(one, f.name) for f in dataclasses.fields(FitResult)}
            out[i] = new_unchecked(FitResult, **{**fields, "robust_weights": w, "outliers": o})
    return out


def _stack_results(results: dict, n: int, errors: dict) -> FitResult:
    """One batched :class:`FitResult` of ``n`` members; the failed ones NaN (False, 0), padded to the longest."""
    template = next(iter(results.values()))
    fields = {}
    for f in dataclasses.fields(FitResult):
        if f.metadata.get("static"):
            continue
        arrs = [None if i not in results else np.asarray(getattr(results[i], f.name)) for i in range(n)]
        ref = np.asarray(getattr(template, f.name))
        shape = tuple(max(a.shape[d] for a in arrs if a is not None) for d in range(ref.ndim))
        fill = np.nan if np.issubdtype(ref.dtype, np.floating) else (0 if ref.dtype != bool else False)
        out = np.full((n,) + shape, fill, ref.dtype)
        for i, a in enumerate(arrs):
            if a is not None:
                out[(i,) + tuple(slice(0, s) for s in a.shape)] = a
        fields[f.name] = jnp.asarray(out)
    fields["failed"] = jnp.asarray([i in errors for i in range(n)])
    return new_unchecked(
        FitResult,
        **fields,
        scale_fixed=template.scale_fixed,
        segments=max(r.segments for r in results.values()),
        member_errors=tuple(f"recording {i}: {msg}" for i, msg in sorted(errors.items())),
        **_NOT_JOINT,
    )


def _sample_weights(prob, rw: np.ndarray, outlier_weight: float):
    """Segment-row weights ``(*N, S, B, K+1)`` as ``(*N, T, 3)`` [orientation, gyro, accelerometer]
    (1 for a sensor not fitted), and the outliers ``(*N, T)``."""
    rw = rw if prob.batched else rw[None]
    idx, valid = prob.sample_index[prob.sample_valid], prob.sample_valid
    T = int(idx.max()) + 1
    W = np.ones((rw.shape[0], T, 3), rw.dtype)
    for b, name in enumerate(prob.sensors):
        W[:, idx, ("orientation", "gyro", "accelerometer").index(name)] = rw[:, :, b, :][:, valid]
    outliers = np.any(W < outlier_weight, -1)
    if not prob.batched:
        W, outliers = W[0], outliers[0]
    return jnp.asarray(W), jnp.asarray(outliers)
