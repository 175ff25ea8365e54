"""Saving and loading states and trajectories: NPZ files with a metadata record.

One file is a plain ``.npz`` archive with a metadata record (the layout is in
:mod:`rbjax._npz`); arrays are stored as they are, so the round trip is bitwise.

A long run writes a directory of numbered chunk files through
:class:`ChunkWriter`, each written to a temporary name and renamed into
place, so a crash loses at most the chunk being written; :func:`load` of the
directory concatenates them along the time axis.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ._chunk_dir import chunk_files, load_chunks, read_run
from ._io_check import check_arrays
from ._npz import check_expect, metadata, read_npz, rebuild, to_jax, write_npz

__all__ = ["save", "load", "read_metadata"]


def save(
    path: str | os.PathLike,
    obj: Any,
    *,
    method: str | None = None,
    dt: Any = None,
    save_every: int | None = None,
    t0: Any = None,
    trajectory: bool | None = None,
) -> None:
    """Save a state, trajectory, :class:`Body`, :class:`Forces` or :class:`FitResult` to an ``.npz`` file.

    Args:
        path: file to write (written as given; no ``.npz`` is appended). Written
            atomically: a temporary file renamed into place.
        obj: a :class:`State`, :class:`MatrixState`, :class:`ParticleState` (one
            body, a batch ``(*B, ...)`` or a trajectory ``(T, *B, ...)``; a gyrostat's
            :class:`Rotors` and ``rotor_momentum`` with it), a :class:`Body`,
            :class:`Rotors` or :class:`Forces`, or a :class:`FitResult` (one fit or a batch; its
            flags and ``member_errors`` are kept in the metadata record).
            Leaves are stored exactly, in their dtype.
        method, dt, save_every, t0: optional metadata describing how a
            trajectory was made (``dt``, ``t0`` in s); see :func:`read_metadata`.
        trajectory: whether the leading axis of the changing fields is time
            (recorded, so that chunks concatenate); default: ``True`` when
            ``method`` or ``dt`` is given.

    ``load(path)`` returns an equal object, bitwise.
    """
    if trajectory is None:
        trajectory = method is not None or dt is not None
    meta = metadata(obj, trajectory=trajectory, method=method, dt=dt, save_every=save_every, t0=t0)
    write_npz(Path(path), obj, meta)


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """The metadata record of a file (or of the first chunk of a chunk directory).

    Keys: ``rbjax_version``, ``dtype``, ``method``, ``dt`` (s), ``save_every``,
    ``t0`` (s), ``time_stacked`` (field names), ``tree`` (the pytree structure:
    type names and fields, nested), ``format``, ``format_version``; for chunk
    directories also ``chunks`` (the number present), ``run`` (the planned run
    recorded by :func:`rbjax.simulate_chunked`, or ``None``) and ``complete``
    (whether that run finished; ``None`` without a record).
    """
    p = Path(path)
    if p.is_dir():
        files = chunk_files(p)
        meta, _ = read_npz(files[0])
        run = read_run(p)
        return {**meta, "chunks": len(files), "complete": None if run is None else bool(run["complete"]), "run": run}
    return read_npz(p)[0]


def load(
    path: str | os.PathLike, expect: type | tuple[type, ...] | None = None, *, allow_incomplete: bool = False
) -> Any:
    """Load what :func:`save` or a :class:`ChunkWriter` wrote.

    Args:
        path: an ``.npz`` file, or a directory of chunks from :class:`ChunkWriter`
            (concatenated along the time axis into one trajectory ``(T, *B, ...)``).
        expect: a pytree type (or tuple of types), e.g. ``rbjax.State``: raise
            ``ValueError`` if the file holds another.
        allow_incomplete: load the chunks of an interrupted run (whose record
            says it did not finish) instead of raising ``ValueError``.

    Returns the saved object with JAX arrays, bitwise equal to what was saved.
    Raises ``ValueError``, naming the file (and the field), for a missing,
    truncated or corrupted file; an array missing, unexpected, of another dtype
    than recorded, or of the wrong per-body shape (checked against each field's
    declaration, see :mod:`rbjax._io_check`); batch shapes that do not
    broadcast or time axes of different lengths; finite orientations that are
    not unit quaternions / rotations (non-finite frames of a diverged run load
    as saved); a file of another rbjax major version, a newer file format, a
    type other than ``expect``, or 64-bit data while JAX runs in 32-bit mode
    (which would round it); for a directory, an interrupted run (see
    ``allow_incomplete``) or chunks that disagree (``dt``, method,
    ``save_every``, dtype, repeated or missing frames). Orphaned ``*.tmp``
    files in a directory are ignored with a warning.
    """
    p = Path(path)
    if p.is_dir():
        return load_chunks(p, expect, allow_incomplete)
    meta, arrays = read_npz(p)
    check_expect(meta, expect, p)
    check_arrays(meta, arrays, p)
    return rebuild(meta["tree"], "", to_jax(arrays, p))
