"""Rotors on rigid bodies (gyrostats): the configuration :class:`Rotors` and its one-body algebra.

A gyrostat is a rigid body carrying ``k`` axisymmetric rotors that spin about
body-fixed axes ``a_k`` (unit vectors, body frame) with axial inertias ``J_k``
(kg m²) at rates ``Ω_k`` (rad/s) relative to the body. The body's inertia ``I``
(kg m², body frame) is that of the whole gyrostat with the rotors held still
(the rotors as rigid masses). The rotors' spin momentum relative to the body is

    h = Σ_k h_k a_k,   h_k = J_k Ω_k   (body frame, kg m²/s),

and a state carries the scalar momenta ``h_k`` (``rotor_momentum``, ``(*B, k)``).
The total angular momentum (world) is ``L = R (I ω_b + h)``; the body rate is
``ω_b = I⁻¹ (Rᵀ L - h)``. A rotor torque ``τ_k`` (``Forces.rotor_torque``) is
internal: it changes ``h_k`` (``ḣ_k = τ_k``) and never ``L``; Euler's equation
in the body frame gains the rotor terms ``I ω̇_b = Rᵀ τ - ω_b × (I ω_b + h) - ḣ``.

The torque a motor exerts on rotor ``k`` is ``τ_k + J_k a_k · ω̇_b``: ``τ_k``
is the rate of the rotor's momentum relative to the body, which is what a
prescribed rate schedule fixes (``τ_k = J_k Ω̇_k``, :func:`rbjax.rotor_rates`). The
kinetic energy is ``T = ½ ω_bᵀ I ω_b + ω_b · h + ½ Σ_k h_k² / J_k`` and changes
at the motors' power ``Σ_k Ω_k (τ_k + J_k a_k · ω̇_b)``.

Everything below the class is written for one body and lifted by its callers.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from ._body import finite_float
from ._math import array_arg, broadcasts_to, is_concrete
from ._pytree import field, pytree_dataclass, replace
from ._typing import array_like

__all__ = ["Rotors", "spin_momentum", "rotor_energy"]

#: Relative tolerance on ``|a_k| = 1``: axes further from unit length are refused (``Rotors``
#: normalises the rest), so that a mistyped axis is not rescaled silently.
AXIS_RTOL = 1e-3


@pytree_dataclass
class Rotors:
    """The rotors of a gyrostat: spin axes and axial inertias, per body or shared by a batch.

    Attributes:
        axes: ``(*B, k, 3)`` unit spin axes ``a_k`` (body frame). Given axes must have
            ``|a_k| = 1`` within :data:`AXIS_RTOL` (1e-3) and are normalised to unit length.
        inertia: ``(*B, k)`` axial inertias ``J_k`` (kg m²), ``> 0``.

    ``B`` broadcasts against the state's batch shape (a ``(k, 3)``/``(k,)`` pair is
    shared by every body). A state with rotors carries their momenta
    ``rotor_momentum`` ``h_k = J_k Ω_k`` ``(*B, k)`` (kg m²/s, relative to the
    body); see :class:`rbjax.State`. The body's ``inertia`` is the whole
    gyrostat's with the rotors held still. Construction checks shapes, finiteness,
    ``J_k > 0`` and the axes' lengths when values are concrete (``ValueError``).
    """

    axes: Float[Array, "*B k 3"] = field(core_ndim=2, converter=array_like)
    inertia: Float[Array, "*B k"] = field(core_ndim=1, converter=array_like)

    def __post_init__(self) -> None:
        a = array_arg("Rotors", "axes", self.axes, (3,))
        J = array_arg("Rotors", "inertia", self.inertia)
        if a.ndim < 2:
            raise ValueError(
                f"Rotors: axes must have shape (k, 3) (one unit axis per rotor, body frame) or (*B, k, 3), "
                f"got {tuple(a.shape)}; for one rotor give [[ax, ay, az]]"
            )
        if J.ndim < 1 or J.shape[-1] != a.shape[-2]:
            raise ValueError(
                f"Rotors: inertia must have shape (k,) or (*B, k) with k = {a.shape[-2]} (one axial inertia "
                f"in kg m² per axis), got {tuple(J.shape)}"
            )
        dtype = jnp.result_type(a, J)
        a, J = a.astype(dtype), J.astype(dtype)
        if is_concrete(a, J):
            an, Jn = np.asarray(a), np.asarray(J)
            if not (np.all(np.isfinite(an)) and np.all(np.isfinite(Jn))):
                raise ValueError("Rotors: axes and inertia must be finite, got non-finite entries")
            if np.any(Jn <= 0):
                raise ValueError(f"Rotors: inertia (axial, kg m²) must be > 0, got {Jn[Jn <= 0].ravel()[:3]}")
            norms = np.linalg.norm(an, axis=-1)
            if np.any(np.abs(norms - 1) > AXIS_RTOL):
                raise ValueError(
                    f"Rotors: axes must be unit vectors (|a| = 1 within {AXIS_RTOL}); got lengths "
                    f"{norms[np.abs(norms - 1) > AXIS_RTOL].ravel()[:3]}: divide each axis by its length"
                )
        a = a / jnp.linalg.norm(a, axis=-1, keepdims=True)
        object.__setattr__(self, "axes", a)
        object.__setattr__(self, "inertia", J)

    @property
    def count(self) -> int:
        """The number of rotors ``k``."""
        return int(self.inertia.shape[-1])

    @property
    def dtype(self) -> Any:
        """Floating dtype of ``axes`` and ``inertia``."""
        return self.inertia.dtype

    def astype(self, dtype: Any) -> Rotors:
        """The same rotors with arrays of ``dtype`` (unchecked: the values were checked)."""
        if self.inertia.dtype == dtype:
            return self
        return replace(self, axes=self.axes.astype(dtype), inertia=self.inertia.astype(dtype))


def convert_rotors(obj: Any, dtype: Any) -> None:
    """In a rigid state's ``__post_init__``: ``rotors`` and ``rotor_momentum`` both or neither, checked, in ``dtype``.

    ``TypeError``/``ValueError`` naming the field: ``rotors`` must be :class:`rbjax.Rotors`,
    ``rotor_momentum`` ``(*B, k)`` (kg m²/s) finite with ``k`` the rotors' count.
    """
    rotors, h = getattr(obj, "rotors", None), getattr(obj, "rotor_momentum", None)
    cls = type(obj).__name__
    if rotors is None and h is None:
        return
    if not isinstance(rotors, Rotors):
        if rotors is None:
            raise ValueError(
                f"{cls}: rotor_momentum was given without rotors; give rotors=rb.Rotors(axes, inertia) too"
            )
        raise TypeError(f"{cls}: rotors must be an rbjax.Rotors, got {type(rotors).__name__}")
    if h is None:
        raise ValueError(
            f"{cls}: rotors were given without rotor_momentum (h_k = J_k Ω_k, kg m²/s, (*B, k)); give it, or "
            f"build the state with {cls}.create(..., rotors=..., rotor_rates=...)"
        )
    h = finite_float(cls, "rotor_momentum", h)
    if h.ndim < 1 or h.shape[-1] != rotors.count:
        raise ValueError(
            f"{cls}: rotor_momentum must end in (k,) = ({rotors.count},), one momentum per rotor, got shape {h.shape}"
        )
    object.__setattr__(obj, "rotors", rotors.astype(dtype))
    if h.dtype != dtype and not isinstance(h, jax.core.Tracer):
        h = h.astype(dtype)
    object.__setattr__(obj, "rotor_momentum", h)


def rotor_rates_of(where: str, rotors: Rotors, rates: Any, dtype: Any) -> tuple[Rotors, Array]:
    """``create``'s ``rotors`` in ``dtype`` and its ``rotor_rates`` ``Ω`` (rad/s, ``(*B, k)``; ``None``: zero),
    checked (finite, ending in ``(k,)``), in ``dtype``."""
    rotors = rotors.astype(dtype)
    rates = jnp.zeros(rotors.inertia.shape[-1:], dtype) if rates is None else rates
    rates = finite_float(where, "rotor_rates", rates).astype(dtype)
    if rates.ndim < 1 or rates.shape[-1] != rotors.count:
        raise ValueError(
            f"{where}: rotor_rates must end in (k,) = ({rotors.count},) (rad/s per rotor), got shape {rates.shape}"
        )
    return rotors, rates


def rotor_torque_shape(forces: Any, state: Any, where: str, series: bool = False) -> tuple[int, ...] | None:
    """The shape ``(*B, k)`` that ``forces.rotor_torque`` broadcasts to, or ``None`` when it is absent.

    ``ValueError`` in rbjax's words for a rotor torque given to a state without rotors
    (there is nothing for it to turn: it would be dropped) or of a shape that does not
    broadcast to ``(*B, k)`` (``series``: ``(steps, *B, k)``, the leading axis not checked here).
    """
    tau = forces.rotor_torque
    if tau is None:
        return None
    if getattr(state, "rotors", None) is None:
        raise ValueError(
            f"{where}: forces.rotor_torque was given, but the state has no rotors; build it with "
            "rb.State.create(..., rotors=rb.Rotors(axes, inertia)) or drop rotor_torque"
        )
    want = tuple(state.batch_shape) + (state.rotors.count,)
    if not broadcasts_to(tuple(tau.shape)[1:] if series else tuple(tau.shape), want):
        raise ValueError(
            f"{where}: rotor_torque has shape {tuple(tau.shape)}, which does not broadcast to the state's "
            f"{'(steps, ' if series else '('}*batch, k) = {want} (one torque per rotor, N m)"
        )
    return want


def spin_momentum(rotors: Rotors, h: Array | None) -> Array:
    """``h = Σ_k h_k a_k`` (body frame, kg m²/s, ``(3,)``) of one body's rotor momenta ``h_k`` ``(k,)``."""
    return _momenta(h) @ rotors.axes


def _momenta(h: Array | None) -> Array:
    """A gyrostat state's ``rotor_momentum``: its ``rotors`` come with it (:func:`convert_rotors`)."""
    if h is None:
        raise ValueError("a state with rotors must carry rotor_momentum (h_k = J_k Ω_k, kg m²/s, (*B, k))")
    return h


def rotor_energy(rotors: Rotors, h: Array | None) -> Array:
    """``½ Σ_k h_k² / J_k`` (J, scalar): the rotors' spin energy relative to the body, for one body."""
    h = _momenta(h)
    return 0.5 * jnp.sum(h * h / rotors.inertia, axis=-1)
