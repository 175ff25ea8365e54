"""The native kernels' call: operands packed from the state and forces, the FFI call, its JVP.

See :mod:`rbjax._native` for what the kernels compute.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental.xla_metadata import set_xla_metadata

from .._pytree import replace
from .._state import Forces, State, split_constants
from .._validate import as_force_fn, checked_force_fn
from ._laws import LAWS
from ._load import METHODS, TARGET
from ._plan import native_terms

__all__ = ["advance", "frames_advance"]


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

    for term in native_terms(forces) or ():
        LAWS[type(term)](term, add, n, dtype)
    rows = max(acc[k].shape[0] for k in ("b", "br", "c", "cr"))
    drag = jnp.concatenate([jnp.broadcast_to(acc[k], (rows, 1)) for k in ("b", "br", "c", "cr")], axis=1)
    terms = (1 if used else 0) | (2 if used & {"c", "cr"} else 0) | (4 if "thrust" in used else 0)
    terms |= 8 if "tau" in used else 0
    return {"F": acc["F"], "tau": acc["tau"], "g": acc["g"], "drag": drag, "thrust": acc["thrust"]}, terms


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
    the laws of ``LAWS``, or with ``series`` a :class:`Forces` of fields ``(steps, *B', 3)``,
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
    call = jax.ffi.ffi_call(TARGET, results, vmap_method="broadcast_all", input_output_aliases={0: 0, 1: 1, 2: 2, 3: 3})
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
    if series or (force_fn is None and native_terms(forces) is not None):
        return _call(code, steps, dyn, body, forces, dt, series, sharded)
    fn = force_fn if force_fn is not None else checked_force_fn(forces)

    def one(d: State, t: jax.Array) -> tuple[State, None]:
        f = fn(replace(d, **{**consts, "time": t}), t)
        return _call(code, 1, d, body, f, dt, sharded=sharded), None

    return jax.lax.scan(one, dyn, ts)[0]


@advance.defjvp
def _advance_jvp(code, steps, reference, series, force_fn, sharded, primals, tangents):
    return jax.jvp(reference, primals, tangents)


def frames_advance(
    step_fn: Callable[..., Any],
    code: int,
    save_every: int,
    series: bool,
    force_fn: Callable[[Any, Any], Forces] | None,
    user_fn: Callable[[Any, Any], Forces],
    sharded: bool,
    consts_soa: dict[str, Any],
    consts: dict[str, Any],
    forces: Any,
    dt: jax.Array,
    t0: jax.Array,
    k0: jax.Array,
) -> Callable[[Any, Any], Any]:
    """``advance(carry, xs) -> carry``: the steps between two saved frames of ``simulate``'s scan in one
    kernel call (see :func:`advance`), for the method numbered ``code`` whose JAX step ``step_fn`` is the
    reference its derivatives come from.

    ``carry`` is ``(dyn, record)`` (the stripped batch-first state, the checked-mode
    record, passed on) and ``xs`` is ``(ks (save_every,), fs)``: the steps' numbers
    from ``k0`` and, with ``series``, their forces ``(save_every, *B, 3)``. Step ``k``
    starts at ``t0 + (k0 + k) dt`` (s), as the JAX path's steps do. ``force_fn`` is
    the user's callable (``None`` for forces the kernel may know), ``user_fn`` its
    checked form or that of ``forces``; ``consts_soa`` the constant fields with the
    prepared body, ``consts`` the unprepared ones (the force models see those).
    """
    dtype = dt.dtype

    # a force law the kernel does not know: XLA evaluates it at each step's start, one call per step
    def reference(dyn, cs_soa, cs, frc, h, ts):
        # frc: None, constant Forces, a force model, or a time series' chunk (save_every, *B, 3)
        frc_fn = user_fn if force_fn is not None else checked_force_fn(as_force_fn(None if series else frc))

        def one_step(d, t_and_f):  # batch-first, as the kernel's state
            tt, f = t_and_f
            if series:
                fn = lambda s, _: f
            else:
                fn = lambda s, t: frc_fn(replace(split_constants(s)[0], **{**cs, "time": t}), t)
            return split_constants(step_fn(replace(d, **cs_soa), fn, tt, h))[0], None

        return jax.lax.scan(one_step, dyn, (ts, frc if series else None))[0]

    def advance_native(carry, xs):
        dyn, rec = carry
        ks, fs = xs
        ts = t0 + (k0 + ks).astype(dtype) * dt  # each step's start time, as the JAX steps see it
        new = advance(
            code,
            save_every,
            reference,
            series,
            user_fn if force_fn is not None else None,
            sharded,
            dyn,
            consts_soa,
            consts,
            fs if series else forces,
            dt,
            ts,
        )
        return new, rec

    return advance_native
