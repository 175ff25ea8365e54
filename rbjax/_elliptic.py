"""Elliptic integrals and Jacobi elliptic functions in JAX (private).

Everything here runs a *fixed* number of iterations, so it traces once under
``jit``, maps under ``vmap`` and differentiates with ``grad`` (no data-dependent
loops). The parameter convention is scipy's, ``m = k²``. Functions that must
stay accurate as ``m → 1`` take the complementary parameter ``mc = 1 - m = k'²``
as well, because ``1 - m`` formed from a rounded ``m`` has no correct digits once
``mc < 1e-16``; ``mc`` is floored at ``1e-300`` (float32: ``1e-36``), so ``m = 1``
gives a large finite ``K ≈ 346``, never ``inf`` or ``NaN``.

* AGM / descending Landen (Abramowitz & Stegun 16.4, 17.6):
  ``K(m) = π / (2 a_N)`` with ``a_N = AGM(1, k')``; ``am(u|m)`` by the backward
  recurrence ``φ_{n-1} = (φ_n + asin(c_n/a_n sin φ_n)) / 2`` from
  ``φ_N = 2^N a_N u``, after reducing ``u`` modulo the period ``4K``;
  ``sn = sin φ_0``, ``cn = cos φ_0``, ``dn = sqrt(cn² + k'² sn²)``.
* Carlson's symmetric integrals ``R_F``, ``R_J`` by the duplication theorem
  (B. C. Carlson, Numer. Algorithms 10 (1995) 13-26), and on top of them, for
  ``φ ∈ [-π/2, π/2]`` (``s = sin φ``, ``c = cos φ``, ``Δ² = 1 - m s²``;
  DLMF 19.25.5, 19.25.14) ``F(φ|m) = s R_F(c², Δ², 1)`` and
  ``Π(n; φ|m) = F + (n/3) s³ R_J(c², Δ², 1, 1 - n s²)``; other ``φ`` by
  ``F(φ + jπ) = F(φ) + 2jK`` and ``Π(n; φ + jπ) = Π(n; φ) + 2jΠ(n)``.
  For ``n < -1`` the characteristic is first swapped to ``n' = m/n ∈ (-1, 0]``
  (DLMF 19.7.9), which keeps the last argument of ``R_J`` in ``[1, 2]``:
  duplication does not shrink a large ``p`` relative to ``x, y, z`` faster than
  ``4×`` per step, so ``R_J(…, 1 - n s²)`` with ``n = -1e16`` would need ~35 steps.

Iteration counts, for float64 (measured against scipy in ``tests/test_elliptic.py``):

* ``_AGM_STEPS = 12``. While ``b ≪ a`` the AGM only halves ``log(a/b)``
  (``b_{n+1}/a_{n+1} ≈ 2 sqrt(b_n/a_n)``), then converges quadratically. From
  ``k' = 1e-150`` (``mc`` at its floor) that is 9 halvings and 3 quadratic steps
  to ``c_n/a_n < 1e-17``. For ``m < 1 - 1e-8`` steps past the 7th are exact
  no-ops (``c_n`` underflows to 0).
* ``_CARLSON_STEPS = 12``. Duplication divides the spread of the arguments by 4
  per step once they are comparable; a tiny argument first grows like the AGM
  (``y ← (y + √y …)/4``, its exponent halving). The degree-5 series then errs
  by ``~ε⁶``, ``ε = max|1 - x_N/A_N|``. For the arguments used here (``x, y`` in
  ``[0, 1]`` down to ``1e-300``, ``z = 1``, ``p ∈ [1, 2]``) 11 steps leave
  ``1e-12`` and 12 reach rounding (``< 2e-15``). Arguments spread over more than
  ``~1e6`` need more steps; keep to the documented domain.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

__all__ = [
    "agm_sequence",
    "carlson_rf",
    "carlson_rj",
    "ellipf",
    "ellipj",
    "ellipk",
    "ellippi",
    "ellippi_complete",
    "jacobi_from_agm",
    "jacobi_half_period",
    "pi_complete",
    "pi_reduced",
]

_AGM_STEPS = 12
_CARLSON_STEPS = 12


def mc_floor(dtype) -> float:
    """Smallest complementary parameter ``k'²`` used (so that ``K`` stays finite)."""
    return 1e-300 if jnp.finfo(dtype).bits == 64 else 1e-36


def _floored(mc: Array) -> Array:
    # a where, not clip/maximum: those halve the gradient at equality (m = 0 is mc = 1)
    f = mc_floor(mc.dtype)
    return jnp.where(mc < f, f, mc)


def _sqrt0(x: Array) -> Array:
    """``sqrt`` with slope 0 instead of ``inf`` at 0 (``0 · inf`` would make a NaN tangent).

    Carlson's integrals get exact zeros as arguments (``R_F(0, k'², 1) = K``).
    """
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def _asfloat(*xs: ArrayLike) -> list[Array]:
    arrs = [jnp.asarray(x) for x in xs]
    floats = [a for a in arrs if jnp.issubdtype(a.dtype, jnp.floating)]
    dtype = jnp.result_type(*floats) if floats else jnp.result_type(float)
    return [a.astype(dtype) for a in arrs]


def agm_sequence(mc: ArrayLike) -> tuple[Array, Array]:
    """Descending-Landen sequences ``a_n``, ``c_n`` for ``n = 1..N`` (leading axis), ``k'² = mc``.

    ``a_0 = 1``, ``b_0 = k'``, ``a_{n+1} = (a_n + b_n)/2``, ``b_{n+1} = sqrt(a_n b_n)``,
    ``c_{n+1} = (a_n - b_n)/2``, the latter as ``c_n² / (4 a_{n+1})`` for ``n ≥ 1`` to
    avoid the cancellation in ``a_n - b_n``. ``c_0 = k`` is never used, so
    no ``sqrt(m)`` (infinite slope at ``m = 0``) is taken.
    """
    (mc,) = _asfloat(mc)
    mc = _floored(mc)
    a, b = (1 + jnp.sqrt(mc)) / 2, mc**0.25  # first step done by hand: c_1 = (1 - k')/2
    c = (1 - jnp.sqrt(mc)) / 2

    def step(carry, _):
        a, b, c = carry
        a, b = (a + b) / 2, jnp.sqrt(a * b)
        c = c * c / (4 * a)
        return (a, b, c), (a, c)

    _, (a_s, c_s) = jax.lax.scan(step, (a, b, c), None, length=_AGM_STEPS - 1)
    return jnp.concatenate([a[None], a_s]), jnp.concatenate([c[None], c_s])


def _complement(m: ArrayLike, mc: ArrayLike | None) -> tuple[Array, Array]:
    if mc is None:
        (m,) = _asfloat(m)
        return m, 1 - m
    m, mc = _asfloat(m, mc)
    return m, mc


def ellipk(m: ArrayLike, mc: ArrayLike | None = None) -> Array:
    """Complete integral of the first kind ``K(m) = ∫₀^{π/2} dθ / sqrt(1 - m sin²θ)``, ``0 ≤ m < 1``.

    ``K = π / (2 AGM(1, sqrt(1 - m)))``. Pass ``mc = 1 - m`` for full accuracy
    near ``m = 1`` (then ``m`` is ignored).
    """
    _, mc = _complement(m, mc)
    return (math.pi / 2) / agm_sequence(mc)[0][-1]


def ellipj(u: ArrayLike, m: ArrayLike, mc: ArrayLike | None = None) -> tuple[Array, Array, Array, Array]:
    """Jacobi elliptic functions ``(sn, cn, dn, am)`` of ``u`` with parameter ``0 ≤ m < 1``.

    ``am(u|m) = φ`` with ``u = F(φ|m)``; ``sn = sin φ``, ``cn = cos φ``,
    ``dn = sqrt(1 - m sn²)``. Broadcasts ``u`` against ``m``; pass ``mc = 1 - m``
    for accuracy near ``m = 1`` (then ``m`` is ignored). Absolute error
    ``~ 2 eps (1 + |u|)`` (the reduction of ``u`` modulo ``4K`` is exact only to
    rounding of ``u``).
    """
    _, mc = _complement(m, mc)
    u, mc = _asfloat(u, mc)
    return jacobi_from_agm(u, mc, *agm_sequence(mc))


def jacobi_from_agm(u: Array, mc: Array, a_s: Array, c_s: Array) -> tuple[Array, Array, Array, Array]:
    """:func:`ellipj` given the (per-parameter) AGM sequences, to reuse them across many ``u``."""
    K = (math.pi / 2) / a_s[-1]
    turns = jnp.round(u / (4 * K))
    phi = (2.0**_AGM_STEPS) * a_s[-1] * (u - 4 * K * turns)

    def back(phi, ac):
        a, c = ac
        # c_n/a_n = (1 - k')/(1 + k') < 1 at n = 1 and smaller after; clip guards rounding only
        x = jnp.clip(c / a * jnp.sin(phi), -1.0, 1.0)
        return (phi + jnp.arcsin(x)) / 2, None

    phi, _ = jax.lax.scan(back, phi, (a_s, c_s), reverse=True)
    sn, cn = jnp.sin(phi), jnp.cos(phi)
    # dn² = cn² + k'² sn²: no cancellation, and > 0 for k' > 0 (finite gradients)
    dn = jnp.sqrt(cn * cn + _floored(mc) * sn * sn)
    return sn, cn, dn, phi + 2 * math.pi * turns


def jacobi_half_period(u: Array, mc: Array, a_s: Array, c_s: Array) -> tuple[Array, Array, Array]:
    """``sn, cn, dn`` for ``|u| ≤ K/2``, with ``cn`` and ``dn`` *relatively* accurate as ``m → 1``.

    Near ``m = 1`` the Landen recurrence feeds ``asin`` arguments within ``~k'`` of
    1, so ``cn ≈ dn ≈ sech u`` carry an absolute error ``~eps/√k'``: a relative
    error ``~1e-7`` at ``u = 11``, ``k' = 1e-15``. For ``mc < 1e-17`` the first-order
    expansion in ``mc`` (A&S 16.15) is used instead:
    ``sn = tanh u + mc/4 (sinh u cosh u - u) sech² u``,
    ``cn = sech u - mc/4 (sinh u cosh u - u) tanh u sech u``,
    ``dn = sech u + mc/4 (sinh u cosh u + u) tanh u sech u``;
    for ``|u| ≤ K/2`` its first-order term is ``≤ k'`` relative, so the neglected
    second-order one is ``≤ mc`` relative: below rounding.
    """
    sn, cn, dn, _ = jacobi_from_agm(u, mc, a_s, c_s)
    tiny = mc < 1e-17
    us = jnp.where(tiny, u, 0.0)
    ch, th = jnp.cosh(us), jnp.tanh(us)
    sech = 1 / ch
    q = jnp.where(tiny, mc, 0.0) / 4
    sh_ch = th * ch * ch
    sn1 = th + q * (sh_ch - us) * sech * sech
    cn1 = sech - q * (sh_ch - us) * th * sech
    dn1 = sech + q * (sh_ch + us) * th * sech
    return jnp.where(tiny, sn1, sn), jnp.where(tiny, cn1, cn), jnp.where(tiny, dn1, dn)


def _rc1(e: Array) -> Array:
    """``R_C(1, 1 + e)`` for ``|e| < 1``: ``atan(√e)/√e`` (``e > 0``) or ``atanh(√-e)/√-e`` (``e < 0``).

    The series ``1 - e/3 + e²/5 - e³/7 + e⁴/9`` replaces both for ``|e| < 1e-3``
    (truncation ``< e⁵/11 < 1e-16``), so value and gradient are finite at 0.
    """
    small = jnp.abs(e) < 1e-3
    es = jnp.where(small, 1.0, e)
    r = jnp.sqrt(jnp.abs(es))
    big = jnp.where(es > 0, jnp.arctan(r) / r, jnp.arctanh(jnp.minimum(r, 1.0)) / r)
    series = 1 + e * (-1 / 3 + e * (1 / 5 + e * (-1 / 7 + e / 9)))
    return jnp.where(small, series, big)


def carlson_rf(x: ArrayLike, y: ArrayLike, z: ArrayLike) -> Array:
    """Carlson's ``R_F(x, y, z) = ½ ∫₀^∞ dt / sqrt((t+x)(t+y)(t+z))``, ``x, y, z ≥ 0``, at most one 0.

    Duplication ``(x, y, z) ← ((x, y, z) + λ)/4``, ``λ = √x√y + √y√z + √z√x``,
    leaves ``R_F`` unchanged; then with ``X = 1 - x/A`` etc. (``A`` the mean),
    ``E2 = XY - Z²``, ``E3 = XYZ``:
    ``R_F = A^{-1/2} (1 - E2/10 + E3/14 + E2²/24 - 3 E2 E3/44)``.
    """
    x, y, z = jnp.broadcast_arrays(*_asfloat(x, y, z))

    def step(_: int, xyz: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
        x, y, z = xyz
        sx, sy, sz = _sqrt0(x), _sqrt0(y), _sqrt0(z)
        lam = sx * sy + sy * sz + sz * sx
        return (x + lam) / 4, (y + lam) / 4, (z + lam) / 4

    xyz: tuple[Array, Array, Array] = jax.lax.fori_loop(0, _CARLSON_STEPS, step, (x, y, z))
    x, y, z = xyz
    A = (x + y + z) / 3
    X, Y = 1 - x / A, 1 - y / A
    Z = -(X + Y)
    E2 = X * Y - Z * Z
    E3 = X * Y * Z
    return (1 - E2 / 10 + E3 / 14 + E2 * E2 / 24 - 3 * E2 * E3 / 44) / jnp.sqrt(A)


def carlson_rj(x: ArrayLike, y: ArrayLike, z: ArrayLike, p: ArrayLike) -> Array:
    """Carlson's ``R_J(x, y, z, p) = 3/2 ∫₀^∞ dt / ((t+p) sqrt((t+x)(t+y)(t+z)))``.

    ``x, y, z ≥ 0`` (at most one 0), ``p > 0``. Duplication as in
    :func:`carlson_rf`, accumulating ``6 Σ_k 4^{-k} R_C(1, 1 + e_k) / d_k`` with
    ``d_k = (√p+√x)(√p+√y)(√p+√z)``, ``e_k = 4^{-3k} δ / d_k²``,
    ``δ = (p-x)(p-y)(p-z)`` (``|e_k| < 1``), plus the degree-5 series
    ``4^{-N} A^{-3/2} (1 - 3E2/14 + E3/6 + 9E2²/88 - 3E4/22 - 9E2E3/52 + 3E5/26)``.
    """
    x, y, z, p = jnp.broadcast_arrays(*_asfloat(x, y, z, p))
    delta = (p - x) * (p - y) * (p - z)

    def step(_, carry):
        x, y, z, p, total, scale = carry  # scale = 4^{-k}
        sx, sy, sz, sp = _sqrt0(x), _sqrt0(y), _sqrt0(z), jnp.sqrt(p)
        lam = sx * sy + sy * sz + sz * sx
        d = (sp + sx) * (sp + sy) * (sp + sz)
        total = total + scale * _rc1(scale**3 * delta / (d * d)) / d
        return (x + lam) / 4, (y + lam) / 4, (z + lam) / 4, (p + lam) / 4, total, scale / 4

    init = (x, y, z, p, jnp.zeros_like(x), jnp.ones_like(x))
    x, y, z, p, total, scale = jax.lax.fori_loop(0, _CARLSON_STEPS, step, init)
    A = (x + y + z + 2 * p) / 5
    X, Y, Z = 1 - x / A, 1 - y / A, 1 - z / A
    P = -(X + Y + Z) / 2
    E2 = X * Y + X * Z + Y * Z - 3 * P * P
    E3 = X * Y * Z + 2 * E2 * P + 4 * P**3
    E4 = (2 * X * Y * Z + E2 * P + 3 * P**3) * P
    E5 = X * Y * Z * P * P
    series = 1 - 3 * E2 / 14 + E3 / 6 + 9 * E2 * E2 / 88 - 3 * E4 / 22 - 9 * E2 * E3 / 52 + 3 * E5 / 26
    return scale * series / (A * jnp.sqrt(A)) + 6 * total


def _swap(n: Array, m: Array) -> tuple[Array, Array]:
    """``(n < -1, n_eff)``: ``n_eff = m/n`` where swapped, else ``n``."""
    big = n < -1
    return big, jnp.where(big, m / jnp.where(big, n, -1.0), n)


def pi_reduced(n: ArrayLike, s: ArrayLike, c: ArrayLike, d2: ArrayLike, f: ArrayLike, m: ArrayLike) -> Array:
    """``Π(n; φ|m)`` for ``φ ∈ [-π/2, π/2]`` given ``s = sin φ``, ``c = cos φ``,
    ``d2 = 1 - m s²`` and ``f = F(φ|m)``; ``n < 1``.

    ``n ≥ -1``: ``f + (n/3) s³ R_J(c², d2, 1, 1 - n s²)``. ``n < -1``: with
    ``n' = m/n`` and ``g = (1 - n)(1 - n')``, DLMF 19.7.9 as
    ``Π(n; φ) = atan2(s √g, c √d2)/√g - (n'/3) s³ R_J(c², d2, 1, 1 - n' s²)``.
    Its ``R_C`` term, written with ``atan2``, is odd in ``s`` with a finite slope
    at ``s = 0`` and ``c = 0``; and ``f`` is not used, so a small ``Π`` (large
    ``-n``) keeps its relative accuracy instead of being ``F`` minus nearly ``F``.
    """
    n, s, c, d2, f, m = _asfloat(n, s, c, d2, f, m)
    big, ne = _swap(n, m)
    s3rj = s**3 * carlson_rj(c * c, d2, jnp.ones_like(s), 1 - ne * s * s)
    g = (1 - n) * (1 - ne)
    swapped = jnp.arctan2(s * jnp.sqrt(g), c * jnp.sqrt(d2)) / jnp.sqrt(g) - ne / 3 * s3rj
    return jnp.where(big, swapped, f + n / 3 * s3rj)


def pi_complete(n: ArrayLike, m: ArrayLike, mc: ArrayLike | None = None) -> Array:
    """Complete integral of the third kind ``Π(n|m)``, ``n < 1``: :func:`pi_reduced` at ``φ = π/2``.

    ``K(m) + (n/3) R_J(0, 1 - m, 1, 1 - n)``, or for ``n < -1``
    ``π / (2√g) - (n'/3) R_J(0, 1 - m, 1, 1 - n')``. Pass ``mc = 1 - m`` for
    accuracy near ``m = 1``.
    """
    m, mc = _complement(m, mc)
    n, m, mc = _asfloat(n, m, mc)
    big, ne = _swap(n, m)
    zero = jnp.zeros_like(n + m)
    rj = carlson_rj(zero, mc, zero + 1, 1 - ne)
    g = (1 - n) * (1 - ne)
    swapped = (math.pi / 2) / jnp.sqrt(g) - ne / 3 * rj
    return jnp.where(big, swapped, ellipk(m, mc) + n / 3 * rj)


def _reduce(phi: Array) -> tuple[Array, Array, Array]:
    """``sin``, ``cos`` of ``φ`` reduced to ``[-π/2, π/2]``, and the half turns ``j``."""
    j = jnp.round(phi / math.pi)
    pr = phi - math.pi * j
    return jnp.sin(pr), jnp.cos(pr), j


def ellipf(phi: ArrayLike, m: ArrayLike) -> Array:
    """Incomplete integral of the first kind ``F(φ|m) = ∫₀^φ dθ / sqrt(1 - m sin²θ)``, any real ``φ``."""
    phi, m = _asfloat(phi, m)
    s, c, j = _reduce(phi)
    return s * carlson_rf(c * c, 1 - m * s * s, jnp.ones_like(s)) + 2 * j * ellipk(m)


def ellippi_complete(n: ArrayLike, m: ArrayLike) -> Array:
    """Complete integral of the third kind, ``n < 1``:

    ``Π(n|m) = ∫₀^{π/2} dθ / ((1 - n sin²θ) sqrt(1 - m sin²θ))``.
    """
    return pi_complete(n, m)


def ellippi(n: ArrayLike, phi: ArrayLike, m: ArrayLike) -> Array:
    """Incomplete integral of the third kind ``Π(n; φ|m) = ∫₀^φ dθ / ((1 - n sin²θ) sqrt(1 - m sin²θ))``.

    Any real ``φ``, ``n < 1``, ``0 ≤ m < 1``.
    """
    n, phi, m = _asfloat(n, phi, m)
    s, c, j = _reduce(phi)
    d2 = 1 - m * s * s
    f = s * carlson_rf(c * c, d2, jnp.ones_like(s))
    return pi_reduced(n, s, c, d2, f, m) + 2 * j * pi_complete(n, m)
