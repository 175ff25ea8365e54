"""Classical fourth-order Runge–Kutta on the full state.

``k1 = f(y, t)``, ``k2 = f(y + h/2 k1, t + h/2)``, ``k3 = f(y + h/2 k2, t + h/2)``,
``k4 = f(y + h k3, t + h)``, ``y ← y + h/6 (k1 + 2k2 + 2k3 + k4)`` with ``f`` the
Newton–Euler right-hand side (:func:`rbjax.derivative`); forces are evaluated
at each stage. Afterwards the quaternion is normalised (``MatrixState``: ``R``
re-orthonormalised).

The classical tableau through the explicit Runge–Kutta driver
(:mod:`rbjax._methods.explicit_rk`).

Order 4. Conserves nothing exactly: energy and ``|L|`` drift slowly (``O(h⁴)``
per unit time) and the drift accumulates over long horizons. Cost: 4 force
evaluations and 4 derivative evaluations per step; the measured cost relative to
``"euler"`` is ``rb.methods()["rk4"].cost`` (docs/integrators.md). Choose it for
short, accurate horizons and smooth time-varying forces.
"""

from __future__ import annotations

import math

from . import specialised
from .explicit_rk import CLASSICAL_RK4, tableau_method

RK4 = tableau_method(
    "rk4",
    4,
    *CLASSICAL_RK4,
    cost=2.4,
    # benchmarks/results/stability_limits.json
    stable_dt_omega={"State": 7.5, "MatrixState": 1.0, "ParticleState": math.inf},
    kernels=specialised.kernels(specialised.rk4),
    native_code=1,
)
