"""Sharding a batch of bodies over devices: one ``NamedSharding`` per leaf."""

from __future__ import annotations

from typing import Any

import jax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._batching import map_leaves
from ._pytree import is_rbjax_dataclass
from ._trajectory import full_batch_shape

__all__ = ["batch_sharding"]


def batch_sharding(obj: Any, mesh: Mesh, axis_name: str = "bodies", batch_axis: int = 0) -> Any:
    """Shardings that split ``obj``'s batch axis ``batch_axis`` over the mesh axis ``axis_name``.

    Args:
        obj: a state, trajectory, :class:`rbjax.Body` or :class:`rbjax.Forces`
            of batch shape ``B`` (``(T, *B)`` for a trajectory: pass
            ``batch_axis=1`` to split its bodies).
        mesh: the device mesh, e.g. ``jax.make_mesh((jax.device_count(),), ("bodies",))``.
        axis_name: the mesh axis to split the bodies over.
        batch_axis: which batch axis holds the bodies.

    Returns the same pytree with a ``NamedSharding`` in place of every leaf: a
    leaf with the full batch axis is split along it; a leaf the batch shares
    (one ``Body`` for all, a state's ``time``, size 1 or missing along the
    axis) is replicated. Use it with ``jax.device_put(obj, batch_sharding(obj,
    mesh))``, ``jax.make_array_from_process_local_data`` or ``out_shardings``.
    """
    if not is_rbjax_dataclass(obj):
        raise TypeError(
            f"batch_sharding: obj must be an rbjax state, trajectory, Body or Forces, got {type(obj).__name__}"
        )
    if not isinstance(mesh, Mesh):
        raise TypeError(f"batch_sharding: mesh must be a jax.sharding.Mesh, got {type(mesh).__name__}")
    shape = full_batch_shape(obj)
    if not -len(shape) <= batch_axis < len(shape):
        raise ValueError(f"batch_sharding: batch_axis {batch_axis} is out of range for batch shape {shape}")
    if axis_name not in mesh.axis_names:
        raise ValueError(f"batch_sharding: the mesh has axes {mesh.axis_names}, not {axis_name!r}")
    nd, axis = len(shape), batch_axis % len(shape)

    def spec(a: Any, core: int) -> NamedSharding:
        lead = nd - (a.ndim - core)
        parts: list[Any] = [None] * a.ndim
        p = axis - lead
        if p >= 0 and a.shape[p] == shape[axis] != 1:
            parts[p] = axis_name
        return NamedSharding(mesh, PartitionSpec(*parts))

    out = map_leaves(obj, spec)
    # the result is a pytree of shardings with obj's structure (no array work was done)
    assert jax.tree.structure(out) == jax.tree.structure(obj)
    return out
