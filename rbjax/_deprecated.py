"""Old spellings of public arguments, accepted for one release with a :class:`DeprecationWarning`.

Each warning names the new spelling and points at the user's call (``stacklevel``), so that
``python -W error::DeprecationWarning`` finds every call to change.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["warn_deprecated", "move_renamed_keywords", "renamed_keywords"]

F = TypeVar("F", bound=Callable[..., Any])


def warn_deprecated(message: str, stacklevel: int) -> None:
    """``DeprecationWarning`` ``message``, blamed on the frame ``stacklevel`` above the caller."""
    warnings.warn(message, DeprecationWarning, stacklevel=stacklevel + 1)


def move_renamed_keywords(kwargs: dict[str, Any], renames: dict[str, str], where: str, stacklevel: int) -> None:
    """Move each deprecated keyword of ``kwargs`` (a key of ``renames``) to its new name, warning.

    ``stacklevel`` counts from the caller of this function, as in :func:`warnings.warn`.
    Both spellings at once is a ``TypeError``: one of the two values would be dropped.
    """
    for old, new in renames.items():
        if old not in kwargs:
            continue
        if new in kwargs:
            raise TypeError(f"{where}: got both {new}= and its deprecated spelling {old}=; pass {new}= only")
        warn_deprecated(
            f"{where}: {old}= is deprecated and will be removed in the next release; use {new}= (same meaning)",
            stacklevel + 1,
        )
        kwargs[new] = kwargs.pop(old)


def renamed_keywords(where: str, **renames: str) -> Callable[[F], F]:
    """Decorator: the function also takes each old keyword ``old=new`` of ``renames``, with a warning."""

    def decorate(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            move_renamed_keywords(kwargs, renames, where, stacklevel=2)
            return fn(*args, **kwargs)

        return wrapper  # type: ignore[return-value]

    return decorate
