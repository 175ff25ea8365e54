"""Symplectic splitting of the free rotor about its middle axis, Strang-composed with kicks.

One step of ``h``::

    kick(h/2) ∘ drift(h) ∘ kick(h/2)

* kick: ``v += F/m h/2``, ``L += τ h/2`` (world), forces at the step's start
  (``t``) and end (``t + h``, after the drift): two force evaluations per step.
* drift: ``x += v h`` and the free rotor. In the principal frame (axes ``P``,
  moments ``d₁ ≤ d₂ ≤ d₃``, ``e_i = 1/d_i``, momentum ``m = R_pᵀ L``) the
  rotational energy is split about the middle moment::

      H = |m|²/(2 d₂)  +  ½ (e₁ - e₂) m₁²  +  ½ (e₃ - e₂) m₃²
        =     H_L      +       H₁        +       H₃

  Each term has an exact flow. ``H_L`` is a Casimir of the body-frame motion:
  it turns the body about the fixed world ``L`` by ``|L| t/d₂``
  (``R ← Rot_L(|L| t/d₂) R``, ``m`` unchanged) and commutes with everything.
  ``H_i`` turns the body about principal axis ``i`` by ``θ = (e_i - e₂) m_i t``
  (``R_p ← R_p Rot_i(θ)``, ``m ← Rot_i(-θ) m``). One step is the symmetric
  composition ``Rot_L(h) · H₃(h/2) H₁(h) H₃(h/2)``; world ``L`` is untouched.

Why this split (Fassò 2003 compares splittings of the free rigid body): the
error of the composition comes from the commutator of ``H₁`` and ``H₃``, whose
size is ``(e₁ - e₂)(e₂ - e₃)``: it vanishes when two moments are equal, so the
drift is the *exact* free rotor for spheres and symmetric tops, and it is small
for nearly symmetric bodies. The earlier split into the three terms
``m_i²/(2 d_i)`` (McLachlan 1993; Touma & Wisdom 1994; Reich 1994; Dullweber,
Leimkuhler & McLachlan 1997) needs five rotations, is exact for no body (its
terms do not commute even for a sphere), and was, over 20 s against
:func:`rbjax.torque_free` (float64, dt = 0.05 and 0.01), 2.8x (T-handle), 7.5x
(a box 1.3 : 2.1 : 2.9) and 1600x (moments 2 : 2.05 : 3) less accurate in
orientation at the same ``dt``; its energy error was 1.35x smaller on the
T-handle, and 2.9x and 210x larger on the other two. (Of the two symmetric
orders, ``H₃`` outside was 1.1-2.4x more accurate than ``H₁`` outside on all
three.)

Each rotation is a Cayley rotation (:func:`_cayley`, rational, exactly unit),
not ``sin``/``cos``: its angle is the intended one to ``O(θ¹¹)`` and, since
it depends only on a conserved quantity of its own flow (``m_i``, or ``|L|``),
the rotation is still the exact flow of a Hamiltonian (``H_i + O(θ¹⁰)``).

Order 2 (symmetric composition). Torque-free: ``L`` (world) is bitwise exact,
``|L|`` exact, ``|q| = 1`` by construction (products of unit quaternions,
re-normalised against round-off), and the method is symplectic, so the energy
error stays bounded (``O(h²)``) with no drift over any horizon -- in float64. In
float32 the round-off of the orientation update (about ε₃₂ per step, and
correlated from step to step because the state changes little in one step)
adds an energy error that grows linearly with the number of steps, about
1.4e-9 per step whatever ``dt``: measured (benchmarks/float32_drift.py, 100 boxes,
|ω| ≈ 3.5 rad/s) 1.1e-4, 2.3e-4 and 5.7e-4 after 0.8, 1.6 and 4 x 10⁵ steps at
dt = 0.01 (float64: bounded, ≤ 2.1e-5, the method's own ``O(h²)`` error) and
2.8e-4 after 10⁵ steps at dt = 0.001 (float64: 2.1e-7). Bounding it needs a
compensated (two-word) orientation, which ``State`` does not carry; use float64
for runs of more than ~10⁴ steps that need the energy better than ~1e-5. Particles get
velocity Verlet. Cost: see ``benchmarks/integrator_cost.py`` (four rational
rotations, two force evaluations, sub-steps materialised; see :func:`free_rotor`).
Choose it for long or stiff (fast-spinning, anisotropic) runs, Dzhanibekov
flips, and anything where energy must not drift.

Gyrostats (rotors, :mod:`rbjax._rotors`): the kicks also take the rotor
momenta (``h_k += τ_k h/2``) and the drift turns the body by the split flow of
:func:`free_gyrostat` with the rotor momentum held fixed: still explicit,
symmetric (order 2), world ``L`` untouched.

The principal frame is computed from the body by :func:`rbjax._eigh3.principal_frame`
(Jacobi sweeps, :func:`rbjax._eigh3.eigh3`, outside the differentiated path),
once per ``simulate`` call, before its loop (:func:`rbjax._body.prepare`).
Gradients with respect to the inertia come from perturbation theory. Where two
moments are equal the split depends on axes the inertia does not determine,
and a perturbation that splits them is carried by ``w`` (zero by value) through
the flow of ``H_w = ½ mᵀ w m``, taken as two half-steps around the middle turn
(:func:`._common.degenerate_flow`: the identity unless differentiated). For a
sphere or a symmetric top the split is the exact flow, and the derivative is
then the exact flow's derivative to the method's ``O(h²)``: no single derivative
of the split itself exists there, since which axis is "middle" changes with the
sign of the perturbation.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._batching import lift
from .._body import principal_frame_of
from .._math import (
    dot3,
    kick3,
    quat_conjugate,
    quat_multiply,
    quat_normalize_unchecked,
    quat_rotate_inverse_unchecked,
)
from .._pytree import replace
from .._rotors import spin_momentum
from .._state import ParticleState, State
from ._base import Method
from ._common import degenerate_flow, kick, rigid_steps

# (principal axis, fraction of h) of the symmetric composition H₃(h/2) H₁(h) H₃(h/2)
_SEQUENCE = ((2, 0.5), (0, 1.0), (2, 0.5))


def _cayley(g, n2):
    """Half-angle pair of a turn by ``θ = 4 g n`` about a unit axis, as ``(cos θ/2, sin θ/2 / n)``.

    ``n = |v|`` is the length of the vector ``v`` the turn is about (given as
    ``n2 = n²``, so no square root is taken and ``n = 0`` is finite), ``g`` the
    angle per unit length over 4. With ``a = N/D ≈ tan(θ/4)`` the pair
    ``(D² - N², 2ND) / (D² + N²)`` is the half-angle cosine and sine of the angle
    ``θ' = 4 atan a`` and has unit norm whatever ``a`` is. ``N/D`` is tan's
    [5/4] Padé approximant ``x(945 - 105x² + x⁴) / (945 - 420x² + 15x⁴)``
    (``x = θ/4``), so ``θ' - θ`` is 1e-13 rad at ``θ = 1``, 2.6e-12 at 1.35
    and 2e-10 at 2 (computed in 40-digit arithmetic): round-off in float64 for
    the turns of any useful step. Why not ``sin`` and ``cos``: on XLA:CPU their
    range reduction and polynomials took more than half of a splitting step
    (measured: 2.4e7 -> 5.3e7 body-steps/s at N = 1e5, float32, five turns).
    """
    x2 = g * g * n2
    num = g * (945 + x2 * (x2 - 105))  # N / n
    den = 945 + x2 * (15 * x2 - 420)
    num2, den2 = num * num * n2, den * den
    r = 1 / (den2 + num2)
    return (den2 - num2) * r, 2 * num * den * r


def _rotate_about(qp, m, k, i, h):
    """Exact flow of ``H_i ≈ ½ k_i m_i²`` over ``h``: a turn about principal axis ``i`` (static).

    Angle ``θ = h k_i m_i`` (see :func:`_cayley`); ``qp ← qp ⊗ (cos θ/2, sin θ/2 e_i)``,
    ``m ← Rot_i(-θ) m``: with ``(i, j, k)`` cyclic, ``m_j ← c m_j + s m_k``,
    ``m_k ← c m_k - s m_j`` (``c, s = cos θ, sin θ``), ``m_i`` unchanged.
    """
    c2, t2 = _cayley(h * k[i] / 4, m[i] * m[i])
    return _turn(qp, m, i, c2, t2 * m[i])


def _turn(qp, m, i, c2, s2):
    """A turn about principal axis ``i`` (static) of half-angle cosine and sine ``c2``, ``s2``:
    ``qp ← qp ⊗ (c2, s2 e_i)``, ``m ← Rot_i(-θ) m`` (see :func:`_rotate_about`)."""
    j, l = (i + 1) % 3, (i + 2) % 3
    c, s = 1 - 2 * s2 * s2, 2 * s2 * c2
    qw, u = qp[0], (qp[1], qp[2], qp[3])
    # (qw, u) ⊗ (c2, s2 e_i) = (qw c2 - s2 u_i, c2 u + s2 (qw e_i + u × e_i)), (u × e_i) = (0, u_l, -u_j) in (i, j, l)
    nu = {i: c2 * u[i] + s2 * qw, j: c2 * u[j] + s2 * u[l], l: c2 * u[l] - s2 * u[j]}
    nm = {i: m[i], j: c * m[j] + s * m[l], l: c * m[l] - s * m[j]}
    return jnp.stack([qw * c2 - s2 * u[i], nu[0], nu[1], nu[2]]), jnp.stack([nm[0], nm[1], nm[2]])


def _turn_about_momentum(L, e2, h):
    """Exact flow of ``H_L = |L|²/(2 d₂)`` over ``h``: the world turn ``(cos φ/2, sin φ/2 L̂)``, ``φ = |L| h e₂``."""
    c2, t2 = _cayley(h * e2 / 4, dot3(L, L))
    return jnp.stack([c2, t2 * L[0], t2 * L[1], t2 * L[2]])


def free_rotor(q, L, body, h):
    """Orientation after the split free-rotor flow of time ``h`` (world ``L`` unchanged)."""
    d, p, w = principal_frame_of(body)  # computed once per simulate (rbjax._body.prepare)
    e = 1 / d
    k = jnp.stack([e[0] - e[1], e[1] * 0, e[2] - e[1]])  # k[1] unused: H₂ is inside H_L
    qp = quat_multiply(q, p)  # principal frame -> world
    m = quat_rotate_inverse_unchecked(qp, L)
    # A barrier after each sub-step: chained scalar components made XLA:CPU fuse
    # the sub-steps into one kernel that recomputed each sub-step for each of
    # its consumers (3ⁿ times the work: 125 ms instead of ~1 ms per step of 10⁴
    # bodies with five sub-steps).
    for axis, frac in _SEQUENCE:
        if axis == 0:  # the middle turn: H_w's half-flows around it keep the composition symmetric
            qp, m = degenerate_flow(qp, m, w, h / 2)
        qp, m = jax.lax.optimization_barrier(_rotate_about(qp, m, k, axis, frac * h))
        if axis == 0:
            qp, m = degenerate_flow(qp, m, w, h / 2)
    # H_L commutes with H₁ and H₃, so its two half-steps are one full turn
    qp = quat_multiply(_turn_about_momentum(L, e[1], h), qp)
    return quat_normalize_unchecked(quat_multiply(qp, quat_conjugate(p)))


# (principal axis, fraction of h) of the gyrostat's symmetric composition H₃'(h/2) H₂'(h/2) H₁'(h) H₂'(h/2) H₃'(h/2)
_GYROSTAT_SEQUENCE = ((2, 0.5), (1, 0.5), (0, 1.0), (1, 0.5), (2, 0.5))


def free_gyrostat(q, L, hb, body, h):
    """Orientation after the split flow of time ``h`` of a free gyrostat with rotor momentum ``hb`` held fixed.

    ``hb`` (body frame, kg m²/s, ``(3,)``) is ``Σ_k h_k a_k`` (:mod:`rbjax._rotors`),
    constant over the drift; world ``L`` is unchanged. In the principal frame
    (moments ``d_i``, ``e_i = 1/d_i``, momentum ``m``, rotor momentum ``η``) the
    energy ``H = Σ_i (m_i - η_i)² / (2 d_i)`` is, up to a constant,
    ``|m|²/(2 d₂) + Σ_i H_i'`` with ``H_i' = ½ (e_i - e₂) m_i² - e_i η_i m_i``:
    each ``H_i'`` depends on ``m_i`` alone, so its exact flow turns the body about
    principal axis ``i`` by ``θ_i = h ((e_i - e₂) m_i - e_i η_i)`` (``m_i`` kept),
    and ``|m|²/(2 d₂)`` turns it about world ``L`` as in :func:`free_rotor`. The
    composition ``Rot_L(h) H₃'(h/2) H₂'(h/2) H₁'(h) H₂'(h/2) H₃'(h/2)`` is symmetric:
    order 2, world ``L`` untouched, and exact when the ``H_i'`` commute (a
    symmetric top with its rotors on the symmetry axis). Turns are Cayley
    rotations (:func:`_cayley`) of their angle.
    """
    d, p, w = principal_frame_of(body)
    e = 1 / d
    k = jnp.stack([e[0] - e[1], e[1] * 0, e[2] - e[1]])
    eta = e * quat_rotate_inverse_unchecked(p, hb)
    qp = quat_multiply(q, p)
    m = quat_rotate_inverse_unchecked(qp, L)
    for axis, frac in _GYROSTAT_SEQUENCE:
        if axis == 0:
            qp, m = degenerate_flow(qp, m, w, h / 2)
        # θ = 4 g with the unit "length" n² = 1 of _cayley: a turn by the angle itself
        c2, s2 = _cayley(frac * h * (k[axis] * m[axis] - eta[axis]) / 4, jnp.ones_like(m[axis]))
        qp, m = jax.lax.optimization_barrier(_turn(qp, m, axis, c2, s2))
        if axis == 0:
            qp, m = degenerate_flow(qp, m, w, h / 2)
    qp = quat_multiply(_turn_about_momentum(L, e[1], h), qp)
    return quat_normalize_unchecked(quat_multiply(qp, quat_conjugate(p)))


def free_rotor_of_kind(q, L, body, h, kind: str):
    """:func:`free_rotor` for a body known to be ``"isotropic"`` or ``"axisymmetric"`` (about body z).

    With two equal moments one of the body turns has ``k = 0`` and is the
    identity, and the other turns about the symmetry axis: no principal frame,
    no ``eigh``. Isotropic ``I = i·1``: ``q ← Rot_L(|L| h / i) q``, the exact
    flow. Axisymmetric ``I = diag(a, a, c)``: the middle moment is ``a`` whether
    the top is oblate or prolate, so ``q ← Rot_L(|L| h / a) q Rot_z(θ)`` with
    ``θ = (1/c - 1/a) m_z h`` and ``m_z = L·n``, ``n = R e_z``: the exact flow of
    the symmetric top. Both are :func:`free_rotor` to round-off (the general
    path's two half turns about the symmetry axis of an oblate top are one turn
    here: the same angle to ``O(θ¹¹)``, see :func:`_cayley`).
    """
    e = body.inverse_inertia[0, 0]
    if kind == "axisymmetric":
        w, x, y, z = q[0], q[1], q[2], q[3]
        n = jnp.stack([2 * (x * z + w * y), 2 * (y * z - w * x), w * w - x * x - y * y + z * z])
        m_z = dot3(L, n)
        c2, t2 = _cayley(h * (body.inverse_inertia[2, 2] - e) / 4, m_z * m_z)
        s2 = t2 * m_z
        q = jnp.stack([w * c2 - z * s2, x * c2 + y * s2, y * c2 - x * s2, z * c2 + w * s2])  # q ⊗ (c2, s2 e_z)
    elif kind != "isotropic":
        raise ValueError(f"free_rotor_of_kind: kind must be 'isotropic' or 'axisymmetric', got {kind!r}")
    return quat_normalize_unchecked(quat_multiply(_turn_about_momentum(L, e, h), q))


def splitting_of_kind(state, force_fn, t, dt, kind: str, torque_free: bool):
    """The ``"splitting"`` step of a :class:`rbjax.Scene` of ``kind`` bodies (see :func:`free_rotor_of_kind`)."""

    def drift(s: State, h) -> State:
        q = free_rotor_of_kind(s.orientation, s.angular_momentum, s.body, h, kind)
        return replace(s, position=s.position + s.velocity * h, orientation=q)

    def forces(s, tt):
        f = force_fn(s, tt)
        return replace(f, torque=None) if torque_free else f

    return _strang(kick, drift)(state, forces, t, dt)


def _drift(s: State, h) -> State:
    if s.rotors is None:
        q = free_rotor(s.orientation, s.angular_momentum, s.body, h)
    else:
        hb = spin_momentum(s.rotors, s.rotor_momentum)
        q = free_gyrostat(s.orientation, s.angular_momentum, hb, s.body, h)
    return replace(s, position=s.position + s.velocity * h, orientation=q)


def _drift_particles(s: ParticleState, h) -> ParticleState:
    return replace(s, position=s.position + s.velocity * h)


def _kick_particles(s: ParticleState, f, h) -> ParticleState:
    return s if f.force is None else replace(s, velocity=kick3(s.velocity, f.force, s.mass, h))


def _strang(kick_fn, drift_fn):
    def step(state, force_fn, t, dt):
        s = lift(kick_fn)(state, force_fn(state, t), dt / 2)
        s = lift(drift_fn)(s, dt)
        return lift(kick_fn)(s, force_fn(s, t + dt), dt / 2)

    return step


splitting_state = _strang(kick, _drift)

SPLITTING = Method(
    name="splitting",
    order=2,
    steps={
        **rigid_steps(splitting_state),
        ParticleState: _strang(_kick_particles, _drift_particles),
    },
    conserves=(
        "torque-free: L exactly, |L|, |q|; symplectic: energy error bounded, no drift in float64 "
        "(float32: round-off drift ~1e-9 per step)"
    ),
    cost=2.3,
    # spheres and cylinders turn without a principal frame (free_rotor_of_kind)
    kernels={(kind, State): splitting_of_kind for kind in ("isotropic", "axisymmetric")},
    native_code=2,
    principal_frame=True,
    order_with_velocity_forces=1,
    rotors=True,
)
