"""The registry of time-stepping methods: :class:`Method`, and ``register``/``get``/``available``.

Each method module registers itself on import; this module imports none of them.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

from .._state import MatrixState, ParticleState, State

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


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Method:
    """An integrator: its steps, the Scene kernels specialised from them, and what is known of it.

    Calling it, ``method(state, force_fn, t, dt)``, takes one step of its step
    for ``type(state)``: ``force_fn(state, t) -> Forces`` (world frame, N and
    N m) sees the whole batch, ``t`` and ``dt`` are in s, and the state keeps
    its type and shapes ``(*B, ...)``. Two Methods are equal only when they are
    the same object (it is the compiled program's cache key).

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
            kind instead of ``steps`` (see :func:`for_kind`).
        layout_agnostic: the steps and kernels lift all per-body work
            (:func:`rbjax._batching.lift`) and are elementwise elsewhere, so
            ``simulate`` may run them on its batch-last layout (see
            :mod:`rbjax._methods`). ``False``: they are always given batch-first states.
        batch_first_kernels: the keys of ``kernels`` that need batch-first
            states although ``layout_agnostic`` is true (a user's kernel, added by
            :func:`rbjax.register_kernel`).
        native_code: the method's number in the native kernels
            (``rbjax/_native/kernels.cc``: ``Method``), or ``None`` when it has none.
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
    kernels: dict[tuple[str, type], KernelFn] = dataclasses.field(default_factory=dict)
    layout_agnostic: bool = True
    batch_first_kernels: frozenset[tuple[str, type]] = frozenset()
    native_code: int | None = None
    principal_frame: bool = False
    order_with_velocity_forces: int | None = None
    forces_at_step_start: bool = False
    rotors: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise TypeError(f"Method: name must be a non-empty str (the method= string), got {self.name!r}")
        if isinstance(self.order, bool) or not isinstance(self.order, int) or self.order < 0:
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
        if low is not None and (isinstance(low, bool) or not isinstance(low, int) or low < 0):
            raise TypeError(
                f"Method {self.name!r}: order_with_velocity_forces must be None or an int >= 0; got {low!r}"
            )

    def __repr__(self) -> str:
        return f"Method({self.name!r}, order={self.order})"

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
        return self.step(type(state))(state, force_fn, t, dt)


_REGISTRY: dict[str, Method] = {}


def check_rotors(method: Method, state: Any, where: str) -> None:
    """``ValueError`` naming ``method`` and the methods that support rotors, when ``state`` is a
    gyrostat (has ``rotors``) and ``method`` does not handle them (:attr:`Method.rotors`)."""
    if getattr(state, "rotors", None) is None or method.rotors:
        return
    names = ", ".join(repr(n) for n, m in _REGISTRY.items() if m.rotors)
    scene = (
        ""
        if method.name not in _REGISTRY or is_registered(method)
        else " (a Scene steps with kernels specialised on its body kind, which know no rotors: step the "
        "gyrostat with rb.simulate, or with a Scene of 'splitting' built with kind='general')"
    )
    raise ValueError(
        f"{where}: method {method.name!r} does not support rotors (this state is a gyrostat){scene}; "
        f"the methods that do: {names}"
    )


def register(method: Method) -> Method:
    _REGISTRY[method.name] = method
    return method


def lookup(name: str) -> Method:
    """The registered method ``name``; ``ValueError`` naming those there are if none."""
    m = _REGISTRY.get(name)
    if m is None:
        raise ValueError(f"unknown method {name!r}; available: {sorted(_REGISTRY)}")
    return m


def get(name: str, state_type: type) -> StepFn:
    """The step function of ``name`` for ``state_type``; ``ValueError`` if none."""
    return lookup(name).step(state_type)


def available(state_type: type | None = None) -> dict[str, Method]:
    """Registered methods, optionally only those supporting ``state_type``."""
    return {k: m for k, m in _REGISTRY.items() if state_type is None or state_type in m.steps}


def is_registered(method: Method) -> bool:
    """Whether ``method`` is the registry's method of its name (not a scene's or a user's variant)."""
    return _REGISTRY.get(method.name) is method


def resolve(method: Any, where: str) -> Method:
    """The :class:`Method` that ``method=`` names, for the public function ``where``.

    A string is looked up (``ValueError`` for an unknown name); a Method is
    itself; any other callable is a user's batch step ``(state, force_fn, t, dt)
    -> state`` and becomes an anonymous Method (the same one for equal
    callables, so a rerun reuses its compiled program) that runs batch-first.
    Anything else, or an unhashable callable, raises ``TypeError``.
    """
    if isinstance(method, str):
        return lookup(method)
    if isinstance(method, Method):
        return method
    if callable(method):
        try:
            return _anonymous(method)
        except TypeError:  # unhashable: it could not be a static argument of the compiled run
            raise TypeError(
                f"{where}: method must be hashable, as a static argument of the compiled run; got an unhashable "
                f"{type(method).__name__}. Pass a method name such as 'rk4', a Method from rbjax.methods(), or a "
                "step function defined once"
            ) from None
    raise TypeError(
        f"{where}: method must be a method name such as 'rk4' (see rbjax.methods()), a Method from "
        f"rbjax.methods(), or a batch step callable (state, force_fn, t, dt) -> state; got {type(method).__name__}"
    )


@functools.lru_cache(maxsize=1024)
def _anonymous(fn: StepFn) -> Method:
    # a user's step is written for the batch-first layout and takes any state form
    name = getattr(fn, "__qualname__", None) or repr(fn)
    # rotors=True: a user's step is given the whole state, rotors included, and owns what it does with them
    return Method(
        name=name,
        order=0,
        steps=dict.fromkeys((State, MatrixState, ParticleState), fn),
        layout_agnostic=False,
        rotors=True,
    )


@functools.cache
def for_kind(method: Method, kind: str, torque_free: bool) -> Method:
    """``method`` as a :class:`rbjax.Scene` of ``kind`` bodies runs it (the same object for the same arguments).

    Its kernels for ``kind`` replace its steps, called with ``kind`` and
    ``torque_free``; ``method`` itself when it has none for ``kind``. The
    result has no native kernel (a scene steps in JAX) and is batch-first when
    a kernel it uses is.
    """
    own = {T: fn for (k, T), fn in method.kernels.items() if k == kind}
    if not own:
        return method

    def bind(fn: KernelFn) -> StepFn:
        return lambda state, force_fn, t, dt: fn(state, force_fn, t, dt, kind, torque_free)

    return dataclasses.replace(
        method,
        steps={**method.steps, **{T: bind(fn) for T, fn in own.items()}},
        kernels={},
        layout_agnostic=method.layout_agnostic and not any((kind, T) in method.batch_first_kernels for T in own),
        batch_first_kernels=frozenset(),
        native_code=None,
        # the kernels specialised on a body kind know no rotors
        rotors=False,
        # a kind's kernel turns about its symmetry axis: no frame, unless a state type keeps the general step
        principal_frame=method.principal_frame and any(T not in own for T in (State, MatrixState) if T in method.steps),
    )
