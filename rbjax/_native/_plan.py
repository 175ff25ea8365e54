"""Which runs take the native kernels: the methods, the force models, and the reason when not.

See :mod:`rbjax._native` for what the kernels compute.
"""

from __future__ import annotations

import warnings
from typing import Any

import jax
import jax.core
import jax.numpy as jnp

from .._force_model import ForceSum
from .._methods import BUILTIN, AbstractMethod, Method, native_step_is_own
from .._state import Forces, State
from ._laws import NATIVE_TYPES
from ._load import METHODS, native_status

__all__ = [
    "NATIVE_LAWS",
    "AT_STEP_START",
    "native_terms",
    "native_plan",
    "native_path",
    "sharded",
    "say_once_unavailable",
]

# the force models the kernel computes itself, by name, for messages
NATIVE_LAWS = tuple(t.__name__ for t in NATIVE_TYPES if t is not Forces)

# The methods whose steps evaluate the forces once, at the step's start state and time (euler.py:
# euler_state, semi_implicit_euler.py: semi_implicit_state, whose kick sees the old state): with a
# force law the kernel does not know, XLA evaluates it there and the kernel takes the result,
# one call per step. The others need forces at intermediate states (the stages of rk4 and
# rk4_body, splitting's kick after the drift), where a kernel call per stage would cost at
# least four per-step calls. A kernel call per step reads and writes the whole state once,
# as a fused JAX step does: roughly measured (shared 2-core machine, 1e5 bodies, float32),
# euler and semi_implicit_euler with a callable were no faster natively than on JAX, so
# native=None keeps such runs on JAX and native=True takes this path.
AT_STEP_START = tuple(m.name for m in BUILTIN.values() if m.forces_at_step_start and m.native_code is not None)


def native_terms(forces: Any) -> tuple[Any, ...] | None:
    """The terms of ``forces`` the kernel evaluates itself, or ``None`` when it cannot."""
    if forces is None:
        return ()
    terms = forces.terms if type(forces) is ForceSum else (forces,)
    return terms if all(type(t) in NATIVE_TYPES for t in terms) else None


def native_plan(
    state: Any,
    forces: Any,
    method: AbstractMethod,
    *,
    series: bool,
    checked: bool,
    checkpoint: Any,
    default: bool = False,
) -> str:
    """``""`` when this run can take the native kernels, else the reason it cannot (for messages).

    ``forces`` is what the steps see: ``None``, a :class:`Forces` (a time series
    when ``series``), a force model, or a force callable. ``default``: the plan for
    ``native=None``, which keeps forces evaluated by XLA (callables, force models
    other than the kernel's laws) on the JAX path: there a kernel call per step
    was measured no faster than the JAX steps (see ``AT_STEP_START``).
    """
    status = native_status()
    if not status.available:
        return status.reason
    if method.native_code is None:
        if not isinstance(method, Method):  # an instance of a user's AbstractMethod subclass
            return (
                f"method {method.name!r} ({type(method).__qualname__}) is a user's method and has no native kernel: "
                f"the kernels compute rbjax's own methods only ({', '.join(METHODS)}), its __call__ runs on the "
                "JAX path (native=False, or None)"
            )
        return f"method {method.name!r} has no native kernel (those with one: {', '.join(METHODS)})"
    if not native_step_is_own(method):
        own = next((m.name for m in BUILTIN.values() if m.native_code == method.native_code), None)
        if own is None:
            return f"method {method.name!r} has native_code={method.native_code!r}, which no kernel has ({METHODS})"
        return (
            f"method {method.name!r} has native_code={method.native_code}, the kernel of rbjax's {own!r}, but "
            f"steps of its own: the kernel would compute {own!r}'s formulas in their place; its steps run on the "
            "JAX path (native=False, or None)"
        )
    if type(state) is not State:
        return f"{type(state).__name__} has no native kernel (State has)"
    if state.rotors is not None:
        return "a gyrostat (a state with rotors) has no native kernel: it steps in JAX"
    if state.dtype not in (jnp.float32, jnp.float64):
        return f"dtype {state.dtype} has no native kernel (float32 and float64 have)"
    if not series and native_terms(forces) is None and not method.forces_at_step_start:
        return (
            f"method {method.name!r} needs the forces at intermediate states, and these are evaluated by XLA "
            f"(the kernel evaluates none, constant or time-series Forces, {', '.join(NATIVE_LAWS)} and their "
            "sums itself, by their exact types, so not a subclass of one, whose own code runs on the JAX path "
            "(native=None or False); other force models and callables run natively with "
            f"{' and '.join(AT_STEP_START)}, which evaluate the forces once per step, at its start)"
        )
    if default and not series and native_terms(forces) is None:
        return "forces evaluated by XLA take the JAX path unless native=True"
    if checked:
        return "checked mode tests every step in JAX"
    if checkpoint is not None:
        return "gradient checkpointing segments the JAX scan"
    if jax.default_backend() != "cpu":
        return f"the default backend is {jax.default_backend()}, the kernels are for the CPU"
    if sharded(state):
        if series:
            return "a sharded batch with time-series forces (the series' leading axis is time, not the batch)"
        if len(state.batch_shape) != 1:
            return f"a sharded batch of shape {state.batch_shape} (the kernel splits 1-D batches (N,))"
    return ""


def native_path(
    native: bool | None,
    state: Any,
    forces: Any,
    method: AbstractMethod,
    *,
    series: bool,
    checked: bool,
    checkpoint: Any,
) -> bool:
    """Whether a run of :func:`rbjax.simulate` steps natively, for its argument ``native``.

    ``None``: where :func:`native_plan` (with ``default``) finds no reason not to;
    ``False``: never; ``True``: always, or ``ValueError`` saying why it cannot and
    naming ``native``. ``TypeError`` for any other ``native``. A run that could take
    the kernels but finds them unavailable gives one warning per process.
    """
    if native is not None and not isinstance(native, bool):
        raise TypeError(f"simulate: native must be None, True or False, got {native!r}")
    if native is False:
        return False
    reason = native_plan(
        state, forces, method, series=series, checked=checked, checkpoint=checkpoint, default=native is None
    )
    if native and reason:
        raise ValueError(f"simulate(native=True): {reason}; pass native=None to fall back to JAX")
    if reason and method.native_code is not None and type(state).__name__ == "State":
        say_once_unavailable()
    return not reason


def sharded(state: Any) -> bool:
    """Whether some field of ``state`` is laid out over a mesh (see :func:`_sharded`): the kernel call
    is then split over the batch's devices (``_call``'s ``sharded``)."""
    return any(_sharded(a) for a in jax.tree.leaves(state))


def _sharded(a: Any) -> bool:
    """Whether ``a`` is laid out over a mesh, so an unpartitioned custom call would gather it."""
    if isinstance(a, jax.core.Tracer):  # under jit: explicit mesh axes in its type
        spec = getattr(getattr(jax.typeof(a), "sharding", None), "spec", ())
        return any(axis is not None for axis in spec)
    return isinstance(a, jax.Array) and not isinstance(a.sharding, jax.sharding.SingleDeviceSharding)


_warned = False


def say_once_unavailable() -> None:
    """One ``UserWarning`` per process when a run that could use the kernels takes the JAX path for want of them."""
    global _warned
    status = native_status()
    if not status.available and not _warned:
        _warned = True
        warnings.warn(f"rbjax: {status}", stacklevel=5)  # the caller of simulate
