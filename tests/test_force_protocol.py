"""Force laws as a protocol: every subclass is a pytree that runs its own law on every path.

The reference for each case is a :class:`rbjax.CustomForce` written out by hand: a plain
callable that shares no class machinery with the model under test, so a path that ran a
parent's formula (the native kernel picking laws by ``isinstance``, ``rk4_body`` reading a
parent's body-frame torque, ``as_per_body`` rewriting a thruster) would disagree with it.
Float64 throughout; native and JAX paths agree to round-off (tests/test_native.py), so
the tolerance is 1e-11 relative on states of order one after 40 steps.
"""

from __future__ import annotations

import inspect
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb

PATHS = [
    ("euler", None),
    ("rk4", None),
    ("rk4", False),
    ("rk4_body", None),
    ("rk4_body", False),
    ("splitting", None),
    ("semi_implicit_euler", None),
    ("semi_implicit_euler", True),
]
DT, STEPS = 0.01, 40


def _bodies(n: int = 3) -> rb.State:
    rng = np.random.default_rng(7)
    q = rng.normal(size=(n, 4))
    body = rb.box(jnp.asarray(rng.uniform(0.5, 2.0, n)), jnp.asarray(rng.uniform(0.1, 0.5, (n, 3))))
    return rb.State.create(
        body,
        position=rng.normal(size=(n, 3)),
        velocity=rng.normal(size=(n, 3)),
        orientation=q / np.linalg.norm(q, axis=1, keepdims=True),
        angular_velocity=rng.normal(size=(n, 3)) * 3.0,
    )


class MoonGravity(rb.Gravity):
    """Gravity at a sixth: overrides ``on_body`` only."""

    def on_body(self, state, t):
        return rb.Forces(force=super().on_body(state, t).force / 6.0)


class GravityByCall(rb.Gravity):
    """Overrides ``__call__`` (the batch-level law) and not ``on_body``."""

    def __call__(self, state, t):
        return rb.Forces(force=state.mass[..., None] * jnp.asarray([0.0, 0.0, -1.0], state.dtype))


class SpinDrag(rb.LinearDrag):
    """A drag whose torque is twice the parent's: overrides ``on_body`` and not its body-frame form."""

    def on_body(self, state, t):
        f = super().on_body(state, t)
        return rb.Forces(force=f.force, torque=2.0 * f.torque)


class ThrusterByCall(rb.Thruster):
    """A thruster at half thrust, written as ``__call__`` (not ``as_per_body``)."""

    def __call__(self, state, t):
        f = super().__call__(state, t)
        return rb.Forces(force=0.5 * f.force, torque=0.5 * f.torque)


class Buoyancy(rb.ForceModel):
    """A user's own law as docs/scenes.md writes one: fields, ``__call__``, nothing registered."""

    volume: jax.Array
    density: float = 1000.0

    def __call__(self, state, t):
        lift = self.density * self.volume * 9.81
        return rb.Forces(force=jnp.stack([0 * lift, 0 * lift, lift], -1) * jnp.ones_like(state.velocity))


def _omega(s):
    return rb.angular_velocity(s)


# (model, reference callable): the reference is the law written out, batch-level, world frame
CASES = {
    "Gravity subclass, on_body": (
        MoonGravity(),
        lambda s, t: rb.Forces(force=s.mass[:, None] * jnp.array([0.0, 0.0, -9.81 / 6.0])),
    ),
    "Gravity subclass, __call__": (
        GravityByCall(),
        lambda s, t: rb.Forces(force=s.mass[:, None] * jnp.array([0.0, 0.0, -1.0])),
    ),
    "LinearDrag subclass, on_body": (
        SpinDrag(linear=0.3, angular=0.05),
        lambda s, t: rb.Forces(force=-0.3 * s.velocity, torque=-0.1 * _omega(s)),
    ),
    "Thruster subclass, __call__": (
        ThrusterByCall(
            body_index=[0, 2], direction=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], thrust=[2.0, 4.0], point=[0.1, 0, 0]
        ),
        None,  # the reference is the parent at half thrust, below
    ),
    "ForceModel subclass": (
        Buoyancy(volume=jnp.asarray([1e-3, 2e-3, 5e-4])),
        lambda s, t: rb.Forces(force=jnp.array([[0, 0, 9.81]]) * jnp.array([[1e-3], [2e-3], [5e-4]]) * 1000.0),
    ),
}


def _reference(name):
    model, ref = CASES[name]
    if ref is None:
        parent = rb.Thruster(
            body_index=model.body_index, direction=model.direction, thrust=0.5 * model.thrust, point=model.point
        )
        return rb.CustomForce(lambda s, t: parent(s, t))
    return rb.CustomForce(ref)


def _close(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-11, atol=1e-11)


@pytest.fixture(autouse=True)
def _x64():
    with jax.enable_x64(True):
        yield


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("method,native", PATHS, ids=lambda p: str(p))
def test_a_subclass_runs_its_own_law_on_every_path(name, method, native):
    state = _bodies()
    model = CASES[name][0]
    want = rb.simulate(state, _reference(name), DT, STEPS, method, native=False)
    got = rb.simulate(state, model, DT, STEPS, method, native=native)
    _close(got, want)
    # the law changed the motion: a path that dropped the model would not pass
    free = rb.simulate(state, None, DT, STEPS, method, native=False)
    assert (
        np.abs(np.asarray(got.velocity - free.velocity)).max()
        + np.abs(np.asarray(got.angular_momentum - free.angular_momentum)).max()
        > 1e-3
    )


@pytest.mark.parametrize("name", list(CASES))
def test_a_subclass_runs_its_own_law_in_a_scene_and_in_chunks(name):
    state = _bodies()
    model = CASES[name][0]
    # a scene compiles kernels for its bodies' kind: its reference is the same scene's
    scene = rb.Scene.build(state, _reference(name), "rk4").simulate(state, DT, STEPS)
    _close(rb.Scene.build(state, model, "rk4").simulate(state, DT, STEPS), scene)
    want = rb.simulate(state, _reference(name), DT, STEPS, "rk4", native=False)
    chunked = rb.simulate_chunked(state, model, DT, STEPS, "rk4", chunk_steps=15, progress=False)
    _close(chunked, want)
    # and the law moved the bodies: a scene or chunk that dropped the model would differ from free motion
    free = rb.simulate(state, None, DT, STEPS, "rk4", native=False)
    moved = np.abs(np.asarray(chunked.velocity - free.velocity)).max()
    moved += np.abs(np.asarray(chunked.angular_momentum - free.angular_momentum)).max()
    assert moved > 1e-3, moved


def test_native_true_refuses_a_subclass_where_forces_are_needed_between_step_starts():
    with pytest.raises(ValueError, match="exact types, so not a subclass"):
        rb.simulate(_bodies(), MoonGravity(), DT, 2, "rk4", native=True)


def test_a_model_without_its_law_is_refused_when_built():
    class NoLaw(rb.ForceModel):
        k: float = 1.0

    class NoOnBody(rb.PerBodyForce):
        k: float = 1.0

    with pytest.raises(TypeError, match=r"NoLaw cannot be built: it does not define __call__"):
        NoLaw()
    with pytest.raises(TypeError, match=r"NoOnBody cannot be built: it does not define on_body"):
        NoOnBody()


def test_a_model_with_its_own_init_is_refused_at_its_definition():
    with pytest.raises(TypeError, match="writes no __init__: declare its parameters as annotated fields"):

        class WithInit(rb.ForceModel):  # noqa: F841 - the definition is what is refused
            def __init__(self, k):
                self.k = k

            def __call__(self, state, t):
                return rb.Forces()


def test_a_field_jit_cannot_trace_is_named_with_its_remedy_and_a_static_field_runs():
    class Mode(rb.ForceModel):
        mode: str = "push"

        def __call__(self, state, t):
            return rb.Forces(force=jnp.ones_like(state.velocity) * (1.0 if self.mode == "push" else -1.0))

    with pytest.raises(TypeError, match=r"simulate: forces: Mode\.mode holds a str.*rb\.static_field\(\)"):
        rb.simulate(_bodies(), Mode(), DT, 2, "euler")

    class StaticMode(rb.ForceModel):
        mode: str = rb.static_field(default="pull")

        def __call__(self, state, t):
            return rb.Forces(force=jnp.ones_like(state.velocity) * (1.0 if self.mode == "push" else -1.0))

    state = _bodies()
    out = rb.simulate(state, StaticMode(), DT, 10, "euler")
    # v(t) = v0 - t/m exactly under Euler with a constant force
    np.testing.assert_allclose(out.velocity[-1], state.velocity - 0.1 / state.mass[:, None], rtol=1e-12)


def test_a_subclass_cannot_skip_its_parents_checks():
    class Quiet(rb.Gravity):
        def __post_init__(self):
            pass

    with pytest.raises(ValueError, match="Gravity: g must be a"):
        Quiet(g=9.81)
    with pytest.raises(ValueError, match="must be >= 0"):
        SpinDrag(linear=-1.0)


def test_splitting_under_drag_is_first_order_and_says_so():
    """The order the warning states, measured: the error of "splitting" under linear drag halves
    with dt (log2 ratio 1 ± 0.1 over three halvings) against rk8 at dt/8 (error ~1e-12 here,
    far below splitting's 2e-3); gravity alone keeps order 2, unwarned."""
    state = _bodies(1)
    drag = rb.Gravity() + rb.LinearDrag(linear=0.5, angular=0.002)
    ref = rb.simulate(state, drag, 1.0 / 3200, 3200, "rk8", save_every=3200)
    errors = []
    for n in (50, 100, 200, 400):
        with pytest.warns(rb.OrderWarning, match="LinearDrag reads velocities.*order 1"):
            out = rb.simulate(state, drag, 1.0 / n, n, "splitting", save_every=n)
        errors.append(float(jnp.abs(out.velocity[-1] - ref.velocity[-1]).max()))
    np.testing.assert_allclose(np.log2(np.array(errors[:-1]) / np.array(errors[1:])), 1.0, atol=0.1)
    with pytest.warns(rb.OrderWarning, match="splitting4"):
        rb.simulate(state, drag, 0.01, 2, "splitting4")
    with pytest.warns(rb.OrderWarning, match="Spring"):
        rb.simulate(_bodies(), rb.Spring.between([0], [1], 10.0, damping=0.5), 0.01, 2, "splitting")
    with warnings.catch_warnings():
        warnings.simplefilter("error", rb.OrderWarning)
        rb.simulate(state, drag, 0.01, 2, "rk4")  # rk4 keeps its order
        rb.simulate(_bodies(), rb.Spring.between([0], [1], 10.0), 0.01, 2, "splitting")  # no damper
        rb.simulate(state, MoonGravity(), 0.01, 2, "splitting")  # a subclass that says nothing: no claim


def test_a_law_shows_its_fields_as_its_signature_and_an_instance_shows_its_call():
    # the metaclass's __call__ would otherwise show every model as (*args, **kwargs) in help()
    spring = inspect.signature(rb.Spring)
    assert list(spring.parameters)[:2] == ["body_index", "stiffness"]
    assert spring.parameters["rest_length"].default == 0.0
    assert list(inspect.signature(MoonGravity).parameters) == ["g"]
    assert list(inspect.signature(MoonGravity()).parameters) == ["state", "t"]


def test_a_field_off_the_batch_is_named_before_tracing():
    class Wind(rb.PerBodyForce):
        k: jax.Array

        def on_body(self, state, t):
            return rb.Forces(force=-self.k * state.velocity)

    state = rb.State.create(rb.box(jnp.ones(4), jnp.ones((4, 3))))
    with pytest.raises(ValueError, match=r"Wind\.k \(3,\)"):
        rb.simulate(state, Wind(jnp.ones(3)), 0.01, 5)
