"""``"rk4_body"``: classical RK4 on the body-frame equations (against rk4's error constant).

References are independent of rbjax: RK4 on Euler's equations written out in
NumPy, the exact torque-free solution (``rb.torque_free``, itself tested against
DOP853), and scipy's DOP853 (tests/reference.py) for a driven body.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import reference_rotation

import rbjax as rb

I_T = np.diag([1.0, 2.0, 2.8])  # the Dzhanibekov T-handle of the issue
W0 = np.array([1e-3, 2.0, 1e-3])


def _numpy_rk4_euler(w0, h, n):
    """Textbook RK4 on ``I ω̇ = Iω × ω`` (body frame), written out: the rates' reference."""
    Iinv = np.linalg.inv(I_T)
    f = lambda w: Iinv @ np.cross(I_T @ w, w)
    out = [w0]
    w = w0
    for _ in range(n):
        k1 = f(w)
        k2 = f(w + h / 2 * k1)
        k3 = f(w + h / 2 * k2)
        k4 = f(w + h * k3)
        w = w + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(w)
    return np.array(out)


def test_rates_are_textbook_rk4_on_eulers_equations():
    s = rb.State.create(rb.Body(1.0, I_T), angular_velocity=W0)  # identity attitude: body = world at t = 0
    h, n = 0.01, 2000
    traj = rb.simulate(s, None, h, n, "rk4_body")
    # torque-free Euler equations do not involve q, so the rates are RK4's on a 3-D ODE; they
    # differ from the written-out RK4 only by rounding in ω = R(q)ᵀ L (q normalised each step)
    # and the growth of rounding through the flips: 1e-10 over 20 s
    np.testing.assert_allclose(rb.body_angular_velocity(traj), _numpy_rk4_euler(W0, h, n), atol=1e-10)


def test_t_handle_energy_and_flip_times():
    s = rb.State.create(rb.Body(1.0, I_T), angular_velocity=W0)
    h, n = 0.01, 10_000  # 100 s at h = 0.01
    exact = rb.torque_free(s, h * np.arange(n + 1))
    E0 = float(rb.kinetic_energy(s))
    flips = lambda tr: np.nonzero(np.diff(np.sign(np.asarray(rb.body_angular_velocity(tr))[:, 1])))[0]
    drift, offset = {}, {}
    for m in ["rk4", "rk4_body"]:
        tr = rb.simulate(s, None, h, n, m)
        drift[m] = float(np.max(np.abs(np.asarray(rb.kinetic_energy(tr)) - E0)) / E0)
        got, want = flips(tr), flips(exact)
        assert len(got) == len(want) == 6
        offset[m] = int(np.max(np.abs(got - want)))
    # measured: rk4 9.9e-9 and 13 steps late; rk4_body 9.4e-11 and exact to the step
    assert drift["rk4_body"] < 2e-10 and drift["rk4"] > 50 * drift["rk4_body"]
    assert offset["rk4_body"] == 0 and offset["rk4"] >= 10
    # rk4 keeps world L exact torque-free (L̇ = τ = 0); rk4_body only to its O(h⁴) error
    tr = rb.simulate(s, None, h, 1000, "rk4")
    np.testing.assert_array_equal(tr.angular_momentum[-1], s.angular_momentum)


@pytest.mark.parametrize("cls", [rb.State, rb.MatrixState])
def test_fourth_order_with_a_body_fixed_torque_against_dop853(cls):
    q0 = np.asarray(rb.quat_normalize(jnp.asarray([1.0, 0.3, -0.2, 0.1])))
    w0 = np.array([0.5, 1.5, -0.7])
    tau_body = np.array([0.05, -0.1, 0.2])

    def forces(state, t):  # a thruster fixed in the body: τ = R τ_b (varies with the attitude)
        return rb.Forces(torque=rb.quat_rotate(rb.orientation(state), jnp.asarray(tau_body)))

    def tau_world(t, q, w):
        from reference import qrot

        return qrot(q, tau_body)

    T = 2.0
    q_ref, w_ref = reference_rotation(I_T, q0, w0, np.array([0.0, T]), tau_world)
    # one program for the three step sizes: 200 steps saving every 50th state, dt traced; the run
    # at dt = T/n reads its state after n steps (at T), the same numbers as an n-step run on its own
    s = cls.create(rb.Body(1.0, I_T), orientation=q0, angular_velocity=w0)
    errs = []
    for n in (50, 100, 200):
        end = rb.simulate(s, forces, jnp.asarray(T / n), 200, "rk4_body", save_every=50)[n // 50]
        errs.append(np.linalg.norm(np.asarray(rb.angular_velocity(end)) - w_ref[-1]))
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    # fourth order: each halving of h divides the error by ~16 (asymptotic range: 3.8..4.3)
    assert np.all((orders > 3.7) & (orders < 4.4)), (errs, orders)


def test_float32_and_jit_grad():
    s = rb.State.create(
        rb.Body(jnp.float32(1.0), jnp.asarray(I_T, jnp.float32)), angular_velocity=W0.astype(np.float32)
    )
    tr = rb.simulate(s, None, 0.01, 500, "rk4_body")
    assert tr.orientation.dtype == jnp.float32
    # |q| = 1 by normalisation, to float32 rounding
    np.testing.assert_allclose(np.linalg.norm(tr.orientation, axis=-1), 1.0, atol=4 * np.finfo(np.float32).eps)
    # derivative through the step against central differences (float64; O(h²) ≈ 1e-10)

    def loss(w):
        st = rb.State.create(rb.Body(1.0, I_T), angular_velocity=w)
        return rb.simulate(st, None, 0.01, 100, "rk4_body", save_every=100).orientation[-1, 1]

    g = jax.jit(jax.grad(loss))(jnp.asarray(W0))
    e = np.array([0.0, 1.0, 0.0])
    fd = (loss(jnp.asarray(W0 + 1e-5 * e)) - loss(jnp.asarray(W0 - 1e-5 * e))) / 2e-5
    np.testing.assert_allclose(g[1], fd, rtol=1e-6)


def test_forces_see_unit_quaternions_at_the_stages():
    # At an RK4 stage |q| ≠ 1 by O(h²); the forces get q/|q|, as a State promises. A law that
    # reads |q|² - 1 (zero on any State) must then leave the run torque-free to round-off; fed
    # the raw stage q it adds a torque of 1e3 · O(h²) ≈ 1e-2 N·m here (dt·|ω| ≈ 0.2).
    def off_unit(state, t):
        q = rb.orientation(state)
        return rb.Forces(torque=1e3 * (jnp.sum(q * q, axis=-1, keepdims=True) - 1) * jnp.ones(3))

    s = rb.State.create(rb.Body(1.0, I_T), angular_velocity=[0.5, 1.5, -0.7])
    free = rb.simulate(s, None, 0.1, 50, "rk4_body", native=False)
    driven = rb.simulate(s, off_unit, 0.1, 50, "rk4_body", native=False)
    # float64 round-off: |q|² - 1 ~ 1e-16 times 1e3 per evaluation, 200 evaluations
    np.testing.assert_allclose(driven.angular_momentum, free.angular_momentum, atol=1e-10)
    np.testing.assert_allclose(driven.orientation, free.orientation, atol=1e-10)


def _bodies_and_loads():
    rng = np.random.default_rng(7)
    moments = rng.uniform(1.0, 1.9, (5, 3))  # any two sum past the third: physical
    body = rb.Body(rng.uniform(0.5, 2.0, 5), jnp.asarray(np.einsum("ni,ij->nij", moments, np.eye(3))))
    q = rng.normal(size=(5, 4))
    s = rb.State.create(
        body,
        velocity=rng.normal(size=(5, 3)),
        orientation=q / np.linalg.norm(q, axis=-1, keepdims=True),
        angular_velocity=rng.normal(size=(5, 3)) * 2.0,
    )
    directions = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]])
    model = (
        rb.Gravity()
        + rb.QuadraticDrag(0.05, 0.02)
        + rb.LinearDrag(0.1, jnp.asarray([0.01, 0.02, 0.03, 0.04, 0.05]))
        + rb.ConstantForce(torque=jnp.asarray([0.1, -0.2, 0.05]))
        + rb.Thruster([0, 3], directions, [2.0, -1.0], point=[[0.1, 0.0, 0.0], [0.0, -0.2, 0.1]])
    )
    return s, model


def test_per_body_laws_in_the_body_frame_match_the_world_path():
    # simulate evaluates per-body laws with rk4_body's stage derivative and takes their torque in
    # the body frame (drag reads ω_b, nothing turns); a plain callable goes the world-frame way
    # (forces on the batch, torque turned back by R(q̂)ᵀ). The same law both ways: float64
    # round-off over 100 steps (1e-12; the loads change L by O(1), checked below)
    s, model = _bodies_and_loads()
    body_frame = rb.simulate(s, model, 0.01, 100, "rk4_body", native=False, save_every=100)
    world = rb.simulate(s, lambda state, t: model(state, t), 0.01, 100, "rk4_body", native=False, save_every=100)
    free = rb.simulate(s, None, 0.01, 100, "rk4_body", native=False, save_every=100)
    assert np.min(np.linalg.norm(np.asarray(world.angular_momentum - free.angular_momentum)[-1], axis=-1)) > 1e-2
    for name in ("position", "velocity", "orientation", "angular_momentum"):
        np.testing.assert_allclose(getattr(body_frame, name), getattr(world, name), rtol=0, atol=1e-12, err_msg=name)


@pytest.mark.parametrize("drag", [rb.LinearDrag(0.1, 0.3), rb.QuadraticDrag(0.1, 0.3)], ids=["linear", "quadratic"])
def test_drag_in_the_body_frame_is_the_world_torque_turned_back(drag):
    # τ(R ω_b) = R τ(ω_b): the drag's own body-frame form against the world law's torque turned
    # back by R(q)ᵀ in NumPy (float64, a few ulps of O(1) values)
    s, _ = _bodies_and_loads()
    one = jax.tree.map(lambda a: a[2], s)
    w_b = rb.body_angular_velocity(one)
    mine = drag.on_body_in_body_frame(one, w_b, 0.0)
    world = drag.on_body(one, 0.0)
    R = np.asarray(rb.quat_to_matrix(one.orientation))
    np.testing.assert_allclose(mine.torque, R.T @ np.asarray(world.torque), rtol=0, atol=1e-14)
    np.testing.assert_allclose(mine.force, world.force, rtol=0, atol=1e-14)


@pytest.mark.parametrize("native", [False, None], ids=["jax", "default"])
def test_drag_without_a_torque_slows_the_centre_and_leaves_the_rotation(native):
    # LinearDrag(b) and QuadraticDrag(c) without `angular` have no torque. m v' = -(b + c|v|) v keeps
    # v's direction; its speed s obeys s' = -(b s + c s²)/m, whose solution is
    # s(t) = b s0 / ((b + c s0) e^{bt/m} - c s0). RK4 at h = 0.01 over 1 s on rates b/m, c s0/m <= 0.3:
    # global error ~(0.3 h)^4 ≈ 1e-10 relative; tolerance 1e-9. The rotation is the torque-free run's
    # to float64 round-off (1e-12).
    s, _ = _bodies_and_loads()
    b, c = 0.1, 0.05
    model = rb.LinearDrag(b) + rb.QuadraticDrag(c)
    dragged = rb.simulate(s, model, 0.01, 100, "rk4_body", native=native, save_every=100)
    free = rb.simulate(s, None, 0.01, 100, "rk4_body", native=native, save_every=100)
    m, v0 = np.asarray(s.body.mass), np.asarray(s.velocity)
    s0 = np.linalg.norm(v0, axis=-1)
    speed = b * s0 / ((b + c * s0) * np.exp(b * 1.0 / m) - c * s0)
    np.testing.assert_allclose(dragged.velocity[-1], v0 * (speed / s0)[:, None], rtol=1e-9)
    for name in ("orientation", "angular_momentum"):
        np.testing.assert_allclose(getattr(dragged, name), getattr(free, name), rtol=0, atol=1e-12, err_msg=name)
