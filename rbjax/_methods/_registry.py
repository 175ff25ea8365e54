"""The registry of time-stepping methods: :class:`Method`, and ``register``/``get``/``available``.

Each method module registers itself on import; this module imports none of them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

#: The integrator every public function uses when ``method`` is not given (``step``, ``simulate``,
#: ``simulate_chunked``, ``Scene.build``, ``shoot``, ``simulate_truncated``): Strang splitting,
#: second order, symplectic, world ``L`` exact, exact for symmetric tops, ~2.3x Euler's cost per
#: step. On the README's body (box 0.1 x 0.2 x 0.4 m, 1 kg, ω = (0.01, 5, 0.01) rad/s) over 5 s at
#: dt = 1e-3 it is within 2.1e-6 rad of rb.torque_free, energy within 2.1e-7 (relative); Euler
#: was 3.09 rad off with +1.3% energy (docs/integrators.md).
DEFAULT_METHOD = "splitting"

StepFn = Callable[[Any, Callable[[Any, Any], Any], Any, Any], Any]


@dataclasses.dataclass(frozen=True)
class Method:
    """A registered integrator.

    Attributes:
        name: the ``method=`` string.
        order: global order of accuracy.
        steps: ``{state type: batch-level step function}``.
        conserves: short statement of what it conserves (for docs and tests).
        cost: cost per step relative to ``"euler"`` (measured, approximate).
        stable_dt_omega: for explicit methods, ``{state type name: limit}``: the
            largest ``dt·|ω|`` (ω in rad/s, dt in s) at which 1000 torque-free
            steps stayed finite with a unit quaternion / rotation matrix, measured
            in float64 on four body shapes and six spin axes each by
            ``benchmarks/stability_limits.py`` (grid ratio 1.33, so the true limit
            is up to 33% higher). Beyond it the method diverges (NaN, inf or an
            orientation off the rotation group); ``inf``: bounded up to 1000 (the
            state form keeps ``|ω|`` bounded, though the energy still drifts).
            ``None`` for methods that are stable at any step (``"splitting"`` and
            its compositions, the implicit ones). Accuracy needs far smaller steps:
            see the integrator table in the README.
        failure_note: what a checked-mode failure means for this method, added
            to the error message.
    """

    name: str
    order: int
    steps: dict[type, StepFn]
    conserves: str = ""
    cost: float = 1.0
    stable_dt_omega: dict[str, float] | None = None
    failure_note: str = ""


_REGISTRY: dict[str, Method] = {}


def register(method: Method) -> Method:
    _REGISTRY[method.name] = method
    return method


def get(name: str, state_type: type) -> StepFn:
    """The step function of ``name`` for ``state_type``; ``ValueError`` if none."""
    m = _REGISTRY.get(name)
    if m is None:
        raise ValueError(f"unknown method {name!r}; available: {sorted(_REGISTRY)}")
    fn = m.steps.get(state_type)
    if fn is None:
        raise ValueError(
            f"method {name!r} does not support {state_type.__name__}; it supports {sorted(t.__name__ for t in m.steps)}"
        )
    return fn


def available(state_type: type | None = None) -> dict[str, Method]:
    """Registered methods, optionally only those supporting ``state_type``."""
    return {k: m for k, m in _REGISTRY.items() if state_type is None or state_type in m.steps}
