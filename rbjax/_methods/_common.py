"""Pieces shared by the structure-preserving methods: kicks, the principal
frame, 3x3 solves, and running a ``State`` method on a ``MatrixState``.

Everything here is written for one body (lifted by the callers).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array
from jax.extend.core import Literal

from .._batching import lift
from .._math import (
    cross,
    dot3,
    kick3,
    orthonormalize_unchecked,
    quat_multiply,
    quat_normalize_unchecked,
)
from .._pytree import replace
from .._quantities import to_matrix_state, to_state
from .._state import Forces, MatrixState, State
from ._base import StepFn


def kicked_velocity(s: State, f: Forces, h) -> Array:
    """``v + F/m h`` (world frame, m/s): the velocity after a kick by the force (``v`` without one)."""
    return s.velocity if f.force is None else kick3(s.velocity, f.force, s.body.mass, h)


def rotor_kick(s, f: Forces, h) -> dict:
    """``{"rotor_momentum": h_k + τ_k h}`` of a gyrostat (``τ_k`` = ``f.rotor_torque``, N m; ``h`` in s),
    ``{}`` without rotors or rotor torque: fields to ``replace`` after a step's kick."""
    if getattr(s, "rotors", None) is None or f.rotor_torque is None:
        return {}
    return {"rotor_momentum": s.rotor_momentum + f.rotor_torque * h}


def kick(s: State, f: Forces, h) -> State:
    """``v += F/m h``, ``L += τ h`` (world frame), rotor momenta ``h_k += τ_k h``: the exact flow of constant forces."""
    L = s.angular_momentum if f.torque is None else s.angular_momentum + f.torque * h
    return replace(s, velocity=kicked_velocity(s, f, h), angular_momentum=L, **rotor_kick(s, f, h))


def solve3(A: Array, b: Array) -> Array:
    """``A⁻¹ b`` for one ``3x3`` ``A`` by Cramer's rule (explicit components, no LAPACK)."""
    c0 = cross(A[1], A[2])
    c1 = cross(A[2], A[0])
    c2 = cross(A[0], A[1])
    det = dot3(A[0], c0)
    # adj(A) = [c0 c1 c2] (as columns), so A⁻¹ b = (c0 b0 + c1 b1 + c2 b2) / det
    return (c0 * b[0] + c1 * b[1] + c2 * b[2]) / det


@jax.custom_jvp
def degenerate_flow(qp: Array, m: Array, w: Array, h: Array) -> tuple[Array, Array]:
    """The flow over ``h`` of ``H_w = ½ mᵀ w m`` for the ``w`` of :func:`principal_frame`: the identity.

    ``qp`` is the principal-frame-to-world quaternion (4,), ``m`` the momentum
    in the principal frame (3,). ``w``'s value is zero, so the flow is the
    identity and costs nothing unless differentiated; its derivative is the
    first-order flow of ``H_w``: the body turns at ``ω = dw m`` (principal
    frame), so ``d qp = ½ h qp ⊗ (0, dw m)`` and ``dm = h m × (dw m)``
    (``ṁ = m × ω``).
    """
    del w, h
    return qp, m


@degenerate_flow.defjvp
def _degenerate_flow_jvp(primals, tangents):
    qp, m, _, h = primals
    dqp, dm, dw, _ = tangents
    om = h * (dw @ m)
    zero = jnp.zeros_like(om[:1])
    dqp = dqp + 0.5 * quat_multiply(qp, jnp.concatenate([zero, om]))
    return (qp, m), (dqp, dm + cross(m, om))


def batch(kernel):
    """A batch-level step from a one-body ``kernel(state, forces, dt)`` (forces at ``t``)."""

    def step(state, force_fn, t, dt):
        return lift(kernel)(state, force_fn(state, t), dt)

    return step


def _project_one(s):
    if isinstance(s, State):
        return replace(s, orientation=quat_normalize_unchecked(s.orientation))
    if isinstance(s, MatrixState):
        return replace(s, rotation=orthonormalize_unchecked(s.rotation))
    return s


def project(state):
    """Back onto the rotation group: ``q ← q/‖q‖`` (``State``) or ``R`` re-orthonormalised
    (``MatrixState``); particles unchanged. Batch-level (lifted), any layout."""
    return lift(_project_one)(state)


def via_state(state_step):
    """Run a ``State`` step on a ``MatrixState`` by converting both ways.

    The same map in the other coordinates (``L = R I_L Rᵀ ω``; the quaternion
    from ``R`` by Shepperd's method), so the method's conservation properties
    carry over; ``force_fn`` still sees ``MatrixState``\\ s.
    """

    def step(state: MatrixState, force_fn, t, dt) -> MatrixState:
        fn = lambda s, tt: force_fn(to_matrix_state(s), tt)
        return to_matrix_state(state_step(to_state(state), fn, t, dt))

    return step


def rigid_steps(state_step: StepFn) -> dict[type, StepFn]:
    """``Method.steps`` of a ``State`` step: on ``State``, and on ``MatrixState`` through :func:`via_state`."""
    return {State: state_step, MatrixState: via_state(state_step)}


def torque_varies(force_fn, state, t) -> bool:
    """Whether ``force_fn(state, t)``'s torque depends on ``t`` or on the fields a step changes.

    Decided while tracing, by a forward walk over the jaxpr of the torque as a
    function of ``t`` and the changing fields (the body is held fixed).
    Conservative: an equation depends on them if any of its inputs does.
    """
    consts = state.constant_fields
    names = [n for n in type(state)._rbjax_data_fields if n not in consts and getattr(state, n) is not None]

    def torque(dyn, tt):
        return force_fn(replace(state, **dyn), tt).torque

    closed = jax.make_jaxpr(torque)({n: getattr(state, n) for n in names}, t)
    live = set(closed.jaxpr.invars)
    for eqn in closed.jaxpr.eqns:
        if any(not isinstance(v, Literal) and v in live for v in eqn.invars):
            live.update(eqn.outvars)
    return any(not isinstance(v, Literal) and v in live for v in closed.jaxpr.outvars)


def materialise(tree, dt):
    """``tree`` unchanged, but computed into memory once rather than fused into every use.

    XLA:CPU fuses cheap elementwise producers into each consumer and, inside a
    fused loop over ``(component, body)``, recomputes them for every output
    component. In a Runge–Kutta step with a torque that varies over the step
    (a body-fixed thruster, a driven torque) each stage's ``L`` feeds ``ω``,
    ``ω`` the next stage's ``q``, and the recomputation compounds over the
    stages: rk8 with a thruster or a driven torque runs 20–40x its torque-free
    cost without this function and about 10x faster through it. With a
    constant torque the stages are cheap to recompute and materialising costs
    more than it saves, hence :func:`torque_varies` (figures: docs/performance.md,
    "Measured reasons behind the code"). Since ``rbjax.derivative``
    materialises ``ω`` under a torque, four-stage methods (``"rk4"``,
    ``"rk4_body"``) are faster without this (see :mod:`.explicit_rk`).

    ``lax.optimization_barrier`` on the stage state does not stop this fusion
    (no gain for rk4 or rk8), although one on ``ω``
    does stop the scalar outlining that :mod:`rbjax._dynamics` avoids; a conditional's operands and
    results are always materialised, so the stage goes through one. Its
    predicate ``dt == dt`` is true unless ``dt`` is NaN (the step's result is
    NaN then either way); it is traced and the branches differ, so XLA cannot
    fold the conditional away. Under ``vmap`` over ``dt`` it becomes a
    ``select``: one more pass, no value changed.
    """
    keep = lambda u: u
    nan = lambda u: jax.tree.map(lambda a: jnp.full_like(a, jnp.nan), u)
    return jax.lax.cond(dt == dt, keep, nan, tree)
