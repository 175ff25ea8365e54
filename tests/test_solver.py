"""The fit's Levenberg–Marquardt (identification/_solver.py) against MINPACK.

An exponential-decay fit with noise, a classic nonlinear least-squares test:
``y_i = a exp(-b t_i) + c``. scipy's ``least_squares(method="lm")`` (MINPACK's
``lmder``) is the independent reference; both converge to the same minimiser,
so they agree to the tolerance of rbjax's stop. That stop fires once the step
left moves the estimate by under ~0.14 of its standard error (``_SIGMA_TOL``),
here ~1e-4 of the parameters; agreement to 1e-6 (seen: 4e-8) shows both
reached the same minimiser.
"""

from __future__ import annotations

import re

import jax
import jax.extend.core as jex
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import least_squares

from rbjax.identification._solver import LMMember, cholesky_solve, solve_small

T = np.linspace(0.0, 4.0, 60)


def _residuals(y, data):
    return y[0] * jnp.exp(-y[1] * data["t"]) + y[2] - data["obs"]


def _model(y, data):
    return _residuals(y, data), jax.jacfwd(_residuals)(y, data)


@pytest.mark.parametrize("start", [(1.0, 1.0, 0.0), (5.0, 0.1, 1.0)])
def test_levenberg_marquardt_matches_minpack(start):
    rng = np.random.default_rng(0)
    data = dict(t=T, obs=2.5 * np.exp(-1.3 * T) + 0.4 + rng.normal(0, 0.01, T.size))
    lm = LMMember(_model, rtol=1e-10, atol=1e-12, max_steps=200)
    slot = lm.start(jnp.asarray(start), jax.tree.map(jnp.asarray, data))
    slot = jax.jit(lambda s: jax.lax.while_loop(lm.running, lm.advance, s))(slot)
    assert bool(lm.converged(slot)) and int(slot["steps"]) < 200
    ref = least_squares(lambda y: np.asarray(_residuals(y, data)), start, method="lm", xtol=1e-14, ftol=1e-14)
    np.testing.assert_allclose(slot["y"], ref.x, rtol=1e-6)
    # the slot's Gram matrix and gradient are J's at the accepted point
    r, J = _model(slot["y"], data)
    np.testing.assert_allclose(slot["G"], J.T @ J, rtol=1e-12)
    # Jᵀr ≈ 0 at the minimiser: compared on the scale of its terms (rounding of the sum)
    np.testing.assert_allclose(slot["g"], J.T @ r, rtol=0, atol=1e-12 * float(np.linalg.norm(J) * np.linalg.norm(r)))


def test_a_non_finite_start_stops_unconverged():
    lm = LMMember(_model, rtol=1e-10, atol=1e-12, max_steps=50)
    data = dict(t=jnp.asarray(T), obs=jnp.ones(T.size))
    slot = lm.start(jnp.array([np.nan, 1.0, 0.0]), data)
    assert not bool(lm.running(slot)) and not bool(lm.converged(slot))


@pytest.mark.parametrize("n, condition", [(1, 1.0), (11, 1e2), (60, 1e8)])
def test_cholesky_solve_matches_numpy_on_spd_systems(n, condition):
    # SPD A = Q diag(d) Qᵀ with eigenvalues from 1 to 1/condition; a backward-stable Cholesky solve
    # leaves a residual ‖Ax - b‖ of a few n·eps·‖A‖‖x‖ whatever the conditioning (bound 10 n eps)
    rng = np.random.default_rng(n)
    Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
    A = (Q * np.geomspace(1.0, 1.0 / condition, n)) @ Q.T
    A = 0.5 * (A + A.T)
    b = rng.normal(size=(3, n))
    x = np.asarray(jax.jit(jax.vmap(cholesky_solve, in_axes=(None, 0)))(jnp.asarray(A), jnp.asarray(b)))
    eps = np.finfo(np.float64).eps
    for xk, bk in zip(x, b):
        assert np.linalg.norm(A @ xk - bk) <= 10 * n * eps * np.linalg.norm(A, 2) * np.linalg.norm(xk)
    if condition < 1e3:  # well conditioned: the solution itself agrees with LAPACK's to cond·eps
        np.testing.assert_allclose(x, np.linalg.solve(A, b.T).T, rtol=1e-12 * condition, atol=0)


def test_the_levenberg_marquardt_loop_calls_no_lapack():
    # Batched LAPACK calls on CPU fan out over XLA's thread pool and block; two at once in one
    # batched fit deadlocked (see cholesky_solve). The solver's step is plain jnp.
    lm = LMMember(_model, rtol=1e-10, atol=1e-12, max_steps=5)
    data = dict(t=jnp.asarray(T), obs=jnp.ones(T.size))
    slots = jax.vmap(lambda y: lm.start(y, data))(jnp.ones((4, 3)))
    hlo = jax.jit(jax.vmap(lambda s: jax.lax.while_loop(lm.running, lm.advance, s))).lower(slots).compile().as_text()
    assert not re.search(r'custom_call_target="lapack', hlo), "a LAPACK custom call in the solver's loop"


@pytest.mark.parametrize("n", [3, 5, 6])
def test_solve_small_matches_numpy_and_pivots(n):
    # Gaussian elimination with partial pivoting is backward stable: the residual is within a few
    # n·eps·‖A‖‖X‖ (bound 10 n eps); a zero leading pivot needs the row swap
    rng = np.random.default_rng(n)
    A = rng.normal(size=(n, n))
    A[0, 0] = 0.0
    B = rng.normal(size=(n, 4))
    solve = jax.jit(jax.vmap(solve_small, in_axes=(None, 0)))
    X = np.asarray(solve(jnp.asarray(A), jnp.asarray(B[None].repeat(2, 0))))[0]
    eps = np.finfo(np.float64).eps
    assert np.linalg.norm(A @ X - B) <= 10 * n * eps * np.linalg.norm(A, 2) * np.linalg.norm(X)
    np.testing.assert_allclose(X, np.linalg.solve(A, B), rtol=1e-10 * np.linalg.cond(A))
    hlo = solve.lower(jnp.asarray(A), jnp.asarray(B[None].repeat(2, 0))).compile().as_text()
    assert not re.search(r'custom_call_target="lapack', hlo)


# jax primitives that XLA:CPU runs as LAPACK custom calls (det is an lu)
_LAPACK = {"eigh", "svd", "lu", "cholesky", "triangular_solve", "qr", "householder_product", "schur", "eig"}


def _sub_jaxprs(eqn):
    for p in eqn.params.values():
        for v in p if isinstance(p, (tuple, list)) else (p,):
            if isinstance(v, jex.ClosedJaxpr):
                yield v.jaxpr
            elif isinstance(v, jex.Jaxpr):
                yield v


def _calls_lapack(eqn) -> bool:
    return eqn.primitive.name in _LAPACK or any(_calls_lapack(e) for j in _sub_jaxprs(eqn) for e in j.eqns)


def _unordered_lapack_pairs(jaxpr, where="top"):
    """Pairs of LAPACK-calling equations of ``jaxpr`` (and of each nested jaxpr) that no data
    dependency orders: XLA may run them at the same time."""
    producer = {}
    deps = []  # the equations each equation depends on, transitively
    for k, eqn in enumerate(jaxpr.eqns):
        d = set()
        for v in eqn.invars:
            if isinstance(v, jex.Var) and v in producer:
                j = producer[v]
                d |= deps[j] | {j}
        deps.append(d)
        for v in eqn.outvars:
            producer[v] = k
    calls = [k for k, e in enumerate(jaxpr.eqns) if _calls_lapack(e)]
    bad = [
        (where, jaxpr.eqns[a].primitive.name, jaxpr.eqns[b].primitive.name)
        for i, a in enumerate(calls)
        for b in calls[i + 1 :]
        if a not in deps[b]
    ]
    for k, eqn in enumerate(jaxpr.eqns):
        for j in _sub_jaxprs(eqn):
            bad += _unordered_lapack_pairs(j, f"{where}/{eqn.primitive.name}[{k}]")
    return bad


@pytest.mark.slow  # traces a batched fit twice to read its program; the whole suite (CI) runs it
def test_a_batched_fit_runs_its_lapack_calls_one_after_another(monkeypatch):
    # Batched over a fit's members, each LAPACK call (eigh, SVD, det) waits for its batch on
    # XLA's intra-op thread pool; two at once can starve each other on a 2-core machine and hang
    # the fit (reproduced with two batched solves, see cholesky_solve, and with the result pass's
    # SVDs: 100 recordings, 1 process in 3). The result pass chains them: in the jaxpr of the
    # solver's program followed by the result pass's, every two of them are ordered by a data
    # dependency. Also where the result pass runs in slices of _SLOTS members and a partial slice
    # is left (lax.map ran that one beside its loop)
    import rbjax as rb
    from rbjax.identification import _solve

    seen = []

    class Captured(Exception):  # the solver's arguments are all the check needs: nothing is compiled
        pass

    class Recording:
        def __call__(self, *args, **kwargs):
            seen.append((args, kwargs))
            raise Captured

        trace = __call__  # _compile_side_by_side traces before the call

    def recording(backend, small=False):
        return Recording()

    monkeypatch.setattr(_solve, "fit_batch_jit", recording)
    t = np.linspace(0.0, 2.0, 101)  # a tumble near the intermediate axis: every axis excited
    state = rb.State.create(rb.Body(1.0, np.diag([1.0, 2.0, 2.6])), angular_velocity=[0.3, 3.0, 0.4])
    q = np.asarray(rb.torque_free(state, t).orientation)
    with pytest.raises(Captured):
        rb.fit_inertia(t, np.stack([q, q, q]), segments=2)  # a batch of three recordings; joins: two more SVDs
    ((args, kwargs),) = seen
    for slots in (_solve._SLOTS, 2):  # one partial slice of 3; a full slice of 2, then one of 1
        monkeypatch.setattr(_solve, "_SLOTS", slots)
        jaxpr = jax.make_jaxpr(lambda *a: _solve_and_summarise(_solve, *a, **kwargs))(*args).jaxpr
        assert sum(_calls_lapack(e) for e in jaxpr.eqns), "the check found no LAPACK call to order"
        assert not _unordered_lapack_pairs(jaxpr), slots


def _solve_and_summarise(_solve, y0, data, **kwargs):
    """The solver's program and then the result pass's, as one function (they run one after the other)."""
    sols = _solve._fit_batch(y0, data, **kwargs)
    return _solve._summarise_batch(sols, data, **{k: kwargs[k] for k in ("model_opts", "loss", "unbatch")})


@pytest.mark.parametrize("n", [3, 8, 10])  # a partial slice only; full slices only; both
def test_the_result_pass_in_slices_gives_every_member_its_own_result(n):
    # _map_in_order (the batched result pass) runs full slices of `size` members in a loop, then
    # the partial one: every member's output must be that of vmap over the whole batch, in order
    from rbjax.identification._solve import _map_in_order

    xs = {"a": jnp.arange(n * 3.0).reshape(n, 3), "b": jnp.arange(n * 1.0) % 5}
    f = lambda x: {"s": jnp.sum(x["a"]) * x["b"], "v": x["a"][::-1] + x["b"]}
    got, want = _map_in_order(f, xs, 4), jax.vmap(f)(xs)
    for k in want:
        np.testing.assert_array_equal(got[k], want[k])
