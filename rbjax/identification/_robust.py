"""Robust loss by iteratively reweighted least squares (IRLS) around Levenberg–Marquardt.

Each sample of each sensor (orientation, gyro) has a weighted residual
3-vector ``r`` in units of its noise level σ. A robust loss ``ρ(|r|)`` is
minimised by repeated weighted least-squares fits ``Σ w |r|²`` with weights
``w = ρ'(|r|) / |r|`` from the previous fit (Holland & Welsch 1977):

* ``"huber"``: ``w = min(1, c / |r|)``: quadratic within ``c`` σ, linear beyond;
* ``"cauchy"``: ``w = 1 / (1 + (|r| / c)²)``: a glitch's pull fades like ``1/|r|``;

with ``c = loss_scale``. The weights multiply the sample's residual rows
(``√w``) inside the model (:mod:`._model`), so one compiled solver serves
every round. Levenberg–Marquardt is warm-started from the previous round and
the rounds stop when no weight moves by more than ``_WEIGHT_TOL``.
"""

from __future__ import annotations

import jax.numpy as jnp

LOSSES = ("squared", "huber", "cauchy")
_MAX_ROUNDS = 10
_WEIGHT_TOL = 1e-3
OUTLIER_SCALES = 2.0  # residuals beyond 2 loss_scale σ count as outliers (Gaussian 3-vectors: beyond 6 σ, p ≈ 1e-7)


def outlier_weight(loss: str) -> float:
    """The weight of a residual at ``OUTLIER_SCALES · loss_scale``: samples weighted below it are outliers."""
    if loss == "huber":
        return 1 / OUTLIER_SCALES
    if loss == "cauchy":
        return 1 / (1 + OUTLIER_SCALES**2)
    return 0.0  # squared loss: nothing is down-weighted


def weights(r, rw_used, loss: str, c):
    """New IRLS weights ``(S, B, K+1)`` from the model's residuals ``r`` weighted by ``√rw_used``."""
    S, B, K1 = rw_used.shape
    rows = r[: S * B * K1 * 3].reshape(S, B, K1, 3) / jnp.sqrt(rw_used)[..., None]
    u = jnp.sqrt(jnp.sum(rows**2, -1)) / c  # forward only (no gradient): the norm at 0 is harmless
    if loss == "huber":
        return 1 / jnp.maximum(u, 1)
    return 1 / (1 + u**2)


def another_round(rw_used, rw_new, round):
    """Whether round ``round`` (0-based) is followed by another: a weight moved by more than ``_WEIGHT_TOL``."""
    return (jnp.max(jnp.abs(rw_new - rw_used)) > _WEIGHT_TOL) & (round + 1 < _MAX_ROUNDS)
