"""Eigen-decomposition of symmetric 3x3 matrices (inertia tensors) by cyclic Jacobi rotations.

``jnp.linalg.eigh`` calls LAPACK (CPU) or cuSOLVER (GPU) once per matrix: for a
batch of small matrices that is a slow custom call. At 1e5 float32 inertias it
took 77 ms on the 2-core CPU, more than 100 splitting steps of the same bodies
on the native path, and on a GPU it made splitting 18x slower than rk4
(benchmarks/results/gpu_h200_2026-12-04.md). Written with explicit components,
the Jacobi method is elementwise arithmetic over any batch, which XLA fuses
into one loop (CPU) or kernel (GPU).

The method (Golub & Van Loan, *Matrix Computations*, §8.5): each rotation in
the plane ``(p, q)`` zeroes ``a_pq`` with ``t = tan θ`` the smaller root of
``t² + 2ζt - 1 = 0``, ``ζ = (a_qq - a_pp) / (2 a_pq)``; a sweep visits the three
planes. Convergence is quadratic once the off-diagonal part is small against
the gaps, and a symmetric 3x3 reaches round-off within a few sweeps (tests:
against NumPy's ``eigh`` in float64, including repeated, nearly repeated and
widely spread eigenvalues). Jacobi's eigenvalues are accurate to round-off
relative to ``‖A‖``. Each rotation is orthogonal up to rounding, so the
product drifts by a few eps (6 eps after five sweeps, measured); one polar
(Newton–Schulz) step at the end brings ``P`` back to within 2 eps of
orthogonal, for a frame whose quaternion is exactly the rotation it stands for.
A diagonal matrix is returned exactly, with ``P`` a permutation (up to sign) of the identity.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from ._math import matrix_to_quat_unchecked, orthonormalize_unchecked

# Sweeps: the off-diagonal norm falls from ‖A‖ to below round-off within 4 sweeps in float64
# for every matrix in tests/test_eigh3.py (worst case: two eigenvalues 1e-9 apart); one more for margin.
_SWEEPS = 5
_PLANES = ((0, 1), (0, 2), (1, 2))


def _rotate(a: dict, v: list, p: int, q: int) -> tuple[dict, list]:
    """One Jacobi rotation zeroing ``a[p, q]``; ``a`` holds the upper triangle, ``v`` the rows of ``P``."""
    apq, app, aqq = a[p, q], a[p, p], a[q, q]
    # an a_pq below round-off of its diagonal (Demmel & Veselić's test) is left alone: rotating by
    # an angle of round-off would only add round-off to P (a sphere's P would drift from sweep to sweep)
    nonzero = jnp.abs(apq) > jnp.finfo(apq.dtype).eps * jnp.sqrt(jnp.abs(app * aqq))
    # t = tan θ, the smaller root of t² + 2ζt - 1 = 0 with ζ = δ / (2 a_pq), written without ζ so that a
    # rotation costs one division: t = 2 a_pq sgn δ / (|δ| + √(δ² + 4 a_pq²)), |t| ≤ 1 (θ = ±π/4 at δ = 0)
    delta = aqq - app
    root = jnp.sqrt(delta * delta + 4 * apq * apq)
    t = 2 * jnp.where(delta < 0, -apq, apq) / jnp.where(nonzero, jnp.abs(delta) + root, 1)
    t = jnp.where(nonzero, t, 0)
    c = jax.lax.rsqrt(t * t + 1)
    s = t * c
    a = dict(a)
    a[p, p], a[q, q], a[p, q] = app - t * apq, aqq + t * apq, jnp.zeros_like(apq)
    r = 3 - p - q
    rp, rq = (min(r, p), max(r, p)), (min(r, q), max(r, q))
    a[rp], a[rq] = c * a[rp] - s * a[rq], s * a[rp] + c * a[rq]
    v = [[*row[:p], c * row[p] - s * row[q], *row[p + 1 : q], s * row[p] + c * row[q], *row[q + 1 :]] for row in v]
    return a, v


def eigh3(a: Array) -> tuple[Array, Array]:
    """Eigenvalues ``d`` (..., 3), ascending, and eigenvectors ``P`` (..., 3, 3) of a symmetric ``a`` (..., 3, 3).

    ``a = P diag(d) Pᵀ`` with the columns of ``P`` the unit eigenvectors and
    ``det P = +1`` (a rotation: for an inertia tensor in the body frame, the
    principal axes as seen from the body). Only the upper triangle of ``a`` is
    read. Values only: gradients are taken through the principal frame by
    perturbation theory where needed (:func:`principal_frame`),
    since an eigenvector's derivative is undefined at repeated eigenvalues.
    Units: those of ``a`` for ``d``; ``P`` is dimensionless.
    """
    a = jax.lax.stop_gradient(jnp.asarray(a))
    upper = {(i, j): a[..., i, j] for i in range(3) for j in range(i, 3)}
    one, zero = jnp.ones_like(upper[0, 0]), jnp.zeros_like(upper[0, 0])
    rows = [[one if i == j else zero for j in range(3)] for i in range(3)]

    def sweep(_, carry):
        m, v = carry
        for p, q in _PLANES:
            m, v = _rotate(m, v, p, q)
        return m, v

    # named, so that tests can find the loop in the compiled program and check it is hoisted out of simulate's
    with jax.named_scope("eigh3"):
        upper, rows = jax.lax.fori_loop(0, _SWEEPS, sweep, (upper, rows))
    d = [upper[i, i] for i in range(3)]
    cols = [[rows[i][j] for i in range(3)] for j in range(3)]
    # ascending, by a three-comparison sorting network; each swap carries its column along
    for i, j in ((0, 1), (1, 2), (0, 1)):
        swap = d[j] < d[i]
        d[i], d[j] = jnp.where(swap, d[j], d[i]), jnp.where(swap, d[i], d[j])
        ci, cj = cols[i], cols[j]
        cols[i] = [jnp.where(swap, y, x) for x, y in zip(ci, cj, strict=True)]
        cols[j] = [jnp.where(swap, x, y) for x, y in zip(ci, cj, strict=True)]
    (x0, x1, x2), (y0, y1, y2), (z0, z1, z2) = cols
    det = x0 * (y1 * z2 - y2 * z1) + x1 * (y2 * z0 - y0 * z2) + x2 * (y0 * z1 - y1 * z0)
    sign = jnp.where(det < 0, -1, 1).astype(a.dtype)
    P = jnp.stack([jnp.stack([sign * cols[j][i] for j in range(3)], axis=-1) for i in range(3)], axis=-2)
    return jnp.stack(d, axis=-1), orthonormalize_unchecked(P, 1)


def principal_frame(inertia: Array) -> tuple[Array, Array, Array]:
    """Principal moments ``d`` (3,), ascending, the quaternion ``p`` of the axes,
    and ``w`` (3, 3), the carrier of the perturbations that split equal moments.

    ``I = P diag(d) Pᵀ`` with ``P`` (columns = principal axes in the body frame,
    ``det P = +1``) the rotation of ``p``.

    Values: the Jacobi sweeps of :func:`eigh3` of ``stop_gradient(I)`` and the
    quaternion of their ``P`` (``matrix_to_quat_unchecked``), exactly (the native
    kernel computes the same values in C++: rbjax/_native/steps.h). An
    eigen-decomposition's own derivative is NaN at repeated moments (spheres,
    axisymmetric bodies); derivatives come from first-order perturbation theory
    instead, through ``dM = P₀ᵀ (I - stop_gradient(I)) P₀`` (zero by value, its
    tangent ``P₀ᵀ dI P₀``):

    * ``d = d₀ + diag(dM)`` (derivative ``dd_i = dM_ii``, Hellmann–Feynman);
    * ``P = P₀ (1 + A)`` with ``A_ij = dM_ij / (d_j - d_i)`` for ``i ≠ j``:
      value ``P₀``, derivative ``P₀ dA``, the standard eigenvector derivative
      (``1 + A`` is ``exp(A)`` to first order, which is all a first derivative
      sees: second derivatives w.r.t. the inertia are not exact).
    * Where ``|d_i - d_j|`` is within round-off of zero the axes are not
      determined by ``I``: ``A_ij = 0`` (double ``where``: no 0/0 is ever
      evaluated), and ``dM_ij``, which splits the two equal moments along axes
      the perturbation chooses, goes into ``w`` instead. ``w`` is zero by value;
      its tangent is that part of the body's inverse inertia in the principal
      frame, ``d(M⁻¹)_ij = -dM_ij / (d_i d_j)``, which a method adds to its flow
      with :func:`degenerate_flow`. Without it the derivative of a sphere's or a
      symmetric top's motion along such a perturbation would be missing, not
      merely inexact.

    Cost: five Jacobi sweeps per body. The result depends only on the body:
    ``simulate`` computes it once per call, before its loop, for the methods
    that use it (:func:`rbjax._body.prepare`; tests/test_composition.py checks
    the compiled program). LAPACK's ``eigh`` took 7x as long as the sweeps at
    10⁵ float32 bodies on the CPU (benchmarks/results/splitting_principal_frame_2026-12-04.md).
    """
    d0, P0 = eigh3(inertia)  # values only (stop_gradient inside)
    dM = P0.T @ (inertia - jax.lax.stop_gradient(inertia)) @ P0
    d = d0 + jnp.diagonal(dM)
    gap = d0[None, :] - d0[:, None]
    eps = jnp.finfo(inertia.dtype).eps
    tiny = jnp.abs(gap) <= 64 * eps * jnp.max(jnp.abs(d0))
    A = jnp.where(tiny, 0.0, dM / jnp.where(tiny, 1.0, gap))
    P = P0 + P0 @ A
    e0 = 1 / d0
    split = tiny & ~jnp.eye(3, dtype=bool)
    w = jnp.where(split, -dM * (e0[:, None] * e0[None, :]), 0.0)
    return d, matrix_to_quat_unchecked(P), w
