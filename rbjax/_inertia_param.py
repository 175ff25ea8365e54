"""Unconstrained parameters for physically consistent inertia tensors.

Every rigid body's inertia about its centre of mass is
``I = tr(Σ) 1 - Σ`` with ``Σ = ∫ r rᵀ dm`` the (positive semi-definite)
second-moment matrix; conversely ``Σ = ½ tr(I) 1 - I``. ``I`` is physically
consistent (positive definite and meeting the triangle inequalities
``Ij + Ik ≥ Ii``) exactly when ``Σ`` is positive semi-definite, and strictly so
when ``Σ`` is positive definite. Writing ``Σ = L Lᵀ`` with ``L`` lower triangular
and ``L_ii = exp(θ_i)`` (log-Cholesky; Rucker & Wensing, "Smooth Parameterization
of Rigid-Body Inertia", IEEE RA-L 2022) makes every ``θ ∈ ℝ⁶`` a valid inertia and
every valid inertia reachable exactly once: an unconstrained, smooth
parametrisation for gradient-based fitting.

Parameter order: ``θ = (log L00, log L11, log L22, L10, L20, L21)``. Units: ``L``
in ``√(kg) m``, so ``I`` in kg m².
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import Float

from ._body import TRIANGLE_RTOL
from ._math import array_arg, is_concrete
from ._typing import ArrayLike

__all__ = ["inertia_from_params", "params_from_inertia", "second_moment"]


def _lower(theta: Array) -> Array:
    z = jnp.zeros_like(theta[..., 0])
    d0, d1, d2 = jnp.exp(theta[..., 0]), jnp.exp(theta[..., 1]), jnp.exp(theta[..., 2])
    l10, l20, l21 = theta[..., 3], theta[..., 4], theta[..., 5]
    return jnp.stack([jnp.stack([d0, z, z], -1), jnp.stack([l10, d1, z], -1), jnp.stack([l20, l21, d2], -1)], -2)


def inertia_from_params(theta: Float[ArrayLike, "... 6"]) -> Float[Array, "... 3 3"]:
    """Inertia tensor ``(..., 3, 3)`` (body frame, kg m²) from log-Cholesky ``θ`` ``(..., 6)``.

    ``L = [[e^θ0, 0, 0], [θ3, e^θ1, 0], [θ4, θ5, e^θ2]]``, ``Σ = L Lᵀ``,
    ``I = tr(Σ) 1 - Σ``. Always symmetric positive definite with strict triangle
    inequalities (for finite ``θ``); smooth, so gradients flow to ``θ``.
    """
    theta = array_arg("inertia_from_params", "theta", theta, (6,))
    L = _lower(theta)
    sigma = L @ jnp.swapaxes(L, -1, -2)
    tr = jnp.trace(sigma, axis1=-2, axis2=-1)
    return tr[..., None, None] * jnp.eye(3, dtype=sigma.dtype) - sigma


def second_moment(inertia: Float[ArrayLike, "... 3 3"]) -> Float[Array, "... 3 3"]:
    """Second-moment matrix ``Σ = ½ tr(I) 1 - I`` ``(..., 3, 3)`` of an inertia tensor."""
    I = array_arg("second_moment", "inertia", inertia, (3, 3))
    tr = jnp.trace(I, axis1=-2, axis2=-1)
    return 0.5 * tr[..., None, None] * jnp.eye(3, dtype=I.dtype) - I


def params_from_inertia(inertia: Float[ArrayLike, "... 3 3"], rtol: float = TRIANGLE_RTOL) -> Float[Array, "... 6"]:
    """Log-Cholesky parameters ``θ`` ``(..., 6)`` of a physically consistent inertia ``(..., 3, 3)``.

    Inverse of :func:`inertia_from_params`: ``Σ = ½ tr(I) 1 - I = L Lᵀ``
    (Cholesky), ``θ = (log diag L, L10, L20, L21)``; ``I`` in kg m², body frame.

    On the boundary of consistent inertias (``Σ`` singular: ``I1 + I2 = I3``,
    a flat plate, which :class:`rbjax.Body` accepts) ``log L_ii`` would be
    ``-∞``. Each Cholesky pivot is therefore floored at ``16 eps · tr I``, the
    level of its rounding error: the parameters and their gradients stay
    finite, ``inertia_from_params(θ)`` moves a boundary inertia inside by that
    much, and interior inertias round-trip as before. Pivots down to
    ``-rtol · tr I`` (the triangle tolerance :class:`rbjax.Body` accepts,
    :data:`rbjax.TRIANGLE_RTOL`) are floored too. A concrete inertia that breaks
    the triangle inequality by more raises ``ValueError``; a traced one gives NaN.
    """
    I = array_arg("params_from_inertia", "inertia", inertia, (3, 3))
    S = second_moment(0.5 * (I + jnp.swapaxes(I, -1, -2)))
    tr = jnp.trace(I, axis1=-2, axis2=-1)
    floor, worst = 16 * jnp.finfo(I.dtype).eps * tr, -rtol * tr
    if is_concrete(I):
        moments = np.linalg.eigvalsh(np.asarray(S, dtype=np.float64))
        bad = moments[..., 0] < -rtol * np.asarray(np.trace(np.asarray(I), axis1=-2, axis2=-1))
        if np.any(bad):
            raise ValueError(
                "params_from_inertia: the inertia breaks the triangle inequality I1 + I2 >= I3 "
                f"(second-moment eigenvalues {np.atleast_2d(moments)[np.atleast_1d(bad)][0]}); no mass "
                "distribution has it. Check it with rbjax.Body first."
            )
    # Cholesky of the 3x3 by hand, each pivot floored (jnp.linalg.cholesky gives NaN at a zero
    # pivot); a pivot below -rtol tr I is an impossible inertia: NaN, never a silent other one
    s = lambda i, j: S[..., i, j]
    root = lambda d: jnp.sqrt(jnp.where(d < worst, jnp.nan, jnp.maximum(d, floor)))
    l00 = root(s(0, 0))
    l10, l20 = s(1, 0) / l00, s(2, 0) / l00
    l11 = root(s(1, 1) - l10**2)
    l21 = (s(2, 1) - l20 * l10) / l11
    l22 = root(s(2, 2) - l20**2 - l21**2)
    return jnp.stack([jnp.log(l00), jnp.log(l11), jnp.log(l22), l10, l20, l21], axis=-1)
