"""Derived quantities: pure functions of a state (single body or any batch).

Each is written for one body and lifted over the batch with ``vmap``
(:func:`rbjax._batching.lift`), so trajectories ``(T, *B)`` work too.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
from jax import Array
from jaxtyping import Float

from ._batching import lift
from ._body import inertia_of
from ._dynamics import omega_body, omega_world
from ._math import (
    array_arg,
    broadcasts_to,
    cross,
    dot3,
    matmul3,
    matrix_to_quat_unchecked,
    matvec3,
    quat_rotate_inverse_unchecked,
    quat_to_matrix_unchecked,
)
from ._pytree import is_batch_last, new_unchecked, with_batch_last
from ._rotors import rotor_energy, spin_momentum
from ._state import AnyState, MatrixState, ParticleState, RigidState, State
from ._typing import ArrayLike

__all__ = [
    "angular_momentum",
    "angular_velocity",
    "body_angular_velocity",
    "kinetic_energy",
    "linear_momentum",
    "orientation",
    "rotation_matrix",
    "to_matrix_state",
    "to_state",
    "world_inertia",
]


def _expect(state: object, fn: str, types: tuple[type, ...] = (State, MatrixState)) -> None:
    """``TypeError`` unless ``state`` is one of ``types`` (before ``lift`` fails on it obscurely)."""
    if not isinstance(state, types):
        names = " or ".join(t.__name__ for t in types)
        raise TypeError(f"{fn}: state must be a {names}, got {type(state).__name__}")


_ANY = (State, MatrixState, ParticleState)


def _one_angular_velocity(s: RigidState) -> Array:
    if isinstance(s, State):
        return omega_world(s)
    return s.angular_velocity


def angular_velocity(state: RigidState) -> Float[Array, "*B 3"]:
    """World-frame angular velocity ``ω`` (rad/s), ``(*B, 3)``.

    For :class:`State` ``ω = I_w⁻¹ L = R I_L⁻¹ Rᵀ L`` (a gyrostat's:
    ``R I_L⁻¹ (Rᵀ L - h)``, :mod:`rbjax._rotors`); for :class:`MatrixState` the stored ``ω``.
    """
    _expect(state, "angular_velocity")
    return lift(_one_angular_velocity)(state)


def _one_body_angular_velocity(s: RigidState) -> Array:
    if isinstance(s, State):
        if s.rotors is not None:
            return omega_body(s)
        return matvec3(s.body.inverse_inertia, quat_rotate_inverse_unchecked(s.orientation, s.angular_momentum))
    return matvec3(jnp.swapaxes(s.rotation, -1, -2), s.angular_velocity)


def body_angular_velocity(state: RigidState) -> Float[Array, "*B 3"]:
    """Body-frame angular velocity ``ω_L = Rᵀ ω`` (rad/s), ``(*B, 3)``: what a gyroscope reads."""
    _expect(state, "body_angular_velocity")
    return lift(_one_body_angular_velocity)(state)


def _one_rotation(s: RigidState) -> Array:
    return quat_to_matrix_unchecked(s.orientation) if isinstance(s, State) else s.rotation


def rotation_matrix(state: RigidState) -> Float[Array, "*B 3 3"]:
    """Rotation matrix ``R`` (body to world), ``(*B, 3, 3)``."""
    _expect(state, "rotation_matrix")
    return lift(_one_rotation)(state)


def _one_orientation(s: RigidState) -> Array:
    return s.orientation if isinstance(s, State) else matrix_to_quat_unchecked(s.rotation)


def orientation(state: RigidState) -> Float[Array, "*B 4"]:
    """Unit quaternion ``[w, x, y, z]`` (body to world), ``(*B, 4)``."""
    _expect(state, "orientation")
    return lift(_one_orientation)(state)


def _one_world_inertia(s: RigidState) -> Array:
    R = _one_rotation(s)
    return matmul3(matmul3(R, inertia_of(s.body)), R.T)


def world_inertia(state: RigidState) -> Float[Array, "*B 3 3"]:
    """World-frame inertia ``I_w = R I_L Rᵀ`` (kg m², about the centre of mass), ``(*B, 3, 3)``."""
    _expect(state, "world_inertia")
    return lift(_one_world_inertia)(state)


def _one_angular_momentum(s: AnyState, about: Array | None) -> Array:
    if isinstance(s, ParticleState):
        return cross(s.position - (0.0 if about is None else about), s.mass * s.velocity)
    if isinstance(s, State):
        L = s.angular_momentum
    elif s.rotors is not None:
        m = matvec3(inertia_of(s.body), matvec3(s.rotation.T, s.angular_velocity))
        L = matvec3(s.rotation, m + spin_momentum(s.rotors, s.rotor_momentum))
    else:
        L = matvec3(s.rotation, matvec3(inertia_of(s.body), matvec3(s.rotation.T, s.angular_velocity)))
    if about is not None:
        L = L + cross(s.position - about, s.body.mass * s.velocity)
    return L


def angular_momentum(state: AnyState, about: Float[ArrayLike, "*B 3"] | None = None) -> Float[Array, "*B 3"]:
    """Angular momentum (world, kg m²/s), ``(*B, 3)``.

    Rigid bodies: spin ``L = I_w ω`` about the centre of mass (a gyrostat's:
    the total ``R (I_L ω_b + h)`` of body and rotors), plus the orbital
    term ``(x - a) × m v`` when a world point ``about = a`` is given. Particles:
    ``L = r × p`` about ``about`` (default the world origin), as in the notes.
    """
    _expect(state, "angular_momentum", _ANY)
    a = None if about is None else array_arg("angular_momentum", "about", about, (3,)).astype(state.dtype)
    if a is not None:
        want = tuple(state.position.shape)
        ok = broadcasts_to(tuple(a.shape), want)
        if not ok:
            raise ValueError(
                f"angular_momentum: about of shape {tuple(a.shape)} does not fit the state's positions {want}; "
                "give one world point (3,) or one per body (*B, 3)"
            )
    if a is None:
        return lift(lambda s: _one_angular_momentum(s, None))(state)
    # the orbital term (x - a) × m v outside the per-body map: a per-body point (*B, 3) is then
    # paired with its own body (closed over in the map, it met every body: a (*B, *B, 3) result)
    if isinstance(state, ParticleState):
        m, spin = state.mass, 0.0
    else:
        m, spin = state.body.mass, lift(lambda s: _one_angular_momentum(s, None))(state)
    m = jnp.broadcast_to(m, state.batch_shape)
    return spin + cross(state.position - a, m[..., None] * state.velocity)


def _one_linear_momentum(s: AnyState) -> Array:
    m = s.mass if isinstance(s, ParticleState) else s.body.mass
    return m * s.velocity


def linear_momentum(state: AnyState) -> Float[Array, "*B 3"]:
    """Linear momentum ``p = m v`` (world, kg m/s), ``(*B, 3)``."""
    _expect(state, "linear_momentum", _ANY)
    return lift(_one_linear_momentum)(state)


def _one_kinetic_energy(s: AnyState) -> Array:
    m = s.mass if isinstance(s, ParticleState) else s.body.mass
    e = 0.5 * m * dot3(s.velocity, s.velocity)
    if isinstance(s, ParticleState):
        return e
    w = _one_angular_velocity(s)
    L = s.angular_momentum if isinstance(s, State) else _one_angular_momentum(s, None)
    if s.rotors is not None:
        # ½ ω_bᵀ I ω_b + ω_b·h + ½ Σ h_k²/J_k = ½ ω·(L + R h) + ½ Σ h_k²/J_k with L = R (I ω_b + h)
        R = _one_rotation(s)
        h = s.rotor_momentum
        return e + 0.5 * dot3(w, L + matvec3(R, spin_momentum(s.rotors, h))) + rotor_energy(s.rotors, h)
    return e + 0.5 * dot3(w, L)


def kinetic_energy(state: AnyState) -> Float[Array, "*B"]:
    """Kinetic energy ``½ m ‖v‖² + ½ ω · L`` (J), ``(*B,)``; translation only for particles.

    A gyrostat's (:mod:`rbjax._rotors`) includes its rotors:
    ``½ m ‖v‖² + ½ ω_bᵀ I_L ω_b + ω_b · h + ½ Σ_k h_k² / J_k`` (body frame, ``h_k = J_k Ω_k``).
    """
    _expect(state, "kinetic_energy", _ANY)
    return lift(_one_kinetic_energy)(state)


def to_matrix_state(state: State) -> MatrixState:
    """Convert ``(x, v, q, L)`` to ``(x, v, R, ω)`` (same motion, no validation).

    ``R = R(q)`` (body to world, ``(*B, 3, 3)``), ``ω = I_w⁻¹ L`` (world frame;
    a gyrostat's ``R I_L⁻¹ (Rᵀ L - h)``, its rotors carried over).
    """
    _expect(state, "to_matrix_state", (State,))
    return _same_motion(MatrixState, state, rotation=rotation_matrix(state), angular_velocity=angular_velocity(state))


def to_state(state: MatrixState) -> State:
    """Convert ``(x, v, R, ω)`` to ``(x, v, q, L)`` (same motion, no validation).

    ``q`` from ``R`` (body to world, ``(*B, 4)``), ``L = I_w ω`` (world frame;
    a gyrostat's total ``R (I_L ω_b + h)``, its rotors carried over).
    """
    _expect(state, "to_state", (MatrixState,))
    return _same_motion(State, state, orientation=orientation(state), angular_momentum=angular_momentum(state))


def _same_motion(cls: type, state: RigidState, **rotational: Array) -> Any:
    """A ``cls`` with ``state``'s body, position, velocity, time and rotors and the given rotational fields
    (unchecked), in ``state``'s layout (:mod:`rbjax._batching`)."""
    new = new_unchecked(
        cls,
        body=state.body,
        position=state.position,
        velocity=state.velocity,
        time=state.time,
        rotors=state.rotors,
        rotor_momentum=state.rotor_momentum,
        **rotational,
    )
    return with_batch_last(new, is_batch_last(state))
