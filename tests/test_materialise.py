"""The Runge–Kutta stages' fusion boundary (``_methods._common.materialise``).

``torque_varies`` decides from the force's jaxpr whether a step materialises
its stages; materialising must change no value and no gradient. float64.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb
from rbjax._methods import _common, explicit_rk


def _state(n=3):
    rng = np.random.default_rng(0)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return rb.State.create(rb.box(1.0, [0.3, 0.5, 0.9]), orientation=q, angular_velocity=rng.normal(size=(n, 3)))


def thruster(s, t):  # a body-fixed force: torque depends on the orientation
    f = rb.quat_rotate(s.orientation, jnp.asarray([0.0, 0.6, 0.8]))
    return rb.Forces.at_point(f, s.position + rb.quat_rotate(s.orientation, jnp.asarray([0.2, 0.1, 0.3])), s)


def driven(s, t):  # a torque that depends on time only
    return rb.Forces(torque=jnp.stack([jnp.sin(3 * t), jnp.cos(2 * t), 0.2 * t]))


@pytest.mark.parametrize(
    "force, varies",
    [
        (thruster, True),
        (driven, True),
        (lambda s, t: rb.Forces(), False),
        (lambda s, t: rb.Forces(torque=jnp.asarray([0.1, 0.2, 0.3])), False),
        # forces without a torque, even state-dependent ones, and the body (mass) do not count
        (rb.Gravity() + rb.QuadraticDrag(0.1), False),
        (lambda s, t: rb.Forces(force=rb.quat_rotate(s.orientation, jnp.asarray([1.0, 0, 0]))), False),
    ],
)
def test_torque_varies_reads_the_jaxpr(force, varies):
    assert _common.torque_varies(force, _state(), jnp.asarray(0.5)) is varies


# only tableaus of more than four stages materialise (rbjax/_methods/explicit_rk.py): rk8
@pytest.mark.slow
@pytest.mark.parametrize("method", ["rk8"])
@pytest.mark.parametrize("force", [thruster, driven])
def test_materialised_stages_change_no_value_or_derivative(monkeypatch, method, force):
    s0 = _state()

    def run(s, dt, force):
        tr = rb.simulate(s, force, dt, 8, method, save_every=8)
        return jnp.sum(tr.orientation[-1] * jnp.asarray([1.0, -2.0, 0.5, 3.0])) + jnp.sum(tr.angular_momentum[-1])

    # forward mode (compiles in a fraction of reverse mode's time; the cond's transpose is JAX's)
    ds = jax.tree.map(jnp.ones_like, s0)

    def value_and_grads(force):
        jvp = lambda s, dt: jax.jvp(lambda s, dt: run(s, dt, force), (s, dt), (ds, jnp.asarray(1.0)))
        return jax.jit(jvp)(s0, jnp.asarray(0.05))

    on = value_and_grads(force)
    consulted = []
    monkeypatch.setattr(explicit_rk, "torque_varies", lambda *a: consulted.append(1) or False)
    # the same force as a new function: simulate's jit traces anew (with `force` itself it would
    # reuse the trace made before the patch: jax's trace cache does not see the patched global)
    off = value_and_grads(lambda s, t: force(s, t))
    assert consulted
    # the same arithmetic, possibly reassociated by a different fusion: a few ulp of O(10) values
    for a, b in zip(jax.tree.leaves(on), jax.tree.leaves(off), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13)


def test_materialise_under_vmap_over_dt_keeps_values():
    # vmapped dt turns the cond into a select; NaN dt gives NaN either way
    tree = {"a": jnp.arange(3.0), "b": jnp.ones((2, 3))}
    out = jax.vmap(lambda dt: _common.materialise(tree, dt))(jnp.asarray([0.1, 0.2]))
    np.testing.assert_array_equal(out["a"], np.tile(np.arange(3.0), (2, 1)))
    np.testing.assert_array_equal(out["b"], np.ones((2, 2, 3)))
