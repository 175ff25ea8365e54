"""State pytrees (the notes' two simulation columns and particles) and forces.

All vectors are in the world frame unless a name says otherwise; SI units
(m, m/s, kg m²/s, N, N m). Batch dimensions lead; see :mod:`rbjax._batching`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar, Union

import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from ._body import Body, as_float, finite_float, floats, inertia_of
from ._math import (
    array_arg,
    check_rotations,
    check_unit_quaternions,
    cross,
    is_concrete,
    matrix_to_quat_unchecked,
    matvec3,
    quat_rotate_inverse_unchecked,
    quat_rotate_unchecked,
    quat_to_matrix_unchecked,
    quat_tolerance,
)
from ._pytree import core_shape_of, field, is_batch_last, pytree_dataclass, replace, with_batch_last
from ._rotors import Rotors, convert_rotors, rotor_rates_of
from ._trajectory import BatchIndexing
from ._typing import ArrayLike, array_like, optional_array_like

__all__ = [
    "Forces",
    "MatrixState",
    "ParticleState",
    "RigidState",
    "RigidStateT",
    "State",
    "StateT",
    "quat_tolerance",
    "split_constants",
]


def _check_vectors(cls: str, **arrays: Array | None) -> None:
    """``ValueError`` unless each array ends in its field's declared single-body shape and is finite."""
    for name, a in arrays.items():
        if a is None:
            continue
        want = _CORE_SHAPES[name]
        if a.shape[a.ndim - len(want) :] != want:
            raise ValueError(f"{cls}: {name} must end in {want}, got shape {a.shape}")
        if is_concrete(a) and not np.all(np.isfinite(np.asarray(a))):
            raise ValueError(f"{cls}: {name} must be finite, got non-finite entries")


def _convert_and_check(obj: Any) -> None:
    """In ``__post_init__``: convert the array fields (:func:`_convert`), check the vectors (:func:`_check_vectors`)."""
    shapes = core_shape_of(type(obj))
    names = [n for n in shapes if n != "time"]
    _convert(obj, *names)
    _check_vectors(type(obj).__name__, **{n: getattr(obj, n) for n in names if shapes[n]})


def _convert(obj: Any, *names: str) -> None:
    """In ``__post_init__``: array-likes (nested lists too) as float arrays of one dtype, with ``time`` and ``body``.

    The dtype follows :func:`_dtype_of` (the rule of :class:`State`): a float32
    state built from float32 arrays and Python lists stays float32, and a
    float32 body in a float64 state is cast to float64, so every leaf shares it.
    """
    body = getattr(obj, "body", None)
    dtype = _dtype_of(body, *(getattr(obj, n) for n in names))
    floats(obj, *names)
    for n in names:
        a = getattr(obj, n)
        if a.dtype != dtype and not isinstance(a, jax.core.Tracer):
            object.__setattr__(obj, n, a.astype(dtype))
    if body is not None:
        object.__setattr__(obj, "body", _body_as(body, dtype))
    convert_rotors(obj, dtype)
    batch = getattr(obj, names[0]).shape[:-1]
    # one clock per body, so that slicing every leaf of a batch (jax.tree.map) keeps it
    t = _time(type(obj).__name__, obj.time, dtype, batch)
    object.__setattr__(obj, "time", t)


def _typed(x: Any) -> Any:
    """The float dtype ``x`` asserts, or ``None``.

    NumPy and JAX float arrays (and NumPy float scalars) assert theirs; Python
    numbers, (nested) lists and tuples, integer arrays and weakly typed JAX
    values do not: they take the dtype of the arrays they are combined with.
    """
    if isinstance(x, (np.ndarray, np.generic)):
        return x.dtype if np.issubdtype(x.dtype, np.floating) else None
    if isinstance(x, (jax.Array, jax.core.Tracer)):
        weak = getattr(x, "weak_type", False) or getattr(getattr(x, "aval", None), "weak_type", False)
        return None if weak or not jnp.issubdtype(x.dtype, jnp.floating) else x.dtype
    return None


def _dtype_of(body: Body | None, *xs: Any) -> Any:
    """The one float dtype of a state: ``result_type`` of the float arrays among ``xs`` and the body's.

    Python numbers and lists are weakly typed (see :func:`_typed`); with no
    typed array at all, the default float dtype (float64 under x64, else
    float32). ``TypeError`` for an argument that is not a real number or array.
    """
    for x in xs:
        if x is not None:
            as_float(x)  # TypeError in rbjax's words for strings, complex, float16, ...
    typed = [d for d in (_typed(x) for x in xs if x is not None) if d is not None]
    if body is not None:
        typed.append(body.mass.dtype)
    # NumPy's promotion of the dtypes themselves (float32 with float64 is float64), which JAX's strict
    # promotion mode would refuse; canonical, so float64 means float32 without x64
    return jax.dtypes.canonicalize_dtype(np.result_type(*typed)) if typed else jnp.result_type(float)


def _body_as(body: Body, dtype: Any) -> Body:
    """``body`` with its arrays in ``dtype`` (the state's): one dtype per state."""
    return body if body.mass.dtype == dtype else jax.tree.map(lambda a: a.astype(dtype), body)


def _time(cls: str, time: Any, dtype: Any, shape: tuple[int, ...]) -> Array:
    """``time`` (s) as ``dtype`` broadcast to the batch ``shape``; ``TypeError``/``ValueError`` naming it otherwise."""
    t = finite_float(cls, "time", time)
    try:
        return jnp.broadcast_to(t.astype(dtype), shape)
    except ValueError:
        raise ValueError(
            f"{cls}: time of shape {t.shape} does not broadcast to the batch shape {shape}; give one time "
            "(a scalar, in seconds) or one per body"
        ) from None


def _vec(x: ArrayLike | None, default: tuple[float, ...], dtype: Any) -> Array:
    return jnp.asarray(default if x is None else as_float(x), dtype=dtype)


def _kinematics(body: Body, position: Any, velocity: Any, orientation: Any, angular_velocity: Any) -> tuple:
    """``create``'s arguments in the state's dtype: the body, and ``x``, ``v``, orientation, ``ω`` as arrays.

    Missing ones are zero, and the identity quaternion ``[1, 0, 0, 0]`` for the orientation.
    """
    dtype = _dtype_of(body, position, velocity, orientation, angular_velocity)
    return (
        _body_as(body, dtype),
        _vec(position, (0.0, 0.0, 0.0), dtype),
        _vec(velocity, (0.0, 0.0, 0.0), dtype),
        _vec(orientation, (1.0, 0.0, 0.0, 0.0), dtype),
        _vec(angular_velocity, (0.0, 0.0, 0.0), dtype),
    )


def _batch(cls: str, body_shape: tuple[int, ...] | None, **shapes: tuple[int, ...]) -> tuple[int, ...]:
    """The broadcast batch shape of ``create``'s arguments; ``ValueError`` naming each one's otherwise."""
    named = ({"body": body_shape} if body_shape is not None else {}) | shapes
    try:
        return tuple(jnp.broadcast_shapes(*named.values()))
    except ValueError:
        listed = ", ".join(f"{k} {v}" for k, v in named.items())
        raise ValueError(
            f"{cls}: the batch shapes do not broadcast ({listed}); give each argument the batch shape "
            "B or a trailing part of it"
        ) from None


class _StateBase(BatchIndexing):
    """What the state types share: the batch shape and dtype, read from ``position``, and ``constant_fields``."""

    #: Fields that no integrator method changes: carried outside a time loop (see
    #: :func:`split_constants`). ``time`` is among them because a method is given
    #: ``t`` as an argument; ``step`` and ``simulate`` advance it.
    constant_fields: ClassVar[tuple[str, ...]] = ("body", "time")

    if TYPE_CHECKING:
        position: Array

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading batch shape ``B`` (``()`` for a single body); trailing in a batch-last state
        (:mod:`rbjax._batching`)."""
        return tuple(self.position.shape[1:] if is_batch_last(self) else self.position.shape[:-1])

    @property
    def dtype(self) -> Any:
        """Floating dtype of the state's arrays (float32 or float64)."""
        return self.position.dtype


_Rigid = TypeVar("_Rigid", bound="_RigidStateBase")  # create returns the class it is called on
_Rotor = Union[tuple[Rotors, Array], None]  # a gyrostat's rotors and their momenta (*B, k), or none


class _RigidStateBase(_StateBase):
    """What :class:`State` and :class:`MatrixState` share beyond :class:`_StateBase`: the body's mass."""

    if TYPE_CHECKING:
        body: Body

    @property
    def mass(self) -> Array:
        """Mass ``m`` (kg) of each body: ``(*B,)``, or the shared body's shape (broadcasts to ``(*B,)``)."""
        return self.body.mass

    @classmethod
    def create(
        cls: type[_Rigid],
        body: Body,
        *,
        position: Float[ArrayLike, "*B 3"] | None = None,
        velocity: Float[ArrayLike, "*B 3"] | None = None,
        orientation: Float[ArrayLike, "*B 4"] | Float[ArrayLike, "*B 3 3"] | None = None,
        angular_velocity: Float[ArrayLike, "*B 3"] | None = None,
        time: Float[ArrayLike, ""] = 0.0,
        rotors: Rotors | None = None,
        rotor_rates: Float[ArrayLike, "*B k"] | None = None,
    ) -> _Rigid:
        """State from kinematic quantities; missing ones are zero / identity.

        ``position`` ``x`` (m) and ``velocity`` ``v`` (m/s) are world-frame;
        ``orientation`` (body to world) is a unit quaternion ``[w, x, y, z]``
        ``(*B, 4)`` or a rotation matrix ``(*B, 3, 3)``; ``angular_velocity``
        ``ω`` is world-frame (rad/s). :class:`State` stores the momentum
        ``L = R I_L Rᵀ ω`` and the quaternion, :class:`MatrixState` ``ω`` and
        ``R``. All arguments broadcast against the body's batch shape; ``time``
        (s) is the state's ``t``.

        ``rotors`` (:class:`rbjax.Rotors`) makes the body a gyrostat, its rotors
        spinning at ``rotor_rates`` ``Ω`` ``(*B, k)`` (rad/s, relative to the body;
        default zero): the state carries ``rotor_momentum`` ``h_k = J_k Ω_k``
        (kg m²/s), and the angular momentum is the total ``L = R (I ω_b + h)``
        with ``h = Σ_k h_k a_k`` (body frame).
        """
        where = f"{cls.__name__}.create"
        if rotors is None and rotor_rates is not None:
            raise ValueError(f"{where}: rotor_rates were given without rotors; give rotors=rb.Rotors(axes, inertia)")
        if rotors is not None and not isinstance(rotors, Rotors):
            raise TypeError(f"{where}: rotors must be an rbjax.Rotors, got {type(rotors).__name__}")
        body, x, v, o, w = _kinematics(body, position, velocity, orientation, angular_velocity)
        if is_concrete(o) and not np.all(np.isfinite(np.asarray(o))):
            raise ValueError(f"{where}: orientation must be finite, got non-finite entries")
        if o.shape[-1:] == (4,):
            check_unit_quaternions(where, "orientation", o)
        elif o.shape[-2:] == (3, 3):
            check_rotations(where, "orientation", o)
        else:
            raise ValueError(
                f"{where}: orientation must end in (4,) (a unit quaternion [w, x, y, z]) or (3, 3) "
                f"(a rotation matrix), got shape {o.shape}"
            )
        _check_vectors(where, position=x, velocity=v, angular_velocity=w)
        vectors = dict(position=x.shape[:-1], velocity=v.shape[:-1], angular_velocity=w.shape[:-1])
        orientation_batch = o.shape[:-1] if o.shape[-1:] == (4,) else o.shape[:-2]
        if rotors is None:
            shape = _batch(where, body.batch_shape, **vectors, orientation=orientation_batch)
            return cls._from_kinematics(body, x, v, o, w, _time(where, time, x.dtype, shape))
        rotors, rates = rotor_rates_of(where, rotors, rotor_rates, x.dtype)
        rotor_batch = dict(rotors=rotors.inertia.shape[:-1], rotor_rates=rates.shape[:-1])
        shape = _batch(where, body.batch_shape, **vectors, orientation=orientation_batch, **rotor_batch)
        h = jnp.broadcast_to(rotors.inertia * rates, shape + rates.shape[-1:])
        t = _time(where, time, x.dtype, shape)
        return cls._from_kinematics(body, x, v, o, w, t, (rotors, h))

    @classmethod
    def _from_kinematics(
        cls: type[_Rigid], body: Body, x: Array, v: Array, o: Array, w: Array, t: Array, rotor: _Rotor = None
    ) -> _Rigid:
        """The state from ``create``'s checked arrays, broadcast to ``t``'s batch shape ``B``.

        ``o``: a unit quaternion ``(..., 4)`` or a rotation matrix ``(..., 3, 3)``;
        ``rotor``: the rotors and their momenta ``h`` ``(*B, k)``, or ``None``.
        """
        raise NotImplementedError


@pytree_dataclass
class State(_RigidStateBase):
    """Rigid-body state in the notes' ``(x, v, q, L)`` form.

    Attributes:
        body: mass properties (:class:`Body`), per body or shared by the batch.
        position: ``(*B, 3)`` centre of mass ``x`` (world, m).
        velocity: ``(*B, 3)`` centre-of-mass velocity ``v`` (world, m/s).
        orientation: ``(*B, 4)`` unit quaternion ``q = [w, x, y, z]``, body to world.
        angular_momentum: ``(*B, 3)`` ``L`` about the centre of mass (world, kg m²/s);
            of a gyrostat, the total of body and rotors.
        time: ``(*B,)`` time ``t`` (s) of each state; the bodies of a batch that
            is stepped together share one clock. ``step`` advances it by ``dt``;
            ``simulate`` starts from it, so continuing a run needs no ``t0``.
        rotors: :class:`rbjax.Rotors` (axes, axial inertias) of a gyrostat, or
            ``None`` (default: a plain rigid body, no pytree leaves).
        rotor_momentum: ``(*B, k)`` rotor momenta ``h_k = J_k Ω_k`` (kg m²/s)
            relative to the body, or ``None`` (with ``rotors``).

    The angular velocity is derived: ``ω = I_w⁻¹ L`` with ``I_w = R I_L Rᵀ``;
    with rotors ``ω = R I_L⁻¹ (Rᵀ L - h)``, ``h = Σ_k h_k a_k`` (body frame;
    see :mod:`rbjax._rotors`).
    Direct construction takes array-likes (nested lists too) and validates shapes,
    finiteness and ``‖q‖ = 1`` (tolerance :func:`quat_tolerance`) when values
    are concrete.

    One dtype: every leaf (the body's too) has the state's dtype, the NumPy
    promotion (``result_type``) of the float arrays given (NumPy or JAX, the
    body's included); Python numbers and lists, integer arrays and ``time``
    take it. So a float32 body with float32 arrays and Python lists is a
    float32 state, and a float32 body with a float64 array (under x64) a
    float64 state with its body cast. With no float array at all, the default
    float dtype (float64 under x64, else float32). The same rule holds for
    :class:`MatrixState` and :class:`ParticleState` and their ``create``.
    """

    body: Body
    position: Float[Array, "*B 3"] = field(core_shape=(3,), converter=array_like)
    velocity: Float[Array, "*B 3"] = field(core_shape=(3,), converter=array_like)
    orientation: Float[Array, "*B 4"] = field(core_shape=(4,), converter=array_like)
    angular_momentum: Float[Array, "*B 3"] = field(core_shape=(3,), converter=array_like)
    time: Float[Array, "*B"] = field(core_shape=(), default=0.0, converter=array_like)
    rotors: Rotors | None = None
    rotor_momentum: Float[Array, "*B k"] | None = field(core_ndim=1, default=None, converter=optional_array_like)

    constant_fields: ClassVar[tuple[str, ...]] = ("body", "rotors", "time")

    def __post_init__(self) -> None:
        _convert_and_check(self)
        check_unit_quaternions("State", "orientation", self.orientation)

    @classmethod
    def _from_kinematics(
        cls, body: Body, x: Array, v: Array, o: Array, w: Array, t: Array, rotor: _Rotor = None
    ) -> State:
        q = o if o.shape[-1:] == (4,) else matrix_to_quat_unchecked(o)
        w_b = quat_rotate_inverse_unchecked(q, w)
        if rotor is None:
            L = quat_rotate_unchecked(q, matvec3(inertia_of(body), w_b))
        else:
            rotors, h = rotor
            hb = jnp.einsum("...k,...kj->...j", h, rotors.axes)  # Σ_k h_k a_k, per body or shared axes
            L = quat_rotate_unchecked(q, matvec3(inertia_of(body), w_b) + hb)
        bc = lambda a: jnp.broadcast_to(a, t.shape + a.shape[-1:])
        rotors, h = (None, None) if rotor is None else rotor
        return cls(body, bc(x), bc(v), bc(q), bc(L), t, rotors, h)


@pytree_dataclass
class MatrixState(_RigidStateBase):
    """Rigid-body state in the notes' ``(x, v, R, ω)`` form.

    Attributes:
        body: mass properties (:class:`Body`).
        position: ``(*B, 3)`` centre of mass (world, m).
        velocity: ``(*B, 3)`` centre-of-mass velocity (world, m/s).
        rotation: ``(*B, 3, 3)`` rotation matrix ``R``, body to world (columns are
            the body axes in world coordinates).
        angular_velocity: ``(*B, 3)`` ``ω`` (world, rad/s).
        time: ``(*B,)`` time ``t`` (s), as in :class:`State`.
        rotors: :class:`rbjax.Rotors` of a gyrostat, or ``None``, as in :class:`State`.
        rotor_momentum: ``(*B, k)`` ``h_k = J_k Ω_k`` (kg m²/s), or ``None``, as in :class:`State`.

    With rotors, Euler's equation (body frame) is
    ``I ω̇_b = Rᵀ τ - ω_b × (I ω_b + h) - ḣ`` (:mod:`rbjax._rotors`).
    """

    body: Body
    position: Float[Array, "*B 3"] = field(core_shape=(3,), converter=array_like)
    velocity: Float[Array, "*B 3"] = field(core_shape=(3,), converter=array_like)
    rotation: Float[Array, "*B 3 3"] = field(core_shape=(3, 3), converter=array_like)
    angular_velocity: Float[Array, "*B 3"] = field(core_shape=(3,), converter=array_like)
    time: Float[Array, "*B"] = field(core_shape=(), default=0.0, converter=array_like)
    rotors: Rotors | None = None
    rotor_momentum: Float[Array, "*B k"] | None = field(core_ndim=1, default=None, converter=optional_array_like)

    constant_fields: ClassVar[tuple[str, ...]] = ("body", "rotors", "time")

    def __post_init__(self) -> None:
        _convert_and_check(self)
        check_rotations("MatrixState", "rotation", self.rotation)

    @classmethod
    def _from_kinematics(
        cls, body: Body, x: Array, v: Array, o: Array, w: Array, t: Array, rotor: _Rotor = None
    ) -> MatrixState:
        R = quat_to_matrix_unchecked(o) if o.shape[-1:] == (4,) else o
        bc = lambda a: jnp.broadcast_to(a, t.shape + a.shape[-1:])
        Rb = jnp.broadcast_to(R, t.shape + (3, 3))
        rotors, h = (None, None) if rotor is None else rotor
        return cls(body, bc(x), bc(v), Rb, bc(w), t, rotors, h)


def check_particle_mass(mass: Any, owner: str = "ParticleState", name: str = "mass") -> None:
    """Raise ``ValueError`` unless the concrete particle masses (kg) are finite and ``> 0``.

    :class:`ParticleState` and :func:`rbjax.load` both call it; ``owner`` starts the
    message and ``name`` is what it calls the array.
    """
    m = np.asarray(mass)
    if not np.all(np.isfinite(m)) or np.any(m <= 0):
        raise ValueError(f"{owner}: {name} must be finite and > 0, got {m[~(np.isfinite(m) & (m > 0))].ravel()[:3]}")


@pytree_dataclass
class ParticleState(_StateBase):
    """Point masses (the notes' first slide): no orientation, nothing rotational.

    Attributes:
        position: ``(*B, 3)`` (world, m).
        velocity: ``(*B, 3)`` (world, m/s).
        mass: ``(*B,)`` kg, > 0.
        time: ``(*B,)`` time ``t`` (s), as in :class:`State`.
    """

    position: Float[Array, "*B 3"] = field(core_shape=(3,), converter=array_like)
    velocity: Float[Array, "*B 3"] = field(core_shape=(3,), converter=array_like)
    mass: Float[Array, "*B"] = field(core_shape=(), converter=array_like)
    time: Float[Array, "*B"] = field(core_shape=(), default=0.0, converter=array_like)

    constant_fields: ClassVar[tuple[str, ...]] = ("mass", "time")

    def __post_init__(self) -> None:
        _convert_and_check(self)
        if is_concrete(self.mass):
            check_particle_mass(self.mass)

    @classmethod
    def create(
        cls,
        mass: Float[ArrayLike, "*B"],
        *,
        position: Float[ArrayLike, "*B 3"] | None = None,
        velocity: Float[ArrayLike, "*B 3"] | None = None,
        time: Float[ArrayLike, ""] = 0.0,
    ) -> ParticleState:
        """Particles from mass (kg), optional position and velocity (zeros) and time (s)."""
        m = as_float(mass)
        dtype = _dtype_of(None, mass, position, velocity)
        x = _vec(position, (0.0, 0.0, 0.0), dtype)
        v = _vec(velocity, (0.0, 0.0, 0.0), dtype)
        _check_vectors("ParticleState.create", position=x, velocity=v)
        shape = _batch("ParticleState.create", None, mass=m.shape, position=x.shape[:-1], velocity=v.shape[:-1])
        return cls(
            jnp.broadcast_to(x, shape + (3,)),
            jnp.broadcast_to(v, shape + (3,)),
            jnp.broadcast_to(m.astype(dtype), shape),
            _time("ParticleState.create", time, dtype, shape),
        )


RigidState = Union[State, MatrixState]
AnyState = Union[State, MatrixState, ParticleState]
# a function returning "the same state type as its input" (step, simulate, ...)
StateT = TypeVar("StateT", bound=AnyState)
RigidStateT = TypeVar("RigidStateT", bound=RigidState)


def split_constants(state: Any) -> tuple[Any, dict[str, Any]]:
    """``(changing, constants)``: ``state`` with its ``constant_fields`` set to ``None``, and those fields by name.

    A time loop carries ``changing`` and closes over ``constants``: the body's
    per-call set-up stays loop-invariant, and a shared body is not copied per
    step. ``replace(changing, **constants)`` is the state again.
    """
    constants = {n: getattr(state, n) for n in state.constant_fields}
    return replace(state, **dict.fromkeys(constants)), constants


@pytree_dataclass
class Forces:
    """Applied force and torque, world frame.

    Attributes:
        force: ``(*B, 3)`` net force on the centre of mass (N), or ``None`` for none.
        torque: ``(*B, 3)`` net torque about the centre of mass (N m), or ``None``.
        rotor_torque: ``(*B, k)`` torques on a gyrostat's rotors (N m), or ``None``:
            ``τ_k = ḣ_k``, the rate of rotor ``k``'s momentum relative to the body.
            Internal: it changes the rotor momenta, never the total ``L``. The
            motor's own torque is ``τ_k + J_k a_k · ω̇_b`` (see :mod:`rbjax._rotors`).
            Only for states with ``rotors``.

    ``None`` is static: a step given ``Forces(force=f)`` compiles no torque work.
    Forces add with ``+``.
    """

    force: Float[Array, "*B 3"] | None = field(core_shape=(3,), default=None, converter=optional_array_like)
    torque: Float[Array, "*B 3"] | None = field(core_shape=(3,), default=None, converter=optional_array_like)
    rotor_torque: Float[Array, "*B k"] | None = field(core_ndim=1, default=None, converter=optional_array_like)

    def __post_init__(self) -> None:
        floats(self, "force", "torque", "rotor_torque")
        _check_vectors("Forces", force=self.force, torque=self.torque)
        if self.rotor_torque is not None and self.rotor_torque.ndim < 1:
            raise ValueError("Forces: rotor_torque must end in (k,), one torque (N m) per rotor, got a scalar")

    @classmethod
    def at_point(cls, force: Float[ArrayLike, "*B 3"], point: Float[ArrayLike, "*B 3"], state: AnyState) -> Forces:
        """Force ``F`` (N, world) applied at world point ``p`` (m): torque ``τ = (p - x) × F`` (N m).

        ``force``, ``point``: ``(*B, 3)`` or ``(3,)``, broadcast against the state's positions ``(*B, 3)``.
        """
        f = array_arg("Forces.at_point", "force", force, (3,)).astype(state.dtype)
        p = array_arg("Forces.at_point", "point", point, (3,)).astype(state.dtype)
        _batch("Forces.at_point", None, force=f.shape[:-1], point=p.shape[:-1], state=state.batch_shape)
        return cls(force=f, torque=cross(p - state.position, f))

    @classmethod
    def gravity(
        cls, state: AnyState, g: Float[ArrayLike, " 3"] | tuple[float, float, float] = (0.0, 0.0, -9.81)
    ) -> Forces:
        """Uniform gravity ``F = m g`` (world frame, m/s²), no torque.

        ``g``: ``(3,)`` or ``(*B, 3)`` acceleration vector (a scalar is refused, as by
        :class:`rbjax.Gravity`); returns ``force`` ``(*B, 3)`` in N.
        """
        m = state.mass
        try:
            g = as_float(g).astype(state.dtype)
        except TypeError as e:
            raise TypeError(f"Forces.gravity: g: {e}") from None
        if g.shape[-1:] != (3,):
            raise ValueError(
                f"Forces.gravity: g must be a (3,) acceleration vector in m/s² (e.g. (0, 0, -9.81)), got shape "
                f"{tuple(g.shape)}"
            )
        if _batch("Forces.gravity", None, state=state.batch_shape, g=g.shape[:-1]) != state.batch_shape:
            raise ValueError(
                f"Forces.gravity: g of shape {tuple(g.shape)} does not fit the state's batch shape {state.batch_shape}"
            )
        return cls(force=jnp.broadcast_to(m[..., None] * g, state.position.shape))

    def __add__(self, other: Forces) -> Forces:
        if not isinstance(other, Forces):  # a force model's __radd__ says how to combine the two
            return NotImplemented

        def add(a: Array | None, b: Array | None) -> Array | None:
            if a is None:
                return b
            if b is None:
                return a
            return a + b

        # both were checked when built; their sum is not re-checked, so that it also adds the
        # batch-last (3, *B) forces of simulate's scan, and is batch-last when either is (the other
        # then has no batch dimensions: an empty Forces() or a shared one)
        total = replace(
            self,
            force=add(self.force, other.force),
            torque=add(self.torque, other.torque),
            rotor_torque=add(self.rotor_torque, other.rotor_torque),
        )
        return with_batch_last(total, is_batch_last(self) or is_batch_last(other))


ForceLike = Union[Forces, Callable[[Any, Array], Forces], None]

# every vector field's single-body shape, by name, as its class declares it (the names agree across classes)
_CORE_SHAPES: dict[str, tuple[int, ...]] = {
    name: shape for cls in (State, MatrixState, ParticleState, Forces) for name, shape in core_shape_of(cls).items()
}
