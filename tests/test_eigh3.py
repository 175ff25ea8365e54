"""The symmetric 3x3 eigen-decomposition behind the principal frame (``rbjax._eigh3.eigh3``).

Reference: NumPy's LAPACK ``eigvalsh`` in float64. Tolerances are in units of the
dtype's epsilon times ``‖A‖`` (Frobenius): Jacobi's eigenvalues and its
reconstruction ``P diag(d) Pᵀ`` are backward stable, so round-off of a few eps
is what a correct result has. Measured over 20,000 matrices per family: at most
7.1 eps (eigenvalues), 2.8 eps (reconstruction) and 2 eps (orthogonality of
``P``) in float64; 16 eps leaves room without admitting an unconverged sweep,
which is off by 1e4 eps or more after too few sweeps.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rbjax._eigh3 import eigh3

N = 2000
TOL = 16  # eps x ‖A‖ (see the module docstring)


def _rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def _moments(family, rng, n):
    if family == "random":
        return rng.uniform(0.1, 3, (n, 3))
    if family == "spread":  # six decades: a thin rod's moments
        return 10.0 ** rng.uniform(-6, 0, (n, 3))
    d = rng.uniform(1, 2, (n, 3))
    if family == "sphere":
        return np.repeat(d[:, :1], 3, axis=1)
    gap = {"repeated": 0.0, "gap 1e-9": 1e-9, "gap 1e-5": 1e-5}[family]
    d[:, 1] = d[:, 0] * (1 + gap)
    return d


FAMILIES = ("random", "spread", "sphere", "repeated", "gap 1e-9", "gap 1e-5")


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("family", FAMILIES)
def test_eigenvalues_vectors_and_frame_agree_with_lapack(family, dtype):
    rng = np.random.default_rng(FAMILIES.index(family))
    R = _rotations(rng, N)
    A = np.einsum("nij,nj,nkj->nik", R, _moments(family, rng, N), R).astype(dtype)
    d, P = jax.jit(jax.vmap(eigh3))(jnp.asarray(A))
    assert d.dtype == P.dtype == dtype
    d, P, A = (np.asarray(x, np.float64) for x in (d, P, A))
    eps = np.finfo(dtype).eps
    scale = np.linalg.norm(A, axis=(1, 2))[:, None]
    d_ref = np.linalg.eigvalsh(A)
    assert np.all(np.abs(d - d_ref) <= TOL * eps * scale)
    assert np.all(np.diff(d, axis=1) >= 0), "ascending"
    rebuilt = np.einsum("nij,nj,nkj->nik", P, d, P)
    assert np.all(np.abs(rebuilt - A).max(axis=2) <= TOL * eps * scale)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", P, P), np.broadcast_to(np.eye(3), A.shape), atol=TOL * eps)
    np.testing.assert_allclose(np.linalg.det(P), 1.0, atol=TOL * eps)


def test_a_diagonal_matrix_is_returned_exactly():
    # no rotation is made: the moments come back bit for bit, sorted, and P is a signed permutation
    A = jnp.diag(jnp.array([3.0, 1.0, 2.0]))
    d, P = eigh3(A)
    assert np.array_equal(np.asarray(d), [1.0, 2.0, 3.0])
    assert np.array_equal(np.abs(np.asarray(P)), [[0, 0, 1], [1, 0, 0], [0, 1, 0]])
    assert np.linalg.det(np.asarray(P)) == 1.0


@pytest.mark.parametrize("batch", [(), (4,), (2, 3)])
def test_batches_broadcast_like_one_matrix_each(batch):
    rng = np.random.default_rng(1)
    n = int(np.prod(batch, dtype=int))
    R = _rotations(rng, n)
    A = np.einsum("nij,nj,nkj->nik", R, rng.uniform(0.5, 2, (n, 3)), R).reshape(*batch, 3, 3)
    d, P = eigh3(jnp.asarray(A))
    flat = [eigh3(jnp.asarray(a)) for a in A.reshape(-1, 3, 3)]
    # the same arithmetic, compiled for another shape: equal up to the order of round-off (8 eps)
    tol = 8 * np.finfo(np.float64).eps
    np.testing.assert_allclose(np.asarray(d).reshape(-1, 3), np.stack([f[0] for f in flat]), rtol=0, atol=2 * tol)
    np.testing.assert_allclose(np.asarray(P).reshape(-1, 3, 3), np.stack([f[1] for f in flat]), rtol=0, atol=tol)
