"""Log-Cholesky inertia parametrisation: round trip, validity of every draw, gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import rbjax as rb


def test_known_body_round_trip():
    # a box: Σ = m/12 diag(a², b², c²) exactly, so θ is known in closed form
    m, size = 2.0, np.array([0.3, 0.5, 0.7])
    I = rb.box(m, jnp.asarray(size)).inertia
    theta = rb.params_from_inertia(I)
    expect = np.concatenate([np.log(np.sqrt(m / 12) * size), np.zeros(3)])
    # float64 Cholesky of a diagonal matrix: a few ulp
    np.testing.assert_allclose(theta, expect, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(rb.inertia_from_params(theta), I, rtol=1e-14, atol=1e-16)


def test_random_round_trip_and_every_draw_is_valid():
    rng = np.random.default_rng(0)
    # wide draws: diagonal logs over ±4 (moments spanning ~7 decades), off-diagonals up to ±30
    theta = np.concatenate([rng.uniform(-4, 4, (20000, 3)), rng.normal(0, 10, (20000, 3))], axis=1)
    I = np.asarray(rb.inertia_from_params(jnp.asarray(theta)))
    # the library's own validation (symmetry, positive definite, triangle inequality) on the whole batch
    rb.Body(np.ones(len(I)), I)
    moments = np.linalg.eigvalsh(I)
    assert np.all(moments[:, 0] > 0)
    assert np.all(moments[:, 0] + moments[:, 1] >= moments[:, 2] * (1 - 1e-9))
    # round trip on the better-conditioned part (cond(Σ) < 1e8): Cholesky loses ~cond·eps relative
    sigma_cond = np.linalg.cond(np.asarray(rb.second_moment(I)))
    ok = sigma_cond < 1e8
    assert ok.mean() > 0.5
    back = np.asarray(rb.params_from_inertia(jnp.asarray(I[ok])))
    err = np.abs(back - theta[ok]) / (1 + np.abs(theta[ok]))
    assert np.max(err / (sigma_cond[ok, None] * 1e-16)) < 100


def test_inconsistent_inertia_raises_or_gives_nan_under_jit():
    # moments (1, 1, 3) break the triangle inequality: Σ has a negative eigenvalue, no valid θ
    bad = jnp.diag(jnp.array([1.0, 1.0, 3.0]))
    with pytest.raises(ValueError, match="triangle inequality"):
        rb.params_from_inertia(bad)
    assert np.any(np.isnan(jax.jit(rb.params_from_inertia)(bad)))  # traced: NaN, never another inertia


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_dtype_preserved_and_float32_valid(dtype):
    theta = jnp.asarray(np.random.default_rng(1).normal(0, 1, (1000, 6)), dtype)
    I = rb.inertia_from_params(theta)
    assert I.dtype == dtype
    rb.Body(jnp.ones(1000, dtype), I)  # validation passes in float32 too


def test_gradients_match_finite_differences():
    theta = jnp.array([0.1, -0.3, 0.2, 0.5, -0.4, 0.3])
    # central differences in float64: check_grads' default tolerance (~1e-5 relative) is ample
    check_grads(rb.inertia_from_params, (theta,), order=1, modes=("fwd", "rev"))
    check_grads(rb.params_from_inertia, (rb.inertia_from_params(theta),), order=1, modes=("fwd", "rev"))
    J = jax.jacfwd(lambda t: rb.params_from_inertia(rb.inertia_from_params(t)))(theta)
    np.testing.assert_allclose(J, np.eye(6), atol=1e-12)  # identity map: Jacobian 1 to round-off
