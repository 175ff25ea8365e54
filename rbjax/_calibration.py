"""Calibrating a thrown device with a flywheel, then weighing objects on it: its ``J``, inertia and centre of mass.

A thrown IMU with a flywheel of unknown axial inertia ``J`` is fitted in units of ``J``
(:func:`rbjax.fit_inertia` without ``rotor_inertia``). Two throws, the device alone and
with a proof body of known mass and inertia bolted on, fix ``J``: the proof adds a known
inertia, and ``J`` is the scale at which the two fits differ by it. The device's inertia
and centre of mass follow, and with them the inertia of any object thrown on the device,
about the object's own centre of mass, the device and the parallel-axis terms removed.

Frames and points: everything is in the IMU's (gyro's) body frame, the frame of the fits,
and every position is relative to the IMU's accelerometer, which is where the fits'
``lever_arm`` (the IMU seen from the centre of mass) puts it: a centre of mass is at
``c = -lever_arm``. σ is first order: the Jacobian (``jax.jacfwd``) of the whole
calibration map applied to the fits' covariances.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jaxtyping import ArrayLike, Float

from ._body import parallel_axis
from ._math import is_concrete
from ._pytree import field, pytree_dataclass
from .identification._result import FitResult
from .identification._tails import chi2_sf

__all__ = ["DeviceCalibration", "ObjectInertia", "calibrate_device", "object_inertia"]

# (I_xx, I_yy, I_zz, I_xy, I_xz, I_yz): FitResult.inertia_covariance's order
_ROWS, _COLS = np.array([0, 1, 2, 0, 0, 1]), np.array([0, 1, 2, 1, 2, 2])
_FULL = np.array([[0, 3, 4], [3, 1, 5], [4, 5, 2]])  # the (3, 3) tensor's entries from the six
_J_UNITS, _KG = "rotor inertia J", "kg m^2"


def _vec6(inertia: Array) -> Array:
    return inertia[..., _ROWS, _COLS]


def _mat(v: Array) -> Array:
    return v[_FULL]


def _steiner(mass: float, offset: Array) -> Array:
    """``m (|d|² 1 - d dᵀ)``: the parallel-axis term alone (``rb.parallel_axis`` of a point mass)."""
    return parallel_axis(jnp.zeros((3, 3), offset.dtype), jnp.asarray(mass, offset.dtype), offset)


def _std3(cov6: np.ndarray) -> np.ndarray:
    """``(3, 3)`` σ of each entry of a symmetric tensor from the covariance of its six entries."""
    return np.sqrt(np.clip(np.diag(cov6), 0.0, None))[_FULL]


def _moments(inertia: np.ndarray, cov6: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ascending principal moments, their axes (columns) and σ (first order: ``aᵀ C a``)."""
    lam, vecs = np.linalg.eigh(inertia)
    v = vecs.T  # rows: the axes
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    a = np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z], -1)
    return lam, vecs, np.sqrt(np.clip(np.einsum("ki,ij,kj->k", a, cov6, a), 0.0, None))


def _propagate(
    fn: Callable[[Array], Array], x: np.ndarray, cov: np.ndarray, dtype: Any
) -> tuple[np.ndarray, np.ndarray]:
    """``fn(x)`` and its first-order covariance ``D C Dᵀ`` (``D = ∂fn/∂x`` by ``jax.jacfwd``)."""
    y, D = jax.jit(lambda x: (fn(x), jax.jacfwd(fn)(x)))(jnp.asarray(x, dtype))
    y, D = np.asarray(y, np.float64), np.asarray(D, np.float64)
    return y, D @ cov @ D.T


def _fit_arg(fn: str, name: str, fit: Any, units: tuple[str, ...], how: str) -> tuple[np.ndarray, np.ndarray]:
    """The fit's inertia entries ``(6,)`` and their covariance ``(6, 6)``, or an error naming ``name``."""
    if not isinstance(fit, FitResult):
        raise TypeError(f"{fn}: {name} must be a FitResult of rb.fit_inertia, got {type(fit).__name__}")
    if np.ndim(fit.inertia) != 2:
        raise ValueError(
            f"{fn}: {name} must be one fit (inertia (3, 3)), got a batch of inertias {np.shape(fit.inertia)}; "
            f"pass one recording's: jax.tree.map(lambda x: x[i], fits) (or fit with joint=True)"
        )
    if bool(np.asarray(fit.failed)):
        raise ValueError(f"{fn}: {name} is a fit that failed: {fit.member_errors or 'see its fit'}")
    if fit.inertia_units not in units:
        raise ValueError(f"{fn}: {name} must be fitted {how}; got a fit in units {fit.inertia_units!r}")
    cov = np.asarray(fit.inertia_covariance, np.float64)
    if not np.all(np.isfinite(cov)):
        raise ValueError(
            f"{fn}: {name}.inertia_covariance is not finite (a direction of the inertia the throw does not "
            f"determine, or a fit on the edge of physical inertias): throw it again, tumbling about all three axes"
        )
    return np.asarray(_vec6(jnp.asarray(fit.inertia)), np.float64), cov


def _lever(fn: str, name: str, fit: FitResult, instead: str) -> tuple[np.ndarray, np.ndarray]:
    r, s = np.asarray(fit.lever_arm, np.float64), np.asarray(fit.lever_arm_std, np.float64)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(s))):
        raise ValueError(
            f"{fn}: {name} has no lever arm (it was fitted without accelerations=, or its σ is not finite): "
            f"fit it with the accelerometer's readings, or give {instead}"
        )
    return r, s**2


def _mass(fn: str, name: str, m: Any) -> float:
    if isinstance(m, (str, bytes, bool, np.bool_)) or m is None:
        raise TypeError(f"{fn}: {name} must be a number (kg), got {type(m).__name__} {m!r:.40}")
    try:
        v = np.asarray(m, np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{fn}: {name} must be a number (kg), got {type(m).__name__} {m!r:.40}") from None
    if v.shape != () or not np.isfinite(v) or v <= 0:
        raise ValueError(f"{fn}: {name} must be one finite mass > 0 (kg), got {m!r:.40}")
    return float(v)


def _array(fn: str, name: str, x: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    if isinstance(x, (str, bytes, bool, np.bool_)) or x is None:
        raise TypeError(f"{fn}: {name} must be real numbers ({what}), got {type(x).__name__} {x!r:.40}")
    try:
        a = np.asarray(x, np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{fn}: {name} must be real numbers ({what}), got {type(x).__name__} {x!r:.40}") from None
    if a.shape != shape:
        raise ValueError(f"{fn}: {name} must have shape {shape} ({what}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{fn}: {name} must be finite ({what})")
    return a


def _pm(value: Any, std: Any, digits: int = 4) -> str:
    """``"[a ± sa, b ± sb, ...]"`` (or ``"a ± sa"``) of concrete arrays."""
    v, e = np.atleast_1d(np.asarray(value)), np.atleast_1d(np.asarray(std))
    parts = [f"{a:.{digits}g} ± {b:.2g}" for a, b in zip(v.ravel(), e.ravel(), strict=True)]
    return parts[0] if np.ndim(value) == 0 else "[" + ", ".join(parts) + "]"


@pytree_dataclass
class DeviceCalibration:
    """The calibrated device (:func:`calibrate_device`): its flywheel's ``J``, inertia and centre of mass.

    Attributes:
        rotor_inertia: the flywheel's axial inertia ``J`` (kg m²).
        rotor_inertia_std: its one-sigma uncertainty (kg m²).
        inertia: ``(3, 3)`` the device's inertia about its own centre of mass, IMU (body) frame
            (kg m², the flywheel included as a rigid mass: what :func:`rbjax.fit_inertia` fits).
        inertia_covariance: ``(6, 6)`` covariance of its entries ``(I_xx, I_yy, I_zz, I_xy, I_xz,
            I_yz)`` ((kg m²)², as :class:`rbjax.FitResult`'s ``inertia_covariance``).
        inertia_std: ``(3, 3)`` one-sigma uncertainty of each entry of ``inertia`` (kg m²).
        principal_moments: ``(3,)`` ascending eigenvalues of ``inertia`` (kg m²).
        moment_std: ``(3,)`` their one-sigma uncertainty (kg m², first order).
        centre_of_mass: ``(3,)`` the device's centre of mass relative to the IMU's accelerometer,
            IMU frame (m): ``-alone.lever_arm``, or ``device_centre_of_mass`` as given.
        centre_of_mass_std: ``(3,)`` its one-sigma uncertainty (m); 0 when given.
        mass: the device's mass (kg), as given.
        proof_position: ``(3,)`` the proof body's centre of mass relative to the IMU (m): as given,
            or from the two fits' lever arms.
        proof_position_std: ``(3,)`` its one-sigma uncertainty (m); 0 when given.
        covariance: ``(10, 10)`` the joint covariance of ``(J, I_xx, I_yy, I_zz, I_xy, I_xz, I_yz,
            c_x, c_y, c_z)`` (``c`` the centre of mass): ``J``, the inertia and the centre of mass
            come from the same fits, so they are correlated; :func:`object_inertia` uses it.
        consistency_chi2: ``χ²`` of the six entries of ``B - A`` (the two fits, in units of ``J``)
            against ``ΔI / J``, weighted by their covariance: ≈ 5 (its degrees of freedom) when the
            proof adds the inertia its given mass, inertia and position say.
        consistency_pvalue: ``P(χ²(5) ≥ consistency_chi2)``: below 1e-3 the proof body's numbers (its
            inertia's frame, its position, a mass) or one of the throws disagree with the model.
    """

    rotor_inertia: Float[Array, ""] = field()
    rotor_inertia_std: Float[Array, ""] = field()
    inertia: Float[Array, "3 3"] = field(core_ndim=2)
    inertia_covariance: Float[Array, "6 6"] = field(core_ndim=2)
    inertia_std: Float[Array, "3 3"] = field(core_ndim=2)
    principal_moments: Float[Array, " 3"] = field(core_ndim=1)
    moment_std: Float[Array, " 3"] = field(core_ndim=1)
    centre_of_mass: Float[Array, " 3"] = field(core_ndim=1)
    centre_of_mass_std: Float[Array, " 3"] = field(core_ndim=1)
    mass: Float[Array, ""] = field()
    proof_position: Float[Array, " 3"] = field(core_ndim=1)
    proof_position_std: Float[Array, " 3"] = field(core_ndim=1)
    covariance: Float[Array, "10 10"] = field(core_ndim=2)
    consistency_chi2: Float[Array, ""] = field()
    consistency_pvalue: Float[Array, ""] = field()

    def __repr__(self) -> str:
        if np.ndim(self.inertia) != 2 or not is_concrete(self.inertia):
            return f"DeviceCalibration(inertia={getattr(self.inertia, 'shape', '?')}, ...)"
        return (
            f"DeviceCalibration(rotor_inertia={_pm(self.rotor_inertia, self.rotor_inertia_std)} kg m^2, "
            f"principal_moments={_pm(self.principal_moments, self.moment_std)} kg m^2, "
            f"centre_of_mass={_pm(self.centre_of_mass, self.centre_of_mass_std, 3)} m, "
            f"consistency_pvalue={float(self.consistency_pvalue):.2g})"
        )


@pytree_dataclass
class ObjectInertia:
    """An object's inertia about its own centre of mass (:func:`object_inertia`), with σ.

    Attributes:
        inertia: ``(3, 3)`` the object's inertia about its centre of mass, IMU (body) frame
            axes (kg m²).
        inertia_covariance: ``(6, 6)`` covariance of its entries ``(I_xx, I_yy, I_zz, I_xy, I_xz,
            I_yz)`` ((kg m²)²): the object fit's, the device calibration's (``J``, the device's
            inertia and centre of mass) and the lever arm's, to first order.
        inertia_std: ``(3, 3)`` one-sigma uncertainty of each entry (kg m²).
        principal_moments: ``(3,)`` ascending eigenvalues of ``inertia`` (kg m²).
        principal_axes: ``(3, 3)`` columns are the principal axes (IMU frame).
        moment_std: ``(3,)`` one-sigma uncertainty of ``principal_moments`` (kg m², first order).
        centre_of_mass: ``(3,)`` the object's centre of mass relative to the IMU, IMU frame (m).
        centre_of_mass_std: ``(3,)`` its one-sigma uncertainty (m); 0 when given.
        mass: the object's mass (kg), as given.
    """

    inertia: Float[Array, "3 3"] = field(core_ndim=2)
    inertia_covariance: Float[Array, "6 6"] = field(core_ndim=2)
    inertia_std: Float[Array, "3 3"] = field(core_ndim=2)
    principal_moments: Float[Array, " 3"] = field(core_ndim=1)
    principal_axes: Float[Array, "3 3"] = field(core_ndim=2)
    moment_std: Float[Array, " 3"] = field(core_ndim=1)
    centre_of_mass: Float[Array, " 3"] = field(core_ndim=1)
    centre_of_mass_std: Float[Array, " 3"] = field(core_ndim=1)
    mass: Float[Array, ""] = field()

    def __repr__(self) -> str:
        if np.ndim(self.inertia) != 2 or not is_concrete(self.inertia):
            return f"ObjectInertia(inertia={getattr(self.inertia, 'shape', '?')}, ...)"
        return (
            f"ObjectInertia(principal_moments={_pm(self.principal_moments, self.moment_std)} kg m^2, "
            f"centre_of_mass={_pm(self.centre_of_mass, self.centre_of_mass_std, 3)} m, mass={float(self.mass):.4g} kg)"
        )


def calibrate_device(
    alone: FitResult,
    with_proof: FitResult,
    *,
    device_mass: float,
    proof_mass: float,
    proof_inertia: Float[ArrayLike, "3 3"],
    proof_position: Float[ArrayLike, " 3"] | None = None,
    device_centre_of_mass: Float[ArrayLike, " 3"] | None = None,
) -> DeviceCalibration:
    """A thrown device's flywheel inertia ``J``, inertia and centre of mass, from two fits in units of ``J``.

    ``alone`` and ``with_proof`` are :func:`rbjax.fit_inertia` results of throws of the device
    alone and with a proof body of known mass and inertia fixed to it, both fitted with the
    flywheel's rates and axis but without ``rotor_inertia`` (``inertia_units == "rotor inertia
    J"``): ``A = I_d / J`` and ``B = I_c / J``. Several throws of each, fitted together
    (``fit_inertia(..., joint=True)``: one inertia, one lever arm), make each fit and so ``J`` tighter.
    Everything is in the IMU (body) frame, positions
    relative to the IMU's accelerometer (m). With the device's centre of mass ``c_d`` (mass
    ``m_d``), the proof's ``p`` (mass ``m_p``, inertia ``I_p`` about its own centre of mass) and
    the combination's ``c = (m_d c_d + m_p p) / (m_d + m_p)``, Steiner's theorem
    (:func:`rbjax.parallel_axis`) gives the combination's inertia about ``c``:

        I_c = I_d + m_d S(c_d - c) + I_p + m_p S(p - c),   S(d) = |d|² 1 - d dᵀ,

    so ``I_c - I_d = ΔI`` is known, and ``(B - A) = ΔI / J`` holds for each of the six entries.
    ``1 / J`` is their generalised least-squares slope, ``1/J = ΔIᵀ W (B - A) / ΔIᵀ W ΔI``, with
    ``W`` the inverse covariance of ``B - A - ΔI / J`` (the fits' covariances, and the lever arms'
    through ``ΔI``); then ``I_d = J A``. Centres of mass: ``c_d = -alone.lever_arm`` (the fits'
    lever arm is the IMU seen from the centre of mass) unless ``device_centre_of_mass`` is given;
    ``p = ((m_d + m_p) c_w - m_d c_d) / m_p`` with ``c_w = -with_proof.lever_arm`` unless
    ``proof_position`` is given. Without accelerometer data (no lever arms) both must be given.

    σ: first order, the Jacobian of this whole map (``jax.jacfwd``) applied to the fits'
    ``inertia_covariance`` and ``lever_arm_std`` (the two fits independent; within a fit, the
    lever arm taken as independent of the inertia, whose cross-covariance ``FitResult`` does not
    carry). The σ are only as good as the fits' (check each fit's ``converged``).

    Args:
        alone: the fit of a throw of the device alone, in units of ``J``.
        with_proof: the fit of a throw of the device with the proof body, in units of ``J``.
        device_mass: the device's mass ``m_d`` (kg, > 0), weighed.
        proof_mass: the proof body's mass ``m_p`` (kg, > 0).
        proof_inertia: ``(3, 3)`` the proof body's inertia about its own centre of mass, in the
            IMU frame (kg m²; turn a tabulated one with :func:`rbjax.rotate_inertia`).
        proof_position: ``(3,)`` the proof body's centre of mass relative to the IMU, IMU frame
            (m), e.g. from a jig; default: from the two fits' lever arms.
        device_centre_of_mass: ``(3,)`` the device's centre of mass relative to the IMU, IMU frame
            (m); default: ``-alone.lever_arm``.

    Returns:
        A :class:`DeviceCalibration`.

    Raises:
        TypeError: a fit that is not a ``FitResult``; a mass, inertia or position that is not numbers.
        ValueError: a batch of fits; a failed fit; a fit not in units of ``J`` (fitted with
            ``rotor_inertia``, or without a rotor); a covariance that is not finite; a lever arm
            needed and missing; a mass ``≤ 0``; an inertia not symmetric positive definite; a
            proof body whose ``ΔI`` the fits do not see (``1/J ≤ 0``).
    """
    fn = "calibrate_device"
    how = (
        'with rotor_rates and rotor_axis but without rotor_inertia (inertia_units "rotor inertia J": J is what '
        "the calibration finds)"
    )
    A, C_A = _fit_arg(fn, "alone", alone, (_J_UNITS,), how)
    B, C_B = _fit_arg(fn, "with_proof", with_proof, (_J_UNITS,), how)
    m_d, m_p = _mass(fn, "device_mass", device_mass), _mass(fn, "proof_mass", proof_mass)
    I_p = _array(fn, "proof_inertia", proof_inertia, (3, 3), "kg m², about its centre of mass, IMU frame")
    if not np.allclose(I_p, I_p.T, rtol=1e-6, atol=0) or np.linalg.eigvalsh(I_p)[0] <= 0:
        raise ValueError(f"{fn}: proof_inertia must be symmetric positive definite (kg m²), got {I_p.tolist()}")
    M = m_d + m_p
    zero = np.zeros(3)
    if device_centre_of_mass is None:
        r_a, v_a = _lever(fn, "alone", alone, "device_centre_of_mass")
    else:
        c_given = _array(fn, "device_centre_of_mass", device_centre_of_mass, (3,), "m, relative to the IMU")
        r_a, v_a = -c_given, zero
    if proof_position is None:
        r_w, v_w = _lever(fn, "with_proof", with_proof, "proof_position")
    else:
        p_given = _array(fn, "proof_position", proof_position, (3,), "m, relative to the IMU")
        r_w, v_w = np.zeros(3), zero
    dtype = jnp.result_type(alone.inertia, with_proof.inertia)

    def centres(x: Array) -> tuple[Array, Array]:
        c_d = -x[12:15]
        p = jnp.asarray(p_given, x.dtype) if proof_position is not None else (M * -x[15:18] - m_d * c_d) / m_p
        return c_d, p

    def delta(x: Array) -> Array:
        c_d, p = centres(x)
        c = (m_d * c_d + m_p * p) / M
        proof = parallel_axis(jnp.asarray(I_p, x.dtype), jnp.asarray(m_p, x.dtype), p - c)
        return _vec6(proof + _steiner(m_d, c_d - c))

    x0 = np.concatenate([A, B, r_a, r_w])
    C_x = np.zeros((18, 18))
    C_x[:6, :6], C_x[6:12, 6:12] = C_A, C_B
    C_x[12:15, 12:15], C_x[15:18, 15:18] = np.diag(v_a), np.diag(v_w)
    K, C_K = _propagate(delta, x0, C_x, dtype)
    u = B - A
    kappa0 = float(K @ u / (K @ K))  # 1/J, unweighted: sets the weights' ΔI term
    W = np.linalg.pinv(C_A + C_B + kappa0**2 * C_K)

    def calibrate(x: Array) -> Array:
        k = delta(x)
        kappa = k @ (jnp.asarray(W, x.dtype) @ (x[6:12] - x[:6])) / (k @ (jnp.asarray(W, x.dtype) @ k))
        c_d, p = centres(x)
        return jnp.concatenate([(1 / kappa)[None], x[:6] / kappa, c_d, p])

    kappa = float(K @ W @ u / (K @ W @ K))
    if not kappa > 0:
        raise ValueError(
            f"{fn}: the proof body does not add the inertia it should (1/J = {kappa:.3g} ≤ 0): check that "
            f"alone and with_proof are not swapped and that proof_inertia is in kg m² in the IMU frame"
        )
    y, C_y = _propagate(calibrate, x0, C_x, dtype)
    e = u - kappa * K
    chi2 = float(e @ W @ e)
    inertia = y[1:7][_FULL]
    C_I = C_y[1:7, 1:7]
    lam, _, s_lam = _moments(inertia, C_I)
    s = np.sqrt(np.clip(np.diag(C_y), 0.0, None))
    as_j = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    return DeviceCalibration(
        rotor_inertia=as_j(y[0]),
        rotor_inertia_std=as_j(s[0]),
        inertia=as_j(inertia),
        inertia_covariance=as_j(C_I),
        inertia_std=as_j(_std3(C_I)),
        principal_moments=as_j(lam),
        moment_std=as_j(s_lam),
        centre_of_mass=as_j(y[7:10]),
        centre_of_mass_std=as_j(s[7:10]),
        mass=as_j(m_d),
        proof_position=as_j(y[10:13]),
        proof_position_std=as_j(s[10:13]),
        covariance=as_j(C_y[:10, :10]),
        consistency_chi2=as_j(chi2),
        consistency_pvalue=as_j(chi2_sf(5, chi2)),
    )


def object_inertia(
    fit: FitResult,
    device: DeviceCalibration,
    *,
    object_mass: float,
    object_position: Float[ArrayLike, " 3"] | None = None,
) -> ObjectInertia:
    """An object's inertia about its own centre of mass, from a throw of it fixed to a calibrated device.

    ``fit`` is the :func:`rbjax.fit_inertia` result of a throw of the device and the object
    together: in units of ``J`` (fitted without ``rotor_inertia``: ``I_c = J B``, ``J`` the
    device's) or in kg m² fitted with ``rotor_inertia=device.rotor_inertia`` (``I_c`` as fitted;
    its σ still takes ``J``'s in, the fit scaling with the ``J`` it was given). Frames and points as
    in :func:`calibrate_device`: IMU (body) frame, positions relative to the IMU (m). The
    combination's centre of mass is ``c = -fit.lever_arm``, the object's
    ``c_o = ((m_d + m_o) c - m_d c_d) / m_o`` (or ``c_o = object_position`` and ``c`` from it), and
    Steiner's theorem (:func:`rbjax.parallel_axis`) taken back to the object's centre of mass:

        I_o = I_c - parallel_axis(I_d, m_d, c_d - c) - m_o S(c_o - c),   S(d) = |d|² 1 - d dᵀ.

    A light object far from the device loses precision here: ``c_o - c_d`` is ``(m_d + m_o) / m_o``
    times ``c - c_d``, and so is the lever arm's σ. σ: first order (``jax.jacfwd`` of this map)
    from the fit's ``inertia_covariance`` and ``lever_arm_std`` and the device's ``covariance``
    (``J``, its inertia and centre of mass, with their correlations); the fit's lever arm taken as
    independent of its inertia.

    Args:
        fit: the fit of a throw of the device with the object fixed to it.
        device: the device's calibration, from :func:`calibrate_device`.
        object_mass: the object's mass ``m_o`` (kg, > 0), weighed.
        object_position: ``(3,)`` the object's centre of mass relative to the IMU, IMU frame (m);
            default: from ``fit.lever_arm`` (the fit needs ``accelerations=``).

    Returns:
        An :class:`ObjectInertia`.

    Raises:
        TypeError: ``fit`` not a ``FitResult``, ``device`` not a ``DeviceCalibration``, or a mass or
            position that is not numbers.
        ValueError: a batch of fits; a failed fit; a fit in trace-normalised units; a covariance
            that is not finite; no lever arm and no ``object_position``; a mass ``≤ 0``.
    """
    fn = "object_inertia"
    if not isinstance(device, DeviceCalibration):
        raise TypeError(f"{fn}: device must be a DeviceCalibration (rb.calibrate_device), got {type(device).__name__}")
    how = "with the rotor: without rotor_inertia (in units of J), or with rotor_inertia=device.rotor_inertia (kg m²)"
    Bo, C_Bo = _fit_arg(fn, "fit", fit, (_J_UNITS, _KG), how)
    m_o = _mass(fn, "object_mass", object_mass)
    m_d = float(np.asarray(device.mass))
    M = m_d + m_o
    J_fit = 1.0 if fit.inertia_units == _J_UNITS else float(np.asarray(device.rotor_inertia))
    if object_position is None:
        r, v = _lever(fn, "fit", fit, "object_position")
    else:
        p_given = _array(fn, "object_position", object_position, (3,), "m, relative to the IMU")
        r, v = np.zeros(3), np.zeros(3)
    dtype = jnp.result_type(fit.inertia, device.inertia)
    dev = np.concatenate(
        [np.asarray(device.rotor_inertia, np.float64)[None], np.asarray(_vec6(device.inertia), np.float64)]
        + [np.asarray(device.centre_of_mass, np.float64)]
    )

    def centres(x: Array) -> tuple[Array, Array, Array]:
        c_d = x[16:19]
        if object_position is not None:
            c_o = jnp.asarray(p_given, x.dtype)
            return c_d, (m_d * c_d + m_o * c_o) / M, c_o
        c = -x[6:9]
        return c_d, c, (M * c - m_d * c_d) / m_o

    def remove_device(x: Array) -> Array:
        c_d, c, c_o = centres(x)
        I_c = _mat(x[:6]) * (x[9] / J_fit)
        I_o = I_c - parallel_axis(_mat(x[10:16]), jnp.asarray(m_d, x.dtype), c_d - c) - _steiner(m_o, c_o - c)
        return jnp.concatenate([_vec6(I_o), c_o])

    x0 = np.concatenate([Bo, r, dev])
    C_x = np.zeros((19, 19))
    C_x[:6, :6], C_x[6:9, 6:9], C_x[9:, 9:] = C_Bo, np.diag(v), np.asarray(device.covariance, np.float64)
    y, C_y = _propagate(remove_device, x0, C_x, dtype)
    inertia = y[:6][_FULL]
    C_I = C_y[:6, :6]
    lam, axes, s_lam = _moments(inertia, C_I)
    as_j = lambda a: jnp.asarray(a, dtype)  # noqa: E731
    return ObjectInertia(
        inertia=as_j(inertia),
        inertia_covariance=as_j(C_I),
        inertia_std=as_j(_std3(C_I)),
        principal_moments=as_j(lam),
        principal_axes=as_j(axes),
        moment_std=as_j(s_lam),
        centre_of_mass=as_j(y[6:9]),
        centre_of_mass_std=as_j(np.sqrt(np.clip(np.diag(C_y)[6:9], 0.0, None))),
        mass=as_j(m_o),
    )
