"""The host-side NumPy quaternion helpers (identification's data checks, the animation) against
scipy's Rotation, an independent implementation. scipy stores quaternions ``[x, y, z, w]``."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbjax._rotations_np import np_qlog, np_qmat, np_qmul


def _random_unit(n, rng):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    # the identity, angles below and above the log's series switch (√eps ≈ 1.5e-8), and near π
    small = [[1, 0, 0, 0], [np.cos(5e-9), np.sin(5e-9), 0, 0], [np.cos(1e-7), 0, np.sin(1e-7), 0]]
    near_pi = [[np.cos(np.pi / 2 - 1e-9), 0, 0, np.sin(np.pi / 2 - 1e-9)], [0, 1, 0, 0]]
    return np.concatenate([q, small, near_pi])


def _scipy(q):
    return Rotation.from_quat(np.roll(q, -1, axis=-1))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_numpy_rotation_helpers_match_scipy(dtype):
    # float64: a few ulps of the result (~1e-15); float32: the same formulas at eps 1.2e-7, 10 eps.
    # The logarithm near π is ill-conditioned in the axis's sign convention only: scipy and rbjax
    # both return θ ∈ [0, π], so compare the rotation vectors directly
    rng = np.random.default_rng(0)
    p, q = _random_unit(1000, rng), _random_unit(1000, rng)[::-1].copy()
    tol = 1e-14 if dtype == np.float64 else 10 * np.finfo(np.float32).eps
    R = np_qmat(q.astype(dtype))
    assert R.dtype == dtype
    np.testing.assert_allclose(R, _scipy(q).as_matrix(), rtol=0, atol=tol)
    pq = np_qmul(p.astype(dtype), q.astype(dtype)).astype(np.float64)
    np.testing.assert_allclose(_scipy(pq).as_matrix(), (_scipy(p) * _scipy(q)).as_matrix(), rtol=0, atol=4 * tol)
    v = np_qlog(q.astype(dtype))
    assert v.dtype == dtype and np.all(np.isfinite(v))
    ref = _scipy(q).as_rotvec()
    # near π the two ±q of one rotation give ±the same vector, either is right
    flip = np.linalg.norm(v - ref, axis=1) > np.linalg.norm(v + ref, axis=1)
    ref[flip] *= -1
    np.testing.assert_allclose(v, ref, rtol=0, atol=4 * tol * np.pi)
