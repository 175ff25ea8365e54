"""Composable force models: small pytrees ``model(state, t) -> Forces`` (world frame).

A force model is a frozen pytree dataclass whose arrays (stiffnesses, anchors,
drag coefficients) are leaves, so they can be differentiated and fitted, and
whose structure (which terms, which are ``None``) is static. Models add with
``+`` into a :class:`ForceSum`; its ``terms`` tuple is part of the treedef, so
the compiled step contains exactly the terms present. A model that produces no
torque returns ``Forces(torque=None)``, and the sum keeps ``None`` when every
term does, so a step under forces only compiles no torque work.

Conventions: SI units (N, N m, m, s); world frame unless a name says ``body``;
the state may be :class:`State`, :class:`MatrixState` or
:class:`ParticleState` of batch shape ``B``; every model returns forces of
shape ``(*B, 3)``. Models that name bodies by index (:class:`Spring`,
:class:`Thruster`) need a one-dimensional batch ``(N,)``.

Every model checks its arguments in rbjax's words (``TypeError``/``ValueError``
naming the model and the argument): shapes and signs at construction
(coefficients that dissipate or restore, such as drag, stiffness and
damping, must be ``>= 0``; a body index must be a non-negative integer), and
against the state when it is simulated (a per-body array must fit the batch;
a body index must be ``< N``: ``simulate``, ``step`` and ``Scene`` check it
before tracing). Values traced by a caller's ``jit`` cannot be read there:
``simulate(..., checked=True)`` tests traced body indices and the signs of
traced coefficients at run time (an ``equinox`` error carrying the message);
unchecked runs compile no test.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import NamedSharding, PartitionSpec
from jaxtyping import Float, Int

from ._body import as_float, floats
from ._math import broadcasts_to, cross, matvec3, quat_rotate, safe_norm
from ._pytree import field, pytree_dataclass, replace, static_field
from ._quantities import angular_velocity
from ._state import AnyState, Forces, MatrixState, ParticleState, RigidState, State
from ._typing import ArrayLike

__all__ = [
    "ForceModel",
    "ForceSum",
    "Gravity",
    "LinearDrag",
    "QuadraticDrag",
    "Spring",
    "ConstantForce",
    "TimeSeriesForce",
    "ExternalForce",
    "Thruster",
    "CustomForce",
]


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
                msg = (
                    f"{fn}(checked=...): {type(self).__name__}: {_ALIAS.get(name, name)} holds an index outside "
                    f"the batch of {n} bodies (a traced index was; indices must be in 0..{n - 1})"
                )
                changes[name] = eqx.error_if(i, (i < 0) | (i >= n), msg)
        for name in self._NON_NEGATIVE:
            c = getattr(self, name, None)
            if isinstance(c, jax.core.Tracer):
                msg = f"{fn}(checked=...): {type(self).__name__}: {name} must be >= 0 (a traced value was negative)"
                changes[name] = eqx.error_if(c, c < 0, msg)
        return replace(self, **changes) if changes else self

    def __add__(self, other: ForceModel) -> ForceSum:
        if not isinstance(other, ForceModel):
            return NotImplemented
        a = self.terms if isinstance(self, ForceSum) else (self,)
        b = other.terms if isinstance(other, ForceSum) else (other,)
        return ForceSum(a + b)


def _concrete(a: Any) -> bool:
    return a is not None and not isinstance(a, jax.core.Tracer) and getattr(a, "is_fully_addressable", True)


def _core(model: Any, name: str, core: tuple[int, ...], extra: str = "") -> None:
    """``ValueError`` unless field ``name`` (if given) ends in ``core``, e.g. ``(3,)`` for a vector."""
    a = getattr(model, name)
    if a is None:
        return
    if tuple(a.shape[a.ndim - len(core) :]) != core or a.ndim < len(core):
        dims = ", ".join(str(c) for c in core)
        raise ValueError(
            f"{type(model).__name__}: {name} must have shape (..., {dims}){extra}, got shape {tuple(a.shape)}"
        )


def _non_negative(model: Any, *names: str) -> None:
    """``ValueError`` for a concrete negative coefficient (it would add energy, not take it)."""
    for name in names:
        a = getattr(model, name)
        if _concrete(a) and np.any(np.asarray(a) < 0):
            raise ValueError(
                f"{type(model).__name__}: {name} must be >= 0 (a negative coefficient adds energy instead of "
                f"removing or restoring it), got {np.asarray(a).ravel()[:4]}; pass its magnitude"
            )


def _fits(model: Any, name: str, core: int, shape: tuple[int, ...], what: str) -> None:
    """``ValueError`` unless field ``name``'s leading shape (all but ``core`` axes) broadcasts to ``shape``."""
    a = getattr(model, name)
    if a is None:
        return
    lead = tuple(a.shape[: a.ndim - core])
    ok = broadcasts_to(lead, tuple(shape))
    if not ok:
        raise ValueError(
            f"{type(model).__name__}: {name} of shape {tuple(a.shape)} does not fit {what} {tuple(shape)}; give it "
            f"the shape {tuple(shape) + tuple(a.shape[a.ndim - core :])} or a broadcastable one"
        )


def _mass(state: AnyState) -> Array:
    return state.mass if isinstance(state, ParticleState) else state.body.mass


def _cast(x: Any, state: AnyState) -> Array:
    return jnp.asarray(x).astype(state.dtype)


def _full(x: Array, state: AnyState) -> Array:
    return jnp.broadcast_to(x, state.position.shape)


def _no_torque_for_particles(name: str, state: AnyState) -> RigidState:
    """``state``, known to be rigid; ``ValueError`` for particles."""
    if isinstance(state, ParticleState):
        raise ValueError(f"{name}: a torque needs rigid bodies; ParticleState has no rotation")
    return state


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


@pytree_dataclass
class Gravity(ForceModel):
    """Uniform gravity ``F = m g`` on the centre of mass; no torque.

    ``g``: ``(3,)`` (or ``(*B, 3)``) acceleration, world frame, m/s²; default
    ``(0, 0, -9.81)``. A scalar is refused (``ValueError``): it would broadcast
    to ``(g, g, g)``; give the vector, e.g. ``(0, 0, -9.81)``.
    """

    g: Float[Array, "*B 3"] = field(core_shape=(3,), default=(0.0, 0.0, -9.81))

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(self, g: Float[ArrayLike, "*B 3"] | tuple[float, float, float] = (0.0, 0.0, -9.81)) -> None: ...

    def __post_init__(self) -> None:
        if self.g is None:
            raise TypeError("Gravity: g must be a (3,) acceleration vector in m/s², e.g. (0, 0, -9.81); got None")
        floats(self, "g")
        if self.g.ndim == 0:
            raise ValueError(
                f"Gravity: g must be a (3,) acceleration vector in m/s² (world frame), got the scalar {self.g}; "
                "for gravity of that magnitude downward pass g=(0, 0, -magnitude)"
            )
        _core(self, "g", (3,), " (an acceleration vector, m/s²)")

    def check(self, state: AnyState) -> None:
        _fits(self, "g", 1, state.batch_shape, "the batch shape")

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        return Forces(force=_full(_mass(state)[..., None] * _cast(self.g, state), state))


class _Drag(ForceModel):
    """The coefficients of :class:`LinearDrag` and :class:`QuadraticDrag`: ``linear`` and
    ``angular``, scalar or ``(*B,)``, ``>= 0``, ``angular`` ``None`` for no torque."""

    linear: Array
    angular: Array | None
    _NON_NEGATIVE = ("linear", "angular")

    def __post_init__(self) -> None:
        floats(self, "linear", "angular")
        _non_negative(self, "linear", "angular")

    def check(self, state: AnyState) -> None:
        for name in ("linear", "angular"):
            _fits(self, name, 0, state.batch_shape, "the batch shape")


@pytree_dataclass
class LinearDrag(_Drag):
    """Viscous drag ``F = -b v`` and, if ``angular`` is given, ``τ = -b_r ω``.

    ``linear`` ``b``: scalar or ``(*B,)``, N s/m, ``>= 0``. ``angular`` ``b_r``: scalar or
    ``(*B,)``, N m s, ``>= 0``, or ``None`` (no torque: the step compiles none). ``v`` is the
    centre-of-mass velocity and ``ω`` the angular velocity, both world frame.
    """

    linear: Float[Array, "*B"] = field(default=0.0)
    angular: Float[Array, "*B"] | None = field(default=None)

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(
            self, linear: Float[ArrayLike, "*B"] = 0.0, angular: Float[ArrayLike, "*B"] | None = None
        ) -> None: ...

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        f = -_cast(self.linear, state)[..., None] * state.velocity
        if self.angular is None:
            return Forces(force=f)
        rigid = _no_torque_for_particles("LinearDrag(angular=...)", state)
        return Forces(force=f, torque=-_cast(self.angular, state)[..., None] * angular_velocity(rigid))


@pytree_dataclass
class QuadraticDrag(_Drag):
    """Quadratic drag ``F = -c ‖v‖ v`` and, if ``angular`` is given, ``τ = -c_r ‖ω‖ ω``.

    ``linear`` ``c``: scalar or ``(*B,)``, kg/m (``½ ρ C_d A``), ``>= 0``. ``angular``
    ``c_r``: kg m², ``>= 0``, or ``None`` (no torque). World frame. Terminal speed under
    gravity: ``√(m g / c)``.
    """

    linear: Float[Array, "*B"] = field(default=0.0)
    angular: Float[Array, "*B"] | None = field(default=None)

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(
            self, linear: Float[ArrayLike, "*B"] = 0.0, angular: Float[ArrayLike, "*B"] | None = None
        ) -> None: ...

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        v = state.velocity
        f = -_cast(self.linear, state)[..., None] * safe_norm(v, keepdims=True) * v
        if self.angular is None:
            return Forces(force=f)
        w = angular_velocity(_no_torque_for_particles("QuadraticDrag(angular=...)", state))
        c_r = _cast(self.angular, state)[..., None]
        return Forces(force=f, torque=-c_r * safe_norm(w, keepdims=True) * w)


# ---------------------------------------------------------------- attached points


def _check_flat(name: str, state: AnyState) -> int:
    if len(state.batch_shape) != 1:
        raise ValueError(
            f"{name} names bodies by index and needs a 1-D batch (N,); got batch shape {state.batch_shape}"
        )
    return state.batch_shape[0]


def _offset(state: AnyState, idx: Array, point: Array | None) -> Array | None:
    """World offset ``r = R p`` of body-frame points ``p`` on bodies ``idx`` (``None`` at the COM)."""
    return None if point is None else _to_world(state, idx, point)


def _to_world(state: AnyState, idx: Array, point: Array) -> Array:
    """Body-frame vectors ``p`` on bodies ``idx`` in the world frame: ``R p``."""
    p = _cast(point, state)
    if isinstance(state, State):
        return quat_rotate(_gather(state.orientation, idx), p)
    if isinstance(state, MatrixState):
        return matvec3(_gather(state.rotation, idx), p)
    raise ValueError("a body-frame attachment point needs rigid bodies; ParticleState has no rotation")


def _point_motion(state: AnyState, idx: Array, r: Array | None, omega: Array | None) -> tuple[Array, Array]:
    """World position ``x + r`` and velocity ``v + ω × r`` of attached points."""
    x, v = _gather(state.position, idx), _gather(state.velocity, idx)
    if r is None or omega is None:  # omega is given whenever an offset r is
        return x, v
    return x + r, v + cross(_gather(omega, idx), r)


def _explicit_sharding(x: Array) -> Any:
    """The sharding of ``x`` if it is sharded over an explicit mesh axis (else ``None``)."""
    sh = jax.typeof(x).sharding
    return sh if any(a is not None for a in getattr(sh, "spec", ())) else None


def _gather(x: Array, idx: Array) -> Array:
    # Explicit sharding asks where a gather's result lives: the few attached bodies' values
    # are replicated (the scatter below returns them to the bodies' shards).
    sh = _explicit_sharding(x)
    if sh is None:
        return x[idx]
    return x.at[idx].get(out_sharding=NamedSharding(sh.mesh, PartitionSpec()))


def _add_at(total: Array, idx: Array, values: Array) -> Array:
    return total.at[idx].add(values, out_sharding=_explicit_sharding(total))


def _scatter(state: AnyState, idx: Array, values: Array) -> Array:
    return _add_at(jnp.zeros_like(state.position), idx, values)


def _as_index(model: str, name: str, x: ArrayLike) -> Array:
    """Body indices ``(S,)``: integers ``>= 0`` (a negative one would count from the end: refused)."""
    try:
        i = jnp.asarray(x)
    except (TypeError, ValueError):
        raise TypeError(f"{model}: {name} must be body indices (integers), got {type(x).__name__}") from None
    if not jnp.issubdtype(i.dtype, jnp.integer):
        raise ValueError(f"{model}: {name} must be body indices (integers), got dtype {i.dtype}")
    i = jnp.atleast_1d(i)
    if i.ndim != 1:
        raise ValueError(f"{model}: {name} must be a 1-D array of body indices (S,), got shape {tuple(i.shape)}")
    if _concrete(i) and np.any(np.asarray(i) < 0):
        raise ValueError(
            f"{model}: {name} must be body indices >= 0 (a negative index would count from the end), got "
            f"{np.asarray(i)[np.asarray(i) < 0][:4]}"
        )
    return i


_ALIAS = {"other": "other (body_b of Spring.between)"}


def _indices_in(model: Any, name: str, n: int) -> None:
    """``ValueError`` unless the (concrete) indices of field ``name`` are ``< n``, the batch size."""
    i = getattr(model, name)
    if i is None or not _concrete(i) or i.size == 0:
        return
    top = int(np.max(np.asarray(i)))
    if top >= n:
        raise ValueError(
            f"{type(model).__name__}: {_ALIAS.get(name, name)} index {top} is outside the batch of {n} bodies "
            f"(indices 0..{n - 1}); an index past the end would be dropped or clamped silently"
        )


def _per_item(model: Any, s: int, vectors: tuple[str, ...], scalars: tuple[str, ...]) -> None:
    """Shapes of a model of ``s`` items: ``vectors`` ``(S, 3)`` or ``(3,)``, ``scalars`` ``(S,)`` or ``()``."""
    items = f"the number of {type(model).__name__.lower()}s S (the length of body)"
    for name in vectors:
        _core(model, name, (3,), " (a 3-vector each)")
        _fits(model, name, 1, (s,), items)
    for name in scalars:
        _fits(model, name, 0, (s,), items)


@pytree_dataclass
class Spring(ForceModel):
    """Springs (with optional linear dampers) from body points to world anchors or other bodies.

    Spring ``s`` joins point ``a`` (``point`` in body ``body[s]``'s frame, or its
    centre of mass if ``point`` is ``None``) to point ``b``: the world ``anchor``
    if ``other`` is ``None``, else ``anchor`` in body ``other[s]``'s frame (its
    centre of mass if ``anchor`` is ``None``). With ``d = x_b - x_a`` (world):

        F_a = k (1 - l₀/‖d‖) d + c (v_b - v_a),      F_b = -F_a,
        τ_a = r_a × F_a,  τ_b = r_b × F_b,           r = R p (world offset),

    so a zero-length spring is ``F_a = k d``. ``v = v_com + ω × r`` is the point
    velocity; the damper is a vector dashpot on the relative velocity. Equal and
    opposite forces conserve total linear momentum; the spring force is central
    (along ``d``), so without damping total angular momentum is conserved too.
    The dashpot is not central (``v_b - v_a`` need not be along ``d``): with
    ``damping`` the springs exert a net torque ``(p_a - p_b) × F_a`` on the
    pair and total angular momentum changes.

    Shapes (``S`` springs): ``body``, ``other``: ``(S,)`` int, each ``>= 0`` and
    ``< N`` (checked when simulated); ``point``, ``anchor``: ``(S, 3)`` or
    ``(3,)`` m; ``stiffness`` ``k`` N/m, ``rest_length`` ``l₀`` m, ``damping``
    ``c`` N s/m: ``(S,)`` or scalars, each ``>= 0``. Build with :meth:`to_anchor`
    or :meth:`between`. Points at the centre of mass (``None``) add no torque
    and no rotation work; with both ends there the model returns ``torque=None``.
    """

    body: Int[Array, " S"]
    stiffness: Float[Array, "*S"]
    point: Float[Array, "S 3"] | None = None
    anchor: Float[Array, "S 3"] | None = None
    other: Int[Array, " S"] | None = None
    rest_length: Float[Array, "*S"] = field(default=0.0)
    damping: Float[Array, "*S"] | None = None
    _INDEX_FIELDS = ("body", "other")
    _NON_NEGATIVE = ("stiffness", "rest_length", "damping")

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(
            self,
            body: Int[ArrayLike, " S"],
            stiffness: Float[ArrayLike, "*S"],
            point: Float[ArrayLike, "S 3"] | None = None,
            anchor: Float[ArrayLike, "S 3"] | None = None,
            other: Int[ArrayLike, " S"] | None = None,
            rest_length: Float[ArrayLike, "*S"] = 0.0,
            damping: Float[ArrayLike, "*S"] | None = None,
        ) -> None: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "body", _as_index("Spring", "body", self.body))
        if self.other is not None:
            object.__setattr__(self, "other", _as_index("Spring", "other", self.other))
            if self.other.shape != self.body.shape:
                raise ValueError(
                    f"Spring: body {tuple(self.body.shape)} and other {tuple(self.other.shape)} must name the same "
                    "number of springs"
                )
        elif self.anchor is None:
            raise ValueError("Spring: a world anchor is required when other is None")
        floats(self, "stiffness", "point", "anchor", "rest_length", "damping")
        _per_item(self, self.body.shape[0], ("point", "anchor"), ("stiffness", "rest_length", "damping"))
        _non_negative(self, "stiffness", "rest_length", "damping")

    def check(self, state: AnyState) -> None:
        n = _check_flat("Spring", state)
        _indices_in(self, "body", n)
        _indices_in(self, "other", n)

    @classmethod
    def to_anchor(
        cls,
        body: Int[ArrayLike, " S"],
        anchor: Float[ArrayLike, "S 3"],
        stiffness: Float[ArrayLike, "*S"],
        *,
        point: Float[ArrayLike, "S 3"] | None = None,
        rest_length: Float[ArrayLike, "*S"] = 0.0,
        damping: Float[ArrayLike, "*S"] | None = None,
    ) -> Spring:
        """Springs from body points (body frame; ``None`` = COM) to world ``anchor`` points."""
        return cls(
            body=body,
            stiffness=stiffness,
            point=point,
            anchor=anchor,
            rest_length=rest_length,
            damping=damping,
        )

    @classmethod
    def between(
        cls,
        body_a: Int[ArrayLike, " S"],
        body_b: Int[ArrayLike, " S"],
        stiffness: Float[ArrayLike, "*S"],
        *,
        point_a: Float[ArrayLike, "S 3"] | None = None,
        point_b: Float[ArrayLike, "S 3"] | None = None,
        rest_length: Float[ArrayLike, "*S"] = 0.0,
        damping: Float[ArrayLike, "*S"] | None = None,
    ) -> Spring:
        """Springs between points on two bodies (each in its own body frame; ``None`` = COM)."""
        return cls(
            body=body_a,
            stiffness=stiffness,
            point=point_a,
            anchor=point_b,
            other=body_b,
            rest_length=rest_length,
            damping=damping,
        )

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        _check_flat("Spring", state)
        rotating = self.point is not None or (self.other is not None and self.anchor is not None)
        omega = angular_velocity(_no_torque_for_particles("Spring(point=...)", state)) if rotating else None
        r_a = _offset(state, self.body, self.point)
        x_a, v_a = _point_motion(state, self.body, r_a, omega)
        r_b = None
        if self.other is None:
            x_b, v_b = _cast(self.anchor, state), None
        else:
            r_b = _offset(state, self.other, self.anchor)
            x_b, v_b = _point_motion(state, self.other, r_b, omega)
        d = x_b - x_a
        k = _cast(self.stiffness, state)[..., None]
        l0 = _cast(self.rest_length, state)[..., None]
        length = safe_norm(d, keepdims=True)
        # (1 - l0/|d|) d, with a zero force (not NaN) at |d| = 0
        scale = jnp.where(length > 0, 1 - l0 / jnp.where(length > 0, length, 1), 0)
        f_a = k * scale * d
        if self.damping is not None:
            rel = -v_a if v_b is None else v_b - v_a
            f_a = f_a + _cast(self.damping, state)[..., None] * rel
        f_a = jnp.broadcast_to(f_a, d.shape)
        force = _scatter(state, self.body, f_a)
        torque = None if r_a is None else _scatter(state, self.body, cross(r_a, f_a))
        if self.other is not None:
            force = _add_at(force, self.other, -f_a)
            if r_b is not None:
                tb = cross(r_b, -f_a)
                torque = _scatter(state, self.other, tb) if torque is None else _add_at(torque, self.other, tb)
        return Forces(force=force, torque=torque)


@pytree_dataclass
class Thruster(ForceModel):
    """Body-fixed thrusters: force ``F = T R d`` at body point ``p``, turning with the body.

    Thruster ``s`` on body ``body[s]`` pushes with magnitude ``thrust`` ``T`` (N)
    along the body-frame ``direction`` ``d`` (unit, not renormalised) at the
    body-frame ``point`` ``p`` (m; ``None`` = centre of mass, no torque). World
    force ``F = T R d``, torque about the centre of mass ``τ = (R p) × F``.
    Shapes (``S`` thrusters): ``body`` ``(S,)`` int, each ``>= 0`` and ``< N``
    (checked when simulated); ``direction`` (unit: checked when concrete),
    ``point``: ``(S, 3)`` or ``(3,)``; ``thrust`` ``(S,)`` or scalar, of either
    sign (a negative thrust pushes along ``-d``). Rigid states only.
    """

    body: Int[Array, " S"]
    direction: Float[Array, "S 3"]
    thrust: Float[Array, "*S"]
    point: Float[Array, "S 3"] | None = None
    _INDEX_FIELDS = ("body",)

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(
            self,
            body: Int[ArrayLike, " S"],
            direction: Float[ArrayLike, "S 3"],
            thrust: Float[ArrayLike, "*S"],
            point: Float[ArrayLike, "S 3"] | None = None,
        ) -> None: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "body", _as_index("Thruster", "body", self.body))
        floats(self, "direction", "thrust", "point")
        _per_item(self, self.body.shape[0], ("direction", "point"), ("thrust",))
        d = self.direction
        if _concrete(d) and d.size:
            err = np.max(np.abs(np.linalg.norm(np.asarray(d, np.float64), axis=-1) - 1))
            tol = max(1e-6, 128 * float(np.finfo(d.dtype).eps))
            if err > tol:
                raise ValueError(
                    f"Thruster: direction must be unit vectors (the thrust gives the magnitude); |‖d‖ - 1| = "
                    f"{err:.3g} exceeds {tol:.3g}: normalise it, d / ‖d‖"
                )

    def check(self, state: AnyState) -> None:
        _indices_in(self, "body", _check_flat("Thruster", state))

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        _check_flat("Thruster", state)
        if isinstance(state, ParticleState):
            raise ValueError("Thruster: a body-fixed direction needs rigid bodies, not ParticleState")
        d = _to_world(state, self.body, self.direction)
        f = _cast(self.thrust, state)[..., None] * d
        r = _offset(state, self.body, self.point)
        force = _scatter(state, self.body, f)
        return Forces(force=force, torque=None if r is None else _scatter(state, self.body, cross(r, f)))


# ---------------------------------------------------------------- prescribed loads


@pytree_dataclass
class ConstantForce(ForceModel):
    """Constant world-frame force and torque: ``F(t) = F₀``, ``τ(t) = τ₀``.

    ``force``: ``(*B, 3)`` or ``(3,)`` in N (on the centre of mass); ``torque``:
    ``(*B, 3)`` or ``(3,)`` in N m (about it). Either may be ``None`` (absent).
    """

    force: Float[Array, "*B 3"] | None = None
    torque: Float[Array, "*B 3"] | None = None

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(
            self, force: Float[ArrayLike, "*B 3"] | None = None, torque: Float[ArrayLike, "*B 3"] | None = None
        ) -> None: ...

    def __post_init__(self) -> None:
        floats(self, "force", "torque")
        _core(self, "force", (3,), " (a force vector, N)")
        _core(self, "torque", (3,), " (a torque vector, N m)")

    def check(self, state: AnyState) -> None:
        for name in ("force", "torque"):
            _fits(self, name, 1, state.batch_shape, "the batch shape")

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        f = None if self.force is None else _full(_cast(self.force, state), state)
        if self.torque is None:
            return Forces(force=f)
        rigid = _no_torque_for_particles("ConstantForce(torque=...)", state)
        return Forces(force=f, torque=_full(_cast(self.torque, state), rigid))


def _sample(times: Array, values: Array, t: Array, interpolation: str) -> Array:
    """Series value at ``t``: clamped to the end samples outside ``[t_0, t_K-1]``."""
    k = times.shape[0]
    i = jnp.searchsorted(times, t, side="right") - 1
    if interpolation == "hold" or k == 1:
        return values[jnp.clip(i, 0, k - 1)]
    i = jnp.clip(i, 0, k - 2)
    t0, t1 = times[i], times[i + 1]
    w = jnp.clip((t - t0) / (t1 - t0), 0, 1)
    return (1 - w) * values[i] + w * values[i + 1]


@pytree_dataclass
class TimeSeriesForce(ForceModel):
    """Force and torque sampled at increasing ``times`` ``(K,)`` (s), world frame.

    ``force``, ``torque``: ``(K, *B, 3)`` or ``(K, 3)`` (shared), or ``None``.
    ``interpolation`` (static): ``"linear"`` (piecewise linear between samples,
    so a Runge–Kutta stage at ``t + dt/2`` sees the midpoint value) or
    ``"hold"`` (zero-order hold: the last sample at or before ``t``). Before
    the first and after the last sample the end value holds.
    """

    times: Float[Array, " K"]
    force: Float[Array, "K *B 3"] | None = None
    torque: Float[Array, "K *B 3"] | None = None
    interpolation: str = static_field(default="linear")

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(
            self,
            times: Float[ArrayLike, " K"],
            force: Float[ArrayLike, "K *B 3"] | None = None,
            torque: Float[ArrayLike, "K *B 3"] | None = None,
            interpolation: str = "linear",
        ) -> None: ...

    def __post_init__(self) -> None:
        if self.interpolation not in ("linear", "hold"):
            raise ValueError(f"TimeSeriesForce: interpolation must be 'linear' or 'hold', got {self.interpolation!r}")
        floats(self, "times")
        if self.times.ndim != 1 or self.times.shape[0] < 1:
            raise ValueError(f"TimeSeriesForce: times must have shape (K,) with K >= 1, got {tuple(self.times.shape)}")
        if _concrete(self.times) and np.any(np.diff(np.asarray(self.times)) <= 0):
            raise ValueError("TimeSeriesForce: times must be strictly increasing (s); sort them with their samples")
        k = self.times.shape[0]
        for name in ("force", "torque"):
            v = getattr(self, name)
            if v is not None:
                floats(self, name)
                v = getattr(self, name)
                if v.ndim < 2 or v.shape[0] != k or v.shape[-1] != 3:
                    raise ValueError(
                        f"TimeSeriesForce: {name} must have shape (K={k}, ..., 3) matching times (K,); got {v.shape}"
                    )
                object.__setattr__(self, name, v)

    def check(self, state: AnyState) -> None:
        want = tuple(state.position.shape)
        for name in ("force", "torque"):
            a = getattr(self, name)
            if a is None:
                continue
            ok = broadcasts_to(tuple(a.shape[1:]), want)
            if not ok:
                raise ValueError(
                    f"TimeSeriesForce: {name} samples of shape {tuple(a.shape[1:])} do not fit the batch: each must "
                    f"broadcast to {want} (give {name} the shape (K, 3) or (K, *batch shape, 3))"
                )

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        times = _cast(self.times, state)
        t = _cast(t, state)

        def get(v: Array | None) -> Array | None:
            return None if v is None else _full(_sample(times, _cast(v, state), t, self.interpolation), state)

        if self.torque is not None:
            _no_torque_for_particles("TimeSeriesForce(torque=...)", state)
        return Forces(force=get(self.force), torque=get(self.torque))


@pytree_dataclass
class ExternalForce(ForceModel):
    """Force and torque given as functions of time: ``force(t)``, ``torque(t)`` (world, N / N m).

    Each is a static callable ``t -> (*B, 3)`` or ``(3,)`` array, or ``None``
    (no term compiled). A new function object compiles anew.
    """

    force: Callable[[Any], Float[ArrayLike, "*B 3"]] | None = static_field(default=None)
    torque: Callable[[Any], Float[ArrayLike, "*B 3"]] | None = static_field(default=None)

    def __post_init__(self) -> None:
        for name in ("force", "torque"):
            fn = getattr(self, name)
            if fn is not None and not callable(fn):
                raise TypeError(f"ExternalForce: {name} must be a callable t -> (3,) or (*B, 3) array, or None")

    def _value(self, name: str, state: AnyState, t: Any) -> Array:
        fn = getattr(self, name)
        try:
            a = as_float(fn(t)).astype(state.dtype)
        except TypeError as e:
            raise TypeError(f"ExternalForce: {name}(t) must return a real (3,) or (*B, 3) array: {e}") from None
        want = tuple(state.position.shape)
        ok = broadcasts_to(tuple(a.shape), want)
        if not ok:
            raise ValueError(
                f"ExternalForce: {name}(t) returned shape {tuple(a.shape)}, which does not broadcast to the "
                f"state's {want}; return a (3,) or (*batch shape, 3) array"
            )
        return jnp.broadcast_to(a, want)

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        f = None if self.force is None else self._value("force", state, t)
        if self.torque is None:
            return Forces(force=f)
        _no_torque_for_particles("ExternalForce(torque=...)", state)
        return Forces(force=f, torque=self._value("torque", state, t))


@pytree_dataclass
class CustomForce(ForceModel):
    """A user's force law ``fn(state, t) -> Forces`` or, with ``params``, ``fn(state, t, params)``.

    ``fn`` is static (hash by identity); ``params`` is any pytree of arrays and is
    differentiated through like every other model's leaves. Return world-frame
    ``Forces`` of shape ``(*B, 3)``; ``torque=None`` keeps the step torque-free.
    """

    fn: Callable[..., Forces] = static_field()
    params: Any = None

    def __post_init__(self) -> None:
        if not callable(self.fn):
            raise TypeError(f"CustomForce: fn must be a callable fn(state, t[, params]) -> Forces, got {self.fn!r:.60}")

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        return self.fn(state, t) if self.params is None else self.fn(state, t, self.params)
