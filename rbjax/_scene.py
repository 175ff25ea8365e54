"""``Scene``: bodies, force models and a method, compiled to only what they use.

A scene decides, once, from concrete inputs, what its step needs:

* ``kind`` ``"particles"`` (a :class:`ParticleState`: no rotation at all),
  ``"isotropic"`` (every ``I = i·1``: ``ω = L/i``, no gyroscopic term, no
  principal-frame work), ``"axisymmetric"`` (every ``I = diag(a, a, c)``:
  closed forms with the symmetry axis ``n = R e_z``) or ``"general"``; a mixed
  batch takes the most general kind any of its bodies needs;
* ``torque_free``: the force model returns ``torque=None`` (found by tracing it
  once with :func:`jax.eval_shape`), so no torque is accumulated or integrated.

These are static fields; ``Body`` is untouched. The specialised kernels are the
method's own (:attr:`rbjax._methods.Method.kernels`): ``"euler"`` and ``"rk4"``
have them for every rigid kind (:mod:`rbjax._methods.specialised`),
``"splitting"`` for isotropic and axisymmetric bodies (the exact free rotor
without a principal frame, :func:`rbjax._methods.splitting.free_rotor_of_kind`);
another method gets one with :meth:`rbjax.Method.with_kernel` (a user's method class
declares its ``kernels``), and otherwise runs its
general step, which still skips rotation for particles and torque for
torque-free forces (``Forces.torque is None`` is structural).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from . import _methods
from ._body import Body
from ._deprecated import renamed_keywords, warn_deprecated
from ._force_model import ForceModel, ForceSum
from ._math import is_concrete
from ._methods import DEFAULT_METHOD, KINDS, AbstractMethod
from ._pytree import pytree_dataclass, static_field
from ._simulate import simulate as _simulate_fn
from ._simulate import step as _step_fn
from ._state import AnyState, ParticleState, StateT
from ._typing import ArrayLike

__all__ = ["Scene", "body_kind", "register_kernel"]


def register_kernel(method: str, kind: str, state_type: type, step: Callable[..., Any]) -> None:
    """Deprecated: use ``rb.methods()[method].with_kernel(kind, state_type, step)`` and pass the result as ``method=``.

    Replaces the method that the string ``method`` names by one whose
    :class:`rbjax.Scene` kernel for ``(kind, state_type)`` is ``step(state,
    force_fn, t, dt, kind, torque_free) -> state`` (see
    :meth:`rbjax.Method.with_kernel`; states ``(*B, ...)``, world frame, ``t`` and
    ``dt`` in s): scenes built afterwards by that name use it. ``ValueError``
    for an unknown method or kind. Gives a ``DeprecationWarning``: a global
    replacement makes what a name means depend on what ran before.
    """
    warn_deprecated(
        f"rbjax.register_kernel is deprecated and will be removed in the next release; use "
        f"rb.methods()[{method!r}].with_kernel(kind, state_type, step) and pass that method to Scene.build "
        "(nothing global is replaced)",
        stacklevel=2,
    )
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    _methods.register(_methods.lookup(method).with_kernel(kind, state_type, step))


def body_kind(body: Body) -> str:
    """``"isotropic"``, ``"axisymmetric"`` (about body z) or ``"general"`` for a concrete batch.

    A body counts as isotropic / axisymmetric when its off-diagonal entries and
    the differences of the equal moments are below ``16 eps`` of its largest
    moment (round-off of the constructors); the specialised algebra then agrees
    with the general one to round-off. Traced bodies are ``"general"``.
    ``body.inertia`` is ``(*B, 3, 3)`` in the body frame (kg m²); the answer
    covers the whole batch (the most general kind any body needs).
    """
    I = body.inertia
    if not _has_value(I):
        return "general"
    # a jax.Array is reduced by XLA where it lives: no host copy of the batch, and
    # a batch split over processes (not fully addressable) yields one replicated answer
    iso, axisym = _kind_flags_jit(I) if isinstance(I, jax.Array) else _kind_flags(np.asarray(I), np)
    if bool(iso):
        return "isotropic"
    return "axisymmetric" if bool(axisym) else "general"


def _has_value(a: Any) -> bool:
    """Concrete on this host, or a ``jax.Array`` spread over processes (reduced by XLA): not traced."""
    return is_concrete(a) or (isinstance(a, jax.Array) and not isinstance(a, jax.core.Tracer))


def _kind_flags(I: Any, xp: Any) -> tuple[Any, Any]:
    """(every body isotropic, every body axisymmetric about z) for inertias ``I`` ``(*B, 3, 3)``."""
    tol = 16 * np.finfo(I.dtype).eps * xp.max(xp.abs(I), axis=(-1, -2))
    off = xp.max(xp.abs(I - I * xp.eye(3, dtype=I.dtype)), axis=(-1, -2))
    d = xp.diagonal(I, axis1=-2, axis2=-1)
    axisym = (off <= tol) & (xp.abs(d[..., 0] - d[..., 1]) <= tol)
    return xp.all(axisym & (xp.abs(d[..., 0] - d[..., 2]) <= tol)), xp.all(axisym)


_kind_flags_jit = jax.jit(functools.partial(_kind_flags, xp=jnp))


@pytree_dataclass
class Scene:
    """Bodies under force models, integrated by one method, specialised on their structure.

    Attributes:
        body: the batch's :class:`Body` (``None`` for particles). A state passed
            to :meth:`step` / :meth:`simulate` must carry bodies of this kind.
        forces: a :class:`ForceModel` (e.g. ``Gravity() + LinearDrag(0.1)``); its
            arrays are leaves, its composition is static.
        method: integrator name, a method object (a ``Method`` from :func:`rbjax.methods`, an
            instance of a user's :class:`rbjax.AbstractMethod` subclass), or a hashable
            batch step ``(state, force_fn, t, dt) -> state``, as in :func:`rbjax.simulate` (static);
            default ``"splitting"``, the house default (see :func:`rbjax.simulate`).
            Specialised kernels exist for ``"euler"`` and ``"rk4"`` (every rigid kind) and
            ``"splitting"`` (isotropic, axisymmetric); other methods (a user's, unless it
            declares ``kernels``) step through their generic batch step.
        kind: ``"particles"``, ``"isotropic"``, ``"axisymmetric"`` or ``"general"`` (static).
        torque_free: the forces never produce a torque (static).

    Build with :meth:`Scene.build`, which decides ``kind`` and ``torque_free``.
    """

    body: Body | None
    forces: ForceModel
    method: str | AbstractMethod | Callable[..., Any] = static_field(default=DEFAULT_METHOD)
    kind: str = static_field(default="general")
    torque_free: bool = static_field(default=False)

    @classmethod
    def build(
        cls,
        state: AnyState,
        forces: ForceModel | None = None,
        method: str | AbstractMethod | Callable[..., Any] = DEFAULT_METHOD,
        *,
        kind: str | None = None,
    ) -> Scene:
        """Scene for ``state``'s bodies under ``forces`` (``None``: free motion), integrated by ``method``.

        ``kind`` overrides the detected body kind (``"general"`` forces the
        general path, e.g. to compare; a more special kind than the bodies have
        raises ``ValueError``). Traces ``forces`` once on ``state`` to check
        its output shapes and learn whether it returns a torque. ``method`` is a
        name, a method object or a batch step, as in :func:`rbjax.simulate`
        (``TypeError`` for anything else, ``ValueError`` for an unknown name or a state form it
        does not support).
        """
        _methods.resolve(method, "Scene.build").step(type(state))
        forces = ForceSum(()) if forces is None else forces
        if not isinstance(forces, ForceModel):
            raise TypeError(f"forces must be a ForceModel, e.g. Gravity() + LinearDrag(0.1); got {forces!r}")
        detected = "particles" if isinstance(state, ParticleState) else body_kind(state.body)
        if kind is not None:
            order = KINDS
            if kind not in order or (detected == "particles") != (kind == "particles"):
                raise ValueError(f"kind {kind!r} does not apply to {type(state).__name__}")
            if order.index(kind) < order.index(detected):
                raise ValueError(f"kind {kind!r} is more special than the bodies ({detected!r})")
            detected = kind
        out = jax.eval_shape(forces, state, jnp.zeros((), state.dtype))
        for name in ("force", "torque"):
            v = getattr(out, name)
            if v is not None and jnp.broadcast_shapes(v.shape, state.position.shape) != state.position.shape:
                raise ValueError(
                    f"forces returned {name} of shape {v.shape}; it must broadcast to {state.position.shape}"
                )
        torque_free = out.torque is None
        if not torque_free and isinstance(state, ParticleState):
            raise ValueError("forces return a torque, but particles cannot take one")
        body = None if isinstance(state, ParticleState) else state.body
        return cls(body=body, forces=forces, method=method, kind=detected, torque_free=torque_free)

    @property
    def kernel(self) -> AbstractMethod:
        """The batch step ``(state, force_fn, t, dt) -> state`` that this scene compiles.

        A method object: the scene's method with its kernels for this scene's kind
        in place of its general steps (the same object for equal scenes, so a
        rerun reuses the compiled program); pass it as ``method=`` or call it.
        """
        return _methods.for_kind(_methods.resolve(self.method, "Scene"), self.kind, self.torque_free)

    def _check(self, state: AnyState) -> None:
        if (self.kind == "particles") != isinstance(state, ParticleState):
            raise ValueError(f"a {self.kind!r} scene cannot step a {type(state).__name__}")
        if isinstance(state, ParticleState) or self.kind == "general" or state.body is self.body:
            return
        found = body_kind(state.body)
        rank = KINDS.index
        if _has_value(state.body.inertia) and rank(found) > rank(self.kind):
            raise ValueError(f"this scene is specialised for {self.kind!r} bodies; the state's are {found!r}")

    @renamed_keywords("Scene.step", t="t0")
    def step(self, state: StateT, dt: Float[ArrayLike, ""], t0: Float[ArrayLike, ""] | None = None) -> StateT:
        """One step of ``dt`` seconds from time ``t0`` (default ``None``: ``state.time``); as
        :func:`rbjax.step` with the scene's forces."""
        self._check(state)
        return _step_fn(state, self.forces, dt, self.kernel, t0=t0)

    def simulate(
        self,
        state: StateT,
        dt: Float[ArrayLike, ""],
        steps: int,
        *,
        save_every: int = 1,
        t0: Float[ArrayLike, ""] | None = None,
    ) -> StateT:
        """Trajectory of ``steps`` steps, every ``save_every``-th state kept; as :func:`rbjax.simulate`.

        ``t0``: start time (s); default ``None``: ``state.time``.
        Returns the state type with a leading time axis of length
        ``steps // save_every + 1`` (initial state first) on every leaf.
        A batch sharded over devices on its body axis stays sharded.
        """
        self._check(state)
        return _simulate_fn(state, self.forces, dt, steps, self.kernel, save_every=save_every, t0=t0)
