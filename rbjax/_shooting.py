"""Multiple shooting and truncated gradients: tools for fitting sensitive trajectories.

Near a separatrix the derivative of a long trajectory with respect to its
initial state or parameters grows by orders of magnitude (see docs/gradients.md,
"Sensitivity of long trajectories"), and a loss on the whole trajectory becomes
rugged. Two standard remedies, both built on :func:`rbjax.step` /
:func:`rbjax.simulate`:

* :func:`shoot` integrates ``S`` segments from ``S`` independent start states
  in parallel (``vmap`` over segments, one ``lax.scan`` of ``steps`` steps
  each), and :func:`defects` measures how far each segment's end is from the
  next segment's start. Fitting the starts as free parameters with the
  defects as extra residuals (or constraints) keeps every simulation short.
* :func:`simulate_truncated` runs one trajectory but cuts the derivative at
  every ``truncate_every`` steps (``lax.stop_gradient`` on the state carried
  between chunks): each chunk's gradient is exact with respect to everything
  but the chunk's start, and nothing flows across a cut. Biased, but bounded.

:func:`rbjax.fit_inertia` shoots the same way, with the step functions of
:func:`rbjax.step`, but carries forward sensitivities through its own scan
(:mod:`rbjax.identification._model`): its solver needs the Jacobian, not just the states.
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any, cast

import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from . import _methods
from ._batching import batch_shape, in_axes_of
from ._math import quat_conjugate, quat_log, quat_multiply
from ._methods import DEFAULT_METHOD, AbstractMethod
from ._pytree import replace
from ._simulate import prepare_state, run_simulation, simulate
from ._state import AnyState, ForceLike, Forces, State, split_constants
from ._trajectory import stack_frames
from ._typing import ArrayLike
from ._validate import as_force_fn, check_dt, check_state, start_time, warn_turn_per_step

__all__ = ["shoot", "defects", "simulate_truncated"]


def _scan_segment(state: Any, force_fn: Callable, dts: Array, t0: Array, method: AbstractMethod) -> Any:
    """One segment: ``dts`` ``(n_save, save_every)`` per-step sizes; frames after each row.

    Returns the trajectory with a leading time axis of ``n_save + 1`` (initial
    state first). A step with ``dt = 0`` leaves the state unchanged (padding).
    The body's inverse inertia (and principal frame, for a method that turns
    about it) is computed once, before the loops, as ``simulate`` does.
    """
    step_fn = method.step(type(state))
    dyn0, consts = split_constants(prepare_state(state, method.principal_frame))

    def sub(carry, dt):
        dyn, t = carry
        new = step_fn(replace(dyn, **consts), force_fn, t, dt)
        return (split_constants(new)[0], t + dt), None

    def row(carry, dts_row):
        carry, _ = jax.lax.scan(sub, carry, dts_row)
        return carry, carry

    _, (frames, times) = jax.lax.scan(row, (dyn0, t0), dts)
    traj = jax.tree.map(lambda a0, a: jnp.concatenate([a0[None], a]), dyn0, frames)
    return replace(traj, **{**consts, "time": jnp.concatenate([t0[None], times])})


def shoot(
    starts: AnyState,
    forces: ForceLike,
    dt: Float[ArrayLike, ""] | Float[ArrayLike, "S steps"],
    steps: int,
    method: str | AbstractMethod | Callable[..., Any] = DEFAULT_METHOD,
    *,
    save_every: int | None = None,
    t0: Float[ArrayLike, ""] | Float[ArrayLike, " S"] | None = None,
) -> tuple[AnyState, AnyState]:
    """Simulate ``S`` segments from ``S`` start states in parallel (multiple shooting).

    Segment ``s`` integrates ``x_s(t)`` from ``x_s(t_s) = starts[s]`` over
    ``steps`` steps of ``method`` (world-frame Newton–Euler equations, as
    :func:`rbjax.simulate`); segments are independent, so the work is one
    ``lax.scan`` of ``steps`` steps ``vmap``-ped over segments (depth ``steps``,
    not ``S·steps``).

    Args:
        starts: start states with a leading segment axis: batch shape ``(S, *B)``
            (fields without it, e.g. one shared ``Body``, are shared).
        forces: world-frame forces as for :func:`rbjax.simulate` (``None``, a
            constant :class:`rbjax.Forces`, or a callable ``(state, t) -> Forces``
            that sees one segment's ``(*B)`` state and the absolute time ``t`` in s).
        dt: step (s): a scalar, or ``(S, steps)`` per-segment per-step sizes
            (irregular sampling; ``dt = 0`` steps are no-ops, for padding).
        steps: steps per segment (static).
        method: integrator name, ``Method`` (see :func:`rbjax.methods`) or hashable batch step
            ``(state, force_fn, t, dt) -> state``, as in :func:`rbjax.simulate`; default ``"splitting"``,
            the house default.
        save_every: keep every ``save_every``-th state (must divide ``steps``);
            default ``steps``: start and end only.
        t0: scalar start time of segment 0, the segments tiling
            ``[t0, t0 + Σ dt]`` back to back; or ``(S,)`` start times (s).
            Default ``None``: segment 0's ``starts.time`` (one clock for its
            bodies), tiled as a scalar ``t0`` is.

    Returns:
        ``(trajectories, ends)``: trajectories with leading axes
        ``(steps // save_every + 1, S, *B)`` (time first, as
        :func:`rbjax.simulate`, every leaf; ``time`` is ``(T, S, 1, ...)``, each
        segment's own) and the end states ``(S, *B)``.
    """
    save_every = steps if save_every is None else save_every
    if not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"shoot: steps must be a positive int, got {steps!r}")
    if not isinstance(save_every, (int, np.integer)) or save_every < 1 or steps % save_every:
        raise ValueError(f"shoot: save_every must be a positive int dividing steps={steps}, got {save_every!r}")
    bshape = batch_shape(starts)
    if not bshape:
        raise ValueError("shoot: starts need a leading segment axis (batch shape (S, *B))")
    S, nd = bshape[0], len(bshape)
    resolved = _methods.resolve(method, "shoot")
    resolved.step(type(starts))  # ValueError now for a state type the method has no step for
    _methods.check_rotors(resolved, starts, "shoot")  # ValueError for a gyrostat the method would not turn
    dtype = starts.dtype
    dt = jnp.asarray(dt, dtype)
    if dt.ndim == 0:
        d = np.asarray(dt) if not isinstance(dt, jax.core.Tracer) else None
        if d is not None and not (np.isfinite(d) and d > 0):
            raise ValueError(f"shoot: dt must be finite and > 0, got {d}")
        dts = jnp.broadcast_to(dt, (S, steps))
    elif dt.shape == (S, steps):
        dts = dt
    else:
        raise ValueError(f"shoot: dt must be a scalar or (S, steps) = {(S, steps)}, got {dt.shape}")
    t0 = jnp.asarray(_first_segment_time(starts) if t0 is None else t0, dtype)
    if t0.ndim == 0:
        t0 = t0 + jnp.concatenate([jnp.zeros(1, dtype), jnp.cumsum(dts.sum(-1))[:-1]])
    elif t0.shape != (S,):
        raise ValueError(f"shoot: t0 must be a scalar or (S,) = {(S,)}, got {t0.shape}")
    force_fn = as_force_fn(forces)
    n_save = steps // save_every
    run = lambda s, d, t: _scan_segment(s, force_fn, d.reshape(n_save, save_every), t, resolved)
    traj = jax.vmap(run, in_axes=(in_axes_of(starts, 0, nd, last=False), 0, 0))(starts, dts, t0)
    consts = starts.constant_fields
    # vmap put segments first; time leads in rbjax trajectories
    moved = {
        n: jax.tree.map(lambda a: jnp.moveaxis(a, 1, 0), getattr(traj, n))
        for n in type(traj)._rbjax_data_fields
        if n not in consts
    }
    times = jnp.moveaxis(traj.time, 1, 0)  # (T, S)
    frames = replace(traj, **moved, **{n: None for n in consts})
    ends = replace(jax.tree.map(lambda a: a[-1], frames), **{n: getattr(starts, n) for n in consts if n != "time"})
    ends = replace(ends, time=times[-1].reshape(times.shape[1:] + (1,) * (nd - 1)))
    return stack_frames(frames, starts, times.reshape(times.shape + (1,) * (nd - 1))), ends


def _first_segment_time(starts: AnyState) -> Array:
    """Segment 0's one clock (s), read as :func:`start_time` reads a batch's."""
    return start_time(SimpleNamespace(time=starts.time[0]))  # pyright: ignore[reportArgumentType]  (reads .time only)


def defects(ends: State, starts: State) -> Float[Array, "S-1 *B 12"]:
    """Mismatch between each segment's end and the next segment's start.

    For segments ``s = 0 .. S-2``: ``[p_{s+1} - p_s(end), v_{s+1} - v_s(end),
    log(q_s(end)⁻¹ ⊗ q_{s+1}), L_{s+1} - L_s(end)]`` — position (m), velocity
    (m/s), the rotation vector from the end orientation to the next start in
    the end's body frame (rad; sign-insensitive in ``q``), angular momentum
    (world, kg m²/s). All zero for a continuous trajectory.

    Args:
        ends: end states ``(S, *B)`` (e.g. from :func:`shoot`).
        starts: start states ``(S, *B)``.

    Returns:
        ``(S - 1, *B, 12)``.
    """
    if not (isinstance(ends, State) and isinstance(starts, State)):
        raise ValueError("defects: ends and starts must be rbjax.State (quaternion form)")
    if batch_shape(ends)[:1] != batch_shape(starts)[:1]:
        raise ValueError(f"defects: segment counts differ: {batch_shape(ends)} vs {batch_shape(starts)}")
    e = lambda a: a[:-1]
    n = lambda a: a[1:]
    rot = quat_log(quat_multiply(quat_conjugate(e(ends.orientation)), n(starts.orientation)))
    return jnp.concatenate(
        [
            n(starts.position) - e(ends.position),
            n(starts.velocity) - e(ends.velocity),
            rot,
            n(starts.angular_momentum) - e(ends.angular_momentum),
        ],
        -1,
    )


def simulate_truncated(
    state: AnyState,
    forces: ForceLike,
    dt: Float[ArrayLike, ""],
    steps: int,
    method: str | AbstractMethod | Callable[..., Any] = DEFAULT_METHOD,
    *,
    truncate_every: int,
    save_every: int = 1,
    t0: Float[ArrayLike, ""] | None = None,
) -> AnyState:
    """:func:`rbjax.simulate` with the derivative cut every ``truncate_every`` steps.

    Values equal ``simulate(state, forces, dt, steps, method, save_every=...)``.
    Derivatives: the trajectory is run in ``steps / truncate_every`` chunks and
    the state carried into each chunk after the first passes through
    ``lax.stop_gradient`` (the dynamic fields only; the ``Body`` and other
    parameters keep their derivatives). So ``∂x(t)/∂x(t')`` is exactly zero
    when a cut lies between ``t'`` and ``t``, and the gradient of a loss
    summed over chunks is the sum of each chunk's gradient taken from its
    (fixed) start: bounded however unstable the motion, at the price of
    ignoring how earlier chunks steer later ones.

    Args:
        state: initial state (any batch shape).
        forces: ``None``, a constant :class:`rbjax.Forces`, a callable
            ``(state, t) -> Forces`` (absolute time, s), or time-series
            :class:`rbjax.Forces` with a leading ``(steps, ...)`` axis.
        dt: step (s), > 0.
        steps: total steps (static), a multiple of ``truncate_every``.
        method: integrator name, ``Method`` (see :func:`rbjax.methods`) or hashable batch
            step ``(state, force_fn, t, dt) -> state``, as in :func:`rbjax.simulate`; default
            ``"splitting"``, the house default.
        truncate_every: chunk length in steps (static); must be a multiple of ``save_every``.
        save_every: keep every ``save_every``-th state.
        t0: start time (s); default ``state.time``.

    Returns:
        Trajectory as :func:`rbjax.simulate`: leading time axis
        ``steps // save_every + 1`` on every leaf.
    """
    check_state(state, "simulate_truncated")
    check_dt(dt)
    if t0 is not None:
        check_dt(t0, "t0", positive=False)
    k = truncate_every
    if not isinstance(k, (int, np.integer)) or k < 1 or steps % k or k % save_every:
        raise ValueError(
            f"simulate_truncated: truncate_every={k!r} must be a positive int dividing steps={steps} "
            f"and a multiple of save_every={save_every}"
        )
    warn_turn_per_step(state, dt, "simulate_truncated", _methods.resolve(method, "simulate_truncated"))
    n_chunks = steps // k
    const_vals = split_constants(state)[1]
    series = isinstance(forces, Forces) and any(
        a is not None and a.ndim >= 2 and a.shape[0] == steps and a.ndim - 1 > len(state.batch_shape)
        for a in (forces.force, forces.torque)
    )
    fs = jax.tree.map(lambda a: a.reshape((n_chunks, k) + a.shape[1:]), forces) if series else None
    dtype = state.dtype
    t0 = start_time(state) if t0 is None else jnp.asarray(t0, dtype)

    def chunk(dyn, xs):
        i, f = xs
        s = replace(jax.lax.stop_gradient(dyn), **const_vals)
        traj = simulate(s, f if series else forces, dt, k, method, save_every=save_every, t0=t0 + i * k * dt)
        traj = split_constants(traj)[0]
        return jax.tree.map(lambda a: a[-1], traj), jax.tree.map(lambda a: a[1:], traj)

    # the first chunk starts from the caller's state, with its derivatives
    f0 = jax.tree.map(lambda a: a[0], fs) if series else forces
    first = run_simulation(state, f0, dt, k, method, save_every=save_every, t0=t0, checked=False, warn_step_size=False)
    first = split_constants(first)[0]
    carry = jax.tree.map(lambda a: a[-1], first)
    rest_f = jax.tree.map(lambda a: a[1:], fs) if series else None
    _, rest = jax.lax.scan(chunk, carry, (jnp.arange(1, n_chunks, dtype=dtype), rest_f))
    rest = jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), rest)
    traj = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), first, rest)
    # check_dt passed: dt is a real scalar (the cast is for the type checker)
    times = t0 + (save_every * jnp.arange(steps // save_every + 1)).astype(dtype) * cast(Array, dt)  # as simulate's
    return stack_frames(traj, state, times)
