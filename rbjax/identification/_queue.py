"""A batch of iterative solves in which every member stops on its own: a work queue of slots.

``vmap`` of a ``while_loop`` steps the whole batch until its slowest member
stops. On short recordings that is most of the work: measured on 100 random
1 s @ 200 Hz tumbles, Levenberg–Marquardt took a median of 12 steps and a
mean of 30, but 200 for the slowest (near-symmetric tops creeping along a
flat valley), so the vmapped solve did 6.7x the necessary steps.

Here ``C`` slots hold ``C`` members at a time. Every round steps the active
slots at most ``K`` times, ``W`` at a time (the active ones gathered into
chunks of ``W``; a slot that is done idles until the chunk is), then retires
the slots whose member stopped, ``R`` at a time, writes their outputs, and
refills the slots from the queue. A round costs ``⌈active / W⌉`` chunks, so
the stragglers at the end are not stepped as a wide batch. Everything runs
inside one compiled program with static shapes, and each of the functions
below appears in it once: the member's step (the fit's model) is compiled
once, whatever the batch.

Members are described by four functions of one member (lifted with ``vmap``):

* ``start(i)``: the slot of member ``i`` (traced index);
* ``advance(slot)``: one solver step;
* ``running(slot)``: whether it needs another step;
* ``retire(slot)``: ``(again, next_slot, out)``: ``again`` restarts the
  member from ``next_slot`` (e.g. another round of reweighting), otherwise
  ``out`` is its result.

Each member's iterates are exactly those of a solve on its own: a slot only
ever advances its own member, with the same steps in the same order.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp


def _select(mask, a, b):
    """``a`` where ``mask`` (per slot, leading axis) else ``b``, leaf by leaf."""
    return jax.tree.map(lambda x, y: jnp.where(mask.reshape(mask.shape + (1,) * (x.ndim - 1)), x, y), a, b)


def run_queue(
    n: int,
    start: Callable,
    advance: Callable,
    running: Callable,
    retire: Callable,
    *,
    slots: int,
    chunk: int,
    steps_per_round: int,
    retire_chunk: int = 4,
):
    """Outputs of ``n`` members (each leaf with a leading ``n`` axis); see the module docstring.

    ``slots``: at most ``C`` members in flight; ``chunk``: ``W``, the members stepped
    together; ``retire_chunk``: ``R``, the members retired together.
    """
    W = min(chunk, n, slots)
    C = W * -(-min(n, slots) // W)  # whole chunks: a chunk never overlaps the next
    R = max(r for r in range(1, min(retire_chunk, C) + 1) if C % r == 0)
    v_start, v_running, v_retire = jax.vmap(start), jax.vmap(running), jax.vmap(retire)

    def k_steps(slot, active):
        def cond(c):
            return active & (c[1] < steps_per_round) & running(c[0])

        return jax.lax.while_loop(cond, lambda c: (advance(c[0]), c[1] + 1), (slot, 0))[0]

    idx = jnp.arange(C)
    first = v_start(jnp.minimum(idx, n - 1))
    member = jnp.where(idx < n, idx, n)  # n: no member (writes go to a spare row)
    one = jax.tree.map(lambda a: a[0], first)
    out_shape = jax.eval_shape(lambda s: retire(s)[2], one)
    outputs = jax.tree.map(lambda s: jnp.zeros((n + 1,) + s.shape, s.dtype), out_shape)
    take = lambda tree, at: jax.tree.map(lambda a: a[at], tree)
    put = lambda tree, at, sub: jax.tree.map(lambda a, b: a.at[at].set(b), tree, sub)

    def step_chunk(k, c):  # the k-th W of the active slots (active ones first)
        slots, active, order = c
        at = jax.lax.dynamic_slice_in_dim(order, k * W, W)
        return put(slots, at, jax.vmap(k_steps)(take(slots, at), active[at])), active, order

    def retire_chunk_(k, c):  # the k-th R of the slots whose member stopped
        slots, member, active, queued, outputs, order, finished = c
        pick = jax.lax.dynamic_slice_in_dim(order, k * R, R)
        picked = finished[pick]
        sub = take(slots, pick)
        again, restarted, out = v_retire(sub)
        done = picked & ~again
        rows = jnp.where(done, member[pick], n)
        outputs = jax.tree.map(lambda buf, o: buf.at[rows].set(o), outputs, out)
        new = queued + jnp.cumsum(done) - 1  # queue positions for the freed slots
        refill = done & (new < n)
        sub = _select(picked & again, restarted, sub)
        sub = _select(refill, v_start(jnp.clip(new, 0, n - 1)), sub)
        slots = put(slots, pick, sub)
        member = member.at[pick].set(jnp.where(refill, new, jnp.where(done, n, member[pick])))
        active = active.at[pick].set((active[pick] & ~done) | refill)
        queued = jnp.minimum(queued + jnp.sum(done), n)
        return slots, member, active, queued, outputs, order, finished

    def body(c):
        slots, member, active, queued, outputs = c
        chunks = (jnp.sum(active) + W - 1) // W
        order = jnp.argsort(~active, stable=True)
        slots = jax.lax.fori_loop(0, chunks, step_chunk, (slots, active, order))[0]
        finished = active & ~v_running(slots)
        order = jnp.argsort(~finished, stable=True)
        c = (slots, member, active, queued, outputs, order, finished)
        c = jax.lax.fori_loop(0, (jnp.sum(finished) + R - 1) // R, retire_chunk_, c)
        return c[:5]

    carry = (first, member, idx < n, jnp.asarray(min(C, n)), outputs)
    carry = jax.lax.while_loop(lambda c: jnp.any(c[2]), body, carry)
    return jax.tree.map(lambda a: a[:n], carry[4])
