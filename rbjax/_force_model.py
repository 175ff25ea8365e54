"""The force-model protocol: ``model(state, t) -> Forces`` (world frame), ``+`` composes.

:class:`ForceModel` is the base of the models in :mod:`rbjax._forces` (laws per body and
prescribed loads) and :mod:`rbjax._attached` (springs and thrusters, which name bodies by
index); :class:`ForceSum` is what ``+`` builds. The checks of their fields are in
:mod:`rbjax._force_checks`. See :mod:`rbjax._forces` for the conventions every model follows.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.core
from jax import Array
from jaxtyping import Float

from ._batching import lift
from ._math import quat_rotate_inverse_unchecked
from ._pytree import pytree_dataclass, replace
from ._state import AnyState, Forces, State
from ._typing import ArrayLike

__all__ = ["ForceModel", "ForceSum"]


class ForceModel:
    """Base of force models: ``model(state, t) -> Forces`` (world frame), ``+`` composes.

    A model maps a state batch of shape ``B`` and a time ``t`` (s) to world-frame
    :class:`rbjax.Forces` (force ``(*B, 3)`` in N on the centre of mass, torque
    ``(*B, 3)`` in N m about it, either ``None`` when the model has none).
    """

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:  # pragma: no cover - abstract
        raise NotImplementedError

    def check(self, state: AnyState) -> None:
        """``ValueError`` naming the argument unless this model's arrays fit ``state``'s batch.

        Shapes are checked always (they are static), body indices against the
        batch size ``N`` when their values are concrete. Called by
        :func:`rbjax.simulate`, :func:`rbjax.step` and :class:`rbjax.Scene`
        before tracing, and by each model while it is traced.
        """

    # fields holding body indices, and coefficients that must be >= 0 (see _run_time_checked)
    _INDEX_FIELDS: tuple[str, ...] = ()
    _NON_NEGATIVE: tuple[str, ...] = ()
    # how an error message names a field, where its name alone would mislead
    _FIELD_LABELS: dict[str, str] = {}

    def _run_time_checked(self, state: AnyState, fn: str) -> ForceModel:
        """This model with its *traced* indices and coefficients checked at run time (checked mode).

        Concrete values were checked already (construction, :meth:`check`); a value
        traced by a caller's ``jit`` gets an ``equinox`` run-time error carrying
        rbjax's ``(checked=...)`` message when it is an index outside ``[0, N)``
        or a negative coefficient. Without checked mode nothing is compiled.
        """
        import equinox as eqx

        changes = {}
        n = state.batch_shape[0] if len(state.batch_shape) == 1 else None
        for name in self._INDEX_FIELDS:
            i = getattr(self, name, None)
            if isinstance(i, jax.core.Tracer) and n is not None:
                label = self._FIELD_LABELS.get(name, name)
                msg = (
                    f"{fn}(checked=...): {type(self).__name__}: {label} holds an index outside "
                    f"the batch of {n} bodies (a traced index was; indices must be in 0..{n - 1})"
                )
                changes[name] = eqx.error_if(i, (i < 0) | (i >= n), msg)
        for name in self._NON_NEGATIVE:
            c = getattr(self, name, None)
            if isinstance(c, jax.core.Tracer):
                msg = f"{fn}(checked=...): {type(self).__name__}: {name} must be >= 0 (a traced value was negative)"
                changes[name] = eqx.error_if(c, c < 0, msg)
        return replace(self, **changes) if changes else self

    def as_per_body(self, state: AnyState) -> PerBodyForce | None:
        """This model as a :class:`PerBodyForce` on ``state``'s batch, or ``None`` when it is not one.

        A per-body law is its own; a model that names bodies by index may return an
        equivalent per-body law (the same formulas, so the same values) when its
        indices are concrete and name each body at most once (:class:`rbjax.Thruster`).
        """
        return None

    def __add__(self, other: ForceModel) -> ForceSum:
        if not isinstance(other, ForceModel):
            _refuse_sum(self, other)
            return NotImplemented
        a = self.terms if isinstance(self, ForceSum) else (self,)
        b = other.terms if isinstance(other, ForceSum) else (other,)
        return ForceSum(a + b)

    def __radd__(self, other: Any) -> ForceSum:
        _refuse_sum(other, self)
        return NotImplemented


def _refuse_sum(a: Any, b: Any) -> None:
    """``TypeError`` naming the remedy when a force model is added to a plain function or a ``Forces``."""
    other = b if isinstance(a, ForceModel) else a
    what = "Forces arrays" if type(other).__name__ == "Forces" else "a function" if callable(other) else None
    if what is None:
        return  # Python's own TypeError names the two types
    fix = "rb.ConstantForce(force=..., torque=...)" if what == "Forces arrays" else "rb.CustomForce(fn)"
    raise TypeError(
        f"cannot add {what} to a force model ({type(a).__name__} + {type(b).__name__}): wrap it as {fix}, "
        "which is a force model, and add that"
    )


class PerBodyForce(ForceModel):
    """A force law in which each body feels a force of its own state alone (gravity, drag, a constant load).

    Subclasses write :meth:`on_body` for one body; ``model(state, t)`` lifts it over the
    batch with ``vmap`` (``rbjax._batching.lift``), each array of the model mapped with the
    bodies where it is per body (its fields declare their per-body rank) and shared where
    it is not. ``simulate`` lifts :meth:`on_body` itself inside its steps, in the layout its
    scan carries the state in, so the law fuses with the step instead of needing the batch
    transposed around it (see :func:`split_per_body`).
    """

    def on_body(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:  # pragma: no cover - abstract
        """World-frame :class:`Forces` (force ``(3,)`` N, torque ``(3,)`` N m or ``None``) on one
        body of batch shape ``()``, with this model's arrays for that body."""
        raise NotImplementedError

    def on_body_in_body_frame(self, state: State, omega_body: Array, t: Float[ArrayLike, ""]) -> Forces:
        """:meth:`on_body` with the torque in the body frame: ``(F, R(q)ᵀ τ)`` for one body.

        ``state`` is a world-frame :class:`~rbjax.State` with a unit ``q``; ``omega_body`` is its
        ``ω_b = R(q)ᵀ ω`` ``(3,)`` (rad/s), which a step on the body-frame equations has already
        (``"rk4_body"``). This default turns :meth:`on_body`'s torque back; a law whose torque
        turns with the body (drag: ``τ(R ω_b) = R τ(ω_b)``) overrides it and needs no rotation.
        """
        return torque_to_body(self.on_body(state, t), state)

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        return lift(lambda model, s: model.on_body(s, t))(self, state)

    def as_per_body(self, state: AnyState) -> PerBodyForce | None:
        return self


class PerBodyForces:
    """The steps' force function when every term of a model is per body: ``fn(state, t) -> Forces``.

    Called, it lifts the sum of the terms' :meth:`PerBodyForce.on_body` over the batch (world
    frame), in the layout the step carries the state in. A method that evaluates its own
    right-hand side one body at a time may read :attr:`terms` instead and lift the forces with
    it (``"rk4_body"`` takes the torque in the body frame from
    :meth:`PerBodyForce.on_body_in_body_frame`).
    """

    def __init__(self, terms: tuple[PerBodyForce, ...]) -> None:
        self.terms = terms

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        return lift(lambda s, *terms: sum_on_body(terms, s, t))(state, *self.terms)


def torque_to_body(f: Forces, state: State) -> Forces:
    """``f`` with its world torque turned into ``state``'s body frame, ``R(q)ᵀ τ`` (one body; force kept)."""
    if f.torque is None:
        return f
    return replace(f, torque=quat_rotate_inverse_unchecked(state.orientation, f.torque))


def sum_on_body(terms: tuple[PerBodyForce, ...], state: AnyState, t: Any, omega_body: Array | None = None) -> Forces:
    """``Σ`` of the terms' forces on one body: world frame, or with the torque in the body frame
    (:meth:`PerBodyForce.on_body_in_body_frame`; ``state`` a :class:`~rbjax.State`) when
    ``omega_body`` is given."""
    total = Forces()
    for term in terms:
        if omega_body is None:
            total = total + term.on_body(state, t)
        elif isinstance(state, State):
            total = total + term.on_body_in_body_frame(state, omega_body, t)
        else:  # pragma: no cover - only rk4_body asks, with a State
            raise TypeError(f"sum_on_body: the body-frame form needs a State, got {type(state).__name__}")
    return total


def split_per_body(forces: ForceModel) -> tuple[tuple[PerBodyForce, ...], ForceModel | None]:
    """The :class:`PerBodyForce` terms of ``forces`` (a sum or one model) and the sum of the others.

    The rest is ``None`` when every term is per body, one model when one is left, else a
    :class:`ForceSum`; the order of the terms within each part is kept.
    """
    terms = forces.terms if isinstance(forces, ForceSum) else (forces,)
    per_body = tuple(term for term in terms if isinstance(term, PerBodyForce))
    others = tuple(term for term in terms if not isinstance(term, PerBodyForce))
    rest = None if not others else others[0] if len(others) == 1 else ForceSum(others)
    return per_body, rest


def with_per_body_terms(forces: ForceModel, state: AnyState) -> ForceModel:
    """``forces`` with every term that has a per-body form (:meth:`ForceModel.as_per_body`) in that form.

    Called on concrete models before ``simulate`` traces them, so that a sum of such
    terms is lifted inside the step (see :func:`split_per_body`); terms without one
    are kept as they are.
    """
    terms = forces.terms if isinstance(forces, ForceSum) else (forces,)
    new = tuple(term.as_per_body(state) or term for term in terms)
    if all(a is b for a, b in zip(new, terms)):
        return forces
    return ForceSum(new) if isinstance(forces, ForceSum) else new[0]


@pytree_dataclass
class ForceSum(ForceModel):
    """Sum of force models: ``F = Σ F_i``, ``τ = Σ τ_i`` (``None`` when every ``τ_i`` is).

    ``terms`` is a tuple of models; its length and order are static.
    """

    terms: tuple = ()

    def __post_init__(self) -> None:
        for term in self.terms:
            if not isinstance(term, ForceModel):
                raise TypeError(f"ForceSum: terms must be force models, got {type(term).__name__}")

    def check(self, state: AnyState) -> None:
        for term in self.terms:
            term.check(state)

    def _run_time_checked(self, state: AnyState, fn: str) -> ForceModel:
        return replace(self, terms=tuple(term._run_time_checked(state, fn) for term in self.terms))

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        total = Forces()
        for term in self.terms:
            total = total + term(state, t)
        return total
