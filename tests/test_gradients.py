"""Derivatives of trajectories: forward and reverse mode vs central differences, for every method.

The inputs cover everything a fit or a controller differentiates: mass and
inertia (the ``Body`` is built inside the differentiated function), the initial
state (orientation as a rotation vector, so perturbations stay unit
quaternions), a per-step force/torque time series, and ``dt``.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb
from rbjax._methods.composition import COEFFICIENTS

# The compositions ("splitting4/6/8") run the registered "splitting" step 5-17 times: the
# differentiated code is the base step's, tested here; tests/test_composition.py checks a
# composed gradient against central differences. Repeating every case for them would add
# minutes of compile time and no new code path. "rk8" is left out too: its 12 unrolled stages
# take ~1-2 min per case to compile under reverse mode on 2 cores (measured 290 s for its four
# cases); tests/test_rk8.py checks its derivative against central differences, and its driver
# given rk4's tableau reproduces "rk4" (tested here) to 1e-13.
METHODS = sorted(set(rb.methods(rb.State)) - set(COEFFICIENTS) - {"rk8"})
# the implicit methods' Newton loops compile for 15-35 s per case under both modes: their
# finite-difference and degenerate-state cases run with --runslow (tests/test_integrators.py
# checks their gradients at symmetric bodies at rest in the quick suite)
HEAVY = [pytest.param(m, marks=pytest.mark.slow) if m.startswith("implicit") else m for m in METHODS]


def _quick_only(quick):
    """``HEAVY``, with every method not in ``quick`` behind ``--runslow`` too.

    Each explicit case compiles jacfwd and jacrev of its scan (12-36 s on 2 cores). The quick
    suite runs finite differences for euler and finiteness at degenerate states for rk4 and the
    symplectic Euler (tests/test_integrators.py checks splitting's and implicit_midpoint's inertia
    gradients against finite differences too); ``--runslow`` runs every pair.
    """
    return [m if not isinstance(m, str) or m in quick else pytest.param(m, marks=pytest.mark.slow) for m in HEAVY]


FD_METHODS = _quick_only({"euler"})
DEGENERATE_METHODS = _quick_only({"rk4", "semi_implicit_euler"})
# checkpointing wraps whichever step it is given in the same segment loop. Its gradient check runs
# reverse mode twice per method (~20 s each): with --runslow, for every method; the quick suite
# checks the option's forward pass in test_checkpoint_with_save_every_and_bad_values
CHECKPOINT = [pytest.param(m, marks=pytest.mark.slow) for m in METHODS]
STEPS = 12


def _final(method, m, I_entries, r0, x0, v0, w0, F, tau, dt, checkpoint=None, steps=STEPS):
    xx, yy, zz, xy, xz, yz = I_entries
    I = jnp.stack([jnp.stack([xx, xy, xz]), jnp.stack([xy, yy, yz]), jnp.stack([xz, yz, zz])])
    body = rb.Body(m, I)
    s = rb.State.create(body, position=x0, velocity=v0, orientation=rb.quat_exp(r0), angular_velocity=w0)
    tr = rb.simulate(s, rb.Forces(force=F, torque=tau), dt, steps, method, checkpoint=checkpoint)
    R = rb.rotation_matrix(tr)[-1]
    return jnp.concatenate([tr.position[-1], tr.velocity[-1], R.ravel(), tr.angular_momentum[-1]])


def _args(seed=0, w0=(0.4, 2.0, -0.3), r0=(0.2, -0.1, 0.3), I=(1.0, 2.0, 2.6, 0.1, -0.05, 0.08)):
    rng = np.random.default_rng(seed)
    return (
        jnp.asarray(1.3),
        jnp.asarray(I),
        jnp.asarray(r0),
        jnp.asarray([0.1, 0.0, -0.2]),
        jnp.asarray([0.5, -0.2, 0.1]),
        jnp.asarray(w0),
        jnp.asarray(rng.normal(0, 1, (STEPS, 3))),
        jnp.asarray(rng.normal(0, 0.5, (STEPS, 3))),
        jnp.asarray(0.02),
    )


class _Derivatives(NamedTuple):
    Jv: np.ndarray  # forward mode: J v, (18,)
    fd: np.ndarray  # the central difference along v, (18,)
    uJ: np.ndarray  # reverse mode: the VJP of u, every argument's components in one vector
    uJ_fwd: np.ndarray  # uᵀJ from the forward-mode J, the same layout
    uJv: float  # reverse mode along v: (uᵀJ) v
    u_fd: float  # u · fd


_FORWARD = {}


def _forward_jacobian(method):
    """``jit`` of ``jacfwd`` of :func:`_final` of ``method`` in all nine arguments: one program per
    method, which the finite-difference and the degenerate-state tests share (their arguments have
    the same shapes and dtypes, as NumPy arrays; only the values differ)."""
    if method not in _FORWARD:
        _FORWARD[method] = jax.jit(jax.jacfwd(lambda *a: _final(method, *a), argnums=tuple(range(9))))
    return _FORWARD[method]


def _derivatives(final, args, jacobian=None) -> _Derivatives:
    """Forward and reverse mode of ``final(*args)`` (a vector) and float64 central differences.

    Forward mode: the full Jacobian ``J`` with respect to every argument (``jit`` of ``jacfwd``),
    applied to a random direction ``v`` in all arguments at once; the central difference of every
    output component along ``v`` (step 1e-4: truncation ~1e-8 relative, so 1e-5 absolute and
    relative, ``jax.test_util.check_grads``' float64 tolerance, has a wide margin). Reverse mode:
    the VJP of a random cotangent ``u``, to be ``uᵀJ`` to round-off in each of the inputs'
    components, and ``uᵀJ v`` against ``u · fd`` as ``check_grads``' reverse check. One compiled
    program per mode, beside the function itself: ``check_grads`` and eager Jacobians compiled each
    mode two or three times, and a reverse-mode Jacobian (18 VJPs) compiles for up to twice as
    long as one VJP.
    """
    final = jax.jit(final)
    # as NumPy arrays (strongly typed): the perturbed points below then run the same program
    args = [np.asarray(a) for a in args]
    argnums = tuple(range(len(args)))
    rng = np.random.default_rng(1)
    v = [rng.normal(size=np.shape(a)) for a in args]
    u = rng.normal(size=final(*args).shape)
    J = (jacobian or jax.jit(jax.jacfwd(final, argnums=argnums)))(*args)
    uJ = jax.jit(lambda *a: jax.vjp(final, *a)[1](u))(*args)
    eps = 1e-4  # perturbed in NumPy: no eager JAX operation (each a compile of its own)
    fd = (final(*(a + eps * d for a, d in zip(args, v))) - final(*(a - eps * d for a, d in zip(args, v)))) / (2 * eps)
    flat = lambda parts: np.concatenate([np.ravel(p) for p in parts])
    return _Derivatives(
        Jv=sum(np.tensordot(Ji, d, axes=d.ndim) for Ji, d in zip(J, v, strict=True)),
        fd=np.asarray(fd),
        uJ=flat(uJ),
        uJ_fwd=flat(np.tensordot(u, Ji, axes=1) for Ji in J),
        uJv=float(flat(uJ) @ flat(v)),
        u_fd=float(u @ fd),
    )


@pytest.mark.parametrize("method", FD_METHODS)
def test_fwd_and_rev_match_finite_differences(method):
    d = _derivatives(lambda *a: _final(method, *a), _args(), _forward_jacobian(method))
    np.testing.assert_allclose(d.Jv, d.fd, rtol=1e-5, atol=1e-5)  # forward mode: central differences
    np.testing.assert_allclose(d.uJ, d.uJ_fwd, rtol=1e-10, atol=1e-12)  # reverse = forward, to round-off
    np.testing.assert_allclose(d.uJv, d.u_fd, rtol=1e-5, atol=1e-5)  # reverse mode: central differences


@pytest.mark.parametrize("method", DEGENERATE_METHODS)
def test_gradients_finite_at_degenerate_states(method):
    # zero angular velocity, identity orientation, a sphere (three equal moments), and q -> -q
    sphere = (0.4, 0.4, 0.4, 0.0, 0.0, 0.0)
    a = _args(w0=(0.0, 0.0, 0.0), r0=(0.0, 0.0, 0.0), I=sphere)
    # as NumPy arrays, the finite-difference test's types: the same forward-mode program
    a = [np.asarray(x) for x in a[:6] + (jnp.zeros((STEPS, 3)), jnp.zeros((STEPS, 3))) + a[8:]]
    grads = jax.jacrev(lambda *x: _final(method, *x), argnums=tuple(range(9)))(*a)
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grads))
    fwd = _forward_jacobian(method)(*a)
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(fwd))
    # at rest nothing moves: d(final L)/d(w0) = I (world = body frame here), exactly
    np.testing.assert_allclose(fwd[5][-3:], 0.4 * np.eye(3), atol=1e-14)


@pytest.mark.parametrize("method", METHODS)
def test_sign_of_quaternion_does_not_change_gradients(method):
    a = _args()
    q0 = rb.quat_exp(a[2])

    def final_R(w0, q0):
        s = rb.State.create(rb.Body(a[0], jnp.diag(a[1][:3])), orientation=q0, angular_velocity=w0)
        return rb.rotation_matrix(rb.simulate(s, None, a[8], STEPS, method))[-1]

    jac = jax.jit(jax.jacfwd(final_R))  # one program for both signs
    Jp = jac(a[5], q0)
    Jm = jac(a[5], -q0)
    assert np.all(np.isfinite(Jm))
    # R(q) = R(-q) and every update is odd in q: identical to round-off
    np.testing.assert_allclose(Jp, Jm, rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("method", CHECKPOINT)
def test_checkpointing_gives_the_same_gradient(method):
    steps = 48
    rng = np.random.default_rng(2)
    a = _args()[:6] + (
        jnp.asarray(rng.normal(0, 1, (steps, 3))),
        jnp.asarray(rng.normal(0, 0.5, (steps, 3))),
        jnp.asarray(0.02),
    )

    def loss(ck, *x):
        return jnp.sum(_final(method, *x, checkpoint=ck, steps=steps) ** 2)

    # inertia, initial rotation, initial spin, torque series, dt
    args = (1, 2, 5, 7, 8)
    # jitted: an eager grad compiles the scan's forward and backward passes and each small
    # operation around them on its own
    g0 = jax.jit(jax.grad(lambda *x: loss(None, *x), argnums=args))(*a)
    g = jax.jit(jax.grad(lambda *x: loss(12, *x), argnums=args))(*a)
    for x, y in zip(jax.tree.leaves(g), jax.tree.leaves(g0), strict=True):
        # the same arithmetic recomputed: equal up to XLA re-association, ~1e-15 relative
        np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-14)


def test_checkpoint_with_save_every_and_bad_values():
    s = rb.State.create(rb.box(1.0, jnp.array([1.0, 2.0, 3.0])), angular_velocity=jnp.array([0.1, 2.0, 0.1]))
    # checkpointing segments the JAX steps: bitwise those of the JAX path (the native kernel agrees
    # with them to round-off, tests/test_native.py)
    full = rb.simulate(s, None, 0.01, 40, "rk4", save_every=10, native=False)
    for ck in (2, 5, 20, 40):  # divides save_every, or a multiple of it
        np.testing.assert_array_equal(
            rb.simulate(s, None, 0.01, 40, "rk4", save_every=10, checkpoint=ck).orientation, full.orientation
        )
    for bad in (0, 3, 15, 2.0):
        with pytest.raises(ValueError, match="checkpoint"):
            rb.simulate(s, None, 0.01, 40, "rk4", save_every=10, checkpoint=bad)


# two reverse-mode compiles of a 1024-step rk4 scan (~20 s): with --runslow;
# benchmarks/grad_memory.py measures the same saving up to 1e5 steps
@pytest.mark.slow
def test_checkpoint_reduces_compiled_memory():
    def loss(w, ck):
        body = rb.box(1.0, jnp.array([1.0, 2.0, 3.0]))
        s = rb.State.create(body, angular_velocity=jnp.broadcast_to(w, (8, 3)))
        q = rb.simulate(s, None, 1e-3, 1024, "rk4", save_every=1024, checkpoint=ck).orientation
        return jnp.sum(q[-1] * jnp.arange(4.0))  # torque-free L is constant: use the orientation

    w = jnp.array([0.1, 2.0, 0.1])
    mem = {
        ck: jax.jit(jax.grad(loss), static_argnums=1).lower(w, ck).compile().memory_analysis().temp_size_in_bytes
        for ck in (None, 32)
    }
    # 1024 steps stored vs 32 boundaries + one 32-step segment: ~16x less; assert 5x
    assert mem[32] * 5 < mem[None], mem


# Bodies where the principal axes are not determined by the inertia: the gradient must not depend
# on eigenvector derivatives there (eigh's is NaN; a fixed frame misses the perturbations that
# split equal moments). A generic body is the control.
SYMMETRIC_BODIES = {
    "sphere": (2.5, 2.5, 2.5),
    "oblate top": (2.0, 2.0, 3.0),
    "prolate top": (2.0, 3.0, 3.0),
    "generic": (1.3, 2.1, 2.9),
}
# each method's inertia gradient at all four bodies is one compiled program (the inertia is an
# argument); the quick suite runs the methods whose frame handling differs (splitting's principal
# frame, rk4's world frame, the symplectic Euler's body-frame solve), the others with --runslow
QUICK_SYMMETRIC = {"splitting", "rk4", "semi_implicit_euler"}
ALL_METHODS = [m if m in QUICK_SYMMETRIC else pytest.param(m, marks=pytest.mark.slow) for m in sorted(rb.methods())]
_DIRECTION = np.random.default_rng(7).normal(size=(3, 3))
DIRECTION = jnp.asarray(_DIRECTION + _DIRECTION.T)  # every entry, the ones that split equal moments too
WEIGHTS = jnp.asarray(np.random.default_rng(8).normal(size=4))


def _symmetric_loss(final_orientation):
    """A scalar of the final orientation of a body of inertia ``I`` given its ω₀ (so L₀ = I ω₀)."""

    def loss(I):
        s = rb.State.create(rb.Body(1.0, I), angular_velocity=[0.4, 1.5, -0.3], orientation=rb.quat_exp([0.3, 0, 0.1]))
        return jnp.dot(WEIGHTS, final_orientation(s))

    return jax.jit(loss), jax.jit(jax.grad(loss))


def _gradient_and_central_difference(loss, grad, moments):
    """The directional derivative along ``DIRECTION`` by ``grad`` and by central differences."""
    I = jnp.diag(jnp.asarray(moments))
    g = grad(I)
    h = 1e-5
    fd = (loss(I + h * DIRECTION) - loss(I - h * DIRECTION)) / (2 * h)
    return float(jnp.sum(g * DIRECTION)), float(fd)


@pytest.mark.parametrize("method", ALL_METHODS)
def test_inertia_gradient_at_symmetric_bodies(method):
    # 2 s at dt = 0.02. The central difference (h = 1e-5, float64) has truncation ~h² |f'''| ~ 1e-10
    # and round-off ~eps/h ~ 1e-11, so 1e-7 leaves a wide margin. At equal moments the splitting
    # methods' maps have a kink (which axis is "middle" flips with the perturbation's sign) of the
    # size of their own O(dt²) error; the central difference averages the two sides, which agree
    # with the exact flow's derivative to that error: 2e-4 covers splitting's (dt |ω| = 0.03, 100
    # steps) with a margin of ~10 and still fails the frame-fixed gradient (off by 0.3 or more).
    steps = 100
    final = lambda s: rb.simulate(s, None, 0.02, steps, method, save_every=steps).orientation[-1]
    loss, grad = _symmetric_loss(final)
    for name, moments in SYMMETRIC_BODIES.items():
        tol = 2e-4 if method.startswith("splitting") and name != "generic" else 1e-7
        ad, fd = _gradient_and_central_difference(loss, grad, moments)
        assert abs(ad - fd) <= tol * (1 + abs(fd)), (name, ad, fd)


@pytest.mark.slow
def test_torque_free_inertia_gradient_at_symmetric_bodies():
    # the exact solution is smooth in the inertia: its gradient is the central difference's to the
    # difference's own error (~1e-10, see above) at every body. Slow: reverse mode through the
    # closed form's custom JVP (four evaluations) compiles for ~30 s on 2 cores
    loss, grad = _symmetric_loss(lambda s: rb.torque_free(s, 2.0).orientation)
    for name, moments in SYMMETRIC_BODIES.items():
        ad, fd = _gradient_and_central_difference(loss, grad, moments)
        assert abs(ad - fd) <= 1e-7 * (1 + abs(fd)), (name, ad, fd)


def _final_matrix(method, m, I_entries, r0, x0, v0, w0, F, tau, dt):
    xx, yy, zz, xy, xz, yz = I_entries
    I = jnp.stack([jnp.stack([xx, xy, xz]), jnp.stack([xy, yy, yz]), jnp.stack([xz, yz, zz])])
    s = rb.MatrixState.create(
        rb.Body(m, I), position=x0, velocity=v0, orientation=rb.quat_to_matrix(rb.quat_exp(r0)), angular_velocity=w0
    )
    tr = rb.simulate(s, rb.Forces(force=F, torque=tau), dt, STEPS, method)
    return jnp.concatenate([tr.position[-1], tr.velocity[-1], tr.rotation[-1].ravel(), tr.angular_velocity[-1]])


@pytest.mark.parametrize("method", ["euler", *(pytest.param(m, marks=pytest.mark.slow) for m in ("rk4", "rk8"))])
def test_matrix_state_gradients_match_finite_differences(method):
    # The (x, v, R, ω) form has its own rates (rbjax._dynamics.matrix_rates, ω̇ in the body
    # frame) and projection (R re-orthonormalised): both modes against float64 central
    # differences with step 1e-4 (truncation ~1e-8 relative; check_grads' float64 tolerance
    # 1e-5), with respect to mass, inertia, initial state, the force/torque series and dt
    # (:func:`_derivatives`).
    d = _derivatives(lambda *a: _final_matrix(method, *a), _args())
    np.testing.assert_allclose(d.Jv, d.fd, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(d.uJ, d.uJ_fwd, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(d.uJv, d.u_fd, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("method", [None, "euler"])
def test_matrix_state_reverse_pass_stores_each_rotation_entry_once(method):
    # Reverse mode stores every slice a product reads as a residual of its own, and a scan stacks
    # each one per step: the rates read R's entries from one set of slices (rbjax._math.entries3),
    # where three slicings of R (Rᵀ ω, R (...), ω̃ R) stored each entry three times and made a VJP
    # through 12 rk8 steps compile for 36 s instead of 21 s (XLA's defaults;
    # benchmarks/results/matrix_rates_residuals_ab_2026-12-05.md). A structural check, not a
    # timing: the residuals of one evaluation of the rates (and of one "euler" step) hold each of
    # R's nine entries (distinct values) exactly once; the three slicings give 3 for each.
    rng = np.random.default_rng(3)
    R = np.asarray(rb.quat_to_matrix(rb.quat_normalize(rng.normal(size=4))))
    I = np.array([[1.0, 0.1, -0.05], [0.1, 2.0, 0.08], [-0.05, 0.08, 2.6]])
    s = rb.MatrixState.create(rb.Body(1.0, I), orientation=R, angular_velocity=rng.normal(size=3))
    forces = rb.Forces(torque=jnp.asarray(rng.normal(size=3)))
    fn = (lambda s: rb.derivative(s, forces)) if method is None else (lambda s: rb.step(s, forces, 1e-3, method))
    _, pullback = jax.vjp(fn, s)
    residuals = [np.asarray(leaf) for leaf in jax.tree.leaves(pullback)]
    stored = [sum(int(np.sum(leaf == r)) for leaf in residuals) for r in R.ravel()]
    assert stored == [1] * 9, stored
