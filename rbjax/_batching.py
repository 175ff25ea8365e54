"""Lifting one-body functions to batches with ``vmap``.

Every physics kernel in rbjax is written for a single body. ``lift`` maps it
over any leading batch shape with numpy broadcasting semantics: a leaf of an
rbjax pytree whose rank equals its per-body rank (``core_ndim``) is shared by
every body (``in_axes=None``); one with ``k`` extra leading dimensions is batched
over the last ``k`` batch dimensions. So a single ``Body`` can drive a batch of
states, and a trajectory ``(T, N)`` can share its ``(N,)`` bodies over time.
Arguments that are not rbjax pytrees (``dt``, ``t``) are always shared.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax

from ._pytree import is_rbjax_dataclass, replace

__all__ = ["lift", "batch_shape"]


def _batch_dims(obj: Any) -> list[tuple[int, ...]]:
    """Leading batch shapes of every array leaf of an rbjax pytree."""
    out: list[tuple[int, ...]] = []
    for name, core in type(obj)._rbjax_core_ndim.items():
        if name not in type(obj)._rbjax_data_fields:
            continue
        v = getattr(obj, name)
        if v is None:
            continue
        if is_rbjax_dataclass(v):
            out.extend(_batch_dims(v))
        else:
            out.append(tuple(v.shape[: v.ndim - core]))
    return out


def batch_shape(*trees: Any) -> tuple[int, ...]:
    """Broadcast batch shape of rbjax pytrees; ``ValueError`` if incompatible."""
    shapes = [s for t in trees if is_rbjax_dataclass(t) for s in _batch_dims(t)]
    nd = max((len(s) for s in shapes), default=0)
    result: list[int] = []
    for i in range(nd):
        sizes = {s[len(s) - nd + i] for s in shapes if len(s) >= nd - i}
        if len(sizes) > 1:
            raise ValueError(
                f"batch shapes {sorted(set(shapes))} do not broadcast: each leaf must have "
                "the full batch shape or a trailing part of it (shared over the rest)"
            )
        result.append(sizes.pop())
    return tuple(result)


def _in_axes(obj: Any, level: int, nd: int) -> Any:
    """in_axes for the vmap over batch dimension ``level`` of ``nd``."""
    if not is_rbjax_dataclass(obj):
        return None
    changes = {}
    for name in type(obj)._rbjax_data_fields:
        v = getattr(obj, name)
        if v is None:
            changes[name] = None
        elif is_rbjax_dataclass(v):
            changes[name] = _in_axes(v, level, nd)
        else:
            k = v.ndim - type(obj)._rbjax_core_ndim[name]
            changes[name] = 0 if k >= nd - level else None
    return replace(obj, **changes)


def lift(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Map a one-body function over the broadcast batch shape of its arguments."""

    def lifted(*args: Any) -> Any:
        nd = len(batch_shape(*args))
        f = fn
        # innermost vmap maps the last batch dimension
        for level in reversed(range(nd)):
            f = jax.vmap(f, in_axes=tuple(_in_axes(a, level, nd) for a in args))
        return f(*args)

    return lifted
