"""The force function a time loop's steps call, built once per compiled run from what ``simulate`` was given.

``simulate`` takes forces as ``None``, constant or time-series :class:`rbjax.Forces`,
a callable ``(state, t) -> Forces`` or a force model; its steps call one
``force_fn(state, t) -> Forces`` (world frame, N and N m). This module builds that
function for the layout the steps run in (see :mod:`rbjax._batching`): batch-first
``(*B, 3)``, or batch-last ``(3, *B)`` (marked so) inside ``simulate``'s scan, where per-body
laws (:class:`rbjax.PerBodyForce`) are lifted inside the step and every other
model or callable, written batch-first, is handed a batch-first state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ._batching import to_batch_first, to_batch_last
from ._force_model import ForceModel, PerBodyForces, split_per_body
from ._pytree import replace
from ._state import Forces, split_constants
from ._validate import checked_force_fn

__all__ = ["ForceFn", "step_force_fn"]

#: ``(state, t) -> Forces``: world-frame forces (N) and torques about the centre of mass (N m) of every body.
ForceFn = Callable[[Any, Any], Forces]


def _same(x: Any) -> Any:
    return x


def step_force_fn(
    forces: Any, user_fn: ForceFn, consts: dict[str, Any], *, series: bool, soa: bool
) -> Callable[[Any], ForceFn]:
    """``step_forces(f) -> force_fn``: the steps' force function for the forces ``f`` of one step.

    Args:
        forces: a constant :class:`Forces` (fields ``(*B, 3)`` or broadcastable), a
            force model, or ``None`` / anything else (then ``user_fn`` alone is called).
        user_fn: ``(state, t) -> Forces`` on batch-first states, the checked and cast
            form of the user's callable or of ``forces`` (``rbjax._validate.checked_force_fn``).
        consts: the state's constant fields, batch-first and unprepared (a force
            callable sees those, with ``time = t``).
        series: the forces are a time series: ``f`` is step ``k``'s slice
            ``(*B, 3)``, held over the step's stages; otherwise ``f`` is ignored
            and one function serves every step.
        soa: the steps run in the batch-last layout (``simulate``'s scan): states
            and the returned forces are ``(3, *B)`` per vector field, marked batch-last.
    """
    to_soa = to_batch_last if soa else _same
    to_aos = to_batch_first if soa else _same

    def soa_forces_of(fn: ForceFn) -> ForceFn:
        def soa_forces(state: Any, t: Any) -> Forces:
            # force callables and models are batch-level code written batch-first: they are given a
            # batch-first state, and the batch's one clock as a scalar time (it broadcasts, and a
            # sharded batch needs no unsharded (N,) array beside its sharded fields)
            out = fn(replace(to_aos(split_constants(state)[0]), **{**consts, "time": t}), t)
            return to_soa(out)

        return soa_forces

    def batch_first_forces(state: Any, t: Any) -> Forces:
        return user_fn(replace(state, time=t), t)

    # per-body laws: each body's law lifted inside the step, in the scan's layout, so XLA fuses
    # it with the step; the other terms of a sum (springs, ...) through the batch-level path,
    # which transposes the batch around every call
    per_body, rest = split_per_body(forces) if soa and isinstance(forces, ForceModel) else ((), None)
    per_body_forces = PerBodyForces(tuple(to_soa(term) for term in per_body))

    # chosen once; time-series forces give one per step, from its slice
    if series:

        def step_forces(f: Any) -> ForceFn:
            f = to_soa(f)
            return lambda state, t: f

        return step_forces

    if isinstance(forces, Forces):
        const_forces = to_soa(forces)
        fn: ForceFn = lambda state, t: const_forces
    elif per_body and rest is None:
        fn = per_body_forces
    elif per_body and rest is not None:
        rest_forces = soa_forces_of(checked_force_fn(rest))
        fn = lambda state, t: per_body_forces(state, t) + rest_forces(state, t)
    else:
        fn = soa_forces_of(user_fn) if soa else batch_first_forces
    return lambda f: fn
