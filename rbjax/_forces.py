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
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
from jax import Array
from jax.sharding import NamedSharding, PartitionSpec
from jaxtyping import Float, Int

from ._body import _floats
from ._math import cross, quat_rotate, safe_norm
from ._pytree import field, pytree_dataclass, static_field
from ._quantities import angular_velocity
from ._state import AnyState, Forces, MatrixState, ParticleState, RigidState, State, _apply
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

    def __add__(self, other: ForceModel) -> ForceSum:
        if not isinstance(other, ForceModel):
            return NotImplemented
        a = self.terms if isinstance(self, ForceSum) else (self,)
        b = other.terms if isinstance(other, ForceSum) else (other,)
        return ForceSum(a + b)


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

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        total = Forces()
        for term in self.terms:
            total = total + term(state, t)
        return total


@pytree_dataclass
class Gravity(ForceModel):
    """Uniform gravity ``F = m g`` on the centre of mass; no torque.

    ``g``: ``(3,)`` (or ``(*B, 3)``) acceleration, world frame, m/s²; default
    ``(0, 0, -9.81)``.
    """

    g: Float[Array, "*B 3"] = field(core_ndim=1, default=(0.0, 0.0, -9.81))

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(self, g: Float[ArrayLike, "*B 3"] | tuple[float, float, float] = (0.0, 0.0, -9.81)) -> None: ...

    def __post_init__(self) -> None:
        _floats(self, "g")

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        return Forces(force=_full(_mass(state)[..., None] * _cast(self.g, state), state))


@pytree_dataclass
class LinearDrag(ForceModel):
    """Viscous drag ``F = -b v`` and, if ``angular`` is given, ``τ = -b_r ω``.

    ``linear`` ``b``: scalar or ``(*B,)``, N s/m. ``angular`` ``b_r``: scalar or
    ``(*B,)``, N m s, or ``None`` (no torque: the step compiles none). ``v`` is the
    centre-of-mass velocity and ``ω`` the angular velocity, both world frame.
    """

    linear: Float[Array, "*B"] = field(default=0.0)
    angular: Float[Array, "*B"] | None = field(default=None)

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(
            self, linear: Float[ArrayLike, "*B"] = 0.0, angular: Float[ArrayLike, "*B"] | None = None
        ) -> None: ...

    def __post_init__(self) -> None:
        _floats(self, "linear", "angular")

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        f = -_cast(self.linear, state)[..., None] * state.velocity
        if self.angular is None:
            return Forces(force=f)
        rigid = _no_torque_for_particles("LinearDrag(angular=...)", state)
        return Forces(force=f, torque=-_cast(self.angular, state)[..., None] * angular_velocity(rigid))


@pytree_dataclass
class QuadraticDrag(ForceModel):
    """Quadratic drag ``F = -c ‖v‖ v`` and, if ``angular`` is given, ``τ = -c_r ‖ω‖ ω``.

    ``linear`` ``c``: scalar or ``(*B,)``, kg/m (``½ ρ C_d A``). ``angular``
    ``c_r``: kg m², or ``None`` (no torque). World frame. Terminal speed under
    gravity: ``√(m g / c)``.
    """

    linear: Float[Array, "*B"] = field(default=0.0)
    angular: Float[Array, "*B"] | None = field(default=None)

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(
            self, linear: Float[ArrayLike, "*B"] = 0.0, angular: Float[ArrayLike, "*B"] | None = None
        ) -> None: ...

    def __post_init__(self) -> None:
        _floats(self, "linear", "angular")

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
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
        return _apply(_gather(state.rotation, idx), p)
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


def _scatter(n: int, state: AnyState, idx: Array, values: Array) -> Array:
    return _add_at(jnp.zeros_like(state.position), idx, values)


def _as_index(x: ArrayLike) -> Array:
    i = jnp.asarray(x)
    if not jnp.issubdtype(i.dtype, jnp.integer):
        raise ValueError(f"body indices must be integers, got dtype {i.dtype}")
    return jnp.atleast_1d(i)


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
    opposite forces conserve total linear and angular momentum.

    Shapes (``S`` springs): ``body``, ``other``: ``(S,)`` int; ``point``,
    ``anchor``: ``(S, 3)`` m; ``stiffness`` ``k`` N/m, ``rest_length`` ``l₀`` m,
    ``damping`` ``c`` N s/m: ``(S,)`` or scalars. Build with :meth:`to_anchor`
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
        object.__setattr__(self, "body", _as_index(self.body))
        if self.other is not None:
            object.__setattr__(self, "other", _as_index(self.other))
        elif self.anchor is None:
            raise ValueError("Spring: a world anchor is required when other is None")
        _floats(self, "stiffness", "point", "anchor", "rest_length", "damping")

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
        n = _check_flat("Spring", state)
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
        force = _scatter(n, state, self.body, f_a)
        torque = None if r_a is None else _scatter(n, state, self.body, cross(r_a, f_a))
        if self.other is not None:
            force = _add_at(force, self.other, -f_a)
            if r_b is not None:
                tb = cross(r_b, -f_a)
                torque = _scatter(n, state, self.other, tb) if torque is None else _add_at(torque, self.other, tb)
        return Forces(force=force, torque=torque)


@pytree_dataclass
class Thruster(ForceModel):
    """Body-fixed thrusters: force ``F = T R d`` at body point ``p``, turning with the body.

    Thruster ``s`` on body ``body[s]`` pushes with magnitude ``thrust`` ``T`` (N)
    along the body-frame ``direction`` ``d`` (unit, not renormalised) at the
    body-frame ``point`` ``p`` (m; ``None`` = centre of mass, no torque). World
    force ``F = T R d``, torque about the centre of mass ``τ = (R p) × F``.
    Shapes (``S`` thrusters): ``body`` ``(S,)`` int, ``direction``, ``point``
    ``(S, 3)``, ``thrust`` ``(S,)`` or scalar. Rigid states only.
    """

    body: Int[Array, " S"]
    direction: Float[Array, "S 3"]
    thrust: Float[Array, "*S"]
    point: Float[Array, "S 3"] | None = None

    if TYPE_CHECKING:  # __post_init__ converts: the constructor takes array-likes

        def __init__(
            self,
            body: Int[ArrayLike, " S"],
            direction: Float[ArrayLike, "S 3"],
            thrust: Float[ArrayLike, "*S"],
            point: Float[ArrayLike, "S 3"] | None = None,
        ) -> None: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "body", _as_index(self.body))
        _floats(self, "direction", "thrust", "point")

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        n = _check_flat("Thruster", state)
        if isinstance(state, ParticleState):
            raise ValueError("Thruster: a body-fixed direction needs rigid bodies, not ParticleState")
        d = _to_world(state, self.body, self.direction)
        f = _cast(self.thrust, state)[..., None] * d
        r = _offset(state, self.body, self.point)
        force = _scatter(n, state, self.body, f)
        return Forces(force=force, torque=None if r is None else _scatter(n, state, self.body, cross(r, f)))


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
        _floats(self, "force", "torque")

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
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
        _floats(self, "times")
        k = self.times.shape[0] if self.times.ndim == 1 else -1
        for name in ("force", "torque"):
            v = getattr(self, name)
            if v is not None:
                _floats(self, name)
                v = getattr(self, name)
                if v.ndim < 2 or v.shape[0] != k or v.shape[-1] != 3:
                    raise ValueError(
                        f"TimeSeriesForce: {name} must have shape (K={k}, ..., 3) matching times (K,); got {v.shape}"
                    )
                object.__setattr__(self, name, v)

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
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

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        f = None if self.force is None else _full(_cast(self.force(t), state), state)
        if self.torque is None:
            return Forces(force=f)
        _no_torque_for_particles("ExternalForce(torque=...)", state)
        return Forces(force=f, torque=_full(_cast(self.torque(t), state), state))


@pytree_dataclass
class CustomForce(ForceModel):
    """A user's force law ``fn(state, t) -> Forces`` or, with ``params``, ``fn(state, t, params)``.

    ``fn`` is static (hash by identity); ``params`` is any pytree of arrays and is
    differentiated through like every other model's leaves. Return world-frame
    ``Forces`` of shape ``(*B, 3)``; ``torque=None`` keeps the step torque-free.
    """

    fn: Callable[..., Forces] = static_field()
    params: Any = None

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        return self.fn(state, t) if self.params is None else self.fn(state, t, self.params)
