"""Frozen-dataclass pytrees.

Registration is by hand rather than with ``jax.tree_util.register_dataclass``
because that function unflattens through ``__init__``: every jit output, every
``tree_map`` would re-run the validation in ``__post_init__`` (and a device-to-host
copy with it). Here unflattening bypasses ``__init__`` as equinox does, so
validation runs once, where a user builds the object.

Each object also records the memory layout of its arrays (see :mod:`rbjax._batching`):
batch-first ``(*B, *core)``, as users build them, or batch-last ``(*core, *B)``, as
``simulate`` carries its state. The layout is data, not a setting: it rides in the
treedef (a batch-last object's auxiliary data ends in :data:`_BATCH_LAST`; a batch-first
object's treedef is what it would be without layouts), so it survives ``jit``,
``vmap``, ``scan`` and ``tree_map``, and :func:`replace` keeps it.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable
from typing import Any, TypeVar

import jax

if sys.version_info >= (3, 11):
    from typing import dataclass_transform
else:  # typing_extensions comes with jax's dependencies (equinox, chex)
    from typing_extensions import dataclass_transform

T = TypeVar("T")

__all__ = [
    "pytree_dataclass",
    "field",
    "static_field",
    "replace",
    "new_unchecked",
    "core_ndim_of",
    "core_shape_of",
    "data_fields",
    "is_batch_last",
    "with_batch_last",
]


def field(
    *,
    core_ndim: int = 0,
    core_shape: tuple[int, ...] | None = None,
    converter: Callable[[Any], Any] | None = None,
    **kwargs: Any,
) -> Any:
    """A data field (a pytree leaf or subtree) of rank ``core_ndim`` per body, for a force model's fields.

    ``rb.field(core_shape=(3,))`` declares a vector per body: an array ``(3,)`` is
    shared by the batch, ``(N, 3)`` gives each body its own when a
    :class:`rbjax.PerBodyForce` is lifted over the batch (a plain field is per body
    when it has any dimension).

    ``core_ndim`` is the rank of the field for a single body (0 for a mass, 1 for
    a vector, 2 for a 3x3 tensor). Leading dimensions beyond it are batch
    dimensions; see :mod:`rbjax._batching`. ``core_shape`` declares the
    single-body shape itself (``(3,)``, ``(4,)``, ``(3, 3)``; its length is the
    rank): constructors and :func:`rbjax.load` check arrays against it.
    ``converter`` is applied to the constructor's argument before
    ``__post_init__`` and ``__check_init__``; type checkers take its parameter type as the
    constructor's (e.g. :func:`rbjax._typing.array_like`).
    """
    metadata = dict(kwargs.pop("metadata", {}))
    metadata["core_ndim"] = core_ndim if core_shape is None else len(core_shape)
    if core_shape is not None:
        metadata["core_shape"] = tuple(core_shape)
    if converter is not None:
        metadata["converter"] = converter
    return dataclasses.field(metadata=metadata, **kwargs)


def static_field(**kwargs: Any) -> Any:
    """A field stored in the treedef: hashable static configuration, part of the compiled program.

    For a force model's options that are not arrays (a mode string, a count, a
    function): ``mode: str = rb.static_field(default="push")``. Changing one compiles
    a new program; ``jit`` and ``grad`` never see it as data. It has no shape or
    unit of its own: it is not an array.
    """
    metadata = dict(kwargs.pop("metadata", {}))
    metadata["static"] = True
    return dataclasses.field(metadata=metadata, **kwargs)


def _is_static(f: dataclasses.Field) -> bool:
    return bool(f.metadata.get("static", False))


def _summary_repr(self: Any) -> str:
    # shapes and dtypes, not values: a batch of 1,000 states printed as numbers was
    # 7,000 characters (equinox's tree printer, which rbjax already depends on)
    import equinox as eqx

    return eqx.tree_pformat(self, short_arrays=True)


# tells type checkers that decorated classes are frozen dataclasses with these field specifiers
@dataclass_transform(frozen_default=True, field_specifiers=(field, static_field, dataclasses.field))
def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass registered as a pytree with keyed paths (once: again is a no-op)."""
    if "_rbjax_data_fields" in cls.__dict__:
        return cls
    own_repr = "__repr__" in cls.__dict__
    _convert_before_post_init(cls)
    cls = dataclasses.dataclass(frozen=True, repr=False)(cls)
    if not own_repr:
        cls.__repr__ = _summary_repr  # type: ignore[method-assign]
    fields = dataclasses.fields(cls)  # pyright: ignore[reportArgumentType]  (a dataclass since the line above)
    data = tuple(f.name for f in fields if not _is_static(f))
    meta = tuple(f.name for f in fields if _is_static(f))
    keys = tuple(jax.tree_util.GetAttrKey(n) for n in data)

    def aux_of(obj):
        aux = tuple(getattr(obj, n) for n in meta)
        return aux + (_BATCH_LAST,) if obj.__dict__.get(_LAYOUT, False) else aux

    def flatten_with_keys(obj):
        return [(k, getattr(obj, n)) for k, n in zip(keys, data)], aux_of(obj)

    def flatten(obj):
        return [getattr(obj, n) for n in data], aux_of(obj)

    def unflatten(aux, children):
        obj = object.__new__(cls)
        for n, v in zip(meta, aux):
            object.__setattr__(obj, n, v)
        if len(aux) > len(meta):
            object.__setattr__(obj, _LAYOUT, True)
        for n, v in zip(data, children):
            object.__setattr__(obj, n, v)
        return obj

    jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten, flatten)
    cls._rbjax_data_fields = data  # type: ignore[attr-defined]
    cls._rbjax_core_ndim = {f.name: f.metadata.get("core_ndim", 0) for f in fields}  # type: ignore[attr-defined]
    cls._rbjax_core_shape = {f.name: f.metadata["core_shape"] for f in fields if "core_shape" in f.metadata}  # type: ignore[attr-defined]
    return cls


def _convert_before_post_init(cls: type) -> None:
    """Give ``cls`` a ``__post_init__`` that applies its fields' converters, then its own (if any).

    Reads the fields from the class body (``cls`` is not a dataclass yet) and its pytree-dataclass bases.
    """
    own = {n: v for n, v in vars(cls).items() if isinstance(v, dataclasses.Field)}
    bases = [b for b in cls.__mro__[1:] if dataclasses.is_dataclass(b)]
    inherited = {f.name: f for base in bases for f in dataclasses.fields(base)}
    converters = {n: f.metadata["converter"] for n, f in {**inherited, **own}.items() if "converter" in f.metadata}
    if not converters:
        return
    post_init = getattr(cls, "__post_init__", None)

    def __post_init__(self: Any) -> None:
        for name, convert in converters.items():
            object.__setattr__(self, name, convert(getattr(self, name)))
        if post_init is not None:
            post_init(self)

    cls.__post_init__ = __post_init__  # type: ignore[attr-defined]


def replace(obj: T, **changes: Any) -> T:
    """``dataclasses.replace`` without re-running ``__init__`` validation; the result keeps ``obj``'s layout.

    For library-internal updates of values that are already valid (or traced).
    """
    fields = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}  # type: ignore[arg-type]
    return with_batch_last(new_unchecked(type(obj), **{**fields, **changes}), is_batch_last(obj))


def new_unchecked(cls: type[T], **fields: Any) -> T:
    """Build ``cls(**fields)`` without ``__init__``: for values already known valid
    (a field not given takes its default; one without a default is a ``KeyError``).
    Batch-first, as ``cls(...)`` is: :func:`with_batch_last` marks it otherwise."""
    obj = object.__new__(cls)
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        value = fields[f.name] if f.name in fields or f.default is dataclasses.MISSING else f.default
        object.__setattr__(obj, f.name, value)
    return obj


def core_ndim_of(obj: Any) -> dict[str, int]:
    """Per-field single-body rank of a pytree dataclass made by this module."""
    return type(obj)._rbjax_core_ndim  # type: ignore[attr-defined]


def core_shape_of(cls: type) -> dict[str, tuple[int, ...]]:
    """The declared single-body shape of each field of ``cls`` that declares one (``field(core_shape=...)``)."""
    return cls._rbjax_core_shape  # type: ignore[attr-defined]


def data_fields(obj: Any) -> tuple[str, ...]:
    """Names of the data (non-static) fields of a pytree dataclass made by this module."""
    return type(obj)._rbjax_data_fields  # type: ignore[attr-defined]


def is_rbjax_dataclass(obj: Any) -> bool:
    return hasattr(type(obj), "_rbjax_data_fields")


# The layout of an object's own array fields: an instance attribute, set only on batch-last
# objects (a constructor, ``dataclasses.replace`` and :func:`new_unchecked` give batch-first
# ones), and a marker at the end of their treedef's auxiliary data.
_LAYOUT = "_rbjax_batch_last"
_BATCH_LAST = "batch-last"


def is_batch_last(obj: Any) -> bool:
    """Whether ``obj``'s own array fields are batch-last, ``(*core, *B)`` (see :mod:`rbjax._batching`)."""
    return bool(getattr(obj, "__dict__", {}).get(_LAYOUT, False))


def with_batch_last(obj: T, on: bool) -> T:
    """``obj`` (this one object, not the objects in its fields) marked batch-last (``on``) or batch-first.

    Marks only: no array moves (:func:`rbjax._batching.to_batch_last` moves them).
    """
    if is_batch_last(obj) == on:
        return obj
    new = object.__new__(type(obj))
    new.__dict__.update(obj.__dict__)
    if on:
        object.__setattr__(new, _LAYOUT, True)
    else:
        del new.__dict__[_LAYOUT]
    return new
