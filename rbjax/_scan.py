"""The time loop's scans for ``simulate``: saving frames, and gradient checkpointing.

``simulate`` advances the state one saved chunk of steps at a time (``advance``)
and keeps the state after each chunk as a frame of the trajectory; with
``checkpoint=`` reverse mode recomputes segments instead of storing them.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["check_checkpoint", "checkpointed_scan", "frames_as_outputs", "frames_in_buffer"]


def frames_in_buffer(advance, carry0, xs, first, to_aos):
    """The saved frames and the checked-mode record: ``advance`` once per saved chunk, frames in one buffer.

    The saved frames go straight into the trajectory: one (n_out + 1)-frame
    buffer, filled with the initial state ``first`` and carried through the
    scan, each chunk's state written in place at its index. Scan outputs would
    need the initial frame put in front afterwards, a second copy of every saved
    frame (peak memory); emitting each chunk's state before advancing it would
    need a ``lax.cond`` to skip the last advance, and XLA hoists no loop-invariant
    work out of a cond branch (it would run every step).
    The buffer is linear in the loop (``dynamic_update_slice``), so reverse mode
    stores no copy of it per chunk.
    """
    n_out = xs[0].shape[0]
    buf0 = jax.tree.map(lambda a: jnp.broadcast_to(a[None], (n_out + 1,) + a.shape), first)

    def chunk(carry, xs):
        i, xs = xs
        inner_carry, buf = carry
        inner_carry = advance(inner_carry, xs)
        put = lambda b, a: jax.lax.dynamic_update_index_in_dim(b, a, i + 1, 0)
        return (inner_carry, jax.tree.map(put, buf, to_aos(inner_carry[0]))), None

    ((_, rec), traj), _ = jax.lax.scan(chunk, (carry0, buf0), (jnp.arange(n_out), xs))
    return traj, rec


def frames_as_outputs(advance, carry0, xs, first, to_aos, segment: int):
    """As :func:`frames_in_buffer`, in checkpointed segments of ``segment`` chunks.

    Checkpointed segments save their carry entering each segment for reverse
    mode: a carried buffer would be stored once per segment, so the frames are
    scan outputs here, with the initial one ``first`` put in front (a copy).
    """

    def emit(carry, xs):
        carry = advance(carry, xs)
        return carry, to_aos(carry[0])

    (_, rec), traj = checkpointed_scan(emit, carry0, xs, segment)
    return jax.tree.map(lambda a0, a: jnp.concatenate([a0[None], a]), first, traj), rec


def check_checkpoint(checkpoint: Any, steps: int, save_every: int) -> None:
    if checkpoint is None:
        return
    bad = isinstance(checkpoint, bool) or not isinstance(checkpoint, (int, np.integer))
    if bad or checkpoint < 1 or steps % checkpoint:
        raise ValueError(f"checkpoint must be None or a positive int dividing steps={steps}, got {checkpoint!r}")
    if save_every % checkpoint and checkpoint % save_every:
        raise ValueError(f"checkpoint={checkpoint} must divide save_every={save_every} or be a multiple of it")


def checkpointed_scan(f, carry, xs, segment: int | None):
    """``lax.scan(f, carry, xs)``, rematerialised in segments of ``segment`` iterations.

    The scan is split into an outer scan over segments whose body, an inner scan
    over one segment, is wrapped in ``jax.checkpoint``: reverse mode saves only
    the carry entering each segment and recomputes the segment's residuals when
    it reaches it. ``segment=None`` is the plain scan.
    """
    if segment is None:
        return jax.lax.scan(f, carry, xs)
    n = jax.tree.leaves(xs)[0].shape[0]
    split = lambda a: a.reshape((n // segment, segment) + a.shape[1:])

    @jax.checkpoint
    def run_segment(c, seg_xs):
        return jax.lax.scan(f, c, seg_xs)

    carry, ys = jax.lax.scan(run_segment, carry, jax.tree.map(split, xs))
    return carry, jax.tree.map(lambda a: a.reshape((n,) + a.shape[2:]), ys)
