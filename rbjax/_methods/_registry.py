"""The table of rbjax's methods by name, and ``lookup``/``available``/``resolve``/``for_kind``.

The table is written out below, in one place: every method module defines its
:class:`~rbjax._methods._base.Method` as a constant and registers nothing, so
which methods exist and in which order does not depend on what was imported
first. A ``method=`` string is a look-up here; a method object
(:class:`~rbjax._methods._base.AbstractMethod`) is itself.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

from .._state import MatrixState, ParticleState, State
from ._base import DEFAULT_METHOD, KINDS, AbstractMethod, KernelFn, Method, OrderWarning, StepFn
from .composition import SPLITTING4, SPLITTING6, SPLITTING8
from .euler import EULER
from .implicit_gyroscopic import IMPLICIT_GYROSCOPIC
from .implicit_midpoint import IMPLICIT_MIDPOINT
from .rk4 import RK4
from .rk4_body import RK4_BODY
from .rk8 import RK8
from .semi_implicit_euler import SEMI_IMPLICIT_EULER
from .splitting import SPLITTING

__all__ = [
    "DEFAULT_METHOD",
    "KINDS",
    "AbstractMethod",
    "KernelFn",
    "Method",
    "OrderWarning",
    "StepFn",
    "BUILTIN",
    "available",
    "check_rotors",
    "for_kind",
    "get",
    "is_registered",
    "lookup",
    "native_step_is_own",
    "register",
    "resolve",
]

#: rbjax's own methods by name, in the order :func:`rbjax.methods` lists them.
BUILTIN: dict[str, Method] = {
    m.name: m
    for m in (
        EULER,
        IMPLICIT_GYROSCOPIC,
        IMPLICIT_MIDPOINT,
        RK4,
        RK4_BODY,
        RK8,
        SEMI_IMPLICIT_EULER,
        SPLITTING,
        SPLITTING4,
        SPLITTING6,
        SPLITTING8,
    )
}

#: The methods a ``method=`` string names: :data:`BUILTIN`, and what the deprecated
#: :func:`rbjax.register_kernel` put in their place.
_REGISTRY: dict[str, Method] = dict(BUILTIN)


def check_rotors(method: AbstractMethod, state: Any, where: str) -> None:
    """``ValueError`` naming ``method`` and the methods that support rotors, when ``state`` is a
    gyrostat (has ``rotors``) and ``method`` does not handle them (:attr:`AbstractMethod.rotors`)."""
    if getattr(state, "rotors", None) is None or method.rotors:
        return
    names = ", ".join(repr(n) for n, m in _REGISTRY.items() if m.rotors)
    scene = (
        ""
        if method.name not in _REGISTRY or is_registered(method)
        else " (a Scene steps with kernels specialised on its body kind, which know no rotors: step the "
        "gyrostat with rb.simulate, or with a Scene of 'splitting' built with kind='general')"
    )
    raise ValueError(
        f"{where}: method {method.name!r} does not support rotors (this state is a gyrostat){scene}; "
        f"the methods that do: {names}"
    )


def register(method: Method) -> Method:
    """Make ``method`` the one a ``method=`` string of its name looks up (only the deprecated
    :func:`rbjax.register_kernel` does this; rbjax's own methods are the table :data:`BUILTIN`)."""
    _REGISTRY[method.name] = method
    return method


def lookup(name: str) -> Method:
    """The registered method ``name``; ``ValueError`` naming those there are if none."""
    m = _REGISTRY.get(name)
    if m is None:
        raise ValueError(f"unknown method {name!r}; available: {sorted(_REGISTRY)}")
    return m


def get(name: str, state_type: type) -> StepFn:
    """The step function of ``name`` for ``state_type``; ``ValueError`` if none."""
    return lookup(name).step(state_type)


def available(state_type: type | None = None) -> dict[str, Method]:
    """Registered methods, optionally only those supporting ``state_type``."""
    return {k: m for k, m in _REGISTRY.items() if state_type is None or state_type in m.steps}


def is_registered(method: AbstractMethod) -> bool:
    """Whether ``method`` is the registry's method of its name (not a scene's or a user's variant)."""
    return _REGISTRY.get(method.name) is method


_BY_CODE = {m.native_code: m for m in BUILTIN.values() if m.native_code is not None}


def native_step_is_own(method: AbstractMethod) -> bool:
    """Whether the native kernel numbered ``method.native_code`` computes ``method``'s own steps: it is a
    :class:`Method` whose :class:`rbjax.State` step is that of rbjax's method of that number (the kernel
    mirrors that step; any other step would be silently swapped for it)."""
    own = None if method.native_code is None else _BY_CODE.get(method.native_code)
    return (
        own is not None
        and type(method) is Method
        and State in own.steps
        and method.steps.get(State) is own.steps[State]
    )


def resolve(method: Any, where: str) -> AbstractMethod:
    """The method object that ``method=`` names, for the public function ``where``.

    A string is looked up (``ValueError`` for an unknown name); an
    :class:`AbstractMethod` (a :class:`Method` or an instance of a user's
    subclass) is itself; any other callable is a user's batch step ``(state,
    force_fn, t, dt) -> state`` and becomes an anonymous Method (the same one for
    equal callables, so a rerun reuses its compiled program) that runs
    batch-first. A method class instead of an instance, anything else, or an
    unhashable method raises ``TypeError``.
    """
    if isinstance(method, str):
        return lookup(method)
    if isinstance(method, type) and issubclass(method, AbstractMethod):
        raise TypeError(
            f"{where}: method must be a method object, got the class {method.__qualname__}: pass an instance, "
            f"method={method.__qualname__}()"
        )
    if isinstance(method, AbstractMethod) or callable(method):
        try:
            if isinstance(method, AbstractMethod):
                hash(method)
                return method
            return _anonymous(method)
        except TypeError:  # unhashable: it could not be a static argument of the compiled run
            raise TypeError(
                f"{where}: method must be hashable, as a static argument of the compiled run; got an unhashable "
                f"{type(method).__name__}. Pass a method name such as 'rk4', a Method from rbjax.methods(), a "
                "method object whose attributes are hashable, or a step function defined once"
            ) from None
    raise TypeError(
        f"{where}: method must be a method name such as 'rk4' (see rbjax.methods()), a Method from "
        f"rbjax.methods(), an instance of an rbjax.AbstractMethod subclass, or a batch step callable "
        f"(state, force_fn, t, dt) -> state; got {type(method).__name__}"
    )


@functools.lru_cache(maxsize=1024)
def _anonymous(fn: StepFn) -> Method:
    # a user's step is written for the batch-first layout and takes any state form
    name = getattr(fn, "__qualname__", None) or repr(fn)
    # rotors=True: a user's step is given the whole state, rotors included, and owns what it does with them
    return Method(
        name=name,
        order=0,
        steps=dict.fromkeys((State, MatrixState, ParticleState), fn),
        layout_agnostic=False,
        rotors=True,
    )


@functools.cache
def for_kind(method: AbstractMethod, kind: str, torque_free: bool) -> AbstractMethod:
    """``method`` as a :class:`rbjax.Scene` of ``kind`` bodies runs it (the same object for the same arguments).

    Its kernels for ``kind`` replace its steps, called with ``kind`` and
    ``torque_free``; ``method`` itself when it has none for ``kind``. The
    result has no native kernel (a scene steps in JAX) and is batch-first when
    a kernel it uses is. A user's method (an :class:`AbstractMethod` subclass)
    with ``kernels`` becomes a :class:`Method` of its own steps and kernels.
    """
    own = {T: fn for (k, T), fn in method.kernels.items() if k == kind}
    if not own:
        return method

    def bind(fn: KernelFn) -> StepFn:
        return lambda state, force_fn, t, dt: fn(state, force_fn, t, dt, kind, torque_free)

    if not isinstance(method, Method):
        method = Method(
            name=method.name,
            order=method.order,
            steps={T: method.step(T) for T in method.state_types},
            conserves=method.conserves,
            cost=method.cost,
            stable_dt_omega=method.stable_dt_omega,
            failure_note=method.failure_note,
            kernels=dict(method.kernels),
            layout_agnostic=method.layout_agnostic,
            batch_first_kernels=method.batch_first_kernels,
            principal_frame=method.principal_frame,
            order_with_velocity_forces=method.order_with_velocity_forces,
            forces_at_step_start=method.forces_at_step_start,
        )
    return dataclasses.replace(
        method,
        steps={**method.steps, **{T: bind(fn) for T, fn in own.items()}},
        kernels={},
        layout_agnostic=method.layout_agnostic and not any((kind, T) in method.batch_first_kernels for T in own),
        batch_first_kernels=frozenset(),
        native_code=None,
        # the kernels specialised on a body kind know no rotors
        rotors=False,
        # a kind's kernel turns about its symmetry axis: no frame, unless a state type keeps the general step
        principal_frame=method.principal_frame and any(T not in own for T in (State, MatrixState) if T in method.steps),
    )
