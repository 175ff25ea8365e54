"""rb.calibrate_device and rb.object_inertia (issue 58, item 5): J, the device, then an object on it.

The throws come from tests/_gyrostat_truth.py (scipy's DOP853 at rtol = atol = 1e-12 on the
body-frame gyrostat equations, not rbjax's integrator): the device alone, with a brass proof
cylinder on a jig, and with a 0.6 kg block turned against the IMU's axes, each body's inertia and
centre of mass combined by Steiner's theorem in NumPy (``g.combine``, not ``rb.parallel_axis``).
Every fit is in units of J (no ``rotor_inertia``), gyro and accelerometer, 2,001 samples at 4 kHz:
one compiled program for all of them.
"""

from __future__ import annotations

import dataclasses
import functools

import _gyrostat_truth as g
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb

T4K = np.arange(2001) / 4000.0
W0 = np.array([10.0, 20.0, 12.0])  # rad/s
DEVICE = (g.I_DEVICE, g.DEVICE_MASS, g.DEVICE_COM)
I_PROOF, _, C_PROOF = g.combine(*DEVICE, g.PROOF_INERTIA, g.PROOF_MASS, g.PROOF_POSITION)
I_OBJ, _, C_OBJ = g.combine(*DEVICE, g.OBJECT_INERTIA, g.OBJECT_MASS, g.OBJECT_POSITION)
BODIES = [(g.I_DEVICE, g.DEVICE_COM), (I_PROOF, C_PROOF), (I_OBJ, C_OBJ)]  # alone, with the proof, with the object
KNOWN = dict(device_mass=g.DEVICE_MASS, proof_mass=g.PROOF_MASS, proof_inertia=g.PROOF_INERTIA)


@functools.cache
def _throws(seed=None, gyro_std=0.02, acc_std=0.05):
    """The three throws' fits; gyro (rad/s) and accelerometer (m/s²) noise with ``seed`` (kept: a test reuses them)."""
    rng = None if seed is None else np.random.default_rng(seed)
    fits = []
    for I, c in BODIES:
        _, w, W = g.throw(T4K, W0, I=I)
        a = g.accelerations(T4K, w, I=I, lever=-c)
        if rng is not None:
            w, a = w + rng.normal(0, gyro_std, w.shape), a + rng.normal(0, acc_std, a.shape)
        fits.append(rb.fit_inertia(T4K, None, body_rates=w, rotor_rates=W, rotor_axis=g.AXIS, accelerations=a))
    return fits


@pytest.fixture(scope="module")
def clean():
    return _throws()


def test_noise_free_throws_give_j_the_device_and_the_object(clean):
    alone, proof, obj = clean
    assert alone.inertia_units == "rotor inertia J"
    dev = rb.calibrate_device(alone, proof, **KNOWN, proof_position=g.PROOF_POSITION)
    # each fit is within 2e-7-5e-7 of the truth (the linear interpolation of the rotor's rate between
    # samples: tests/test_fit_rotor.py); measured 1.9e-7 on J, 1.8e-7 (of the largest moment) on the
    # device's inertia, 6.3e-7 of tr I on the object's, centres of mass within 3e-9 m
    np.testing.assert_allclose(dev.rotor_inertia, g.J_FLYWHEEL, rtol=2e-6)
    assert np.max(np.abs(dev.inertia - g.I_DEVICE)) < 2e-6 * np.max(g.MOMENTS)
    np.testing.assert_allclose(dev.centre_of_mass, g.DEVICE_COM, atol=1e-8)
    np.testing.assert_array_equal(dev.proof_position, g.PROOF_POSITION)
    np.testing.assert_array_equal(dev.proof_position_std, 0.0)
    assert dev.covariance.shape == (10, 10) and float(dev.rotor_inertia_std) > 0
    np.testing.assert_allclose(dev.principal_moments, np.sort(g.MOMENTS), rtol=2e-6)
    # the proof's position from the lever arms instead of the jig
    by_lever = rb.calibrate_device(alone, proof, **KNOWN)
    np.testing.assert_allclose(by_lever.rotor_inertia, g.J_FLYWHEEL, rtol=2e-6)
    np.testing.assert_allclose(by_lever.proof_position, g.PROOF_POSITION, atol=1e-8)

    res = rb.object_inertia(obj, dev, object_mass=g.OBJECT_MASS)
    assert np.max(np.abs(res.inertia - g.OBJECT_INERTIA)) < 3e-6 * np.trace(g.OBJECT_INERTIA)
    np.testing.assert_allclose(res.principal_moments, np.linalg.eigvalsh(g.OBJECT_INERTIA), rtol=3e-6)
    np.testing.assert_allclose(res.centre_of_mass, g.OBJECT_POSITION, atol=1e-8)
    assert float(res.mass) == g.OBJECT_MASS
    assert repr(dev).startswith("DeviceCalibration(rotor_inertia=1.7e-06 ± ") and "consistency_pvalue=" in repr(dev)
    assert repr(res).startswith("ObjectInertia(principal_moments=[0.00017 ± ") and "mass=0.6 kg" in repr(res)


def test_without_lever_arms_the_positions_are_given(clean):
    alone, proof, obj = clean
    # as fits without accelerations= report them
    blind = [dataclasses.replace(f, lever_arm=jnp.full(3, jnp.nan), lever_arm_std=jnp.full(3, jnp.nan)) for f in clean]
    with pytest.raises(ValueError, match="alone has no lever arm .* give device_centre_of_mass"):
        rb.calibrate_device(blind[0], blind[1], **KNOWN, proof_position=g.PROOF_POSITION)
    with pytest.raises(ValueError, match="with_proof has no lever arm .* give proof_position"):
        rb.calibrate_device(blind[0], blind[1], **KNOWN, device_centre_of_mass=g.DEVICE_COM)
    dev = rb.calibrate_device(
        blind[0], blind[1], **KNOWN, proof_position=g.PROOF_POSITION, device_centre_of_mass=g.DEVICE_COM
    )
    np.testing.assert_allclose(dev.rotor_inertia, g.J_FLYWHEEL, rtol=2e-6)
    np.testing.assert_array_equal(dev.centre_of_mass_std, 0.0)
    with pytest.raises(ValueError, match="fit has no lever arm .* give object_position"):
        rb.object_inertia(blind[2], dev, object_mass=g.OBJECT_MASS)
    res = rb.object_inertia(blind[2], dev, object_mass=g.OBJECT_MASS, object_position=g.OBJECT_POSITION)
    assert np.max(np.abs(res.inertia - g.OBJECT_INERTIA)) < 3e-6 * np.trace(g.OBJECT_INERTIA)
    np.testing.assert_array_equal(res.centre_of_mass_std, 0.0)


def _z(fits):
    """z-scores of J, the device's moments and centre of mass, the object's moments and centre of mass."""
    alone, proof, obj = fits
    dev = rb.calibrate_device(alone, proof, **KNOWN, proof_position=g.PROOF_POSITION)
    res = rb.object_inertia(obj, dev, object_mass=g.OBJECT_MASS)
    z = lambda est, std, true: (np.asarray(est) - true) / np.asarray(std)  # noqa: E731
    return (
        dev,
        res,
        np.concatenate(
            [
                [z(dev.rotor_inertia, dev.rotor_inertia_std, g.J_FLYWHEEL)],
                z(dev.principal_moments, dev.moment_std, np.sort(g.MOMENTS)),
                z(dev.centre_of_mass, dev.centre_of_mass_std, g.DEVICE_COM),
                z(res.principal_moments, res.moment_std, np.linalg.eigvalsh(g.OBJECT_INERTIA)),
                z(res.centre_of_mass, res.centre_of_mass_std, g.OBJECT_POSITION),
            ]
        ),
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noisy_throws_cover_the_truth_within_3_sigma(seed):
    fits = _throws(seed)
    dev, res, z = _z(fits)
    assert np.all(np.abs(z) < 3), z
    # 0.02 rad/s of gyro noise: J to ~5e-5 (σ measured 5.4e-5), the object's moments to ~1e-3
    assert 1e-5 < float(dev.rotor_inertia_std) / g.J_FLYWHEEL < 2e-4
    assert np.all(np.asarray(res.moment_std) / np.asarray(res.principal_moments) < 3e-3)
    assert float(dev.consistency_pvalue) > 1e-3
    # a jig 1 cm off along x: the proof no longer adds what its numbers say, and the test says so
    (alone, proof, _) = fits
    off = rb.calibrate_device(alone, proof, **KNOWN, proof_position=g.PROOF_POSITION + [0.01, 0.0, 0.0])
    assert float(off.consistency_pvalue) < 1e-3, float(off.consistency_chi2)


def test_object_fitted_in_kg_m2_with_the_calibrated_j_agrees():
    alone, proof, _ = _throws(0)  # the noisy test's, kept
    dev = rb.calibrate_device(alone, proof, **KNOWN, proof_position=g.PROOF_POSITION)
    I, c = BODIES[2]
    rng = np.random.default_rng(4)
    _, w, W = g.throw(T4K, W0, I=I)
    a = g.accelerations(T4K, w, I=I, lever=-c)
    w, a = w + rng.normal(0, 0.02, w.shape), a + rng.normal(0, 0.05, a.shape)
    fit = lambda **kw: rb.fit_inertia(T4K, None, body_rates=w, rotor_rates=W, rotor_axis=g.AXIS, accelerations=a, **kw)  # noqa: E731
    in_j, kg = fit(), fit(rotor_inertia=float(dev.rotor_inertia))
    assert kg.inertia_units == "kg m^2"
    a_j, a_kg = rb.object_inertia(in_j, dev, object_mass=0.6), rb.object_inertia(kg, dev, object_mass=0.6)
    # the same throw in other units: the same answer, J's σ taken in by both
    np.testing.assert_allclose(a_kg.inertia, a_j.inertia, rtol=0, atol=1e-6 * np.trace(g.OBJECT_INERTIA))
    np.testing.assert_allclose(a_kg.moment_std, a_j.moment_std, rtol=0.02)
    assert np.all(np.abs(a_kg.principal_moments - np.linalg.eigvalsh(g.OBJECT_INERTIA)) < 3 * a_kg.moment_std)


def _bad_fit(fit, **changes):
    return dataclasses.replace(fit, **changes)


def test_bad_inputs_are_refused_in_words(clean):
    alone, proof, obj = clean
    dev = rb.calibrate_device(alone, proof, **KNOWN, proof_position=g.PROOF_POSITION)
    cal = lambda a=alone, p=proof, **kw: rb.calibrate_device(a, p, **{**KNOWN, **kw})  # noqa: E731
    with pytest.raises(TypeError, match="calibrate_device: alone must be a FitResult of rb.fit_inertia, got ndarray"):
        cal(np.eye(3))
    kg = _bad_fit(proof, inertia_units="kg m^2")
    with pytest.raises(ValueError, match=r"with_proof must be fitted .* without rotor_inertia .* in units 'kg m\^2'"):
        cal(p=kg)
    with pytest.raises(ValueError, match="alone must be fitted .* 'trace-normalised'"):
        cal(_bad_fit(alone, inertia_units="trace-normalised"))
    batch = jax.tree.map(lambda x: jnp.stack([x, x]), alone)
    with pytest.raises(ValueError, match=r"alone must be one fit \(inertia \(3, 3\)\), got a batch"):
        cal(batch)
    with pytest.raises(ValueError, match="alone is a fit that failed"):
        cal(_bad_fit(alone, failed=jnp.asarray(True)))
    nan_cov = _bad_fit(alone, inertia_covariance=jnp.full((6, 6), jnp.nan))
    with pytest.raises(ValueError, match="alone.inertia_covariance is not finite"):
        cal(nan_cov)
    with pytest.raises(ValueError, match="device_mass must be one finite mass > 0"):
        cal(device_mass=0.0)
    with pytest.raises(TypeError, match="proof_mass must be a number"):
        cal(proof_mass="200 g")
    with pytest.raises(ValueError, match=r"proof_inertia must have shape \(3, 3\)"):
        cal(proof_inertia=np.diag(g.PROOF_INERTIA))
    with pytest.raises(ValueError, match="proof_inertia must be symmetric positive definite"):
        cal(proof_inertia=-g.PROOF_INERTIA)
    with pytest.raises(ValueError, match=r"proof_position must have shape \(3,\)"):
        cal(proof_position=[0.0, 0.0])
    with pytest.raises(ValueError, match="the proof body does not add the inertia it should .* swapped"):
        cal(proof, alone, proof_position=g.PROOF_POSITION)
    with pytest.raises(TypeError, match="object_inertia: device must be a DeviceCalibration"):
        rb.object_inertia(obj, alone, object_mass=0.6)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="object_inertia: fit must be fitted with the rotor"):
        rb.object_inertia(_bad_fit(obj, inertia_units="trace-normalised"), dev, object_mass=0.6)
    with pytest.raises(ValueError, match="object_mass must be one finite mass > 0"):
        rb.object_inertia(obj, dev, object_mass=float("nan"))


@pytest.mark.slow
def test_sigma_is_calibrated_over_20_seeds():
    # measured 2026-12-07 (seeds 100-119, 13 numbers each: J, the device's moments and centre of mass,
    # the object's moments and centre of mass): 96.2% within 2σ overall, 90-100% per number, all within
    # 3σ (max |z| 2.8); the assertion leaves room for 20 seeds' scatter (a binomial 95% of 260 is 91.7-97.5%)
    zs = np.array([_z(_throws(seed))[2] for seed in range(100, 120)])
    share = np.mean(np.abs(zs) < 2, axis=0)
    print("share within 2σ:", np.round(share, 2), "all:", float(np.mean(np.abs(zs) < 2)), "max |z|:", np.abs(zs).max())
    assert float(np.mean(np.abs(zs) < 2)) > 0.88
    assert np.all(share >= 0.75), share
