"""Mass properties against independent computations, and validation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate
from scipy.spatial.transform import Rotation

import rbjax as rb


def _notes_inertia(masses, points):
    """The notes' written-out matrix: Σ m [[y²+z², -xy, -xz], [-xy, x²+z², -yz], [-xz, -yz, x²+y²]]."""
    I = np.zeros((3, 3))
    for m, (x, y, z) in zip(masses, points):
        I += m * np.array(
            [
                [y * y + z * z, -x * y, -x * z],
                [-x * y, x * x + z * z, -y * z],
                [-x * z, -y * z, x * x + y * y],
            ]
        )
    return I


def test_from_particles_matches_the_notes_formula():
    rng = np.random.default_rng(0)
    m = rng.uniform(0.5, 2.0, size=7)
    p = rng.normal(size=(7, 3))
    body, com = rb.from_particles(m, p)
    c = (m[:, None] * p).sum(0) / m.sum()
    np.testing.assert_allclose(com, c, atol=1e-14)
    np.testing.assert_allclose(body.mass, m.sum(), rtol=1e-15)
    np.testing.assert_allclose(body.inertia, _notes_inertia(m, p - c), rtol=1e-13)
    # L = Σ r_i × m_i (ω × r_i) = I ω: the derivation the notes start from
    w = rng.normal(size=3)
    r = p - c
    L = sum(mi * np.cross(ri, np.cross(w, ri)) for mi, ri in zip(m, r))
    np.testing.assert_allclose(body.inertia @ w, L, rtol=1e-13)
    # translating every point leaves the inertia about the centre of mass unchanged
    body2, _ = rb.from_particles(m, p + np.array([3.0, -1.0, 2.0]))
    np.testing.assert_allclose(body2.inertia, body.inertia, rtol=1e-12, atol=1e-12)


def _ellipsoid_integral(a, b, c):
    """∫ x², y², z² over the solid ellipsoid, by nested quadrature (tolerance 1e-11)."""

    def second_moments():
        out = []
        for k in range(3):
            f = lambda z, y, x, k=k: (x, y, z)[k] ** 2
            val, _ = integrate.tplquad(
                f,
                -a,
                a,
                lambda x: -b * np.sqrt(max(0.0, 1 - (x / a) ** 2)),
                lambda x: b * np.sqrt(max(0.0, 1 - (x / a) ** 2)),
                lambda x, y: -c * np.sqrt(max(0.0, 1 - (x / a) ** 2 - (y / b) ** 2)),
                lambda x, y: c * np.sqrt(max(0.0, 1 - (x / a) ** 2 - (y / b) ** 2)),
                epsabs=1e-11,
                epsrel=1e-11,
            )
            out.append(val)
        return np.array(out)

    return second_moments(), 4 / 3 * np.pi * a * b * c


def test_ellipsoid_and_sphere_against_quadrature():
    a, b, c, m = 0.7, 1.1, 1.6, 3.0
    mom, vol = _ellipsoid_integral(a, b, c)
    mom *= m / vol
    ref = np.diag([mom[1] + mom[2], mom[0] + mom[2], mom[0] + mom[1]])
    # quadrature accurate to ~1e-9 relative (the square-root edges limit it)
    np.testing.assert_allclose(rb.ellipsoid(m, [a, b, c]).inertia, ref, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(rb.sphere(m, 1.3).inertia, rb.ellipsoid(m, [1.3, 1.3, 1.3]).inertia, rtol=1e-15)


def test_box_and_cylinder_against_quadrature():
    m, (a, b, c) = 2.0, (0.5, 1.5, 2.5)
    vol = a * b * c
    sq = [integrate.quad(lambda x: x * x, -s / 2, s / 2)[0] * vol / s for s in (a, b, c)]
    mom = m / vol * np.array(sq)
    np.testing.assert_allclose(
        rb.box(m, [a, b, c]).inertia, np.diag([mom[1] + mom[2], mom[0] + mom[2], mom[0] + mom[1]]), rtol=1e-13
    )
    r, l = 0.4, 1.7
    vol = np.pi * r * r * l
    # ∫ x² dV over the cylinder = l ∫∫ x² dA (polar); ∫ z² dV = π r² l³/12
    x2 = l * integrate.dblquad(lambda rho, th: (rho * np.cos(th)) ** 2 * rho, 0, 2 * np.pi, 0, r)[0]
    z2 = np.pi * r * r * integrate.quad(lambda z: z * z, -l / 2, l / 2)[0]
    ref = m / vol * np.diag([x2 + z2, x2 + z2, 2 * x2])
    np.testing.assert_allclose(rb.cylinder(m, r, l).inertia, ref, rtol=1e-12)


def test_parallel_axis_and_rotation_against_particles():
    rng = np.random.default_rng(1)
    m = rng.uniform(0.5, 2.0, size=9)
    p = rng.normal(size=(9, 3))
    body, com = rb.from_particles(m, p)
    point = np.array([0.3, -2.0, 1.0])
    # inertia about `point` computed directly from the particles
    direct = _notes_inertia(m, p - point)
    np.testing.assert_allclose(rb.parallel_axis(body.inertia, body.mass, com - point), direct, rtol=1e-12)
    R = Rotation.random(random_state=2).as_matrix()
    rotated, _ = rb.from_particles(m, p @ R.T)
    np.testing.assert_allclose(rb.rotate_inertia(body.inertia, R), rotated.inertia, rtol=1e-12, atol=1e-12)


def test_principal_axes_diagonalise():
    R = Rotation.random(random_state=3).as_matrix()
    I = R @ np.diag([1.0, 2.0, 2.5]) @ R.T
    moments, axes = rb.Body(1.0, I).principal()
    np.testing.assert_allclose(moments, [1.0, 2.0, 2.5], rtol=1e-13)
    np.testing.assert_allclose(axes @ np.diag(moments) @ axes.T, I, atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(axes), 1.0, atol=1e-13)


def test_inverse_inertia_is_cached_and_correct():
    R = Rotation.random(random_state=4).as_matrix()
    # a thin rod: moments ≈ (1.7e-7, 0.083, 0.083), condition number 5e5
    I = R @ rb.box(1.0, [1e-3, 1e-3, 1.0]).inertia @ R.T
    b = rb.Body(1.0, I)
    # adjugate inverse: error ~ cond · eps ≈ 1e-10
    np.testing.assert_allclose(np.asarray(b.inverse_inertia) @ I, np.eye(3), atol=1e-9)


@pytest.mark.parametrize("shape", [(4,), (2, 3)])
def test_batched_constructors_equal_per_body(shape):
    rng = np.random.default_rng(5)
    m = rng.uniform(1, 2, size=shape)
    size = rng.uniform(0.1, 2, size=shape + (3,))
    b = rb.box(m, size)
    assert b.batch_shape == shape
    for idx in np.ndindex(shape):
        np.testing.assert_allclose(b.inertia[idx], rb.box(m[idx], size[idx]).inertia, rtol=1e-15)


def test_constructors_trace_under_jit_and_grad():
    # d Izz / d size_x of a box is m a / 6
    g = jax.grad(lambda s: rb.box(2.0, s).inertia[2, 2])(jnp.array([0.5, 1.0, 1.5]))
    np.testing.assert_allclose(g, [2.0 * 0.5 / 6, 2.0 * 1.0 / 6, 0.0], rtol=1e-14)
    out = jax.jit(lambda m: rb.sphere(m, 1.0).inverse_inertia)(3.0)
    np.testing.assert_allclose(out, np.eye(3) / 1.2, rtol=1e-14)


BAD_BODIES = {
    "mass must be > 0": (0.0, np.eye(3)),
    "mass must be > 0 ": (-1.0, np.eye(3)),
    "mass must be finite": (np.nan, np.eye(3)),
    "inertia must be finite": (1.0, np.diag([1.0, np.inf, 1.0])),
    "symmetric": (1.0, np.array([[1.0, 0.1, 0], [0, 1, 0], [0, 0, 1]])),
    "positive definite": (1.0, np.diag([1.0, 1.0, -0.5])),
    "positive definite ": (1.0, np.diag([0.0, 1.0, 1.0])),
    "triangle inequality": (1.0, np.diag([1.0, 1.0, 2.5])),
    "shape": (np.ones(3), np.eye(3)),
}


@pytest.mark.parametrize("rule", list(BAD_BODIES))
def test_invalid_bodies_raise(rule):
    mass, inertia = BAD_BODIES[rule]
    with pytest.raises(ValueError, match=rule.strip()):
        rb.Body(mass, inertia)


def test_a_bad_body_in_a_batch_is_named_by_plain_integers():
    # a tuple of NumPy integers prints as (np.int64(1),): the message says (1,), as one types it
    inertia = np.stack([np.eye(3), np.array([[1.0, 0.1, 0], [0, 1, 0], [0, 0, 1]])])
    with pytest.raises(ValueError, match=r"must be symmetric; \|I - Iᵀ\| = 0.1 at batch index \(1,\)$"):
        rb.Body(np.ones(2), inertia)


def test_triangle_inequality_tolerance():
    # a flat plate meets I1 + I2 = I3 exactly: valid, even with round-off
    rb.Body(1.0, np.diag([1.0, 2.0, 3.0 * (1 + 0.5 * rb.TRIANGLE_RTOL)]))
    with pytest.raises(ValueError, match="triangle"):
        rb.Body(1.0, np.diag([1.0, 2.0, 3.0 * (1 + 10 * rb.TRIANGLE_RTOL)]))
    # a thin rod (a box of size 1e-3 x 1e-3 x 1) is near the limit and valid
    rb.box(1.0, [1e-3, 1e-3, 1.0])


def test_collinear_particles_raise():
    with pytest.raises(ValueError, match="positive definite"):
        rb.from_particles([1.0, 1.0, 1.0], [[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0]])
    with pytest.raises(ValueError, match="mass"):
        rb.from_particles([1.0, -1.0], [[0, 0, 0], [1.0, 0, 0]])


def test_parallel_axis_needs_the_bodys_positive_mass_and_subtracts_a_hole():
    # a solid cube of side 2 (mass 8) less a unit cube (mass 1) whose centre sits at d = (0.5, 0.5, 0.5):
    # about the big cube's centre, I = I_big - (I_small + m (|d|² 1 - d dᵀ)), against the same body
    # built from particles (a 2x2x2 grid of unit cells, one cell removed, each cell a unit-mass cube)
    with pytest.raises(ValueError, match=r"parallel_axis: mass must be > 0 .*subtract its own parallel_axis"):
        rb.parallel_axis(np.eye(3), -1.0, np.array([0.5, 0.5, 0.5]))
    cell = rb.box(1.0, np.ones(3)).inertia  # a unit cube about its centre: 1/6 on the diagonal
    d = np.array([0.5, 0.5, 0.5])
    big = rb.box(8.0, 2 * np.ones(3)).inertia
    holed = big - rb.parallel_axis(cell, 1.0, d)
    centres = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    kept = centres[np.any(centres != d, axis=1)]
    direct = sum(rb.parallel_axis(cell, 1.0, c) for c in kept)
    np.testing.assert_allclose(holed, direct, rtol=1e-12)  # float64 (the suite runs x64): sums of O(1) terms
