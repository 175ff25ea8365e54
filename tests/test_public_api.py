"""Every public name of rbjax is documented; array-taking functions say shapes or frames."""

from __future__ import annotations

import inspect
import re

import pytest

import rbjax as rb

# words that show a docstring tells the reader about shapes, frames or units
_SHAPE_OR_FRAME = re.compile(
    r"\(\*B|\(\.\.\.|\(T,|\(N,|\(P,|\(3|\(4|shape|world|body frame|body x|frame|\((m|s|kg|J|rad/s)\)|radians"
)


def _public():
    names = sorted(set(rb.__all__) | {n for n in dir(rb) if not n.startswith("_")})
    # functions and classes; constants (TRIANGLE_RTOL) are documented by a #: comment at definition
    return [n for n in names if inspect.isfunction(getattr(rb, n)) or inspect.isclass(getattr(rb, n))]


def test_all_lists_every_public_name():
    missing = sorted({n for n in dir(rb) if not n.startswith("_")} - set(rb.__all__) - {"annotations"})
    assert not [n for n in missing if not inspect.ismodule(getattr(rb, n))]
    assert all(hasattr(rb, n) for n in rb.__all__)


@pytest.mark.parametrize("name", _public())
def test_public_name_is_documented(name):
    obj = getattr(rb, name)
    doc = inspect.getdoc(obj) or ""
    assert doc.strip(), f"rbjax.{name} has no docstring"
    lines = [ln for ln in doc.strip().splitlines() if ln.strip()]
    takes_arrays = inspect.isfunction(obj) and any(
        p.name not in ("method", "name", "path", "state_type") for p in inspect.signature(obj).parameters.values()
    )
    if takes_arrays:
        # one line is enough when it gives the shapes or frames, e.g. "R (body to world), (*B, 3, 3)"
        assert _SHAPE_OR_FRAME.search(doc), f"rbjax.{name}: docstring mentions no shape, frame or unit"
    else:
        assert len(lines) > 1, f"rbjax.{name}: a one-line docstring for a class or registry function"


def _public_methods():
    out = []
    for n in _public():
        cls = getattr(rb, n)
        if not inspect.isclass(cls):
            continue
        # a public class's methods, also those it inherits from a private base (LinearDrag's on_body)
        own = {}
        for klass in reversed(cls.__mro__):
            if klass is cls or (klass.__module__.startswith("rbjax") and klass.__name__.startswith("_")):
                own.update(vars(klass))
        for m, v in own.items():
            if m.startswith("_"):
                continue
            if isinstance(v, (classmethod, staticmethod)):
                v = v.__func__
            if inspect.isfunction(v) or isinstance(v, property):
                out.append(f"{n}.{m}")
    return out


@pytest.mark.parametrize("qualname", _public_methods())
def test_public_method_is_documented(qualname):
    cls, name = qualname.split(".")
    assert (inspect.getdoc(getattr(getattr(rb, cls), name)) or "").strip(), f"rbjax.{qualname} has no docstring"
