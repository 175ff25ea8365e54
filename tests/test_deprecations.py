"""Old spellings of public arguments: each still works for one release, warns, and names the new one.

Every alias gives the same bits as the new spelling, and its ``DeprecationWarning`` points at the
caller's line (this file), so ``-W error::DeprecationWarning`` finds the call to change.
"""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb

RNG = np.random.default_rng(7)
N = 3
QUATS = RNG.normal(size=(N, 4))
QUATS /= np.linalg.norm(QUATS, axis=-1, keepdims=True)
OMEGA = RNG.normal(size=(N, 3))


def _state(time=0.0):
    body = rb.box(1.0, jnp.array([0.1, 0.2, 0.4]))
    return rb.State.create(body, orientation=QUATS, angular_velocity=OMEGA, velocity=OMEGA / 2, time=time)


def _torque(state, t):  # time-dependent: a wrong start time changes the bits
    return rb.Forces(torque=jnp.stack([jnp.sin(3 * t), 0.1 + 0 * t, jnp.cos(t)]))


def _bitwise_equal(a, b):
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    return ta == tb and all(
        x.dtype == y.dtype and x.shape == y.shape and np.asarray(x).tobytes() == np.asarray(y).tobytes()
        for x, y in zip(la, lb, strict=True)
    )


def _old(call, *new_names):
    """``call()`` under deprecated spellings: its result, after checking the one warning each gives."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = call()
    deprecations = [w for w in caught if issubclass(w.category, DeprecationWarning)]
    assert len(deprecations) == len(new_names), [str(w.message) for w in caught]
    for w, new_name in zip(deprecations, new_names):
        assert f"{new_name}=" in str(w.message) or f".{new_name}" in str(w.message), str(w.message)
        assert w.filename == __file__, (w.filename, str(w.message))  # blamed on the user's call
    return out


def _new(call):
    """``call()`` under the new spelling: no DeprecationWarning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        return call()


# ---- time: t0 everywhere, None = the state's own time


def test_step_t_is_t0():
    s = _state()
    new = _new(lambda: rb.step(s, _torque, 0.01, "rk4", t0=0.3))
    old = _old(lambda: rb.step(s, _torque, 0.01, "rk4", t=0.3), "t0")
    assert _bitwise_equal(old, new)
    assert not _bitwise_equal(new, rb.step(s, _torque, 0.01, "rk4"))  # t0 was used
    with pytest.raises(TypeError, match="both t0= and its deprecated spelling t="):
        rb.step(s, _torque, 0.01, "rk4", t=0.3, t0=0.3)


def test_step_t_under_jit_is_t0():
    s = _state()
    new = jax.jit(lambda s, t: rb.step(s, _torque, 0.01, "rk4", t0=t))(s, 0.3)
    old = _old(lambda: jax.jit(lambda s, t: rb.step(s, _torque, 0.01, "rk4", t=t))(s, 0.3), "t0")
    assert _bitwise_equal(old, new)


def test_scene_step_t_is_t0():
    s = _state()
    scene = rb.Scene.build(s, rb.Gravity() + rb.LinearDrag(0.1), "rk4")
    new = _new(lambda: scene.step(s, 0.01, t0=0.3))
    old = _old(lambda: scene.step(s, 0.01, t=0.3), "t0")
    assert _bitwise_equal(old, new)
    assert _bitwise_equal(scene.step(s, 0.01, 0.3), new)  # positional: the same place as before


def test_shoot_t0_defaults_to_the_first_segments_time():
    # time 0 (every start state made by State.create): the same bits as the old default t0=0.0
    s = _state()
    got = _new(lambda: rb.shoot(s, _torque, 0.01, 8, "rk4"))
    assert _bitwise_equal(got, rb.shoot(s, _torque, 0.01, 8, "rk4", t0=0.0))
    # a state of its own time: segment 0 starts there (the old default started it at 0)
    late = _state(time=2.5)
    got = rb.shoot(late, _torque, 0.01, 8, "rk4")
    assert _bitwise_equal(got, rb.shoot(late, _torque, 0.01, 8, "rk4", t0=2.5))
    assert not _bitwise_equal(got, rb.shoot(late, _torque, 0.01, 8, "rk4", t0=0.0))
    np.testing.assert_allclose(got[1].time, 2.5 + 0.08 * np.arange(1, N + 1), rtol=1e-12)


# ---- fit_inertia_linear(times, orientations=None, *, body_rates, torques), as fit_inertia


def _tumble(torque):
    body = rb.Body(1.0, jnp.diag(jnp.array([1.0, 2.0, 2.6])))
    s = rb.State.create(body, angular_velocity=jnp.array([0.3, 2.0, 0.2]))
    traj = rb.simulate(s, rb.Forces(torque=torque), 1e-3, 2000, "rk4", save_every=10)
    times = np.asarray(traj.time)
    return (
        times,
        np.asarray(rb.orientation(traj)),
        np.asarray(rb.body_angular_velocity(traj)),
        np.tile(torque, (times.size, 1)),
    )


def test_fit_inertia_linear_old_positional_order():
    times, _, w, _ = _tumble(jnp.zeros(3))
    new = _new(lambda: rb.fit_inertia_linear(times, body_rates=w))
    old = _old(lambda: rb.fit_inertia_linear(times, w), "body_rates")
    assert _bitwise_equal(old, new)
    times, q, w, tau = _tumble(jnp.array([0.2, 0.1, -0.1]))
    new = _new(lambda: rb.fit_inertia_linear(times, q, body_rates=w, torques=tau))
    assert _bitwise_equal(_old(lambda: rb.fit_inertia_linear(times, w, q, tau), "body_rates"), new)
    assert _bitwise_equal(_old(lambda: rb.fit_inertia_linear(times, w, orientations=q, torques=tau), "body_rates"), new)
    np.testing.assert_allclose(new, np.diag([1.0, 2.0, 2.6]), atol=1e-2)  # absolute: the torques were used


# ---- body indices of Spring and Thruster: body_index, other_index


def _three():
    body = rb.box(jnp.ones(3), jnp.array([0.1, 0.2, 0.4]))
    return rb.State.create(body, position=np.eye(3), orientation=QUATS, angular_velocity=OMEGA, velocity=OMEGA / 2)


_P = [[0.1, 0.0, 0.05]]
_D = [[0.0, 0.6, 0.8]]


def _same_model(old, new):
    s = _three()
    assert type(old) is type(new) and _bitwise_equal(old, new)
    assert _bitwise_equal(old(s, 0.0), new(s, 0.0))
    assert _bitwise_equal(rb.simulate(s, old, 0.01, 4, "rk4"), rb.simulate(s, new, 0.01, 4, "rk4"))


def test_spring_body_and_other_keywords():
    new = _new(lambda: rb.Spring.to_anchor(body_index=[1], anchor=[0.0, 0, 1], stiffness=3.0, point=_P))
    old = _old(lambda: rb.Spring.to_anchor(body=[1], anchor=[0.0, 0, 1], stiffness=3.0, point=_P), "body_index")
    _same_model(old, new)
    new = _new(lambda: rb.Spring(body_index=[0], other_index=[2], stiffness=3.0, point=_P, anchor=_P, damping=0.1))
    old = _old(
        lambda: rb.Spring(body=[0], other=[2], stiffness=3.0, point=_P, anchor=_P, damping=0.1),
        "body_index",
        "other_index",
    )
    _same_model(old, new)
    assert _bitwise_equal(new, rb.Spring.between([0], [2], 3.0, point_a=_P, point_b=_P, damping=0.1))
    assert _bitwise_equal(_old(lambda: new.body, "body_index"), new.body_index)
    assert _bitwise_equal(_old(lambda: new.other, "other_index"), new.other_index)
    with pytest.raises(AttributeError):
        new.body = np.array([1])  # type: ignore[misc]
    with pytest.raises(TypeError, match="both body_index= and its deprecated spelling body="):
        rb.Spring.to_anchor(body_index=[1], anchor=[0.0, 0, 1], stiffness=3.0, body=[1])


def test_thruster_body_keyword():
    new = _new(lambda: rb.Thruster(body_index=[1], direction=_D, thrust=2.0, point=_P))
    old = _old(lambda: rb.Thruster(body=[1], direction=_D, thrust=2.0, point=_P), "body_index")
    _same_model(old, new)
    assert _bitwise_equal(_old(lambda: new.body, "body_index"), new.body_index)
    with pytest.raises(TypeError, match="both body_index= and its deprecated spelling body="):
        rb.Thruster(body_index=[1], body=[1], direction=_D, thrust=2.0)

    class Half(rb.Thruster):  # a user's subclass keeps the old keyword too
        def __call__(self, state, t):
            f = super().__call__(state, t)
            return rb.Forces(force=0.5 * f.force, torque=0.5 * f.torque)

    _same_model(
        _old(lambda: Half(body=[1], direction=_D, thrust=2.0, point=_P), "body_index"),
        _new(lambda: Half(body_index=[1], direction=_D, thrust=2.0, point=_P)),
    )


def test_spring_between_index_keywords():
    new = _new(lambda: rb.Spring.between(index_a=[0], index_b=[2], stiffness=3.0, point_a=_P, damping=0.1))
    old = _old(
        lambda: rb.Spring.between(body_a=[0], body_b=[2], stiffness=3.0, point_a=_P, damping=0.1), "index_a", "index_b"
    )
    _same_model(old, new)
    # the indices land where they belong: index_a is the spring's body, index_b its other end
    np.testing.assert_array_equal(new.body_index, [0])
    np.testing.assert_array_equal(new.other_index, [2])
    with pytest.raises(TypeError, match="both index_a= and its deprecated spelling body_a="):
        rb.Spring.between(index_a=[0], body_a=[0], index_b=[2], stiffness=3.0)
