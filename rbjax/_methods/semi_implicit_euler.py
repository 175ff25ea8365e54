"""Semi-implicit (symplectic) Euler: momenta first, then positions with the new momenta.

One step of ``dt`` (forces ``F``, ``τ`` evaluated once, at the old state and ``t``):

* ``State`` ``(x, v, q, L)``: ``v₁ = v + F/m dt``, ``x₁ = x + v₁ dt``;
  ``L₁ = L + τ dt``; ``ω = R₀ I_L⁻¹ R₀ᵀ L₁`` (new momentum, old attitude);
  ``q₁ = exp(ω dt) ⊗ q`` with the exact quaternion exponential (then
  re-normalised against round-off).
* ``MatrixState``: the same map in ``(x, v, R, ω)`` coordinates
  (``L = R I_L Rᵀ ω``; ``R₁ = exp(ω̃ dt) R``; ``ω₁ = R₁ I_L⁻¹ R₁ᵀ L₁``).
* ``ParticleState``: ``v₁ = v + F/m dt``, ``x₁ = x + v₁ dt`` (symplectic Euler).
* Gyrostats (:mod:`rbjax._rotors`): the kick also takes ``h_k₁ = h_k + τ_k dt``,
  and ``ω = R₀ I_L⁻¹ (R₀ᵀ L₁ - h₁)``; a gyrostat's ``MatrixState`` runs the
  ``State`` step through the conversion (the same map).

Order 1. Conserves: torque-free ``L`` (world) exactly, ``|q| = 1`` to round-off;
for particles in conservative fields the energy error stays bounded (it is
symplectic in translation). Its rotation ``exp(ω dt)`` with ``ω`` frozen over
the step (Lie–Euler) keeps ``|L|`` in body axes, but torque-free the map agrees
with explicit Euler to ``O(dt²)`` per step, so the rotational energy of a
tumbling body grows as Euler's does (measured in tests/test_stability.py).
Measured cost: ``rb.methods()["semi_implicit_euler"].cost``. Choose it where
a game engine would: cheap, robust, one force evaluation per step, first order.
"""

from __future__ import annotations

import math

from .._dynamics import omega_world
from .._math import (
    kick3,
    matmul3,
    matvec3,
    orthonormalize_unchecked,
    quat_exp,
    quat_multiply,
    quat_normalize_unchecked,
    quat_to_matrix_unchecked,
)
from .._pytree import replace
from .._state import Forces, MatrixState, ParticleState, State
from ._base import Method
from ._common import batch, kick, via_state


def semi_implicit_state(s: State, f: Forces, dt) -> State:
    """One semi-implicit Euler step of one body in the ``(x, v, q, L)`` form."""
    s = kick(s, f, dt)
    q = quat_normalize_unchecked(quat_multiply(quat_exp(omega_world(s) * dt), s.orientation))
    return replace(s, position=s.position + s.velocity * dt, orientation=q)


def semi_implicit_matrix(s: MatrixState, f: Forces, dt) -> MatrixState:
    """One semi-implicit Euler step of one body in the ``(x, v, R, ω)`` form."""
    R, I, I_inv = s.rotation, s.body.inertia, s.body.inverse_inertia
    v = s.velocity if f.force is None else kick3(s.velocity, f.force, s.body.mass, dt)
    L = matvec3(R, matvec3(I, matvec3(R.T, s.angular_velocity)))
    if f.torque is not None:
        L = L + f.torque * dt
    w = matvec3(R, matvec3(I_inv, matvec3(R.T, L)))
    # one Newton–Schulz pass stops round-off in the product from accumulating
    R = orthonormalize_unchecked(matmul3(quat_to_matrix_unchecked(quat_exp(w * dt)), R), iterations=1)
    w = matvec3(R, matvec3(I_inv, matvec3(R.T, L)))
    return replace(s, position=s.position + v * dt, velocity=v, rotation=R, angular_velocity=w)


def semi_implicit_particles(s: ParticleState, f: Forces, dt) -> ParticleState:
    """One symplectic-Euler step of one particle."""
    v = s.velocity if f.force is None else kick3(s.velocity, f.force, s.mass, dt)
    return replace(s, position=s.position + v * dt, velocity=v)


_state_step = batch(semi_implicit_state)
_matrix_step = batch(semi_implicit_matrix)
_gyrostat_matrix_step = via_state(_state_step)


def _matrix_or_gyrostat(state, force_fn, t, dt):
    # a gyrostat's MatrixState runs the L-form step through via_state (the same map), which
    # carries the rotors' momenta; the direct (x, v, R, ω) step knows none
    return (_matrix_step if state.rotors is None else _gyrostat_matrix_step)(state, force_fn, t, dt)


SEMI_IMPLICIT_EULER = Method(
    name="semi_implicit_euler",
    order=1,
    steps={
        State: _state_step,
        MatrixState: _matrix_or_gyrostat,
        ParticleState: batch(semi_implicit_particles),
    },
    conserves="torque-free: L exactly, |L| in body axes; energy drifts O(dt) (particles: bounded)",
    cost=1.9,
    # benchmarks/results/stability_limits.json: finite up to dt·|ω| = 1000 in both forms
    stable_dt_omega={"State": math.inf, "MatrixState": math.inf, "ParticleState": math.inf},
    native_code=3,
    # its steps read the forces once, at the step's start state and time
    forces_at_step_start=True,
    rotors=True,
)
