"""Levenberg–Marquardt for the fit: optimistix with MINPACK's stop and a dense Jacobian.

optimistix (with lineax for the damped solves) supplies the trust-region
Levenberg–Marquardt; this module adds MINPACK's relative-reduction stop and
hands it the model's hand-assembled Jacobian (:mod:`._model`), so the
integrator is traced once.
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

# the stop also fires once a trial step's reductions are below σ_tol² of ½χ² per degree of
# freedom, i.e. the step left moves the estimate by ≲ √2 · 0.1 σ (see _TrustRegion)
_SIGMA_TOL = 0.1
_EXPAND_RATIO = 0.75


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

    On short recordings that is far stricter than the data warrant: for 1 s @
    200 Hz (n ≈ 1200) ``ftol · L`` is 6e-6 of ``½χ²``, and on weakly determined
    bodies (near-spherical, σ of the moments ~0.1-1) the solver crept along the
    flat valley for hundreds of steps; measured on 100 random tumbles
    (``benchmarks/fit_convergence.py``) 30% stopped at ``max_steps = 100``,
    every one of them a near-spherical body. So the tolerance is also at least
    ``2 sigma_tol² / (n - p)`` of the loss: a step that reduces ``½χ²`` by
    less than ``sigma_tol²`` (≈ ``L / (n - p)`` is ½ per degree of freedom when
    the weights fit) moves the estimate by less than ``√2 · sigma_tol``
    standard errors. With ``sigma_tol = 0.1`` and 200 steps, 99-100% of those
    fits stopped, with 98-99% of the moments within 3σ.

    The step size is also kept in the parameters' dtype: the stock ``init``
    starts from ``jnp.array(1.0)``, float64 whenever x64 is on, and the damping
    ``1/step_size`` would promote a float32 Jacobian's damped system to float64,
    which lineax rejects.
    """

    ftol: float = 1e-8
    sigma_tol: float = 0.0

    def init(self, y, f_info_struct):
        dtype = jnp.result_type(*jax.tree.leaves(y))
        return _TrustRegionState(jnp.ones((), dtype), jnp.array(False))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        # the stock step reads only ``state.step_size``
        step_size, accept, result, inner = super().step(first_step, y, y_eval, f_info, f_eval_info, state)
        loss = f_info.as_min()
        predicted = -self.predict_reduction(y_eval - y, f_info)
        actual = loss - f_eval_info.as_min()
        n = sum(jnp.size(r) for r in jax.tree.leaves(getattr(f_info, "residual", ())))  # Levenberg–Marquardt's
        dof = max(n - y.size, 1)
        tol = loss * max(self.ftol, 2 * self.sigma_tol**2 / dof)
        stalled = ~first_step & (jnp.abs(actual) <= tol) & (predicted <= tol) & (actual <= 2 * predicted)
        return step_size, accept, result, _TrustRegionState(inner.step_size, stalled)


class _LevenbergMarquardt(optx.LevenbergMarquardt):
    """optimistix's Levenberg–Marquardt that also stops when :class:`_TrustRegion` stalls."""

    def __init__(self, rtol: float, atol: float):
        super().__init__(rtol=rtol, atol=atol)
        self.search = _TrustRegion(ftol=rtol, sigma_tol=_SIGMA_TOL, high_cutoff=_EXPAND_RATIO)

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


class LMMember:
    """One member's Levenberg–Marquardt solve as a state machine for :func:`._queue.run_queue`.

    ``init``/``step``/``terminate`` are optimistix's iterative-solver interface,
    driven here exactly as ``optx.least_squares`` drives them (its
    ``_iterate``), so the iterates are the same; but the loop belongs to the
    caller, which may stop, move and restart members one by one.
    """

    def __init__(self, fn, solver, static_state, max_steps: int):
        self.fn = fn  # closure-converted r(y, data) -> (r, None)
        self.solver = solver
        self.static_state = static_state  # the non-array part of the solver state (jaxprs), shared by all
        self.max_steps = max_steps

    @staticmethod
    def make(res_fn, solver, y, data, max_steps):
        """For residuals ``res_fn(y, data)`` and one member's example ``y``, ``data``."""
        fn = eqx.filter_closure_convert(lambda y, d: (res_fn(y, d), None), y, data)
        f_struct, aux_struct = fn.out_struct  # pyright: ignore[reportFunctionMemberAccess]
        state = solver.init(fn, y, data, {}, f_struct, aux_struct, frozenset())
        return LMMember(fn, solver, eqx.partition(state, eqx.is_array)[1], max_steps)

    def start(self, y, data):
        """A fresh solve from ``y``: ``dict(y, data, lm, steps, terminate, result)``."""
        f_struct, aux_struct = self.fn.out_struct  # pyright: ignore[reportAttributeAccessIssue]
        state = self.solver.init(self.fn, y, data, {}, f_struct, aux_struct, frozenset())
        terminate, result = self._terminate(y, data, state)
        lm = eqx.partition(state, eqx.is_array)[0]
        return dict(y=y, data=data, lm=lm, steps=jnp.zeros((), jnp.int32), terminate=terminate, result=result)

    def _terminate(self, y, data, state):
        terminate, result = self.solver.terminate(self.fn, y, data, {}, state, frozenset())
        return terminate, optx.RESULTS.where(_allfinite(y), result, optx.RESULTS.nonfinite)

    def advance(self, slot):
        state = eqx.combine(self.static_state, slot["lm"])
        y, state, _ = self.solver.step(self.fn, slot["y"], slot["data"], {}, state, frozenset())
        terminate, result = self._terminate(slot["y"], slot["data"], state)
        lm = eqx.partition(state, eqx.is_array)[0]
        return dict(slot, y=y, lm=lm, steps=slot["steps"] + 1, terminate=terminate, result=result)

    def running(self, slot):
        return ~slot["terminate"] & (slot["result"] == optx.RESULTS.successful) & (slot["steps"] < self.max_steps)

    def solution(self, slot):
        """``(y, r, J, ok)`` of a stopped member: the residual and Jacobian as last linearised.

        Reusing them keeps a second copy of the simulation out of the compiled program.
        """
        f_info = eqx.combine(self.static_state, slot["lm"]).f_info
        r, J = f_info.residual, lx.materialise(f_info.jac).as_matrix()
        ok = slot["terminate"] & (slot["result"] == optx.RESULTS.successful)
        return slot["y"], r, J, ok


def _allfinite(y):
    return jnp.all(jnp.isfinite(y))
