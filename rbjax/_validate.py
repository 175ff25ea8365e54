"""A run's arguments, normalised and checked: shared by ``step``, ``simulate`` and ``simulate_chunked``.

Everything here runs before or while tracing, in rbjax's words: a concrete bad
value raises ``TypeError``/``ValueError`` naming the argument; a traced one is
checked at run time by :func:`traced_step_size` in checked mode only (off, the
compiled program has no checks); a force callable's output is checked once,
while it is traced, by :func:`checked_force_fn`.
"""

from __future__ import annotations

import functools
import math
import os
import sys
import warnings
import weakref
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax import Array

from . import _methods
from ._math import broadcasts_to, index_tuple
from ._methods import AbstractMethod
from ._pytree import data_fields, is_rbjax_dataclass, new_unchecked, replace
from ._quantities import body_angular_velocity
from ._rotors import rotor_torque_shape
from ._state import AnyState, ForceLike, Forces, MatrixState, ParticleState, State

__all__ = [
    "check_dt",
    "check_count",
    "check_state",
    "traced_step_size",
    "checked_force_fn",
    "as_force_fn",
    "cast_forces",
    "start_time",
    "is_time_series",
    "check_run",
    "StepSizeWarning",
    "warn_turn_per_step",
]

_STATE_TYPES = (State, MatrixState, ParticleState)


def check_dt(dt: Any, name: str = "dt", *, positive: bool = True) -> None:
    """``TypeError`` unless ``dt`` is a real scalar; ``ValueError`` unless it is finite (and > 0).

    ``positive=False`` for a time such as ``t0``, which may be of any sign. A
    traced value passes here; checked mode tests it at run time
    (:func:`traced_step_size`).
    """
    if isinstance(dt, jax.core.Tracer):
        return
    if dt is None or isinstance(dt, (bool, np.bool_, str, bytes)):
        raise TypeError(f"{name} must be a real number (seconds), got {dt!r}")
    try:
        d = np.asarray(dt)
    except Exception:  # noqa: BLE001  (anything numpy cannot convert is the wrong type)
        raise TypeError(f"{name} must be a real number (seconds), got {type(dt).__name__}") from None
    if d.dtype == bool or not (np.issubdtype(d.dtype, np.integer) or np.issubdtype(d.dtype, np.floating)):
        raise TypeError(f"{name} must be a real number (seconds), got {dt!r} of dtype {d.dtype}")
    if np.issubdtype(d.dtype, np.floating) and np.finfo(d.dtype).bits < 32:
        raise TypeError(f"{name} must be float32 or float64 (or a Python number), got dtype {d.dtype}")
    if d.ndim != 0:
        raise ValueError(f"{name} must be a scalar, got shape {d.shape}")
    if not np.isfinite(d) or (positive and d <= 0):
        raise ValueError(f"{name} must be finite{' and > 0' if positive else ''}, got {d}")


def check_count(name: str, value: Any, minimum: int) -> int:
    """``value`` as an int; ``ValueError`` unless it is an int (not a bool) ``>= minimum``."""
    if isinstance(value, jax.core.Tracer):  # a count sets a shape or a loop's length: it must be known to trace
        raise TypeError(
            f"{name} must be a Python int, known before tracing (it sets the run's length and shapes), got a "
            f"traced value {value!r}; mark it static (jax.jit(..., static_argnames=...)) or close over it"
        )
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        kind = "non-negative" if minimum == 0 else f">= {minimum}" if minimum > 1 else "positive"
        raise ValueError(f"{name} must be a {kind} int, got {value!r}")
    return int(value)


class StepSizeWarning(RuntimeWarning):
    """A step turns a body by more than half a turn: the attitude a run returns is not to be trusted.

    Given by :func:`rbjax.simulate`, :func:`rbjax.simulate_chunked`,
    :func:`rbjax.simulate_truncated` and :func:`rbjax.step` when, at the start state, ``dt·|ω| > π`` (rad) for some
    body. Then the attitudes a step method samples cannot be told from those of
    a slower turn the other way, and an explicit method's local error, a power
    series in ``dt·|ω|``, no longer shrinks: ``"euler"`` returns finite unit
    quaternions that have nothing to do with the motion. Methods that keep the
    energy and momentum (``"splitting"``, ``"implicit_midpoint"``) still keep
    them; their attitudes are as wrong. A motion a method integrates exactly
    (a steady spin about a principal axis) is the exception.

    Filter it (``warnings.simplefilter("ignore", rbjax.StepSizeWarning)``) for a
    study of the methods themselves at such steps.
    """


def turn_limits(method: AbstractMethod | None, state_type: str) -> tuple[float, float]:
    """``(diverges, inaccurate)``: the ``dt·|ω|`` (rad per step) beyond which ``method`` cannot follow a ``state_type``.

    ``diverges``: where :attr:`Method.stable_dt_omega` saw it diverge, the grid
    point after its last stable one (the measurement's grid ratio 1.33; below,
    a run stays finite). ``inaccurate``: for an explicit method of order ``p``,
    where the leading term of its one-step error on a rotation,
    ``(dt·|ω|)^(p+1) / (p+1)!`` (its stability function against ``exp``), reaches
    1 rad: each step errs by as much as it turns, and no digit of the attitude
    is right (euler and semi-implicit Euler 1.41, rk4 2.61, rk8 4.15). ``inf``
    where neither applies (no method, the implicit and splitting methods).
    """
    limits = getattr(method, "stable_dt_omega", None)
    if limits is None:
        return math.inf, math.inf
    diverges = 1.33 * limits.get(state_type, math.inf)
    order = int(getattr(method, "order", 0) or 0)
    inaccurate = math.factorial(order + 1) ** (1 / (order + 1)) if order > 0 else math.inf
    return diverges, inaccurate


def turn_threshold(method: AbstractMethod | None, state_type: str) -> float:
    """The ``dt·|ω|`` (rad) beyond which :class:`StepSizeWarning` is given: ``π`` or below (:func:`turn_limits`)."""
    return min(math.pi, *turn_limits(method, state_type))


def warn_turn_per_step(state: Any, dt: Any, fn: str, method: AbstractMethod | None = None) -> None:
    """:class:`StepSizeWarning` when a concrete start state turns some body too far in one step for ``method``.

    Too far: ``dt·|ω| > π`` (half a turn, for any method), or beyond where
    ``method`` diverges or loses every digit of the attitude for this state type
    (:func:`turn_limits`). ``ω`` (rad/s, world frame) is
    :func:`rbjax.angular_velocity` of the start state; torques can make it grow
    later, which this does not see. Traced states and steps (inside ``jit``,
    ``vmap``, ``grad``) pass silently.
    """
    start_checks(state, dt, None, fn, method, time=False)


def start_checks(
    state: Any, dt: Any, t0: Any, fn: str, method: AbstractMethod | None, *, time: bool = True, turn: bool = True
) -> Any:
    """The run's start time and the checks of its start state, from one compiled reduction.

    Returns ``t0`` when given, else (``time``) the batch's one clock read from
    ``state.time`` (:func:`start_time`: ``ValueError`` when the bodies' times
    differ). With ``turn``, :class:`StepSizeWarning` as :func:`warn_turn_per_step`
    says. Both are reductions over the batch: they run compiled, in one small program
    per shape, and a handful of scalars come back to the host, so an eager call pays
    no pass of NumPy over its bodies (at 1e4 bodies such passes cost as much as 100
    native Euler steps). Traced or multi-process states take :func:`start_time` alone.
    """
    time = time and t0 is None
    turn = turn and isinstance(state, (State, MatrixState))
    leaves = jax.tree.leaves(state)
    concrete = (
        isinstance(state, _STATE_TYPES)
        and not isinstance(dt, jax.core.Tracer)
        and 0 not in state.batch_shape
        and all(not isinstance(x, jax.core.Tracer) and getattr(x, "is_fully_addressable", True) for x in leaves)
    )
    if not concrete:
        return start_time(state) if time else t0
    if not (time or turn):
        return t0
    first, last, most = _reduced(state, dt, time, turn)
    if time:
        if jnp.size(state.time) > 1 and not first == last:
            raise ValueError(
                f"the states of a batch must share one time to be stepped together; state.time has shape "
                f"{jnp.shape(state.time)}. Set one with dataclasses.replace(state, time=t) or pass t0="
            )
        t0 = np.asarray(first, state.time.dtype)
    if turn and most > turn_threshold(method, type(state).__name__):  # the bound passes: the exact rate
        with jax.ensure_compile_time_eval():  # concrete inputs under a caller's trace: values, not tracers
            most = float(jnp.max(_turn_per_step(state, dt)))
            text = _turn_text(most, state, dt, fn, method)
        if text is not None:
            warnings.warn(text, StepSizeWarning, stacklevel=user_stacklevel())
    return t0


# The start state's reductions, once per distinct input: JAX arrays are immutable, so the same
# objects hold the same values (a run repeated from one state, a sweep over forces or methods);
# an entry goes when one of its arrays is collected, before its id can be reused.
_REDUCED: dict[tuple[Any, ...], tuple[float, float, float]] = {}


def _reduced(state: Any, dt: Any, time: bool, turn: bool) -> tuple[float, float, float]:
    """:func:`_start_reductions` on the host, ``(first, last, most)``, computed once per distinct input."""
    read = [state.time] if time else []
    if turn:
        rigid = isinstance(state, MatrixState)
        read += [state.angular_velocity] if rigid else [state.angular_momentum, state.body.inertia]
    key = (tuple(map(id, read)), float(dt) if turn else None, time, turn)
    hit = _REDUCED.get(key)
    if hit is not None:
        return hit
    # one array of three scalars: each array brought to the host is a transfer of its own
    with jax.ensure_compile_time_eval():  # concrete inputs under a caller's trace: values, not tracers
        first, last, most = np.asarray(_start_reductions(state, dt, time=time, turn=turn)).tolist()
    if all(isinstance(a, jax.Array) for a in read):  # a NumPy array may change in place: not kept
        _REDUCED[key] = (first, last, most)
        for a in read:
            weakref.finalize(a, _REDUCED.pop, key, None)
    return first, last, most


@functools.partial(jax.jit, static_argnames=("time", "turn"))
def _start_reductions(state: Any, dt: Any, *, time: bool, turn: bool) -> Array:
    """``[first, last, most]`` in the state's dtype: the smallest and largest ``state.time`` (``first``
    is the clock when they are equal) and an upper bound on the largest ``dt·|ω|`` (rad; exact for a
    :class:`MatrixState`), each ``0`` when not asked."""
    zero = jnp.zeros((), state.dtype)
    first = last = most = zero
    if time:
        t = jnp.reshape(state.time, -1)
        first, last = jnp.min(t), jnp.max(t)
    if turn:
        most = jnp.max(_turn_bound(state, dt))
    return jnp.stack([first, last, most]).astype(state.dtype)


def _turn_bound(state: Any, dt: Any) -> Array:
    """An upper bound on ``dt·|ω|`` per body, ``(*B,)``, elementwise (no 3x3 inverse).

    ``|ω| = |I_L⁻¹ Rᵀ L| ≤ |L| / λ_min`` and ``λ_min = det I / (λ_mid λ_max) ≥ det I / ‖I‖_F²``;
    for the bodies rbjax accepts it is 2-6 times ``|ω|``. The exact rate
    (:func:`_turn_per_step`, whose 3x3 inverses cost five times as much) is computed only
    where the bound passes a limit. Each component is a strided slice of the flat batch
    (sliced from ``(N, 3, 3)``, XLA:CPU transposed the whole array for each), computed
    apart from the reduction that follows (an optimisation barrier).
    """
    dt = jnp.asarray(dt, state.dtype)

    def rows(a: Array, width: int) -> list[Array]:  # each component a strided slice of the flat batch
        flat = jnp.reshape(a, -1)
        return [jax.lax.slice(flat, (k,), (flat.size - width + k + 1,), (width,)) for k in range(width)]

    if isinstance(state, MatrixState):
        w0, w1, w2 = rows(state.angular_velocity, 3)
        bound = dt * jnp.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    else:
        a, b, c, _, e, f, _, _, i = rows(state.body.inertia, 9)
        det = a * (e * i - f * f) - b * (b * i - f * c) + c * (b * f - e * c)
        frobenius2 = a * a + e * e + i * i + 2 * (b * b + c * c + f * f)
        l0, l1, l2 = rows(state.angular_momentum, 3)
        bound = dt * jnp.sqrt(l0 * l0 + l1 * l1 + l2 * l2) * frobenius2 / det
    return jax.lax.optimization_barrier(jnp.reshape(bound, state.batch_shape))


@jax.jit
def _turn_per_step(state: Any, dt: Any) -> Array:
    """``dt·|ω|`` (rad) per body, ``(*B,)``: the body-frame rate of a :class:`State` (the same norm,
    one rotation fewer), the world rate of a :class:`MatrixState`."""
    dt = jnp.asarray(dt, state.dtype)
    if isinstance(state, MatrixState):
        return dt * jnp.linalg.norm(state.angular_velocity, axis=-1)
    return dt * jnp.linalg.norm(body_angular_velocity(state), axis=-1)


def _turn_text(most: float, state: Any, dt: Any, fn: str, method: AbstractMethod | None) -> str | None:
    """The :class:`StepSizeWarning` for the largest turn per step ``most`` (rad), or ``None`` when
    it is within ``method``'s limits (:func:`turn_limits`); the body is found only then."""
    state_type = type(state).__name__
    diverges, inaccurate = turn_limits(method, state_type)
    if not most > turn_threshold(method, state_type):
        return None
    shape = state.batch_shape
    worst = int(np.argmax(np.asarray(_turn_per_step(state, dt)))) if shape else 0
    which = f" (body {index_tuple(np.unravel_index(worst, shape))})" if shape else ""
    rate = most / float(dt)
    head = f"{fn}: dt·|ω| = {most:.3g} rad at the start{which}"
    if most > math.pi:
        return (
            f"{head}: each step turns the body by more than half a "
            "turn, beyond what a step method follows (explicit ones return attitudes unrelated to the motion; "
            f"conservative ones keep energy and momentum, not the attitude). Use dt < π/|ω| = {math.pi / rate:.3g} s, "
            "and far less for accuracy (rbjax.methods(), docs/integrators.md); rbjax.torque_free gives the exact "
            "torque-free motion at any time"
        )
    assert method is not None  # the other limits are a method's
    if most > diverges:
        return (
            f"{head}: beyond where {method.name!r} diverges for {state_type} (≈ {diverges:.3g}, measured over "
            "1000 torque-free steps: rbjax.methods()): the run will end in NaN or an orientation off the rotation "
            f'group. Use dt < {diverges / 1.33 / rate:.3g} s (dt·|ω| < {diverges / 1.33:g}), or "splitting" '
            "(stable at any dt)"
        )
    p = method.order
    return (
        f"{head}: {method.name!r} (order {p}) errs by about (dt·|ω|)^{p + 1}/{p + 1}! = "
        f"{most ** (p + 1) / math.factorial(p + 1):.2g} rad per step, as much as it turns: no digit of the "
        f"attitude is right. Use dt < {inaccurate / rate:.3g} s, and far less for accuracy "
        "(rbjax.methods(), docs/integrators.md)"
    )


def user_stacklevel() -> int:
    """``warnings.warn``'s ``stacklevel`` that points at the first caller outside rbjax."""
    package = os.path.dirname(os.path.abspath(__file__)) + os.sep
    frame, level = sys._getframe(1), 1
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(package):
        frame, level = frame.f_back, level + 1
    return level


def check_state(state: Any, fn: str) -> None:
    """``TypeError`` unless ``state`` is an rbjax state with float32/float64 arrays."""
    if not isinstance(state, _STATE_TYPES):
        raise TypeError(f"{fn}: state must be a State, MatrixState or ParticleState, got {type(state).__name__}")
    for leaf in jax.tree.leaves(state):
        dt = getattr(leaf, "dtype", None) or jnp.result_type(leaf)
        if dt not in (jnp.float32, jnp.float64):
            raise TypeError(
                f"{fn}: state arrays must be float32 or float64, got {dt}; convert the inputs "
                "(float16/bfloat16 cannot resolve a unit quaternion or an inertia tensor)"
            )


def traced_step_size(dt: Any, t0: Any, fn: str) -> tuple[Any, Any]:
    """``dt``, ``t0`` with run-time checks (checked mode): ``dt`` finite and > 0, ``t0`` finite.

    Concrete values were checked already; only tracers gain a check, so an eager
    call compiles the same program as before.
    """
    if not (isinstance(dt, jax.core.Tracer) or isinstance(t0, jax.core.Tracer)):
        return dt, t0
    dt = jnp.asarray(dt)  # a Python float would pass through error_if unchecked
    bad_dt = ~(jnp.isfinite(dt) & (dt > 0))
    bad_t0 = ~jnp.isfinite(t0)
    msgs = (
        f"{fn}(checked=...): dt must be finite and > 0 (a traced dt was not)",
        f"{fn}(checked=...): t0 must be finite (a traced t0 was not)",
    )
    # both on dt, which every step uses: a check on t0 alone is dead code when no force reads t
    dt = eqx.branched_error_if(dt, bad_dt | bad_t0, jnp.where(bad_dt, 0, 1), msgs)
    return dt, t0


def _describe(x: Any) -> str:
    if is_rbjax_dataclass(x):
        return f"{type(x).__name__}({', '.join(f'{n}={_describe(getattr(x, n))}' for n in data_fields(x))})"
    shape = getattr(x, "shape", None)
    if shape is not None:
        return f"array of shape {tuple(shape)} and dtype {x.dtype}"
    return repr(x) if x is None else type(x).__name__


def _name(fn: Any) -> str:
    return getattr(fn, "__qualname__", None) or type(fn).__name__


def check_forces_output(out: Any, state: Any, fn: Any) -> Forces:
    """``out`` as ``Forces`` of the state's dtype; ``TypeError``/``ValueError`` otherwise."""
    want = tuple(state.position.shape)
    expected = f"rbjax.Forces(force=None or {want}, torque=None or {want})"
    if not isinstance(out, Forces):
        raise TypeError(f"force callable {_name(fn)!r} must return {expected}; it returned {_describe(out)}")
    fixed = {}
    for name in ("force", "torque"):
        a = getattr(out, name)
        if a is None:
            fixed[name] = None
            continue
        dt = getattr(a, "dtype", None)
        if dt is None or not (jnp.issubdtype(dt, jnp.floating) or jnp.issubdtype(dt, jnp.integer)):
            raise TypeError(f"force callable {_name(fn)!r}: {name} must be a real array; it returned {_describe(out)}")
        ok = broadcasts_to(tuple(a.shape), want)
        if not ok:
            raise ValueError(
                f"force callable {_name(fn)!r}: {name} has shape {tuple(a.shape)}, which does not broadcast "
                f"to the state's {want} (batch shape {tuple(state.batch_shape)} + (3,)); expected {expected}"
            )
        # broadcast here: the batch-last transposes that follow assume full shapes
        fixed[name] = jnp.broadcast_to(jnp.asarray(a).astype(state.dtype), want)
    k = rotor_torque_shape(out, state, f"force callable {_name(fn)!r}")
    if k is not None:
        fixed["rotor_torque"] = jnp.broadcast_to(jnp.asarray(out.rotor_torque).astype(state.dtype), k)
    return new_unchecked(Forces, **fixed)


def checked_force_fn(fn: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Forces]:
    """``fn`` with its output checked each time it is traced (free at run time)."""

    @functools.wraps(fn)
    def wrapped(state: Any, t: Any) -> Forces:
        return check_forces_output(fn(state, t), state, fn)

    return wrapped


def as_force_fn(forces: ForceLike) -> Callable[[Any, Array], Forces]:
    """Normalise ``None`` / ``Forces`` / callable to ``(state, t) -> Forces``."""
    if forces is None:
        return lambda state, t: Forces()
    if isinstance(forces, Forces):
        return lambda state, t: forces
    if callable(forces):
        return forces
    raise TypeError(f"forces must be Forces, a callable (state, t) -> Forces, or None; got {type(forces)}")


def cast_forces(forces: Forces, dtype: Any) -> Forces:
    """``forces`` with its arrays in the state's ``dtype`` (a float64 force must not promote a float32 state)."""
    cast = lambda a: None if a is None else a.astype(dtype)
    if all(a is None or a.dtype == dtype for a in (forces.force, forces.torque, forces.rotor_torque)):
        return forces
    return replace(forces, force=cast(forces.force), torque=cast(forces.torque), rotor_torque=cast(forces.rotor_torque))


def start_time(state: AnyState) -> Array:
    """The one time ``t`` (s) of a state or batch, from ``state.time``.

    A batch is stepped on one clock: concrete times must all be equal; traced
    ones (inside ``jit``) are taken from the first body. An empty batch
    (``N = 0``) has no clock: its time is 0 (pass ``t0`` to choose another).
    """
    t = state.time
    if jnp.size(t) == 0:  # static shape: no body, no clock to read
        return jnp.zeros((), jnp.result_type(t))
    if not isinstance(t, jax.core.Tracer) and isinstance(t, jax.Array) and not t.is_fully_addressable:
        # a batch split over processes: its clock from a reduction (replicated), not a host copy
        lo, hi = _time_range(t)
        if lo != hi:
            raise ValueError(
                f"the states of a batch must share one time to be stepped together; state.time of shape "
                f"{t.shape} ranges over [{float(lo)}, {float(hi)}]. Set one with dataclasses.replace(state, "
                "time=t) or pass t0="
            )
        return jnp.asarray(np.asarray(lo))
    if not isinstance(t, jax.core.Tracer):
        host = np.asarray(t)
        if host.size > 1 and np.ptp(host) != 0:
            raise ValueError(
                f"the states of a batch must share one time to be stepped together; state.time has shape "
                f"{t.shape}. Set one with dataclasses.replace(state, time=t) or pass t0="
            )
        return jnp.asarray(host.reshape(-1)[0])  # from the host: a sharded time needs no gather
    return jnp.max(t)  # all equal; a reduction, which sharded batches allow


@jax.jit
def _time_range(t: Array) -> tuple[Array, Array]:
    return jnp.min(t), jnp.max(t)


def is_time_series(forces: Forces, state: AnyState, steps: int) -> bool:
    """Whether ``forces`` has a leading time axis ``(steps, *B, 3)`` (``rotor_torque``: ``(steps, *B, k)``);
    ``ValueError`` when some of its arrays have one and others not, or a wrong length."""
    leaves = [a for a in (forces.force, forces.torque, forces.rotor_torque) if a is not None]
    if not leaves:
        return False
    nb = len(state.batch_shape)
    series = [a.ndim - 1 > nb for a in leaves]
    if any(series):
        for a in leaves:
            if a.ndim - 1 <= nb or a.shape[0] != steps:
                raise ValueError(
                    f"time-series forces must have shape (steps={steps}, *batch, 3) (rotor_torque: "
                    f"(steps, *batch, k)); got {a.shape} for a state of batch shape {state.batch_shape}"
                )
    rotor_torque_shape(forces, state, "simulate: forces", series=any(series))
    return any(series)


def check_run(
    state, dt, steps, method, save_every, t0, fn: str, *, warn_step_size: bool = True
) -> tuple[int, int, AbstractMethod]:
    """``TypeError``/``ValueError`` for a bad argument of a run (``simulate``, ``simulate_chunked``).

    Returns ``(steps, save_every)`` as ints and the :class:`Method` that
    ``method`` names. A concrete ``dt`` and ``t0`` are checked here; traced ones
    only in checked mode, at run time. A concrete start state that turns a body
    by more than half a turn per step gets a :class:`StepSizeWarning` unless
    ``warn_step_size=False`` (a caller that warned already).
    """
    check_state(state, fn)
    method = _methods.resolve(method, fn)
    method.step(type(state))
    _methods.check_rotors(method, state, fn)
    steps = check_count("steps", steps, 0)
    save_every = check_count("save_every", save_every, 1)
    if steps % save_every:
        raise ValueError(f"save_every must be a positive int dividing steps={steps}, got {save_every!r}")
    check_dt(dt)
    if t0 is not None:
        check_dt(t0, "t0", positive=False)
    if warn_step_size:
        warn_turn_per_step(state, dt, fn, method)
    return steps, save_every, method
