"""Griffe extension for the API reference: rbjax's docstrings, written for ``help()``, rendered well.

Grouped arguments (``rtol, atol: tolerances ...``), which the Google style has no form for, become
one entry each, the first with the description and the others pointing to it.

Sphinx roles become links.

rbjax's docstrings (read by ``help()`` as well as by this site) write ``:func:`rbjax.step```,
``:class:`State``` and ``:data:`TRIANGLE_RTOL```. A role naming a public name of rbjax becomes an
autorefs cross-reference, ``[`rbjax.step`][rbjax.step]``, so a stale one fails the strict build; any
other role (a private helper, another library) becomes plain code.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

import rbjax

_ROLE = re.compile(r":(?:func|class|meth|data|attr|mod|obj):`~?([^`]+)`")
_PUBLIC = set(rbjax.__all__)


def _link(match: re.Match) -> str:
    name = match.group(1)
    short = name.removeprefix("rbjax.")
    head = short.split(".")[0]
    if head in _PUBLIC:
        return f"[`{name}`][rbjax.{short}]"
    return f"`{name}`"


_GROUPED = re.compile(r"^(\s+)(\w+(?:, \w+)+): (.*)$")


def _split_grouped(text: str) -> str:
    lines = text.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        m = _GROUPED.match(lines[i])
        if not m:
            out.append(lines[i])
            i += 1
            continue
        indent, names = m.group(1), m.group(2).split(", ")
        out.append(f"{indent}{names[0]}: {m.group(3)}")
        i += 1
        while i < len(lines) and lines[i].strip() and len(lines[i]) - len(lines[i].lstrip()) > len(indent):
            out.append(lines[i])  # the description's continuation lines stay with the first name
            i += 1
        out += [f"{indent}{n}: see `{names[0]}`." for n in names[1:]]
    return "\n".join(out)


class SphinxRoles(griffe.Extension):
    def on_object(self, *, obj: Any, **kwargs: Any) -> None:
        doc = getattr(obj, "docstring", None)
        if doc is not None:
            doc.value = _split_grouped(_ROLE.sub(_link, doc.value))
