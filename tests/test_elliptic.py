"""Elliptic functions and integrals (rbjax._elliptic) against scipy.special, float64.

scipy's routines are independent implementations (cephes AGM / Landen for
``ellipj``/``ellipk``, Carlson with convergence-tested loops for ``elliprf``/
``elliprj``). Tolerances are a few units of float64 rounding times the
condition of the function, stated per test.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special as sp

from rbjax import _elliptic as _E


class E:
    """The module's functions, jitted once (eager dispatch of the unrolled loops is slow)."""

    ellipk = staticmethod(jax.jit(_E.ellipk))
    ellipj = staticmethod(jax.jit(_E.ellipj))
    ellipf = staticmethod(jax.jit(_E.ellipf))
    ellippi = staticmethod(jax.jit(_E.ellippi))
    ellippi_complete = staticmethod(jax.jit(_E.ellippi_complete))
    carlson_rf = staticmethod(jax.jit(_E.carlson_rf))
    carlson_rj = staticmethod(jax.jit(_E.carlson_rj))


# grid of parameters in [0, 1), including the separatrix side 1 - 1e-8
M_GRID = np.array([0.0, 1e-12, 0.1, 0.5, 0.9, 0.99, 1 - 1e-4, 1 - 1e-6, 1 - 1e-8])


def test_ellipk_matches_scipy():
    # AGM converged to rounding: 2 ulp relative (K is well conditioned in mc)
    np.testing.assert_allclose(E.ellipk(M_GRID), sp.ellipk(M_GRID), rtol=1e-15, atol=0)
    # complementary-parameter path, down to the floor 1e-300 (K ≈ 346)
    mc = np.array([1e-20, 1e-100, 1e-300])
    np.testing.assert_allclose(E.ellipk(1 - mc, mc), sp.ellipkm1(mc), rtol=1e-15, atol=0)


def test_ellipj_matches_scipy():
    # |u| ≤ 3K (scipy's cephes switches to a first-order 1 - m expansion above
    # m = 1 - 1e-9 that ignores periodicity, so the grid stops at 1 - 1e-8).
    # Absolute 1e-14: both reduce u modulo the period and round u·eps.
    for m in M_GRID:
        u = np.linspace(-3, 3, 121) * sp.ellipk(m)
        got = np.stack([np.asarray(a) for a in E.ellipj(u, m)])
        ref = np.stack(sp.ellipj(u, m))
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-14, err_msg=f"m={m}")


def test_ellipj_inverts_ellipkinc():
    # am(F(φ|m)|m) = φ, including m = 1 - 1e-12 and |φ| up to 20 rad, where scipy's
    # ellipj is inaccurate. Tolerance 1e-15 (4.5 eps) per unit of |u| + |φ|: rounding
    # of u, of scipy's F and of the reduction modulo 4K (measured up to 3 eps per unit).
    phi = np.linspace(-20, 20, 801)
    for m in [*M_GRID, 1 - 1e-12]:
        u = sp.ellipkinc(phi, m)
        sn, cn, dn, am = E.ellipj(u, m)
        tol = 1e-15 * (1 + np.abs(u) + np.abs(phi))
        assert np.all(np.abs(np.asarray(am) - phi) < tol), m
        assert np.all(np.abs(np.asarray(sn) - np.sin(phi)) < tol), m
        assert np.all(np.abs(np.asarray(cn) - np.cos(phi)) < tol), m
        np.testing.assert_allclose(dn, np.sqrt(1 - m * np.sin(phi) ** 2), rtol=0, atol=float(tol.max()))


def test_carlson_rf_rj_match_scipy():
    rng = np.random.default_rng(0)
    # the domain torque_free uses: x, y in [0, 1] (y down to 1e-300), z = 1, p in [1, 2]
    x = rng.uniform(0, 1, 500) ** rng.choice([1, 4, 40], 500)
    y = 10.0 ** rng.uniform(-300, 0, 500)
    p = rng.uniform(1, 2, 500)
    x[:5], y[:5] = 0.0, 1e-300
    # 1e-14 relative: a few ulp after 12 duplication steps (measured: 2e-15)
    np.testing.assert_allclose(E.carlson_rf(x, y, 1.0), sp.elliprf(x, y, 1.0), rtol=1e-14)
    np.testing.assert_allclose(E.carlson_rj(x, y, 1.0, p), sp.elliprj(x, y, 1.0, p), rtol=1e-14)
    # general arguments spread over 1e-3..1e3 (documented domain: spreads ≤ ~1e6);
    # R_J's sum of 12 R_C terms rounds to ~2e-14 relative there
    a, b, c, q = 10.0 ** rng.uniform(-3, 3, (4, 500))
    np.testing.assert_allclose(E.carlson_rf(a, b, c), sp.elliprf(a, b, c), rtol=1e-14)
    np.testing.assert_allclose(E.carlson_rj(a, b, c, q), sp.elliprj(a, b, c, q), rtol=5e-14)


def _scipy_pi(n, phi, m):
    """Π(n; φ|m) from scipy's Carlson functions (valid where n s² is modest)."""
    j = np.round(phi / np.pi)
    s, c = np.sin(phi - np.pi * j), np.cos(phi - np.pi * j)
    d2 = 1 - m * s * s
    inc = s * sp.elliprf(c * c, d2, 1) + n / 3 * s**3 * sp.elliprj(c * c, d2, 1, 1 - n * s * s)
    return inc + 2 * j * (sp.elliprf(0, 1 - m, 1) + n / 3 * sp.elliprj(0, 1 - m, 1, 1 - n))


@pytest.mark.parametrize("n", [-30.0, -1.5, -1.0, -0.3, 0.0, 0.5, 0.9])
def test_first_and_third_kind(n):
    phi = np.linspace(-7, 7, 57)
    P, M = np.meshgrid(phi, M_GRID)
    # F: 1e-14 relative to max(1, |F|) (rounding of φ reduction and R_F)
    F = sp.ellipkinc(P, M)
    assert np.max(np.abs(np.asarray(E.ellipf(P, M)) - F) / np.maximum(1, np.abs(F))) < 1e-14
    # Π, including the n < -1 branch (DLMF 19.7.9), against scipy's R_F/R_J formula:
    # 5e-14 relative to max(1, |Π|) (the scipy formula itself cancels F against
    # (n/3) s³ R_J by up to |n|·eps for n = -30)
    ref = _scipy_pi(n, P, M)
    assert np.max(np.abs(np.asarray(E.ellippi(n, P, M)) - ref) / np.maximum(1, np.abs(ref))) < 5e-14


def test_third_kind_large_negative_n_vs_closed_form():
    # m = 0: Π(n; φ|0) = atan(√(1-n) tan φ)/√(1-n), exact; n = -1e12 keeps full relative
    # accuracy (no F - F cancellation): 4 ulp
    n = -1e12
    phi = np.array([0.1, 0.7, 1.2, np.pi / 2 - 1e-9])
    ref = np.arctan(np.sqrt(1 - n) * np.tan(phi)) / np.sqrt(1 - n)
    np.testing.assert_allclose(E.ellippi(n, phi, 0.0), ref, rtol=1e-15)
    np.testing.assert_allclose(E.ellippi_complete(n, 0.0), np.pi / 2 / np.sqrt(1 - n), rtol=1e-15)


def test_gradients_finite_and_correct():
    # d sn/du = cn dn and dK/dm = (E - (1-m) K) / (2 m (1-m)) are closed forms, so no
    # finite differences are needed; 1e-13 (a few ulp of the O(1) derivatives).
    dsn = jax.jit(jax.vmap(jax.grad(lambda u, m: _E.ellipj(u, m)[0]), in_axes=(0, None)))
    jac = E.ellipj
    u = jnp.linspace(-5.0, 5.0, 21)
    for m in (0.0, 0.3, 0.9, 1 - 1e-8):
        _, cn, dn, _ = jac(u, m)
        np.testing.assert_allclose(dsn(u, m), cn * dn, rtol=0, atol=1e-13)
    dk = jax.jit(jax.vmap(jax.grad(_E.ellipk)))
    m = np.array([0.1, 0.5, 0.9])
    np.testing.assert_allclose(dk(m), (sp.ellipe(m) - (1 - m) * sp.ellipk(m)) / (2 * m * (1 - m)), rtol=1e-13)
    # at m = 0 the AGM takes no sqrt(m): finite slope π/8
    np.testing.assert_allclose(dk(jnp.zeros(1)), [np.pi / 8], rtol=1e-14)
    # at m = 1 (floored) the value and gradient stay finite
    v, g = jax.jit(jax.value_and_grad(lambda m: _E.ellipj(3.0, m)[1]))(1.0)
    assert np.isfinite(v) and np.isfinite(g)
