"""Time-stepping methods: the protocol (:mod:`._base`), one module per method, and the table by name.

Every method is an :class:`AbstractMethod`: its batch-level step, its kernels
specialised on a :class:`rbjax.Scene`'s body kind (:mod:`.specialised`),
whether they run in the batch-last layout, its native kernel's number, and what
is measured of it (order, cost, stability) are attributes of it. rbjax's own
are :class:`Method` constants of their modules, listed by name in one table
(:data:`._registry.BUILTIN`); no module registers itself, so nothing depends on
the order of imports. Every public function's ``method=`` takes a name, a
method object, or a batch step callable (:func:`resolve`).

A step is a batch-level function ``step(state, force_fn, t, dt) -> state``:
``force_fn(state, t) -> Forces`` sees the whole batch (so forces may couple
bodies) and may be called at intermediate stages; the per-body arithmetic
inside is written for one body and lifted with :func:`rbjax._batching.lift`.

Step functions of a layout-agnostic method must not depend on where the batch
axes are: ``simulate`` runs them with the state in the batch-last layout
(:func:`rbjax._batching.to_batch_last`; the state says so in its treedef, and
``lift`` reads it from there), so batch-level code outside ``lift`` may only be
elementwise (``x + h k``) and must rebuild states with
:func:`rbjax._pytree.replace`, which keeps the layout (a constructor or
``dataclasses.replace`` makes a batch-first object); anything that names an axis
(a norm, a ``@``) goes inside a lifted one-body function.
"""

from ._base import DEFAULT_METHOD, KINDS, AbstractMethod, KernelFn, Method, OrderWarning, StepFn
from ._registry import (
    BUILTIN,
    available,
    check_rotors,
    for_kind,
    get,
    is_registered,
    lookup,
    native_step_is_own,
    register,
    resolve,
)

__all__ = [
    "DEFAULT_METHOD",
    "KINDS",
    "AbstractMethod",
    "BUILTIN",
    "KernelFn",
    "Method",
    "OrderWarning",
    "StepFn",
    "register",
    "get",
    "lookup",
    "available",
    "resolve",
    "check_rotors",
    "for_kind",
    "is_registered",
    "native_step_is_own",
]
