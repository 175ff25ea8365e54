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

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax.numpy as jnp

from .._dynamics import derivative
from .._pytree import replace
from .._state import MatrixState, ParticleState, State
from ._base import KernelFn, Method, StepFn
from ._common import materialise, project, torque_varies

__all__ = ["CLASSICAL_RK4", "Tableau", "explicit_rk", "tableau_method", "tableau_step"]


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
    """``state + dt Σ_j w_j k_j`` on the changing fields; zero weights cost nothing.

    Each ``k_j`` is a rate of the state's type (:func:`rbjax.derivative`) or a
    ``{field: rate}`` dict in which a field that does not change is missing or
    ``None`` (:mod:`rbjax._methods.specialised`); those fields are left as they are.
    """
    terms = [(w, k) for w, k in zip(weights, ks, strict=True) if w != 0.0]
    if not terms:
        return state
    consts = state.constant_fields
    out = {}
    for n in type(state)._rbjax_data_fields:
        rates: list[tuple[float, Any]] = [(w, k.get(n) if isinstance(k, dict) else getattr(k, n)) for w, k in terms]
        if n in consts or rates[0][1] is None:
            continue
        x = getattr(state, n)
        # weights cast to the field's dtype: a float32 state stays float32
        incr = sum(jnp.asarray(w, x.dtype) * r for w, r in rates)
        out[n] = x + dt * incr
    return replace(state, **out)


def tableau_step(tableau: Tableau, state, t, dt, rates: Callable, stage: Callable | None = None):
    """One explicit Runge–Kutta step of tableau ``(a, b, c)`` for the rates ``rates(y, t)``.

    ``k_i = rates(y_i, t + c_i dt)`` with ``y_i = y + dt Σ_j a_ij k_j``
    (``stage(y_i)`` when given, from the second stage on); returns
    ``y + dt Σ_i b_i k_i`` with the quaternion normalised (``R``
    re-orthonormalised; lifted, so it holds in ``simulate``'s batch-last layout
    too). ``rates`` returns a rate of the state's type or a ``{field: rate}``
    dict (see :func:`combine`).
    """
    a, b, c = tableau
    ks = []
    for i in range(len(b)):
        y = combine(state, dt, a[i], ks[:i])
        y = stage(y) if stage is not None and i > 0 else y
        ks.append(rates(y, t + c[i] * dt))
    return project(combine(state, dt, b, ks))


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
    tableau = Tableau(
        tuple(tuple(float(x) for x in row) for row in a), tuple(float(x) for x in b), tuple(float(x) for x in c)
    )

    # With a torque that varies over the step, every stage feeds the next through L and ω (see
    # materialise): eight or more stages are cheaper to store than to recompute, four are
    # cheaper to recompute (docs/performance.md, "Measured reasons behind the code").
    many_stages = s > 4

    def step(state, force_fn, t, dt):
        varies = many_stages and torque_varies(force_fn, state, t)
        stage = (lambda y: materialise(y, dt)) if varies else None
        return tableau_step(tableau, state, t, dt, lambda y, tt: derivative(y, force_fn(y, tt)), stage)

    return step


def tableau_method(
    name: str,
    order: int,
    a: Sequence[Sequence[float]],
    b: Sequence[float],
    c: Sequence[float],
    *,
    cost: float,
    stable_dt_omega: dict[str, float] | None = None,
    kernels: dict[tuple[str, type], KernelFn] | None = None,
    native_code: int | None = None,
) -> Method:
    """The explicit Runge–Kutta method ``name`` of tableau ``(a, b, c)`` (registered by nothing: see
    :mod:`rbjax._methods._registry` for the table of methods).

    It supports ``State``, ``MatrixState`` and ``ParticleState`` and conserves
    nothing exactly (energy and ``|L|`` drift as ``O(dt^order)`` per unit time).
    ``cost`` is the measured cost per step relative to ``"euler"``;
    ``stable_dt_omega`` the measured stability limits, ``kernels`` its
    specialised Scene kernels and ``native_code`` its native kernel's number
    (see :class:`Method`).
    """
    fn = explicit_rk(a, b, c)
    return Method(
        name=name,
        order=order,
        steps={State: fn, MatrixState: fn, ParticleState: fn},
        conserves=f"nothing exactly; energy and |L| drift as O(dt^{order}) per unit time",
        cost=cost,
        stable_dt_omega=stable_dt_omega,
        kernels=kernels or {},
        native_code=native_code,
        # derivative() carries the rotor terms and the rotor momenta's rates
        rotors=True,
    )
