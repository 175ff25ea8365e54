"""Implicit midpoint rule for the free rotor (Newton-solved), Strang-composed with kicks.

One step of ``h``: ``kick(h/2) ∘ drift(h) ∘ kick(h/2)`` as in ``"splitting"``
(forces at ``t`` and ``t + h``, never inside the implicit solve, so a force
callable needs no Jacobian), with the free rotor advanced by the midpoint rule
on the body-frame angular momentum ``Π`` (Lie–Poisson form, any body axes,
no principal frame needed)::

    (Π₁ - Π₀)/h = Π_½ × I_L⁻¹ Π_½,   Π_½ = (Π₀ + Π₁)/2,
    R₁ = R₀ cay(h ω̃_½),   ω_½ = I_L⁻¹ Π_½.

The Cayley rotation is the quaternion ``(1, h ω_½/2)/‖·‖`` (no trigonometry),
and it maps ``Π₁`` back to ``Π₀`` exactly (``(1 + h/2 ω̃)Π₁ = (1 - h/2 ω̃)Π₀`` is
the midpoint equation), so world ``L = R Π`` is unchanged by the drift; it is
kept as is. The midpoint rule preserves every quadratic invariant, here
``|Π|²`` and the energy ``½ Π·I_L⁻¹Π``: torque-free both are conserved to solver
tolerance at any step size.

Solver: Newton on ``G(Π_½) = Π_½ - Π₀ - h/2 Π_½ × I_L⁻¹ Π_½`` from ``Π_½ = Π₀``,
3x3 Jacobian solved by Cramer's rule. A fixed count keeps the usual step a
straight-line, fusible, ``vmap``-uniform program with no data-dependent loop:
``_NEWTON`` iterations (see its comment) without gradient tracking, then one
more Newton step with it. The residual after that step is tested per body
(``‖G‖ ≤ 256 ε`` of the equation's largest term); if any body misses it, a
batch-level ``lax.cond`` runs a continuation in ``h`` for the batch
(:func:`_continuation_guess`, ``_STAGES`` stages) and keeps it for those
bodies. A body whose solve still fails gets a NaN orientation from that step
on: the documented non-convergence flag, which checked mode reports as an
error naming the step and body (unchecked, test ``isnan(traj.orientation)``).
Measured (float64, 200 random boxes, random axes, 200 steps): every solve
converges at ``h|ω| ≤ 3`` (energy kept to 1e-14) and at 30; at 10 and 100,
2 and 0 of 200 bodies are flagged, the rest keep energy to 1e-12. A box
0.1x0.2x0.4 at ``h|ω| = 10``, which loses 165% of its energy in 100 steps
with the fixed count alone, keeps it to 1.4e-15. At the solution Newton's map has zero derivative in
``Π_½``, so the derivative of that last step is exactly the implicit-function
derivative ``-J⁻¹ ∂G/∂θ`` and the reverse pass stores one iteration, not all.
(Fixed-point iteration would diverge near ``h|ω| ≈ 2``; Newton does not.)

Order 2. Symmetric, time-reversible; torque-free ``L`` exact, ``|L|`` and energy
to solver tolerance wherever the solve converges (above; otherwise NaN).
Cost: eight Newton iterations, each a 3x3 Jacobian and Cramer solve, and two
force evaluations, plus one iteration's work for the residual test; measured:
``rb.methods()["implicit_midpoint"].cost``.
Choose it where energy must be kept exactly (not just bounded) or no principal
frame is wanted; ``"splitting"`` is cheaper for equal accuracy on most bodies.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._batching import lift
from .._math import (
    cross,
    dot3,
    matmul3,
    matvec3,
    quat_multiply,
    quat_normalize_unchecked,
    quat_rotate_inverse_unchecked,
    skew,
)
from .._pytree import replace
from .._state import State
from ._base import Method
from ._common import kick, rigid_steps, solve3

# Newton iterations before the differentiated one. From Π_½ = Π₀ the residual
# is squared each iteration once it is small. Measured (50 random axes per
# case, residual < 1e-14 |Π|): a generic 1:2:3 body needs 3 at h|ω| = 0.1,
# 5 at 2 and 6 at 3; an extreme moment ratio 1:30:1000 (not a physical body, but a hard
# test of the solver) 4 at 0.1, 7 at 1 and 9 at 1.5,
# and beyond h|ω| ≈ 2 it need not converge (the midpoint equation then has
# several roots; no step size that resolves the motion goes there). Seven plus
# the final one cover all of that at ~10 flops-per-component each.
_NEWTON = 7

# The fallback when those do not converge (see _continuation_guess): _STAGES
# increments of h with _STAGE_ITERATIONS Newton iterations each.
_STAGES = 16
_STAGE_ITERATIONS = 5


def _newton_iterations(dtype) -> int:
    """``_NEWTON`` in float64; one fewer in float32, whose ~1e-7 round-off the
    quadratically converging iterate reaches one iteration earlier than 1e-14
    (measured on the cases above: float32 residual < 1e-6 |Π| always one
    iteration before the float64 one is < 1e-13 |Π|)."""
    return _NEWTON if jnp.finfo(dtype).bits > 32 else _NEWTON - 1


def _newton(y, pi0, I_inv, h):
    w = matvec3(I_inv, y)
    G = y - pi0 - 0.5 * h * cross(y, w)
    J = jnp.eye(3, dtype=y.dtype) - 0.5 * h * (matmul3(skew(y), I_inv) - skew(w))
    # one materialised (4, 3) block per body: otherwise each entry of the solve
    # re-evaluates J and G inside the fused loop
    JG = jax.lax.optimization_barrier(jnp.concatenate([J, G[None]]))
    return y - solve3(JG[:3], JG[3])


def _fixed_newton(pi0, I_inv, h):
    """The fixed count of Newton iterations from ``Π_½ = Π₀`` (body frame), one body;
    the caller stops the gradient."""
    y = pi0
    for _ in range(_newton_iterations(y.dtype)):
        # materialise each iterate: fused across iterations, XLA:CPU re-evaluated
        # earlier iterations once per component of the later ones
        y = jax.lax.optimization_barrier(_newton(y, pi0, I_inv, h))
    return y


def _body_momentum(s: State):
    return quat_rotate_inverse_unchecked(s.orientation, s.angular_momentum)


def _residual(y, pi0, I_inv, h):
    """``‖G(y)‖`` and the tolerance it must meet: a few hundred ulp of the
    equation's largest term (``h/2 ‖Π_½ × ω_½‖`` can exceed ``‖Π‖`` when ``h|ω| > 2``)."""
    w = matvec3(I_inv, y)
    c = cross(y, w)
    G = y - pi0 - 0.5 * h * c
    norm = lambda v: jnp.sqrt(dot3(v, v))
    eps = jnp.finfo(y.dtype).eps
    return norm(G), 256 * eps * (norm(pi0) + norm(y) + 0.5 * jnp.abs(h) * norm(y) * norm(w))


def _fast_guess(s: State, h) -> State:
    """The fixed Newton iterations from ``Π_½ = Π₀`` (no gradient), stored in ``angular_momentum``:
    NaN there where the final Newton step from it would miss the tolerance (the body then
    needs :func:`_continuation_guess`)."""
    pi0 = jax.lax.stop_gradient(_body_momentum(s))
    I_inv = jax.lax.stop_gradient(s.body.inverse_inertia)
    y = _fixed_newton(pi0, I_inv, h)
    res, tol = _residual(_newton(y, pi0, I_inv, h), pi0, I_inv, h)
    return replace(s, angular_momentum=jnp.where(res <= tol, y, jnp.nan))


def _continuation_guess(s: State, guess: State, h) -> State:
    """Homotopy in the step: solve at ``h j/K``, ``j = 1 … K``, each from the last.

    The root at ``h = 0`` is ``Π₀``; following it in small increments of ``h``
    stays on the branch connected to it, which Newton from ``Π₀`` at the full
    ``h`` can miss (at ``h|ω| = 10`` it needed 10 iterations where 7 are run, and
    from farther it wanders between the equation's several roots).
    """
    pi0 = jax.lax.stop_gradient(_body_momentum(s))
    I_inv = jax.lax.stop_gradient(s.body.inverse_inertia)

    def iteration(k, y):
        # stage k // _STAGE_ITERATIONS solves at h (stage + 1) / _STAGES; one flat loop,
        # not unrolled: this branch is rare, and unrolled it doubled the compile time
        hj = h * (k // _STAGE_ITERATIONS + 1).astype(y.dtype) / _STAGES
        return _newton(y, pi0, I_inv, hj)

    y = jax.lax.fori_loop(0, _STAGES * _STAGE_ITERATIONS, iteration, pi0)
    kept = guess.angular_momentum
    return replace(s, angular_momentum=jnp.where(jnp.isfinite(kept), kept, y))


def _finish(s: State, guess: State, h) -> State:
    """The differentiated Newton step, the Cayley rotation, and NaN where the solve failed."""
    pi0 = _body_momentum(s)
    I_inv = s.body.inverse_inertia
    y = _newton(jax.lax.stop_gradient(guess.angular_momentum), pi0, I_inv, h)
    res, tol = _residual(jax.lax.stop_gradient(y), jax.lax.stop_gradient(pi0), jax.lax.stop_gradient(I_inv), h)
    w = matvec3(I_inv, y)
    # (1, a)/‖(1, a)‖, a = h ω/2, by components (no unbatched constant 1 stacked in)
    a = 0.5 * h * w
    n = 1 / jnp.sqrt(1 + dot3(a, a))
    cay = jnp.stack([n, a[0] * n, a[1] * n, a[2] * n])
    q = quat_normalize_unchecked(quat_multiply(s.orientation, cay))
    # not converged: NaN, the documented flag (checked mode names the step and body),
    # rather than a finite orientation off the midpoint solution
    q = jnp.where(res <= tol, q, jnp.nan)
    return replace(s, position=s.position + s.velocity * h, orientation=q)


def _drift(s: State, h) -> State:
    """The free-rotor midpoint drift of a batch (batch level, any layout)."""
    guess = lift(_fast_guess)(s, h)
    # the continuation runs only when some body needs it (a batch-level cond, so the
    # usual step costs one extra residual); under a vmap over dt both branches run
    done = jnp.all(jnp.isfinite(guess.angular_momentum))
    guess = jax.lax.cond(done, lambda g: g, lambda g: lift(_continuation_guess)(s, g, h), guess)
    return lift(_finish)(s, guess, h)


def implicit_midpoint_state(state, force_fn, t, dt):
    """One step: ``kick(dt/2) ∘ drift(dt) ∘ kick(dt/2)`` (forces at ``t`` and ``t + dt``)."""
    s = lift(kick)(state, force_fn(state, t), dt / 2)
    s = _drift(s, dt)
    return lift(kick)(s, force_fn(s, t + dt), dt / 2)


IMPLICIT_MIDPOINT = Method(
    name="implicit_midpoint",
    order=2,
    steps=rigid_steps(implicit_midpoint_state),
    conserves=(
        "torque-free: L exactly; |L| and energy to Newton tolerance where the solve converges "
        "(all tested bodies to dt·|ω| = 3, ~99% at 10-100); a failed solve gives NaN, never a wrong state"
    ),
    failure_note=(
        "for implicit_midpoint a non-finite state means its Newton solve did not converge at this "
        "dt·|ω| (even with the continuation fallback)"
    ),
    cost=34.1,
)
