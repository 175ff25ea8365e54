"""Classical RK4 on the body-frame equations: Euler's equations for ``π = Rᵀ L`` and ``q``.

The stages integrate ``(x, v, q, π)`` with

* ``ẋ = v``, ``v̇ = F/m`` (world frame);
* ``π̇ = π × ω + Rᵀ τ`` with ``ω = I_L⁻¹ π`` (Euler's equations, body frame);
* ``q̇ = ½ q ⊗ (0, ω)`` (body-frame rate on the right);

by the classical tableau, forces evaluated at each stage on the world-frame
state ``(q̂, L = R(q̂) π)`` with ``q̂ = q/|q|``; afterwards ``q`` is normalised
and ``L = R(q) π``.

Why forces see ``q̂``. At an RK4 stage ``|q| ≠ 1`` (by ``O(h²)``), and the map of
``quat_rotate(q, ·)`` is then not a rotation. Any smooth continuation of the right-hand side off
``|q| = 1`` keeps the order, so the choice is free; with ``q̂`` a force law sees
what a :class:`~rbjax.State` promises (a unit quaternion), and a law that
turns with the body costs nothing to turn back: ``ω = R̂ ω_b``, so drag
``-(b_r + c_r|ω|) ω`` is ``-(b_r + c_r|ω_b|) ω_b`` in the body frame, and a
thruster's torque ``R̂ᵀ (R̂ p × R̂ f) = p × f``. The native kernel uses this: with
gravity and drag its stages need no rotation at all (rbjax/_native/steps.h); so does the JAX
path for per-body laws (:meth:`~rbjax._force_model.PerBodyForce.on_body_in_body_frame`).

Why a second RK4. ``"rk4"`` integrates the notes' world-frame loop ``(q, L)``,
where ``ω = R I_L⁻¹ Rᵀ L`` depends on the attitude: its local error couples the
attitude's error into the rates. Here the rates obey Euler's equations, which do
not involve ``q`` at all, so their error is that of RK4 on a 3-dimensional ODE.
On the Dzhanibekov T-handle (``I = diag(1, 2, 2.8)``, ``ω₀ = (1e-3, 2, 1e-3)``,
``h = 0.01``, 100 s, float64) the energy drifts ~3e-11 here against ~1e-8 for
``"rk4"``, and the flip times match the exact solution to the step (tests/test_rk4_body.py).

What each conserves. Neither conserves the energy exactly. ``"rk4"`` keeps world
``L`` exact when there is no torque (``L̇ = τ`` is integrated exactly) and ``|π|``
only to ``O(h⁴)``; ``"rk4_body"`` has RK4's (small) error in ``|π|`` and so in
``|L|``, and world ``L``'s direction drifts at ``O(h⁴)`` per unit time through the
attitude. Both keep ``|q| = 1`` by normalisation. Order 4 for both.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from .._batching import lift
from .._force_model import PerBodyForces, sum_on_body, torque_to_body
from .._math import (
    cross,
    matvec3,
    over,
    quat_multiply,
    quat_normalize_unchecked,
    quat_rotate_inverse_unchecked,
    quat_rotate_unchecked,
)
from .._pytree import replace
from .._state import Forces, State
from ._base import Method
from ._common import project, rigid_steps
from .explicit_rk import CLASSICAL_RK4, combine

__all__ = ["rk4_body"]

_A, _B, _C = CLASSICAL_RK4


# The stages carry π (body frame) in the ``angular_momentum`` field of a State.
def _to_body(s: State) -> State:
    return replace(s, angular_momentum=quat_rotate_inverse_unchecked(s.orientation, s.angular_momentum))


def _to_world(s: State) -> State:
    return replace(s, angular_momentum=quat_rotate_unchecked(s.orientation, s.angular_momentum))


def _to_unit_world(s: State) -> State:
    q = quat_normalize_unchecked(s.orientation)
    return replace(s, orientation=q, angular_momentum=quat_rotate_unchecked(q, s.angular_momentum))


def _body_derivative(s: State, f: Forces, w: Array | None = None) -> State:
    """``(ẋ, v̇, q̇, π̇)`` of one body, stored in a State's fields (π̇ in ``angular_momentum``).

    ``f``'s force is world frame and its torque body frame (see :func:`_stage_derivative`);
    ``w``: the stage's ``ω_b = I_L⁻¹ π`` ``(3,)`` if the caller has it, else computed here.
    """
    q, pi = s.orientation, s.angular_momentum
    w = matvec3(s.body.inverse_inertia, pi) if w is None else w
    dpi = cross(pi, w) if f.torque is None else cross(pi, w) + f.torque
    a = jnp.zeros_like(s.velocity) if f.force is None else over(f.force, s.body.mass)
    dq = 0.5 * quat_multiply(q, jnp.concatenate([jnp.zeros_like(w[:1]), w]))
    return replace(s, position=s.velocity, velocity=a, orientation=dq, angular_momentum=dpi)


def _world_for_forces(y: State) -> State:
    """The world-frame stage state ``(q̂, L = R(q̂) π)`` that the forces see, ``L`` computed into memory.

    A force law that reads ``ω`` (drag) turns ``L`` back into the body frame:
    fused, XLA:CPU emits the chain ``R I⁻¹ Rᵀ R Rᵀ L`` as scalar code with
    outlined per-element functions, and the first call spends most of its time
    compiling them. When no force reads ``L`` the barrier's result is unused
    and XLA removes it (the force-free step compiles as before).
    """
    w = lift(_to_unit_world)(y)
    return replace(w, angular_momentum=jax.lax.optimization_barrier(w.angular_momentum))


def _stage_derivative(force_fn, y: State, t) -> State:
    """The right-hand side at stage ``y`` (``π`` in ``angular_momentum``), forces on its world state.

    Per-body laws (:class:`~rbjax._force_model.PerBodyForces`) are evaluated with the
    derivative, one body at a time, and give their torque in the body frame: drag reads
    ``ω_b = I_L⁻¹ π`` directly, where the world path would rotate ``π`` out and back twice.
    Any other force function sees the batch and its torque is turned back here.

    On the per-body path ``ω_b`` is computed into memory once per stage: fused, XLA:CPU
    recomputes ``I_L⁻¹ π`` in every kernel that reads it (the rows of ``π̇`` and ``q̇``, and
    with a drag torque ``|ω_b|`` in each); benchmarks/results/forces_rk4_body_omega_2026-12-04.md has the A/B.
    """
    world = _world_for_forces(y)
    if isinstance(force_fn, PerBodyForces):

        def one(s: State, w: State, *terms) -> State:
            w_b = jax.lax.optimization_barrier(matvec3(s.body.inverse_inertia, s.angular_momentum))
            f = sum_on_body(terms, w, t, omega_body=w_b)
            return _body_derivative(s, f, w_b)

        return lift(one)(y, world, *force_fn.terms)
    return lift(lambda s, f, w: _body_derivative(s, torque_to_body(f, w)))(y, force_fn(world, t), world)


def rk4_body(state: State, force_fn, t, dt) -> State:
    """One RK4 step of the body-frame equations (see the module docstring); batch-level."""
    y0 = lift(_to_body)(state)
    ks = []
    for i in range(4):
        y = combine(y0, dt, _A[i], ks[:i])
        ks.append(_stage_derivative(force_fn, y, t + _C[i] * dt))
    return lift(_to_world)(project(combine(y0, dt, _B, ks)))


RK4_BODY = Method(
    name="rk4_body",
    order=4,
    steps=rigid_steps(rk4_body),
    conserves=(
        "nothing exactly; the rates have the error of RK4 on Euler's equations (energy ~300x below "
        "'rk4' on the T-handle); world L drifts at O(dt^4) where 'rk4' keeps it exact torque-free"
    ),
    cost=3.9,
    native_code=4,
)
