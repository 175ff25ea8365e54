"""Lifting one-body functions to batches with ``vmap``.

Every physics kernel in rbjax is written for a single body. ``lift`` maps it
over any leading batch shape with numpy broadcasting semantics: a leaf of an
rbjax pytree whose rank equals its per-body rank (``core_ndim``) is shared by
every body (``in_axes=None``); one with ``k`` extra leading dimensions is batched
over the last ``k`` batch dimensions. So a single ``Body`` can drive a batch of
states, and a trajectory ``(T, N)`` can share its ``(N,)`` bodies over time.
Arguments that are not rbjax pytrees (``dt``, ``t``) are always shared.

Layout. By default batch dimensions lead every leaf, ``(*B, *core)`` (array of
structures). Inside :func:`batch_last` they trail it, ``(*core, *B)``
(structure of arrays): ``simulate`` carries its state that way through the
scan, so that the vmapped one-body kernel reads and writes whole contiguous
rows per component and XLA:CPU fuses a step into one vectorised loop (with
the batch leading, the per-body components are a stride-3/4 gather that does
not vectorise). Kernels are the same either way; only ``lift`` and the
layout converters below look at the mode.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Callable, Iterator
from typing import Any

import jax
import jax.numpy as jnp

from ._pytree import is_rbjax_dataclass, replace

__all__ = ["lift", "batch_shape", "batch_last", "to_batch_last", "to_batch_first"]

_BATCH_LAST = contextvars.ContextVar("rbjax_batch_last", default=False)


@contextlib.contextmanager
def batch_last(on: bool = True) -> Iterator[None]:
    """Trace code inside with rbjax pytrees in the batch-last layout ``(*core, *B)``."""
    token = _BATCH_LAST.set(on)
    try:
        yield
    finally:
        _BATCH_LAST.reset(token)


def map_leaves(obj: Any, fn: Callable[[Any, int], Any]) -> Any:
    """Apply ``fn(leaf, core_ndim)`` to every array leaf of an rbjax pytree."""
    if not is_rbjax_dataclass(obj):
        return obj
    changes = {}
    for name in type(obj)._rbjax_data_fields:
        v = getattr(obj, name)
        if v is None:
            continue
        changes[name] = map_leaves(v, fn) if is_rbjax_dataclass(v) else fn(v, type(obj)._rbjax_core_ndim[name])
    return replace(obj, **changes)


def to_batch_last(obj: Any) -> Any:
    """``(*B, *core)`` → ``(*core, *B)`` on every leaf (a shared leaf is unchanged)."""
    return map_leaves(obj, lambda a, c: jnp.moveaxis(a, tuple(range(a.ndim - c, a.ndim)), tuple(range(c))))


def to_batch_first(obj: Any) -> Any:
    """``(*core, *B)`` → ``(*B, *core)`` on every leaf; inverse of :func:`to_batch_last`."""
    return map_leaves(obj, lambda a, c: jnp.moveaxis(a, tuple(range(c)), tuple(range(a.ndim - c, a.ndim))))


def _batch_dims(obj: Any) -> list[tuple[int, ...]]:
    """Batch shapes of every array leaf of an rbjax pytree (in the current layout)."""
    return [shape for _, shape in _leaf_batch_dims(obj, None)]


def _leaf_batch_dims(obj: Any, owner: str | None) -> list[tuple[str, tuple[int, ...]]]:
    """``(name, batch shape)`` of every array leaf; the names (``Class.field``, nested
    ``Outer.field.inner``) are written only when ``owner`` is given: an error message needs
    them, the traces that call this on every leaf do not."""
    last = _BATCH_LAST.get()
    if owner == "":
        owner = type(obj).__name__
    out: list[tuple[str, tuple[int, ...]]] = []
    for name, core in type(obj)._rbjax_core_ndim.items():
        if name not in type(obj)._rbjax_data_fields:
            continue
        v = getattr(obj, name)
        if v is None:
            continue
        label = "" if owner is None else f"{owner}.{name}"
        if is_rbjax_dataclass(v):
            out.extend(_leaf_batch_dims(v, None if owner is None else label))
        else:
            out.append((label, tuple(v.shape[core:] if last else v.shape[: v.ndim - core])))
    return out


def batch_shape(*trees: Any) -> tuple[int, ...]:
    """Broadcast batch shape of rbjax pytrees; ``ValueError`` naming the fields if incompatible."""
    shapes = [s for t in trees if is_rbjax_dataclass(t) for s in _batch_dims(t)]
    nd = max((len(s) for s in shapes), default=0)
    result: list[int] = []
    for i in range(nd):
        sizes = {s[len(s) - nd + i] for s in shapes if len(s) >= nd - i}
        if len(sizes) > 1:
            sizes.discard(1)  # NumPy rules: a size-1 axis is shared (a trajectory's shared body)
        if len(sizes) > 1:
            # name one field per distinct batch shape, so a user sees which of their arrays is off
            named: dict[tuple[int, ...], str] = {}
            for label, s in (e for t in trees if is_rbjax_dataclass(t) for e in _leaf_batch_dims(t, "")):
                named.setdefault(s, label)
            listed = ", ".join(f"{label} {s}" for s, label in sorted(named.items()))
            raise ValueError(
                f"batch shapes do not broadcast ({listed}): each array field must have the full batch shape "
                "or a trailing part of it (shared over the rest); give it one entry per body, or one "
                "shared by all"
            )
        result.append(sizes.pop())
    return tuple(result)


def in_axes_of(obj: Any, level: int, nd: int, last: bool) -> Any:
    """in_axes for the vmap over batch dimension ``level`` of ``nd``.

    Batch-first, a mapped leaf's axis is 0 (outer levels are already removed);
    batch-last it is the first axis after the core ones.
    """
    if not is_rbjax_dataclass(obj):
        return None
    return map_leaves(obj, lambda v, core: (core if last else 0) if v.ndim - core >= nd - level else None)


def _expand_ones(obj: Any, full: tuple[int, ...], last: bool) -> Any:
    """Broadcast the size-1 batch axes of ``obj``'s leaves to ``full`` (``vmap`` cannot share them)."""
    nd = len(full)

    def expand(a: Any, core: int) -> Any:
        k = a.ndim - core
        batch = a.shape[core:] if last else a.shape[:k]
        want = tuple(n if b == 1 else b for b, n in zip(batch, full[nd - k :]))
        if want == tuple(batch):
            return a
        return jnp.broadcast_to(a, a.shape[:core] + want if last else want + a.shape[k:])

    return map_leaves(obj, expand)


def lift(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Map a one-body function over the broadcast batch shape of its arguments."""

    def lifted(*args: Any) -> Any:
        last = _BATCH_LAST.get()
        full = batch_shape(*args)
        nd = len(full)
        if 1 in [s for a in args if is_rbjax_dataclass(a) for d in _batch_dims(a) for s in d]:
            args = tuple(_expand_ones(a, full, last) for a in args)
        f = fn
        # innermost vmap maps the last batch dimension; batch-last, each level's
        # output axis goes just before those of the levels inside it
        for level in reversed(range(nd)):
            in_axes = tuple(in_axes_of(a, level, nd, last) for a in args)
            f = jax.vmap(f, in_axes=in_axes, out_axes=level - nd if last else 0)
        return f(*args)

    return lifted
