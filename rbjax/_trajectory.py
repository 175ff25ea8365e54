"""Trajectories as batches whose leading axis is time: frames, slices, bodies, concatenation.

A trajectory from :func:`rbjax.simulate` (or :func:`rbjax.torque_free` with an
array of times) is a state of the same type whose every leaf has a leading time
axis ``T``: the changing fields ``(T, *B, ...)``, and the fields no integrator
changes (``body``, a particle's ``mass``) and ``time`` (``(T, *B)``) too. A body
shared by the whole batch keeps size-1 batch axes, ``(T, 1, ..., 1, ...)``, and
broadcasts like NumPy: one body per frame, not one per body and frame.

Because every leaf has the time axis, the JAX idioms work on trajectories as
they are: ``jax.tree.map(lambda x: x[-1], traj)`` is the last frame,
``jax.vmap(rb.kinetic_energy)(traj)`` maps over frames, and concatenating
leaves along axis 0 joins runs. Indexing (``traj[i]``, ``traj[a:b]``,
``traj[:, j]``), ``len``, iteration and :func:`concatenate` do the same with
checks and in rbjax's words, for every state type and for ``Body``.
"""

from __future__ import annotations

import operator
from collections.abc import Iterator, Sequence
from typing import Any, TypeVar

import jax
import jax.core
import jax.numpy as jnp
import numpy as np

from ._batching import map_leaves
from ._pytree import is_rbjax_dataclass, replace

__all__ = ["BatchIndexing", "concatenate", "index", "stack_frames"]

T = TypeVar("T")


def _leaves(obj: Any, prefix: str = "") -> Iterator[tuple[Any, str, str, Any, int]]:
    """``(owner, field, path, leaf, core_ndim)`` for every array leaf of an rbjax pytree."""
    for name in type(obj)._rbjax_data_fields:
        v = getattr(obj, name)
        if v is None:
            continue
        if is_rbjax_dataclass(v):
            yield from _leaves(v, f"{prefix}{name}.")
        else:
            yield obj, name, prefix + name, v, type(obj)._rbjax_core_ndim[name]


def full_batch_shape(obj: Any) -> tuple[int, ...]:
    """The broadcast batch shape of every leaf of ``obj`` (NumPy rules, size-1 axes broadcast)."""
    shapes = [leaf.shape[: leaf.ndim - core] for *_, leaf, core in _leaves(obj)]
    try:
        return tuple(np.broadcast_shapes(*shapes)) if shapes else ()
    except ValueError:
        raise ValueError(f"{type(obj).__name__}: the batch shapes of its fields {shapes} do not broadcast") from None


def stack_frames(frames: Any, initial: Any, times: Any) -> Any:
    """A trajectory from ``frames`` (changing fields ``(T, *B, ...)``) and the ``initial`` state.

    Every other field of ``initial`` (``body``, particle ``mass``) gets a leading
    time axis of length ``T``: shared batch axes stay size 1, so nothing is copied
    per body. ``times`` ``(T,)`` (or ``(T, S, 1, ...)``, one per segment) is
    broadcast to ``time`` ``(T, *B)``.
    """
    n = times.shape[0]
    nb = len(initial.batch_shape)
    changes = {}
    for name in type(initial)._rbjax_data_fields:
        if name == "time" or getattr(frames, name) is not None or getattr(initial, name) is None:
            continue

        def per_frame(a: Any, core: int) -> Any:
            lead = nb - (a.ndim - core)  # batch axes the leaf shares (missing in front)
            a = jnp.reshape(a, (1,) * (lead + 1) + a.shape)
            return jnp.broadcast_to(a, (n,) + a.shape[1:])

        v = getattr(initial, name)
        changes[name] = map_leaves(v, per_frame) if is_rbjax_dataclass(v) else per_frame(v, 0)
    lead = jnp.reshape(times, (n,) + (1,) * nb) if times.ndim == 1 else times
    # built on the frames' positions so that it takes their sharding (a batch split over
    # devices gets its times split the same way, not replicated)
    changes["time"] = lead + jnp.zeros_like(frames.position[..., 0])
    return replace(frames, **changes)


# --- indexing ---


def _normalise(idx: Any, shape: tuple[int, ...], what: str) -> tuple[Any, ...]:
    """``idx`` as one int / slice / 1-D integer array per leading batch axis, checked against ``shape``."""
    if not isinstance(idx, tuple):
        idx = (idx,)
    if sum(i is Ellipsis for i in idx) > 1:
        raise IndexError(f"{what}: an index can have only one Ellipsis (...)")
    if any(i is Ellipsis for i in idx):
        k = next(j for j, i in enumerate(idx) if i is Ellipsis)
        idx = idx[:k] + (slice(None),) * (len(shape) - len(idx) + 1) + idx[k + 1 :]
    if not shape:
        raise TypeError(
            f"{what} is a single body (batch shape ()): there is no batch or time axis to index. "
            "Index a batch or a trajectory from rb.simulate."
        )
    if len(idx) > len(shape):
        raise IndexError(
            f"{what} has batch shape {shape} ({len(shape)} axes; a trajectory's first axis is time), "
            f"but the index has {len(idx)} components. Vector components are not indexed this way: "
            "use the field, e.g. state.position[..., 0]."
        )
    out: list[Any] = []
    arrays = 0
    for axis, (i, n) in enumerate(zip(idx, shape)):
        if i is None:
            raise TypeError(f"{what}: None (a new axis) cannot index a state; reshape the fields instead")
        if isinstance(i, slice):
            out.append(i)
            continue
        if isinstance(i, (bool, np.bool_)):
            raise TypeError(f"{what}: a bool cannot index batch axis {axis}; use an integer or a slice")
        if isinstance(i, (int, np.integer)):
            if not -n <= int(i) < n:
                raise IndexError(f"{what}: index {int(i)} is out of range for batch axis {axis} of size {n}")
            out.append(int(i))
            continue
        a = i if isinstance(i, jax.core.Tracer) else jnp.asarray(i)
        if a.dtype == bool:
            raise TypeError(
                f"{what}: boolean masks are not supported on batch axis {axis}; use jnp.nonzero(mask)[0] as an index"
            )
        if not jnp.issubdtype(a.dtype, jnp.integer):
            raise TypeError(f"{what}: batch axis {axis} needs an integer index, got dtype {a.dtype}")
        if a.ndim > 1:
            raise IndexError(f"{what}: an index array must be 0-D or 1-D, got shape {a.shape}")
        if not isinstance(a, jax.core.Tracer):
            an = np.asarray(a)
            if an.size and (an.min() < -n or an.max() >= n):
                raise IndexError(f"{what}: indices {an} are out of range for batch axis {axis} of size {n}")
        if a.ndim == 1:
            arrays += 1
        out.append(a)
    if arrays > 1:
        raise IndexError(f"{what}: index with at most one integer array at a time (index one axis, then the next)")
    return tuple(out)


def index(obj: T, idx: Any) -> T:
    """``obj[idx]`` over the leading batch axes of every leaf, NumPy-broadcasting aware.

    A leaf that shares a batch axis (missing it, or size 1 there) is not
    indexed along it: a shared body stays shared.
    """
    shape = full_batch_shape(obj)
    comps = _normalise(idx, shape, type(obj).__name__)
    nd = len(shape)

    def pick(a: Any, core: int) -> Any:
        k = a.ndim - core
        lead = nd - k
        per_leaf = []
        for axis, c in enumerate(comps):
            p = axis - lead
            if p < 0:
                continue  # the leaf does not have this axis: shared along it
            if a.shape[p] == 1 and shape[axis] != 1:
                per_leaf.append(0 if isinstance(c, int) or getattr(c, "ndim", 1) == 0 else slice(None))
            else:
                per_leaf.append(c)
        return a[tuple(per_leaf)] if per_leaf else a

    return map_leaves(obj, pick)


class BatchIndexing:
    """Mixin: ``obj[i]``, ``len(obj)`` and iteration over the first batch axis (time, in a trajectory)."""

    def __getitem__(self: Any, idx: Any) -> Any:
        """Frame(s) or body(s): ``traj[i]``, ``traj[a:b]``, ``traj[:, j]``, ``batch[j]``.

        Indexes the leading batch axes only (never a vector's components);
        fields shared by the batch (a shared ``body``) stay shared.
        """
        return index(self, idx)

    def __len__(self: Any) -> int:
        shape = full_batch_shape(self)
        if not shape:
            raise TypeError(f"len() of a single {type(self).__name__} (batch shape ()): it has no batch axis")
        return shape[0]

    def __iter__(self: Any) -> Iterator[Any]:
        for i in range(len(self)):
            yield index(self, i)

    def __bool__(self) -> bool:  # not len(): a single body is an object, not an empty sequence
        return True


# --- concatenation ---


def _same(arrays: Sequence[Any]) -> bool:
    first = arrays[0]
    if any(a is not first for a in arrays[1:]):
        if any(isinstance(a, jax.core.Tracer) for a in arrays):
            return False
        if any(a.shape != first.shape for a in arrays):
            return False
        return all(bool(np.array_equal(np.asarray(a), np.asarray(first))) for a in arrays[1:])
    return True


def concatenate(items: Sequence[T], axis: int = 0) -> T:
    """Join states, trajectories or bodies along batch axis ``axis`` (0: time, for trajectories).

    ``items`` must be of one type, with the same batch shape except along
    ``axis`` and the same dtype. A field that every item shares along ``axis``
    with equal values (one body for all) stays shared; otherwise it is
    broadcast to each item's size along the axis first.

    Continuing a run: ``rb.concatenate([traj, rb.simulate(traj[-1], ...)[1:]])``
    (the continuation's first frame repeats ``traj[-1]``; ``time`` carries on, so
    time-dependent forces need no ``t0``). Concrete times must not go backwards.
    """
    items = list(items)
    if not items:
        raise ValueError("concatenate: needs at least one state")
    kind = type(items[0])
    if not is_rbjax_dataclass(items[0]) or any(type(s) is not kind for s in items):
        raise TypeError(
            f"concatenate: items must all be rbjax states or bodies of one type, got {[type(s) for s in items]}"
        )
    shapes = [full_batch_shape(s) for s in items]
    nd = len(shapes[0])
    if not -nd <= axis < nd:
        raise ValueError(f"concatenate: axis {axis} is out of range for batch shape {shapes[0]}")
    axis = operator.index(axis) % nd
    for s in shapes[1:]:
        if len(s) != nd or s[:axis] + s[axis + 1 :] != shapes[0][:axis] + shapes[0][axis + 1 :]:
            raise ValueError(f"concatenate: batch shapes {shapes} differ other than along axis {axis}")
    treedefs = {jax.tree.structure(s) for s in items}
    if len(treedefs) > 1:
        raise ValueError(f"concatenate: the {kind.__name__}s have different structures (a field None in some)")
    dtypes = {str(jax.tree.leaves(s)[0].dtype) for s in items}
    if len(dtypes) > 1:
        raise ValueError(
            f"concatenate: dtypes differ ({sorted(dtypes)}); cast first, e.g. jax.tree.map(lambda a: a.astype(...))"
        )
    per_item = [list(_leaves(s)) for s in items]
    new_leaves = []
    for j, (*_, leaf, core) in enumerate(per_item[0]):
        arrays = [p[j][3] for p in per_item]
        lead = nd - (leaf.ndim - core)
        shared = all(a.ndim == leaf.ndim for a in arrays) and (
            lead > axis or all(a.shape[axis - lead] == 1 for a in arrays)
        )
        if shared and _same(arrays):
            new_leaves.append(leaf)
            continue
        full = []
        for a, s in zip(arrays, shapes):
            a = jnp.reshape(a, (1,) * (nd - (a.ndim - core)) + a.shape)
            target = list(a.shape)
            target[axis] = s[axis]
            full.append(jnp.broadcast_to(a, tuple(target)))
        new_leaves.append(jnp.concatenate(full, axis=axis))
    times = [getattr(s, "time", None) for s in items]
    if axis == 0 and all(t is not None and t.ndim == nd for t in times):
        _check_times(times)  # only where the items look like trajectories (see there)
    # _leaves walks the fields in pytree order, as jax.tree.leaves does
    return jax.tree.unflatten(jax.tree.structure(items[0]), new_leaves)


def _check_times(times: list[Any]) -> None:
    """Trajectories must not go back in time from one item to the next.

    Items count as trajectories when their concrete times increase along the
    first axis (a batch of bodies at one time does not, and is not checked).
    """
    if any(isinstance(t, jax.core.Tracer) for t in times):
        return
    arrs = [np.asarray(t).reshape(t.shape[0], -1)[:, 0] for t in times]
    if not any(len(a) > 1 for a in arrs) or not all(np.all(np.diff(a) > 0) for a in arrs):
        return
    ends = [(float(np.min(np.asarray(t)[:1])), float(np.max(np.asarray(t)[-1:]))) for t in times]
    for k in range(1, len(ends)):
        if ends[k][0] < ends[k - 1][1]:
            raise ValueError(
                f"concatenate: item {k} starts at t = {ends[k][0]:g} s, before item {k - 1} ends "
                f"(t = {ends[k - 1][1]:g} s). To continue a run, drop the repeated first frame: "
                "rb.concatenate([traj, more[1:]])"
            )
