"""The batch layout travels with the data (rbjax._batching): no hidden state decides how ``lift`` maps.

``simulate`` carries its state batch-last ``(*core, *B)`` through the scan; ``to_batch_last`` marks
the objects it returns, and ``lift`` reads the mark from its arguments. Before 2026-12-08 a
ContextVar set around the trace decided the layout for every ``lift`` inside it, whatever the
arguments' own layout.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rbjax as rb
from rbjax._batching import batch_shape, lift, to_batch_first, to_batch_last


def _batch(shape=(2, 3)):
    rng = np.random.default_rng(0)
    n = int(np.prod(shape))
    I = np.stack([np.diag(rng.uniform(1.0, 3.0, 3)) for _ in range(n)]).reshape(*shape, 3, 3)
    body = rb.Body(rng.uniform(0.5, 2.0, shape), jnp.asarray(I))
    w = rng.normal(size=(*shape, 3))
    v = rng.normal(size=(*shape, 3))
    return rb.State.create(body, velocity=jnp.asarray(v), angular_velocity=jnp.asarray(w))


@pytest.mark.parametrize("shape", [(5,), (2, 3)])
def test_a_batch_last_state_gives_the_per_body_results_of_the_batch_first_one(shape):
    state = _batch(shape)
    first = rb.kinetic_energy(state)  # (*B,): mass ½ m v² + ½ ωᵀ I ω, body by body
    last = to_batch_last(state)
    assert batch_shape(last) == shape
    # the same public function on the batch-last state maps the trailing axes: the same numbers, no
    # ContextVar set (the layout is read off the state itself)
    np.testing.assert_array_equal(np.asarray(rb.kinetic_energy(last)), np.asarray(first))
    # lift's results keep the layout: a step's state comes back batch-last and round-trips exactly
    moved = lift(lambda s: s)(last)
    back = to_batch_first(moved)
    for a, b in zip(jax.tree.leaves(back), jax.tree.leaves(state), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_batch_first_object_beside_batch_last_ones_is_refused_in_words():
    # a tree rebuilt by a constructor from batch-last arrays loses its mark; mapped as batch-first it
    # would pair the wrong axes, so lift names the mix instead of guessing
    state = _batch((4,))
    last = to_batch_last(state)
    with pytest.raises(ValueError, match=r"batch-first Body beside batch-last arguments"):
        lift(lambda s, b: s)(last, state.body)
