"""Levenberg–Marquardt on the model's dense Jacobian, one member at a time.

The classical trust-region Levenberg–Marquardt (Moré 1978; Nocedal & Wright
§10.3), written for a residual map that returns its Jacobian as a matrix
(:mod:`._model`): at the accepted point ``y`` with residuals ``r`` and
Jacobian ``J``, the trial step is

    δ = -(JᵀJ + λ I)⁻¹ Jᵀ r,   λ = 1 / s,

with ``s`` the step size. The trial point is accepted when the loss
``½‖r‖²`` falls by at least ``0.01`` of the reduction the linear model
predicts, ``−(½‖J δ + r‖² − ½‖r‖²)``; ``s`` grows 3.5x when the ratio is
above ``_EXPAND_RATIO`` and shrinks 4x on a rejection.

This is the map of optimistix's ``LevenbergMarquardt`` with
``ClassicalTrustRegion``, written out so that a step costs one ``JᵀJ`` and an
``n x n`` Cholesky factorisation: through lineax's linear operators the
Jacobian is re-materialised from its linearisation and stacked with ``√λ I``
before every solve, a large share of a step (docs/fitting.md, Speed).

Stopping, on top of the accepted-step test (``|Δy| ≤ atol + rtol·|y|`` and
``|Δr| ≤ atol + rtol·|r|``, max-norm): MINPACK's relative-reduction test
(``lmder``'s ``ftol``): a trial step whose actual and predicted reductions of
the loss are both at most ``tol`` of it (and ratio ≤ 2) means the model
itself says nothing is left to gain. At the optimum of a noisy fit the
actual change of a step is rounding noise far larger than the predicted one,
so without it the ratio test rejects step after step while the radius
shrinks; measured on 4 s @ 1 kHz the optimum was reached in 4–6 steps and
followed by ~16 rejections. ``tol = max(rtol, 2 σ_tol² / (n − p))`` of the
loss: ``rtol = 1e-8`` alone moves the parameters by ``√(1e-8 n)`` of their
standard error, far stricter than short recordings warrant (for 1 s @ 200 Hz,
n ≈ 1200, weakly determined near-spherical bodies crept along the flat
valley for hundreds of steps; 30% of 100 random tumbles stopped at
``max_steps = 100``). A step that reduces ``½χ²`` by less than
``σ_tol² = 0.01`` (½ per degree of freedom when the weights fit) moves the
estimate by less than ``√2 · 0.1`` standard errors; with it, 99–100% of those
fits stopped within 200 steps, with 98–99% of the moments within 3σ
(``benchmarks/fit_convergence.py``).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
from jax import Array

_SIGMA_TOL = 0.1
# the trust region grows when the actual reduction is at least this fraction of the predicted
# one: MINPACK's and Nocedal–Wright's 0.75 (optimistix's default 0.99 grows it far less often)
_EXPAND_RATIO = 0.75
_ACCEPT_RATIO = 0.01
_GROW, _SHRINK = 3.5, 0.25


def _damped_step(G, g, step_size):
    """``δ = -(G + λI)⁻¹ g`` with ``G = JᵀJ``, ``g = Jᵀr``, ``λ = 1/s`` (``s`` below eps: a vanishing step).

    The normal equations with a Cholesky factorisation (``n x n``, ``n`` ≈
    11–60). They square the condition number of ``J``, but the step only has
    to be a descent direction inside the trust region, and ``λ`` bounds the
    conditioning of ``G + λI`` where the step would be long.
    """
    dtype = G.dtype
    tiny = step_size <= jnp.finfo(dtype).eps
    lam = jnp.where(tiny, jnp.finfo(dtype).max, 1 / jnp.where(tiny, 1, step_size))
    return -cholesky_solve(G + lam * jnp.eye(G.shape[0], dtype=dtype), g)


def after(done: Any, x: Array) -> Array:
    """``x``, not to be used before ``done`` is computed: orders a program's LAPACK calls.

    Batched over a batch's members, each eigh, SVD or det is a LAPACK call that waits for its
    batch on XLA's intra-op thread pool; two independent ones may run at once, and on a 2-thread
    pool two such waits starve each other (a hang, reproduced with two batched solves, and with
    two batched SVDs of the result pass). Chained through an optimisation barrier, one runs after
    the other.
    """
    return jax.lax.optimization_barrier((done, x))[1]


def cholesky_solve(A, b):
    """``x = A⁻¹ b`` for a symmetric positive definite ``(n, n)`` ``A`` and ``(n,)`` ``b``, in plain jnp.

    ``A = L Lᵀ`` column by column (``L[i, j] = (A[i, j] - Σ_{k<j} L[i, k] L[j, k]) / L[j, j]``),
    then ``L y = b`` forwards and ``Lᵀ x = y`` backwards: ``3n`` vector steps of ``O(n²)``.

    Not LAPACK (``jax.scipy.linalg.cho_solve``): on CPU each batched LAPACK call fans its
    batch out over XLA's thread pool and blocks until it is done, and when two such calls
    ran at once in a batched fit they held every pool thread and waited on each other
    forever (seen with 100 recordings on 2 cores, jaxlib 0.10.2). ``n`` is small here, so
    the loops cost little beside the model. A NaN in ``A`` (or a matrix that is not
    positive definite) gives NaN, as LAPACK's factorisation would.
    """
    n = A.shape[-1]
    idx = jnp.arange(n)

    def column(j, L):
        # columns < j of L are final, so row j holds L[j, :j] and zeros
        Lj = L[j]
        d = jnp.sqrt(A[j, j] - Lj @ Lj)
        c = (A[:, j] - L @ Lj) / d
        return L.at[:, j].set(jnp.where(idx > j, c, jnp.where(idx == j, d, 0)))

    L = jax.lax.fori_loop(0, n, column, jnp.zeros_like(A))

    def forward(i, y):
        return y.at[i].set((b[i] - L[i] @ y) / L[i, i])

    y = jax.lax.fori_loop(0, n, forward, jnp.zeros_like(b))

    def backward(k, x):
        i = n - 1 - k
        return x.at[i].set((y[i] - L[:, i] @ x) / L[i, i])

    return jax.lax.fori_loop(0, n, backward, jnp.zeros_like(b))


def solve_small(A, B):
    """``X = A⁻¹ B`` for a small square ``(n, n)`` ``A`` (``n`` ≤ ~8) and ``(n, k)`` ``B``, in plain jnp.

    Gaussian elimination with partial pivoting, unrolled over the ``n`` columns, then back
    substitution. Not ``jnp.linalg.solve``, for the reason :func:`cholesky_solve` gives: two batched
    LAPACK solves running at once in one program deadlock on a small CPU (reproduced with jaxlib
    0.10.2 on 2 cores: two independent ``vmap``-ed 6x6 solves over 1,000 members never return).
    """
    n = A.shape[0]
    M = jnp.concatenate([A, B], axis=1)
    for k in range(n):
        p = k + jnp.argmax(jnp.abs(M[k:, k]))
        row_k, row_p = M[k], M[p]
        M = M.at[k].set(row_p).at[p].set(row_k)
        M = M.at[k + 1 :].add(-(M[k + 1 :, k] / M[k, k])[:, None] * M[k])
    X = [None] * n
    for i in reversed(range(n)):
        acc = M[i, n:]
        for j in range(i + 1, n):
            acc = acc - M[i, j] * X[j]
        X[i] = acc / M[i, i]
    return jnp.stack(X)


class LMMember:
    """One member's Levenberg–Marquardt solve as a state machine for :func:`._queue.run_queue`.

    ``model(y, data) -> (r, J)``: residuals ``(m,)`` and their Jacobian
    ``(m, n)``, or a pytree of its blocks with ``normal(r, J) -> (JᵀJ, Jᵀr)``.
    A slot is a dict of arrays: ``y`` (accepted), ``y_eval``
    (trial), at ``y`` the residuals ``r``, ``G = JᵀJ`` and ``g = Jᵀr``,
    ``step_size``, ``first``, ``steps``, ``terminate`` and ``ok`` (every
    iterate finite). ``J`` itself is kept only with ``keep_jacobian`` (then
    as ``J``, at ``y``): the step needs only ``G`` and ``g``, but with ``J``
    the caller can form the covariance without evaluating (and compiling) the
    model a second time, at the cost of an ``(m, n)`` matrix per slot carried
    through the loops. The loop belongs to
    the caller, which may stop, move and restart members one by one.
    ``shapes(y, data)``: ``model``'s output shapes (``jax.ShapeDtypeStruct``);
    default ``jax.eval_shape`` of it, which traces the model once more.
    """

    def __init__(
        self, model, rtol: float, atol: float, max_steps: int, keep_jacobian: bool = False, shapes=None, normal=None
    ):
        self.model, self.rtol, self.atol, self.max_steps = model, rtol, atol, max_steps
        self.keep_jacobian = keep_jacobian
        # (r, J) -> (JᵀJ, Jᵀr): for a J that is not a matrix (a pytree of its nonzero blocks)
        self.normal = normal or (lambda r, J: (J.T @ J, J.T @ r))
        # (y, data) -> the shapes of model(y, data), if known without tracing the model
        self.shapes = shapes or functools.partial(jax.eval_shape, model)

    def start(self, y, data):
        """A fresh solve from ``y``; ``r``, ``G`` and ``g`` are filled in by the first step."""
        r, J = self.shapes(y, data)
        n = y.shape[0]
        kept = {"J": jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), J)} if self.keep_jacobian else {}
        return {
            **kept,
            "y": y,
            "y_eval": y,
            "data": data,
            "r": jnp.zeros(r.shape, r.dtype),
            "G": jnp.zeros((n, n), y.dtype),
            "g": jnp.zeros(n, y.dtype),
            "step_size": jnp.ones((), y.dtype),
            "first": jnp.array(True),
            "steps": jnp.zeros((), jnp.int32),
            "terminate": jnp.array(False),
            "ok": jnp.all(jnp.isfinite(y)),
        }

    def advance(self, slot):
        """Evaluate the trial point, accept or reject it, and propose the next one."""
        y, y_eval, r, G, g, first = (slot[k] for k in ("y", "y_eval", "r", "G", "g", "first"))
        r_e, J_e = self.model(y_eval, slot["data"])
        loss, loss_e = 0.5 * jnp.sum(r * r), 0.5 * jnp.sum(r_e * r_e)
        d = y_eval - y
        predicted = 0.5 * d @ G @ d + d @ g  # ½‖J d + r‖² − ½‖r‖², the model's loss change: ≤ 0
        change = loss_e - loss
        accept = (change <= _ACCEPT_RATIO * predicted) | first
        good = (change < _EXPAND_RATIO * predicted) & (predicted < 0) & ~first
        step_size = slot["step_size"] * jnp.where(accept, jnp.where(good, _GROW, 1.0), _SHRINK).astype(y.dtype)

        # MINPACK's relative-reduction stop (module docstring)
        dof = max(r.size - y.size, 1)
        tol = loss * max(self.rtol, 2 * _SIGMA_TOL**2 / dof)
        stalled = ~first & (jnp.abs(change) <= tol) & (-predicted <= tol) & (-change <= -2 * predicted)
        # the accepted-step test on y and on the residuals (max-norm)
        small_y = jnp.max(jnp.abs(d) / (self.atol + self.rtol * jnp.abs(y_eval))) < 1
        small_r = jnp.max(jnp.abs(r_e - r) / (self.atol + self.rtol * jnp.abs(r_e))) < 1
        terminate = (accept & small_y & small_r) | stalled

        y = jnp.where(accept, y_eval, y)
        r = jnp.where(accept, r_e, r)
        G_e, g_e = self.normal(r_e, J_e)
        G, g = jnp.where(accept, G_e, G), jnp.where(accept, g_e, g)
        kept = {"J": jax.tree.map(lambda a, b: jnp.where(accept, a, b), J_e, slot["J"])} if self.keep_jacobian else {}
        y_next = y + _damped_step(G, g, step_size)
        ok = slot["ok"] & jnp.all(jnp.isfinite(y_next)) & jnp.all(jnp.isfinite(r))
        return {
            **slot,
            **kept,
            "y": y,
            "y_eval": y_next,
            "r": r,
            "G": G,
            "g": g,
            "step_size": step_size,
            "first": jnp.array(False),
            "steps": slot["steps"] + 1,
            "terminate": terminate,
            "ok": ok,
        }

    def running(self, slot):
        return ~slot["terminate"] & slot["ok"] & (slot["steps"] < self.max_steps)

    def converged(self, slot):
        return slot["terminate"] & slot["ok"]
