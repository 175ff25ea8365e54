"""Small facts about state types shared by ``simulate`` and the methods."""

from __future__ import annotations

from typing import Any

from ._state import ParticleState

__all__ = ["constant_fields"]

# Fields that no integrator method changes: carried outside the scan. ``time`` is
# among them because a method is given ``t`` as an argument; ``step`` and
# ``simulate`` advance it.
_CONSTANT_FIELDS: dict[type, tuple[str, ...]] = {ParticleState: ("mass", "time")}


def constant_fields(state: Any) -> tuple[str, ...]:
    """Names of the fields of ``state`` that no integrator method changes (``body``, ``time``, ...)."""
    return _CONSTANT_FIELDS.get(type(state), ("body", "time"))
