"""Mass properties of rigid bodies: ``Body`` and its constructors.

A body is its mass ``m`` (kg) and its inertia tensor ``I`` (kg m²), a symmetric
3x3 matrix in the body frame about the centre of mass. Its principal axes need
not be the body axes.
"""

from __future__ import annotations

from typing import Any, cast

import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from ._eigh3 import principal_frame
from ._math import array_arg, check_rotations, first_index, holds_text, is_concrete, skew
from ._pytree import field, new_unchecked, pytree_dataclass
from ._trajectory import BatchIndexing
from ._typing import ArrayLike, array_like

__all__ = [
    "Body",
    "box",
    "cylinder",
    "ellipsoid",
    "from_particles",
    "inverse_3x3",
    "parallel_axis",
    "rotate_inertia",
    "sphere",
    "symmetric_part",
    "TRIANGLE_RTOL",
]

#: Relative tolerance of the triangle inequality ``I1 + I2 ≥ I3 (1 - rtol)``
#: checked at construction. A flat plate meets it with equality, so round-off in
#: the eigenvalues (a few ulp of ``trace I``) must not fail it; 1e-6 is ~10 float32
#: epsilons and far below any physical violation.
TRIANGLE_RTOL = 1e-6


def as_float(x: ArrayLike) -> Array:
    if x is None or isinstance(x, (str, bytes, dict)):
        raise TypeError(f"rbjax expected a real number or array, got {type(x).__name__} {x!r}")
    if holds_text(x):  # before jnp.asarray reads a string as a dtype name (holds_text)
        raise TypeError(f"rbjax expected a real number or array, got a {type(x).__name__} holding text: {x!r:.80}")
    try:
        x = jnp.asarray(x)
    except TypeError:
        raise TypeError(f"rbjax expected a real number or array, got {type(x).__name__}: {x!r:.80}") from None
    if jnp.issubdtype(x.dtype, jnp.complexfloating):
        raise TypeError(f"expected real values, got dtype {x.dtype}")
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    elif jnp.finfo(x.dtype).bits < 32:
        # eigenvalues, unit quaternions and inertia checks need float32 at least
        raise TypeError(f"rbjax computes in float32 or float64; got dtype {x.dtype}: convert with .astype")
    return x


def floats(obj: Any, *names: str) -> None:
    """In ``__post_init__`` of a frozen pytree dataclass: the named fields as float arrays (``None`` stays).

    ``TypeError`` for values that are not real numbers, ``ValueError`` for
    concrete non-finite ones (a NaN parameter would make every step NaN).
    """
    for name in names:
        v = getattr(obj, name)
        if v is not None:
            object.__setattr__(obj, name, finite_float(type(obj).__name__, name, v))


def finite_float(owner: str, name: str, x: Any) -> Array:
    """``x`` as a float array; ``TypeError``/``ValueError`` naming ``owner: name`` unless it is
    real and (when concrete) finite."""
    try:
        a = as_float(x)
    except TypeError as e:
        raise TypeError(f"{owner}: {name}: {e}") from None
    if is_concrete(a) and not np.all(np.isfinite(np.asarray(a))):
        raise ValueError(f"{owner}: {name} must be finite, got non-finite entries")
    return a


def inverse_3x3(A: Float[ArrayLike, "... 3 3"]) -> Float[Array, "... 3 3"]:
    """Inverse of ``(..., 3, 3)`` matrices by the adjugate: ``A⁻¹ = adj(A) / det(A)``.

    Closed form (no pivoting, no LAPACK call), differentiable, and cheap under
    ``vmap``; meant for the well-conditioned inertia tensors checked by ``Body``.
    """
    A = jnp.asarray(A)
    c0 = jnp.cross(A[..., 1, :], A[..., 2, :])
    c1 = jnp.cross(A[..., 2, :], A[..., 0, :])
    c2 = jnp.cross(A[..., 0, :], A[..., 1, :])
    det = jnp.sum(A[..., 0, :] * c0, axis=-1)
    return jnp.stack([c0, c1, c2], axis=-1) / det[..., None, None]


def check_body(
    mass: ArrayLike, inertia: ArrayLike, owner: str = "Body", names: tuple[str, str] = ("mass", "inertia")
) -> None:
    """Raise ``ValueError`` unless concrete ``mass``, ``inertia`` describe valid rigid bodies.

    The one definition of a valid body: mass finite and ``> 0``; inertia finite,
    symmetric, positive definite and within the triangle inequality
    ``I1 + I2 ≥ I3``. ``Body(...)`` and :func:`rbjax.load` both call it;
    ``owner`` starts the message and ``names`` are what it calls the two arrays
    (a file's field names for ``load``).
    """
    m = np.asarray(mass)
    I = np.asarray(inertia)
    mass_name, inertia_name = names
    if I.shape[-2:] != (3, 3) or I.shape[:-2] != m.shape:
        raise ValueError(
            f"{owner}: {inertia_name} must have shape {mass_name}.shape + (3, 3) = {m.shape + (3, 3)}, got {I.shape}"
        )
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{owner}: {mass_name} must be finite, got {m[~np.isfinite(m)].ravel()[:3]}")
    if not np.all(np.isfinite(I)):
        raise ValueError(f"{owner}: {inertia_name} must be finite, got non-finite entries")
    if np.any(m <= 0):
        raise ValueError(f"{owner}: {mass_name} must be > 0, got {m[m <= 0].ravel()[:3]}")
    scale = np.max(np.abs(I), axis=(-1, -2))
    eps = np.finfo(I.dtype).eps
    asym = np.max(np.abs(I - np.swapaxes(I, -1, -2)), axis=(-1, -2))
    bad = asym > 64 * eps * scale
    if np.any(bad):
        idx = first_index(bad)
        raise ValueError(
            f"{owner}: {inertia_name} must be symmetric; |I - Iᵀ| = {asym[idx]:.3g}"
            + (f" at batch index {idx}" if idx else "")
        )
    moments = np.linalg.eigvalsh(0.5 * (I + np.swapaxes(I, -1, -2)))
    if np.any(moments[..., 0] <= 0):
        bad = np.atleast_2d(moments)[np.atleast_2d(moments)[:, 0] <= 0][0]
        raise ValueError(f"{owner}: {inertia_name} must be positive definite; principal moments {bad} include one <= 0")
    # sorted ascending: the binding inequality is I1 + I2 >= I3
    slack = moments[..., 0] + moments[..., 1] - moments[..., 2]
    if np.any(slack < -TRIANGLE_RTOL * np.sum(moments, axis=-1)):
        bad = np.atleast_2d(moments)[np.atleast_1d(slack < -TRIANGLE_RTOL * np.sum(moments, axis=-1))][0]
        raise ValueError(
            f"{owner}: {inertia_name}'s principal moments {bad} break the triangle inequality I1 + I2 >= I3 "
            f"(relative tolerance {TRIANGLE_RTOL}); no mass distribution has this inertia"
        )


def symmetric_part(A: Float[ArrayLike, "... 3 3"]) -> Float[Array, "... 3 3"]:
    """``½ (A + Aᵀ)`` of ``(..., 3, 3)`` matrices.

    The value of a symmetric ``A`` is unchanged; what changes is the derivative:
    a function that reads an inertia through this has a symmetric gradient with
    respect to it, so one gradient step keeps the inertia symmetric.
    """
    A = array_arg("symmetric_part", "A", A, (3, 3))
    return 0.5 * (A + jnp.swapaxes(A, -1, -2))


@pytree_dataclass
class Body(BatchIndexing):
    """Mass properties of one rigid body, or of a batch of them.

    Attributes:
        mass: ``(*B,)`` mass ``m`` in kg.
        inertia: ``(*B, 3, 3)`` inertia tensor ``I_L`` in kg m², body frame, about
            the centre of mass (stored as its symmetric part ``½ (I + Iᵀ)``).

    ``inverse_inertia`` (``I_L⁻¹``, ``(*B, 3, 3)``) is derived from ``inertia``,
    not a second pytree leaf: ``jax.grad`` with respect to a ``Body`` returns the
    total derivative in its ``inertia`` (symmetric, as rbjax reads the inertia
    through :func:`symmetric_part`), and a gradient step cannot leave a stale
    inverse behind. ``step`` and ``simulate`` compute the inverse once per call,
    outside the time loop.

    ``Body(mass, inertia)`` checks, outside ``jit`` (when values are concrete),
    that the mass is positive and finite and that the inertia is symmetric,
    positive definite and meets the triangle inequality of principal moments
    ``I1 + I2 ≥ I3`` (relative tolerance :data:`TRIANGLE_RTOL`), raising
    ``ValueError`` otherwise. Under tracing it checks shapes only.
    """

    mass: Float[Array, "*B"] = field(core_shape=(), converter=array_like)
    inertia: Float[Array, "*B 3 3"] = field(core_shape=(3, 3), converter=array_like)
    # Set only inside step/simulate (see `prepare`): the inverse computed once from
    # the symmetrised inertia, so the time loop never inverts. Never user-facing.
    _inverse: Float[Array, "*B 3 3"] | None = field(core_shape=(3, 3), default=None, init=False, repr=False)
    # Set only inside simulate, for the methods that turn about the principal axes
    # (see `prepare`): `principal_frame`'s moments, axes quaternion and split carrier.
    _moments: Float[Array, "*B 3"] | None = field(core_shape=(3,), default=None, init=False, repr=False)
    _axes: Float[Array, "*B 4"] | None = field(core_shape=(4,), default=None, init=False, repr=False)
    _split: Float[Array, "*B 3 3"] | None = field(core_shape=(3, 3), default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        mass = as_float(self.mass)
        inertia = as_float(self.inertia)
        dtype = jnp.result_type(mass, inertia)
        mass, inertia = mass.astype(dtype), inertia.astype(dtype)
        if inertia.shape[-2:] != (3, 3):
            raise ValueError(f"Body: inertia must end in (3, 3), got shape {inertia.shape}")
        if is_concrete(mass, inertia):
            check_body(mass, inertia)
        object.__setattr__(self, "mass", mass)
        object.__setattr__(self, "inertia", symmetric_part(inertia))

    @property
    def inverse_inertia(self) -> Float[Array, "*B 3 3"]:
        """``I_L⁻¹`` ``(*B, 3, 3)`` (kg⁻¹ m⁻², body frame), from the symmetric inertia."""
        if self._inverse is not None:
            return self._inverse
        return _inverse_symmetric(symmetric_part(self.inertia))

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading batch shape ``B`` (``()`` for a single body)."""
        return tuple(self.mass.shape)

    @property
    def dtype(self) -> Any:
        """Floating dtype of ``mass`` and ``inertia``."""
        return self.mass.dtype

    def principal(self) -> tuple[Float[Array, "*B 3"], Float[Array, "*B 3 3"]]:
        """Principal moments ``(*B, 3)`` (ascending) and axes ``(*B, 3, 3)``.

        ``I = P diag(moments) Pᵀ`` with the axes as columns of ``P`` (a proper
        rotation, ``det P = +1``). Uses ``eigh``, whose gradient is undefined at
        repeated moments: do not differentiate through it for symmetric bodies.
        """
        moments, axes = jnp.linalg.eigh(self.inertia)
        sign = jnp.sign(jnp.linalg.det(axes))
        return moments, axes * sign[..., None, None]


def prepare(body: Body, principal: bool = False) -> Body:
    """``body`` with its inertia symmetrised and its inverse computed, for a time loop;
    with ``principal``, its principal frame too (:func:`rbjax._eigh3.principal_frame`).

    Inside ``step`` and ``simulate`` every read of the inertia, its inverse and
    (for the methods that ask) its principal frame then costs nothing extra per
    step, and the derivative still flows through ``inertia`` alone. The frame
    is computed here, before the time loop, rather than left for the compiler
    to hoist out of it: XLA:CPU hoists the Jacobi sweeps' loop, but XLA:GPU
    (jaxlib 0.11.2 on an H200) kept it in the step's loop body and ran it every
    step, 3-4x the step's own cost (benchmarks/results/gpu_h200_2026-12-04.md, run 4).
    """
    if body._inverse is None:
        I = symmetric_part(body.inertia)
        body = new_unchecked(Body, mass=body.mass, inertia=I, _inverse=_inverse_symmetric(I))
    if principal and body._moments is None:
        moments, axes, split = principal_frame(body.inertia)
        fields = {f: getattr(body, f) for f in ("mass", "inertia", "_inverse")}
        body = new_unchecked(Body, **fields, _moments=moments, _axes=axes, _split=split)
    return body


def principal_frame_of(body: Body) -> tuple[Array, Array, Array]:
    """:func:`rbjax._eigh3.principal_frame` of ``body``'s inertia: moments ``(3,)``, axes
    quaternion ``(4,)`` and split carrier ``(3, 3)``, read from a body :func:`prepare`
    gave them to (it sets the three together), else computed (one body)."""
    if body._moments is not None:
        return body._moments, cast(Array, body._axes), cast(Array, body._split)
    return principal_frame(inertia_of(body))


def _inverse_symmetric(S: Array) -> Array:
    """``S⁻¹`` of symmetric ``(..., 3, 3)`` matrices from their six entries, by components.

    The adjugate written out: one fused pass under ``vmap``, where
    ``inverse_3x3``'s row slices and crosses run as several passes over the
    batch (docs/performance.md, "Measured reasons behind the code"). Reads the
    upper triangle only; callers symmetrise.
    """
    a00, a01, a02 = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    a11, a12, a22 = S[..., 1, 1], S[..., 1, 2], S[..., 2, 2]
    c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
    c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
    r = 1 / (a00 * c00 + a01 * c01 + a02 * c02)
    rows = [[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]
    return jnp.stack([jnp.stack([c * r for c in row], axis=-1) for row in rows], axis=-2)


def inertia_of(body: Body) -> Array:
    """``body.inertia`` read through :func:`symmetric_part` (free for a prepared body)."""
    return body.inertia if body._inverse is not None else symmetric_part(body.inertia)


def _size(fn: str, name: str, x: ArrayLike, *, vector: bool = False) -> Array:
    """A length argument of a shape constructor as a float array: ``ValueError``
    unless (when concrete) finite and > 0, and for ``vector`` ending in (3,)."""
    if isinstance(x, (bool, np.bool_)) or np.dtype(getattr(x, "dtype", None) or "f8") == np.bool_:
        raise TypeError(f"{fn}: {name} must be lengths in m (real numbers), got a bool")
    try:
        a = as_float(x)
    except TypeError as e:
        raise TypeError(f"{fn}: {name}: {e}") from None
    if vector and a.shape[-1:] != (3,):
        raise ValueError(f"{fn}: {name} must end in (3,) (one length per body axis x, y, z), got shape {a.shape}")
    if is_concrete(a):
        v = np.asarray(a)
        if not np.all(np.isfinite(v)) or np.any(v <= 0):
            bad = v[~(np.isfinite(v) & (v > 0))].ravel()[:3]
            raise ValueError(f"{fn}: {name} must be finite and > 0 (m), got {bad}")
    return a


def _diag(d0: Array, d1: Array, d2: Array) -> Array:
    d = jnp.stack(jnp.broadcast_arrays(d0, d1, d2), axis=-1)
    return d[..., :, None] * jnp.eye(3, dtype=d.dtype)


def box(mass: Float[ArrayLike, "*B"], size: Float[ArrayLike, "*B 3"]) -> Body:
    """Solid cuboid with full side lengths ``size = (a, b, c)`` along body x, y, z (m).

    ``I = m/12 · diag(b² + c², a² + c², a² + b²)``.
    """
    m, s = as_float(mass), _size("box", "size", size, vector=True)
    a2, b2, c2 = s[..., 0] ** 2, s[..., 1] ** 2, s[..., 2] ** 2
    return Body(m, (m / 12)[..., None, None] * _diag(b2 + c2, a2 + c2, a2 + b2))


def sphere(mass: Float[ArrayLike, "*B"], radius: Float[ArrayLike, "*B"]) -> Body:
    """Solid sphere of ``radius`` (m): ``I = 2/5 m r² · 1``.

    ``mass`` (kg) and ``radius`` broadcast to the batch shape ``B`` of the body.
    """
    m, r = as_float(mass), _size("sphere", "radius", radius)
    i = 0.4 * m * r**2
    return Body(m, _diag(i, i, i))


def cylinder(mass: Float[ArrayLike, "*B"], radius: Float[ArrayLike, "*B"], length: Float[ArrayLike, "*B"]) -> Body:
    """Solid cylinder with its axis along body z.

    ``Izz = m r²/2``, ``Ixx = Iyy = m (3 r² + l²)/12``.
    """
    m, r, l = as_float(mass), _size("cylinder", "radius", radius), _size("cylinder", "length", length)
    t = m * (3 * r**2 + l**2) / 12
    return Body(m, _diag(t, t, 0.5 * m * r**2))


def ellipsoid(mass: Float[ArrayLike, "*B"], semi_axes: Float[ArrayLike, "*B 3"]) -> Body:
    """Solid ellipsoid with semi-axes ``(a, b, c)`` along body x, y, z (m).

    ``I = m/5 · diag(b² + c², a² + c², a² + b²)``.
    """
    m, s = as_float(mass), _size("ellipsoid", "semi_axes", semi_axes, vector=True)
    a2, b2, c2 = s[..., 0] ** 2, s[..., 1] ** 2, s[..., 2] ** 2
    return Body(m, (m / 5)[..., None, None] * _diag(b2 + c2, a2 + c2, a2 + b2))


def particle_inertia(
    masses: Float[ArrayLike, "*B P"], points: Float[ArrayLike, "*B P 3"]
) -> tuple[Float[Array, "*B"], Float[Array, "*B 3"], Float[Array, "*B 3 3"]]:
    """Mass, centre of mass and inertia of point masses, without validation.

    ``masses``: ``(P,)``; ``points``: ``(P, 3)``. Returns ``M = Σ m_i``,
    ``c = Σ m_i p_i / M`` and ``I = -Σ m_i r̃_i r̃_i`` with ``r_i = p_i - c``
    (the notes' formula), about the centre of mass.
    """
    m, p = as_float(masses), as_float(points)
    total = jnp.sum(m, axis=-1)
    com = jnp.sum(m[..., None] * p, axis=-2) / total[..., None]
    rt = skew(p - com[..., None, :])
    inertia = -jnp.sum(m[..., None, None] * (rt @ rt), axis=-3)
    return total, com, inertia


def from_particles(masses: Float[ArrayLike, " P"], points: Float[ArrayLike, "P 3"]) -> tuple[Body, Float[Array, " 3"]]:
    """Rigid body made of point masses; returns ``(body, centre_of_mass)``.

    ``masses``: ``(P,)`` kg; ``points``: ``(P, 3)`` m, in the body frame. The
    inertia is ``I = -Σ m_i r̃_i r̃_i`` with ``r_i = p_i - c`` about the centre of
    mass ``c = Σ m_i p_i / Σ m_i``, as derived in the notes from
    ``L = Σ r_i × m_i (ω × r_i)``. Collinear points give a singular inertia and
    raise ``ValueError``.
    """
    m = array_arg("from_particles", "masses", masses)
    p = array_arg("from_particles", "points", points, (3,))
    if m.shape[-1:] != p.shape[-2:-1] or p.ndim < 2:
        raise ValueError(
            f"from_particles: masses (P,) and points (P, 3) must name the same particles, got masses of shape "
            f"{tuple(m.shape)} and points of shape {tuple(p.shape)}"
        )
    if is_concrete(m) and np.any(np.asarray(m) <= 0):
        raise ValueError(f"from_particles: every particle mass must be > 0, got {np.asarray(m)}")
    total, com, inertia = particle_inertia(m, p)
    return Body(total, inertia), com


def parallel_axis(
    inertia: Float[ArrayLike, "... 3 3"], mass: Float[ArrayLike, " ..."], offset: Float[ArrayLike, "... 3"]
) -> Float[Array, "... 3 3"]:
    """Inertia about a point displaced by ``offset`` from the centre of mass.

    ``I_p = I_c + m (‖d‖² 1 - d dᵀ)``, all in the same frame (Steiner's theorem).
    ``inertia``: ``(..., 3, 3)`` (kg m², about the centre of mass), ``mass``: ``(...)``
    (kg, > 0: the body's), ``offset``: ``(..., 3)`` (m). A concrete ``mass ≤ 0`` raises
    ``ValueError``; to take a part (a hole) away, subtract its own ``parallel_axis``.
    """
    I = array_arg("parallel_axis", "inertia", inertia, (3, 3))
    m, d = array_arg("parallel_axis", "mass", mass), array_arg("parallel_axis", "offset", offset, (3,))
    if is_concrete(m) and not np.all(np.asarray(m) > 0):
        raise ValueError(
            f"parallel_axis: mass must be > 0 (kg, the body's), got {np.asarray(m).min():.4g}; to take a part "
            "away (a hole), subtract its own parallel_axis result"
        )
    try:
        jnp.broadcast_shapes(I.shape[:-2], m.shape, d.shape[:-1])
    except ValueError:
        raise ValueError(
            f"parallel_axis: the batch shapes of inertia {I.shape[:-2]}, mass {m.shape} and offset "
            f"{d.shape[:-1]} do not broadcast"
        ) from None
    dd = jnp.sum(d * d, axis=-1)[..., None, None] * jnp.eye(3, dtype=d.dtype)
    return I + m[..., None, None] * (dd - d[..., :, None] * d[..., None, :])


def rotate_inertia(
    inertia: Float[ArrayLike, "... 3 3"], rotation: Float[ArrayLike, "... 3 3"]
) -> Float[Array, "... 3 3"]:
    """Express an inertia tensor in a rotated frame: ``I' = R I Rᵀ``.

    With ``R`` body to world this is the notes' world inertia ``I_w = R I_L R⁻¹``
    (kg m², in the frame ``R`` maps into). ``inertia``, ``rotation``: ``(..., 3, 3)``,
    broadcast against each other. ``Rᵀ`` stands for ``R⁻¹``, so ``R`` must be
    orthogonal: a concrete ``R`` with ``max |RᵀR - 1|`` beyond ``max(1e-6, 128 eps)``
    raises ``ValueError`` (a reflection, ``det R = -1``, is allowed: the inertia of
    the mirrored body); under ``jit`` it is not checked.
    """
    I = array_arg("rotate_inertia", "inertia", inertia, (3, 3))
    R = array_arg("rotate_inertia", "rotation", rotation, (3, 3))
    check_rotations("rotate_inertia", "rotation", R, "; project a near-rotation with rb.orthonormalize", proper=False)
    try:
        jnp.broadcast_shapes(I.shape[:-2], R.shape[:-2])
    except ValueError:
        raise ValueError(
            f"rotate_inertia: the batch shapes of inertia {I.shape[:-2]} and rotation {R.shape[:-2]} do not broadcast"
        ) from None
    return R @ I @ jnp.swapaxes(R, -1, -2)
