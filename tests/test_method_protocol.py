"""Methods are a protocol: a user's ``rb.AbstractMethod`` subclass runs its own step on every path.

A hand-written explicit midpoint for particles is held to a plain JAX reference written here
(not through rbjax) on the JAX path, a ``Scene`` and a chunked run; those three are one
compiled program, so they agree bit for bit. The native kernels, which compute rbjax's own
methods only, refuse a user's method in words instead of running a built-in in its place.
An abstract class, a class without ``order`` or with a ``native_code``, and a subclass of the
final ``rb.Method`` are refused when built or defined.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb
from rbjax import _simulate

pytestmark = pytest.mark.filterwarnings("ignore::rbjax.OrderWarning")  # splitting under drag, compared on purpose

# all in float64 (the suite's conftest enables x64): the reference's round-off is ~1e-16 per step
N, STEPS, DT = 3, 40, 1e-2
G = np.array([0.0, 0.0, -9.81])
DRAG = 0.4  # N s/m
RNG = np.random.default_rng(7)
MASS = RNG.uniform(0.5, 2.0, N)
X0 = RNG.normal(size=(N, 3))
V0 = RNG.normal(size=(N, 3)) * 3
FORCES = rb.Gravity(g=G) + rb.LinearDrag(DRAG)


class Midpoint(rb.AbstractMethod):
    """Explicit midpoint: ``y₁ = y₀ + h f(y₀ + h/2 f(y₀, t), t + h/2)``, second order, for particles."""

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


def _reference(steps):
    """Explicit midpoint of ``x' = v, v' = g - (b/m) v`` in plain JAX, every state from the first."""
    m = jnp.asarray(MASS)[:, None]

    def accel(v):
        return jnp.asarray(G) - DRAG / m * v

    xs, vs = [jnp.asarray(X0)], [jnp.asarray(V0)]
    for _ in range(steps):
        x, v = xs[-1], vs[-1]
        vh = v + DT / 2 * accel(v)  # the half-step position is not needed: no force depends on it
        xs.append(x + DT * vh)
        vs.append(v + DT * accel(vh))
    return np.stack(xs), np.stack(vs)


def _particles():
    return rb.ParticleState.create(MASS, position=X0, velocity=V0)


def _bitwise_equal(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return len(la) == len(lb) and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


def test_a_users_method_gives_the_reference_on_the_jax_path_a_scene_and_a_chunked_run():
    p = _particles()
    want_x, want_v = _reference(STEPS)
    got = rb.simulate(p, FORCES, DT, STEPS, Midpoint())
    # the same formulas in another order of operations: round-off of 40 float64 steps (|x| ~ 10 m)
    np.testing.assert_allclose(got.position, want_x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.velocity, want_v, rtol=0, atol=1e-12)
    # its own step, not a built-in in its place: euler and splitting differ from it at O(dt) and O(dt²)
    for other in ("euler", "splitting"):
        assert np.max(np.abs(rb.simulate(p, FORCES, DT, STEPS, other).position - got.position)) > 1e-6, other
    scene = rb.Scene.build(p, FORCES, Midpoint())
    assert scene.kind == "particles" and scene.kernel == Midpoint()
    assert _bitwise_equal(scene.simulate(p, DT, STEPS), got)  # one compiled program: the same bits
    chunked = rb.simulate_chunked(p, FORCES, DT, STEPS, Midpoint(), chunk_steps=10, progress=False)
    assert _bitwise_equal(chunked, got)
    one = rb.step(p, FORCES, DT, Midpoint())
    np.testing.assert_allclose(one.position, want_x[1], rtol=0, atol=1e-14)
    assert _bitwise_equal(scene.step(p, DT), one)


def test_equal_method_objects_are_one_compiled_program():
    p = _particles()
    assert Midpoint() == Midpoint() and hash(Midpoint()) == hash(Midpoint())
    first = rb.simulate(p, FORCES, DT, 8, Midpoint(), save_every=8)
    size = _simulate._simulate._cache_size()
    again = rb.simulate(p, FORCES, DT, 8, Midpoint(), save_every=8)
    assert _simulate._simulate._cache_size() == size  # a new instance, no new compile
    assert _bitwise_equal(first, again)


def test_a_method_name_and_its_object_give_the_same_bits_in_a_scene_and_a_run():
    p = _particles()
    obj = rb.methods()["semi_implicit_euler"]
    by_name = rb.simulate(p, FORCES, DT, 8, "semi_implicit_euler")
    assert _bitwise_equal(rb.simulate(p, FORCES, DT, 8, obj), by_name)
    scene = rb.Scene.build(p, FORCES, obj)
    assert scene.kernel is rb.Scene.build(p, FORCES, "semi_implicit_euler").kernel
    assert _bitwise_equal(scene.simulate(p, DT, 8), by_name)


def test_a_users_method_declares_a_scene_kernel_and_the_scene_runs_it():
    seen = []

    class WithKernel(Midpoint):
        def particles_kernel(state, force_fn, t, dt, kind, torque_free):
            seen.append((kind, torque_free))
            return Midpoint()(state, force_fn, t, dt)

        kernels = {("particles", rb.ParticleState): particles_kernel}

    p = _particles()
    scene = rb.Scene.build(p, FORCES, WithKernel())
    got = scene.simulate(p, DT, 8)
    assert seen and set(seen) == {("particles", True)}  # gravity and drag: no torque
    assert _bitwise_equal(got, rb.simulate(p, FORCES, DT, 8, Midpoint()))


def test_with_kernel_gives_a_new_method_and_registers_nothing():
    seen = []
    euler = rb.methods()["euler"]

    def kernel(state, force_fn, t, dt, kind, torque_free):
        seen.append(kind)
        return euler.steps[rb.ParticleState](state, force_fn, t, dt)

    mine = euler.with_kernel("particles", rb.ParticleState, kernel)
    assert rb.methods()["euler"] is euler and mine is not euler and mine.name == "euler"
    p = _particles()
    got = rb.Scene.build(p, FORCES, mine).simulate(p, DT, 8)
    assert seen == ["particles"]  # traced once
    np.testing.assert_array_equal(got.position, rb.Scene.build(p, FORCES, "euler").simulate(p, DT, 8).position)
    with pytest.raises(ValueError, match="kind must be one of"):
        euler.with_kernel("round", rb.State, kernel)


def test_an_abstract_method_and_a_class_without_order_are_refused():
    class NoStep(rb.AbstractMethod):
        order = 1

    with pytest.raises(TypeError, match=r"NoStep is abstract: a method must define __call__"):
        NoStep()
    with pytest.raises(TypeError, match="set the class attribute order"):

        class NoOrder(rb.AbstractMethod):
            def __call__(self, state, force_fn, t, dt):
                return state

    with pytest.raises(TypeError, match="state_types must be"):

        class BadStates(Midpoint):
            state_types = ("ParticleState",)

    with pytest.raises(TypeError, match="native_code must stay None"):

        class ClaimsEuler(Midpoint):
            native_code = 0

    with pytest.raises(TypeError, match="rb.Method is final"):

        class MyTable(rb.Method):
            pass


def test_a_method_class_a_state_it_does_not_step_and_an_unhashable_method_are_refused():
    p = _particles()
    with pytest.raises(TypeError, match=r"pass an instance, method=.*Midpoint\(\)"):
        rb.simulate(p, FORCES, DT, 4, Midpoint)
    s = rb.State.create(rb.sphere(1.0, 0.1))
    with pytest.raises(ValueError, match="'Midpoint' does not support State"):
        rb.simulate(s, None, DT, 4, Midpoint())

    class Holds(Midpoint):
        def __init__(self):
            self.table = [1.0]  # a list: unhashable

    with pytest.raises(TypeError, match="method must be hashable"):
        rb.simulate(p, FORCES, DT, 4, Holds())


class Stay(rb.AbstractMethod):
    """Leaves the state as it is: any built-in would move the bodies."""

    order = 0

    def __call__(self, state, force_fn, t, dt):
        return state


def test_the_native_path_refuses_a_users_method_in_words_and_never_runs_a_builtin():
    if not rb.native_status().available:
        pytest.skip("native kernels not built")
    s = rb.State.create(rb.box(1.0, [0.1, 0.2, 0.3]), velocity=[1.0, 0.0, 0.0], angular_velocity=[0.3, 2.0, 0.1])
    with pytest.raises(ValueError, match=r"native=True\).*user's method.*native=False"):
        rb.simulate(s, None, DT, 4, Stay(), native=True)
    # a Method that claims euler's kernel number with steps of its own: refused with native=True,
    # and with native=None its own steps run (the bodies stay), not euler's kernel (they would move)
    fake = rb.Method(name="fake", order=1, steps={rb.State: Stay()}, native_code=0)
    with pytest.raises(ValueError, match=r"native_code=0, the kernel of rbjax's 'euler', but steps of its own"):
        rb.simulate(s, None, DT, 4, fake, native=True)
    for method in (fake, Stay()):
        traj = rb.simulate(s, None, DT, 4, method)
        np.testing.assert_array_equal(traj.position[-1], s.position)
        np.testing.assert_array_equal(traj.orientation[-1], s.orientation)
