"""Long runs in chunks: a host loop over one compiled ``simulate``, with progress.

One ``lax.scan`` over a million steps is fast but silent, holds the whole
trajectory on the device and loses everything on a crash. Here a Python loop
calls the same compiled ``simulate`` on chunks of ``chunk_steps`` steps (same
shapes, so it compiles once; ``t0`` is a traced argument), updates a tqdm bar
and can hand each chunk to a :class:`rbjax.ChunkWriter`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from ._checked import Checks
from ._chunk_dir import ChunkWriter, chunk_files, fingerprint
from ._io import load
from ._methods import DEFAULT_METHOD, AbstractMethod, is_registered
from ._simulate import run_simulation
from ._state import ForceLike, Forces, StateT
from ._typing import ArrayLike
from ._validate import check_run, is_time_series, start_time

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
    method: str | AbstractMethod | Callable[..., Any] = DEFAULT_METHOD,
    *,
    save_every: int = 1,
    chunk_steps: int | None = None,
    t0: Float[ArrayLike, ""] | None = None,
    progress: bool = True,
    writer: ChunkWriter | None = None,
    keep: bool = True,
    checked: bool | Checks = False,
    resume: bool = False,
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
        resume: continue an interrupted run in ``writer``'s directory (open it
            with ``ChunkWriter(directory, resume=True)``) from its last complete
            chunk, with the same arguments as the first call: they are compared
            with the run record (steps, ``dt``, method, ``save_every``,
            ``chunk_steps``, ``t0``, dtype, the initial state's fingerprint and
            the forces' where they have one: ``Forces`` and force models without
            function fields; a plain callable is not checked), ``ValueError``
            on any difference. The finished directory, and the returned
            trajectory, are bitwise equal to an uninterrupted run's: each chunk
            starts from the stored last frame of the one before, which is the
            state the uninterrupted run carried.

    Returns the trajectory with a leading time axis of ``steps // save_every +
    1`` frames on every leaf (as :func:`rbjax.simulate`), bitwise equal to
    ``simulate``'s (step ``k`` of every chunk runs at ``t0 + (steps done + k)
    dt``, as in one run). Time-series forces ``(steps, *B, 3)`` are sliced per
    chunk. Not differentiable as a whole (it is a host loop); use ``simulate``
    for gradients.

    With a ``writer`` the directory gets a run record (``run.json``: the plan
    above, marked complete after the last chunk), so ``rbjax.load`` refuses an
    interrupted run unless asked (``allow_incomplete=True``).
    """
    steps, save_every, method = check_run(state, dt, steps, method, save_every, t0, "simulate_chunked")
    # a registered method is recorded by name (method="rk4" and rb.methods()["rk4"] resume each other)
    name = method.name if is_registered(method) else None
    t0 = start_time(state) if t0 is None else t0
    if chunk_steps is None:
        chunk_steps = -(-10_000 // save_every) * save_every
    if isinstance(chunk_steps, bool) or not isinstance(chunk_steps, (int, np.integer)) or chunk_steps < 1:
        raise ValueError(f"chunk_steps must be a positive multiple of save_every={save_every}, got {chunk_steps!r}")
    if chunk_steps % save_every:
        raise ValueError(f"chunk_steps must be a positive multiple of save_every={save_every}, got {chunk_steps!r}")
    chunk_steps = int(min(chunk_steps, max(steps, save_every)))
    series = isinstance(forces, Forces) and is_time_series(forces, state, steps)
    kept: list[Any] = []
    current = state
    done, started = 0, False
    if writer is not None:
        writer.set_defaults(method=name, dt=dt, save_every=save_every, t0=t0)
        plan = _plan(state, forces, dt, steps, name, save_every, chunk_steps, t0)
        if resume:
            done, current, kept = _resume(writer, plan, keep)
            started = current is not None
            current = state if current is None else current
        else:
            if writer.count:
                raise ValueError(
                    f"simulate_chunked: {writer.directory} already holds {writer.count} chunk(s); pass "
                    "resume=True to continue that run"
                )
            writer.start_run(plan)
    elif resume:
        raise ValueError("simulate_chunked: resume=True needs writer=rbjax.ChunkWriter(directory, resume=True)")
    bar = _progress_bar(progress, steps)
    if bar is not None and done:
        bar.update(done)
    dt_arr, t0_arr = jnp.asarray(dt), jnp.asarray(t0)
    try:
        while done < steps or not started:  # steps=0 still makes (and writes) the one-frame trajectory
            started = True
            n = min(chunk_steps, steps - done)
            f = jax.tree.map(lambda a, sl=slice(done, done + n): a[sl], forces) if series else forces
            traj = run_simulation(
                current,
                f,
                dt_arr,
                n,
                method,
                save_every=save_every,
                t0=t0_arr,
                checked=checked,
                step_offset=done,
                warn_step_size=False,  # check_run above warned for the start state
            )
            part = traj if done == 0 else _frames(traj, slice(1, None))
            if writer is not None:
                writer.write(part, first_step=0 if done == 0 else done + save_every)
            if keep:
                kept.append(part)
            current = _frames(traj, -1)
            done += n
            if bar is not None:
                jax.block_until_ready(current)
                bar.update(n)
    finally:
        if bar is not None:
            bar.close()
    if writer is not None:
        writer.finish()
    if not keep:
        return current
    if len(kept) == 1:
        return kept[0]
    return jax.tree.map(lambda *a: jnp.concatenate(a), *kept)


def _plan(state, forces, dt, steps, method: str | None, save_every, chunk_steps, t0) -> dict[str, Any]:
    """The run record: what a resumed call must repeat exactly (``method``: its name, ``None`` if unregistered)."""
    return {
        "steps": int(steps),
        "dt": float(np.asarray(dt)),
        "method": method,
        "save_every": int(save_every),
        "chunk_steps": int(chunk_steps),
        "chunks_planned": max(1, -(-int(steps) // int(chunk_steps))),
        "t0": float(np.asarray(t0)),
        "dtype": str(state.dtype),
        "state_fingerprint": fingerprint(state),
        "forces_fingerprint": fingerprint(forces),
        "forces_kind": "None" if forces is None else type(forces).__name__,
    }


def _resume(writer: ChunkWriter, plan: dict[str, Any], keep: bool) -> tuple[int, Any, list[Any]]:
    """``(steps done, state to continue from, kept chunks)`` of the interrupted run in ``writer``'s directory."""
    run = writer.run
    if run is None:
        raise ValueError(f"simulate_chunked(resume=True): {writer.directory} has no run record to resume")
    for key, want in plan.items():
        if run.get(key) != want:
            raise ValueError(
                f"simulate_chunked(resume=True): {key} is {want!r} but the interrupted run in {writer.directory} "
                f"had {run.get(key)!r}; resume with the same arguments (or start afresh with overwrite=True)"
            )
    if writer.count == 0:
        return 0, None, []
    files = chunk_files(writer.directory)[: writer.count]
    parts = [load(f) for f in (files if keep else files[-1:])]  # each file checked as it loads
    done = min(writer.count * plan["chunk_steps"], plan["steps"])
    return done, _frames(parts[-1], -1), parts if keep else []
