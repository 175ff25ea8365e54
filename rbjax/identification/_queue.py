"""A batch of iterative solves in which every member stops on its own: a work queue of slots.

``vmap`` of a ``while_loop`` steps the whole batch until its slowest member
stops. On short recordings that is most of the work: measured on 100 random
1 s @ 200 Hz tumbles, Levenberg–Marquardt took a median of 12 steps and a
mean of 30, but 200 for the slowest (near-symmetric tops creeping along a
flat valley), so the vmapped solve did 6.7x the necessary steps.

Here ``C`` slots hold ``C`` members at a time. Every round steps all slots
at most ``K`` times (a slot that is done idles), then retires the slots whose
member stopped, writes their outputs, and refills the slots from the queue.
When the queue is empty and few members are left, the survivors are packed
into a narrower stage (``C / 4``) so that the stragglers are not stepped as
a wide batch. Everything runs inside one compiled program with static
shapes: one ``while_loop`` per stage.

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


def stage_widths(n: int, first: int = 128, last: int = 4) -> tuple[int, ...]:
    """Slot counts of the stages: ``min(n, first)``, then a quarter each time, down to ``last``."""
    widths = [min(n, first)]
    while widths[-1] // 4 >= last:
        widths.append(widths[-1] // 4)
    return tuple(widths)


def run_queue(
    n: int,
    start: Callable,
    advance: Callable,
    running: Callable,
    retire: Callable,
    *,
    widths: tuple[int, ...],
    steps_per_round: int,
):
    """Outputs of ``n`` members (each leaf with a leading ``n`` axis); see the module docstring."""
    v_start, v_running, v_retire = jax.vmap(start), jax.vmap(running), jax.vmap(retire)

    def k_steps(slot, active):
        def cond(c):
            return active & (c[1] < steps_per_round) & running(c[0])

        return jax.lax.while_loop(cond, lambda c: (advance(c[0]), c[1] + 1), (slot, 0))[0]

    C = widths[0]
    idx = jnp.arange(C)
    slots = v_start(jnp.minimum(idx, n - 1))
    member = jnp.where(idx < n, idx, n)  # n: no member (writes go to a spare row)
    active = idx < n
    out_shape = jax.eval_shape(lambda s: retire(s)[2], jax.tree.map(lambda a: a[0], slots))
    outputs = jax.tree.map(lambda s: jnp.zeros((n + 1,) + s.shape, s.dtype), out_shape)
    carry = (slots, member, active, jnp.asarray(min(C, n)), outputs)

    for k, C in enumerate(widths):
        if k:  # pack the survivors into the first C slots (stable: active ones first)
            slots, member, active, queued, outputs = carry
            keep = jnp.argsort(~active, stable=True)[:C]
            slots = jax.tree.map(lambda a: a[keep], slots)  # noqa: B023
            carry = (slots, member[keep], active[keep], queued, outputs)
        narrower = widths[k + 1] if k + 1 < len(widths) else 0

        def cond(c, narrower=narrower):
            _, _, active, queued, _ = c
            return jnp.any(active) & ((queued < n) | (jnp.sum(active) > narrower))

        retired = max(C // 4, 1)

        def body(c, R=retired):
            slots, member, active, queued, outputs = c
            slots = jax.vmap(k_steps)(slots, active)
            finished = active & ~v_running(slots)
            # up to R stopped slots are retired and refilled per round (any others idle until the
            # next): retiring and restarting every slot, then selecting, moved the whole batch's
            # state several times a round, as much as two solver steps at C = 128
            pick = jnp.argsort(~finished, stable=True)[:R]
            picked = finished[pick]
            sub = jax.tree.map(lambda a: a[pick], slots)
            again, restarted, out = v_retire(sub)
            done = picked & ~again
            rows = jnp.where(done, member[pick], n)
            outputs = jax.tree.map(lambda buf, o: buf.at[rows].set(o), outputs, out)
            new = queued + jnp.cumsum(done) - 1  # queue positions for the freed slots
            refill = done & (new < n)
            sub = _select(picked & again, restarted, sub)
            sub = _select(refill, v_start(jnp.clip(new, 0, n - 1)), sub)
            slots = jax.tree.map(lambda a, b: a.at[pick].set(b), slots, sub)
            member = member.at[pick].set(jnp.where(refill, new, jnp.where(done, n, member[pick])))
            active = active.at[pick].set((active[pick] & ~done) | refill)
            return slots, member, active, jnp.minimum(queued + jnp.sum(done), n), outputs

        carry = jax.lax.while_loop(cond, body, carry)
    return jax.tree.map(lambda a: a[:n], carry[4])
