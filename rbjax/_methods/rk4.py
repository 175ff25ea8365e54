"""Classical fourth-order Runge–Kutta on the full state.

``k1 = f(y, t)``, ``k2 = f(y + h/2 k1, t + h/2)``, ``k3 = f(y + h/2 k2, t + h/2)``,
``k4 = f(y + h k3, t + h)``, ``y ← y + h/6 (k1 + 2k2 + 2k3 + k4)`` with ``f`` the
Newton–Euler right-hand side (:func:`rbjax.derivative`); forces are evaluated
at each stage. Afterwards the quaternion is normalised (``MatrixState``: ``R``
re-orthonormalised).

Order 4. Conserves nothing exactly: energy and ``|L|`` drift slowly (``O(h⁴)``
per unit time) and the drift accumulates over long horizons. Cost ≈ 4 force
evaluations and 4 derivative evaluations; measured 1.2x ``"euler"`` per step
(benchmarks/integrator_cost.py: the step is not arithmetic-bound). Choose it for
short, accurate horizons and smooth time-varying forces.
"""

from __future__ import annotations

import jax

from .._dynamics import derivative
from .._pytree import replace
from .._simulate_support import constant_fields
from .._state import MatrixState, ParticleState, State
from . import Method, register
from ._common import materialise, project, torque_varies


def _axpy(state, h, k):
    """``state + h k`` on the changing fields only."""
    consts = constant_fields(state)
    dyn = {n: getattr(state, n) + h * getattr(k, n) for n in type(state)._rbjax_data_fields if n not in consts}
    return replace(state, **dyn)


def rk4(state, force_fn, t, dt):
    f = lambda s, tt: derivative(s, force_fn(s, tt))  # noqa: E731
    k1 = f(state, t)
    # a varying torque makes every stage feed the next through L and ω: see materialise
    m = (lambda y: materialise(y, dt)) if torque_varies(force_fn, state, t) else (lambda y: y)  # noqa: E731
    k2 = f(m(_axpy(state, dt / 2, k1)), t + dt / 2)
    k3 = f(m(_axpy(state, dt / 2, k2)), t + dt / 2)
    k4 = f(m(_axpy(state, dt, k3)), t + dt)
    consts = constant_fields(state)
    incr = jax.tree.map(
        lambda a, b, c, d: (a + 2 * b + 2 * c + d) / 6,
        *(replace(k, **{n: None for n in consts}) for k in (k1, k2, k3, k4)),
    )
    out = _axpy(state, dt, replace(incr, **{n: getattr(state, n) for n in consts}))
    return project(out)


register(
    Method(
        name="rk4",
        order=4,
        steps={State: rk4, MatrixState: rk4, ParticleState: rk4},
        conserves="nothing exactly; energy and |L| drift as O(dt^4) per unit time",
        cost=1.2,
    )
)
