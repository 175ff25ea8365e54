"""Math helpers against independent references (numpy, scipy.spatial.transform)."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rbjax as rb

BATCH_SHAPES = [(), (5,), (2, 3)]
# float64 round-off on O(1) quantities composed of a few dozen operations
TOL = 1e-13


def _rand_quat(rng, shape):
    q = rng.normal(size=shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _scipy_rot(q):
    """scipy stores quaternions as [x, y, z, w]."""
    q = np.asarray(q).reshape(-1, 4)
    return Rotation.from_quat(q[:, [1, 2, 3, 0]])


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_skew_is_the_cross_product(shape):
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=shape + (3,)), rng.normal(size=shape + (3,))
    S = rb.skew(a)
    np.testing.assert_allclose(np.einsum("...ij,...j->...i", S, b), np.cross(a, b), atol=TOL)
    # the notes' identities: ã b = a × b = -b × a = -b̃ a, and ãᵀ = -ã
    np.testing.assert_allclose(-np.einsum("...ij,...j->...i", rb.skew(b), a), np.cross(a, b), atol=TOL)
    np.testing.assert_allclose(np.swapaxes(S, -1, -2), -S, atol=0)
    np.testing.assert_allclose(rb.cross(a, b), np.cross(a, b), atol=TOL)


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_quaternion_matrix_against_scipy(shape):
    rng = np.random.default_rng(1)
    q = _rand_quat(rng, shape)
    R = np.asarray(rb.quat_to_matrix(q))
    np.testing.assert_allclose(R.reshape(-1, 3, 3), _scipy_rot(q).as_matrix(), atol=TOL)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=TOL)
    v = rng.normal(size=shape + (3,))
    np.testing.assert_allclose(rb.quat_rotate(q, v), np.einsum("...ij,...j->...i", R, v), atol=TOL)


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_quaternion_product_composes_rotations(shape):
    rng = np.random.default_rng(2)
    p, q = _rand_quat(rng, shape), _rand_quat(rng, shape)
    lhs = rb.quat_to_matrix(rb.quat_multiply(p, q))
    rhs = np.asarray(rb.quat_to_matrix(p)) @ np.asarray(rb.quat_to_matrix(q))
    np.testing.assert_allclose(lhs, rhs, atol=TOL)
    ident = rb.quat_multiply(q, rb.quat_conjugate(q))
    np.testing.assert_allclose(ident, np.broadcast_to([1.0, 0, 0, 0], shape + (4,)), atol=TOL)
    # q and -q are the same orientation (the notes' one ambiguity)
    np.testing.assert_allclose(rb.quat_to_matrix(-q), rb.quat_to_matrix(q), atol=0)


def _hard_rotations():
    """Random rotations plus the ones that break naive matrix->quaternion formulas."""
    rng = np.random.default_rng(3)
    mats = list(Rotation.random(200, random_state=4).as_matrix())
    for axis in np.eye(3).tolist() + [[1, 1, 0], [1, 1, 1], [0, -1, 1]]:
        axis = np.asarray(axis, float) / np.linalg.norm(axis)
        for angle in [np.pi, np.pi - 1e-9, np.pi - 1e-4, 1e-12, 0.0, 2.5]:
            mats.append(Rotation.from_rotvec(angle * axis).as_matrix())
    del rng
    return np.stack(mats)


def test_matrix_to_quat_is_robust_for_every_rotation():
    R = _hard_rotations()
    q = np.asarray(rb.matrix_to_quat(R))
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=TOL)
    # the round trip reproduces R to round-off even at half turns
    np.testing.assert_allclose(rb.quat_to_matrix(q), R, atol=1e-14 * 20)
    ref = _scipy_rot(q).as_matrix()
    np.testing.assert_allclose(ref, R, atol=1e-13)


def test_matrix_to_quat_gradient_finite_at_identity_and_half_turn():
    for R in [np.eye(3), Rotation.from_rotvec([np.pi, 0, 0]).as_matrix()]:
        g = jax.jacfwd(rb.matrix_to_quat)(jnp.asarray(R))
        assert np.all(np.isfinite(g))


@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_exp_and_log_against_scipy(shape):
    rng = np.random.default_rng(5)
    v = rng.normal(size=shape + (3,))
    q = np.asarray(rb.quat_exp(v))
    ref = _scipy_rot(q).as_rotvec().reshape(shape + (3,))
    # |v| may exceed π: compare rotations, not vectors
    np.testing.assert_allclose(_scipy_rot(q).as_matrix(), Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix(), atol=TOL)
    np.testing.assert_allclose(rb.quat_log(q), ref, atol=1e-12)
    # small angles: the series branch agrees with scipy to round-off
    small = 1e-6 * v
    np.testing.assert_allclose(
        _scipy_rot(rb.quat_exp(small)).as_matrix(),
        Rotation.from_rotvec(small.reshape(-1, 3)).as_matrix(),
        atol=TOL,
    )
    np.testing.assert_allclose(rb.quat_log(rb.quat_exp(small)), small, rtol=1e-10, atol=1e-20)


def test_gradients_finite_at_zero_rotation():
    z = jnp.zeros(3)
    # d exp(v)/dv at 0 is [0; ½·1] (first order: q ≈ [1, v/2])
    J = jax.jacfwd(rb.quat_exp)(z)
    np.testing.assert_allclose(J, np.vstack([np.zeros(3), 0.5 * np.eye(3)]), atol=TOL)
    Jr = jax.jacrev(rb.quat_exp)(z)
    np.testing.assert_allclose(Jr, J, atol=TOL)
    # log at the identity: d log(q)/d(vector part) = 2·1
    Jl = jax.jacfwd(rb.quat_log)(jnp.array([1.0, 0, 0, 0]))
    np.testing.assert_allclose(Jl[:, 1:], 2 * np.eye(3), atol=TOL)
    assert np.all(np.isfinite(jax.grad(lambda x: rb.safe_norm(x))(z)))
    assert np.all(
        np.isfinite(jax.grad(lambda q: rb.quat_angle(q, jnp.array([1.0, 0, 0, 0])))(jnp.array([1.0, 0, 0, 0])))
    )


def test_quat_angle_matches_scipy_and_ignores_sign():
    rng = np.random.default_rng(6)
    p, q = _rand_quat(rng, (50,)), _rand_quat(rng, (50,))
    ref = (_scipy_rot(p).inv() * _scipy_rot(q)).magnitude()
    np.testing.assert_allclose(rb.quat_angle(p, q), ref, atol=1e-12)
    np.testing.assert_allclose(rb.quat_angle(p, -q), ref, atol=1e-12)


def test_orthonormalize_gives_the_polar_factor():
    rng = np.random.default_rng(7)
    R = Rotation.random(20, random_state=8).as_matrix()
    noisy = R + 1e-4 * rng.normal(size=R.shape)  # ‖RᵀR - 1‖ = ε ≈ 5e-4
    U, _, Vt = np.linalg.svd(noisy)
    polar = U @ Vt  # the nearest orthogonal matrix in Frobenius norm
    out = np.asarray(rb.orthonormalize(noisy))
    # two Newton–Schulz steps leave O(ε⁴) ≈ 1e-13 (quadratic convergence)
    np.testing.assert_allclose(out, polar, atol=1e-12)
    np.testing.assert_allclose(np.swapaxes(out, -1, -2) @ out, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_float32_stays_float32():
    q = jnp.asarray([0.5, 0.5, 0.5, 0.5], jnp.float32)
    v = jnp.ones(3, jnp.float32)
    for out in [
        rb.quat_rotate(q, v),
        rb.quat_to_matrix(q),
        rb.matrix_to_quat(rb.quat_to_matrix(q)),
        rb.quat_exp(v),
        rb.quat_log(q),
    ]:
        assert out.dtype == jnp.float32
    # float32 rotation accuracy is a few epsilons
    np.testing.assert_allclose(rb.quat_rotate(q, v), [1, 1, 1], atol=8 * np.finfo(np.float32).eps)


# The helpers whose formulas hold only on the rotation group: given a concrete value off it they
# raise (before, each returned a finite answer that was no rotation, without a word). Off by
# 1e-3 is 1000x quat_tolerance in float64 and ~70x in float32, and far above what a normalised
# input carries (a few eps).
_OFF = 1e-3


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("shape", BATCH_SHAPES)
def test_quaternion_helpers_refuse_a_quaternion_off_the_unit_sphere(shape, dtype):
    rng = np.random.default_rng(11)
    q = _rand_quat(rng, shape).astype(dtype)
    v = rng.normal(size=shape + (3,)).astype(dtype)
    # within tolerance (a normalised input in its own precision) they run and rotate
    np.testing.assert_allclose(
        np.asarray(rb.quat_rotate(q, v)).reshape(-1, 3),
        _scipy_rot(q).apply(np.asarray(v, np.float64).reshape(-1, 3)),
        atol=32 * float(jnp.finfo(dtype).eps),
    )
    bad = np.array(q).reshape(-1, 4)
    bad[-1] *= 1 + _OFF  # the last body, named by its batch index
    bad = bad.reshape(q.shape)
    where = "" if shape == () else " at batch index " + re.escape(str(tuple(n - 1 for n in shape)))
    for fn, args in [(rb.quat_rotate, (bad, v)), (rb.quat_to_matrix, (bad,))]:
        with pytest.raises(
            ValueError, match=rf"{fn.__name__}: q must be a unit quaternion.* = 0.00(1|0999){where} .*quat_normalize"
        ):
            fn(*args)
    # under jit the value is not known: no check (simulate's checked mode is the check there)
    assert np.all(np.isfinite(np.asarray(jax.jit(rb.quat_rotate)(bad, v))))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_matrix_to_quat_refuses_what_is_not_a_rotation(dtype):
    R = Rotation.random(4, random_state=3).as_matrix()
    # a rotation rounded to the dtype passes and round-trips
    q = rb.matrix_to_quat(jnp.asarray(R, dtype))
    np.testing.assert_allclose(rb.quat_to_matrix(q), R, atol=16 * float(jnp.finfo(dtype).eps))
    sheared = R.copy()
    sheared[2] = sheared[2] @ (np.eye(3) + _OFF * np.triu(np.ones((3, 3)), 1))
    with pytest.raises(
        ValueError, match=r"matrix_to_quat: R must be a proper rotation.* at batch index \(2,\).*orthonormalize"
    ):
        rb.matrix_to_quat(jnp.asarray(sheared, dtype))
    # a reflection is orthogonal but no rotation: the message says orthonormalize cannot fix it
    with pytest.raises(ValueError, match=r"det R = -1.*reflection"):
        rb.matrix_to_quat(jnp.asarray(-np.eye(3), dtype))
    # the remedy the message names works on the sheared matrices
    q = rb.matrix_to_quat(rb.orthonormalize(jnp.asarray(sheared)))
    np.testing.assert_allclose(rb.quat_to_matrix(q)[:2], R[:2], atol=1e-12)


def test_rotate_inertia_needs_an_orthogonal_matrix_and_takes_a_reflection():
    I = np.diag([1.0, 2.0, 3.0])
    R = Rotation.from_rotvec([0.3, -0.2, 0.9]).as_matrix()
    # I' = R I Rᵀ keeps the eigenvalues (principal moments) of I
    np.testing.assert_allclose(np.linalg.eigvalsh(rb.rotate_inertia(I, R)), [1, 2, 3], atol=1e-13)
    # a mirror image: still R I Rᵀ, the inertia of the mirrored body
    P = np.diag([1.0, 1.0, -1.0]) @ R
    np.testing.assert_allclose(rb.rotate_inertia(I, P), P @ I @ P.T, atol=1e-14)
    with pytest.raises(ValueError, match=r"rotate_inertia: rotation must be orthogonal.*orthonormalize"):
        rb.rotate_inertia(I, 1.01 * R)


def test_quat_normalize_refuses_a_zero_or_non_finite_quaternion():
    q = np.array([[2.0, 0, 0, 0], [0, 0, 0, 0], [1, 1, 1, 1]])
    np.testing.assert_allclose(rb.quat_normalize(q[[0, 2]]), [[1, 0, 0, 0], [0.5, 0.5, 0.5, 0.5]], atol=TOL)
    with pytest.raises(
        ValueError, match=r"quat_normalize: q must be finite and non-zero; ‖q‖ = 0.0 at batch index \(1,\)"
    ):
        rb.quat_normalize(q)
    with pytest.raises(ValueError, match=r"non-finite"):
        rb.quat_normalize([np.nan, 0, 0, 1])


@pytest.mark.parametrize("batch", [(), (5,), (2, 3)])
def test_rotate_inverse_takes_world_vectors_into_the_body_frame(batch):
    # R(q)ᵀ v by scipy's rotation matrix (scalar-last quaternions); and for a q off the unit sphere
    # (an RK stage), the rotation by q* that it stands for in the steps, to round-off
    from rbjax._math import quat_conjugate, quat_rotate_inverse_unchecked, quat_rotate_unchecked

    rng = np.random.default_rng(3)
    q = rng.normal(size=(*batch, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    v = rng.normal(size=(*batch, 3))
    R = Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_matrix()
    want = np.einsum("bji,bj->bi", R, v.reshape(-1, 3)).reshape(v.shape)
    got = np.asarray(quat_rotate_inverse_unchecked(jnp.asarray(q), jnp.asarray(v)))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)  # float64 round-off of O(1) values
    off = 1.1 * jnp.asarray(q)  # |q|² = 1.21: not a rotation, the same polynomial
    np.testing.assert_allclose(
        np.asarray(quat_rotate_inverse_unchecked(off, jnp.asarray(v))),
        np.asarray(quat_rotate_unchecked(quat_conjugate(off), jnp.asarray(v))),
        rtol=0,
        atol=1e-14,
    )
