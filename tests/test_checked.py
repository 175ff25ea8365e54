"""Checked mode: failures name the step and the body, sound runs are unchanged, off is free."""

from __future__ import annotations

import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import failure_under_default_xla

import rbjax as rb

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DT = 0.01
N = 5


def _state(dtype=jnp.float64):
    rng = np.random.default_rng(11)
    body = rb.box(jnp.asarray(rng.uniform(0.5, 2, N), dtype), jnp.asarray(rng.uniform(0.3, 1.5, (N, 3)), dtype))
    return rb.State.create(body, angular_velocity=jnp.asarray(rng.normal(size=(N, 3)), dtype))


def _nan_force_on(body: int, from_step: int):
    """Force that turns NaN on one body from the step starting at t = from_step·dt (0-based)."""

    def forces(state, t):
        bad = jnp.where(t > (from_step - 0.5) * DT, jnp.nan, 0.0).astype(state.dtype)
        return rb.Forces(force=jnp.zeros(state.position.shape, state.dtype).at[body, 0].set(bad))

    return forces


NAN_ON_3_AT_7 = _nan_force_on(3, 7)


def test_nan_names_step_and_body_eagerly_and_under_jit():
    s = _state()
    # the step from t = 7 dt (0-based step 7) produces the state at t = 8 dt: "step 8", body 3
    want = r"at step 8 \(time t0 \+ 8·dt\), body \(3,\) of batch shape \(5,\): the state became non-finite"
    with pytest.raises(Exception, match=want):
        rb.simulate(s, NAN_ON_3_AT_7, DT, 20, "euler", checked=True)
    with pytest.raises(Exception, match=want):
        jax.block_until_ready(jax.jit(lambda s: rb.simulate(s, NAN_ON_3_AT_7, DT, 20, "euler", checked=True))(s))
    # the saved frames do not matter: the step is exact even between saves
    with pytest.raises(Exception, match=want):
        rb.simulate(s, NAN_ON_3_AT_7, DT, 20, "euler", save_every=5, checked=True)
    # unchecked, the same run silently returns NaN for body 3 from frame 8 on, and only there
    traj = rb.simulate(s, NAN_ON_3_AT_7, DT, 20, "euler")
    bad = ~np.isfinite(np.asarray(traj.velocity)).all(axis=-1)
    assert np.argwhere(bad)[0].tolist() == [8, 3] and bad[:, [0, 1, 2, 4]].sum() == 0


def test_chunked_errors_name_the_absolute_step():
    s = _state()
    with pytest.raises(Exception, match=r"at step 8 \(time t0 \+ 8·dt\), body \(3,\)"):
        rb.simulate_chunked(s, NAN_ON_3_AT_7, DT, 20, "euler", chunk_steps=5, progress=False, checked=True)


def test_explicit_euler_blow_up_in_the_matrix_form():
    # (x, v, R, ω) Euler with ω dt ~ 10: R + ω̃R dt is far from SO(3) and two Newton–Schulz
    # iterations cannot restore it, so step 1 already leaves SO(3) (unchecked: it later overflows)
    m = rb.to_matrix_state(_state())
    w = rb.angular_velocity(m)
    fast = rb._pytree.replace(m, angular_velocity=w.at[2].multiply(1e3))  # only body 2 spins fast
    with (
        pytest.warns(rb.StepSizeWarning, match=r"body \(2,\)"),
        pytest.raises(Exception, match=r"at step 1 .*body \(2,\).*left the unit sphere / SO\(3\)"),
    ):
        rb.simulate(fast, None, DT, 50, "euler", checked=True)


def test_energy_jump_is_reported_at_the_saved_step():
    s = _state()

    def kick(state, t):  # impulse on body 1 in step 12: |ΔL| = 1e4·dt·√3 ≈ 170 against |L| ~ 1
        on = jnp.where(jnp.abs(t - 12 * DT) < 0.5 * DT, 1e4, 0.0).astype(state.dtype)
        return rb.Forces(torque=jnp.zeros(state.position.shape, state.dtype).at[1].set(on))

    # the kick also spins body 1 past half a turn per step (max_turn fails at step 13): off here,
    # for this test of the energy check
    with pytest.raises(
        Exception, match=r"at step 15 .*body \(1,\).*kinetic energy jumped by more than energy_factor=100"
    ):
        rb.simulate(s, kick, DT, 30, "euler", save_every=5, checked=rb.Checks(max_turn=None))
    # a looser factor lets the same run through: the check is the only thing that failed
    loose = rb.Checks(energy_factor=1e9, max_turn=None)
    traj = rb.simulate(s, kick, DT, 30, "euler", save_every=5, checked=loose)
    assert np.isfinite(np.asarray(traj.angular_momentum)).all()


def sound_runs_are_bitwise_unchecked(dtype) -> None:
    """A sound run's checked trajectory is bitwise the unchecked one (``AssertionError`` otherwise)."""
    s = _state(dtype)
    gravity = rb.Forces.gravity(s)  # from rest translationally: energy starts at rotation only
    # the matrix form in float64 only, to keep compilations few
    for state in (s,) if dtype == jnp.float32 else (rb.to_matrix_state(s),):
        # checked mode tests the JAX steps (the native kernel agrees with them to round-off,
        # tests/test_native.py)
        plain = rb.simulate(state, gravity, DT, 40, "euler", save_every=4, native=False)
        checked = rb.simulate(state, gravity, DT, 40, "euler", save_every=4, checked=True)
        # the checks only read the state: bitwise the same trajectory
        for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(checked), strict=True):
            assert a.dtype == b.dtype and np.asarray(a).tobytes() == np.asarray(b).tobytes()


def sound_runs_are_bitwise_unchecked_in_both_dtypes() -> None:
    sound_runs_are_bitwise_unchecked(jnp.float32)
    sound_runs_are_bitwise_unchecked(jnp.float64)


@pytest.mark.slow  # a fresh process under XLA's default flags, every method checked and unchecked (~9 s)
def test_sound_runs_pass_and_equal_the_unchecked_result():
    # Bitwise equality is a property of the programs XLA compiles by default, not of the suite's
    # fast-compile flags (tests/conftest.py): checked in a process with XLA's default flags.
    failure = failure_under_default_xla("test_checked", "sound_runs_are_bitwise_unchecked_in_both_dtypes")
    assert failure is None, failure
    # a particle dropped from exact rest: E = 0 initially is not above the floor, then grows ∝ t²
    p = rb.ParticleState.create(jnp.ones(3))
    rb.simulate(p, rb.Forces.gravity(p), DT, 40, "euler", checked=True)


def test_off_compiles_no_checks():
    s = _state()

    def jaxpr(checked):
        return str(jax.make_jaxpr(lambda s: rb.simulate(s, None, DT, 10, "euler", checked=checked))(s))

    off, on = jaxpr(False), jaxpr(True)
    assert "callback" not in off and "cond" not in off and "is_finite" not in off
    assert "callback" in on and "is_finite" in on
    # off is the default: the same program, not merely an equivalent one
    assert off == str(jax.make_jaxpr(lambda s: rb.simulate(s, None, DT, 10, "euler"))(s))


def test_checks_validation():
    for bad in (dict(energy_factor=1.0), dict(energy_floor=-1.0), dict(quat_tol=0.0)):
        with pytest.raises(ValueError, match="Checks:"):
            rb.Checks(**bad)
    with pytest.raises(TypeError, match="checked must be a bool or rbjax.Checks"):
        rb.simulate(_state(), None, DT, 2, checked="yes")


def test_checks_without_energy_still_report_and_errors_are_plain_value_errors():
    # energy_factor=None used to fail while formatting the message (None:g) and hide the failure
    s = _state()
    want = r"^rbjax.simulate\(checked=...\): at step 8 .*body \(3,\).*non-finite"
    with pytest.raises(ValueError, match=want):
        rb.simulate(s, NAN_ON_3_AT_7, DT, 20, "euler", checked=rb.Checks(energy_factor=None))


def test_under_jax_jit_the_message_is_on_its_own_line_with_the_remedy():
    s = _state()
    run = lambda s: rb.simulate(s, NAN_ON_3_AT_7, DT, 20, "euler", checked=rb.Checks(energy_factor=None))
    with pytest.raises(Exception) as info:
        jax.block_until_ready(jax.jit(run)(s))
    lines = str(info.value).splitlines()
    # rbjax's message is a whole line (not glued to a traceback frame), followed by how to unwrap it
    i = next(i for i, line in enumerate(lines) if line.startswith("rbjax.simulate(checked=...): at step 8"))
    assert "body (3,)" in lines[i] and "non-finite" in lines[i]
    assert "equinox.filter_jit" in lines[i + 1]
    # equinox.filter_jit unwraps it into its own error type, rbjax's message on a line of its own
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"(?m)^rbjax.simulate\(checked=...\): at step 8 .*body \(3,\)"):
        jax.block_until_ready(eqx.filter_jit(run)(s))


@pytest.mark.parametrize("bad", [-0.01, 0.0, float("nan"), float("inf")])
def test_traced_bad_dt_is_caught_in_checked_mode(bad):
    s = _state()
    run = jax.jit(lambda dt: rb.simulate(s, None, dt, 3, "euler", checked=True).position)
    with pytest.raises(Exception, match=r"simulate\(checked=...\): dt must be finite and > 0"):
        jax.block_until_ready(run(bad))
    # the same compiled program accepts a sound dt: the check is on the value, not the trace
    assert np.isfinite(np.asarray(run(DT))).all()


def test_traced_non_finite_t0_is_caught_in_checked_mode():
    s = _state()
    run = jax.jit(lambda t0: rb.simulate(s, None, DT, 3, "euler", t0=t0, checked=True).position)
    with pytest.raises(Exception, match=r"t0 must be finite"):
        jax.block_until_ready(run(jnp.nan))


def test_divergence_message_quotes_the_measured_stability_limit():
    # rk4 goes NaN on the first step at dt·|ω| = 100; checked mode names the step and body
    # and quotes the measured limit (benchmarks/stability_limits.py) stored on the Method
    assert rb.methods()["rk4"].stable_dt_omega == {"State": 7.5, "MatrixState": 1.0, "ParticleState": np.inf}
    s = rb.State.create(rb.box(1.0, [0.1, 0.2, 0.4]), angular_velocity=jnp.array([0.3, 100.0, 0.3]))
    with (
        pytest.warns(rb.StepSizeWarning, match=r"dt·\|ω\| = 100 rad"),
        pytest.raises(ValueError, match=r"at step 1 .*the body: .*dt·\|ω\| = 100 before .*beyond .* ≈ 7.5 for State"),
    ):
        rb.simulate(s, None, 1.0, 10, "rk4", checked=True)
    with pytest.warns(rb.StepSizeWarning):  # unchecked: the warning is what is said
        traj = rb.simulate(s, None, 1.0, 10, "rk4")
    q1 = np.asarray(traj.orientation[1])
    assert not (np.isfinite(q1).all() and abs(np.linalg.norm(q1) - 1) < 1e-6)


@pytest.mark.parametrize("form", ["State", "MatrixState"])
def test_a_stiff_spring_is_not_blamed_on_the_rotation(form):
    # two spheres that never turn, joined by a spring with dt·sqrt(k/m) = 0.05·sqrt(1e4 / 0.5) ≈ 7:
    # explicit Euler blows up from the spring's stiffness. The message said "euler diverges beyond
    # dt·|ω| ≈ 0.13 (MatrixState)" for either form; it names the stiffness now, and the rotation
    # limit only for a body that turns fast, and for its own form
    body = rb.sphere(jnp.ones(2), jnp.full(2, 0.1))
    s = rb.State.create(body, position=jnp.array([[0.0, 0, 0], [1.0, 0, 0]]))
    s = s if form == "State" else rb.to_matrix_state(s)
    spring = rb.Spring.between(jnp.array([0]), jnp.array([1]), 1e4, rest_length=0.5)
    with pytest.raises(ValueError) as info:
        rb.simulate(s, spring, 0.05, 400, "euler", checked=True)
    message = str(info.value)
    assert "body (0,)" in message and "a force law may be too stiff for dt" in message, message
    assert "diverges beyond" not in message and "(MatrixState)" not in message, message
    # a fast tumble in the matrix form is the rotation's doing, and says so for MatrixState
    fast = rb.to_matrix_state(
        rb.State.create(rb.box(1.0, [0.1, 0.2, 0.4]), angular_velocity=jnp.array([0.3, 50.0, 0.3]))
    )
    with (
        pytest.warns(rb.StepSizeWarning, match=r"beyond where 'euler' diverges for MatrixState"),
        pytest.raises(ValueError, match=r"dt·\|ω\| = 0.5 before the failure\. .*≈ 0.13 for MatrixState"),
    ):
        rb.simulate(fast, None, 0.01, 400, "euler", checked=True, save_every=10)
