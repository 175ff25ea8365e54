"""The continuous equations of motion (Newton–Euler) as a time derivative.

``derivative(state, forces)`` returns ``d(state)/dt`` in the same pytree type,
for the integrators written as ODE methods (RK4), for peers such as diffrax,
and for tests against scipy:

* ``State`` ``(x, v, q, L)``: ``ẋ = v``, ``v̇ = F/m``, ``q̇ = ½ (0, ω) ⊗ q`` with
  ``ω = I_w⁻¹ L``, ``L̇ = τ`` (Euler's law in the world frame: no gyroscopic term
  appears, it is hidden in ``I_w`` changing with ``R``).
* ``MatrixState`` ``(x, v, R, ω)``: ``Ṙ = ω̃ R``,
  ``ω̇ = I_w⁻¹ (τ - ω × I_w ω)`` (the Coriolis/gyroscopic term of the notes).
* ``ParticleState``: ``ẋ = v``, ``v̇ = F/m``.
"""

from __future__ import annotations

import jax.numpy as jnp

from ._batching import lift
from ._body import inertia_of
from ._math import _matmul3, _over, _pure_quat_multiply, cross, skew
from ._pytree import replace
from ._quantities import _omega_world
from ._state import AnyState, Forces, ParticleState, State, StateT, _apply

__all__ = ["derivative"]


def _one_derivative(s: AnyState, f: Forces) -> AnyState:
    m = s.mass if isinstance(s, ParticleState) else s.body.mass
    a = jnp.zeros_like(s.velocity) if f.force is None else _over(f.force, m)
    if isinstance(s, ParticleState):
        return replace(s, position=s.velocity, velocity=a)
    tau = jnp.zeros_like(s.velocity) if f.torque is None else f.torque
    if isinstance(s, State):
        w = _omega_world(s)
        return replace(
            s,
            position=s.velocity,
            velocity=a,
            orientation=0.5 * _pure_quat_multiply(w, s.orientation),
            angular_momentum=tau,
        )
    R, w = s.rotation, s.angular_velocity
    I_w = _matmul3(_matmul3(R, inertia_of(s.body)), R.T)
    I_w_inv = _matmul3(_matmul3(R, s.body.inverse_inertia), R.T)
    return replace(
        s,
        position=s.velocity,
        velocity=a,
        rotation=_matmul3(skew(w), R),
        angular_velocity=_apply(I_w_inv, tau - cross(w, _apply(I_w, w))),
    )


def derivative(state: StateT, forces: Forces) -> StateT:
    """Time derivative of every changing field of ``state`` under ``forces`` (world frame).

    Returns the same pytree type; its constant fields (``body``, particle
    ``mass``) are the state's own, unchanged. Shapes as the state's.
    """
    return lift(_one_derivative)(state, forces)
