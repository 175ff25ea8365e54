"""The rbjax file format: one ``.npz`` archive per state, trajectory, body or forces.

One array per pytree leaf, named by its path (``"body.inertia"``,
``"orientation"``), plus ``__rbjax__``, a JSON string (a NumPy unicode array,
so reading needs no pickle) recording the rbjax version, the pytree structure
(type names, nested bodies, absent ``None`` fields), the dtype, which fields
carry a time axis, and optional ``method`` / ``dt`` / ``save_every`` / ``t0``.
Arrays are stored as they are, so the round trip is bitwise. Files are written
atomically (:func:`write_atomic`).

Imports run one way: this module (the format) <- :mod:`._io_check` (checks of
a file's arrays) <- :mod:`._chunk_dir` (chunk directories) <- :mod:`._io`
(``save``/``load``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import jax
import jax.numpy as jnp
import numpy as np

from ._body import Body
from ._pytree import is_rbjax_dataclass, new_unchecked
from ._rotors import Rotors
from ._state import Forces, MatrixState, ParticleState, State
from .identification._result import FitResult

__all__ = [
    "META_KEY",
    "TYPES",
    "check_expect",
    "metadata",
    "read_npz",
    "rebuild",
    "to_jax",
    "write_atomic",
    "write_npz",
]

_FORMAT = "rbjax-npz"
_FORMAT_VERSION = 1
META_KEY = "__rbjax__"
# the pytree types a file may hold, by name
TYPES: dict[str, type] = {t.__name__: t for t in (State, MatrixState, ParticleState, Body, Rotors, Forces, FitResult)}


def _version() -> str:
    """``rbjax.__version__``, read when a file is written or read (the package is imported by then)."""
    return sys.modules[__name__.rpartition(".")[0]].__version__


def _major(version: str) -> str:
    return version.split(".", 1)[0]


def write_atomic(path: Path, write: Callable[[IO[bytes]], object]) -> None:
    """Write ``path`` through ``write(file)`` into a temporary file in the same directory, then rename.

    A crash leaves either the old file or the new one, never half a file (the
    temporary ``<name>.*.tmp`` is removed on any error, left behind only if
    the process dies).
    """
    if not path.parent.is_dir():  # else mkstemp's error names the temporary file, not the user's path
        raise FileNotFoundError(f"save: the folder {path.parent} of {path.name} does not exist; create it first")
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _structure(obj: Any, prefix: str, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    """JSON description of ``obj``; fills ``arrays`` with its leaves by dotted path."""
    if type(obj).__name__ not in TYPES or type(obj) is not TYPES[type(obj).__name__]:
        raise TypeError(
            f"save: can store State, MatrixState, ParticleState, Body, Rotors, Forces or FitResult, got {type(obj)}"
        )
    fields: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        path = f"{prefix}{f.name}"
        if f.metadata.get("static"):
            # a static field (a flag, a count, messages) is part of the structure: stored in the JSON record
            fields[f.name] = {"static": list(v) if isinstance(v, tuple) else v}
        elif v is None:
            fields[f.name] = None
        elif is_rbjax_dataclass(v):
            fields[f.name] = _structure(v, path + ".", arrays)
        else:
            arrays[path] = np.asarray(v)
            fields[f.name] = "array"
    return {"type": type(obj).__name__, "fields": fields}


def rebuild(spec: dict[str, Any], prefix: str, arrays: dict[str, Any]) -> Any:
    cls = TYPES.get(spec.get("type", ""))
    if cls is None:
        raise ValueError(f"load: unknown pytree type {spec.get('type')!r} in the metadata")
    values = {}
    for f in dataclasses.fields(cls):
        if f.name not in spec["fields"] and f.default is not dataclasses.MISSING:
            # a field newer than the file
            values[f.name] = f.default if f.default is None or f.metadata.get("static") else jnp.asarray(f.default)
    for name, sub in spec["fields"].items():
        path = f"{prefix}{name}"
        if sub is None:
            values[name] = None
        elif isinstance(sub, dict) and "static" in sub:
            values[name] = tuple(sub["static"]) if isinstance(sub["static"], list) else sub["static"]
        elif sub == "array":
            values[name] = arrays[path]
        else:
            values[name] = rebuild(sub, path + ".", arrays)
    # no re-validation: the file holds what was saved, including a blown-up run
    return new_unchecked(cls, **values)


def _time_stacked(obj: Any) -> list[str]:
    """Top-level fields of a trajectory that carry the leading time axis."""
    if isinstance(obj, (State, MatrixState, ParticleState)):
        # every field of a trajectory has the time axis (see rbjax._trajectory)
        return [f.name for f in dataclasses.fields(obj) if getattr(obj, f.name) is not None]
    return []


def metadata(
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


def write_npz(path: Path, obj: Any, meta: dict[str, Any]) -> None:
    """Write ``obj`` with the metadata record ``meta`` (plus its ``tree``) to ``path``, atomically."""
    arrays: dict[str, np.ndarray] = {}
    meta = {**meta, "tree": _structure(obj, "", arrays)}

    def write(f: IO[bytes]) -> None:
        # numpy's stub lets a ** mapping fill allow_pickle; these keys are field names
        np.savez(f, **{META_KEY: np.array(json.dumps(meta))}, **arrays)  # pyright: ignore[reportArgumentType]

    write_atomic(path, write)


def read_npz(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    try:
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ValueError(f"load: {path} does not exist") from None
    except Exception as e:  # noqa: BLE001  (zipfile, zlib, numpy and OS errors alike: the file is unreadable)
        # numpy reads a file without the zip signature as a pickle and suggests allow_pickle: not a remedy here
        why = "it is not a zip archive" if "pickled" in str(e) else e
        raise ValueError(f"load: cannot read {path} as an .npz archive (truncated or corrupted?): {why}") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"load: {path} is a single .npy array, not an rbjax .npz file")
    with z:
        if META_KEY not in z.files:
            raise ValueError(f"load: {path} is not an rbjax file (no {META_KEY!r} record)")
        try:
            meta = json.loads(str(z[META_KEY]))
            # every member is read (and CRC-checked) here, so a damaged one is named now
            arrays = {}
            for k in z.files:
                if k != META_KEY:
                    arrays[k] = z[k]
        except Exception as e:  # noqa: BLE001  (BadZipFile, bad CRC-32, zlib, truncated member, bad JSON)
            raise ValueError(f"load: {path} is damaged (truncated or corrupted?): {type(e).__name__}: {e}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("tree"), dict):
        raise ValueError(f"load: {path} has a malformed {META_KEY!r} record")
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


def check_expect(meta: dict[str, Any], expect: type | tuple[type, ...] | None, path: Path) -> None:
    if expect is None:
        return
    wanted = expect if isinstance(expect, tuple) else (expect,)
    name = meta["tree"]["type"]
    if name not in {t.__name__ for t in wanted}:
        raise ValueError(f"load: {path} holds a {name}, expected {' or '.join(t.__name__ for t in wanted)}")


def to_jax(arrays: dict[str, np.ndarray], path: Path) -> dict[str, Any]:
    wide = [k for k, a in arrays.items() if a.dtype in (np.float64, np.complex128, np.int64)]
    if wide and not jax.config.read("jax_enable_x64"):
        raise ValueError(
            f"load: {path} holds 64-bit arrays ({wide[0]!r}, ...) but JAX runs in 32-bit mode, which "
            "would round them; enable it first with jax.config.update('jax_enable_x64', True)"
        )
    return {k: jnp.asarray(a) for k, a in arrays.items()}
