"""Small facts about state types shared by ``simulate`` and the methods."""

from __future__ import annotations

from typing import Any

from ._state import ParticleState

__all__ = ["DEFAULT_METHOD", "constant_fields"]

#: The integrator every public function uses when ``method`` is not given (``step``, ``simulate``,
#: ``simulate_chunked``, ``Scene.build``, ``shoot``, ``simulate_truncated``): Strang splitting,
#: second order, symplectic, world ``L`` exact, exact for symmetric tops, ~2.3x Euler's cost per
#: step. On the README's body (box 0.1 x 0.2 x 0.4 m, 1 kg, ω = (0.01, 5, 0.01) rad/s) over 5 s at
#: dt = 1e-3 it is within 2.1e-6 rad of rb.torque_free, energy within 2.1e-7 (relative); Euler, the
#: default until 2026-12-02, was 3.09 rad off with +1.3% energy (docs/integrators.md).
DEFAULT_METHOD = "splitting"

# Fields that no integrator method changes: carried outside the scan. ``time`` is
# among them because a method is given ``t`` as an argument; ``step`` and
# ``simulate`` advance it.
_CONSTANT_FIELDS: dict[type, tuple[str, ...]] = {ParticleState: ("mass", "time")}


def constant_fields(state: Any) -> tuple[str, ...]:
    """Names of the fields of ``state`` that no integrator method changes (``body``, ``time``, ...)."""
    return _CONSTANT_FIELDS.get(type(state), ("body", "time"))
