"""Time-stepping methods, one per module, registered by name.

Each is a :class:`Method`, the one record of an integrator: its batch-level
steps per state type, its kernels specialised on a :class:`rbjax.Scene`'s body
kind (:mod:`.specialised`), whether they run in the batch-last layout, its
native kernel's number, and what is measured of it (order, cost, stability).
Every public function's ``method=`` takes a name or a Method (:func:`resolve`).

A step is a batch-level function ``step(state, force_fn, t, dt) -> state``:
``force_fn(state, t) -> Forces`` sees the whole batch (so forces may couple
bodies) and may be called at intermediate stages; the per-body arithmetic
inside is written for one body and lifted with :func:`rbjax._batching.lift`.

Step functions must not depend on where the batch axes are: ``simulate`` runs
them with the state in the batch-last layout (:func:`rbjax._batching.batch_last`),
so batch-level code outside ``lift`` may only be elementwise (``x + h k``);
anything that names an axis (a norm, a ``@``) goes inside a lifted one-body function.
"""

# Each method module registers itself on import. They import the registry, never this package.
from . import euler as euler
from . import explicit_rk as explicit_rk
from . import implicit_gyroscopic as implicit_gyroscopic
from . import implicit_midpoint as implicit_midpoint
from . import rk4 as rk4
from . import rk4_body as rk4_body
from . import rk8 as rk8
from . import semi_implicit_euler as semi_implicit_euler
from . import splitting as splitting

# isort: split
# composition builds on registered methods ("splitting"): it must come after them
from . import composition as composition
from ._registry import (
    DEFAULT_METHOD,
    KINDS,
    KernelFn,
    Method,
    OrderWarning,
    StepFn,
    available,
    check_rotors,
    for_kind,
    get,
    is_registered,
    lookup,
    register,
    resolve,
)

__all__ = [
    "DEFAULT_METHOD",
    "KINDS",
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
]
