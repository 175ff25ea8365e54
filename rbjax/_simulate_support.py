"""Small facts about state types shared by ``simulate`` and the methods."""

from __future__ import annotations

from typing import Any

from ._state import ParticleState

__all__ = ["constant_fields"]

# Fields that do not change along a trajectory: carried outside the scan and not
# stacked over time in a returned trajectory.
_CONSTANT_FIELDS: dict[type, tuple[str, ...]] = {ParticleState: ("mass",)}


def constant_fields(state: Any) -> tuple[str, ...]:
    """Names of the fields of ``state`` that no integrator changes."""
    return _CONSTANT_FIELDS.get(type(state), ("body",))
