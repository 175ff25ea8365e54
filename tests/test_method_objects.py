"""``method=`` takes a name or a ``Method`` from ``rb.methods()``: the same run, bit for bit.

A ``Method`` names its steps, its Scene kernels, its layout and its native kernel; passing the
object is the same as passing its name (one compiled program, so bitwise equal results), on the
JAX path and the native one. A user's own batch step still works, batch-first as before, and
anything else is refused in rbjax's words.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb
from rbjax._methods import _registry

# these tests run "splitting" under drag on purpose (paths held to each other, inputs refused):
# its first order there is tests/test_force_protocol.py's to check
pytestmark = pytest.mark.filterwarnings("ignore::rbjax.OrderWarning")

RNG = np.random.default_rng(3)
N = 5
QUATS = RNG.normal(size=(N, 4))
QUATS /= np.linalg.norm(QUATS, axis=-1, keepdims=True)
OMEGA = RNG.normal(size=(N, 3)) * 2
FORCES = rb.Gravity() + rb.LinearDrag(0.2, angular=0.1)


def _state(body=None):
    body = rb.box(1.0, jnp.array([0.1, 0.2, 0.4])) if body is None else body
    return rb.State.create(body, orientation=QUATS, angular_velocity=OMEGA, velocity=OMEGA / 2)


def _bitwise_equal(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return len(la) == len(lb) and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


@pytest.mark.parametrize("name", ["rk4", "splitting", "euler"])
@pytest.mark.parametrize("native", [None, False])
def test_simulate_with_a_method_object_is_bitwise_the_name(name, native):
    s = _state()
    by_name = rb.simulate(s, FORCES, 1e-2, 40, name, save_every=10, native=native)
    by_object = rb.simulate(s, FORCES, 1e-2, 40, rb.methods()[name], save_every=10, native=native)
    assert _bitwise_equal(by_object, by_name)
    # ... and the motion is not trivial: the bodies turned
    assert float(jnp.max(jnp.abs(by_name.orientation[-1] - by_name.orientation[0]))) > 0.1


def test_native_true_takes_a_method_object():
    if not rb.native_status().available:
        pytest.skip("native kernels not built")
    s = _state()
    m = rb.methods()["rk4"]
    by_object = rb.simulate(s, FORCES, 1e-2, 40, m, native=True)
    assert _bitwise_equal(by_object, rb.simulate(s, FORCES, 1e-2, 40, "rk4", native=True))
    # the native kernel agrees with the JAX steps to round-off, not bitwise: it was taken
    jax_path = rb.simulate(s, FORCES, 1e-2, 40, m, native=False)
    np.testing.assert_allclose(by_object.orientation, jax_path.orientation, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="'rk8' has no native kernel"):
        rb.simulate(s, FORCES, 1e-2, 4, rb.methods()["rk8"], native=True)


def test_every_function_taking_method_takes_the_object_bitwise():
    s = _state()
    m = rb.methods()["rk4"]
    assert _bitwise_equal(rb.step(s, FORCES, 1e-2, m), rb.step(s, FORCES, 1e-2, "rk4"))
    chunked = rb.simulate_chunked(s, FORCES, 1e-2, 8, m, chunk_steps=4, progress=False)
    assert _bitwise_equal(chunked, rb.simulate_chunked(s, FORCES, 1e-2, 8, "rk4", chunk_steps=4, progress=False))
    trunc = rb.simulate_truncated(s, FORCES, 1e-2, 8, m, truncate_every=4)
    assert _bitwise_equal(trunc, rb.simulate_truncated(s, FORCES, 1e-2, 8, "rk4", truncate_every=4))
    assert _bitwise_equal(rb.shoot(s, None, 1e-2, 8, m), rb.shoot(s, None, 1e-2, 8, "rk4"))
    spheres = _state(rb.sphere(jnp.ones(N), 0.3))
    scene = rb.Scene.build(spheres, FORCES, m)
    assert scene.kind == "isotropic"
    by_name = rb.Scene.build(spheres, FORCES, "rk4")
    assert scene.kernel is by_name.kernel  # one specialised Method: one compiled program
    assert _bitwise_equal(scene.simulate(spheres, 1e-2, 20), by_name.simulate(spheres, 1e-2, 20))


def test_a_scene_kernel_is_the_method_with_its_kind_kernels():
    spheres = _state(rb.sphere(jnp.ones(N), 0.3))
    kernel = rb.Scene.build(spheres, FORCES, "rk4").kernel
    rk4 = rb.methods()["rk4"]
    assert (kernel.name, kernel.order, kernel.stable_dt_omega) == ("rk4", 4, rk4.stable_dt_omega)
    assert kernel.steps[rb.State] is not rk4.steps[rb.State]  # the isotropic kernel, not the general step
    assert kernel.layout_agnostic and kernel.native_code is None
    # a method without kernels for the kind is itself: the scene runs the plain method's program
    assert rb.Scene.build(spheres, FORCES, "rk8").kernel is rb.methods()["rk8"]
    # passed as method=, the scene's kernel is its run
    want = rb.Scene.build(spheres, FORCES, "rk4").simulate(spheres, 1e-2, 20)
    assert _bitwise_equal(rb.simulate(spheres, FORCES, 1e-2, 20, kernel), want)


def test_a_users_own_step_still_runs_batch_first():
    s = _state()
    seen = []
    rk4_step = rb.methods()["rk4"].steps[rb.State]

    def my_step(state, force_fn, t, dt):
        seen.append(state.position.shape)
        return rk4_step(state, force_fn, t, dt)

    got = rb.simulate(s, FORCES, 1e-2, 40, my_step, save_every=10)
    assert seen and set(seen) == {(N, 3)}  # batch-first, as a user writes it
    want = rb.simulate(s, FORCES, 1e-2, 40, "rk4", save_every=10, native=False)
    # the same formulas in the other layout: round-off
    np.testing.assert_allclose(got.orientation, want.orientation, rtol=0, atol=1e-13)
    np.testing.assert_allclose(got.angular_momentum, want.angular_momentum, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(rb.step(s, FORCES, 1e-2, my_step).position, rb.step(s, FORCES, 1e-2, "rk4").position)


def test_every_entry_point_takes_a_step_callable_as_simulate_does():
    s = _state()
    rk4_step = rb.methods()["rk4"].steps[rb.State]

    def my_step(state, force_fn, t, dt):
        return rk4_step(state, force_fn, t, dt)

    want = rb.simulate(s, FORCES, 1e-2, 8, my_step)
    assert _bitwise_equal(rb.simulate_chunked(s, FORCES, 1e-2, 8, my_step, chunk_steps=4, progress=False), want)
    # another program (chunks in a scan): the same values to round-off under the suite's compiler flags
    trunc = rb.simulate_truncated(s, FORCES, 1e-2, 8, my_step, truncate_every=4)
    np.testing.assert_allclose(trunc.orientation, want.orientation, rtol=0, atol=1e-13)
    np.testing.assert_allclose(trunc.angular_momentum, want.angular_momentum, rtol=0, atol=1e-13)
    scene = rb.Scene.build(s, FORCES, my_step)
    assert _bitwise_equal(scene.simulate(s, 1e-2, 8), want)
    assert _bitwise_equal(scene.step(s, 1e-2), rb.step(s, FORCES, 1e-2, my_step))
    # shoot: each body its own segment, stepped one at a time (vmapped), not as one batch: round-off
    _, ends = rb.shoot(s, FORCES, 1e-2, 8, my_step)
    np.testing.assert_allclose(ends.orientation, want.orientation[-1], rtol=0, atol=1e-13)
    np.testing.assert_allclose(ends.velocity, want.velocity[-1], rtol=0, atol=1e-13)
    np.testing.assert_allclose(ends.angular_momentum, want.angular_momentum[-1], rtol=0, atol=1e-13)


def test_a_registered_users_kernel_is_used_and_sees_batch_first_states(monkeypatch):
    # register_kernel replaces the registry's method; the monkeypatch puts the original back
    monkeypatch.setitem(_registry._REGISTRY, "rk8", rb.methods()["rk8"])
    seen = []
    rk8_step = rb.methods()["rk8"].steps[rb.State]

    def kernel(state, force_fn, t, dt, kind, torque_free):
        seen.append((state.position.shape, kind, torque_free))
        return rk8_step(state, force_fn, t, dt)

    with pytest.warns(DeprecationWarning, match="with_kernel"):  # the old spelling of Method.with_kernel
        rb.register_kernel("rk8", "isotropic", rb.State, kernel)
    spheres = _state(rb.sphere(jnp.ones(N), 0.3))
    scene = rb.Scene.build(spheres, FORCES, "rk8")
    assert not scene.kernel.layout_agnostic
    got = scene.simulate(spheres, 1e-2, 20)
    assert seen and set(seen) == {((N, 3), "isotropic", False)}  # angular drag: a torque
    want = rb.simulate(spheres, FORCES, 1e-2, 20, "rk8")
    np.testing.assert_allclose(got.orientation, want.orientation, rtol=0, atol=1e-13)
    # the plain method keeps its own, layout-agnostic steps
    assert rb.methods()["rk8"].layout_agnostic
    with pytest.raises(ValueError, match="unknown method 'nope'"), pytest.warns(DeprecationWarning):
        rb.register_kernel("nope", "isotropic", rb.State, kernel)


BAD = [None, 3, ["rk4"], {"name": "rk4"}]


@pytest.mark.parametrize("bad", BAD, ids=repr)
def test_a_wrong_method_type_is_refused_naming_method_and_remedy(bad):
    s = _state()
    calls = {
        "simulate": lambda: rb.simulate(s, None, 1e-2, 4, bad),
        "step": lambda: rb.step(s, None, 1e-2, bad),
        "simulate_chunked": lambda: rb.simulate_chunked(s, None, 1e-2, 4, bad, progress=False),
        "simulate_truncated": lambda: rb.simulate_truncated(s, None, 1e-2, 4, bad, truncate_every=2),
        "shoot": lambda: rb.shoot(s, None, 1e-2, 4, bad),
        "Scene.build": lambda: rb.Scene.build(s, None, bad),
    }
    for name, call in calls.items():
        with pytest.raises(TypeError) as info:
            call()
        msg = str(info.value)
        assert "method must be" in msg and "rbjax.methods()" in msg, (name, msg)
        assert type(bad).__name__ in msg, (name, msg)


def test_an_unhashable_step_callable_is_refused_in_rbjax_words():
    class Unhashable:
        __hash__ = None  # type: ignore[assignment]

        def __call__(self, state, force_fn, t, dt):
            return state

    with pytest.raises(TypeError, match="method must be hashable"):
        rb.simulate(_state(), None, 1e-2, 4, Unhashable())


def test_an_unknown_name_and_an_unsupported_state_form_are_value_errors():
    s = _state()
    with pytest.raises(ValueError, match="unknown method 'leapfrog'"):
        rb.simulate(s, None, 1e-2, 4, "leapfrog")
    p = rb.ParticleState.create(jnp.ones(N), velocity=OMEGA)
    with pytest.raises(ValueError, match="'rk4_body' does not support ParticleState"):
        rb.simulate(p, None, 1e-2, 4, rb.methods()["rk4_body"])


def test_a_users_method_is_a_public_method_object_run_by_every_entry_point():
    # a user's step written as rb.Method: its order is known, and simulate runs it as it runs "euler"
    euler = rb.methods()["euler"]
    mine = rb.Method(name="my_euler", order=1, steps=dict(euler.steps), layout_agnostic=euler.layout_agnostic)
    s = rb.State.create(rb.box(1.0, [0.1, 0.2, 0.4]), angular_velocity=[0.1, 2.0, 0.1], velocity=[1.0, 0, 0])
    want = rb.simulate(s, rb.Gravity(), 1e-3, 50, "euler", native=False)
    got = rb.simulate(s, rb.Gravity(), 1e-3, 50, mine)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))  # the same steps: the same bits
    assert repr(mine) == "Method('my_euler', order=1)"


@pytest.mark.parametrize(
    "fields,named",
    [
        (dict(name="", order=1, steps={rb.State: lambda *a: a[0]}), "name"),
        (dict(name="m", order=-1, steps={rb.State: lambda *a: a[0]}), "order"),
        (dict(name="m", order=True, steps={rb.State: lambda *a: a[0]}), "order"),
        (dict(name="m", order=1, steps={}), "steps"),
        (dict(name="m", order=1, steps={"State": lambda *a: a[0]}), "steps"),
        (dict(name="m", order=1, steps={rb.State: 3.0}), "steps"),
        (dict(name="m", order=2, steps={rb.State: lambda *a: a[0]}, order_with_velocity_forces=1.5), "order_with"),
    ],
)
def test_a_method_with_fields_it_cannot_mean_is_refused_naming_the_field(fields, named):
    with pytest.raises(TypeError, match=named):
        rb.Method(**fields)
