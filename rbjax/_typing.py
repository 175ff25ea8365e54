"""The array-like input type of rbjax's annotations.

``jax.typing.ArrayLike`` leaves out lists and tuples on purpose: ``jnp`` functions
reject them. rbjax's public functions convert their inputs with ``jnp.asarray``
and accept them, as users write ``rb.box(1.0, [0.1, 0.2, 0.3])``; so here
``ArrayLike`` is JAX's plus (nested) sequences of numbers. Shapes are given with
jaxtyping, e.g. ``Float[ArrayLike, "*B 3"]``; nothing is checked at run time.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Union

import jax.typing
from jax import Array

__all__ = ["ArrayLike", "array_like", "optional_array_like"]

ArrayLike = Union[jax.typing.ArrayLike, Sequence[Any]]


# Field converters (``rbjax._pytree.field(converter=...)``) of array fields. Type checkers read
# a converter's parameter type as the constructor's (PEP 681's dataclass_transform with the
# typing spec's ``converter``): the constructor takes any array-like, the attribute is an Array.
# They pass the value through: each class's ``__post_init__`` converts its array fields together,
# because the dtype of one field depends on the others (a Python list takes the dtype of the
# arrays beside it) and an error should name the class and the field.
def array_like(x: ArrayLike) -> Array:
    """Converter of an array field: declares the constructor argument array-like (see above)."""
    return x  # type: ignore[return-value]


def optional_array_like(x: ArrayLike | None) -> Array | None:
    """Converter of an optional array field (``None`` = absent): as :func:`array_like`."""
    return x  # type: ignore[return-value]
