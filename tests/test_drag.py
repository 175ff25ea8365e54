"""Air drag on a tossed body: ``fit_inertia(..., drag="linear" | "quadratic")``.

Data: Euler's equations with the body-frame damping ``τ_b = -(c₁ + c₂|ω|) ω``
integrated by scipy DOP853 (rtol = atol = 1e-12, float64): a 1 s throw at 100 Hz
that loses ~15% of |L|, gyro noise 0.005 rad/s, as real phone tosses do.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import rbjax as rb

jax.config.update("jax_enable_x64", True)

MOMENTS = np.array([1.0, 3.2, 4.1]) * 1e-4  # kg m²
TRUTH = MOMENTS / MOMENTS.sum()
GYRO_STD = 0.005  # rad/s


def drag_throw(c1, c2, seed=3, n=101, dt=0.01):
    """``(t, gyro, |L| lost)``: a tumble with drag, c₁ (N m s) and c₂ (N m s²)."""
    rng = np.random.default_rng(seed)
    w0 = np.array([3.0, 8.0, 4.0])

    def rhs(_, w):
        Iw = MOMENTS * w
        return (-np.cross(w, Iw) - (c1 + c2 * np.linalg.norm(w)) * w) / MOMENTS

    t = np.arange(n) * dt
    sol = solve_ivp(rhs, (0, t[-1]), w0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t)
    w = sol.y.T
    lost = 1 - np.linalg.norm(MOMENTS * w[-1]) / np.linalg.norm(MOMENTS * w[0])
    return t, w + rng.normal(0, GYRO_STD, w.shape), lost


# c₁ / tr I = 0.055 1/s: |L| falls ~15% in the 1 s throw
C1 = 0.055 * MOMENTS.sum()


@pytest.fixture(scope="module")
def linear():
    t, w, lost = drag_throw(C1, 0.0)
    assert 0.1 < lost < 0.2  # the real throws' ~15%
    return t, w


def test_linear_drag_is_fitted_and_its_absence_is_flagged(linear):
    t, w = linear
    res = rb.fit_inertia(t, body_rates=w, drag="linear")
    assert bool(res.model_consistent) and bool(res.converged)
    m, s = np.asarray(res.principal_moments), np.asarray(res.moment_std)
    np.testing.assert_array_less(np.abs(m - TRUTH), 3 * s)
    c, cs = np.asarray(res.drag), np.asarray(res.drag_std)
    # c₁ / tr I within 3σ, and σ small enough that this says something (under 10% of the value)
    assert abs(c[0] - C1 / MOMENTS.sum()) < 3 * cs[0] and cs[0] < 0.1 * c[0], (c, cs)
    assert c[1] == 0 and np.isnan(cs[1])  # measured c₁/trI = 0.05499 ± 0.00006 (truth 0.055)
    # the torque-free model cannot lose |L|: its residuals are far above the noise, correlated over much
    # of the throw, and the diagnosis names drag. Refused outright until 2026-12-08; now trusted only with
    # σ widened for that misfit (fixed-b) and covering the truth (measured: 0.1198 ± 0.026,
    # 0.3865 ± 0.020, 0.4937 ± 0.0057 against 0.1205, 0.3855, 0.4940), 320-560x the drag fit's σ
    plain = rb.fit_inertia(t, body_rates=w)
    assert not bool(plain.model_consistent)
    assert float(plain.rate_rms) > 3 * GYRO_STD
    assert "may be drag" in plain.diagnosis, plain.diagnosis
    mp, sp = np.asarray(plain.principal_moments), np.asarray(plain.moment_std)
    assert not bool(plain.converged) or np.all(np.abs(mp - TRUTH) < 3 * sp), (plain.diagnosis, mp, sp)
    assert np.all(sp > s), (sp, s)  # the unmodelled drag costs precision, never claims more


@pytest.mark.slow  # "quadratic" compiles its own program (~15 s)
def test_quadratic_drag_is_told_from_linear_by_the_nutation():
    # the same |L| loss (~12%) from c₂|ω| alone (c₂|ω₀| ≈ c₁ above): c₁ and c₂ are told apart only
    # as far as |ω| varies within the throw (here the flat body's nutation swings it); on this 1 s
    # throw enough that a linear fit is flagged and the quadratic fit recovers c₂ with σ a few
    # percent of it
    c2 = C1 / 9.0
    t, w, _ = drag_throw(0.0, c2)
    lin = rb.fit_inertia(t, body_rates=w, drag="linear")
    assert not bool(lin.model_consistent)
    res = rb.fit_inertia(t, body_rates=w, drag="quadratic")
    assert bool(res.model_consistent) and bool(res.converged)
    m, s = np.asarray(res.principal_moments), np.asarray(res.moment_std)
    np.testing.assert_array_less(np.abs(m - TRUTH), 3 * s)
    c, cs = np.asarray(res.drag), np.asarray(res.drag_std)
    truth = np.array([0.0, c2 / MOMENTS.sum()])
    np.testing.assert_array_less(np.abs(c - truth), 3 * cs)
    assert cs[1] < 0.1 * truth[1]


def test_bad_drag_option_raises():
    t = np.arange(50) * 0.01
    with pytest.raises(ValueError, match="drag must be None, 'linear' or 'quadratic'"):
        rb.fit_inertia(t, body_rates=np.ones((50, 3)), drag="cubic")


@pytest.mark.slow  # a joint fit with drag compiles its own program (~10 s)
def test_a_joint_fit_with_drag_converges_when_blank_segments_pad_it():
    # Nine throws pad the joint problem to twelve segments (its segment buckets): the blank ones
    # started from a scrambled copy of the last throw's start, at ω = 0, where the damping's |ω| had
    # an infinite derivative; their NaN tangents (times zero weights) stopped the solver after one
    # step with σ = inf and the drag at its start value.
    def throw(w0, seed):
        rng = np.random.default_rng(seed)
        rhs = lambda _, w: (-np.cross(w, MOMENTS * w) - C1 * w) / MOMENTS
        t = np.arange(61) * 0.01
        w = solve_ivp(rhs, (0, t[-1]), w0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t).y.T
        return t, w + rng.normal(0, GYRO_STD, w.shape)

    rng = np.random.default_rng(11)
    throws = [throw(rng.normal(0, 5, 3), seed) for seed in range(9)]
    res = rb.fit_inertia([t for t, _ in throws], body_rates=[w for _, w in throws], joint=True, drag="linear")
    assert bool(res.solver_converged) and int(res.iterations) > 1
    m, s = np.asarray(res.principal_moments), np.asarray(res.moment_std)
    assert np.all(np.isfinite(s)) and np.all(s > 0)
    np.testing.assert_array_less(np.abs(m - TRUTH), 3 * s)  # 3σ: a two-sided 0.3% miss per moment
    c, cs = np.asarray(res.drag), np.asarray(res.drag_std)
    assert abs(c[0] - C1 / MOMENTS.sum()) < 3 * cs[0] and cs[0] < 0.1 * c[0], (c, cs)
