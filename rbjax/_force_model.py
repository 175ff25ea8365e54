"""The force-model protocol: ``model(state, t) -> Forces`` (world frame), ``+`` composes.

:class:`ForceModel` is the base of the models in :mod:`rbjax._forces` (laws per body and
prescribed loads) and :mod:`rbjax._attached` (springs and thrusters, which name bodies by
index); :class:`ForceSum` is what ``+`` builds. The checks of their fields are in
:mod:`rbjax._force_checks`. See :mod:`rbjax._forces` for the conventions every model follows.
"""

from __future__ import annotations

import abc
import dataclasses
import inspect
from typing import Any, ClassVar, TypeGuard

import jax
import jax.core
import numpy as np
from jax import Array
from jaxtyping import Float

from ._batching import lift
from ._math import quat_rotate_inverse_unchecked
from ._pytree import dataclass_transform, field, pytree_dataclass, replace, static_field
from ._state import AnyState, Forces, State
from ._typing import ArrayLike

__all__ = ["ForceModel", "PerBodyForce", "ForceSum", "own_law", "check_force_model", "reads_velocity"]


class _ForceModelMeta(abc.ABCMeta):
    """Builds force models: refuses an abstract one in rbjax's words, then runs every
    ``__check_init__`` of the class and its bases (bases first) after ``__init__``, so that a
    subclass cannot skip the checks of the law it extends by writing a ``__post_init__``."""

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        missing = sorted(getattr(cls, "__abstractmethods__", ()))
        if missing:
            raise TypeError(
                f"{cls.__name__} cannot be built: it does not define {', '.join(missing)}. A force model "
                "defines __call__(self, state, t) -> rb.Forces (subclass rb.ForceModel), or, for a law in "
                "which each body feels a force of its own state alone, on_body(self, state, t) for one body "
                "(subclass rb.PerBodyForce)"
            )
        obj = super().__call__(*args, **kwargs)
        for klass in reversed(cls.__mro__):
            check = klass.__dict__.get("__check_init__")
            if check is not None:
                check(obj)
        return obj

    @property
    def __signature__(cls) -> inspect.Signature:
        # inspect.signature(cls) and help() would show this metaclass's (*args, **kwargs); a
        # property of the metaclass answers for the class only, never for its instances, whose
        # own signature is that of __call__
        init = inspect.signature(cls.__init__)
        return init.replace(parameters=list(init.parameters.values())[1:])


# subclasses are frozen dataclasses (see __init_subclass__): tells type checkers so
@dataclass_transform(frozen_default=True, field_specifiers=(field, static_field, dataclasses.field))
class ForceModel(metaclass=_ForceModelMeta):
    """Base of force models: ``model(state, t) -> Forces`` (world frame), ``+`` composes.

    A model maps a state batch of shape ``B`` and a time ``t`` (s) to world-frame
    :class:`rbjax.Forces` (force ``(*B, 3)`` in N on the centre of mass, torque
    ``(*B, 3)`` in N m about it, either ``None`` when the model has none).

    Every subclass is a frozen dataclass and a pytree, as equinox's ``Module`` is: its
    annotated fields are the model's parameters, arrays that ``jit`` traces and ``grad``
    differentiates, or static configuration declared with :func:`rbjax.static_field`.
    A subclass defines ``__call__`` (a missing one is refused when the model is built)
    and may define ``__check_init__`` to validate its fields: it runs after ``__init__``
    for the class and every base that defines one, so a subclass of a built-in law
    keeps that law's checks. Every path of :func:`rbjax.simulate` (native kernels, JAX,
    body-frame methods, :class:`rbjax.Scene`, chunked runs) evaluates the model's own
    ``__call__``; the kernels run a law of their own only for the built-in laws' exact
    types (:func:`own_law`).
    """

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "__init__" in cls.__dict__:
            raise TypeError(
                f"{cls.__name__}: a force model is a frozen dataclass and writes no __init__: declare its "
                "parameters as annotated fields (e.g. 'stiffness: jax.Array') and check them in "
                "__check_init__(self)"
            )
        pytree_dataclass(cls)

    @abc.abstractmethod
    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        """World-frame :class:`rbjax.Forces` on the batch ``state`` at time ``t`` (s)."""

    def check(self, state: AnyState) -> None:
        """``ValueError`` naming the argument unless this model's arrays fit ``state``'s batch.

        Shapes are checked always (they are static), body indices against the
        batch size ``N`` when their values are concrete. Called by
        :func:`rbjax.simulate`, :func:`rbjax.step` and :class:`rbjax.Scene`
        before tracing, and by each model while it is traced.
        """

    # fields holding body indices, and coefficients that must be >= 0 (see _run_time_checked)
    _INDEX_FIELDS: ClassVar[tuple[str, ...]] = ()
    _NON_NEGATIVE: ClassVar[tuple[str, ...]] = ()
    # how an error message names a field, where its name alone would mislead
    _FIELD_LABELS: ClassVar[dict[str, str]] = {}

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

    def depends_on_velocity(self) -> bool | None:
        """Whether this law reads the bodies' velocities or angular velocities (drag, a damper).

        ``True`` or ``False`` as the law declares, ``None`` when it does not (a law of your
        own may override this). A method whose order drops under such forces
        (``Method.order_with_velocity_forces``) warns when it is given one that does.
        """
        return None

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
    bodies where it is per body and shared where it is not: a field declared with
    ``rb.field(core_shape=(3,))`` (a vector per body) or ``core_ndim`` is per body when it
    has more dimensions than that, a plain field when it has any. ``simulate`` lifts
    :meth:`on_body` itself inside its steps, in the layout its scan carries the state in, so
    the law fuses with the step instead of needing the batch transposed around it (see
    :func:`split_per_body`): the fast path for a law of your own.

    Example, buoyancy ``F = -ρ V g`` (world frame, N) per body::

        class Buoyancy(rb.PerBodyForce):
            volume: jax.Array  # m³, scalar or (N,)
            density: float = 1000.0  # kg/m³

            def on_body(self, state, t):
                return rb.Forces(force=jnp.array([0.0, 0.0, 9.81]) * self.density * self.volume)
    """

    @abc.abstractmethod
    def on_body(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        """World-frame :class:`Forces` (force ``(3,)`` N, torque ``(3,)`` N m or ``None``) on one
        body of batch shape ``()``, with this model's arrays for that body."""

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
            if own_law(term, "on_body_in_body_frame"):
                total = total + term.on_body_in_body_frame(state, omega_body, t)
            else:
                total = total + torque_to_body(term.on_body(state, t), state)
        else:  # pragma: no cover - only rk4_body asks, with a State
            raise TypeError(f"sum_on_body: the body-frame form needs a State, got {type(state).__name__}")
    return total


def split_per_body(forces: ForceModel) -> tuple[tuple[PerBodyForce, ...], ForceModel | None]:
    """The :class:`PerBodyForce` terms of ``forces`` (a sum or one model) and the sum of the others.

    The rest is ``None`` when every term is per body, one model when one is left, else a
    :class:`ForceSum`; the order of the terms within each part is kept.
    """
    terms = forces.terms if isinstance(forces, ForceSum) else (forces,)
    per_body = tuple(term for term in terms if _is_per_body(term))
    others = tuple(term for term in terms if not _is_per_body(term))
    rest = None if not others else others[0] if len(others) == 1 else ForceSum(others)
    return per_body, rest


def with_per_body_terms(forces: ForceModel, state: AnyState) -> ForceModel:
    """``forces`` with every term that has a per-body form (:meth:`ForceModel.as_per_body`) in that form.

    Called on concrete models before ``simulate`` traces them, so that a sum of such
    terms is lifted inside the step (see :func:`split_per_body`); terms without one
    are kept as they are.
    """
    terms = forces.terms if isinstance(forces, ForceSum) else (forces,)
    new = tuple((term.as_per_body(state) if own_law(term, "as_per_body") else None) or term for term in terms)
    if all(a is b for a, b in zip(new, terms)):
        return forces
    return ForceSum(new) if isinstance(forces, ForceSum) else new[0]


class ForceSum(ForceModel):
    """Sum of force models: ``F = Σ F_i``, ``τ = Σ τ_i`` (``None`` when every ``τ_i`` is).

    ``terms`` is a tuple of models; its length and order are static.
    """

    terms: tuple = ()

    def __check_init__(self) -> None:
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


# Each shortcut a path may take instead of a model's ``__call__``, and the method whose law it
# restates: the shortcut stands for the model only where the class that wrote it also wrote (or
# inherits unchanged) that method, or where it is the generic form defined on the base itself.
_SHORTCUTS: dict[str, tuple[str, type]] = {
    # lifting on_body inside the step instead of calling the model on the batch
    "on_body": ("__call__", PerBodyForce),
    # rk4_body's torque in the body frame instead of on_body's turned back
    "on_body_in_body_frame": ("on_body", PerBodyForce),
    # an index-based model rewritten as a per-body law
    "as_per_body": ("__call__", ForceModel),
}


def _owner(cls: type, name: str) -> type:
    """The class of ``cls``'s MRO that defines the attribute ``name``."""
    return next(klass for klass in cls.__mro__ if name in klass.__dict__)


def own_law(model: Any, shortcut: str) -> bool:
    """Whether the path named by ``shortcut`` computes ``model``'s own law.

    ``"on_body"`` (lift :meth:`PerBodyForce.on_body` inside the step),
    ``"on_body_in_body_frame"`` (rk4_body's body-frame torque) and ``"as_per_body"``
    (an index-based model rewritten per body) each restate another method of the model.
    A subclass that overrides that method and not the shortcut (``__call__`` of a
    :class:`rbjax.Gravity` subclass, ``on_body`` of a :class:`rbjax.LinearDrag` one)
    would have the shortcut run its parent's law: then this is ``False`` and the path
    calls the overridden method instead.
    """
    reference, generic = _SHORTCUTS[shortcut]
    if not isinstance(model, generic):
        return False
    cls = type(model)
    owner = _owner(cls, shortcut)
    return owner is generic or issubclass(owner, _owner(cls, reference))


def reads_velocity(model: ForceModel) -> bool | None:
    """:meth:`ForceModel.depends_on_velocity` of ``model`` (a sum: of any term), taken only from
    the class that wrote the law (a subclass that rewrote ``__call__`` or ``on_body`` and not the
    declaration has not declared it: ``None``)."""
    if isinstance(model, ForceSum):
        said = [reads_velocity(term) for term in model.terms]
        return True if True in said else None if None in said else False
    cls = type(model)
    owner = _owner(cls, "depends_on_velocity")
    laws = ("__call__", "on_body") if isinstance(model, PerBodyForce) else ("__call__",)
    if owner is not ForceModel and all(issubclass(owner, _owner(cls, law)) for law in laws):
        return model.depends_on_velocity()
    return None


def _is_per_body(term: Any) -> TypeGuard[PerBodyForce]:
    """Whether ``term`` may be lifted per body through its ``on_body`` (see :func:`own_law`)."""
    return isinstance(term, PerBodyForce) and own_law(term, "on_body")


def check_force_model(forces: ForceModel, state: AnyState, fn: str) -> None:
    """``forces.check(state)``, after ``TypeError`` naming the field for a parameter ``jit`` cannot trace.

    A force model's fields are traced as arrays by :func:`rbjax.simulate`; a string, a
    function or another Python object there would reach JAX as "Error interpreting
    argument": it belongs in a :func:`rbjax.static_field`.
    """
    for path, leaf in jax.tree_util.tree_flatten_with_path(forces)[0]:
        if isinstance(leaf, (jax.Array, np.ndarray, np.generic, int, float, complex)) and not isinstance(leaf, str):
            continue
        where = type(forces).__name__ + jax.tree_util.keystr(path)
        raise TypeError(
            f"{fn}: forces: {where} holds a {type(leaf).__name__}, which jit cannot trace as an array: "
            "declare that field with rb.static_field() (static configuration, part of the compiled "
            "program) or give it as an array"
        )
    forces.check(state)
