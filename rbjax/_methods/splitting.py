"""Symplectic splitting of the free rotor about the principal axes, Strang-composed with kicks.

One step of ``h`` (McLachlan 1993; Touma & Wisdom 1994; Reich 1994;
Dullweber, Leimkuhler & McLachlan 1997)::

    kick(h/2) ∘ drift(h) ∘ kick(h/2)

* kick: ``v += F/m h/2``, ``L += τ h/2`` (world), forces at the step's start
  (``t``) and end (``t + h``, after the drift): two force evaluations per step.
* drift: ``x += v h`` and the free rotor. In the principal frame (axes ``P``,
  moments ``d₁ ≤ d₂ ≤ d₃``) the rotational energy ``Σ m_i²/(2 d_i)`` is split
  into its three terms; the flow of each is an exact rotation about one
  principal axis by ``θ = m_i/d_i · t`` (orientation ``R_p ← R_p Rot_i(θ)``,
  principal-frame momentum ``m ← Rot_i(-θ) m``). They are composed
  symmetrically, ``R₁(h/2) R₂(h/2) R₃(h) R₂(h/2) R₁(h/2)``. World ``L`` is
  untouched by the drift.

Order 2 (symmetric composition). Torque-free: ``L`` (world) is bitwise exact,
``|L|`` exact, ``|q| = 1`` by construction (products of unit quaternions,
re-normalised against round-off), and the method is symplectic, so the energy
error stays bounded (``O(h²)``) with no drift over any horizon -- in float64. In
float32 the round-off of the orientation update (about ε₃₂ per step, and
correlated from step to step because the state changes little in one step)
adds an energy error that grows linearly with the number of steps, about
1e-9 per step whatever ``dt``: measured (benchmarks/float32_drift.py, 100 boxes,
|ω| ≈ 3.5 rad/s) 8.4e-5, 1.7e-4 and 4.2e-4 after 0.8, 1.6 and 4 x 10⁵ steps at
dt = 0.01 (float64: bounded, ≤ 1.1e-4, the method's own ``O(h²)`` error) and
8.9e-5 after 10⁵ steps at dt = 0.001 (float64: 1e-6). Bounding it needs a
compensated (two-word) orientation, which ``State`` does not carry; use float64
for runs of more than ~10⁴ steps that need the energy better than ~1e-5. Particles get
velocity Verlet. Cost ≈ 4x ``"euler"`` (measured: five sincos, two force
evaluations, sub-steps materialised; see :func:`free_rotor`).
Choose it for long or stiff (fast-spinning, anisotropic) runs, Dzhanibekov
flips, and anything where energy must not drift.

The principal frame is computed from the body by :func:`._common.principal_frame`
(``eigh`` outside the differentiated path, gradients by perturbation theory,
finite for spheres and symmetric tops; hoisted out of ``simulate``'s loop).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._batching import lift
from .._math import quat_conjugate, quat_multiply, quat_normalize, quat_rotate
from .._pytree import replace
from .._state import MatrixState, ParticleState, State
from . import Method, register
from ._common import kick, principal_frame, via_state

# (principal axis, fraction of h) of the symmetric composition
_SEQUENCE = ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5))


def _half_angle(theta):
    """``(cos θ/2, sin θ/2)`` up to ``O(θ⁷)`` in the angle, exactly unit: a Cayley rotation.

    With ``a ≈ tan(θ/4)`` the pair ``((1 - a²), 2a) / (1 + a²)`` is the half-angle
    cosine and sine of the angle ``θ' = 4 atan a``, and has unit norm whatever
    ``a`` is. ``a = x + x³/3 + 2x⁵/15`` (``x = θ/4``, tan's series) makes
    ``θ' = θ - 17 θ⁷/(315·4⁶) + …``: below 1.3e-5 rad for ``θ ≤ 1`` rad and at
    round-off for the angles of accurate runs (``θ ≲ 0.05``). Why not ``sin``
    and ``cos``: on XLA:CPU their range reduction and polynomials made up ~60%
    of a splitting step (measured: 2.4e7 -> 5.7e7 body-steps/s at N = 1e5,
    float32). A rotation about a principal axis by an angle that depends only
    on the conserved ``m_i`` is the exact flow of *some* function of ``m_i``
    (here ``H̃_i = m_i²/(2 d_i) + O(θ⁶)``), so each sub-step stays an exact
    Poisson map: world ``L`` exact, symplectic, bounded energy error.
    """
    x = theta / 4
    x2 = x * x
    a = x * (1 + x2 * (1 / 3 + x2 * (2 / 15)))
    r = 1 / (1 + a * a)
    return (1 - a * a) * r, 2 * a * r


def _rotate_about(qp, m, d, i, h):
    """Exact flow of ``H̃_i(m_i) ≈ m_i²/(2 d_i)`` over ``h`` about principal axis ``i`` (static).

    Angle ``θ = h m_i/d_i`` (see :func:`_half_angle`); ``qp ← qp ⊗ (cos θ/2, sin θ/2 e_i)``,
    ``m ← Rot_i(-θ) m``: with ``(i, j, k)`` cyclic, ``m_j ← c m_j + s m_k``,
    ``m_k ← c m_k - s m_j`` (``c, s = cos θ, sin θ``), ``m_i`` unchanged.
    """
    j, k = (i + 1) % 3, (i + 2) % 3
    c2, s2 = _half_angle(h * m[i] * d[i])
    c, s = 1 - 2 * s2 * s2, 2 * s2 * c2
    qw, u = qp[0], (qp[1], qp[2], qp[3])
    # (qw, u) ⊗ (c2, s2 e_i) = (qw c2 - s2 u_i, c2 u + s2 (qw e_i + u × e_i)), (u × e_i) = (0, u_k, -u_j) in (i, j, k)
    nu = {i: c2 * u[i] + s2 * qw, j: c2 * u[j] + s2 * u[k], k: c2 * u[k] - s2 * u[j]}
    nm = {i: m[i], j: c * m[j] + s * m[k], k: c * m[k] - s * m[j]}
    return jnp.stack([qw * c2 - s2 * u[i], nu[0], nu[1], nu[2]]), jnp.stack([nm[0], nm[1], nm[2]])


def free_rotor(q, L, inertia, h):
    """Orientation after the split free-rotor flow of time ``h`` (world ``L`` unchanged)."""
    d, p = principal_frame(inertia)
    inv_d = 1 / d  # loop-invariant: hoisted out of simulate's scan with the principal frame
    qp = quat_multiply(q, p)  # principal frame -> world
    m = quat_rotate(quat_conjugate(qp), L)
    # A barrier after each sub-step: chained scalar components made XLA:CPU fuse
    # the five sub-steps into one kernel that recomputed each sub-step for each
    # of its consumers (3⁵ times the work: 125 ms instead of ~1 ms per step of
    # 10⁴ bodies).
    for axis, frac in _SEQUENCE:
        qp, m = jax.lax.optimization_barrier(_rotate_about(qp, m, inv_d, axis, frac * h))
    return quat_normalize(quat_multiply(qp, quat_conjugate(p)))


def _drift(s: State, h) -> State:
    q = free_rotor(s.orientation, s.angular_momentum, s.body.inertia, h)
    return replace(s, position=s.position + s.velocity * h, orientation=q)


def _drift_particles(s: ParticleState, h) -> ParticleState:
    return replace(s, position=s.position + s.velocity * h)


def _kick_particles(s: ParticleState, f, h) -> ParticleState:
    return s if f.force is None else replace(s, velocity=s.velocity + f.force / s.mass * h)


def _strang(kick_fn, drift_fn):
    def step(state, force_fn, t, dt):
        s = lift(kick_fn)(state, force_fn(state, t), dt / 2)
        s = lift(drift_fn)(s, dt)
        return lift(kick_fn)(s, force_fn(s, t + dt), dt / 2)

    return step


splitting_state = _strang(kick, _drift)

register(
    Method(
        name="splitting",
        order=2,
        steps={
            State: splitting_state,
            MatrixState: via_state(splitting_state),
            ParticleState: _strang(_kick_particles, _drift_particles),
        },
        conserves=(
            "torque-free: L exactly, |L|, |q|; symplectic: energy error bounded, no drift in float64 "
            "(float32: round-off drift ~1e-9 per step)"
        ),
        cost=4.0,
    )
)
