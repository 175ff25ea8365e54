"""Force models attached to bodies named by index: :class:`Spring` and :class:`Thruster`.

They act at points fixed in the bodies (body frame), so the world offset ``r = R p`` of each
point and its velocity ``v + ω × r`` are gathered from the bodies named, and the forces and
torques are scattered back onto them. They need a one-dimensional batch ``(N,)``; each index
must be in ``0..N-1`` (checked before tracing by :func:`rbjax.simulate`, :func:`rbjax.step`
and :class:`rbjax.Scene`, and at run time in checked mode). Conventions as in
:mod:`rbjax._forces`.
"""

from __future__ import annotations

import functools
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import NamedSharding, PartitionSpec
from jaxtyping import Float, Int

from ._body import floats
from ._deprecated import move_renamed_keywords, renamed_keywords, warn_deprecated
from ._force_checks import cast_to, check_core, check_fits, check_non_negative, rigid_only
from ._force_model import ForceModel, PerBodyForce
from ._math import cross, is_concrete, matvec3, quat_rotate_unchecked, safe_norm, scale3
from ._pytree import field
from ._quantities import angular_velocity
from ._state import AnyState, Forces, MatrixState, ParticleState, RigidState, State
from ._typing import ArrayLike, array_like, optional_array_like

__all__ = ["Spring", "Thruster"]


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
    p = cast_to(point, state)
    if isinstance(state, State):
        return quat_rotate_unchecked(_gather(state.orientation, idx), p)
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
    if is_concrete(i) and np.any(np.asarray(i) < 0):
        raise ValueError(
            f"{model}: {name} must be body indices >= 0 (a negative index would count from the end), got "
            f"{np.asarray(i)[np.asarray(i) < 0][:4]}"
        )
    return i


def _indices_in(model: Any, name: str, n: int) -> None:
    """``ValueError`` unless the (concrete) indices of field ``name`` are ``< n``, the batch size."""
    i = getattr(model, name)
    if i is None or not is_concrete(i) or i.size == 0:
        return
    top = int(np.max(np.asarray(i)))
    if top >= n:
        label = model._FIELD_LABELS.get(name, name)
        raise ValueError(
            f"{type(model).__name__}: {label} index {top} is outside the batch of {n} bodies "
            f"(indices 0..{n - 1}); an index past the end would be dropped or clamped silently"
        )


def _per_item(model: Any, s: int, vectors: tuple[str, ...], scalars: tuple[str, ...]) -> None:
    """Shapes of a model of ``s`` items: ``vectors`` ``(S, 3)`` or ``(3,)``, ``scalars`` ``(S,)`` or ``()``."""
    items = f"the number of {type(model).__name__.lower()}s S (the length of body_index)"
    for name in vectors:
        check_core(model, name, (3,), " (a 3-vector each)")
        check_fits(model, name, 1, (s,), items)
    for name in scalars:
        check_fits(model, name, 0, (s,), items)


class _RenamedKeywords:
    """Base of a force model whose constructor also takes, for one release, the old keywords
    ``_RENAMED`` (old name -> field) with a ``DeprecationWarning``; its subclasses too.

    A force model writes no ``__init__`` (:class:`ForceModel` makes it a dataclass), so the
    dataclass's own one is wrapped once the class is made.
    """

    _RENAMED: ClassVar[dict[str, str]] = {}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)  # ForceModel's: cls is a dataclass from here on
        init, renames, where = cls.__init__, cls._RENAMED, cls.__name__

        @functools.wraps(init)
        def __init__(self: Any, *args: Any, **kw: Any) -> None:
            # the user's call is 3 frames up: this, the force-model metaclass's __call__, the call
            move_renamed_keywords(kw, renames, where, stacklevel=3)
            init(self, *args, **kw)

        cls.__init__ = __init__


def _deprecated_field(cls: str, old: str, new: str) -> property:
    """Read-only ``old``, the field's name before it was ``new``, with a ``DeprecationWarning``."""

    def get(self: Any) -> Any:
        warn_deprecated(
            f"{cls}.{old} is deprecated and will be removed in the next release; use {cls}.{new} (the same array)",
            stacklevel=2,
        )
        return getattr(self, new)

    return property(get, doc=f"Deprecated spelling of :attr:`{new}`.")


class Spring(_RenamedKeywords, ForceModel):
    """Springs (with optional linear dampers) from body points to world anchors or other bodies.

    Spring ``s`` joins point ``a`` (``point`` in body ``body_index[s]``'s frame, or
    its centre of mass if ``point`` is ``None``) to point ``b``: the world
    ``anchor`` if ``other_index`` is ``None``, else ``anchor`` in body
    ``other_index[s]``'s frame (its centre of mass if ``anchor`` is ``None``). With ``d = x_b - x_a`` (world):

        F_a = k (1 - l₀/‖d‖) d + c (v_b - v_a),      F_b = -F_a,
        τ_a = r_a × F_a,  τ_b = r_b × F_b,           r = R p (world offset),

    so a zero-length spring is ``F_a = k d``. ``v = v_com + ω × r`` is the point
    velocity; the damper is a vector dashpot on the relative velocity. Equal and
    opposite forces conserve total linear momentum; the spring force is central
    (along ``d``), so without damping total angular momentum is conserved too.
    The dashpot is not central (``v_b - v_a`` need not be along ``d``): with
    ``damping`` the springs exert a net torque ``(p_a - p_b) × F_a`` on the
    pair and total angular momentum changes.

    Shapes (``S`` springs): ``body_index``, ``other_index``: ``(S,)`` int, each ``>= 0`` and
    ``< N`` (checked when simulated); ``point``, ``anchor``: ``(S, 3)`` or
    ``(3,)`` m; ``stiffness`` ``k`` N/m, ``rest_length`` ``l₀`` m, ``damping``
    ``c`` N s/m: ``(S,)`` or scalars, each ``>= 0``. Build with :meth:`to_anchor`
    or :meth:`between`. Points at the centre of mass (``None``) add no torque
    and no rotation work; with both ends there the model returns ``torque=None``.
    """

    body_index: Int[Array, " S"] = field(converter=array_like)
    stiffness: Float[Array, "*S"] = field(converter=array_like)
    point: Float[Array, "S 3"] | None = field(default=None, converter=optional_array_like)
    anchor: Float[Array, "S 3"] | None = field(default=None, converter=optional_array_like)
    other_index: Int[Array, " S"] | None = field(default=None, converter=optional_array_like)
    rest_length: Float[Array, "*S"] = field(default=0.0, converter=array_like)
    damping: Float[Array, "*S"] | None = field(default=None, converter=optional_array_like)
    _INDEX_FIELDS = ("body_index", "other_index")
    _NON_NEGATIVE = ("stiffness", "rest_length", "damping")
    _FIELD_LABELS = {"other_index": "other_index (index_b of Spring.between)"}
    _RENAMED = {"body": "body_index", "other": "other_index"}
    body = _deprecated_field("Spring", "body", "body_index")
    other = _deprecated_field("Spring", "other", "other_index")

    def __check_init__(self) -> None:
        object.__setattr__(self, "body_index", _as_index("Spring", "body_index", self.body_index))
        if self.other_index is not None:
            object.__setattr__(self, "other_index", _as_index("Spring", "other_index", self.other_index))
            if self.other_index.shape != self.body_index.shape:
                raise ValueError(
                    f"Spring: body_index {tuple(self.body_index.shape)} and other_index "
                    f"{tuple(self.other_index.shape)} must name the same number of springs"
                )
        elif self.anchor is None:
            raise ValueError("Spring: a world anchor is required when other_index is None")
        floats(self, "stiffness", "point", "anchor", "rest_length", "damping")
        _per_item(self, self.body_index.shape[0], ("point", "anchor"), ("stiffness", "rest_length", "damping"))
        check_non_negative(self, "stiffness", "rest_length", "damping")

    def check(self, state: AnyState) -> None:
        n = _check_flat("Spring", state)
        _indices_in(self, "body_index", n)
        _indices_in(self, "other_index", n)

    @classmethod
    @renamed_keywords("Spring.to_anchor", body="body_index")
    def to_anchor(
        cls,
        body_index: Int[ArrayLike, " S"],
        anchor: Float[ArrayLike, "S 3"],
        stiffness: Float[ArrayLike, "*S"],
        *,
        point: Float[ArrayLike, "S 3"] | None = None,
        rest_length: Float[ArrayLike, "*S"] = 0.0,
        damping: Float[ArrayLike, "*S"] | None = None,
    ) -> Spring:
        """Springs from points on bodies ``body_index`` (body frame; ``None`` = COM) to world ``anchor`` points."""
        return cls(body_index, stiffness, point=point, anchor=anchor, rest_length=rest_length, damping=damping)

    @classmethod
    @renamed_keywords("Spring.between", body_a="index_a", body_b="index_b")
    def between(
        cls,
        index_a: Int[ArrayLike, " S"],
        index_b: Int[ArrayLike, " S"],
        stiffness: Float[ArrayLike, "*S"],
        *,
        point_a: Float[ArrayLike, "S 3"] | None = None,
        point_b: Float[ArrayLike, "S 3"] | None = None,
        rest_length: Float[ArrayLike, "*S"] = 0.0,
        damping: Float[ArrayLike, "*S"] | None = None,
    ) -> Spring:
        """Springs between points on bodies ``index_a`` and ``index_b`` (each in its own body frame; ``None`` = COM)."""
        return cls(
            index_a,
            stiffness,
            point=point_a,
            anchor=point_b,
            other_index=index_b,
            rest_length=rest_length,
            damping=damping,
        )

    def depends_on_velocity(self) -> bool:
        """Whether a damper reads the ends' velocities: ``damping`` given and not all zero (when concrete)."""
        if self.damping is None:
            return False
        return not is_concrete(self.damping) or bool(np.any(np.asarray(self.damping) != 0))

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        _check_flat("Spring", state)
        rotating = self.point is not None or (self.other_index is not None and self.anchor is not None)
        omega = angular_velocity(rigid_only("Spring(point=...)", state)) if rotating else None
        r_a = _offset(state, self.body_index, self.point)
        x_a, v_a = _point_motion(state, self.body_index, r_a, omega)
        r_b = None
        if self.other_index is None:
            x_b, v_b = cast_to(self.anchor, state), None
        else:
            r_b = _offset(state, self.other_index, self.anchor)
            x_b, v_b = _point_motion(state, self.other_index, r_b, omega)
        d = x_b - x_a
        k = cast_to(self.stiffness, state)[..., None]
        l0 = cast_to(self.rest_length, state)[..., None]
        length = safe_norm(d, keepdims=True)
        # (1 - l0/|d|) d, with a zero force (not NaN) at |d| = 0
        scale = jnp.where(length > 0, 1 - l0 / jnp.where(length > 0, length, 1), 0)
        f_a = k * scale * d
        if self.damping is not None:
            rel = -v_a if v_b is None else v_b - v_a
            f_a = f_a + cast_to(self.damping, state)[..., None] * rel
        f_a = jnp.broadcast_to(f_a, d.shape)
        force = _scatter(state, self.body_index, f_a)
        torque = None if r_a is None else _scatter(state, self.body_index, cross(r_a, f_a))
        if self.other_index is not None:
            force = _add_at(force, self.other_index, -f_a)
            if r_b is not None:
                tb = cross(r_b, -f_a)
                other = self.other_index
                torque = _scatter(state, other, tb) if torque is None else _add_at(torque, other, tb)
        return Forces(force=force, torque=torque)


class Thruster(_RenamedKeywords, ForceModel):
    """Body-fixed thrusters: force ``F = T R d`` at body point ``p``, turning with the body.

    Thruster ``s`` on body ``body_index[s]`` pushes with magnitude ``thrust`` ``T`` (N)
    along the body-frame ``direction`` ``d`` (unit, not renormalised) at the
    body-frame ``point`` ``p`` (m; ``None`` = centre of mass, no torque). World
    force ``F = T R d``, torque about the centre of mass ``τ = (R p) × F``.
    Shapes (``S`` thrusters): ``body_index`` ``(S,)`` int, each ``>= 0`` and ``< N``
    (checked when simulated); ``direction`` (unit: checked when concrete),
    ``point``: ``(S, 3)`` or ``(3,)``; ``thrust`` ``(S,)`` or scalar, of either
    sign (a negative thrust pushes along ``-d``). Rigid states only.

    :func:`rbjax.simulate` (JAX path) steps thrusters whose ``body_index`` is concrete
    (not traced by a caller's ``jit``) and names each body at most once as a
    per-body law inside its step, without the gather and scatter (see
    :meth:`as_per_body`): the same formulas, so the same values.
    """

    body_index: Int[Array, " S"] = field(converter=array_like)
    direction: Float[Array, "S 3"] = field(converter=array_like)
    thrust: Float[Array, "*S"] = field(converter=array_like)
    point: Float[Array, "S 3"] | None = field(default=None, converter=optional_array_like)
    _INDEX_FIELDS = ("body_index",)
    _RENAMED = {"body": "body_index"}
    body = _deprecated_field("Thruster", "body", "body_index")

    def __check_init__(self) -> None:
        object.__setattr__(self, "body_index", _as_index("Thruster", "body_index", self.body_index))
        floats(self, "direction", "thrust", "point")
        _per_item(self, self.body_index.shape[0], ("direction", "point"), ("thrust",))
        d = self.direction
        if is_concrete(d) and d.size:
            err = np.max(np.abs(np.linalg.norm(np.asarray(d, np.float64), axis=-1) - 1))
            tol = max(1e-6, 128 * float(np.finfo(d.dtype).eps))
            if err > tol:
                raise ValueError(
                    f"Thruster: direction must be unit vectors (the thrust gives the magnitude); |‖d‖ - 1| = "
                    f"{err:.3g} exceeds {tol:.3g}: normalise it, d / ‖d‖"
                )

    def check(self, state: AnyState) -> None:
        _indices_in(self, "body_index", _check_flat("Thruster", state))

    def depends_on_velocity(self) -> bool:
        return False

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        _check_flat("Thruster", state)
        if isinstance(state, ParticleState):
            raise ValueError("Thruster: a body-fixed direction needs rigid bodies, not ParticleState")
        d = _to_world(state, self.body_index, self.direction)
        f = cast_to(self.thrust, state)[..., None] * d
        r = _offset(state, self.body_index, self.point)
        force = _scatter(state, self.body_index, f)
        return Forces(force=force, torque=None if r is None else _scatter(state, self.body_index, cross(r, f)))

    def as_per_body(self, state: AnyState) -> PerBodyForce | None:
        """These thrusters as :class:`_OneThrusterPerBody` when ``body_index`` is concrete and names each
        body at most once (the bodies without one get zero thrust along a zero direction), else ``None``."""
        if not is_concrete(self.body_index) or len(state.batch_shape) != 1 or isinstance(state, ParticleState):
            return None
        idx = np.asarray(self.body_index)
        if np.unique(idx).size != idx.size:
            return None
        n, s = state.batch_shape[0], idx.size

        def per_body(a: Array, core: tuple[int, ...]) -> Array:
            a = jnp.broadcast_to(cast_to(a, state), (s, *core))
            return jnp.zeros((n, *core), state.dtype).at[idx].set(a)

        point = None if self.point is None else per_body(self.point, (3,))
        return _OneThrusterPerBody(per_body(self.direction, (3,)), per_body(self.thrust, ()), point)


class _OneThrusterPerBody(PerBodyForce):
    """:class:`Thruster` with at most one thruster on each body, as a per-body law: ``F = T R d`` and
    ``τ = (R p) × F`` (``p`` ``None``: no torque), the same formulas, so the same values.

    ``direction`` ``(N, 3)``, ``thrust`` ``(N,)``, ``point`` ``(N, 3)`` or ``None``, per body
    (body frame, N and m); a body without a thruster has zero ``thrust`` and ``direction``.
    ``simulate`` lifts it inside its step (no gather or scatter by index, no transposes around it).
    """

    direction: Float[Array, "*B 3"] = field(core_shape=(3,))
    thrust: Float[Array, "*B"] = field()
    point: Float[Array, "*B 3"] | None = field(core_shape=(3,), default=None)

    def on_body(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        rigid = rigid_only("Thruster", state)
        f = scale3(self.thrust, _one_to_world(rigid, self.direction))
        return Forces(force=f, torque=None if self.point is None else cross(_one_to_world(rigid, self.point), f))


def _one_to_world(state: RigidState, p: Array) -> Array:
    """``R p`` for one body."""
    return quat_rotate_unchecked(state.orientation, p) if isinstance(state, State) else matvec3(state.rotation, p)
