"""Saving and loading states and trajectories: NPZ files with a metadata record.

One file is a plain ``.npz`` archive: one array per pytree leaf, named by its
path (``"body.inertia"``, ``"orientation"``), plus ``__rbjax__``, a JSON string
(a NumPy unicode array, so loading needs no pickle) recording the rbjax
version, the pytree structure (type names, nested bodies, absent ``None``
fields), the dtype, which fields carry a time axis, and optional ``method`` /
``dt`` / ``save_every`` / ``t0``. Arrays are stored as they are, so the round
trip is bitwise.

A long run writes a directory of numbered chunk files through
:class:`ChunkWriter`, each written to a temporary name and renamed into
place, so a crash loses at most the chunk being written; :func:`load` of the
directory concatenates them along the time axis.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._body import Body
from ._io_check import check_arrays
from ._pytree import is_rbjax_dataclass, new_unchecked
from ._state import Forces, MatrixState, ParticleState, State

__all__ = ["save", "load", "read_metadata"]

_FORMAT = "rbjax-npz"
_FORMAT_VERSION = 1
_META_KEY = "__rbjax__"
_TYPES: dict[str, type] = {t.__name__: t for t in (State, MatrixState, ParticleState, Body, Forces)}


def _version() -> str:
    from . import __version__

    return __version__


def _major(version: str) -> str:
    return version.split(".", 1)[0]


def _structure(obj: Any, prefix: str, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    """JSON description of ``obj``; fills ``arrays`` with its leaves by dotted path."""
    if type(obj).__name__ not in _TYPES or type(obj) is not _TYPES[type(obj).__name__]:
        raise TypeError(f"save: can store State, MatrixState, ParticleState, Body or Forces, got {type(obj)}")
    fields: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        path = f"{prefix}{f.name}"
        if v is None:
            fields[f.name] = None
        elif is_rbjax_dataclass(v):
            fields[f.name] = _structure(v, path + ".", arrays)
        else:
            arrays[path] = np.asarray(v)
            fields[f.name] = "array"
    return {"type": type(obj).__name__, "fields": fields}


def _rebuild(spec: dict[str, Any], prefix: str, arrays: dict[str, Any]) -> Any:
    cls = _TYPES.get(spec.get("type", ""))
    if cls is None:
        raise ValueError(f"load: unknown pytree type {spec.get('type')!r} in the metadata")
    values = {}
    for f in dataclasses.fields(cls):
        if f.name not in spec["fields"] and f.default is not dataclasses.MISSING:
            values[f.name] = None if f.default is None else jnp.asarray(f.default)  # a field newer than the file
    for name, sub in spec["fields"].items():
        path = f"{prefix}{name}"
        if sub is None:
            values[name] = None
        elif sub == "array":
            values[name] = arrays[path]
        else:
            values[name] = _rebuild(sub, path + ".", arrays)
    # no re-validation: the file holds what was saved, including a blown-up run
    return new_unchecked(cls, **values)


def _time_stacked(obj: Any) -> list[str]:
    """Top-level fields of a trajectory that carry the leading time axis."""
    if isinstance(obj, (State, MatrixState, ParticleState)):
        # every field of a trajectory has the time axis (see rbjax._trajectory)
        return [f.name for f in dataclasses.fields(obj) if getattr(obj, f.name) is not None]
    return []


def _metadata(
    obj: Any,
    *,
    trajectory: bool,
    method: str | None,
    dt: Any,
    save_every: int | None,
    t0: Any,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    leaves = jax.tree_util.tree_leaves(obj)
    dtypes = sorted({str(np.asarray(a).dtype) for a in leaves})
    meta = {
        "format": _FORMAT,
        "format_version": _FORMAT_VERSION,
        "rbjax_version": _version(),
        "dtype": dtypes[0] if len(dtypes) == 1 else dtypes,
        "time_stacked": _time_stacked(obj) if trajectory else [],
        "method": method,
        "dt": None if dt is None else float(np.asarray(dt)),
        "save_every": None if save_every is None else int(save_every),
        "t0": None if t0 is None else float(np.asarray(t0)),
    }
    meta.update(extra or {})
    return meta


def _write_npz(path: Path, obj: Any, meta: dict[str, Any]) -> None:
    arrays: dict[str, np.ndarray] = {}
    meta = {**meta, "tree": _structure(obj, "", arrays)}
    # Write to a temporary file in the same directory and rename: a crash leaves
    # either the old file or the new one, never half a file.
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            # numpy's stub lets a ** mapping fill allow_pickle; these keys are field names
            np.savez(f, **{_META_KEY: np.array(json.dumps(meta))}, **arrays)  # pyright: ignore[reportArgumentType]
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


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
    """Save a state, trajectory, :class:`Body` or :class:`Forces` to an ``.npz`` file.

    Args:
        path: file to write (written as given; no ``.npz`` is appended). Written
            atomically: a temporary file renamed into place.
        obj: a :class:`State`, :class:`MatrixState`, :class:`ParticleState` (one
            body, a batch ``(*B, ...)`` or a trajectory ``(T, *B, ...)``), a :class:`Body` or
            :class:`Forces`. Leaves are stored exactly, in their dtype.
        method, dt, save_every, t0: optional metadata describing how a
            trajectory was made (``dt``, ``t0`` in s); see :func:`read_metadata`.
        trajectory: whether the leading axis of the changing fields is time
            (recorded, so that chunks concatenate); default: ``True`` when
            ``method`` or ``dt`` is given.

    ``load(path)`` returns an equal object, bitwise.
    """
    if trajectory is None:
        trajectory = method is not None or dt is not None
    meta = _metadata(obj, trajectory=trajectory, method=method, dt=dt, save_every=save_every, t0=t0)
    _write_npz(Path(path), obj, meta)


def _read_npz(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    try:
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ValueError(f"load: {path} does not exist") from None
    except Exception as e:  # noqa: BLE001  (zipfile, zlib, numpy and OS errors alike: the file is unreadable)
        raise ValueError(f"load: cannot read {path} as an .npz archive (truncated or corrupted?): {e}") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"load: {path} is a single .npy array, not an rbjax .npz file")
    with z:
        if _META_KEY not in z.files:
            raise ValueError(f"load: {path} is not an rbjax file (no {_META_KEY!r} record)")
        try:
            meta = json.loads(str(z[_META_KEY]))
            # every member is read (and CRC-checked) here, so a damaged one is named now
            arrays = {}
            for k in z.files:
                if k != _META_KEY:
                    arrays[k] = z[k]
        except Exception as e:  # noqa: BLE001  (BadZipFile, bad CRC-32, zlib, truncated member, bad JSON)
            raise ValueError(f"load: {path} is damaged (truncated or corrupted?): {type(e).__name__}: {e}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("tree"), dict):
        raise ValueError(f"load: {path} has a malformed {_META_KEY!r} record")
    if meta.get("format") != _FORMAT:
        raise ValueError(f"load: {path} is not an rbjax file (format {meta.get('format')!r})")
    if meta.get("format_version", 0) > _FORMAT_VERSION:
        raise ValueError(
            f"load: {path} uses file format {meta.get('format_version')}, newer than this rbjax "
            f"({_version()}) reads ({_FORMAT_VERSION}); upgrade rbjax"
        )
    saved = str(meta.get("rbjax_version", "?"))
    if _major(saved) != _major(_version()):
        raise ValueError(
            f"load: {path} was written by rbjax {saved}, whose major version differs from this "
            f"rbjax {_version()}; load it with rbjax {_major(saved)}.x"
        )
    return meta, arrays


def _check_expect(meta: dict[str, Any], expect: type | tuple[type, ...] | None, path: Path) -> None:
    if expect is None:
        return
    wanted = expect if isinstance(expect, tuple) else (expect,)
    name = meta["tree"]["type"]
    if name not in {t.__name__ for t in wanted}:
        raise ValueError(f"load: {path} holds a {name}, expected {' or '.join(t.__name__ for t in wanted)}")


def _to_jax(arrays: dict[str, np.ndarray], path: Path) -> dict[str, Any]:
    wide = [k for k, a in arrays.items() if a.dtype in (np.float64, np.complex128, np.int64)]
    if wide and not jax.config.read("jax_enable_x64"):
        raise ValueError(
            f"load: {path} holds 64-bit arrays ({wide[0]!r}, ...) but JAX runs in 32-bit mode, which "
            "would round them; enable it first with jax.config.update('jax_enable_x64', True)"
        )
    return {k: jnp.asarray(a) for k, a in arrays.items()}


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """The metadata record of a file (or of the first chunk of a chunk directory).

    Keys: ``rbjax_version``, ``dtype``, ``method``, ``dt`` (s), ``save_every``,
    ``t0`` (s), ``time_stacked`` (field names), ``tree`` (the pytree structure:
    type names and fields, nested), ``format``, ``format_version``; for chunk
    directories also ``chunks`` (the number present), ``run`` (the planned run
    recorded by :func:`rbjax.simulate_chunked`, or ``None``) and ``complete``
    (whether that run finished; ``None`` without a record).
    """
    from ._chunk_dir import chunk_files, read_run  # builds on this module

    p = Path(path)
    if p.is_dir():
        files = chunk_files(p)
        meta, _ = _read_npz(files[0])
        run = read_run(p)
        return {**meta, "chunks": len(files), "complete": None if run is None else bool(run["complete"]), "run": run}
    return _read_npz(p)[0]


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
    from ._chunk_dir import load_chunks  # builds on this module

    p = Path(path)
    if p.is_dir():
        return load_chunks(p, expect, allow_incomplete)
    meta, arrays = _read_npz(p)
    _check_expect(meta, expect, p)
    check_arrays(meta, arrays, p)
    return _rebuild(meta["tree"], "", _to_jax(arrays, p))
