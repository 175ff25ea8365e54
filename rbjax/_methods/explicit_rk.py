"""Explicit Runge–Kutta from a Butcher tableau: the driver behind ``"rk4"`` and ``"rk8"``.

For a tableau ``(A, b, c)`` with ``A`` strictly lower triangular, one step of
``y' = f(y, t)`` is ::

    k_i = f(y + h Σ_{j<i} a_ij k_j,  t + c_i h),   i = 1 … s
    y  ← y + h Σ_i b_i k_i

with ``f`` the Newton–Euler right-hand side (:func:`rbjax.derivative`, world
frame, SI units) and forces evaluated at every stage time. Only the fields an
integrator changes are combined; zero tableau entries are skipped. Afterwards
the quaternion is normalised (``MatrixState``: ``R`` re-orthonormalised).
When the torque varies over the step, the stage states of a tableau of more
than four stages are materialised (see :func:`rbjax._methods._common.materialise`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp

from .._dynamics import derivative
from .._pytree import replace
from .._state import MatrixState, ParticleState, State
from ._common import materialise, project, torque_varies
from ._registry import Method, StepFn, register

__all__ = ["CLASSICAL_RK4", "Tableau", "explicit_rk", "register_tableau"]


class Tableau(NamedTuple):
    """A Butcher tableau: rows ``a[i]`` of ``A`` (``i`` entries each), weights ``b``, nodes ``c``."""

    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]


#: The classical fourth-order tableau: ``"rk4"``, ``"rk4_body"`` and the fitting model's flow use it.
CLASSICAL_RK4 = Tableau(
    a=((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
    b=(1 / 6, 1 / 3, 1 / 3, 1 / 6),
    c=(0.0, 0.5, 0.5, 1.0),
)


def combine(state, dt, weights: Sequence[float], ks: Sequence):
    """``state + dt Σ_j w_j k_j`` on the changing fields; zero weights cost nothing."""
    terms = [(w, k) for w, k in zip(weights, ks, strict=True) if w != 0.0]
    if not terms:
        return state
    consts = state.constant_fields
    out = {}
    for n in type(state)._rbjax_data_fields:
        if n in consts:
            continue
        x = getattr(state, n)
        # weights cast to the field's dtype: a float32 state stays float32
        incr = sum(jnp.asarray(w, x.dtype) * getattr(k, n) for w, k in terms)
        out[n] = x + dt * incr
    return replace(state, **out)


def explicit_rk(a: Sequence[Sequence[float]], b: Sequence[float], c: Sequence[float]) -> StepFn:
    """A batch-level step ``(state, force_fn, t, dt) -> state`` for an explicit Runge–Kutta tableau.

    ``a[i]`` holds ``a_i1 … a_i,i-1`` (``len(a[i]) == i``), ``b`` the weights and
    ``c`` the stage times (as fractions of ``dt``). Works for ``State``,
    ``MatrixState`` and ``ParticleState``: the stages are
    ``k_i = derivative(y_i, force_fn(y_i, t + c_i dt))`` with
    ``y_i = y + dt Σ_j a_ij k_j``; the result is ``y + dt Σ_i b_i k_i`` with
    the quaternion normalised (``R`` re-orthonormalised). ``ValueError`` for
    a tableau that is not explicit or whose sizes disagree.
    """
    s = len(b)
    if len(a) != s or len(c) != s or any(len(row) != i for i, row in enumerate(a)):
        raise ValueError(
            f"explicit tableau needs len(a[i]) == i and len(a) == len(b) == len(c); got rows "
            f"{[len(r) for r in a]}, {len(b)} weights, {len(c)} nodes"
        )
    a = tuple(tuple(float(x) for x in row) for row in a)
    b = tuple(float(x) for x in b)
    c = tuple(float(x) for x in c)

    # With a torque that varies over the step, every stage feeds the next through L and ω (see
    # materialise). Measured 2026-12-01 (work_precision.py, float64, 1e4 bodies, ns per
    # body-step, with ω materialised in `derivative` either way): rk8 on the thruster 1376 -> 317
    # and on the driven torque 660 -> 163 with its stages materialised, but rk4 48 -> 98 and
    # 24 -> 45: four stages are cheaper to recompute than to store.
    many_stages = s > 4

    def step(state, force_fn, t, dt):
        varies = many_stages and torque_varies(force_fn, state, t)
        stage = (lambda y: materialise(y, dt)) if varies else (lambda y: y)
        ks = []
        for i in range(s):
            y = combine(state, dt, a[i], ks[:i])
            y = stage(y) if i > 0 else y
            ks.append(derivative(y, force_fn(y, t + c[i] * dt)))
        # lifted, so it holds in simulate's batch-last layout too
        return project(combine(state, dt, b, ks))

    return step


def register_tableau(
    name: str,
    order: int,
    a: Sequence[Sequence[float]],
    b: Sequence[float],
    c: Sequence[float],
    *,
    cost: float,
    stable_dt_omega: dict[str, float] | None = None,
) -> StepFn:
    """Register ``name`` as the explicit Runge–Kutta method of tableau ``(a, b, c)``; returns its step.

    It supports ``State``, ``MatrixState`` and ``ParticleState`` and conserves
    nothing exactly (energy and ``|L|`` drift as ``O(dt^order)`` per unit time).
    ``cost`` is the measured cost per step relative to ``"euler"``;
    ``stable_dt_omega`` the measured stability limits (see :class:`Method`).
    """
    fn = explicit_rk(a, b, c)
    register(
        Method(
            name=name,
            order=order,
            steps={State: fn, MatrixState: fn, ParticleState: fn},
            conserves=f"nothing exactly; energy and |L| drift as O(dt^{order}) per unit time",
            cost=cost,
            stable_dt_omega=stable_dt_omega,
        )
    )
    return fn
