"""Force models against closed forms, conservation laws and hand-computed frames."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb
from tests.reference import qrot

# these tests run "splitting" under drag on purpose (paths held to each other, inputs refused):
# its first order there is tests/test_force_protocol.py's to check
pytestmark = pytest.mark.filterwarnings("ignore::rbjax.OrderWarning")

G = 9.81


def _particles(m, x0=None, v0=None):
    n = len(m)
    return rb.ParticleState.create(
        jnp.asarray(m),
        position=np.zeros((n, 3)) if x0 is None else x0,
        velocity=np.zeros((n, 3)) if v0 is None else v0,
    )


def test_gravity_and_linear_drag_match_analytic_velocity():
    # m v' = m g - b v: v(t) = v_T + (v0 - v_T) e^{-b t/m}, v_T = m g / b. Spheres and particles
    # share the translational law. RK4, dt = 0.01 over 2 s: global error ~ (b/m dt)^4 ≈ 1e-10;
    # 1e-9 relative leaves round-off margin. Angular drag on the sphere: ω = ω0 e^{-λt}, λ = b_r/I
    # = 3/s, faster: RK4's relative error on e^{-λt} is N (λ dt)^5 / 120 ≈ 4e-8, tolerance 1e-7.
    m, b, br, r = np.array([1.0, 2.0]), 0.7, 0.3, 0.5
    v0 = np.array([[1.0, -2.0, 3.0], [0.0, 0.5, -1.0]])
    w0 = np.array([[2.0, -1.0, 0.5], [0.0, 3.0, 1.0]])
    forces = rb.Gravity() + rb.LinearDrag(b, angular=br)
    dt, steps = 0.01, 200
    t = dt * steps
    vT = m[:, None] * np.array([0, 0, -G]) / b
    v_exact = vT + (v0 - vT) * np.exp(-b * t / m)[:, None]
    body = rb.sphere(jnp.asarray(m), r)
    I = 0.4 * m * r**2
    w_exact = w0 * np.exp(-br * t / I)[:, None]

    sphere = rb.State.create(body, velocity=v0, angular_velocity=w0)
    tr = rb.Scene.build(sphere, forces, "rk4").simulate(sphere, dt, steps, save_every=steps)
    np.testing.assert_allclose(tr.velocity[-1], v_exact, rtol=1e-9)
    np.testing.assert_allclose(rb.angular_velocity(tr)[-1], w_exact, rtol=1e-7, atol=1e-15)

    p = _particles(m, v0=v0)
    tr = rb.Scene.build(p, rb.Gravity() + rb.LinearDrag(b), "rk4").simulate(p, dt, steps, save_every=steps)
    np.testing.assert_allclose(tr.velocity[-1], v_exact, rtol=1e-9)


def test_quadratic_drag_terminal_velocity():
    # m v' = -m g - c |v| v from rest: v(t) = -v_T tanh(g t / v_T), v_T = sqrt(m g / c). RK4,
    # dt = 0.005 over 4 s (≈ 4 time constants): error ~1e-11; tolerance 1e-9 relative. At t = 4 s
    # the speed is within 0.1% of v_T (tanh(4.5)), checked separately.
    m, c = np.array([1.0, 3.0]), np.array([0.2, 0.5])
    p = _particles(m)
    forces = rb.Gravity() + rb.QuadraticDrag(jnp.asarray(c))
    dt, steps = 0.005, 800
    tr = rb.Scene.build(p, forces, "rk4").simulate(p, dt, steps, save_every=steps)
    vT = np.sqrt(m * G / c)
    vz = -vT * np.tanh(G * dt * steps / vT)
    np.testing.assert_allclose(tr.velocity[-1, :, 2], vz, rtol=1e-9)
    np.testing.assert_allclose(tr.velocity[-1, :, 2], -vT, rtol=1e-3)


def test_spring_damper_to_anchor_is_a_damped_oscillator():
    # m x'' = -k (x - a) - c x' (zero-length spring at the COM, vector dashpot):
    # x - a = e^{-γt} (x0 cos ω_d t + (v0 + γ x0)/ω_d sin ω_d t), γ = c/2m, ω_d = sqrt(k/m - γ²).
    # Body 1 has a rest length along x: x = a + l0 + (oscillator) while it stays on the x side.
    # RK4, dt = 0.01, ω = 2 rad/s over 3 s: (ω dt)^4 ≈ 2e-7 per unit, global error ~1e-9 of the
    # amplitude; tolerance 1e-8 absolute on unit amplitudes.
    m, k, c, l0 = np.array([1.0, 2.0]), np.array([4.0, 8.0]), np.array([0.4, 0.0]), np.array([0.0, 1.5])
    a = np.array([[1.0, 2.0, 3.0], [-1.0, 0.0, 0.0]])
    x0 = a + np.array([[1.0, -0.5, 0.2], [l0[1] + 0.5, 0.0, 0.0]])
    v0 = np.array([[0.0, 1.0, 0.0], [0.3, 0.0, 0.0]])
    spring = rb.Spring.to_anchor(np.arange(2), a, jnp.asarray(k), rest_length=jnp.asarray(l0), damping=jnp.asarray(c))
    p = _particles(m, x0=x0, v0=v0)
    dt, steps = 0.01, 300
    tr = rb.Scene.build(p, spring, "rk4").simulate(p, dt, steps, save_every=steps)
    t = dt * steps
    g = c / (2 * m)
    wd = np.sqrt(k / m - g**2)
    d0 = x0 - a - np.array([[0, 0, 0], [l0[1], 0, 0]])
    d = np.exp(-g * t)[:, None] * (
        d0 * np.cos(wd * t)[:, None] + (v0 + g[:, None] * d0) / wd[:, None] * np.sin(wd * t)[:, None]
    )
    np.testing.assert_allclose(tr.position[-1], a + d + np.array([[0, 0, 0], [l0[1], 0, 0]]), atol=1e-8)


def _energy_two_body(traj, spring):
    """Kinetic + spring energy ½ k (|d| - l0)² of a two-body spring trajectory."""
    ke = np.sum(np.asarray(rb.kinetic_energy(traj)), axis=-1)
    R = np.asarray(rb.rotation_matrix(traj))
    pa = R[:, 0] @ np.asarray(spring.point[0]) + np.asarray(traj.position[:, 0])
    pb = R[:, 1] @ np.asarray(spring.anchor[0]) + np.asarray(traj.position[:, 1])
    ext = np.linalg.norm(pb - pa, axis=-1) - float(spring.rest_length)
    return ke + 0.5 * float(spring.stiffness[0]) * ext**2


def test_two_body_spring_conserves_momenta_and_energy():
    # Off-COM attachment: forces equal and opposite, torques r × F about each COM. Total linear
    # momentum is a linear invariant, which RK4 preserves to round-off (1e-12 absolute on O(1)).
    # Total angular momentum (spin + x × m v) and energy are quadratic: RK4 keeps them to
    # O(dt^4 T); with dt = 2e-3 over 2 s the drift is ~1e-10, tolerance 1e-8 relative.
    # (A symplectic method would bound the energy error for all time; none is registered here.)
    body = rb.Body(
        jnp.array([1.0, 2.5]),
        jnp.stack([jnp.diag(jnp.array([0.3, 0.4, 0.5])), jnp.diag(jnp.array([1.0, 0.8, 0.6]))]),
    )
    s = rb.State.create(
        body,
        position=np.array([[0.0, 0.0, 0.0], [1.5, 0.2, -0.1]]),
        velocity=np.array([[0.1, 0.5, -0.2], [0.0, -0.3, 0.4]]),
        angular_velocity=np.array([[1.0, -0.5, 2.0], [0.3, 0.2, -1.0]]),
        orientation=np.array([[1.0, 0, 0, 0], [np.cos(0.4), np.sin(0.4), 0, 0]]),
    )
    spring = rb.Spring.between(
        [0], [1], [30.0], point_a=[[0.2, 0.1, -0.3]], point_b=[[-0.1, 0.4, 0.2]], rest_length=1.0
    )
    tr = rb.Scene.build(s, spring, "rk4").simulate(s, 2e-3, 1000, save_every=50)
    P = np.sum(np.asarray(rb.linear_momentum(tr)), axis=1)
    np.testing.assert_allclose(P, np.broadcast_to(P[0], P.shape), atol=1e-12)
    L = np.sum(np.asarray(rb.angular_momentum(tr, about=jnp.zeros(3))), axis=1)
    np.testing.assert_allclose(L, np.broadcast_to(L[0], L.shape), rtol=1e-8, atol=1e-8 * np.abs(L[0]).max())
    E = _energy_two_body(tr, spring)
    assert np.ptp(E) < 1e-8 * E[0]
    # and the spring did work: the bodies' kinetic energy changed by far more than the tolerance
    assert np.ptp(np.sum(np.asarray(rb.kinetic_energy(tr)), axis=-1)) > 1e-2


def test_thruster_force_and_torque_turn_with_the_body():
    # F = T R d, τ = (R p) × F, checked with numpy rotation matrices (tests/reference.qrot) at random
    # orientations; float64 round-off, tolerance 1e-12.
    rng = np.random.default_rng(3)
    q = rng.normal(size=(3, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    s = rb.State.create(rb.box(jnp.ones(3), jnp.ones((3, 3))), orientation=q)
    idx = np.array([2, 0, 2])
    d = rng.normal(size=(3, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    p, T = rng.normal(size=(3, 3)), np.array([1.0, 2.0, 3.0])
    thruster = jax.jit(lambda s: rb.Thruster(idx, d, T, point=p)(s, 0.0))
    out = thruster(s)
    F = np.zeros((3, 3))
    tau = np.zeros((3, 3))
    for j, i in enumerate(idx):
        f = T[j] * qrot(q[i], d[j])
        F[i] += f
        tau[i] += np.cross(qrot(q[i], p[j]), f)
    np.testing.assert_allclose(out.force, F, atol=1e-12)
    np.testing.assert_allclose(out.torque, tau, atol=1e-12)
    # the same for the matrix form
    out_m = thruster(rb.to_matrix_state(s))
    np.testing.assert_allclose(out_m.torque, tau, atol=1e-12)
    # at the centre of mass: no torque, structurally
    assert rb.Thruster(idx, d, T)(s, 0.0).torque is None


def test_constant_torque_and_force():
    # L(t) = L0 + τ t and v(t) = v0 + F/m t exactly (constant rates); Euler is exact for them.
    body = rb.box(jnp.array([2.0, 1.0]), jnp.array([[1.0, 2.0, 3.0], [1.0, 1.0, 2.0]]))
    s = rb.State.create(body, angular_velocity=np.array([[0.5, 0.2, 0.1], [0.0, 1.0, 0.0]]))
    tau, F = np.array([0.1, -0.2, 0.3]), np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    tr = rb.Scene.build(s, rb.ConstantForce(F, tau), "euler").simulate(s, 0.01, 100, save_every=100)
    np.testing.assert_allclose(tr.angular_momentum[-1], s.angular_momentum + tau, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(tr.velocity[-1], F / np.array([2.0, 1.0])[:, None], rtol=1e-12)


def test_time_series_linear_interpolation_and_hold():
    # Linear: samples of F(t) = α t (exact for a piecewise-linear interpolant); then
    # v = α t²/2m, x = α t³/6m, polynomials RK4 integrates exactly: tolerance 1e-12.
    alpha, m = np.array([1.0, -2.0, 0.5]), 2.0
    times = np.linspace(0.0, 1.0, 11)
    series = rb.TimeSeriesForce(times, force=times[:, None] * alpha)
    p = _particles([m])
    tr = rb.Scene.build(p, series, "rk4").simulate(p, 0.01, 100, save_every=100)
    np.testing.assert_allclose(tr.velocity[-1, 0], alpha / (2 * m), rtol=1e-12)
    np.testing.assert_allclose(tr.position[-1, 0], alpha / (6 * m), rtol=1e-12)
    # Hold: the last sample at or before t, end values outside the range.
    vals = np.arange(4.0)[:, None] * np.ones(3)
    hold = rb.TimeSeriesForce(np.array([0.0, 1.0, 2.0, 3.0]), force=vals, interpolation="hold")
    for t, want in [(-1.0, 0.0), (0.0, 0.0), (0.99, 0.0), (1.0, 1.0), (2.5, 2.0), (7.0, 3.0)]:
        np.testing.assert_array_equal(hold(p, jnp.asarray(t)).force[0], want * np.ones(3))
    with pytest.raises(ValueError, match="interpolation"):
        rb.TimeSeriesForce(times, force=times[:, None] * alpha, interpolation="cubic")


def test_external_force_function_of_time():
    # m x'' = A sin(Ω t), x(0) = v(0) = 0: x = A/(m Ω) (t - sin(Ω t)/Ω). RK4, Ω dt = 0.02 over
    # 2 s: error ~1e-10; tolerance 1e-9 absolute.
    A, Om, m = np.array([1.0, 0.0, -2.0]), 3.0, 1.5
    ext = rb.ExternalForce(force=lambda t: jnp.sin(Om * t) * jnp.asarray(A, t.dtype))
    p = _particles([m])
    tr = rb.Scene.build(p, ext, "rk4").simulate(p, 0.01, 200, save_every=200)
    t = 2.0
    np.testing.assert_allclose(tr.position[-1, 0], A / (m * Om) * (t - np.sin(Om * t) / Om), atol=1e-9)


def test_custom_force_is_differentiable_in_its_params():
    # x(T) = f T² / 2m for a constant force f = params: d x_z(T) / d f_z = T² / 2m exactly (RK4 is
    # exact on quadratics); gravity's g gives the same derivative per unit mass times m.
    m, T = 2.0, 1.0
    p = _particles([m])
    custom = rb.CustomForce(lambda s, t, f: rb.Forces(force=jnp.broadcast_to(f, s.position.shape)), jnp.zeros(3))

    def final_z(params):
        scene = rb.Scene.build(p, rb.CustomForce(custom.fn, params), "rk4")
        return scene.simulate(p, 0.1, 10, save_every=10).position[-1, 0, 2]

    grad = jax.grad(final_z)(jnp.zeros(3))
    np.testing.assert_allclose(grad, [0.0, 0.0, T**2 / (2 * m)], rtol=1e-12, atol=1e-15)
    dz_dg = jax.grad(
        lambda g: rb.Scene.build(p, rb.Gravity(g), "rk4").simulate(p, 0.1, 10, save_every=10).position[-1, 0, 2]
    )
    np.testing.assert_allclose(dz_dg(jnp.zeros(3)), [0.0, 0.0, T**2 / 2], rtol=1e-12, atol=1e-15)


def test_sum_is_static_and_keeps_torque_absent():
    # Forces add term by term; the torque stays absent (None) unless some term has one.
    p = _particles([1.0, 2.0], v0=np.ones((2, 3)))
    total = rb.Gravity() + rb.LinearDrag(0.5) + rb.QuadraticDrag(0.1)
    assert isinstance(total, rb.ForceSum) and len(total.terms) == 3
    out = total(p, 0.0)
    assert out.torque is None
    m = np.array([1.0, 2.0])[:, None]
    want = m * np.array([0, 0, -G]) - 0.5 * np.ones(3) - 0.1 * np.sqrt(3) * np.ones(3)
    np.testing.assert_allclose(out.force, want, rtol=1e-14)
    s = rb.State.create(rb.sphere(1.0, 1.0), angular_velocity=jnp.array([0.0, 0.0, 2.0]))
    assert (rb.Gravity() + rb.LinearDrag(0.1, angular=0.2))(s, 0.0).torque[2] == pytest.approx(-0.2 * 2.0)


def test_bad_inputs_raise_value_error():
    p = _particles([1.0])
    with pytest.raises(ValueError, match="ParticleState has no rotation"):
        rb.Scene.build(p, rb.LinearDrag(0.1, angular=0.1))
    with pytest.raises(ValueError, match="anchor"):
        rb.Spring(body_index=[0], stiffness=1.0)
    with pytest.raises(ValueError, match="integers"):
        rb.Spring.to_anchor([0.0], [[0, 0, 0]], 1.0)
    with pytest.raises(ValueError, match="1-D batch"):
        rb.Spring.to_anchor([0], [[0.0, 0, 0]], 1.0)(rb.ParticleState.create(jnp.ones((2, 2))), 0.0)
    with pytest.raises(ValueError, match="broadcast"):
        rb.Scene.build(p, rb.ConstantForce(jnp.ones((5, 3))))


# every method with per-body laws on the path simulate lifts them on (inside the step, batch-last)
# against the same model as an opaque callable, which simulate evaluates on the whole batch-first
# batch between transposes: the same formulas, so equal to round-off (measured at most 0.6 eps per
# step of each field's scale; the bound allows 8, as tests/test_native.py does for its two paths)
# (the three methods with the heaviest steps to compile run in the whole suite only)
_PER_BODY_CASES = [
    pytest.param(m, d, marks=[pytest.mark.slow] if m in ("rk4_body", "rk8", "implicit_midpoint") else [])
    for m in ["euler", "rk4", "splitting", "semi_implicit_euler", "rk4_body", "rk8", "implicit_midpoint"]
    for d in ([jnp.float32, jnp.float64] if m in ("euler", "rk4", "splitting") else [jnp.float64])
]


@pytest.mark.parametrize(("method", "dtype"), _PER_BODY_CASES)
def test_per_body_laws_inside_the_step_match_the_batch_path(method, dtype):
    rng = np.random.default_rng(4)
    n, steps = 5, 12
    state = _tumbling_boxes(rng, n, dtype)
    _assert_lifted_matches_batch_path(state, _per_body_laws(rng, n, dtype), method, steps)


def _tumbling_boxes(rng, n, dtype):
    body = rb.box(jnp.asarray(rng.uniform(0.5, 2.0, n), dtype), jnp.asarray(rng.uniform(0.1, 1.0, (n, 3)), dtype))
    return rb.State.create(
        body,
        velocity=jnp.asarray(rng.normal(size=(n, 3)), dtype),
        angular_velocity=jnp.asarray(rng.normal(size=(n, 3)) * 3, dtype),
    )


def _per_body_laws(rng, n, dtype):
    return (
        rb.Gravity()
        + rb.QuadraticDrag(jnp.asarray(rng.uniform(0.0, 0.1, n), dtype), 0.01)
        + rb.LinearDrag(0.05, jnp.asarray(rng.uniform(0.0, 0.1, n), dtype))
        + rb.ConstantForce(force=[0.1, 0.0, 0.2], torque=jnp.asarray(rng.normal(size=(n, 3)), dtype))
    )


def _assert_lifted_matches_batch_path(state, model, method, steps):
    lifted = rb.simulate(state, model, 1e-2, steps, method, save_every=4, native=False)
    batch = rb.simulate(state, lambda s, t: model(s, t), 1e-2, steps, method, save_every=4, native=False)
    eps = float(jnp.finfo(state.dtype).eps)
    for f in ("position", "velocity", "orientation", "angular_momentum"):
        a, b = np.asarray(getattr(lifted, f), np.float64), np.asarray(getattr(batch, f), np.float64)
        scale = max(1.0, float(np.max(np.abs(b))))
        np.testing.assert_allclose(a, b, rtol=0, atol=8 * steps * eps * scale, err_msg=f)


# a sum of per-body laws and a spring (which names bodies by index): the per-body terms are lifted
# inside the step and the spring goes through the batch-level path, their forces added; held to
# the whole sum as one opaque callable, to the bound above
@pytest.mark.parametrize(
    ("method", "dtype"), [("euler", jnp.float32), ("rk4", jnp.float64), ("splitting", jnp.float64)]
)
def test_a_sum_with_a_spring_keeps_its_per_body_terms_inside_the_step(method, dtype):
    rng = np.random.default_rng(6)
    n = 5
    spring = rb.Spring.between([0, 1], [2, 4], 5.0, point_a=[[0.1, 0.0, 0.0]] * 2, damping=0.2)
    _assert_lifted_matches_batch_path(
        _tumbling_boxes(rng, n, dtype), _per_body_laws(rng, n, dtype) + spring, method, 12
    )


# thrusters naming each body at most once are lifted per body inside simulate's step (no gather,
# scatter or transposes); held to the same model as an opaque callable, which keeps the scatter
# path, to the bound of the per-body test above (measured: bitwise in most cases, at most ~1 eps)
@pytest.mark.parametrize("method", ["euler", "rk4", "splitting", "rk4_body"])
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_one_thruster_per_body_is_lifted_and_matches_the_scatter_path(method, dtype):
    from rbjax._attached import _OneThrusterPerBody
    from rbjax._force_model import with_per_body_terms

    rng = np.random.default_rng(5)
    n, steps = 6, 12
    state = _tumbling_boxes(rng, n, dtype)
    d = rng.normal(size=(4, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # bodies 1 and 3 have none; the order of the thrusters is not the bodies'
    thrusters = rb.Thruster(
        [4, 0, 2, 5],
        jnp.asarray(d, dtype),
        jnp.asarray(rng.uniform(-1, 2, 4), dtype),
        jnp.asarray(rng.normal(size=(4, 3)), dtype),
    )
    model = rb.Gravity() + thrusters + rb.QuadraticDrag(0.05, 0.01)
    converted = with_per_body_terms(model, state)
    assert isinstance(converted, rb.ForceSum) and isinstance(converted.terms[1], _OneThrusterPerBody)
    # a body named twice keeps the scatter
    assert with_per_body_terms(rb.Thruster([0, 0], d[:2], 1.0), state).__class__ is rb.Thruster
    lifted = rb.simulate(state, model, 1e-2, steps, method, save_every=4, native=False)
    batch = rb.simulate(state, lambda s, t: model(s, t), 1e-2, steps, method, save_every=4, native=False)
    eps = float(jnp.finfo(dtype).eps)
    for f in ("position", "velocity", "orientation", "angular_momentum"):
        a, b = np.asarray(getattr(lifted, f), np.float64), np.asarray(getattr(batch, f), np.float64)
        scale = max(1.0, float(np.max(np.abs(b))))
        np.testing.assert_allclose(a, b, rtol=0, atol=8 * steps * eps * scale, err_msg=f)


def test_adding_a_function_or_forces_arrays_to_a_model_names_the_wrapper():
    law = lambda s, t: rb.Forces(force=jnp.ones_like(s.position))
    for make in (lambda: rb.Gravity() + law, lambda: law + rb.Gravity()):
        with pytest.raises(TypeError, match=r"cannot add a function to a force model .*rb\.CustomForce\(fn\)"):
            make()
    arrays = rb.Forces(force=jnp.ones(3))
    for make in (lambda: rb.Gravity() + arrays, lambda: arrays + rb.Gravity()):
        with pytest.raises(TypeError, match=r"cannot add Forces arrays to a force model .*rb\.ConstantForce"):
            make()
    # the wrapped forms add, and act as the sum of their parts: a unit force on a unit mass
    # under gravity g gains velocity (1 + g) dt per step
    s = rb.State.create(rb.sphere(1.0, 0.1))
    g = np.array([0.0, 0.0, -9.81])
    for total in (rb.Gravity() + rb.CustomForce(law), rb.Gravity() + rb.ConstantForce(force=jnp.ones(3))):
        v = np.asarray(rb.simulate(s, total, 0.1, 3, "semi_implicit_euler").velocity[-1])
        np.testing.assert_allclose(v, 0.3 * (1.0 + g), rtol=1e-6)
