"""Checks and casts of a force model's fields, shared by :mod:`rbjax._forces` and :mod:`rbjax._attached`.

Each check raises ``ValueError`` in the model's name, naming the field and the remedy;
values that cannot be read here (traced, or spread over processes) are left to checked mode.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from jax import Array

from ._math import broadcasts_to, is_concrete
from ._state import AnyState, ParticleState, RigidState


def check_core(model: Any, name: str, core: tuple[int, ...], extra: str = "") -> None:
    """``ValueError`` unless field ``name`` (if given) ends in ``core``, e.g. ``(3,)`` for a vector."""
    a = getattr(model, name)
    if a is None:
        return
    if tuple(a.shape[a.ndim - len(core) :]) != core or a.ndim < len(core):
        dims = ", ".join(str(c) for c in core)
        raise ValueError(
            f"{type(model).__name__}: {name} must have shape (..., {dims}){extra}, got shape {tuple(a.shape)}"
        )


def check_non_negative(model: Any, *names: str) -> None:
    """``ValueError`` for a concrete negative coefficient (it would add energy, not take it)."""
    for name in names:
        a = getattr(model, name)
        if is_concrete(a) and np.any(np.asarray(a) < 0):
            raise ValueError(
                f"{type(model).__name__}: {name} must be >= 0 (a negative coefficient adds energy instead of "
                f"removing or restoring it), got {np.asarray(a).ravel()[:4]}; pass its magnitude"
            )


def check_fits(model: Any, name: str, core: int, shape: tuple[int, ...], what: str) -> None:
    """``ValueError`` unless field ``name``'s leading shape (all but ``core`` axes) broadcasts to ``shape``."""
    a = getattr(model, name)
    if a is None:
        return
    lead = tuple(a.shape[: a.ndim - core])
    ok = broadcasts_to(lead, tuple(shape))
    if not ok:
        raise ValueError(
            f"{type(model).__name__}: {name} of shape {tuple(a.shape)} does not fit {what} {tuple(shape)}; give it "
            f"the shape {tuple(shape) + tuple(a.shape[a.ndim - core :])} or a broadcastable one"
        )


def cast_to(x: Any, state: AnyState) -> Array:
    """``x`` as an array of the state's dtype."""
    return jnp.asarray(x).astype(state.dtype)


def full_batch(x: Array, state: AnyState) -> Array:
    """``x`` broadcast to the state's ``(*B, 3)``."""
    return jnp.broadcast_to(x, state.position.shape)


def rigid_only(name: str, state: AnyState) -> RigidState:
    """``state``, known to be rigid; ``ValueError`` for particles."""
    if isinstance(state, ParticleState):
        raise ValueError(f"{name}: a torque needs rigid bodies; ParticleState has no rotation")
    return state
