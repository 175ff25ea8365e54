"""The native CPU kernels (rbjax/_native) against the JAX reference they mirror.

Both paths evaluate the same maps; they round differently: the kernel builds
the rotation matrix of ``q`` once where JAX rotates twice, multiplies by ``1/m``,
takes ``sin`` and ``cos`` from its own polynomials, fuses other multiply-adds
than XLA does, sums ``‖v‖`` and ``‖ω‖`` in another order and terms of one kind
(two ``Gravity``) before the others. Each step then adds a few ulps, and the
states drift apart at most linearly in the number of steps: the tolerance is
``8 · steps · eps`` of each field's scale, a bound the measured differences
(at most 3.9 steps · eps, rk4_body float32, 130 bodies, 24 steps) stay inside,
and which an error in any formula (a wrong sign, a missed term, a transposed
inertia) exceeds by orders of magnitude.
"""

import os
import shutil
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb
from rbjax import _native

# these tests run "splitting" under drag on purpose (paths held to each other, inputs refused):
# its first order there is tests/test_force_protocol.py's to check
pytestmark = pytest.mark.filterwarnings("ignore::rbjax.OrderWarning")

STEPS, SAVE = 24, 6

needs_kernels = pytest.mark.skipif(not rb.native_status().available, reason="native kernels not built")


def test_kernels_are_built_where_a_compiler_is():
    # CI has g++: a build that silently failed would otherwise skip every case below
    status = rb.native_status()
    if shutil.which("g++") or shutil.which("c++"):
        assert status.available, str(status)
        assert status.instruction_set in ("x86-64 baseline", "AVX2", "AVX-512")
    assert ("loaded from" if status.available else "not available") in str(status)


def _state(batch, dtype, shared_body=False, seed=0):
    rng = np.random.default_rng(seed)
    n = int(np.prod(batch, dtype=int))

    def arr(*shape, scale=1.0):
        return jnp.asarray(rng.normal(size=batch + shape) * scale, dtype)

    if shared_body:
        body = rb.Body(
            jnp.asarray(1.3, dtype), jnp.asarray([[1.0, 0.1, -0.05], [0.1, 2.0, 0.08], [-0.05, 0.08, 2.6]], dtype)
        )
    else:
        masses = jnp.asarray(rng.uniform(0.5, 2.0, batch), dtype)
        body = rb.box(masses, jnp.asarray(rng.uniform(0.1, 1.0, batch + (3,)), dtype))
    q = rb.quat_normalize(arr(4)) if n else jnp.zeros(batch + (4,), dtype)
    return rb.State.create(body, position=arr(3), velocity=arr(3), orientation=q, angular_velocity=arr(3, scale=3.0))


def _forces(kind, batch, dtype):
    rng = np.random.default_rng(1)
    if kind == "none":
        return None
    if kind == "constant":
        return rb.Forces(
            force=jnp.asarray([0.3, -0.2, 1.0], dtype), torque=jnp.asarray(rng.normal(size=batch + (3,)), dtype)
        )
    if kind == "gravity+quadratic":
        return rb.Gravity() + rb.QuadraticDrag(0.05, 0.01)
    # per-body coefficients, every term of the kernel, and two of one kind
    per_body = jnp.asarray(rng.uniform(0.0, 0.2, batch), dtype)
    g = jnp.asarray(rng.normal(size=batch + (3,)), dtype)
    return (
        rb.LinearDrag(per_body, 0.02)
        + rb.Gravity(g)
        + rb.ConstantForce(torque=jnp.asarray([0.1, 0.0, -0.3], dtype))
        + rb.QuadraticDrag(0.03, per_body)
        + rb.Gravity()
    )


def _assert_close(a, b, steps, dtype, case=""):
    eps = float(jnp.finfo(dtype).eps)
    for f in ("position", "velocity", "orientation", "angular_momentum", "time"):
        x, y = np.asarray(getattr(a, f), np.float64), np.asarray(getattr(b, f), np.float64)
        scale = max(1.0, float(np.max(np.abs(y), initial=0.0)))
        np.testing.assert_allclose(x, y, rtol=0, atol=8 * steps * eps * scale, err_msg=f"{case} {f}".strip())


def _both(state, forces, method, **kw):
    nat = rb.simulate(state, forces, 1e-2, STEPS, method, save_every=SAVE, native=True, **kw)
    ref = rb.simulate(state, forces, 1e-2, STEPS, method, save_every=SAVE, native=False, **kw)
    return nat, ref


@needs_kernels
@pytest.mark.parametrize("method", sorted(_native.METHODS))
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
# "gravity+quadratic" with --runslow: "every term" has both laws (per-body and shared coefficients)
@pytest.mark.parametrize(
    "forces", ["none", "constant", pytest.param("gravity+quadratic", marks=pytest.mark.slow), "every term"]
)
def test_native_matches_jax(method, dtype, forces):
    state = _state((7,), dtype)
    nat, ref = _both(state, _forces(forces, (7,), dtype), method)
    _assert_close(nat, ref, STEPS, dtype)


# one body, a batch of one, two batch axes, three blocks of 64 bodies; the quick suite runs two
SHAPES = [
    pytest.param(b, shared, marks=() if (b, shared) in {((2, 3), True), ((130,), False)} else pytest.mark.slow)
    for b in [(), (1,), (2, 3), (130,)]
    for shared in (False, True)
]


@needs_kernels
@pytest.mark.parametrize("method", sorted(_native.METHODS))
@pytest.mark.parametrize(("batch", "shared_body"), SHAPES)
def test_native_matches_jax_over_batch_shapes_and_shared_bodies(method, batch, shared_body):
    state = _state(batch, jnp.float64, shared_body)
    nat, ref = _both(state, _forces("every term", batch, jnp.float64), method)
    _assert_close(nat, ref, STEPS, jnp.float64)


def _both_branches(dtype):
    """Eight bodies spinning at 0 to 10 rad/s: one block on both sides of quat_exp's series switch."""
    state = _state((8,), dtype)
    rates = jnp.asarray([0.0, 1e-7, 1e-5, 1e-3, 0.1, 1.0, 3.0, 10.0], dtype)
    direction = rb.quat_normalize(jnp.asarray(np.random.default_rng(2).normal(size=(8, 4)), dtype))[:, 1:]
    return rb.State.create(state.body, orientation=state.orientation, angular_velocity=rates[:, None] * direction)


@needs_kernels
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_native_quat_exp_takes_both_branches(dtype):
    # quat_exp switches to its series below θ² = √eps: rates from 0 to 10 rad/s put bodies of
    # one block on both sides of the switch in either dtype
    nat, ref = _both(_both_branches(dtype), _forces("every term", (8,), dtype), "semi_implicit_euler")
    _assert_close(nat, ref, STEPS, dtype)


@needs_kernels
def test_native_under_jit_vmap_and_chunked_runs(tmp_path):
    state = _state((4,), jnp.float64)
    forces = _forces("gravity+quadratic", (4,), jnp.float64)
    run = lambda s, native: rb.simulate(s, forces, 1e-2, STEPS, "rk4", save_every=SAVE, native=native)
    ref = run(state, False)
    _assert_close(jax.jit(run, static_argnums=1)(state, True), ref, STEPS, jnp.float64)
    # vmap over a stack of initial states: the kernel sees an extra leading batch
    stack = jax.tree.map(lambda a: jnp.stack([a, a * 1.0]), state)
    both = jax.vmap(lambda s: run(s, True))(stack)
    _assert_close(jax.tree.map(lambda a: a[1], both), ref, STEPS, jnp.float64)
    # a chunked run steps through the same path and gives the same frames
    chunked = rb.simulate_chunked(state, forces, 1e-2, STEPS, "rk4", save_every=SAVE, chunk_steps=12, progress=False)
    _assert_close(chunked, ref, STEPS, jnp.float64)


@needs_kernels
@pytest.mark.parametrize(
    ("method", "mode"),
    [("euler", jax.grad), pytest.param("euler", jax.jacfwd, marks=pytest.mark.slow)]
    + [
        pytest.param(m, mode, marks=pytest.mark.slow)
        for m in ("rk4", "splitting", "semi_implicit_euler", "rk4_body")
        for mode in (jax.grad, jax.jacfwd)
    ],
)
def test_gradients_through_the_native_path_are_the_jax_steps(method, mode):
    # derivatives come from the JAX steps (custom_jvp): the same to round-off in both modes
    forces = rb.Gravity() + rb.LinearDrag(0.1, 0.05)

    def loss(w0, dt, native):
        s = rb.State.create(rb.box(1.2, [0.2, 0.4, 0.7]), velocity=[1.0, 0.0, 2.0], angular_velocity=w0)
        tr = rb.simulate(s, forces, dt, 12, method, save_every=4, native=native)
        return jnp.sum(tr.orientation[-1] * jnp.asarray([0.3, -1.0, 0.5, 2.0])) + jnp.sum(tr.velocity**2)

    w0, dt = jnp.asarray([0.4, 2.0, -0.3]), jnp.asarray(0.02)
    g_nat = mode(loss, argnums=(0, 1))(w0, dt, True)
    g_ref = mode(loss, argnums=(0, 1))(w0, dt, False)
    for a, b in zip(g_nat, g_ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_native_true_says_why_it_cannot():
    state = _state((3,), jnp.float64)
    cases = [
        (dict(method="rk8"), "no native kernel"),
        (dict(forces=rb.Spring.between([0], [1], 1.0)), "needs the forces at intermediate states"),
        (dict(forces=lambda s, t: rb.Forces(torque=jnp.ones(3) * t)), "needs the forces at intermediate states"),
        (dict(checked=True), "checked mode"),
        (dict(state=rb.to_matrix_state(state)), "MatrixState has no native kernel"),
    ]
    for change, message in cases:
        args = dict(state=state, forces=None, method="rk4", checked=False) | change
        if not rb.native_status().available:
            message = "not"
        with pytest.raises(ValueError, match=message):
            rb.simulate(args["state"], args["forces"], 1e-2, 4, args["method"], checked=args["checked"], native=True)
    # without native=True such a run takes the JAX path
    assert np.all(np.isfinite(rb.simulate(state, None, 1e-2, 4, "rk4", checked=True).orientation))
    with pytest.raises(TypeError, match="native must be None, True or False"):
        rb.simulate(state, None, 1e-2, 4, "rk4", native="yes")


def test_without_the_library_simulate_runs_on_jax_and_says_so_once(monkeypatch):
    missing = rb.NativeStatus(False, None, None, "the library was not built at install (no C++ compiler?)")
    # patched where the plan reads them
    monkeypatch.setattr(_native._plan, "native_status", lambda: missing)
    monkeypatch.setattr(_native._plan, "_warned", False)
    state = _state((3,), jnp.float64)
    with pytest.warns(UserWarning, match="not available.*JAX path"):
        out = rb.simulate(state, None, 1e-2, 6, "euler")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said once: the second run is silent
        again = rb.simulate(state, None, 1e-2, 6, "euler")
    _assert_close(out, again, 6, jnp.float64)
    with pytest.raises(ValueError, match="not built at install"):
        rb.simulate(state, None, 1e-2, 6, "euler", native=True)


def test_the_docs_name_every_method_with_a_kernel():
    # the prose lists are written by hand: each must name every method of METHODS
    readme = (Path(_native.__file__).parent / "README.md").read_text()
    for text in (_native.__doc__, _native.native_status.__doc__, rb.simulate.__doc__):
        assert text is not None
        assert all(f'``"{m}"``' in text for m in _native.METHODS), text
    assert all(f"`{m}_steps`" in readme or f"{m}.py" in readme for m in _native.METHODS)


@needs_kernels
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_native_splitting_frames_of_any_inertia_match_jax(dtype):
    # The kernel computes splitting's principal frames itself (steps.h: principal_frame, eigh3's
    # sweeps, sort, sign and polar step, then the quaternion), where the JAX step takes
    # rbjax._eigh3.principal_frame. Inertias turned by random rotations (full tensors, every plane
    # rotated, every Shepperd candidate): generic, both symmetric tops, a sphere, and moments 1e-9
    # apart (axes ill-determined in their plane, whose turn is as small); with and without
    # gravity + drag. Held to the module's 8 · steps · eps.
    rng = np.random.default_rng(7)
    moments = [(1.0, 2.0, 2.6), (1.0, 1.0, 1.8), (1.0, 1.9, 1.9), (1.5, 1.5, 1.5), (1.0, 1.0 + 1e-9, 1.7)]
    R = np.asarray(rb.quat_to_matrix(rb.quat_normalize(rng.normal(size=(4 * len(moments), 4)))))
    inertia = np.stack([r @ np.diag(moments[k % len(moments)]) @ r.T for k, r in enumerate(R)])
    n = len(inertia)
    body = rb.Body(jnp.ones(n, dtype), jnp.asarray(inertia, dtype))
    s = rb.State.create(
        body,
        orientation=rb.quat_normalize(jnp.asarray(rng.normal(size=(n, 4)), dtype)),
        angular_velocity=jnp.asarray(rng.normal(size=(n, 3)) * 3.0, dtype),
    )
    for forces in (None, rb.Gravity() + rb.QuadraticDrag(0.05, 0.01)):
        nat, ref = _both(s, forces, "splitting")
        _assert_close(nat, ref, STEPS, dtype)


@needs_kernels
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_native_semi_implicit_turns_through_every_quadrant(dtype):
    # the kernel's vectorised sin and cos of θ/2 reduce θ/2 by multiples of π/2 up to 8192 (float32)
    # or 1e6 (float64) and hand larger angles to libm. Spins about the x axis of a body with a
    # diagonal inertia: ω = L stays exact and every step turns by the same θ, so after n steps
    # q = [cos(n θ/2), sin(n θ/2), 0, 0]. The half angles cover all four quadrants and both sides
    # of each limit; each is a small binary fraction (θ² exact), so both paths see the same θ.
    half = np.asarray([0.375, 2.0, 3.5, 5.0, 100.0, 5000.0, 20000.0, 2.0e6])
    dt = 1 / 64
    body = rb.Body(jnp.asarray(1.0, dtype), jnp.diag(jnp.asarray([2.0, 3.0, 4.0], dtype)))
    w = np.zeros((half.size, 3))
    w[:, 0] = 2 * half / dt
    state = rb.State.create(body, angular_velocity=jnp.asarray(w, dtype))
    # up to 4e6 rad a step: a steady spin about a principal axis, which this method turns exactly,
    # is the one motion where such steps are sound; rbjax's warning cannot tell, and says so
    with pytest.warns(rb.StepSizeWarning):
        nat = rb.simulate(state, None, dt, STEPS, "semi_implicit_euler", save_every=SAVE, native=True)
    with pytest.warns(rb.StepSizeWarning):
        ref = rb.simulate(state, None, dt, STEPS, "semi_implicit_euler", save_every=SAVE, native=False)
    _assert_close(nat, ref, STEPS, dtype)
    # against the exact turn, in float64: each step's product and normalisation add a few ulps
    n = np.arange(nat.orientation.shape[0])[:, None] * SAVE
    exact = np.stack([np.cos(n * half), np.sin(n * half), 0 * n * half, 0 * n * half], axis=-1)
    eps = float(jnp.finfo(dtype).eps)
    np.testing.assert_allclose(np.asarray(nat.orientation, np.float64), exact, rtol=0, atol=8 * STEPS * eps)


def _series(batch, dtype, steps=STEPS, torque=True, shared_force=False, seed=4):
    # per-body forces (or shared ones) and a torque shared by the batch (shape (steps, 1, ..., 3)),
    # both varying per step
    rng = np.random.default_rng(seed)
    shared = (steps,) + (1,) * len(batch) + (3,)
    force = jnp.asarray(rng.normal(size=shared if shared_force else (steps,) + batch + (3,)), dtype)
    return rb.Forces(force=force, torque=jnp.asarray(rng.normal(size=shared), dtype) if torque else None)


@needs_kernels
@pytest.mark.parametrize("method", sorted(_native.METHODS))
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_native_time_series_matches_jax(method, dtype):
    # one slice per step, held over the step's stages, all the steps of a frame in one kernel call
    state = _state((7,), dtype)
    nat, ref = _both(state, _series((7,), dtype), method)
    _assert_close(nat, ref, STEPS, dtype)


@needs_kernels
@pytest.mark.parametrize("method", sorted(_native.METHODS))
@pytest.mark.parametrize(("batch", "shared_body"), SHAPES)
def test_native_time_series_over_batch_shapes_and_shared_bodies(method, batch, shared_body):
    state = _state(batch, jnp.float64, shared_body)
    # a force series alone (no torque), and force and torque shared by the whole batch
    for forces in (_series(batch, jnp.float64, torque=False), _series(batch, jnp.float64, shared_force=True)):
        nat, ref = _both(state, forces, method)
        _assert_close(nat, ref, STEPS, jnp.float64)


@needs_kernels
@pytest.mark.slow  # ~7 s; the quick suite runs this check with force models and with a callable
def test_native_time_series_under_jit_vmap_chunked_runs_and_grad():
    state = _state((4,), jnp.float64)
    forces = _series((4,), jnp.float64)
    run = lambda s, f, native: rb.simulate(s, f, 1e-2, STEPS, "splitting", save_every=SAVE, native=native)
    ref = run(state, forces, False)
    _assert_close(jax.jit(run, static_argnums=2)(state, forces, True), ref, STEPS, jnp.float64)
    # vmap over a stack of series: the kernel sees (V, steps, n, 3)
    stack = jax.tree.map(lambda a: jnp.stack([a * 0.5, a]), forces)
    both = jax.vmap(lambda f: run(state, f, True))(stack)
    _assert_close(jax.tree.map(lambda a: a[1], both), ref, STEPS, jnp.float64)
    _assert_close(
        jax.tree.map(lambda a: a[0], both), run(state, jax.tree.map(lambda a: a[0], stack), False), STEPS, jnp.float64
    )
    # a chunked run slices the series per chunk
    chunked = rb.simulate_chunked(
        state, forces, 1e-2, STEPS, "splitting", save_every=SAVE, chunk_steps=12, progress=False
    )
    _assert_close(chunked, ref, STEPS, jnp.float64)

    # the derivative with respect to the series comes from the JAX steps (custom_jvp)
    def loss(f, native):
        return jnp.sum(run(state, f, native).angular_momentum[-1] ** 2)

    g_nat = jax.grad(loss)(forces, True)
    g_ref = jax.grad(loss)(forces, False)
    for a, b in zip(jax.tree.leaves(g_nat), jax.tree.leaves(g_ref), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def _callable(dtype):
    # depends on the time, the velocity, the momentum and the body: a change of any input shows
    def forces(s, t):
        force = s.body.mass[..., None] * jnp.asarray([0.0, 0.0, -9.81], dtype) - 0.3 * s.velocity
        return rb.Forces(force=force + jnp.sin(3 * t), torque=-0.1 * s.angular_momentum + 0.2 * jnp.cos(t))

    return forces


@needs_kernels
@pytest.mark.parametrize("method", _native.AT_STEP_START)
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("kind", ["callable", "spring"])
def test_native_forces_evaluated_by_xla_match_jax(method, dtype, kind):
    # XLA evaluates the forces at each step's start, the kernel takes them: one call per step
    state = _state((7,), dtype)
    if kind == "callable":
        forces = _callable(dtype)
    else:
        forces = rb.Spring.between([0, 2], [1, 5], 3.0, damping=0.2) + rb.Gravity()
    t0 = 0.37  # the steps' times enter a time-dependent callable
    nat = rb.simulate(state, forces, 1e-2, STEPS, method, save_every=SAVE, t0=t0, native=True)
    ref = rb.simulate(state, forces, 1e-2, STEPS, method, save_every=SAVE, t0=t0, native=False)
    _assert_close(nat, ref, STEPS, dtype)
    # without native=True such forces stay on the JAX path: the same bits as native=False
    default = rb.simulate(state, forces, 1e-2, STEPS, method, save_every=SAVE, t0=t0)
    for a, b in zip(jax.tree.leaves(default), jax.tree.leaves(ref), strict=True):
        np.testing.assert_array_equal(a, b)


@needs_kernels
@pytest.mark.parametrize(("batch", "shared_body"), SHAPES)
def test_native_callable_over_batch_shapes_and_shared_bodies(batch, shared_body):
    state = _state(batch, jnp.float64, shared_body)
    for method in _native.AT_STEP_START:
        nat = rb.simulate(state, _callable(jnp.float64), 1e-2, STEPS, method, save_every=SAVE, native=True)
        ref = rb.simulate(state, _callable(jnp.float64), 1e-2, STEPS, method, save_every=SAVE, native=False)
        _assert_close(nat, ref, STEPS, jnp.float64)


@needs_kernels
def test_native_callable_under_jit_vmap_chunked_runs_and_grad():
    state = _state((4,), jnp.float64)
    forces = _callable(jnp.float64)
    run = lambda s, dt, native: rb.simulate(s, forces, dt, STEPS, "euler", save_every=SAVE, native=native)
    ref = run(state, 1e-2, False)
    _assert_close(jax.jit(run, static_argnums=2)(state, 1e-2, True), ref, STEPS, jnp.float64)
    stack = jax.tree.map(lambda a: jnp.stack([a, a * 1.0]), state)
    both = jax.vmap(lambda s: run(s, 1e-2, True))(stack)
    _assert_close(jax.tree.map(lambda a: a[1], both), ref, STEPS, jnp.float64)

    def loss(dt, native):
        return jnp.sum(run(state, dt, native).orientation[-1] * jnp.asarray([0.3, -1.0, 0.5, 2.0]))

    np.testing.assert_allclose(jax.grad(loss)(0.01, True), jax.grad(loss)(0.01, False), rtol=1e-12, atol=1e-12)


def _thrusters(dtype):
    # two thrusters on body 1 (their torques sum in the body frame), one on body 4, off-centre
    d = jnp.asarray([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0], [0.0, 1.0, 0.0]], dtype)
    point = jnp.asarray([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [0.3, -0.1, 0.2]], dtype)
    return rb.Thruster([1, 4, 1], d, jnp.asarray([2.0, -1.0, 0.5], dtype), point=point)


@needs_kernels
# the quick suite runs every method in float64 and the one-stage ones in float32 too
@pytest.mark.parametrize(
    ("method", "dtype"),
    [
        pytest.param(m, d, marks=pytest.mark.slow if d == jnp.float32 and m not in _native.AT_STEP_START else ())
        for m in sorted(_native.METHODS)
        for d in (jnp.float32, jnp.float64)
    ],
)
def test_native_thrusters_match_jax(method, dtype):
    # in the kernel: the body-frame sums turned by R(q) at each evaluation, the torque by cof(R),
    # which is (R p) × (R f) also at RK4's stages, where |q| ≠ 1 and R is no rotation
    state = _state((7,), dtype)
    for forces in (
        _thrusters(dtype),
        rb.Gravity() + _thrusters(dtype) + rb.QuadraticDrag(0.05, 0.01),
        rb.Thruster([2], jnp.asarray([[0.0, 1.0, 0.0]], dtype), 3.0),  # at the centre of mass: no torque
    ):
        nat, ref = _both(state, forces, method)
        _assert_close(nat, ref, STEPS, dtype)


@needs_kernels
@pytest.mark.slow  # ~6 s a case; the quick suite holds thrusters to JAX in test_native_thrusters_match_jax
@pytest.mark.parametrize("shared_body", [False, True])
def test_native_thrusters_over_blocks_under_vmap_and_grad(shared_body):
    # 130 bodies (three blocks), thrusters in the first and last; vmap over thrust; grad from JAX
    # (euler: the cheapest gradient to compile; every method meets thrusters above)
    state = _state((130,), jnp.float64, shared_body)
    d = jnp.asarray([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]], jnp.float64)

    def run(thrust, native):
        forces = rb.Thruster([3, 129], d, thrust, point=jnp.asarray([0.1, -0.2, 0.05])) + rb.LinearDrag(0.1, 0.02)
        return rb.simulate(state, forces, 1e-2, STEPS, "euler", save_every=SAVE, native=native)

    thrust = jnp.asarray([2.0, -1.5])
    _assert_close(run(thrust, True), run(thrust, False), STEPS, jnp.float64)
    both = jax.vmap(lambda T: run(T, True))(jnp.stack([thrust, 2 * thrust]))
    _assert_close(jax.tree.map(lambda a: a[1], both), run(2 * thrust, False), STEPS, jnp.float64)
    loss = lambda T, native: jnp.sum(run(T, native).angular_momentum[-1] ** 2)
    np.testing.assert_allclose(jax.grad(loss)(thrust, True), jax.grad(loss)(thrust, False), rtol=1e-12, atol=1e-12)


SHARDED_CHECK = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    import rbjax as rb
    assert len(jax.devices()) == 2
    n = 130  # 65 bodies a device: a full block and a partial one each
    rng = np.random.default_rng(0)
    per_body = rb.State.create(rb.box(rng.uniform(1, 2, n), rng.uniform(0.5, 1.5, (n, 3))),
                               velocity=rng.normal(size=(n, 3)), angular_velocity=rng.normal(size=(n, 3)))
    shared = rb.State.create(rb.box(1.0, [0.1, 0.2, 0.4]), angular_velocity=rng.normal(size=(n, 3)))
    laws = rb.Gravity() + rb.LinearDrag(0.1, angular=0.05) + rb.QuadraticDrag(0.02, 0.01)
    thrusters = rb.Thruster([3, 129], jnp.asarray([[0.0, 0, 1], [1.0, 0, 0]]), 2.0, point=jnp.asarray([0.1, 0, 0]))
    callable_forces = lambda s, t: rb.Forces(force=-0.3 * s.velocity, torque=-0.1 * s.angular_momentum)
    explicit = jax.make_mesh((2,), ("bodies",))  # jax's default: explicit axis types
    auto = jax.sharding.Mesh(np.array(jax.devices()), ("bodies",))  # GSPMD propagation
    cases = [(m, f) for m in ("euler", "rk4", "splitting", "semi_implicit_euler", "rk4_body") for f in (laws, None)]
    cases += [("rk4", thrusters), ("euler", callable_forces)]
    worst = 0.0
    for mesh in (explicit, auto):
        for s in (per_body, shared):
            st = jax.device_put(s, rb.batch_sharding(s, mesh))
            for method, f in cases:
                traj = rb.simulate(st, f, 0.01, 20, method, save_every=5, native=True)
                ref = rb.simulate(s, f, 0.01, 20, method, save_every=5, native=True)
                for path, leaf in jax.tree_util.tree_leaves_with_path(traj):
                    key = jax.tree_util.keystr(path)
                    if key.startswith(".body") and s is shared or mesh is auto and key == ".time":
                        continue  # a shared body stays replicated; GSPMD replicates the times it builds
                    assert leaf.sharding.spec[1] == "bodies", (key, leaf.sharding)
                for a, b in zip(jax.tree.leaves(traj), jax.tree.leaves(ref)):
                    worst = max(worst, float(jnp.max(jnp.abs(a - b))))
    # split, not gathered: the kernel runs on 65 bodies a device, with no collective in the program
    import rbjax._simulate as sim
    lowered = {}
    run = sim._simulate
    def spy(*a, **k):
        lowered["x"] = run.lower(*a, **k)
        return run(*a, **k)
    sim._simulate = spy
    rb.simulate(jax.device_put(shared, rb.batch_sharding(shared, auto)), laws, 0.01, 20, "rk4", save_every=5)
    sim._simulate = run
    hlo = lowered["x"].compile().as_text()
    calls = [line for line in hlo.splitlines() if "custom-call(" in line]
    assert calls and all("[65,3]" in line for line in calls), calls
    assert not any(op in hlo for op in ("all-gather(", "all-to-all(", "collective-permute(")), "a collective"
    # under vmap the marked call has a leading vmap axis (num_batch_dims counts it): still right
    for mesh in (explicit, auto):
        st = jax.device_put(per_body, rb.batch_sharding(per_body, mesh))
        run = lambda dt: rb.simulate(st, laws, dt, 20, "rk4", save_every=5, native=True)
        both = jax.vmap(run)(jnp.asarray([0.01, 0.02]))
        assert both.position.sharding.spec[2] == "bodies", both.position.sharding
        ref = rb.simulate(per_body, laws, 0.02, 20, "rk4", save_every=5, native=True)
        for a, b in zip(jax.tree.leaves(both), jax.tree.leaves(ref)):
            worst = max(worst, float(jnp.max(jnp.abs(a[1] - b))))
    # inside a caller's jit an auto-sharded batch is not seen as sharded: the call is not marked,
    # not split, and still right
    st = jax.device_put(per_body, rb.batch_sharding(per_body, auto))
    traj = jax.jit(lambda s: rb.simulate(s, laws, 0.01, 20, "rk4", save_every=5, native=True))(st)
    ref = rb.simulate(per_body, laws, 0.01, 20, "rk4", save_every=5, native=True)
    for a, b in zip(jax.tree.leaves(traj), jax.tree.leaves(ref)):
        worst = max(worst, float(jnp.max(jnp.abs(a - b))))
    print("WORST", worst)
    """
)


@needs_kernels
@pytest.mark.slow  # a fresh process with 2 host devices
def test_native_kernel_splits_a_sharded_batch_over_its_devices():
    # the kernel call is batch-partitionable: each device steps its own bodies (no collective),
    # every leaf stays split on its body axis, and the values are the unsharded run's: each body's
    # arithmetic is the same whichever device runs it, so they agree to the bit (asserted: 0)
    # the suite's XLA flags (its fast compile) and 2 host devices
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2".strip()
    env = dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1])
    out = subprocess.run([sys.executable, "-c", SHARDED_CHECK], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert float(out.stdout.split("WORST")[-1]) == 0.0


def test_native_plan_refuses_a_sharded_series_and_a_sharded_batch_of_two_axes(monkeypatch):
    # the reasons native_plan gives where a sharded batch cannot be split (one device here: the
    # sharding is pretended)
    monkeypatch.setattr(_native._plan, "sharded", lambda state: True)
    method = rb.methods()["rk4"]
    plan = lambda state, series: _native.native_plan(state, None, method, series=series, checked=False, checkpoint=None)
    if not rb.native_status().available:
        return
    assert "time-series" in plan(_state((4,), jnp.float64), True)
    assert "1-D batches" in plan(_state((2, 3), jnp.float64), False)
    assert plan(_state((4,), jnp.float64), False) == ""


def _isa_cases():
    """``{name: (state, forces, method)}``: every method and dtype without forces and with every
    term, thrusters, three blocks of bodies (the vector loops' full and partial blocks), and
    quat_exp's two branches: the steps' template instances (kForces, kQuad, kThrust)."""
    cases = {}
    for m in sorted(_native.METHODS):
        for dtype in (jnp.float32, jnp.float64):
            d = jnp.dtype(dtype).name
            for kind in ("none", "every term"):
                cases[f"{m}|{d}|{kind}"] = (_state((7,), dtype), _forces(kind, (7,), dtype), m)
            cases[f"{m}|{d}|130"] = (_state((130,), dtype), _forces("every term", (130,), dtype), m)
        cases[f"{m}|thrusters"] = (_state((7,), jnp.float64), _thrusters(jnp.float64), m)
    cases["branches"] = (_both_branches(jnp.float64), _forces("every term", (8,), jnp.float64), "semi_implicit_euler")
    return cases


_FIELDS = ("position", "velocity", "orientation", "angular_momentum", "time")


def _native_runs(path):
    """The kernel's trajectories of :func:`_isa_cases`, saved to ``path`` (run in a fresh process)."""
    out = {}
    for name, (state, forces, method) in _isa_cases().items():
        traj = rb.simulate(state, forces, 1e-2, STEPS, method, save_every=SAVE, native=True)
        out.update({f"{name}|{f}": np.asarray(getattr(traj, f)) for f in _FIELDS})
    np.savez(path, **out)


@needs_kernels
@pytest.mark.slow  # a fresh process per instruction set
def test_the_narrower_instruction_sets_match_jax(tmp_path):
    # The library carries the steps for three instruction sets and runs the widest this processor
    # has; a wheel ships all three. RBJAX_NATIVE_ISA caps the choice, so the narrower ones are held
    # to the JAX steps here too, with this module's tolerance: the kernel runs in a fresh process
    # per cap, the JAX reference once here (while the first process runs), for every cap
    have = rb.native_status().instruction_set
    caps, left = [], []
    for cap in ("baseline", "avx2"):
        want = _native.ISA[_native.ISA_CAPS.index(cap)]
        if _native.ISA.index(have) < _native.ISA.index(want):
            left.append(f"{cap}: this processor runs {have}, narrower than {want}")
        elif have == want != _native.ISA[0]:  # the cap changes nothing: this module's other tests hold them to JAX
            left.append(f"{cap}: this processor's widest instruction set is {have}: this module's other tests run it")
        else:
            caps.append(cap)
    if not caps:
        pytest.skip("; ".join(left))
    here = Path(__file__).resolve().parent
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(here), str(here.parent)]))

    def start(cap):
        code = (
            "import jax; jax.config.update('jax_enable_x64', True); import rbjax, test_native; "
            f"print(rbjax.native_status().instruction_set); test_native._native_runs({str(tmp_path / cap)!r})"
        )
        cmd = [sys.executable, "-c", code]
        return subprocess.Popen(
            cmd, env=dict(env, RBJAX_NATIVE_ISA=cap), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )

    # one process at a time: the second reads the programs the first compiled from the run's cache
    first = start(caps[0])
    cases = _isa_cases()
    refs = {name: rb.simulate(s, f, 1e-2, STEPS, m, save_every=SAVE, native=False) for name, (s, f, m) in cases.items()}
    for k, cap in enumerate(caps):
        proc = first if k == 0 else start(cap)
        stdout, stderr = proc.communicate(timeout=600)
        assert proc.returncode == 0, (cap, stderr[-3000:])
        assert stdout.split("\n")[0] == _native.ISA[_native.ISA_CAPS.index(cap)], (cap, stdout)
        got = np.load(tmp_path / f"{cap}.npz")
        for name, (state, _, _) in cases.items():
            nat = SimpleNamespace(**{f: got[f"{name}|{f}"] for f in _FIELDS})
            _assert_close(nat, refs[name], STEPS, state.position.dtype, case=f"{cap} {name}")
    # an unknown cap is named, not silently taken for "no cap"
    warned = subprocess.run(
        [sys.executable, "-c", "import rbjax; rbjax.native_status()"],
        env=dict(env, RBJAX_NATIVE_ISA="avx3"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "RBJAX_NATIVE_ISA='avx3' is not one of baseline, avx2, avx512" in warned.stderr, warned.stderr[-2000:]
