"""The exact torque-free solution ``rbjax.torque_free`` (float64 unless stated).

References: scipy DOP853 on Euler's body-frame equations (tests/reference.py,
independent of rbjax), closed forms (sphere, steady spins), conservation laws,
the Newton–Euler right-hand side, finite differences and the flow property.
All single-body calls use the same shapes, so ``torque_free`` compiles once.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import failure_under_default_xla
from reference import reference_rotation

import rbjax

Q0 = np.array([0.3, -0.5, 0.2, 0.7]) / np.linalg.norm([0.3, -0.5, 0.2, 0.7])
NONDIAG = np.array([[2.0, 0.3, -0.2], [0.3, 1.5, 0.1], [-0.2, 0.1, 2.5]])
TIMES = np.linspace(0.0, 15.0, 31)  # ~2.5 turns at |ω| ≈ 1 rad/s, several body-frame periods


def _state(inertia, omega_body, q0=Q0, dtype=np.float64):
    """State with body-frame rate ``omega_body`` (so pure spins are exact in the body frame)."""
    inertia = np.asarray(inertia, dtype)
    w_world = np.asarray(rbjax.quat_rotate(q0, np.asarray(omega_body, np.float64)))
    return rbjax.State.create(
        rbjax.Body(dtype(1.0), inertia), orientation=np.asarray(q0, dtype), angular_velocity=w_world.astype(dtype)
    )


CASES = {
    # moments (1, 2, 3): M² > 2E I2 (about the major axis) and M² < 2E I2 (about the minor axis)
    "major-side": (np.diag([1.0, 2.0, 3.0]), [0.3, 0.2, 1.0]),
    "minor-side": (np.diag([1.0, 2.0, 3.0]), [1.0, 0.2, 0.3]),
    "reversed-labels": (np.diag([3.0, 2.0, 1.0]), [0.3, 0.9, 0.4]),
    "non-diagonal": (NONDIAG, [1.0, -0.5, 0.7]),
    "oblate": (np.diag([1.0, 1.0, 2.0]), [1.0, 0.2, 0.3]),
    "prolate": (np.diag([1.0, 2.0, 2.0]), [1.0, 0.2, 0.3]),
    "sphere": (np.diag([2.0, 2.0, 2.0]), [1.0, 0.2, 0.3]),
    "spin-minor": (np.diag([1.0, 2.0, 3.0]), [1.3, 0.0, 0.0]),
    "spin-middle": (np.diag([1.0, 2.0, 3.0]), [0.0, 1.3, 0.0]),
    "spin-major": (np.diag([1.0, 2.0, 3.0]), [0.0, 0.0, 1.3]),
    "spin-principal-nondiag": (NONDIAG, None),  # about the middle principal axis of NONDIAG
    "at-rest": (np.diag([1.0, 2.0, 3.0]), [0.0, 0.0, 0.0]),
}


def _omega_body(inertia, w):
    if w is not None:
        return np.asarray(w, float)
    _, axes = np.linalg.eigh(inertia)
    return 1.3 * axes[:, 1]


@pytest.mark.parametrize("name", list(CASES))
def test_matches_dop853(name):
    inertia, w = CASES[name]
    wb = _omega_body(inertia, w)
    s = _state(inertia, wb)
    out = rbjax.torque_free(s, TIMES)
    w_world0 = np.asarray(rbjax.angular_velocity(s))
    # DOP853 at rtol 1e-13 errs by up to ~1e-11 in ω over 15 s (measured: at its
    # tightest, rtol = atol = 2.3e-14, it moves toward the closed form by ~10x), so the
    # reference runs at 2.3e-14; then ω to 1e-12 absolute (|ω| ≈ 1 rad/s) and the
    # attitude to 1e-10 rad over 15 s (measured: ~2e-13 for both).
    q_ref, w_ref = reference_rotation(inertia, Q0, w_world0, TIMES, rtol=2.3e-14, atol=2.3e-14)
    # (prolate: 1.2e-12, where the reference still moves by 4e-12 between rtol 1e-13
    # and 2.3e-14; the closed form matches the body-frame regular precession to 5e-16)
    # spin-middle: an unstable equilibrium; the two codes round the initial state
    # differently (~1e-16 off the axis) and the offsets grow as e^{λt}, λ = 0.75/s: x8e4
    atol = 5e-11 if name == "spin-middle" else 2e-12
    np.testing.assert_allclose(rbjax.angular_velocity(out), w_ref, rtol=0, atol=atol)
    assert float(jnp.max(rbjax.quat_angle(out.orientation, q_ref))) < 1e-10
    assert out.orientation.shape == (len(TIMES), 4)


def test_closed_forms_sphere_and_steady_spins():
    # q(t) = exp(ω t) ⊗ q0 for a sphere (any rate) and for a pure spin about any principal
    # axis, including the unstable middle one when the state lies exactly on it (identity
    # attitude: no rounding off the axis). 1e-13: rounding only.
    cases = [(np.diag([2.0, 2.0, 2.0]), [1.0, 0.2, 0.3], Q0)]
    cases += [(np.diag([1.0, 2.0, 3.0]), 1.3 * e, np.array([1.0, 0, 0, 0])) for e in np.eye(3)]
    for inertia, wb, q0 in cases:
        s = _state(inertia, wb, q0=q0)
        w = rbjax.angular_velocity(s)
        q = rbjax.quat_multiply(rbjax.quat_exp(TIMES[:, None] * w), s.orientation)
        out = rbjax.torque_free(s, TIMES)
        assert float(jnp.max(rbjax.quat_angle(out.orientation, q))) < 1e-13


def test_translation_and_conservation():
    s = _state(NONDIAG, [1.0, -0.5, 0.7])
    s = rbjax._pytree.replace(s, position=jnp.array([1.0, 2.0, 3.0]), velocity=jnp.array([0.5, -1.0, 2.0]))
    t = np.linspace(-5.0, 200.0, 31)
    out = rbjax.torque_free(s, t)
    np.testing.assert_allclose(out.position, s.position + t[:, None] * s.velocity, rtol=1e-15, atol=1e-13)
    np.testing.assert_array_equal(out.velocity, np.broadcast_to(s.velocity, (len(t), 3)))
    # world L is a constant of the motion and is carried exactly
    np.testing.assert_array_equal(out.angular_momentum, np.broadcast_to(s.angular_momentum, (len(t), 3)))
    # energy ½ ω·L depends on the attitude relative to L: constant to rounding (1e-13 relative)
    e = rbjax.kinetic_energy(out)
    np.testing.assert_allclose(e, rbjax.kinetic_energy(s), rtol=1e-13)
    # |q| = 1 to rounding
    np.testing.assert_allclose(jnp.linalg.norm(out.orientation, axis=-1), 1.0, atol=1e-15)


def flow_property_holds_to_round_off() -> None:
    # φ_{t2}(φ_{t1}(s)) = φ_{t1+t2}(s): exact for the true solution; tolerance 1e-12 rad
    # at t up to 2000 s (phase rounding ~ eps·|ω|·t ≈ 5e-13), both sides of the separatrix
    for wb in ([0.3, 0.2, 1.0], [1.0, 0.2, 0.3]):
        s = _state(NONDIAG, wb)
        t = np.linspace(0.0, 2000.0, 31)
        direct = rbjax.torque_free(s, t)
        mid = rbjax.torque_free(s, 1234.5)
        composed = rbjax.torque_free(mid, t - 1234.5)
        assert float(jnp.max(rbjax.quat_angle(direct.orientation, composed.orientation))) < 1e-12


@pytest.mark.slow  # a fresh process under XLA's default flags (~8 s)
def test_flow_property_long_horizon():
    # the round-off bound holds for XLA's default (optimised) programs; unoptimised, as the suite
    # compiles (tests/conftest.py), the two sides round differently (1.07e-12 measured)
    failure = failure_under_default_xla("test_torque_free", "flow_property_holds_to_round_off")
    assert failure is None, failure


def _final(inertia, w_world, t):
    """Attitude and world rate at ``t`` from rate ``w_world`` at ``Q0`` (all arguments traced)."""
    s = rbjax.State.create(rbjax.Body(1.0, inertia), orientation=Q0, angular_velocity=w_world)
    out = rbjax.torque_free(s, t)
    return jnp.concatenate([out.orientation, rbjax.angular_velocity(out)])


def _rhs_q(inertia, w_world, t):
    s = rbjax.State.create(rbjax.Body(1.0, inertia), orientation=Q0, angular_velocity=w_world)
    return rbjax.derivative(rbjax.torque_free(s, t), rbjax.Forces()).orientation


# compiled once for all cases: the body is an argument, not a closure constant
_final_jit = jax.jit(_final)
_dt_fwd = jax.jit(jax.vmap(jax.jacfwd(_final, argnums=2), in_axes=(None, None, 0)))
_dt_rev = jax.jit(
    jax.vmap(jax.grad(lambda i, w, t: _final(i, w, t) @ jnp.arange(1.0, 8.0), argnums=2), in_axes=(None, None, 0))
)
_dw_fwd = jax.jit(jax.jacfwd(_final, argnums=1))
_dw_rev = jax.jit(jax.jacrev(_final, argnums=1))
_rhs = jax.jit(jax.vmap(_rhs_q, in_axes=(None, None, 0)))


# every case, the sphere and prolate included: with `--dist loadfile` this module runs in one
# worker, so the programs above compile once and each further case costs well under a second
@pytest.mark.parametrize("name", ["non-diagonal", "oblate", "prolate", "sphere", "spin-major", "at-rest"])
def test_time_derivative_is_newton_euler(name):
    # d/dt of the exact solution (forward-mode AD through sn/cn/dn and Π) equals the
    # Newton-Euler right-hand side at the solution: 1e-12 (rounding in Π' and in AD
    # through the 12-step recurrences, |q'| ≈ 0.5). Reverse mode agrees to 1e-12.
    inertia, w = CASES[name]
    w_world = np.asarray(rbjax.quat_rotate(Q0, _omega_body(inertia, w)))
    t = jnp.asarray(TIMES)
    dq = _dt_fwd(inertia, w_world, t)
    assert np.all(np.isfinite(np.asarray(dq)))
    np.testing.assert_allclose(dq[:, :4], _rhs(inertia, w_world, t), rtol=0, atol=1e-12)
    np.testing.assert_allclose(_dt_rev(inertia, w_world, t), dq @ jnp.arange(1.0, 8.0), rtol=0, atol=1e-12)


_GRAD_CASES = {
    "generic": (NONDIAG, [1.0, -0.5, 0.7]),
    "oblate": (np.diag([1.0, 1.0, 2.0]), [1.0, 0.2, 0.3]),
    "prolate": (np.diag([1.0, 2.0, 2.0]), [1.0, 0.2, 0.3]),
    # a pure spin about the major axis: smooth in ω0 although its polar amplitude is not
    "pure-spin": (np.diag([1.0, 2.0, 3.0]), [0.0, 0.0, 1.3]),
    "at-rest": (np.diag([1.0, 2.0, 3.0]), [0.0, 0.0, 0.0]),
}


@pytest.mark.slow  # compiles jacfwd and jacrev of the exact solution (~35 s on 2 cores)
@pytest.mark.parametrize("name", list(_GRAD_CASES))
def test_gradient_wrt_initial_rate_matches_finite_differences(name):
    inertia, wb = _GRAD_CASES[name]
    t = 7.0
    w0 = np.asarray(rbjax.quat_rotate(Q0, np.asarray(wb)))
    jac = np.asarray(_dw_fwd(inertia, w0, t))
    jac_rev = np.asarray(_dw_rev(inertia, w0, t))
    assert np.all(np.isfinite(jac)) and np.all(np.isfinite(jac_rev))
    h = 1e-5
    f = lambda w: np.asarray(_final_jit(inertia, w, t))
    fd = np.stack([(f(w0 + h * e) - f(w0 - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
    # central differences: truncation h^2 |f'''| ~ 1e-9 (|f'''| ~ t^3 = 350), rounding eps/h ~ 1e-11
    np.testing.assert_allclose(jac, fd, rtol=0, atol=2e-8)
    np.testing.assert_allclose(jac_rev, jac, rtol=0, atol=1e-12)


@pytest.mark.slow  # jacfwd through eigh and the elliptic functions (~20 s)
def test_gradient_wrt_inertia():
    # through eigh (distinct moments): forward AD vs central differences of a symmetric
    # perturbation, 1e-8 absolute (truncation h^2 t^3 with h = 1e-5)
    dI = np.array([[0.3, 0.1, -0.2], [0.1, -0.4, 0.25], [-0.2, 0.25, 0.15]])
    w0 = np.array([1.0, -0.5, 0.7])
    d = jax.jit(jax.jacfwd(lambda eps: _final(NONDIAG + eps * dI, w0, 6.0)))(0.0)
    h = 1e-5
    fd = (_final_jit(NONDIAG + h * dI, w0, 6.0) - _final_jit(NONDIAG - h * dI, w0, 6.0)) / (2 * h)
    np.testing.assert_allclose(d, fd, rtol=0, atol=1e-8)


@pytest.mark.slow  # 100 single-body programs and a vmapped one (~24 s)
def test_batch_equals_single_bodies():
    rng = np.random.default_rng(3)
    n = 100
    moments = np.sort(rng.uniform(0.5, 1.5, (n, 3)), axis=1)
    moments[:10, 1] = moments[:10, 0]  # a few symmetric bodies
    moments[:, 2] = np.minimum(moments[:, 2], 0.99 * (moments[:, 0] + moments[:, 1]))  # triangle inequality
    rot = np.asarray(rbjax.quat_to_matrix(rbjax.quat_normalize(rng.normal(size=(n, 4)))))
    inertia = rot @ (moments[:, :, None] * np.eye(3)) @ np.swapaxes(rot, 1, 2)
    inertia = (inertia + np.swapaxes(inertia, 1, 2)) / 2
    q0 = np.asarray(rbjax.quat_normalize(rng.normal(size=(n, 4))))
    w0 = rng.normal(size=(n, 3))
    w0[-5:] = 0.0  # some at rest
    batch = rbjax.State.create(rbjax.Body(np.ones(n), inertia), orientation=q0, angular_velocity=w0)
    t = np.linspace(0.0, 10.0, 11)
    out = rbjax.torque_free(batch, t)
    assert out.orientation.shape == (len(t), n, 4) and out.body.mass.shape == (len(t), n)
    vm = jax.vmap(lambda s: rbjax.torque_free(s, t).orientation, out_axes=1)(batch)
    # vmap and per-body calls are the same arithmetic up to XLA's fusion choices: 1e-13
    np.testing.assert_allclose(vm, out.orientation, rtol=0, atol=1e-13)
    for i in range(n):
        one = batch[i]
        q_one = rbjax.torque_free(one, t).orientation
        np.testing.assert_allclose(q_one, out.orientation[:, i], rtol=0, atol=1e-13)
    # and each body is exact: energy conserved to 1e-12 relative across the random set
    e0 = np.broadcast_to(rbjax.kinetic_energy(batch), (len(t), n))
    np.testing.assert_allclose(rbjax.kinetic_energy(out), e0, rtol=1e-12, atol=1e-15)


def test_near_separatrix_is_finite_and_accurate():
    # moments (1, 2, 3), m = (0.3, 1, √(3(0.09 + ε))): 1 - m_param ≈ 3ε. Exactly on the
    # separatrix (ε = 0) the parameter is floored; no NaN anywhere, values and gradients.
    inertia = np.diag([1.0, 2.0, 3.0])
    for eps, tol in [(1e-6, 1e-10), (1e-10, 1e-6), (0.0, None)]:
        wb = np.array([0.3, 1.0, np.sqrt(3 * (0.09 + eps))]) / np.array([1.0, 2.0, 3.0])
        s = _state(inertia, wb)
        out = rbjax.torque_free(s, TIMES)
        assert np.all(np.isfinite(np.asarray(out.orientation)))
        g = _dt_fwd(inertia, np.asarray(rbjax.angular_velocity(s)), jnp.asarray(TIMES))
        assert np.all(np.isfinite(np.asarray(g)))
        if tol is not None:
            # error ~ eps/(1 - m) · few (the problem's conditioning; see the docstring table)
            q_ref, _ = reference_rotation(inertia, Q0, np.asarray(rbjax.angular_velocity(s)), TIMES)
            assert float(jnp.max(rbjax.quat_angle(out.orientation, q_ref))) < tol


def test_matrix_state_scalar_time_and_errors():
    s = _state(NONDIAG, [1.0, -0.5, 0.7])
    ms = rbjax.to_matrix_state(s)
    out_m = rbjax.torque_free(ms, 4.0)
    out_s = rbjax.torque_free(s, 4.0)
    assert isinstance(out_m, rbjax.MatrixState) and out_s.orientation.shape == (4,)
    np.testing.assert_allclose(out_m.rotation, rbjax.rotation_matrix(out_s), atol=1e-14)
    with pytest.raises(ValueError, match="1-D"):
        rbjax.torque_free(s, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="finite"):
        rbjax.torque_free(s, np.nan)
    with pytest.raises(TypeError):
        rbjax.torque_free(rbjax.ParticleState.create(1.0), 1.0)


def test_float32():
    # float32 users: the same formula in float32 vs float64, 2e-5 rad over 15 s
    # (phase rounding ~ eps32·|ω|·t·few ≈ 1e-5); no dtype promotion (strict mode).
    s32 = _state(NONDIAG, [1.0, -0.5, 0.7], dtype=np.float32)
    out32 = rbjax.torque_free(s32, TIMES.astype(np.float32))
    assert out32.orientation.dtype == jnp.float32
    out64 = rbjax.torque_free(_state(NONDIAG, [1.0, -0.5, 0.7]), TIMES)
    assert float(jnp.max(rbjax.quat_angle(out32.orientation.astype(jnp.float64), out64.orientation))) < 2e-5
