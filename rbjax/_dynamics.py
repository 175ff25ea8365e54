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

With rotors (a gyrostat, :mod:`rbjax._rotors`) ``ω = R I_L⁻¹ (Rᵀ L - h)``,
``ḣ_k = τ_k`` (``Forces.rotor_torque``), and in the ``(x, v, R, ω)`` form
``ω̇ = R I_L⁻¹ (Rᵀ τ - ω_b × (I_L ω_b + h) - ḣ)``.
"""

from __future__ import annotations

from typing import cast

import jax
import jax.numpy as jnp
from jax import Array

from ._batching import lift
from ._body import Body, inertia_of
from ._math import (
    apply3,
    cross_components,
    entries3,
    matvec3,
    over,
    pure_quat_multiply,
    quat_rotate_inverse_unchecked,
    quat_rotate_unchecked,
    stack3x3,
    transpose3,
)
from ._pytree import replace
from ._rotors import spin_momentum
from ._state import AnyState, Forces, ParticleState, State, StateT

__all__ = ["derivative"]


def omega_world(s: State) -> Array:
    """``ω = I_w⁻¹ L`` (world, rad/s, ``(3,)``) of one body; of a gyrostat ``R I_L⁻¹ (Rᵀ L - h)``."""
    if s.rotors is not None:
        return quat_rotate_unchecked(s.orientation, omega_body(s))
    # ω = I_w⁻¹ L = R I_L⁻¹ Rᵀ L, evaluated with quaternion rotations (no matrix)
    return quat_rotate_unchecked(
        s.orientation,
        matvec3(s.body.inverse_inertia, quat_rotate_inverse_unchecked(s.orientation, s.angular_momentum)),
    )


def omega_body(s: State) -> Array:
    """``ω_b = I_L⁻¹ (Rᵀ L - h)`` (body frame, rad/s, ``(3,)``) of one body; ``h = 0`` without rotors."""
    m = quat_rotate_inverse_unchecked(s.orientation, s.angular_momentum)
    if s.rotors is not None:
        m = m - spin_momentum(s.rotors, s.rotor_momentum)
    return matvec3(s.body.inverse_inertia, m)


def _one_derivative(s: AnyState, f: Forces) -> AnyState:
    m = s.mass if isinstance(s, ParticleState) else s.body.mass
    a = jnp.zeros_like(s.velocity) if f.force is None else over(f.force, m)
    if isinstance(s, ParticleState):
        return replace(s, position=s.velocity, velocity=a)
    tau = jnp.zeros_like(s.velocity) if f.torque is None else f.torque
    rotor = {}
    if s.rotors is not None:
        h_dot = jnp.zeros_like(cast(Array, s.rotor_momentum)) if f.rotor_torque is None else f.rotor_torque
        rotor = {"rotor_momentum": h_dot}
    if isinstance(s, State):
        w = omega_world(s)
        if f.torque is not None:
            # With a torque, a Runge-Kutta stage's L is L + h Σ a_ij τ_j, and XLA:CPU's fusion
            # emitters then outline ω's components as per-element functions called from each of
            # q̇'s four rows: scalar code, ω computed four times. Materialised, ω is one vectorised
            # pass. rk4 at N = 1e4 (float32, constant torque): 1.4 ms -> 0.18 ms per step, rk8
            # 4.5 -> 0.8 ms. Torque-free, XLA folds the stages' L back to the state's and the
            # barrier would only add a pass (rk4 1.5-2x slower), hence the condition.
            w = jax.lax.optimization_barrier(w)
        return replace(
            s,
            position=s.velocity,
            velocity=a,
            orientation=0.5 * pure_quat_multiply(w, s.orientation),
            angular_momentum=tau,
            **rotor,
        )
    if s.rotors is not None:
        h = spin_momentum(s.rotors, s.rotor_momentum)
        hd = None if f.rotor_torque is None else f.rotor_torque @ s.rotors.axes
        R_dot, w_dot = matrix_rates(s.rotation, s.angular_velocity, s.body, tau, h, hd)
        return replace(s, position=s.velocity, velocity=a, rotation=R_dot, angular_velocity=w_dot, **rotor)
    R_dot, w_dot = matrix_rates(s.rotation, s.angular_velocity, s.body, tau)
    return replace(s, position=s.velocity, velocity=a, rotation=R_dot, angular_velocity=w_dot)


def _rotation_rate(r: tuple, w: tuple) -> Array:
    # column j of Ṙ is ω × R e_j (18 products, where skew(ω) @ R takes 27)
    columns = [cross_components(w, (r[0][j], r[1][j], r[2][j])) for j in range(3)]
    return stack3x3(zip(*columns))


def rotation_rate(R: Array, w: Array) -> Array:
    """``Ṙ = ω̃ R`` (1/s, (3, 3)) for ``R`` (3, 3) body to world and world ``ω`` (3,) (rad/s)."""
    return _rotation_rate(entries3(R), (w[..., 0], w[..., 1], w[..., 2]))


def matrix_rates(
    R: Array, w: Array, body: Body, torque: Array | None, h: Array | None = None, h_dot: Array | None = None
) -> tuple[Array, Array]:
    """``(Ṙ, ω̇)`` of one body in the ``(x, v, R, ω)`` form: ``Ṙ = ω̃ R`` (1/s, (3, 3)) and
    ``ω̇ = I_w⁻¹ (τ - ω × I_w ω)`` (rad/s², world frame, (3,)).

    ``R`` (3, 3) body to world, ``ω`` (rad/s) and ``τ`` (N·m) (3,) world frame
    (``torque=None``: no torque). With ``I_w = R I_L Rᵀ``, ``ω̇`` is evaluated in
    the body frame, ``ω̇ = R I_L⁻¹ (Rᵀτ - ω_b × I_L ω_b)`` with ``ω_b = Rᵀ ω``:
    the same on rotations, and four products of a 3x3 with a vector where
    building ``I_w`` and ``I_w⁻¹`` takes four 3x3 products, which made gradients
    through the Runge–Kutta methods compile several times slower (figures in
    the CHANGELOG, 2026-12-04). Within a Runge–Kutta stage ``R`` is ``O(dt²)``
    off orthogonal, where the two forms differ: both are the same ODE on
    rotations, so the method's order is kept. The two rates read ``R``'s entries
    from one set of slices (:func:`rbjax._math.entries3`). :func:`derivative`
    (hence the Runge–Kutta methods), ``"euler"`` and the Scene's general kernel
    take their rates from here.

    A gyrostat's rotors add ``h`` and ``ḣ`` (body frame, ``(3,)``, kg m²/s and
    N m; :mod:`rbjax._rotors`): ``ω̇_b = I_L⁻¹ (Rᵀ τ - ω_b × (I_L ω_b + h) - ḣ)``.
    """
    r = entries3(R)
    rt = transpose3(r)
    w_world = (w[..., 0], w[..., 1], w[..., 2])
    w_b = apply3(rt, w_world)
    momentum = apply3(entries3(inertia_of(body)), w_b)
    if h is not None:
        momentum = tuple(p + h[..., i] for i, p in enumerate(momentum))
    gyro = cross_components(w_b, momentum)
    if h_dot is not None:
        gyro = tuple(g + h_dot[..., i] for i, g in enumerate(gyro))
    if torque is None:
        rhs = tuple(-g for g in gyro)
    else:
        tau_b = apply3(rt, (torque[..., 0], torque[..., 1], torque[..., 2]))
        rhs = tuple(t - g for t, g in zip(tau_b, gyro))
    w_dot = apply3(r, apply3(entries3(body.inverse_inertia), rhs))
    return _rotation_rate(r, w_world), jnp.stack(w_dot, axis=-1)


def derivative(state: StateT, forces: Forces) -> StateT:
    """Time derivative of every changing field of ``state`` under ``forces`` (world frame).

    Returns the same pytree type; its constant fields (``body``, particle
    ``mass``) are the state's own, unchanged. Shapes as the state's. A
    gyrostat's ``rotor_momentum`` rate is ``forces.rotor_torque`` (``ḣ_k = τ_k``,
    zero without); a rotor torque for a state without rotors is a ``ValueError``.
    """
    if forces.rotor_torque is not None and getattr(state, "rotors", None) is None:
        raise ValueError(
            "derivative: forces.rotor_torque was given, but the state has no rotors; build it with "
            "rb.State.create(..., rotors=rb.Rotors(axes, inertia)) or drop rotor_torque"
        )
    return lift(_one_derivative)(state, forces)
