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

__all__ = ["ArrayLike"]

ArrayLike = Union[jax.typing.ArrayLike, Sequence[Any]]
