"""Checked mode for ``simulate``: runtime sanity checks that work under ``jit``.

With ``checked=True`` (or a :class:`Checks`) the scan carries a small record of
the first failure: the step, the body's flat batch index and what went wrong.
Each step tests every body for a non-finite state and for an orientation off
the unit sphere (``|‖q‖ - 1|``, or ``max |RᵀR - 1|`` for a rotation matrix);
each saved frame tests for a rate the steps cannot follow (``dt·|ω| > π``) and
for an energy jump. After the scan, called eagerly (the
usual case: ``simulate`` is compiled inside), the record is read on the host and
a plain ``ValueError`` carries rbjax's message. Traced by a caller's ``jax.jit``
the record is a tracer, so a single :func:`equinox.error_if` raises at run time
instead; JAX then wraps the message in a ``JaxRuntimeError`` (``CpuCallback
error``), so the message repeats itself on one line at its end and names the
remedy (call ``simulate`` outside ``jax.jit``, or use ``equinox.filter_jit``,
which unwraps it). The step and body reach the message through equinox's
message index: the messages are a lazy sequence that formats the one it is
asked for, so the run costs one integer, not one string per step.

Off (the default) none of this is traced: the compiled program is the one
without checks.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import equinox as eqx
import jax
import jax.core
import jax.numpy as jnp
import numpy as np

from ._math import index_tuple, quat_tolerance
from ._methods import AbstractMethod
from ._pytree import core_ndim_of
from ._quantities import body_angular_velocity, kinetic_energy
from ._state import MatrixState, State

__all__ = ["Checks", "resolve", "init_record", "after_step", "after_save", "raise_on_failure"]

_KINDS = ("non_finite", "orientation", "energy", "turn")


@dataclasses.dataclass(frozen=True)
class Checks:
    """What ``simulate(..., checked=Checks(...))`` tests, and how strictly.

    Attributes:
        energy_factor: fail when a body's kinetic energy ``½ m ‖v‖² + ½ ω·L``
            (J) at a saved frame exceeds ``energy_factor`` times the largest
            value it had at any earlier saved frame (the initial state included).
            The running maximum, not the previous frame, so a body passing
            through rest (a ball at the top of its arc) is not flagged.
            ``None`` turns the energy check off.
        energy_floor: ignore energy jumps while that running maximum is at or
            below this (J). The default 0 skips bodies that start exactly at rest;
            raise it when bodies start almost at rest and are then driven hard.
        quat_tol: fail when ``|‖q‖ - 1|`` (``State``) or ``max |RᵀR - 1|``
            (``MatrixState``) exceeds this; ``None`` means
            :func:`rbjax._state.quat_tolerance` of the state's dtype (``1e-6`` in
            float64, ``~1.5e-5`` in float32), the tolerance applied to inputs.
        max_turn: fail when a body's ``dt·|ω|`` (rad per step, ``ω`` at a saved
            frame) exceeds this. The default ``π``: a step that turns a body by
            more than half a turn no longer follows its attitude, whatever the
            method (see :class:`rbjax.StepSizeWarning`, which tests the start
            state of an eager run; this tests every saved frame, also under
            ``jit``, so it sees a body that torques spin up). ``None`` turns it
            off, for a study of the methods themselves at such steps.

    Non-finite states (any NaN or inf in a changing field) always fail.
    ``checked=True`` means ``Checks()``. Hashable: it is part of the compiled
    program.
    """

    energy_factor: float | None = 100.0
    energy_floor: float = 0.0
    quat_tol: float | None = None
    max_turn: float | None = math.pi

    def __post_init__(self) -> None:
        if self.energy_factor is not None and not self.energy_factor > 1:
            raise ValueError(f"Checks: energy_factor must be > 1 or None, got {self.energy_factor}")
        if not self.energy_floor >= 0:
            raise ValueError(f"Checks: energy_floor must be >= 0, got {self.energy_floor}")
        if self.quat_tol is not None and not self.quat_tol > 0:
            raise ValueError(f"Checks: quat_tol must be > 0 or None, got {self.quat_tol}")
        if self.max_turn is not None and not (self.max_turn > 0 and math.isfinite(self.max_turn)):
            raise ValueError(f"Checks: max_turn must be finite and > 0 (rad per step) or None, got {self.max_turn}")


def resolve(checked: bool | Checks, state: Any) -> Checks | None:
    """``None`` when off; otherwise a :class:`Checks` with the tolerance filled in."""
    if checked is False or checked is None:
        return None
    if checked is True:
        checked = Checks()
    if not isinstance(checked, Checks):
        raise TypeError(f"checked must be a bool or rbjax.Checks, got {type(checked)}")
    tol = checked.quat_tol if checked.quat_tol is not None else quat_tolerance(state.dtype)
    turn = None if checked.max_turn is None else float(checked.max_turn)
    return dataclasses.replace(checked, quat_tol=float(tol), energy_floor=float(checked.energy_floor), max_turn=turn)


def _index_dtype() -> Any:
    return jnp.int64 if jax.config.read("jax_enable_x64") else jnp.int32


def _encodes_body(steps: int, n_bodies: int) -> bool:
    """Whether ``(step, body, kind)`` fits the index integer (int32 without x64)."""
    limit = np.iinfo(np.int64 if jax.config.read("jax_enable_x64") else np.int32).max
    return (steps + 1) * max(n_bodies, 1) * len(_KINDS) < limit


def init_record(state: Any, checks: Checks) -> dict[str, Any]:
    """Empty failure record; ``emax`` starts at the initial kinetic energy per body."""
    energy = jnp.broadcast_to(kinetic_energy(state), state.batch_shape)
    return {
        "failed": jnp.zeros((), bool),
        "code": jnp.zeros((), _index_dtype()),
        "emax": energy,
        # |ω| per body at the start and then at each saved frame up to the failure, and dt (set at
        # the saved frames, which follow a failure too): the message blames the rotation only
        # where dt·|ω| was large
        "rate": _rate(state, energy.dtype),
        "dt": jnp.full((), jnp.nan, energy.dtype),
    }


def _rate(state: Any, dtype: Any) -> jax.Array:
    """``|ω|`` per body (rad/s); NaN for particles."""
    if isinstance(state, (State, MatrixState)):
        rate = jnp.linalg.norm(body_angular_velocity(state), axis=-1)  # body frame: the same norm
        return jnp.broadcast_to(rate, state.batch_shape).astype(dtype)
    return jnp.full(state.batch_shape, jnp.nan, dtype)


def _per_body_any(x: Any, core: int, batch: tuple[int, ...]) -> jax.Array:
    return jnp.broadcast_to(jnp.any(x, axis=tuple(range(x.ndim - core, x.ndim))), batch)


def _record(rec: dict, bad_kind: jax.Array, step: Any, steps: int) -> dict:
    """Record the first failing body (flat index) if nothing failed before.

    ``bad_kind``: ``(*B,)`` int, ``len(_KINDS)`` where the body is sound.
    """
    flat = bad_kind.reshape(-1)
    n = flat.shape[0]
    bad = flat < len(_KINDS)
    body = jnp.argmax(bad)
    idt = rec["code"].dtype
    step = jnp.asarray(step).astype(idt)
    with_body = _encodes_body(steps, n)
    where = step * n + body.astype(idt) if with_body else step
    code = where * len(_KINDS) + flat[body].astype(idt)
    new = jnp.any(bad) & ~rec["failed"]
    return {
        **rec,
        "failed": rec["failed"] | new,
        "code": jnp.where(new, code, rec["code"]),
    }


def after_step(rec: dict, state: Any, step: Any, checks: Checks, steps: int) -> dict:
    """Test the state reached by step number ``step`` (1-based) for every body."""
    assert checks.quat_tol is not None  # resolve() fills it in
    batch = state.batch_shape
    consts = state.constant_fields
    cores = core_ndim_of(state)
    nonfinite = jnp.zeros(batch, bool)
    for name in type(state)._rbjax_data_fields:
        if name in consts or getattr(state, name) is None:
            continue
        nonfinite = nonfinite | _per_body_any(~jnp.isfinite(getattr(state, name)), cores[name], batch)
    if isinstance(state, State):
        q = state.orientation
        off = jnp.abs(jnp.sqrt(jnp.sum(q * q, axis=-1)) - 1) > checks.quat_tol
    elif isinstance(state, MatrixState):
        R = state.rotation
        gram = jnp.swapaxes(R, -1, -2) @ R - jnp.eye(3, dtype=R.dtype)
        off = jnp.max(jnp.abs(gram), axis=(-1, -2)) > checks.quat_tol
    else:
        off = jnp.zeros(batch, bool)
    kind = jnp.where(nonfinite, 0, jnp.where(off, 1, len(_KINDS)))
    return _record(rec, kind, step, steps)


def after_save(rec: dict, state: Any, step: Any, checks: Checks, steps: int, dt: Any) -> dict:
    """Test the saved frame at step ``step`` for a turn past ``max_turn`` per step of ``dt`` and
    for an energy jump; update the running maximum."""
    if isinstance(state, (State, MatrixState)):
        # a failure in the steps before this frame keeps the last sound frame's rate
        rate = _rate(state, rec["rate"].dtype)
        rec = {**rec, "rate": jnp.where(rec["failed"], rec["rate"], rate)}
    rec = {**rec, "dt": jnp.asarray(dt).astype(rec["dt"].dtype)}
    if checks.max_turn is not None and isinstance(state, (State, MatrixState)):
        # at the saved frames, not every step: |ω| costs a rotation and a matvec per body (measured,
        # benchmarks/checked_cost.py: every step took a quarter to a third of the checked run's rate)
        turn = dt * jnp.linalg.norm(body_angular_velocity(state), axis=-1)  # body frame: the same norm
        fast = jnp.broadcast_to(turn > jnp.asarray(checks.max_turn, turn.dtype), state.batch_shape)
        rec = _record(rec, jnp.where(fast, 3, len(_KINDS)), step, steps)
    if checks.energy_factor is None:
        return rec
    energy = jnp.broadcast_to(kinetic_energy(state), state.batch_shape)
    emax = rec["emax"]
    floor = jnp.asarray(checks.energy_floor, emax.dtype)
    jump = (emax > floor) & (energy > jnp.asarray(checks.energy_factor, emax.dtype) * emax)
    rec = _record(rec, jnp.where(jump, 2, len(_KINDS)), step, steps)
    return {**rec, "emax": jnp.maximum(emax, energy)}


def _advice(method: AbstractMethod, state_type: str, turn: float | None) -> str:
    """What to try: the method's rotation limit for ``state_type`` only where the rotation can be to blame.

    ``turn``: the failing body's ``dt·|ω|``, ``ω`` at the start or the last
    saved frame before the failure; ``None`` or NaN where it is not known (a
    run inside a caller's ``jit``; particles). A run diverges from a
    step too coarse for the rotation (``dt·|ω|`` near the method's measured
    limit for this state type) or for a force law (a spring's
    ``dt·sqrt(k/m)``, which the rotation limit says nothing about).
    """
    note = f" ({method.failure_note})" if method.failure_note else ""
    limit = (method.stable_dt_omega or {}).get(state_type, math.inf)
    force = (
        "a force law may be too stiff for dt (a spring of stiffness k on mass m needs dt·sqrt(k/m) well "
        "below 1 with an explicit method): take a smaller dt"
    )
    rotation = (
        f"Method {method.name!r} diverges beyond dt·|ω| ≈ {limit:g} for {state_type} (measured, 1000 "
        'torque-free steps; see rbjax.methods()): keep dt·|ω| well below that, or use "splitting" (stable at any dt)'
    )
    turn = turn if turn is not None and math.isfinite(turn) else None
    if not math.isfinite(limit) or state_type == "ParticleState":
        measured = f"dt·|ω| = {turn:.3g} before the failure; " if turn is not None and turn > 0 else ""
        return f"Method {method.name!r}{note}: {measured}{force}, or use a more stable method"
    if turn is None:
        return f"{rotation}; if dt·|ω| was well below that, {force}"
    if turn >= 0.5 * limit:
        return f"dt·|ω| = {turn:.3g} before the failure. {rotation}"
    return (
        f"dt·|ω| = {turn:.3g} before the failure, well below where {method.name!r} diverges for "
        f"{state_type} (≈ {limit:g}): not the rotation; {force}"
    )


@dataclasses.dataclass(frozen=True)
class _Messages:
    """The error messages, one per possible index, formatted when asked for.

    Equinox picks ``msgs[index]`` on the host after the run; this sequence is
    hashable (equinox treats it as static) and never materialised.
    """

    method: AbstractMethod
    batch_shape: tuple[int, ...]
    steps: int
    step_offset: int
    checks: Checks
    state_type: str = "State"

    def __len__(self) -> int:
        return (self.steps + 1) * max(int(np.prod(self.batch_shape, dtype=np.int64)), 1) * len(_KINDS)

    def body_of(self, index: int) -> int | None:
        """The failing body's flat batch index encoded in ``index``; ``None`` where it is not recorded."""
        n = int(np.prod(self.batch_shape, dtype=np.int64))
        if not _encodes_body(self.steps, n):
            return None
        return (int(index) // len(_KINDS)) % max(n, 1)

    def __getitem__(self, index: int) -> str:
        return self.message(index)

    def message(self, index: int, turn: float | None = None) -> str:
        """The message of ``index``; ``turn``: the body's ``dt·|ω|`` before the failure, if known (:func:`_advice`)."""
        n = int(np.prod(self.batch_shape, dtype=np.int64))
        where, kind = divmod(int(index), len(_KINDS))
        if _encodes_body(self.steps, n):
            step, flat = divmod(where, max(n, 1))
            where_in_batch = index_tuple(np.unravel_index(flat, self.batch_shape))
            body = f"body {where_in_batch}" if self.batch_shape else "the body"
        else:
            step, body = where, "a body (index not recorded: steps x bodies overflows int32; enable x64)"
        step += self.step_offset
        # built per kind: a field that is None (energy_factor=None) is never formatted
        advice = f"{_advice(self.method, self.state_type, turn)}; see rbjax.Checks."
        if kind == 0:
            what = "the state became non-finite (NaN or inf)"
        elif kind == 1:
            what = f"the orientation left the unit sphere / SO(3) by more than quat_tol={self.checks.quat_tol:.3g}"
        elif kind == 2:
            what = (
                f"the kinetic energy jumped by more than energy_factor={self.checks.energy_factor:g} "
                "times its largest earlier saved value"
            )
        else:
            what = (
                f"dt·|ω| exceeded max_turn={self.checks.max_turn:.3g} rad per step: the steps are too coarse "
                "for its attitude (beyond π, half a turn, no method follows it)"
            )
            advice = "Take dt below π/|ω| at the fastest rate the body reaches; see rbjax.Checks."
        return (
            f"rbjax.simulate(checked=...): at step {step} (time t0 + {step}·dt), {body}"
            f"{' of batch shape ' + str(self.batch_shape) if self.batch_shape else ''}: {what}. {advice}"
        )


def raise_on_failure(
    traj: Any,
    rec: dict,
    checks: Checks,
    *,
    method: AbstractMethod,
    batch_shape: tuple[int, ...],
    steps: int,
    step_offset: int = 0,
) -> Any:
    """``traj`` unchanged, or an error naming the step and body.

    Concrete record (``simulate`` called eagerly): ``ValueError`` raised here.
    Traced (inside a caller's ``jit``): an equinox runtime error at run time,
    whose message ends with a one-line copy of rbjax's (see the module docstring).
    """
    state_type = type(traj).__name__
    msgs = _Messages(method, tuple(batch_shape), int(steps), int(step_offset), checks, state_type)
    failed, code = rec["failed"], rec["code"]
    if not isinstance(failed, jax.core.Tracer):
        if bool(failed):
            turns = (np.asarray(rec["rate"]) * np.asarray(rec["dt"])).reshape(-1)
            flat = msgs.body_of(int(code))
            if turns.size == 0:
                turn = None
            elif flat is None:  # the body is not recorded: the fastest, where the rotation is to blame
                turn = float(np.nanmax(turns)) if np.isfinite(turns).any() else None
            else:
                turn = float(turns[flat])
            raise ValueError(msgs.message(int(code), turn))
        return traj
    # msgs is a lazy, hashable stand-in for Sequence[str]: equinox only indexes it
    return eqx.branched_error_if(traj, failed, code, _Traced(msgs))  # pyright: ignore[reportArgumentType]


@dataclasses.dataclass(frozen=True)
class _Traced:
    """The messages for a run inside a caller's ``jit``: JAX prints a traceback
    before the message, so each also says how to get it as a plain error."""

    msgs: _Messages

    def __len__(self) -> int:
        return len(self.msgs)

    def __getitem__(self, index: int) -> str:
        return (
            f"\n\n{self.msgs[index]}\n(Under jax.jit this arrives wrapped in a JaxRuntimeError "
            "'CpuCallback error'; call rbjax.simulate outside jax.jit (it is compiled already) or use "
            "equinox.filter_jit to get it unwrapped.)\n"
        )
