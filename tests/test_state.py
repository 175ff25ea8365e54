"""States, derived quantities and forces against independent particle sums."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rbjax as rb

TOL = 1e-12  # float64 round-off on sums of a few dozen O(1) terms


@pytest.fixture
def particle_body():
    """A rigid body made of 8 particles, with its particles in body coordinates about the COM."""
    rng = np.random.default_rng(0)
    m = rng.uniform(0.5, 2.0, size=8)
    p = rng.normal(size=(8, 3))
    body, com = rb.from_particles(m, p)
    return body, m, np.asarray(p - com)


def _kinematics(q, w):
    R = Rotation.from_quat(np.asarray(q)[[1, 2, 3, 0]]).as_matrix()
    return R, np.asarray(w)


def test_quantities_equal_particle_sums(particle_body):
    body, m, r_body = particle_body
    rng = np.random.default_rng(1)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, v = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
    s = rb.State.create(body, position=x, velocity=v, orientation=q, angular_velocity=w)
    R, _ = _kinematics(q, w)
    r = r_body @ R.T  # particle offsets in the world frame
    vel = v + np.cross(w, r)  # rigid-body velocity field v_i = v + ω × r_i
    np.testing.assert_allclose(rb.angular_velocity(s), w, rtol=TOL)
    np.testing.assert_allclose(rb.body_angular_velocity(s), R.T @ w, rtol=TOL, atol=TOL)
    np.testing.assert_allclose(rb.linear_momentum(s), (m[:, None] * vel).sum(0), rtol=TOL)
    np.testing.assert_allclose(rb.angular_momentum(s), (m[:, None] * np.cross(r, vel)).sum(0), rtol=TOL, atol=TOL)
    np.testing.assert_allclose(rb.kinetic_energy(s), 0.5 * (m * (vel**2).sum(1)).sum(), rtol=TOL)
    # I_w = R I_L Rᵀ equals the inertia of the rotated particles
    np.testing.assert_allclose(rb.world_inertia(s), rb.from_particles(m, r)[0].inertia, rtol=1e-11, atol=TOL)
    np.testing.assert_allclose(rb.rotation_matrix(s), R, atol=TOL)
    # about a world point a: L_a = Σ (x + r_i - a) × m_i v_i
    a = np.array([1.0, 2.0, -0.5])
    La = (m[:, None] * np.cross(x + r - a, vel)).sum(0)
    np.testing.assert_allclose(rb.angular_momentum(s, about=a), La, rtol=TOL, atol=TOL)


def test_matrix_state_agrees_with_state(particle_body):
    body = particle_body[0]
    q = rb.quat_exp(jnp.array([0.3, -1.2, 2.0]))
    s = rb.State.create(body, orientation=q, angular_velocity=[0.5, -1.0, 2.0], velocity=[1.0, 0, 0])
    ms = rb.MatrixState.create(body, orientation=q, angular_velocity=[0.5, -1.0, 2.0], velocity=[1.0, 0, 0])
    for f in [
        rb.kinetic_energy,
        rb.angular_momentum,
        rb.angular_velocity,
        rb.world_inertia,
        rb.rotation_matrix,
    ]:
        np.testing.assert_allclose(f(ms), f(s), rtol=TOL, atol=TOL)
    back = rb.to_state(rb.to_matrix_state(s))
    assert float(rb.quat_angle(back.orientation, s.orientation)) < 1e-7  # arccos-free angle, round-off level
    np.testing.assert_allclose(back.angular_momentum, s.angular_momentum, rtol=TOL)
    # either state from a rotation matrix: the same state as from its quaternion
    R = _kinematics(q, [0, 0, 0])[0]  # scipy's matrix, independent of rbjax's quat_to_matrix
    from_R = rb.State.create(body, orientation=R, angular_velocity=[0.5, -1.0, 2.0], velocity=[1.0, 0, 0])
    assert float(rb.quat_angle(from_R.orientation, s.orientation)) < 1e-7
    np.testing.assert_allclose(from_R.angular_momentum, s.angular_momentum, rtol=TOL, atol=TOL)
    ms_from_R = rb.MatrixState.create(body, orientation=R, angular_velocity=[0.5, -1.0, 2.0])
    np.testing.assert_allclose(ms_from_R.rotation, ms.rotation, atol=TOL)


def test_particles_angular_momentum_is_r_cross_p():
    rng = np.random.default_rng(2)
    x, v, m = rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), rng.uniform(1, 2, 5)
    p = rb.ParticleState.create(m, position=x, velocity=v)
    np.testing.assert_allclose(rb.angular_momentum(p), np.cross(x, m[:, None] * v), rtol=TOL)
    np.testing.assert_allclose(rb.kinetic_energy(p), 0.5 * m * (v**2).sum(1), rtol=TOL)


def test_forces_at_point_and_gravity():
    s = rb.State.create(rb.box(2.0, [1, 2, 3]), position=[1.0, 0, 0])
    F, p = np.array([0.0, 3.0, 0.0]), np.array([1.0, 0.0, 2.0])
    f = rb.Forces.at_point(F, p, s)
    np.testing.assert_allclose(f.torque, np.cross(p - [1.0, 0, 0], F))
    g = rb.Forces.gravity(s)
    np.testing.assert_allclose(g.force, [0, 0, -2 * 9.81])
    assert g.torque is None  # gravity at the COM: no torque work compiled
    total = f + g
    np.testing.assert_allclose(total.force, F + [0, 0, -2 * 9.81])
    np.testing.assert_allclose(total.torque, f.torque)


def test_batched_state_with_shared_body():
    body = rb.box(1.0, [1.0, 2.0, 3.0])
    w = np.random.default_rng(3).normal(size=(6, 3))
    s = rb.State.create(body, angular_velocity=w)
    assert s.batch_shape == (6,) and body.batch_shape == ()
    for i in range(6):
        np.testing.assert_allclose(
            rb.kinetic_energy(s)[i],
            rb.kinetic_energy(rb.State.create(body, angular_velocity=w[i])),
            rtol=1e-15,
        )


def test_pytrees_work_under_jit_vmap_grad():
    body = rb.box(1.0, [1.0, 2.0, 3.0])
    f = lambda w: rb.kinetic_energy(rb.State.create(body, angular_velocity=w))
    w = jnp.array([0.1, 0.2, 0.3])
    # ∂T/∂ω = I_w ω = L
    np.testing.assert_allclose(jax.grad(f)(w), np.asarray(body.inertia) @ w, rtol=TOL)
    np.testing.assert_allclose(jax.jit(f)(w), f(w), rtol=TOL)
    np.testing.assert_allclose(jax.vmap(f)(jnp.stack([w, 2 * w])), [f(w), 4 * f(w)], rtol=TOL)
    leaves = jax.tree_util.tree_leaves(rb.State.create(body))
    assert len(leaves) == 7  # mass, inertia, inverse inertia, x, v, q, L
    # zero angular velocity at the identity: gradient finite
    assert np.all(
        np.isfinite(
            jax.grad(lambda w: rb.angular_velocity(rb.State.create(body, angular_velocity=w)).sum())(jnp.zeros(3))
        )
    )


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(orientation=[1.0, 0.1, 0, 0]), "unit quaternion"),
        (dict(position=[np.nan, 0, 0]), "finite"),
        (dict(position=[0.0, 0.0]), "shape"),
        (dict(angular_velocity=[0.0, 0.0, 1.0, 0.0]), "broadcast|shape"),
        (dict(orientation=[1.0, 0.0, 0.0]), r"orientation must end in \(4,\) .* or \(3, 3\)"),
        (dict(orientation=np.diag([1.0, 1.0, -1.0])), "orientation must be a proper rotation matrix"),
    ],
)
@pytest.mark.parametrize("cls", [rb.State, rb.MatrixState])
def test_invalid_states_raise(cls, kwargs, match):
    with pytest.raises(ValueError, match=match):
        cls.create(rb.sphere(1.0, 1.0), **kwargs)


def test_invalid_matrix_and_particles_raise():
    with pytest.raises(ValueError, match="rotation"):
        rb.MatrixState.create(rb.sphere(1.0, 1.0), orientation=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="mass"):
        rb.ParticleState.create([1.0, 0.0])
