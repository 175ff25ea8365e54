"""Several throws of one body fitted together: ``fit_inertia(..., joint=True)``.

Data: torque-free tumbles of a phone-like body integrated by scipy DOP853
(rtol = atol = 1e-12, float64), sampled at 100 Hz, gyro noise 0.005 rad/s: the
short real throws (40-100 samples) the joint fit is for.
"""

from __future__ import annotations

import inspect

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import rbjax as rb
from rbjax.identification import _joint, _members, _solve

jax.config.update("jax_enable_x64", True)

MOMENTS = np.array([1.0, 3.2, 4.1]) * 1e-4  # kg m²
TRUTH = MOMENTS / MOMENTS.sum()  # gyro-only: I / tr I
GYRO_STD = 0.005  # rad/s
LENGTHS = (40, 55, 70, 85, 100)


def _euler(_, w, moments):
    I1, I2, I3 = moments
    return [(I2 - I3) / I1 * w[1] * w[2], (I3 - I1) / I2 * w[2] * w[0], (I1 - I2) / I3 * w[0] * w[1]]


def throws(seed=1, moments=MOMENTS, lengths=LENGTHS, starts=None):
    """``(times, gyro)`` lists: one throw per length, 8-12 rad/s about a random axis.

    ``starts``: a list that receives each throw's true ``ω(0)`` (body frame, rad/s).
    """
    rng = np.random.default_rng(seed)
    ts, ws = [], []
    for n in lengths:
        t = np.arange(n) * 0.01
        w0 = rng.normal(0, 1, 3)
        w0 = w0 / np.linalg.norm(w0) * rng.uniform(8, 12)
        if starts is not None:
            starts.append(w0)
        sol = solve_ivp(_euler, (0, t[-1]), w0, args=(moments,), method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t)
        ts.append(t)
        ws.append(sol.y.T + rng.normal(0, GYRO_STD, (n, 3)))
    return ts, ws


@pytest.fixture(scope="module")
def five():
    ts, ws = throws()
    return ts, ws, rb.fit_inertia(ts, body_rates=ws, joint=True)


def test_each_throw_gets_its_own_start_state(five):
    ts, ws, joint = five
    w_true = []
    throws(starts=w_true)  # the same draws as the fixture's (seed 1): their true ω(0)
    w, w_std = np.asarray(joint.member_initial_angular_velocity), np.asarray(joint.member_initial_angular_velocity_std)
    assert w.shape == w_std.shape == (5, 3)
    # every throw's fitted ω(0) within 4σ of the DOP853 truth (15 linearised components); σ below the
    # 0.005 rad/s per-sample noise (40-100 samples inform it) and above 1e-4 (not a blanket 0)
    np.testing.assert_array_less(np.abs(w - np.array(w_true)), 4 * w_std)
    assert np.all((w_std > 1e-4) & (w_std < GYRO_STD))
    # gyro only: the body frame at each throw's first sample is its world frame, δ not fitted
    np.testing.assert_array_equal(np.asarray(joint.member_initial_orientation), np.tile([1.0, 0, 0, 0], (5, 1)))
    assert np.all(np.isnan(np.asarray(joint.member_initial_orientation_std)))


def test_joint_fit_recovers_the_inertia(five):
    _, _, joint = five
    assert joint.joint and joint.principal_moments.shape == (3,) and bool(joint.converged)
    sigma = np.asarray(joint.moment_std)
    # within 3σ of the truth (measured z = 0.8, -0.9, 0.1); σ itself is checked against the
    # separate fits below (slow) and its size here: ~1e-5 of tr I = 1, not a blanket
    np.testing.assert_array_less(np.abs(np.asarray(joint.principal_moments) - TRUTH), 3 * sigma)
    np.testing.assert_array_less(sigma, 1e-4)
    # per throw: residuals at the joint level (measured 0.88-1.08), none flagged (measured p ≥ 0.03)
    assert len(joint.member_rms) == 5 and all(0.7 < r < 1.3 for r in joint.member_rms)
    assert min(joint.member_pvalue) > 1e-3
    # the per-throw statistics split the joint fit's: χ² and the degrees of freedom add up (the
    # whole fit's come from its result pass; the members' from their own residual rows), plain floats
    stats = (*joint.member_chi2, *joint.member_dof, *joint.member_rms, *joint.member_pvalue)
    assert all(type(x) is float for x in stats)
    np.testing.assert_allclose(sum(joint.member_chi2), float(joint.chi2), rtol=1e-12)  # float64 sums
    np.testing.assert_allclose(sum(joint.member_dof), float(joint.dof), rtol=1e-12)
    assert abs(float(joint.rate_rms) - GYRO_STD) < 0.2 * GYRO_STD  # ~1000 residuals: rms within ~5%


@pytest.mark.slow  # the separate fits compile their own batched program (~17 s)
def test_joint_sigma_is_smaller_than_one_throws_and_agrees_with_the_separate_fits(five):
    ts, ws, joint = five
    sep = rb.fit_inertia(ts, body_rates=ws)
    sigma = np.asarray(joint.moment_std)
    # five throws hold ~5x the information of one, so σ shrinks ~sqrt(5) = 2.2x against a typical
    # throw; the throws differ in length (40-100) and a short throw's information grows faster than
    # its length (the shape shows through the nutation), so the median throw's σ is not the mean's:
    # bound 1.5x, a floor that could fail (measured 4.1, 4.1, 7.7x)
    med = np.median(np.asarray(sep.moment_std), 0)
    np.testing.assert_array_less(sigma * 1.5, med)
    # each throw's own fit agrees with the joint one within its σ and the joint σ combined: 4σ for
    # 15 comparisons of linearised σ on 40-100 samples (measured |z| ≤ 3.2, on the 40-sample throw)
    diff = np.abs(np.asarray(sep.principal_moments) - np.asarray(joint.principal_moments))
    np.testing.assert_array_less(diff, 4 * np.hypot(np.asarray(sep.moment_std), sigma))


def test_joint_fit_leaves_out_a_bad_throw_and_names_a_disagreeing_one(five):
    ts, ws, _ = five
    # throw 2 of another body (I2 and I3 swapped roles: a different shape), throw 5 too short
    other_t, other_w = throws(seed=7, moments=np.array([1.0, 2.0, 2.6]) * 1e-4, lengths=(70,))
    ts2 = [ts[0], ts[1], other_t[0], ts[3], ts[4], np.arange(6) * 0.01]
    ws2 = [ws[0], ws[1], other_w[0], ws[3], ws[4], ws[0][:6]]
    res = rb.fit_inertia(ts2, body_rates=ws2, joint=True)
    assert len(res.member_errors) == 1 and res.member_errors[0].startswith("recording 5:")
    assert np.isnan(res.member_rms[5]) and not bool(res.failed)
    p = np.asarray(res.member_pvalue[:5])
    assert p[2] < 1e-3 and np.all(np.delete(p, 2) > 1e-3), p
    assert int(np.argmax(res.member_rms[:5])) == 2
    assert not bool(res.model_consistent)  # the joint χ² sees the other body too


@pytest.mark.slow  # three joint fits and the refits without the odd throw (~9 s on 2 cores)
def test_the_odd_throw_is_blamed_wherever_it_stands():
    # three throws of one body and one of a body whose largest moment is 0.1% larger (DOP853, 0.005
    # rad/s gyro noise). Against the joint fit's s² (which the odd throw inflates, its pull on the
    # shared inertia spread over the others) the 40-sample throw was blamed: p = 0.0047 against the
    # odd one's 0.125, as the odd one last gave in the report. Each throw is now tested against the
    # others' fit (measured: odd 1.3e-13; good 0.87, 0.16, 0.55), wherever it is put
    ts, ws = throws(seed=2, lengths=(40, 55, 70))
    odd_t, odd_w = throws(seed=9, moments=np.array([1.0, 3.2, 4.105]) * 1e-4, lengths=(50,))
    good = []
    for at in (0, 2, 3):
        t, w = list(ts), list(ws)
        t.insert(at, odd_t[0])
        w.insert(at, odd_w[0])
        p = list(rb.fit_inertia(t, body_rates=w, joint=True).member_pvalue)
        odd = p.pop(at)
        assert odd < 1e-3 and odd < min(p) and min(p) > 0.01, (at, odd, p)
        good.append(p)
    # the same problem with its rows and columns permuted: the solves agree to round-off (measured:
    # bitwise for the good throws, 2e-12 relative for the odd one's); 1e-6 leaves the solver's
    # tolerance (rtol = 1e-8 on the parameters) room on another BLAS
    np.testing.assert_allclose(good[1:], [good[0]] * 2, rtol=1e-6)


def test_joint_fit_of_new_lengths_in_the_same_buckets_does_not_recompile(five):
    # throws a few samples shorter: the same segments (1 each), the longest's intervals in the same
    # bucket (98 and 99 → 104 padded), the same substeps: the compiled joint program is reused
    ts, ws, _ = five
    cut = (38, 53, 66, 84, 99)
    # the five throws' program in the cache first (conftest drops compiled programs when a worker
    # holds too many memory mappings; then this compiles it again, once)
    rb.fit_inertia(ts, body_rates=ws, joint=True)
    n_compiled = _solve.compiled_programs()
    res = rb.fit_inertia([t[:n] for t, n in zip(ts, cut)], body_rates=[w[:n] for w, n in zip(ws, cut)], joint=True)
    assert _solve.compiled_programs() == n_compiled
    np.testing.assert_array_less(np.abs(np.asarray(res.principal_moments) - TRUTH), 3 * np.asarray(res.moment_std))


def test_a_gyro_bias_is_shared_by_the_throws(five):
    # one phone, one gyro: the same bias on every throw is one shared parameter of the joint fit
    ts, ws, _ = five
    bias = np.array([0.02, -0.01, 0.015])  # rad/s
    res = rb.fit_inertia(ts, body_rates=[w + bias for w in ws], joint=True, gyro_bias=True)
    assert bool(res.converged)
    # within 3σ, and σ well below the bias (measured 0.0197, -0.0100, 0.0146 ± 0.0005 rad/s)
    b, bs = np.asarray(res.gyro_bias), np.asarray(res.gyro_bias_std)
    np.testing.assert_array_less(np.abs(b - bias), 3 * bs)
    np.testing.assert_array_less(bs, 0.005)
    np.testing.assert_array_less(np.abs(np.asarray(res.principal_moments) - TRUTH), 3 * np.asarray(res.moment_std))


def test_joint_needs_several_recordings():
    t = np.arange(50) * 0.01
    with pytest.raises(ValueError, match="joint=True fits several recordings"):
        rb.fit_inertia(t, body_rates=np.zeros((50, 3)), joint=True)
    with pytest.raises(TypeError, match="joint must be True or False"):
        rb.fit_inertia([t, t], body_rates=[np.zeros((50, 3))] * 2, joint="yes")


def test_a_sixth_throw_reuses_the_program_and_blank_segments_change_nothing(five, monkeypatch):
    ts, ws, joint = five
    # 5 and 6 one-segment throws both pad to 6 segments (segment_bucket): one compiled program
    t6, w6 = throws(seed=4, lengths=(60,))
    rb.fit_inertia(ts, body_rates=ws, joint=True)  # the five throws' program in the cache (as above)
    n_compiled = _solve.compiled_programs()
    six = rb.fit_inertia(ts + t6, body_rates=ws + w6, joint=True)
    assert _solve.compiled_programs() == n_compiled
    assert six.segments == 6 and len(six.member_rms) == 6
    np.testing.assert_array_less(np.abs(np.asarray(six.principal_moments) - TRUTH), 3 * np.asarray(six.moment_std))
    # blank segments carry no data: the five throws padded to 9 segments instead of 6 give the same
    # fit. Their parameters have zero Jacobian columns, so the damped steps of the real ones are the
    # same arithmetic; agreement to rounding (1e-9 relative), dof and χ² included
    monkeypatch.setattr(_joint, "segment_bucket", lambda n: n + 4)
    padded = rb.fit_inertia(ts, body_rates=ws, joint=True)
    assert padded.segments == joint.segments == 5
    np.testing.assert_allclose(padded.principal_moments, joint.principal_moments, rtol=1e-9)
    np.testing.assert_allclose(padded.moment_std, joint.moment_std, rtol=1e-9)
    np.testing.assert_allclose([padded.chi2, padded.dof], [joint.chi2, joint.dof], rtol=1e-9)
    np.testing.assert_allclose(padded.member_pvalue, joint.member_pvalue, rtol=1e-9)
    assert int(padded.iterations) == int(joint.iterations)


def test_segment_buckets_pad_by_at_most_half():
    sizes = [_joint.segment_bucket(n) for n in range(1, 200)]
    assert sizes[:8] == [1, 2, 3, 4, 6, 6, 8, 8]
    assert all(n <= b <= 1.5 * n for n, b in zip(range(1, 200), sizes))
    assert len(set(sizes)) <= 16  # 199 counts, few programs


@pytest.mark.parametrize("gyro_bias", [False, True])
def test_the_solver_sizes_its_slots_as_the_model_shapes_its_output(gyro_bias):
    # the solver takes the residual and Jacobian shapes from _model.model_shapes instead of tracing
    # the model; they must be the model's own for a single recording of 1 and 4 segments (with
    # orientations) and a joint problem (joins inside each recording only, a blank segment)
    from rbjax.identification._model import model_residuals, model_shapes

    defaults = {k: p.default for k, p in inspect.signature(rb.fit_inertia).parameters.items()}
    opts = dict(defaults, gyro_bias=gyro_bias)
    ts, ws = throws(lengths=(40, 100, 100))
    q = np.tile([1.0, 0, 0, 0], (100, 1))
    arrays = lambda **given: {k: given.get(k) for k in _members.PER_MEMBER_NDIM}
    packed = [
        _solve.pack(t, arrays(body_rates=w), opts, segments=s, substeps=4, pad_intervals=99)
        for t, w, s in zip(ts, ws, (1, 2, 2), strict=True)
    ]
    probs = [
        _solve.pack(ts[1], arrays(body_rates=ws[1]), opts),
        _solve.pack(ts[1], arrays(orientations=q, body_rates=ws[1]), dict(opts, segments=4)),
        _joint._pad_segments(_joint.join_problems(packed), 6),
    ]
    for prob in probs:
        y, data = prob.y0[0], jax.tree.map(lambda a: a[0], prob.data)
        expected = jax.eval_shape(lambda y, d: model_residuals(y, d, **prob.static), y, data)  # noqa: B023
        assert model_shapes(y, data, **prob.static) == expected


@pytest.mark.slow  # its own joint program, with orientations
def test_a_joint_fit_with_orientations_recovers_each_throws_start_attitude_and_rate():
    # Three throws of one body recorded with orientations (1e-3 rad) and a gyro (0.005 rad/s),
    # each from a random attitude: each throw's fitted start orientation q₀ ⊗ exp(δ) and body
    # rate ω(0) lie within 4σ of the DOP853 truth, component by component (18 linearised
    # components: 4σ bounds a false failure at ~1e-3), and σ is neither 0 nor above the noise.
    from reference import imu_noise, qmul, quat_angle, reference_rotation, to_body

    rng = np.random.default_rng(5)
    ts, qs, ws, q_true, w_true = [], [], [], [], []
    for n in (50, 75, 100):
        t = np.arange(n) * 0.01
        q0 = rng.normal(size=4)
        q0 /= np.linalg.norm(q0)
        w0 = rng.normal(size=3)
        w0 *= rng.uniform(8, 12) / np.linalg.norm(w0)
        q, w = reference_rotation(np.diag(MOMENTS), q0, w0, t)  # w0: world frame
        wb = to_body(q, w)
        qn, wn = imu_noise(q, wb, rng, sq=1e-3, sw=GYRO_STD)
        ts.append(t), qs.append(qn), ws.append(wn)
        q_true.append(q[0]), w_true.append(wb[0])
    res = rb.fit_inertia(ts, orientations=qs, body_rates=ws, joint=True)
    assert bool(res.converged)
    q_fit = np.asarray(res.member_initial_orientation)
    q_std = np.asarray(res.member_initial_orientation_std)
    w_fit = np.asarray(res.member_initial_angular_velocity)
    w_std = np.asarray(res.member_initial_angular_velocity_std)
    # δ's error in the fitted body frame: log(q_fit* ⊗ q_true), small, so 2·vec to first order
    err = np.stack([2 * qmul(a * [1, -1, -1, -1], b)[1:] for a, b in zip(q_fit, q_true, strict=True)])
    np.testing.assert_array_less(np.abs(err), 4 * q_std)
    np.testing.assert_array_less(quat_angle(q_fit, np.array(q_true)), 1e-2)  # not merely a wide σ
    assert np.all((q_std > 1e-5) & (q_std < 1e-3))  # 50-100 samples of 1e-3 rad inform it
    np.testing.assert_array_less(np.abs(w_fit - np.array(w_true)), 4 * w_std)
    assert np.all((w_std > 1e-5) & (w_std < GYRO_STD))


@pytest.mark.parametrize("drop", [None, 2])
def test_member_tests_equal_dense_least_squares_of_the_stacked_rows(drop):
    # The per-member elimination against its definition: lstsq of the stacked rows of each
    # reference set (unit columns, zero columns dropped), on a block-arrow Jacobian with the
    # cases that need care: a member whose own columns are rank deficient (a repeated column),
    # a column no row touches, a shared column only one member touches, padding rows (-1).
    # Both are float64 least squares of the same rows: agreement to 1e-9 (conditioning ~1e3).
    rng = np.random.default_rng(7)
    members, shared = 5, 4
    sizes, own = [30, 45, 28, 60, 33], [6, 6, 12, 6, 6]
    n = shared + 1 + sum(own)
    J = np.zeros((sum(sizes) + 7, n))
    owner = np.full(J.shape[0], -1)
    row, col = 0, shared + 1  # column `shared` stays zero: no row touches it
    for k in range(members):
        rows = slice(row, row + sizes[k])
        J[rows, : shared - 1] = rng.normal(size=(sizes[k], shared - 1))
        J[rows, col : col + own[k]] = rng.normal(size=(sizes[k], own[k]))
        owner[rows] = k
        row, col = row + sizes[k], col + own[k]
    J[owner == 1, shared - 1] = rng.normal(size=sizes[1])  # "shared", yet only member 1 has it
    J[owner == 3, -2] = J[owner == 3, -1]  # member 3's own columns are rank deficient
    J *= rng.uniform(0.1, 10.0, n)  # units: the test normalises the columns
    r = rng.normal(size=J.shape[0])
    r[owner == 2] *= 3.0  # member 2 is noisier: its p-value is small

    def dense(keep):
        A = J[keep] / np.where(np.linalg.norm(J[owner >= 0], axis=0) > 0, np.linalg.norm(J[owner >= 0], axis=0), 1)
        A = A[:, np.linalg.norm(A, axis=0) > 0]
        delta, _, rank, _ = np.linalg.lstsq(A, -r[keep], rcond=1e-10)
        return float(np.sum((r[keep] + A @ delta) ** 2)), float(keep.sum() - rank)

    got = _joint._left_out_tests(r, J, owner, members, drop=drop)
    for k in range(members):
        ref = (owner >= 0) & (owner != k)
        if drop is not None and k != drop:
            ref &= owner != drop
        (c_r, d_r), (c, d) = dense(ref), dense(ref | (owner == k))
        f = (c - c_r) / (d - d_r) / (c_r / d_r)
        np.testing.assert_allclose(got[k][0], np.sqrt(f), rtol=1e-9)
    assert got[2][1] < 1e-6 < min(p for k, (_, p) in enumerate(got) if k != 2)


def test_normal_equations_from_the_blocks_equal_those_of_the_dense_jacobian():
    # JᵀJ and Jᵀr from the segments' nonzero blocks (what the solver uses) against the products
    # of the dense matrix laid out block by block by hand here; float64 sums of the same
    # products in another order: 1e-12 relative
    from rbjax.identification import _model

    rng = np.random.default_rng(3)
    S, m, nt, joins = 4, 9, 5, 2
    seg = rng.normal(size=(S, m, nt + 6))
    n = nt + 6 * S
    Jc = rng.normal(size=(6 * joins, n))
    r = rng.normal(size=S * m + 6 * joins)
    dense = np.zeros((S * m, n))
    for s in range(S):
        dense[s * m : (s + 1) * m, :nt] = seg[s, :, :nt]
        dense[s * m : (s + 1) * m, nt + 6 * s : nt + 6 * (s + 1)] = seg[s, :, nt:]
    dense = np.concatenate([dense, Jc])
    G, g = _model.normal_equations(jnp.asarray(r), _model.SegmentJacobian(jnp.asarray(seg), jnp.asarray(Jc), nt))
    np.testing.assert_allclose(G, dense.T @ dense, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(g, dense.T @ r, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(_model.densify(_model.SegmentJacobian(jnp.asarray(seg), jnp.asarray(Jc), nt)), dense)
