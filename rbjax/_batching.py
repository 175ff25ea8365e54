"""Lifting one-body functions to batches with ``vmap``.

Every physics kernel in rbjax is written for a single body. ``lift`` maps it
over any leading batch shape with numpy broadcasting semantics: a leaf of an
rbjax pytree whose rank equals its per-body rank (``core_ndim``) is shared by
every body (``in_axes=None``); one with ``k`` extra leading dimensions is batched
over the last ``k`` batch dimensions. So a single ``Body`` can drive a batch of
states, and a trajectory ``(T, N)`` can share its ``(N,)`` bodies over time.
Arguments that are not rbjax pytrees (``dt``, ``t``) are always shared.

Layout. Batch dimensions lead every leaf, ``(*B, *core)`` (array of
structures), in every object a user builds. :func:`to_batch_last` moves them
behind it, ``(*core, *B)`` (structure of arrays), and marks the objects it
returns so (:func:`rbjax._pytree.is_batch_last`; the mark rides in the treedef):
``simulate`` carries its state that way through the scan, so that the vmapped
one-body kernel reads and writes whole contiguous rows per component and
XLA:CPU fuses a step into one vectorised loop (with the batch leading, the
per-body components are a stride-3/4 gather that does not vectorise). Kernels
are the same either way; ``lift`` and :func:`batch_shape` read the layout from
their arguments, and ``lift`` marks what it returns with it, so a step that
lifts its per-body work runs unchanged in either layout and nothing outside the
arguments (no setting, no context) changes what a function does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from ._pytree import is_batch_last, is_rbjax_dataclass, replace, with_batch_last

__all__ = ["lift", "batch_shape", "to_batch_last", "to_batch_first", "with_layout"]


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


def with_layout(tree: Any, batch_last: bool) -> Any:
    """``tree`` with every rbjax object in it marked batch-last (``batch_last``) or batch-first; no array moves."""

    def mark(obj: Any) -> Any:
        if not is_rbjax_dataclass(obj):
            return obj
        inner = {n: with_layout(getattr(obj, n), batch_last) for n in type(obj)._rbjax_data_fields}
        changed = {n: v for n, v in inner.items() if v is not getattr(obj, n)}
        return with_batch_last(replace(obj, **changed) if changed else obj, batch_last)

    return jax.tree.map(mark, tree, is_leaf=is_rbjax_dataclass)


def _moved(obj: Any, batch_last: bool) -> Any:
    if not is_rbjax_dataclass(obj):
        return obj
    if is_batch_last(obj) == batch_last:
        raise ValueError(
            f"{type(obj).__name__} is already {'batch-last' if batch_last else 'batch-first'}: "
            "convert a tree once each way"
        )
    if batch_last:
        move = lambda a, c: jnp.moveaxis(a, tuple(range(a.ndim - c, a.ndim)), tuple(range(c)))
    else:
        move = lambda a, c: jnp.moveaxis(a, tuple(range(c)), tuple(range(a.ndim - c, a.ndim)))
    changes = {}
    for name in type(obj)._rbjax_data_fields:
        v = getattr(obj, name)
        if v is None:
            continue
        changes[name] = _moved(v, batch_last) if is_rbjax_dataclass(v) else move(v, type(obj)._rbjax_core_ndim[name])
    return with_batch_last(replace(obj, **changes), batch_last)


def to_batch_last(obj: Any) -> Any:
    """``(*B, *core)`` → ``(*core, *B)`` on every leaf (a shared leaf is unchanged), marked batch-last.

    ``ValueError`` for an object already batch-last. Anything but an rbjax pytree is returned as it is.
    """
    return _moved(obj, True)


def to_batch_first(obj: Any) -> Any:
    """``(*core, *B)`` → ``(*B, *core)`` on every leaf, marked batch-first; inverse of :func:`to_batch_last`."""
    return _moved(obj, False)


def _batch_dims(obj: Any) -> list[tuple[int, ...]]:
    """Batch shapes of every array leaf of an rbjax pytree (each object in its own layout)."""
    return [shape for _, shape in _leaf_batch_dims(obj, None)]


def _leaf_batch_dims(obj: Any, owner: str | None) -> list[tuple[str, tuple[int, ...]]]:
    """``(name, batch shape)`` of every array leaf; the names (``Class.field``, nested
    ``Outer.field.inner``) are written only when ``owner`` is given: an error message needs
    them, the traces that call this on every leaf do not."""
    last = is_batch_last(obj)
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


def _layout_of(args: tuple[Any, ...]) -> bool:
    """Whether ``lift``'s rbjax arguments are batch-last: ``ValueError`` where an object with batch
    dimensions is batch-first beside a batch-last one (a tree rebuilt by ``dataclasses.replace`` or a
    constructor from batch-last arrays: use :func:`rbjax._pytree.replace`, or mark it with
    :func:`with_layout`)."""
    marks: list[tuple[bool, bool, str]] = []  # (batch-last, has batch dimensions, class name)

    def visit(obj: Any) -> None:
        batched = False
        for name in type(obj)._rbjax_data_fields:
            v = getattr(obj, name)
            if is_rbjax_dataclass(v):
                visit(v)
            elif getattr(v, "ndim", 0) > type(obj)._rbjax_core_ndim[name]:
                batched = True
        marks.append((is_batch_last(obj), batched, type(obj).__name__))

    for a in args:
        if is_rbjax_dataclass(a):
            visit(a)
    if not any(last for last, _, _ in marks):
        return False
    mixed = sorted({name for last, batched, name in marks if batched and not last})
    if mixed:
        raise ValueError(
            f"lift: batch-first {', '.join(mixed)} beside batch-last arguments: their arrays' layout is unknown"
        )
    return True


def lift(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Map a one-body function over the broadcast batch shape of its arguments.

    In the layout of its arguments (:func:`to_batch_last`): batch-last arguments give
    batch-last results, every rbjax object in them marked so.
    """

    def lifted(*args: Any) -> Any:
        last = _layout_of(args)
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
        out = f(*args)
        # what the one-body function built is marked as its own arguments were: mark it as the batch's
        return with_layout(out, True) if last else out

    return lifted
