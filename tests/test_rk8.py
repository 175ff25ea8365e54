"""``"rk8"`` (DOP853's 8th-order tableau at fixed step) and the explicit Runge–Kutta driver.

Coefficients against scipy's copy of DOP853 and the order conditions;
convergence order against the independent scipy DOP853 reference
(tests/reference.py) for ``State`` and ``MatrixState``; float32 at its floor;
a gradient against central differences. float64 unless said.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate._ivp import dop853_coefficients as scipy_dop853
from scipy.spatial.transform import Rotation

import rbjax as rb
from rbjax._methods.explicit_rk import explicit_rk
from rbjax._methods.rk8 import DOP853_A, DOP853_B, DOP853_C
from rbjax._pytree import replace as _replace
from tests.reference import quat_angle, reference_rotation


def _tableau():
    s = len(DOP853_B)
    A = np.zeros((s, s))
    for i, row in enumerate(DOP853_A):
        A[i, : len(row)] = row
    return A, np.asarray(DOP853_B), np.asarray(DOP853_C)


def test_coefficients_match_scipy_and_consistency_conditions():
    A, b, c = _tableau()
    n = scipy_dop853.N_STAGES
    # the same 30-digit literals, rounded by the same parser: bitwise equal
    np.testing.assert_array_equal(A, scipy_dop853.A[:n, :n])
    np.testing.assert_array_equal(b, scipy_dop853.B)
    np.testing.assert_array_equal(c, scipy_dop853.C[:n])
    # c_i = Σ_j a_ij and Σ b_i = 1, to the round-off of summing up to 11 terms as large as 44
    # (ulp(44) = 7e-15; measured 1e-15)
    np.testing.assert_allclose(A.sum(axis=1), c, rtol=0, atol=5e-14)
    assert abs(b.sum() - 1) < 1e-15 * np.abs(b).sum()
    # the quadrature conditions of order 8, Σ b_i c_i^(k-1) = 1/k for k = 1..8 (round-off: Σ|b| ≈ 13 ulp)
    for k in range(1, 9):
        assert abs(b @ c ** (k - 1) - 1 / k) < 1e-14, k
    # and two of the tree conditions of order 3 and 4, Σ b_i a_ij c_j = 1/6, Σ b_i c_i a_ij c_j = 1/8
    assert abs(b @ A @ c - 1 / 6) < 1e-14
    assert abs((b * c) @ A @ c - 1 / 8) < 1e-14


def test_bad_tableau_is_rejected():
    with pytest.raises(ValueError, match="explicit tableau"):
        explicit_rk([(), (0.5, 0.5)], [0.5, 0.5], [0.0, 1.0])  # row 2 is implicit (a_22 ≠ 0)
    with pytest.raises(ValueError, match="explicit tableau"):
        explicit_rk([(), (1.0,)], [1.0], [0.0, 1.0])


def _classical_rk4(state, force_fn, t, dt):
    """Classical RK4 written out by hand on ``rb.derivative`` (an independent check of the driver)."""
    f = lambda s, tt: rb.derivative(s, force_fn(s, tt))
    k1 = f(state, t)
    k2 = f(_axpy(state, dt / 2, k1), t + dt / 2)
    k3 = f(_axpy(state, dt / 2, k2), t + dt / 2)
    k4 = f(_axpy(state, dt, k3), t + dt)
    out = state
    for w, k in ((1 / 6, k1), (1 / 3, k2), (1 / 3, k3), (1 / 6, k4)):
        out = _axpy(out, dt * w, k)
    q = out.orientation
    return _replace(out, orientation=q / jnp.linalg.norm(q, axis=-1, keepdims=True))


def _axpy(state, h, k):
    return _replace(
        state,
        position=state.position + h * k.position,
        velocity=state.velocity + h * k.velocity,
        orientation=state.orientation + h * k.orientation,
        angular_momentum=state.angular_momentum + h * k.angular_momentum,
    )


def test_rk4_is_the_driver_with_the_classical_tableau():
    # "rk4" (the generic driver with the classical tableau) against RK4 written out by hand:
    # 20 steps with a time-varying torque agree to round-off (1e-13: same arithmetic up to
    # summation order)
    I, w0 = BODIES["aniso"]
    s = rb.State.create(rb.Body(1.0, I), orientation=Q0, angular_velocity=w0, velocity=[0.1, 0.2, 0.3])

    @jax.jit
    def both(s):
        body = lambda k, ab: (
            _classical_rk4(ab[0], _tau_fn, 0.05 * k, 0.05),
            rb.step(ab[1], _tau_fn, 0.05, "rk4", t0=0.05 * k),
        )
        return jax.lax.fori_loop(0, 20, body, (s, s))

    a, b = both(s)
    np.testing.assert_allclose(b.time, 20 * 0.05, rtol=1e-15)  # rb.step advances the state's time
    a, b = dataclasses.replace(a, time=b.time), b  # the hand-written step leaves it alone
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-13, atol=1e-13)


def _rot(a, b, c):
    return Rotation.from_euler("xyz", [a, b, c]).as_matrix()


# An asymmetric tumble with principal axes away from the body axes: the 1 : 30 : 1000
# box of test_integrators (moments ∝ 1030, 1001, 31). Its error is in the asymptotic
# regime from n = 8 on T = 4 s (local slopes measured 8.04..8.12 from n = 8 to 32).
# The generic 1 : 2 : 2.7 tumble is pre-asymptotic down to ~1e-11 (slopes 7.4 → 8.0
# between n = 16 and 64, where the error meets the reference's ~1e-12 floor).
BODIES = {
    "aniso": (_rot(0.1, 0.2, -0.3) @ np.diag([1030.0, 1001.0, 31.0]) @ _rot(0.1, 0.2, -0.3).T, [0.4, 0.3, 0.05]),
    "generic": (_rot(0.3, -0.5, 0.8) @ np.diag([1.0, 2.0, 2.7]) @ _rot(0.3, -0.5, 0.8).T, [0.9, -1.3, 0.6]),
}
Q0 = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
T = 4.0
# A time-varying world torque strong enough to more than double |ω| (0.50 -> 1.20 rad/s
# over T on the aniso box), so the stage times c_i matter.
TAU_SCALE = 300.0


def _tau_np(t):
    return TAU_SCALE * np.array([0.3 * np.sin(t), 0.2 * np.cos(2 * t), 0.1])


def _tau_fn(s, t):
    return rb.Forces(torque=TAU_SCALE * jnp.stack([0.3 * jnp.sin(t), 0.2 * jnp.cos(2 * t), 0.1 + 0 * t]))


def _masked_tau(s, t):
    # body 0 torque-free, body 1 driven: one compile covers both cases
    mask = jnp.asarray([0.0, 1.0], s.dtype)[:, None]
    return rb.Forces(torque=mask * _tau_fn(s, t).torque)


@functools.partial(jax.jit, static_argnames="force")
def _run(state, dt, n, force):
    """``n`` (traced: one compile for every step count) steps of ``"rk8"`` from t = 0."""
    return jax.lax.fori_loop(0, n, lambda k, s: rb.step(s, force, dt, "rk8", t0=k * dt), state)


@pytest.fixture(scope="module")
def references():
    I, w0 = BODIES["aniso"]
    free = reference_rotation(I, Q0, np.array(w0), np.array([0.0, T]))
    driven = reference_rotation(I, Q0, np.array(w0), np.array([0.0, T]), lambda t, q, w: _tau_np(t))
    return [(q[-1], w[-1]) for q, w in (free, driven)]


# (case -> [(n, 2n, tolerance on the observed order)]) per state form; case 0 is torque-free,
# case 1 driven. Pairs are where the local slope was measured settled, errors 3e-6 .. 5e-11.
PAIRS = {
    # (x, v, q, L): slopes 8.04..8.08 torque-free, 7.88..8.05 driven (n < 16 is pre-asymptotic
    # under the strong torque)
    rb.State: {0: [(8, 16, 0.3), (12, 24, 0.3)], 1: [(16, 32, 0.3), (24, 48, 0.3)]},
    # (x, v, R, ω): another ODE (ω̇ and the 9 entries of R integrated), another error constant.
    # Torque-free its error is ~25x smaller than (x, v, q, L)'s (ω̇ in the body frame) and falls
    # below 10x the reference's floor by n = 10: slopes 8.57, 8.38, 8.17, 7.98 from n = 3, 4, 5, 6,
    # of which (3, 6) and (4, 8) end above the floor (3.1e-10, 2.9e-11). Driven, the slope
    # approaches 8 from above and slowly: 8.40 (16), 8.35 (24), 8.24 (32), so that case gets ±0.5
    # too (still far from order 7 or 9.5).
    rb.MatrixState: {0: [(3, 6, 0.6), (4, 8, 0.5)], 1: [(16, 32, 0.5), (24, 48, 0.5)]},
}


@pytest.mark.parametrize(
    "form",
    # MatrixState: the same driver on another form; slow only by its own ~15 s compile
    [rb.State, pytest.param(rb.MatrixState, marks=pytest.mark.slow)],
)
def test_convergence_order_8(form, references):
    # Observed order log2(e(n) / e(2n)) near 8, error = rotation angle + relative ω error
    # at T, for the torque-free tumble and the driven one; every error is > 10x the
    # DOP853 reference's ~1e-12 floor.
    I, w0 = BODIES["aniso"]
    s = form.create(rb.Body(np.ones(2), np.stack([I, I])), orientation=Q0, angular_velocity=w0)
    pairs = PAIRS[form]
    errs = {}
    for n in sorted({n for ps in pairs.values() for p in ps for n in p[:2]}):
        out = _run(s, jnp.asarray(T / n), n, _masked_tau)
        st = out if form is rb.State else rb.to_state(out)
        q, w = np.asarray(st.orientation), np.asarray(rb.angular_velocity(st))
        errs[n] = [
            quat_angle(q[i], qr) + np.linalg.norm(w[i] - wr) / np.linalg.norm(wr)
            for i, (qr, wr) in enumerate(references)
        ]
    for case, ps in pairs.items():
        for n, m, tol in ps:
            observed = np.log2(errs[n][case] / errs[m][case])
            assert abs(observed - 8) < tol, (form.__name__, case, n, m, errs[n][case], errs[m][case], observed)
            assert errs[m][case] > 1e-11  # far above the reference's floor


def test_float32_reaches_its_floor():
    # float32 generic tumble, T = 4 s, n = 64: the float64 truncation error there is
    # 2.5e-14, so what remains is float32 round-off: 64 steps of 12 stages, each
    # ~eps32 = 1.2e-7 relative, accumulate to ~1e-6. Asserted: below 2e-5 (the
    # floors of every float32 method measured in tests/test_composition.py are
    # 1e-5..7e-5), above 1e-8 (it is round-off, not float64 in disguise), and the
    # state stays float32.
    I, w0 = BODIES["generic"]
    s = rb.State.create(rb.Body(1.0, I), orientation=Q0, angular_velocity=w0)
    exact = rb.torque_free(s, T)
    s32 = jax.tree.map(lambda a: a.astype(jnp.float32), s)
    out = _run(s32, jnp.asarray(T / 64, jnp.float32), 64, None)
    assert all(x.dtype == jnp.float32 for x in jax.tree.leaves(out))
    err = quat_angle(np.asarray(out.orientation, np.float64), np.asarray(exact.orientation))
    assert 1e-8 < err < 2e-5, err


def test_gradient_matches_central_differences():
    # d(loss)/d(inertia, ω0) along a direction, forward mode, vs central differences
    # with step 1e-6 (truncation O(h²) ≈ 1e-12 against round-off O(eps/h) ≈ 1e-10):
    # they agree to 1e-7 relative. 20 steps of 0.1 s with the driven torque.
    I0, w0 = (np.asarray(x) for x in BODIES["generic"])
    dI = np.array([[0.3, -0.2, 0.1], [-0.2, 0.5, 0.25], [0.1, 0.25, -0.4]])
    dw = np.array([0.2, -0.1, 0.3])

    def loss(eps):
        s = rb.State.create(rb.Body(1.0, I0 + eps * dI), orientation=Q0, angular_velocity=w0 + eps * dw)
        tr = rb.simulate(s, lambda s, t: rb.Forces(torque=_tau_fn(s, t).torque / 300), 0.1, 20, "rk8", save_every=20)
        return jnp.sum(tr.orientation[-1] * jnp.array([0.3, -1.0, 2.0, 0.5])) + jnp.sum(
            rb.angular_velocity(tr)[-1] * jnp.array([1.0, 0.2, -0.7])
        )

    # one compile: the jvp's primal outputs at ±h give the differences, its tangent at 0 the derivative
    h = 1e-6
    values, tangents = jax.jit(jax.vmap(lambda e: jax.jvp(loss, (e,), (jnp.ones_like(e),))))(jnp.asarray([0.0, h, -h]))
    analytic, fd = tangents[0], (values[1] - values[2]) / (2 * h)
    assert abs(float(analytic) - fd) < 1e-7 * max(1.0, abs(fd)), (float(analytic), fd)
