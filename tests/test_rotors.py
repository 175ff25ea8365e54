"""Gyrostats (bodies with rotors): every method against an independent DOP853 reference, conservation,
the motors' work, a closed form, orders, float32, and the refusals.

The reference is written here in plain NumPy in the body-frame form
``I ω̇ = -ω × (I ω + h) - ḣ``, ``ḣ_k = τ_k``, ``q̇ = ½ q ⊗ (0, ω)`` (rbjax steps the world-frame
``L``-form with ``ω = I⁻¹ (Rᵀ L - h)``), so agreement checks the physics, not one implementation
against itself.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import rbjax as rb
from tests.reference import qmul

INERTIA = np.array([[0.30, 0.02, -0.01], [0.02, 0.45, 0.03], [-0.01, 0.03, 0.62]])
AXES = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]])
J = np.array([2e-3, 1e-3])
W0 = np.array([0.4, 2.5, -0.3])
RATES0 = np.array([150.0, -80.0])
Q0 = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
T_END = 1.0

SUPPORTED = ("euler", "semi_implicit_euler", "rk4", "rk8", "splitting", "splitting4", "splitting6", "splitting8")


def rotor_torque(t):
    """The motor schedule of the driven cases (N m, (k,)): smooth, so every order shows."""
    return np.array([0.02 * np.cos(3.0 * t), -0.01 + 0.005 * t])


def torque_fn(state, t):
    tau = jnp.stack([0.02 * jnp.cos(3.0 * t), -0.01 + 0.005 * t])
    return rb.Forces(rotor_torque=jnp.broadcast_to(tau.astype(state.dtype), state.batch_shape + (2,)))


def reference(times, driven=True, inertia=INERTIA, axes=AXES, J=J, w0=W0, rates0=RATES0):
    """Body-frame gyrostat equations by DOP853 (rtol = atol = 1e-13): q (T, 4), ω_b (T, 3), h (T, k)."""
    I_inv = np.linalg.inv(inertia)

    def rhs(t, y):
        q, w, h = y[:4], y[4:7], y[7:]
        tau = rotor_torque(t) if driven else np.zeros_like(h)
        hb = h @ axes
        w_dot = I_inv @ (-np.cross(w, inertia @ w + hb) - tau @ axes)
        q_dot = 0.5 * qmul(q, np.concatenate([[0.0], w]))
        return np.concatenate([q_dot, w_dot, tau])

    y0 = np.concatenate([Q0, w0, J * rates0])
    sol = solve_ivp(rhs, (0, times[-1]), y0, method="DOP853", t_eval=times, rtol=1e-13, atol=1e-13)
    return sol.y[:4].T, sol.y[4:7].T, sol.y[7:].T


def gyrostat(cls=rb.State, dtype=np.float64, inertia=INERTIA, axes=AXES, J=J, w0=W0, rates0=RATES0):
    R0 = np.asarray(rb.rotation_matrix(rb.State.create(rb.Body(1.0, np.eye(3)), orientation=Q0)))
    body = rb.Body(np.asarray(2.0, dtype), np.asarray(inertia, dtype))
    return cls.create(
        body,
        orientation=Q0.astype(dtype),
        angular_velocity=(R0 @ w0).astype(dtype),
        rotors=rb.Rotors(np.asarray(axes, dtype), np.asarray(J, dtype)),
        rotor_rates=np.asarray(rates0, dtype),
    )


def error(traj, ref):
    """Largest error in the body rate (rad/s) and the rotor momenta (scaled by |ω| J) over the frames."""
    q_ref, w_ref, h_ref = ref
    w_b = np.asarray(rb.body_angular_velocity(traj))
    h = np.asarray(traj.rotor_momentum)
    return max(np.max(np.abs(w_b - w_ref)), np.max(np.abs(h - h_ref)) / np.max(J))


# Tolerances: each method at its step against the reference over 1 s of a tumble (|ω| ≈ 2.6 rad/s,
# rotors at 150 and 80 rad/s) with a time-varying rotor torque. The error is the largest of the body
# rate's (rad/s) and the rotor rates' (h_k / J, rad/s). Measured 2026-12-07 (float64), in the order
# (State, MatrixState): euler and semi_implicit_euler 9.9e-3 (the rotor rates' O(dt) quadrature of
# τ(t)), rk4 2.1e-9 / 4.6e-8, rk8 2.2e-13, splitting 6.2e-5, splitting4 1.9e-8, splitting6 1.9e-11,
# splitting8 3.9e-13. Tolerances about 3x those, and 1e-11 where the error is round-off; a lost rotor
# term is an O(1) change.
CASES = {
    "euler": (1e-3, 3e-2),
    "semi_implicit_euler": (1e-3, 3e-2),
    "rk4": (0.01, 1.5e-7),
    "rk8": (0.05, 1e-11),
    "splitting": (0.005, 2e-4),
    "splitting4": (0.02, 6e-8),
    "splitting6": (0.05, 6e-11),
    "splitting8": (0.05, 1e-11),
}


@pytest.mark.parametrize("cls", [rb.State, rb.MatrixState])
@pytest.mark.parametrize("method", SUPPORTED)
def test_matches_reference(method, cls):
    dt, tol = CASES[method]
    steps = round(T_END / dt)
    every = max(1, steps // 10)
    traj = rb.simulate(gyrostat(cls), torque_fn, dt, steps, method, save_every=every)
    ref = reference(np.asarray(traj.time))
    assert error(traj, ref) < tol


@pytest.mark.parametrize(("method", "order"), [("euler", 1), ("splitting", 2), ("splitting4", 4), ("rk4", 4)])
def test_convergence_order(method, order):
    """Error at T = 1 s drops by 2^order per halving of dt (measured ratio within 25% of it)."""
    ref = reference(np.array([0.0, T_END]))
    errs = []
    for dt in (0.02, 0.01, 0.005):
        traj = rb.simulate(gyrostat(), torque_fn, dt, round(T_END / dt), method, save_every=round(T_END / dt))
        errs.append(_final_error(traj, ref))
    ratios = [errs[i] / errs[i + 1] for i in range(2)]
    for r in ratios:
        assert 0.75 * 2**order < r < 1.3 * 2**order, (errs, ratios)


def _final_error(traj, ref):
    q_ref, w_ref, h_ref = ref
    w_b = np.asarray(rb.body_angular_velocity(traj))[-1]
    h = np.asarray(traj.rotor_momentum)[-1]
    return max(np.max(np.abs(w_b - w_ref[-1])), np.max(np.abs(h - h_ref[-1])) / np.max(J))


@pytest.mark.parametrize("method", SUPPORTED)
def test_world_momentum_exact(method):
    """Rotor torques are internal: the total world L of a State is untouched, bitwise, by every method."""
    s = gyrostat()
    traj = rb.simulate(s, torque_fn, 0.01, 50, method)
    L = np.asarray(traj.angular_momentum)
    assert np.array_equal(L, np.broadcast_to(L[0], L.shape))
    # and the rotors did take the torque: their momenta moved
    assert np.max(np.abs(traj.rotor_momentum[-1] - traj.rotor_momentum[0])) > 1e-3


@pytest.mark.parametrize("method", ["splitting", "splitting4", "semi_implicit_euler", "rk8"])
def test_world_momentum_matrix_state(method):
    """In the (x, v, R, ω) form the total L = R (I ω_b + h) is kept to round-off (a few ulp of |L| per
    step over 50 steps: 1e-13 relative)."""
    traj = rb.simulate(gyrostat(rb.MatrixState), torque_fn, 0.01, 50, method)
    L = np.asarray(rb.angular_momentum(traj))
    assert np.max(np.abs(L - L[0])) < 1e-13 * np.linalg.norm(L[0])


def test_energy_change_is_motor_work():
    """T(t) - T(0) = ∫ Σ_k Ω_k (τ_k + J_k a_k · ω̇_b) dt, the motors' work (τ_k = ḣ_k, see rbjax._rotors).

    rk8 at dt = 1e-3 (its error ~1e-13 here); the integral by Simpson's rule over the 1001 frames,
    with ω̇_b from rb.derivative: quadrature error ~1e-11 of the work (0.2 J). Tolerance 1e-8 J.
    """
    dt, steps = 1e-3, 1000
    traj = rb.simulate(gyrostat(rb.MatrixState), torque_fn, dt, steps, "rk8")
    t = np.asarray(traj.time)
    rates = np.asarray(traj.rotor_momentum) / J
    tau = np.stack([rotor_torque(x) for x in t])
    rate = rb.derivative(traj, jax.vmap(torque_fn)(traj, traj.time))
    w_dot_b = np.einsum("tji,tj->ti", np.asarray(traj.rotation), np.asarray(rate.angular_velocity))
    power = np.sum(rates * (tau + J * (w_dot_b @ AXES.T)), axis=-1)
    work = (dt / 3) * (power[0] + power[-1] + 4 * power[1:-1:2].sum() + 2 * power[2:-1:2].sum())
    E = np.asarray(rb.kinetic_energy(traj))
    assert abs(work) > 0.1  # the motors do work: the check is not 0 = 0
    assert abs((E[-1] - E[0]) - work) < 1e-8


def test_axisymmetric_closed_form():
    """Axisymmetric gyrostat, rotor on the symmetry axis, no rotor torque: ω_3 constant and the
    transverse rate turns at λ = ((I3 - I1) ω3 + h) / I1 in the body frame.

    The splitting's parts commute here, so its drift is the exact flow: agreement to round-off
    (1e-12 rad/s over 200 steps of dt·|ω| ≈ 0.2) at a step where the method's own error would be 1e-3.
    """
    I1, I3, h = 0.4, 0.7, 0.3
    inertia, axes, Jz = np.diag([I1, I1, I3]), np.array([[0.0, 0.0, 1.0]]), np.array([1e-3])
    w0 = np.array([0.8, -0.3, 1.5])
    s = gyrostat(inertia=inertia, axes=axes, J=Jz, w0=w0, rates0=np.array([h]) / Jz)
    dt, steps = 0.1, 200
    traj = rb.simulate(s, None, dt, steps, "splitting")
    t = np.asarray(traj.time)
    lam = ((I3 - I1) * w0[2] + h) / I1
    z = (w0[0] + 1j * w0[1]) * np.exp(1j * lam * t)
    want = np.stack([z.real, z.imag, np.full_like(t, w0[2])], axis=-1)
    assert np.max(np.abs(np.asarray(rb.body_angular_velocity(traj)) - want)) < 1e-12


@pytest.mark.parametrize("method", ["splitting", "rk4", "semi_implicit_euler"])
def test_float32(method):
    """float32 stays float32 and agrees with float64 to float32 round-off over 100 steps (5e-5 rad/s
    of |ω| ≈ 2.6: ~100 ε₃₂ accumulated)."""
    s32 = gyrostat(dtype=np.float32)
    assert s32.dtype == jnp.float32 and s32.rotors.dtype == jnp.float32
    traj32 = rb.simulate(s32, torque_fn, 0.01, 100, method, save_every=100)
    traj64 = rb.simulate(gyrostat(), torque_fn, 0.01, 100, method, save_every=100)
    assert traj32.rotor_momentum.dtype == jnp.float32
    w32, w64 = rb.body_angular_velocity(traj32), rb.body_angular_velocity(traj64)
    assert np.max(np.abs(np.asarray(w32, np.float64) - np.asarray(w64))) < 5e-5


def test_zero_rotor_momentum_is_the_plain_body():
    """Rotors at rest relative to the body, no rotor torque: the plain rigid body's motion (round-off)."""
    s = gyrostat(rates0=np.zeros(2))
    plain = rb.State.create(s.body, orientation=s.orientation, angular_velocity=rb.angular_velocity(s))
    for method in ("splitting", "rk4"):
        a = rb.simulate(s, None, 0.01, 50, method)
        b = rb.simulate(plain, None, 0.01, 50, method)
        assert np.max(np.abs(np.asarray(a.orientation) - np.asarray(b.orientation))) < 1e-14


def test_rotor_free_adds_no_leaves():
    """A rotor-free state has the leaves it had before rotors existed (body 2, x, v, q, L, t)."""
    s = rb.State.create(rb.box(1.0, [0.1, 0.2, 0.3]))
    assert s.rotors is None and s.rotor_momentum is None
    assert len(jax.tree.leaves(s)) == 7
    assert len(jax.tree.leaves(rb.to_matrix_state(s))) == 7
    assert len(jax.tree.leaves(rb.Forces(torque=[0.0, 0, 1]))) == 1


def test_batch_with_per_body_and_shared_rotors():
    """A batch of two gyrostats: per-body rotors (2, k, 3) and the same rotors shared (k, 3) agree,
    and each body matches its own single-body run."""
    bodies = rb.Body([2.0, 2.0], np.stack([INERTIA, INERTIA]))
    rates = np.stack([RATES0, -RATES0])
    shared = rb.State.create(bodies, angular_velocity=W0, rotors=rb.Rotors(AXES, J), rotor_rates=rates)
    own = rb.State.create(
        bodies, angular_velocity=W0, rotors=rb.Rotors(np.stack([AXES, AXES]), np.stack([J, J])), rotor_rates=rates
    )
    a = rb.simulate(shared, torque_fn, 0.01, 20, "splitting")
    b = rb.simulate(own, torque_fn, 0.01, 20, "splitting")
    np.testing.assert_allclose(a.orientation, b.orientation, rtol=0, atol=1e-15)
    one = rb.State.create(rb.Body(2.0, INERTIA), angular_velocity=W0, rotors=rb.Rotors(AXES, J), rotor_rates=-RATES0)
    c = rb.simulate(one, torque_fn, 0.01, 20, "splitting")
    np.testing.assert_allclose(a.orientation[:, 1], c.orientation, rtol=0, atol=1e-15)


def test_rate_schedule_sampled_is_exact():
    """rb.rotor_rates with rates sampled at the step times: h = J Ω_n at every step (round-off)."""
    dt, steps = 0.01, 60
    t = dt * np.arange(steps + 1)
    rates = np.stack([150 + 400 * t**2, -80 + 30 * np.sin(5 * t)], axis=-1)
    s = gyrostat(rates0=rates[0])
    forces = rb.rotor_rates(s.rotors, rates, dt)
    for method in ("splitting", "rk4", "euler"):
        traj = rb.simulate(s, forces, dt, steps, method)
        np.testing.assert_allclose(traj.rotor_momentum, J * rates, rtol=1e-13, atol=0)


def test_rate_schedule_callable():
    """rb.rotor_rates with a callable: the momenta follow J Ω(t) to the method's order (rk4 at
    dt = 0.01 integrates the smooth τ = J Ω̇ to 6.5e-11 kg m²/s, measured; tolerance 2e-10)."""
    s = gyrostat()

    def rates(t):
        return jnp.stack([150.0 + 400 * t**2, -80.0 + 30 * jnp.sin(5 * t)])

    traj = rb.simulate(s, rb.rotor_rates(s.rotors, rates), 0.01, 60, "rk4")
    want = J * np.stack([np.asarray(rates(t)) for t in np.asarray(traj.time)])
    np.testing.assert_allclose(traj.rotor_momentum, want, rtol=0, atol=2e-10)


@pytest.mark.parametrize("method", sorted(set(rb.methods()) - set(SUPPORTED)))
def test_other_methods_refuse_in_words(method):
    with pytest.raises(ValueError, match=rf"method '{method}' does not support rotors.*'splitting'"):
        rb.simulate(gyrostat(), None, 0.01, 2, method)
    with pytest.raises(ValueError, match="does not support rotors"):
        rb.step(gyrostat(), None, 0.01, method)


def test_shoot_refuses_and_runs():
    starts = rb.State.create(
        rb.Body(2.0, INERTIA), angular_velocity=np.stack([W0, -W0]), rotors=rb.Rotors(AXES, J), rotor_rates=RATES0
    )
    with pytest.raises(ValueError, match="shoot: method 'rk4_body' does not support rotors"):
        rb.shoot(starts, None, 0.01, 3, "rk4_body")
    traj, ends = rb.shoot(starts, None, 0.01, 3, "splitting")
    np.testing.assert_array_equal(ends.angular_momentum, starts.angular_momentum)


def test_scene_kernels_refuse():
    """A Scene specialised on an axisymmetric body would step with kernels that know no rotors."""
    s = gyrostat(inertia=np.diag([0.4, 0.4, 0.7]))
    scene = rb.Scene.build(s, None, "splitting")
    with pytest.raises(ValueError, match="kind='general'"):
        scene.simulate(s, 0.01, 2)
    with pytest.raises(ValueError, match="method 'rk4' does not support rotors"):  # rk4's kernels cover every kind
        rb.Scene.build(s, None, "rk4", kind="general").simulate(s, 0.01, 2)
    general = rb.Scene.build(s, None, "splitting", kind="general")
    a = general.simulate(s, 0.01, 5)
    b = rb.simulate(s, None, 0.01, 5, "splitting")
    np.testing.assert_allclose(a.orientation, b.orientation, rtol=0, atol=1e-15)


def test_native_routes_to_jax():
    s = gyrostat()
    with pytest.raises(ValueError, match="gyrostat"):
        rb.simulate(s, None, 0.01, 2, "splitting", native=True)
    a = rb.simulate(s, None, 0.01, 5, "euler")
    b = rb.simulate(s, None, 0.01, 5, "euler", native=False)
    assert np.array_equal(np.asarray(a.orientation), np.asarray(b.orientation))


def test_torque_free_refuses_gyrostats():
    with pytest.raises(ValueError, match="torque_free: .* gyrostat"):
        rb.torque_free(gyrostat(), 1.0)


def test_rotor_torque_without_rotors_refused():
    plain = rb.State.create(rb.box(1.0, [0.1, 0.2, 0.3]), angular_velocity=[1.0, 2, 3])
    with pytest.raises(ValueError, match="state has no rotors"):
        rb.simulate(plain, rb.Forces(rotor_torque=[0.1]), 0.01, 2)
    with pytest.raises(ValueError, match="state has no rotors"):
        rb.simulate(plain, lambda s, t: rb.Forces(rotor_torque=jnp.ones(1)), 0.01, 2, "rk4")
    with pytest.raises(ValueError, match="state has no rotors"):
        rb.step(plain, rb.Forces(rotor_torque=[0.1]), 0.01)
    with pytest.raises(ValueError, match="state has no rotors"):
        rb.derivative(plain, rb.Forces(rotor_torque=[0.1]))
    with pytest.raises(ValueError, match=r"rotor_torque has shape \(3,\)"):
        rb.simulate(gyrostat(), rb.Forces(rotor_torque=[0.1, 0.2, 0.3]), 0.01, 2)


@pytest.mark.parametrize(
    ("axes", "inertia", "error", "match"),
    [
        ([0.0, 0.0, 1.0], [1e-3], ValueError, r"shape \(k, 3\)"),
        ([[0.0, 0.0, 2.0]], [1e-3], ValueError, "unit vectors"),
        ([[0.0, 0.0, 0.0]], [1e-3], ValueError, "unit vectors"),
        ([[0.0, 0.0, 1.0]], [0.0], ValueError, "> 0"),
        ([[0.0, 0.0, 1.0]], [np.nan], ValueError, "finite"),
        ([[0.0, 0.0, 1.0]], [1e-3, 1e-3], ValueError, "k = 1"),
        ([[0.0, 0.0, 1.0]], "a", TypeError, "inertia"),
    ],
)
def test_rotors_validation(axes, inertia, error, match):
    with pytest.raises(error, match=match):
        rb.Rotors(axes, inertia)


def test_rotors_normalise_near_unit_axes():
    r = rb.Rotors([[0.0, 0.0, 1.0004]], [1e-3])
    np.testing.assert_allclose(np.linalg.norm(r.axes, axis=-1), 1.0, rtol=1e-15)


def test_state_validation():
    body, rotors = rb.Body(1.0, INERTIA), rb.Rotors(AXES, J)
    with pytest.raises(ValueError, match="rotor_rates were given without rotors"):
        rb.State.create(body, rotor_rates=[1.0, 2.0])
    with pytest.raises(ValueError, match=r"end in \(k,\) = \(2,\)"):
        rb.State.create(body, rotors=rotors, rotor_rates=[1.0, 2.0, 3.0])
    with pytest.raises(TypeError, match="rotors must be an rbjax.Rotors"):
        rb.State.create(body, rotors=AXES)
    s = rb.State.create(body, rotors=rotors)
    with pytest.raises(ValueError, match="without rotor_momentum"):
        rb.State(body, s.position, s.velocity, s.orientation, s.angular_momentum, rotors=rotors)
    with pytest.raises(ValueError, match="without rotors"):
        rb.State(body, s.position, s.velocity, s.orientation, s.angular_momentum, rotor_momentum=[1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        rb.State(
            body, s.position, s.velocity, s.orientation, s.angular_momentum, rotors=rotors, rotor_momentum=[np.nan, 1]
        )


def test_quantities_include_rotors():
    """L is the total R (I ω_b + h); T = ½ ω_bᵀ I ω_b + ω_b·h + ½ Σ h_k²/J_k; the two forms agree."""
    s = gyrostat()
    m = rb.to_matrix_state(s)
    R = np.asarray(rb.rotation_matrix(s))
    w_b = R.T @ np.asarray(rb.angular_velocity(s))
    np.testing.assert_allclose(w_b, W0, rtol=1e-14, atol=1e-14)
    h = J * RATES0
    hb = h @ AXES
    np.testing.assert_allclose(rb.angular_momentum(m), R @ (INERTIA @ W0 + hb), rtol=1e-14)
    np.testing.assert_allclose(s.angular_momentum, R @ (INERTIA @ W0 + hb), rtol=1e-14)
    T = 0.5 * W0 @ INERTIA @ W0 + W0 @ hb + 0.5 * np.sum(h**2 / J)
    np.testing.assert_allclose(rb.kinetic_energy(s), T, rtol=1e-14)
    np.testing.assert_allclose(rb.kinetic_energy(m), T, rtol=1e-14)
    back = rb.to_state(m)
    np.testing.assert_allclose(back.angular_momentum, s.angular_momentum, rtol=1e-14)
    assert back.rotors is s.rotors or np.array_equal(back.rotor_momentum, s.rotor_momentum)


@pytest.mark.parametrize("method", ["rk4", "splitting"])
def test_gradients_match_finite_differences(method):
    """d/d(J, rotor torque schedule) of the final body rate through simulate, against central finite
    differences along a random direction (step 1e-6: truncation ~1e-12, round-off ~1e-10; tolerance
    1e-7 relative)."""
    steps, dt = 30, 0.01
    c = jnp.array([0.3, -1.0, 0.5])

    def final(J_, tau):
        s = rb.State.create(
            rb.Body(2.0, INERTIA), orientation=Q0, angular_velocity=W0, rotors=rb.Rotors(AXES, J_), rotor_rates=RATES0
        )
        traj = rb.simulate(s, rb.Forces(rotor_torque=tau), dt, steps, method, save_every=steps)
        return jnp.dot(rb.body_angular_velocity(traj)[-1], c)

    tau0 = jnp.asarray(np.stack([rotor_torque(k * dt) for k in range(steps)]))
    J0 = jnp.asarray(J)
    gJ, gtau = jax.grad(final, argnums=(0, 1))(J0, tau0)
    rng = np.random.default_rng(0)
    dJ, dtau = rng.normal(size=J.shape) * J, rng.normal(size=tau0.shape) * 0.01
    eps = 1e-6
    fd = (final(J0 + eps * dJ, tau0 + eps * dtau) - final(J0 - eps * dJ, tau0 - eps * dtau)) / (2 * eps)
    ad = jnp.sum(gJ * dJ) + jnp.sum(gtau * dtau)
    assert abs(float(fd)) > 1e-3  # the schedule and the wheels matter
    assert abs(float(ad - fd)) < 1e-7 * abs(float(fd))


def test_checked_and_chunked_runs(tmp_path):
    """Checked mode and a chunked run give the plain run to round-off (other compiled programs: 1e-14);
    a gyrostat's state, trajectory and chunk directory load back bitwise, rotors included."""
    s = gyrostat()
    plain = rb.simulate(s, torque_fn, 0.01, 20, "splitting")
    checked = rb.simulate(s, torque_fn, 0.01, 20, "splitting", checked=True)
    np.testing.assert_allclose(checked.orientation, plain.orientation, rtol=0, atol=1e-14)
    writer = rb.ChunkWriter(tmp_path / "run")
    chunked = rb.simulate_chunked(s, torque_fn, 0.01, 20, "splitting", chunk_steps=5, progress=False, writer=writer)
    np.testing.assert_allclose(chunked.rotor_momentum, plain.rotor_momentum, rtol=0, atol=1e-14)
    np.testing.assert_allclose(chunked.orientation, plain.orientation, rtol=0, atol=1e-14)
    for obj, path in ((s, "state.npz"), (plain, "trajectory.npz")):
        rb.save(tmp_path / path, obj, dt=0.01 if obj is plain else None)
        back = rb.load(tmp_path / path)
        assert jax.tree.structure(back) == jax.tree.structure(obj)
        assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(back), jax.tree.leaves(obj), strict=True))
    from_disk = rb.load(tmp_path / "run")
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(from_disk), jax.tree.leaves(chunked), strict=True))
    # a loaded gyrostat runs on as the saved one would: the same step, bitwise
    again = rb.simulate(rb.load(tmp_path / "state.npz"), torque_fn, 0.01, 20, "splitting")
    assert np.array_equal(again.rotor_momentum, plain.rotor_momentum)


def test_a_file_edited_to_an_unphysical_rotor_is_refused(tmp_path):
    # as load checks a Body as its constructor does: a rotor of J <= 0 or a non-unit axis would run
    # and report negative energies (before: save refused gyrostats altogether)
    rb.save(tmp_path / "g.npz", gyrostat())
    with np.load(tmp_path / "g.npz") as z:
        arrays = dict(z)
    for key, value, match in (
        ("rotors.inertia", -np.asarray(J), "inertia .axial, kg m². must be > 0"),
        ("rotors.axes", 2 * np.asarray(AXES), "axes must be unit vectors"),
    ):
        edited = dict(arrays, **{key: value})
        np.savez(tmp_path / "edited.npz", **edited)
        with pytest.raises(ValueError, match=f"edited.npz: rotors: Rotors: {match}"):
            rb.load(tmp_path / "edited.npz")
