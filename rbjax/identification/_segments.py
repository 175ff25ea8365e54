"""The recording as the fit's model reads it: cut into multiple-shooting segments.

:func:`._problem.prepare` builds one :class:`Segments` per recording; a batch
stacks them (leading ``N``), and the model maps over the segment axis ``S``.
Each segment has ``K`` sample intervals after its start sample (the last
segment padded to ``K``: ``mask = 0``, ``dt = 0``). A new sensor or torque
model adds its fields here, its block to the model (:mod:`._model`) and its
check (:mod:`._checks`).
"""

from __future__ import annotations

from typing import Any

from .._pytree import field, pytree_dataclass

__all__ = ["Segments"]


@pytree_dataclass
class Segments:
    """One recording's segments (NumPy or JAX arrays; a batch adds a leading ``N`` to each).

    Shapes per recording; ``S`` segments, ``K`` intervals each, ``B`` sensor blocks
    (orientation, gyro, accelerometer: those present, in that order). Weights are
    inverse noise levels (1/rad, s/rad, s²/m), so a weighted residual is in units
    of its σ.

    Attributes:
        q_start: ``(S, 4)`` measured orientation at each segment's start sample
            (the model's ``q_s = q_start ⊗ exp(δ_s)``).
        q_first, w_first: ``(S, 4)``, ``(S, 3)`` the recording's first sample
            (orientation, body rate rad/s), repeated per segment; its residual
            counts in segment 0 only (``first``).
        first: ``(S,)`` 1 for segment 0, else 0.
        q_meas, w_meas: ``(S, K, 4)``, ``(S, K, 3)`` the samples after each start.
        dt: ``(S, K)`` sample intervals (s); 0 for padding.
        t0: ``(S,)`` each segment's start time from the recording's first sample (s).
        mask: ``(S, K)`` 1 for a real sample, 0 for padding.
        wq, ww: ``(S,)`` inverse noise levels of the orientation (1/rad) and gyro
            (s/rad) residuals (1 for an absent sensor).
        wcq, wc: ``(S,)`` weights of the joins' orientation and rate gaps.
        delta_free: ``(S,)`` 1 where ``δ_s`` is fitted; 0 pins segment 0's
            rotation when there are no orientations.
        rw: ``(S, B, K+1)`` robust-loss weights per sensor block and sample (1:
            squared loss; the IRLS rounds update them).
        a_first, a_meas, wa: accelerometer (m/s²): first sample ``(S, 3)``,
            samples ``(S, K, 3)`` and inverse noise level ``(S,)``; ``None``
            without accelerations.
        t_samples: ``(S, K+1)`` times of each segment's samples (s, from the
            first sample), where known torques are interpolated; ``None``
            without torques.
        tau, tau_b: ``(S, K+1, 3)`` known torques at those times (N m), world
            or body frame; ``None`` when not given.
        h: ``(S, K+1, 3)`` the rotors' momentum relative to the body at each
            segment's samples, ``Σ_k J_k Ω_k a_k`` (body frame, kg m²/s, or in
            units of ``J``), linear in time between them; ``None`` without rotors.
        h_rate: ``(S, K+1, 3)`` its rate at those samples (kg m²/s²): the mean of
            the linear interpolant's slopes on either side (one-sided at the
            recording's ends), for the accelerometer's ``ω̇``; ``None`` without
            rotors or accelerations.
        h_noise: ``(S, 3, 3)`` the covariance of ``h``'s errors at each sample
            (``._noise.roughness_covariance`` of the recording's logged momentum:
            a motor's rate telemetry is quantised and noisy), repeated per segment;
            ``None`` without rotors. σ allows for it (:func:`._verdict.telemetry_covariance`).
    """

    q_start: Any = field(core_ndim=2)
    q_first: Any = field(core_ndim=2)
    w_first: Any = field(core_ndim=2)
    first: Any = field(core_ndim=1)
    q_meas: Any = field(core_ndim=3)
    w_meas: Any = field(core_ndim=3)
    dt: Any = field(core_ndim=2)
    t0: Any = field(core_ndim=1)
    mask: Any = field(core_ndim=2)
    wq: Any = field(core_ndim=1)
    wcq: Any = field(core_ndim=1)
    delta_free: Any = field(core_ndim=1)
    rw: Any = field(core_ndim=3)
    ww: Any = field(core_ndim=1)
    wc: Any = field(core_ndim=1)
    a_first: Any = field(core_ndim=2, default=None)
    a_meas: Any = field(core_ndim=3, default=None)
    wa: Any = field(core_ndim=1, default=None)
    t_samples: Any = field(core_ndim=2, default=None)
    tau: Any = field(core_ndim=3, default=None)
    tau_b: Any = field(core_ndim=3, default=None)
    h: Any = field(core_ndim=3, default=None)
    h_rate: Any = field(core_ndim=3, default=None)
    h_noise: Any = field(core_ndim=3, default=None)
