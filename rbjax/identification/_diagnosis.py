"""What the misfit looks like, and what a candidate cause does to σ.

Each candidate cause is a few extra columns ``X`` of the gyro rows (whitened like
the residuals): the first-order change of the rates per unit of the parameters a
model with that cause would add (:func:`._verdict.rate_sensitivity`, body frame,
per sample ``t`` and axis ``a``):

- ``drag``: a torque ``-c_a ω_a e_a`` (per axis, so anisotropic drag too): ``|L|``
  decays in the body;
- ``bias``: the reading plus ``e_a``: a constant residual mean (a gyro bias);
- ``rotor``: an internal rotor's constant body-frame momentum ``h``,
  ``ω = I⁻¹ (L - h)``, ``L̇ = L × ω``: a constant offset ``-I⁻¹h`` of the rates and the
  torque ``-L × I⁻¹ h`` it exerts; with rotors modelled (``rotor_rates=``), a constant
  momentum beyond theirs (e.g. a wrong ``rotor_inertia``, or a rotor left out), the
  linearisation taken about ``L = I ω + h_modelled``;
- ``scale``: the reading plus ``ω_a e_a``: a residual proportional to the rate.

Its share is what ``X`` explains of the residual beyond the fit's own parameters
(``X⊥ = (1 - U Uᵀ) X``, ``U`` the fit's data Jacobian's orthonormal basis):
``share = rᵀ P r / rᵀ r``, ``P`` the projection onto ``X⊥``; ``rᵀ P r / s²`` is the
score (LM) test of adding the cause, ``χ²`` with ``c`` degrees of freedom when
the cause is absent. Each cause fitted alongside, linearly, has parameters ``β̂ = -(X⊥ᵀX⊥)⁺ X⊥ᵀ r``
that would move the inertia's functionals by ``Δ = G Uᵀ X β̂`` and add
``s² (G UᵀX) (X⊥ᵀX⊥)⁺ (G UᵀX)ᵀ`` to their covariance. Of the causes significant at
``CAUSE_ALPHA`` (Bonferroni over the four), σ allows (``covariance + Δ Δᵀ``) for the
one that explains most and a second if it adds significantly beyond it: σ then
covers the shift a present cause makes in the estimate, not only the noise.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ._verdict import rate_sensitivity

__all__ = ["CAUSES", "cause_terms", "comparison", "diagnosis"]

#: The candidate causes, in the order of ``FitResult.cause_share``.
CAUSES = ("drag", "bias", "rotor", "scale")
#: Significance of each cause's score test (Bonferroni over the four: 1e-3 in all)
CAUSE_ALPHA = 1e-3 / 4
# the χ²(3) quantile at 1 - CAUSE_ALPHA (scipy.stats.chi2.isf(2.5e-4, 3)): every cause has 3 columns
_CHI2_3 = 19.18788483710136
_WHAT = dict(
    drag="drag (|L| decays in the body; try drag=)",
    bias="a gyro bias (a constant rate offset; try gyro_bias=True)",
    rotor="an internal rotor (a constant body-frame momentum offset)",
    scale="a gyro scale error (residual proportional to ω)",
)
_SENSORS = ("orientation", "gyro", "accelerometer")


def _pinv_psd(G):
    """Pseudo-inverse of a positive semi-definite ``G``, directions below ``sqrt(eps)`` of the largest dropped."""
    w, V = jnp.linalg.eigh(G)
    keep = w > jnp.finfo(G.dtype).eps ** 0.5 * jnp.maximum(w[-1], jnp.finfo(G.dtype).tiny)
    return (V * jnp.where(keep, 1 / jnp.where(keep, w, 1), 0)) @ V.T


def cause_terms(seg, kept, r_kept, U_good, G, I, gyro_block, rows_shape, s2_gyro):
    """Per cause its share of the residual and whether it is in the model that σ allows for; those causes'
    the covariance ``(f, f)`` to add to the functionals ``G`` describes (the selected causes'); per cause
    its score statistic ``rᵀ P r`` (``(len(CAUSES),)``, in the rows' units: the noise level's) and the
    residual rows it would leave fitted linearly (``(len(CAUSES), rows)``).

    ``G (f, k)`` from :func:`._verdict.covariance`; ``s2_gyro``: the gyro residual variance per
    degree of freedom (units of its noise level squared).
    """
    S, B, K1, _ = rows_shape
    n_rows = S * B * K1 * 3
    valid = kept[:, gyro_block]
    g = jnp.sqrt(seg.rw[:, gyro_block]) * valid * seg.ww[:, None]  # (S, K+1): the rows' whitening
    r_g = r_kept[:, gyro_block]  # (S, K+1, 3) = g (ω_model - ω_meas)
    w_meas = jnp.concatenate([seg.w_first[:, None], seg.w_meas], 1)
    # the model's rates, not the measured ones: a column made of the noise would explain the noise
    w = w_meas + r_g / jnp.where(g > 0, g, 1)[..., None]
    eye = jnp.eye(3, dtype=w.dtype)
    per_axis = w[..., None, :] * eye  # (S, K+1, 3 [column], 3 [axis])
    zero = jnp.zeros_like(per_axis)
    I_inv = jnp.linalg.inv(I)
    ones = jnp.broadcast_to(eye, per_axis.shape)
    L = w @ I if seg.h is None else w @ I + seg.h  # body-frame momentum, modelled rotors' included
    h_torque = -jnp.cross(L[..., None, :], jnp.broadcast_to(I_inv, per_axis.shape))  # -L × I⁻¹ e_a
    sens = dict(
        drag=rate_sensitivity(I_inv, w, seg.dt, valid, -per_axis, zero, seg.h),
        bias=ones * valid[..., None, None],
        rotor=rate_sensitivity(I_inv, w, seg.dt, valid, h_torque, -jnp.broadcast_to(I_inv, per_axis.shape), seg.h),
        scale=per_axis * valid[..., None, None],
    )
    r_rows = r_kept.reshape(-1)
    total = jnp.sum(r_rows**2)

    def rows(X):  # (S, K+1, c, 3) -> (n_rows, c) in the gyro block, whitened
        Xg = jnp.moveaxis(g[..., None, None] * X, 2, -1)
        return jnp.zeros((S, B, K1, 3, Xg.shape[-1]), w.dtype).at[:, gyro_block].set(Xg).reshape(n_rows, -1)

    def project(X):
        UX = U_good.T @ X
        Xp = X - U_good @ UX
        P = _pinv_psd(Xp.T @ Xp)
        b = Xp.T @ r_rows
        return UX, P, b, b @ P @ b

    Xs = [rows(sens[c]) for c in CAUSES]
    projected = [project(X) for X in Xs]
    explained = jnp.stack([pr[3] for pr in projected])
    # the residual each cause, fitted linearly, would leave: r + X⊥ β̂ = r - X⊥ P b
    after = jnp.stack([r_rows - (X - U_good @ UX) @ (P @ b) for X, (UX, P, b, _) in zip(Xs, projected, strict=True)])
    shares = explained / jnp.where(total > 0, total, 1)
    significant = explained > _CHI2_3 * s2_gyro
    # forward selection: the cause that explains most, then the one that adds most beyond it if that
    # addition is significant too. (Allowing for every significant cause, or the one that would move the
    # moments most, charges σ for columns the inertia absorbs: a per-axis scale error is nearly an
    # inertia change, measured 27-34x the white σ on bias, rotor and scale cases alike.)
    idx = jnp.arange(len(CAUSES))
    first = jnp.argmax(jnp.where(significant, explained, -1))
    X1 = jnp.stack(Xs)[first] * jnp.any(significant).astype(w.dtype)
    gain = jnp.stack([project(jnp.concatenate([X1, X], 1))[3] for X in Xs]) - project(X1)[3]
    second = jnp.argmax(jnp.where(idx == first, -1, gain))
    adds = gain[second] > _CHI2_3 * s2_gyro
    # a bias and a rotor both offset the rates by a constant (the rotor also torques the body): when
    # both are significant the data cannot rank them, and σ allows for both
    b, r = CAUSES.index("bias"), CAUSES.index("rotor")
    pair = significant[b] & significant[r] & ((first == b) | (first == r))
    second = jnp.where(pair, b + r - first, second)
    adds = adds | pair
    used = ((idx == first) & jnp.any(significant)) | ((idx == second) & adds)
    UX, P, b, _ = project(jnp.concatenate([X1, jnp.stack(Xs)[second] * adds.astype(w.dtype)], 1))
    H = G @ UX  # (f, c): the functionals' change per unit of the causes' parameters, through the fit
    shift = H @ P @ b  # -H β̂, β̂ = -P b
    extra = s2_gyro * H @ P @ H.T + shift[:, None] * shift[None, :]
    return shares, used, extra, explained, after


def diagnosis(noise_scale, correlation_length, cause_share, significant, structured, noise_estimated) -> str:
    """One line: how large the misfit is against the noise, over how many samples, on which sensor, and why.

    ``noise_scale``, ``correlation_length`` ``(3,)`` per sensor (NaN if absent),
    ``cause_share`` and ``significant`` ``(len(CAUSES),)``, ``structured``: ``FitResult``'s fields.
    """
    scale = np.asarray(noise_scale, np.float64)
    if not np.any(np.isfinite(scale)):
        return "no fit"
    k = int(np.nanargmax(scale))
    level = "estimated" if bool(np.asarray(noise_estimated)[k]) else "given"
    ell = float(np.asarray(correlation_length)[k])
    head = f"misfit {scale[k]:.3g}x the {_SENSORS[k]} noise ({level}), correlated over {ell:.3g} samples"
    shares = np.where(np.asarray(significant, bool), np.asarray(cause_share, np.float64), np.nan)
    if scale[k] < 0.5:  # far below the noise level (a noise-free recording's floor): nothing to explain
        return f"residuals within the noise ({head})"
    if np.any(np.isfinite(shares)):
        c = int(np.nanargmax(shares))
        why = f"; may be {_WHAT[CAUSES[c]]}: explains {shares[c]:.0%}, σ includes it"
    elif scale[k] < 1.5 and ell < 2:
        return f"residuals like the noise ({head})"
    else:
        why = "; no candidate (drag, bias, rotor, scale) explains it"
    tail = "; slow: σ widened for it (fixed-b)" if bool(structured) else ""
    return head + why + tail


_PART_NAMES = dict(
    drag="drag",
    drag_axes="per-axis drag (over one coefficient for all axes)",
    gyro_bias="the gyro bias",
    gyro_scale="the gyro scale factor",
)


def comparison(parts, delta_bic, fitted) -> str:
    """``"; drag is supported by the data (ΔBIC = 42)"`` for each fitted part (``fitted`` ``(len(parts),)``
    bools) with a finite ``delta_bic``; ``""`` for none."""
    out = []
    for name, d, on in zip(parts, np.asarray(delta_bic, np.float64), np.asarray(fitted, bool), strict=True):
        if on and np.isfinite(d):
            verdict = "is supported by the data" if d > 0 else "is not supported by the data"
            out.append(
                f"{_PART_NAMES[name]} {verdict} (ΔBIC = {d:.0f})"
                if abs(d) >= 10
                else f"{_PART_NAMES[name]} {verdict} (ΔBIC = {d:.1f})"
            )
    return "".join("; " + o for o in out)
