"""Per-body kernels specialised on a scene's static body structure.

A body's inertia decides how much rotational work a step needs:

* ``"isotropic"`` (``I = i·1``: spheres, cubes): ``I_w = R I Rᵀ = i·1`` in every
  orientation, so ``ω = L / i`` needs no rotation of ``L`` into the body frame,
  and the gyroscopic term ``ω × I_w ω = i ω × ω`` vanishes.
* ``"axisymmetric"`` (``I = diag(a, a, c)``, symmetry axis body z: cylinders,
  spinning tops): with ``n = R e_z`` (third column of ``R``),
  ``I_w = a·1 + (c - a) n nᵀ``, ``I_w⁻¹ = 1/a + (1/c - 1/a) n nᵀ`` and
  ``ω × I_w ω = (c - a)(n·ω)(ω × n)``: a dot product instead of two rotations.
* ``"general"``: the full ``ω = R I⁻¹ Rᵀ L`` of :func:`rbjax.derivative`.

The rates below are :func:`rbjax.derivative` with that algebra, returning
``None`` for a field that does not change (``v`` without force, ``L`` or ``ω``
of an isotropic body without torque), so the explicit Euler and RK4 steps here
skip its update entirely. They reproduce ``method="euler"`` / ``"rk4"`` of
:mod:`rbjax._methods` to round-off (tested): Euler's update formulas in the
same order, and RK4 by the same tableau and stepping code
(:func:`rbjax._methods.explicit_rk.tableau_step`), with ``ω`` evaluated more cheaply.
``"euler"`` and ``"rk4"`` carry them as their :attr:`Method.kernels`.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp

from .._batching import lift
from .._dynamics import matrix_rates, omega_world, rotation_rate
from .._math import cross, dot3, over, pure_quat_multiply, quat_normalize_unchecked
from .._pytree import replace
from .._state import Forces, MatrixState, State
from ._base import KernelFn
from ._common import project
from .explicit_rk import CLASSICAL_RK4, combine, tableau_step

__all__ = ["euler", "rk4", "kernels"]


def _axis_from_quat(q: Any) -> Any:
    """``n = R(q̂) e_z``: the body z axis in the world for ``q̂ = q/‖q‖``.

    The homogeneous form ``(2(xz + wy), 2(yz - wx), w² - x² - y² + z²) / ‖q‖²`` is
    a unit vector also at a Runge–Kutta stage, where ``‖q‖ = 1 + O(dt²)``.
    """
    w, x, y, z = q[0], q[1], q[2], q[3]
    n = jnp.stack([2 * (x * z + w * y), 2 * (y * z - w * x), w * w - x * x - y * y + z * z])
    return n / (w * w + x * x + y * y + z * z)


def _axisym_inv(body: Any, n: Any, u: Any) -> Any:
    """``I_w⁻¹ u = u/a + (1/c - 1/a)(n·u) n`` for ``I = diag(a, a, c)``."""
    a_inv, c_inv = body.inverse_inertia[0, 0], body.inverse_inertia[2, 2]
    return a_inv * u + (c_inv - a_inv) * dot3(n, u) * n


def omega_of(s: State, kind: str) -> Any:
    """World ``ω = R I⁻¹ Rᵀ L`` of one body in the ``(x, v, q, L)`` form, by the kind's algebra.

    ``R`` is the rotation of ``q̂ = q/‖q‖`` for every kind, so the kinds agree to
    round-off also at Runge–Kutta stages, where ``q`` is off the unit sphere by
    ``O(dt²)``.
    """
    if kind == "isotropic":
        return s.body.inverse_inertia[0, 0] * s.angular_momentum
    if kind == "axisymmetric":
        return _axisym_inv(s.body, _axis_from_quat(s.orientation), s.angular_momentum)
    # q̂ materialised: fused into its uses, its 1/‖q‖ is recomputed in every component of both
    # rotations and of q̇, many times the cost of the step (docs/performance.md, "Measured reasons")
    q_hat = jax.lax.optimization_barrier(quat_normalize_unchecked(s.orientation))
    return omega_world(replace(s, orientation=q_hat))


def _rates(s: Any, f: Forces, kind: str) -> dict[str, Any]:
    """``d/dt`` of each changing field of one body; ``None`` where it is zero by structure."""
    out: dict[str, Any] = {
        "position": s.velocity,
        "velocity": None if f.force is None else over(f.force, s.body.mass),
    }
    if isinstance(s, State):
        w = omega_of(s, kind)
        if f.torque is not None:
            w = jax.lax.optimization_barrier(w)  # see rbjax._dynamics: scalar code otherwise
        out["orientation"] = 0.5 * pure_quat_multiply(w, s.orientation)
        out["angular_momentum"] = f.torque
        return out
    R, w = s.rotation, s.angular_velocity
    if kind == "isotropic":
        # gyroscopic term i ω × ω = 0; I_w⁻¹ = 1/i
        out["rotation"] = rotation_rate(R, w)
        out["angular_velocity"] = None if f.torque is None else s.body.inverse_inertia[0, 0] * f.torque
        return out
    if kind == "axisymmetric":
        n = R[:, 2]
        a, c = s.body.inertia[0, 0], s.body.inertia[2, 2]
        gyro = (c - a) * dot3(n, w) * cross(w, n)
        tau = -gyro if f.torque is None else f.torque - gyro
        out["rotation"] = rotation_rate(R, w)
        out["angular_velocity"] = _axisym_inv(s.body, n, tau)
        return out
    out["rotation"], out["angular_velocity"] = matrix_rates(R, w, s.body, f.torque)
    return out


def _rates_batch(state: Any, forces: Forces, kind: str) -> dict[str, Any]:
    return lift(functools.partial(_rates, kind=kind))(state, forces)


def _drop_torque(forces: Forces, torque_free: bool) -> Forces:
    return replace(forces, torque=None) if torque_free else forces


def euler(state: Any, force_fn: Any, t: Any, dt: Any, kind: str, torque_free: bool) -> Any:
    """Explicit Euler ``y ← y + dt f(y)``, then ``q`` normalised / ``R`` re-orthonormalised."""
    k = _rates_batch(state, _drop_torque(force_fn(state, t), torque_free), kind)
    return project(combine(state, dt, (1.0,), [k]))


def rk4(state: Any, force_fn: Any, t: Any, dt: Any, kind: str, torque_free: bool) -> Any:
    """Classical RK4 (:data:`rbjax._methods.explicit_rk.CLASSICAL_RK4`) with the kind's rates."""
    rates = lambda s, tt: _rates_batch(s, _drop_torque(force_fn(s, tt), torque_free), kind)
    return tableau_step(CLASSICAL_RK4, state, t, dt, rates)


def kernels(step: KernelFn) -> dict[tuple[str, type], KernelFn]:
    """``Method.kernels`` of a specialised step: every rigid kind, both rigid state forms."""
    return {(kind, T): step for kind in ("isotropic", "axisymmetric", "general") for T in (State, MatrixState)}
