"""Optional model parts of fit_inertia chosen by the data: per-axis drag, a common gyro scale, ΔBIC.

Recordings come from benchmarks/fit_verdict.py's DOP853 generator (never rbjax): the docs'
tumble, gyro only, 2 s @ 200 Hz, 0.01 rad/s white noise, one fixed random body.
"""

from __future__ import annotations

import functools
import os
import sys

import jax
import numpy as np
import pytest

import rbjax as rb

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
from fit_verdict import gyrostat, random_body  # noqa: E402

from rbjax.identification._result import MODEL_PARTS  # noqa: E402

T = np.arange(401) / 200.0
W0 = np.array([0.5, 5.0, 1.0])
SW = 0.01
DRAG, AXES, BIAS, SCALE = (MODEL_PARTS.index(k) for k in ("drag", "drag_axes", "gyro_bias", "gyro_scale"))


@functools.cache
def _body():
    return random_body(np.random.default_rng(3))


@functools.cache
def _gyro(c_rel=(0.0, 0.0, 0.0), scale=0.0, seed=0):
    """Gyro readings ``(1 + scale) ω + noise`` of the tumble under ``τ_b = -c ⊙ ω``, ``c = c_rel tr I``."""
    jax.config.update("jax_enable_x64", True)
    I = _body()
    c = np.asarray(c_rel) * np.trace(I)
    w = gyrostat(I, W0, T, drag=(lambda w: -c * w) if np.any(c) else None)
    return (1 + scale) * w + np.random.default_rng(seed).normal(0, SW, w.shape)


@functools.cache
def _fit(c_rel=(0.0, 0.0, 0.0), scale=0.0, **kw):
    return rb.fit_inertia(T, None, body_rates=_gyro(c_rel, scale), **kw)


ANISO = (0.02, 0.0, 0.05)  # c / tr I (1/s): |L| loses ~5-10% per second, one axis undamped


def test_per_axis_drag_is_recovered_within_3_sigma_and_never_negative():
    # the truth's y coefficient is 0: its estimate must be >= 0 (the map onto c >= 0), not a
    # negative, energy-adding one. 3σ: one draw per coefficient (fixed seed), σ from the fit
    res = _fit(ANISO, drag="linear", drag_axes=True)
    c, s = np.asarray(res.drag_per_axis), np.asarray(res.drag_per_axis_std)
    assert c.shape == (2, 3) and np.all(c >= 0), c
    assert np.all(c[1] == 0) and np.all(np.isnan(s[1])), (c, s)  # the linear law has no c₂
    np.testing.assert_array_less(np.abs(c[0] - ANISO), 3 * s[0])
    assert np.all(s[0] < 0.002), s  # resolved: 0.02 at > 10σ
    assert np.all(np.isnan(np.asarray(res.drag)))  # no single coefficient describes it
    assert bool(res.converged), res.diagnosis
    d = np.asarray(res.delta_bic)
    assert d[DRAG] > 100 and d[AXES] > 100, d  # drag, and its anisotropy, supported
    assert "drag is supported by the data (ΔBIC = " in res.diagnosis
    assert "per-axis drag (over one coefficient for all axes) is supported" in res.diagnosis


def test_drag_is_not_supported_on_drag_free_data_and_supported_with_drag():
    # the same fit (drag="linear") on data without and with drag: ΔBIC < 0 and > 0, said in the diagnosis
    free = _fit(drag="linear")
    assert np.asarray(free.drag)[0] >= 0
    d = float(np.asarray(free.delta_bic)[DRAG])
    # the Wald statistic of a coefficient at ~0 is ~χ²(1): ΔBIC ≈ W - ln(n) (n = 1203 rows: 7.1)
    assert -7.2 < d < 0, d
    assert "drag is not supported by the data (ΔBIC = " in free.diagnosis, free.diagnosis
    dragged = _fit(ANISO, drag="linear")
    assert float(np.asarray(dragged.delta_bic)[DRAG]) > 100, dragged.delta_bic
    assert "drag is supported by the data" in dragged.diagnosis


def test_delta_bic_against_refits():
    # ΔBIC from the Wald statistic of the fitted part, and from the score (LM) statistic of a part
    # not fitted, against the likelihood ratio of actual refits: -2 Δlog L = Δχ² (whitened by the
    # same estimated noise level) over the full model's s², less k ln n. Both statistics are first
    # order in the part; measured on this body: per-axis drag against one coefficient (a large
    # effect) Wald 3806 against 4086 (7%); a weak drag (c / tr I = 4e-4, 0, 1e-3 1/s, near the
    # decision) score 29.0 and Wald 28.7 against 31.7 (9%, 10%); the strong drag of ANISO, score
    # 124,390 and Wald 151,851 against 172,030 (the linearisation reads low, in the same sign).
    # Hence 10-15%: the sign and the size of the evidence, not its digits
    n = 3 * T.size
    axes, iso = _fit(ANISO, drag="linear", drag_axes=True), _fit(ANISO, drag="linear")
    s2 = float(axes.chi2) / float(axes.dof)
    lr_axes = (float(iso.chi2) - float(axes.chi2)) / s2 - 2 * np.log(n)
    assert float(np.asarray(axes.delta_bic)[AXES]) == pytest.approx(lr_axes, rel=0.1)
    weak = tuple(0.02 * np.array(ANISO))
    with_drag, none = _fit(weak, drag="linear", drag_axes=True), _fit(weak)
    # both in the full model's residual variance (the score's from the restricted fit's residual
    # less what the part explains)
    gain = float(none.chi2) - float(with_drag.chi2)
    lr = gain * float(with_drag.dof) / float(with_drag.chi2) - 3 * np.log(n)
    assert lr > 10  # the case is one the data decide
    assert float(np.asarray(none.delta_bic)[DRAG]) == pytest.approx(lr, rel=0.15)
    assert float(np.asarray(with_drag.delta_bic)[DRAG]) == pytest.approx(lr, rel=0.15)
    assert np.isnan(np.asarray(none.delta_bic)[AXES]) and np.isnan(np.asarray(none.delta_bic)[SCALE])


def test_common_gyro_scale_is_recovered():
    # a 1% scale error on all three axes, gyro only: the Euler equations are quadratic in ω, so a
    # scaled rate is a faster motion, which no inertia reproduces at the sample times. Measured
    # s = 1.45% ± 0.16% on this draw (2.9σ: the same noise draw reads +0.44% on unscaled data; the
    # calibration over random tumbles is the slow test below); 3σ, and σ below 0.5% so that 1% is
    # resolved
    res = _fit(scale=0.01, gyro_scale=True)
    s, sd = float(res.gyro_scale), float(res.gyro_scale_std)
    assert abs(s - 0.01) < 3 * sd and sd < 0.005, (s, sd)
    assert float(np.asarray(res.delta_bic)[SCALE]) > 0
    assert "the gyro scale factor is supported by the data" in res.diagnosis
    I = _body() / np.trace(_body())
    z = np.abs(np.asarray(res.principal_moments) - np.linalg.eigvalsh(I)) / np.asarray(res.moment_std)
    assert np.all(z < 3), z


@pytest.mark.slow
def test_gyro_scale_sigma_is_calibrated_over_random_tumbles():
    # 24 random bodies and spins (fit_verdict's generator), half with a 1% scale error: measured
    # 23 of 24 within 2σ (a calibrated σ: 95% ± 4.5%, 1 sd), all within 3σ; σ spans 0.12% to 31%
    # (median ~1%): a common scale is identifiable, but a tumble resolves 1% only where its nutation
    # is strong. ΔBIC on the 12 unscaled: -7.1 to -1.5 (never supported)
    rng = np.random.default_rng(11)
    gyro, truth = [], np.tile([0.0, 0.01], 12)
    for s in truth:
        I = random_body(rng)
        d = rng.normal(size=3)
        w0 = d / np.linalg.norm(d) * rng.uniform(3, 8)
        gyro.append((1 + s) * gyrostat(I, w0, T) + rng.normal(0, SW, (T.size, 3)))
    res = rb.fit_inertia(T, None, body_rates=np.stack(gyro), gyro_scale=True)
    ok = ~np.asarray(res.failed)
    z = np.abs(np.asarray(res.gyro_scale) - truth) / np.asarray(res.gyro_scale_std)
    assert ok.sum() >= 22 and np.mean(z[ok] < 2) >= 0.85 and np.all(z[ok] < 3.5), z
    assert np.all(np.asarray(res.delta_bic)[ok & (truth == 0), SCALE] < 6)


@pytest.mark.slow
def test_per_axis_quadratic_drag_never_negative_and_joint():
    res = _fit(ANISO, drag="quadratic", drag_axes=True)
    c = np.asarray(res.drag_per_axis)
    assert np.all(c >= 0) and np.all(np.isfinite(np.asarray(res.drag_per_axis_std))), c
    # a list of two recordings: one (2, 3) each; joint=True: one set for both
    g = _gyro(ANISO)
    listed = rb.fit_inertia([T, T[:301]], None, body_rates=[g, g[:301]], drag="linear", drag_axes=True)
    assert np.asarray(listed.drag_per_axis).shape == (2, 2, 3)
    both = rb.fit_inertia(
        [T, T[:301]], None, body_rates=[g, _gyro(ANISO, seed=1)[:301]], drag="linear", drag_axes=True, joint=True
    )
    c = np.asarray(both.drag_per_axis)
    np.testing.assert_array_less(np.abs(c[0] - ANISO), 3 * np.asarray(both.drag_per_axis_std)[0])


def _scale_study(I, mode):
    """Relative singular values of the whitened Jacobian of gyro-only readings in (I / tr I (5), ω₀ (3),
    scale (1 common, or 3 per axis)), central differences through DOP853; and the scales' linearised σ."""
    from scipy.integrate import solve_ivp

    def readings(p):
        a, b, c, d, e = p[:5]
        J = np.array([[a, c, d], [c, b, e], [d, e, 1 - a - b]])
        Ji = np.linalg.inv(J)
        f = lambda _, w: -Ji @ np.cross(w, J @ w)  # noqa: E731
        w = solve_ivp(f, (0, T[-1]), p[5:8], method="DOP853", t_eval=T, rtol=1e-13, atol=1e-13).y.T
        return w * (1 + p[8:])

    I = I / np.trace(I)
    p0 = np.concatenate([[I[0, 0], I[1, 1], I[0, 1], I[0, 2], I[1, 2]], W0, np.zeros(1 if mode == "common" else 3)])
    h = 1e-6
    cols = [(readings(p0 + h * e) - readings(p0 - h * e)).ravel() / (2 * h * SW) for e in np.eye(p0.size)]
    J = np.stack(cols, 1)
    sv = np.linalg.svd(J, compute_uv=False)
    return sv / sv[0], np.sqrt(np.diag(np.linalg.pinv(J.T @ J)))[8:]


def test_a_per_axis_gyro_scale_is_not_identifiable_from_torque_free_motion():
    # per-axis scales k_a turn Euler's (I2 - I3)/I1 into k1/(k2 k3) times it, and the inertia's shape
    # absorbs all but one combination: on a body whose principal axes are the gyro's, two singular
    # values at rounding level (measured 5.6e-12, 2.5e-12), against 2.6e-4 for the common scale
    box = np.diag([1.0, 2.0, 2.6])
    assert _scale_study(box, "axes")[0][-2] < 1e-9
    assert _scale_study(box, "common")[0][-1] > 1e-5


@pytest.mark.slow
def test_per_axis_gyro_scales_of_an_oblique_body_are_too_uncertain_to_see():
    # with principal axes oblique to the gyro's the per-axis scales are determined only in principle:
    # σ 6.5-7.9% each (measured), so a 1% error is unseen; the common scale's σ is 0.56% there
    oblique = random_body(np.random.default_rng(1))
    assert np.all(_scale_study(oblique, "axes")[1] > 0.03)
    assert _scale_study(oblique, "common")[1][0] < 0.01


def test_new_options_are_checked_in_words():
    g = _gyro()
    with pytest.raises(ValueError, match="drag_axes=True .* drag='linear' or drag='quadratic'"):
        rb.fit_inertia(T, None, body_rates=g, drag_axes=True)
    with pytest.raises(TypeError, match="drag_axes must be True or False"):
        rb.fit_inertia(T, None, body_rates=g, drag="linear", drag_axes="yes")
    with pytest.raises(TypeError, match="gyro_scale must be True or False"):
        rb.fit_inertia(T, None, body_rates=g, gyro_scale=1)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (T.size, 1))
    with pytest.raises(ValueError, match="gyro_scale=True needs body_rates"):
        rb.fit_inertia(T, q, gyro_scale=True)


def test_a_per_axis_drag_never_reaches_an_isotropic_force_model():
    # the plot's model is rb.LinearDrag + rb.QuadraticDrag, isotropic: a per-axis drag is refused in
    # words (not silently plotted without drag); equal columns are one coefficient and pass
    from rbjax._cli_plot import fitted_rates

    I, w0, t = np.diag([0.2, 0.35, 0.45]), np.array([0.5, 5.0, 1.0]), T[:21]
    with pytest.raises(ValueError, match="differs between the body axes.*isotropic"):
        fitted_rates(I, w0, t, np.array([[0.02, 0.0, 0.05], [0.0, 0.0, 0.0]]))
    same = fitted_rates(I, w0, t, np.array([[0.02] * 3, [0.0] * 3]))
    np.testing.assert_array_equal(same, fitted_rates(I, w0, t, np.array([0.02, 0.0])))


@pytest.mark.slow
def test_drag_auto_picks_no_drag_on_drag_free_data():
    res = rb.fit_inertia(T, None, body_rates=_gyro(), drag="auto")
    assert np.all(np.isnan(np.asarray(res.drag))) and np.all(np.isnan(np.asarray(res.drag_per_axis)))


@pytest.mark.slow
def test_drag_auto_picks_per_axis_linear_drag_on_anisotropic_linear_drag():
    # candidates: none, linear, quadratic, and per axis linear (3) and quadratic (6): the truth's
    # law, per axis, has the smallest BIC (the quadratic terms' 3 more parameters gain ~nothing)
    res = rb.fit_inertia(T, None, body_rates=_gyro(ANISO), drag="auto", drag_axes=True)
    c = np.asarray(res.drag_per_axis)
    assert np.all(np.isfinite(c[0])) and np.all(c[1] == 0), c
    lists = rb.fit_inertia([T, T[:301]], None, body_rates=[_gyro(ANISO), _gyro(ANISO, seed=1)[:301]], drag="auto")
    assert np.all(np.isfinite(np.asarray(lists.drag)))  # one isotropic law for both recordings


@pytest.mark.slow
def test_command_line_drag_auto_and_gyro_scale(tmp_path, capsys):
    import json

    from rbjax._cli import main

    path, out = tmp_path / "rec.csv", tmp_path / "fit.json"
    np.savetxt(path, np.column_stack([T, _gyro(ANISO)]), delimiter=",", header="t,gx,gy,gz", comments="")
    assert main(["fit", str(path), "--out", str(out), "--drag", "auto", "--gyro-scale"]) in (0, 1, 3)
    res = json.loads(out.read_text())
    assert res["drag"][0] > 0 and res["delta_bic"]["drag"] > 0, res  # an isotropic law: drag_axes is not a flag
    assert "gyro_scale" in res and "gyro scale error s" in capsys.readouterr().out


def test_model_jacobian_of_the_new_parts_matches_finite_differences():
    # the solver's hand-assembled Jacobian (flow tangents, the gyro scale's column and its (1 + s)
    # on the rate rows, the per-axis drag's six coefficients) against central differences of the
    # residuals, with orientations, a gyro bias and a gyro rotation beside them, three segments
    # and padding, off the optimum. h = 1e-6 in float64: truncation ~1e-12, rounding ~1e-10 of
    # the residuals' scale over h, so 1e-6 of the largest entry
    from rbjax.identification import _model, _problem

    jax.config.update("jax_enable_x64", True)
    t = np.cumsum(np.r_[0.0, np.random.default_rng(3).uniform(0.01, 0.03, 61)])  # 62 samples
    w, q = gyrostat(_body(), W0, t, drag=lambda w: -0.05 * w, with_q=True)
    prob = _problem.prepare(
        t, q, 1.01 * w, None, initial_inertia=None, method="rk4", segments=3, substeps=None,
        orientation_std=1e-3, rate_std=1e-2, continuity_weight=1000.0, excitation_tol=1e-3,
        gyro_bias=True, gyro_rotation=True, drag="quadratic", drag_axes=True, gyro_scale=True,
    )  # fmt: skip
    layout = prob.static["layout"]
    assert layout.drag == 6 and layout.gyro_scale == 1
    model = jax.jit(lambda y, d: _model.model_residuals(y, d, **prob.static))
    data = jax.tree.map(lambda a: a[0], prob.data)
    assert data["seg"].mask.min() == 0  # padding exercised
    rng = np.random.default_rng(4)
    y = prob.y0[0] + rng.normal(0, 0.05, prob.y0.shape[1])
    y[layout.span("drag")] = rng.uniform(0.005, 0.03, 6)  # coefficients above the map's bend
    y[layout.span("gyro_scale")] = 0.02
    r, J = model(y, data)
    h = 1e-6
    fd = np.stack([(model(y + h * e, data)[0] - model(y - h * e, data)[0]) / (2 * h) for e in np.eye(y.size)], 1)
    np.testing.assert_allclose(J, fd, rtol=0, atol=1e-6 * np.abs(fd).max())
