"""The README's API section, generated from the docstrings of ``rbjax.__all__``.

``python -m rbjax._apidoc`` prints the section; ``python -m rbjax._apidoc --write``
puts it into README.md between ``<!-- api:start -->`` and ``<!-- api:end -->``.
tests/test_public_api.py fails when the README's block differs from this output.
One line per public name: the name with its required parameters (``...`` when it
has optional ones) and the first line of its docstring, grouped by concept.
"""

from __future__ import annotations

import inspect
import re
import sys
from pathlib import Path

START, END = "<!-- api:start -->", "<!-- api:end -->"
README = Path(__file__).resolve().parent.parent / "README.md"

# concept of each defining module, in the order shown; a module not listed gets its own group
_GROUPS = {
    "_body": "Bodies and mass properties",
    "_state": "States and forces",
    "_quantities": "Derived quantities",
    "_simulate": "Simulation",
    "_dynamics": "Simulation",
    "rbjax": "Simulation",  # rbjax.methods, defined in __init__
    "_torque_free": "Simulation",
    "_math": "Rotations and vector algebra",
    "_fit": "Fitting inertia tensors",
    "_fit_data": "Fitting inertia tensors",
    "_inertia_param": "Fitting inertia tensors",
    "_forces": "Scenes and force models",
    "_scene": "Scenes and force models",
    "_io": "Saving, long runs, checked mode",
    "_chunked": "Saving, long runs, checked mode",
    "_checked": "Saving, long runs, checked mode",
}


def _call(name: str, obj: object) -> str:
    """``name(a, b, ...)``: required parameters, ``...`` when there are optional ones."""
    try:
        params = list(inspect.signature(obj).parameters.values())  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return name
    required = [
        p.name for p in params if p.default is p.empty and p.kind in (p.POSITIONAL_OR_KEYWORD, p.POSITIONAL_ONLY)
    ]
    if len(required) > 5:  # a record such as FitResult, returned rather than built by users
        return f"{name}(...)"
    optional = len(required) < len(params)
    return f"{name}({', '.join(required + (['...'] if optional else []))})"


def _summary(obj: object) -> str:
    doc = inspect.getdoc(obj) or ""
    first = doc.strip().split("\n\n")[0]  # the first paragraph may wrap over lines
    first = re.sub(r":(?:func|class|meth|data|mod):`([^`]+)`", r"``\1``", " ".join(first.split()))
    return re.sub(r"``(.+?)``", r"`\1`", first)


def section() -> str:
    """The generated Markdown block (without the markers)."""
    import rbjax

    groups: dict[str, list[str]] = {}
    for name in rbjax.__all__:
        obj = getattr(rbjax, name)
        if inspect.isfunction(obj) or inspect.isclass(obj):
            module = obj.__module__.rsplit(".", 1)[-1]
            line = f"- `{_call(name, obj)}`: {_summary(obj)}"
        else:  # a constant, documented by a #: comment where it is defined
            module, line = "_body", f"- `{name} = {obj!r}`"
        groups.setdefault(_GROUPS.get(module, module.lstrip("_")), []).append(line)
    order = list(dict.fromkeys(_GROUPS.values()))
    titles = sorted(groups, key=lambda g: (order.index(g) if g in order else len(order), g))
    body = ["Generated from the docstrings by `python -m rbjax._apidoc --write`; `help(rbjax.NAME)` has the rest."]
    for title in titles:
        body += ["", f"**{title}**", "", *groups[title]]
    return "\n".join(body)


def readme_block(text: str) -> str | None:
    """The text between the markers in ``text``, or ``None`` without markers."""
    if START not in text or END not in text:
        return None
    return text.split(START, 1)[1].split(END, 1)[0].strip("\n")


def write(path: Path = README) -> bool:
    """Replace the block in ``path``; ``True`` if it changed."""
    text = path.read_text()
    old = readme_block(text)
    if old is None:
        raise SystemExit(f"{path}: no {START} ... {END} markers")
    new = section()
    if old == new:
        return False
    head, rest = text.split(START, 1)
    path.write_text(f"{head}{START}\n{new}\n{END}{rest.split(END, 1)[1]}")
    return True


if __name__ == "__main__":
    if "--write" in sys.argv[1:]:
        print("README.md updated" if write() else "README.md already up to date")
    else:
        print(section())
