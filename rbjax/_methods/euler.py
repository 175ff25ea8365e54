"""The notes' explicit Euler integration, for all three state forms.

Every update uses the old state (no update sees another's new value):

* ``State`` ``(x, v, q, L)``: ``x += v dt``; ``v += F/m dt``;
  ``q += ½ (0, ω) ⊗ q dt`` with ``ω = I_w⁻¹ L``, then ``q ← q/‖q‖``; ``L += τ dt``.
* ``MatrixState`` ``(x, v, R, ω)``: ``R += ω̃ R dt``, then re-orthonormalised by
  two Newton–Schulz polar iterations (:func:`rbjax.orthonormalize`);
  ``ω += I_w⁻¹ (τ - ω × I_w ω) dt`` with ``I_w⁻¹ = R I_L⁻¹ Rᵀ``.
* ``ParticleState``: ``x += v dt``; ``v += F/m dt``.

Gyrostats (rotors, :mod:`rbjax._rotors`): ``ω = R I_L⁻¹ (Rᵀ L - h)`` and
``h_k += τ_k dt`` in the L-form; the rotor terms of Euler's equation in the
``(x, v, R, ω)`` form.

First order. In the L-form torque-free ``L`` is exact, but ``|L|`` in body
axes and the energy grow every step (by ``dt² |L × ω|²`` in ``|L|²``-weighted
terms): choose it for teaching and for matching the notes, not for long runs.
"""

from __future__ import annotations

import math

import jax

from .._batching import lift
from .._dynamics import matrix_rates, omega_world
from .._math import (
    kick3,
    orthonormalize_unchecked,
    pure_quat_multiply,
    quat_normalize_unchecked,
)
from .._pytree import replace
from .._rotors import spin_momentum
from .._state import Forces, MatrixState, ParticleState, State
from . import specialised
from ._base import Method
from ._common import rotor_kick


def _translate(x, v, m, f: Forces, dt):
    v_new = v if f.force is None else kick3(v, f.force, m, dt)
    return x + v * dt, v_new


def euler_state(s: State, f: Forces, dt) -> State:
    """One explicit-Euler step of one body in the ``(x, v, q, L)`` form."""
    x, v = _translate(s.position, s.velocity, s.body.mass, f, dt)
    w = omega_world(s)
    if f.torque is not None:
        # A force law with a torque usually reads ω of the same state (drag): computed into memory,
        # it is one pass that XLA's CSE shares with the law's own materialised ω (rbjax._forces),
        # instead of a second pass over q, L and I⁻¹; torque-free it would only add a pass.
        w = jax.lax.optimization_barrier(w)
    q = s.orientation
    q = quat_normalize_unchecked(q + 0.5 * dt * pure_quat_multiply(w, q))
    L = s.angular_momentum if f.torque is None else s.angular_momentum + f.torque * dt
    return replace(s, position=x, velocity=v, orientation=q, angular_momentum=L, **rotor_kick(s, f, dt))


def euler_matrix(s: MatrixState, f: Forces, dt) -> MatrixState:
    """One explicit-Euler step of one body in the ``(x, v, R, ω)`` form."""
    x, v = _translate(s.position, s.velocity, s.body.mass, f, dt)
    R, w = s.rotation, s.angular_velocity
    if s.rotors is None:
        R_dot, w_dot = matrix_rates(R, w, s.body, f.torque)
    else:
        h = spin_momentum(s.rotors, s.rotor_momentum)
        h_dot = None if f.rotor_torque is None else spin_momentum(s.rotors, f.rotor_torque)
        R_dot, w_dot = matrix_rates(R, w, s.body, f.torque, h, h_dot)
    R_new = orthonormalize_unchecked(R + R_dot * dt)
    w_new = w + w_dot * dt
    return replace(s, position=x, velocity=v, rotation=R_new, angular_velocity=w_new, **rotor_kick(s, f, dt))


def euler_particles(s: ParticleState, f: Forces, dt) -> ParticleState:
    """One explicit-Euler step of one particle."""
    x, v = _translate(s.position, s.velocity, s.mass, f, dt)
    return replace(s, position=x, velocity=v)


def _batch(kernel):
    def step(state, force_fn, t, dt):
        return lift(kernel)(state, force_fn(state, t), dt)

    return step


EULER = Method(
    name="euler",
    order=1,
    steps={State: _batch(euler_state), MatrixState: _batch(euler_matrix), ParticleState: _batch(euler_particles)},
    conserves="torque-free: L exactly (L-form); nothing else — energy grows every step",
    cost=1.0,
    # benchmarks/results/stability_limits.json: the L-form keeps |L| and so |ω| bounded
    stable_dt_omega={"State": math.inf, "MatrixState": 0.13, "ParticleState": math.inf},
    kernels=specialised.kernels(specialised.euler),
    native_code=0,
    # its steps read the forces once, at the step's start state and time
    forces_at_step_start=True,
    rotors=True,
)
