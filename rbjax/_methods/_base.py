"""The method protocol: :class:`AbstractMethod`, the one base of every integrator, and :class:`Method`.

An integrator is an instance of a subclass of :class:`AbstractMethod` (the model
is diffrax's ``AbstractSolver``): what is known of it, its order, its native
kernel's number, whether it reads the forces only at the step's start, the
memory layout its steps run in, are class attributes, and its one step,
``__call__(state, force_fn, t, dt) -> state``, is the abstract method a
subclass must write. :class:`Method` is the final, data-driven subclass that
holds rbjax's own integrators (a table of steps per state form, and the
kernels a :class:`rbjax.Scene` specialises on). This module imports no method
module and registers nothing: the table of rbjax's methods by name is
:mod:`rbjax._methods._registry`.
"""

from __future__ import annotations

import abc
import dataclasses
import types
from collections.abc import Callable, Mapping
from typing import Any

from .._state import MatrixState, ParticleState, State

__all__ = ["AbstractMethod", "Method", "OrderWarning", "StepFn", "KernelFn", "KINDS", "DEFAULT_METHOD"]

#: The integrator every public function uses when ``method`` is not given (``step``, ``simulate``,
#: ``simulate_chunked``, ``Scene.build``, ``shoot``, ``simulate_truncated``): Strang splitting,
#: second order, symplectic, world ``L`` exact, exact for symmetric tops. Its cost against Euler's
#: is the registry's ``cost``; its accuracy on the README's body is in docs/integrators.md.
DEFAULT_METHOD = "splitting"

#: The body kinds a :class:`rbjax.Scene` specialises on, from the most special to the most general
#: (see :mod:`rbjax._methods.specialised` for the algebra each allows).
KINDS = ("particles", "isotropic", "axisymmetric", "general")

#: A batch-level step ``(state, force_fn, t, dt) -> state``.
StepFn = Callable[[Any, Callable[[Any, Any], Any], Any, Any], Any]
#: A batch-level step specialised on a body kind: ``(state, force_fn, t, dt, kind, torque_free) -> state``.
KernelFn = Callable[..., Any]

_ALL_STATES = (State, MatrixState, ParticleState)


class OrderWarning(UserWarning):
    """A method runs below its order: its forces depend on velocities and it kicks with stale ones.

    Given by :func:`rbjax.simulate` (and the runs built on it) when ``method`` has an
    ``order_with_velocity_forces`` below its ``order`` (``"splitting"`` and its
    compositions: first order) and ``forces`` declares a law that reads velocities or
    angular velocities (:class:`rbjax.LinearDrag`, :class:`rbjax.QuadraticDrag`, a damped
    :class:`rbjax.Spring`; :meth:`rbjax.ForceModel.depends_on_velocity`). The run is
    correct to ``O(dt)``, not ``O(dt²)``: use ``"rk4"`` or ``"rk8"`` for accuracy, or
    filter the warning where first order is enough.
    """


def _is_order(x: Any) -> bool:
    return not isinstance(x, bool) and isinstance(x, int) and x >= 0


class AbstractMethod(abc.ABC):
    """An integrator: one step ``y(t) → y(t + dt)`` of the Newton–Euler equations, and what is known of it.

    Subclass it, set ``order`` and write ``__call__``; pass an instance as
    ``method=`` to :func:`rbjax.simulate`, :func:`rbjax.step`,
    :func:`rbjax.simulate_chunked`, :func:`rbjax.simulate_truncated`,
    :func:`rbjax.shoot` or :meth:`rbjax.Scene.build` (a string such as ``"rk4"``
    is a look-up of rbjax's own, :func:`rbjax.methods`)::

        class Midpoint(rb.AbstractMethod):
            # explicit midpoint for particles: second order
            order = 2
            state_types = (rb.ParticleState,)

            def __call__(self, state, force_fn, t, dt):
                m = state.mass[..., None]
                a = force_fn(state, t).force / m
                half = dataclasses.replace(
                    state, position=state.position + dt / 2 * state.velocity, velocity=state.velocity + dt / 2 * a
                )
                a_half = force_fn(half, t + dt / 2).force / m
                return dataclasses.replace(
                    state, position=state.position + dt * half.velocity, velocity=state.velocity + dt * a_half
                )

        traj = rb.simulate(particles, rb.Gravity(), 1e-2, 100, Midpoint())

    ``__call__(state, force_fn, t, dt) -> state`` takes one step of the whole
    batch: ``state`` is one of ``state_types`` with fields ``(*B, ...)``,
    ``force_fn(state, t) -> Forces`` gives world-frame forces (N) and torques
    about the centre of mass (N m) of every body, and may be called at any
    intermediate state and time; ``t`` (the step's start) and ``dt`` are in s.
    It returns the state after the step, of the same type and shapes (the
    caller sets ``time``). It is traced once per compiled run, so it must be a
    pure JAX function.

    A class without ``__call__`` cannot be instantiated (``TypeError``), and a
    concrete class without a valid ``order`` is refused when it is defined.
    Instances compare equal when they are of one class with equal attributes, so
    ``Midpoint()`` twice reuses one compiled program; their attributes must then
    be hashable.

    Class attributes (the defaults are those of a user's method):

    Attributes:
        name: the name used in messages (default: the class's name). rbjax's
            own methods are looked up by it from a ``method=`` string.
        order: global order of accuracy ``p`` (error ``O(dt^p)`` over a fixed
            time), an int ``>= 0`` (0: not known). Required.
        state_types: the state forms ``__call__`` steps (:class:`rbjax.State`,
            :class:`rbjax.MatrixState`, :class:`rbjax.ParticleState`; default all
            three); any other is refused with ``ValueError`` before tracing.
        layout_agnostic: the memory layout the steps run in. ``False`` (default):
            states are batch-first, ``(*B, 3)`` per vector field, as a user writes
            them. ``True``: ``simulate`` may hand them in its batch-last layout
            (``(3, *B)``, marked so in the state itself), so the step must be
            elementwise outside ``rbjax._batching.lift`` (rbjax's own steps; see
            :mod:`rbjax._methods`). ``__call__``'s arguments are the same either way.
        native_code: the method's number in the native C++ kernels
            (``rbjax/_native/kernels.cc``), ``None`` for none. Only rbjax's own
            methods have one; a subclass that sets it is refused when defined, and
            ``simulate(..., native=True)`` refuses a user's method with
            ``ValueError`` (its steps run on the JAX path).
        forces_at_step_start: the steps evaluate ``force_fn`` once per step, at
            the start state and time (the native kernel of such a method takes
            forces XLA evaluates, one call per step).
        principal_frame: the steps read each body's principal frame from the
            body prepared by ``simulate`` (:func:`rbjax._body.prepare`).
        rotors: the steps handle gyrostats (states with ``rotors``); otherwise a
            gyrostat state is refused with ``ValueError``.
        order_with_velocity_forces: the order under forces that read velocities,
            where it is below ``order`` (``None``: ``order``); ``simulate`` then
            gives an :class:`rbjax.OrderWarning`.
        conserves: short statement of what it conserves (for docs).
        cost: cost per step relative to ``"euler"`` (1.0 when not measured).
        stable_dt_omega: ``{state type name: limit of dt·|ω|}`` where explicit
            steps stay bounded, or ``None`` (not measured / unconditionally stable).
        failure_note: added to a checked-mode failure's message.
        kernels: ``{(kind, state type): kernel}``: batch steps
            ``(state, force_fn, t, dt, kind, torque_free) -> state`` specialised on a
            :class:`rbjax.Scene`'s body kind (one of ``"particles"``,
            ``"isotropic"``, ``"axisymmetric"``, ``"general"``); each must give the
            general step's result to round-off for every body of that kind.
        batch_first_kernels: the keys of ``kernels`` given batch-first states
            although ``layout_agnostic`` is true.
    """

    name: str
    order: int
    state_types: tuple[type, ...] = _ALL_STATES
    layout_agnostic: bool = False
    native_code: int | None = None
    forces_at_step_start: bool = False
    principal_frame: bool = False
    rotors: bool = False
    order_with_velocity_forces: int | None = None
    conserves: str = ""
    cost: float = 1.0
    stable_dt_omega: dict[str, float] | None = None
    failure_note: str = ""
    kernels: Mapping[tuple[str, type], KernelFn] = types.MappingProxyType({})
    batch_first_kernels: frozenset[tuple[str, type]] = frozenset()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__module__ == __name__:  # Method: its fields are per instance, checked in __post_init__
            return
        if "name" not in cls.__dict__:
            cls.name = cls.__qualname__
        if getattr(cls.__call__, "__isabstractmethod__", False):
            return  # still abstract: checked in its concrete subclasses
        where = f"method class {cls.__qualname__}"
        if not _is_order(getattr(cls, "order", None)):
            raise TypeError(
                f"{where}: set the class attribute order, an int >= 0 (the global order of accuracy; 0: not "
                f"known), e.g. order = 2; got {getattr(cls, 'order', None)!r}"
            )
        low = cls.order_with_velocity_forces
        if low is not None and not _is_order(low):
            raise TypeError(f"{where}: order_with_velocity_forces must be None or an int >= 0; got {low!r}")
        st = cls.state_types
        if not isinstance(st, tuple) or not st or not all(T in _ALL_STATES for T in st):
            raise TypeError(
                f"{where}: state_types must be a non-empty tuple of rb.State, rb.MatrixState and rb.ParticleState; "
                f"got {st!r}"
            )
        if cls.native_code is not None:
            raise TypeError(
                f"{where}: native_code must stay None: the native kernels compute rbjax's own methods only, so "
                "a native code would run their formulas in place of this class's __call__"
            )
        for key in cls.kernels:
            if not (isinstance(key, tuple) and len(key) == 2 and key[0] in KINDS and key[1] in st):
                raise TypeError(
                    f"{where}: kernels maps (kind, state type) to a kernel, kind one of {KINDS} and the state "
                    f"type one of state_types; got the key {key!r}"
                )

    def __new__(cls, *args: Any, **kwargs: Any) -> Any:
        missing = sorted(getattr(cls, "__abstractmethods__", ()))
        if missing:
            raise TypeError(
                f"{cls.__qualname__} is abstract: a method must define {', '.join(missing)}"
                "(self, state, force_fn, t, dt) -> state, one step of dt seconds of the whole batch"
            )
        return super().__new__(cls)

    @abc.abstractmethod
    def __call__(self, state: Any, force_fn: Callable[[Any, Any], Any], t: Any, dt: Any) -> Any:
        """One step of ``dt`` s from time ``t`` s: the state after it, same type and shapes ``(*B, ...)``."""

    def step(self, state_type: type) -> StepFn:
        """The batch step for states of ``state_type``; ``ValueError`` if the method does not support it."""
        if state_type not in self.state_types:
            raise ValueError(
                f"method {self.name!r} does not support {state_type.__name__}; it supports "
                f"{sorted(t.__name__ for t in self.state_types)}"
            )
        return self.__call__

    def __eq__(self, other: object) -> bool:
        return type(self) is type(other) and vars(self) == vars(other)

    def __hash__(self) -> int:
        return hash((type(self), tuple(sorted(vars(self).items()))))


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Method(AbstractMethod):
    """An integrator given as a table: its steps per state form, the Scene kernels specialised from them.

    rbjax's own methods are Methods (:func:`rbjax.methods`); a plain batch step
    passed as ``method=`` becomes one, and so can a user's, without a class::

        rb.Method(name="my_euler", order=1, steps={rb.State: my_step})

    Calling it, ``method(state, force_fn, t, dt)``, takes one step of its step
    for ``type(state)`` (see :class:`AbstractMethod` for the arguments: world
    frame forces in N and N m, ``t`` and ``dt`` in s, states ``(*B, ...)``).
    Two Methods are equal only when they are the same object (it is the
    compiled program's cache key). The class is final: a method of one's own is
    a subclass of :class:`AbstractMethod`.

    Attributes:
        name: the ``method=`` string.
        order: global order of accuracy (0: not known, e.g. a user's own step).
        steps: ``{state type: batch-level step function}``.
        conserves: short statement of what it conserves (for docs and tests).
        cost: cost per step relative to ``"euler"``, both on their JAX step
            measured by ``benchmarks/integrator_cost.py`` (approximate: the ratios
            move between machines; ``benchmarks/results/integrator_cost_*.md``). The
            native kernels' rates are in docs/performance.md.
        stable_dt_omega: for explicit methods, ``{state type name: limit}``: the
            largest ``dt·|ω|`` (ω in rad/s, dt in s) at which 1000 torque-free
            steps stayed finite with a unit quaternion / rotation matrix, measured
            in float64 on four body shapes and six spin axes each by
            ``benchmarks/stability_limits.py`` (grid ratio 1.33, so the true limit
            is up to 33% higher). Beyond it the method diverges (NaN, inf or an
            orientation off the rotation group); ``inf``: bounded up to 1000 (the
            state form keeps ``|ω|`` bounded, though the energy still drifts).
            ``None`` for methods that are stable at any step (``"splitting"`` and
            its compositions, the implicit ones). Accuracy needs far smaller steps:
            see the integrator table in the README.
        failure_note: what a checked-mode failure means for this method, added
            to the error message.
        kernels: ``{(kind, state type): KernelFn}``: steps specialised on a
            :class:`rbjax.Scene`'s body kind (one of :data:`KINDS`) and on its
            forces returning no torque; each gives the general step's result to
            round-off for every body of that kind. A scene uses the one of its
            kind instead of ``steps`` (see :func:`rbjax._methods.for_kind`).
        layout_agnostic: the steps and kernels lift all per-body work
            (:func:`rbjax._batching.lift`, which reads the layout from the state) and
            are elementwise elsewhere, so ``simulate`` may run them on its batch-last
            layout (see :mod:`rbjax._methods`). ``False``: they are always given
            batch-first states.
        batch_first_kernels: the keys of ``kernels`` that need batch-first
            states although ``layout_agnostic`` is true (a user's kernel, added by
            :meth:`with_kernel`).
        native_code: the method's number in the native kernels
            (``rbjax/_native/kernels.cc``: ``Method``), or ``None`` when it has none.
            The native path takes it only when the steps are rbjax's own for that number.
        principal_frame: the steps turn about each body's principal axes
            (:func:`rbjax._eigh3.principal_frame`): ``simulate`` computes the frame
            once per call, before its loop (:func:`rbjax._body.prepare`), and the
            steps read it from the body.
        forces_at_step_start: the steps evaluate the forces once per step, at its
            start state and time (``"euler"``, ``"semi_implicit_euler"``): a native
            kernel can then take forces XLA evaluates, one call per step.
        order_with_velocity_forces: the global order under forces that depend on
            velocities (drag, a damper), where it is lower than ``order`` (the
            splitting methods kick with the start velocities: first order, measured
            in tests/test_force_protocol.py); ``None`` when it is ``order``.
            :func:`rbjax.simulate` gives an :class:`rbjax.OrderWarning` for such a run.
        rotors: the steps handle gyrostats (states with ``rotors``, :mod:`rbjax._rotors`):
            the rotor momenta in the map from ``L`` to ``ω`` (or in Euler's equation)
            and ``Forces.rotor_torque``. Every public run refuses a gyrostat state,
            with ``ValueError`` naming the methods that do, for a method without.
    """

    name: str
    order: int
    steps: dict[type, StepFn]
    conserves: str = ""
    cost: float = 1.0
    stable_dt_omega: dict[str, float] | None = None
    failure_note: str = ""
    kernels: dict[tuple[str, type], KernelFn] = dataclasses.field(default_factory=dict)  # type: ignore[assignment]
    layout_agnostic: bool = True
    batch_first_kernels: frozenset[tuple[str, type]] = frozenset()
    native_code: int | None = None
    principal_frame: bool = False
    order_with_velocity_forces: int | None = None
    forces_at_step_start: bool = False
    rotors: bool = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        raise TypeError(
            f"{cls.__qualname__}: rb.Method is final (the table of a method's steps); write a method of your own "
            "as a subclass of rb.AbstractMethod with order and __call__(self, state, force_fn, t, dt); to start "
            "from a built-in one, call it inside, e.g. rb.methods()['rk4'](state, force_fn, t, dt)"
        )

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise TypeError(f"Method: name must be a non-empty str (the method= string), got {self.name!r}")
        if not _is_order(self.order):
            raise TypeError(f"Method {self.name!r}: order must be an int >= 0 (0: not known), got {self.order!r}")
        if not isinstance(self.steps, dict) or not self.steps:
            raise TypeError(
                f"Method {self.name!r}: steps must be a dict {{state type: batch step (state, force_fn, t, dt) -> "
                f"state}}, e.g. {{rb.State: my_step}}; got {self.steps!r}"
            )
        for kind, fn in self.steps.items():
            if not isinstance(kind, type) or not callable(fn):
                raise TypeError(
                    f"Method {self.name!r}: steps maps state types (rb.State, rb.MatrixState, rb.ParticleState) "
                    f"to step callables; got {kind!r}: {fn!r}"
                )
        low = self.order_with_velocity_forces
        if low is not None and not _is_order(low):
            raise TypeError(
                f"Method {self.name!r}: order_with_velocity_forces must be None or an int >= 0; got {low!r}"
            )

    # identity, not fields: a Method is the compiled program's cache key, and its steps are functions
    __eq__ = object.__eq__  # type: ignore[assignment]
    __hash__ = object.__hash__  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"Method({self.name!r}, order={self.order})"

    @property
    def state_types(self) -> tuple[type, ...]:  # type: ignore[override]
        """The state forms it steps: the keys of ``steps``."""
        return tuple(self.steps)

    def step(self, state_type: type) -> StepFn:
        """The step function for ``state_type``; ``ValueError`` if the method has none."""
        fn = self.steps.get(state_type)
        if fn is None:
            raise ValueError(
                f"method {self.name!r} does not support {state_type.__name__}; it supports "
                f"{sorted(t.__name__ for t in self.steps)}"
            )
        return fn

    def __call__(self, state: Any, force_fn: Callable[[Any, Any], Any], t: Any, dt: Any) -> Any:
        """One step of its step for ``type(state)`` (see :class:`AbstractMethod`)."""
        return self.step(type(state))(state, force_fn, t, dt)

    def with_kernel(self, kind: str, state_type: type, kernel: KernelFn) -> Method:
        """This method with ``kernel`` as its :class:`rbjax.Scene` kernel for ``(kind, state_type)``.

        ``kernel(state, force_fn, t, dt, kind, torque_free) -> state`` must give
        this method's general step to round-off for every body of ``kind`` (one of
        ``"particles"``, ``"isotropic"``, ``"axisymmetric"``, ``"general"``; see
        :mod:`rbjax._methods.specialised` for the algebra each allows). It is given
        batch-first states ``(*B, ...)``, world frame, ``t`` and ``dt`` in s.
        Returns a new Method (the same name, order and steps; nothing is
        registered): pass it as ``method=`` to :meth:`rbjax.Scene.build`.
        ``ValueError`` for an unknown kind or a state type it has no step for.
        """
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
        self.step(state_type)
        key = (kind, state_type)
        return dataclasses.replace(
            self, kernels={**self.kernels, key: kernel}, batch_first_kernels=self.batch_first_kernels | {key}
        )
