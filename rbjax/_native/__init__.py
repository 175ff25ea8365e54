"""Native CPU kernels behind :func:`rbjax.simulate`, through XLA's FFI.

``kernels.cc`` (built at install, see README.md beside this file) advances a
batch of :class:`rbjax.State` bodies by all the steps between two saved frames
in one call: the methods of ``METHODS`` (``"euler"``, ``"rk4"``, ``"splitting"``,
``"semi_implicit_euler"``, ``"rk4_body"``), float32 and float64, with the force
laws that are per body evaluated inside the kernel (none, constant
:class:`rbjax.Forces`, and sums of :class:`rbjax.Gravity`,
:class:`rbjax.LinearDrag`, :class:`rbjax.QuadraticDrag`,
:class:`rbjax.ConstantForce` and :class:`rbjax.Thruster`, whose body-frame sums
per body the kernel turns by the attitude at each evaluation). A time series
of :class:`rbjax.Forces` (``(steps, *B, 3)``, world frame, N and N·m) goes in by
the frame's slice, ``(save_every, n, 3)``, one row per step, held over the
step's stages. With ``native=True``, ``"euler"`` and ``"semi_implicit_euler"``
(``AT_STEP_START``: forces once per step, at its start) also take any other
force model or callable ``(state, t) -> Forces``: XLA evaluates it at each
step's start and the kernel takes the result, one call per step. A batch
sharded over devices (1-D, no series) is split: the call is
batch-partitionable, each device runs the kernel on its bodies. Anything else
runs the JAX implementation, which stays the reference: the kernel mirrors it
to round-off (tests/test_native.py) and supplies nothing but values.
Derivatives come from the JAX step through a ``custom_jvp``, so ``grad`` and
``jvp`` see exactly the JAX path.

:func:`native_status` says whether the kernels were built and loaded, and why
not; ``simulate(..., native=...)`` forces either path.
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import importlib.util
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax.experimental.xla_metadata import set_xla_metadata

from .._attached import Thruster
from .._force_model import ForceSum
from .._forces import ConstantForce, Gravity, LinearDrag, QuadraticDrag
from .._methods import Method, available
from .._pytree import replace
from .._state import Forces, State
from .._validate import checked_force_fn

__all__ = ["NativeStatus", "native_status", "native_plan", "advance"]

# the methods with a kernel and their codes (block.h: Method), as each Method records its own
METHODS = dict(
    sorted(((m.name, m.native_code) for m in available().values() if m.native_code is not None), key=lambda p: p[1])
)
_TARGET = "rbjax_advance"
_ABI = 4  # kernels.cc: rbjax_native_abi, the version of the call's operands and attributes
_ISA = ("x86-64 baseline", "AVX2", "AVX-512")
# RBJAX_NATIVE_ISA's values (kernels.cc: isa): the widest instruction set the kernels may use
_ISA_CAPS = ("baseline", "avx2", "avx512")


@dataclasses.dataclass(frozen=True)
class NativeStatus:
    """Whether :func:`rbjax.simulate` can use the native kernels here.

    Attributes:
        available: the library was built, loaded and registered with XLA.
        library: its path, or ``None``.
        instruction_set: what its steps run with on this processor
            (``"AVX-512"``, ``"AVX2"``, ``"x86-64 baseline"``), or ``None``.
        reason: why not, when not available.
        methods: the methods it implements.
    """

    available: bool
    library: str | None
    instruction_set: str | None
    reason: str
    methods: tuple[str, ...] = tuple(METHODS)

    def __str__(self) -> str:
        if self.available:
            return (
                f"native kernels: loaded from {self.library} ({self.instruction_set}); simulate uses them for "
                f"{', '.join(self.methods)} on State batches on the CPU, the JAX path otherwise"
            )
        return f"native kernels: not available ({self.reason}); simulate uses the JAX path"


def _library_path() -> Path | None:
    spec = importlib.util.find_spec(__name__ + "._kernels")
    if spec is not None and spec.origin:
        return Path(spec.origin)
    return None


@functools.cache
def native_status() -> NativeStatus:
    """Whether the native kernels were built at install and loaded, and which path ``simulate`` takes.

    The library ``rbjax/_native/_kernels*.so`` is compiled by the package's build
    from ``kernels.cc`` (a C++ compiler is needed; without one the install still
    succeeds and every run takes the JAX path). Loaded on the first call and
    registered with XLA as the CPU custom call ``"rbjax_advance"``. Returns a
    :class:`NativeStatus`; ``str()`` of it is one line for a log, and its ``methods``
    the methods with a kernel (``"euler"``, ``"rk4"``, ``"splitting"``,
    ``"semi_implicit_euler"``, ``"rk4_body"``).
    """
    path = _library_path()
    if path is None:
        return NativeStatus(False, None, None, "the library was not built at install (no C++ compiler?)")
    try:
        lib = ctypes.CDLL(str(path))
        abi = int(lib.rbjax_native_abi()) if hasattr(lib, "rbjax_native_abi") else 1
        if abi != _ABI:
            return NativeStatus(
                False,
                str(path),
                None,
                f"{path.name} was built from another kernels.cc (call version {abi}, this rbjax needs {_ABI}): "
                "rebuild it (pip install -e ., or python setup.py build_ext --inplace)",
            )
        jax.ffi.register_ffi_target(_TARGET, jax.ffi.pycapsule(lib.RbjaxAdvance), platform="cpu")
        # a call marked num_batch_dims = 1 (only `_call` with sharded=True, whose operands are all
        # (N, c)) is split over the devices of its batch; unmarked calls are not partitioned
        jax.ffi.register_ffi_target_as_batch_partitionable(_TARGET)
        isa = _ISA[min(int(lib.rbjax_native_isa()), 2)]
        cap = os.environ.get("RBJAX_NATIVE_ISA")
        if cap is not None and cap not in _ISA_CAPS:
            warnings.warn(
                f"rbjax: RBJAX_NATIVE_ISA={cap!r} is not one of {', '.join(_ISA_CAPS)}: ignored, the kernels run {isa}",
                stacklevel=2,
            )
    except (OSError, AttributeError, ValueError, RuntimeError) as e:
        return NativeStatus(False, str(path), None, f"{path.name} could not be loaded: {e}")
    return NativeStatus(True, str(path), isa, "")


# --- which runs the kernels take -------------------------------------------------------------

# How each law the kernel computes itself adds to its parameters (see _parameters): ``add(key,
# array, components)`` with the law's arrays, ``n`` bodies, the state's dtype.
_Add = Callable[[str, Any, int], None]


def _constant(f: Any, add: _Add, n: int, dtype: Any) -> None:
    add("F", f.force, 3)
    add("tau", f.torque, 3)


def _gravity(f: Gravity, add: _Add, n: int, dtype: Any) -> None:
    add("g", f.g, 3)


def _linear_drag(f: LinearDrag, add: _Add, n: int, dtype: Any) -> None:
    add("b", f.linear, 1)
    add("br", f.angular, 1)


def _quadratic_drag(f: QuadraticDrag, add: _Add, n: int, dtype: Any) -> None:
    add("c", f.linear, 1)
    add("cr", f.angular, 1)


def _thruster(f: Thruster, add: _Add, n: int, dtype: Any) -> None:
    add("thrust", _thrust_sums(f, n, dtype), 6)


# The laws the kernel computes itself, listed once, by exact type: a subclass may compute
# anything, so it is evaluated by XLA like any other model (the JAX path, or at each step's
# start with AT_STEP_START), never with its parent's formula.
_LAWS: dict[type, Callable[[Any, _Add, int, Any], None]] = {
    Forces: _constant,
    ConstantForce: _constant,
    Gravity: _gravity,
    LinearDrag: _linear_drag,
    QuadraticDrag: _quadratic_drag,
    Thruster: _thruster,
}
NATIVE_LAWS = tuple(t.__name__ for t in _LAWS if t is not Forces)

# The methods whose steps evaluate the forces once, at the step's start state and time (euler.py:
# euler_state, semi_implicit_euler.py: semi_implicit_state, whose kick sees the old state): with a
# force law the kernel does not know, XLA evaluates it there and the kernel takes the result,
# one call per step. The others need forces at intermediate states (the stages of rk4 and
# rk4_body, splitting's kick after the drift), where a kernel call per stage would cost at
# least four per-step calls. A kernel call per step reads and writes the whole state once,
# as a fused JAX step does: roughly measured (shared 2-core machine, 1e5 bodies, float32),
# euler and semi_implicit_euler with a callable were no faster natively than on JAX, so
# native=None keeps such runs on JAX and native=True takes this path.
AT_STEP_START = tuple(m.name for m in available().values() if m.forces_at_step_start and m.native_code is not None)


def _terms(forces: Any) -> tuple[Any, ...] | None:
    """The terms of ``forces`` the kernel evaluates itself, or ``None`` when it cannot."""
    if forces is None:
        return ()
    terms = forces.terms if type(forces) is ForceSum else (forces,)
    return terms if all(type(t) in _LAWS for t in terms) else None


def native_plan(
    state: Any, forces: Any, method: Method, *, series: bool, checked: bool, checkpoint: Any, default: bool = False
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
        return f"method {method.name!r} has no native kernel (those with one: {', '.join(METHODS)})"
    if type(state) is not State:
        return f"{type(state).__name__} has no native kernel (State has)"
    if state.dtype not in (jnp.float32, jnp.float64):
        return f"dtype {state.dtype} has no native kernel (float32 and float64 have)"
    if not series and _terms(forces) is None and not method.forces_at_step_start:
        return (
            f"method {method.name!r} needs the forces at intermediate states, and these are evaluated by XLA "
            f"(the kernel evaluates none, constant or time-series Forces, {', '.join(NATIVE_LAWS)} and their "
            "sums itself, by their exact types, so not a subclass of one, whose own code runs on the JAX path "
            "(native=None or False); other force models and callables run natively with "
            f"{' and '.join(AT_STEP_START)}, which evaluate the forces once per step, at its start)"
        )
    if default and not series and _terms(forces) is None:
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


# --- the call --------------------------------------------------------------------------------


def _parameters(forces: Any, batch: tuple[int, ...], dtype: Any) -> tuple[dict[str, jax.Array], int]:
    """The kernel's force parameters ``F, tau, g (n, 3)``, ``drag (n, 4)``, ``thrust (n, 6)`` (``n`` = 1
    when shared) and its ``terms`` bits.

    ``thrust`` holds the thrusters' body-frame sums per body, ``f_b = Σ T_s d_s`` (N) and
    ``τ_b = Σ p_s × T_s d_s`` (N·m) over the thrusters ``s`` on the body (zero rows for the
    others), which the kernel turns by ``R(q)`` at each evaluation (steps.h: ``forces``).
    """
    n = int(np.prod(batch, dtype=np.int64))

    def per_body(a: Any, comps: int) -> jax.Array:
        a = jnp.asarray(a, dtype)
        a = a if comps > 1 else a[..., None]
        if int(np.prod(a.shape[:-1], dtype=np.int64)) == 1:
            return a.reshape(1, comps)
        return jnp.broadcast_to(a, batch + (comps,)).reshape(n, comps)

    zero3, zero = jnp.zeros((1, 3), dtype), jnp.zeros((1, 1), dtype)
    acc: dict[str, Any] = {"F": zero3, "tau": zero3, "g": zero3, "b": zero, "br": zero, "c": zero, "cr": zero}
    acc["thrust"] = jnp.zeros((1, 6), dtype)
    used: set[str] = set()

    def add(key: str, a: Any, comps: int) -> None:
        if a is None:
            return
        p = a if key == "thrust" else per_body(a, comps)
        acc[key] = p if key not in used else acc[key] + p
        used.add(key)

    for term in _terms(forces) or ():
        _LAWS[type(term)](term, add, n, dtype)
    rows = max(acc[k].shape[0] for k in ("b", "br", "c", "cr"))
    drag = jnp.concatenate([jnp.broadcast_to(acc[k], (rows, 1)) for k in ("b", "br", "c", "cr")], axis=1)
    terms = (1 if used else 0) | (2 if used & {"c", "cr"} else 0) | (4 if "thrust" in used else 0)
    terms |= 8 if "tau" in used else 0
    return {"F": acc["F"], "tau": acc["tau"], "g": acc["g"], "drag": drag, "thrust": acc["thrust"]}, terms


def _thrust_sums(thruster: Thruster, n: int, dtype: Any) -> jax.Array:
    """``(n, 6)``: per body the body-frame sums ``f_b = Σ T_s d_s`` and ``τ_b = Σ p_s × T_s d_s``
    over its thrusters (``body[s]`` = the body; ``Thruster`` needs a 1-D batch of ``n`` bodies)."""
    s = thruster.body.shape[0]
    d = jnp.broadcast_to(jnp.asarray(thruster.direction, dtype), (s, 3))
    f = jnp.broadcast_to(jnp.asarray(thruster.thrust, dtype), (s,))[:, None] * d
    fb = jnp.zeros((n, 3), dtype).at[thruster.body].add(f)
    if thruster.point is None:
        return jnp.concatenate([fb, jnp.zeros((n, 3), dtype)], axis=1)
    p = jnp.broadcast_to(jnp.asarray(thruster.point, dtype), (s, 3))
    return jnp.concatenate([fb, jnp.zeros((n, 3), dtype).at[thruster.body].add(jnp.cross(p, f))], axis=1)


def _inertias(body: Any, shared: bool, batch: tuple[int, ...], n: int) -> jax.Array:
    """``(1, 6)`` or ``(n, 6)``: the inertia's upper triangle ``I00 I01 I02 I11 I12 I22``, from which
    the kernel computes ``"splitting"``'s principal frames once per call (steps.h: ``principal_frame``,
    the values of :func:`rbjax._eigh3.principal_frame`, to which tests/test_native.py holds it)."""
    inertia = body.inertia
    inertia = inertia.reshape(1, 3, 3) if shared else jnp.broadcast_to(inertia, batch + (3, 3)).reshape(n, 3, 3)
    return jnp.stack([inertia[:, i, j] for i in range(3) for j in range(i, 3)], axis=1)


def _series_parameters(forces: Forces, steps: int, batch: tuple[int, ...], dtype: Any) -> dict[str, jax.Array]:
    """A time series' ``F, tau`` as the kernel takes them, ``(steps, n, 3)`` (``n`` = 1 when shared):
    ``forces``' fields are ``(steps, *B', 3)`` with ``B'`` broadcastable to ``batch``, or ``None``."""
    n = int(np.prod(batch, dtype=np.int64))

    def rows(a: Any) -> jax.Array:
        if a is None:
            return jnp.zeros((steps, 1, 3), dtype)
        a = jnp.asarray(a, dtype)
        if int(np.prod(a.shape[1:-1], dtype=np.int64)) == 1:
            return a.reshape(steps, 1, 3)
        return jnp.broadcast_to(a, (steps,) + batch + (3,)).reshape(steps, n, 3)

    return {"F": rows(forces.force), "tau": rows(forces.torque)}


def _call(
    code: int,
    steps: int,
    dyn: State,
    body: Any,
    forces: Any,
    dt: jax.Array,
    series: bool = False,
    sharded: bool = False,
) -> State:
    """``steps`` steps of the kernel's method ``code`` on a batch-first state ``dyn`` (fields ``(*B, c)``).

    ``forces``: ``None``, a constant :class:`Forces`, a sum of the laws of
    the laws of ``_LAWS``, or with ``series`` a :class:`Forces` of fields ``(steps, *B', 3)``,
    one slice per step. ``sharded`` (a 1-D batch, no series): every operand is
    made ``(N, c)`` (shared rows broadcast) and the call is marked with
    ``num_batch_dims = 1``, so XLA's batch partitioner splits it over the
    devices of the batch (each runs the kernel on its bodies; a shared ``(1, c)``
    row would be split as if it were bodies, hence the broadcast).
    """
    batch = tuple(dyn.position.shape[:-1])
    n = int(np.prod(batch, dtype=np.int64))
    dtype = dyn.position.dtype
    fields = ("position", "velocity", "orientation", "angular_momentum")
    flat = [getattr(dyn, f).reshape(n, getattr(dyn, f).shape[-1]) for f in fields]
    # a body shared by the whole batch stays one row; one shared over some batch axes is spread
    shared = body.mass.size == 1
    m = body.mass.reshape(1, 1) if shared else jnp.broadcast_to(body.mass, batch).reshape(n, 1)
    inv = body.inverse_inertia
    inv = inv.reshape(1, 9) if shared else jnp.broadcast_to(inv, batch + (3, 3)).reshape(n, 9)
    if series:
        zero3 = jnp.zeros((1, 3), dtype)
        params = _series_parameters(forces, steps, batch, dtype) | {
            "g": zero3,
            "drag": jnp.zeros((1, 4), dtype),
            "thrust": jnp.zeros((1, 6), dtype),
        }
        terms = 1 | (8 if forces.torque is not None else 0)
    else:
        params, terms = _parameters(forces, batch, dtype)
    inertia = _inertias(body, shared, batch, n) if code == METHODS["splitting"] else jnp.zeros((1, 6), dtype)
    operands = [m, inv, params["F"], params["tau"], params["g"], params["drag"], inertia, params["thrust"]]
    if sharded:
        operands = [jnp.broadcast_to(a, (n, a.shape[-1])) for a in operands]
    results = tuple(
        jax.ShapeDtypeStruct(a.shape, dtype, sharding=jax.typeof(a).sharding if sharded else None) for a in flat
    )
    call = jax.ffi.ffi_call(
        _TARGET, results, vmap_method="broadcast_all", input_output_aliases={0: 0, 1: 1, 2: 2, 3: 3}
    )
    attrs = dict(
        steps=np.int64(steps), method=np.int64(code), terms=np.int64(terms), series=np.int64(steps if series else 0)
    )
    if sharded:
        with set_xla_metadata(num_batch_dims="1"):
            out = call(*flat, *operands, jnp.asarray(dt, dtype), **attrs)
    else:
        out = call(*flat, *operands, jnp.asarray(dt, dtype), **attrs)
    x, v, q, L = (a.reshape(batch + a.shape[-1:]) for a in out)
    return replace(dyn, position=x, velocity=v, orientation=q, angular_momentum=L)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2, 3, 4, 5))
def advance(
    code: int,
    steps: int,
    reference: Callable[..., State],
    series: bool,
    force_fn: Callable[[Any, jax.Array], Forces] | None,
    sharded: bool,
    dyn: State,
    consts_soa: dict[str, Any],
    consts: dict[str, Any],
    forces: Any,
    dt: jax.Array,
    ts: jax.Array,
) -> State:
    """``steps`` steps of the method numbered ``code`` (:attr:`rbjax._methods.Method.native_code`) by the kernel,
    with the values of ``reference`` (same arguments, less the first six); ``sharded``: the batch
    is laid out over devices, and each call is split over them (see ``_call``).

    ``dyn`` is the stripped, batch-first state (fields ``(*B, c)``: the
    kernel gathers each block of bodies itself, so no transposes);
    ``consts_soa`` its constant fields with the prepared body (``mass``
    ``(*B)`` or ``()``, ``inverse_inertia`` ``(*B, 3, 3)`` or ``(3, 3)``), and
    ``consts`` the unprepared ones (the force models see those); ``dt`` the
    step (s) and ``ts`` ``(steps,)`` each step's start time (s). The forces:

    * ``force_fn`` ``None`` and ``forces`` ``None``, a constant batch-first
      :class:`Forces` or a sum of the laws the kernel knows: all ``steps`` in one call;
    * ``series``: ``forces`` a :class:`Forces` of fields ``(steps, *B', 3)``,
      step ``k``'s slice held over its stages: all ``steps`` in one call;
    * else (a method of ``AT_STEP_START`` only) ``force_fn`` ``(state, t) ->
      Forces`` (checked and cast, a user's callable) or, when it is ``None``,
      the force model ``forces``, evaluated by XLA at each step's start state
      (batch-first, with ``consts``, ``time = t``) and start time ``ts[k]``, then
      one kernel call per step with that constant :class:`Forces`.

    Differentiated through ``reference``, the JAX steps.
    """
    del reference
    body = consts_soa["body"]
    if series or (force_fn is None and _terms(forces) is not None):
        return _call(code, steps, dyn, body, forces, dt, series, sharded)
    fn = force_fn if force_fn is not None else checked_force_fn(forces)

    def one(d: State, t: jax.Array) -> tuple[State, None]:
        f = fn(replace(d, **{**consts, "time": t}), t)
        return _call(code, 1, d, body, f, dt, sharded=sharded), None

    return jax.lax.scan(one, dyn, ts)[0]


@advance.defjvp
def _advance_jvp(code, steps, reference, series, force_fn, sharded, primals, tangents):
    return jax.jvp(reference, primals, tangents)
