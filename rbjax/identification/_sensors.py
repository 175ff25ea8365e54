"""Sensor models: what a gyro and an accelerometer read, given the body's motion.

The residual model (:mod:`._model`) simulates the body-frame rate ``ω`` (rad/s);
these maps give the readings to compare with, each with its nuisance
parameters (fitted when their options are on):

* gyro: ``R_gᵀ ω + b`` (``gyro_rotation``: ``R_g = exp(ρ)`` maps gyro-frame
  vectors to body-frame ones; ``gyro_bias``: ``b``, rad/s; the bias is added
  in :mod:`._model`, where it is linear);
* accelerometer at ``r`` (m) from the centre of mass, in free flight (gravity
  is not sensed): ``ω̇ × r + ω × (ω × r) + b_a`` (m/s²), ``ω̇`` from the
  torque-free Euler equations ``I ω̇ = -ω × I ω``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from .._body import inverse_3x3
from .._math import quat_exp, quat_rotate_inverse_unchecked


def gyro_reading(rho: Array, w: Array) -> Array:
    """Gyro-frame reading ``R_gᵀ ω`` ``(3,)`` of the body rate ``w`` ``(3,)``, ``R_g = exp(rho)``."""
    return quat_rotate_inverse_unchecked(quat_exp(rho), w)


def accelerometer_reading(
    I: Array, w: Array, r: Array, b: Array, h: Array | None = None, h_rate: Array | None = None
) -> Array:
    """Free-flight reading ``ω̇ × r + ω × (ω × r) + b`` ``(3,)`` (body frame, m/s²).

    ``ω̇ = -I⁻¹ (ω × I ω)``: the torque-free Euler equations with the model's
    inertia ``I`` ``(3, 3)`` (any scale: ``ω̇`` does not depend on it). With
    rotors of body-frame momentum ``h`` ``(3,)`` changing at ``h_rate`` ``(3,)``
    (in the units of ``I`` times rad/s, and per s): ``ω̇ = -I⁻¹ (ω × (I ω + h) + ḣ)``.
    """
    # closed-form inverse: a batched LAPACK solve here could deadlock beside another (see _solver.solve_small)
    if h is None:
        wd = -inverse_3x3(I) @ jnp.cross(w, I @ w)
    else:  # without h_rate, the rotors' momentum is constant
        wd = -inverse_3x3(I) @ (jnp.cross(w, I @ w + h) + (0 if h_rate is None else h_rate))
    return jnp.cross(wd, r) + jnp.cross(w, jnp.cross(w, r)) + b
