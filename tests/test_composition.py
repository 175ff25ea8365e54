"""High-order symmetric compositions of "splitting" (splitting4/6/8): weights,
measured order against scipy DOP853, invariants over long horizons, float32,
gradients. float64 unless said."""

from __future__ import annotations

import functools
from decimal import Decimal, getcontext

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.extend.core import jaxprs_in_params
from scipy.spatial.transform import Rotation

import rbjax as rb
from rbjax._methods.composition import COEFFICIENTS
from tests.reference import qrot, quat_angle, reference_rotation

COMPOSED = ["splitting4", "splitting6", "splitting8"]
ORDER = {"splitting4": 4, "splitting6": 6, "splitting8": 8}

_R = Rotation.from_euler("xyz", [0.3, -0.5, 0.8]).as_matrix()
INERTIA = _R @ np.diag([1.0, 2.0, 2.7]) @ _R.T  # generic: principal axes not the body axes
W0 = np.array([0.9, -1.3, 0.6])  # world ω (rad/s), |ω| = 1.7
Q0 = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
TAU_B = np.array([0.2, -0.1, 0.15])  # body-fixed torque (N m)
T = 4.0


def _tau_t(t, xp=np):
    return xp.stack([0.3 * xp.sin(t), 0.2 * xp.cos(2 * t), 0.1 + 0 * t])


# Three copies of the body in one batch: torque-free, a time-varying world torque τ(t),
# and a body-fixed torque (orientation-dependent: the kicks see the rotated state).
CASES = ("free", "tau(t)", "body-fixed")
REF_TORQUES = (None, lambda t, q, w: _tau_t(t), lambda t, q, w: qrot(q, TAU_B))


def _batch_forces(s, t):
    dt = s.dtype
    tau_t = _tau_t(t, jnp).astype(dt)
    tau_b = rb.quat_rotate(s.orientation, jnp.asarray(TAU_B, dt))
    on_t, on_b = jnp.asarray([[0.0], [1.0], [0.0]], dt), jnp.asarray([[0.0], [0.0], [1.0]], dt)
    return rb.Forces(torque=on_t * tau_t + on_b * tau_b)


def _state(dtype=jnp.float64, n=3):  # n = len(CASES)
    body = rb.Body(jnp.ones(n), jnp.broadcast_to(jnp.asarray(INERTIA), (n, 3, 3)))
    s = rb.State.create(body, orientation=Q0, angular_velocity=W0)
    return jax.tree.map(lambda a: a.astype(dtype), s)


@functools.partial(jax.jit, static_argnames=("method", "forces"))
def _run(s, dt, n, *, method, forces=_batch_forces):
    """``n`` steps (traced: one compile per method for every step count)."""
    return jax.lax.fori_loop(0, n, lambda k, x: rb.step(x, forces, dt, method, t0=k * dt), s)


@pytest.fixture(scope="module")
def reference():
    return [reference_rotation(INERTIA, Q0, W0, np.array([0.0, T]), tq) for tq in REF_TORQUES]


def _errors(out, reference):
    """Orientation angle + relative ω error at T per case (float64 arithmetic)."""
    q = np.asarray(out.orientation, np.float64)
    w = np.asarray(rb.angular_velocity(out), np.float64)
    return np.array(
        [
            quat_angle(q[i], qr[-1]) + np.linalg.norm(w[i] - wr[-1]) / np.linalg.norm(wr[-1])
            for i, (qr, wr) in enumerate(reference)
        ]
    )


# --- the weights ----------------------------------------------------------------------


@pytest.mark.parametrize("method", COMPOSED)
def test_weights_are_a_symmetric_composition_of_the_declared_order(method):
    # Exact decimal arithmetic on the published digits (28 significant digits).
    # Palindromic (the composition is symmetric, so its order is even), Σγ = 1
    # (consistency), and the necessary order conditions of a symmetric composition
    # of a symmetric 2nd-order method: Σγ³ = 0 for order 4, also Σγ⁵ = 0 for 6,
    # also Σγ⁷ = 0 for 8 (HLW 2006 §V.3.2). Tolerance 1e-24: the published weights
    # have 26 digits; splitting4's are float64 closed forms (1e-15).
    getcontext().prec = 40
    g = [Decimal(x) for x in COEFFICIENTS[method]]
    assert g == g[::-1]
    tol = Decimal("1e-15") if method == "splitting4" else Decimal("1e-24")
    assert abs(sum(g) - 1) < tol
    for k in range(3, ORDER[method], 2):
        assert abs(sum(x**k for x in g)) < tol, (method, k)
    # and the next odd moment does not vanish (it is small by design: Kahan & Li minimise
    # the error coefficients; s17odr8a has Σγ⁹ = -7.5e-4)
    assert abs(sum(x ** (ORDER[method] + 1) for x in g)) > Decimal("1e-4")
    m = rb.methods()[method]
    assert m.order == ORDER[method]
    assert set(m.steps) == set(rb.methods()["splitting"].steps)  # every state form of the base


# --- measured order -------------------------------------------------------------------

# (n, 2n) step counts over T = 4 s: in the asymptotic range (the local slopes over
# n = 8..256 are flat at the declared order from here on) and with errors 1e-6..1e-9,
# well above the DOP853 reference's ~5e-13.
PAIRS = {"splitting4": 32, "splitting6": 16, "splitting8": 8}


@pytest.mark.parametrize("method", COMPOSED)
def test_measured_order(method, reference):
    # log2(e(n) / e(2n)) within ±0.3 of the declared order, for each case: torque-free
    # tumble, time-varying torque (sub-steps must sample τ at their own times), and an
    # orientation-dependent torque.
    n = PAIRS[method]
    s = _state()
    e1 = _errors(_run(s, T / n, n, method=method), reference)
    e2 = _errors(_run(s, T / (2 * n), 2 * n, method=method), reference)
    observed = np.log2(e1 / e2)
    assert np.all(e2 > 1e-11), e2  # far from the reference's floor
    assert np.all(np.abs(observed - ORDER[method]) < 0.3), dict(zip(CASES, observed, strict=True))


@pytest.mark.parametrize("method", COMPOSED)
def test_particles_measured_order(method):
    # Composed velocity Verlet on x'' = -x (a callable, position-dependent force):
    # exact x(t) = cos t. Over T = 4 with n and 2n steps (n = 16, 8, 4 for orders 4, 6, 8)
    # the errors are 3e-5..3e-8 (measured; asymptotic: slopes 4.01, 6.00, 8.05); observed
    # order within ±0.3 of declared.
    n = {"splitting4": 16, "splitting6": 8, "splitting8": 4}[method]
    spring = lambda s, t: rb.Forces(force=-s.position)
    s = rb.ParticleState.create(1.0, position=[1.0, 0.0, 0.0])
    err = []
    for k in (n, 2 * n):
        out = _run(s, T / k, k, method=method, forces=spring)
        err.append(abs(float(out.position[0]) - np.cos(T)) + abs(float(out.velocity[0]) + np.sin(T)))
    assert abs(np.log2(err[0] / err[1]) - ORDER[method]) < 0.3, err


# --- invariants -----------------------------------------------------------------------


@pytest.mark.parametrize("method", COMPOSED)
def test_torque_free_invariants_over_long_horizon(method):
    # 10 000 steps of dt = 0.2 (dt|ω| = 0.34, T = 2000 s ≈ 500 tumbling periods).
    # World L: bitwise constant (kicks of a zero torque are skipped, the drift never
    # touches L). |q| = 1 to round-off. Energy: symplectic and symmetric, so the error
    # is bounded, O(dt^p), with no drift: the largest error over the last tenth of the
    # run is no more than 1.5x that over the first tenth (a drift of the size of the
    # bounded error per 100 s would grow it 20-fold; rk4 at this step grows 10-fold), and
    # it is O(dt^p): measured 1.9e-6, 1.6e-8, 1.1e-11 for orders 4, 6, 8; bounds 5x that.
    s = _state(n=1)
    steps, every = 10_000, 10
    tr = rb.simulate(s, None, 0.2, steps, method, save_every=every)
    L = np.asarray(tr.angular_momentum)
    assert np.array_equal(L, np.broadcast_to(L[0], L.shape))
    assert np.max(np.abs(np.linalg.norm(np.asarray(tr.orientation), axis=-1) - 1)) < 1e-14
    E = np.asarray(rb.kinetic_energy(tr))[:, 0]
    dE = np.abs(E / E[0] - 1)
    tenth = len(dE) // 10
    first, last = np.max(dE[: tenth + 1]), np.max(dE[-tenth:])
    assert last <= 1.5 * first + 1e-14, (first, last)
    assert np.max(dE) < {4: 1e-5, 6: 1e-7, 8: 5e-11}[ORDER[method]]


# --- float32 --------------------------------------------------------------------------


@pytest.mark.parametrize("method", COMPOSED)
def test_float32_error_at_the_float32_floor(method, reference):
    # At a step where the float64 error is < 1e-8 (truncation is negligible), the float32
    # run errs only by round-off: eps32 = 1.2e-7 per operation, accumulated as a random
    # walk over n steps x s sub-steps x 5 sub-rotations (80 to 100 rotations deep) and
    # amplified by the tumble's sensitivity over |ω| T ≈ 7 rad. Measured 7e-6..7e-5;
    # bound 2e-4 (1700 eps32). For scale: float32 "splitting" and "rk4" at their own
    # float64-accurate steps err 1e-6..1e-3 on the same cases. A truncation error that
    # failed to converge would exceed it; a silent float64 promotion is caught by the
    # strict promotion of conftest.py.
    n = {"splitting4": 256, "splitting6": 64, "splitting8": 32}[method]
    out = _run(_state(jnp.float32), jnp.float32(T / n), n, method=method)
    assert out.orientation.dtype == jnp.float32
    err32 = _errors(out, reference)
    err64 = _errors(_run(_state(), T / n, n, method=method), reference)
    assert np.all(err64 < 1e-8), err64
    assert np.all(err32 < 2e-4), err32


# --- gradients ------------------------------------------------------------------------


def test_gradient_matches_central_differences():
    # Derivative of a scalar of the final state after 10 steps of splitting8 with a
    # time-varying torque, w.r.t. (ω0, inertia scale) along a random direction u: forward
    # mode (jvp) vs the central difference of the loss along u (step 1e-5: truncation
    # ~1e-10, round-off ~1e-16/1e-5 = 1e-11 relative); tolerance 1e-7 relative.
    # (tests/test_gradients.py checks every method, these included, in forward and reverse
    # mode component-wise; forward mode here keeps this file's compile time down.)
    forces = lambda s, t: rb.Forces(torque=_tau_t(t, jnp))

    def loss(x):
        body = rb.Body(jnp.asarray(1.0), x[3] * jnp.asarray(INERTIA))
        s = rb.State.create(body, orientation=Q0, angular_velocity=x[:3])
        tr = rb.simulate(s, forces, 0.1, 10, "splitting8", save_every=10)
        return jnp.dot(tr.orientation[-1], jnp.array([1.0, -2.0, 0.5, 3.0])) + jnp.sum(tr.angular_momentum[-1] ** 2)

    x = jnp.asarray([*W0, 1.2])
    u = jnp.asarray(np.random.default_rng(3).normal(size=4))
    _, du = jax.jvp(loss, (x,), (u,))
    h = 1e-5
    fd = (loss(x + h * u) - loss(x - h * u)) / (2 * h)
    np.testing.assert_allclose(du, fd, rtol=1e-7)


def _sweep_loop_depths(jaxpr, depth=0):
    """The number of loops (scan, while) around each of eigh3's sweep loops (a fori_loop: a scan
    or a while) in ``jaxpr``."""
    found = []
    for eqn in jaxpr.eqns:
        loop = eqn.primitive.name in ("scan", "while")
        if loop and "eigh3" in str(eqn.source_info.name_stack):
            found.append(depth)
            continue
        inner = depth + loop
        for sub in jaxprs_in_params(eqn.params):
            found += _sweep_loop_depths(sub, inner)
    return found


@pytest.mark.parametrize("method", ["splitting", "splitting8"])
def test_principal_frame_is_computed_outside_the_loops(method):
    # The body's eigendecomposition depends only on the body: it must run once per simulate,
    # not once per step (17 per step for splitting8). simulate computes it before its loops
    # (rbjax._body.prepare) rather than leaving XLA to hoist it: XLA:GPU kept it in the loop
    # body (jaxlib 0.11.2, H200), 3-4x the step's own cost. In the program simulate traces, the
    # Jacobi sweeps' loop (named "eigh3") is inside no scan or while; in the compiled program
    # of this backend it sits in the entry computation.
    s = _state()
    f = jax.jit(lambda s: rb.simulate(s, _batch_forces, 0.01, 8, method, save_every=4, native=False))
    depths = _sweep_loop_depths(jax.make_jaxpr(f)(s).jaxpr)
    assert depths == [0], depths
    hlo = f.lower(s).compile().as_text()
    blocks = [b for b in hlo.split("\n\n") if any(" while(" in ln and "eigh3" in ln for ln in b.splitlines())]
    assert blocks, "no eigh3 loop found (has the lowering changed?)"
    assert all(b.lstrip().startswith("ENTRY") for b in blocks), [b.splitlines()[0] for b in blocks]


def test_shoot_computes_the_principal_frame_outside_its_loops():
    # multiple shooting's segments step in their own scans: the frame once, before them, as in simulate
    starts = _state()
    f = jax.jit(lambda s: rb.shoot(s, None, 0.01, 8, "splitting", save_every=4))
    assert _sweep_loop_depths(jax.make_jaxpr(f)(starts).jaxpr) == [0]
