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

Levenberg–Marquardt (optimistix, with MINPACK's relative-reduction stop)
minimises their sum of squares with Jacobians by forward-mode differentiation
through the integrator (:mod:`rbjax._fit_model`). The start is a linear
least-squares fit of the conservation law ``R_i I ω_i - L_0 = ∫τ dt`` (no
differentiated data), which also gives the identifiability check
(:mod:`rbjax._fit_data`).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.extend.core as jec
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jax import Array
from jaxtyping import Bool, Float, Int

from . import _fit_data
from ._fit_data import fit_inertia_linear
from ._fit_model import _model, _normalised_moments, _unpack
from ._math import quat_exp, quat_multiply
from ._pytree import field, new_unchecked, pytree_dataclass, static_field
from ._typing import ArrayLike

__all__ = ["FitResult", "fit_inertia", "fit_inertia_linear"]


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
    scale_fixed: bool = static_field(default=False)
    segments: int = static_field(default=1)


_BOUNDARY_RTOL = 1e-3  # (I1 + I2 - I3) / tr I below this: on the edge of the consistent set
_RESIDUAL_RATIO_MAX = 3.0  # RMS weighted residual above this: the noise model does not fit


class _TrustRegionState(eqx.Module):
    step_size: Array
    stalled: Array  # the last trial step passed the MINPACK ftol test


class _TrustRegion(optx.ClassicalTrustRegion):
    """optimistix's trust-region search, plus MINPACK's relative-reduction stop.

    The stock search only ever stops on an *accepted* step that is small in
    both ``y`` and the residuals. At the optimum of a noisy fit the actual loss
    change of a step is rounding noise far larger than the predicted one, so
    the ratio test rejects step after step while the radius shrinks 4× each
    time; measured on 4 s @ 1 kHz, the optimum was reached in 4–6 steps and
    followed by ~16 rejections. MINPACK's ``lmder`` (Moré 1978) stops instead
    when a trial step's actual and predicted reductions of the sum of squares
    are both at most ``ftol`` of it (and ratio ≤ 2): the model itself says
    nothing is left to gain. ``ftol = 1e-8`` moves the parameters by about
    ``sqrt(1e-8 · n)`` of their standard error (δᵀJᵀJδ/s² = 2Δ·(n−p)/L),
    i.e. 0.02 σ for n = 24 000 residuals.

    The step size is also kept in the parameters' dtype: the stock ``init``
    starts from ``jnp.array(1.0)``, float64 whenever x64 is on, and the damping
    ``1/step_size`` would promote a float32 Jacobian's damped system to float64,
    which lineax rejects.
    """

    ftol: float = 1e-8

    def init(self, y, f_info_struct):
        dtype = jnp.result_type(*jax.tree.leaves(y))
        return _TrustRegionState(jnp.ones((), dtype), jnp.array(False))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        # the stock step reads only ``state.step_size``
        step_size, accept, result, inner = super().step(first_step, y, y_eval, f_info, f_eval_info, state)
        loss = f_info.as_min()
        predicted = -self.predict_reduction(y_eval - y, f_info)
        actual = loss - f_eval_info.as_min()
        stalled = (
            ~first_step
            & (jnp.abs(actual) <= self.ftol * loss)
            & (predicted <= self.ftol * loss)
            & (actual <= 2 * predicted)
        )
        return step_size, accept, result, _TrustRegionState(inner.step_size, stalled)


class _LevenbergMarquardt(optx.LevenbergMarquardt):
    """optimistix's Levenberg–Marquardt that also stops when :class:`_TrustRegion` stalls."""

    def __init__(self, rtol: float, atol: float):
        super().__init__(rtol=rtol, atol=atol)
        self.search = _TrustRegion(ftol=rtol)

    def terminate(self, fn, y, args, options, state, tags):
        terminate, result = super().terminate(fn, y, args, options, state, tags)
        return terminate | state.search_state.stalled, result


def _with_dense_jacobian(model):
    """``r(y, data)`` whose JVP in ``y`` is ``J @ ẏ`` with ``J`` from :func:`_model`.

    Levenberg–Marquardt linearises, materialises and transposes the residual
    map; through the integrator's scan each of those would be a separate
    compiled copy of the simulation. Handing it a matrix formed by the
    segment-local forward pass means one copy, no reverse pass through the
    scan. Not differentiable in ``data``.
    """

    # optimistix shape-evaluates the residual (primal) and linearises it (JVP
    # rule) under different trace contexts (abstract mesh unset / empty), so a
    # jitted model would be traced twice (~0.5 s each, a third of the fit's
    # compile time). The model is traced once here, shapes from the first call,
    # and both paths replay its jaxpr; the primal is only ever shape-evaluated.
    @functools.cache
    def traced(avals):
        closed, out = jax.make_jaxpr(model, return_shape=True)(*jax.tree.unflatten(avals[0], avals[1:]))
        return jec.jaxpr_as_fun(closed), jax.tree.structure(out)

    def residual_and_jacobian(y, data):
        leaves, tree = jax.tree.flatten((y, data))
        fn, out_tree = traced((tree, *(jax.ShapeDtypeStruct(a.shape, a.dtype) for a in leaves)))
        return jax.tree.unflatten(out_tree, fn(*leaves))

    @jax.custom_jvp
    def g(y, data):
        return residual_and_jacobian(y, data)[0]

    @g.defjvp
    def g_jvp(primals, tangents):
        y, data = primals
        r, J = residual_and_jacobian(y, data)
        return r, J @ tangents[0]

    return g


@functools.cache
def _fit_batch_jit(backend: str):
    """The jitted solver for ``backend``; made on first use, so importing rbjax starts no backend.

    On CPU it is compiled with XLA's classic loop emitters instead of the MLIR
    fusion emitters: for the 4 s @ 1 kHz fit that halved the compile (10.6 → 5.1
    CPU-s) and made the solve faster too (3.1 → 2.0 CPU-s), same result.
    """
    options = {"xla_cpu_use_fusion_emitters": False} if backend == "cpu" else None
    static = ("scale_fixed", "method", "substeps", "use_rates", "gyro_bias", "rtol", "atol", "max_steps", "unbatch")
    return jax.jit(_fit_batch, static_argnames=static, compiler_options=options)


def _fit_batch(y0, data, *, scale_fixed, method, substeps, use_rates, gyro_bias, rtol, atol, max_steps, unbatch):
    model = functools.partial(
        _model, scale_fixed=scale_fixed, method=method, substeps=substeps, use_rates=use_rates, gyro_bias=gyro_bias
    )
    res_fn = _with_dense_jacobian(model)
    solver = _LevenbergMarquardt(rtol, atol)

    def one(y0, data):
        sol = optx.least_squares(res_fn, solver, y0, data, max_steps=max_steps, throw=False)
        y = sol.value
        # residual and Jacobian at the accepted point, as the solver last linearised them:
        # reusing them keeps a second copy of the simulation out of the compiled program
        f_info = sol.state.f_info
        r, J = f_info.residual, lx.materialise(f_info.jac).as_matrix()
        seg = data["seg"]
        S, K = seg["dt"].shape
        p = y.shape[0]
        n_rows = S * (3 + 3 * K) * (2 if use_rates else 1)  # data rows, incl. zero padding
        n_cont = r.shape[0] - n_rows
        # continuity residuals act as constraints: they remove degrees of freedom, add no data
        s2 = jnp.sum(r[:n_rows] ** 2) / (data["n_data"] - (p - n_cont))
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
        _, P = _unpack(y, n_I + (3 if gyro_bias else 0), S)
        if gyro_bias:
            bias, bias_std = y[n_I : n_I + 3], jnp.sqrt(jnp.diagonal(cov)[n_I : n_I + 3])
        else:
            bias, bias_std = jnp.zeros(3, y.dtype), jnp.full(3, jnp.nan, y.dtype)
        r_seg = r[:n_rows].reshape(S, 2 if use_rates else 1, 3 + 3 * K)
        nq = seg["mask"].sum() * 3 + 3
        q_rms = jnp.sqrt(jnp.sum(r_seg[:, 0] ** 2) / nq) / seg["wq"][0]
        if use_rates:
            w_rms = jnp.sqrt(jnp.sum(r_seg[:, 1] ** 2) / nq) / seg["ww"][0]
        else:
            w_rms = jnp.full((), jnp.nan, r.dtype)
        # honest failure: the triangle margin I1 + I2 - I3 = 2 λ_min(Σ) near zero, or residuals
        # far above the noise model
        on_boundary = (moments[0] + moments[1] - moments[2]) < _BOUNDARY_RTOL * jnp.sum(moments)
        ratio = jnp.sqrt(s2)
        solver_ok = sol.result == optx.RESULTS.successful
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
            iterations=sol.stats["num_steps"],
            solver_converged=solver_ok,
            on_boundary=on_boundary,
            residual_ratio=ratio,
            gyro_bias=bias,
            gyro_bias_std=bias_std,
        )

    if unbatch:  # one recording: no vmap, whose batching of the solver's loops doubles tracing
        return one(y0[0], jax.tree.map(lambda a: a[0], data))
    return jax.vmap(one)(y0, data)


# ----------------------------------------------------------------------------------------
# Public entry point


def fit_inertia(
    times: Float[ArrayLike, " T"],
    orientations: Float[ArrayLike, "*N T 4"],
    *,
    body_rates: Float[ArrayLike, "*N T 3"] | None = None,
    torques: Float[ArrayLike, "*N T 3"] | None = None,
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
    max_steps: int = 100,
    check_gyro_frame: bool = True,
    gyro_bias: bool = False,
) -> FitResult:
    """Fit a body-frame inertia tensor to a recording of free (or known-torque) rotation.

    Model: ``d(R I ω)/dt = τ`` (Euler's law, world frame), ``q̇ = ½ q ⊗ (0, ω)``
    with ``ω`` in the body frame, integrated by :func:`rbjax.step` (``method``)
    between the samples. See the module docstring for residuals and solver.

    Args:
        times: ``(T,)`` sample times (s), strictly increasing, possibly irregular
            (each interval is its own ``dt``, split into ``substeps`` steps).
        orientations: ``(T, 4)`` unit quaternions ``[w, x, y, z]`` body to world,
            or ``(N, T, 4)`` for ``N`` recordings fitted together (one compiled
            program, ``vmap`` over recordings).
        body_rates: optional ``(T, 3)`` / ``(N, T, 3)`` gyro readings, body frame (rad/s).
        torques: optional ``(T, 3)`` / ``(N, T, 3)`` known world-frame torques
            about the centre of mass (N m), taken as linear in time between
            samples. With them the inertia is absolute (kg m²); without them only
            its shape is identifiable and the result is normalised to ``tr I = 1``
            (``FitResult.scale_fixed = False``).
        initial_inertia: optional ``(3, 3)`` starting guess (body frame); default:
            linear least squares on conservation of angular momentum.
        method: integrator (see :func:`rbjax.methods`); ``"rk4"`` recommended.
        segments: number of multiple-shooting segments; default one per ``2π``
            of recorded rotation, at least 1 and at most ``(T-1) // 8``.
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
            squares are both below ``rtol`` of it (MINPACK's ``ftol`` test).
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

    Returns:
        :class:`FitResult` (with a leading ``N`` axis for batched input).

    Raises:
        TypeError: before any tracing, for options of the wrong type (e.g. a
            float or bool ``max_steps``/``segments``/``substeps``).
        ValueError: before any tracing, for noise levels, ``continuity_weight``,
            tolerances that are not finite and > 0; ``max_steps``, ``segments``
            or ``substeps`` < 1; all-zero ``torques`` (they cannot fix the scale:
            omit ``torques=``); non-monotonic or non-finite times, non-unit
            quaternions, shape mismatches, too few samples for the parameters,
            or too little excitation (naming the unidentifiable directions), or
            ``body_rates`` that look world-frame (``check_gyro_frame``).
    """
    _fit_data.check_options(
        orientation_std=orientation_std,
        rate_std=rate_std,
        continuity_weight=continuity_weight,
        excitation_tol=excitation_tol,
        rtol=rtol,
        atol=atol,
        max_steps=max_steps,
        segments=segments,
        substeps=substeps,
    )
    prob = _fit_data.prepare(
        times,
        orientations,
        body_rates,
        torques,
        initial_inertia=initial_inertia,
        method=method,
        segments=segments,
        substeps=substeps,
        orientation_std=orientation_std,
        rate_std=rate_std,
        continuity_weight=continuity_weight,
        excitation_tol=excitation_tol,
        check_gyro_frame=bool(check_gyro_frame),
        gyro_bias=gyro_bias,
    )
    out = _fit_batch_jit(jax.default_backend())(
        prob.y0,
        prob.data,
        **prob.static,
        rtol=float(rtol),
        atol=float(atol),
        max_steps=int(max_steps),
        unbatch=not prob.batched,
    )
    return new_unchecked(FitResult, **out, scale_fixed=prob.static["scale_fixed"], segments=prob.segments)
