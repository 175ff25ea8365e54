"""Rotation and vector math: skew matrices, unit quaternions and rotation matrices.

Conventions (as in the lecture notes):

* Quaternions are ``[w, x, y, z]`` with the scalar first. A unit quaternion ``q``
  maps body-frame vectors to the world frame: ``v_world = q ⊗ (0, v_body) ⊗ q*``.
* ``skew(a) @ b == a × b`` (the notes' tilde).

Every function broadcasts over leading batch dimensions and is written with
explicit components, so that under ``vmap`` and inside ``lax.scan`` XLA sees
elementwise arithmetic it can fuse rather than small batched matmuls.
Functions that take a norm are NaN-safe: values and gradients are finite at zero.

Arguments are checked while tracing (shapes and dtypes are static): a last axis
of the wrong size (a 3-vector where a quaternion belongs, a fifth component)
raises ``ValueError`` naming the argument, a non-real argument ``TypeError``;
integer arrays are computed in the default float dtype, as everywhere in rbjax.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import jax
import jax.core
import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from ._typing import ArrayLike

__all__ = [
    "cross",
    "matrix_to_quat",
    "orthonormalize",
    "quat_angle",
    "quat_conjugate",
    "quat_exp",
    "quat_log",
    "quat_multiply",
    "quat_normalize",
    "quat_rotate",
    "quat_to_matrix",
    "safe_norm",
    "skew",
]


_NORMALISE = "; normalise it first with rb.quat_normalize(q)"
_WHAT = {(3,): "3-vectors", (4,): "quaternions [w, x, y, z]", (3, 3): "3x3 matrices", (6,): "6-vectors"}


def holds_text(x: Any) -> bool:
    """Whether ``x`` is a (nested) list or tuple with a string among its entries.

    Checked before ``jnp.asarray``, which reads a string such as ``'a'`` as a dtype name (and NumPy
    warns that alias is deprecated) before it fails: rbjax refuses such input in its own words.
    """
    return isinstance(x, (list, tuple)) and any(isinstance(e, (str, bytes)) or holds_text(e) for e in x)


def array_arg(fn: str, name: str, x: Any, core: tuple[int, ...] = ()) -> Array:
    """``x`` as a float array whose shape ends in ``core``; ``TypeError``/``ValueError`` naming ``fn``'s ``name``.

    Runs while tracing (shape and dtype are static), so it costs nothing in a
    compiled step. Integers are cast to the default float dtype (as rbjax's
    constructors do); booleans, complex numbers and 16-bit floats are refused.
    """
    if x is None or isinstance(x, (str, bytes, dict, bool, np.bool_)):
        raise TypeError(f"{fn}: {name} must be a real float array, got {type(x).__name__} {x!r:.60}")
    if holds_text(x):
        raise TypeError(f"{fn}: {name} must be a real float array, got a {type(x).__name__} holding text: {x!r:.60}")
    try:
        a = jnp.asarray(x)
    except (TypeError, ValueError):
        raise TypeError(f"{fn}: {name} must be a real float array, got {type(x).__name__}: {x!r:.60}") from None
    dt = a.dtype
    if jnp.issubdtype(dt, jnp.integer):
        a = a.astype(jnp.result_type(float))
    elif not jnp.issubdtype(dt, jnp.floating):
        raise TypeError(f"{fn}: {name} must be a real float array, got dtype {dt}")
    elif jnp.finfo(dt).bits < 32:
        raise TypeError(f"{fn}: {name} has dtype {dt}; rbjax computes in float32 or float64: convert with .astype")
    if core and tuple(a.shape[-len(core) :]) != core:
        dims = ", ".join(str(c) for c in core)
        raise ValueError(
            f"{fn}: {name} must have shape (..., {dims}) ({_WHAT.get(core, 'arrays')}), got shape {tuple(a.shape)}"
        )
    return a


def _batches(fn: str, **named: tuple[Array, int]) -> None:
    """``ValueError`` naming ``fn``'s arguments unless their batch shapes (all but ``core`` trailing axes) broadcast."""
    shapes = {k: tuple(a.shape[: a.ndim - core]) for k, (a, core) in named.items()}
    try:
        jnp.broadcast_shapes(*shapes.values())
    except ValueError:
        listed = ", ".join(f"{k} {v}" for k, v in shapes.items())
        raise ValueError(f"{fn}: the batch shapes do not broadcast ({listed})") from None


def broadcasts_to(shape: tuple[int, ...], want: tuple[int, ...]) -> bool:
    """Whether an array of ``shape`` broadcasts to exactly ``want``."""
    try:
        return jnp.broadcast_shapes(tuple(shape), tuple(want)) == tuple(want)
    except ValueError:
        return False


def is_concrete(*xs: Any) -> bool:
    """Whether the values of ``xs`` can be read on this host (and so checked before tracing).

    A ``jax.Array`` spread over several processes (not fully addressable) has no
    host value here: like a traced one, it is checked only by ``checked`` mode.
    """
    return all(
        isinstance(x, (np.ndarray, np.generic, float, int, jax.Array))
        and not isinstance(x, jax.core.Tracer)
        and (not isinstance(x, jax.Array) or x.is_fully_addressable)
        for x in xs
    )


def quat_tolerance(dtype: Any) -> float:
    """Accepted ``|‖q‖ - 1|`` for an input quaternion (and ``max |RᵀR - 1|`` for a rotation): ``max(1e-6, 128 eps)``.

    1e-6 in float64 admits quaternions typed or computed by hand to ~6 digits;
    in float32 128 eps ≈ 1.5e-5 admits a normalised float32 quaternion that went
    through a few operations.
    """
    return max(1e-6, 128 * float(np.finfo(dtype).eps))


def index_tuple(index: Any) -> tuple[int, ...]:
    """A NumPy index (a row of ``np.argwhere``, the result of ``np.unravel_index``) as plain ints.

    For messages: a tuple of NumPy integers prints as ``(np.int64(0),)``; this one as ``(0,)``.
    """
    return tuple(int(i) for i in np.ravel(np.asarray(index, dtype=np.int64)))


def first_index(bad: Any) -> tuple[int, ...]:
    """The index of the first ``True`` in ``bad`` (``()`` for a single value), as plain ints."""
    bad = np.asarray(bad)
    return index_tuple(np.argwhere(bad)[0]) if bad.ndim else ()


def _first_bad(bad: np.ndarray) -> str:
    """`` at batch index (i, j)`` of the first ``True`` in ``bad``, or nothing for a single value."""
    return f" at batch index {first_index(bad)}" if bad.ndim else ""


def check_unit_quaternions(fn: str, name: str, q: Array, remedy: str = "") -> None:
    """``ValueError`` unless the concrete ``q`` ``(..., 4)`` are unit quaternions within :func:`quat_tolerance`.

    Traced (or multi-process) values are not read: a compiled function is not
    checked here, ``checked`` mode is the check there.
    """
    if not is_concrete(q) or q.size == 0:
        return
    err = np.abs(np.linalg.norm(np.asarray(q, np.float64), axis=-1) - 1)
    tol = quat_tolerance(q.dtype)
    bad = ~(err <= tol)  # NaN is bad too
    if np.any(bad):
        raise ValueError(
            f"{fn}: {name} must be a unit quaternion [w, x, y, z]; |‖q‖ - 1| = {np.nanmax(np.where(bad, err, 0)):.3g}"
            f"{_first_bad(bad)} exceeds the tolerance {tol:.3g}{remedy}"
        )


def check_rotations(fn: str, name: str, R: Array, remedy: str = "", proper: bool = True) -> None:
    """``ValueError`` unless the concrete ``R`` ``(..., 3, 3)`` are orthogonal, ``RᵀR = 1`` within
    :func:`quat_tolerance`, and (``proper``) rotations, ``det R > 0``. Traced values are not read
    (as :func:`check_unit_quaternions`)."""
    if not is_concrete(R) or R.size == 0:
        return
    R64 = np.asarray(R, np.float64)
    err = np.max(np.abs(np.swapaxes(R64, -1, -2) @ R64 - np.eye(3)), axis=(-2, -1))
    det = np.linalg.det(R64)
    tol = quat_tolerance(R.dtype)
    bad = ~(err <= tol) | (~(det > 0) if proper else False)
    if np.any(bad):
        at = first_index(bad)
        what = "a proper rotation matrix (RᵀR = 1, det R = +1)" if proper else "orthogonal (RᵀR = 1)"
        if proper and not det[at] > 0:  # no rotation is near a reflection: orthonormalize cannot help
            remedy = ": a reflection or a singular matrix, which no rotation approximates"
        raise ValueError(
            f"{fn}: {name} must be {what}; max |RᵀR - 1| = {err[at]:.3g}, det R = {det[at]:.3g}"
            f"{_first_bad(bad)}, tolerance {tol:.3g}{remedy}"
        )


def _eps(x: Array) -> Array:
    return jnp.asarray(jnp.finfo(x.dtype).eps, x.dtype)


def safe_norm(x: Float[ArrayLike, " ..."], axis: int = -1, keepdims: bool = False) -> Float[Array, " ..."]:
    """Euclidean norm ``‖x‖`` along ``axis`` whose gradient is 0, not NaN, at ``x = 0``.

    Uses the double-``where`` pattern: the square root never sees a zero that
    would be differentiated. ``x``: ``(..., n, ...)``; returns ``x``'s shape without ``axis``.
    """
    x = array_arg("safe_norm", "x", x)
    if isinstance(axis, (bool, np.bool_)) or not isinstance(axis, (int, np.integer)) or not -x.ndim <= axis < x.ndim:
        raise ValueError(
            f"safe_norm: axis must be an int in [-{x.ndim}, {x.ndim}) for x of shape {x.shape}, got {axis!r}"
        )
    sq = jnp.sum(x * x, axis=axis, keepdims=keepdims)
    zero = sq == 0
    return jnp.where(zero, 0.0, jnp.sqrt(jnp.where(zero, 1.0, sq)))


def skew(a: Float[ArrayLike, "... 3"]) -> Float[Array, "... 3 3"]:
    """Skew-symmetric matrix ``ã`` with ``ã b = a × b`` (the notes' tilde).

    ``a``: ``(..., 3)`` → ``(..., 3, 3)``::

        ã = [[ 0, -az,  ay],
             [ az,  0, -ax],
             [-ay, ax,   0]]
    """
    a = array_arg("skew", "a", a, (3,))
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    z = jnp.zeros_like(ax)
    return jnp.stack(
        [
            jnp.stack([z, -az, ay], axis=-1),
            jnp.stack([az, z, -ax], axis=-1),
            jnp.stack([-ay, ax, z], axis=-1),
        ],
        axis=-2,
    )


def cross(a: Float[ArrayLike, "... 3"], b: Float[ArrayLike, "... 3"]) -> Float[Array, "... 3"]:
    """Cross product ``a × b`` of ``(..., 3)`` vectors, written by components."""
    a, b = array_arg("cross", "a", a, (3,)), array_arg("cross", "b", b, (3,))
    _batches("cross", a=(a, 1), b=(b, 1))
    return jnp.stack(cross_components(_unstack(a), _unstack(b)), axis=-1)


# Component helpers: the vector functions here index single components and stack
# once at the end. Multi-component slices (``q[..., 1:]``) and broadcasts of a
# size-1 slice made XLA:CPU materialise each intermediate vector in its own loop
# (one pass over the batch each) instead of fusing a whole step into one loop.
def _unstack(a: Array) -> tuple[Array, ...]:
    return tuple(a[..., i] for i in range(a.shape[-1]))


def over(a: Array, s: Array) -> Array:
    """``a / s`` for ``(..., 3)`` vectors and per-body scalars, by components.

    ``a / s`` itself mixes a vector with a scalar of another rank; under ``vmap``
    in the batch-last layout the two batch axes are aligned by transposing ``a``,
    and XLA:CPU then gives the velocity it updates the force's batch-first layout
    (strided updates, a copy per step: about half the rate at N = 1e4).
    """
    return jnp.stack([a[..., k] / s for k in range(3)], axis=-1)


def scale3(s: Array, a: Array) -> Array:
    """``s a`` for a per-body scalar ``s`` and ``(..., 3)`` vectors, by components (see :func:`over`).

    Under ``vmap`` in the batch-last layout ``s * a`` puts the batch axis first
    (``(N, 3)``) and transposes it back: where the product is loop-invariant
    (gravity's ``m g``), XLA:CPU hoists it out of ``simulate``'s loop in that
    layout, and the kicks then read it strided and split into one fusion per
    component. By components the product comes out ``(3, N)`` directly.
    """
    return jnp.stack([s * a[..., k] for k in range(3)], axis=-1)


def kick3(v: Array, f: Array, m: Array, h: Array) -> Array:
    """``v + f/m h`` by components (see :func:`over`): the same operations, which XLA may fuse
    (contract) differently from the vector form, so results differ from it by round-off only."""
    return jnp.stack([v[..., k] + f[..., k] / m * h for k in range(3)], axis=-1)


def dot3(a: Array, b: Array) -> Array:
    """``a · b`` of ``(..., 3)`` vectors by components (a sum would be a reduction)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def norm3(a: Array) -> Array:
    """``‖a‖`` of ``(..., 3)`` vectors by components (:func:`safe_norm` sums, a reduction that
    XLA:CPU does not fuse into a step), with its double ``where``: gradient 0, not NaN, at ``a = 0``."""
    sq = dot3(a, a)
    zero = sq == 0
    return jnp.where(zero, 0.0, jnp.sqrt(jnp.where(zero, 1.0, sq)))


def entries3(A: Array) -> tuple[tuple[Array, Array, Array], ...]:
    """The nine entries ``A[..., i, j]`` of ``(..., 3, 3)`` matrices as rows of components.

    Each entry is sliced once however often a formula reads it: reverse mode keeps every slice
    that a product reads as a residual of its own, so slicing an entry again for each use
    multiplied the residuals that a gradient through ``simulate`` stores per step (and its
    compile time: an rk8 ``MatrixState`` VJP compiled in 2.5x the time of a ``State`` one).
    """
    return tuple((A[..., i, 0], A[..., i, 1], A[..., i, 2]) for i in range(3))


def stack3x3(rows: Iterable[Iterable[Array]]) -> Array:
    """``(..., 3, 3)`` matrices from rows of components (the inverse of :func:`entries3`)."""
    return jnp.stack([jnp.stack(tuple(row), axis=-1) for row in rows], axis=-2)


def apply3(a: tuple, v: tuple) -> tuple[Array, Array, Array]:
    """``A v`` on components: ``a`` from :func:`entries3`, ``v`` a 3-tuple of components."""
    return tuple(row[0] * v[0] + row[1] * v[1] + row[2] * v[2] for row in a)


def transpose3(a: tuple) -> tuple:
    """``Aᵀ`` on components (the same slices, no new operation)."""
    return tuple(zip(*a))


def matmul3(A: Array, B: Array) -> Array:
    """``A @ B`` of ``(..., 3, 3)`` matrices by components: a batched ``dot`` of 3x3
    blocks is a separate, unfused XLA:CPU kernel per product."""
    # (A B)_ij = (row i of A) · (column j of B): Bᵀ applied to each row of A
    a, bt = entries3(A), transpose3(entries3(B))
    return stack3x3(apply3(bt, row) for row in a)


def pure_quat_multiply(w: Array, q: Array) -> Array:
    """``(0, w) ⊗ q`` for a ``(..., 3)`` vector ``w``: ``(-w·u, q_w w + w × u)`` with ``q = (q_w, u)``.

    The quaternion rate ``q̇ = ½ (0, ω) ⊗ q`` without building ``(0, ω)`` (a
    zero stacked onto ``ω`` would be an unbatched constant under ``vmap``).
    """
    qw, u = q[..., 0], (q[..., 1], q[..., 2], q[..., 3])
    wv = _unstack(w)
    c = cross_components(wv, u)
    return jnp.stack([-(wv[0] * u[0] + wv[1] * u[1] + wv[2] * u[2])] + [qw * wv[i] + c[i] for i in range(3)], axis=-1)


def matvec3(A: Array, v: Array) -> Array:
    """``A v`` for ``(..., 3, 3)`` and ``(..., 3)``, by components (fuses under vmap)."""
    # single components only (see _unstack): rows of A dotted with v
    return jnp.stack(apply3(entries3(A), _unstack(v)), axis=-1)


def cross_components(a: tuple, b: tuple) -> tuple:
    """``a × b`` on 3-tuples of components (arrays or NumPy values alike)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


# The quaternion formulas below act on component tuples, so that one formula serves both
# these jnp functions and the NumPy ones of the host-side code (identification's data checks,
# the animation), which stack the same components with NumPy.
def hamilton(p: Iterable[Any], q: Iterable[Any]) -> tuple[Any, Any, Any, Any]:
    """Components of ``p ⊗ q`` from the components ``(w, x, y, z)`` of ``p`` and ``q`` (any array type)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


def rotate_components(q: tuple, v: tuple) -> tuple:
    """Components of ``q ⊗ (0, v) ⊗ q*`` from those of ``q = (w, u)`` and ``v``: ``v + w t + u × t``, ``t = 2 u × v``.

    A rotation for a unit ``q`` only (no check here; see :func:`quat_rotate`).
    """
    w, u = q[0], tuple(q[1:])
    t = tuple(2 * c for c in cross_components(u, v))
    ut = cross_components(u, t)
    return tuple(v[i] + w * t[i] + ut[i] for i in range(3))


def rotation_rows(q: Iterable[Any]) -> tuple[tuple[Any, Any, Any], ...]:
    """Rows of ``R(q) = (w² - u·u) 1 + 2 u uᵀ + 2 w ũ`` from the components ``(w, x, y, z)`` of a unit ``q``."""
    w, x, y, z = q
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return (
        (1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)),
        (2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)),
        (2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)),
    )


def quat_multiply(p: Float[ArrayLike, "... 4"], q: Float[ArrayLike, "... 4"]) -> Float[Array, "... 4"]:
    """Hamilton product ``p ⊗ q`` of ``(..., 4)`` quaternions ``[w, x, y, z]``.

    ``(pw, pv) ⊗ (qw, qv) = (pw qw - pv·qv, pw qv + qw pv + pv × qv)``.
    """
    p, q = array_arg("quat_multiply", "p", p, (4,)), array_arg("quat_multiply", "q", q, (4,))
    _batches("quat_multiply", p=(p, 1), q=(q, 1))
    return jnp.stack(hamilton(_unstack(p), _unstack(q)), axis=-1)


def quat_conjugate(q: Float[ArrayLike, "... 4"]) -> Float[Array, "... 4"]:
    """Conjugate ``q* = [w, -x, -y, -z]``; the inverse rotation for a unit ``q``.

    ``q``: ``(..., 4)``; returns ``(..., 4)``.
    """
    q = array_arg("quat_conjugate", "q", q, (4,))
    return jnp.stack([q[..., 0], -q[..., 1], -q[..., 2], -q[..., 3]], axis=-1)


def quat_rotate_unchecked(q: ArrayLike, v: ArrayLike) -> Array:
    """:func:`quat_rotate` without the unit-norm check (the steps rotate by RK4 stage values, off the sphere)."""
    q, v = array_arg("quat_rotate", "q", q, (4,)), array_arg("quat_rotate", "v", v, (3,))
    _batches("quat_rotate", q=(q, 1), v=(v, 1))
    return jnp.stack(rotate_components(_unstack(q), _unstack(v)), axis=-1)


def quat_rotate_inverse_unchecked(q: ArrayLike, v: ArrayLike) -> Array:
    """``R(q)ᵀ v = q* ⊗ (0, v) ⊗ q``: a world-frame ``(..., 3)`` vector in the body frame of ``q``.

    No unit-norm check (see :func:`quat_rotate_unchecked`); units of ``v``. Why
    through ``q*`` rather than the equal ``v - w t + u × t`` (``t = 2 u × v``),
    which needs no negations: XLA:CPU ran the explicit-Euler and RK4 steps built
    on that form slower, with the same fusions and fewer operations in them
    (benchmarks/results/ab_rotate_inverse_without_conjugate_2026-12-04.json).
    """
    return quat_rotate_unchecked(quat_conjugate(q), v)


def quat_rotate(q: Float[ArrayLike, "... 4"], v: Float[ArrayLike, "... 3"]) -> Float[Array, "... 3"]:
    """Rotate ``(..., 3)`` vectors by unit quaternions: ``q ⊗ (0, v) ⊗ q*``.

    Evaluated as ``v + w t + u × t`` with ``t = 2 u × v`` (``q = [w, u]``): 18
    multiplies, no rotation matrix. The formula is a rotation only for
    ``‖q‖ = 1``: a concrete ``q`` off the unit sphere by more than
    ``max(1e-6, 128 eps)`` raises ``ValueError`` (normalise it with
    :func:`quat_normalize`); under ``jit`` it is not checked. Frames: ``q``
    body to world takes body-frame ``v`` to the world frame; units of ``v``.
    """
    q = array_arg("quat_rotate", "q", q, (4,))
    check_unit_quaternions("quat_rotate", "q", q, _NORMALISE)
    return quat_rotate_unchecked(q, v)


def quat_normalize_unchecked(q: ArrayLike) -> Array:
    """:func:`quat_normalize` without the check for zero or non-finite ``q`` (the steps' projection)."""
    q = array_arg("quat_normalize", "q", q, (4,))
    # explicit components, not a reduce: a reduction ends an XLA:CPU loop fusion
    w, x, y, z = _unstack(q)
    inv = 1 / jnp.sqrt(w * w + x * x + y * y + z * z)
    return jnp.stack([w * inv, x * inv, y * inv, z * inv], axis=-1)


def quat_normalize(q: Float[ArrayLike, "... 4"]) -> Float[Array, "... 4"]:
    """``q / ‖q‖`` for ``(..., 4)`` quaternions ``[w, x, y, z]`` (finite gradient for ``q ≠ 0``).

    ``q = 0`` has no direction: a concrete ``q`` with a zero-norm or non-finite
    quaternion raises ``ValueError``; under ``jit`` it gives NaN there.
    Dimensionless; returns ``(..., 4)``.
    """
    q = array_arg("quat_normalize", "q", q, (4,))
    if is_concrete(q) and q.size:
        n = np.linalg.norm(np.asarray(q, np.float64), axis=-1)
        bad = ~(np.isfinite(n) & (n > 0))
        if np.any(bad):
            worst = n[first_index(bad)]
            why = "a zero quaternion has no direction" if worst == 0 else "non-finite entries"
            raise ValueError(f"quat_normalize: q must be finite and non-zero; ‖q‖ = {worst}{_first_bad(bad)} ({why})")
    return quat_normalize_unchecked(q)


def quat_to_matrix_unchecked(q: ArrayLike) -> Array:
    """:func:`quat_to_matrix` without the unit-norm check."""
    q = array_arg("quat_to_matrix", "q", q, (4,))
    return jnp.stack([jnp.stack(row, axis=-1) for row in rotation_rows(_unstack(q))], axis=-2)


def quat_to_matrix(q: Float[ArrayLike, "... 4"]) -> Float[Array, "... 3 3"]:
    """Rotation matrix ``R`` (body to world) of unit quaternions ``(..., 4)`` → ``(..., 3, 3)``.

    ``R = (w² - u·u) 1 + 2 u uᵀ + 2 w ũ``. Columns of ``R`` are the body axes
    expressed in the world frame, as in the notes. The formula (written with
    ``w² + u·u = 1``) is a rotation only for unit ``q``: a concrete ``q`` off the
    sphere by more than ``max(1e-6, 128 eps)`` raises ``ValueError``; under
    ``jit`` it is not checked.
    """
    q = array_arg("quat_to_matrix", "q", q, (4,))
    check_unit_quaternions("quat_to_matrix", "q", q, _NORMALISE)
    return quat_to_matrix_unchecked(q)


def matrix_to_quat_unchecked(R: ArrayLike) -> Array:
    """:func:`matrix_to_quat` without the rotation check (the package's own, nearly orthogonal ``R``)."""
    R = array_arg("matrix_to_quat", "R", R, (3, 3))
    r00, r01, r02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    r10, r11, r12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    r20, r21, r22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    tr = r00 + r11 + r22
    # 4 w² = 1 + tr, 4 x² = 1 + r00 - r11 - r22, ...
    four_sq = jnp.stack([1 + tr, 1 + r00 - r11 - r22, 1 - r00 + r11 - r22, 1 - r00 - r11 + r22], axis=-1)
    s = 2 * jnp.sqrt(jnp.maximum(four_sq, _eps(R)))  # s_k = 4 |q_k|
    cand = jnp.stack(
        [
            jnp.stack([s[..., 0] / 4, (r21 - r12) / s[..., 0], (r02 - r20) / s[..., 0], (r10 - r01) / s[..., 0]], -1),
            jnp.stack([(r21 - r12) / s[..., 1], s[..., 1] / 4, (r01 + r10) / s[..., 1], (r02 + r20) / s[..., 1]], -1),
            jnp.stack([(r02 - r20) / s[..., 2], (r01 + r10) / s[..., 2], s[..., 2] / 4, (r12 + r21) / s[..., 2]], -1),
            jnp.stack([(r10 - r01) / s[..., 3], (r02 + r20) / s[..., 3], (r12 + r21) / s[..., 3], s[..., 3] / 4], -1),
        ],
        axis=-2,
    )
    k = jnp.argmax(four_sq, axis=-1)
    q = jnp.take_along_axis(cand, k[..., None, None], axis=-2)[..., 0, :]
    q = jnp.where(q[..., :1] < 0, -q, q)
    return quat_normalize_unchecked(q)


def matrix_to_quat(R: Float[ArrayLike, "... 3 3"]) -> Float[Array, "... 4"]:
    """Unit quaternion ``[w, x, y, z]`` with ``w ≥ 0`` of rotation matrices ``(..., 3, 3)``.

    Shepperd's method: of the four candidate formulas, take the one whose
    divisor ``4·max(w², x², y², z²)`` is largest, so the result is accurate for
    every rotation, including half turns. The square roots of the unused
    candidates are clamped, so gradients carry no NaN from branches not taken.
    A concrete ``R`` that is not a proper rotation (``max |RᵀR - 1|`` beyond
    ``max(1e-6, 128 eps)``, or ``det R ≤ 0``) raises ``ValueError``: the formulas
    would return some unit quaternion, not the nearest rotation's. Project a
    near-rotation with :func:`orthonormalize` first. Under ``jit`` it is not
    checked. Frames: ``R`` body to world gives ``q`` body to world.
    """
    R = array_arg("matrix_to_quat", "R", R, (3, 3))
    check_rotations("matrix_to_quat", "R", R, "; project a near-rotation with rb.orthonormalize(R) first")
    return matrix_to_quat_unchecked(R)


def quat_exp(rotvec: Float[ArrayLike, "... 3"]) -> Float[Array, "... 4"]:
    """Exponential map: rotation vector ``θ n`` (radians) → unit quaternion.

        ``exp(θ n) = [cos(θ/2), sin(θ/2) n]``. Near ``θ = 0`` a Taylor series replaces
        ``sin(θ/2)/θ``, so the value and every gradient are finite at zero rotation.
    ``rotvec``: ``(..., 3)``; returns ``(..., 4)``.
    """
    v = array_arg("quat_exp", "rotvec", rotvec, (3,))
    th2 = dot3(v, v)[..., None]
    small = th2 < jnp.sqrt(_eps(v))
    th = jnp.sqrt(jnp.where(small, 1.0, th2))
    half_sinc = jnp.where(small, 0.5 - th2 / 48 + th2 * th2 / 3840, jnp.sin(th / 2) / th)
    cos_half = jnp.where(small, 1 - th2 / 8 + th2 * th2 / 384, jnp.cos(th / 2))
    s = half_sinc[..., 0]
    return jnp.stack([cos_half[..., 0], s * v[..., 0], s * v[..., 1], s * v[..., 2]], axis=-1)


def quat_log(q: Float[ArrayLike, "... 4"]) -> Float[Array, "... 3"]:
    """Logarithm: unit quaternion → rotation vector ``θ n`` with ``θ ∈ [0, π]``.

    ``q`` and ``-q`` give the same result (the shorter rotation). Finite
    gradients at the identity. ``q``: ``(..., 4)``; returns ``(..., 3)``.
    """
    q = array_arg("quat_log", "q", q, (4,))
    q = jnp.where(q[..., :1] < 0, -q, q)
    w, u = q[..., :1], q[..., 1:]
    return log_scale(w, safe_norm(u, keepdims=True), _eps(q), jnp) * u


def log_scale(w: Any, s: Any, eps: Any, xp: Any) -> Any:
    """``θ / s`` for a unit quaternion ``(w, s n)`` with ``w ≥ 0``, ``θ = 2 atan2(s, w)``: the factor
    taking its vector part to the rotation vector, for :func:`quat_log` and the NumPy twin of the
    host-side code (``xp`` is ``jnp`` or ``numpy``). Below ``s < √eps`` its series
    ``(2/w)(1 - s²/(3w²))`` avoids ``0/0``."""
    small = s < xp.sqrt(eps)
    s_safe, w_safe = xp.where(small, 1.0, s), xp.where(small, w, 1.0)  # w = 0 (θ = π) only where not small
    return xp.where(small, 2 / w_safe * (1 - s * s / (3 * w_safe * w_safe)), 2 * xp.arctan2(s_safe, w) / s_safe)


def quat_angle(p: Float[ArrayLike, "... 4"], q: Float[ArrayLike, "... 4"]) -> Float[Array, " ..."]:
    """Angle (radians, in ``[0, π]``) of the rotation taking ``p`` to ``q``.

        ``2 atan2(‖vec(p* ⊗ q)‖, |scal(p* ⊗ q)|)``; insensitive to the sign of either
        quaternion, accurate for small angles (unlike ``arccos``). ``p``, ``q``:
    ``(..., 4)``, broadcast; returns ``(...)``.
    """
    p, q = array_arg("quat_angle", "p", p, (4,)), array_arg("quat_angle", "q", q, (4,))
    _batches("quat_angle", p=(p, 1), q=(q, 1))
    d = quat_multiply(quat_conjugate(p), q)
    return 2 * jnp.arctan2(safe_norm(d[..., 1:]), jnp.abs(d[..., 0]))


def orthonormalize_unchecked(R: Array, iterations: int = 2) -> Array:
    """Newton–Schulz polar iterations ``R ← R (3·1 - RᵀR) / 2`` (the integrators' projection).

    Unchecked and unscaled: for the nearly orthogonal matrices of a step
    (``‖RᵀR - 1‖ ≪ 1``); :func:`orthonormalize` is the public, checked form.
    """
    eye = jnp.eye(3, dtype=R.dtype)
    for _ in range(iterations):
        RtR = matmul3(jnp.swapaxes(R, -1, -2), R)
        R = 0.5 * matmul3(R, 3 * eye - RtR)
    return R


def _det3(R: Array) -> Array:
    c = cross_components(_unstack(R[..., 1, :]), _unstack(R[..., 2, :]))
    return R[..., 0, 0] * c[0] + R[..., 0, 1] * c[1] + R[..., 0, 2] * c[2]


def orthonormalize(R: Float[ArrayLike, "... 3 3"], iterations: int = 2) -> Float[Array, "... 3 3"]:
    """Nearest rotation matrix (the polar factor) of ``R`` ``(..., 3, 3)``, a near-rotation up to a positive scale.

    ``R`` is first divided by ``∛det R``, so any positive multiple ``c Q``
    (``c > 0``) of a rotation ``Q`` returns ``Q``; then Newton–Schulz iterations
    for the polar factor, ``R ← R (3·1 - RᵀR) / 2``, converge quadratically:
    an ``R`` with ``‖RᵀR - 1‖ = ε`` (after the scaling) comes out with
    ``O(ε^(2^k))`` after ``k = iterations`` iterations. Unlike Gram–Schmidt it
    treats the three axes alike (no drift toward the first column).

    Range: ``det R > 0`` and, after the scaling, ``‖RᵀR - 1‖ < 1`` (singular
    values within ``(0, √2)``); more iterations for inputs farther off. A
    concrete ``R`` outside it, or one the ``iterations`` did not bring within
    ``max(1e-6, 128 eps)`` of orthogonal, raises ``ValueError``; under ``jit``
    an ``R`` with ``det R ≤ 0`` (a reflection: no nearest rotation in this
    sense) gives NaN. Dimensionless; returns ``(..., 3, 3)``.
    """
    R = array_arg("orthonormalize", "R", R, (3, 3))
    if isinstance(iterations, (bool, np.bool_)) or not isinstance(iterations, (int, np.integer)) or iterations < 0:
        raise ValueError(f"orthonormalize: iterations must be a non-negative int, got {iterations!r}")
    det = _det3(R)
    positive = det > 0
    scale = jnp.cbrt(jnp.where(positive, det, 1.0))
    out = orthonormalize_unchecked(R / scale[..., None, None], int(iterations))
    out = jnp.where(positive[..., None, None], out, jnp.nan)
    if not isinstance(out, jax.core.Tracer):
        _check_rotation_out(R, out, int(iterations))
    return out


def _check_rotation_out(R: Array, out: Array, iterations: int) -> None:
    """``ValueError`` unless ``orthonormalize`` produced rotations (concrete values only)."""
    if not (isinstance(out, jax.Array) and out.is_fully_addressable):
        return
    R64, Q = np.asarray(R, np.float64), np.asarray(out, np.float64)
    if Q.size == 0:
        return
    if not np.all(np.linalg.det(R64) > 0):
        raise ValueError(
            "orthonormalize: R must have det R > 0 (a rotation up to a positive scale and a small error); "
            f"got det R = {np.min(np.linalg.det(R64)):.3g}: a reflection or a singular matrix has no nearest "
            "rotation here"
        )
    err = np.max(np.abs(np.swapaxes(Q, -1, -2) @ Q - np.eye(3))) if np.all(np.isfinite(Q)) else np.inf
    tol = max(1e-6, 128 * float(np.finfo(R.dtype).eps))
    if not err <= tol:
        raise ValueError(
            f"orthonormalize: R is too far from a rotation for {iterations} iteration(s): the result is off "
            f"orthogonal by {err:.3g} (tolerance {tol:.3g}). Pass more iterations (valid while "
            "‖RᵀR/∛det(R)² - 1‖ < 1), or build the rotation another way (e.g. matrix_to_quat of an SVD's U Vᵀ)"
        )
