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
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from ._body import as_float, floats
from ._force_checks import cast_to, check_core, check_fits, check_non_negative, full_batch, rigid_only
from ._force_model import ForceModel, PerBodyForce
from ._math import broadcasts_to, is_concrete, norm3, scale3
from ._pytree import field, static_field
from ._quantities import angular_velocity
from ._state import AnyState, Forces, State
from ._typing import ArrayLike, array_like, optional_array_like

__all__ = [
    "Gravity",
    "LinearDrag",
    "QuadraticDrag",
    "ConstantForce",
    "TimeSeriesForce",
    "ExternalForce",
    "CustomForce",
]


class Gravity(PerBodyForce):
    """Uniform gravity ``F = m g`` on the centre of mass; no torque.

    ``g``: ``(3,)`` (or ``(*B, 3)``) acceleration, world frame, m/s²; default
    ``(0, 0, -9.81)``. A scalar is refused (``ValueError``): it would broadcast
    to ``(g, g, g)``; give the vector, e.g. ``(0, 0, -9.81)``.
    """

    g: Float[Array, "*B 3"] = field(core_shape=(3,), default=(0.0, 0.0, -9.81), converter=array_like)

    def __check_init__(self) -> None:
        if self.g is None:
            raise TypeError("Gravity: g must be a (3,) acceleration vector in m/s², e.g. (0, 0, -9.81); got None")
        floats(self, "g")
        if self.g.ndim == 0:
            raise ValueError(
                f"Gravity: g must be a (3,) acceleration vector in m/s² (world frame), got the scalar {self.g}; "
                "for gravity of that magnitude downward pass g=(0, 0, -magnitude)"
            )
        check_core(self, "g", (3,), " (an acceleration vector, m/s²)")

    def check(self, state: AnyState) -> None:
        check_fits(self, "g", 1, state.batch_shape, "the batch shape")

    def depends_on_velocity(self) -> bool:
        return False

    def on_body(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        return Forces(force=scale3(state.mass, cast_to(self.g, state)))


def _materialised(w: Array) -> Array:
    """``w`` (a drag's ``ω``), computed once into memory: fused instead into the Runge–Kutta
    stages it feeds, XLA:CPU recomputes its two rotations in every consumer (as in
    ``rbjax._dynamics``). Measured 2026-12-02 (shared 2-core machine, indicative): rk4, float32,
    1e5 bodies, quadratic drag with a torque, 0.6x the torque-free rate with this, 0.03x without."""
    return jax.lax.optimization_barrier(w)


class _Drag(PerBodyForce):
    """The coefficients of :class:`LinearDrag` and :class:`QuadraticDrag`: ``linear`` and
    ``angular``, scalar or ``(*B,)``, ``>= 0``, ``angular`` ``None`` for no torque."""

    linear: Array
    angular: Array | None
    _NON_NEGATIVE = ("linear", "angular")

    def __check_init__(self) -> None:
        floats(self, "linear", "angular")
        check_non_negative(self, "linear", "angular")

    def check(self, state: AnyState) -> None:
        for name in ("linear", "angular"):
            check_fits(self, name, 0, state.batch_shape, "the batch shape")

    def _law(self, state: AnyState, w: Array | None) -> Forces:
        """The force from ``v`` and, when ``angular`` is given, the torque from ``w`` (one body)."""
        raise NotImplementedError  # pragma: no cover - each drag writes its own

    def depends_on_velocity(self) -> bool:
        return True

    def on_body(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        """World-frame force from ``v`` (m/s) and, with ``angular``, torque from the world ``ω``
        (rad/s) of one body: :class:`Forces` ``(3,)`` N and ``(3,)`` N m (``None`` without)."""
        if self.angular is None:
            return self._law(state, None)
        return self._law(
            state, _materialised(angular_velocity(rigid_only(f"{type(self).__name__}(angular=...)", state)))
        )

    def on_body_in_body_frame(self, state: State, omega_body: Array, t: Float[ArrayLike, ""]) -> Forces:
        """:meth:`on_body` with the torque in the body frame, from ``omega_body`` ``ω_b`` ``(3,)`` rad/s.

        The law turns with the body, ``τ(R ω_b) = R τ(ω_b)`` (``|R ω_b| = |ω_b|``), so in the
        body frame it reads ``ω_b`` and turns nothing; the force stays world frame (from ``v``).
        Without ``angular`` there is no torque, as in :meth:`on_body`.
        """
        return self._law(state, None if self.angular is None else omega_body)


class LinearDrag(_Drag):
    """Viscous drag ``F = -b v`` and, if ``angular`` is given, ``τ = -b_r ω``.

    ``linear`` ``b``: scalar or ``(*B,)``, N s/m, ``>= 0``. ``angular`` ``b_r``: scalar or
    ``(*B,)``, N m s, ``>= 0``, or ``None`` (no torque: the step compiles none). ``v`` is the
    centre-of-mass velocity and ``ω`` the angular velocity, both world frame.
    """

    linear: Float[Array, "*B"] = field(default=0.0, converter=array_like)
    angular: Float[Array, "*B"] | None = field(default=None, converter=optional_array_like)

    def _law(self, state: AnyState, w: Array | None) -> Forces:
        f = scale3(-cast_to(self.linear, state), state.velocity)
        if w is None:
            return Forces(force=f)
        return Forces(force=f, torque=scale3(-cast_to(self.angular, state), w))


class QuadraticDrag(_Drag):
    """Quadratic drag ``F = -c ‖v‖ v`` and, if ``angular`` is given, ``τ = -c_r ‖ω‖ ω``.

    ``linear`` ``c``: scalar or ``(*B,)``, kg/m (``½ ρ C_d A``), ``>= 0``. ``angular``
    ``c_r``: kg m², ``>= 0``, or ``None`` (no torque). World frame. Terminal speed under
    gravity: ``√(m g / c)``.
    """

    linear: Float[Array, "*B"] = field(default=0.0, converter=array_like)
    angular: Float[Array, "*B"] | None = field(default=None, converter=optional_array_like)

    def _law(self, state: AnyState, w: Array | None) -> Forces:
        v = state.velocity
        f = scale3(-cast_to(self.linear, state) * norm3(v), v)
        if w is None:
            return Forces(force=f)
        return Forces(force=f, torque=scale3(-cast_to(self.angular, state) * norm3(w), w))


# ---------------------------------------------------------------- prescribed loads


class ConstantForce(PerBodyForce):
    """Constant world-frame force and torque: ``F(t) = F₀``, ``τ(t) = τ₀``.

    ``force``: ``(*B, 3)`` or ``(3,)`` in N (on the centre of mass); ``torque``:
    ``(*B, 3)`` or ``(3,)`` in N m (about it). Either may be ``None`` (absent).
    """

    force: Float[Array, "*B 3"] | None = field(core_shape=(3,), default=None, converter=optional_array_like)
    torque: Float[Array, "*B 3"] | None = field(core_shape=(3,), default=None, converter=optional_array_like)

    def __check_init__(self) -> None:
        floats(self, "force", "torque")
        check_core(self, "force", (3,), " (a force vector, N)")
        check_core(self, "torque", (3,), " (a torque vector, N m)")

    def check(self, state: AnyState) -> None:
        for name in ("force", "torque"):
            check_fits(self, name, 1, state.batch_shape, "the batch shape")

    def depends_on_velocity(self) -> bool:
        return False

    def on_body(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        f = None if self.force is None else cast_to(self.force, state)
        if self.torque is None:
            return Forces(force=f)
        rigid_only("ConstantForce(torque=...)", state)
        return Forces(force=f, torque=cast_to(self.torque, state))


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


class TimeSeriesForce(ForceModel):
    """Force and torque sampled at increasing ``times`` ``(K,)`` (s), world frame.

    ``force``, ``torque``: ``(K, *B, 3)`` or ``(K, 3)`` (shared), or ``None``.
    ``interpolation`` (static): ``"linear"`` (piecewise linear between samples,
    so a Runge–Kutta stage at ``t + dt/2`` sees the midpoint value) or
    ``"hold"`` (zero-order hold: the last sample at or before ``t``). Before
    the first and after the last sample the end value holds.
    """

    times: Float[Array, " K"] = field(converter=array_like)
    force: Float[Array, "K *B 3"] | None = field(default=None, converter=optional_array_like)
    torque: Float[Array, "K *B 3"] | None = field(default=None, converter=optional_array_like)
    interpolation: str = static_field(default="linear")

    def __check_init__(self) -> None:
        if self.interpolation not in ("linear", "hold"):
            raise ValueError(f"TimeSeriesForce: interpolation must be 'linear' or 'hold', got {self.interpolation!r}")
        floats(self, "times")
        if self.times.ndim != 1 or self.times.shape[0] < 1:
            raise ValueError(f"TimeSeriesForce: times must have shape (K,) with K >= 1, got {tuple(self.times.shape)}")
        if is_concrete(self.times) and np.any(np.diff(np.asarray(self.times)) <= 0):
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

    def depends_on_velocity(self) -> bool:
        return False

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        self.check(state)
        times = cast_to(self.times, state)
        t = cast_to(t, state)

        def get(v: Array | None) -> Array | None:
            return None if v is None else full_batch(_sample(times, cast_to(v, state), t, self.interpolation), state)

        if self.torque is not None:
            rigid_only("TimeSeriesForce(torque=...)", state)
        return Forces(force=get(self.force), torque=get(self.torque))


class ExternalForce(ForceModel):
    """Force and torque given as functions of time: ``force(t)``, ``torque(t)`` (world, N / N m).

    Each is a static callable ``t -> (*B, 3)`` or ``(3,)`` array, or ``None``
    (no term compiled). A new function object compiles anew.
    """

    force: Callable[[Any], Float[ArrayLike, "*B 3"]] | None = static_field(default=None)
    torque: Callable[[Any], Float[ArrayLike, "*B 3"]] | None = static_field(default=None)

    def __check_init__(self) -> None:
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
        rigid_only("ExternalForce(torque=...)", state)
        return Forces(force=f, torque=self._value("torque", state, t))


class CustomForce(ForceModel):
    """A user's force law ``fn(state, t) -> Forces`` or, with ``params``, ``fn(state, t, params)``.

    ``fn`` is static (hash by identity); ``params`` is any pytree of arrays and is
    differentiated through like every other model's leaves. Return world-frame
    ``Forces`` of shape ``(*B, 3)``; ``torque=None`` keeps the step torque-free.
    """

    fn: Callable[..., Forces] = static_field()
    params: Any = None

    def __check_init__(self) -> None:
        if not callable(self.fn):
            raise TypeError(f"CustomForce: fn must be a callable fn(state, t[, params]) -> Forces, got {self.fn!r:.60}")

    def __call__(self, state: AnyState, t: Float[ArrayLike, ""]) -> Forces:
        return self.fn(state, t) if self.params is None else self.fn(state, t, self.params)
