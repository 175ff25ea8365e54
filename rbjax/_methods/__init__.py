"""Time-stepping methods, one per module, registered by name.

A method is a batch-level function ``step(state, force_fn, t, dt) -> state``:
``force_fn(state, t) -> Forces`` sees the whole batch (so forces may couple
bodies) and may be called at intermediate stages; the per-body arithmetic
inside is written for one body and lifted with :func:`rbjax._batching.lift`.

Step functions must not depend on where the batch axes are: ``simulate`` runs
them with the state in the batch-last layout (:func:`rbjax._batching.batch_last`),
so batch-level code outside ``lift`` may only be elementwise (``x + h k``);
anything that names an axis (a norm, a ``@``) goes inside a lifted one-body function.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

__all__ = ["Method", "register", "get", "available"]

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


from . import euler as euler  # noqa: E402  (each module registers itself)
from . import explicit_rk as explicit_rk  # noqa: E402
from . import implicit_gyroscopic as implicit_gyroscopic  # noqa: E402
from . import implicit_midpoint as implicit_midpoint  # noqa: E402
from . import rk4 as rk4  # noqa: E402
from . import rk4_body as rk4_body  # noqa: E402
from . import rk8 as rk8  # noqa: E402
from . import semi_implicit_euler as semi_implicit_euler  # noqa: E402
from . import splitting as splitting  # noqa: E402

# isort: split
# composition builds on registered methods ("splitting"): it must come after them
from . import composition as composition  # noqa: E402
