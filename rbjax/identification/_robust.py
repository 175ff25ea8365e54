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

import jax
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


def irls(solve, y0, data, loss: str):
    """``solve(y, data) -> (y, r, J, ok, steps)`` repeated with IRLS weights; returns the last solve and its data."""

    def with_w(rw):
        return {**data, "seg": {**data["seg"], "rw": rw}}

    rw0 = data["seg"]["rw"]
    shapes = jax.eval_shape(solve, y0, data)
    zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    def cond(c):
        k, change = c[0], c[1]
        return (k == 0) | ((change > _WEIGHT_TOL) & (k < _MAX_ROUNDS))

    def body(c):
        k, _, rw_next, _, out, steps = c
        y = jnp.where(k == 0, y0, out[0])
        new = solve(y, with_w(rw_next))
        rw_new = weights(new[1], rw_next, loss, data["loss_scale"])
        change = jnp.max(jnp.abs(rw_new - rw_next))
        return k + 1, change, rw_new, rw_next, new, steps + new[4]

    init = (jnp.zeros((), jnp.int32), jnp.array(jnp.inf, rw0.dtype), rw0, rw0, zeros, zeros[4])
    _, _, _, rw_used, out, steps = jax.lax.while_loop(cond, body, init)
    return (out[0], out[1], out[2], out[3], steps), with_w(rw_used)
