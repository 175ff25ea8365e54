"""``step`` and ``simulate``: pure functions over state pytrees."""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from . import _checked, _methods, _native
from ._batching import batch_shape, lift, map_leaves, to_batch_first, to_batch_last, with_layout
from ._body import prepare
from ._deprecated import renamed_keywords
from ._force_fn import step_force_fn
from ._force_model import (
    ForceModel,
    ForceSum,
    check_force_model,
    reads_velocity,
    with_per_body_terms,
)
from ._math import broadcasts_to
from ._methods import DEFAULT_METHOD, AbstractMethod, OrderWarning
from ._pytree import replace
from ._rotors import rotor_torque_shape
from ._scan import check_checkpoint, checkpointed_scan, frames_as_outputs, frames_in_buffer
from ._state import ForceLike, Forces, ParticleState, StateT, split_constants
from ._trajectory import stack_frames
from ._typing import ArrayLike
from ._validate import (
    as_force_fn,
    cast_forces,
    check_dt,
    check_run,
    check_state,
    checked_force_fn,
    is_time_series,
    start_checks,
    start_time,
    traced_step_size,
    user_stacklevel,
    warn_turn_per_step,
)

__all__ = ["step", "simulate", "run_simulation"]


def _canonical(state: Any) -> Any:
    """A frame of a trajectory in the shapes of a fresh state: one compiled program for both.

    Drops the leading size-1 batch axes of the shared fields (``body``, ``rotors``:
    ``(1,)`` → ``()``) and makes a one-element ``time`` a scalar.
    """
    if isinstance(state, ParticleState):
        return state
    rotors = state.rotors
    if 1 not in state.body.mass.shape and (rotors is None or 1 not in rotors.inertia.shape[:-1]):
        return state

    def squeeze(a: Array, core: int) -> Array:
        k = a.ndim - core
        drop = 0
        while drop < k and a.shape[drop] == 1:  # leading size-1 axes broadcast: drop them
            drop += 1
        return a.reshape(a.shape[drop:])

    return replace(state, body=map_leaves(state.body, squeeze), rotors=map_leaves(rotors, squeeze))


def prepare_state(state: Any, principal: bool = False) -> Any:
    """``state`` with its body prepared for a time loop (see :func:`rbjax._body.prepare`; with
    ``principal``, its principal frame too, for a method with ``principal_frame``); lifted."""
    if isinstance(state, ParticleState):
        return state
    return replace(state, body=lift(lambda b: prepare(b, principal))(state.body))


@renamed_keywords("step", t="t0")
def step(
    state: StateT,
    forces: ForceLike,
    dt: Float[ArrayLike, ""],
    method: str | AbstractMethod | Callable[..., Any] = DEFAULT_METHOD,
    *,
    t0: Float[ArrayLike, ""] | None = None,
) -> StateT:
    """Advance ``state`` by one step of ``dt`` seconds.

    Args:
        state: :class:`State`, :class:`MatrixState` or :class:`ParticleState`,
            one body or a batch of any leading shape.
        forces: world-frame :class:`Forces` (force on and torque about the centre
            of mass), a callable ``(state, t) -> Forces`` evaluated by the method
            where it needs it, or ``None``.
        dt: step (s), > 0.
        method: integrator name, method object (:class:`rbjax.AbstractMethod`) or batch step callable (static), as in
            :func:`simulate`; see :func:`rbjax.methods`. Default ``"splitting"`` (second order, symplectic).
        t0: time (s) at the start of the step, passed to a callable ``forces``;
            default ``None``: ``state.time`` (as ``t0`` of :func:`simulate`).

    Returns the new state, of the same type and shape, with ``time = t0 + dt``.
    Forces are cast to the state's dtype. Pure; ``jit`` it with
    ``static_argnames="method"``. Concrete bad arguments raise ``TypeError`` /
    ``ValueError`` (as in :func:`simulate`); a traced ``dt`` is not tested here
    (``step`` has no checked mode: use ``simulate(..., checked=True)``).
    """
    check_state(state, "step")
    resolved = _methods.resolve(method, "step")
    fn = resolved.step(type(state))
    _methods.check_rotors(resolved, state, "step")
    check_dt(dt)
    if t0 is not None:
        check_dt(t0, "t0", positive=False)
    warn_turn_per_step(state, dt, "step", resolved)
    dtype = state.dtype
    if isinstance(forces, Forces):
        forces = cast_forces(forces, dtype)
        want = state.batch_shape + (3,)
        for name in ("force", "torque"):
            a = getattr(forces, name)
            if a is not None and not broadcasts_to(tuple(a.shape), want):
                raise ValueError(
                    f"step: forces.{name} has shape {tuple(a.shape)}, which does not broadcast to the state's "
                    f"{want} (batch shape {state.batch_shape} + (3,)); step takes one step's forces (a time "
                    "series (steps, *batch, 3) is for simulate)"
                )
        rotor_torque_shape(forces, state, "step: forces")
    elif isinstance(forces, ForceModel):
        check_force_model(forces, state, "step")
    dt = jnp.asarray(dt, dtype)
    t = start_time(state) if t0 is None else jnp.asarray(t0, dtype)
    new = fn(prepare_state(_canonical(state)), checked_force_fn(as_force_fn(forces)), t, dt)
    keep = {k: getattr(state, k) for k in state.constant_fields if k != "time"}
    return replace(new, **keep, time=jnp.broadcast_to(t + dt, jnp.shape(state.time)).astype(dtype))


def _scalar(x: Any) -> Any:
    """``x`` as an argument of the compiled run: a JAX array (or tracer) as it is, else a NumPy
    scalar, which ``jit`` takes at the cost of a copy (``jnp.asarray`` of a Python number dispatched
    an operation of its own, about a tenth of 100 native Euler steps of 1e4 bodies)."""
    return x if isinstance(x, jax.Array) else np.asarray(x)


def _warn_below_order(method: AbstractMethod, forces: ForceModel) -> None:
    """:class:`rbjax.OrderWarning` when ``method`` loses order under ``forces``' velocity-dependent laws."""
    low = method.order_with_velocity_forces
    if low is None or low >= method.order or reads_velocity(forces) is not True:
        return
    terms = forces.terms if isinstance(forces, ForceSum) else (forces,)
    names = sorted({type(term).__name__ for term in terms if reads_velocity(term)})
    warnings.warn(
        f"simulate: method {method.name!r} is order {method.order} for forces of position and time, but "
        f"{' and '.join([', '.join(names[:-1]), names[-1]] if len(names) > 1 else names)} "
        f"read{'s' if len(names) == 1 else ''} velocities: its kicks use the velocities at their "
        f"start, so the run is order {low}. Use method='rk4' or 'rk8' for accuracy, or filter "
        "rbjax.OrderWarning where that is enough",
        OrderWarning,
        stacklevel=user_stacklevel(),
    )


def simulate(
    state: StateT,
    forces: ForceLike,
    dt: Float[ArrayLike, ""],
    steps: int,
    method: str | AbstractMethod | Callable[..., Any] = DEFAULT_METHOD,
    *,
    save_every: int = 1,
    t0: Float[ArrayLike, ""] | None = None,
    checked: bool | _checked.Checks = False,
    checkpoint: int | None = None,
    native: bool | None = None,
) -> StateT:
    """Integrate ``steps`` steps of ``dt`` with ``lax.scan`` and return the trajectory.

    Args:
        state: initial state (one body or any batch).
        forces: world-frame forces, one of

            * a constant :class:`Forces` (``(*B, 3)`` or broadcastable);
            * a :class:`Forces` with a leading time axis, ``(steps, *B, 3)``, one
              per step (held constant within the step);
            * a callable ``(state, t) -> Forces`` on the whole batch;
            * a force model (:class:`rbjax.ForceModel`, e.g. ``Gravity() + LinearDrag(0.1)``),
              whose arrays are traced data (changing them does not recompile);
            * ``None``.
        dt: step (s), > 0; differentiable. A concrete ``dt`` is checked here
            (``TypeError``/``ValueError``); a traced one (under a caller's ``jit``,
            ``grad`` or ``vmap``) only with ``checked``, at run time.
        steps: number of steps (static).
        method: integrator name, or a method object: a ``Method`` from :func:`rbjax.methods` (the
            same run: ``method=rb.methods()["rk4"]`` gives ``method="rk4"``'s bits) or an
            instance of a user's :class:`rbjax.AbstractMethod` subclass (its own steps on every
            path; ``native=True`` refuses it), or a hashable batch step function ``(state, force_fn, t, dt) -> state``
            such as a :class:`rbjax.Scene`'s kernel; static. Anything else raises
            ``TypeError``. Default ``"splitting"``: Strang splitting, second order and symplectic
            (energy error bounded, world ``L`` exact, exact for symmetric tops), at a
            few times ``"euler"``'s cost per step (``rb.methods()[name].cost``); the
            accuracy it buys on the README's body is in docs/integrators.md.
            Pass ``"euler"`` for the lecture notes' update.
        save_every: keep every ``save_every``-th state (static); must divide ``steps``.
        t0: start time (s); default ``state.time``, so ``simulate(traj[-1], ...)``
            continues a run where it ended.
        checked: ``True`` or an :class:`rbjax.Checks` to test every step for a
            non-finite state or an orientation off the unit sphere, and every saved
            frame for a body turning more than half a turn per step
            (``dt·|ω| > π``) and for an energy jump, raising an error that names the step and the
            body's batch index (works under ``jit``; see :class:`rbjax.Checks`);
            a force model's traced body indices and coefficient signs are tested
            too. ``False`` (default) compiles no checks at all.
        checkpoint: segment length in steps for gradient checkpointing (static),
            or ``None``. Reverse mode then stores only the state at each segment
            boundary and recomputes one segment's forward pass while
            differentiating it: memory ``O(steps/checkpoint + checkpoint)``
            states instead of ``O(steps)``, for about one extra forward pass
            (``checkpoint ≈ √steps`` minimises memory). Must divide ``steps`` and
            either divide ``save_every`` or be a multiple of it. Values and
            gradients are unchanged (to round-off). See :func:`rbjax._scan.checkpointed_scan`.
        native: which implementation steps the bodies. ``None`` (default): the
            native CPU kernel where one applies (``"euler"``, ``"rk4"``, ``"splitting"``,
            ``"semi_implicit_euler"``, ``"rk4_body"`` on :class:`State` batches, float32/float64, no force,
            constant or time-series :class:`Forces`, or sums of ``Gravity``, ``LinearDrag``,
            ``QuadraticDrag``, ``ConstantForce``, ``Thruster``; see :func:`rbjax.native_status`), else JAX.
            ``False``: always JAX. ``True``: the kernel, or ``ValueError`` saying
            why it does not apply; with ``True``, ``"euler"`` and ``"semi_implicit_euler"``
            also take any other force model or callable, evaluated by XLA at each step's
            start and handed to the kernel (one call per step; ``None`` keeps these on
            JAX, which was no slower). A batch sharded over devices runs the kernel on
            each device's bodies (1-D batches, no time series). Both give the same values to round-off;
            derivatives always come from the JAX steps.

    Returns:
        The trajectory: the same pytree type as ``state`` with a leading time axis
        of length ``T = steps // save_every + 1`` on every leaf, starting with the
        initial state. ``time`` ``(T, *B)`` holds each frame's time
        ``t0 + k save_every dt``. Fields no integrator changes (``body``; ``mass`` of
        particles) are repeated per frame but not per body where the batch
        shares them (a shared body is ``(T, 1, ...)``: one body per frame), so
        ``jax.tree.map(lambda x: x[-1], traj)``, ``jax.vmap`` over frames and
        concatenation along axis 0 all work on it; ``traj[i]``, ``traj[a:b]``,
        ``traj[:, j]``, iteration and :func:`rbjax.concatenate` do the same with
        checks. Forces are cast to the state's dtype.

    A new callable ``forces`` object compiles anew (it is a static argument). Its
    output is checked once, while tracing: anything but :class:`Forces` raises
    ``TypeError``, a force or torque not broadcastable to ``(*B, 3)`` ``ValueError``.
    With ``checked``, a failure raises ``ValueError`` when ``simulate`` is called
    eagerly; inside a caller's ``jax.jit`` it arrives wrapped in JAX's
    ``JaxRuntimeError`` (use ``equinox.filter_jit`` to unwrap it).
    """
    return run_simulation(
        state,
        forces,
        dt,
        steps,
        method,
        save_every=save_every,
        t0=t0,
        checked=checked,
        checkpoint=checkpoint,
        native=native,
    )


def run_simulation(
    state,
    forces,
    dt,
    steps,
    method,
    *,
    save_every,
    t0,
    checked,
    checkpoint=None,
    step_offset=0,
    native=None,
    warn_step_size=True,
):
    """``simulate`` after its signature.

    ``step_offset`` is the number of steps already done from ``t0`` (a chunked
    run): step ``k`` runs at ``t0 + (step_offset + k) dt``, and checked-mode
    errors count from it. ``warn_step_size=False``: the caller has given the
    :class:`StepSizeWarning` (or found none) for the whole run.
    """
    steps, save_every, method = check_run(state, dt, steps, method, save_every, t0, "simulate", warn_step_size=False)
    check_checkpoint(checkpoint, steps, save_every)
    force_fn = None
    state = _canonical(state)
    t0 = start_checks(state, dt, t0, "simulate", method, turn=warn_step_size)
    if isinstance(forces, Forces):
        forces = cast_forces(forces, state.dtype)
        series = is_time_series(forces, state, steps)
        if not series:
            batch_shape(state, forces)
    elif isinstance(forces, ForceModel):
        check_force_model(forces, state, "simulate")  # shapes and body indices, before they are traced
        _warn_below_order(method, forces)
        series, force_fn = False, None  # a pytree: its arrays are traced data, not static
    elif forces is None or callable(forces):
        series, force_fn, forces = False, forces, None
    else:
        raise TypeError(f"forces must be Forces, a callable (state, t) -> Forces, or None; got {type(forces)}")
    checks = _checked.resolve(checked, state)
    if checks is not None:
        dt, t0 = traced_step_size(dt, t0, "simulate")
        if isinstance(forces, ForceModel):  # traced body indices and coefficients, at run time
            forces = forces._run_time_checked(state, "simulate")
    # a force callable (force_fn) is not a force law the kernel knows: it names one, so pass it on
    native = _native.native_path(
        native,
        state,
        force_fn if force_fn is not None else forces,
        method,
        series=series,
        checked=checks is not None,
        checkpoint=checkpoint,
    )
    if not native and isinstance(forces, ForceModel):
        # concrete index-based models (one thruster per body) become per-body laws, lifted inside the step
        forces = with_per_body_terms(forces, state)
    out = _simulate(
        state,
        forces,
        _scalar(dt),
        _scalar(t0),
        _scalar(step_offset),
        steps=int(steps),
        method=method,
        save_every=int(save_every),
        series=series,
        force_fn=force_fn,
        checks=checks,
        checkpoint=None if checkpoint is None else int(checkpoint),
        native=native,
        sharded=bool(native and _native.sharded(state)),
    )
    if checks is None:
        return out
    traj, rec = out
    return _checked.raise_on_failure(
        traj,
        rec,
        checks,
        method=method,
        batch_shape=state.batch_shape,
        steps=int(steps),
        step_offset=step_offset,
    )


@functools.partial(
    jax.jit,
    static_argnames=(
        "steps",
        "method",
        "save_every",
        "series",
        "force_fn",
        "checks",
        "checkpoint",
        "native",
        "sharded",
    ),
)
def _simulate(
    state, forces, dt, t0, k0, *, steps, method, save_every, series, force_fn, checks, checkpoint, native, sharded=False
):
    step_fn = method.step(type(state))
    dtype = state.dtype
    dt, t0 = dt.astype(dtype), t0.astype(dtype)
    n_out = steps // save_every
    # Inside the scan the state is carried batch-last ((3, N) per field: one
    # contiguous row per component), transposed once at each end and marked so
    # in its treedef (rbjax._batching.to_batch_last), which the step's lifted
    # kernels read; they then compile to one vectorised loop over the batch. Steps
    # that are not layout-agnostic (a user's step or Scene kernel) and force
    # callables see the usual batch-first layout.
    # the native kernel reads the batch-first layout itself: no transposes at either end
    soa = not native and method.layout_agnostic
    to_soa = to_batch_last if soa else (lambda x: x)
    to_aos = to_batch_first if soa else (lambda x: x)

    initial = state
    dyn0, consts = split_constants(state)
    consts_soa = {k: to_soa(v) for k, v in consts.items()}
    if "body" in consts_soa:
        # the inverse inertia (and the principal frame, for the methods that turn about it), once per
        # call, in the scan's layout (contiguous rows per component); the native kernels take their frame
        # themselves, and their JAX reference is only differentiated
        principal = method.principal_frame and not native
        consts_soa["body"] = lift(lambda b: prepare(b, principal))(consts_soa["body"])
    # checked mode reads the batch-first state: its body prepared once too (|ω| and the energy at each frame)
    consts_checked = consts
    if checks is not None and "body" in consts:
        consts_checked = {**consts, "body": lift(prepare)(consts["body"])}
    # the time rides outside the carry too: one scalar per step, not one per body
    # wrapped here, not by the caller: force_fn is static, and a new wrapper per call would recompile;
    # it checks the callable's output while tracing and casts it to the state's dtype
    user_fn = checked_force_fn(force_fn if force_fn is not None else as_force_fn(forces))

    step_forces = step_force_fn(forces, user_fn, consts, series=series, soa=soa)

    # the checked-mode record rides in the carry; None (an empty pytree) when off
    def one(carry, k_and_f):
        dyn, rec = carry
        k, f = k_and_f
        s = replace(dyn, **consts_soa)
        new = split_constants(step_fn(s, step_forces(f), t0 + (k0 + k).astype(dtype) * dt, dt))[0]
        if soa:
            # a layout-agnostic step returns the layout it was given: the carry's treedef says so
            new = with_layout(new, True)
        if checks is not None:
            rec = _checked.after_step(rec, replace(to_aos(new), **consts_checked), k + 1, checks, steps)
        return (new, rec), None

    # checkpoint segments inside a saved chunk, or whole chunks grouped into segments
    inner = checkpoint if checkpoint is not None and checkpoint < save_every else None
    outer = checkpoint // save_every if checkpoint is not None and checkpoint >= save_every else None

    def advance_jax(carry, xs):
        (dyn, rec), _ = checkpointed_scan(one, carry, xs, inner)
        if checks is not None:
            rec = _checked.after_save(rec, replace(to_aos(dyn), **consts_checked), xs[0][-1] + 1, checks, steps, dt)
        return dyn, rec

    if native:
        # the steps between two saved frames in one kernel call; derivatives from the JAX steps
        assert method.native_code is not None  # native_path takes only a method with a kernel
        advance = _native.frames_advance(
            step_fn,
            method.native_code,
            save_every,
            series,
            force_fn,
            user_fn,
            sharded,
            consts_soa,
            consts,
            forces,
            dt,
            t0,
            k0,
        )
    else:
        advance = advance_jax

    ks = jnp.arange(steps).reshape(n_out, save_every)
    rec0 = None if checks is None else _checked.init_record(state, checks)
    carry0 = (to_soa(dyn0), rec0)
    fs = jax.tree.map(lambda a: a.reshape((n_out, save_every) + a.shape[1:]), forces) if series else None
    if outer is None:
        traj, rec = frames_in_buffer(advance, carry0, (ks, fs), dyn0, to_aos)
    else:
        traj, rec = frames_as_outputs(advance, carry0, (ks, fs), dyn0, to_aos, outer)
    # t0 + (absolute step) dt, as the steps saw it: a chunked run gives the same bits
    times = t0 + (k0 + save_every * jnp.arange(n_out + 1)).astype(dtype) * dt
    traj = stack_frames(traj, initial, times)
    return traj if checks is None else (traj, rec)
