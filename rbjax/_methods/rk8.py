"""Explicit Runge–Kutta from a Butcher tableau, and ``"rk8"``: the 8th-order DOP853 tableau at fixed step.

For a tableau ``(A, b, c)`` with ``A`` strictly lower triangular, one step of
``y' = f(y, t)`` is ::

    k_i = f(y + h Σ_{j<i} a_ij k_j,  t + c_i h),   i = 1 … s
    y  ← y + h Σ_i b_i k_i

with ``f`` the Newton–Euler right-hand side (:func:`rbjax.derivative`, world
frame, SI units) and forces evaluated at every stage time. Only the fields an
integrator changes are combined; zero tableau entries are skipped. Afterwards
the quaternion is normalised (``MatrixState``: ``R`` re-orthonormalised), as
in ``"rk4"``.

``"rk8"`` uses the 12-stage, 8th-order solution of Dormand & Prince's
DOP853 (E. Hairer, S. P. Nørsett & G. Wanner, *Solving Ordinary Differential
Equations I*, 2nd ed., Springer 1993, §II.10; coefficients from Hairer's
``dop853.f``, the same as ``scipy.integrate._ivp.dop853_coefficients``) with
a fixed step: no error estimator, no step-size control, no dense output.

Order 8. Conserves nothing exactly: energy and ``|L|`` drift as ``O(h⁸)`` per
unit time. Cost: 12 force and 12 derivative evaluations per step, about
3x ``"rk4"``'s step. Choose it for smooth problems at tight accuracy
(1e-6 … 1e-12 in float64): there it needs far fewer steps than ``"rk4"`` and
no rejected steps. In float32 its error floors at round-off (~1e-6) after a
few dozen steps, like every method.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp

from .._dynamics import derivative
from .._pytree import replace
from .._simulate_support import constant_fields
from .._state import MatrixState, ParticleState, State
from . import Method, StepFn, register
from ._common import materialise, project, torque_varies

__all__ = ["DOP853_A", "DOP853_B", "DOP853_C", "explicit_rk"]

# DOP853 (Hairer, Nørsett & Wanner; dop853.f): 30 significant digits as published,
# which float64 rounds once. Row i of A holds a_i1 … a_i,i-1 (stage 1 has none).
DOP853_C: tuple[float, ...] = (
    0.0,
    0.526001519587677318785587544488e-01,
    0.789002279381515978178381316732e-01,
    0.118350341907227396726757197510,
    0.281649658092772603273242802490,
    0.333333333333333333333333333333,
    0.25,
    0.307692307692307692307692307692,
    0.651282051282051282051282051282,
    0.6,
    0.857142857142857142857142857142,
    1.0,
)

DOP853_A: tuple[tuple[float, ...], ...] = (
    (),
    (5.26001519587677318785587544488e-2,),
    (1.97250569845378994544595329183e-2, 5.91751709536136983633785987549e-2),
    (2.95875854768068491816892993775e-2, 0.0, 8.87627564304205475450678981324e-2),
    (2.41365134159266685502369798665e-1, 0.0, -8.84549479328286085344864962717e-1, 9.24834003261792003115737966543e-1),
    (
        3.7037037037037037037037037037e-2,
        0.0,
        0.0,
        1.70828608729473871279604482173e-1,
        1.25467687566822425016691814123e-1,
    ),
    (
        3.7109375e-2,
        0.0,
        0.0,
        1.70252211019544039314978060272e-1,
        6.02165389804559606850219397283e-2,
        -1.7578125e-2,
    ),
    (
        3.70920001185047927108779319836e-2,
        0.0,
        0.0,
        1.70383925712239993810214054705e-1,
        1.07262030446373284651809199168e-1,
        -1.53194377486244017527936158236e-2,
        8.27378916381402288758473766002e-3,
    ),
    (
        6.24110958716075717114429577812e-1,
        0.0,
        0.0,
        -3.36089262944694129406857109825,
        -8.68219346841726006818189891453e-1,
        2.75920996994467083049415600797e1,
        2.01540675504778934086186788979e1,
        -4.34898841810699588477366255144e1,
    ),
    (
        4.77662536438264365890433908527e-1,
        0.0,
        0.0,
        -2.48811461997166764192642586468,
        -5.90290826836842996371446475743e-1,
        2.12300514481811942347288949897e1,
        1.52792336328824235832596922938e1,
        -3.32882109689848629194453265587e1,
        -2.03312017085086261358222928593e-2,
    ),
    (
        -9.3714243008598732571704021658e-1,
        0.0,
        0.0,
        5.18637242884406370830023853209,
        1.09143734899672957818500254654,
        -8.14978701074692612513997267357,
        -1.85200656599969598641566180701e1,
        2.27394870993505042818970056734e1,
        2.49360555267965238987089396762,
        -3.0467644718982195003823669022,
    ),
    (
        2.27331014751653820792359768449,
        0.0,
        0.0,
        -1.05344954667372501984066689879e1,
        -2.00087205822486249909675718444,
        -1.79589318631187989172765950534e1,
        2.79488845294199600508499808837e1,
        -2.85899827713502369474065508674,
        -8.87285693353062954433549289258,
        1.23605671757943030647266201528e1,
        6.43392746015763530355970484046e-1,
    ),
)

# The 8th-order weights (dop853.f's b1, b6 … b12; scipy's A[12, :12] = B).
DOP853_B: tuple[float, ...] = (
    5.42937341165687622380535766363e-2,
    0.0,
    0.0,
    0.0,
    0.0,
    4.45031289275240888144113950566,
    1.89151789931450038304281599044,
    -5.8012039600105847814672114227,
    3.1116436695781989440891606237e-1,
    -1.52160949662516078556178806805e-1,
    2.01365400804030348374776537501e-1,
    4.47106157277725905176885569043e-2,
)


def _combine(state, dt, weights: Sequence[float], ks: Sequence):
    """``state + dt Σ_j w_j k_j`` on the changing fields; zero weights cost nothing."""
    terms = [(w, k) for w, k in zip(weights, ks, strict=True) if w != 0.0]
    if not terms:
        return state
    consts = constant_fields(state)
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

    def step(state, force_fn, t, dt):
        # a varying torque makes every stage feed the next through L and ω: see materialise
        stage = (lambda y: materialise(y, dt)) if torque_varies(force_fn, state, t) else (lambda y: y)
        ks = []
        for i in range(s):
            y = _combine(state, dt, a[i], ks[:i])
            y = stage(y) if i > 0 else y
            ks.append(derivative(y, force_fn(y, t + c[i] * dt)))
        # lifted, so it holds in simulate's batch-last layout too
        return project(_combine(state, dt, b, ks))

    return step


rk8 = explicit_rk(DOP853_A, DOP853_B, DOP853_C)

register(
    Method(
        name="rk8",
        order=8,
        steps={State: rk8, MatrixState: rk8, ParticleState: rk8},
        conserves="nothing exactly; energy and |L| drift as O(dt^8) per unit time",
        cost=6.0,
    )
)
