"""High-order methods by symmetric composition of the symmetric second-order ``"splitting"`` step.

If ``Φ_h`` is a symmetric (time-reversible, ``Φ_h⁻¹ = Φ_{-h}``) method of order
2, the composition ::

    Ψ_h = Φ_{γ_s h} ∘ … ∘ Φ_{γ_2 h} ∘ Φ_{γ_1 h},   γ_i = γ_{s+1-i},  Σ γ_i = 1

is again symmetric, and the palindromic weights ``γ`` can be chosen so that
it has order 4, 6 or 8 (Yoshida 1990; Suzuki 1990; McLachlan 1995; Kahan &
Li 1997; Hairer, Lubich & Wanner, *Geometric Numerical Integration*, 2nd ed.
2006, §V.3.2). Sub-step ``i`` starts at time ``t + (γ_1 + … + γ_{i-1}) h``, so
time-dependent forces are sampled where the sub-step really is and the
composition keeps its order with ``τ(t)`` and with position- and
orientation-dependent forces: ``"splitting"`` kicks with forces at both
ends of each sub-step, which keeps it symmetric for any force that does
not depend on the velocities. A velocity-dependent force (damping) makes
the kick an explicit-Euler step: measured with ``τ = -0.3 ω``, ``"splitting"``
and all three compositions are then first order; use ``"rk4"`` there.

Every property of ``"splitting"`` that is preserved by composing maps
carries over: torque-free, world ``L`` is untouched (bitwise), ``|L|`` and
``|q| = 1`` are exact, the map is symplectic and time-reversible, so the
energy error stays bounded (now ``O(h^p)``) with no drift. Some ``γ_i`` are
negative (unavoidable above order 2 for real weights, Sheng 1989; Suzuki
1991): those sub-steps run backwards in time, which the exact sub-flows of
the splitting do without trouble.

Weights (the ones recommended in Hairer, Lubich & Wanner §V.3.2 as the most
accurate per unit work; digits from that section, 26 significant digits,
more than float64 can hold):

* ``"splitting4"``, 5 stages (Suzuki 1990, "fractal" ``p4 s5``):
  ``γ_1 = γ_2 = γ_4 = γ_5 = 1/(4 - 4^{1/3})``, ``γ_3 = 1 - 4 γ_1``. Chosen over
  Yoshida's 3-stage triple jump (``γ = 1/(2 - 2^{1/3})``, ``-2^{1/3} γ``): its
  sub-steps are short (largest ``|γ|``: 0.66 against 1.70) and its error
  constant far smaller. Measured on a generic tumble with a time-varying
  torque: at equal work (sub-steps) its error is ~7x smaller, so it reaches
  a given error with ~1.6x less work.
* ``"splitting6"``, 9 stages: Kahan & Li (1997) ``s9odr6a``; at equal work
  ~4x more accurate than Yoshida's 7-stage order-6 weights on the same test.
* ``"splitting8"``, 17 stages: Kahan & Li (1997) ``s17odr8a``; at equal work
  ~8x more accurate than McLachlan's 15-stage ``s15odr8`` on the same test.

Cost: ``s`` steps of ``"splitting"`` (each 2 force evaluations and 5
sub-rotations). The base step is reused as it is (``SPLITTING``'s), not re-derived, so
every state form it supports is supported, and improvements to the
splitting kernel carry over.

References: H. Yoshida, Phys. Lett. A 150 (1990) 262–268; M. Suzuki, Phys.
Lett. A 146 (1990) 319–323; W. Kahan & R.-C. Li, Math. Comp. 66 (1997)
1089–1099; R. I. McLachlan, SIAM J. Sci. Comput. 16 (1995) 151–168.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp

from .._pytree import replace
from .._state import split_constants
from ._base import Method, StepFn
from .splitting import SPLITTING

__all__ = ["COEFFICIENTS", "compose", "composed", "palindrome", "SPLITTING4", "SPLITTING6", "SPLITTING8"]


def palindrome(first_half: Sequence[str]) -> tuple[str, ...]:
    """``(a, b, …, m)`` -> ``(a, b, …, m, …, b, a)``: the last entry is the middle weight."""
    return tuple(first_half) + tuple(reversed(first_half[:-1]))


_SUZUKI = 1.0 / (4.0 - 4.0 ** (1.0 / 3.0))

# Weights as decimal strings (exact as published; float64 rounds them once).
# Each tuple is the full palindromic sequence γ_1 … γ_s.
COEFFICIENTS: dict[str, tuple[str, ...]] = {
    # Suzuki (1990) p4 s5 by its closed form (float64-rounded: 17 digits are exact to 1 ulp)
    "splitting4": palindrome([repr(_SUZUKI), repr(_SUZUKI), repr(1.0 - 4.0 * _SUZUKI)]),
    # Kahan & Li (1997) s9odr6a, digits as printed in HLW (2006) §V.3.2
    "splitting6": palindrome(
        [
            "0.39216144400731413927925056",
            "0.33259913678935943859974864",
            "-0.70624617255763935980996482",
            "0.08221359629355080023149045",
            "0.79854399093482996339895035",
        ]
    ),
    # Kahan & Li (1997) s17odr8a, digits as printed in HLW (2006) §V.3.2
    "splitting8": palindrome(
        [
            "0.13020248308889008087881763",
            "0.56116298177510838456196441",
            "-0.38947496264484728640807860",
            "0.15884190655515560089621075",
            "-0.39590389413323757733623154",
            "0.18453964097831570709183254",
            "0.25837438768632204729397911",
            "0.29501172360931029887096624",
            "-0.60550853383003451169892108",
        ]
    ),
}


def compose(base_step: StepFn, gammas: Sequence[float]) -> StepFn:
    """The batch-level step ``Φ_{γ_s h} ∘ … ∘ Φ_{γ_1 h}`` of a batch-level ``base_step``.

    Sub-step ``i`` runs ``base_step(state, force_fn, t + c_i h, γ_i h)`` with
    ``c_i = γ_1 + … + γ_{i-1}`` (summed exactly, then rounded to the state's
    dtype; ``h`` and ``t`` keep the state's dtype).

    The sub-steps are a ``lax.scan``: one copy of the base step in the compiled
    program, so compile time does not grow with ``s``. The scan carries the
    current ``(γ_i, c_i)`` and reads the next pair as its input: read directly
    from the scan's input, ``γ_i`` becomes a ``dynamic-slice`` of the table
    inside every fused kernel of the sub-step, several times the cost of a
    plain ``"splitting"`` step; unrolling the sub-steps runs as fast as the
    carried pair but compiles several times longer (docs/performance.md,
    "Measured reasons behind the code"). The body (the fields no method
    changes) is closed over rather than carried, so the per-body set-up
    ``simulate`` gave it before its loop (the inverse inertia, the principal
    frame: :func:`rbjax._body.prepare`) is read by every sub-step, not recomputed.
    """
    gammas = tuple(float(g) for g in gammas)
    starts = tuple(math.fsum(gammas[:i]) for i in range(len(gammas)))

    def step(state, force_fn, t, dt):
        dyn0, consts = split_constants(state)

        def sub(dyn, gc):
            g, c = gc
            return split_constants(base_step(replace(dyn, **consts), force_fn, t + c * dt, g * dt))[0], None

        # γ_i, c_i of the current sub-step are carried (the scan reads the next ones), so that
        # the sub-step's kernels see a loop-carried scalar, not a dynamic-slice of the table
        nxt = (jnp.asarray(gammas[1:] + (0.0,), state.dtype), jnp.asarray(starts[1:] + (0.0,), state.dtype))

        def carried(c, gc_next):
            dyn, gc = c
            return (sub(dyn, gc)[0], gc_next), None

        first = (jnp.asarray(gammas[0], state.dtype), jnp.asarray(starts[0], state.dtype))
        (dyn, _), _ = jax.lax.scan(carried, (dyn0, first), nxt)
        return replace(dyn, **consts)

    return step


def composed(name: str, base_method: Method, order: int, cost: float) -> Method:
    """The composition ``name`` of :data:`COEFFICIENTS` built on ``base_method``'s steps (every state form
    of the base), of order ``order`` and measured ``cost`` per step relative to ``"euler"``."""
    gammas = [float(g) for g in COEFFICIENTS[name]]
    return Method(
        name=name,
        order=order,
        steps={T: compose(fn, gammas) for T, fn in base_method.steps.items()},
        conserves=base_method.conserves.replace("bounded", f"bounded (O(dt^{order}))"),
        order_with_velocity_forces=base_method.order_with_velocity_forces,
        cost=cost,
        principal_frame=base_method.principal_frame,
        rotors=base_method.rotors,
    )


# costs measured (benchmarks/results/integrator_cost_2026-12-03.md), not derived as sub-steps x
# "splitting"'s: a sub-step of the composition's scan costs more than a plain step
SPLITTING4 = composed("splitting4", SPLITTING, 4, cost=13.9)
SPLITTING6 = composed("splitting6", SPLITTING, 6, cost=25.0)
SPLITTING8 = composed("splitting8", SPLITTING, 8, cost=46.9)
