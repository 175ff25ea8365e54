"""Checks of a loaded file's arrays against its metadata, generic over the pytree dataclasses.

Each array is checked against its field's declaration: present, of the
annotation's kind (``Float``: a real dtype equal to the recorded one;
``Bool``: bool; ``Int``: an integer dtype recorded), and the per-body trailing
shape the field declares (``field(core_shape=(4,))``: ends in ``(4,)``), so a
new field is checked without listing it here. Batch shapes must broadcast
across an object's fields, and the time axis of a trajectory must have one
length. Two semantic checks know field names, the
orientation kinds: ``orientation`` must hold unit quaternions and ``rotation``
rotation matrices (tolerance :func:`rbjax._state.quat_tolerance`), in every
frame that is finite; non-finite frames load as saved (a run that blew up).
A :class:`Body` (alone, or a state's), a :class:`ParticleState`'s masses and a
gyrostat's :class:`Rotors` go through the constructors' own checks
(:func:`rbjax._body.check_body`, :func:`rbjax._state.check_particle_mass`,
``Rotors``): a file edited to a negative mass, an indefinite inertia or a
rotor of ``J ≤ 0`` would otherwise run, and report negative energies. A
simulation never changes them, so a run that blew up still loads.
Errors are ``ValueError`` naming the file and the field.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ._body import Body, check_body
from ._math import quat_tolerance
from ._npz import TYPES
from ._pytree import core_shape_of
from ._rotors import Rotors
from ._state import ParticleState, check_particle_mass

__all__ = ["check_arrays", "core_shape"]


def core_shape(cls: type, name: str) -> tuple[int, ...] | None:
    """Declared per-body trailing shape of field ``name`` (``field(core_shape=...)``); ``None`` if it declares none."""
    return core_shape_of(cls).get(name)


def _kind(cls: type, name: str) -> str:
    """``"bool"``, ``"int"`` or ``"float"``: the dtype kind of field ``name``'s jaxtyping annotation."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            text = str(f.type)
            return "bool" if text.startswith("Bool[") else "int" if text.startswith("Int[") else "float"
    return "float"


def check_arrays(meta: dict[str, Any], arrays: dict[str, np.ndarray], path: Path) -> None:
    """``ValueError`` unless ``arrays`` are exactly what ``meta["tree"]`` describes."""
    wanted = meta.get("dtype")
    dtypes = set(wanted) if isinstance(wanted, list) else {wanted}
    expected: set[str] = set()
    stacked = set(meta.get("time_stacked", []))
    lengths: dict[str, int] = {}
    _check_object(meta["tree"], "", arrays, path, dtypes, expected, stacked, lengths, top=True)
    extra = sorted(set(arrays) - expected)
    if extra:
        raise ValueError(f"load: {path} holds array(s) {extra} that its metadata does not describe")
    if len(set(lengths.values())) > 1:
        raise ValueError(f"load: {path}: the time-stacked fields disagree on the number of frames: {lengths}")


def _check_object(spec, prefix, arrays, path, dtypes, expected, stacked, lengths, *, top: bool) -> list:
    cls = TYPES.get(spec.get("type", "")) if isinstance(spec, dict) else None
    if cls is None:
        raise ValueError(f"load: {path}: unknown pytree type {spec.get('type') if isinstance(spec, dict) else spec!r}")
    fields = spec.get("fields")
    declared = [f.name for f in dataclasses.fields(cls)]
    if not isinstance(fields, dict) or sorted(fields) != sorted(declared):
        raise ValueError(f"load: {path}: the metadata's fields of {cls.__name__} are not {declared}")
    cores: dict[str, int] = cls._rbjax_core_ndim  # type: ignore[attr-defined]
    batches = []
    for name, sub in fields.items():
        key = f"{prefix}{name}"
        if sub is None or (isinstance(sub, dict) and "static" in sub):
            continue
        if sub != "array":
            batches += _check_object(sub, key + ".", arrays, path, dtypes, expected, stacked, lengths, top=False)
            continue
        expected.add(key)
        if key not in arrays:
            raise ValueError(f"load: {path} lacks the array {key!r} that its metadata lists (truncated or edited?)")
        a = arrays[key]
        kind = _kind(cls, name)
        if kind == "bool":
            ok = a.dtype == np.bool_
        else:
            ok = np.issubdtype(a.dtype, np.integer if kind == "int" else np.floating) and str(a.dtype) in dtypes
        if not ok:
            raise ValueError(f"load: {path}: {key!r} has dtype {a.dtype}, but the metadata records {sorted(dtypes)}")
        core = cores.get(name, 0)
        want = core_shape(cls, name)
        lead = 1 if top and name in stacked else 0
        if a.ndim < core + lead:
            raise ValueError(f"load: {path}: {key!r} has shape {a.shape}, too few axes for {cls.__name__}.{name}")
        if want is not None and a.shape[a.ndim - core :] != want:
            raise ValueError(
                f"load: {path}: {key!r} has shape {a.shape}, but {cls.__name__}.{name} ends in {want} per body"
            )
        if lead:
            lengths[key] = a.shape[0]
        batches.append((key, a.shape[lead : a.ndim - core]))
        _check_orientation(name, key, a, core, path)
    try:
        np.broadcast_shapes(*(b for _, b in batches))
    except ValueError:
        raise ValueError(
            f"load: {path}: the batch shapes of {cls.__name__}'s fields do not broadcast: {batches}"
        ) from None
    _check_masses(cls, prefix, arrays, path)
    return batches


def _check_masses(cls: type, prefix: str, arrays: dict[str, np.ndarray], path: Path) -> None:
    """The constructors' checks of a :class:`Body` or :class:`ParticleState` read from a file."""
    owner = f"load: {path}"
    try:
        if cls is Body:
            mass, inertia = arrays[prefix + "mass"], arrays[prefix + "inertia"]
            batch = np.broadcast_shapes(mass.shape, inertia.shape[:-2])
            check_body(
                np.broadcast_to(mass, batch),
                np.broadcast_to(inertia, batch + (3, 3)),
                owner,
                (repr(prefix + "mass"), repr(prefix + "inertia")),
            )
        elif cls is ParticleState:
            check_particle_mass(arrays[prefix + "mass"], owner, repr(prefix + "mass"))
        elif cls is Rotors:
            try:  # the constructor's checks: unit axes, J > 0, finite
                Rotors(arrays[prefix + "axes"], arrays[prefix + "inertia"])
            except ValueError as e:
                raise ValueError(f"{owner}: {prefix.rstrip('.')}: {e}") from None
    except ValueError as e:
        raise ValueError(f"{e} (the file was edited or corrupted)") from None


def _check_orientation(name: str, key: str, a: np.ndarray, core: int, path: Path) -> None:
    if name not in ("orientation", "rotation") or a.size == 0:
        return
    x = a.astype(np.float64)
    finite = np.isfinite(x).reshape(x.shape[: x.ndim - core] + (-1,)).all(axis=-1)
    tol = quat_tolerance(a.dtype)
    if name == "orientation":
        err = np.abs(np.linalg.norm(x, axis=-1) - 1)
    else:
        err = np.max(np.abs(np.swapaxes(x, -1, -2) @ x - np.eye(3)), axis=(-1, -2))
    err = np.where(finite, err, 0.0)
    if np.any(err > tol):
        what = "unit quaternions" if name == "orientation" else "rotation matrices (RᵀR = 1)"
        raise ValueError(
            f"load: {path}: {key!r} must hold {what}; the worst finite entry is off by {np.max(err):.3g} "
            f"(tolerance {tol:.3g}): the file was edited or corrupted"
        )
