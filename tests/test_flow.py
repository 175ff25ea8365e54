"""The fit model's rk4 flow (identification/_flow.py) against rbjax's own ``"rk4"`` step.

The flow is the same map as ``rbjax.step(method="rk4")`` written in structure of
arrays, so both are the same float64 arithmetic in a different order: states
agree to rounding (1e-13 after a few steps of O(1) values) and so do their
forward-mode tangents, with the RK4 stages written out or looped. Under ``vmap`` a batch is folded into the flow's body
axis (its ``custom_vmap`` rule), which must not change any number.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rbjax import Body, Forces, State, _methods, quat_rotate
from rbjax._pytree import new_unchecked
from rbjax.identification._flow import flow

M, K, N_TANGENTS = 3, 5, 2


def _observe(q, L, inv, obs, const):
    """A one-body observation: the state itself, weighted per sample and per body."""
    return obs["w"] * const["c"] * q, L


def _inputs(seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(M, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    A = rng.normal(size=(M, 3, 3))
    inertia = np.einsum("bij,bkj->bik", A, A) + 2 * np.eye(3)
    return dict(
        q=q,
        L=rng.normal(size=(M, 3)),
        inv=np.linalg.inv(inertia),
        dq=rng.normal(size=(M, N_TANGENTS, 4)),
        dL=rng.normal(size=(M, N_TANGENTS, 3)),
        dinv=rng.normal(size=(M, N_TANGENTS, 3, 3)) * 0.1,
        dt=np.concatenate([rng.uniform(0.01, 0.05, (M, K - 1)), np.zeros((M, 1))], 1),  # one padding interval
        tau=rng.normal(size=(M, K + 1, 3)),
        obs=dict(w=rng.uniform(0.5, 2.0, (M, K))),
        const=dict(c=rng.uniform(0.5, 2.0, M)),
    )


def _reference(substeps, frame):
    """One body's states after each interval by rbjax's "rk4" step, ``run(q, L, inv, dt, tau)``."""
    step = _methods.get("rk4", State)
    zero = jnp.zeros(3)

    def run(q, L, inv, dt, tau):
        body = new_unchecked(Body, mass=jnp.ones(()), inertia=jnp.linalg.inv(inv), _inverse=inv)

        def interval(c, x):
            q, L, t0 = c
            h, lo, hi = x

            def forces(st, t):
                if frame is None:
                    return Forces()
                f = jnp.where(h > 0, (t - t0) / jnp.where(h > 0, h, 1.0), 0.0)
                w = lo + f * (hi - lo)
                return Forces(torque=quat_rotate(st.orientation, w) if frame == "body" else w)

            for j in range(substeps):
                s = new_unchecked(
                    State, body=body, position=zero, velocity=zero, orientation=q, angular_momentum=L, time=t0
                )
                s = step(s, forces, t0 + j * h / substeps, h / substeps)
                q, L = s.orientation, s.angular_momentum
            return (q, L, t0 + h), (q, L)

        return jax.lax.scan(interval, (q, L, jnp.zeros((), dt.dtype)), (dt, tau[:-1], tau[1:]))[1]

    return run


@functools.cache
def _reference_run(substeps, frame):
    """rbjax's "rk4" on :func:`_inputs`' bodies, ``((q, L), (dq, dL))`` after each interval, with
    the tangents ``(n, K, ...)``: computed once for both stage layouts of the flow below."""
    args = jax.tree.map(jnp.asarray, _inputs())
    run = _reference(substeps, frame)

    def reference(q, L, inv, dq, dL, dinv, dt, tau):  # one body: states and tangents (n, K, ...)
        primal = run(q, L, inv, dt, tau)
        tangents = jax.vmap(lambda t: jax.jvp(lambda *p: run(*p, dt, tau), (q, L, inv), t)[1])((dq, dL, dinv))
        return primal, tangents

    inputs = (args[k] for k in ("q", "L", "inv", "dq", "dL", "dinv", "dt", "tau"))
    return jax.tree.map(np.asarray, jax.jit(jax.vmap(reference))(*inputs))


@pytest.mark.parametrize("frame", [None, "world", "body"])
@pytest.mark.parametrize("substeps", [1, pytest.param(2, marks=pytest.mark.slow)])
@pytest.mark.parametrize("looped", [False, True], ids=["stages-written-out", "stages-looped"])
def test_flow_is_rbjax_rk4_with_its_tangents(frame, substeps, looped):
    args = jax.tree.map(jnp.asarray, _inputs())
    if frame is None:
        args.pop("tau")
    (q_end, dq_end), (oq, oL), (doq, doL) = jax.jit(flow(substeps, frame, _observe, looped=looped))(args)
    (q, L), (dq, dL) = _reference_run(substeps, frame)
    w = (args["obs"]["w"] * args["const"]["c"][:, None])[..., None]  # (M, K, 1)
    np.testing.assert_allclose(oq, w * q, rtol=0, atol=1e-13)
    np.testing.assert_allclose(oL, L, rtol=0, atol=1e-13)
    np.testing.assert_allclose(q_end, q[:, -1], rtol=0, atol=1e-13)
    np.testing.assert_allclose(doq, w[:, None] * dq, rtol=0, atol=1e-12)
    np.testing.assert_allclose(doL, dL, rtol=0, atol=1e-12)
    np.testing.assert_allclose(dq_end, dq[:, :, -1], rtol=0, atol=1e-12)


def test_vmap_folds_members_into_the_body_axis_exactly():
    # three members of three bodies each: vmapped (folded into 9 bodies) against one by one
    members = [_inputs(seed) for seed in range(3)]
    batch = jax.tree.map(lambda *a: jnp.stack(a), *members)
    fn = flow(1, "world", _observe)
    folded = jax.jit(jax.vmap(fn))(batch)
    for i, member in enumerate(members):
        alone = jax.jit(fn)(jax.tree.map(jnp.asarray, member))
        jax.tree.map(lambda a, b, i=i: np.testing.assert_allclose(a[i], b, rtol=1e-14, atol=1e-14), folded, alone)
    # a member axis shared by all (unbatched leaves) is broadcast, not misread
    shared = jax.jit(jax.vmap(fn, in_axes=(dict.fromkeys(batch, 0) | {"inv": None},)))
    out = shared({**batch, "inv": batch["inv"][0]})
    alone = jax.jit(fn)({**jax.tree.map(lambda a: a[1], batch), "inv": batch["inv"][0]})
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a[1], b, rtol=1e-14, atol=1e-14), out, alone)


def test_looped_stages_match_the_written_out_ones_with_drag_and_torque():
    # the drag torque reads each stage's (q, L): a stage fed the wrong predecessor, weight or node
    # moves the states by O(dt), far above the 1e-13 of the same float64 arithmetic in a loop
    args = jax.tree.map(jnp.asarray, _inputs(1))
    rng = np.random.default_rng(2)
    args.update(drag=jnp.asarray(rng.uniform(0.1, 0.5, (M, 2))), ddrag=jnp.asarray(rng.normal(size=(M, N_TANGENTS, 2))))
    out, looped = (jax.jit(flow(2, "body", _observe, True, looped=lp))(args) for lp in (False, True))
    jax.tree.map(lambda a, b: np.testing.assert_allclose(b, a, rtol=0, atol=1e-13), out, looped)
    # and the drag was felt: the momentum changed by far more than the tolerance
    assert np.max(np.abs(np.asarray(out[1][1][:, -2]) - np.asarray(args["L"]))) > 1e-2
