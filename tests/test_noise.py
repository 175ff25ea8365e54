"""Noise levels estimated from the data (rbjax.identification._noise) and what the fit makes of them.

References: white noise of known σ (NumPy), and torque-free tumbles from scipy's DOP853
(tests/reference.py) on a phone-like clock: 100 Hz with ±1 ms jitter.
"""

from __future__ import annotations

import numpy as np
import pytest
from reference import imu_noise, reference_rotation, to_body

import rbjax as rb
from rbjax.identification import _noise

RNG = np.random.default_rng(42)


def _clock(T: int, jitter: float) -> np.ndarray:
    t = np.cumsum(0.01 + RNG.uniform(-jitter, jitter, T))
    return t - t[0]


@pytest.mark.parametrize("jitter", [0.0, 2e-3])
def test_white_noise_level_and_its_degrees_of_freedom(jitter):
    # 4000 recordings of 60 samples of unit white noise. The MAD of the standardised residuals
    # estimates σ; its square has mean 1 up to the MAD's small-sample bias (+3% at T = 60,
    # measured) and a spread of ±0.01 over 4000 draws (sd of σ̂² ≈ 0.24). Its effective
    # degrees of freedom ν = 2 E[σ̂²]² / var(σ̂²), which the consistency test's F distribution
    # takes from DOF_PER_RESIDUAL, must not be overstated (the test would then flag clean fits):
    # measured 0.20-0.22 per residual at T = 60; the constant may undershoot by at most 25%.
    T = 60
    t = _clock(T, jitter)
    s2 = _noise.noise_std(t, RNG.normal(size=(4000, T, 3)), eps=2.2e-16) ** 2
    assert 0.98 < np.mean(s2) < 1.08
    nu = 2 * np.mean(s2) ** 2 / np.var(s2)
    assert 1.0 <= nu / _noise.noise_dof(T) < 1.34


def _tumble(T: int = 60, speed: float = 1.0, dt: float = 0.01):
    """A tumble (|ω| ≈ 13 speed rad/s) on a jittered clock of step ``dt``: times, orientations, body rates."""
    t = _clock(T, 0.1 * dt) * (dt / 0.01)
    w0 = speed * np.array([3.0, 12.0, 4.0])
    q, w = reference_rotation(np.diag([1.0, 2.0, 2.6]), np.array([1.0, 0, 0, 0]), w0, t)
    return t, q, to_body(q, w)


def test_levels_of_a_fast_tumble_on_a_jittered_clock():
    # 1e-3 rad on the orientation and 0.005 rad/s on the gyro, 50 draws. Each estimate has a
    # spread of ~12% (ν ≈ 35), so the mean of 50 is within ~2% of the truth. Second differences
    # of the same samples keep the motion's ω̇ Δt-jitter and ω̈ Δt² terms: they read the levels
    # 2.4-2.8x too high (measured), which is what the local quadratics remove.
    t, q, wb = _tumble()
    sq, sw, sq_diff = [], [], []
    for _ in range(50):
        qn, wn = imu_noise(q, wb, RNG, sq=1e-3, sw=0.005)
        sq.append(_noise.orientation_noise_std(t, qn, eps=2.2e-16))
        sw.append(_noise.noise_std(t, wn, eps=2.2e-16))
        sq_diff.append(1.4826 * np.median(np.abs(np.diff(wn, 2, axis=0))) / np.sqrt(6.0))
    assert abs(np.mean(sq) / 1e-3 - 1) < 0.08 and abs(np.mean(sw) / 0.005 - 1) < 0.08
    assert np.mean(sq_diff) / 0.005 > 2.0  # the case is a hard one for the plain estimate


def test_clean_data_give_the_floor_of_the_fit_arithmetic():
    # noise-free samples of a slow tumble (1.3 rad/s at 200 Hz: what a quadratic cannot follow is
    # ~1e-10 rad, measured): the level is the floor, max(FLOOR_EPS eps, MODEL_FLOOR) x the signal's
    # RMS (1 rad for orientations), so a clean fit's own integration error is not called noise.
    # (The fast tumble below leaves 8e-6 rad and 5e-5 rad/s: 1% of its noise levels.)
    t, q, wb = _tumble(400, speed=0.1, dt=0.005)
    for dtype in (np.float32, np.float64):
        eps = float(np.finfo(dtype).eps)
        floor = max(_noise.FLOOR_EPS * eps, _noise.MODEL_FLOOR)
        assert _noise.orientation_noise_std(t, q.astype(dtype), eps) == pytest.approx(floor, rel=1e-12)
        rms = np.sqrt(np.mean(wb.astype(dtype).astype(np.float64) ** 2))
        assert _noise.noise_std(t, wb.astype(dtype), eps) == pytest.approx(floor * rms, rel=1e-6)


def test_an_unmodelled_gyro_bias_on_a_jittered_throw_is_flagged():
    # A gyro-only 0.6 s throw, 0.005 rad/s noise not given to the fit. Without a bias the fit is
    # consistent and its reported level is the truth's; with an unmodelled bias of 0.06 rad/s per
    # axis (12x the noise) the residuals are 1.7-2.3x the estimated level (measured over 5 draws,
    # p-value < 1e-4 in each): the white-noise test says so, and the verdict either distrusts the
    # fit or widens σ to cover the truth (measured: trusted, within 1.3σ in all 5). With the levels
    # read 2.4x too high, as second differences do here, the misfit would pass as noise. (Half that
    # bias the fit mostly absorbs into the start rate and the inertia: fit it with gyro_bias=True.)
    t, _, wb = _tumble()
    wn = wb + RNG.normal(0, 0.005, wb.shape)
    clean = rb.fit_inertia(t, None, body_rates=wn)
    assert bool(clean.model_consistent) and bool(clean.converged)
    assert abs(float(np.asarray(clean.noise_std)[1]) / 0.005 - 1) < 0.35  # one draw: ±12% spread, ~3σ
    biased = rb.fit_inertia(t, None, body_rates=wn + 0.06 * np.array([1.0, -0.67, 0.83]))
    assert not bool(biased.model_consistent)
    assert "x the gyro noise" in biased.diagnosis
    truth = np.array([1.0, 2.0, 2.6]) / 5.6
    m, sd = np.asarray(biased.principal_moments), np.asarray(biased.moment_std)
    assert not bool(biased.converged) or np.all(np.abs(m - truth) < 3 * sd)  # 3σ: no trusted miss
