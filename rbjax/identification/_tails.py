"""Tail probabilities of the χ² and F distributions in NumPy, for the fit's consistency tests.

They run on the host after the compiled solve: as XLA programs the incomplete
gamma and beta functions are long loops of special cases, compiled into every
fit program (and, for the joint fit's per-recording tests, into programs of
their own), for a handful of scalars per fit.

``Q(a, x) = Γ(a, x) / Γ(a)`` (regularised upper incomplete gamma) by its series
for ``x < a + 1`` and by its continued fraction otherwise, and ``I_x(a, b)``
(regularised incomplete beta) by its continued fraction (modified Lentz;
Numerical Recipes §6.2, §6.4), to ~1e-14 relative.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["chi2_sf", "f_sf"]

_EPS = 1e-15
_TINY = 1e-300
_MAX_TERMS = 10_000


def _gammaincc(a: float, x: float) -> float:
    if not (math.isfinite(a) and a > 0) or math.isnan(x):
        return math.nan
    if x <= 0:
        return 1.0
    if math.isinf(x):
        return 0.0
    log_front = a * math.log(x) - x - math.lgamma(a)
    if x < a + 1:  # series of P(a, x)
        term = total = 1.0 / a
        ap = a
        for _ in range(_MAX_TERMS):
            ap += 1
            term *= x / ap
            total += term
            if abs(term) < abs(total) * _EPS:
                break
        return max(0.0, 1.0 - total * math.exp(log_front))
    b = x + 1 - a  # continued fraction of Q(a, x)
    c, d = 1 / _TINY, 1 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1 / d
        h *= d * c
        if abs(d * c - 1) < _EPS:
            break
    return math.exp(log_front) * h


def _betacf(a: float, b: float, x: float) -> float:
    qab, qap, qam = a + b, a + 1, a - 1
    c, d = 1.0, 1 - qab * x / qap
    d = 1 / (_TINY if abs(d) < _TINY else d)
    h = d
    for m in range(1, _MAX_TERMS):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1 + aa * d
            d = 1 / (_TINY if abs(d) < _TINY else d)
            c = 1 + aa / c
            c = _TINY if abs(c) < _TINY else c
            h *= d * c
        if abs(d * c - 1) < _EPS:
            break
    return h


def _betainc(a: float, b: float, x: float) -> float:
    if not (math.isfinite(a) and math.isfinite(b) and a > 0 and b > 0) or math.isnan(x):
        return math.nan
    if x <= 0:
        return 0.0
    if x >= 1:
        return 1.0
    log_front = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    if x < (a + 1) / (a + b + 2):
        return math.exp(log_front) * _betacf(a, b, x) / a
    return 1.0 - math.exp(log_front) * _betacf(b, a, 1 - x) / b


def chi2_sf(dof, chi2) -> np.ndarray:
    """``P(χ²(ν) ≥ c)`` elementwise for ``dof = ν > 0`` and ``chi2 = c`` (NaN for a NaN or ``ν ≤ 0``)."""
    dof, chi2 = np.broadcast_arrays(np.asarray(dof, np.float64), np.asarray(chi2, np.float64))
    return np.vectorize(lambda n, c: _gammaincc(n / 2, c / 2), otypes=[np.float64])(dof, chi2)


def f_sf(dfn, dfd, f) -> np.ndarray:
    """``P(F(d₁, d₂) ≥ f)`` elementwise (``dfn = d₁``, ``dfd = d₂``): ``I_{d₂/(d₂ + d₁ f)}(d₂/2, d₁/2)``."""
    dfn, dfd, f = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (dfn, dfd, f)))
    return np.vectorize(lambda n, d, v: _betainc(d / 2, n / 2, d / (d + n * v)), otypes=[np.float64])(dfn, dfd, f)
