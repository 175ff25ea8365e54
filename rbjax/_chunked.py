"""Long runs in chunks: a host loop over one compiled ``simulate``, with progress.

One ``lax.scan`` over a million steps is fast but silent, holds the whole
trajectory on the device and loses everything on a crash. Here a Python loop
calls the same compiled ``simulate`` on chunks of ``chunk_steps`` steps (same
shapes, so it compiles once; ``t0`` is a traced argument), updates a tqdm bar
and can hand each chunk to a :class:`rbjax.ChunkWriter`.
"""

from __future__ import annotations

import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from ._checked import Checks
from ._io import ChunkWriter
from ._simulate import _is_time_series, _run, start_time
from ._state import ForceLike, Forces, StateT
from ._typing import ArrayLike

__all__ = ["simulate_chunked"]


def _progress_bar(progress: bool, total: int) -> Any:
    if not progress:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:
        warnings.warn("progress=True needs tqdm (pip install 'rbjax[demo]'); running without a bar", stacklevel=3)
        return None
    return tqdm(total=total, unit="step", unit_scale=True, desc="rbjax.simulate_chunked")


def _frames(traj: Any, sl: slice | int) -> Any:
    """Slice the time axis (every leaf of a trajectory has it)."""
    return jax.tree.map(lambda a: a[sl], traj)


def simulate_chunked(
    state: StateT,
    forces: ForceLike,
    dt: Float[ArrayLike, ""],
    steps: int,
    method: str = "euler",
    *,
    save_every: int = 1,
    chunk_steps: int | None = None,
    t0: Float[ArrayLike, ""] | None = None,
    progress: bool = True,
    writer: ChunkWriter | None = None,
    keep: bool = True,
    checked: bool | Checks = False,
) -> StateT:
    """:func:`rbjax.simulate` in chunks of ``chunk_steps`` steps, with a progress bar.

    Same arguments and result as :func:`rbjax.simulate` (state ``(*B, ...)``,
    world-frame forces, ``dt`` and ``t0`` in s), plus:

    Args:
        chunk_steps: steps per chunk, a multiple of ``save_every``; default
            ``10_000`` rounded up to one, at most ``steps``. Every full chunk
            reuses one compiled program; a shorter last chunk compiles once more.
        progress: show a tqdm bar (steps done).
        writer: a :class:`rbjax.ChunkWriter` that receives each chunk as it is
            done (the first whole, later ones without their repeated initial
            frame), so ``rbjax.load(directory)`` returns the whole trajectory and a
            crash loses at most one chunk. ``method``, ``dt``, ``save_every`` and
            ``t0`` go into its metadata unless it has its own.
        keep: return the whole trajectory (``True``) or only the final state
            (``False``; for runs written to disk that do not fit in memory).
        checked: as in :func:`rbjax.simulate`; errors name the absolute step.

    Returns the trajectory with a leading time axis of ``steps // save_every +
    1`` frames (as :func:`rbjax.simulate`), equal to ``simulate``'s to round-off in
    the time ``t`` passed to callable forces (each chunk starts at
    ``t0 + k dt``). Time-series forces ``(steps, *B, 3)`` are sliced per
    chunk. Not differentiable as a whole (it is a host loop); use ``simulate``
    for gradients.
    """
    if not isinstance(steps, (int, np.integer)) or steps < 0:
        raise ValueError(f"steps must be a non-negative int, got {steps!r}")
    if not isinstance(save_every, (int, np.integer)) or save_every < 1 or steps % save_every:
        raise ValueError(f"save_every must be a positive int dividing steps={steps}, got {save_every!r}")
    if chunk_steps is None:
        chunk_steps = -(-10_000 // save_every) * save_every
    if not isinstance(chunk_steps, (int, np.integer)) or chunk_steps < 1 or chunk_steps % save_every:
        raise ValueError(f"chunk_steps must be a positive multiple of save_every={save_every}, got {chunk_steps!r}")
    chunk_steps = int(min(chunk_steps, max(steps, save_every)))
    series = isinstance(forces, Forces) and _is_time_series(forces, state, steps)
    t0 = start_time(state) if t0 is None else t0
    if writer is not None:
        writer.set_defaults(method=method, dt=dt, save_every=save_every, t0=t0)
    bar = _progress_bar(progress, steps)
    dt_arr, t0_arr = jnp.asarray(dt), jnp.asarray(t0)
    kept: list[Any] = []
    current = state
    done = 0
    try:
        while True:
            n = min(chunk_steps, steps - done)
            f = jax.tree.map(lambda a, sl=slice(done, done + n): a[sl], forces) if series else forces
            traj = _run(
                current,
                f,
                dt_arr,
                n,
                method,
                save_every=save_every,
                t0=t0_arr,
                checked=checked,
                step_offset=done,
            )
            part = traj if done == 0 else _frames(traj, slice(1, None))
            if writer is not None:
                writer.write(part)
            if keep:
                kept.append(part)
            current = _frames(traj, -1)
            done += n
            if bar is not None:
                jax.block_until_ready(current)
                bar.update(n)
            if done >= steps:
                break
    finally:
        if bar is not None:
            bar.close()
    if not keep:
        return current
    if len(kept) == 1:
        return kept[0]
    return jax.tree.map(lambda *a: jnp.concatenate(a), *kept)
