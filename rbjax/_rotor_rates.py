"""Prescribed rotor rates as the rotor torques that realise them (:func:`rotor_rates`).

See :mod:`rbjax._rotors` for the gyrostat's equations; here ``τ_k = J_k Ω̇_k``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from jaxtyping import Float

from ._math import array_arg
from ._rotors import Rotors
from ._state import Forces
from ._typing import ArrayLike

__all__ = ["rotor_rates"]


def rotor_rates(
    rotors: Rotors,
    rates: Callable[[Any], Any] | Float[ArrayLike, "T *B k"],
    dt: Float[ArrayLike, ""] | None = None,
) -> Any:
    """The rotor torques that make the rotors follow prescribed rates ``Ω_k(t)`` (rad/s, relative to the body).

    ``τ_k = J_k Ω̇_k`` (N m), the rate of each rotor's momentum relative to the
    body (see :mod:`rbjax._rotors`), as forces for :func:`rbjax.simulate`:

    * ``rates`` a callable ``t -> (*B, k)`` (or ``(k,)``): returns a force callable
      ``(state, t) -> Forces(rotor_torque=J Ω̇(t))`` with ``Ω̇`` from ``jax.jvp``
      (the callable must be differentiable in ``t``). Each method integrates it at
      its own order, so the momenta follow ``J Ω(t)`` to that order.
    * ``rates`` an array ``(steps + 1, *B, k)`` of rates at the step times
      ``t0 + n dt`` and ``dt`` (s): returns time-series :class:`rbjax.Forces`
      ``(steps, *B, k)`` with ``τ_n = J (Ω_{n+1} - Ω_n) / dt``, constant over
      step ``n``. Every method that supports rotors integrates a constant torque
      exactly, so the momenta equal ``J Ω_n`` at every step (to round-off).

    Start the state with ``rotor_rates=Ω(t0)`` (:meth:`rbjax.State.create`).
    """
    if not isinstance(rotors, Rotors):
        raise TypeError(f"rotor_rates: rotors must be an rbjax.Rotors, got {type(rotors).__name__}")
    J = rotors.inertia
    if callable(rates):

        def forces(state: Any, t: Any) -> Any:
            t = jnp.asarray(t, state.dtype)
            _, rate = jax.jvp(lambda s: jnp.asarray(rates(s), state.dtype), (t,), (jnp.ones_like(t),))
            return Forces(rotor_torque=J.astype(state.dtype) * rate)

        return forces
    if dt is None:
        raise ValueError(
            "rotor_rates: a sampled schedule needs dt, the step (s) of the run whose step times it samples; "
            "or pass a callable t -> rates"
        )
    r = array_arg("rotor_rates", "rates", rates)
    if r.ndim < 2 or r.shape[-1] != rotors.count or r.shape[0] < 2:
        raise ValueError(
            f"rotor_rates: rates must have shape (steps + 1, *B, k) with k = {rotors.count} (rad/s at the step "
            f"times, two at least), got {tuple(r.shape)}"
        )
    h = jnp.asarray(dt, r.dtype)
    return Forces(rotor_torque=J.astype(r.dtype) * (r[1:] - r[:-1]) / h)
